r"""The saddle-point corrector on the engine's load stepping: predictor, Newton, chord rows, relaxation.

The solver knows nothing of fabrics (as NGSolve's ``nonlinearsolvers.py``): it talks to a
:class:`~ngbet.numerics.newton.Problem` through numpy views of the state and residual,
a factorization of the linearization, and the load parameter λ that the Dirichlet data follow.
Newton at a fixed load is :mod:`ngbet.numerics.newton`; the rows of an output grid between the
load steps are corrected by :mod:`ngbet.numerics.chord`.

Predictor:        tangent (Euler): x += ∂x/∂λ Δλ from the last factorization, or the clamp one;
                  at the loads of an output grid (``chord_at``) the polynomial through the last
                  converged states (:func:`ngbet.numerics.chord.extrapolate`).
Stepping:         :func:`ngbet.numerics.engine.path_steps`: cut by ``cut`` on failure, grow by ``growth``
                  after easy increments, land on stops (:func:`load_steps` puts it together, with
                  the settings of :mod:`ngbet.numerics.settings`: a generator of step records
                  that the runner iterates).

Snap-through:     under displacement control, when an increment no longer than ``relax_below``
                  fails (the path folds or branches: past the fold there is no equilibrium
                  near the predicted state), :func:`ngbet.numerics.relax.relax` looks for a stable equilibrium at
                  the same clamp displacement by pseudo-transient continuation from the predicted
                  state, kicked along the lowest mode of the tangent if that is unstable: shifted
                  Newton steps (J + s |diag J|) dx = −r, s raised until the matrix is positive
                  definite, with a line search on the problem's merit (infinite outside the energy's
                  domain: inverted material). The state found is accepted only if it is admissible
                  and the tangent positive definite there; if the step released energy beyond the
                  clamp's work, it is a snap-through (load, energy released, force before and after,
                  where the jump lives); the branch left rides on the step's record (``left``).

A load that cannot be reached raises :class:`ngbet.errors.ConvergenceError` carrying every
attempt's decrements, the last converged load [mm] and the diagnosis; each converged step has
been yielded to the caller by then.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Generator, Sequence

import numpy as np

from ..errors import Attempt, ConvergenceError
from .chord import ChordRows, tangent_at_hand
from .engine import Outcome, PathResult, StepRecord, path_steps
from .newton import (
    Diagnosis,
    JammingWatch,
    Locating,
    NewtonReport,
    Problem,
    Relaxable,
    Settling,
    failure_pattern,
    newton,
)
from .relax import RelaxSettings, relax
from .settings import NewtonSettings, PathSettings

__all__ = ["JAMMING_MISSED", "RELAX_DEFAULTS", "SNAP_RELEASE", "ArcLength", "SaddlePointNewton", "load_steps"]

log = logging.getLogger(__name__)


#: a relaxed step that releases more than this fraction of the clamp's work in it is a snap-through
#: (the network's threshold with the work by a rule that has the tangents: ``snap_release_hermite``)
SNAP_RELEASE = 1e-3
#: the relaxation's settings unless a caller gives others
RELAX_DEFAULTS = RelaxSettings()
#: why an increment whose state lies past the jamming angle, solved with the barrier off, is solved again
JAMMING_MISSED = "the yarns close past the jamming angle in the state found without the barrier; solved again with it"


def _stalled(rep: NewtonReport) -> bool:
    """Whether a failed Newton run stalled (no damping helped, or the decrement stopped falling).

    A run that only ran out of iterations while its decrement kept falling was converging: a
    shorter step, not a relaxation, is the answer (and ``solver.max_iterations`` stays the user's bound).
    """
    if rep.reason != "iteration limit":
        return True
    h = rep.history
    return len(h) >= 2 and h[-1] >= h[-2]


class SaddlePointNewton:
    """The saddle-point corrector for :func:`ngbet.numerics.engine.path_steps`.

    A tangent (or clamp) predictor and the damped Newton :func:`newton` on a :class:`Problem`.
    The capabilities are explicit: ``hessian`` (the problem again, when its Newton matrix is a
    Hessian) relaxes a short increment that fails (``relax_below`` > 0), ``watch`` is asked after
    each converged correction whether a barrier was missed, ``locate`` says where a snap-through lives,
    ``settle`` solves the problem's stiff unknowns before each linearization (:func:`newton`).

    The load tangent ∂x/∂λ comes from the factorization at hand (that of the last Newton
    iteration of the accepted step, or a fresh one after a rejected trial); it is computed when a
    step is accepted, so that the step record carries dR/du0 = ψ·(J ∂x/∂λ) at no extra solve
    when ``psi`` (the reaction's test vector) is given, and the next predictor reuses it.
    """

    def __init__(
        self,
        problem: Problem,
        settings: NewtonSettings,
        *,
        diagnose: Callable[[], Diagnosis] | None = None,
        psi: np.ndarray | None = None,
        hessian: Relaxable | None = None,
        watch: JammingWatch | None = None,
        locate: Locating | None = None,
        settle: Settling | None = None,
        relax_below: float = 0.0,
        relax_settings: RelaxSettings = RELAX_DEFAULTS,
        chord_at: Sequence[float] = (),
        length: float = 1.0,
        on_relax: Callable[[float, np.ndarray, bool], None] | None = None,
    ) -> None:
        if relax_below > 0 and hessian is None:
            raise ValueError("relax_below > 0 needs hessian (a problem whose Newton matrix is a Hessian)")
        self.problem, self.hessian, self.watch, self.locate = problem, hessian, watch, locate
        self.settle = settle
        self.on_relax = on_relax  # told of each relaxation: (load [m], the branch left, snap?)
        self._left: tuple[float, np.ndarray, bool] | None = None
        #: the loads where a chord correction with the factorization at hand is tried first
        #: (:mod:`ngbet.numerics.chord`); ``length`` scales its difference step
        self.chord = ChordRows(chord_at, length)
        self._chorded = False
        self.settings, self._diagnose, self._psi = settings, diagnose, psi
        #: an increment shorter than this that fails is relaxed to a stable state (0: never)
        self.relax_below, self.relax_settings = relax_below, relax_settings
        #: the snap-throughs met, as the summary records them
        self.snaps: list[dict[str, object]] = []
        self.relaxations = 0
        self._predicted: np.ndarray | None = None
        self._jump: dict[str, object] | None = None  # the snap of the trial being corrected
        self._tangent: np.ndarray | None = None  # ∂x/∂λ at the converged state
        self._factorized = False
        self._saved = problem.x.copy()
        self.report: NewtonReport | None = None  # of the last correction

    def predict(self, u0: float, h: float) -> None:
        """X += ∂x/∂λ h (tangent) or the clamp's linear field; at a chord row the polynomial through the last states."""
        p = self.problem
        self._saved = p.x.copy()
        guess = self.chord.predictor(p.x, u0, h)
        if guess is not None:
            p.x[:] = guess
        else:
            self._predict_newton(h)

    def _predict_newton(self, h: float) -> None:
        """X = the converged state + ∂x/∂λ h (tangent) or the clamp's linear field."""
        p = self.problem
        p.x[:] = self._saved
        if self.settings.predictor == "tangent":
            p.x[:] += h * self._load_tangent()
        else:
            p.x[:] += p.state.clamp_predictor(h)
        self._predicted = p.x.copy() if self.relax_below > 0 else None

    def _load_tangent(self) -> np.ndarray:
        if self._tangent is None:
            if not self._factorized:
                self.problem.factorize()
                self.chord.refactorized()
                self._factorized = True
            self._tangent = self.problem.load_tangent(1.0)
        return self._tangent

    def correct(self, u0: float, h: float) -> Outcome:
        """Newton at the load u0 + h from the predicted state."""
        p = self.problem
        p.state.set_load(u0 + h)
        e_ref = p.energy()
        e_ref = e_ref if math.isfinite(e_ref) else 0.0
        self._jump = self._left = None
        self._chorded = False
        if self._factorized and self.chord.due(u0 + h):
            self.report = rep = self.chord.correct(p, self.settings, e_ref, settle=self.settle)
            if rep.converged and not self._jamming_missed():
                self._chorded = True
                return Outcome("converged", rep.iterations, list(rep.history), rep.reason)
            log.debug("chord at %.6g mm: %s; Newton takes over", (u0 + h) * 1e3, rep.reason)
            self._predict_newton(h)  # from Newton's own predictor
            p.state.set_load(u0 + h)
            e_ref = p.energy()
            e_ref = e_ref if math.isfinite(e_ref) else 0.0
        self.chord.refactorized()  # Newton factorizes anew
        self.report = rep = newton(p, self.settings, e_ref, settle=self.settle)
        if not rep.converged and h < self.relax_below and self._predicted is not None and _stalled(rep):
            return self._relax(u0, h, e_ref, rep)
        if rep.converged and self._jamming_missed():
            if h >= self.relax_below or self._predicted is None:
                return Outcome("failed", rep.iterations, list(rep.history), JAMMING_MISSED)
            # too short to cut: the same increment again with the barrier everywhere, relaxed where Newton fails
            first = rep
            p.x[:] = self._predicted
            self.report = rep = newton(p, self.settings, e_ref, settle=self.settle)
            if not rep.converged and _stalled(rep):
                return self._relax(u0, h, e_ref, rep)
            return Outcome(
                "converged" if rep.converged else "failed",
                first.iterations + rep.iterations,
                [*first.history, *rep.history],
                rep.reason if rep.converged else JAMMING_MISSED,
            )
        return Outcome("converged" if rep.converged else "failed", rep.iterations, list(rep.history), rep.reason)

    def _jamming_missed(self) -> bool:
        """Whether the state just found lies past the jamming angle with the barrier off (it is on now)."""
        return self.watch is not None and self.watch.jamming_missed()

    def _relax(self, u0: float, h: float, e_ref: float, failed: NewtonReport) -> Outcome:
        """After Newton failed on a short increment: a stable equilibrium at u0 + h by :func:`relax`."""
        p = self.problem
        assert self._predicted is not None and self.hessian is not None
        self.relaxations += 1
        before = self._state_at(self._saved, u0)
        p.x[:] = self._predicted
        p.state.set_load(u0 + h)
        log.info(
            "Newton failed on %.6g -> %.6g mm (%s): relaxing to a stable state", u0 * 1e3, (u0 + h) * 1e3, failed.reason
        )
        rel = relax(self.hessian, self.settings, e_ref, self.relax_settings)
        its = failed.iterations + rel.iterations
        history = [*failed.history, *rel.history]
        if not rel.converged:
            return Outcome("failed", its, history, f"{failed.reason}; relaxation: {rel.reason}")
        self.report = NewtonReport(True, its, history, [], rel.reason, rel.residual)
        E1 = p.energy()
        R1 = float(self._psi @ rel.residual) if self._psi is not None and rel.residual is not None else math.nan
        E0, R0 = before
        work = 0.5 * h * (R0 + R1) if math.isfinite(R0 + R1) else math.nan
        released = E0 + work - E1 if math.isfinite(work) else math.nan
        # a jump to another state: energy released beyond the clamp's work (the network's criterion)
        jumped = math.isfinite(released) and released > SNAP_RELEASE * abs(work)
        if jumped:
            self._jump = {
                "u0_mm": (u0 + h) * 1e3,
                "u0_before_mm": u0 * 1e3,
                "energy_before": E0,
                "energy_after": E1,
                "released": released,
                "work": work,
                "reaction_before": R0,
                "reaction_after": R1,
                "lowest_eigenvalue_after": rel.lowest_eigenvalue,
                "lowest_eigenvalue_before": rel.kicked_from,
                "relaxation_iterations": rel.iterations,
            }
            if self.locate is not None:
                self._jump.update(self.locate.locate(p.x - self._predicted))
        self._left = (u0, self._saved.copy(), jumped) if self.on_relax is not None else None
        return Outcome("converged", its, history, rel.reason + (" (snap-through)" if jumped else ""))

    def _state_at(self, x: np.ndarray, u0: float) -> tuple[float, float]:
        """Energy and reaction psi·r of the state x at load u0 (the problem's state is left at x)."""
        p = self.problem
        p.x[:] = x
        p.state.set_load(u0)
        r = p.residual()
        return p.energy(), float(self._psi @ r) if self._psi is not None else math.nan

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        """The state is converged: its residual, and the load tangent for dR/du0 and the next predictor."""
        assert self.report is not None
        self.problem.state.converged()
        self._factorized = True  # Newton factorized at its iterates
        self.chord.converged(u0 + h, self.problem.x, None if self._tangent is None else (u0, self._tangent))
        self._tangent = None
        dR = math.nan
        # the factorization is an earlier state's (a chord row, or Newton's single linearization
        # before the local solves moved the state far): the tangent refined (chord module)
        refined = self._chorded or self.report.settled > 0
        if refined and (self.settings.predictor == "tangent" or self._psi is not None):
            if self._chorded:
                found = self.chord.tangent(self.problem, self._psi, u0 + h, self.report.residual)
            else:
                found = tangent_at_hand(self.problem, self._psi, self.chord.fd_step, self.report.residual)
            if found is None:  # too far from the factorization: the tangent of a new one
                self.problem.factorize()
                self.chord.refactorized()
                refined = False
            else:
                self._tangent, dR = found
        rec = StepRecord(
            0,
            u0 + h,
            outcome.iterations,
            residual=self.report.residual,
            history=list(outcome.history),
            reason=outcome.reason,
        )
        if self._jump is not None:
            rec.snap = True
            rec.released = float(self._jump["released"])  # type: ignore[arg-type]
            self.snaps.append(self._jump)
            log.warning(
                "snap-through at u0 = %.6g mm: the state jumped to a stable one (energy released %.3g "
                "J per metre of thickness)",
                (u0 + h) * 1e3,
                rec.released,
            )
            self._jump = None
            self.chord.forget()  # a jump: no extrapolation across it
        if self._left is not None and self.on_relax is not None:
            self.on_relax(*self._left)
        if refined:
            rec.dforce_du0 = dR
        elif self.settings.predictor == "tangent" and self._psi is not None:
            rec.dforce_du0 = self.problem.load_derivative(self._psi, self._load_tangent())
        return rec

    def reject(self, u0: float, outcome: Outcome) -> None:
        """Back to the converged state; the factorization now belongs to a rejected state: rebuild it."""
        p = self.problem
        p.x[:] = self._saved
        p.state.set_load(u0)
        self._tangent = None
        if self.settings.predictor == "tangent":
            p.factorize()
            self._factorized = True
            self.chord.refactorized()

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        """The failure pattern of the last attempts and the problem's own diagnosis (text and object)."""
        detail = self._diagnose() if self._diagnose is not None else None
        texts = (failure_pattern(attempts), detail.message() if detail is not None else "")
        return "; ".join(t for t in texts if t), detail


#: an arc-length continuation that goes on from a result (its steps appended): a generator of step records
ArcLength = Callable[[PathResult], Generator[StepRecord, None, PathResult]]


def load_steps(
    problem: Problem,
    path: PathSettings,
    settings: NewtonSettings,
    *,
    hessian: Relaxable | None = None,
    watch: JammingWatch | None = None,
    locate: Locating | None = None,
    settle: Settling | None = None,
    diagnose: Callable[[], Diagnosis] | None = None,
    psi: np.ndarray | None = None,
    arclength: ArcLength | None = None,
) -> Generator[StepRecord, None, PathResult]:
    """Carry the load from 0 to ``path.target``: a generator of the converged increments' records.

    The caller decides what to keep and write; the return value is the
    :class:`~ngbet.numerics.engine.PathResult`. ``path.path_following``: "displacement" control
    (:class:`SaddlePointNewton` on the engine; with ``path.snap`` and ``hessian``, an increment that
    fails at the shortest length is relaxed to a stable state, :func:`relax`, and its record carries
    the branch left in ``left``); "arclength": ``arclength(result)`` from the start; "auto":
    displacement control, and where it fails ``arclength(result)`` goes on (its steps appended).

    ``hessian`` is ``problem`` itself when its Newton matrix is a Hessian (relaxation, and the chord
    rows of ``path.chord_at``, which measure their contraction in its energy norm; None: neither),
    ``watch``, ``locate`` and ``settle`` the problem's barrier watch, snap locator and local solve
    where it has them (:class:`SaddlePointNewton`). Raises ValueError at once for an unknown ``path_following`` or arc
    length without ``arclength``; :class:`~ngbet.errors.ConvergenceError` while iterating, below
    ``min_step`` or after ``max_attempts`` increments, with the failures' pattern and what
    ``diagnose()`` finds.
    """
    if path.path_following not in ("displacement", "arclength", "auto"):
        raise ValueError(f"path_following = {path.path_following!r}: not 'displacement', 'arclength' or 'auto'")
    chord_at = path.chord_at if hessian is not None else ()
    if path.path_following == "displacement":
        below = min(path.min_step / path.cut, 2 * path.min_step) if path.snap and hessian is not None else 0.0
        left: list[tuple[float, np.ndarray]] = []  # the branch left by the step being accepted
        corrector = SaddlePointNewton(
            problem,
            settings,
            diagnose=diagnose,
            psi=psi,
            hessian=hessian,
            watch=watch,
            locate=locate,
            settle=settle,
            relax_below=below,
            chord_at=chord_at,
            length=path.length,
            on_relax=lambda lam, x, _snap: left.append((lam, x)),
        )
        return _displacement_steps(corrector, path, left)
    if arclength is None:
        raise ValueError(f"path_following = {path.path_following!r} needs an arc-length runner; none was given")
    if path.path_following == "arclength":
        return arclength(PathResult(0.0))
    # where displacement control fails arc length diagnoses: no eigen-solve here
    corrector = SaddlePointNewton(
        problem, settings, psi=psi, watch=watch, settle=settle, chord_at=chord_at, length=path.length
    )
    return _auto_steps(corrector, path, arclength)


def _displacement_steps(
    corrector: SaddlePointNewton, path: PathSettings, left: list[tuple[float, np.ndarray]]
) -> Generator[StepRecord, None, PathResult]:
    """Displacement control, relaxing where the path folds (the branch left comes in ``left``)."""
    out = PathResult(0.0)
    try:
        for rec in path_steps(corrector, path, out):
            rec.left = left.pop() if left else None
            yield rec
    except ConvergenceError as err:
        err.path_info.update(_snap_info(corrector))
        raise
    except KeyboardInterrupt as err:  # a signal's summary keeps the snaps so far too
        info: dict[str, object] = getattr(err, "path_info", {})
        info.update(_snap_info(corrector))
        err.path_info = info  # type: ignore[attr-defined]
        raise
    out.path_info.update(_snap_info(corrector))
    return out


def _auto_steps(
    corrector: SaddlePointNewton, path: PathSettings, arclength: ArcLength
) -> Generator[StepRecord, None, PathResult]:
    """Displacement control, then arc length where it fails."""
    partial = PathResult(0.0)
    try:
        return (yield from path_steps(corrector, path, partial))
    except ConvergenceError as err:
        log.warning("displacement control stops at %.6g mm; following the path by arc length", err.last_converged_mm)
        partial.u0 = err.last_converged_mm * 1e-3
        partial.attempts = list(err.attempts)
        partial.cuts = sum(not a.converged for a in err.attempts)
    return (yield from arclength(partial))


def _snap_info(corrector: SaddlePointNewton) -> dict[str, object]:
    """The snap-throughs and relaxations of a displacement-controlled path, and its chord rows, for the summary."""
    info: dict[str, object] = {}
    if corrector.chord.loads.size:
        info.update(chord_rows=corrector.chord.rows, chord_handovers=corrector.chord.handovers)
    if corrector.relaxations:
        info.update(snaps=list(corrector.snaps), relaxations=corrector.relaxations)
    return info
