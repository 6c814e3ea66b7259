"""The half-turn symmetry of a BET network, and the two half-size blocks of a tangent it gives.

The specimen, its yarn lines and its clamps are mapped onto themselves by the half-turn R about the
centre C (X -> 2C - X), the fixed clamp onto the moving one. On nodal dofs the half-turn acts as

    (S v)_i = sigma_i v_pi(i),   pi(i): the same dof of the image node,
    sigma = -1 on the translations (R reverses vectors), +1 on the rotations (R keeps angles),

so that S^2 = I and S is orthogonal. The energy is invariant under u -> c u0 + S u, with c the
translation (1, 0) of every node (the elements see only differences of translations), and the
prescribed values are mapped onto themselves (fixed clamp 0 <-> moving clamp (u0, 0)). A state
of the symmetric path has u = c u0 + S u, and there the tangent commutes with S. In an orthonormal
basis of the symmetric (S v = v) and antisymmetric (S v = -v) free vectors, the columns of B_s and
B_a, the free block is therefore block diagonal,

    K_ff = B_s K_s B_s^T + B_a K_a B_a^T,   K_s = B_s^T K_ff B_s,   K_a = B_a^T K_ff B_a,

two blocks of half the size, each factorized in about half the time of K_ff (nested dissection of
a planar network) and solved in about half the time. K_ff^-1 b = B_s K_s^-1 B_s^T b + B_a K_a^-1
B_a^T b is exact for any b. The Newton step of a symmetric state needs K_s only: its residual is
symmetric. Whether a tangent is of a symmetric state is read off the tangent itself: its coupling
block B_s^T K_ff B_a must vanish to round-off (a state off the symmetric path, after an escape
along an antisymmetric unstable mode, has a coupling many orders above it).

Basis: each pair {i, pi(i)}, i < pi(i), gives (e_i + sigma_i e_pi(i)) / sqrt 2 to B_s and
(e_i - sigma_i e_pi(i)) / sqrt 2 to B_a; a dof mapped onto itself (the two nodes at the centre
crossing, if there is one) is symmetric when sigma_i = +1 (a rotation) and antisymmetric otherwise.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp

__all__ = ["COUPLING_TOL", "STATE_TOL", "Blocks", "HalfTurn", "Symmetric", "half_turn"]

log = logging.getLogger(__name__)

COUPLING_TOL = 1e-9
"""A tangent is block diagonal when every entry of its coupling block is below COUPLING_TOL times
the geometric mean of the two diagonal entries it couples. At the symmetric states of the BET
paths measured the largest such ratio is about 1e-13 (assembly round-off); an antisymmetric
perturbation of 1e-6 of the state raises it to about 1e-5 (tests/test_discrete_symmetry.py)."""


STATE_TOL = 1e-7
"""A state within STATE_TOL (max-norm, relative to the state's) of the symmetric path is taken for
one of its states and projected onto it (:meth:`HalfTurn.project`). Round-off leaves states of the
symmetric path about 1e-10 off it (a Newton solve amplifies assembly round-off by the tangent's
condition); the kick along an antisymmetric unstable mode is about 1e-3 of the state."""


@dataclass(frozen=True)
class HalfTurn:
    """The half-turn on the dofs: ``perm[i]`` is the dof dof i is mapped onto, ``sign[i]`` sigma_i.

    ``shift``: the translation c = (1, 0) of every node (the symmetric path's u - S u per unit u0).
    """

    perm: np.ndarray
    sign: np.ndarray
    shift: np.ndarray

    def project(self, u: np.ndarray, u0: float, tol: float = STATE_TOL) -> np.ndarray | None:
        """The state of the symmetric path nearest to u, (u + S u + c u0) / 2, when u is within ``tol``.

        None when u is further off: a state that has left the symmetric path (an escape along an
        antisymmetric mode) is not projected back.
        """
        v = 0.5 * (u + self.sign * u[self.perm] + u0 * self.shift)
        scale = max(float(np.abs(u).max(initial=0.0)), 1e-300)
        return v if float(np.abs(v - u).max(initial=0.0)) <= tol * scale else None


class Symmetric(Protocol):
    """What :func:`half_turn` reads of a model: its network, element groups, and prescribed dofs.

    (:class:`ngbet.discrete.model.NetworkModel` has it; the protocol keeps this module free of the
    model's import.)
    """

    @property
    def net(self) -> Any: ...  # noqa: D102
    @property
    def groups(self) -> Sequence[Any]: ...  # noqa: D102
    @property
    def fixed(self) -> np.ndarray: ...  # noqa: D102
    @property
    def load(self) -> np.ndarray: ...  # noqa: D102
    @property
    def n_dofs(self) -> int: ...  # noqa: D102


def half_turn(model: Symmetric, rel_tol: float = 1e-9) -> HalfTurn | None:
    """The half-turn of ``model`` about the specimen's centre, or None where the model lacks it.

    The nodes must be mapped onto nodes of the same family (to ``rel_tol`` of the yarn spacing),
    every element group onto itself (the element parameters are uniform per group), the
    prescribed dofs onto prescribed dofs, and the prescribed values u0 * load onto themselves
    (load_i = c_i + sigma_i load_pi(i)).
    """
    net = model.net
    X = net.X
    centre = np.array([net.L / 2, net.W / 2])
    img = _image_nodes(X, net.node_family, centre, rel_tol * net.spacing)
    if img is None:
        return _without("a node has no image of its family")
    perm = (3 * img[:, None] + np.arange(3)).ravel()
    sign = np.tile([-1.0, -1.0, 1.0], len(img))
    for grp in model.groups:
        if not _same_rows(grp.dofs, perm[grp.dofs]):
            return _without(f"the elements of {grp.name!r} are not mapped onto themselves")
    if not np.array_equal(model.fixed[perm], model.fixed):
        return _without("the prescribed dofs are not mapped onto prescribed dofs")
    c = np.zeros(model.n_dofs)
    c[0::3] = 1.0
    fixed = model.fixed
    if not np.allclose(model.load[fixed], c[fixed] + sign[fixed] * model.load[perm][fixed], rtol=0, atol=1e-12):
        return _without("the prescribed displacements are not mapped onto themselves")
    return HalfTurn(perm, sign, c)


def _without(why: str) -> HalfTurn | None:
    log.info("no half-turn symmetry (%s): the tangent is factorized whole", why)
    return None


def _image_nodes(X: np.ndarray, family: np.ndarray, centre: np.ndarray, tol: float) -> np.ndarray | None:
    """The node at 2C - X of each node, of the same family; None when one is missing.

    Nodes and images are sorted alike (by coordinates on a grid of 1000 tol, far coarser than the
    round-off of 2C - X and far finer than the yarn spacing) and paired in that order; the pairs
    must then lie within ``tol``.
    """
    img = np.full(len(X), -1)
    for fam in np.unique(family):
        idx = np.flatnonzero(family == fam)
        Y = 2 * centre - X[idx]
        grid = 1e3 * tol
        a = np.lexsort(np.round(X[idx] / grid).T[::-1])
        b = np.lexsort(np.round(Y / grid).T[::-1])
        if np.any(np.abs(X[idx][a] - Y[b]) > tol):
            return None
        img[idx[b]] = idx[a]
    if np.any(img[img] != np.arange(len(X))):
        return None
    return img


def _same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the rows of a and b, each taken as a set, are the same collection."""
    sa, sb = np.sort(a, axis=1), np.sort(b, axis=1)
    return bool(np.array_equal(sa[np.lexsort(sa.T[::-1])], sb[np.lexsort(sb.T[::-1])]))


class Blocks:
    """Maps between the free block K_ff (a fixed CSR pattern) and its two half-turn blocks.

    Parameters
    ----------
    ht : the half-turn
    free : indices of the free dofs (ascending)
    rows, cols : the pattern of K_ff (CSR order)
    """

    def __init__(self, ht: HalfTurn, free: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        nf = len(free)
        newid = np.full(len(ht.perm), -1)
        newid[free] = np.arange(nf)
        pi = newid[ht.perm[free]]
        if np.any(pi < 0):
            raise ValueError("the half-turn maps a free dof onto a prescribed one")
        sg = ht.sign[free]
        self.col_s, self.w_s, self.n_s = _basis(pi, sg, +1)
        self.col_a, self.w_a, self.n_a = _basis(pi, sg, -1)
        self.B_s, self.B_a = self._matrix(self.col_s, self.w_s, self.n_s), self._matrix(self.col_a, self.w_a, self.n_a)
        self.Bt_s, self.Bt_a = self.B_s.T.tocsr(), self.B_a.T.tocsr()
        # (B∘B)^T: the blocks' diagonal scalings from K_ff's (B^T D B is diagonal for a diagonal D)
        self.B2t_s, self.B2t_a = self.B_s.multiply(self.B_s).T.tocsr(), self.B_a.multiply(self.B_a).T.tocsr()
        self.M_s, self.rows_s, self.cols_s = self._data_map(rows, cols, "s", "s")
        self.M_a, self.rows_a, self.cols_a = self._data_map(rows, cols, "a", "a")
        self.M_sa, rows_sa, cols_sa = self._data_map(rows, cols, "s", "a")
        self._diag_s = np.flatnonzero(self.rows_s == self.cols_s)
        self._diag_a = np.flatnonzero(self.rows_a == self.cols_a)
        if len(self._diag_s) != self.n_s or len(self._diag_a) != self.n_a:
            raise ValueError("a half-turn block has an empty diagonal entry")
        # the coupling entries' diagonal partners, as positions in the blocks' diagonals
        self._sa_rows, self._sa_cols = rows_sa, cols_sa
        self._M_a_diag = self.M_a[self._diag_a]

    def _matrix(self, col: np.ndarray, w: np.ndarray, n: int) -> sp.csr_matrix:
        i = np.flatnonzero(col >= 0)
        return sp.csr_matrix((w[i], (i, col[i])), shape=(len(col), n))

    def _data_map(
        self, rows: np.ndarray, cols: np.ndarray, left: str, right: str
    ) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        """M with (B_left^T K B_right).data = M @ K.data, and the block's pattern (CSR order)."""
        c1, w1, _ = self._side(left)
        c2, w2, n2 = self._side(right)
        k = np.flatnonzero((c1[rows] >= 0) & (c2[cols] >= 0))
        key = c1[rows[k]].astype(np.int64) * n2 + c2[cols[k]]
        uniq, inv = np.unique(key, return_inverse=True)
        M = sp.csr_matrix((w1[rows[k]] * w2[cols[k]], (inv, k)), shape=(len(uniq), len(rows)))
        return M, uniq // n2, uniq % n2

    def _side(self, kind: str) -> tuple[np.ndarray, np.ndarray, int]:
        return (self.col_s, self.w_s, self.n_s) if kind == "s" else (self.col_a, self.w_a, self.n_a)

    def coupling(self, vals: np.ndarray, vals_s: np.ndarray) -> float:
        """The largest entry of B_s^T K_ff B_a relative to the diagonal entries it couples.

        ``vals``: K_ff's values; ``vals_s``: those of K_s (``M_s @ vals``).
        """
        c = self.M_sa @ vals
        if len(c) == 0:
            return 0.0
        ds = np.abs(vals_s[self._diag_s])
        da = np.abs(self._M_a_diag @ vals)
        scale = np.sqrt(ds[self._sa_rows] * da[self._sa_cols])
        return float(np.max(np.abs(c) / np.maximum(scale, 1e-300)))


def _basis(pi: np.ndarray, sg: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Column index (-1: none) and weight of each free dof in the basis of S v = s v."""
    f = np.arange(len(pi))
    first = f[pi > f]  # the first dof of each pair
    self_mapped = f[(pi == f) & (sg == s)]
    col = np.full(len(pi), -1)
    w = np.zeros(len(pi))
    col[first] = col[pi[first]] = np.arange(len(first))
    w[first] = np.sqrt(0.5)
    w[pi[first]] = s * sg[first] * np.sqrt(0.5)
    col[self_mapped] = len(first) + np.arange(len(self_mapped))
    w[self_mapped] = 1.0
    return col, w, len(first) + len(self_mapped)
