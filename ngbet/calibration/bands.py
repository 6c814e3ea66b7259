"""Predictions of the fitted model on other specimens, and what their band holds.

:func:`predict_specimen` runs the fitted scene on another specimen and gives the force with its
standard deviation, part by part: the parameters, the discretization, and the model error.

A fitted model can miss a specimen it has not seen by more than its parameters' uncertainty: by
the model's own error between specimens. Only a fit of two or more specimens of a test shows it
(one parameter set had to fit them all); :func:`model_error` estimates it there from the fitted
curves' misfit beyond their noise, and elsewhere says that the band leaves it out and which data
would estimate it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..scene.document import Scene
from .fit_params import CurveFit, JointFit, band

__all__ = ["CurvePrediction", "misfit_beyond_noise", "model_error", "predict_specimen", "weigh_model_error"]


def misfit_beyond_noise(e: np.ndarray, sd: np.ndarray, F: np.ndarray, dof: int) -> float:
    """σ ≥ 0 with Σ e_i²/(sd_i² + σ² F_i²) = dof: the relative error the residuals ``e`` show beyond their noise.

    ``sd`` the points' standard deviations, ``F`` the forces (≠ 0) the error is relative to; 0
    where the misfit is within the noise (Σ e²/sd² <= dof).
    """
    from scipy.optimize import brentq

    def excess(sigma: float) -> float:
        return float(np.sum(e**2 / (sd**2 + (sigma * F) ** 2))) - dof

    if excess(0.0) <= 0:
        return 0.0
    return float(brentq(excess, 0.0, 10.0 * float(np.max(np.abs(e) / F)) + 1.0))


def _between_specimens(curves: list[CurveFit], forces: list[np.ndarray], n: int) -> dict[str, float]:
    """σ_m per test whose ``curves`` hold two or more specimens, from the residuals of the model ``forces``."""
    out = {}
    for test in sorted({c.curve.test for c in curves}):
        mine = [k for k, c in enumerate(curves) if c.curve.test == test]
        if len({curves[k].label for k in mine}) < 2:
            continue
        e = np.concatenate([forces[k] - curves[k].measured_N for k in mine])
        sd = np.concatenate([curves[k].sd_N for k in mine])
        F = np.abs(np.concatenate([forces[k] for k in mine]))
        ok = (F > 0) & np.isfinite(e)  # a relative error needs a force (and a run that ended)
        out[test] = misfit_beyond_noise(e[ok], sd[ok], F[ok], max(int(ok.sum()) - n, 1))
    return out


def weigh_model_error(curves: list[CurveFit], forces: list[np.ndarray], n: int) -> bool:
    """Weigh each fitted point with the model error between specimens that the model ``forces`` show.

    Where a fit holds two or more specimens of a test, one parameter set has to fit them all, and
    where the model cannot, their misfit beyond the points' noise is the model's own error between
    specimens (σ_m of :func:`model_error`, relative to the force). Weighting a point by its own
    standard deviation alone then lets the curve with the narrowest error bars decide the
    parameters and leaves the others missed by far more than the model's error; weighted by
    √(sd² + σ_m² F²) (maximum likelihood for a relative model error of that size), each specimen
    counts by what the model can do for it. Sets ``model_sd_N`` = σ_m |F_measured| of every curve of
    such a test (fixed for a search: the weights do not follow the parameters) and returns whether
    any σ_m moved by more than a tenth of itself (or 0.5 % of the force) from the weights in place:
    a search under the new weights would move the parameters.
    """
    moved = False
    for test, sigma in _between_specimens(curves, forces, n).items():
        for c in curves:
            if c.curve.test != test:
                continue
            before = float(np.max(c.model_sd_N / np.abs(c.measured_N))) if len(c.model_sd_N) else 0.0
            moved = moved or abs(sigma - before) > max(0.1 * sigma, 0.005)
            c.model_sd_N = sigma * np.abs(c.measured_N)
    return moved


def model_error(result: JointFit, test: str) -> tuple[float, str]:
    """The relative model error of a prediction of another specimen in ``test``, and what the band holds.

    Returns (σ_m, words): σ_m the standard deviation of the model's error relative to the force.
    Where the fit used curves of two or more specimens (sizes, frames) of ``test``, one parameter
    set had to fit them all: their misfit beyond their noise is the model error between specimens,
    σ_m the root of Σ e_i²/(sd_i² + σ_m² F_i²) = m − n over their m force points (e_i the residual,
    sd_i the point's standard deviation, F_i ≠ 0 the model's force, n the fitted parameters; 0
    where the misfit is within the noise: :func:`misfit_beyond_noise`). Otherwise the data cannot
    estimate it, σ_m = 0, and the words say so and name the data that would: a fit of one specimen
    is fitted to its own curve only, and a fit of another test says nothing of the error between
    the tests.
    """
    mine = [c for c in result.curves if c.curve.test == test]
    what = "specimen sizes" if test == "bias_extension" else "frames"
    base = "parameters and discretization"
    if not mine:
        other = " and ".join(sorted({c.curve.test.replace("_", " ") for c in result.curves}))
        return 0.0, (
            f"{base} only: the fit used no {test.replace('_', ' ')} curve ({other} only), so no model error "
            f"between the tests; a fit of both tests would estimate it"
        )
    if len({c.label for c in mine}) < 2:
        return 0.0, (
            f"{base} only: the fit used one {what[:-1]}, so no model error between {what}; "
            f"a fit of two or more {what} would estimate it"
        )
    sigma = _between_specimens(mine, [c.model_N for c in mine], len(result.names))[test]
    if sigma == 0:
        return 0.0, (
            f"parameters, discretization and the model error between {what}, which their fit puts at 0: "
            f"the fitted {what} agree within their noise"
        )
    return sigma, (
        f"parameters, discretization and the model error between {what} (the fitted {what}' misfit beyond their noise: "
        f"{100 * sigma:.1f} % of the force)"
    )


@dataclass
class CurvePrediction:
    """The fitted model on another specimen: force and its standard deviation, part by part.

    ``sd_param_N`` from the parameters (fitted and held), ``sd_disc_N`` from the discretization,
    ``sd_model_N`` the model error the fit's curves estimate for this specimen (zero where they
    cannot: :func:`model_error`); ``band`` says in words what the band
    holds and what it leaves out.
    """

    u_mm: np.ndarray
    force_N: np.ndarray
    sd_param_N: np.ndarray
    sd_disc_N: np.ndarray
    scene: Scene
    sd_model_N: np.ndarray = field(default_factory=lambda: np.zeros(0))
    band: str = ""

    @property
    def sd_N(self) -> np.ndarray:
        """The whole standard deviation of the model's force [N]: parameters, discretization, model error."""
        model = self.sd_model_N if len(self.sd_model_N) else 0.0
        return cast(np.ndarray, np.sqrt(self.sd_param_N**2 + self.sd_disc_N**2 + model**2))


def predict_specimen(
    result: JointFit, specimen: dict[str, Any], u_mm: np.ndarray, fixed_var_log: dict[str, float] | None = None
) -> CurvePrediction:
    """The fitted scene on ``specimen`` (scene keys) at the displacements ``u_mm``, with its band.

    The band's standard deviation is √(g Σ gᵀ + Σ_k g_k² var_k + δ² + (σ_m F)²): parameters,
    discretization, and the model error σ_m that the fit's curves estimate for this test
    (:func:`model_error`; its words are the prediction's ``band``).

    ``fixed_var_log``: parameters held fixed in the fit whose value is uncertain, with the
    variance of their ln p (independent of the fitted ones); they widen the band by g_k² var_k.
    """
    from ..runner.sensitivity import force_path

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
    sigma, words = model_error(result, sc.test)
    return CurvePrediction(np.asarray(u_mm, float), r.force_N, np.sqrt(var), disc, sc, sigma * np.abs(r.force_N), words)
