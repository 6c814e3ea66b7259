"""The stability check of the network: the eigenvalues of K_ff v = lambda D v nearest to 0.

D = diag K_ff, so lambda is unit-free. Block Lanczos in shift-invert mode with the factorization
already made for the next predictor (ARPACK where it does not converge); on half-turn symmetric
states each of the two half-size blocks apart (:mod:`ngbet.discrete.symmetry`).
:mod:`ngbet.discrete.solver` says what is done with lambda_min < 0.
"""

from __future__ import annotations

import logging
import sys
from typing import cast

import numpy as np
import scipy.sparse as sp

from .linsolve import EigenBlock, FreeBlockSolver, LinearSolverError
from .newton import StepControl

__all__ = ["OTHER_BLOCK_TOL", "check_stability", "lowest_eigenvalues", "lowest_eigenvalues_arpack"]

log = logging.getLogger(__name__)


def _orthonormalize(W: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the part of W orthogonal to Q (classical Gram-Schmidt, twice)."""
    for _ in range(2):
        if Q.shape[1]:
            W = W - Q @ (Q.T @ W)
        nrm = np.linalg.norm(W, axis=0)
        W = W[:, nrm > 1e-10 * max(nrm.max(initial=0.0), 1e-300)]
        if W.shape[1] == 0:
            return W
        W, Rw = np.linalg.qr(W)
        W = W[:, np.abs(np.diag(Rw)) > 1e-12 * np.abs(Rw).max()]
    return W


def _start_block(X0: np.ndarray | None, s: np.ndarray, k: int) -> np.ndarray:
    """The scaled modes of the previous check (filled up with fixed random vectors), or (1, ..., 1) and those."""
    n = s.shape[0]
    if X0 is not None and X0.ndim == 2 and X0.shape[0] == n and X0.shape[1] >= 1:
        Y = X0[:, :k] * s[:, None]
        if Y.shape[1] < k:
            Y = np.column_stack([Y, np.random.default_rng(0).standard_normal((n, k - Y.shape[1]))])
        return cast(np.ndarray, Y)
    return np.column_stack([np.ones(n)] + [np.random.default_rng(j).standard_normal(n) for j in range(k - 1)])


def _ritz_pairs(Q: np.ndarray, AQ: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k Ritz values nearest to 0 in span(Q), their vectors Y and A Y."""
    H = Q.T @ AQ
    th, C = np.linalg.eigh(0.5 * (H + H.T))
    idx = np.argsort(np.abs(th))[:k]
    th, C = th[idx], C[:, idx]
    return th, Q @ C, AQ @ C


def lowest_eigenvalues(
    lin: FreeBlockSolver, k: int, X0: np.ndarray | None = None, tol: float = 1e-3, max_expansions: int = 40
) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs of K_ff v = lambda D v nearest to 0, D = diag(K_ff), using the current factorization.

    Block shift-invert Lanczos (sigma = 0) with full reorthogonalization, started from ``X0``
    (the modes of the previous load step: they change little from step to step, so that one or
    two expansions usually suffice) or from (1, ..., 1) and a fixed random vector. In the
    scaled variables y = D^(1/2) v the problem is A y = lambda y with A = D^(-1/2) K_ff D^(-1/2);
    the first expansion applies A^(-1) (one solve with the factorization) to all current Ritz
    vectors, each later one to the vector nearest 0 only (4 solves a check at 17k dofs instead
    of 6, the eigenvalues the same to 2e-7). Converged when the pair nearest to 0 has a residual
    |A y - theta y| <= tol |theta| (|y| = 1): an eigenvalue then lies within tol |theta| of
    theta, so that its sign is certain, and the Ritz value itself is accurate to ~tol^2 |theta|
    relative (the other k - 1 pairs are Ritz approximations: they serve as the start block of
    the next check; eigenvalues 2 and 3 of the BET networks can lie within 2 % of each other,
    where resolving them would cost dozens of solves).
    Falls back to ARPACK (``eigsh`` in shift-invert mode) if that does not happen within
    ``max_expansions``.

    A tangent factorized in its half-turn blocks is checked block by block
    (:func:`_lowest_eigenvalues_split`): there the k nearest pairs come with each block's nearest.

    Returns
    -------
    lam (k,) ascending (k or more with the half-turn blocks), V (n_free, len(lam)): D-normalized modes
    """
    Kff = lin.Kff
    assert Kff is not None
    n = Kff.shape[0]
    k = min(k, n - 2)
    s = np.sqrt(np.abs(lin.diagonal()))
    s[s == 0] = 1.0
    blocks = lin.half_turn_blocks()
    if blocks is not None:
        return _lowest_eigenvalues_split(lin, blocks, s, k, X0, tol, max_expansions)

    def A(Y: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, (Kff @ (Y / s[:, None])) / s[:, None])

    def Ainv(Y: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, s[:, None] * lin.solve_many(s[:, None] * Y))

    Q = _orthonormalize(_start_block(X0, s, k), np.zeros((n, 0)))
    AQ = A(Q)
    for n_exp in range(max_expansions):
        th, Yr, AYr = _ritz_pairs(Q, AQ, k)
        res = np.linalg.norm(AYr - Yr * th, axis=0)
        if Yr.shape[1] == k and res[0] <= tol * abs(th[0]) + 1e-14:
            order = np.argsort(th)
            return th[order], (Yr / s[:, None])[:, order]
        # the first expansion takes the whole block (the two lowest modes may be a near-degenerate
        # pair), the later ones the pair nearest 0 only, whose residual decides
        W = _orthonormalize(Ainv(Yr if n_exp == 0 else Yr[:, :1]), Q)
        if W.shape[1] == 0:
            break
        if Q.shape[1] + W.shape[1] > 60:  # restart with the Ritz vectors
            Q, AQ = Yr, AYr
            W = _orthonormalize(W, Q)
        Q, AQ = np.column_stack([Q, W]), np.column_stack([AQ, A(W)])
    log.info("block Lanczos did not converge; falling back to ARPACK")
    return lowest_eigenvalues_arpack(lin, k)


OTHER_BLOCK_TOL = 0.3
"""Half-turn blocks: the relative residual to which the block without the Ritz value nearest 0 has
its own nearest pair resolved, when that pair lies clear of the nearest one (else to ``tol``)."""


class _SplitBasis:
    """The Lanczos basis of one half-turn block, in the block's scaled coordinates."""

    def __init__(self, block: EigenBlock, s: np.ndarray, Y0: np.ndarray, seed: int) -> None:
        self.block = block
        B = block.B
        self.s = np.sqrt(block.B2t @ (s * s))  # D_b = B^T D B is diagonal (D is half-turn invariant)
        self.s[self.s == 0] = 1.0
        Yb = block.Bt @ Y0
        # the start vectors' parts in this block (parts at round-off level are left out)
        Yb = Yb[:, np.linalg.norm(Yb, axis=0) > 1e-6 * np.linalg.norm(Y0, axis=0)]
        if Yb.shape[1] == 0:
            Yb = np.random.default_rng(seed).standard_normal((B.shape[1], 1))
        self.Q = _orthonormalize(Yb, np.zeros((B.shape[1], 0)))
        self.AQ = self.A(self.Q)

    def A(self, Y: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, (self.block.K @ (Y / self.s[:, None])) / self.s[:, None])

    def ritz(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The k Ritz pairs nearest 0 (values, vectors, A times them) and the nearest one's residual."""
        th, Y, AY = _ritz_pairs(self.Q, self.AQ, min(k, self.Q.shape[1]))
        return th, Y, AY, float(np.linalg.norm(AY[:, 0] - Y[:, 0] * th[0]))

    def expand(self, Y: np.ndarray) -> None:
        """Add A^-1 Y (a half-size solve per column) to the basis."""
        W = _orthonormalize(self.s[:, None] * self.block.solve(self.s[:, None] * Y), self.Q)
        if W.shape[1] == 0:
            return
        if self.Q.shape[1] + W.shape[1] > 60:  # restart with the Ritz vectors
            _, Yr, AYr = _ritz_pairs(self.Q, self.AQ, 4)
            self.Q, self.AQ = Yr, AYr
            W = _orthonormalize(W, self.Q)
        self.Q, self.AQ = np.column_stack([self.Q, W]), np.column_stack([self.AQ, self.A(W)])


def _lowest_eigenvalues_split(
    lin: FreeBlockSolver,
    blocks: list[EigenBlock],
    s: np.ndarray,
    k: int,
    X0: np.ndarray | None,
    tol: float,
    max_expansions: int,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`lowest_eigenvalues` of a tangent factorized in its half-turn blocks.

    K_ff = B_s K_s B_s^T + B_a K_a B_a^T, and D = diag(K_ff) commutes with the half-turn, so that
    K v = lambda D v is the union of the blocks' problems K_b y = lambda D_b y, D_b = B_b^T D B_b
    (diagonal). A Krylov space grown from vectors of one block stays in that block: started from
    the last check's modes, all antisymmetric on the BET path, the whole-space method never sees
    the symmetric block again. Here each block keeps its own basis, started from the block parts
    of the start vectors (or from a fixed random vector), and each block's pair nearest 0 is
    resolved: the block holding the Ritz value nearest 0 to ``tol``; the other to ``tol`` as well,
    or only to :data:`OTHER_BLOCK_TOL` where its eigenvalue then lies clear of the nearest one.
    Expanding a Ritz vector is one half-size solve with its block's factorization; the first
    expansion takes, in each block, its Ritz vectors among the k nearest 0 overall (at least one).

    Returns the k pairs nearest 0 and, where not among them, each block's nearest pair, sorted
    ascending: the next check starts from all of them.
    """
    if X0 is not None and X0.ndim == 2 and X0.shape[0] == len(s) and X0.shape[1] >= 1:
        Y0 = X0 * s[:, None]
    else:
        Y0 = _start_block(None, s, k)
    bases = [_SplitBasis(b, s, Y0, seed) for seed, b in enumerate(blocks)]
    for n_exp in range(max_expansions):
        pairs = [bb.ritz(k) for bb in bases]
        cand = sorted((abs(th[j]), i, j) for i, (th, _, _, _) in enumerate(pairs) for j in range(len(th)))[:k]
        i0 = cand[0][1]
        th0, r0 = abs(pairs[i0][0][0]), pairs[i0][3]
        done = []
        for i, (th, _, _, res) in enumerate(pairs):
            t = abs(th[0])
            clear = i != i0 and res <= OTHER_BLOCK_TOL * t and t - res > th0 + r0
            done.append(res <= tol * t + 1e-14 or clear)
        if all(done) and len(cand) == k:
            keep = sorted({(i, j) for _, i, j in cand} | {(i, 0) for i in range(len(pairs))})
            lam = np.array([pairs[i][0][j] for i, j in keep])
            V = np.column_stack([bases[i].block.B @ (pairs[i][1][:, j] / bases[i].s) for i, j in keep])
            order = np.argsort(lam)
            return lam[order], V[:, order]
        for i, bb in enumerate(bases):
            if n_exp == 0:
                bb.expand(pairs[i][1][:, sorted({0} | {j for _, ii, j in cand if ii == i})])
            elif not done[i]:
                bb.expand(pairs[i][1][:, :1])
    log.info("block Lanczos did not converge in the half-turn blocks; falling back to ARPACK")
    return lowest_eigenvalues_arpack(lin, k)


def lowest_eigenvalues_arpack(lin: FreeBlockSolver, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The same eigenpairs by ARPACK in shift-invert mode: the reference of :func:`lowest_eigenvalues`.

    It needs many more solves with the factorization than the block Lanczos started from the
    previous modes; it is the fallback where that does not converge.
    """
    import scipy.sparse.linalg as spla  # (the fallback alone: a network run need not import it)

    Kff = lin.Kff
    assert Kff is not None
    n = Kff.shape[0]
    D = sp.diags(np.abs(lin.diagonal()))
    op = spla.LinearOperator((n, n), matvec=lambda b: lin.solve(np.ravel(b)), dtype=float)
    k = min(k, n - 2)
    lam, V = spla.eigsh(Kff, k=k, M=D, sigma=0.0, which="LM", OPinv=op, tol=1e-6, v0=np.ones(n), maxiter=2000)
    order = np.argsort(lam)
    return lam[order], V[:, order]


def check_stability(
    lin: FreeBlockSolver, ctl: StepControl, X0: np.ndarray | None = None
) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """The stability check of the current state: (lambda_min, its mode, all computed modes).

    The modes are the start block ``X0`` of the next check. Where the eigensolvers fail the state
    is not classified: (nan, None, None), with a warning; a failed check never stops the path.
    """
    try:
        lam, V = lowest_eigenvalues(lin, ctl.n_eigs, X0)
    except _failures() as exc:
        log.warning("stability check failed (%s): state not classified", exc)
        return float("nan"), None, None
    return float(lam[0]), V[:, 0], V


def _failures() -> tuple[type[Exception], ...]:
    """The errors of a stability check that leave the state unclassified (ARPACK's once it has run)."""
    spla = sys.modules.get("scipy.sparse.linalg")
    arpack = () if spla is None else (spla.ArpackNoConvergence, spla.ArpackError)
    return (*arpack, LinearSolverError, np.linalg.LinAlgError)
