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
scaled up by it (never down: s² >= 1).

A prediction of another specimen is the fitted scene run there, with the standard deviation
√(g Σ gᵀ + δ²): g = dF/dθ from the same run, Σ the covariance of θ, and δ the discretization
error estimated as the change of the force when the displacement order rises by one.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..scene.document import Scene
from ..scene.validate import SceneError
from .data import MeasuredCurve

__all__ = ["BOUND_FACTOR", "TABLE_KEY", "CurveFit", "CurvePrediction", "JointFit", "Progress", "band", "bounds",
           "curve_scene", "expand_params", "fit_curves", "portable_scene", "predict_specimen", "terminal_progress",
           "value_of", "with_values"]

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
    from ..continuum.sensitivity import DIFFERENTIABLE, table_index

    for p in out:
        key = p.partition(".")[2]
        if key not in DIFFERENTIABLE and table_index(key) is None:
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


def curve_scene(scene: Scene, curve: MeasuredCurve, u_mm: np.ndarray) -> Scene:
    """The scene on the curve's specimen (its header keys), loaded to its last fitted displacement."""
    changes: dict[str, Any] = dict(curve.specimen)
    changes.update({"loading.u0_mm": float(u_mm.max()), "loading.stops_mm": []})
    try:
        sc = scene.with_changes(**changes)
    except SceneError as exc:
        raise SceneError(f"{curve.source}: its specimen keys do not make a valid scene: {exc}") from None
    if u_mm.max() >= sc.specimen.locking_u0_mm * 1.2:
        raise SceneError(f"{curve.source}: the fitted points reach {u_mm.max():g} mm, far beyond the ideal yarn "
                         f"locking of its {sc.specimen.width_mm:g} x {sc.specimen.length_mm:g} mm specimen "
                         f"({sc.specimen.locking_u0_mm:.1f} mm): are the header's specimen keys right?")
    return sc


def portable_scene(scene: Scene) -> Scene:
    """The fitted scene without the load of one specimen: it runs on any other as it is."""
    return scene.with_changes(**{"loading.stops_mm": [], "loading.u0_mm": 0.8 * scene.specimen.locking_u0_mm})


@dataclass
class CurveFit:
    """One curve of a joint fit: the fitted points and the model on them."""

    curve: MeasuredCurve
    scene: Scene
    u_mm: np.ndarray
    measured_N: np.ndarray
    sd_N: np.ndarray
    model_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    start_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dlogp: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def rms_relative(self) -> float:
        """RMS of (model − measured)/measured over the fitted points."""
        return float(np.sqrt(np.mean(((self.model_N - self.measured_N) / self.measured_N) ** 2)))


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

    @property
    def se_log(self) -> np.ndarray:
        """Standard errors of ln p."""
        return np.sqrt(np.abs(np.diag(self.cov_log)))

    def to_json(self) -> dict[str, Any]:
        """The content of fit.json."""
        se = self.se_log

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "parameters": {n: {"value": float(self.values[k]), "start": float(self.start[k]),
                               "standard_error": num(self.values[k] * se[k]), "standard_error_log": num(se[k]),
                               "bounds": [float(self.lower[k]), float(self.upper[k])],
                               "at_bound": n in self.at_bound}
                           for k, n in enumerate(self.names)},
            "covariance_log": [[float(x) for x in row] for row in self.cov_log],
            "noise_scale": self.noise_scale, "model_runs": self.model_runs, "wall_s": self.wall_s,
            "converged": self.converged, "optimizer_message": self.message,
            "curves": [{"data": c.curve.source, "specimen": c.curve.specimen, "points": len(c.u_mm),
                        "range_mm": [float(c.u_mm.min()), float(c.u_mm.max())],
                        "rms_relative_error": c.rms_relative, "u_mm": c.u_mm.tolist(),
                        "measured_N": c.measured_N.tolist(), "sd_N": c.sd_N.tolist(), "model_N": c.model_N.tolist(),
                        "start_N": c.start_N.tolist(),
                        "band_N": band(c.dlogp, self.cov_log).tolist()} for c in self.curves],
        }


def band(dlogp: np.ndarray, cov_log: np.ndarray) -> np.ndarray:
    """√diag(G Σ Gᵀ) [N]: the force's standard deviation from the parameters."""
    return np.sqrt(np.maximum(np.einsum("ik,kl,il->i", dlogp, cov_log, dlogp), 0.0))


class _Model:
    """Forces and dF/dθ of every curve at θ = ln p, cached by θ; meshes made once per curve."""

    def __init__(self, curves: list[CurveFit], names: list[str]) -> None:
        self.curves, self.names = curves, names
        self.meshes: list[Any] = [None] * len(curves)
        self.runs = 0
        self._cache: dict[bytes, list[tuple[np.ndarray, np.ndarray]]] = {}

    def __call__(self, theta: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        key = np.asarray(theta, float).tobytes()
        if key in self._cache:
            return self._cache[key]
        from ..continuum.mesh import make_mesh
        from ..continuum.sensitivity import force_path
        from ..errors import ConvergenceError

        self.runs += 1
        out = []
        for k, c in enumerate(self.curves):
            sc = with_values(c.scene, self.names, np.exp(theta))
            if self.meshes[k] is None:
                self.meshes[k] = make_mesh(sc.specimen, sc.discretization)
            try:
                r = force_path(sc, c.u_mm, self.names, mesh=self.meshes[k])
                assert r.dlogp is not None
                out.append((r.force_N, r.dlogp))
            except (ConvergenceError, SceneError) as exc:
                log.info("model run failed on %s: %s", c.curve.label, exc)
                out.append((np.full(len(c.u_mm), np.nan), np.zeros((len(c.u_mm), len(self.names)))))
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


def fit_curves(curves: Sequence[MeasuredCurve], scene: Scene, params: Sequence[str] | None = None,
               max_runs: int = 40, progress: Progress | None = None,
               fractions: Sequence[tuple[float, float]] | None = None) -> JointFit:
    """Fit ``params`` (default: the scene's ``calibration.params``) to all ``curves`` at once.

    ``fractions``: the part of each curve's displacement range fitted (default 10–90 %).
    """
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    if scene.model != "continuum":
        raise SceneError(f"model = {scene.model!r}: ngbet fit calibrates the continuum model")
    params = list(params) if params else list(scene.calibration.params)
    if not params:
        raise SceneError("no parameters to fit: give --params, or name them in the scene's [calibration] params")
    if not isinstance(max_runs, int) or max_runs < 1:
        raise SceneError(f"--max-runs = {max_runs!r}: must be an integer >= 1")
    names = expand_params(scene, params)
    start = np.array([value_of(scene, n) for n in names])
    bad = [n for n, v in zip(names, start, strict=True) if not v > 0]
    if bad:
        raise SceneError(f"parameter(s) {', '.join(bad)}: the fit works on ln p and needs positive start values")
    lo, hi = bounds(scene, params, names, start)
    start = np.clip(start, lo * (1 + 1e-9), hi * (1 - 1e-9))
    cfs = []
    for k, c in enumerate(curves):
        u, F = c.sample(fraction=fractions[k]) if fractions is not None else c.sample()
        cfs.append(CurveFit(c, curve_scene(scene, c, u), u, F, c.sd(u, F)))
    model = _Model(cfs, names)
    best = [math.inf]
    quiet = [False]

    def resid(theta: np.ndarray) -> np.ndarray:
        res = model(theta)
        e = np.concatenate([(Fm - c.measured_N) / c.sd_N for (Fm, _), c in zip(res, cfs, strict=True)])
        e = np.where(np.isfinite(e), e, 1e3)
        cost = float(e @ e)
        best[0] = min(best[0], cost)
        if progress is not None and not quiet[0]:
            progress(model.runs, [float(np.sqrt(np.nanmean(((Fm - c.measured_N) / c.measured_N) ** 2)))
                                  for (Fm, _), c in zip(res, cfs, strict=True)], best[0])
        return e

    def jac(theta: np.ndarray) -> np.ndarray:
        return np.vstack([G / c.sd_N[:, None] for (_, G), c in zip(model(theta), cfs, strict=True)])

    th0 = np.log(start)
    sol = least_squares(resid, th0, jac=jac, bounds=(np.log(lo), np.log(hi)), method="trf", x_scale=1.0,
                        max_nfev=max_runs, xtol=1e-6, ftol=1e-6, gtol=1e-8)
    th = sol.x
    quiet[0] = True
    e, J = resid(th), jac(th)
    m, n = J.shape
    s2 = max(float(e @ e) / max(m - n, 1), 1.0)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    cov = s2 * (Vt.T / np.maximum(sv, 1e-12 * sv[0]) ** 2) @ Vt
    start_res = model(th0)
    for cf, (Fm, G), (F0, _) in zip(cfs, model(th), start_res, strict=True):
        cf.model_N, cf.dlogp, cf.start_N = Fm, G, F0
    values = np.exp(th)
    at_bound = [nm for nm, t, a, b in zip(names, th, np.log(lo), np.log(hi), strict=True)
                if t - a < 1e-3 or b - t < 1e-3]
    fitted = portable_scene(with_values(scene, names, values))
    ok = bool(sol.success and sol.status > 0)
    if not ok:
        # the caller says it (the command with its option, a study in its table): no advice from here
        log.info("the least-squares search stopped without converging after %d model runs (%s)", model.runs,
                 sol.message)
    return JointFit(params, names, values, np.exp(th0), lo, hi, cov, cfs, fitted, math.sqrt(s2), model.runs,
                    time.perf_counter() - t0, ok, str(sol.message), at_bound)


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
    r = force_path(sc, u_mm, [*result.names, *fixed])
    assert r.dlogp is not None
    n = len(result.names)
    var = band(r.dlogp[:, :n], result.cov_log) ** 2 + (r.dlogp[:, n:] ** 2) @ np.array(list(fixed.values()))
    d = sc.discretization
    finer = sc.with_changes(**{"discretization.order_u": d.order_u + 1})
    disc = np.abs(force_path(finer, u_mm).force_N - r.force_N)
    return CurvePrediction(np.asarray(u_mm, float), r.force_N, np.sqrt(var), disc, sc)
