"""Factorization of the free-dof block of the tangent, with the pattern analysed once.

The free block K_ff of a CSR matrix whose free dofs are in ascending order keeps the entry order
of the full matrix, so its values are ``K.data[sel]`` for a selection ``sel`` computed once.

Backends
--------
``"sparsecholesky"`` (default, also ``"auto"``): NGSolve's sparse LDL^T. The NGSolve matrix is
created once from the free pattern (``SparseMatrixd.CreateFromCOO``); each new tangent is copied in
place into ``AsVector()`` and the factorization refreshed by ``Update()``, which reuses the
ordering and symbolic factorization. It works without pivoting, hence also for the indefinite
tangents met past a bifurcation (as long as no pivot vanishes).
``"umfpack"``, ``"pardiso"``: the same NGSolve matrix with that inverse type (if NGSolve has it).
``"splu"``: scipy's SuperLU, refactorized from scratch each time (for comparison; bench_discrete).
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger(__name__)

BACKENDS = ("sparsecholesky", "umfpack", "pardiso", "splu")


class LinearSolverError(RuntimeError):
    """The tangent could not be factorized (singular pivot, NaN) or the backend is unknown."""


class FreeBlockSolver:
    """Solve K_ff x = b for the free block of matrices sharing one CSR pattern.

    Parameters
    ----------
    K : a matrix with the pattern (values ignored)
    free : bool mask of the free dofs
    backend : one of ``BACKENDS`` or ``"auto"``
    """

    def __init__(self, K: sp.csr_matrix, free: np.ndarray, backend: str = "auto") -> None:
        backend = "sparsecholesky" if backend == "auto" else backend
        if backend not in BACKENDS:
            raise LinearSolverError(f"linear solver {backend!r} unknown; known: {', '.join(BACKENDS)}")
        self.backend = backend
        self.free = np.flatnonzero(free)
        n = K.shape[0]
        rows = np.repeat(np.arange(n), np.diff(K.indptr))
        keep = free[rows] & free[K.indices]
        self.sel = np.flatnonzero(keep)
        newid = -np.ones(n, np.int64)
        newid[self.free] = np.arange(len(self.free))
        self.rows, self.cols = newid[rows[keep]], newid[K.indices[keep]]
        self.nf = len(self.free)
        self.Kff: sp.csr_matrix | None = None
        self.shifted = False  # the last factorization was of K_ff + diag(shift)
        self.n_factor = 0  # factorizations made (statistics)
        self.n_solve = 0
        self.t_factor = self.t_solve = 0.0  # wall time in factor() and solve() [s]
        self._lu: Any = None  # scipy's SuperLU ("splu")
        if backend != "splu":
            from ngsolve.la import SparseMatrixd

            self._mat = SparseMatrixd.CreateFromCOO(self.rows.tolist(), self.cols.tolist(),
                                                    [1.0] * len(self.rows), self.nf, self.nf)
            _, ci, rp = self._mat.CSR()
            if not (np.array_equal(np.asarray(ci), self.cols) and np.asarray(rp)[-1] == len(self.sel)):
                raise LinearSolverError("NGSolve reordered the free-block pattern; in-place update impossible")
            self._vec = self._mat.AsVector()
            self._vals = self._vec.FV().NumPy()
            self._inv = None
            self._b = self._mat.CreateColVector()
            self._x = self._mat.CreateColVector()

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
        if shift is not None:
            vals = vals.copy()
            vals[self.rows == self.cols] += shift
        if not np.all(np.isfinite(vals)):
            raise LinearSolverError("tangent has non-finite entries")
        self.Kff = sp.csr_matrix((vals, self.cols, self._indptr()), shape=(self.nf, self.nf))
        if self.backend == "splu":
            try:
                self._lu = spla.splu(self.Kff.tocsc())
            except RuntimeError as exc:
                raise LinearSolverError(f"SuperLU failed: {exc}") from None
            return
        self._vals[:] = vals
        if self._inv is None:
            self._inv = self._mat.Inverse(inverse=self.backend)
        else:
            self._inv.Update()

    def _indptr(self) -> np.ndarray:
        if not hasattr(self, "_ip"):
            self._ip = np.concatenate([[0], np.cumsum(np.bincount(self.rows, minlength=self.nf))])
        return self._ip

    def solve(self, b: np.ndarray) -> np.ndarray:
        """X = K_ff^{-1} b for b of length n_free."""
        t0 = time.perf_counter()
        self.n_solve += 1
        try:
            return self._solve(b)
        finally:
            self.t_solve += time.perf_counter() - t0

    def solve_many(self, B: np.ndarray) -> np.ndarray:
        """X = K_ff^{-1} B for the columns of B (n_free, m).

        One pass over the factor for all columns with NGSolve (a MultiVector; 2 columns: 20 % less
        than two solves at 17k dofs).
        """
        if self.backend == "splu" or B.shape[1] == 1:
            return np.column_stack([self.solve(B[:, j]) for j in range(B.shape[1])])
        from ngsolve.la import MultiVector

        t0 = time.perf_counter()
        self.n_solve += B.shape[1]
        try:
            m = B.shape[1]
            if getattr(self, "_mv_size", 0) != m:
                self._mv_b, self._mv_x, self._mv_size = MultiVector(self._b, m), MultiVector(self._x, m), m
            for j in range(m):
                self._mv_b[j].FV().NumPy()[:] = B[:, j]
            self._mv_x[:] = self._inv * self._mv_b
            X = np.column_stack([np.array(self._mv_x[j].FV().NumPy()) for j in range(m)])
        finally:
            self.t_solve += time.perf_counter() - t0
        if not np.all(np.isfinite(X)):
            raise LinearSolverError("solution of the tangent system is not finite (singular tangent?)")
        return X

    def _solve(self, b: np.ndarray) -> np.ndarray:
        if self.backend == "splu":
            assert self._lu is not None
            x = self._lu.solve(b)
        else:
            self._b.FV().NumPy()[:] = b
            self._x.data = self._inv * self._b
            x = np.array(self._x.FV().NumPy())
        if not np.all(np.isfinite(x)):
            raise LinearSolverError("solution of the tangent system is not finite (singular tangent?)")
        return x
