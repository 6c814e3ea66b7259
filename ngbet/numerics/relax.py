r"""Relaxation at a fixed clamp displacement: a stable equilibrium where Newton failed on a short increment.

:func:`relax` runs pseudo-transient continuation from the predicted state, kicked along the lowest
mode of the tangent if that is unstable: shifted Newton steps (J + s |diag J|) dx = −r, s raised
until the matrix is positive definite, with a line search on the problem's merit (infinite outside
the energy's domain: inverted material). The state found is accepted only if it is admissible and
the tangent positive definite there. Called by :class:`ngbet.numerics.path.SaddlePointNewton`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .engine import past_deadline
from .newton import Relaxable, newton
from .settings import NewtonSettings

__all__ = ["RelaxReport", "RelaxSettings", "relax"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class RelaxSettings:
    """Pseudo-transient continuation to a stable equilibrium at a fixed load (:func:`relax`)."""

    max_iterations: int = 500  #: factorizations allowed for one relaxation
    #: the first shift s (of |diag J|), and at least twice the lowest scaled eigenvalue's modulus
    first_shift: float = 1e-6
    min_shift: float = 1e-12  #: the smallest shift
    #: a decrement below the tolerance ends the shifted steps only with a shift at most this
    #: (a larger one hides soft directions that Newton would still move along)
    newton_shift: float = 1e-8
    max_shift: float = 1e3  #: the largest shift before giving up
    #: the kick along an unstable mode: its largest weighted entry (u/L, phi)
    kick: float = 1e-3
    min_step: float = 1.0 / 1024  #: the shortest step of the line search
    kicks: int = 3  #: tries with a larger kick when the equilibrium found is unstable


@dataclass
class RelaxReport:
    """How a relaxation ended."""

    converged: bool
    iterations: int
    history: list[float]
    reason: str
    residual: np.ndarray | None = None
    lowest_eigenvalue: float = math.nan  # at the state found (scaled tangent)
    kicked_from: float = math.nan  # the lowest eigenvalue at the start when it was kicked along its mode


def relax(
    problem: Relaxable,
    newton_settings: NewtonSettings,
    e_ref: float,
    settings: RelaxSettings = RelaxSettings(),
    start_eigen: tuple[float, np.ndarray] | None = None,
) -> RelaxReport:
    """A stable equilibrium at the current load from the current state, by a shifted descent.

    ``problem`` has a Hessian tangent (:class:`~ngbet.numerics.newton.Relaxable`): shifted
    factorizations, its lowest mode, a merit and what is admissible. The state is first moved
    along the lowest mode when that eigenvalue is not positive (the sign that lowers the energy
    to first order). Then :func:`_flow`: shifted Newton steps (J + s|diag J|) dx = −r with s at
    least what makes the matrix positive definite and a line search on the merit, s falling as
    full steps are taken (a pseudo-transient continuation that becomes Newton as it settles).
    Newton (:func:`newton`) finishes; the state is accepted if admissible and the tangent's
    lowest eigenvalue is positive; an unstable one is kicked along its mode (twice as far each
    time) and the descent goes on. On failure x is left where it stopped.
    """
    history: list[float] = []
    tol = newton_settings.rtol * abs(e_ref) + newton_settings.atol
    weights = problem.state.weights
    problem.state.begin_relaxation()  # what the problem counts as admissible is judged against the start
    mu, mode = start_eigen if start_eigen is not None else problem.lowest_mode()
    kicked = math.nan
    its = 0
    for attempt in range(settings.kicks + 1):
        if mu <= 0:
            kicked = mu if math.isnan(kicked) else kicked
            _kick(problem, mode, weights, settings.kick * 2**attempt)
        shift = max(settings.first_shift, -2.0 * mu)
        done, its, why = _flow(problem, tol, settings, shift, history, its)
        if not done:
            return RelaxReport(False, its, history, why, kicked_from=kicked)
        rep = newton(problem, newton_settings, e_ref)
        its += rep.iterations
        history.extend(rep.history)
        bad = problem.state.admissible() if rep.converged else ""
        if bad:
            return RelaxReport(False, its, history, f"the equilibrium found is not physical: {bad}", kicked_from=kicked)
        mu, mode = problem.lowest_mode()
        if rep.converged and mu > 0:
            return RelaxReport(True, its, history, "relaxed to a stable equilibrium", rep.residual, mu, kicked)
        why = (
            f"the equilibria found are unstable (lowest scaled eigenvalue {mu:.3g})"
            if rep.converged
            else f"Newton after the relaxation: {rep.reason}"
        )
    return RelaxReport(False, its, history, why, lowest_eigenvalue=mu, kicked_from=kicked)


def _kick(problem: Relaxable, mode: np.ndarray, weights: np.ndarray, size: float) -> None:
    """X += a mode, its largest weighted entry ``size``, the sign lowering the energy to first order."""
    big = float(np.max(np.abs(weights * mode)))
    if big <= 0:
        return
    a = size / big
    r = problem.residual()
    if np.isfinite(r).all() and float(r @ mode) > 0:
        a = -a
    problem.x[:] += a * mode


def _flow(
    problem: Relaxable, tol: float, settings: RelaxSettings, shift: float, history: list[float], its: int
) -> tuple[bool, int, str]:
    """Shifted Newton steps with a line search on the merit until the decrement is small (True).

    Each step solves (J + s|diag J|) dx = −r with s at least what makes the matrix positive
    definite (``problem.factorize(shift)``), then halves the step until the merit (``problem.merit``,
    the energy with the constraint's violation penalized; the energy without it) falls by at
    least 1e-4 of the decrement; a full step lowers s by 4, a shortened one doubles it, no
    descent at all raises it tenfold.
    """
    merit = problem.merit
    r = problem.residual()
    E = merit(r)
    if not (np.all(np.isfinite(r)) and math.isfinite(E)):
        return False, its, "the relaxation starts outside the energy's domain (or with a non-finite residual)"
    barrier = False  # a trial step left the energy's domain (e.g. inverted material)
    while its < settings.max_iterations:
        if past_deadline():  # a relaxation may take hundreds of factorizations: the budget bounds it too
            return False, its, "the time budget was spent in the relaxation"
        its += 1
        shift = problem.factorize(shift)
        dx = problem.solve(r)
        delta = abs(float(dx @ r))
        if not math.isfinite(delta):
            return False, its, "the relaxation gave a non-finite correction"
        history.append(delta)
        if delta <= tol:
            if shift <= settings.newton_shift:
                return True, its, ""
            shift = max(shift / 100.0, settings.min_shift)  # small only because shifted: go on towards Newton
            continue
        x0 = problem.x.copy()
        t = 1.0
        while t >= settings.min_step:
            problem.x[:] = x0 + t * dx
            r_new = problem.residual()
            E_new = merit(r_new)
            barrier = barrier or E_new == math.inf
            if np.all(np.isfinite(r_new)) and E_new <= E - 1e-4 * t * delta:
                break
            t *= 0.5
        else:
            problem.x[:] = x0
            shift = max(10.0 * shift, 1e-6)
            if shift > settings.max_shift:
                return (
                    False,
                    its,
                    (
                        "the descent ends where the material would turn inside out (det F <= 0): no "
                        "physical stable state was found at this clamp displacement" + _hint(problem)
                        if barrier
                        else "no descent direction found in the relaxation"
                    ),
                )
            continue
        log.debug("relaxation %d: shift %.3g, step %.3g, decrement %.3g, energy %.12g", its, shift, t, delta, E_new)
        r, E = r_new, E_new
        shift = shift / 4.0 if t == 1.0 else 2.0 * shift
        if shift < settings.min_shift:
            shift = settings.min_shift
    if barrier:
        return (
            False,
            its,
            (
                f"no physical stable state was found within {settings.max_iterations} relaxation "
                "iterations: the descent kept meeting states where the material would turn inside "
                "out (det F <= 0)" + _hint(problem)
            ),
        )
    return False, its, f"no equilibrium within {settings.max_iterations} relaxation iterations"


def _hint(problem: Relaxable) -> str:
    """The problem's advice for a relaxation that meets its inadmissible states ("; ..." or "")."""
    return f"; {hint}" if (hint := problem.state.inadmissible_hint) else ""
