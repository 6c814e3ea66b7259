r"""Calibration: material parameters from a measured force–displacement curve, with their uncertainty.

``ngbet fit DATA.csv [scene.toml] --params material.K_sh,material.K_lock --out DIR``

Model. One continuum run gives the whole curve: the load steps land on the measured displacements
(``loading.stops_mm``), so the model is compared with the data at the data's own abscissae, with
no interpolation. The derivatives of the force with respect to the parameters come from the same
run by implicit differentiation (:mod:`ngbet.continuum.sensitivity`), so one least-squares
iteration costs one load path.

Least squares. The parameters are fitted as θ = ln p (positive, scale-free) by
:func:`scipy.optimize.least_squares` (trust region, within a factor 10⁴ of the start values) on
the weighted residuals e_i = (F_model(u_i) − F_i)/w_i, with w_i = |F_i| (``noise = "relative"``,
default: a constant relative error) or w_i = 1 (``"absolute"``). The noise scale is estimated
from the fit, s² = Σe²/(m − n), and the covariance of θ is s²(JᵀJ)⁻¹ by the singular value
decomposition of J = ∂e/∂θ. A parameter is reported as *undetermined* when its standard error
in θ exceeds :data:`UNDETERMINED_SE` (its 95 % interval spans more than a factor e^(1.96·0.5) ≈ 2.7 either way),
or when it is a large component of a flat direction (singular value below :data:`FLAT_RCOND`
times the largest); pairs with |correlation| > :data:`STRONG_CORRELATION` are named too.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .scene.document import Scene
from .scene.validate import SceneError

__all__ = ["BOUND_FACTOR", "FLAT_RCOND", "STRONG_CORRELATION", "UNDETERMINED_SE", "Curve", "FitResult", "Prediction",
           "Profile", "band", "check_inputs", "fit", "fitted_points", "predict", "read_curve", "read_profile",
           "start_vector"]

log = logging.getLogger(__name__)

#: standard error of ln p above which a parameter is reported as undetermined (its 95 % interval then spans
#: more than a factor e^(1.96·0.5) ≈ 2.7 either way)
UNDETERMINED_SE = 0.5
#: singular values of J below this fraction of the largest are flat directions
FLAT_RCOND = 1e-3
#: |correlation| above which a pair of parameters is reported as strongly correlated
STRONG_CORRELATION = 0.95
#: the fit keeps each parameter within this factor of its start value
BOUND_FACTOR = 1e4


@dataclass(frozen=True)
class Curve:
    """A measured force–displacement curve: clamp displacement [mm], force [N]."""

    u_mm: np.ndarray
    force_N: np.ndarray
    source: str = ""


def _csv_rows(path: Path, what: str) -> list[list[str]]:
    try:
        with path.open(newline="") as fh:
            return list(csv.reader(fh))
    except FileNotFoundError:
        raise SceneError(f"{what} file not found: {path}") from None


def read_curve(path: str | Path) -> Curve:
    """Read a measured force curve from a CSV with a header, checked line by line.

    The checks are those of :func:`ngbet.calibration.data.read_measured`. The first column is the
    clamp displacement [mm], the column ``force_N`` (or the second column) the force [N]. Rows are
    sorted by displacement; rows of equal displacement are averaged.
    """
    from .calibration.data import read_measured

    c = read_measured(path)
    return Curve(c.u_mm, c.force_N, c.source)


@dataclass(frozen=True)
class Profile:
    """A measured mid-axis profile: u_y [mm] at X [mm] on Y = W/2, at clamp displacement(s) u0 [mm]."""

    u0_mm: np.ndarray
    X_mm: np.ndarray
    uy_mm: np.ndarray
    source: str = ""

    def points(self) -> dict[float, np.ndarray]:
        """{u0: X} in the order of :meth:`measured`."""
        return {float(u0): self.X_mm[self.u0_mm == u0] for u0 in np.unique(self.u0_mm)}

    def measured(self) -> np.ndarray:
        """The measured u_y [mm], grouped by load in the order of :meth:`points`."""
        return np.concatenate([self.uy_mm[self.u0_mm == u0] for u0 in np.unique(self.u0_mm)])

    def inside(self, length_mm: float) -> Profile:
        """The points strictly between the clamps (on them u_y = 0 holds by construction)."""
        m = (self.X_mm > 1e-9 * length_mm) & (self.X_mm < length_mm * (1 - 1e-9))
        return Profile(self.u0_mm[m], self.X_mm[m], self.uy_mm[m], self.source)


def read_profile(path: str | Path) -> Profile:
    """Read a CSV with the columns ``u0_mm``, ``X_mm``, ``uy_mm``.

    Other columns, such as the ``step`` of ngbet's own profile.csv, are ignored.
    """
    path = Path(path)
    rows = _csv_rows(path, "profile")
    need = ("u0_mm", "X_mm", "uy_mm")
    head = [h.strip() for h in rows[0]] if rows else []
    if len(rows) < 2 or any(k not in head for k in need):
        raise SceneError(f"profile file {path}: needs the columns {', '.join(need)}")
    cols = [head.index(k) for k in need]
    try:
        a = np.array([[float(r[j]) for j in cols] for r in rows[1:] if r])
    except (ValueError, IndexError) as exc:
        raise SceneError(f"profile file {path}: not a table of numbers: {exc}") from None
    return Profile(a[:, 0], a[:, 1], a[:, 2], str(path))


@dataclass
class FitResult:
    """What :func:`fit` found; ``to_json`` gives the content of fit.json."""

    params: list[str]
    values: np.ndarray
    start: np.ndarray
    se_log: np.ndarray  # standard errors of ln p (inf: not determined)
    cov_log: np.ndarray
    singular_values: np.ndarray
    undetermined: dict[str, str]
    correlated: list[tuple[str, str, float]]
    flat_directions: list[dict[str, float]]
    residual_norm: float
    noise_scale: float
    rms_relative_error: float
    model_runs: int
    wall_s: float
    scene: Scene
    data: Curve
    used: np.ndarray  # mask of the data points fitted
    model_N: np.ndarray  # fitted model at the used points
    start_N: np.ndarray  # model with the start values at the used points
    model_dlogp: np.ndarray  # dF/d ln p of the fitted model at the used points [N]
    extra: dict[str, Any] = field(default_factory=dict)

    def interval95(self) -> np.ndarray:
        """95 % confidence intervals of the parameters (Student t on ln p), one row (low, high) each."""
        dof = max(int(self.used.sum()) - len(self.params), 1)
        from scipy.stats import t as student

        q = float(student.ppf(0.975, dof))
        with np.errstate(over="ignore", invalid="ignore"):
            return np.column_stack([self.values * np.exp(-q * self.se_log), self.values * np.exp(q * self.se_log)])

    def to_json(self) -> dict[str, Any]:
        """The content of fit.json."""
        ci = self.interval95()
        n = len(self.params)
        corr = _correlation(self.cov_log)

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "parameters": {p: {"value": float(self.values[k]), "start": float(self.start[k]),
                               "standard_error": num(self.values[k] * self.se_log[k]),
                               "standard_error_log": num(self.se_log[k]),
                               "interval95": [num(ci[k, 0]), num(ci[k, 1])],
                               "determined": p not in self.undetermined}
                           for k, p in enumerate(self.params)},
            "correlation": {"params": self.params,
                            "matrix": [[num(corr[i, j]) for j in range(n)] for i in range(n)]},
            "undetermined": self.undetermined,
            "strongly_correlated": [{"params": [a, b], "correlation": c} for a, b, c in self.correlated],
            "singular_values": [float(s) for s in self.singular_values],
            "flat_directions": self.flat_directions,
            "residual_norm": self.residual_norm,
            "noise_scale": self.noise_scale,
            "rms_relative_error": self.rms_relative_error,
            "points": int(self.used.sum()),
            "range_mm": [float(self.data.u_mm[self.used].min()), float(self.data.u_mm[self.used].max())],
            "model_runs": self.model_runs,
            "wall_s": self.wall_s,
            "data": self.data.source,
            "curve": {"u_mm": self.data.u_mm[self.used].tolist(), "measured_N": self.data.force_N[self.used].tolist(),
                      "model_N": self.model_N.tolist(), "start_N": self.start_N.tolist(),
                      "sd_N": band(self.model_dlogp, self.cov_log).tolist()},
            **self.extra,
        }


def _correlation(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = cov / np.outer(d, d)
    return np.where(np.isfinite(c), c, np.nan)


class _Model:
    """The model's force (and profile) and their Jacobian in θ = ln p, cached by θ; counts the runs."""

    def __init__(self, scene: Scene, params: Sequence[str], u_mm: np.ndarray, profile: Profile | None) -> None:
        self.scene, self.params, self.u, self.profile = scene, list(params), u_mm, profile
        self.runs = 0
        self._cache: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def scene_at(self, theta: np.ndarray) -> Scene:
        return self.scene.with_changes(**{p: float(math.exp(t)) for p, t in zip(self.params, theta, strict=True)})

    def __call__(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Force [N], dF/dθ, profile [mm] (empty without one), du_y/dθ."""
        key = np.asarray(theta, float).tobytes()
        if key not in self._cache:
            from .continuum.sensitivity import force_path
            from .errors import ConvergenceError

            self.runs += 1
            n, m = len(self.params), len(self.u)
            pts = self.profile.points() if self.profile is not None else {}
            k = sum(len(x) for x in pts.values())
            try:
                res = force_path(self.scene_at(theta), self.u, self.params, pts)
                assert res.dlogp is not None
                P = np.concatenate([res.profiles[u0] for u0 in pts]) if pts else np.zeros(0)
                GP = np.vstack([res.profile_dlogp[u0] for u0 in pts]) if pts else np.zeros((0, n))
                self._cache[key] = (res.force_N, res.dlogp, P, GP)
            except (ConvergenceError, SceneError) as exc:
                log.warning("model run failed at %s: %s", dict(zip(self.params, np.exp(theta), strict=True)), exc)
                self._cache[key] = (np.full(m, np.nan), np.zeros((m, n)), np.full(k, np.nan), np.zeros((k, n)))
        return self._cache[key]


def _select(data: Curve, u_range: tuple[float, float] | None) -> np.ndarray:
    lo, hi = u_range if u_range is not None else (0.1 * data.u_mm.max(), data.u_mm.max())
    used = (data.u_mm >= lo) & (data.u_mm <= hi) & (data.u_mm > 0)
    if used.sum() < 2:
        raise SceneError(f"only {int(used.sum())} data points in the range {lo:g} to {hi:g} mm")
    return used


def fitted_points(curve: Curve, scene: Scene, u_range: tuple[float, float] | None, noise: str
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points fitted (mask, displacements, forces) and their weights; refused when the scene cannot carry them."""
    used = _select(curve, u_range)
    u, F = curve.u_mm[used], curve.force_N[used]
    if u.max() >= scene.specimen.locking_u0_mm:
        raise SceneError(f"the data reach {u.max():g} mm, beyond the specimen's locking load "
                         f"{scene.specimen.locking_u0_mm:.1f} mm: is the scene the data's specimen?")
    w = np.abs(F) if noise == "relative" else np.ones_like(F)
    if np.any(w == 0):
        raise SceneError("noise = 'relative' needs non-zero measured forces in the fitted range")
    return used, u, F, w


def start_vector(scene: Scene, params: Sequence[str]) -> np.ndarray:
    """The start values of the fitted material keys ``params`` (the fit works on ln p).

    A SceneError names a key that is not a positive material value.
    """
    vals = []
    for p in params:
        section, _, key = p.partition(".")
        v = getattr(getattr(scene, section, None), key, None)
        if section != "material" or not isinstance(v, (int, float)):
            raise SceneError(f"--params: '{p}' is not a material key (e.g. material.K_sh)")
        if v <= 0:
            raise SceneError(f"--params: '{p}' = {v!r}: the fit works on ln p and needs a positive start value "
                             f"(give one with --set {p}=...)")
        vals.append(float(v))
    return np.array(vals)


def fit(data: Curve | str | Path, scene: Scene, params: Sequence[str],
        u_range: tuple[float, float] | None = None, noise: str = "relative", max_runs: int = 60,
        profile: Profile | str | Path | None = None, force_sd: float = 0.01, profile_sd_mm: float = 1.0) -> FitResult:
    """Fit ``params`` of ``scene`` to the measured curve ``data`` by nonlinear least squares in ln p.

    ``params``: material keys, e.g. ``["material.K_sh", "material.K_lock"]``.

    ``u_range`` (mm): the data points used (default: from a tenth of the largest displacement
    to the end; the first tenth holds the initial slack and friction that no elastic law has).
    ``noise``: ``"relative"`` (errors proportional to the force) or ``"absolute"``.
    ``profile``: a measured mid-axis profile fitted together with the force; its residuals [mm]
    are weighted by ``force_sd / profile_sd_mm``, the ratio of the two error scales
    (``force_sd`` a fraction for relative noise, N for absolute).
    """
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    curve = data if isinstance(data, Curve) else read_curve(data)
    prof = check_inputs(scene, noise, profile, force_sd, profile_sd_mm)
    used, u, F, w = fitted_points(curve, scene, u_range, noise)
    start = start_vector(scene, params)
    model = _Model(scene, params, u, prof)
    Pd = prof.measured() if prof is not None else np.zeros(0)
    rho = force_sd / profile_sd_mm

    def resid(theta: np.ndarray) -> np.ndarray:
        Fm, _, Pm, _ = model(theta)
        e = np.concatenate([(Fm - F) / w, (Pm - Pd) * rho])
        return np.where(np.isfinite(e), e, 1e3)

    def jac(theta: np.ndarray) -> np.ndarray:
        _, G, _, GP = model(theta)
        return np.vstack([G / w[:, None], GP * rho])

    th0 = np.log(start)
    span = math.log(BOUND_FACTOR)
    sol = least_squares(resid, th0, jac=jac, bounds=(th0 - span, th0 + span), method="trf",
                        x_scale=1.0, max_nfev=max_runs, xtol=1e-8, ftol=1e-10, gtol=1e-10)
    res = _statistics(resid(sol.x), jac(sol.x), list(params))
    Fm, G, Pm, _ = model(sol.x)
    extra: dict[str, Any] = {}
    if prof is not None:
        extra["profile"] = {"data": prof.source, "points": len(Pd), "weight": rho,
                            "rms_mm": float(np.sqrt(np.mean((Pm - Pd) ** 2))),
                            "u0_mm": np.concatenate([[u0] * len(x) for u0, x in prof.points().items()]).tolist(),
                            "X_mm": np.concatenate(list(prof.points().values())).tolist(),
                            "measured_mm": Pd.tolist(), "model_mm": Pm.tolist()}
    if not sol.success or sol.status <= 0:
        log.warning("the least-squares search did not converge (%s): the values and intervals are not a "
                    "fit's; raise --max-runs", sol.message)
    extra["converged"] = bool(sol.success and sol.status > 0)
    extra["optimizer_message"] = str(sol.message)
    return FitResult(params=list(params), values=np.exp(sol.x), start=start, scene=model.scene_at(sol.x),
                     data=curve, used=used, model_N=Fm, model_dlogp=G, start_N=model(th0)[0],
                     model_runs=model.runs, wall_s=time.perf_counter() - t0, extra=extra,
                     rms_relative_error=float(np.sqrt(np.mean(((Fm - F) / F) ** 2))), **res)


def check_inputs(scene: Scene, noise: str, profile: Profile | str | Path | None, force_sd: float,
                  profile_sd_mm: float) -> Profile | None:
    """Refuse inputs the fit cannot use (a SceneError naming them); returns the profile inside the specimen, or None."""
    if scene.model != "continuum":
        raise SceneError(f"model = {scene.model!r}: ngbet fit calibrates the continuum model (model = 'continuum')")
    if noise not in ("relative", "absolute"):
        raise SceneError(f"noise = {noise!r}: must be 'relative' or 'absolute'")
    if not (force_sd > 0 and profile_sd_mm > 0):
        raise SceneError(f"--force-sd = {force_sd}, --profile-sd = {profile_sd_mm}: both must be > 0")
    if profile is None:
        return None
    prof = (profile if isinstance(profile, Profile) else read_profile(profile)).inside(scene.specimen.length_mm)
    if len(prof.X_mm) == 0:
        raise SceneError(f"profile {prof.source}: no point strictly between the clamps (0 < X < L)")
    return prof


def _statistics(e: np.ndarray, J: np.ndarray, params: list[str]) -> dict[str, Any]:
    """Covariance of θ = ln p from the SVD of J, and what the data leave undetermined."""
    m, n = J.shape
    s2 = float(e @ e) / max(m - n, 1)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    # a vanishing singular value gives its direction a huge (not infinite) variance
    inv_sv2 = 1.0 / np.maximum(sv, 1e-150 + 1e-15 * sv[0]) ** 2
    cov = s2 * (Vt.T * inv_sv2) @ Vt
    se = np.sqrt(np.abs(np.diag(cov)))
    undetermined: dict[str, str] = {}
    flat = []
    for k in range(n):
        if sv[k] <= FLAT_RCOND * sv[0]:
            direction = {params[i]: float(Vt[k, i]) for i in range(n) if abs(Vt[k, i]) > 0.3}
            flat.append(direction)
            for p in direction:
                undetermined[p] = (f"on a flat direction of the fit (singular value {sv[k]:.3g}, "
                                   f"{sv[k] / sv[0]:.2g} of the largest): the data do not move it")
    for k, p in enumerate(params):
        if p not in undetermined and not se[k] <= UNDETERMINED_SE:
            undetermined[p] = (f"standard error of ln {p} = {se[k]:.3g} > {UNDETERMINED_SE}: its 95 % interval "
                               f"spans more than a factor {math.exp(1.96 * UNDETERMINED_SE):.1f} either way")
    corr = _correlation(cov)
    pairs = [(params[i], params[j], float(corr[i, j])) for i in range(n) for j in range(i + 1, n)
             if abs(corr[i, j]) > STRONG_CORRELATION]
    for a, b, c in pairs:
        log.info("%s and %s strongly correlated (%.3f)", a, b, c)
    return {"se_log": se, "cov_log": cov, "singular_values": sv, "undetermined": undetermined,
            "correlated": pairs, "flat_directions": flat, "residual_norm": float(np.linalg.norm(e)),
            "noise_scale": math.sqrt(s2)}


def band(dlogp: np.ndarray, cov_log: np.ndarray) -> np.ndarray:
    """Standard deviation of the model force propagated from the parameters: √diag(G Σ Gᵀ) [N]."""
    return np.sqrt(np.maximum(np.einsum("ik,kl,il->i", dlogp, cov_log, dlogp), 0.0))


@dataclass
class Prediction:
    """The fitted model on another test, with its propagated uncertainty (1 standard deviation)."""

    data: Curve
    scene: Scene
    u_mm: np.ndarray
    force_N: np.ndarray
    sd_N: np.ndarray
    measured_N: np.ndarray

    def to_json(self) -> dict[str, Any]:
        """The prediction's record (fit.json keeps it under ``prediction``, without the arrays)."""
        rel = (self.force_N - self.measured_N) / self.measured_N
        return {"data": self.data.source, "points": len(self.u_mm),
                "range_mm": [float(self.u_mm.min()), float(self.u_mm.max())],
                "rms_relative_error": float(np.sqrt(np.mean(rel ** 2))),
                "within_2sd": float(np.mean(np.abs(self.force_N - self.measured_N) <= 2 * self.sd_N)),
                "u_mm": self.u_mm.tolist(), "force_N": self.force_N.tolist(), "sd_N": self.sd_N.tolist()}


def predict(result: FitResult, data: Curve | str | Path, scene: Scene | None = None,
            u_range: tuple[float, float] | None = None) -> Prediction:
    """The fitted force at the displacements of ``data``, with the parameters' covariance propagated to it.

    ``scene`` (default: the fitted one) runs with the fitted parameter values.
    """
    from .continuum.sensitivity import force_path

    curve = data if isinstance(data, Curve) else read_curve(data)
    base = scene if scene is not None else result.scene
    sc = base.with_changes(**{p: float(v) for p, v in zip(result.params, result.values, strict=True)})
    used = _select(curve, u_range)
    res = force_path(sc, curve.u_mm[used], result.params)
    assert res.dlogp is not None
    return Prediction(curve, sc, res.u_mm, res.force_N, band(res.dlogp, result.cov_log), curve.force_N[used])
