"""One continuation engine for both models: load stepping with stops, growth and cut.

The engine carries the clamp displacement u0 [m] from 0 to a target in increments and knows
nothing of the model: a :class:`Corrector` moves the state along the load (``predict``), brings
it back to equilibrium (``correct``), and commits or discards the result (``accept``,
``reject``). Two correctors exist: the continuum's damped Newton for the saddle point
(:class:`ngbet.numerics.path.SaddlePointNewton`) and the network's shifted minimizing Newton
with its stability check and snap handling (:class:`ngbet.discrete.solver.ShiftedNewton`).

Step length
    What a length measures is the :class:`StepLength`'s: by default the clamp displacement, as
    follows (arc length brings its own, :mod:`ngbet.numerics.arclength`). A nominal length
    starts at ``first_step`` (at most ``max_step``); a trial ends at the nearer of u0 + step
    and the next stop (``stops`` and the target); a stop that the trial would miss by less
    than ``land_within`` steps is landed on. After a converged increment with at most
    ``grow_after`` corrector iterations the nominal length grows by ``growth`` (up to
    ``max_step``); a stop that shortened a step does not shorten the next one.
Outcomes
    ``converged``: the step is accepted and recorded. ``retry``: the corrector asks for another
    length (e.g. to bracket a snap-through), not a failure. ``failed``: the length is cut by
    ``cut``; below ``min_step`` (or after ``max_attempts`` trials) :class:`ConvergenceError`
    is raised with every attempt and the corrector's diagnosis; each converged step has been
    yielded by then.
Consumers
    :func:`path_steps` is a generator (as scikit-fem's continuation): it yields the record of each
    converged step and returns the :class:`PathResult`. The runner iterates it and alone decides
    what to write (:class:`Steps` keeps the return value of a ``for`` loop over it); it is the one
    way a load path is consumed.

:class:`PathControl` is the one class of the step fields; the models' settings hold or extend it
(:class:`ngbet.numerics.settings.PathSettings`, :class:`ngbet.discrete.newton.StepControl`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

from ..errors import Attempt, ConvergenceError

log = logging.getLogger(__name__)

__all__ = [
    "STOP_REQUESTED",
    "Corrector",
    "Outcome",
    "PathControl",
    "PathResult",
    "StepLength",
    "StepRecord",
    "Steps",
    "check_stop",
    "request_stop",
    "past_deadline",
    "stop_deferred",
    "path_steps",
    "progress_bar",
    "time_budget",
    "uninterrupted",
]


@dataclass(frozen=True, kw_only=True)
class PathControl:
    """Step-length control of a load path; loads in metres of clamp displacement (module docstring).

    The one place of the step fields: the continuum's path settings extend it, the network's step
    control holds one.
    """

    target: float
    first_step: float
    max_step: float = math.inf
    min_step: float = 0.0
    growth: float = 1.5
    cut: float = 0.5
    grow_after: int = 4
    stops: tuple[float, ...] = ()
    #: a stop closer than this many nominal steps beyond a trial load is landed on instead
    land_within: float = 0.0
    #: bound on the number of trials, converged or not (None: none)
    max_attempts: int | None = None


@dataclass
class Outcome:
    """What a corrector made of one trial increment."""

    kind: Literal["converged", "retry", "failed"]
    iterations: int
    history: list[float] = field(default_factory=list)  # corrector decrements per iteration
    reason: str = ""
    retry_step: float = 0.0  # the next trial length for ``kind == "retry"``
    #: the load [m] the corrector ended at, where it chooses it (arc length); None: the trial's end
    u0: float | None = None


@dataclass
class StepRecord:
    """What the engine reports for each converged increment (fields a model does not have stay NaN)."""

    step: int
    u0: float  # clamp displacement reached [m]
    iterations: int
    wall_s: float = 0.0
    residual: np.ndarray | None = None  # r (dE/dx) at the state; its prescribed rows hold the reactions
    energy: float = math.nan
    dforce_du0: float = math.nan  # dR/du0 from the load tangent at the state (R in the model's force unit)
    lambda_min: float = math.nan  # lowest scaled tangent eigenvalue, when checked
    snap: bool = False
    released: float = 0.0  # energy released beyond the clamp work in the step [J] (a snap-through)
    history: list[float] = field(default_factory=list)
    reason: str = ""
    #: the model's unknowns at the step, where the caller cannot read them from the problem (the
    #: network's); a generator may drop it once it moves on, so that a path keeps no states
    state: np.ndarray | None = None
    #: a relaxation left a branch in this step: the load [m] of the converged state before it and
    #: that state (the snap flag is ``snap``)
    left: tuple[float, np.ndarray] | None = None
    #: what path following found in this step beyond displacement control (arc length's instabilities)
    instabilities: list[Any] = field(default_factory=list)


class Corrector(Protocol):
    """The model side of the engine; it owns the state."""

    def predict(self, u0: float, h: float) -> None:
        """Move the state from the converged load u0 towards u0 + h."""

    def correct(self, u0: float, h: float) -> Outcome:
        """Restore equilibrium at the load u0 + h from the predicted state."""

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        """Commit the corrected state as the new converged one; ``step`` and ``wall_s`` are set by the engine."""

    def reject(self, u0: float, outcome: Outcome) -> None:
        """Return to the converged state at u0 after a trial that is not accepted."""

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        """What the corrector concludes after the last failure.

        The text for the error message, and the structured diagnosis it was written from (or None).
        """


class StepLength(Protocol):
    """What the engine's step length measures, where a trial ends and when the path is done.

    the default measures the clamp displacement; the arc-length
    continuation (:mod:`ngbet.numerics.arclength`) measures the arc length of the path.
    """

    def first_step(self) -> float:
        """The first nominal length."""

    def max_step(self) -> float:
        """The largest nominal length a step grows to."""

    def too_short(self, step: float) -> bool:
        """Whether a length cut to ``step`` is below the smallest one."""

    def finished(self, u0: float) -> bool:
        """Whether the path is done at the converged load ``u0``."""

    def trial(self, u0: float, step: float) -> tuple[float, float, float]:
        """The trial from the converged load ``u0`` with the nominal length ``step``.

        Returns its length h (shortened to land on a stop), the load it ends at (NaN where the
        corrector chooses it, :attr:`Outcome.u0`) and the nominal length from then on.
        """


class _LoadLength:
    """Displacement control: h is the increment of u0.

    A trial lands on a stop it would miss by less than ``land_within`` steps; a stop that
    shortened a step does not shorten the next one.
    """

    def __init__(self, ctl: PathControl) -> None:
        self.ctl = ctl
        self.marks = sorted({s for s in ctl.stops if 0 < s < ctl.target} | {ctl.target})
        self.eps = 1e-12 * max(1.0, abs(ctl.target))

    def first_step(self) -> float:
        return min(self.ctl.first_step, self.ctl.max_step)

    def max_step(self) -> float:
        return self.ctl.max_step

    def too_short(self, step: float) -> bool:
        return step < self.ctl.min_step * (1 - 1e-9)

    def finished(self, u0: float) -> bool:
        return not u0 < self.ctl.target - self.eps

    def trial(self, u0: float, step: float) -> tuple[float, float, float]:
        nxt, h = _trial_load(u0, step, self.marks, self.eps, self.ctl.land_within)
        return h, nxt, step


@dataclass
class PathResult:
    """The load reached, the converged steps and every trial increment."""

    u0: float
    steps: list[StepRecord] = field(default_factory=list)
    attempts: list[Attempt] = field(default_factory=list)
    cuts: int = 0
    retries: int = 0
    #: what the path found beyond the steps, for the summary: arc length's instabilities, the
    #: continuum's snap-throughs and chord rows, the network's solver statistics
    path_info: dict[str, object] = field(default_factory=dict)


#: Set by the command line's signal handler (Ctrl-C, SIGTERM) when it raises KeyboardInterrupt.
#: That exception can be lost: raised while pybind11 converts the arguments of an NGSolve call
#: (e.g. in ``ngs.IfPos(...)`` while an observable is evaluated), it is cleared as a failed
#: conversion and the run would go on to the end. The load loops check this flag between steps,
#: so that such a run stops at its next step.
STOP_REQUESTED = threading.Event()
#: the name of the signal that set :data:`STOP_REQUESTED` (:func:`request_stop`)
_STOP_SIGNAL = ["SIGINT"]


def request_stop(signal_name: str) -> None:
    """Ask the run to stop at its next step (:func:`check_stop`), which names ``signal_name``."""
    _STOP_SIGNAL[0] = signal_name
    STOP_REQUESTED.set()


#: the time (``time.perf_counter()``) after which a path stops at its next trial (inf: none); set by :func:`time_budget`
_DEADLINE: ContextVar[float] = ContextVar("path_deadline", default=math.inf)


@contextlib.contextmanager
def time_budget(seconds: float) -> Iterator[None]:
    """Inside: a path that is still going ``seconds`` from now stops at its next trial with a ConvergenceError.

    Every converged step has been yielded by then, as for a step cut below the minimum: a bound
    on the time of a setting that cannot carry the load (each trial is bounded by Newton's
    iteration limit), for a caller with other settings to try.
    """
    token = _DEADLINE.set(min(_DEADLINE.get(), time.perf_counter() + seconds))
    try:
        yield
    finally:
        _DEADLINE.reset(token)


def past_deadline() -> bool:
    """Whether the time budget of the enclosing :func:`time_budget` is spent.

    The path checks it before each trial; a relaxation, whose trial may take hundreds of
    factorizations, checks it before each of them.
    """
    return time.perf_counter() > _DEADLINE.get()


def check_stop() -> None:
    """Raise KeyboardInterrupt if a signal asked the run to stop (:data:`STOP_REQUESTED`)."""
    if STOP_REQUESTED.is_set():
        raise KeyboardInterrupt(_STOP_SIGNAL[0])  # the signal's name, as the handler's own exception says


#: how many :func:`uninterrupted` blocks are open (main thread)
_UNCUT = [0]


def stop_deferred() -> bool:
    """Whether a stop signal must wait: an :func:`uninterrupted` block is open.

    The signal's handler then only calls :func:`request_stop`, and the block raises as it ends.
    """
    return _UNCUT[0] > 0


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """A block that a stop signal does not cut: the signal's KeyboardInterrupt comes as it ends.

    For a write and its record that must stay together (a row on disk and the count of rows that
    summary.json reports). Blocks nest; the outermost ends with :func:`check_stop`. If the block
    itself raises, that exception propagates, and the stop request stands for the next step.
    """
    _UNCUT[0] += 1
    try:
        yield
    finally:
        _UNCUT[0] -= 1
    if _UNCUT[0] == 0:
        check_stop()


def path_steps(
    corrector: Corrector, ctl: PathControl, out: PathResult | None = None, *, length: StepLength | None = None
) -> Generator[StepRecord, None, PathResult]:
    """Carry the load from 0 to ``ctl.target``, yielding each converged step's record as it is accepted.

    The one step loop of the package: ``length`` says what the step length measures (None: the
    clamp displacement; the arc-length continuation passes its own) and when
    the path is done; the loop trials, records, grows, cuts and stops.

    The caller decides what to keep and write; the generator's return value (``StopIteration.value``,
    or ``yield from``) is the :class:`PathResult`, which ``out`` (filled as the path goes) also is.

    Raises
    ------
    ConvergenceError
        when a failed increment is cut below ``ctl.min_step`` or after ``ctl.max_attempts``
        trials; every converged step has been yielded by then.
    """
    out = PathResult(0.0) if out is None else out
    measure = _LoadLength(ctl) if length is None else length
    step = measure.first_step()
    while not measure.finished(out.u0):
        check_stop()
        lam = out.u0
        if past_deadline():
            text, detail = corrector.diagnose(out.attempts)
            raise ConvergenceError(
                f"time budget spent on the way from {lam * 1e3:.6g} mm to {ctl.target * 1e3:.6g} mm",
                lam * 1e3,
                out.attempts,
                text,
                detail,
            )
        h, nxt, step = measure.trial(lam, step)
        t0 = time.perf_counter()
        corrector.predict(lam, h)
        outcome = corrector.correct(lam, h)
        end = nxt if outcome.u0 is None else outcome.u0
        out.attempts.append(
            Attempt(lam, end, outcome.kind == "converged", outcome.iterations, outcome.reason, list(outcome.history))
        )
        if outcome.kind == "converged":
            _record(corrector, out, lam, end, h, outcome, t0)
            yield out.steps[-1]
            if outcome.iterations <= ctl.grow_after:
                step = min(step * ctl.growth, measure.max_step())
            continue
        corrector.reject(lam, outcome)
        step = _after_rejection(corrector, ctl, measure, out, lam, end, h, outcome)
    return out


class Steps:
    """Iterate a path generator's step records in a ``for`` loop and keep its return value.

    ``result`` is the :class:`PathResult` once the loop has run to the end (None before)::

        steps = Steps(path_steps(corrector, ctl))
        for rec in steps:
            ...  # write what the runner wants of the step
        res = steps.result
    """

    def __init__(self, steps: Generator[StepRecord, None, PathResult]) -> None:
        self._steps = steps
        self.result: PathResult | None = None

    def __iter__(self) -> Iterator[StepRecord]:
        self.result = yield from self._steps


def _trial_load(lam: float, step: float, marks: list[float], eps: float, land_within: float) -> tuple[float, float]:
    """The end of the next trial and its length: u0 + step, or the next stop if it comes first or just after."""
    upcoming = next(m for m in marks if m > lam + eps)
    if upcoming - (lam + step) < land_within * step:
        return upcoming, upcoming - lam
    return lam + step, step


def _record(
    corrector: Corrector, out: PathResult, lam: float, nxt: float, h: float, outcome: Outcome, t0: float
) -> None:
    """Accept a converged trial and append its step record."""
    rec = corrector.accept(lam, h, outcome)
    rec.step = len(out.steps) + 1
    if outcome.u0 is None:  # else the corrector chose the load and set it (arc length)
        rec.u0 = nxt
    rec.wall_s = time.perf_counter() - t0
    out.u0 = rec.u0
    out.steps.append(rec)
    log.info("u0 = %.6g mm reached in %d iterations", rec.u0 * 1e3, outcome.iterations)


def _after_rejection(
    corrector: Corrector,
    ctl: PathControl,
    measure: StepLength,
    out: PathResult,
    lam: float,
    nxt: float,
    h: float,
    outcome: Outcome,
) -> float:
    """The next nominal step after a rejected trial; raises when the path cannot go on."""
    if outcome.kind == "retry":
        out.retries += 1
        step = outcome.retry_step
    else:
        out.cuts += 1
        log.info("increment %.6g -> %.6g mm failed (%s); cutting the step", lam * 1e3, nxt * 1e3, outcome.reason)
        step = h * ctl.cut
    too_short = outcome.kind == "failed" and measure.too_short(step)
    too_many = ctl.max_attempts is not None and len(out.attempts) >= ctl.max_attempts
    if too_short or too_many:
        why = (
            f"load step cut below the minimum {ctl.min_step * 1e3:.3g} mm"
            if too_short
            else f"{len(out.attempts)} increments tried (limit {ctl.max_attempts})"
        )
        text, detail = corrector.diagnose(out.attempts)
        raise ConvergenceError(
            f"{why} on the way from {lam * 1e3:.6g} mm to {ctl.target * 1e3:.6g} mm",
            lam * 1e3,
            out.attempts,
            text,
            detail,
        )
    return step


@contextlib.contextmanager
def progress_bar(show: bool, target_mm: float, desc: str = "u0") -> Iterator[Callable[[float], None] | None]:
    """A tqdm bar over the clamp displacement [mm]: a callable the runner feeds with each step's u0 [m].

    Yields None when not shown.
    """
    if not show:
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(
        total=round(target_mm, 6),
        unit="mm",
        desc=desc,
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} mm [{elapsed}<{remaining}]",
    )
    try:
        yield lambda u0: bar.update(u0 * 1e3 - bar.n)
    finally:
        bar.close()
