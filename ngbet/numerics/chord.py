r"""Rows between the load steps: a chord (modified Newton) correction and the load tangent it leaves.

Where a run asks for results at closely spaced loads (``loading.output_every_mm``), each of them
is an equilibrium; Newton with a new linearization at each would cost an assembly and a
factorization per row. Between those the Jacobian changes little, so the factorization at hand
(that of the last Newton step) is reused, from a predictor that needs no linear solve:

Predictor:        the quartic through the last five converged states (:func:`extrapolate`), where
                  they are no closer together than half the step (else Newton's predictor).
Chord step:       dx_k = −J₀⁻¹ r(x_k),  J₀ the factorized matrix of an earlier state.
Contraction:      θ_k = (δ_k / δ_k−1)^½ with the decrements δ_k = |dx_k·r_k| = ‖dx_k‖²_J₀, the
                  contraction in the energy norm of J₀. Where θ_k > ``max_contraction`` and the
                  step does not already pass the test below (θ_k < 1), the
                  problem is linearized again at x_k (once) and the chord goes on; a run that still
                  does not contract fails, and Newton takes over from its own predictor. The
                  first step of a load may be judged by the contraction the same factorization
                  showed at the last load.
Convergence:      |dx_k·r_k| ≤ (1 − θ_k) · m · tol, tol = rtol · E_ref + atol as Newton's (m =
                  :data:`CHORD_MARGIN`); then
                  x += dx_k. With ‖J₀⁻¹J − I‖ ≤ θ the Newton decrement r·J⁻¹r is at most
                  |dx_k·r_k| / (1 − θ): the state passes Newton's own test, and the step
                  taken after it leaves an error θ times smaller still.

The load tangent at such a state, t = ∂x/∂λ (prescribed entries d, free ones from
J_ff t_f = −J_fd d), and the load derivative of the reaction dR/dλ = ψ·J t, are computed without
a new linearization: t₀ a guess (the extrapolation of the last two rows' tangents, else
d − J₀⁻¹ J₀ d from the factorization at hand; error e = t₀ − t, zero on the prescribed entries),
J t₀ by forward differences of the residual (the residual at the state is at hand), and

.. math::  dR/dλ = t₀·J t₀ − g·J₀⁻¹ g + O(‖J₀⁻¹J − I‖ ‖e‖²_J), \qquad g = (J t₀)_{free} = J_{ff} e,

because t·J t = ψ·J t (ψ = d on the prescribed entries, J t = 0 on the free ones) and
t₀·J t₀ = t·J t + e·J e with e·J e = g·J_ff⁻¹ g. The refined tangent t₀ − J₀⁻¹ g (one chord
step on the tangent's equation) is refined again until the correction term g·J₀⁻¹g is below
:data:`TANGENT_RTOL` of dR/dλ, else the problem is linearized anew. The accuracy of the rows and
of dR/dλ, and the measurements behind the constants below, are in docs/numerics.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import cast

import numpy as np

from .newton import NewtonReport, Problem, Settling
from .settings import NewtonSettings

__all__ = [
    "CHORD_CONTRACTION",
    "CHORD_ITERATIONS",
    "CHORD_MARGIN",
    "CHORD_PREDICTOR_STATES",
    "FD_STEP",
    "TANGENT_REFINEMENTS",
    "TANGENT_RTOL",
    "ChordRows",
    "chord",
    "extrapolate",
    "jacobian_times",
    "tangent_at_hand",
]

#: a chord correction contracting by more than this (energy norm) linearizes again, once; if it still
#: does, Newton takes over (the fewest factorizations at no more residuals)
CHORD_CONTRACTION = 0.2
#: the chord's predictor is the polynomial through this many last converged states (a quartic:
#: fewer states leave a larger first decrement, more refactorize more often; a cubic Hermite
#: predictor with the rows' tangents is worse, the tangents being accurate to TANGENT_RTOL only)
CHORD_PREDICTOR_STATES = 5
#: the chord's decrement must be below this fraction of Newton's tolerance: Newton's last step,
#: quadratic, leaves its rows far inside the tolerance, the chord's linear one does not
CHORD_MARGIN = 0.01
#: chord steps allowed for one load
CHORD_ITERATIONS = 6
#: the step of the differences J t ≈ (r(x + εt) − r(x)) / ε, relative to the problem's length scale
#: (the tangent moves the clamp by 1 per unit load): between the truncation error of a larger step
#: and the round-off of a smaller one
FD_STEP = 1e-8
#: the tangent is refined until the correction of dR/dλ is below this fraction of it
TANGENT_RTOL = 1e-3
#: refinements of the tangent at most
TANGENT_REFINEMENTS = 3


def chord(
    problem: Problem,
    settings: NewtonSettings,
    e_ref: float,
    max_iterations: int = CHORD_ITERATIONS,
    max_contraction: float = CHORD_CONTRACTION,
    refactorizations: int = 1,
    prior: float = math.nan,
    settle: Settling | None = None,
) -> NewtonReport:
    """Modified Newton from the current x with the factorization at hand (module docstring).

    Where a correction contracts by more than ``max_contraction`` the problem is linearized again
    at the current iterate (at most ``refactorizations`` times) and the iteration goes on with that
    factorization. ``prior``: the contraction this factorization showed at the last load, which
    the first step may be judged by (``report.contraction`` says which factorization it was:
    nan after a new one). ``settle``: before each step the problem's stiff unknowns are solved
    with the rest held (:class:`~ngbet.numerics.newton.Settling`, to the chord's own tolerance),
    so that the chord corrects the smooth rest. On failure x is left where it stopped (the caller
    restores it).
    """
    history: list[float] = []
    r = problem.residual()
    if not np.all(np.isfinite(r)):
        return NewtonReport(False, 0, history, [], "residual is not finite at the start")
    tol = settings.rtol * abs(e_ref) + settings.atol
    previous = math.nan  # the last decrement with the present factorization
    settled = 0
    for it in range(1, max_iterations + 1):
        settled += settle.settle(CHORD_MARGIN * tol, r) if settle is not None else 0
        dx = problem.solve(r)
        delta = abs(float(dx @ r))
        theta = math.sqrt(delta / previous) if previous > 0 else prior if it == 1 else math.nan
        done = delta == 0.0 or (theta < 1.0 and delta <= (1.0 - theta) * CHORD_MARGIN * tol)
        if not done and theta > max_contraction and refactorizations > 0:
            refactorizations -= 1
            problem.factorize()
            dx = problem.solve(r)
            delta, theta, prior = abs(float(dx @ r)), math.nan, math.nan
        history.append(delta)
        if not math.isfinite(delta) or (theta > max_contraction and not done):
            return NewtonReport(False, it, history, [], f"chord contraction {theta:.3g}", contraction=theta)
        problem.x[:] += dx
        r = problem.residual()
        if not np.all(np.isfinite(r)):
            return NewtonReport(False, it, history, [], "residual is not finite")
        if delta == 0.0 or (math.isfinite(theta) and delta <= (1.0 - theta) * CHORD_MARGIN * tol):
            measured = theta if it > 1 else prior
            return NewtonReport(
                True, it, history, [1.0] * it, "converged (chord)", residual=r, contraction=measured, settled=settled
            )
        previous = delta
    return NewtonReport(False, max_iterations, history, [], "chord iteration limit", settled=settled)


def extrapolate(states: list[tuple[float, np.ndarray]], lam: float) -> np.ndarray:
    """The polynomial through the converged ``states`` [(load, x), ...] at the load ``lam`` (Lagrange form)."""
    loads = [s[0] for s in states]
    out = np.zeros_like(states[0][1])
    for i, (li, xi) in enumerate(states):
        w = math.prod((lam - lj) / (li - lj) for j, lj in enumerate(loads) if j != i)
        out += w * xi
    return out


def jacobian_times(problem: Problem, v: np.ndarray, eps: float, r: np.ndarray | None = None) -> np.ndarray:
    """J(x) v by differences of the residual (full length): central, or forward from ``r`` = r(x); x is restored."""
    x0 = problem.x.copy()
    try:
        problem.x[:] = x0 + eps * v
        rp = problem.residual()
        if r is None:
            problem.x[:] = x0 - eps * v
            return cast(np.ndarray, (rp - problem.residual()) / (2.0 * eps))
    finally:
        problem.x[:] = x0
    return cast(np.ndarray, (rp - r) / eps)


def tangent_at_hand(
    problem: Problem,
    psi: np.ndarray | None,
    eps: float,
    r: np.ndarray | None = None,
    rel: float = TANGENT_RTOL,
    max_refinements: int = TANGENT_REFINEMENTS,
    start: np.ndarray | None = None,
) -> tuple[np.ndarray, float] | None:
    """The load tangent at the current (converged) state and dR/dλ (nan without ``psi``), without a linearization.

    From the factorization at hand, of an earlier state (module docstring), refined until the
    correction term of dR/dλ is below ``rel`` of it (its error is then a contraction factor
    smaller still): each refinement one residual (two without ``r``, the residual at the state)
    and one solve. None when ``max_refinements`` did not get there (the factorization is too far
    from the state: linearize anew). ``start``: a first guess of the tangent (its prescribed
    entries those of the load), else the factorization's own.
    """
    t = problem.load_tangent(1.0) if start is None else start
    prescribed = problem.state.dirichlet
    if psi is not None and not np.allclose(psi[prescribed], t[prescribed]):
        raise ValueError(
            "dR/dλ = t·J t needs the reaction's test vector equal to the load tangent on the prescribed entries"
        )
    for _ in range(max_refinements):
        Jt = jacobian_times(problem, t, eps, r)
        corr = problem.solve(Jt)  # −J₀⁻¹ (J t)_free, zero on the prescribed entries
        dR, term = float(t @ Jt + Jt @ corr), float(Jt @ corr)
        t = t + corr
        if abs(term) <= rel * abs(dR):
            return t, dR if psi is not None else math.nan
    return None


class ChordRows:
    """The rows of an output grid on a path: where the chord is tried, what it extrapolates from, counts.

    Parameters
    ----------
    loads : sequence of float
        The loads [m] corrected by the chord (the output grid).
    length : float
        The problem's length scale [m] (the difference step of the tangent, :data:`FD_STEP`).
    """

    def __init__(self, loads: Sequence[float], length: float = 1.0) -> None:
        self.loads = np.sort(np.asarray(loads, dtype=float))
        self.fd_step = FD_STEP * length
        #: the chord's contraction with the factorization at hand, at the last load (nan: a new one)
        self.contraction = math.nan
        self.states: list[tuple[float, np.ndarray]] = []  # the last converged loads and states
        self.tangents: list[tuple[float, np.ndarray]] = []  # the last two loads and tangents
        self.rows = 0
        self.handovers = 0

    def due(self, lam: float) -> bool:
        """Whether ``lam`` is one of the loads where the chord is tried."""
        return bool(self.loads.size) and bool(np.min(np.abs(self.loads - lam)) <= 1e-12 * max(1.0, abs(lam)))

    def predictor(self, x: np.ndarray, u0: float, h: float) -> np.ndarray | None:
        """The polynomial through the last states at u0 + h (``x``: the state at u0), or None.

        None unless the load is due and there are at least three states, ending at u0 and no
        closer together than half the step (a cut step's closely spaced states extrapolated far
        amplify their differences): then Newton's predictor.
        """
        if not self.loads.size:
            return None
        if not self.states and u0 == 0.0:  # the unloaded state is the first
            self.states = [(0.0, x.copy())]
        s = self.states
        if (
            not self.due(u0 + h)
            or len(s) < 3
            or abs(s[-1][0] - u0) > 1e-12 * max(1.0, abs(u0))
            or np.min(np.diff([st[0] for st in s])) < (0.5 - 1e-9) * h
        ):
            return None
        return extrapolate(s, u0 + h)

    def correct(
        self, problem: Problem, settings: NewtonSettings, e_ref: float, settle: Settling | None = None
    ) -> NewtonReport:
        """:func:`chord` from the predicted state, judged by the contraction at hand; counts a hand-over."""
        rep = chord(problem, settings, e_ref, prior=self.contraction, settle=settle)
        self.contraction = rep.contraction if rep.converged else math.nan
        if not rep.converged:
            self.handovers += 1
        return rep

    def refactorized(self) -> None:
        """The factorization at hand is new: no contraction is known for it."""
        self.contraction = math.nan

    def converged(self, lam: float, x: np.ndarray, tangent: tuple[float, np.ndarray] | None) -> None:
        """A converged state at ``lam``, and the tangent at the previous converged load (if known)."""
        if not self.loads.size:
            return
        self.states = [*self.states[1 - CHORD_PREDICTOR_STATES :], (lam, x.copy())]
        if tangent is not None:
            self.tangents = [*self.tangents[-1:], tangent]

    def forget(self) -> None:
        """A jump (snap-through): no extrapolation across it."""
        self.states, self.tangents = [], []

    def tangent(
        self, problem: Problem, psi: np.ndarray | None, lam: float, r: np.ndarray | None
    ) -> tuple[np.ndarray, float] | None:
        """:func:`tangent_at_hand` at a chord row at ``lam``, from the extrapolation of the last two tangents.

        The extrapolation is of the free entries only: the prescribed ones are the load's at every
        load and are copied from the last tangent. Extrapolated, their round-off would grow from row to
        row by the ratio of the steps (e_n+1 = e_n + a (e_n − e_n−1)) until the reaction's test vector
        no longer matched the tangent.
        """
        self.rows += 1
        start = None
        if len(self.tangents) == 2:
            start = extrapolate(self.tangents, lam)
            prescribed = problem.state.dirichlet
            start[prescribed] = self.tangents[-1][1][prescribed]
        return tangent_at_hand(problem, psi, self.fd_step, r, start=start)
