"""Ideal BET kinematics: inextensible yarns, no slip, no bending (docs/model.md, *Ideal kinematics*).

For yarns at ±a to the axis and D = L − W/tan a, the central zone A turns the yarns from the
half-angle a to β with cos β = (D + u0) cos a / D; the angle between the yarns changes by
γ_A = 2a − 2β (for a = 45°: γ_A = π/2 − 2 arccos((D + u0)/(√2 D))). Zones B shear γ_A/2,
zones C do not shear. The yarns lock at u0 = D (1/cos a − 1).

The normalised shear force of the bias extension test (Launay et al. 2008; Cao et al. 2008,
Eq. 18), for 45° yarns, a specimen of clamp-to-clamp length H and width W [mm] and the clamp force
F [N] at the kinematic shear angle γ (Cao's Eq. 13, the γ_A above with D = H − W):

    F_sh(γ) = [(H/W − 1) F (cos γ/2 − sin γ/2) − W F_sh(γ/2) cos γ/2] / [(2H − 3W) cos γ]   [N/mm]

It is the power balance of the ideal zones: zone A (area (2HW − 3W²)/2) shears γ, zones B
(W²) shear γ/2. Cao et al. letter the central zone C; here it is A, as everywhere in ngbet.
F_sh(γ/2) comes from the smaller angles reached earlier on the same curve.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from .scene.document import Scene
from .scene.physical import Specimen

__all__ = [
    "CAO_YARN_ANGLE_DEG",
    "BetColumns",
    "force_from_normalised",
    "gamma_a",
    "ideal_energy",
    "ideal_force",
    "normalised_shear_force",
    "shear_angle_rad",
    "zone_areas_m2",
    "zone_index",
]


def gamma_a(specimen: Specimen, u0_mm: float) -> float:
    """Shear angle of zone A [rad] at clamp displacement u0 [mm]."""
    a = math.radians(specimen.yarn_angle_deg)
    D = specimen.zone_a_length_mm
    c = (D + u0_mm) * math.cos(a) / D
    if c >= 1.0:
        raise ValueError(f"u0 = {u0_mm} mm is beyond yarn locking at {specimen.locking_u0_mm:.2f} mm")
    return 2 * a - 2 * math.acos(c)


def zone_areas_m2(specimen: Specimen) -> tuple[float, float, float]:
    """Areas of zones A, B (all four), C (both clamp triangles) for 45° yarns [m²]."""
    L, W = specimen.L, specimen.W
    return L * W - 1.5 * W * W, W * W, 0.5 * W * W


def ideal_energy(scene: Scene, u0_mm: float) -> float:
    """E_id = ½ K_sh t (A_A sin²γ_A + A_B sin²γ_B) [J] (45° yarns; shear energy only)."""
    sp = scene.specimen
    g = gamma_a(sp, u0_mm)
    A_A, A_B, _ = zone_areas_m2(sp)
    return 0.5 * scene.material.K_sh * sp.t * (A_A * math.sin(g) ** 2 + A_B * math.sin(g / 2) ** 2)


def ideal_force(scene: Scene, u0_mm: float, h_mm: float = 1e-3) -> float:
    """dE_id/du0 [N]: the ideal-kinematics force estimate, by a central difference."""
    return (ideal_energy(scene, u0_mm + h_mm) - ideal_energy(scene, u0_mm - h_mm)) / (2 * h_mm * 1e-3)


def shear_angle_rad(d_mm: ArrayLike, H_mm: float, W_mm: float) -> np.ndarray:
    """Kinematic shear angle γ(d) of the ideal test [rad] (45° yarns; Cao et al. 2008, Eq. 13).

    γ = π/2 − 2 arccos((D + d) / (√2 D)), D = H − W. Displacements at or beyond yarn locking,
    d ≥ (√2 − 1) D, are refused.
    """
    d = np.asarray(d_mm, dtype=float)
    D = H_mm - W_mm
    if not D > 0:
        raise ValueError(f"the clamp-to-clamp length {H_mm:g} mm must exceed the width {W_mm:g} mm")
    c = (D + d) / (math.sqrt(2.0) * D)
    if np.any(c >= 1.0) or np.any(d < 0):
        raise ValueError(
            f"displacements must lie in [0, {(math.sqrt(2.0) - 1.0) * D:.2f}) mm "
            f"(yarn locking of a {W_mm:g} x {H_mm:g} mm specimen); got up to {np.max(d):g} mm"
        )
    return np.pi / 2 - 2.0 * np.arccos(c)


def _eq18(gamma: np.ndarray, H_mm: float, W_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The coefficients of Eq. 18 written as b F_sh(γ) + W c F_sh(γ/2) = a F."""
    a = (H_mm / W_mm - 1.0) * (np.cos(gamma / 2) - np.sin(gamma / 2))
    b = (2.0 * H_mm - 3.0 * W_mm) * np.cos(gamma)
    c = W_mm * np.cos(gamma / 2)
    return a, b, c


def normalised_shear_force(
    d_mm: ArrayLike, force_N: ArrayLike, H_mm: float, W_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """The normalised shear force F_sh [N/mm] along a measured or computed BET curve.

    Solves Eq. 18 (module docstring) along the curve: F_sh is taken piecewise linear in γ through
    (0, 0) and the curve's points, so F_sh(γ/2) is an interpolation between points of smaller γ,
    or, where γ/2 lies beyond the previous point, involves the point itself; either way each
    point's equation is linear in its own F_sh, and the system is lower triangular.

    Parameters
    ----------
    d_mm, force_N : array_like
        Clamp displacement [mm] (strictly increasing, below yarn locking) and clamp force [N].
    H_mm, W_mm : float
        Clamp-to-clamp length and width of the specimen [mm].

    Returns
    -------
    gamma_rad, fsh_N_per_mm : numpy.ndarray
        The kinematic shear angle at each point and the normalised shear force there.
    """
    d = np.asarray(d_mm, dtype=float)
    F = np.asarray(force_N, dtype=float)
    if d.shape != F.shape or d.ndim != 1:
        raise ValueError("displacement and force must be 1-D arrays of the same length")
    if np.any(np.diff(d) <= 0):
        raise ValueError("displacements must increase strictly along the curve")
    gamma = shear_angle_rad(d, H_mm, W_mm)
    a, b, c = _eq18(gamma, H_mm, W_mm)
    g = np.r_[0.0, gamma]  # the grid with the unloaded state
    f = np.zeros(len(g))  # F_sh on it, filled point by point
    for i in range(1, len(g)):
        half = g[i] / 2
        j = max(int(np.searchsorted(g[: i + 1], half, side="right")), 1)  # g[j-1] <= half < g[j]
        w = (half - g[j - 1]) / (g[j] - g[j - 1]) if g[j] > g[j - 1] else 0.0
        known = (1.0 - w) * f[j - 1] + (w * f[j] if j < i else 0.0)
        own = w if j == i else 0.0  # the share of F_sh(γ_i) in F_sh(γ_i / 2)
        f[i] = (a[i - 1] * F[i - 1] - c[i - 1] * known) / (b[i - 1] + c[i - 1] * own)
    return gamma, f[1:]


def force_from_normalised(
    gamma_rad: ArrayLike, fsh_N_per_mm: ArrayLike, d_mm: ArrayLike, H_mm: float, W_mm: float
) -> np.ndarray:
    """The clamp force [N] that a normalised shear force curve predicts for a specimen H x W.

    Eq. 18 solved for F: the normalisation method's prediction of another specimen size, with
    F_sh(γ) interpolated linearly in γ through (0, 0) and the given points (no extrapolation:
    displacements whose γ lies beyond the table give NaN). The ideal test has no shear angle at
    or beyond yarn locking, d ≥ (√2 − 1)(H − W): a measured curve may go on there, the method
    cannot (NaN).
    """
    gt = np.r_[0.0, np.asarray(gamma_rad, dtype=float)]
    ft = np.r_[0.0, np.asarray(fsh_N_per_mm, dtype=float)]
    d = np.asarray(d_mm, dtype=float)
    locked = d >= (math.sqrt(2.0) - 1.0) * (H_mm - W_mm)
    gamma = np.full(d.shape, np.nan)
    gamma[~locked] = shear_angle_rad(d[~locked], H_mm, W_mm)
    a, b, c = _eq18(gamma, H_mm, W_mm)
    f = np.interp(gamma, gt, ft, right=np.nan)
    fh = np.interp(gamma / 2, gt, ft, right=np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(a > 0, (b * f + c * fh) / a, np.nan)


#: the yarn angle [deg] of Cao's Eqs. 13 and 18 (the zone geometry and the power balance assume it)
CAO_YARN_ANGLE_DEG = 45.0


def zone_index(X_mm: ArrayLike, Y_mm: ArrayLike, L_mm: float, W_mm: float, yarn_angle_deg: float = 45.0) -> np.ndarray:
    """The ideal BET zone of reference points: 0 = A (central), 1 = B, 2 = C (clamp triangles).

    A point's two yarns (along m1 = (cos a, sin a) and m2 = (−cos a, sin a)) each end either on a
    free edge or on a clamp: zone A when neither ends on a clamp, B when exactly one does, C when
    both do (docs/model.md, *Zones*). The same rule as the discrete model's crossings.
    """
    X = np.asarray(X_mm, dtype=float)
    Y = np.asarray(Y_mm, dtype=float)
    t = math.tan(math.radians(yarn_angle_deg))
    held_1 = (Y - X * t >= 0) | (Y + (L_mm - X) * t <= W_mm)
    held_2 = (Y + X * t <= W_mm) | (Y - (L_mm - X) * t >= 0)
    return cast(np.ndarray, held_1.astype(int) + held_2.astype(int))


class BetColumns:
    """The BET-standard columns of a run's results.csv, row by row, for both models.

    ``gamma_kinematic_deg``: Cao's Eq. 13 at the row's clamp displacement [deg];
    ``fsh_N_per_mm``: the normalised shear force of Eq. 18 (:func:`normalised_shear_force`) solved
    along the rows so far with the run's own force. Both are empty ("") where they are not
    defined: yarns not at 45° (Eqs. 13 and 18 are the ±45° bias test's), displacements at or
    beyond yarn locking, and, for F_sh, rows without a force or where the path has turned back in
    u0 (Eq. 18 follows a curve along increasing γ; such rows are left out of the recursion).
    """

    def __init__(self, length_mm: float, width_mm: float, yarn_angle_deg: float) -> None:
        self.H, self.W = length_mm, width_mm
        self.applies = abs(yarn_angle_deg - CAO_YARN_ANGLE_DEG) < 1e-9
        self.locking_mm = (math.sqrt(2.0) - 1.0) * (length_mm - width_mm)
        self.d: list[float] = []
        self.F: list[float] = []

    def row(self, u0_mm: float, force_N: float | None) -> dict[str, float | str]:
        """The two columns of the row at clamp displacement ``u0_mm`` with force ``force_N`` [N]."""
        out: dict[str, float | str] = {"gamma_kinematic_deg": "", "fsh_N_per_mm": ""}
        if not self.applies or not 0.0 < u0_mm < self.locking_mm:
            return out
        out["gamma_kinematic_deg"] = math.degrees(float(shear_angle_rad(u0_mm, self.H, self.W)))
        if force_N is None or not math.isfinite(force_N) or (self.d and u0_mm <= self.d[-1]):
            return out
        self.d.append(u0_mm)
        self.F.append(force_N)
        out["fsh_N_per_mm"] = float(normalised_shear_force(self.d, self.F, self.H, self.W)[1][-1])
        return out


# --------------------------------------------------------------------------- picture frame
# A rigid square frame of side L_frame, hinged at its four pins, is pulled along a diagonal: the
# crosshead travel d opens the pin-to-pin diagonal from √2 L to √2 L + d = 2 L cos θ (Cao et al.
# 2008, Eq. 1), θ the frame angle between a bar and the loading axis, γ = 90° − 2θ (Eq. 2). With
# the fixed pin at the origin and the loading axis e1, every point of the frame moves by the affine
# map X -> F X with F = diag(√2 cos θ, √2 sin θ): the square turned into the rhombus.


def frame_angle_rad(d_mm: ArrayLike, frame_mm: float) -> np.ndarray:
    """The frame angle θ [rad] at crosshead travel d [mm] (Eq. 1): cos θ = (√2 L + d) / (2 L).

    Travels outside [0, (2 − √2) L] (the frame turned the other way, or past flat) are refused.
    """
    d = np.asarray(d_mm, dtype=float)
    c = (math.sqrt(2.0) * frame_mm + d) / (2.0 * frame_mm)
    if np.any(c > 1.0) or np.any(d < 0):
        raise ValueError(
            f"crosshead travels must lie in [0, {(2.0 - math.sqrt(2.0)) * frame_mm:.4g}] mm (a frame "
            f"of side {frame_mm:g} mm closes flat at the upper end); got up to {np.max(d):g} mm"
        )
    return np.arccos(c)


def frame_shear_angle_rad(d_mm: ArrayLike, frame_mm: float) -> np.ndarray:
    """The frame's shear angle γ = π/2 − 2θ [rad] (Eqs. 1–2)."""
    return np.pi / 2 - 2.0 * frame_angle_rad(d_mm, frame_mm)


def frame_stretches(d_m: float, frame_m: float) -> tuple[float, float, float, float]:
    """F = diag(A, B) of the frame at travel d [m] and dA/dd, dB/dd [1/m]: (A, B, A', B').

    A = √2 cos θ = 1 + d/(√2 L), B = √2 sin θ = √(2 − A²) (any consistent unit of d and L).
    """
    A = 1.0 + d_m / (math.sqrt(2.0) * frame_m)
    B = math.sqrt(max(2.0 - A * A, 0.0))
    dA = 1.0 / (math.sqrt(2.0) * frame_m)
    dB = -A * dA / B if B > 0 else -math.inf
    return A, B, dA, dB


def shear_force(force_N: ArrayLike, d_mm: ArrayLike, frame_mm: float) -> np.ndarray:
    """The total shear force F_s = F / (2 cos θ) [N] (Eq. 3) of crosshead force F at travel d."""
    return cast(np.ndarray, np.asarray(force_N, dtype=float) / (2.0 * np.cos(frame_angle_rad(d_mm, frame_mm))))


def frame_normalised_force(shear_force_N: ArrayLike, frame_mm: float, fabric_mm: float) -> np.ndarray:
    """F_norm = F_s L_frame / L_fabric² [N/mm] (Eq. 10): the shear force of a unit area of fabric.

    The power balance of a homogeneously sheared inner square: F_s L_frame dγ is the work of the
    bars, L_fabric² the area that shears.
    """
    return np.asarray(shear_force_N, dtype=float) * frame_mm / fabric_mm**2


class PictureFrameColumns:
    """The picture-frame columns of a run's results.csv, row by row.

    ``shear_angle_deg``: the frame's shear angle γ (Eqs. 1–2); ``shear_force_N``: F_s = F/(2 cos θ)
    (Eq. 3); ``fnorm_N_per_mm``: F_norm = F_s L_frame / L_fabric² (Eq. 10). The two forces are
    empty ("") on rows without a force.
    """

    def __init__(self, frame_mm: float, fabric_mm: float) -> None:
        self.frame, self.fabric = frame_mm, fabric_mm

    def row(self, u0_mm: float, force_N: float | None) -> dict[str, float | str]:
        """The three columns of the row at crosshead travel ``u0_mm`` with force ``force_N`` [N]."""
        out: dict[str, float | str] = {
            "shear_angle_deg": math.degrees(float(frame_shear_angle_rad(max(u0_mm, 0.0), self.frame))),
            "shear_force_N": "",
            "fnorm_N_per_mm": "",
        }
        if force_N is None or not math.isfinite(force_N):
            return out
        fs = float(shear_force(force_N, max(u0_mm, 0.0), self.frame))
        out["shear_force_N"] = fs
        out["fnorm_N_per_mm"] = float(frame_normalised_force(fs, self.frame, self.fabric))
        return out
