"""Drawing functions shared by the run's force plot, :meth:`ngbet.Result.plot` and the studies.

matplotlib is imported by the callers, only when they draw (it is not needed to compute).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

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


def force_curve(ax: Any, u0: ArrayLike, force: ArrayLike, dforce: ArrayLike | None = None,
                label: str | None = None, color: str | None = None, **kwargs: Any) -> Any:
    """Draw a force–displacement curve on ``ax``.

    The curve (see :func:`dense_force`) and the converged steps as markers; the legend says how the
    curve between steps was drawn.
    """
    ud, Fd, how = dense_force(u0, force, dforce)
    (line,) = ax.plot(ud, Fd, "-", color=color, label=f"{label + ': ' if label else ''}{how}", **kwargs)
    ax.plot(np.r_[0.0, np.asarray(u0, dtype=float)], np.r_[0.0, np.asarray(force, dtype=float)], "o",
            ms=4, color=line.get_color(), label="converged steps")
    ax.grid(alpha=0.3)
    return line


#: one angle convention in every figure of both models: the shear angle γ, the change of the
#: angle between the yarns (0 at rest; 90° − γ between the yarns of a ±45° fabric)
SHEAR_LABEL = "shear angle γ [°] (0 at rest)"
