"""What the band of a prediction holds beyond the parameters and the discretization: the model error.

A fitted model can miss a specimen it has not seen by more than its parameters' uncertainty: by
the model's own error between specimens. Only a fit of two or more specimens of a test shows it
(one parameter set had to fit them all); :func:`model_error` estimates it there from the fitted
curves' misfit beyond their noise, and elsewhere says that the band leaves it out and which data
would estimate it.
"""

from __future__ import annotations

import numpy as np

from .fit_params import JointFit

__all__ = ["model_error"]


def model_error(result: JointFit, test: str) -> tuple[float, str]:
    """The relative model error of a prediction of another specimen in ``test``, and what the band holds.

    Returns (σ_m, words): σ_m the standard deviation of the model's error relative to the force.
    Where the fit used curves of two or more specimens (sizes, frames) of ``test``, one parameter
    set had to fit them all: their misfit beyond their noise is the model error between specimens,
    σ_m the root of Σ e_i²/(sd_i² + σ_m² F_i²) = m − n over their m force points (e_i the residual,
    sd_i the point's standard deviation, F_i ≠ 0 the model's force, n the fitted parameters; 0
    where the misfit is within the noise). Otherwise the data cannot estimate it, σ_m = 0, and the words
    say so and name the data that would: a fit of one specimen is fitted to its own curve only, and
    a fit of another test says nothing of the error between the tests.
    """
    from scipy.optimize import brentq

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
    e = np.concatenate([c.model_N - c.measured_N for c in mine])
    sd = np.concatenate([c.sd_N for c in mine])
    F = np.abs(np.concatenate([c.model_N for c in mine]))
    e, sd, F = e[F > 0], sd[F > 0], F[F > 0]  # a relative error needs a force
    dof = max(len(e) - len(result.names), 1)

    def excess(sigma: float) -> float:
        return float(np.sum(e**2 / (sd**2 + (sigma * F) ** 2))) - dof

    if excess(0.0) <= 0:
        return 0.0, (
            f"parameters, discretization and the model error between {what}, which their fit puts at 0: "
            f"the fitted {what} agree within their noise"
        )
    sigma = float(brentq(excess, 0.0, 10.0 * float(np.max(np.abs(e) / F)) + 1.0))
    return sigma, (
        f"parameters, discretization and the model error between {what} (the fitted {what}' misfit beyond their noise: "
        f"{100 * sigma:.1f} % of the force)"
    )
