"""The statistics of a fit where it ends: the covariance of θ = ln p and what the data leave open.

:func:`fit_statistics`, from the residuals and the Jacobian (:func:`ngbet.calibration.joint.fit_curves`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .fit_params import FLAT_RCOND, STRONG_CORRELATION, UNDETERMINED_SE, WHAT_FIXES, correlation, inverse_normal

__all__ = ["fit_statistics"]


def fit_statistics(
    e: np.ndarray, J: np.ndarray, names: list[str], prior_rows: int = 0, own: np.ndarray | None = None
) -> dict[str, Any]:
    """Covariance of θ = ln p from the SVD of J, and what the data leave undetermined.

    The last ``prior_rows`` rows of ``e`` and ``J`` are the smoothness prior's
    (:func:`~ngbet.calibration.fit_params.smoothness_rows`): the covariance holds them (the bands
    are those of data and prior), while what is undetermined, flat or correlated is judged from the
    data's rows alone (the report names what the data leave open, also where the prior holds it).
    s² = Σe²/(m − n) over the data's m rows, floored at 1 (error bars that do not cover the misfit
    are scaled up, never down); ``residual_scale`` is s itself, or that of ``own``, the data's
    residuals over the points' own standard deviations where the rows are weighted otherwise
    (with the model error between specimens).
    """
    m = len(e) - prior_rows
    n = J.shape[1]
    r2 = float(e[:m] @ e[:m]) / max(m - n, 1)
    s2 = max(r2, 1.0)
    if own is not None:
        r2 = float(own @ own) / max(m - n, 1)
    _, sv, Vt = np.linalg.svd(J[:m], full_matrices=False)
    cov_data = s2 * inverse_normal(sv, Vt)
    cov = s2 * inverse_normal(*np.linalg.svd(J, full_matrices=False)[1:]) if prior_rows else cov_data
    se = np.sqrt(np.abs(np.diag(cov_data)))
    undetermined: dict[str, str] = {}
    flat = []
    for k in range(len(sv)):
        if sv[k] <= FLAT_RCOND * sv[0]:
            direction = {names[i]: float(Vt[k, i]) for i in range(n) if abs(Vt[k, i]) > 0.3}
            flat.append(direction)
            for p in direction:
                undetermined[p] = (
                    f"on a flat direction of the fit (singular value {sv[k]:.3g}, "
                    f"{sv[k] / sv[0]:.2g} of the largest): the data do not move it"
                )
    for k, p in enumerate(names):
        if p not in undetermined and not se[k] <= UNDETERMINED_SE:
            undetermined[p] = (
                f"standard error of ln p = {se[k]:.3g} > {UNDETERMINED_SE}: its 95 % interval "
                f"spans more than a factor {math.exp(1.96 * UNDETERMINED_SE):.1f} either way"
            )
    held_by_prior = set(np.nonzero(J[m:])[1].tolist())
    for p in undetermined:
        if names.index(p) in held_by_prior:
            undetermined[p] += (
                f"; the smoothness prior on the table's rises holds it (standard error of ln p with the "
                f"prior: {math.sqrt(abs(cov[names.index(p), names.index(p)])):.3g})"
            )
        hint = next((h for k, h in WHAT_FIXES.items() if p.startswith(k)), "")
        if hint:
            undetermined[p] += f"; {hint}"
    corr = correlation(cov_data)
    pairs = [
        (names[i], names[j], float(corr[i, j]))
        for i in range(n)
        for j in range(i + 1, n)
        if abs(corr[i, j]) > STRONG_CORRELATION
    ]
    return {
        "cov": cov,
        "cov_data": cov_data,
        "undetermined": undetermined,
        "flat": flat,
        "correlated": pairs,
        "noise_scale": math.sqrt(s2),
        "residual_scale": math.sqrt(r2),
    }
