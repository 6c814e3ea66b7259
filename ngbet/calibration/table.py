r"""A starting shear table from a measured curve by the normalisation method.

The normalised shear force F_sh(γ) [N/mm] of a BET curve (Cao et al. 2008, Eq. 18;
:func:`ngbet.kinematics.normalised_shear_force`) is the shear moment per unit area divided by
cos γ: the power balance of the ideal zones reads F ḋ = Σ_zones A M(γ_zone) γ̇_zone with
M(γ) = F_sh(γ) cos γ. The continuum's shear energy per unit volume W(i8), with i8 = −sin γ for
inextensible yarns at ±45°, gives M = t dW/dγ = t τ(sin γ) cos γ, τ = dW/d|i8|. Hence

.. math::  τ(\sin γ) = F_{sh}(γ) / t

(F_sh in N/m, t in m: τ in Pa). The rises of the table's control values (all >= 0:
:func:`ngbet.continuum.physics.table_stress_spline`) are fitted to these points by non-negative
least squares, relative to each point's stress.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from ..continuum.physics import table_stress_spline
from ..kinematics import normalised_shear_force
from ..measured.curves import MeasuredCurve

__all__ = ["shear_stress_points", "start_table"]


def shear_stress_points(
    curve: MeasuredCurve, thickness_mm: float, n: int = 40, fraction: tuple[float, float] = (0.02, 0.9)
) -> tuple[np.ndarray, np.ndarray]:
    """(|i8| = sin γ, τ [Pa]) from the curve by the normalisation method, at n displacements.

    A picture-frame curve: γ the frame's shear angle and τ = F_norm / t (Eq. 10, the shear force of
    a unit area of fabric over its thickness).
    """
    if curve.test == "picture_frame":
        from ..kinematics import frame_normalised_force, frame_shear_angle_rad, shear_force

        L, Lf = curve.frame["picture_frame.frame_mm"], curve.frame["picture_frame.fabric_mm"]
        a, b = curve.window(fraction)
        u = np.linspace(max(a, 1e-3), b, n)
        F = np.interp(u, curve.u_mm, curve.force_N)
        fn = frame_normalised_force(shear_force(np.maximum(F, 0.0), u, L), L, Lf)
        return np.sin(frame_shear_angle_rad(u, L)), fn * 1e3 / (thickness_mm * 1e-3)
    H = curve.specimen["specimen.length_mm"]
    W = curve.specimen["specimen.width_mm"]
    a, b = curve.window(fraction)
    u = np.linspace(max(a, 1e-3), b, n)
    F = np.interp(u, curve.u_mm, curve.force_N)
    gamma, fsh = normalised_shear_force(u, np.maximum(F, 0.0), H, W)
    return np.sin(gamma), fsh * 1e3 / (thickness_mm * 1e-3)


def start_table(curve: MeasuredCurve, thickness_mm: float, n_steps: int, x_max: float) -> np.ndarray:
    """Rises [Pa] of a table whose stress follows the normalisation method's on ``curve``."""
    from scipy.optimize import nnls

    x, tau = shear_stress_points(curve, thickness_mm)
    basis = np.column_stack([np.nan_to_num(table_stress_spline(np.eye(n_steps)[j], x_max)(x)) for j in range(n_steps)])
    w = 1.0 / np.maximum(np.abs(tau), 0.05 * np.abs(tau).max())
    steps, _ = nnls(basis * w[:, None], tau * w)
    # a rise of exactly 0 cannot be fitted in ln p: a small floor
    return cast(np.ndarray, np.maximum(steps, 1e-3 * max(float(steps.max()), 1.0)))


def start_locking(curve: MeasuredCurve, thickness_mm: float) -> tuple[float, float, float]:
    """(K_sh [Pa], K_lock [Pa], γ_lock [deg]) of the locking law whose stress follows the normalisation method's.

    The locking law's stress τ(i8) = K_sh i8 + K_lock i8 x/(1 − x), x = (i8/sin γ_lock)²
    (:func:`ngbet.continuum.physics.locking_shear_energy`), fitted to the points of
    :func:`shear_stress_points` relative to each point's stress; γ_lock is kept beyond the largest
    shear angle of the points.
    """
    from scipy.optimize import least_squares

    x, tau = shear_stress_points(curve, thickness_mm)
    w = 1.0 / np.maximum(np.abs(tau), 0.05 * np.abs(tau).max())
    s_min = float(x.max()) * 1.01

    def stress(p: np.ndarray) -> np.ndarray:
        K_sh, K_lock, s = np.exp(p[0]), np.exp(p[1]), s_min + (1 - s_min) / (1 + np.exp(-p[2]))
        r = (x / s) ** 2
        return np.asarray(K_sh * x + K_lock * x * r / (1 - r))

    p0 = np.array([np.log(max(float(tau[0] / x[0]), 1.0)), np.log(max(float(tau.max()), 1.0)), 0.0])
    sol = least_squares(lambda p: (stress(p) - tau) * w, p0)
    s = s_min + (1 - s_min) / (1 + np.exp(-sol.x[2]))
    return float(np.exp(sol.x[0])), float(np.exp(sol.x[1])), float(np.degrees(np.arcsin(min(s, 0.999))))
