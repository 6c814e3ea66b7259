"""Checks of a scene against this machine, before anything is meshed, built or written.

:func:`preflight` runs them for every run (the run folder's writer calls it first): a load past
ideal yarn locking and a discretization known to lock are warned about; the size of the problem
(dofs and peak memory, estimated from the scene alone, for both models) is warned about above
0.5 GB and refused (:class:`SceneError` naming the key) when it exceeds the memory available; a
yarn network that carries no load is refused.
"""

from __future__ import annotations

import logging
import math

from .scene.document import Scene
from .scene.validate import SceneError

__all__ = [
    "SIZE_MARGIN",
    "available_memory",
    "check_size",
    "estimate_discrete_size",
    "estimate_size",
    "locking_warning",
    "order_warning",
    "preflight",
]

log = logging.getLogger(__name__)


def preflight(scene: Scene) -> list[str]:
    """Checks of a scene against this machine before anything is built.

    Returns the warnings (a load past ideal yarn locking, an order that locks, a large problem),
    each also logged and kept in every summary.json of the run (done, failed or interrupted);
    raises :class:`SceneError` naming the keys for a problem that cannot fit in the available memory
    or, in the discrete model, for a yarn spacing whose network joins the clamps by no chain of
    yarns and crossings (it would carry no load).
    """
    found = [w for w in (locking_warning(scene), order_warning(scene), check_size(scene)) if w]
    if scene.model == "discrete":  # once it fits: a network that joins the clamps (built once, kept for the run)
        from .discrete.network import network_from_scene

        network_from_scene(scene)
    for w in found:
        log.warning("%s", w)
    return found


def locking_warning(scene: Scene) -> str | None:
    """A warning when the load passes ideal yarn locking.

    Inextensible yarns would lock there; the model's yarns stretch, so it runs, with the yarns
    carrying the load by elongation.
    """
    if scene.test == "picture_frame":  # the frame closes before its yarns lock: the scene refuses that travel
        return None
    lock = scene.specimen.locking_u0_mm
    if scene.loading.u0_mm < lock:
        return None
    d = scene.discrete
    stiffness = (
        f"EA1 = {d.EA1:.3g} N, EA2 = {d.EA2:.3g} N"
        if scene.model == "discrete"
        else f"K_el = {scene.material.K_el:.3g} Pa"
    )
    return (
        f"loading.u0_mm = {scene.loading.u0_mm:g} mm is past ideal yarn locking (u0 = {lock:.1f} mm for "
        f"this specimen): beyond it the yarns must stretch ({stiffness}) and the force rises steeply"
    )


def order_warning(scene: Scene) -> str | None:
    """A warning for order_u = 1 in the second-gradient continuum: P1 locks under the constraint phi = i8.

    Measured on the default scene at 37 mm: 84.4, 80.3, 76.3 N on h = 10, 5, 2.5 mm against 61.2 N
    (p = 2, 3 extrapolated), with the multiplier's norm doubling at each refinement; on meshes graded
    to the clamp corners the first load step finds no equilibrium at all.
    """
    if scene.model != "continuum" or not scene.effects.bending or scene.discretization.p_u != 1:
        return None
    return (
        "order_u = 1 locks under the constraint phi = i8 (the force converges very slowly from above "
        "and the multiplier grows like 1/h); use order_u >= 2"
    )


# fitted to the default specimen (70 x 220 mm): Netgen's triangles have about 0.42 h² each, and the
# peak memory of assembly + sparse Cholesky (condensed) grew like 250 B x dofs x (p + 2) over
# 150 MB of libraries (h = 10, 5, 2.5 mm; p = 2 to 8: 159 to 313 MB after factorizing)
_TRIANGLE_AREA = 0.42
_BYTES_PER_DOF_ORDER = 250.0
_BASE_BYTES = 1.5e8
_WARN_BYTES = 5e8


def estimate_size(scene: Scene) -> tuple[int, float]:
    """(dofs, peak memory [bytes]) of a run, estimated before meshing or building the network.

    Continuum: triangles are the specimen area over 0.42 h² (plus about 12 per halving of the size
    at each graded corner and about 17 per corner bisection); an H1 field of order p has about
    p²/2 dofs per triangle (u two of them, phi one), the multiplier (p_lam + 1)(p_lam + 2)/2.
    Discrete: see :func:`estimate_discrete_size`.
    """
    if scene.model == "discrete":
        return estimate_discrete_size(scene)
    sp, d = scene.specimen, scene.discretization
    area, corners = sp.length_mm * sp.width_mm, 4
    if scene.test == "picture_frame":  # the cross, graded at its 12 corners (4 without cuts or with held arms)
        pf = scene.picture_frame
        area, corners = pf.fabric_area_mm2, 12 if pf.arm_mm > 0 and pf.arms == "sheared" else 4
    ntri = area / _TRIANGLE_AREA / d.mesh_size_mm / d.mesh_size_mm  # inf, never 1/0
    if d.corner_mesh_size_mm > 0:
        ntri += corners * 12 * math.log2(d.mesh_size_mm / d.corner_mesh_size_mm)  # measured 9-12 per halving
    ntri += corners * 17 * d.corner_bisections  # measured 12-17 per bisection and corner (1 mm corners)
    per_tri: float = d.p_u**2
    if scene.effects.bending:
        per_tri += d.p_phi**2 / 2 + (d.p_lam + 1) * (d.p_lam + 2) / 2
    dofs = min(ntri * per_tri, _MAX_DOFS)
    return int(dofs), _BASE_BYTES + _BYTES_PER_DOF_ORDER * dofs * (max(d.p_u, d.p_phi) + 2)


# measured on the default specimen, spacing 5, 2.5 and 1.25 mm (4 086, 15 594 and 60 966 dofs): peak
# memory 181, 237 and 521 MB, i.e. about 150 MB of libraries plus 375 B x dofs x log2(dofs) (the fill-in
# of the sparse factorization of a 2D network), within 8 %
_DISCRETE_BYTES_PER_DOF_LOG = 375.0
#: beyond any machine: the estimates stop growing here (and a finite number is reported)
_MAX_DOFS = 1e15


def estimate_discrete_size(scene: Scene) -> tuple[int, float]:
    """(dofs, peak memory [bytes]) of a discrete run, estimated before the network is built.

    Crossings: the specimen area times sin 2a over the spacing squared (the cell of two yarn
    families at ±a); two nodes per crossing (one on each yarn), ``elements_per_segment`` - 1 more
    along each of the two beams per crossing, three dofs per node. The yarn ends are left out: the
    estimate is a little low (about 12 % at the 5 mm spacing of the default network).
    """
    sp, dd = scene.specimen, scene.discrete
    crossings = sp.length_mm * sp.width_mm * math.sin(2 * math.radians(sp.yarn_angle_deg)) / dd.spacing_mm**2
    dofs = min(3 * 2 * crossings * dd.elements_per_segment, _MAX_DOFS)
    return int(dofs), _BASE_BYTES + _DISCRETE_BYTES_PER_DOF_LOG * dofs * math.log2(max(dofs, 2.0))


def available_memory() -> float | None:
    """Available memory [bytes] (Linux /proc/meminfo MemAvailable; None elsewhere)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return None


#: a problem is refused when this many times its estimated memory exceeds what is available: the
#: estimate is fitted on problems up to some 10^5 dofs, and a 70 x 220 mm mesh of 0.2 mm at p = 3
#: (15 million dofs, estimated 19.1 GB) was killed by the kernel at 23.6 GB
SIZE_MARGIN = 1.5


def check_size(scene: Scene) -> str | None:
    """Refuse a problem that will not fit in the available memory, before anything is built.

    Returns a warning naming the estimated dofs and memory when the estimate exceeds 0.5 GB, else
    None. Raises :class:`SceneError` naming the key to change when :data:`SIZE_MARGIN` times the
    estimate exceeds the available memory (where the machine tells it; elsewhere only the warning).
    """
    dofs, mem = estimate_size(scene)
    if scene.model == "discrete":
        dd = scene.discrete
        key, value = "discrete.spacing_mm", dd.spacing_mm
        what = (
            f"discrete.spacing_mm = {dd.spacing_mm:g}, elements_per_segment = {dd.elements_per_segment}: "
            f"about {dofs:,} dofs and {mem / 1e9:.3g} GB (estimated before building the network)"
        )
        fix = "widen the spacing"
    else:
        d = scene.discretization
        key, value = "discretization.order_u", d.order_u
        what = (
            f"discretization.mesh_size_mm = {d.mesh_size_mm:g}, order_u = {d.order_u}: about {dofs:,} dofs "
            f"and {mem / 1e9:.3g} GB (estimated before meshing)"
        )
        fix = "coarsen the mesh or lower the order"
    avail = available_memory()
    if avail is not None and SIZE_MARGIN * mem >= avail:
        raise SceneError(
            f"scene key '{key}' = {value!r}: {what}; only {avail / 1e9:.1f} GB are available, and "
            f"ngbet asks for {SIZE_MARGIN:g} times its estimate: {fix}"
        )
    return f"a large problem: {what}" if mem > _WARN_BYTES else None
