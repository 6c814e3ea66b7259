r"""The continuum's corrector: damped Newton for a saddle point, on the engine's load stepping.

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
Stepping:         :func:`ngbet.engine.follow_path`: cut by ``cut`` on failure, grow by ``growth``
                  after easy increments, land on stops (:func:`continuation` puts it together).

A load that cannot be reached raises :class:`ngbet.errors.ConvergenceError` carrying every
attempt's decrements, the last converged load [mm] and the diagnosis; the caller has already
saved each converged step.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..engine import Outcome, PathControl, PathResult, StepRecord, follow_path
from ..errors import Attempt, ConvergenceError

log = logging.getLogger(__name__)


class Diagnosis(Protocol):
    """A structured diagnosis of a failure that can put itself in words."""

    def message(self) -> str:
        """The diagnosis for the error message."""


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
        """Dx = −J⁻¹ r on the free entries, 0 on Dirichlet entries (last factorization)."""

    def load_tangent(self, dlam: float) -> np.ndarray:
        """Dx with Dirichlet entries moved by dlam and free entries from −J⁻¹ J_fd dlam."""

    def clamp_predictor(self, dlam: float) -> np.ndarray:
        """A cheap load-following guess (for the problem to define)."""

    def norm(self, dx: np.ndarray) -> float:
        """A unit-free norm of a correction."""

    def load_derivative(self, psi: np.ndarray, tangent: np.ndarray) -> float:
        """psi·(J tangent): the load derivative of the reaction psi·r along the tangent."""


@dataclass(frozen=True)
class NewtonSettings:
    """Tolerances, damping and step control of the continuum's Newton (from ``scene.solver``)."""

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
    """How a Newton run at fixed load ended."""

    converged: bool
    iterations: int
    history: list[float]  # Newton decrement |dx·r| per iteration
    damping: list[float]  # accepted damping factor per iteration
    reason: str = ""
    residual: np.ndarray | None = None  # r at the returned state (reactions come from it)


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
        step = _damped_step(problem, dx, delta <= tol, settings.min_damping)
        if step is None:
            return NewtonReport(False, it, history, damping, "no damping factor reduced the residual")
        lam, r, dx_bar, theta = step
        damping.append(lam)
        if delta <= tol and lam == 1.0:
            return NewtonReport(True, it, history, damping, "converged", residual=r)
        if dx_bar is not None and lam == 1.0 and theta <= settings.simplified_theta:
            done = _simplified_exit(problem, dx_bar, r, tol)
            if done is not None:
                history.append(done[0])
                return NewtonReport(True, it, history, damping, "converged (simplified correction)",
                                    residual=done[1])
    return NewtonReport(False, settings.max_iterations, history, damping, "iteration limit")


def _damped_step(problem: NonlinearProblem, dx: np.ndarray, last: bool, min_damping: float
                 ) -> tuple[float, np.ndarray, np.ndarray | None, float] | None:
    """X += λ dx with the largest λ = 1, 1/2, ... that passes the natural monotonicity test.

    ``last``: the decrement is below the tolerance, the step needs no test. Returns λ, the
    residual there, the simplified correction dx̄ and θ = ‖dx̄‖/‖dx‖ (None, 0 when not computed);
    None (x restored) when λ fell below ``min_damping``.
    """
    x0 = problem.x.copy()
    ndx = problem.norm(dx)
    lam = 1.0
    while True:
        problem.x[:] = x0 + lam * dx
        r_trial = problem.residual()
        if np.all(np.isfinite(r_trial)):
            if last:  # quadratic convergence: the last step needs no test
                return lam, r_trial, None, 0.0
            dx_bar = problem.solve(r_trial)
            theta = problem.norm(dx_bar) / ndx if ndx > 0 else 0.0
            if theta <= 1.0 - lam / 4.0:
                return lam, r_trial, dx_bar, theta
        lam *= 0.5
        if lam < min_damping:
            problem.x[:] = x0
            return None


def _simplified_exit(problem: NonlinearProblem, dx_bar: np.ndarray, r: np.ndarray, tol: float
                     ) -> tuple[float, np.ndarray] | None:
    """End Newton with the simplified correction when its decrement is below the tolerance.

    Deuflhard's NLEQ-ERR: the correction dx̄ = −J(x_k)⁻¹ r(x_k+1), already computed for the
    monotonicity test, is the next Newton correction up to O(θ) relative; when its decrement is
    below the tolerance, x_k+1 + dx̄ is the solution and the linearization that would only confirm
    it is saved (one per load step). Returns the decrement and the residual, or None (x unchanged).
    """
    delta_bar = abs(float(dx_bar @ r))
    if delta_bar > tol:
        return None
    problem.x[:] += dx_bar
    r_new = problem.residual()
    if np.all(np.isfinite(r_new)):
        return delta_bar, r_new
    problem.x[:] -= dx_bar
    return None


class SaddlePointNewton:
    """The continuum's corrector for :func:`ngbet.engine.follow_path`.

    A tangent (or clamp) predictor and the damped Newton :func:`newton` on a
    :class:`NonlinearProblem`.

    The load tangent ∂x/∂λ comes from the factorization at hand (that of the last Newton
    iteration of the accepted step, or a fresh one after a rejected trial); it is computed when a
    step is accepted, so that the step record carries dR/du0 = ψ·(J ∂x/∂λ) at no extra solve
    when ``psi`` (the reaction's test vector) is given, and the next predictor reuses it.
    """

    def __init__(self, problem: NonlinearProblem, settings: NewtonSettings,
                 diagnose: Callable[[], Diagnosis] | None = None, psi: np.ndarray | None = None) -> None:
        self.problem = problem
        self.settings = settings
        self._diagnose = diagnose
        self._psi = psi
        self._tangent: np.ndarray | None = None  # ∂x/∂λ at the converged state
        self._factorized = False
        self._saved = problem.x.copy()
        self.report: NewtonReport | None = None  # of the last correction

    def predict(self, u0: float, h: float) -> None:
        """X += ∂x/∂λ h (tangent) or the clamp's linear field."""
        p = self.problem
        self._saved = p.x.copy()
        if self.settings.predictor == "tangent":
            p.x[:] += h * self._load_tangent()
        else:
            p.x[:] += p.clamp_predictor(h)

    def _load_tangent(self) -> np.ndarray:
        if self._tangent is None:
            if not self._factorized:
                self.problem.factorize()
                self._factorized = True
            self._tangent = self.problem.load_tangent(1.0)
        return self._tangent

    def correct(self, u0: float, h: float) -> Outcome:
        """Newton at the load u0 + h from the predicted state."""
        p = self.problem
        p.set_load(u0 + h)
        e_ref = p.energy()
        self.report = rep = newton(p, self.settings, e_ref if math.isfinite(e_ref) else 0.0)
        return Outcome("converged" if rep.converged else "failed", rep.iterations, list(rep.history), rep.reason)

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        """The state is converged: its residual, and the load tangent for dR/du0 and the next predictor."""
        assert self.report is not None
        self._factorized = True  # Newton factorized at its iterates
        self._tangent = None
        rec = StepRecord(0, u0 + h, outcome.iterations, residual=self.report.residual,
                         history=list(outcome.history), reason=outcome.reason)
        if self.settings.predictor == "tangent" and self._psi is not None:
            rec.dforce_du0 = self.problem.load_derivative(self._psi, self._load_tangent())
        return rec

    def reject(self, u0: float, outcome: Outcome) -> None:
        """Back to the converged state; the factorization now belongs to a rejected state: rebuild it."""
        p = self.problem
        p.x[:] = self._saved
        p.set_load(u0)
        self._tangent = None
        if self.settings.predictor == "tangent":
            p.factorize()
            self._factorized = True

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        """The failure pattern of the last attempts and the problem's own diagnosis (text and object)."""
        detail = self._diagnose() if self._diagnose is not None else None
        texts = (failure_pattern(attempts), detail.message() if detail is not None else "")
        return "; ".join(t for t in texts if t), detail


def continuation(
    problem: NonlinearProblem,
    target: float,
    first_step: float,
    settings: NewtonSettings,
    *,
    max_step: float = math.inf,
    min_step: float = 0.0,
    stops: Sequence[float] = (),
    on_step: Callable[[StepRecord], None] | None = None,
    diagnose: Callable[[], Diagnosis] | None = None,
    max_attempts: int = 500,
    psi: np.ndarray | None = None,
    progress: Callable[[float], None] | None = None,
    path_following: str = "displacement",
    arclength: Callable[[PathResult], PathResult] | None = None,
) -> PathResult:
    """Carry the load from 0 to ``target`` with :class:`SaddlePointNewton` on the engine.

    A stop within a fifth of a step beyond a trial load is landed on. ``on_step`` is called after
    every converged increment.

    Raises
    ------
    ngbet.errors.ConvergenceError
        when the increment has been cut below ``min_step``, or after ``max_attempts`` increments
        (converged or not: a bound on the time), with the pattern of the last failures and what
        ``diagnose`` finds.

    ``path_following`` (``solver.path_following``): "displacement" control alone; "arclength":
    ``arclength(result)`` follows the path from the start; "auto": displacement control, and
    where it fails, ``arclength(result)`` goes on from the last converged state (the steps are
    appended to the same result).
    """
    if path_following == "arclength" and arclength is not None:
        return arclength(PathResult(0.0))
    ctl = PathControl(target=target, first_step=first_step, max_step=max_step, min_step=min_step,
                      growth=settings.growth, cut=settings.cut, grow_after=settings.grow_after,
                      stops=tuple(stops), land_within=0.2, max_attempts=max_attempts)
    if path_following != "auto" or arclength is None:
        corrector = SaddlePointNewton(problem, settings, diagnose, psi)
        return follow_path(corrector, ctl, on_step=on_step, progress=progress)
    # under "auto" a failure hands over to arc length, which reports the path's instabilities
    # itself: no diagnosis (an eigen-solve) at the hand-over
    corrector = SaddlePointNewton(problem, settings, None, psi)
    partial = PathResult(0.0)

    def keep(rec: StepRecord) -> None:
        partial.steps.append(rec)
        if on_step is not None:
            on_step(rec)

    try:
        return follow_path(corrector, ctl, on_step=keep, progress=progress)
    except ConvergenceError as err:
        log.warning("displacement control stops at %.6g mm; following the path by arc length", err.last_converged_mm)
        partial.u0 = err.last_converged_mm * 1e-3
        partial.attempts = list(err.attempts)
        partial.cuts = sum(not a.converged for a in err.attempts)
        return arclength(partial)


def failure_pattern(attempts: Sequence[Attempt]) -> str:
    """What the last failed increments say (near the last converged load).

    With a tangent predictor the residual after the predictor is O(Δλ²) on a smooth solution path,
    so the first Newton decrement (an energy) falls like Δλ⁴ when the increment is cut. If it falls
    much slower, or Newton fails however small the increment, the path is not smooth there: it turns
    back in the load (limit point), branches (bifurcation) or the discrete problem locks.
    """
    if not attempts or attempts[-1].converged:
        return ""
    tail = [a for a in attempts[-12:] if not a.converged]
    inc = np.array([a.u0_to - a.u0_from for a in tail if a.history])
    first = np.array([a.history[0] for a in tail if a.history])
    text = (f"{len(tail)} of the last {min(12, len(attempts))} increments failed (last from "
            f"{attempts[-1].u0_from * 1e3:.6g} mm), the smallest {inc.min() * 1e3 if inc.size else 0:.3g} mm "
            f"({tail[-1].reason})")
    ok = (inc > 0) & (first > 0) & np.isfinite(first)
    if ok.sum() >= 3 and np.ptp(np.log(inc[ok])) > 0.5:
        k = float(np.polyfit(np.log(inc[ok]), np.log(first[ok]), 1)[0])
        text += (f"; the first Newton decrement falls like (increment)^{k:.1f} when the increment is cut "
                 f"(a smooth path gives ~4 with the tangent predictor)")
        if k < 2.5:
            text += (": the solution path is not smooth here (limit point or bifurcation in the load, or a "
                     "locking discretization)")
    return text
