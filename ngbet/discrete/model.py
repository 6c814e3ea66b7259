"""Total energy of the yarn network and its exact gradient and Hessian, assembled with a fixed pattern.

    E(u) = sum_beams (psi_axial + psi_bend)  +  sum_crossings (1/2 K_slip |u_a - u_b|^2
           + 1/2 K_phi (theta_b - theta_a)^2)  +  sum_trusses 1/2 K_inter (l - L0)^2 / L0

(element formulas in :mod:`ngbet.discrete.elements`). The sparsity pattern of the Hessian is built
once from the element dof tables; each assembly is then one ``np.bincount`` of the element
matrices into the CSR value array, so that the values can be handed in place to a factorization
that was analysed once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from . import elements as el
from .network import CLAMP_FIXED, CLAMP_MOVING, Network
from .symmetry import HalfTurn, half_turn

if TYPE_CHECKING:
    from ..scene.document import Scene

__all__ = ["ENERGY_PARTS", "MIRROR_TOL", "Group", "Kernel", "NetworkModel", "Pattern"]

ENERGY_PARTS = ("axial", "bending1", "bending2", "slip", "shear_springs", "inter")

Kernel = Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray, "np.ndarray | None"]]


MIRROR_TOL = 1e-13
"""A state within MIRROR_TOL (max-norm, relative) of the symmetric path is evaluated by half the
elements and their images. The solver keeps states on the path to about 1e-16 (projected
predictions, symmetric Newton steps); states off it (an escape along an antisymmetric mode) are
1e-3 off and evaluated element by element."""


@dataclass(frozen=True)
class Group:
    """Elements of one kind: dof table (n, k) and the kernel returning (psi, grad, Hessian).

    With the half-turn, the table's first ``n_pair`` rows are mapped onto its last ``n_pair`` rows
    (row by row, node by node), the ``n_self`` rows between onto themselves; ``half`` is the
    kernel of the first n_pair + n_self rows and ``sgn`` (n_pair, k) the half-turn's signs of their dofs,
    ``sgn2`` (n_pair, k, k) those of their Hessians' entries (sgn_i sgn_j).
    """

    name: str  # the energy part it contributes to
    dofs: np.ndarray
    kernel: Kernel
    half: Kernel | None = None
    n_pair: int = 0
    n_self: int = 0
    sgn: np.ndarray | None = None
    sgn2: np.ndarray | None = None


def _beam_kernel(Xe: np.ndarray, ea: np.ndarray, ei: np.ndarray, ue: np.ndarray, h: bool) -> Any:
    return el.beam(ue, Xe, ea, ei, h)


def _spring_kernel(fn: Callable[..., Any], K: float, ue: np.ndarray, h: bool) -> Any:
    return fn(ue, K, h)


def _truss_kernel(Xt: np.ndarray, kt: np.ndarray, ue: np.ndarray, h: bool) -> Any:
    return el.truss(ue, Xt, kt, h)


class Pattern:
    """CSR pattern of a sum of element matrices, and the map from element entries to CSR values."""

    def __init__(self, dof_tables: list[np.ndarray], n: int) -> None:
        rows = np.concatenate([np.repeat(d, d.shape[1], axis=1).ravel() for d in dof_tables])
        cols = np.concatenate([np.tile(d, (1, d.shape[1])).ravel() for d in dof_tables])
        key = rows.astype(np.int64) * n + cols
        uniq, self.map = np.unique(key, return_inverse=True)
        sizes = [d.shape[0] * d.shape[1] ** 2 for d in dof_tables]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self._index: dict[tuple[bool, ...], np.ndarray] = {}  # entries of the non-constant tables
        self.n = n
        self.nnz = len(uniq)
        r, c = uniq // n, uniq % n
        # scipy's own index type for this size (int32 below 2^31): a wider one would be copied into
        # it by every new matrix
        idx = np.int32 if max(self.nnz, n) < 2**31 - 1 else np.int64
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(idx)
        self.indices = c.astype(idx)
        self.rows = r

    def matrix(self, element_matrices: list[Any], const: np.ndarray | None = None) -> sp.csr_matrix:
        """Sum the element matrices into a CSR matrix.

        The matrices come in the order of the dof tables, one array (or a tuple of arrays, the
        table's rows in order) per table; None marks a table whose sum is in ``const``, the CSR
        values of the constant part.
        """
        key = tuple(H is not None for H in element_matrices)
        if key not in self._index:
            self._index[key] = np.concatenate(
                [self.map[self.offsets[i] : self.offsets[i + 1]] for i, k in enumerate(key) if k]
            )
        vals = np.concatenate(
            [h.reshape(-1) for H in element_matrices if H is not None for h in (H if isinstance(H, tuple) else (H,))]
        )
        data = np.bincount(self._index[key], weights=vals, minlength=self.nnz)
        if const is not None:
            data += const
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def constant_part(self, element_matrices: list[np.ndarray | None]) -> np.ndarray:
        """CSR values of the sum of the given element matrices (None: left out)."""
        data = np.zeros(self.nnz)
        for i, H in enumerate(element_matrices):
            if H is not None:
                data += np.bincount(
                    self.map[self.offsets[i] : self.offsets[i + 1]], weights=np.ravel(H), minlength=self.nnz
                )
        return data


class NetworkModel:
    """Energy of a yarn network under given stiffnesses, with clamp boundary conditions.

    Parameters
    ----------
    net : the network
    EA1, EA2 [N], EI1, EI2 [N m^2], K_phi [N m], K_slip [N/m], K_inter [N] : stiffnesses (paper, Table 2)
    end_rotation : "free" (yarn ends on a clamp are pinned: position prescribed, as the continuum
        prescribes u on the clamp) or "held" (built in: the end rotation is prescribed too)

    Attributes used by the solver: ``n_dofs``, ``fixed`` (bool mask of prescribed dofs), ``load``
    (prescribed dof values per unit clamp displacement: 1 on ux of the moving clamp), ``ramp``
    (the homogeneous field ux = X / L, for the "clamp" predictor) and :meth:`evaluate`.
    """

    def __init__(
        self,
        net: Network,
        EA1: float,
        EA2: float,
        EI1: float,
        EI2: float,
        K_phi: float,
        K_slip: float,
        K_inter: float,
        end_rotation: str = "free",
    ) -> None:
        if end_rotation not in ("free", "held"):
            raise ValueError(f"end_rotation = {end_rotation!r}: must be 'free' or 'held'")
        self.net = net
        self.n_dofs = net.n_dofs
        self.stiffness = dict(EA1=EA1, EA2=EA2, EI1=EI1, EI2=EI2, K_phi=K_phi, K_slip=K_slip, K_inter=K_inter)
        self.end_rotation = end_rotation
        X = net.X
        tables: dict[str, np.ndarray] = {}  # element kind -> node table
        for fam in (1, 2):
            if np.any(net.beam_family == fam):
                tables[f"beam{fam}"] = net.beams[net.beam_family == fam]
        if len(net.crossings) and K_slip > 0:
            tables["slip"] = net.crossings
        if len(net.crossings) and K_phi > 0:
            tables["shear_springs"] = net.crossings
        if len(net.trusses) and K_inter > 0:
            tables["inter"] = net.trusses
        self.groups: list[Group] = [self._group(name, T) for name, T in tables.items()]

        fixed_nodes = np.flatnonzero(net.node_end != 0)
        held = np.arange(3 if end_rotation == "held" else 2)
        self.fixed = np.zeros(self.n_dofs, bool)
        self.fixed[(3 * fixed_nodes[:, None] + held).ravel()] = True
        self.moving_nodes = net.clamped_nodes(CLAMP_MOVING)
        self.fixed_nodes = net.clamped_nodes(CLAMP_FIXED)
        self.load = np.zeros(self.n_dofs)
        self.load[3 * self.moving_nodes] = 1.0
        self.ramp = np.zeros(self.n_dofs)
        self.ramp[0::3] = X[:, 0] / net.L

        # with the half-turn, each element table lists pairs of elements mapped onto each other, the
        # image with its nodes in its pair's order: on the symmetric path half the kernels suffice
        self._mirror = half_turn(self)
        if self._mirror is not None and len(self.moving_nodes):
            img = self._mirror.perm[0::3] // 3
            self.groups = [self._group(name, *_paired(T, img)) for name, T in tables.items()]
        else:
            self._mirror = None
        self.pattern = Pattern([g.dofs for g in self.groups], self.n_dofs)
        # the springs' Hessians do not depend on u: summed once (speed only; same matrix)
        self._const_groups = {"slip", "shear_springs"}
        zero = np.zeros(self.n_dofs)
        self._const_data = self.pattern.constant_part(
            [grp.kernel(zero[grp.dofs], True)[2] if grp.name in self._const_groups else None for grp in self.groups]
        )

    def _group(self, name: str, T: np.ndarray, n_pair: int = 0, n_self: int = 0) -> Group:
        """The element group ``name`` on the node table T (its first n_pair rows mirrored by its last n_pair)."""
        X, k = self.net.X, self.stiffness
        n_half = n_pair + n_self if n_pair else len(T)
        if name.startswith("beam"):
            fam = name[-1]
            dofs = (3 * T[..., None] + np.arange(3)).reshape(T.shape[0], -1)
            ea, ei = np.full(len(T), float(k[f"EA{fam}"])), np.full(len(T), float(k[f"EI{fam}"]))
            kernel = functools.partial(_beam_kernel, X[T], ea, ei)
            half = functools.partial(_beam_kernel, X[T[:n_half]], ea[:n_half], ei[:n_half])
        elif name == "inter":
            dofs = np.column_stack([3 * T[:, 0], 3 * T[:, 0] + 1, 3 * T[:, 1], 3 * T[:, 1] + 1])
            kt = np.full(len(T), float(k["K_inter"]))
            kernel = functools.partial(_truss_kernel, X[T], kt)
            half = functools.partial(_truss_kernel, X[T[:n_half]], kt[:n_half])
        elif name == "slip":
            dofs = np.column_stack([3 * T[:, 0], 3 * T[:, 0] + 1, 3 * T[:, 1], 3 * T[:, 1] + 1])
            kernel = half = functools.partial(_spring_kernel, el.slip_spring, float(k["K_slip"]))
        else:
            dofs = np.column_stack([3 * T[:, 0] + 2, 3 * T[:, 1] + 2])
            kernel = half = functools.partial(_spring_kernel, el.rotational_spring, float(k["K_phi"]))
        sgn = sgn2 = None
        if n_pair:
            assert self._mirror is not None
            sgn = self._mirror.sign[dofs[:n_pair]]
            sgn2 = sgn[:, :, None] * sgn[:, None, :]
        return Group(name, dofs, kernel, half, n_pair, n_self, sgn, sgn2)

    def _on_symmetric_path(self, u: np.ndarray) -> bool:
        """Whether u = c u0 + S u to round-off (:mod:`.symmetry`), u0 read off the moving clamp."""
        ht = self._mirror
        if ht is None:
            return False
        u0 = u[3 * self.moving_nodes[0]]
        off = u - ht.sign * u[ht.perm] - u0 * ht.shift
        return float(np.abs(off).max(initial=0.0)) <= MIRROR_TOL * float(np.abs(u).max(initial=0.0))

    @classmethod
    def from_scene(cls, scene: Scene, net: Network | None = None) -> NetworkModel:
        """Model of ``scene.discrete`` on the network of the scene (built unless given)."""
        from .network import network_from_scene

        d = scene.discrete
        return cls(
            net if net is not None else network_from_scene(scene),
            d.EA1,
            d.EA2,
            d.EI1,
            d.EI2,
            d.K_phi,
            d.K_slip,
            d.K_inter,
            d.end_rotation,
        )

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        """Total energy E [J], gradient dE/du and (optionally) the Hessian (full, all dofs) at u."""
        E = 0.0
        g = np.zeros(self.n_dofs)
        Hs: list[Any] = []
        mirror = self._on_symmetric_path(u)
        He: Any
        for grp in self.groups:
            if mirror and grp.n_pair:
                # on the symmetric path an element's image has its energy, and its gradient and
                # Hessian with the half-turn's signs (sigma_i g_i, sigma_i sigma_j H_ij)
                n = grp.n_pair
                sgn, sgn2, half = grp.sgn, grp.sgn2, grp.half
                assert sgn is not None and sgn2 is not None and half is not None
                psi, ge, He = half(u[grp.dofs[: n + grp.n_self]], hessian)
                E += float(psi.sum()) + float(psi[:n].sum())
                ge = np.concatenate([ge, ge[:n] * sgn])
                if hessian and He is not None:
                    He = (He, He[:n] * sgn2)
            else:
                psi, ge, He = grp.kernel(u[grp.dofs], hessian)
                E += float(psi.sum())
            _scatter_add(g, grp.dofs, ge)
            if hessian:
                Hs.append(None if grp.name in self._const_groups else He)
        return E, g, (self.pattern.matrix(Hs, self._const_data) if hessian else None)

    def half_turn(self) -> HalfTurn | None:
        """The network's half-turn symmetry (:mod:`.symmetry`), found when the model was built, or None."""
        return self._mirror

    def energy(self, u: np.ndarray) -> float:
        """Total energy E(u) [J]."""
        return sum(float(grp.kernel(u[grp.dofs], False)[0].sum()) for grp in self.groups)

    def energy_parts(self, u: np.ndarray) -> dict[str, float]:
        """Energy per term [J]: axial (both families), bending1, bending2, slip, shear_springs, inter."""
        out = dict.fromkeys(ENERGY_PARTS, 0.0)
        X = self.net.X
        for grp in self.groups:
            if grp.name.startswith("beam"):
                fam = int(grp.name[-1])
                b = grp.dofs[:, [0, 3]] // 3  # the beams' nodes, in the group's order
                EA, EI = self.stiffness[f"EA{fam}"], self.stiffness[f"EI{fam}"]
                ax, be = el.beam_energy_parts(u[grp.dofs], X[b], np.full(len(b), EA), np.full(len(b), EI))
                out["axial"] += float(ax.sum())
                out[f"bending{fam}"] += float(be.sum())
            else:
                out[grp.name] += float(grp.kernel(u[grp.dofs], False)[0].sum())
        return out

    def reaction(self, g: np.ndarray) -> tuple[float, float]:
        """Force [N] on the moving clamp (sum of the internal forces on its nodes): (F_x, F_y)."""
        m = self.moving_nodes
        return float(g[3 * m].sum()), float(g[3 * m + 1].sum())


def _paired(T: np.ndarray, img: np.ndarray) -> tuple[np.ndarray, int, int]:
    """T's rows as (pairs, self-mapped rows, images of the pairs), the images in their pair's node order.

    ``img``: the image node of each node. Rows are matched as unordered node sets.
    """
    n = len(img)
    key = np.sort(T, axis=1).astype(np.int64)
    key = key[:, 0] * n + key[:, 1] if T.shape[1] == 2 else key[:, 0]
    ik = np.sort(img[T], axis=1).astype(np.int64)
    ik = ik[:, 0] * n + ik[:, 1] if T.shape[1] == 2 else ik[:, 0]
    order = np.argsort(key)
    j = order[np.searchsorted(key, ik, sorter=order)]  # the row each row is mapped onto
    rows = np.arange(len(T))
    first, self_mapped = rows[j > rows], rows[j == rows]
    return np.concatenate([T[first], T[self_mapped], img[T[first]]]), len(first), len(self_mapped)


def _scatter_add(g: np.ndarray, dofs: np.ndarray, ge: np.ndarray) -> None:
    """g[dofs] += ge with repeated indices summed (bincount is much faster than np.add.at)."""
    g += np.bincount(dofs.ravel(), weights=ge.ravel(), minlength=g.shape[0])
