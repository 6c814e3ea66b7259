r"""One parameter set fitted to several measured curves (specimen sizes) of one fabric, and its predictions.

Each curve runs on its own specimen (the keys of its data file's header applied to the scene)
with load steps landing on its fitted displacements (:mod:`ngbet.calibration.data`); the force and
its derivatives with respect to the parameters come from the same run
(:func:`ngbet.continuum.sensitivity.force_path`). Each curve's mesh is made once and reused by
every model run of the fit.

Least squares on the residuals e_i = (F_model(u_i) − F_i)/s_i, s_i the point's standard deviation
(:meth:`MeasuredCurve.sd`: half the printed error bar where the file has error bars, floored by
the reading error and 1 % of the force), in θ = ln p within the bounds of the scene's
``[calibration]`` table (:func:`scipy.optimize.least_squares`, trust region reflective). The
covariance of θ is s²(JᵀJ)⁻¹ with s² = Σe²/(m − n): error bars that do not cover the misfit are
scaled up by it (never down: s² >= 1). A measured mid-axis profile and centre shear angles of the
first curve's specimen (:mod:`ngbet.calibration.observations`) add their residuals over their
standard deviations.

Every model run is within a stated discretization error: the fit chooses each curve's mesh and
order from :data:`FIT_LADDER` (graded towards the clamp corners), coarse to fine, by the estimated
force error at the fitted points (:mod:`ngbet.continuum.estimate`); fit.json records the largest
estimate per curve. A single curve (one specimen size) fitted with the scene's own parameters holds
the bending stiffnesses, which one size cannot determine (:func:`held_parameters`).

A prediction of another specimen is the fitted scene run there, with the standard deviation
√(g Σ gᵀ + δ²): g = dF/dθ from the same run, Σ the covariance of θ, and δ the estimated
discretization error of that run (where the estimate cannot vouch, the change of the force when
the displacement order rises by one).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..continuum.estimate import Rung
from ..scene import Scene, SceneError
from ..scene.physical import Specimen
from .data import RANGE, MeasuredCurve
from .observations import Profile, ShearAngles

log = logging.getLogger(__name__)

TABLE_KEY = "material.shear_stress_steps_Pa"
#: without bounds in the scene, each parameter stays within this factor of its start value
BOUND_FACTOR = 1e4


def expand_params(scene: Scene, params: Sequence[str]) -> list[str]:
    """The scalar parameters: a list key such as the table's rises stands for each entry."""
    out: list[str] = []
    for p in params:
        section, _, key = p.partition(".")
        v = getattr(scene.material, key, None) if section == "material" else None
        if isinstance(v, tuple):
            if not v:
                raise SceneError(f"parameter '{p}' is an empty list in the scene: nothing to fit")
            out += [f"{p}[{j}]" for j in range(len(v))]
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out.append(p)
        else:
            raise SceneError(f"parameter '{p}' is not a material key of the scene (e.g. material.K_el)")
    from ..continuum.sensitivity import DIFFERENTIABLE, _table_index

    for p in out:
        key = p.partition(".")[2]
        if key not in DIFFERENTIABLE and _table_index(key) is None:
            raise SceneError(f"parameter '{p}': ngbet cannot differentiate the force with respect to it; known: "
                             f"{', '.join('material.' + k for k in DIFFERENTIABLE)}")
    return out


def value_of(scene: Scene, name: str) -> float:
    """The start value of a scalar parameter (a table entry too)."""
    from ..continuum.sensitivity import material_value

    return material_value(scene, name.partition(".")[2])


def with_values(scene: Scene, names: Sequence[str], values: Sequence[float]) -> Scene:
    """``scene`` with the scalar parameters ``names`` set (table entries written back as one list)."""
    steps = list(scene.material.shear_stress_steps_Pa)
    changes: dict[str, Any] = {}
    for n, v in zip(names, values, strict=True):
        if n.startswith(TABLE_KEY + "["):
            steps[int(n[len(TABLE_KEY) + 1:-1])] = float(v)
            changes[TABLE_KEY] = steps
        else:
            changes[n] = float(v)
    return scene.with_changes(**changes)


def bounds(scene: Scene, params: Sequence[str], names: Sequence[str],
           start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of each scalar parameter: the scene's [calibration] lower/upper, else start x 1e∓4."""
    cal = scene.calibration
    lo, hi = start / BOUND_FACTOR, start * BOUND_FACTOR
    for k, n in enumerate(names):
        base = n.partition("[")[0]
        if base in params and base in cal.params:
            j = cal.params.index(base)
            if cal.lower:
                lo[k] = cal.lower[j]
            if cal.upper:
                hi[k] = cal.upper[j]
    return lo, hi


def test_changes(curve: MeasuredCurve) -> dict[str, Any]:
    """The scene keys of the curve's test and specimen.

    Its header's specimen keys; for a picture-frame curve ``test = "picture_frame"`` and its frame
    (the specimen's length and width, which the frame does not read, at their defaults so that no
    warning names them).
    """
    changes: dict[str, Any] = dict(curve.specimen)
    if curve.test == "picture_frame":
        sp = Specimen()
        changes.update({"test": "picture_frame", **curve.frame, "specimen.length_mm": sp.length_mm,
                        "specimen.width_mm": sp.width_mm})
    return changes


def curve_scene(scene: Scene, curve: MeasuredCurve, u_mm: np.ndarray) -> Scene:
    """The scene on the curve's specimen (its header keys), loaded to its last fitted displacement.

    A picture-frame curve: the same material in the picture-frame test (``test = "picture_frame"``)
    with the frame of the file's header, loaded to its last fitted crosshead travel.
    """
    changes = test_changes(curve)
    changes.update({"loading.u0_mm": float(u_mm.max()), "loading.stops_mm": []})
    frame = curve.test == "picture_frame"
    try:
        sc = scene.with_changes(**changes)
    except SceneError as exc:
        raise SceneError(f"{curve.source}: its specimen keys do not make a valid scene: {exc}") from None
    if frame:
        return sc
    if u_mm.max() >= sc.specimen.locking_u0_mm * 1.2:
        raise SceneError(f"{curve.source}: the fitted points reach {u_mm.max():g} mm, far beyond the ideal yarn "
                         f"locking of its {sc.specimen.width_mm:g} x {sc.specimen.length_mm:g} mm specimen "
                         f"({sc.specimen.locking_u0_mm:.1f} mm): are the header's specimen keys right?")
    return sc


def portable_scene(scene: Scene) -> Scene:
    """The fitted scene without the load of one specimen: it runs on any other as it is."""
    return scene.with_changes(**{"loading.stops_mm": [], "loading.u0_mm": 0.8 * scene.specimen.locking_u0_mm})


#: the discretizations of a fit's model runs, cheapest first, all graded towards the clamp corners
#: (:class:`ngbet.continuum.estimate.Rung`: mesh size, corner mesh size [mm], order p). Measured on
#: the unbalanced twill 100 x 250 mm to 49.7 mm with its start values (16 loads): the estimated force
#: error is at most 1.2 % on the first rung (1.4 s a run), 0.2 % on the second (1.2-1.6 s), 0.07 %
#: on the third (2.6 s), against 17.5 % on the scene's uniform 25 mm mesh at p = 2 (0.9 s)
FIT_LADDER = tuple(Rung(h, c, p, math.nan) for h, c, p in (
    (40.0, 1.0, 2), (40.0, 1.0, 3), (20.0, 0.25, 3), (20.0, 0.25, 4), (20.0, 0.25, 5), (20.0, 0.25, 6)))
#: the coarse stage's rung: the search gets near the optimum there, unchecked
COARSE_LEVEL = 0
#: the first rung whose estimated error is checked against the target
FIRST_CHECKED = 1
#: tolerance (xtol, ftol) of the search on the checked rungs: a relative change of the cost Σe² below
#: 1e-4 changes it by far less than 1 (the change that moves a parameter by one standard error) on
#: the costs of the shipped fits (50–250), and steps below 1e-4 of |ln p| move no parameter by a
#: visible amount. Measured on the unbalanced twill's two sizes: with 1e-6 the fit stopped at its 40
#: runs (31 on the checked rung) without converging; with 1e-4 it converged in 25 (13 on it) to the
#: same values (K_el 3.86 MPa both, RMS 3.9 % and 5.1 % both)
FINE_TOL = 1e-4
#: default largest estimated discretization error of the force at a fitted point, relative to it
TARGET_ERROR = 0.01
#: standard error of ln p above which a parameter is reported as undetermined (its 95 % interval
#: then spans more than a factor e^(1.96·0.5) ≈ 2.7 either way)
UNDETERMINED_SE = 0.5
#: singular values of J below this fraction of the largest are flat directions
FLAT_RCOND = 1e-3
#: |correlation| above which a pair of parameters is reported as strongly correlated
STRONG_CORRELATION = 0.95
#: what one specimen size cannot determine: held at the scene's values when the parameters are
#: the scene's own and every curve has the same specimen (the size effect needs two sizes)
SIZE_PARAMS = ("material.alpha1", "material.alpha2")


@dataclass
class CurveFit:
    """One curve of a fit: the fitted points, the model on them and its discretization.

    ``profile`` and ``angles``: observations of the same specimen fitted with its force.
    """

    curve: MeasuredCurve
    scene: Scene
    u_mm: np.ndarray
    measured_N: np.ndarray
    sd_N: np.ndarray
    profile: Profile | None = None
    angles: ShearAngles | None = None
    level: int | None = FIRST_CHECKED  # the rung of FIT_LADDER; None: the scene's own discretization
    model_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    start_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dlogp: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    force_error_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    profile_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angles_model_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def label(self) -> str:
        """"W x L mm": the specimen the curve runs on (its header's, else the scene's); "frame F/f mm"."""
        if self.curve.test == "picture_frame":
            return self.curve.label
        sp = self.scene.specimen
        return f"{sp.width_mm:g} x {sp.length_mm:g} mm"

    def measured_on_specimen(self) -> MeasuredCurve:
        """The measured curve with the specimen keys it runs on (the scene's where its header gives none)."""
        if self.curve.test == "picture_frame":
            return self.curve
        sp = self.scene.specimen
        keys = {"specimen.width_mm": sp.width_mm, "specimen.length_mm": sp.length_mm,
                "specimen.thickness_mm": sp.thickness_mm, **self.curve.specimen}
        return dataclasses.replace(self.curve, specimen=keys)

    @property
    def rms_relative(self) -> float:
        """RMS of (model − measured)/measured over the fitted points."""
        return float(np.sqrt(np.mean(((self.model_N - self.measured_N) / self.measured_N) ** 2)))

    @property
    def error_rel_max(self) -> float:
        """The largest estimated discretization error of the model force relative to it (nan: not vouched)."""
        if len(self.force_error_N) == 0 or not np.all(np.isfinite(self.force_error_N)):
            return math.nan
        return float(np.max(self.force_error_N / np.abs(self.model_N)))

    def run_scene(self) -> Scene:
        """The curve's scene on its rung of :data:`FIT_LADDER` (level None: on the scene's discretization)."""
        return self.scene if self.level is None else FIT_LADDER[self.level].apply(self.scene)

    def ideal_angle_deg(self) -> np.ndarray:
        """The centre shear angle of the ideal test (inextensible yarns, pin-jointed) at the fitted points [deg]."""
        from ..kinematics import frame_shear_angle_rad, shear_angle_rad

        if self.curve.test == "picture_frame":
            return np.degrees(frame_shear_angle_rad(self.u_mm, self.scene.picture_frame.frame_mm))
        sp = self.scene.specimen
        return np.degrees(shear_angle_rad(self.u_mm, sp.length_mm, sp.width_mm))


@dataclass
class JointFit:
    """What :func:`fit_curves` found; :meth:`to_json` is the content of fit.json."""

    params: list[str]
    names: list[str]
    values: np.ndarray
    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    cov_log: np.ndarray
    curves: list[CurveFit]
    scene: Scene
    noise_scale: float
    model_runs: int
    wall_s: float
    converged: bool
    message: str
    at_bound: list[str]
    held: dict[str, str] = field(default_factory=dict)
    undetermined: dict[str, str] = field(default_factory=dict)
    correlated: list[tuple[str, str, float]] = field(default_factory=list)
    flat_directions: list[dict[str, float]] = field(default_factory=list)
    residual_scale: float = math.nan
    target_error: float = TARGET_ERROR
    stages: list[dict[str, Any]] = field(default_factory=list)
    profile_sd_mm: float = 1.0
    angle_sd_deg: float = 1.0

    @property
    def se_log(self) -> np.ndarray:
        """Standard errors of ln p."""
        return np.sqrt(np.abs(np.diag(self.cov_log)))

    @property
    def accuracy_met(self) -> bool:
        """Every curve's largest estimated discretization error is within the target."""
        return all(c.error_rel_max <= self.target_error for c in self.curves)

    def to_json(self) -> dict[str, Any]:  # noqa: C901 - one record after the other
        """The content of fit.json."""
        se = self.se_log
        n = len(self.names)
        corr = _correlation(self.cov_log)

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        def curve(c: CurveFit) -> dict[str, Any]:
            d = c.run_scene().discretization
            doc: dict[str, Any] = {"data": c.curve.source, "test": c.curve.test}
            if c.curve.test == "picture_frame":  # the fit in the file's own quantities too
                x, y = c.curve.in_file_units(c.u_mm, c.measured_N)
                doc["frame"] = c.curve.frame
                doc["file_quantities"] = {"shear_angle_deg": x.tolist(), "quantity": c.curve.quantity,
                                          "measured": y.tolist(),
                                          "model": c.curve.in_file_units(c.u_mm, c.model_N)[1].tolist()}
            doc |= {"specimen": c.curve.specimen, "points": len(c.u_mm),
                   "range_mm": [float(c.u_mm.min()), float(c.u_mm.max())],
                   "rms_relative_error": c.rms_relative, "u_mm": c.u_mm.tolist(),
                   "measured_N": c.measured_N.tolist(), "sd_N": c.sd_N.tolist(), "model_N": c.model_N.tolist(),
                   "start_N": c.start_N.tolist(), "band_N": band(c.dlogp, self.cov_log).tolist(),
                   "discretization": {"mesh_size_mm": d.mesh_size_mm, "corner_mesh_size_mm": d.corner_mesh_size_mm,
                                      "order_u": d.order_u, "chosen_by_fit": c.level is not None},
                   "force_error_rel_max": num(c.error_rel_max),
                   "force_error_N": [num(v) for v in c.force_error_N],
                   "shear_angle_deg": c.angle_deg.tolist(), "shear_angle_ideal_deg": c.ideal_angle_deg().tolist()}
            if c.profile is not None:
                Pd = c.profile.measured()
                doc["profile"] = {"data": c.profile.source, "points": len(Pd), "sd_mm": self.profile_sd_mm,
                                  "rms_mm": float(np.sqrt(np.mean((c.profile_mm - Pd) ** 2))),
                                  "u0_mm": np.concatenate([[u0] * len(x) for u0, x in c.profile.points().items()]
                                                          ).tolist(),
                                  "X_mm": np.concatenate(list(c.profile.points().values())).tolist(),
                                  "measured_mm": Pd.tolist(), "model_mm": c.profile_mm.tolist()}
            if c.angles is not None:
                a = c.angles
                doc["shear_angle_data"] = {
                    "data": a.source, "points": len(a.u_mm), "sd_deg": self.angle_sd_deg,
                    "rms_deg": float(np.sqrt(np.mean((c.angles_model_deg - a.angle_deg) ** 2))),
                    "u_mm": a.u_mm.tolist(), "measured_deg": a.angle_deg.tolist(),
                    "model_deg": c.angles_model_deg.tolist()}
            return doc

        return {
            "parameters": {nm: {"value": float(self.values[k]), "start": float(self.start[k]),
                                "standard_error": num(self.values[k] * se[k]), "standard_error_log": num(se[k]),
                                "bounds": [float(self.lower[k]), float(self.upper[k])],
                                "at_bound": nm in self.at_bound, "determined": nm not in self.undetermined}
                           for k, nm in enumerate(self.names)},
            "held": {p: {"value": value_of(self.scene, p), "why": why} for p, why in self.held.items()},
            "undetermined": self.undetermined,
            "strongly_correlated": [{"params": [a, b], "correlation": c} for a, b, c in self.correlated],
            "flat_directions": self.flat_directions,
            "correlation": [[num(corr[i, j]) for j in range(n)] for i in range(n)],
            "covariance_log": [[float(x) for x in row] for row in self.cov_log],
            "noise_scale": self.noise_scale, "residual_scale": self.residual_scale,
            "model_runs": self.model_runs, "wall_s": self.wall_s,
            "converged": self.converged, "optimizer_message": self.message,
            "accuracy": {"target_error": self.target_error, "met": self.accuracy_met,
                         "force_error_rel_max": {c.label: num(c.error_rel_max) for c in self.curves},
                         "stages": self.stages},
            "curves": [curve(c) for c in self.curves],
        }


def band(dlogp: np.ndarray, cov_log: np.ndarray) -> np.ndarray:
    """√diag(G Σ Gᵀ) [N]: the force's standard deviation from the parameters."""
    return np.sqrt(np.maximum(np.einsum("ik,kl,il->i", dlogp, cov_log, dlogp), 0.0))


def _correlation(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = cov / np.outer(d, d)
    return np.where(np.isfinite(c), c, np.nan)


@dataclass
class _Run:
    """One model run of a curve: force, dF/dθ, profile, angles (at the data's loads) and their dθ."""

    F: np.ndarray
    G: np.ndarray
    P: np.ndarray
    GP: np.ndarray
    A: np.ndarray
    GA: np.ndarray
    err: np.ndarray
    angle: np.ndarray  # the centre shear angle at the fitted points (checked runs only)


class _Model:
    """Every curve's observations and their Jacobian at θ = ln p, cached by θ and the discretizations.

    Each curve's mesh is made once per rung and reused. ``check=True`` adds the discretization
    error estimate at the fitted points and the centre shear angle there.
    """

    def __init__(self, curves: list[CurveFit], names: list[str]) -> None:
        self.curves, self.names = curves, names
        self.meshes: dict[tuple[int, int | None], Any] = {}
        self.runs = 0
        self._cache: dict[tuple[bytes, tuple[int | None, ...], bool], list[_Run]] = {}

    def __call__(self, theta: np.ndarray, check: bool = False) -> list[_Run]:
        key = (np.asarray(theta, float).tobytes(), tuple(c.level for c in self.curves), check)
        if key in self._cache:
            return self._cache[key]
        if not check:  # a checked run answers an unchecked question too
            hit = self._cache.get((key[0], key[1], True))
            if hit is not None:
                return hit
        from ..continuum.mesh import make_cross_mesh, make_mesh
        from ..continuum.sensitivity import force_path
        from ..errors import ConvergenceError

        self.runs += 1
        out = []
        n = len(self.names)
        for k, c in enumerate(self.curves):
            sc = with_values(c.run_scene(), self.names, np.exp(theta))
            if (k, c.level) not in self.meshes:
                self.meshes[k, c.level] = (make_cross_mesh(sc.picture_frame, sc.specimen, sc.discretization)
                                           if sc.test == "picture_frame" else make_mesh(sc.specimen, sc.discretization))
            pts = c.profile.points() if c.profile is not None else {}
            a_u = list(c.angles.u_mm) if c.angles is not None else []
            m, kp, ka = len(c.u_mm), sum(len(x) for x in pts.values()), len(a_u)
            try:
                r = force_path(sc, c.u_mm, self.names, pts, mesh=self.meshes[k, c.level],
                               angles=sorted(set(a_u) | (set(map(float, c.u_mm)) if check else set())),
                               estimate=check)
                assert r.dlogp is not None
                P = np.concatenate([r.profiles[u0] for u0 in pts]) if pts else np.zeros(0)
                GP = np.vstack([r.profile_dlogp[u0] for u0 in pts]) if pts else np.zeros((0, n))
                A = np.array([r.angles_deg[float(u)] for u in a_u])
                GA = np.vstack([r.angle_dlogp[float(u)] for u in a_u]) if a_u else np.zeros((0, n))
                err = r.force_error_N if r.force_error_N is not None else np.zeros(0)
                ang = np.array([r.angles_deg[float(u)] for u in c.u_mm]) if check else np.zeros(0)
                out.append(_Run(r.force_N, r.dlogp, P, GP, A, GA, err, ang))
            except (ConvergenceError, SceneError) as exc:
                log.info("model run failed on %s: %s", c.label, exc)
                out.append(_Run(np.full(m, np.nan), np.zeros((m, n)), np.full(kp, np.nan), np.zeros((kp, n)),
                                np.full(ka, np.nan), np.zeros((ka, n)), np.full(m if check else 0, np.nan),
                                np.full(m if check else 0, np.nan)))
        self._cache[key] = out
        return out


Progress = Callable[[int, list[float], float], None]


def terminal_progress(stream: Any = None) -> Progress:
    """A progress line on the terminal: model runs, each curve's RMS, elapsed time."""
    stream = stream or sys.stderr
    tty = hasattr(stream, "isatty") and stream.isatty()
    t0 = time.perf_counter()

    def show(runs: int, rms: list[float], best: float) -> None:
        text = (f"ngbet fit: model run {runs}, RMS " + ", ".join(f"{100 * r:.1f} %" for r in rms)
                + f" (best cost {best:.4g}), {time.perf_counter() - t0:.0f} s")
        stream.write(("\r" + text + "\x1b[K") if tty else text + "\n")
        stream.flush()

    return show


def held_parameters(curves: Sequence[MeasuredCurve], scene: Scene, params: Sequence[str],
                    profile: Profile | None) -> dict[str, str]:
    """The scene's parameters one specimen size cannot determine, with why: {key: reason}.

    One size (every curve on the same specimen) and no mid-axis profile: the bending
    stiffnesses (:data:`SIZE_PARAMS`) set the size effect, which one size does not show.
    """
    sizes = {(c.specimen.get("specimen.width_mm", scene.specimen.width_mm),
              c.specimen.get("specimen.length_mm", scene.specimen.length_mm)) if c.test != "picture_frame"
             else tuple(c.frame.values()) for c in curves}
    if len(sizes) > 1 or profile is not None:
        return {}
    return {p: ("one specimen size: the bending stiffnesses set the size effect, which one size does not show "
                "(measured: they end at their bounds with se(ln p) of 1e3 and more); held at the scene's value. "
                "A second specimen size (e.g. 100 x 200 mm beside 100 x 300 mm) or a measured mid-axis profile "
                "(--profile) determines them")
            for p in params if p in SIZE_PARAMS}


def fit_curves(curves: Sequence[MeasuredCurve], scene: Scene, params: Sequence[str] | None = None,  # noqa: C901
               max_runs: int = 40, progress: Progress | None = None,
               fractions: Sequence[tuple[float, float]] | None = None, *, target_error: float = TARGET_ERROR,
               profile: Profile | None = None, profile_sd_mm: float = 1.0, angles: ShearAngles | None = None,
               angle_sd_deg: float = 1.0, resample: bool = True, coarse: bool = True,
               choose_discretization: bool = True) -> JointFit:
    """Fit ``params`` (default: the scene's ``calibration.params``) to all ``curves`` at once.

    ``fractions``: the part of each curve's displacement range fitted (default 10–90 %).
    ``resample``: the curve sampled at :data:`ngbet.calibration.data.POINTS_PER_CURVE` equally
    spaced displacements (False: its own points in the range).

    Discretization: every curve runs on a rung of :data:`FIT_LADDER` chosen by the fit. The search
    starts on :data:`COARSE_LEVEL` (``coarse``), continues on :data:`FIRST_CHECKED`, and at its end
    the discretization error of the force is estimated at every fitted point
    (:class:`ngbet.continuum.estimate.ForceErrorEstimator`); a curve whose largest estimate is above
    ``target_error`` of its force (or cannot be vouched for) moves one rung up and the search
    continues from where it stood, until every curve meets the target or ``max_runs`` are spent.
    The result records each curve's rung and largest estimate (``accuracy_met`` says whether the
    target was met). ``choose_discretization=False``: every run on the scene's own discretization,
    its estimate recorded all the same.

    ``profile`` (mid-axis u_y) and ``angles`` (centre shear angle) are observations of the first
    curve's specimen, fitted with its force with the standard deviations ``profile_sd_mm`` and
    ``angle_sd_deg``.

    With ``params`` None and every curve of one specimen size (and no profile), the bending
    stiffnesses are held at the scene's values (:func:`held_parameters`; the result's ``held``).
    """
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    if scene.model != "continuum":
        raise SceneError(f"model = {scene.model!r}: ngbet fit calibrates the continuum model")
    if not curves:
        raise SceneError("no measured curve to fit")
    own = not params
    params = list(params) if params else list(scene.calibration.params)
    if not params:
        raise SceneError("no parameters to fit: give --params, or name them in the scene's [calibration] params")
    if not isinstance(max_runs, int) or max_runs < 1:
        raise SceneError(f"--max-runs = {max_runs!r}: must be an integer >= 1")
    if not (0 < target_error < 1):
        raise SceneError(f"--accuracy = {target_error!r}: the largest discretization error of the force relative "
                         "to it, between 0 and 1 (e.g. 0.01)")
    if not (profile_sd_mm > 0 and angle_sd_deg > 0):
        raise SceneError(f"--profile-sd = {profile_sd_mm}, --angle-sd = {angle_sd_deg}: both must be > 0")
    held = held_parameters(curves, scene, params, profile) if own else {}
    fitted_params = [p for p in params if p not in held]
    names = expand_params(scene, fitted_params)
    start = np.array([value_of(scene, n) for n in names])
    bad = [n for n, v in zip(names, start, strict=True) if not v > 0]
    if bad:
        raise SceneError(f"parameter(s) {', '.join(bad)}: the fit works on ln p and needs positive start values")
    lo, hi = bounds(scene, fitted_params, names, start)
    start = np.clip(start, lo * (1 + 1e-9), hi * (1 - 1e-9))
    cfs = []
    for k, c in enumerate(curves):
        frac = fractions[k] if fractions is not None else RANGE
        if resample:
            u, F = c.sample(fraction=frac)
        else:
            a, b = c.window(frac)
            inside = (c.u_mm >= a) & (c.u_mm <= b) & (c.u_mm > 0)
            u, F = c.u_mm[inside], c.force_N[inside]
        sc = curve_scene(scene, c, u)
        prof = ang = None
        if k == 0 and profile is not None:
            prof = profile.inside(sc.specimen.length_mm)
            if len(prof.X_mm) == 0:
                raise SceneError(f"profile {profile.source}: no point strictly between the clamps (0 < X < L)")
        if k == 0 and angles is not None:
            ang = angles
            reach = max(float(np.max(ang.u_mm)), float(u.max()))
            sc = sc.with_changes(**{"loading.u0_mm": reach})
        cfs.append(CurveFit(c, sc, u, F, c.sd(u, F), prof, ang, FIRST_CHECKED if choose_discretization else None))
    model = _Model(cfs, names)
    best = [math.inf]
    quiet = [False]

    def blocks(res: list[_Run]) -> np.ndarray:
        e = []
        for r, c in zip(res, cfs, strict=True):
            e.append((r.F - c.measured_N) / c.sd_N)
            if c.profile is not None:
                e.append((r.P - c.profile.measured()) / profile_sd_mm)
            if c.angles is not None:
                e.append((r.A - c.angles.angle_deg) / angle_sd_deg)
        return np.concatenate(e)

    def resid(theta: np.ndarray) -> np.ndarray:
        res = model(theta)
        e = blocks(res)
        e = np.where(np.isfinite(e), e, 1e3)
        cost = float(e @ e)
        best[0] = min(best[0], cost)
        if progress is not None and not quiet[0]:
            progress(model.runs, [float(np.sqrt(np.mean(((r.F - c.measured_N) / c.measured_N) ** 2)))
                                  for r, c in zip(res, cfs, strict=True)], best[0])
        return e

    def jac(theta: np.ndarray) -> np.ndarray:
        rows = []
        for r, c in zip(model(theta), cfs, strict=True):
            rows.append(r.G / c.sd_N[:, None])
            if c.profile is not None:
                rows.append(r.GP / profile_sd_mm)
            if c.angles is not None:
                rows.append(r.GA / angle_sd_deg)
        return np.vstack(rows)

    def search(theta: np.ndarray, runs: int, tol: float) -> Any:
        return least_squares(resid, theta, jac=jac, bounds=(np.log(lo), np.log(hi)), method="trf", x_scale=1.0,
                             max_nfev=max(runs, 1), xtol=tol, ftol=tol, gtol=1e-8)

    th0 = np.log(start)
    th = th0
    stages: list[dict[str, Any]] = []
    sol = None
    if coarse and choose_discretization and max_runs > 2:
        for cf in cfs:
            cf.level = COARSE_LEVEL
        r0, ts = model.runs, time.perf_counter()
        sol = search(th, max_runs // 2, 1e-3)
        th = sol.x
        stages.append({"rungs": [COARSE_LEVEL] * len(cfs), "model_runs": model.runs - r0, "checked": False,
                       "wall_s": time.perf_counter() - ts})
        for cf in cfs:
            cf.level = FIRST_CHECKED
    while True:
        r0, ts = model.runs, time.perf_counter()
        left = max_runs - model.runs
        if left >= 1 or sol is None:
            sol = search(th, max(left, 1), FINE_TOL)
            th = sol.x
        checked = model(th, check=True)
        for cf, r in zip(cfs, checked, strict=True):
            cf.force_error_N = r.err
            cf.model_N = r.F
        stage = {"rungs": [cf.level for cf in cfs], "model_runs": model.runs - r0, "checked": True,
                 "force_error_rel_max": [None if math.isnan(cf.error_rel_max) else cf.error_rel_max for cf in cfs],
                 "wall_s": time.perf_counter() - ts}
        stages.append(stage)
        up = [cf for cf in cfs if not cf.error_rel_max <= target_error and cf.level is not None
              and cf.level < len(FIT_LADDER) - 1]
        if not up or model.runs >= max_runs:
            break
        for cf in up:
            log.info("%s: estimated discretization error %.3g above %.3g: one rung up", cf.label,
                     cf.error_rel_max, target_error)
            cf.level = (cf.level or 0) + 1
    quiet[0] = True
    e, J = resid(th), jac(th)
    st = _statistics(e, J, names)
    for cf, r in zip(cfs, checked, strict=True):
        cf.model_N, cf.dlogp, cf.force_error_N, cf.angle_deg = r.F, r.G, r.err, r.angle
        cf.profile_mm, cf.angles_model_deg = r.P, r.A
    levels = [cf.level for cf in cfs]
    for cf, r in zip(cfs, model(th0), strict=True):  # the start values on the final discretizations
        cf.start_N = r.F
    assert [cf.level for cf in cfs] == levels
    values = np.exp(th)
    at_bound = [nm for nm, t, a, b in zip(names, th, np.log(lo), np.log(hi), strict=True)
                if t - a < 1e-3 or b - t < 1e-3]
    chosen = [lv for lv in levels if lv is not None]
    on = FIT_LADDER[max(chosen)].apply(scene) if chosen else scene
    fitted = portable_scene(with_values(on, names, values))
    ok = bool(sol.success and sol.status > 0)
    if not ok:
        # the caller says it (the command with its option, a study in its table): no advice from here
        log.info("the least-squares search stopped without converging after %d model runs (%s)", model.runs,
                 sol.message)
    return JointFit(fitted_params, names, values, np.exp(th0), lo, hi, st["cov"], cfs, fitted, st["noise_scale"],
                    model.runs, time.perf_counter() - t0, ok, str(sol.message), at_bound, held,
                    st["undetermined"], st["correlated"], st["flat"], st["residual_scale"], target_error, stages,
                    profile_sd_mm, angle_sd_deg)


#: what data would determine a parameter the fit leaves undetermined (by the start of its name)
WHAT_FIXES = {
    "material.shear_stress_steps_Pa": "what would fix it: a law with fewer coefficients (fewer rises, or the locking "
                                      "law), or data that reach the shear angles of this rise (a larger displacement, "
                                      "a picture-frame test)",
    "material.K_el": "what would fix it: measured shear angles (--angles; yarn elongation keeps them below the ideal "
                     "test's) or a bound on K_el from the yarns",
    "material.alpha": "what would fix it: another specimen size (another aspect ratio) or a measured mid-axis "
                      "profile (--profile)",
    "material.K_lock": "what would fix it: data further into the stiffening (larger displacements)",
    "material.gamma_lock_deg": "what would fix it: data further into the stiffening (larger displacements)",
}


def _statistics(e: np.ndarray, J: np.ndarray, names: list[str]) -> dict[str, Any]:
    """Covariance of θ = ln p from the SVD of J, and what the data leave undetermined.

    s² = Σe²/(m − n), floored at 1 (error bars that do not cover the misfit are scaled up, never
    down); ``residual_scale`` is s itself.
    """
    m, n = J.shape
    r2 = float(e @ e) / max(m - n, 1)
    s2 = max(r2, 1.0)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    # a vanishing singular value gives its direction a huge (not infinite) variance
    cov = s2 * (Vt.T / np.maximum(sv, 1e-150 + 1e-12 * sv[0]) ** 2) @ Vt
    se = np.sqrt(np.abs(np.diag(cov)))
    undetermined: dict[str, str] = {}
    flat = []
    for k in range(len(sv)):
        if sv[k] <= FLAT_RCOND * sv[0]:
            direction = {names[i]: float(Vt[k, i]) for i in range(n) if abs(Vt[k, i]) > 0.3}
            flat.append(direction)
            for p in direction:
                undetermined[p] = (f"on a flat direction of the fit (singular value {sv[k]:.3g}, "
                                   f"{sv[k] / sv[0]:.2g} of the largest): the data do not move it")
    for k, p in enumerate(names):
        if p not in undetermined and not se[k] <= UNDETERMINED_SE:
            undetermined[p] = (f"standard error of ln p = {se[k]:.3g} > {UNDETERMINED_SE}: its 95 % interval "
                               f"spans more than a factor {math.exp(1.96 * UNDETERMINED_SE):.1f} either way")
    for p in undetermined:
        hint = next((h for k, h in WHAT_FIXES.items() if p.startswith(k)), "")
        if hint:
            undetermined[p] += f"; {hint}"
    corr = _correlation(cov)
    pairs = [(names[i], names[j], float(corr[i, j])) for i in range(n) for j in range(i + 1, n)
             if abs(corr[i, j]) > STRONG_CORRELATION]
    return {"cov": cov, "undetermined": undetermined, "flat": flat, "correlated": pairs,
            "noise_scale": math.sqrt(s2), "residual_scale": math.sqrt(r2)}


@dataclass
class CurvePrediction:
    """The fitted model on another specimen: force, its standard deviation (parameters, discretization)."""

    u_mm: np.ndarray
    force_N: np.ndarray
    sd_param_N: np.ndarray
    sd_disc_N: np.ndarray
    scene: Scene

    @property
    def sd_N(self) -> np.ndarray:
        """The whole standard deviation [N]: parameters and discretization."""
        return np.sqrt(self.sd_param_N ** 2 + self.sd_disc_N ** 2)


def predict_specimen(result: JointFit, specimen: dict[str, float], u_mm: np.ndarray,
                     fixed_var_log: dict[str, float] | None = None) -> CurvePrediction:
    """The fitted scene on ``specimen`` (scene keys) at the displacements ``u_mm``, with its band.

    ``fixed_var_log``: parameters held fixed in the fit whose value is uncertain, with the
    variance of their ln p (independent of the fitted ones); they widen the band by g_k² var_k.
    """
    from ..continuum.sensitivity import force_path

    fixed = dict(fixed_var_log or {})
    sc = result.scene.with_changes(**specimen, **{"loading.u0_mm": float(np.max(u_mm)), "loading.stops_mm": []})
    r = force_path(sc, u_mm, [*result.names, *fixed], estimate=True)
    assert r.dlogp is not None and r.force_error_N is not None
    n = len(result.names)
    var = band(r.dlogp[:, :n], result.cov_log) ** 2 + (r.dlogp[:, n:] ** 2) @ np.array(list(fixed.values()))
    disc = np.abs(r.force_error_N)
    if not np.all(np.isfinite(disc)):  # where the estimate cannot vouch: the change one order up
        finer = sc.with_changes(**{"discretization.order_u": sc.discretization.order_u + 1})
        disc = np.where(np.isfinite(disc), disc, np.abs(force_path(finer, u_mm).force_N - r.force_N))
    return CurvePrediction(np.asarray(u_mm, float), r.force_N, np.sqrt(var), disc, sc)
