r"""Damped Newton for a saddle point at a fixed load, and what its failures say.

The solver knows nothing of fabrics (as NGSolve's ``nonlinearsolvers.py``): it talks to a
:class:`Problem` through numpy views of the state and residual, a factorization of the
linearization, and the load parameter λ that the Dirichlet data follow.

Newton step:      J(x) dx = −r(x)
Convergence:      |dx·r| ≤ rtol · E_ref + atol   (an energy, so the test is free of units;
                  E_ref is the energy after the predictor of the increment)
Damping:          natural monotonicity test (Deuflhard): with the simplified correction
                  dx̄ = −J(x)⁻¹ r(x + λ dx), accept λ when ‖dx̄‖ ≤ (1 − λ/4) ‖dx‖, else halve λ.
                  It is affine invariant and needs only one extra back-substitution, so it works
                  for saddle points (Lagrange multiplier) as for minimization.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..errors import Attempt
from .settings import NewtonSettings

__all__ = [
    "AdmissibleState",
    "Diagnosis",
    "JammingWatch",
    "Locating",
    "NewtonReport",
    "Problem",
    "Relaxable",
    "Settling",
    "State",
    "failure_pattern",
    "newton",
]


class Diagnosis(Protocol):
    """A structured diagnosis of a failure that can put itself in words."""

    def message(self) -> str:
        """The diagnosis for the error message."""


class State(Protocol):
    """The state side of a problem: the unknowns, the load they carry and how a correction is measured.

    All vectors are numpy arrays of full length, Dirichlet entries included. The continuum's is
    :class:`ngbet.continuum.problem.ContinuumProblem`.
    """

    x: np.ndarray  # the state, including Dirichlet entries

    @property
    def lam(self) -> float:
        """The load λ of the state (the clamp displacement [m])."""

    @property
    def dirichlet(self) -> np.ndarray:
        """The prescribed entries of ``x`` (a boolean mask)."""

    @property
    def weights(self) -> np.ndarray:
        """The weights that make a correction unit-free: :meth:`norm` is ‖weights · dx‖."""

    def set_load(self, lam: float) -> None:
        """Set the Dirichlet entries of ``x`` for load λ (free entries untouched)."""

    def clamp_predictor(self, dlam: float) -> np.ndarray:
        """A cheap load-following guess (for the problem to define)."""

    def norm(self, dx: np.ndarray) -> float:
        """A unit-free norm of a correction."""

    def converged(self) -> None:
        """The current x is an equilibrium the path keeps (the continuum's jamming barrier watches it)."""


class AdmissibleState(State, Protocol):
    """A state that can be outside the energy's domain (the continuum's inverted material)."""

    def admissible(self) -> str:
        """Why the current state is not a physical one ("" when it is)."""

    def begin_relaxation(self) -> None:
        """A relaxation starts from the current state (what is admissible is judged against it)."""

    @property
    def inadmissible_hint(self) -> str:
        """What keeps the problem out of its inadmissible states, for a message ("" if nothing)."""


class Problem(Protocol):
    """What the numerics drive: a :class:`State` bound to its residual, energy and linear algebra.

    As NGSolve's ``NewtonSolver(a, u, inverse=...)`` is bound to a form, a state and an inverse:
    the continuum's is :class:`ngbet.continuum.solver.ContinuumSolver` (a problem bound to its
    energy forms and linear solver). ``x`` is the state's vector (the same array as ``state.x``),
    which the residual and the linearization read. What only some problems can do is asked for by
    the capability protocols below and handed to the numerics explicitly (``hessian=``,
    ``watch=``, ``locate=``), never probed.
    """

    x: np.ndarray

    @property
    def state(self) -> State:
        """The state: load, Dirichlet entries, norm."""

    def residual(self) -> np.ndarray:
        """r(x), full length (Dirichlet rows hold the reactions)."""

    def energy(self) -> float:
        """Total energy (or Lagrangian) at x."""

    def factorize(self, shift: float = 0.0) -> float:
        """Linearize at x and factorize the free block (reusing the symbolic factorization).

        ``shift`` > 0: J + s|diag J| with s ≥ shift raised until positive definite where that can
        be tested; returns s (for :func:`ngbet.numerics.relax.relax`; 0 without a shift).
        """

    def solve(self, r: np.ndarray) -> np.ndarray:
        """Dx = −J⁻¹ r on the free entries, 0 on Dirichlet entries (last factorization)."""

    def load_tangent(self, dlam: float) -> np.ndarray:
        """Dx with Dirichlet entries moved by dlam and free entries from −J⁻¹ J_fd dlam."""

    def load_derivative(self, psi: np.ndarray, tangent: np.ndarray) -> float:
        """psi·(J tangent): the load derivative of the reaction psi·r along the tangent."""


class Relaxable(Problem, Protocol):
    """A problem whose Newton matrix is a Hessian: energy descent, a stability test, relaxation.

    What :func:`ngbet.numerics.relax.relax` and the chord rows (:mod:`ngbet.numerics.chord`, whose
    contraction is measured in the matrix's energy norm) need beyond :class:`Problem`.
    """

    @property
    def state(self) -> AdmissibleState:
        """The state, with what is admissible."""

    def lowest_mode(self) -> tuple[float, np.ndarray]:
        """The lowest eigenvalue of the scaled tangent at the current state and its mode (full length)."""

    def merit(self, r: np.ndarray) -> float:
        """A merit for descent at the state whose residual is ``r`` (infinite outside the energy's domain)."""


class JammingWatch(Protocol):
    """A problem with a barrier that is off until a converged state crosses it."""

    def jamming_missed(self) -> bool:
        """Whether the state just found lies past the barrier while it was off (it is on now: solve again)."""


class Settling(Protocol):
    """A problem that can drive its residual to zero on a few stiff unknowns, the rest held.

    The continuum's jamming barrier in contact (:class:`ngbet.continuum.patch.BarrierPatch`):
    Newton's full steps contract slowly there, and only there.
    """

    def settle(self, tol: float, r: np.ndarray) -> int:
        """Newton on those unknowns until their decrement is at most ``tol``; the iterations (0: x untouched).

        ``r``, the residual at the current x, is updated in place to the residual at the x settled.
        """


class Locating(Protocol):
    """A problem that can say where a change of state lives (a snap-through's place)."""

    def locate(self, dx: np.ndarray) -> dict[str, object]:
        """Where the change of state ``dx`` lives (fields for the summary)."""


@dataclass
class NewtonReport:
    """How a Newton run at fixed load ended."""

    converged: bool
    iterations: int
    history: list[float]  # Newton decrement |dx·r| per iteration
    damping: list[float]  # accepted damping factor per iteration
    reason: str = ""
    residual: np.ndarray | None = None  # r at the returned state (reactions come from it)
    #: ‖next correction‖ / ‖last correction‖ where measured (one-step estimates), else nan
    contraction: float = math.nan
    #: iterations of the local solves before the linearizations (``settle``; 0 without)
    settled: int = 0


def newton(
    problem: Problem,
    settings: NewtonSettings,
    e_ref: float,
    factorized: bool = False,
    r: np.ndarray | None = None,
    settle: Settling | None = None,
) -> NewtonReport:
    """Damped Newton from the current x at fixed load; on failure x is left where it stopped.

    ``factorized``: the problem's last factorization is that at the current x (the first iteration
    uses it); ``r``: the residual there, when at hand (not modified). ``settle``: before each new
    linearization the problem's stiff unknowns are solved with the rest held (nonlinear
    elimination, :class:`Settling`, to the tolerance of the test below); the test itself is
    unchanged, on the global decrement.
    """
    history: list[float] = []
    damping: list[float] = []
    r = problem.residual() if r is None else r.copy() if settle is not None else r  # settle updates it in place
    if not np.all(np.isfinite(r)):
        return NewtonReport(False, 0, history, damping, "residual is not finite at the start")
    tol = settings.rtol * abs(e_ref) + settings.atol
    theta_last = math.inf  # the contraction of the last full step
    settled = 0
    for it in range(1, settings.max_iterations + 1):
        reuse = it > 1 and theta_last <= settings.reuse_contraction
        if not reuse and (it > 1 or not factorized):
            settled += settle.settle(tol, r) if settle is not None else 0
            problem.factorize()
        tol_it = tol * (1.0 - theta_last) if reuse else tol  # a chord decrement (chord module)
        dx = problem.solve(r)
        delta = abs(float(dx @ r))
        history.append(delta)
        if not math.isfinite(delta):
            return NewtonReport(False, it, history, damping, "linear solve gave a non-finite correction")
        step = _damped_step(problem, dx, delta <= tol_it, settings.min_damping)
        if step is None:
            return NewtonReport(False, it, history, damping, "no damping factor reduced the residual")
        lam, r, dx_bar, theta = step
        damping.append(lam)
        if delta <= tol_it and lam == 1.0:
            return NewtonReport(True, it, history, damping, "converged", residual=r, settled=settled)
        theta_last = theta if lam == 1.0 and dx_bar is not None else math.inf
        if dx_bar is not None and lam == 1.0 and theta <= settings.simplified_theta:
            done = _simplified_exit(problem, dx_bar, r, tol_it)
            if done is not None:
                history.append(done[0])
                return NewtonReport(
                    True, it, history, damping, "converged (simplified correction)", residual=done[1], settled=settled
                )
    return NewtonReport(False, settings.max_iterations, history, damping, "iteration limit", settled=settled)


def _damped_step(
    problem: Problem, dx: np.ndarray, last: bool, min_damping: float
) -> tuple[float, np.ndarray, np.ndarray | None, float] | None:
    """X += λ dx with the largest λ = 1, 1/2, ... that passes the natural monotonicity test.

    ``last``: the decrement is below the tolerance, the step needs no test. Returns λ, the
    residual there, the simplified correction dx̄ and θ = ‖dx̄‖/‖dx‖ (None, 0 when not computed);
    None (x restored) when λ fell below ``min_damping``.
    """
    x0 = problem.x.copy()
    ndx = problem.state.norm(dx)
    lam = 1.0
    while True:
        problem.x[:] = x0 + lam * dx
        r_trial = problem.residual()
        if np.all(np.isfinite(r_trial)):
            if last:  # quadratic convergence: the last step needs no test
                return lam, r_trial, None, 0.0
            dx_bar = problem.solve(r_trial)
            theta = problem.state.norm(dx_bar) / ndx if ndx > 0 else 0.0
            if theta <= 1.0 - lam / 4.0:
                return lam, r_trial, dx_bar, theta
        lam *= 0.5
        if lam < min_damping:
            problem.x[:] = x0
            return None


def _simplified_exit(
    problem: Problem, dx_bar: np.ndarray, r: np.ndarray, tol: float
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
    text = (
        f"{len(tail)} of the last {min(12, len(attempts))} increments failed (last from "
        f"{attempts[-1].u0_from * 1e3:.6g} mm), the smallest {inc.min() * 1e3 if inc.size else 0:.3g} mm "
        f"({tail[-1].reason})"
    )
    ok = (inc > 0) & (first > 0) & np.isfinite(first)
    if ok.sum() >= 3 and np.ptp(np.log(inc[ok])) > 0.5:
        k = float(np.polyfit(np.log(inc[ok]), np.log(first[ok]), 1)[0])
        text += (
            f"; the first Newton decrement falls like (increment)^{k:.1f} when the increment is cut "
            f"(a smooth path gives ~4 with the tangent predictor)"
        )
        if k < 2.5:
            text += (
                ": the solution path is not smooth here (limit point or bifurcation in the load, or a "
                "locking discretization)"
            )
    return text
