"""The yarn network of the discrete model: two families of straight yarns clipped to the specimen.

Geometry (reference configuration, SI units)::

    family 1 (thick):  m1 = ( cos a, sin a),  n1 = (-sin a, cos a)
    family 2 (thin):   m2 = (-cos a, sin a),  n2 = (-sin a, -cos a)
    yarn j of family k:  { X : n_k . X = n_k . C + s j },   C = (L/2, W/2),  j integer

so that neighbouring parallel yarns are a distance s apart and the set of yarns is mapped onto
itself by the half-turn about the centre C (j -> -j). Each line is clipped to B = [0, L] x [0, W].
A yarn ends either on a clamp (X = 0 or X = L: all its end dofs are prescribed) or on a free
edge (Y = 0 or Y = W). Crossings are the intersections of a family-1 and a family-2 yarn strictly
inside B.

Each crossing carries two nodes, one per yarn, at the same reference point, so that the yarns can
slip relative to each other (the slip spring ties them elastically). Every yarn is a chain of
nodes: its two end nodes, its crossing nodes in order along m_k, and ``elements_per_segment - 1``
equally spaced interior nodes between consecutive stations.

BET zones per crossing (docs/model.md, *Ideal kinematics*): A when neither yarn ends on a clamp, B when exactly
one does, C when both end on the same clamp ("other" when they end on different clamps, which
only happens for L < 2 W / tan a and is not one of the three ideal zones).

Inter-yarn trusses (``inter_layout = "neighbours"``): for two adjacent yarns j, j+1 of one family
and each yarn of the other family that crosses both, a truss joins the two crossing nodes of j
and j+1 on that yarn (the "close interaction points of two close yarns of the same family",
paper section 3): it lies along the crossing yarn, has rest length s / sin(2a) and resists the
spreading and the closing of parallel yarns, which the slip springs alone resist only weakly.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..scene.document import Scene

__all__ = [
    "CLAMP_FIXED",
    "CLAMP_MOVING",
    "FREE",
    "ZONE_NAMES",
    "Network",
    "NetworkError",
    "build_network",
    "clip_line",
    "crossing_zone",
    "end_kind",
    "family_frames",
    "network_from_scene",
]

log = logging.getLogger(__name__)

ZONE_NAMES = ("A", "B", "C", "other")
# end kinds of a yarn
FREE, CLAMP_FIXED, CLAMP_MOVING = 0, 1, 2


class NetworkError(ValueError):
    """The yarn network cannot be built from the given geometry."""


@dataclass(frozen=True)
class Network:
    """A yarn network in the reference configuration (SI units; arrays are not to be mutated).

    Attributes
    ----------
    X : (n_nodes, 2) reference node positions [m]
    node_yarn : (n_nodes,) yarn index of each node
    node_family : (n_nodes,) 1 or 2
    node_end : (n_nodes,) FREE for non-end nodes and free ends, CLAMP_FIXED / CLAMP_MOVING for clamped ends
    yarn_family : (n_yarns,) 1 or 2
    yarn_index : (n_yarns,) the integer j of the yarn line
    yarn_nodes : list of (n,) node chains, ordered along m_k
    yarn_ends : (n_yarns, 2) end kinds (start, end)
    beams : (n_beams, 2) node pairs of the beam elements
    beam_family : (n_beams,) 1 or 2
    crossings : (n_cross, 2) nodes (on the family-1 yarn, on the family-2 yarn) of each crossing
    crossing_yarns : (n_cross, 2) yarns (family 1, family 2) of each crossing
    crossing_zone : (n_cross,) 0 = A, 1 = B, 2 = C, 3 = other
    trusses : (n_trusses, 2) node pairs of the inter-yarn trusses
    spacing : s [m]
    L, W : specimen size [m]
    angle : yarn angle a [rad]
    """

    X: np.ndarray
    node_yarn: np.ndarray
    node_family: np.ndarray
    node_end: np.ndarray
    yarn_family: np.ndarray
    yarn_index: np.ndarray
    yarn_nodes: tuple[np.ndarray, ...]
    yarn_ends: np.ndarray
    beams: np.ndarray
    beam_family: np.ndarray
    crossings: np.ndarray
    crossing_yarns: np.ndarray
    crossing_zone: np.ndarray
    trusses: np.ndarray
    spacing: float
    L: float
    W: float
    angle: float

    @property
    def n_nodes(self) -> int:
        """The number of nodes."""
        return int(self.X.shape[0])

    @property
    def n_dofs(self) -> int:
        """Three dofs per node: ux, uy, theta."""
        return 3 * self.n_nodes

    def clamped_nodes(self, which: int) -> np.ndarray:
        """Nodes on the fixed (``CLAMP_FIXED``) or moving (``CLAMP_MOVING``) clamp."""
        return np.flatnonzero(self.node_end == which)

    def counts(self) -> dict[str, int]:
        """Sizes of the network, for logs and summaries."""
        return {
            "yarns_1": int(np.sum(self.yarn_family == 1)),
            "yarns_2": int(np.sum(self.yarn_family == 2)),
            "crossings": int(len(self.crossings)),
            "nodes": self.n_nodes,
            "dofs": self.n_dofs,
            "beams": int(len(self.beams)),
            "trusses": int(len(self.trusses)),
            **{f"crossings_{z}": int(np.sum(self.crossing_zone == i)) for i, z in enumerate(ZONE_NAMES)},
        }


def family_frames(angle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit directions and normals: m1 = (cos a, sin a), m2 = (-cos a, sin a), n_k = R(90°) m_k."""
    c, s = math.cos(angle), math.sin(angle)
    m1, m2 = np.array([c, s]), np.array([-c, s])
    return m1, np.array([-s, c]), m2, np.array([-s, -c])


def clip_line(p0: np.ndarray, m: np.ndarray, L: float, W: float, tol: float) -> tuple[float, float] | None:
    """Parameter interval [t0, t1] of the line p0 + t m inside [0, L] x [0, W] (slab method)."""
    t0, t1 = -math.inf, math.inf
    for k, hi in ((0, L), (1, W)):
        if abs(m[k]) < 1e-14:
            if not (-tol <= p0[k] <= hi + tol):
                return None
            continue
        a, b = (0.0 - p0[k]) / m[k], (hi - p0[k]) / m[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return (t0, t1) if t1 - t0 > tol else None


def end_kind(P: np.ndarray, L: float, tol: float) -> int:
    """Which boundary a yarn end lies on: a clamp wins over a free edge at a corner."""
    if abs(P[0]) <= tol:
        return CLAMP_FIXED
    if abs(P[0] - L) <= tol:
        return CLAMP_MOVING
    return FREE


_Line = tuple[int, int, np.ndarray, np.ndarray, float, float]  # family, j, p0, m, t0, t1


@functools.lru_cache(maxsize=1)  # the run's checks before its folder and the run itself build the same network
def build_network(
    L: float,
    W: float,
    angle_deg: float,
    spacing: float,
    elements_per_segment: int = 1,
    inter_layout: str = "neighbours",
) -> Network:
    """Build the yarn network of a BET specimen.

    Parameters
    ----------
    L, W : float
        Specimen length (along the load) and width [m].
    angle_deg : float
        Angle a of the thick yarns to e1 [deg].
    spacing : float
        Distance s between neighbouring parallel yarns [m].
    elements_per_segment : int
        Beam elements between two consecutive stations (ends, crossings) of a yarn.
    inter_layout : str
        "neighbours" (trusses between adjacent yarns, see module docstring) or "none".

    Returns
    -------
    Network
        The last one built is kept: the same arguments return the same (immutable) object.

    Raises
    ------
    NetworkError
        for a geometry that gives no network, or one in which no chain of yarns and crossings
        joins the two clamps (it would carry no load).
    """
    if spacing <= 0 or L <= 0 or W <= 0:
        raise NetworkError(f"network needs L, W, spacing > 0, got L={L}, W={W}, spacing={spacing}")
    if elements_per_segment < 1:
        raise NetworkError(f"elements_per_segment = {elements_per_segment}: must be >= 1")
    if inter_layout not in ("neighbours", "none"):
        raise NetworkError(f"inter_layout = {inter_layout!r}: must be 'neighbours' or 'none'")
    a = math.radians(angle_deg)
    tol = 1e-9 * max(L, W)
    m1, n1, m2, n2 = family_frames(a)
    lines = _yarn_lines(L, W, spacing, tol, ((1, m1, n1), (2, m2, n2)))
    fam_of = np.array([ln[0] for ln in lines])
    i1, i2 = np.flatnonzero(fam_of == 1), np.flatnonzero(fam_of == 2)
    if len(i1) == 0 or len(i2) == 0:
        raise NetworkError(
            f"spacing {spacing * 1e3:g} mm leaves no yarn of one family in a {L * 1e3:g} x {W * 1e3:g} mm specimen"
        )
    tr, cross_a, cross_b = _crossing_parameters(lines, i1, i2, m1, m2, tol)
    b = _Builder(L, tol, elements_per_segment)
    for fam, lst, cross_self, cross_other in ((1, i1, cross_a, cross_b), (2, i2, cross_b, cross_a)):
        for k in range(len(lst)):
            partners = cross_other[cross_self == k]
            if len(partners) == 0:  # nothing would hold it but its clamp, or nothing at all
                log.info("yarn %d of family %d crosses no other yarn: dropped", lines[lst[k]][1], fam)
                continue
            ts = tr[k, partners, 0] if fam == 1 else tr[partners, k, 1]
            b.add_yarn(lines[lst[k]], k, partners, ts)
    net = b.network(lines, i1, i2, inter_layout, spacing, W, a)
    for arr in (v for v in vars(net).values() if isinstance(v, np.ndarray)):
        arr.flags.writeable = False  # shared by every caller with these arguments (the cache)
    if not _joins_the_clamps(net):
        raise NetworkError(
            f"at a spacing of {spacing * 1e3:g} mm no chain of yarns and crossings joins the two clamps of the "
            f"{L * 1e3:g} x {W * 1e3:g} mm specimen: the network would carry no load; choose a smaller spacing"
        )
    return net


def _joins_the_clamps(net: Network) -> bool:
    """Whether a chain of beams, crossings and trusses joins a node of the fixed clamp to one of the moving clamp."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = np.concatenate([net.beams, net.crossings, net.trusses])
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(net.n_nodes, net.n_nodes))
    _, comp = connected_components(graph, directed=False)
    return bool(np.intersect1d(comp[net.clamped_nodes(CLAMP_FIXED)], comp[net.clamped_nodes(CLAMP_MOVING)]).size)


def _yarn_lines(
    L: float, W: float, spacing: float, tol: float, families: tuple[tuple[int, np.ndarray, np.ndarray], ...]
) -> list[_Line]:
    """Candidate yarn lines of each family, kept if their clipped length is positive."""
    C = np.array([L / 2, W / 2])
    corners = np.array([[0, 0], [L, 0], [0, W], [L, W]], float)
    lines: list[_Line] = []
    for fam, m, n in families:
        c0 = float(n @ C)
        cs = corners @ n
        jmin, jmax = math.ceil((cs.min() - c0) / spacing), math.floor((cs.max() - c0) / spacing)
        for j in range(jmin, jmax + 1):
            p0 = (c0 + spacing * j) * n
            seg = clip_line(p0, m, L, W, tol)
            if seg is not None:
                lines.append((fam, j, p0, m, seg[0], seg[1]))
    return lines


def _crossing_parameters(
    lines: list[_Line], i1: np.ndarray, i2: np.ndarray, m1: np.ndarray, m2: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """p1 + t m1 = p2 + r m2 for all pairs at once: (t, r) per pair, and the pairs that cross inside both yarns."""
    P1 = np.array([lines[i][2] for i in i1])
    P2 = np.array([lines[i][2] for i in i2])
    M = np.column_stack([m1, -m2])
    rhs = P2[None, :, :] - P1[:, None, :]  # (n1, n2, 2)
    tr = np.linalg.solve(M, rhs.reshape(-1, 2).T).T.reshape(len(i1), len(i2), 2)
    T1 = np.array([[lines[i][4], lines[i][5]] for i in i1])
    T2 = np.array([[lines[i][4], lines[i][5]] for i in i2])
    inside = (
        (tr[..., 0] > T1[:, None, 0] + tol)
        & (tr[..., 0] < T1[:, None, 1] - tol)
        & (tr[..., 1] > T2[None, :, 0] + tol)
        & (tr[..., 1] < T2[None, :, 1] - tol)
    )
    cross_a, cross_b = np.nonzero(inside)  # indices into i1, i2
    return tr, cross_a, cross_b


class _Builder:
    """Nodes, beams and crossing nodes of the yarns, added yarn by yarn."""

    def __init__(self, L: float, tol: float, elements_per_segment: int) -> None:
        self.L, self.tol, self.eps = L, tol, elements_per_segment
        self.X: list[np.ndarray] = []
        self.node_yarn: list[int] = []
        self.node_family: list[int] = []
        self.node_end: list[int] = []
        self.yarn_family: list[int] = []
        self.yarn_index: list[int] = []
        self.yarn_nodes: list[np.ndarray] = []
        self.yarn_ends: list[tuple[int, int]] = []
        self.beams: list[tuple[int, int]] = []
        self.beam_family: list[int] = []
        # crossing node of (family-1 yarn a, family-2 yarn b) on each yarn, and the yarn of each line
        self.node_on: dict[int, dict[tuple[int, int], int]] = {1: {}, 2: {}}
        self.yarn_of: dict[int, dict[int, int]] = {1: {}, 2: {}}

    def _node(self, P: np.ndarray, y: int, fam: int, end: int) -> int:
        self.X.append(P)
        self.node_yarn.append(y)
        self.node_family.append(fam)
        self.node_end.append(end)
        return len(self.X) - 1

    def add_yarn(self, line: _Line, k: int, partners: np.ndarray, ts: np.ndarray) -> None:
        """The chain of beams of one yarn (line ``k`` of its family) through its crossings at ``ts``."""
        fam, j, p0, m, t0, t1 = line
        y = len(self.yarn_family)
        self.yarn_of[fam][k] = y
        order = np.argsort(ts)
        partners, ts = partners[order], ts[order]
        ends = (end_kind(p0 + t0 * m, self.L, self.tol), end_kind(p0 + t1 * m, self.L, self.tol))
        stations = np.concatenate([[t0], ts, [t1]])
        chain = [self._node(p0 + t0 * m, y, fam, ends[0])]
        for s_idx in range(1, len(stations)):
            ta, tb = stations[s_idx - 1], stations[s_idx]
            for q in range(1, self.eps):
                chain.append(self._node(p0 + (ta + (tb - ta) * q / self.eps) * m, y, fam, FREE))
            last = s_idx == len(stations) - 1
            chain.append(self._node(p0 + tb * m, y, fam, ends[1] if last else FREE))
            if not last:
                other = int(partners[s_idx - 1])
                self.node_on[fam][(k, other) if fam == 1 else (other, k)] = chain[-1]
        chain_arr = np.array(chain)
        self.beams.extend(zip(chain_arr[:-1].tolist(), chain_arr[1:].tolist(), strict=True))
        self.beam_family.extend([fam] * (len(chain) - 1))
        self.yarn_family.append(fam)
        self.yarn_index.append(j)
        self.yarn_nodes.append(chain_arr)
        self.yarn_ends.append(ends)

    def _trusses(self, lines: list[_Line], i1: np.ndarray, i2: np.ndarray) -> list[tuple[int, int]]:
        """Trusses between the crossing nodes of adjacent parallel yarns."""
        on1, on2 = self.node_on[1], self.node_on[2]
        j1 = {k: lines[i1[k]][1] for k in self.yarn_of[1]}
        j2 = {k: lines[i2[k]][1] for k in self.yarn_of[2]}
        by1 = {(j1[ka], kb): n for (ka, kb), n in on1.items()}  # (j of fam-1 yarn, fam-2 yarn) -> node
        by2 = {(ka, j2[kb]): n for (ka, kb), n in on2.items()}
        trusses = [(n, by1[(jj + 1, kb)]) for (jj, kb), n in sorted(by1.items()) if (jj + 1, kb) in by1]
        trusses += [(n, by2[(ka, jj + 1)]) for (ka, jj), n in sorted(by2.items()) if (ka, jj + 1) in by2]
        return trusses

    def network(
        self, lines: list[_Line], i1: np.ndarray, i2: np.ndarray, inter_layout: str, spacing: float, W: float, a: float
    ) -> Network:
        """The assembled network (crossings, their zones, trusses)."""
        on1, on2 = self.node_on[1], self.node_on[2]
        keys = sorted(on1)
        crossings = np.array([[on1[kk], on2[kk]] for kk in keys], int).reshape(-1, 2)
        crossing_yarns = np.array([[self.yarn_of[1][kk[0]], self.yarn_of[2][kk[1]]] for kk in keys], int).reshape(-1, 2)
        yarn_ends = np.array(self.yarn_ends, int).reshape(-1, 2)
        zone = np.array([crossing_zone(yarn_ends[ya], yarn_ends[yb]) for ya, yb in crossing_yarns], int)
        trusses = self._trusses(lines, i1, i2) if inter_layout == "neighbours" else []
        Xa = np.array(self.X)
        beams = np.array(self.beams, int).reshape(-1, 2)
        seg = np.linalg.norm(Xa[beams[:, 1]] - Xa[beams[:, 0]], axis=1)
        if seg.min() < 1e-3 * spacing / self.eps:
            log.warning(
                "shortest beam element is %.3g mm (spacing %.3g mm): the tangent will be ill-conditioned",
                seg.min() * 1e3,
                spacing * 1e3,
            )
        return Network(
            X=Xa,
            node_yarn=np.array(self.node_yarn),
            node_family=np.array(self.node_family),
            node_end=np.array(self.node_end),
            yarn_family=np.array(self.yarn_family),
            yarn_index=np.array(self.yarn_index),
            yarn_nodes=tuple(self.yarn_nodes),
            yarn_ends=yarn_ends,
            beams=beams,
            beam_family=np.array(self.beam_family),
            crossings=crossings,
            crossing_yarns=crossing_yarns,
            crossing_zone=zone,
            trusses=np.array(trusses, int).reshape(-1, 2),
            spacing=spacing,
            L=self.L,
            W=W,
            angle=a,
        )


def crossing_zone(ends_1: np.ndarray, ends_2: np.ndarray) -> int:
    """BET zone of a crossing from the end kinds of its two yarns: 0 = A, 1 = B, 2 = C, 3 = other."""
    c1 = {e for e in ends_1 if e != FREE}
    c2 = {e for e in ends_2 if e != FREE}
    if not c1 and not c2:
        return 0
    if not c1 or not c2:
        return 1
    return 2 if c1 & c2 else 3


def network_from_scene(scene: Scene) -> Network:
    """The network of ``scene.specimen`` with the spacing and layout of ``scene.discrete``.

    Raises
    ------
    ngbet.scene.validate.SceneError
        naming ``discrete.spacing_mm`` where the spacing gives a network that carries no load
        (no chain of yarns and crossings joins the clamps).
    """
    from ..scene.validate import SceneError

    sp, d = scene.specimen, scene.discrete
    try:
        return build_network(sp.L, sp.W, sp.yarn_angle_deg, d.spacing_mm * 1e-3, d.elements_per_segment, d.inter_layout)
    except NetworkError as exc:
        raise SceneError(f"scene key 'discrete.spacing_mm' = {d.spacing_mm!r}: {exc}") from None
