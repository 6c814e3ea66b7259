"""The one translation of a scene into the path's settings, and path following that cannot be honoured."""

import math

import pytest

from ngbet.continuum.settings import PathSettings, newton_settings, path_settings
from ngbet.continuum.solver import follow
from ngbet.scene import default_scene


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
    path = PathSettings(0.01, 0.01, path_following=following)
    with pytest.raises(ValueError, match="needs an arc-length runner"):
        follow(object(), path, newton_settings(default_scene()))  # type: ignore[arg-type]


def test_an_unknown_path_following_is_refused():
    with pytest.raises(ValueError, match="path_following = 'arc'"):
        follow(object(), PathSettings(0.01, 0.01, path_following="arc"), newton_settings(default_scene()))


def test_path_settings_default_bounds():
    p = PathSettings(0.02, 0.01)
    assert math.isinf(p.max_step) and p.stops == () and p.snap and p.max_attempts == 500


def test_the_path_is_a_generator_of_step_records_the_caller_consumes():
    """The engine yields each converged step as it is accepted (the caller decides what to keep and
    may stop early); its return value is the path, the same records follow_path hands to on_step."""
    from test_engine import Toy

    from ngbet.engine import PathControl, follow_path, path_steps

    ctl = PathControl(target=0.010, first_step=0.001, max_step=0.004, growth=2.0, stops=(0.0035,))
    gen = path_steps(Toy(), ctl)
    seen = [round(next(gen).u0 * 1e3, 9) for _ in range(3)]  # the caller stops after three steps
    assert seen == [1.0, 3.0, 3.5]
    loads = []
    res = follow_path(Toy(), ctl, on_step=lambda rec: loads.append(round(rec.u0 * 1e3, 9)))
    assert loads == [round(s.u0 * 1e3, 9) for s in res.steps] == [1.0, 3.0, 3.5, 7.5, 10.0]
    with pytest.raises(StopIteration) as done:
        for _ in range(10):
            next(gen)
    assert [s.step for s in done.value.value.steps] == [1, 2, 3, 4, 5]
