"""Factorization of the free-dof block of the tangent, with the pattern analysed once.

The free block K_ff of a CSR matrix whose free dofs are in ascending order keeps the entry order
of the full matrix, so its values are ``K.data[sel]`` for a selection ``sel`` computed once.

Backends
--------
``"cholmod"`` (``"auto"`` when cvxopt is installed: ``pip install "ngbet[cholmod]"``): CHOLMOD's
supernodal LL^T through cvxopt, the symbolic factorization made once. A tangent that is not
positive definite (LL^T meets a non-positive pivot) is factorized by NGSolve's LDL^T instead,
which needs no definiteness: the result is that of ``"sparsecholesky"`` for every tangent, to
round-off. On the 16 890-dof network's half-size blocks the LL^T takes half the time of the LDL^T
and a solve 0.4 of it (bench/README.md).
``"sparsecholesky"`` (``"auto"`` without cvxopt): NGSolve's sparse LDL^T. The NGSolve matrix is
created once from the free pattern (``SparseMatrixd.CreateFromCOO``); each new tangent is copied in
place into ``AsVector()`` and the factorization refreshed by ``Update()``, which reuses the
ordering and symbolic factorization. It works without pivoting, hence also for the indefinite
tangents met past a bifurcation (as long as no pivot vanishes).
``"umfpack"``, ``"pardiso"``: the same NGSolve matrix with that inverse type (if NGSolve has it).
``"splu"``: scipy's SuperLU, refactorized from scratch each time (for comparison; bench_discrete).

Half-turn blocks (:mod:`.symmetry`): given the network's half-turn, a tangent whose coupling block
vanishes (a state of the symmetric path) is factorized as its two half-size blocks, the
antisymmetric one only when a right-hand side has an antisymmetric part. Solves are exact for
any right-hand side; ``solve(r, symmetric_rhs=True)`` drops the antisymmetric part of a residual
of such a state (round-off) and needs the symmetric block only. Any other tangent is factorized
whole. Not with ``"splu"``.
"""

from __future__ import annotations

import copy
import logging
import time
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import scipy.sparse as sp

from .. import cholmod
from ..cholmod import free_pattern

if TYPE_CHECKING:
    from .symmetry import HalfTurn

__all__ = ["BACKENDS", "EigenBlock", "FreeBlockSolver", "LinearSolverError", "resolve_backend"]

log = logging.getLogger(__name__)

BACKENDS = ("cholmod", "sparsecholesky", "umfpack", "pardiso", "splu")


def resolve_backend(backend: str) -> str:
    """The backend ``backend`` names ("auto": "cholmod" when cvxopt is installed, else "sparsecholesky").

    Raises
    ------
    LinearSolverError
        for an unknown backend, or "cholmod" without cvxopt.
    """
    if backend == "auto":
        return "cholmod" if cholmod.available() else "sparsecholesky"
    if backend not in BACKENDS:
        raise LinearSolverError(f"linear solver {backend!r} unknown; known: auto, {', '.join(BACKENDS)}")
    if backend == "cholmod" and not cholmod.available():
        raise LinearSolverError(
            "linear solver 'cholmod' needs cvxopt, which is not installed: "
            "pip install \"ngbet[cholmod]\" (or choose 'auto' or 'sparsecholesky')"
        )
    return backend


class LinearSolverError(RuntimeError):
    """The tangent could not be factorized (singular pivot, NaN) or the backend is unknown."""


class FreeBlockSolver:
    """Solve K_ff x = b for the free block of matrices sharing one CSR pattern.

    Parameters
    ----------
    K : a matrix with the pattern (values ignored)
    free : bool mask of the free dofs
    backend : one of ``BACKENDS`` or ``"auto"``
    half_turn : the problem's half-turn symmetry (None: factorize every tangent whole)
    """

    def __init__(
        self, K: sp.csr_matrix, free: np.ndarray, backend: str = "auto", half_turn: HalfTurn | None = None
    ) -> None:
        backend = resolve_backend(backend)
        self.backend = backend
        self.free = np.flatnonzero(free)
        self.sel, self.rows, self.cols = free_pattern(K.indptr, K.indices, free)
        self.nf = len(self.free)
        self.Kff: sp.csr_matrix | None = None
        self.shifted = False  # the last factorization was of K_ff + diag(shift)
        self.n_factor = 0  # factorizations made (statistics): tangents factorized, whole or in blocks
        self.n_factor_antisymmetric = 0  # ... of which also the antisymmetric block (on demand)
        self.n_factor_whole = 0  # ... of which whole, although the problem has a half-turn (off its symmetric path)
        self.n_solve = 0
        self.t_factor = self.t_solve = 0.0  # wall time in factor() and solve() [s]
        self._lu: Any = None  # scipy's SuperLU ("splu")
        self._whole: _Factor | None = None  # K_ff (created when first needed)
        self._blocks: _HalfTurnFactor | None = None
        self.in_blocks = False  # the last tangent was factorized in its half-turn blocks
        if half_turn is not None and backend != "splu":
            self._blocks = _HalfTurnFactor(half_turn, self.free, self.rows, self.cols, backend)
        elif backend != "splu":
            self._whole = _new_factor(self.rows, self.cols, self.nf, backend)

    @property
    def n_factor_ldlt(self) -> int:
        """Factorizations the "cholmod" backend handed to the LDL^T (tangents not positive definite)."""
        fs = [self._whole] + ([] if self._blocks is None else [self._blocks.sym, self._blocks.anti])
        return sum(f.n_ldlt for f in fs if isinstance(f, _CholmodFactor))

    @property
    def has_half_turn(self) -> bool:
        """Whether tangents of symmetric states are factorized in their half-turn blocks."""
        return self._blocks is not None

    def twin(self) -> FreeBlockSolver:
        """A solver of the same pattern (and half-turn maps) with factorizations of its own."""
        other = copy.copy(self)
        other.Kff, other.shifted, other.in_blocks = None, False, False
        other.n_factor = other.n_factor_antisymmetric = other.n_factor_whole = other.n_solve = 0
        other.t_factor = other.t_solve = 0.0
        other._lu = None
        other._whole = None if self._whole is None else _new_factor(self.rows, self.cols, self.nf, self.backend)
        other._blocks = None if self._blocks is None else self._blocks.twin()
        return other

    def free_block(self, K: sp.csr_matrix) -> sp.csr_matrix:
        """K_ff as a scipy CSR matrix (same pattern object every time)."""
        return sp.csr_matrix((K.data[self.sel], self.cols, self._indptr()), shape=(self.nf, self.nf))

    def factor(self, K: sp.csr_matrix, shift: np.ndarray | None = None) -> None:
        """Factorize K_ff (+ diag(shift) when given)."""
        t0 = time.perf_counter()
        try:
            self._factor(K, shift)
        finally:
            self.t_factor += time.perf_counter() - t0

    def _factor(self, K: sp.csr_matrix, shift: np.ndarray | None) -> None:
        vals = K.data[self.sel]
        self.n_factor += 1
        self.shifted = shift is not None
        if not np.all(np.isfinite(vals)):
            raise LinearSolverError("tangent has non-finite entries")
        # the coupling is judged on the tangent itself (a shift by a multiple of its diagonal keeps it)
        self.in_blocks = self._blocks is not None and self._blocks.decoupled(vals)
        if shift is not None:
            vals = vals.copy()
            vals[self.rows == self.cols] += shift
        self.Kff = sp.csr_matrix((vals, self.cols, self._indptr()), shape=(self.nf, self.nf))
        if self.backend == "splu":
            import scipy.sparse.linalg as spla  # (this backend alone: a network run need not import it)

            try:
                self._lu = spla.splu(self.Kff.tocsc())
            except RuntimeError as exc:
                raise LinearSolverError(f"SuperLU failed: {exc}") from None
            return
        if self.in_blocks:
            assert self._blocks is not None
            self._blocks.factor(vals, shift is not None)
            return
        if self._whole is None:
            self._whole = _new_factor(self.rows, self.cols, self.nf, self.backend)
        if self._blocks is not None:
            self.n_factor_whole += 1
        self._whole.factor(vals)

    def half_turn_blocks(self) -> list[EigenBlock] | None:
        """The factorized tangent as its two half-turn blocks (symmetric, antisymmetric), or None.

        None unless the last tangent was factorized in blocks. Each block carries its matrix (the
        values factorized), its basis B (columns in the free dofs) and a solve with its own
        factorization; the antisymmetric block is factorized when first solved with.
        """
        if not self.in_blocks or self._blocks is None:
            return None
        bl = self._blocks
        m = bl.maps
        return [
            EigenBlock(self, "s", bl.block_matrix("s"), m.B_s, m.Bt_s, m.B2t_s),
            EigenBlock(self, "a", bl.block_matrix("a"), m.B_a, m.Bt_a, m.B2t_a),
        ]

    def diagonal(self) -> np.ndarray:
        """The diagonal of the last K_ff factorized (a copy; with its shift where it was shifted)."""
        assert self.Kff is not None
        if not hasattr(self, "_diag_pos"):  # the diagonal's positions in the values, once per pattern
            pos = np.flatnonzero(self.rows == self.cols)
            self._diag_pos = pos if np.array_equal(self.rows[pos], np.arange(self.nf)) else None
        if self._diag_pos is None:  # a pattern without every diagonal entry
            return cast(np.ndarray, self.Kff.diagonal())
        return cast(np.ndarray, self.Kff.data[self._diag_pos])

    def _indptr(self) -> np.ndarray:
        if not hasattr(self, "_ip"):
            self._ip = np.concatenate([[0], np.cumsum(np.bincount(self.rows, minlength=self.nf))])
        return self._ip

    def solve(self, b: np.ndarray, symmetric_rhs: bool = False) -> np.ndarray:
        """X = K_ff^{-1} b for b of length n_free.

        ``symmetric_rhs``: b is a residual of the state whose tangent this is (or made from such
        residuals): where that state is on the symmetric path (the tangent is factorized in its
        half-turn blocks), b's antisymmetric part is round-off and is left out.
        """
        return self.solve_many(b[:, None], symmetric_rhs)[:, 0]

    def solve_many(self, B: np.ndarray, symmetric_rhs: bool = False) -> np.ndarray:
        """X = K_ff^{-1} B for the columns of B (n_free, m); ``symmetric_rhs`` as in :meth:`solve`.

        One pass over the factor for all columns with NGSolve (a MultiVector; 2 columns: 20 % less
        than two solves at 17k dofs).
        """
        t0 = time.perf_counter()
        self.n_solve += B.shape[1]
        try:
            if self.backend == "splu":
                X = np.column_stack([self._lu.solve(B[:, j]) for j in range(B.shape[1])])
            elif self.in_blocks:
                assert self._blocks is not None
                if not symmetric_rhs and self._blocks.needs_antisymmetric(B):
                    t0 += self._factor_antisymmetric()  # (factorization time, not solve time)
                X = self._blocks.solve(B, symmetric_rhs)
            else:
                assert self._whole is not None
                X = self._whole.solve(B)
        finally:
            self.t_solve += time.perf_counter() - t0
        if not np.all(np.isfinite(X)):
            raise LinearSolverError("solution of the tangent system is not finite (singular tangent?)")
        return X

    def _factor_antisymmetric(self) -> float:
        """Factorize the waiting antisymmetric block (counted and timed); returns the time it took."""
        assert self._blocks is not None
        t = time.perf_counter()
        self._blocks.factor_antisymmetric()
        self.n_factor_antisymmetric += 1
        dt = time.perf_counter() - t
        self.t_factor += dt
        return dt


class EigenBlock:
    """One half-turn block of a tangent factorized in blocks (:meth:`FreeBlockSolver.half_turn_blocks`).

    ``K`` (n_b, n_b): the block; ``B`` (n_free, n_b): its orthonormal basis, ``Bt`` its transpose and
    ``B2t`` that of its entries squared (CSR, kept with the half-turn maps: made once per pattern);
    :meth:`solve` uses the block's factorization and counts in the solver's statistics.
    """

    def __init__(
        self, lin: FreeBlockSolver, kind: str, K: sp.csr_matrix, B: sp.csr_matrix, Bt: sp.csr_matrix, B2t: sp.csr_matrix
    ) -> None:
        self.lin, self.kind, self.K, self.B, self.Bt, self.B2t = lin, kind, K, B, Bt, B2t

    def solve(self, Y: np.ndarray) -> np.ndarray:
        """K_b^-1 Y for the columns of Y (n_b, m)."""
        lin = self.lin
        bl = lin._blocks
        assert bl is not None
        t0 = time.perf_counter()
        lin.n_solve += Y.shape[1]
        try:
            if self.kind == "a" and bl.pending():
                t0 += lin._factor_antisymmetric()  # (factorization time, not solve time)
            X = (bl.sym if self.kind == "s" else bl.anti).solve(Y)
        finally:
            lin.t_solve += time.perf_counter() - t0
        if not np.all(np.isfinite(X)):
            raise LinearSolverError("solution of the tangent system is not finite (singular tangent?)")
        return X


class _NgFactor:
    """An NGSolve sparse matrix of a fixed pattern (CSR order) and its factorization, refreshed in place."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, n: int, backend: str) -> None:
        from ngsolve.la import SparseMatrixd

        self.backend = backend
        self.mat = SparseMatrixd.CreateFromCOO(rows.tolist(), cols.tolist(), [1.0] * len(rows), n, n)
        _, ci, rp = self.mat.CSR()
        if not (np.array_equal(np.asarray(ci), cols) and np.asarray(rp)[-1] == len(rows)):
            raise LinearSolverError("NGSolve reordered the free-block pattern; in-place update impossible")
        self._vec = self.mat.AsVector()
        self.vals = self._vec.FV().NumPy()
        self.inv: Any = None
        self._b = self.mat.CreateColVector()
        self._x = self.mat.CreateColVector()
        self._mv_size = 0

    def factor(self, vals: np.ndarray) -> None:
        self.vals[:] = vals
        if self.inv is None:
            self.inv = self.mat.Inverse(inverse=self.backend)
        else:
            self.inv.Update()

    def solve(self, B: np.ndarray) -> np.ndarray:
        """K^-1 B for the columns of B."""
        m = B.shape[1]
        if m == 1:
            self._b.FV().NumPy()[:] = B[:, 0]
            self._x.data = self.inv * self._b
            return np.array(self._x.FV().NumPy())[:, None]
        from ngsolve.la import MultiVector

        if self._mv_size != m:
            self._mv_b, self._mv_x, self._mv_size = MultiVector(self._b, m), MultiVector(self._x, m), m
        for j in range(m):
            self._mv_b[j].FV().NumPy()[:] = B[:, j]
        self._mv_x[:] = self.inv * self._mv_b
        return np.column_stack([np.array(self._mv_x[j].FV().NumPy()) for j in range(m)])


class _CholmodFactor:
    """CHOLMOD's LL^T (:class:`ngbet.cholmod.CholmodFactor`) of a fixed pattern, refactorized in place.

    A matrix that is not positive definite is factorized by NGSolve's LDL^T (:class:`_NgFactor`)
    instead, until the next one; ``n_ldlt`` counts those.
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, n: int) -> None:
        self.rows, self.cols, self.n = rows, cols, n
        self._llt = cholmod.CholmodFactor(rows, cols, n)
        self.vals = np.zeros(len(rows))  # the values last factorized
        self._ldlt: _NgFactor | None = None
        self.indefinite = False  # the last matrix was not positive definite: the LDL^T holds it
        self.n_ldlt = 0

    def factor(self, vals: np.ndarray) -> None:
        self.vals[:] = vals
        self.indefinite = not self._llt.factor(vals)
        if self.indefinite:
            if self._ldlt is None:
                self._ldlt = _NgFactor(self.rows, self.cols, self.n, "sparsecholesky")
            self._ldlt.factor(vals)
            self.n_ldlt += 1

    def solve(self, B: np.ndarray) -> np.ndarray:
        """K^-1 B for the columns of B."""
        if self.indefinite:
            assert self._ldlt is not None
            return self._ldlt.solve(B)
        return self._llt.solve(B)


_Factor = _NgFactor | _CholmodFactor


def _new_factor(rows: np.ndarray, cols: np.ndarray, n: int, backend: str) -> _Factor:
    """A factorization of the pattern (rows, cols) with ``backend`` (not "splu")."""
    return _CholmodFactor(rows, cols, n) if backend == "cholmod" else _NgFactor(rows, cols, n, backend)


class _HalfTurnFactor:
    """A tangent of a symmetric state factorized as its half-turn blocks (the antisymmetric one on demand)."""

    def __init__(self, ht: HalfTurn, free: np.ndarray, rows: np.ndarray, cols: np.ndarray, backend: str) -> None:
        from .symmetry import Blocks

        self.maps = Blocks(ht, free, rows, cols)
        self.backend = backend
        self.sym = _new_factor(self.maps.rows_s, self.maps.cols_s, self.maps.n_s, backend)
        self.anti = _new_factor(self.maps.rows_a, self.maps.cols_a, self.maps.n_a, backend)
        self._vals: np.ndarray | None = None  # K_ff's values, while the antisymmetric block waits
        self._vals_a: np.ndarray | None = None  # ... and the waiting block's own, once computed
        self._vals_s = np.zeros(0)  # K_s's values of the tangent last judged
        self.coupling = 0.0  # of the last tangent judged
        self._row_ptr: dict[str, np.ndarray] = {}  # CSR row pointers of the blocks' patterns

    def twin(self) -> _HalfTurnFactor:
        """The same maps, factorizations of its own."""
        other = copy.copy(self)
        other.sym = _new_factor(self.maps.rows_s, self.maps.cols_s, self.maps.n_s, self.backend)
        other.anti = _new_factor(self.maps.rows_a, self.maps.cols_a, self.maps.n_a, self.backend)
        other._vals, other._vals_a, other._vals_s, other.coupling = None, None, np.zeros(0), 0.0
        return other

    def decoupled(self, vals: np.ndarray) -> bool:
        """Whether K_ff (values ``vals``) is block diagonal: its state is on the symmetric path."""
        from .symmetry import COUPLING_TOL

        self._vals_s = self.maps.M_s @ vals
        self.coupling = self.maps.coupling(vals, self._vals_s)
        return self.coupling <= COUPLING_TOL

    def factor(self, vals: np.ndarray, shifted: bool) -> None:
        """Factorize the symmetric block of K_ff (values ``vals``, judged by :meth:`decoupled` unless ``shifted``)."""
        self.sym.factor(self.maps.M_s @ vals if shifted else self._vals_s)
        self._vals, self._vals_a = vals, None

    def needs_antisymmetric(self, B: np.ndarray) -> bool:
        """Whether solving for B needs the antisymmetric block, not yet factorized."""
        return self.pending() and bool(np.any(self.maps.Bt_a @ B))

    def pending(self) -> bool:
        """Whether the antisymmetric block of the last tangent is not yet factorized."""
        return self._vals is not None

    def block_matrix(self, kind: str) -> sp.csr_matrix:
        """The symmetric ("s") or antisymmetric ("a") block of the last tangent (the values factorized)."""
        m = self.maps
        if kind == "s":
            vals, rows, cols, n = self.sym.vals, m.rows_s, m.cols_s, m.n_s
        else:
            vals = self._pending_a() if self._vals is not None else self.anti.vals
            rows, cols, n = m.rows_a, m.cols_a, m.n_a
        if kind not in self._row_ptr:
            self._row_ptr[kind] = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
        return sp.csr_matrix((np.array(vals), cols, self._row_ptr[kind]), shape=(n, n))

    def _pending_a(self) -> np.ndarray:
        """The values of the waiting antisymmetric block (computed once per tangent)."""
        assert self._vals is not None
        if self._vals_a is None:
            self._vals_a = self.maps.M_a @ self._vals
        return self._vals_a

    def factor_antisymmetric(self) -> None:
        self.anti.factor(self._pending_a())
        self._vals = self._vals_a = None

    def solve(self, B: np.ndarray, symmetric_rhs: bool) -> np.ndarray:
        """K_ff^-1 B (``symmetric_rhs``: B's antisymmetric part left out)."""
        X = self.maps.B_s @ self.sym.solve(self.maps.Bt_s @ B)
        if symmetric_rhs:
            return cast(np.ndarray, X)
        B_a = self.maps.Bt_a @ B
        if not np.any(B_a):
            return cast(np.ndarray, X)
        return cast(np.ndarray, X + self.maps.B_a @ self.anti.solve(B_a))
