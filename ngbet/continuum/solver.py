r"""Damped Newton with adaptive load stepping, for any problem with the small interface below.

The solver knows nothing of fabrics (as NGSolve's ``nonlinearsolvers.py``): it talks to a
:class:`NonlinearProblem` through numpy views of the state and residual, a factorization of the
linearization, and the load parameter λ that the Dirichlet data follow.

Newton step:      J(x) dx = −r(x)
Convergence:      |dx·r| ≤ rtol · E_ref + atol   (an energy, so the test is free of units;
                  E_ref is the energy after the predictor of the increment)
Damping:          natural monotonicity test (Deuflhard): with the simplified correction
                  dx̄ = −J(x)⁻¹ r(x + λ dx), accept λ when ‖dx̄‖ ≤ (1 − λ/4) ‖dx‖, else halve λ.
                  It is affine invariant and needs only one extra back-substitution, so it works
                  for saddle points (Lagrange multiplier) as for minimization.
Predictor:        tangent (Euler): x += ∂x/∂λ Δλ from the last factorization, or the clamp one.
Stepping:         cut by ``cut`` on failure, grow by ``growth`` after easy increments, land on stops.

A load that cannot be reached raises :class:`ConvergenceError` carrying every attempt's residual
history and the last converged load; the caller has already saved each converged step.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

import numpy as np

from ..errors import ConvergenceError as _ConvergenceError

log = logging.getLogger(__name__)


class NonlinearProblem(Protocol):
    """What the solver needs from a problem. All vectors are numpy views of full length."""

    x: np.ndarray  # the state, including Dirichlet entries

    def set_load(self, lam: float) -> None:
        """Set the Dirichlet entries of ``x`` for load λ (free entries untouched)."""

    def residual(self) -> np.ndarray:
        """r(x), full length (Dirichlet rows hold the reactions)."""

    def energy(self) -> float:
        """Total energy (or Lagrangian) at x."""

    def factorize(self) -> None:
        """Linearize at x and factorize the free block (reusing the symbolic factorization)."""

    def solve(self, r: np.ndarray) -> np.ndarray:
        """dx = −J⁻¹ r on the free entries, 0 on Dirichlet entries (last factorization)."""

    def load_tangent(self, dlam: float) -> np.ndarray:
        """dx with Dirichlet entries moved by dlam and free entries from −J⁻¹ J_fd dlam."""

    def clamp_predictor(self, dlam: float) -> np.ndarray:
        """A cheap load-following guess (for the problem to define)."""

    def norm(self, dx: np.ndarray) -> float:
        """A unit-free norm of a correction."""


@dataclass(frozen=True)
class NewtonSettings:
    rtol: float = 1e-10
    atol: float = 1e-14
    max_iterations: int = 12
    min_damping: float = 1.0 / 64
    grow_after: int = 4
    growth: float = 1.5
    cut: float = 0.5
    predictor: str = "tangent"
    #: contraction θ = ‖dx̄‖/‖dx‖ below which a small simplified correction ends Newton without a
    #: new linearization (0 disables the shortcut)
    simplified_theta: float = 0.5


@dataclass
class NewtonReport:
    converged: bool
    iterations: int
    history: list[float]  # Newton decrement |dx·r| per iteration
    damping: list[float]  # accepted damping factor per iteration
    reason: str = ""
    residual: np.ndarray | None = None  # r at the returned state (reactions come from it)


@dataclass
class Attempt:
    lam_from: float
    lam_to: float
    report: NewtonReport


class ConvergenceError(_ConvergenceError):
    """The load could not be carried further (the continuum's attempts and diagnosis).

    Attributes
    ----------
    last_converged : float
        The last load reached (its step is already saved by the caller).
    attempts : list of Attempt
        Every tried increment with its residual history, oldest first.
    diagnosis : str
        What the solver concluded (e.g. a lost stability with the lowest eigenvalue).
    """

    def __init__(self, message: str, last_converged: float, attempts: Sequence[Attempt], diagnosis: str = ""):
        self.last_converged = last_converged
        self.last_converged_mm = last_converged * 1e3
        self.attempts = list(attempts)
        self.diagnosis = diagnosis
        tail = "\n".join(
            f"  {a.lam_from:.6g} -> {a.lam_to:.6g}: {'ok' if a.report.converged else 'FAILED'} after "
            f"{a.report.iterations} it ({a.report.reason}); decrements "
            + ", ".join(f"{h:.2e}" for h in a.report.history[:12])
            for a in self.attempts[-8:]
        )
        super().__init__(f"{message}\nlast converged load: {last_converged:.6g}"
                         + (f"\ndiagnosis: {diagnosis}" if diagnosis else "")
                         + f"\nlast attempts:\n{tail}")


def newton(problem: NonlinearProblem, settings: NewtonSettings, e_ref: float) -> NewtonReport:
    """Damped Newton from the current x at fixed load; on failure x is left where it stopped."""
    history: list[float] = []
    damping: list[float] = []
    r = problem.residual()
    if not np.all(np.isfinite(r)):
        return NewtonReport(False, 0, history, damping, "residual is not finite at the start")
    tol = settings.rtol * abs(e_ref) + settings.atol
    for it in range(1, settings.max_iterations + 1):
        problem.factorize()
        dx = problem.solve(r)
        delta = abs(float(dx @ r))
        history.append(delta)
        if not math.isfinite(delta):
            return NewtonReport(False, it, history, damping, "linear solve gave a non-finite correction")
        x0 = problem.x.copy()
        ndx = problem.norm(dx)
        lam = 1.0
        dx_bar = None
        theta = 0.0
        while True:
            problem.x[:] = x0 + lam * dx
            r_trial = problem.residual()
            if np.all(np.isfinite(r_trial)):
                if delta <= tol:  # quadratic convergence: the last step needs no test
                    break
                dx_bar = problem.solve(r_trial)
                theta = problem.norm(dx_bar) / ndx if ndx > 0 else 0.0
                if theta <= 1.0 - lam / 4.0:
                    break
            lam *= 0.5
            if lam < settings.min_damping:
                problem.x[:] = x0
                return NewtonReport(False, it, history, damping, "no damping factor reduced the residual")
        damping.append(lam)
        r = r_trial
        if delta <= tol and lam == 1.0:
            return NewtonReport(True, it, history, damping, "converged", residual=r)
        if dx_bar is not None and lam == 1.0 and theta <= settings.simplified_theta:
            # Simplified-Newton exit (Deuflhard's NLEQ-ERR): the correction dx̄ = −J(x_k)⁻¹ r(x_k+1),
            # already computed for the monotonicity test, is the next Newton correction up to
            # O(θ) relative; when its decrement is below the tolerance, x_k+1 + dx̄ is the solution
            # and the linearization that would only confirm it is saved (one per load step).
            delta_bar = abs(float(dx_bar @ r_trial))
            if delta_bar <= tol:
                problem.x[:] += dx_bar
                r = problem.residual()
                if np.all(np.isfinite(r)):
                    history.append(delta_bar)
                    return NewtonReport(True, it, history, damping, "converged (simplified correction)",
                                        residual=r)
                problem.x[:] -= dx_bar
                r = r_trial
    return NewtonReport(False, settings.max_iterations, history, damping, "iteration limit")


@dataclass
class StepInfo:
    """What the caller gets for each converged increment."""

    lam: float
    iterations: int
    wall_s: float
    report: NewtonReport


@dataclass
class ContinuationResult:
    lam: float
    steps: list[StepInfo] = field(default_factory=list)
    attempts: list[Attempt] = field(default_factory=list)
    cuts: int = 0


def continuation(
    problem: NonlinearProblem,
    target: float,
    first_step: float,
    settings: NewtonSettings,
    *,
    max_step: float = math.inf,
    min_step: float = 0.0,
    stops: Sequence[float] = (),
    on_step: Callable[[StepInfo], None] | None = None,
    diagnose: Callable[[], str] | None = None,
    max_attempts: int = 500,
) -> ContinuationResult:
    """Carry the load from 0 to ``target``; ``on_step`` is called after every converged increment.

    Raises
    ------
    ConvergenceError
        when the increment has been cut below ``min_step``, or after ``max_attempts`` increments
        (converged or not: a bound on the time), with the pattern of the last failures and what
        ``diagnose`` finds.
    """
    lam = 0.0
    step = min(first_step, max_step)
    marks = sorted({s for s in stops if 0 < s < target} | {target})
    out = ContinuationResult(lam)
    have_tangent = False
    eps = 1e-12 * max(1.0, abs(target))
    while lam < target - eps:
        nxt = min(lam + step, next(m for m in marks if m > lam + eps))
        if nxt > lam + step + eps:  # pragma: no cover - defensive
            nxt = lam + step
        # land on a mark instead of stopping just short of it
        upcoming = next(m for m in marks if m > lam + eps)
        if upcoming - nxt < 0.2 * step:
            nxt = upcoming
        t0 = time.perf_counter()
        saved = problem.x.copy()
        if settings.predictor == "tangent":
            if not have_tangent:
                problem.factorize()
                have_tangent = True
            problem.x[:] += problem.load_tangent(nxt - lam)
        else:
            problem.x[:] += problem.clamp_predictor(nxt - lam)
        problem.set_load(nxt)
        e_ref = problem.energy()
        report = newton(problem, settings, e_ref if math.isfinite(e_ref) else 0.0)
        out.attempts.append(Attempt(lam, nxt, report))
        if report.converged:
            lam = nxt
            info = StepInfo(lam, report.iterations, time.perf_counter() - t0, report)
            out.steps.append(info)
            out.lam = lam
            log.info("load %.6g reached in %d Newton iterations", lam, report.iterations)
            if on_step is not None:
                on_step(info)
            if report.iterations <= settings.grow_after:
                step = min(step * settings.growth, max_step)
            continue
        problem.x[:] = saved
        problem.set_load(lam)
        out.cuts += 1
        log.warning("increment %.6g -> %.6g failed (%s); cutting the step", lam, nxt, report.reason)
        step = (nxt - lam) * settings.cut
        # the factorization now belongs to a rejected state: rebuild it at the restored one
        if settings.predictor == "tangent":
            problem.factorize()
        if step < min_step or len(out.attempts) >= max_attempts:
            diag = "; ".join(d for d in (failure_pattern(out.attempts), diagnose() if diagnose else "") if d)
            why = (f"load step cut below the minimum {min_step:.3g}" if step < min_step
                   else f"{len(out.attempts)} increments tried (limit {max_attempts})")
            raise ConvergenceError(f"{why} on the way from {lam:.6g} to {target:.6g}", lam, out.attempts, diag)
    return out


def failure_pattern(attempts: Sequence[Attempt]) -> str:
    """What the last failed increments say (near the last converged load).

    With a tangent predictor the residual after the predictor is O(Δλ²) on a smooth solution path,
    so the first Newton decrement (an energy) falls like Δλ⁴ when the increment is cut. If it falls
    much slower, or Newton fails however small the increment, the path is not smooth there: it turns
    back in the load (limit point), branches (bifurcation) or the discrete problem locks.
    """
    if not attempts or attempts[-1].report.converged:
        return ""
    lam0 = attempts[-1].lam_from
    tail = [a for a in attempts[-12:] if not a.report.converged]
    inc = np.array([a.lam_to - a.lam_from for a in tail if a.report.history])
    first = np.array([a.report.history[0] for a in tail if a.report.history])
    text = (f"{len(tail)} of the last {min(12, len(attempts))} increments failed (last from load {lam0:.6g}), the smallest {inc.min() if inc.size else 0:.3g} "
            f"({tail[-1].report.reason})")
    ok = (inc > 0) & (first > 0) & np.isfinite(first)
    if ok.sum() >= 3 and np.ptp(np.log(inc[ok])) > 0.5:
        k = float(np.polyfit(np.log(inc[ok]), np.log(first[ok]), 1)[0])
        text += (f"; the first Newton decrement falls like (increment)^{k:.1f} when the increment is cut "
                 f"(a smooth path gives ~4 with the tangent predictor)")
        if k < 2.5:
            text += (": the solution path is not smooth here (limit point or bifurcation in the load, or a "
                     "locking discretization)")
    return text
