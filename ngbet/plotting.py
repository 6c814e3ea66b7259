"""Names of the plotting module :mod:`ngbet.figures` used by :meth:`ngbet.Result.plot` and the studies.

:func:`dense_force` samples the Hermite interpolant of (F, dF/du0) between converged steps, for a
user who wants it; ngbet's figures draw the computed points only.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .figures import SHEAR_LABEL, force_curve

__all__ = ["SHEAR_LABEL", "dense_force", "force_curve"]

#: the curve between converged steps is sampled every this many mm
DENSE_STEP_MM = 0.25


def dense_force(u0: ArrayLike, force: ArrayLike, dforce: ArrayLike | None) -> tuple[np.ndarray, np.ndarray, str]:
    """The force curve through the converged steps and (0, 0), sampled every ``DENSE_STEP_MM``.

    With the derivative dF/du0 at each step (``dforce``, N/mm) the curve is the piecewise cubic
    Hermite interpolant of (F, dF/du0): exact at the steps, with the slopes of the tangent
    stiffness there. Without it the points are joined by straight lines. Returns (u, F, how).
    """
    u = np.r_[0.0, np.asarray(u0, dtype=float)]
    F = np.r_[0.0, np.asarray(force, dtype=float)]
    if (dforce is None or len(u) < 2 or not np.all(np.isfinite(np.asarray(dforce, dtype=float)))
            or np.any(np.diff(u) <= 0)):  # a path followed by arc length may turn back in u0
        return u, F, "straight lines between steps"
    d = np.asarray(dforce, dtype=float)
    # the unloaded state's slope: extrapolate the first step's secant and slope linearly (dF/du0 at 0)
    d0 = 2 * (F[1] - F[0]) / (u[1] - u[0]) - d[0]
    ud = np.unique(np.r_[np.arange(0.0, u[-1], DENSE_STEP_MM), u])
    return ud, _hermite(u, F, np.r_[d0, d], ud), "cubic Hermite in (F, dF/du0) between steps"


def _hermite(x: np.ndarray, y: np.ndarray, dy: np.ndarray, xe: np.ndarray) -> np.ndarray:
    """The piecewise cubic Hermite interpolant of (y, dy) at the increasing nodes x, evaluated at xe."""
    i = np.clip(np.searchsorted(x, xe, side="right") - 1, 0, len(x) - 2)
    h = x[i + 1] - x[i]
    t = (xe - x[i]) / h
    h00, h10, h01, h11 = (1 + 2 * t) * (1 - t) ** 2, t * (1 - t) ** 2, t * t * (3 - 2 * t), t * t * (t - 1)
    return h00 * y[i] + h10 * h * dy[i] + h01 * y[i + 1] + h11 * h * dy[i + 1]
