"""Arc length on the engine's step loop: stops landed on once, the trial bound, the time budget."""

import numpy as np
import pytest
from conftest import Fold

from ngbet.numerics.arclength import ArcLengthSettings, arclength_steps
from ngbet.numerics.engine import Steps, time_budget
from ngbet.numerics.settings import NewtonSettings


def _follow(ctl):
    steps = Steps(
        arclength_steps(
            Fold(), ctl, NewtonSettings(), weights=np.array([0.0, 1.0]), length=1.0, psi=np.array([1.0, 0.0])
        )
    )
    for _ in steps:
        pass
    assert steps.result is not None
    return steps.result


TARGET = Fold.g(1.2)  # 0.288, beyond the second turning point


def test_a_stop_is_landed_on_once_and_the_target_exactly():
    """The path passes λ = 0.05 on the way up, back down between the turning points and up again:
    the engine's loop lands on the stop the first time only (a stop above the largest load
    reached), and on the target exactly; every landed point is in equilibrium."""
    res = _follow(ArcLengthSettings(target=TARGET, first_step=0.01, max_step=0.05, min_step=1e-6, stops=(0.05,)))
    lam = np.array([s.u0 for s in res.steps])
    assert np.sum(lam == 0.05) == 1 and lam[-1] == TARGET and res.u0 == TARGET
    crossings = np.sum(np.diff(np.sign(lam - 0.05)) != 0)
    assert crossings >= 3  # up past 0.05 (from the landed point), down below it, up again
    assert all(abs(s.residual[1]) < 1e-6 for s in res.steps)
    assert [s.step for s in res.steps] == list(range(1, len(res.steps) + 1))


def test_the_path_stops_after_max_steps_trials_without_an_error():
    """``max_steps`` bounds the trials of the loop: 7 trials, 7 attempts, short of the target; the
    caller decides what the unreached target means."""
    res = _follow(ArcLengthSettings(target=TARGET, first_step=0.01, max_step=0.05, min_step=1e-6, max_steps=7))
    assert len(res.attempts) == 7 and len(res.steps) == 7 and 0 < res.u0 < TARGET


def test_the_time_budget_stops_arc_length_as_it_stops_displacement_control():
    """Arc length runs on the engine's loop, so a spent time budget stops it before its first trial."""
    with time_budget(0.0):
        res = _follow(ArcLengthSettings(target=TARGET, first_step=0.01, max_step=0.05, min_step=1e-6))
    assert res.steps == [] and res.attempts == [] and res.u0 == 0.0


def test_a_step_cut_below_its_minimum_ends_the_path_without_an_error():
    """Newton limited to one iteration never converges from a predictor off the path: the first
    step is cut by 0.5 until below the minimum (trials of 0.01, 0.005, 0.0025 and 0.00125 in u0 at
    the start; the next, 0.01/16, is below 1.01 × 0.01/16), then the path ends at its start, every
    trial a recorded failure."""
    ctl = ArcLengthSettings(target=TARGET, first_step=0.01, max_step=0.05, min_step=0.01 / 16 * 1.01)
    steps = Steps(
        arclength_steps(
            Fold(),
            ctl,
            NewtonSettings(max_iterations=1),
            weights=np.array([0.0, 1.0]),
            length=1.0,
            psi=np.array([1.0, 0.0]),
        )
    )
    assert list(steps) == []
    res = steps.result
    assert res is not None and res.u0 == 0.0 and res.cuts == len(res.attempts) == 4
    assert not any(a.converged for a in res.attempts)
    with pytest.raises(ValueError, match="branch must be"):
        arclength_steps(Fold(), ctl, NewtonSettings(), weights=np.ones(2), length=1.0, psi=np.ones(2), branch="x")
