"""Meshing the rectangular BET specimen with named boundaries.

Boundary names (used for Dirichlet conditions and reactions):
``left`` = Σ1 (X = 0, fixed clamp), ``right`` = Σ2 (X = L, moving clamp),
``bottom`` = Σ3 (Y = 0) and ``top`` = Σ4 (Y = W), both free. Coordinates in metres.
"""

from __future__ import annotations

import math

import ngsolve as ngs

from ..scene.numerical import Discretization
from ..scene.physical import Specimen

__all__ = ["FIXED", "FREE", "MOVING", "corner_elements", "corner_refined", "make_mesh"]

FIXED, MOVING, FREE = "left", "right", "bottom|top"


def make_mesh(specimen: Specimen, disc: Discretization) -> ngs.Mesh:
    """Netgen (OCC) triangulation of [0, L] x [0, W], or a structured diagonal one.

    The structured mesh cuts every square along the same diagonal: it is invariant under the
    half-turn about the specimen centre, the symmetry of every BET solution (docs/model.md, *Symmetries*).
    """
    L, W, h = specimen.L, specimen.W, disc.mesh_size_mm * 1e-3
    if disc.structured:
        from ngsolve.meshes import MakeStructured2DMesh

        nx = max(1, round(L / h))
        ny = max(1, round(W / h))
        mesh = MakeStructured2DMesh(quads=False, nx=nx, ny=ny, mapping=lambda x, y: (L * x, W * y))
    else:
        mesh = _netgen_mesh(L, W, h, disc.corner_mesh_size_mm)
    # Netgen puts a single triangle at each 90-degree corner; bisecting it (and its neighbours, for
    # conformity) lets two elements share the corner (discretization.corner_bisections)
    return corner_refined(mesh, specimen, disc.corner_bisections) if disc.corner_bisections else mesh


def _netgen_mesh(L: float, W: float, h: float, corner_mesh_size_mm: float) -> ngs.Mesh:
    """Netgen's triangulation of [0, L] x [0, W] [m] with size h, graded to the corner size."""
    from netgen.occ import OCCGeometry, WorkPlane, X, Y

    face = WorkPlane().Rectangle(L, W).Face()
    face.edges.Min(X).name = "left"
    face.edges.Max(X).name = "right"
    face.edges.Min(Y).name = "bottom"
    face.edges.Max(Y).name = "top"
    if corner_mesh_size_mm > 0:
        # the clamp corners are singular points (the force converges like h^1.1 for every p on
        # uniform meshes); a local size there restores most of the accuracy of p
        for v in face.vertices:
            v.maxh = corner_mesh_size_mm * 1e-3
    # Netgen grades the size geometrically away from the corners (its ``grading``), so a small
    # corner size is a geometric mesh; with p raised as the corner shrinks ((2.5 mm, 2), (1, 3),
    # (0.5, 4), (0.25, 5)) the force converges exponentially in the cube root of the dofs
    # (ngbet.studies.reference). Netgen's RefineHP (hpref vertices) was measured and is not used:
    # its quadrilaterals give 109.57 N at p = 2 with 3 levels of factor 0.2 on the 10 mm mesh
    # (107.24 N converged; 107.41 N with a 0.25 mm corner size), and stop before 56 mm at p >= 3.
    return ngs.Mesh(OCCGeometry(face, dim=2).GenerateMesh(maxh=h))


def corner_refined(mesh: ngs.Mesh, specimen: Specimen, levels: int) -> ngs.Mesh:
    """A copy of ``mesh`` with the elements at the four clamp corners bisected ``levels`` times.

    Each time the elements that touch a corner then are bisected; boundary names are kept.
    """
    m = ngs.Mesh(mesh.ngmesh.Copy())
    corners = ((0.0, 0.0), (specimen.L, 0.0), (0.0, specimen.W), (specimen.L, specimen.W))
    tol = 1e-9 * max(specimen.L, specimen.W)
    for _ in range(levels):
        for el in m.Elements(ngs.VOL):
            pts = [m.vertices[v.nr].point for v in el.vertices]
            m.SetRefinementFlag(el, any(abs(p[0] - cx) + abs(p[1] - cy) < tol for p in pts for cx, cy in corners))
        m.Refine()
    return m


def corner_elements(mesh: ngs.Mesh, corner: tuple[float, float] = (0.0, 0.0)) -> tuple[int, float]:
    """Number and largest diameter [mm] of the elements that hold ``corner`` [m]."""
    diams = []
    for el in mesh.Elements(ngs.VOL):
        pts = [mesh.vertices[v.nr].point for v in el.vertices]
        if any(math.dist(q, corner) < 1e-12 for q in pts):
            diams.append(max(math.dist(a, b) for a in pts for b in pts))
    return len(diams), 1e3 * max(diams)
