"""The network's Newton corrector at a fixed load: shifted minimizing Newton, inexact where large.

``newton`` minimizes the energy of a :class:`Problem` over its free dofs from a start ``u``: the
step du = -K_ff^{-1} r, the tangent shifted by mu diag(K_ff) where du is not a descent direction
(K_ff indefinite), Armijo backtracking on the energy while relaxing past a snap-through, and
conjugate gradients preconditioned with the last factorization once the decrement is small on
large networks. Converged when the Newton decrement |r . du| is below rtol |E| + atol. The load
stepping around it is :mod:`ngbet.discrete.solver`; the whole algorithm is described there.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp

from ..numerics.engine import PathControl
from .linsolve import FreeBlockSolver, LinearSolverError

if TYPE_CHECKING:
    from .symmetry import HalfTurn

__all__ = ["Problem", "StepControl", "StepFailed", "Symmetric", "Tally", "TimedProblem", "newton"]

log = logging.getLogger(__name__)


class Problem(Protocol):
    """What the solver needs from an energy minimization problem (see the module docstring)."""

    n_dofs: int
    fixed: np.ndarray
    load: np.ndarray
    ramp: np.ndarray

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        """E(u), dE/du and (with ``hessian``) d2E/du2."""


@runtime_checkable
class Symmetric(Protocol):
    """A :class:`Problem` that may have a half-turn symmetry (a capability, checked with ``isinstance``).

    The solver then factorizes the tangents of its symmetric states in the symmetry's two blocks
    (:mod:`.symmetry`).
    """

    def half_turn(self) -> HalfTurn | None:
        """The problem's half-turn symmetry, or None where it has none."""


@dataclass(frozen=True, kw_only=True)
class StepControl:
    """Numerics of the network's load path (SI load units); built from the scene by the entry point.

    ``path`` is the step control of the engine (target, steps, growth, cut, and the loads the path
    must hit exactly: shapes are wanted there); the other fields are the corrector's.
    """

    path: PathControl
    rtol: float = 1e-10
    atol: float = 1e-14
    max_iterations: int = 12
    predictor: str = "tangent"
    backend: str = "auto"
    stability: bool = True
    n_eigs: int = 2
    snap_release: float = 0.05  # released fraction of the step's work that marks a snap-through (trapezoid)
    snap_release_hermite: float = 1e-3  # the same with the work by the Hermite rule (tangents at both ends)
    snap_bracket: float = 1e-3  # a step that snaps is cut until it is at most this long
    krylov_tol: float = 0.03  # inexact Newton in a step: CG on the tangent, preconditioned (0: factorize each)
    krylov_max: int = 8  # CG iterations before the tangent is factorized instead
    krylov_below: float = 1.0  # ... once the last decrement is below this fraction of the energy
    krylov_min_free: int = 10_000  # ... on networks with at least this many free dofs
    half_turn: bool = True  # factorize the tangents of symmetric states in their half-turn blocks (.symmetry)


class TimedProblem:
    """The problem with its evaluations timed (assembly with and without the Hessian)."""

    def __init__(self, problem: Problem) -> None:
        self._p = problem
        self.n_dofs, self.fixed, self.load, self.ramp = problem.n_dofs, problem.fixed, problem.load, problem.ramp
        self.t_hessian = self.t_gradient = 0.0
        self.n_hessian = self.n_gradient = 0

    def evaluate(self, u: np.ndarray, hessian: bool = True) -> tuple[float, np.ndarray, sp.csr_matrix | None]:
        """The wrapped problem's energy, gradient and (with ``hessian``) Hessian at ``u``, timed by kind."""
        t = time.perf_counter()
        res = self._p.evaluate(u, hessian)
        if hessian:
            self.t_hessian += time.perf_counter() - t
            self.n_hessian += 1
        else:
            self.t_gradient += time.perf_counter() - t
            self.n_gradient += 1
        return res


class Tally:
    """Factorizations, solves, Newton iterations and wall time of the load path by cause (bench_discrete)."""

    def __init__(self, solvers: tuple[FreeBlockSolver, ...]) -> None:
        self.solvers = solvers
        self.rows: dict[str, dict[str, float]] = {}

    def start(self, t: float | None = None) -> tuple[int, int, float]:
        """A mark: the factorizations and solves so far and the time (``t`` or now), for :meth:`add`."""
        return (
            sum(s.n_factor for s in self.solvers),
            sum(s.n_solve for s in self.solvers),
            time.perf_counter() if t is None else t,
        )

    def add(self, cause: str, mark: tuple[int, int, float], nout: dict[str, Any] | None = None) -> None:
        """Add the work since ``mark`` to the row of ``cause``; ``nout``: a Newton report's counts."""
        row = self.rows.setdefault(
            cause,
            {"calls": 0, "factorizations": 0, "shift_factorizations": 0, "solves": 0, "iterations": 0, "time_s": 0.0},
        )
        row["calls"] += 1
        row["factorizations"] += sum(s.n_factor for s in self.solvers) - mark[0]
        row["solves"] += sum(s.n_solve for s in self.solvers) - mark[1]
        row["time_s"] += time.perf_counter() - mark[2]
        if nout:
            row["iterations"] += nout.get("iterations", 0)
            row["shift_factorizations"] += nout.get("shift_factorizations", 0)


class StepFailed(Exception):
    """Newton gave up.

    ``u`` is its last iterate (None where it is of no use), ``indefinite`` says that it gave up at
    the first tangent that needed a shift (``allow_shift=False``; ``u`` is then the iterate of that
    tangent).
    """

    def __init__(
        self, why: str, history: list[tuple[float, float, float]], u: np.ndarray | None = None, indefinite: bool = False
    ) -> None:
        super().__init__(why)
        self.history = history
        self.u = u
        self.indefinite = indefinite


def newton(
    problem: Problem,
    u: np.ndarray,
    lin: FreeBlockSolver,
    ctl: StepControl,
    max_iterations: int | None = None,
    line_search: bool = False,
    fail_fast: bool = True,
    out: dict[str, Any] | None = None,
    allow_shift: bool = True,
    inexact: bool = False,
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
    first tangent that is not a descent direction (the caller cuts or relaxes the step instead).

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
            try:
                du, dec, mu_prev, n_shift = _descent_direction(lin, K, r, mu_prev, allow_shift, hist, E, out)
            except StepFailed as exc:
                if exc.indefinite and exc.u is None:
                    exc.u = u.copy()
                raise
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
            raise StepFailed("no descent direction even with a shifted tangent", hist)
        if fail_fast and not line_search:
            _check_contraction(hist, it, E, u)
        alpha = 1.0
        if line_search and (dec > 1e-6 * abs(E) + ctl.atol or n_shift > 0):  # far from the solution
            alpha = _line_search(problem, u, free, du, E, dec, extend=n_shift > 0, hist=hist)
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "newton it %d: E %.10g, |r| %.3g, decrement %.3g, shift mu %.0e, step x%g%s",
                it,
                E,
                hist[-1][1],
                dec,
                mu_prev if n_shift else 0.0,
                alpha,
                " (CG)" if step else "",
            )
        u[free] += alpha * du
    raise StepFailed(f"no convergence in {n_max} iterations", hist, u)


def _residual(
    problem: Problem,
    u: np.ndarray,
    free: np.ndarray,
    hist: list[tuple[float, float, float]],
    out: dict[str, Any] | None,
    it: int,
) -> tuple[float, np.ndarray, sp.csr_matrix]:
    """E, the free residual and the tangent at u (iteration ``it``)."""
    E, g, K = problem.evaluate(u, True)
    if out is not None:
        out["iterations"] = it
    r = g[free]
    if not (np.isfinite(E) and np.all(np.isfinite(r))):
        raise StepFailed("energy or residual not finite", hist)
    assert K is not None
    return E, r, K


def _krylov_step(
    lin: FreeBlockSolver, K: sp.csr_matrix, r: np.ndarray, ctl: StepControl
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
        if rz <= ctl.krylov_tol**2 * rz0:
            dec = -float(r @ x)
            return (x, dec) if dec > 0 else None
        p = z + (rz / rz_prev) * p
    return None


def _descent_direction(
    lin: FreeBlockSolver,
    K: sp.csr_matrix,
    r: np.ndarray,
    mu_prev: float,
    allow_shift: bool,
    hist: list[tuple[float, float, float]],
    E: float,
    out: dict[str, Any] | None,
) -> tuple[np.ndarray, float, float, int]:
    """The Newton step du = -K_ff^-1 r (K factorized in ``lin``), K_ff shifted by mu diag(K_ff) until it descends.

    The shift starts from a tenth of the last one that gave descent in this Newton run (1e-6 at
    first) and is raised tenfold until the step descends. Past a limit point the smallest such
    shift matters: along an unstable mode of eigenvalue -lambda the shifted step grows the mode by
    about lambda / mu per iteration, and a fixed mu = 1e-6 >> lambda crept for dozens of
    factorizations.

    Returns du, its decrement -r . du, the last shift tried and the number of shifted factorizations;
    ``out["K"] = K`` (when ``out`` is given).
    """
    if out is not None:
        out["K"] = K
    try:
        lin.factor(K)
        du = -lin.solve(r, symmetric_rhs=True)
        dec = -float(r @ du)
        mu = max(mu_prev / 10, 1e-10) if mu_prev else 1e-6
        if dec <= 0 and not allow_shift:
            hist.append((E, float(np.abs(r).max(initial=0.0)), dec))
            raise StepFailed("tangent not a descent direction (indefinite)", hist, indefinite=True)
        diag = None
        n_shift = 0
        while dec <= 0 and mu < 1e3:  # not a descent direction: K_ff indefinite here
            if diag is None:  # of the unshifted K_ff (lin.Kff holds the last shifted one)
                diag = np.abs(lin.diagonal())
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
        raise StepFailed(str(exc), hist) from None
    return du, dec, mu_prev, n_shift


def _check_contraction(hist: list[tuple[float, float, float]], it: int, E: float, u: np.ndarray) -> None:
    """Give up (the step will be cut) when Newton is not converging from the predictor."""
    dec = hist[-1][2]
    if it >= 2 and dec > 2 * abs(E):
        # the quadratic model predicts an energy drop (dec / 2) larger than the energy itself
        # (E >= 0 for the network): the iterate has left the region where Newton can converge
        raise StepFailed(f"Newton diverging (decrement {dec:.3g} > 2 |E| = {2 * abs(E):.3g})", hist, u)
    if it >= 3 and dec > hist[0][2]:
        # from a predictor the decrement falls, at first perhaps slowly: one above the
        # predictor's own, two iterations on, is Newton bouncing in a soft mode or leaving (in
        # the runs measured the one such step that still converged had snapped: cut anyway)
        raise StepFailed(f"Newton decrement rose above the predictor's ({hist[0][2]:.3g} -> {dec:.3g})", hist, u)
    if it >= 6 and dec > 0.5 * hist[-2][2]:
        # Newton converges quadratically near a solution or not at all: stop wasting factorizations
        raise StepFailed(f"Newton decrement not contracting ({hist[-2][2]:.3g} -> {dec:.3g})", hist, u)


def _line_search(
    problem: Problem,
    u: np.ndarray,
    free: np.ndarray,
    du: np.ndarray,
    E: float,
    dec: float,
    extend: bool,
    hist: list[tuple[float, float, float]],
) -> float:
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
        raise StepFailed("line search found no energy decrease", hist)
    if alpha == 1.0 and extend:
        # extend a shifted step while the energy falls along it (doubling, at most 2^12)
        for _ in range(12):
            v[free] = u[free] + 2 * alpha * du
            E2 = problem.evaluate(v, False)[0]
            if not (np.isfinite(E2) and E2 < Ev):
                break
            alpha, Ev = 2 * alpha, E2
    return alpha
