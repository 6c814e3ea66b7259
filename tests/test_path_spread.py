"""The force's spread over the branches a path left at its relaxations (ngbet.continuum.path_spread)."""

import math

import numpy as np
import pytest
from conftest import DoubleWell, carry

from ngbet.continuum.path_spread import PathSpread
from ngbet.numerics.engine import Steps
from ngbet.numerics.path import load_steps
from ngbet.numerics.settings import NewtonSettings, PathSettings
from ngbet.scene.document import Scene

LAM_FOLD = 2 / (3 * math.sqrt(3))  # the left well's branch folds here


def _roots(lam: float) -> np.ndarray:
    """The real roots of y³ − y − λ, ascending."""
    r = np.roots([1.0, 0.0, -1.0, -lam])
    return np.sort(r[np.abs(r.imag) < 1e-12].real)


def _spread(first_step: float = 0.05) -> PathSpread:
    return PathSpread(
        DoubleWell,
        lambda p, r: float(r[0]),
        NewtonSettings(rtol=1e-14, atol=1e-14),
        first_step=first_step,
        min_step=1e-4,
    )


def test_the_spread_between_two_stable_wells_is_their_force_difference():
    """The left well left at λ = 0 and the path in the right well at λ = 0.2: both are stable
    there, and the spread is the difference of the reactions −y of the outer roots of y³ − y = 0.2."""
    spread = _spread()
    spread.left(0.0, np.array([0.0, -1.0]), snap=True)
    y = _roots(0.2)
    F_path = -y[-1]
    s = spread.at(0.2, F_path)
    assert s == pytest.approx(y[-1] - y[0], rel=1e-10)
    rec = spread.branches[0].records["200"]
    assert rec["stable"] and rec["force_N"] == pytest.approx(-y[0], rel=1e-10)


def test_a_branch_past_its_fold_contributes_nothing_from_then_on():
    """Carried beyond λ_f the left well has no equilibrium: the branch ends at its fold (within the
    shortest step), its record says so, and it gives no spread at that load or any later one."""
    spread = _spread()
    spread.left(0.0, np.array([0.0, -1.0]), snap=True)
    assert spread.at(0.5, -_roots(0.5)[-1]) == 0.0
    b = spread.branches[0]
    assert "folds" in b.ended and LAM_FOLD - 2e-4 < b.lam <= LAM_FOLD
    assert spread.at(0.6, -_roots(0.6)[-1]) == 0.0 and "600" not in b.records


def test_an_unstable_branch_contributes_nothing():
    """The middle root of y³ − y = λ (J = 3y² − 1 < 0) continued from λ = 0 to 0.1 is an
    equilibrium, but unstable: no spread, and its record says so with its force (−y)."""
    spread = _spread()
    spread.left(0.0, np.array([0.0, 0.0]), snap=False)
    assert spread.at(0.1, -_roots(0.1)[-1]) == 0.0
    rec = spread.branches[0].records["100"]
    assert not rec["stable"] and rec["ended"].startswith("unstable at 100 mm")
    # to Newton's tolerance: the decrement (an energy) below 1e-14 leaves y within about its square root
    assert rec["force_N"] == pytest.approx(-_roots(0.1)[1], abs=1e-7)


def test_a_branch_that_is_the_path_itself_gives_no_spread_and_ends():
    """A relaxation that came back to the path's own state: no second equilibrium; the branch has
    rejoined the path and is not continued further."""
    spread = _spread()
    spread.left(0.0, np.array([0.0, 1.0]), snap=False)
    y = _roots(0.2)[-1]
    assert spread.at(0.2, -y, np.array([0.2, y])) == 0.0
    assert spread.branches[0].ended == "rejoined the path at 200 mm"
    assert spread.at(0.3, -_roots(0.3)[-1]) == 0.0 and "300" not in spread.branches[0].records


def test_the_path_tells_the_branch_it_left_at_a_snap_and_its_forces_stay_the_same():
    """Displacement control snaps from the left well to the right at the fold; the record of that
    step carries the state it left (the left well just before λ_f), the others none; the path's
    states are bit for bit those of a path whose records were not kept."""
    a, b = DoubleWell(), DoubleWell()
    res_a = carry(a, 1.0, 0.05, NewtonSettings(), min_step=1e-4, psi=np.array([1.0, 0.0]), hessian=a)
    steps = Steps(
        load_steps(
            b,
            PathSettings(target=1.0, first_step=0.05, min_step=1e-4),
            NewtonSettings(),
            psi=np.array([1.0, 0.0]),
            hessian=b,
        )
    )
    left = [(rec.left[0], rec.left[1].copy(), rec.snap) for rec in steps if rec.left is not None]
    assert steps.result is not None
    res_b = steps.result
    assert [s.u0 for s in res_a.steps] == [s.u0 for s in res_b.steps]
    assert [float(s.residual[0]) for s in res_a.steps] == [float(s.residual[0]) for s in res_b.steps]
    assert len(left) == 1
    lam, x, snap = left[0]
    assert snap and LAM_FOLD - 2e-4 < lam < LAM_FOLD and x[1] < -1 / math.sqrt(3)


def test_the_spread_is_added_to_the_discretization_bar_and_recorded_on_its_own():
    """RunEstimates' fold: the bar becomes η + s (s the spread between the wells at λ = 0.2); a bar
    the estimate cannot vouch for stays empty (nan) with the spread recorded all the same."""
    from types import SimpleNamespace

    from ngbet.continuum.estimate import Estimate
    from ngbet.continuum.path_spread import RunPathSpread

    y = _roots(0.2)
    barrier = SimpleNamespace(problem=SimpleNamespace(jamming=SimpleNamespace(on=False)))  # a solver's problem
    run = RunPathSpread(SimpleNamespace(**vars(barrier), x=np.array([0.2, y[-1]])))
    run.spread = _spread()
    run.spread.problem = DoubleWell()
    run.spread.problem.problem = barrier.problem
    run.spread.left(0.0, np.array([0.0, -1.0]), snap=True)
    e = run.fold(0.2, Estimate(-y[-1], 0.01, math.nan, math.nan, "toy", 0.0, 0))
    assert e.path_spread_N == pytest.approx(y[-1] - y[0], rel=1e-10)
    assert e.force_error_N == 0.01 + e.path_spread_N
    assert run.summary()["force_path_spread_N"] == e.path_spread_N
    e2 = run.fold(0.2, Estimate(-y[-1], math.nan, math.nan, math.nan, "toy", 0.0, 0))
    assert math.isnan(e2.force_error_N) and e2.path_spread_N == e.path_spread_N


@pytest.mark.integration
def test_a_corner_that_relaxes_leaves_branches_that_fold_and_the_bar_is_the_estimate_alone(tmp_path):
    """The default mesh without stabilization relaxes at clamp corners (34.3, 37.7 and 54.1 mm): each
    branch the path left ends at its fold within the shortest step (Newton failed there on the
    path too), so no second stable equilibrium exists at the stops and the spread is exactly 0;
    the bar at 37 mm is the discretization estimate alone, and the summary records every branch."""
    import csv
    import json

    from ngbet.api import simulate

    scene = Scene().with_changes(**{"effects.stabilization_K": 0.0, "outputs.plot": False, "outputs.vtk": False})
    simulate(scene, tmp_path)
    s = json.loads((tmp_path / "summary.json").read_text())
    branches = s["path_spread"]["branches"]
    assert s["relaxations"] == len(branches) >= 1
    min_step = scene.loading.min_step_mm
    for b in branches:
        assert "folds" in b["ended"]
        ended_at = float(b["ended"].split("beyond ")[1].split(" mm")[0])
        assert b["left_at_mm"] <= ended_at < b["left_at_mm"] + 2 * min_step
    rows = {float(r["u0_mm"]): r for r in csv.DictReader((tmp_path / "results.csv").open())}
    assert rows[37.0]["force_path_spread_N"] == "0.0" and rows[56.0]["force_path_spread_N"] == "0.0"
    assert s["force_path_spread_N"] == 0.0
