"""CHOLMOD's supernodal Cholesky factorization (through cvxopt) of a fixed sparsity pattern.

An optional speed-up for both models (``pip install "ngbet[cholmod]"``; cvxopt is GPL-3 licensed,
hence optional). The ordering and symbolic analysis are made once for the pattern; each new
matrix of that pattern is refactorized in place. LL^T needs a positive definite matrix: where a
pivot is not positive, :meth:`CholmodFactor.factor` says so and the caller factorizes that matrix
with NGSolve's LDL^T instead, which needs no definiteness. Its times against NGSolve's
factorizations, for both models, are in bench/README.md.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np

__all__ = ["CholmodFactor", "available", "free_pattern"]


def available() -> bool:
    """Whether CHOLMOD can be used (cvxopt is installed)."""
    return importlib.util.find_spec("cvxopt") is not None


def free_pattern(
    indptr: np.ndarray, indices: np.ndarray, free: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The free-free entries of a CSR pattern: (their positions in the value array, rows, cols).

    Rows and columns are numbered among the free dofs (``free``: bool mask, ascending order kept),
    so that the selected entries stay in CSR order.
    """
    indptr, indices = np.asarray(indptr, np.int64), np.asarray(indices, np.int64)
    n = len(indptr) - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    keep = free[rows] & free[indices]
    newid = -np.ones(n, np.int64)
    newid[np.flatnonzero(free)] = np.arange(int(free.sum()))
    return np.flatnonzero(keep), newid[rows[keep]], newid[indices[keep]]


class CholmodFactor:
    """LL^T of symmetric matrices of one pattern, given in CSR order (the whole matrix or one triangle).

    Parameters
    ----------
    rows, cols : the pattern's entries in CSR order (row-major, columns ascending in a row)
    n : the matrix size
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, n: int) -> None:
        from cvxopt import cholmod, matrix, spmatrix

        self._cholmod, self._matrix = cholmod, matrix
        # CSR of a triangle is CCS of the other one (cvxopt stores CCS): the upper triangle in CSR
        # order is the lower triangle in CCS order; a matrix given by its lower triangle (NGSolve's
        # symmetric storage) is read as the upper triangle in CCS
        upper = bool(np.any(cols > rows))
        self._entries = np.flatnonzero(cols >= rows) if upper else np.arange(len(rows))
        self._uplo = "L" if upper else "U"
        self.mat = spmatrix(
            np.ones(len(self._entries)).tolist(), cols[self._entries].tolist(), rows[self._entries].tolist(), (n, n)
        )
        if not np.array_equal(np.asarray(self.mat.CCS[1]).ravel(), cols[self._entries]):
            raise RuntimeError("cvxopt reordered the pattern; in-place update impossible")
        self._F: Any = None

    def factor(self, vals: np.ndarray) -> bool:
        """Factorize the matrix of values ``vals`` (CSR order); False: not positive definite (no factor)."""
        self.mat.V = self._matrix(np.ascontiguousarray(vals[self._entries], dtype=float))
        if self._F is None:
            self._F = self._cholmod.symbolic(self.mat, uplo=self._uplo)
        try:
            self._cholmod.numeric(self.mat, self._F)
        except ArithmeticError:  # a pivot that is not positive
            return False
        return True

    def solve(self, B: np.ndarray) -> np.ndarray:
        """A^-1 B for B of shape (n,) or (n, m)."""
        X = self._matrix(np.asfortranarray(B, dtype=float))
        self._cholmod.solve(self._F, X)
        return np.asarray(X).reshape(B.shape)
