r"""Discrete parameters equivalent to a continuum scene (small strain, yarns at ±45°).

A yarn family with spacing s carries per unit area of fabric 1/s yarns, and a crossing occupies
the area s² (at ±45°). Matching the energy per unit area of the continuum (thickness t) with that
of the network term by term gives

    EA_k  = t K_el s          (yarn stretch ½ K_el (√i_k − 1)²  ↔  ½ EA ε² per yarn length)
    EI_k  = t α_k s           (½ α_k φ,_k²  ↔  ½ EI κ² per yarn length; φ,_k ≈ κ_k at small shear)
    K_φ   = t K_sh s²         (½ K_sh i8²   ↔  ½ K_φ Δθ² per crossing; i8 ≈ −Δθ)
    K_slip = 100 EA / s       (no slip: the continuum has no relative motion of the two families)
    K_inter = 0               (no counterpart in the continuum)

With pinned yarn ends (``end_rotation = "free"``, the counterpart of the continuum's clamp) such a
network and the continuum give the same S-shape: the side-by-side study and
``tests/test_discrete_bet.py`` compare them.
"""

from __future__ import annotations

from typing import Any

__all__ = ["continuum_equivalent"]


def continuum_equivalent(scene: Any) -> dict[str, float]:
    """``with_changes`` keys that turn ``scene.discrete`` into the network equivalent to ``scene.material``."""
    m, t, s = scene.material, scene.specimen.thickness_mm * 1e-3, scene.discrete.spacing_mm * 1e-3
    EA = t * m.K_el * s
    return {
        "discrete.EA1": EA,
        "discrete.EA2": EA,
        "discrete.EI1": t * m.alpha1 * s,
        "discrete.EI2": t * m.alpha2 * s,
        "discrete.K_phi": t * m.K_sh * s * s,
        "discrete.K_slip": 100.0 * EA / s,
        "discrete.K_inter": 0.0,
    }
