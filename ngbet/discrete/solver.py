"""The network's corrector: shifted minimizing Newton with stability check and snap handling.

:class:`ShiftedNewton` runs on the engine's load stepping (:func:`ngbet.engine.follow_path`);
:func:`solve_path` puts the two together.

The solver knows nothing of yarns. A problem provides ``n_dofs``, ``fixed`` (bool mask of
prescribed dofs), ``load`` (prescribed values per unit load parameter u0), ``ramp`` (a field for
the "clamp" predictor) and ``evaluate(u, hessian) -> (E, dE/du, d2E/du2)``, and may provide
``half_turn()`` (:mod:`.symmetry`): then the tangents of states on the symmetric path are
factorized as their two half-size blocks, and the predictions are projected back onto that path.

Step from u0 to u0 + h:
  predictor  "tangent": u_f += -K_ff^{-1} K_fc h load_c  (K at the last converged state)
             "clamp":   u   += h ramp
  corrector  Newton on the free dofs, du = -K_ff^{-1} r; where du is not a descent direction
             (K_ff indefinite) the tangent is shifted by mu diag(K_ff) until it is (mu from a
             tenth of the last shift of the same Newton run, 1e-6 at first, raised tenfold).
             While relaxing past a snap-through: Armijo backtracking on the energy, and shifted
             steps extended while the energy keeps falling along them.
             Inexact (networks of at least ``krylov_min_free`` free dofs): once the decrement is
             below the energy, an iteration solves its own tangent by conjugate gradients
             preconditioned with the last factorization (to ``krylov_tol``; a factorization
             where CG meets negative curvature or needs more than ``krylov_max`` iterations),
             and a step converged that way ends with one full Newton iteration.
  converged  when the Newton decrement |r . du| (an energy, twice the predicted energy change)
             is below rtol |E| + atol: unit-free.
  step size  (the engine) grows by ``growth`` (up to max_step) after a step with at most
             ``grow_after`` iterations, is cut by ``cut`` after a failed step, and a step below
             ``min_step`` raises :class:`ngbet.errors.ConvergenceError` (every attempt's
             decrements, the last converged u0 in mm). A step
             longer than ``snap_bracket`` stops at its first indefinite tangent and is cut (it
             would be cut as a possible snap anyway, see below).
  snap       a step that releases energy (energy change below the work of the clamp, by the
             Hermite rule with F' = dF/du0 at both ends: exact to O(h^5) on a continuous branch)
             beyond ``snap_release_hermite`` of that work (``snap_release`` for the trapezoid when
             a tangent is missing) has jumped branches: it is cut to ``snap_bracket`` and, at that
             length, accepted and reported as a snap-through.
  stability  at each converged state the eigenvalues of K_ff v = lambda D v nearest to 0
             (D = diag K_ff, so lambda is unit-free) are computed by shift-invert Lanczos with the
             factorization already made for the next predictor. lambda_min < 0 means an unstable
             equilibrium: it is logged, perturbed along the unstable mode (both signs) and
             relaxed to the lower stable neighbour, and counted as a snap event. A step that
             only converges with shifted (indefinite) tangents is also a snap event: the state
             jumped to a non-adjacent branch.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import cholmod
from ..engine import Outcome, PathControl, StepRecord, follow_path
from ..errors import Attempt, ConvergenceError
from .linsolve import EigenBlock, FreeBlockSolver, LinearSolverError

log = logging.getLogger(__name__)



class Problem(Protocol):
    """What the solver needs from an energy minimization problem (see the module docstring)."""

    n_dofs: int
    fixed: np.ndarray
    load: np.ndarray
    ramp: np.ndarray

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        """E(u), dE/du and (with ``hessian``) d2E/du2."""


@dataclass(frozen=True)
class StepControl:
    """Numerics of the load path (SI load units); built from the scene by the entry point."""

    u0_final: float
    first_step: float
    max_step: float
    min_step: float
    rtol: float = 1e-10
    atol: float = 1e-14
    max_iterations: int = 12
    grow_after: int = 4
    growth: float = 1.5
    cut: float = 0.5
    predictor: str = "tangent"
    backend: str = "auto"
    stability: bool = True
    n_eigs: int = 2
    stations: tuple[float, ...] = ()  # loads the path must hit exactly (shapes are wanted there)
    snap_release: float = 0.05  # released fraction of the step's work that marks a snap-through (trapezoid)
    snap_release_hermite: float = 1e-3  # the same with the work by the Hermite rule (tangents at both ends)
    snap_bracket: float = 1e-3  # a step that snaps is cut until it is at most this long
    krylov_tol: float = 0.03  # inexact Newton in a step: CG on the tangent, preconditioned (0: factorize each)
    krylov_max: int = 8  # CG iterations before the tangent is factorized instead
    krylov_below: float = 1.0  # ... once the last decrement is below this fraction of the energy
    krylov_min_free: int = 10_000  # ... on networks with at least this many free dofs
    half_turn: bool = True  # factorize the tangents of symmetric states in their half-turn blocks (.symmetry)


class _TimedProblem:
    """The problem with its evaluations timed (assembly with and without the Hessian)."""

    def __init__(self, problem: Problem) -> None:
        self._p = problem
        self.n_dofs, self.fixed, self.load, self.ramp = problem.n_dofs, problem.fixed, problem.load, problem.ramp
        finder = getattr(problem, "half_turn", None)
        if finder is not None:
            self.half_turn = finder
        self.t_hessian = self.t_gradient = 0.0
        self.n_hessian = self.n_gradient = 0

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        t = time.perf_counter()
        res = self._p.evaluate(u, hessian)
        if hessian:
            self.t_hessian += time.perf_counter() - t
            self.n_hessian += 1
        else:
            self.t_gradient += time.perf_counter() - t
            self.n_gradient += 1
        return res


class _Tally:
    """Factorizations, solves, Newton iterations and wall time of the load path by cause (bench_discrete)."""

    def __init__(self, solvers: tuple[FreeBlockSolver, ...]) -> None:
        self.solvers = solvers
        self.rows: dict[str, dict[str, float]] = {}

    def start(self, t: float | None = None) -> tuple[int, int, float]:
        return (sum(s.n_factor for s in self.solvers), sum(s.n_solve for s in self.solvers),
                time.perf_counter() if t is None else t)

    def add(self, cause: str, mark: tuple[int, int, float], nout: dict[str, Any] | None = None) -> None:
        row = self.rows.setdefault(cause, {"calls": 0, "factorizations": 0, "shift_factorizations": 0,
                                           "solves": 0, "iterations": 0, "time_s": 0.0})
        row["calls"] += 1
        row["factorizations"] += sum(s.n_factor for s in self.solvers) - mark[0]
        row["solves"] += sum(s.n_solve for s in self.solvers) - mark[1]
        row["time_s"] += time.perf_counter() - mark[2]
        if nout:
            row["iterations"] += nout.get("iterations", 0)
            row["shift_factorizations"] += nout.get("shift_factorizations", 0)


class _StepFailed(Exception):
    """Newton gave up.

    ``u`` is its last iterate (None where it is of no use), ``indefinite`` says that it gave up at
    the first tangent that needed a shift (``allow_shift=False``).
    """

    def __init__(self, why: str, history: list[tuple[float, float, float]], u: np.ndarray | None = None,
                 indefinite: bool = False) -> None:
        super().__init__(why)
        self.history = history
        self.u = u
        self.indefinite = indefinite


def newton(problem: Problem, u: np.ndarray, lin: FreeBlockSolver, ctl: StepControl,
           max_iterations: int | None = None, line_search: bool = False, fail_fast: bool = True,
           out: dict[str, Any] | None = None, allow_shift: bool = True, inexact: bool = False
           ) -> tuple[np.ndarray, int, list[tuple[float, float, float]], int]:
    """Minimize the energy over the free dofs from u (prescribed dofs as given).

    Plain Newton by default: with stiff axial terms the full step of a rotating beam stretches it
    and raises the energy, yet the next iteration restores the length and converges
    quadratically, whereas an energy line search would crawl. ``line_search=True`` (Armijo
    backtracking on the energy) is used to relax past a snap-through; there a step with a shifted
    tangent is also extended (x2, x4, ...) while the energy keeps falling along it: past a limit
    point the shift, not the energy, sets the length of that step, and unextended it creeps along
    the unstable mode by a few per cent per factorization. ``fail_fast`` gives up (the step will be
    cut) when the decrement stops contracting after 6 iterations, rises above the first one from
    the third iteration on, or exceeds twice the energy; without it Newton may wander through
    indefinite states to a distant branch (a snap-through). ``allow_shift=False`` gives up at the
    first tangent that is not a descent direction (the caller would reject the step anyway).

    ``inexact=True`` (with ``ctl.krylov_tol > 0`` and at least ``ctl.krylov_min_free`` free
    dofs): after an unshifted factorization, the next iterations solve the Newton system of
    their own tangent by conjugate gradients preconditioned with it (:func:`_krylov_step`), once
    the last decrement is below ``ctl.krylov_below`` times the energy; a tangent that shows
    negative curvature or a solve that misses the tolerance in ``ctl.krylov_max`` iterations is
    factorized instead.
    Converged on such an iteration, a full Newton iteration at the final state follows: the
    converged tangent is then factorized, and the last update made with it, as in plain Newton
    (when its decrement is above the tolerance, which CG may underestimate, Newton goes on).

    Returns
    -------
    u, iterations (up to the one that met the tolerance), history [(E, |r|_inf, decrement)],
    number of iterations with a shifted tangent; ``out["K"]`` (when ``out`` is given): the
    tangent of the last iteration, factorized in ``lin`` (``lin.shifted`` says whether with a
    shift), ``out["iterations"]``: all iterations. At convergence the last update is below the
    tolerance (|r . du| <= rtol |E|), so that factorization serves as the converged tangent.
    """
    free = lin.free
    u = u.copy()
    hist: list[tuple[float, float, float]] = []
    shifted = 0
    mu_prev = 0.0
    n_max = max_iterations or ctl.max_iterations
    inexact = inexact and ctl.krylov_tol > 0 and lin.nf >= ctl.krylov_min_free
    held = False  # lin holds an unshifted factorization of this run: the preconditioner
    n_factor = it = 0
    confirm = False  # the last iteration met the tolerance on CG: this one factorizes
    while (n_factor < n_max or confirm) and it < 4 * n_max:
        it += 1
        E, r, K = _residual(problem, u, free, hist, out, it)
        near = bool(hist) and hist[-1][2] <= ctl.krylov_below * abs(E)  # Newton has come close
        step = _krylov_step(lin, K, r, ctl) if held and near and not confirm else None
        if step is None:
            du, dec, mu_prev, n_shift = _factorized_step(lin, K, r, mu_prev, allow_shift, hist, E, out)
            n_factor += 1
            shifted += n_shift
            held = inexact and n_shift == 0
        else:
            (du, dec), n_shift = step, 0
        hist.append((E, float(np.abs(r).max(initial=0.0)), dec))
        if abs(dec) <= ctl.rtol * abs(E) + ctl.atol:
            u[free] += du
            if step is None:
                return u, it - 1 if confirm else it, hist, shifted
            confirm = True  # one full iteration: the converged tangent factorized, the last update made with it
            continue
        confirm = False  # (the full iteration after CG did not meet the tolerance: Newton goes on)
        if dec <= 0:
            raise _StepFailed("no descent direction even with a shifted tangent", hist)
        if fail_fast and not line_search:
            _check_contraction(hist, it, E, u)
        alpha = 1.0
        if line_search and (dec > 1e-6 * abs(E) + ctl.atol or n_shift > 0):  # far from the solution
            alpha = _line_search(problem, u, free, du, E, dec, extend=n_shift > 0, hist=hist)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("newton it %d: E %.10g, |r| %.3g, decrement %.3g, shift mu %.0e, step x%g%s", it, E,
                      hist[-1][1], dec, mu_prev if n_shift else 0.0, alpha, " (CG)" if step else "")
        u[free] += alpha * du
    raise _StepFailed(f"no convergence in {n_max} iterations", hist, u)


def _residual(problem: Problem, u: np.ndarray, free: np.ndarray, hist: list[tuple[float, float, float]],
              out: dict[str, Any] | None, it: int) -> tuple[float, np.ndarray, sp.csr_matrix]:
    """E, the free residual and the tangent at u (iteration ``it``)."""
    E, g, K = problem.evaluate(u, True)
    if out is not None:
        out["iterations"] = it
    r = g[free]
    if not (np.isfinite(E) and np.all(np.isfinite(r))):
        raise _StepFailed("energy or residual not finite", hist)
    assert K is not None
    return E, r, K


def _factorized_step(lin: FreeBlockSolver, K: sp.csr_matrix, r: np.ndarray, mu_prev: float, allow_shift: bool,
                     hist: list[tuple[float, float, float]], E: float, out: dict[str, Any] | None
                     ) -> tuple[np.ndarray, float, float, int]:
    """The Newton step with K factorized in ``lin`` (see :func:`_descent_direction`); out["K"] = K."""
    if out is not None:
        out["K"] = K
    return _descent_direction(lin, K, r, mu_prev, allow_shift, hist, E, out)


def _krylov_step(lin: FreeBlockSolver, K: sp.csr_matrix, r: np.ndarray, ctl: StepControl
                 ) -> tuple[np.ndarray, float] | None:
    """The Newton step du (K_ff du = -r) and its decrement by conjugate gradients, or None.

    Preconditioned with the factorization in ``lin`` (a tangent of an earlier iterate: the two
    differ mainly in a few soft modes, which CG resolves in a few iterations); stops when the
    preconditioned residual has fallen by ``ctl.krylov_tol``. None when K_ff shows negative
    curvature (indefinite: the caller factorizes and shifts), the preconditioner is not positive
    on a residual, or ``ctl.krylov_max`` iterations do not suffice.
    """
    A = lin.free_block(K)
    x = np.zeros_like(r)
    res = -r
    z = lin.solve(res, symmetric_rhs=True)
    rz = rz0 = float(res @ z)
    p = z
    for _ in range(ctl.krylov_max):
        if not rz > 0:
            return None
        Ap = A @ p
        pAp = float(p @ Ap)
        if not pAp > 0:
            return None
        a = rz / pAp
        x += a * p
        res -= a * Ap
        z = lin.solve(res, symmetric_rhs=True)
        rz, rz_prev = float(res @ z), rz
        if rz <= ctl.krylov_tol ** 2 * rz0:
            dec = -float(r @ x)
            return (x, dec) if dec > 0 else None
        p = z + (rz / rz_prev) * p
    return None


def _descent_direction(lin: FreeBlockSolver, K: sp.csr_matrix, r: np.ndarray, mu_prev: float, allow_shift: bool,
                       hist: list[tuple[float, float, float]], E: float, out: dict[str, Any] | None
                       ) -> tuple[np.ndarray, float, float, int]:
    """The Newton step du = -K_ff^-1 r, with K_ff shifted by mu diag(K_ff) until it descends.

    The shift starts from a tenth of the last one that gave descent in this Newton run (1e-6 at
    first) and is raised tenfold until the step descends. Past a limit point the smallest such
    shift matters: along an unstable mode of eigenvalue -lambda the shifted step grows the mode by
    about lambda / mu per iteration, and a fixed mu = 1e-6 >> lambda crept for dozens of
    factorizations.

    Returns du, its decrement -r . du, the last shift tried and the number of shifted factorizations.
    """
    try:
        lin.factor(K)
        du = -lin.solve(r, symmetric_rhs=True)
        dec = -float(r @ du)
        mu = max(mu_prev / 10, 1e-10) if mu_prev else 1e-6
        if dec <= 0 and not allow_shift:
            hist.append((E, float(np.abs(r).max(initial=0.0)), dec))
            raise _StepFailed("tangent not a descent direction (indefinite)", hist, indefinite=True)
        assert lin.Kff is not None
        diag = np.abs(lin.Kff.diagonal())  # of the unshifted K_ff (lin.Kff holds the last shifted one)
        n_shift = 0
        while dec <= 0 and mu < 1e3:  # not a descent direction: K_ff indefinite here
            try:
                lin.factor(K, shift=mu * diag)
                du = -lin.solve(r, symmetric_rhs=True)
                dec = -float(r @ du)
            except LinearSolverError:  # the shift met an eigenvalue: singular, try the next
                dec = -1.0
            mu_prev = mu
            mu *= 10
            n_shift += 1
            if out is not None:
                out["shift_factorizations"] = out.get("shift_factorizations", 0) + 1
    except LinearSolverError as exc:
        raise _StepFailed(str(exc), hist) from None
    return du, dec, mu_prev, n_shift


def _check_contraction(hist: list[tuple[float, float, float]], it: int, E: float, u: np.ndarray) -> None:
    """Give up (the step will be cut) when Newton is not converging from the predictor."""
    dec = hist[-1][2]
    if it >= 2 and dec > 2 * abs(E):
        # the quadratic model predicts an energy drop (dec / 2) larger than the energy itself
        # (E >= 0 for the network): the iterate has left the region where Newton can converge
        raise _StepFailed(f"Newton diverging (decrement {dec:.3g} > 2 |E| = {2 * abs(E):.3g})", hist, u)
    if it >= 3 and dec > hist[0][2]:
        # from a predictor the decrement falls, at first perhaps slowly: one above the
        # predictor's own, two iterations on, is Newton bouncing in a soft mode or leaving (in
        # the runs measured the one such step that still converged had snapped: cut anyway)
        raise _StepFailed(f"Newton decrement rose above the predictor's ({hist[0][2]:.3g} -> {dec:.3g})", hist, u)
    if it >= 6 and dec > 0.5 * hist[-2][2]:
        # Newton converges quadratically near a solution or not at all: stop wasting factorizations
        raise _StepFailed(f"Newton decrement not contracting ({hist[-2][2]:.3g} -> {dec:.3g})", hist, u)


def _line_search(problem: Problem, u: np.ndarray, free: np.ndarray, du: np.ndarray, E: float, dec: float,
                 extend: bool, hist: list[tuple[float, float, float]]) -> float:
    """Armijo backtracking on the energy; a shifted step (``extend``) is doubled while the energy falls."""
    alpha = 1.0
    v = u.copy()
    for _ in range(12):
        v[free] = u[free] + alpha * du
        Ev = problem.evaluate(v, False)[0]
        if np.isfinite(Ev) and Ev <= E - 1e-4 * alpha * dec:
            break
        alpha *= 0.5
    else:
        raise _StepFailed("line search found no energy decrease", hist)
    if alpha == 1.0 and extend:
        # extend a shifted step while the energy falls along it (doubling, at most 2^12)
        for _ in range(12):
            v[free] = u[free] + 2 * alpha * du
            E2 = problem.evaluate(v, False)[0]
            if not (np.isfinite(E2) and E2 < Ev):
                break
            alpha, Ev = 2 * alpha, E2
    return alpha


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
        return Y
    return np.column_stack([np.ones(n)] + [np.random.default_rng(j).standard_normal(n) for j in range(k - 1)])


def _ritz_pairs(Q: np.ndarray, AQ: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k Ritz values nearest to 0 in span(Q), their vectors Y and A Y."""
    H = Q.T @ AQ
    th, C = np.linalg.eigh(0.5 * (H + H.T))
    idx = np.argsort(np.abs(th))[:k]
    th, C = th[idx], C[:, idx]
    return th, Q @ C, AQ @ C


def lowest_eigenvalues(lin: FreeBlockSolver, k: int, X0: np.ndarray | None = None, tol: float = 1e-3,
                       max_expansions: int = 40) -> tuple[np.ndarray, np.ndarray]:
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
    s = np.sqrt(np.abs(Kff.diagonal()))
    s[s == 0] = 1.0
    blocks = lin.half_turn_blocks()
    if blocks is not None:
        return _lowest_eigenvalues_split(lin, blocks, s, k, X0, tol, max_expansions)

    def A(Y: np.ndarray) -> np.ndarray:
        return (Kff @ (Y / s[:, None])) / s[:, None]

    def Ainv(Y: np.ndarray) -> np.ndarray:
        return s[:, None] * lin.solve_many(s[:, None] * Y)

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
    return _lowest_eigenvalues_arpack(lin, k)


OTHER_BLOCK_TOL = 0.3
"""Half-turn blocks: the relative residual to which the block without the Ritz value nearest 0 has
its own nearest pair resolved, when that pair lies clear of the nearest one (else to ``tol``)."""


class _SplitBasis:
    """The Lanczos basis of one half-turn block, in the block's scaled coordinates."""

    def __init__(self, block: EigenBlock, s: np.ndarray, Y0: np.ndarray, seed: int) -> None:
        self.block = block
        B = block.B
        self.s = np.sqrt(B.multiply(B).T @ (s * s))  # D_b = B^T D B is diagonal (D is half-turn invariant)
        self.s[self.s == 0] = 1.0
        Yb = B.T @ Y0
        # the start vectors' parts in this block (parts at round-off level are left out)
        Yb = Yb[:, np.linalg.norm(Yb, axis=0) > 1e-6 * np.linalg.norm(Y0, axis=0)]
        if Yb.shape[1] == 0:
            Yb = np.random.default_rng(seed).standard_normal((B.shape[1], 1))
        self.Q = _orthonormalize(Yb, np.zeros((B.shape[1], 0)))
        self.AQ = self.A(self.Q)

    def A(self, Y: np.ndarray) -> np.ndarray:
        return (self.block.K @ (Y / self.s[:, None])) / self.s[:, None]

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


def _lowest_eigenvalues_split(lin: FreeBlockSolver, blocks: list[EigenBlock], s: np.ndarray, k: int,
                              X0: np.ndarray | None, tol: float, max_expansions: int
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
    return _lowest_eigenvalues_arpack(lin, k)


def _lowest_eigenvalues_arpack(lin: FreeBlockSolver, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The same eigenpairs by ARPACK in shift-invert mode (20+ solves: the slow reference)."""
    Kff = lin.Kff
    assert Kff is not None
    n = Kff.shape[0]
    D = sp.diags(np.abs(Kff.diagonal()))
    op = spla.LinearOperator((n, n), matvec=lambda b: lin.solve(np.ravel(b)), dtype=float)
    k = min(k, n - 2)
    lam, V = spla.eigsh(Kff, k=k, M=D, sigma=0.0, which="LM", OPinv=op, tol=1e-6,
                        v0=np.ones(n), maxiter=2000)
    order = np.argsort(lam)
    return lam[order], V[:, order]


def _check_stability(problem: Problem, u: np.ndarray, lin: FreeBlockSolver, ctl: StepControl,
                     X0: np.ndarray | None = None) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """lambda_min, its mode and all computed modes (the start block of the next check)."""
    try:
        lam, V = lowest_eigenvalues(lin, ctl.n_eigs, X0)
    except (spla.ArpackNoConvergence, spla.ArpackError, LinearSolverError, np.linalg.LinAlgError) as exc:
        log.warning("stability check failed (%s): state not classified", exc)
        return float("nan"), None, None
    return float(lam[0]), V[:, 0], V


def single_threaded_blas() -> Any:
    """Context holding every BLAS/OpenMP pool of the process to one thread (threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; without it the pools keep their threads
        return contextlib.nullcontext()
    try:  # NGSolve's BLAS and MKL are loaded with it: load them first, so that the limit reaches them
        import ngsolve.la  # noqa: F401
    except ImportError:  # pragma: no cover
        pass
    if cholmod.available():  # cvxopt brings its own OpenBLAS (CHOLMOD's supernodes)
        import cvxopt.cholmod  # noqa: F401
    return threadpool_limits(limits=1)


def solve_path(problem: Problem, ctl: StepControl,
               on_step: Callable[[StepRecord, np.ndarray], None] | None = None,
               progress: Callable[[float], None] | None = None) -> dict[str, Any]:
    """Follow the load path u0 = 0 -> ctl.u0_final with :class:`ShiftedNewton` on the engine.

    ``on_step(record, u)`` is called after each converged step, ``progress(u0)`` after it. The
    BLAS libraries in the process (numpy's and scipy's OpenBLAS, NGSolve's OpenBLAS and MKL)
    are held to one thread meanwhile: the solver's dense operations are vector-sized (dot products,
    the Lanczos block of a few columns), where a second BLAS thread saves nothing and, spinning
    between calls, kept a second core busy for the whole run (CPU time = 2x wall time).

    Returns
    -------
    dict
        Iteration and time statistics, snap events and the final state ``u``.

    Raises
    ------
    ngbet.errors.ConvergenceError
        when a step fails at the minimum step size (the states before it were passed to on_step);
        its ``path_info`` holds the statistics gathered until then (snap events included, not ``u``).
    KeyboardInterrupt
        passed on with the same ``path_info`` attached (Ctrl-C, SIGTERM).
    """
    with single_threaded_blas():
        corrector = ShiftedNewton(problem, ctl)
        path = PathControl(target=ctl.u0_final, first_step=ctl.first_step, max_step=ctl.max_step,
                           min_step=ctl.min_step, growth=ctl.growth, cut=ctl.cut, grow_after=ctl.grow_after,
                           stops=ctl.stations)
        hook = None if on_step is None else (lambda rec: on_step(rec, corrector.u))
        try:
            follow_path(corrector, path, on_step=hook, progress=progress)
        except (ConvergenceError, KeyboardInterrupt) as exc:  # Ctrl-C / SIGTERM too: the statistics so far
            info = {k: v for k, v in corrector.statistics().items() if k != "u"}
            if isinstance(exc, ConvergenceError):
                exc.path_info.update(info)
            else:
                exc.path_info = info  # type: ignore[attr-defined]
            raise
        return corrector.statistics()


@dataclass
class _Trial:
    """A corrected state awaiting acceptance (between ``correct`` and ``accept``)."""

    u: np.ndarray
    iterations: int
    history: list[tuple[float, float, float]]
    shifted: int
    relaxed: bool
    nout: dict[str, Any]
    mark: tuple[int, int, float]
    energy: float = math.nan
    gradient: np.ndarray | None = None
    tangent: np.ndarray | None = None  # du/du0 at the corrected state (None: none at hand)
    dforce_du0: float = math.nan
    released: float = 0.0
    work: float = 0.0
    jumped: bool = False


def _decrements(history: list[tuple[float, float, float]]) -> list[float]:
    return [h[2] for h in history]


class ShiftedNewton:
    """The network's corrector for :func:`ngbet.engine.follow_path` (see the module docstring).

    Two factorizations of the same pattern: ``lin`` holds the tangent at the converged state
    (predictor, stability check, restart after a failed or cut step: no refactorization),
    ``work`` the Newton iterations; they swap roles when a step is accepted.
    """

    def __init__(self, problem: Problem, ctl: StepControl) -> None:
        self.problem = self._timed = _TimedProblem(problem)
        self.ctl = ctl
        self.u = np.zeros(problem.n_dofs)
        self.E, self.g, K = self.problem.evaluate(self.u, True)
        assert K is not None
        self.K: sp.csr_matrix = K
        free_mask = ~problem.fixed
        finder = getattr(problem, "half_turn", None)
        ht = finder() if (ctl.half_turn and finder is not None) else None
        self.half_turn = ht
        self.lin = FreeBlockSolver(K, free_mask, ctl.backend, ht)
        self.work = self.lin.twin()
        self.free = self.lin.free
        self.tally = _Tally((self.lin, self.work))
        mark = self.tally.start()
        self.lin.factor(K)
        self.tally.add("initial tangent", mark)
        self.modes: np.ndarray | None = None  # modes of the last stability check: start block of the next
        self.tangent: np.ndarray | None = None  # du/du0 at the converged state
        self.tangent_prev: tuple[np.ndarray, float] | None = None  # du/du0 one step back, and that step
        self.step = 0
        self.stats: dict[str, Any] = {"newton_iterations": 0, "failed_steps": 0, "snap_events": [],
                                      "unstable_states": 0, "shifted_iterations": 0, "t_stability_s": 0.0,
                                      "lambda_min": [], "factorizations": 0, "snap_bracketing": 0}
        self._predicted = self.u
        self._trial: _Trial | None = None

    # ------------------------------------------------------------------------------ predict
    def _tangent_at(self, lin: FreeBlockSolver, K: sp.csr_matrix) -> np.ndarray:
        """du/du0 at the state whose tangent K is factorized in ``lin``.

        On the symmetric path (``lin`` holds the half-turn blocks) du/du0 - S du/du0 = c, so du/du0
        is c / 2 (a rigid translation, K c = 0) plus a symmetric field w that the symmetric block
        gives alone; solved whole, that translation would come out of the soft antisymmetric
        block only to about 1e-5 (cancellation in K c).
        """
        load, free = self.problem.load, self.free
        ht = self.half_turn
        if ht is None or not lin.in_blocks:
            t = load.copy()
            t[free] = -lin.solve((K @ load)[free])
            return t
        w = np.where(self.problem.fixed, load - 0.5 * ht.shift, 0.0)
        t = 0.5 * ht.shift + w
        t[free] += -lin.solve((K @ w)[free], symmetric_rhs=True)
        return t

    def predict(self, u0: float, h: float) -> None:
        """Tangent predictor with the second-order (Hermite) term, or the clamp's ramp."""
        p, free = self.problem, self.free
        trial = self.u.copy()
        if self.ctl.predictor == "tangent":
            if self.tangent is None:  # at the start and after a jump
                mark = self.tally.start()
                self.tangent = self._tangent_at(self.lin, self.K)
                self.tally.add("predictor tangent", mark)
            trial += h * self.tangent
            if self.tangent_prev is not None:
                t_prev, h_prev = self.tangent_prev
                trial[free] += 0.5 * h * h * (self.tangent[free] - t_prev[free]) / h_prev
        else:
            trial += h * p.ramp
            trial[p.fixed] = self.u[p.fixed] + h * p.load[p.fixed]
        if self.half_turn is not None:
            # on the symmetric path, the prediction is put back on it (off it by round-off only), so
            # that Newton's tangents stay block diagonal and its steps symmetric
            sym = self.half_turn.project(trial, u0 + h)
            trial = trial if sym is None else sym
        self._predicted = trial

    # ------------------------------------------------------------------------------ correct
    def correct(self, u0: float, h: float) -> Outcome:
        """Newton from the prediction; relaxation past a limit point; snap classification."""
        ctl = self.ctl
        nout: dict[str, Any] = {}
        mark = self.tally.start()
        bracketing = h > ctl.snap_bracket * (1 + 1e-9)
        try:
            # a step longer than the snap bracket that meets an indefinite tangent is cut whether or
            # not Newton converges (see ``_classify``): give up at once
            unew, its, hist, shifted = newton(self.problem, self._predicted, self.work, ctl, out=nout,
                                              allow_shift=not bracketing, inexact=True)
            trial = _Trial(unew, its, hist, shifted, False, nout, mark)
        except _StepFailed as exc:
            if exc.indefinite:
                self.tally.add("indefinite tangent (step cut to bracket a snap)", mark, nout)
                log.info("step u0 %.5g -> %.5g mm met an indefinite tangent: cutting to bracket a snap",
                         u0 * 1e3, (u0 + h) * 1e3)
                return self._bracket(h, len(exc.history), _decrements(exc.history), str(exc))
            self.tally.add("failed attempt", mark, nout)
            self.stats["failed_steps"] += 1
            log.info("step u0 %.5g -> %.5g mm failed (%s)", u0 * 1e3, (u0 + h) * 1e3, exc)
            relaxed = None
            if not bracketing or h * ctl.cut < ctl.min_step * (1 - 1e-9):
                relaxed = self._relax(exc, u0, h)
            if relaxed is None:
                return Outcome("failed", len(exc.history), _decrements(exc.history), str(exc))
            trial = relaxed
        return self._classify(trial, u0, h)

    def _bracket(self, h: float, iterations: int, history: list[float], reason: str) -> Outcome:
        """Retry at a shorter step, not below the snap bracket."""
        self.stats["snap_bracketing"] += 1
        return Outcome("retry", iterations, history, reason, retry_step=max(h * self.ctl.cut, self.ctl.snap_bracket))

    def _relax(self, exc: _StepFailed, u0: float, h: float) -> _Trial | None:
        """After a short step failed: no equilibrium near the predictor, the branch ends (limit point).

        A damped Newton (shifted where indefinite) runs long enough to reach the branch the state
        snaps to, from where the failed attempt got if that is lower.
        """
        p, ctl = self.problem, self.ctl
        start = self._predicted
        if exc.u is not None:
            E_fail = p.evaluate(exc.u, False)[0]
            E_trial = exc.history[0][0] if exc.history else p.evaluate(start, False)[0]
            if np.isfinite(E_fail) and E_fail < E_trial:
                start = exc.u
        nout: dict[str, Any] = {}
        mark = self.tally.start()
        trial = None
        try:
            unew, its, hist, shifted = newton(p, start, self.work, ctl, max_iterations=4 * ctl.max_iterations,
                                              line_search=True, fail_fast=False, out=nout, inexact=True)
            # the state left its branch
            trial = _Trial(unew, its + len(exc.history), hist, max(shifted, 1), True, nout, mark)
        except _StepFailed as exc2:
            log.info("relaxation u0 %.5g -> %.5g mm failed (%s)", u0 * 1e3, (u0 + h) * 1e3, exc2)
        self.tally.add("relaxation", mark, nout)
        return trial

    def _classify(self, tr: _Trial, u0: float, h: float) -> Outcome:
        """Accept the converged state, or ask for a shorter step when it has snapped.

        Envelope theorem: on a continuous branch dE/du0 = F = load . g, so the work of the clamp
        equals the energy change; energy released beyond it is a snap-through. The work by the
        trapezoidal rule is exact to O(h^3 F''); with F' = dF/du0 = load . K du/du0 at both ends
        (the tangent at the start is the predictor's, the one at the end the next predictor's,
        from the factorization at hand) the Hermite rule adds h^2/12 (F'_0 - F'_1) and is exact
        to O(h^5): on smooth steps of up to 7.6 mm at 17k dofs it left <= 2e-5 of the step's work,
        snaps released >= 2 %; the trapezoid alone left up to 0.5 %, and a snap of 2-4 % of a
        long step's work hid below its 5 % threshold.
        """
        p, ctl, load = self.problem, self.ctl, self.problem.load
        tr.energy, tr.gradient, _ = p.evaluate(tr.u, False)
        tr.work = 0.5 * h * float(load @ self.g + load @ tr.gradient)
        if self.tangent is not None and not self.work.shifted:
            mark = self.tally.start()
            tr.tangent = self._tangent_at(self.work, tr.nout["K"])
            if tr.relaxed:  # the relaxation's row is closed; a converged step's row is closed later
                self.tally.add("tangent after a relaxation", mark)
            dF0 = float(load @ (self.K @ self.tangent))
            tr.dforce_du0 = float(load @ (tr.nout["K"] @ tr.tangent))
            tr.work += h * h / 12 * (dF0 - tr.dforce_du0)
        tr.released = tr.work - (tr.energy - self.E)
        threshold = ctl.snap_release_hermite if tr.tangent is not None else ctl.snap_release
        tr.jumped = tr.released > threshold * abs(tr.work) or tr.shifted > 0
        decs = _decrements(tr.history)
        if tr.jumped and h > ctl.snap_bracket * (1 + 1e-9):
            if not tr.relaxed:
                self.tally.add("snap bracketing (converged, rejected)", tr.mark, tr.nout)
            log.info("step u0 %.5g -> %.5g mm released %.3g J of %.3g J work (indefinite iterations: %d): "
                     "cutting to bracket the snap", u0 * 1e3, (u0 + h) * 1e3, tr.released, tr.work, tr.shifted)
            return self._bracket(h, tr.iterations, decs, "snap-through: bracketing")
        self._trial = tr
        return Outcome("converged", tr.iterations, decs, "converged")

    # ------------------------------------------------------------------------------ accept / reject
    def reject(self, u0: float, outcome: Outcome) -> None:
        """Nothing to undo: the converged state and its factorization (``lin``) are untouched."""
        self._trial = None

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        """Commit the trial, record a snap-through, check the stability of the new state."""
        tr = self._trial
        assert tr is not None and tr.gradient is not None
        self._commit(tr, h)
        u0_new = u0 + h
        if tr.jumped:
            self._record_snap(tr, u0, u0_new)
        rec = StepRecord(self.step, u0_new, tr.iterations, residual=self.g, energy=self.E, snap=tr.jumped,
                         released=tr.released, history=_decrements(tr.history), dforce_du0=tr.dforce_du0)
        if self.ctl.stability:
            rec.lambda_min, escaped = self._check(u0_new)
            if escaped:
                rec.residual, rec.energy, rec.snap, rec.dforce_du0 = self.g, self.E, True, math.nan
        self.stats["lambda_min"].append(rec.lambda_min)
        return rec

    def _commit(self, tr: _Trial, h: float) -> None:
        """The trial becomes the converged state; ``lin`` gets its tangent (refactorized only after a shift).

        The tangent of the last Newton iteration is the converged one up to the last update
        (below the tolerance).
        """
        K_new = tr.nout["K"]
        if not tr.relaxed:
            self.tally.add("converged step", tr.mark, tr.nout)
        if self.work.shifted:
            mark = self.tally.start()
            K_new = self.problem.evaluate(tr.u, True)[2]
            self.work.factor(K_new)
            self.tally.add("converged tangent after a shifted last iteration", mark)
        self.lin, self.work = self.work, self.lin
        self.tangent_prev = (self.tangent, h) if (self.tangent is not None and not tr.jumped) else None
        self.tangent = tr.tangent  # du/du0 at the new state (None: the predictor solves for it)
        self.stats["newton_iterations"] += tr.iterations
        self.stats["shifted_iterations"] += tr.shifted
        assert tr.gradient is not None
        self.u, self.E, self.g, self.K = tr.u, tr.energy, tr.gradient, K_new
        self.step += 1
        self._trial = None

    def _record_snap(self, tr: _Trial, u0: float, u0_new: float) -> None:
        log.warning("step %d, u0 %.5g -> %.5g mm: snap-through, %.3g J released (%.0f %% of the clamp "
                    "work), indefinite iterations %d", self.step, u0 * 1e3, u0_new * 1e3, tr.released,
                    100 * tr.released / tr.work if tr.work else float("nan"), tr.shifted)
        self.stats["snap_events"].append({"u0": u0_new, "u0_before": u0, "kind": "snap_through", "step": self.step,
                                          "released_J": tr.released, "work_J": tr.work,
                                          "indefinite_iterations": tr.shifted})

    def _check(self, u0: float) -> tuple[float, bool]:
        """Lowest eigenvalue at the converged state; an unstable state is left for a stable neighbour.

        Returns the lowest eigenvalue (after an escape: that of the new state) and whether the
        state changed.
        """
        ts = time.perf_counter()
        mark = self.tally.start(ts)
        lam, v, V = _check_stability(self.problem, self.u, self.lin, self.ctl, self.modes)
        self.modes = V
        self.tally.add("stability check", mark)
        escaped = lam < -1e-9 and v is not None
        if escaped:
            assert v is not None and self.lin.Kff is not None
            self.stats["unstable_states"] += 1
            mark = self.tally.start()
            self.u, self.E, self.g, self.K, lam2, self.modes = _escape(
                self.problem, self.u, self.E, v, self.work, self.ctl, np.abs(self.lin.Kff.diagonal()))
            self.tally.add("escape from an unstable state", mark)
            self.lin, self.work = self.work, self.lin  # _escape left the tangent of the final state in ``work``
            self.tangent_prev = self.tangent = None
            self.stats["snap_events"].append({"u0": u0, "kind": "unstable_equilibrium", "step": self.step,
                                              "lambda_min": lam, "lambda_min_after": lam2})
            log.warning("step %d, u0 = %.5g mm: unstable equilibrium (lambda_min = %.3g); relaxed to "
                        "lambda_min = %.3g", self.step, u0 * 1e3, lam, lam2)
            lam = lam2
        self.stats["t_stability_s"] += time.perf_counter() - ts
        return lam, escaped

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        """The snap events met before the failure (the network fails where it keeps snapping)."""
        n = len(self.stats["snap_events"])
        return (f"{n} snap events before the failure" if n else ""), None

    def statistics(self) -> dict[str, Any]:
        """Iteration, factorization and time statistics of the path, and the final state ``u``."""
        lin, work, t = self.lin, self.work, self._timed
        s = dict(self.stats)
        s.update({"u": self.u, "steps": self.step, "backend": lin.backend, "n_free": len(self.free),
                  "factorizations": lin.n_factor + work.n_factor, "work_by_cause": self.tally.rows,
                  "half_turn_blocks": lin.has_half_turn,
                  "factorizations_antisymmetric": lin.n_factor_antisymmetric + work.n_factor_antisymmetric,
                  "factorizations_ldlt": lin.n_factor_ldlt + work.n_factor_ldlt,
                  "factorizations_off_symmetry": lin.n_factor_whole + work.n_factor_whole})
        s["timers"] = {"assembly_s": t.t_hessian, "assemblies": t.n_hessian,
                       "gradient_only_s": t.t_gradient, "gradients_only": t.n_gradient,
                       "factor_s": lin.t_factor + work.t_factor, "solve_s": lin.t_solve + work.t_solve,
                       "solves": lin.n_solve + work.n_solve}
        return s


def _escape(problem: Problem, u: np.ndarray, E: float, v: np.ndarray, lin: FreeBlockSolver, ctl: StepControl,
            diag: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, sp.csr_matrix, float, np.ndarray | None]:
    """Leave an unstable equilibrium along its unstable mode v (both signs); keep the lower stable state.

    ``lin`` is a solver whose factorization may be overwritten; it holds the tangent at the
    returned state on return. ``diag``: |diag K_ff| at u (the metric of v).
    """
    free = lin.free
    # a kick whose quadratic energy is 1e-3 |E|: large enough to leave the saddle, small on the whole
    amp = np.sqrt(2e-3 * max(abs(E), 1e-30) / max(float(v @ (diag * v)), 1e-300))
    best = None
    for sgn in (1.0, -1.0):
        w = u.copy()
        w[free] += sgn * amp * v
        try:
            w, _, _, _ = newton(problem, w, lin, ctl, max_iterations=20 * ctl.max_iterations, line_search=True)
        except _StepFailed:
            continue
        Ew = problem.evaluate(w, False)[0]
        if best is None or Ew < best[1]:
            best = (w, Ew)
    if best is not None and best[1] < E:
        u = best[0]
    E, g, K = problem.evaluate(u, True)
    lin.factor(K)
    lam2, _, V = _check_stability(problem, u, lin, ctl)
    return u, E, g, K, lam2, V
