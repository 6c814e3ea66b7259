"""Newton's method with displacement load stepping for energy minimization problems.

The solver knows nothing of yarns. A problem provides ``n_dofs``, ``fixed`` (bool mask of
prescribed dofs), ``load`` (prescribed values per unit load parameter u0), ``ramp`` (a field for
the "clamp" predictor) and ``evaluate(u, hessian) -> (E, dE/du, d2E/du2)``.

Step from u0 to u0 + h:
  predictor  "tangent": u_f += -K_ff^{-1} K_fc h load_c  (K at the last converged state)
             "clamp":   u   += h ramp
  corrector  Newton on the free dofs, du = -K_ff^{-1} r; where du is not a descent direction
             (K_ff indefinite) the tangent is shifted by mu diag(K_ff) until it is (mu from a
             tenth of the last shift of the same Newton run, 1e-6 at first, raised tenfold).
             While relaxing past a snap-through: Armijo backtracking on the energy, and shifted
             steps extended while the energy keeps falling along them.
  converged  when the Newton decrement |r . du| (an energy, twice the predicted energy change)
             is below rtol |E| + atol: unit-free.
  step size  grows by ``growth`` (up to max_step) after a step with at most ``grow_after``
             iterations, is cut by ``cut`` after a failed step, and a step below ``min_step``
             raises :class:`ConvergenceError` (residual history, last converged u0). A step
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
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ConvergenceError as _ConvergenceError
from .linsolve import FreeBlockSolver, LinearSolverError

log = logging.getLogger(__name__)


_QUADRATIC = True


class Problem(Protocol):
    n_dofs: int
    fixed: np.ndarray
    load: np.ndarray
    ramp: np.ndarray

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]: ...


class ConvergenceError(_ConvergenceError):
    """A load step could not be completed even with the smallest step size.

    Attributes
    ----------
    last_converged_u0 : load parameter of the last converged state (SI)
    attempted_u0 : the load the failed step aimed at
    residual_history : per Newton iteration of the last attempt: (energy, |r|_inf, decrement)
    """

    def __init__(self, msg: str, last_converged_u0: float, attempted_u0: float,
                 residual_history: list[tuple[float, float, float]]) -> None:
        super().__init__(msg)
        self.last_converged_u0 = last_converged_u0
        self.last_converged_mm = last_converged_u0 * 1e3
        self.attempted_u0 = attempted_u0
        self.residual_history = residual_history


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


@dataclass
class StepInfo:
    """What the solver reports for one converged step."""

    step: int
    u0: float
    iterations: int
    wall_s: float
    energy: float
    gradient: np.ndarray
    lambda_min: float = float("nan")
    snap: bool = False
    released: float = 0.0  # energy released beyond the clamp work in this step [J] (snap-through)
    history: list[tuple[float, float, float]] = field(default_factory=list)


class _TimedProblem:
    """The problem with its evaluations timed (assembly with and without the Hessian)."""

    def __init__(self, problem: Problem) -> None:
        self._p = problem
        self.n_dofs, self.fixed, self.load, self.ramp = problem.n_dofs, problem.fixed, problem.load, problem.ramp
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
    """Factorizations, Newton iterations and wall time of the load path by cause (bench_discrete)."""

    def __init__(self, solvers: tuple[FreeBlockSolver, ...]) -> None:
        self.solvers = solvers
        self.rows: dict[str, dict[str, float]] = {}

    def start(self, t: float | None = None) -> tuple[int, float]:
        return sum(s.n_factor for s in self.solvers), time.perf_counter() if t is None else t

    def add(self, cause: str, mark: tuple[int, float], nout: dict[str, Any] | None = None) -> None:
        row = self.rows.setdefault(cause, {"calls": 0, "factorizations": 0, "shift_factorizations": 0,
                                           "iterations": 0, "time_s": 0.0})
        row["calls"] += 1
        row["factorizations"] += sum(s.n_factor for s in self.solvers) - mark[0]
        row["time_s"] += time.perf_counter() - mark[1]
        if nout:
            row["iterations"] += nout.get("iterations", 0)
            row["shift_factorizations"] += nout.get("shift_factorizations", 0)


class _StepFailed(Exception):
    """Newton gave up; ``u`` is its last iterate (None where it is of no use), ``indefinite``
    says that it gave up at the first tangent that needed a shift (``allow_shift=False``)."""

    def __init__(self, why: str, history: list[tuple[float, float, float]], u: np.ndarray | None = None,
                 indefinite: bool = False) -> None:
        super().__init__(why)
        self.history = history
        self.u = u
        self.indefinite = indefinite


def newton(problem: Problem, u: np.ndarray, lin: FreeBlockSolver, ctl: StepControl,
           max_iterations: int | None = None, line_search: bool = False, fail_fast: bool = True,
           out: dict[str, Any] | None = None, allow_shift: bool = True
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

    Returns
    -------
    u, iterations, history [(E, |r|_inf, decrement)], number of iterations with a shifted tangent;
    ``out["K"]`` (when ``out`` is given): the tangent of the last iteration, factorized in ``lin``
    (``lin.shifted`` says whether with a shift). At convergence the last update is below the
    tolerance (|r . du| <= rtol |E|), so that factorization serves as the converged tangent.
    """
    free = lin.free
    u = u.copy()
    hist: list[tuple[float, float, float]] = []
    shifted = 0
    mu_prev = 0.0
    for it in range(1, (max_iterations or ctl.max_iterations) + 1):
        E, g, K = problem.evaluate(u, True)
        if out is not None:
            out["K"] = K
            out["iterations"] = it
        r = g[free]
        if not (np.isfinite(E) and np.all(np.isfinite(r))):
            raise _StepFailed("energy or residual not finite", hist)
        try:
            lin.factor(K)
            du = -lin.solve(r)
            dec = -float(r @ du)
            # shift mu diag(K_ff): from a tenth of the last one that gave descent in this call (1e-6 at
            # first), raised tenfold until the step descends. Past a limit point the smallest such shift
            # matters: along an unstable mode of eigenvalue -lambda the shifted step grows the mode by
            # about lambda / mu per iteration, and a fixed mu = 1e-6 >> lambda crept for dozens of
            # factorizations
            mu = max(mu_prev / 10, 1e-10) if mu_prev else 1e-6
            shifted_now = dec <= 0
            if shifted_now and not allow_shift:
                hist.append((E, float(np.abs(r).max(initial=0.0)), dec))
                raise _StepFailed("tangent not a descent direction (indefinite)", hist, indefinite=True)
            diag = np.abs(lin.Kff.diagonal())  # of the unshifted K_ff (lin.Kff holds the last shifted one)
            while dec <= 0 and mu < 1e3:  # not a descent direction: K_ff indefinite here
                try:
                    lin.factor(K, shift=mu * diag)
                    du = -lin.solve(r)
                    dec = -float(r @ du)
                except LinearSolverError:  # the shift met an eigenvalue: singular, try the next
                    dec = -1.0
                mu_prev = mu
                mu *= 10
                shifted += 1
                if out is not None:
                    out["shift_factorizations"] = out.get("shift_factorizations", 0) + 1
        except LinearSolverError as exc:
            raise _StepFailed(str(exc), hist) from None
        hist.append((E, float(np.abs(r).max(initial=0.0)), dec))
        tol = ctl.rtol * abs(E) + ctl.atol
        if abs(dec) <= tol:
            u[free] += du
            return u, it, hist, shifted
        if dec <= 0:
            raise _StepFailed("no descent direction even with a shifted tangent", hist)
        if fail_fast and not line_search and it >= 2 and dec > 2 * abs(E):
            # the quadratic model predicts an energy drop (dec / 2) larger than the energy itself
            # (E >= 0 for the network): the iterate has left the region where Newton can converge
            raise _StepFailed(f"Newton diverging (decrement {dec:.3g} > 2 |E| = {2 * abs(E):.3g})", hist, u)
        if fail_fast and not line_search and it >= 3 and dec > hist[0][2]:
            # from a predictor the decrement falls, at first perhaps slowly: one above the
            # predictor's own, two iterations on, is Newton bouncing in a soft mode or leaving (in
            # the runs measured the one such step that still converged had snapped: cut anyway)
            raise _StepFailed(f"Newton decrement rose above the predictor's ({hist[0][2]:.3g} -> {dec:.3g})", hist, u)
        if fail_fast and not line_search and it >= 6 and dec > 0.5 * hist[-2][2]:
            # Newton converges quadratically near a solution or not at all: stop wasting factorizations
            raise _StepFailed(f"Newton decrement not contracting ({hist[-2][2]:.3g} -> {dec:.3g})", hist, u)
        alpha = 1.0
        if line_search and (dec > 1e-6 * abs(E) + ctl.atol or shifted_now):  # far from the solution
            v = u.copy()
            for _ in range(12):
                v[free] = u[free] + alpha * du
                Ev = problem.evaluate(v, False)[0]
                if np.isfinite(Ev) and Ev <= E - 1e-4 * alpha * dec:
                    break
                alpha *= 0.5
            else:
                raise _StepFailed("line search found no energy decrease", hist)
            if alpha == 1.0 and shifted_now:
                # extend a shifted step while the energy falls along it (doubling, at most 2^12)
                for _ in range(12):
                    v[free] = u[free] + 2 * alpha * du
                    E2 = problem.evaluate(v, False)[0]
                    if not (np.isfinite(E2) and E2 < Ev):
                        break
                    alpha, Ev = 2 * alpha, E2
        if log.isEnabledFor(logging.DEBUG):
            log.debug("newton it %d: E %.10g, |r| %.3g, decrement %.3g, shift mu %.0e, step x%g", it, E,
                      hist[-1][1], dec, mu_prev if shifted_now else 0.0, alpha)
        u[free] += alpha * du
    raise _StepFailed(f"no convergence in {max_iterations or ctl.max_iterations} iterations", hist, u)


def lowest_eigenvalues(lin: FreeBlockSolver, k: int, X0: np.ndarray | None = None, tol: float = 1e-3,
                       max_expansions: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs of K_ff v = lambda D v nearest to 0, D = diag(K_ff), using the current factorization.

    Block shift-invert Lanczos (sigma = 0) with full reorthogonalization, started from ``X0``
    (the modes of the previous load step: they change little from step to step, so that one or
    two expansions usually suffice) or from (1, ..., 1) and a fixed random vector. In the
    scaled variables y = D^(1/2) v the problem is A y = lambda y with A = D^(-1/2) K_ff D^(-1/2);
    each expansion applies A^(-1) (one solve with the factorization) to the current Ritz
    vectors. Converged when the pair nearest to 0 has a residual |A y - theta y| <= tol |theta|
    (|y| = 1): an eigenvalue then lies within tol |theta| of theta, so that its sign is certain,
    and the Ritz value itself is accurate to ~tol^2 |theta| relative (the other k - 1 pairs are
    Ritz approximations: they serve as the start block of the next check; eigenvalues 2 and 3
    of the BET networks can lie within 2 % of each other, where resolving them would cost
    dozens of solves).
    Falls back to ARPACK (``eigsh`` in shift-invert mode) if that does not happen within
    ``max_expansions``.

    Returns
    -------
    lam (k,) ascending, V (n_free, k): D-normalized modes
    """
    Kff = lin.Kff
    assert Kff is not None
    n = Kff.shape[0]
    k = min(k, n - 2)
    s = np.sqrt(np.abs(Kff.diagonal()))
    s[s == 0] = 1.0

    def A(Y: np.ndarray) -> np.ndarray:
        return (Kff @ (Y / s[:, None])) / s[:, None]

    def Ainv(Y: np.ndarray) -> np.ndarray:
        return s[:, None] * lin.solve_many(s[:, None] * Y)

    def orth(W: np.ndarray, Q: np.ndarray) -> np.ndarray:
        for _ in range(2):  # classical Gram-Schmidt, twice
            if Q.shape[1]:
                W = W - Q @ (Q.T @ W)
            nrm = np.linalg.norm(W, axis=0)
            W = W[:, nrm > 1e-10 * max(nrm.max(initial=0.0), 1e-300)]
            if W.shape[1] == 0:
                return W
            W, Rw = np.linalg.qr(W)
            W = W[:, np.abs(np.diag(Rw)) > 1e-12 * np.abs(Rw).max()]
        return W

    if X0 is not None and X0.ndim == 2 and X0.shape[0] == n and X0.shape[1] >= 1:
        Y = X0[:, :k] * s[:, None]
        if Y.shape[1] < k:
            Y = np.column_stack([Y, np.random.default_rng(0).standard_normal((n, k - Y.shape[1]))])
    else:
        Y = np.column_stack([np.ones(n)] + [np.random.default_rng(j).standard_normal(n) for j in range(k - 1)])
    Q = orth(Y, np.zeros((n, 0)))
    AQ = A(Q)
    for _ in range(max_expansions):
        H = Q.T @ AQ
        th, C = np.linalg.eigh(0.5 * (H + H.T))
        idx = np.argsort(np.abs(th))[:k]
        th, C = th[idx], C[:, idx]
        Yr, AYr = Q @ C, AQ @ C
        res = np.linalg.norm(AYr - Yr * th, axis=0)
        if Yr.shape[1] == k and res[0] <= tol * abs(th[0]) + 1e-14:
            order = np.argsort(th)
            return th[order], (Yr / s[:, None])[:, order]
        W = orth(Ainv(Yr), Q)
        if W.shape[1] == 0:
            break
        if Q.shape[1] + W.shape[1] > 60:  # restart with the Ritz vectors
            Q, AQ = Yr, AYr
            W = orth(W, Q)
        Q, AQ = np.column_stack([Q, W]), np.column_stack([AQ, A(W)])
    log.info("block Lanczos did not converge; falling back to ARPACK")
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


def solve_path(problem: Problem, ctl: StepControl,
               on_step: Callable[[StepInfo, np.ndarray], None] | None = None,
               progress: Any = None) -> dict[str, Any]:
    """Follow the load path u0 = 0 -> ctl.u0_final; call ``on_step(info, u)`` after each converged step.

    The BLAS libraries in the process (numpy's and scipy's OpenBLAS, NGSolve's OpenBLAS and MKL)
    are held to one thread meanwhile: the solver's dense operations are vector-sized (dot products,
    the Lanczos block of a few columns), where a second BLAS thread saves nothing and, spinning
    between calls, kept a second core busy for the whole run (CPU time = 2x wall time).

    Returns
    -------
    dict with iteration and time statistics, snap events and the final state ``u``.

    Raises
    ------
    ConvergenceError
        when a step fails at the minimum step size (the states before it were passed to on_step).
    """
    with single_threaded_blas():
        return _solve_path(problem, ctl, on_step, progress)


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
    return threadpool_limits(limits=1)


def _solve_path(problem: Problem, ctl: StepControl, on_step: Callable[[StepInfo, np.ndarray], None] | None,
                progress: Any) -> dict[str, Any]:
    problem = problem_t = _TimedProblem(problem)
    n = problem.n_dofs
    u = np.zeros(n)
    free_mask = ~problem.fixed
    E, g, K = problem.evaluate(u, True)
    # two factorizations of the same pattern: ``lin`` holds the tangent at the converged state
    # (predictor, stability check, restart after a failed or cut step: no refactorization),
    # ``work`` the Newton iterations; they swap roles when a step is accepted
    lin = FreeBlockSolver(K, free_mask, ctl.backend)
    work = FreeBlockSolver(K, free_mask, ctl.backend)
    free = lin.free
    tally = _Tally((lin, work))
    mark = tally.start()
    lin.factor(K)
    tally.add("initial tangent", mark)
    modes: np.ndarray | None = None  # modes of the last stability check: start block of the next
    tangent: np.ndarray | None = None  # du/du0 at the converged state
    tangent_prev: tuple[np.ndarray, float] | None = None  # du/du0 at the state before, and the step between
    u0, h, step = 0.0, min(ctl.first_step, ctl.u0_final), 0
    stats: dict[str, Any] = {"newton_iterations": 0, "failed_steps": 0, "snap_events": [],
                             "unstable_states": 0, "shifted_iterations": 0, "t_stability_s": 0.0,
                             "lambda_min": [], "factorizations": 0}
    last_hist: list[tuple[float, float, float]] = []
    while u0 < ctl.u0_final * (1 - 1e-12):
        h_free = h
        h = min(h, ctl.u0_final - u0)
        for st in sorted(ctl.stations):
            if u0 < st * (1 - 1e-12) and u0 + h > st:
                h = st - u0
                break
        t0 = time.perf_counter()
        trial = u.copy()
        dc = h * problem.load
        if ctl.predictor == "tangent":
            if tangent is None:  # du/du0 at the converged state u (K and lin hold its tangent)
                tangent = problem.load.copy()
                tangent[free] = -lin.solve((K @ problem.load)[free])
            trial += h * tangent
            if tangent_prev is not None and _QUADRATIC:
                # second-order term from the change of du/du0 over the last step (Hermite)
                trial[free] += 0.5 * h * h * (tangent[free] - tangent_prev[0][free]) / tangent_prev[1]
        else:
            trial += h * problem.ramp
            trial[problem.fixed] = u[problem.fixed] + dc[problem.fixed]
        nout: dict[str, Any] = {}
        relaxed = None
        mark = tally.start()
        bracketing = h > ctl.snap_bracket * (1 + 1e-9)
        try:
            # a step longer than the snap bracket that meets an indefinite tangent is cut whether or
            # not Newton converges (see ``jumped`` below): give up at once
            unew, its, hist, shifted = newton(problem, trial, work, ctl, out=nout, allow_shift=not bracketing)
        except _StepFailed as exc:
            if exc.indefinite:
                tally.add("indefinite tangent (step cut to bracket a snap)", mark, nout)
                stats["snap_bracketing"] = stats.get("snap_bracketing", 0) + 1
                log.info("step u0 %.5g -> %.5g met an indefinite tangent: cutting to bracket a snap", u0, u0 + h)
                h = max(h * ctl.cut, ctl.snap_bracket)
                continue
            tally.add("failed attempt", mark, nout)
            stats["failed_steps"] += 1
            log.info("step u0 %.5g -> %.5g failed (%s)", u0, u0 + h, exc)
            if not bracketing or h * ctl.cut < ctl.min_step * (1 - 1e-9):
                # a short step and still no equilibrium near the predictor: the branch ends (limit
                # point); let a damped Newton (shifted where indefinite) run long enough to reach
                # the branch it snaps to, from where the failed attempt got if that is lower
                start = trial
                if exc.u is not None:
                    E_fail = problem.evaluate(exc.u, False)[0]
                    E_trial = exc.history[0][0] if exc.history else problem.evaluate(trial, False)[0]
                    if np.isfinite(E_fail) and E_fail < E_trial:
                        start = exc.u
                nout = {}
                mark = tally.start()
                try:
                    relaxed = newton(problem, start, work, ctl, max_iterations=4 * ctl.max_iterations,
                                     line_search=True, fail_fast=False, out=nout)
                except _StepFailed as exc2:
                    last_hist = exc2.history
                    log.info("relaxation u0 %.5g -> %.5g failed (%s)", u0, u0 + h, exc2)
                tally.add("relaxation", mark, nout)
            if relaxed is None:
                # ``lin`` still holds the tangent at the converged state for the next predictor
                if h * ctl.cut < ctl.min_step * (1 - 1e-9):
                    stats["u"] = u
                    raise ConvergenceError(
                        f"load step u0 = {u0:.6g} -> {u0 + h:.6g} failed at the minimum step ({exc}); "
                        f"last converged u0 = {u0:.6g}", u0, u0 + h, last_hist or exc.history) from None
                h *= ctl.cut
                continue
            unew, its, hist, shifted = relaxed
            its += len(exc.history)
            shifted = max(shifted, 1)  # the state left its branch
        E_new, g_new, _ = problem.evaluate(unew, False)
        # envelope theorem: on a continuous branch dE/du0 = F = load . g, so the work of the clamp
        # equals the energy change; energy released beyond it is a snap-through. The work by the
        # trapezoidal rule is exact to O(h^3 F''); with F' = dF/du0 = load . K du/du0 at both ends
        # (the tangent at the start is the predictor's, the one at the end the next predictor's,
        # from the factorization at hand) the Hermite rule adds h^2/12 (F'_0 - F'_1) and is exact
        # to O(h^5): on smooth steps of up to 7.6 mm at 17k dofs it left <= 2e-5 of the step's work,
        # snaps released >= 2 % (bench/README.md); the trapezoid alone left up to 0.5 %, and a snap
        # of 2-4 % of a long step's work hid below its 5 % threshold
        work_ = 0.5 * h * float(problem.load @ g + problem.load @ g_new)
        tangent_new = None
        if tangent is not None and not work.shifted:
            tangent_new = problem.load.copy()
            tangent_new[free] = -work.solve((nout["K"] @ problem.load)[free])
            dF0 = float(problem.load @ (K @ tangent))
            dF1 = float(problem.load @ (nout["K"] @ tangent_new))
            work_ += h * h / 12 * (dF0 - dF1)
        released = work_ - (E_new - E)
        threshold = ctl.snap_release_hermite if tangent_new is not None else ctl.snap_release
        jumped = released > threshold * abs(work_) or shifted > 0
        if jumped and h > ctl.snap_bracket * (1 + 1e-9):
            if relaxed is None:
                tally.add("snap bracketing (converged, rejected)", mark, nout)
            stats["snap_bracketing"] = stats.get("snap_bracketing", 0) + 1
            log.info("step u0 %.5g -> %.5g released %.3g J of %.3g J work (indefinite iterations: %d): "
                     "cutting to bracket the snap", u0, u0 + h, released, work_, shifted)
            h = max(h * ctl.cut, ctl.snap_bracket)
            continue
        # the tangent of the last Newton iteration is the converged one up to the last update
        # (below the tolerance); refactorize only if that iteration needed a shift
        K_new = nout["K"]
        if relaxed is None:
            tally.add("converged step", mark, nout)
        if work.shifted:
            mark = tally.start()
            K_new = problem.evaluate(unew, True)[2]
            work.factor(K_new)
            tally.add("converged tangent after a shifted last iteration", mark)
        lin, work = work, lin
        tangent_prev = (tangent, h) if (tangent is not None and not jumped) else None
        tangent = tangent_new  # du/du0 at the new state (None: the predictor solves for it)
        stats["newton_iterations"] += its
        stats["shifted_iterations"] += shifted
        u, E, g, K = unew, E_new, g_new, K_new
        u0 += h
        step += 1
        lam = float("nan")
        snap = bool(jumped)
        if snap:
            log.warning("step %d, u0 %.5g -> %.5g mm: snap-through, %.3g J released (%.0f %% of the clamp "
                        "work), indefinite iterations %d", step, (u0 - h) * 1e3, u0 * 1e3, released,
                        100 * released / work_ if work_ else float("nan"), shifted)
            stats["snap_events"].append({"u0": u0, "u0_before": u0 - h, "kind": "snap_through", "step": step,
                                         "released_J": released, "work_J": work_, "indefinite_iterations": shifted})
        if ctl.stability:
            ts = time.perf_counter()
            lam, v, V = _check_stability(problem, u, lin, ctl, modes)
            modes = V if V is not None else None
            tally.add("stability check", tally.start(ts))
            if lam < -1e-9 and v is not None:
                stats["unstable_states"] += 1
                mark = tally.start()
                u, E, g, K, lam2, modes = _escape(problem, u, E, v, work, ctl, np.abs(lin.Kff.diagonal()))
                tally.add("escape from an unstable state", mark)
                lin, work = work, lin  # _escape left the tangent of the final state in ``work``
                tangent_prev = tangent = None
                stats["snap_events"].append({"u0": u0, "kind": "unstable_equilibrium", "step": step,
                                             "lambda_min": lam, "lambda_min_after": lam2})
                log.warning("step %d, u0 = %.5g: unstable equilibrium (lambda_min = %.3g); relaxed to "
                            "lambda_min = %.3g", step, u0, lam, lam2)
                lam, snap = lam2, True
            stats["t_stability_s"] += time.perf_counter() - ts
        stats["lambda_min"].append(lam)
        info = StepInfo(step=step, u0=u0, iterations=its, wall_s=time.perf_counter() - t0, energy=E,
                        gradient=g, lambda_min=lam, snap=snap, history=hist, released=released)
        if on_step is not None:
            on_step(info, u)
        if progress is not None:
            progress.update(h)
        h = max(h, h_free) if h < h_free else h  # a station shortened the step, not the difficulty
        if its <= ctl.grow_after:
            h = min(h * ctl.growth, ctl.max_step)
    stats["u"] = u
    stats["steps"] = step
    stats["backend"] = lin.backend
    stats["n_free"] = len(free)
    stats["factorizations"] = lin.n_factor + work.n_factor
    stats["work_by_cause"] = tally.rows
    stats["timers"] = {"assembly_s": problem_t.t_hessian, "assemblies": problem_t.n_hessian,
                       "gradient_only_s": problem_t.t_gradient, "gradients_only": problem_t.n_gradient,
                       "factor_s": lin.t_factor + work.t_factor, "solve_s": lin.t_solve + work.t_solve,
                       "solves": lin.n_solve + work.n_solve}
    return stats


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
