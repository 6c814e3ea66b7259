"""The one translation of a scene into the path's settings, and path following that cannot be honoured."""

import math

import numpy as np
import pytest

from ngbet.numerics.path import load_steps
from ngbet.numerics.settings import PathSettings
from ngbet.runner.settings import newton_settings, path_settings
from ngbet.scene.document import default_scene


def test_path_settings_of_the_default_scene():
    """Loads in metres; the path lands on the 37 mm stop and every 2 mm below 56 mm, and the chord
    corrects the grid's 27 loads but not the stop (nor the final load, which is no stop)."""
    p = path_settings(default_scene())
    assert p.target == pytest.approx(0.056) and p.first_step == pytest.approx(0.016)
    assert len(p.stops) == 28 and 0.037 in p.stops and max(p.stops) == pytest.approx(0.054)
    assert len(p.chord_at) == 27 and 0.037 not in p.chord_at and set(p.chord_at) < set(p.stops)
    assert p.path_following == "displacement" and p.length == pytest.approx(default_scene().specimen.L)
    assert path_settings(default_scene().with_changes(**{"loading.output_every_mm": 0})).chord_at == ()


@pytest.mark.parametrize("following", ["arclength", "auto"])
def test_arc_length_without_a_runner_is_refused(following):
    """Asking for arc length where no arc-length runner is given is an error, not displacement control."""
    path = PathSettings(target=0.01, first_step=0.01, path_following=following)
    with pytest.raises(ValueError, match="needs an arc-length runner"):
        load_steps(object(), path, newton_settings(default_scene()))  # type: ignore[arg-type]


def test_an_unknown_path_following_is_refused():
    with pytest.raises(ValueError, match="path_following = 'arc'"):
        load_steps(
            object(),
            PathSettings(target=0.01, first_step=0.01, path_following="arc"),  # type: ignore[arg-type]
            newton_settings(default_scene()),
        )


def test_path_settings_default_bounds():
    p = PathSettings(target=0.02, first_step=0.01)
    assert math.isinf(p.max_step) and p.stops == () and p.snap and p.max_attempts == 500


def test_the_path_is_a_generator_of_step_records_the_caller_consumes():
    """The engine yields each converged step as it is accepted (the caller decides what to keep and
    may stop early: after k records, exactly k steps are done and no further trial was made); its
    return value is the path, whose records are those yielded."""
    from test_engine import Toy

    from ngbet.numerics.engine import PathControl, Steps, path_steps

    ctl = PathControl(target=0.010, first_step=0.001, max_step=0.004, growth=2.0, stops=(0.0035,))
    toy = Toy()
    gen = path_steps(toy, ctl)
    seen = [round(next(gen).u0 * 1e3, 9) for _ in range(3)]  # the caller stops after three steps
    assert seen == [1.0, 3.0, 3.5]
    assert len(toy.trials) == 3  # nothing was computed beyond the third step
    steps = Steps(path_steps(Toy(), ctl))
    loads = [round(rec.u0 * 1e3, 9) for rec in steps]
    assert steps.result is not None
    assert loads == [round(s.u0 * 1e3, 9) for s in steps.result.steps] == [1.0, 3.0, 3.5, 7.5, 10.0]
    with pytest.raises(StopIteration) as done:
        for _ in range(10):
            next(gen)
    assert [s.step for s in done.value.value.steps] == [1, 2, 3, 4, 5]


def test_the_continuum_path_stops_where_its_caller_stops_and_returns_what_it_yielded():
    """Breaking out of the continuum's generator after k records leaves the problem at the k-th
    load, with k steps done and no trial beyond; carried to the end, the generator's return value
    is the path whose records were yielded, the numbers of a path whose records were not kept
    bit for bit, and the snap-through's step is the one record that carries the branch left."""
    from conftest import DoubleWell, carry

    from ngbet.numerics.engine import Steps
    from ngbet.numerics.settings import NewtonSettings

    path, psi = PathSettings(target=1.0, first_step=0.05, min_step=1e-4), np.array([1.0, 0.0])
    toy = DoubleWell()
    k, loads = 3, []
    for rec in load_steps(toy, path, NewtonSettings(), psi=psi, hessian=toy):
        loads.append(rec.u0)
        if len(loads) == k:
            break
    assert toy.x[0] == loads[-1] == pytest.approx(0.05 * (1 + 1.5 + 2.25))  # grown by 1.5 after easy steps
    again = DoubleWell()
    steps = Steps(load_steps(again, path, NewtonSettings(), psi=psi, hessian=again))
    records = list(steps)
    assert steps.result is not None and steps.result.steps == records and steps.result.u0 == 1.0
    assert [r.u0 for r in records[:k]] == loads
    toy = DoubleWell()
    whole = carry(toy, 1.0, 0.05, NewtonSettings(), min_step=1e-4, psi=psi, hessian=toy)
    assert [r.u0 for r in whole.steps] == [r.u0 for r in records]
    assert [r.dforce_du0 for r in whole.steps] == [r.dforce_du0 for r in records]
    assert [r.snap for r in records].count(True) == 1 == sum(r.left is not None for r in records)
    assert next(r for r in records if r.snap).left is not None
