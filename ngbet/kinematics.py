"""Ideal BET kinematics: inextensible yarns, no slip, no bending (docs/model.md, *Ideal kinematics*).

For yarns at ±a to the axis and D = L − W/tan a, the central zone A turns the yarns from the
half-angle a to β with cos β = (D + u0) cos a / D; the angle between the yarns changes by
γ_A = 2a − 2β (for a = 45°: γ_A = π/2 − 2 arccos((D + u0)/(√2 D))). Zones B shear γ_A/2,
zones C do not shear. The yarns lock at u0 = D (1/cos a − 1).
"""

from __future__ import annotations

import math

from .scene import Scene, Specimen


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
