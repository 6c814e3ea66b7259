"""Meshing the rectangular BET specimen with named boundaries.

Boundary names (used for Dirichlet conditions and reactions):
``left`` = Σ1 (X = 0, fixed clamp), ``right`` = Σ2 (X = L, moving clamp),
``bottom`` = Σ3 (Y = 0) and ``top`` = Σ4 (Y = W), both free. Coordinates in metres.

The picture-frame specimen (:func:`make_cross_mesh`) names its four arm edges, clamped to the bars,
``clamp`` and the edges of its cut-away corners ``free``.
"""

from __future__ import annotations

import math

import ngsolve as ngs

from ..scene.document import Scene
from ..scene.numerical import Discretization
from ..scene.physical import PictureFrame, Specimen

__all__ = [
    "CLAMPED_ARMS",
    "corner_elements",
    "corner_refined",
    "cross_outline",
    "make_cross_mesh",
    "make_mesh",
    "singular_corners",
]

FIXED, MOVING, FREE = "left", "right", "bottom|top"
CLAMPED_ARMS = "clamp"


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


def corner_refined(
    mesh: ngs.Mesh, specimen: Specimen, levels: int, corners: tuple[tuple[float, float], ...] | None = None
) -> ngs.Mesh:
    """A copy of ``mesh`` with the elements at the four clamp corners bisected ``levels`` times.

    Each time the elements that touch a corner then are bisected; boundary names are kept.
    ``corners`` [m]: other points to refine at (default: the specimen's four corners).
    """
    m = ngs.Mesh(mesh.ngmesh.Copy())
    if corners is None:
        corners = ((0.0, 0.0), (specimen.L, 0.0), (0.0, specimen.W), (specimen.L, specimen.W))
    tol = 1e-9 * max(max(abs(c) for p in corners for c in p), specimen.L, specimen.W)
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


def cross_outline(frame: PictureFrame) -> list[tuple[tuple[float, float], str]]:
    """The picture-frame cross [m] as its vertices in order, each with the name of the edge that leaves it.

    In the frame's own coordinates (ξ, η) ∈ [0, L]² along the bars, the cross is the square less
    its four corner squares of side c = (L_frame − L_fabric)/2; a point sits at X = ξ a1 + η a2 with
    a1 = (1, 1)/√2, a2 = (1, −1)/√2: the fixed pin at the origin, the crosshead's pin at (√2 L, 0).
    The edges on the bars (the arms' ends) are ``clamp``, those of the cut corners ``free``;
    without cut corners (c = 0) the whole square's edge is clamped. With the arms held over their
    length (``frame.arms == "held"``) the fabric that deforms is the inner square [c, L − c]², its
    whole edge clamped (the arms' inner ends, moving with the frame). Counter-clockwise.
    """
    L, c = frame.frame_mm * 1e-3, frame.arm_mm * 1e-3
    if c > 0 and frame.arms == "held":
        local = [((c, c), "clamp"), ((L - c, c), "clamp"), ((L - c, L - c), "clamp"), ((c, L - c), "clamp")]
    elif c > 0:
        local = [
            ((c, 0.0), "clamp"),
            ((L - c, 0.0), "free"),
            ((L - c, c), "free"),
            ((L, c), "clamp"),
            ((L, L - c), "free"),
            ((L - c, L - c), "free"),
            ((L - c, L), "clamp"),
            ((c, L), "free"),
            ((c, L - c), "free"),
            ((0.0, L - c), "clamp"),
            ((0.0, c), "free"),
            ((c, c), "free"),
        ]
    else:
        local = [((0.0, 0.0), "clamp"), ((L, 0.0), "clamp"), ((L, L), "clamp"), ((0.0, L), "clamp")]
    r = 1.0 / math.sqrt(2.0)
    pts = [(((xi + eta) * r, (xi - eta) * r), name) for (xi, eta), name in local]
    # (ξ, η) -> X turns the orientation over: walk backwards, each edge keeping its name
    n = len(pts)
    return [(pts[n - 1 - i][0], pts[(n - 2 - i) % n][1]) for i in range(n)]


def make_cross_mesh(frame: PictureFrame, specimen: Specimen, disc: Discretization) -> ngs.Mesh:
    """Netgen (OCC) triangulation of the picture-frame cross (:func:`cross_outline`), size h [m].

    Graded as the BET mesh: every vertex (the ends of the clamped arms, the re-entrant corners of
    the cuts, or the pins when nothing is cut) gets ``corner_mesh_size_mm``, and
    ``corner_bisections`` bisects the elements there. A structured mesh is for the rectangle only
    (the cross is meshed by Netgen in any case).
    """
    from netgen.occ import OCCGeometry, WorkPlane

    outline = cross_outline(frame)
    wp = WorkPlane()
    wp.MoveTo(*outline[0][0])
    for i, (_, name) in enumerate(outline):
        wp.LineTo(*outline[(i + 1) % len(outline)][0], name=name)
    face = wp.Face()
    if disc.corner_mesh_size_mm > 0:
        for v in face.vertices:
            v.maxh = disc.corner_mesh_size_mm * 1e-3
    mesh = ngs.Mesh(OCCGeometry(face, dim=2).GenerateMesh(maxh=disc.mesh_size_mm * 1e-3))
    if disc.corner_bisections:
        mesh = corner_refined(mesh, specimen, disc.corner_bisections, tuple(p for p, _ in outline))
    return mesh


def singular_corners(scene: Scene) -> tuple[tuple[float, float], ...] | None:
    """The corners [m] where the solution is singular, for :func:`corner_refined`: None for the BET's own four.

    The picture frame: every vertex of its cross (:func:`cross_outline`).
    """
    if scene.test != "picture_frame":
        return None
    return tuple(p for p, _ in cross_outline(scene.picture_frame))
