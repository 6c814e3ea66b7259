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
    from ..scene import Scene

ENERGY_PARTS = ("axial", "bending1", "bending2", "slip", "shear_springs", "inter")

Kernel = Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray, "np.ndarray | None"]]


@dataclass(frozen=True)
class Group:
    """Elements of one kind: dof table (n, k) and the kernel returning (psi, grad, Hessian)."""

    name: str  # the energy part it contributes to
    dofs: np.ndarray
    kernel: Kernel


def _beam_kernel(Xe: np.ndarray, ea: np.ndarray, ei: np.ndarray, ue: np.ndarray, h: bool) -> Any:
    return el.beam(ue, Xe, ea, ei, h)


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
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(np.int64)
        self.indices = c.astype(np.int64)
        self.rows = r

    def matrix(self, element_matrices: list[np.ndarray | None], const: np.ndarray | None = None) -> sp.csr_matrix:
        """Sum the element matrices into a CSR matrix.

        The matrices come in the order of the dof tables; None marks a table whose sum is in
        ``const``, the CSR values of the constant part.
        """
        key = tuple(H is not None for H in element_matrices)
        if key not in self._index:
            self._index[key] = np.concatenate([self.map[self.offsets[i]:self.offsets[i + 1]]
                                               for i, k in enumerate(key) if k])
        vals = np.concatenate([H.reshape(-1) for H in element_matrices if H is not None])
        data = np.bincount(self._index[key], weights=vals, minlength=self.nnz)
        if const is not None:
            data += const
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def constant_part(self, element_matrices: list[np.ndarray | None]) -> np.ndarray:
        """CSR values of the sum of the given element matrices (None: left out)."""
        data = np.zeros(self.nnz)
        for i, H in enumerate(element_matrices):
            if H is not None:
                data += np.bincount(self.map[self.offsets[i]:self.offsets[i + 1]], weights=np.ravel(H),
                                    minlength=self.nnz)
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

    def __init__(self, net: Network, EA1: float, EA2: float, EI1: float, EI2: float, K_phi: float,
                 K_slip: float, K_inter: float, end_rotation: str = "free") -> None:
        if end_rotation not in ("free", "held"):
            raise ValueError(f"end_rotation = {end_rotation!r}: must be 'free' or 'held'")
        self.net = net
        self.n_dofs = net.n_dofs
        X = net.X
        dof3 = lambda nodes: (3 * nodes[..., None] + np.arange(3)).reshape(nodes.shape[0], -1)  # noqa: E731
        self.groups: list[Group] = []
        for fam, EA, EI in ((1, EA1, EI1), (2, EA2, EI2)):
            b = net.beams[net.beam_family == fam]
            if len(b) == 0:
                continue
            Xe = X[b]
            ea, ei = np.full(len(b), float(EA)), np.full(len(b), float(EI))
            self.groups.append(Group(f"beam{fam}", dof3(b), functools.partial(_beam_kernel, Xe, ea, ei)))
        c = net.crossings
        if len(c) and K_slip > 0:
            d = np.column_stack([3 * c[:, 0], 3 * c[:, 0] + 1, 3 * c[:, 1], 3 * c[:, 1] + 1])
            self.groups.append(Group("slip", d, lambda ue, h: el.slip_spring(ue, K_slip, h)))
        if len(c) and K_phi > 0:
            d = np.column_stack([3 * c[:, 0] + 2, 3 * c[:, 1] + 2])
            self.groups.append(Group("shear_springs", d, lambda ue, h: el.rotational_spring(ue, K_phi, h)))
        t = net.trusses
        if len(t) and K_inter > 0:
            d = np.column_stack([3 * t[:, 0], 3 * t[:, 0] + 1, 3 * t[:, 1], 3 * t[:, 1] + 1])
            Xt = X[t]
            kt = np.full(len(t), float(K_inter))
            self.groups.append(Group("inter", d, functools.partial(_truss_kernel, Xt, kt)))
        self.pattern = Pattern([g.dofs for g in self.groups], self.n_dofs)
        # the springs' Hessians do not depend on u: summed once (speed only; same matrix)
        self._const_groups = {"slip", "shear_springs"}
        zero = np.zeros(self.n_dofs)
        self._const_data = self.pattern.constant_part(
            [grp.kernel(zero[grp.dofs], True)[2] if grp.name in self._const_groups else None for grp in self.groups])
        self.stiffness = dict(EA1=EA1, EA2=EA2, EI1=EI1, EI2=EI2, K_phi=K_phi, K_slip=K_slip, K_inter=K_inter)
        self.end_rotation = end_rotation

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

    @classmethod
    def from_scene(cls, scene: Scene, net: Network | None = None) -> NetworkModel:
        """Model of ``scene.discrete`` on the network of the scene (built unless given)."""
        from .network import network_from_scene

        d = scene.discrete
        return cls(net if net is not None else network_from_scene(scene), d.EA1, d.EA2, d.EI1, d.EI2,
                   d.K_phi, d.K_slip, d.K_inter, d.end_rotation)

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        """Total energy E [J], gradient dE/du and (optionally) the Hessian (full, all dofs) at u."""
        E = 0.0
        g = np.zeros(self.n_dofs)
        Hs = []
        for grp in self.groups:
            psi, ge, He = grp.kernel(u[grp.dofs], hessian)
            E += float(psi.sum())
            _scatter_add(g, grp.dofs, ge)
            if hessian:
                Hs.append(None if grp.name in self._const_groups else He)
        return E, g, (self.pattern.matrix(Hs, self._const_data) if hessian else None)

    def half_turn(self) -> HalfTurn | None:
        """The network's half-turn symmetry (:mod:`.symmetry`), or None where it lacks one."""
        return half_turn(self)

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
                b = self.net.beams[self.net.beam_family == fam]
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


def _scatter_add(g: np.ndarray, dofs: np.ndarray, ge: np.ndarray) -> None:
    """g[dofs] += ge with repeated indices summed (bincount is much faster than np.add.at)."""
    g += np.bincount(dofs.ravel(), weights=ge.ravel(), minlength=g.shape[0])
