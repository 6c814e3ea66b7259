"""What a joint fit varies and what it found.

The parameters (names, values, bounds, the scene of each curve), the fit's discretization ladder
and tolerances, and the record of a fit (:class:`JointFit`, the content of fit.json).

Read and written by :func:`ngbet.calibration.joint.fit_curves`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..measured.curves import MeasuredCurve
from ..measured.observations import Profile, ShearAngles
from ..measured.table import errorbar_path
from ..runner.ladder import Climb, Rung
from ..scene.document import Scene
from ..scene.physical import SHEAR_LAW_KEYS, Specimen
from ..scene.validate import SceneError

__all__ = [
    "BOUND_FACTOR",
    "COARSE_LEVEL",
    "DOMAINS",
    "FINE_TOL",
    "FIRST_CHECKED",
    "FIT_LADDER",
    "FLAT_RCOND",
    "SIZE_PARAMS",
    "STALL_RUNS",
    "STEP_SE",
    "STRONG_CORRELATION",
    "TABLE_KEY",
    "TARGET_ERROR",
    "UNDETERMINED_SE",
    "WHAT_FIXES",
    "CurveFit",
    "JointFit",
    "band",
    "bounds",
    "correlation",
    "curve_scene",
    "expand_params",
    "gauss_newton_direction",
    "inverse_normal",
    "portable_scene",
    "rises_at_zero",
    "smoothness_rows",
    "test_changes",
    "unread",
    "value_of",
    "with_values",
]

#: what data would determine a parameter the fit leaves undetermined (by the start of its name)
WHAT_FIXES = {
    "material.shear_stress_steps_Pa": "what would fix it: a law with fewer coefficients (fewer rises, or the locking "
    "law), a smoothness prior on the rises ([calibration] table_smoothness_sd), or data that reach the "
    "shear angles of this rise (a larger displacement; the picture frame shears the fabric further than the "
    "bias-extension test)",
    "material.K_el": "what would fix it: measured shear angles (--angles; yarn elongation keeps them below the ideal "
    "test's) or a bound on K_el from the yarns",
    "material.alpha": "what would fix it: a bias-extension test of another specimen size (another aspect ratio) "
    "or a measured mid-axis profile (--profile)",
    "material.K_lock": "what would fix it: data further into the stiffening (larger displacements)",
    "material.gamma_lock_deg": "what would fix it: data further into the stiffening (larger displacements)",
}

TABLE_KEY = "material.shear_stress_steps_Pa"
#: without bounds in the scene, each parameter stays within this factor of its start value
BOUND_FACTOR = 1e4
#: parameters whose scene key has a bounded domain: the default bounds stay inside it (an angle
#: of 0 or 90 degrees is refused by the scene)
DOMAINS = {"material.gamma_lock_deg": (1.0, 89.0)}


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
    from ..continuum.sensitivity import DIFFERENTIABLE, table_index

    for p in out:
        key = p.partition(".")[2]
        if key not in DIFFERENTIABLE and table_index(key) is None:
            raise SceneError(
                f"parameter '{p}': ngbet cannot differentiate the force with respect to it; known: "
                f"{', '.join('material.' + k for k in DIFFERENTIABLE)}"
            )
    for p in params:
        why = unread(scene, p)
        if why:
            raise SceneError(f"parameter '{p}' has no effect on the force in this scene: {why}")
    return out


def unread(scene: Scene, key: str) -> str:
    """Why the scene's energy does not read the material key ``key`` ("material.K_sh"); "" where it does.

    A shear law's coefficient under another law (:data:`ngbet.scene.physical.SHEAR_LAW_KEYS`, the
    keys each law reads), or without shear energy; a bending stiffness without bending; K_el
    without yarn elongation. A fit of such a key would report whatever its start value is.
    """
    name = key.partition(".")[2]
    e = scene.effects
    if name in {k for keys in SHEAR_LAW_KEYS.values() for k in keys}:
        if not e.shear:
            return "effects.shear = false: the scene has no shear energy"
        if name not in SHEAR_LAW_KEYS[e.shear_law]:
            law = SHEAR_LAW_KEYS[e.shear_law]
            return (
                f"the scene's shear law (effects.shear_law = {e.shear_law!r}) does not read it; it reads "
                f"{', '.join('material.' + k for k in law)}. Fit a key the law reads, or choose the law "
                f"whose key it is (--set effects.shear_law={next(n for n, ks in SHEAR_LAW_KEYS.items() if name in ks)})"
            )
    flag = {"alpha1": "bending", "alpha2": "bending", "K_el": "elongation"}.get(name)
    if flag and not getattr(e, flag):
        return f"effects.{flag} = false: the scene has no {flag} energy"
    return ""


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
            steps[int(n[len(TABLE_KEY) + 1 : -1])] = float(v)
            changes[TABLE_KEY] = steps
        else:
            changes[n] = float(v)
    return scene.with_changes(**changes)


def smoothness_rows(names: Sequence[str], sd: float) -> np.ndarray:
    """The rows of the table's smoothness prior on θ = ln p: a (rows, len(names)) matrix P.

    One row (ln r_(j-1) − 2 ln r_j + ln r_(j+1))/``sd`` for each three consecutive rises r of
    the shear table among ``names``; none for ``sd`` = 0 or fewer than three rises. The fit appends
    P θ to its residuals and P to its Jacobian: a Gaussian prior of standard deviation ``sd`` on
    the second differences of ln r (a P-spline's second-order penalty on the logarithm of the rises).

    Why: a rise at shear angles the fitted curves barely reach lies on a flat direction of the fit
    and ends wherever the search leaves it, often at a bound; the prior continues the geometric
    trend of its neighbours there. Its rows weigh as the data's residuals do, each in units of its
    standard deviation: where the misfit is s times the error bars, the covariance scales the
    prior's variance by s² as it scales theirs.
    """
    idx = {int(n[len(TABLE_KEY) + 1 : -1]): k for k, n in enumerate(names) if n.startswith(TABLE_KEY + "[")}
    rows = []
    if sd > 0:
        for j in sorted(idx):
            if j - 1 in idx and j + 1 in idx:
                row = np.zeros(len(names))
                row[[idx[j - 1], idx[j], idx[j + 1]]] = np.array([1.0, -2.0, 1.0]) / sd
                rows.append(row)
    return np.array(rows).reshape(len(rows), len(names))


def bounds(
    scene: Scene, params: Sequence[str], names: Sequence[str], start: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of each scalar parameter: the scene's [calibration] lower/upper, else start x 1e∓4 within its domain.

    The domain (:data:`DOMAINS`) holds for the default bounds only: bounds the scene gives outside it
    are the scene's to answer for (the scene refuses the value when the fit reaches it).
    """
    cal = scene.calibration
    lo, hi = start / BOUND_FACTOR, start * BOUND_FACTOR
    for k, n in enumerate(names):
        base = n.partition("[")[0]
        if base in DOMAINS:
            lo[k], hi[k] = max(lo[k], DOMAINS[base][0]), min(hi[k], DOMAINS[base][1])
        if base in params and base in cal.params:
            j = cal.params.index(base)
            if cal.lower:
                lo[k] = cal.lower[j]
            if cal.upper:
                hi[k] = cal.upper[j]
    return lo, hi


def test_changes(curve: MeasuredCurve) -> dict[str, Any]:
    """The scene keys of the curve's test and specimen: the curve runs the test its file names, whatever the scene's.

    A bias-extension curve: ``test = "bias_extension"`` and its header's specimen keys (none: the
    scene's specimen). A picture-frame curve: ``test = "picture_frame"`` and its frame (the
    specimen's length and width, which the frame does not read, at their defaults so that no
    warning names them).
    """
    changes: dict[str, Any] = {"test": curve.test, **curve.specimen}
    if curve.test == "picture_frame":
        sp = Specimen()
        changes.update({**curve.frame, "specimen.length_mm": sp.length_mm, "specimen.width_mm": sp.width_mm})
    return changes


def curve_scene(scene: Scene, curve: MeasuredCurve, u_mm: np.ndarray) -> Scene:
    """The scene on the curve's specimen (its header keys), loaded to its last fitted displacement.

    A picture-frame curve: the same material in the picture-frame test (``test = "picture_frame"``)
    with the frame of the file's header, loaded to its last fitted crosshead travel.
    """
    changes = test_changes(curve)
    changes.update({"loading.u0_mm": float(u_mm.max()), "loading.stops_mm": []})
    try:
        sc = scene.with_changes(**changes)
    except SceneError as exc:
        raise SceneError(f"{curve.source}: its specimen keys do not make a valid scene: {exc}") from None
    if curve.test == "picture_frame":
        return sc
    if u_mm.max() >= sc.specimen.locking_u0_mm * 1.2:
        raise SceneError(
            f"{curve.source}: the fitted points reach {u_mm.max():g} mm, far beyond the ideal yarn "
            f"locking of its {sc.specimen.width_mm:g} x {sc.specimen.length_mm:g} mm specimen "
            f"({sc.specimen.locking_u0_mm:.1f} mm): are the header's specimen keys right?"
        )
    return sc


def portable_scene(scene: Scene) -> Scene:
    """The fitted scene without the load of one curve: loaded to 0.8 of its ideal locking (a frame's: closing flat).

    It runs as it is, and on any other specimen with that specimen's keys.
    """
    frame = scene.test == "picture_frame"
    lock = scene.picture_frame.locking_mm if frame else scene.specimen.locking_u0_mm
    return scene.with_changes(**{"loading.stops_mm": [], "loading.u0_mm": 0.8 * lock})


#: the discretizations of a fit's model runs, cheapest first, all graded towards the clamp corners
#: (:class:`ngbet.runner.ladder.Rung`: mesh size, corner mesh size [mm], order p). Measured on
#: the unbalanced twill 100 x 250 mm to 49.7 mm with its start values (16 loads): the estimated force
#: error is at most 1.2 % on the first rung (1.4 s a run), 0.2 % on the second (1.2-1.6 s), 0.07 %
#: on the third (2.6 s), against 17.5 % on the scene's uniform 25 mm mesh at p = 2 (0.9 s)
FIT_LADDER = tuple(
    Rung(h, c, p, math.nan)
    for h, c, p in ((40.0, 1.0, 2), (40.0, 1.0, 3), (20.0, 0.25, 3), (20.0, 0.25, 4), (20.0, 0.25, 5), (20.0, 0.25, 6))
)
#: the coarse stage's rung: the search gets near the optimum there, unchecked
COARSE_LEVEL = 0
#: the first rung whose estimated error is checked against the target
FIRST_CHECKED = 1
#: tolerance (xtol, ftol) of the trust-region search on the scene's own discretization (no rungs
#: chosen): a relative change of the cost Σe² below 1e-4 changes it by far less than 1 (the change
#: that moves a parameter by one standard error) on the costs of the shipped fits (50–250), and
#: steps below 1e-4 of |ln p| move no parameter by a visible amount. Measured on the unbalanced
#: twill's two sizes: with 1e-6 the fit stopped at its 40 runs (31 on the checked rung) without
#: converging; with 1e-4 it converged in 25 (13 on it) to the same values (K_el 3.86 MPa both, RMS
#: 3.9 % and 5.1 % both)
FINE_TOL = 1e-4
#: on the checked rungs no search runs, or goes on, where the Gauss-Newton step within the bounds
#: would move the parameters by less than this many standard errors (Mahalanobis norm: the cost it
#: removes is below STEP_SE² s²), nor where a step lowered the cost by less than that: the point
#: is then the optimum for every purpose of the fit
STEP_SE = 0.1
#: the Gauss-Newton steps on the checked rungs end after this many model runs without a fall of the
#: cost (the step halved each time)
STALL_RUNS = 3
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
    climb: Climb = field(default_factory=Climb)
    model_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    start_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dlogp: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    force_error_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    profile_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angles_model_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    model_sd_N: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (bands.weigh_model_error)

    @property
    def weight_sd_N(self) -> np.ndarray:
        """The standard deviation a fitted point is weighted with: √(sd² + model_sd²).

        ``sd_N`` is the point's own (the measurement's); ``model_sd_N`` the model error between
        specimens that the fit estimates from its curves' misfit (empty: none,
        :func:`ngbet.calibration.bands.weigh_model_error`).
        """
        if len(self.model_sd_N) == 0:
            return self.sd_N
        return cast(np.ndarray, np.sqrt(self.sd_N**2 + self.model_sd_N**2))

    @property
    def label(self) -> str:
        """The label "W x L mm" of the specimen the curve runs on (its header's, else the scene's); "frame F/f mm"."""
        if self.curve.test == "picture_frame":
            return self.curve.label
        sp = self.scene.specimen
        return f"{sp.width_mm:g} x {sp.length_mm:g} mm"

    def measured_on_specimen(self) -> MeasuredCurve:
        """The measured curve with the specimen keys it runs on (the scene's where its header gives none)."""
        if self.curve.test == "picture_frame":
            return self.curve
        sp = self.scene.specimen
        keys = {
            "specimen.width_mm": sp.width_mm,
            "specimen.length_mm": sp.length_mm,
            "specimen.thickness_mm": sp.thickness_mm,
            **self.curve.specimen,
        }
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
            return cast(np.ndarray, np.degrees(frame_shear_angle_rad(self.u_mm, self.scene.picture_frame.frame_mm)))
        sp = self.scene.specimen
        return cast(np.ndarray, np.degrees(shear_angle_rad(self.u_mm, sp.length_mm, sp.width_mm)))


@dataclass
class JointFit:
    """What :func:`fit_curves` found; :meth:`to_json` is the content of fit.json.

    ``scene``: the fitted scene, in the test and on the specimen (or frame) of the first curve,
    on the finest rung the fit used (:func:`portable_scene`).
    """

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
    smoothness_sd: float = 0.0
    at_zero: dict[str, str] = field(default_factory=dict)

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
        corr = correlation(self.cov_log)

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        def curve(c: CurveFit) -> dict[str, Any]:
            d = c.run_scene().discretization
            bars = errorbar_path(c.curve.source) if c.curve.bars is not None else None
            doc: dict[str, Any] = {"data": c.curve.source, "errorbars": bars and str(bars), "test": c.curve.test}
            if c.curve.test == "picture_frame":  # the fit in the file's own quantities too
                x, y = c.curve.in_file_units(c.u_mm, c.measured_N)
                doc["frame"] = c.curve.frame
                doc["range_shear_angle_deg"] = [float(x.min()), float(x.max())]
                doc["file_quantities"] = {
                    "shear_angle_deg": x.tolist(),
                    "quantity": c.curve.quantity,
                    "measured": y.tolist(),
                    "model": c.curve.in_file_units(c.u_mm, c.model_N)[1].tolist(),
                }
            doc |= {
                "specimen": c.curve.specimen,
                "points": len(c.u_mm),
                "range_mm": [float(c.u_mm.min()), float(c.u_mm.max())],
                "rms_relative_error": c.rms_relative,
                "u_mm": c.u_mm.tolist(),
                "measured_N": c.measured_N.tolist(),
                "sd_N": c.sd_N.tolist(),
                "weight_sd_N": c.weight_sd_N.tolist(),
                "model_N": c.model_N.tolist(),
                "start_N": c.start_N.tolist(),
                "band_N": band(c.dlogp, self.cov_log).tolist(),
                "discretization": {
                    "mesh_size_mm": d.mesh_size_mm,
                    "corner_mesh_size_mm": d.corner_mesh_size_mm,
                    "order_u": d.order_u,
                    "chosen_by_fit": c.level is not None,
                },
                "force_error_rel_max": num(c.error_rel_max),
                "force_error_N": [num(v) for v in c.force_error_N],
                "shear_angle_deg": c.angle_deg.tolist(),
                "shear_angle_ideal_deg": c.ideal_angle_deg().tolist(),
            }
            if c.profile is not None:
                Pd = c.profile.measured()
                doc["profile"] = {
                    "data": c.profile.source,
                    "points": len(Pd),
                    "sd_mm": self.profile_sd_mm,
                    "rms_mm": float(np.sqrt(np.mean((c.profile_mm - Pd) ** 2))),
                    "u0_mm": np.concatenate([[u0] * len(x) for u0, x in c.profile.points().items()]).tolist(),
                    "X_mm": np.concatenate(list(c.profile.points().values())).tolist(),
                    "measured_mm": Pd.tolist(),
                    "model_mm": c.profile_mm.tolist(),
                }
            if c.angles is not None:
                a = c.angles
                doc["shear_angle_data"] = {
                    "data": a.source,
                    "points": len(a.u_mm),
                    "sd_deg": self.angle_sd_deg,
                    "rms_deg": float(np.sqrt(np.mean((c.angles_model_deg - a.angle_deg) ** 2))),
                    "u_mm": a.u_mm.tolist(),
                    "measured_deg": a.angle_deg.tolist(),
                    "model_deg": c.angles_model_deg.tolist(),
                }
            return doc

        return {
            "parameters": {
                nm: {
                    "value": float(self.values[k]),
                    "start": float(self.start[k]),
                    "standard_error": num(self.values[k] * se[k]),
                    "standard_error_log": num(se[k]),
                    "bounds": [float(self.lower[k]), float(self.upper[k])],
                    "at_bound": nm in self.at_bound,
                    "determined": nm not in self.undetermined,
                    "at_zero": nm in self.at_zero,
                }
                for k, nm in enumerate(self.names)
            },
            "held": {p: {"value": value_of(self.scene, p), "why": why} for p, why in self.held.items()},
            "undetermined": self.undetermined,
            "at_zero": self.at_zero,
            "strongly_correlated": [{"params": [a, b], "correlation": c} for a, b, c in self.correlated],
            "flat_directions": self.flat_directions,
            "correlation": [[num(corr[i, j]) for j in range(n)] for i in range(n)],
            "covariance_log": [[float(x) for x in row] for row in self.cov_log],
            "table_smoothness_sd": self.smoothness_sd,
            "noise_scale": self.noise_scale,
            "residual_scale": self.residual_scale,
            "model_runs": self.model_runs,
            "wall_s": self.wall_s,
            "converged": self.converged,
            "optimizer_message": self.message,
            "accuracy": {
                "target_error": self.target_error,
                "met": self.accuracy_met,
                "force_error_rel_max": {c.label: num(c.error_rel_max) for c in self.curves},
                "climb_ended": {c.label: c.climb.reason for c in self.curves if c.climb.reason},
                "stages": self.stages,
            },
            "curves": [curve(c) for c in self.curves],
        }


def band(dlogp: np.ndarray, cov_log: np.ndarray) -> np.ndarray:
    """√diag(G Σ Gᵀ) [N]: the force's standard deviation from the parameters."""
    return cast(np.ndarray, np.sqrt(np.maximum(np.einsum("ik,kl,il->i", dlogp, cov_log, dlogp), 0.0)))


def gauss_newton_direction(
    J: np.ndarray, e: np.ndarray, theta: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, float]:
    """The Gauss-Newton step d from θ and the largest fraction t <= 1 of it within the bounds ``lo``, ``hi`` of θ.

    d solves J d = −e in the least-squares sense with the flat directions (singular values below
    :data:`FLAT_RCOND` of the largest) left out, which the data do not determine, and with the
    parameters at a bound that d would push outside held there.
    """
    free = np.ones(len(theta), bool)
    d = np.zeros(len(theta))
    for _ in range(len(theta)):
        U, sv, Vt = np.linalg.svd(J[:, free], full_matrices=False)
        keep = sv > FLAT_RCOND * sv[0]
        d[:] = 0.0
        d[free] = -(Vt[keep].T @ ((U[:, keep].T @ e) / sv[keep]))
        out = free & (((theta <= lo + 1e-9) & (d < 0)) | ((theta >= hi - 1e-9) & (d > 0)))
        if not out.any():
            break
        free &= ~out
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(d > 0, (hi - theta) / d, np.where(d < 0, (lo - theta) / d, np.inf))
    return d, min(1.0, 0.999 * float(np.min(room)))


def correlation(cov: np.ndarray) -> np.ndarray:
    """The correlation matrix of a covariance; NaN where a variance is zero."""
    d = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = cov / np.outer(d, d)
    return np.where(np.isfinite(c), c, np.nan)


def rises_at_zero(
    names: Sequence[str], values: np.ndarray, cov_log: np.ndarray, steps: Sequence[float], undetermined: dict[str, str]
) -> dict[str, str]:
    """The rises ``undetermined`` names that the data put at zero, where they determine the law: {name: why}.

    The fit works in θ = ln r, where a rise near its lower bound (1 Pa against kilopascals) lies on
    a flat direction: the force moves with r, not with ln r, when r ≈ 0. What the data determine
    is the shear stress at the knots, the control values c_j = Σ_{i≤j} r_i (``steps``: all rises,
    the held ones constants), with the covariance of the linearized fit (dc_j/dθ_i = r_i, i ≤ j).
    A rise is at zero when r ≤ se(r) and se(c_j) ≤ :data:`UNDETERMINED_SE` c_j: the data ask
    for no rise over its interval of the table (the shear stress of a convex energy cannot fall),
    and the law there is known. A rise the data do not reach leaves c_j with an unbounded error:
    it stays undetermined.
    """
    rises = {k: int(n[len(TABLE_KEY) + 1 : -1]) for k, n in enumerate(names) if n.startswith(TABLE_KEY + "[")}
    B = np.zeros((len(steps), len(names)))
    for k, j in rises.items():
        B[j:, k] = values[k]
    se_c = np.sqrt(np.abs(np.diag(B @ cov_log @ B.T)))
    c = np.cumsum(np.asarray(steps, dtype=float))
    se_r = {k: float(values[k] * math.sqrt(abs(cov_log[k, k]))) for k in rises}
    return {
        names[k]: (
            f"at zero within its error ({values[k]:.3g} ± {se_r[k]:.2g} Pa) where the data determine the law: "
            f"the shear stress at its knot is {c[j]:.3g} Pa ± {100 * se_c[j] / c[j]:.0f} %; the data ask for no "
            "rise over its interval of the table (the shear stress of a convex energy cannot fall)"
        )
        for k, j in rises.items()
        if names[k] in undetermined and values[k] <= se_r[k] and se_c[j] <= UNDETERMINED_SE * c[j]
    }


def inverse_normal(sv: np.ndarray, Vt: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁻¹ from J's singular values and right singular vectors.

    A vanishing singular value gives its direction a huge (not infinite) variance.
    """
    inverse: np.ndarray = (Vt.T / np.maximum(sv, 1e-150 + 1e-12 * sv[0]) ** 2) @ Vt
    return inverse
