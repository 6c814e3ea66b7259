"""The one continuation engine: step logic on a toy corrector, and the numbers of both models pinned.

Reference values (``PINNED``) were obtained with ``ngbet run`` of the scenes below on the code
before the two models shared the engine (each with its own load stepping), and reproduced by the
engine: the continuum to 1e-15 relative, the discrete model bit for bit (same 31 steps, same
snap-through 44.70 -> 45.45 mm). A refactoring of the engine or the correctors must not move them
beyond the tolerances asserted here (1e-9 relative for the continuum, whose Newton converges
quadratically to rtol = 1e-10 of the energy; 1e-6 for the network, whose path crosses a snap).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ngbet.cli import main
from ngbet.errors import ConvergenceError
from ngbet.numerics.engine import Outcome, PathControl, StepRecord, Steps, path_steps
from ngbet.run import run
from ngbet.scene.document import Scene
from ngbet.tables import read_rows

# the scene keys the pinned numbers depend on, spelled out (so that a change of a default does not
# silently change what is pinned)
PINNED_CONTINUUM = {
    "discretization.mesh_size_mm": 5.0,
    "discretization.order_u": 2,
    "discretization.corner_mesh_size_mm": 0.0,
    "discretization.structured": False,
    "material.K_el": 0.7e6,
    "material.K_sh": 21e3,
    "material.alpha1": 2e3,
    "material.alpha2": 20.0,
    "loading.u0_mm": 56.0,
    "loading.stops_mm": [37.0],
    "loading.first_step_mm": 16.0,
    "loading.max_step_mm": 28.0,
    "loading.output_every_mm": 0.0,
    "outputs.vtk": False,
    "outputs.plot": False,
}
PINNED_DISCRETE = {
    "model": "discrete",
    "discrete.spacing_mm": 5.0,
    "loading.u0_mm": 56.0,
    "loading.stops_mm": [37.0],
    "discrete.first_step_mm": 2.0,
    "discrete.max_step_mm": 8.0,
    "loading.output_every_mm": 0.0,
    "outputs.plot": False,
}
PINNED = {
    "continuum": {37.0: 62.40407179415401, 56.0: 109.53820079805064},
    "discrete": {37.0: 5.711766584489289, 56.0: 10.285809592037236},
}


def _forces(out) -> tuple[dict[float, float], list[dict]]:
    rows = read_rows(out / "results.csv")
    return {round(r["u0_mm"], 6): r["force_N"] for r in rows}, rows


def test_continuum_default_forces_are_pinned(tmp_path):
    s = run(Scene().with_changes(**PINNED_CONTINUUM), tmp_path)
    F, rows = _forces(tmp_path)
    assert s["status"] == "ok"
    for u0, ref in PINNED["continuum"].items():
        assert F[u0] == pytest.approx(ref, rel=1e-9), (u0, F[u0])
    _assert_tangent_slopes_match_the_force(rows, 0.02)  # measured: 0.3 and 0.7 % over the 16-21 mm steps


def test_discrete_default_forces_and_snap_are_pinned(tmp_path):
    s = run(Scene().with_changes(**PINNED_DISCRETE), tmp_path)
    F, rows = _forces(tmp_path)
    for u0, ref in PINNED["discrete"].items():
        assert F[u0] == pytest.approx(ref, rel=1e-6), (u0, F[u0])
    # Table 2 at spacing 5 mm (pinned ends) snaps between u0 = 44.6 and 45.5 mm (the energy drop
    # exceeds the clamp work of that step): the event is bracketed to <= 1 mm, logged, counted,
    # and the force drops across it; the run goes on
    snaps = [r["u0_mm"] for r in rows if r["snap"]]
    assert s["snap_event_count"] == 1 and len(snaps) == 1 and 44.6 < snaps[0] < 45.5, snaps
    ev = s["snap_events"][0]
    assert ev["u0_mm"] - ev["u0_before_mm"] <= 1.0 * (1 + 1e-9) and ev["released_J"] > 0.5 * ev["work_J"] > 0, ev
    k = next(i for i, r in enumerate(rows) if r["snap"])
    assert rows[k]["force_N"] < rows[k - 1]["force_N"], (rows[k - 1]["force_N"], rows[k]["force_N"])
    assert (tmp_path / "state_37mm.npz").exists()  # loading.stops_mm is a station of the network's path
    # near the snap F' turns fast: 2 % there, 0.5 % on the typical step
    _assert_tangent_slopes_match_the_force(rows, 0.03, typical=0.005)


def _assert_tangent_slopes_match_the_force(rows: list[dict], tol: float, typical: float | None = None) -> None:
    """(F1 - F0)/h over a smooth step is the mean of the recorded slopes at both ends.

    It is the trapezoid rule of the integral of F' over the step, up to O(h^2 F3), F3 the third
    derivative.
    """
    errors = []
    for a, b in zip(rows[:-1], rows[1:], strict=True):
        if b.get("snap"):
            continue
        fd = (b["force_N"] - a["force_N"]) / (b["u0_mm"] - a["u0_mm"])
        mean = 0.5 * (a["dforce_du0_N_per_mm"] + b["dforce_du0_N_per_mm"])
        errors.append(abs(fd - mean) / abs(fd))
        assert errors[-1] <= tol, (a["u0_mm"], b["u0_mm"], fd, mean)
    assert errors and (typical is None or float(np.median(errors)) <= typical), errors


# ------------------------------------------------------------------------------ toy corrector
class Toy:
    """A corrector with x(u0) = u0 exactly.

    It fails at trial lengths above ``max_h`` or beyond ``wall``, and asks for a retry at
    ``retry_at`` (lengths above 0.5 mm there).
    """

    def __init__(self, max_h: float = math.inf, wall: float = math.inf, retry_at: float = math.inf) -> None:
        self.x, self.max_h, self.wall, self.retry_at = 0.0, max_h, wall, retry_at
        self.trials: list[tuple[float, float]] = []

    def predict(self, u0: float, h: float) -> None:
        self.trial = self.x + h

    def correct(self, u0: float, h: float) -> Outcome:
        self.trials.append((u0, h))
        if u0 + h > self.wall or h > self.max_h:
            return Outcome("failed", 3, [1.0, 0.5, 0.4], "toy failure")
        if u0 < self.retry_at < u0 + h and h > 5e-4:
            return Outcome("retry", 1, [1.0], "bracket", retry_step=5e-4)
        return Outcome("converged", 1, [1e-20], "converged")

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        self.x = self.trial
        return StepRecord(0, u0 + h, outcome.iterations)

    def reject(self, u0: float, outcome: Outcome) -> None:
        pass

    def diagnose(self, attempts) -> tuple[str, None]:
        return "toy diagnosis", None


def _to_end(corrector, ctl):
    """The engine's path carried to its end, its records kept: the PathResult."""
    steps = Steps(path_steps(corrector, ctl))
    for _ in steps:
        pass
    return steps.result


def test_steps_grow_land_on_stops_and_resume_their_length():
    ctl = PathControl(target=0.010, first_step=0.001, max_step=0.004, growth=2.0, stops=(0.0035,))
    res = _to_end(Toy(), ctl)
    loads = [round(s.u0 * 1e3, 9) for s in res.steps]
    # 1, 2 (x2), then 4 would pass the stop at 3.5: land on it; the stop does not shorten the next
    # step (4, capped by max_step), then the target
    assert loads == [1.0, 3.0, 3.5, 7.5, 10.0], loads


def test_a_stop_just_beyond_a_trial_is_landed_on():
    ctl = PathControl(target=0.010, first_step=0.003, max_step=0.003, growth=1.0, stops=(0.0032,), land_within=0.2)
    loads = [round(s.u0 * 1e3, 9) for s in _to_end(Toy(), ctl).steps]
    assert loads[0] == 3.2  # 3.2 - 3.0 = 0.2 mm < 0.2 x 3 mm


def test_failures_cut_the_step_and_retries_take_the_correctors_length():
    toy = Toy(max_h=0.0015, retry_at=0.0055)
    res = _to_end(toy, PathControl(target=0.008, first_step=0.004, cut=0.5, growth=1.0))
    assert res.cuts == 2 and [round(h * 1e3, 9) for _, h in toy.trials[:3]] == [4.0, 2.0, 1.0]
    # 5 -> 6 mm crosses the retry point at 5.5 mm: the corrector's 0.5 mm, then on at 0.5 mm
    assert res.retries == 1 and (0.005, 0.0005) in [(round(u, 9), round(h, 9)) for u, h in toy.trials]
    assert math.isclose(res.u0, 0.008)


def test_convergence_error_names_the_last_load_in_mm_and_keeps_the_attempts():
    toy = Toy(wall=0.00481)
    ctl = PathControl(target=0.010, first_step=0.002, min_step=1e-4, growth=1.0)
    with pytest.raises(ConvergenceError) as info:
        _to_end(toy, ctl)
    err = info.value
    # halving the step creeps up to the wall at 4.81 mm until the step is below 0.1 mm
    assert 4.81 - 0.1 <= err.last_converged_mm <= 4.81
    assert f"last converged load: {err.last_converged_mm:.6g} mm" in str(err) and err.diagnosis == "toy diagnosis"
    failed = [a for a in err.attempts if not a.converged]
    assert failed and all(a.history == [1.0, 0.5, 0.4] for a in failed)
    assert np.all(np.diff([a.u0_from for a in err.attempts]) >= 0)


def _failed_run(tmp_path, capsys, model: str) -> tuple[int, str, dict]:
    """``ngbet run`` with one Newton iteration to a tolerance no single iteration meets: the first
    increment and its one cut fail, the next cut would be below min_step. Exit code, stderr, summary."""
    sets = {
        "model": model,
        "loading.u0_mm": 4,
        "loading.first_step_mm": 4,
        "loading.min_step_mm": 2,
        "discrete.first_step_mm": 4,
        "solver.max_iterations": 1,
        "solver.rtol": 1e-30,
        "solver.atol_energy": 1e-40,
        "discretization.mesh_size_mm": 20,
        "outputs.vtk": "false",
        "outputs.plot": "false",
        "loading.output_every_mm": 0,
    }
    del sets["discrete.first_step_mm" if model == "continuum" else "discretization.mesh_size_mm"]
    args = ["run", "--quiet", "--out", str(tmp_path / "run")]
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
    code = main(args)  # the exit status of `ngbet run` (in this process: no second NGSolve import)
    return code, capsys.readouterr().err, json.loads((tmp_path / "run" / "summary.json").read_text())


@pytest.mark.parametrize("model", ["continuum", "discrete"])
def test_a_failed_run_exits_1_with_the_same_error_shape_for_both_models(tmp_path, capsys, model):
    code, stderr, summary = _failed_run(tmp_path, capsys, model)  # both models stop the same way
    assert code == 1, stderr
    assert summary["status"] == "failed"
    # one line on stderr (loads in mm), the attempts in summary.json
    assert stderr.count("\n") == 1, stderr
    assert "load step cut below the minimum 2 mm" in stderr and "after u0 = 0 mm" in stderr, stderr
    text = summary["error"]
    assert "load step cut below the minimum 2 mm" in text and "last converged load: 0 mm" in text, text
    assert "0 -> 4 mm: FAILED after 1 it" in text and "0 -> 2 mm: FAILED after 1 it" in text, text


def test_a_failed_network_run_keeps_its_solver_statistics(tmp_path, capsys):
    """The network's statistics until the failure reach summary.json: the two failed attempts
    factorized and solved, and no snap happened."""
    code, stderr, summary = _failed_run(tmp_path, capsys, "discrete")
    assert code == 1, stderr
    assert summary["factorizations"] >= 2 and summary["snap_event_count"] == 0, summary
    assert summary["timers"]["solves"] >= 2 and summary["work_by_cause"], summary


def test_the_discrete_model_honours_stops_and_output_flags(tmp_path):
    scene = Scene().with_changes(
        **{
            "model": "discrete",
            "loading.u0_mm": 2.0,
            "loading.stops_mm": [0.5],
            "discrete.first_step_mm": 1.0,
            "outputs.reaction": False,
            "outputs.energy": False,
            "outputs.profile": False,
            "outputs.plot": False,
        }
    )
    run(scene, tmp_path)
    rows = read_rows(tmp_path / "results.csv")
    # the stop shortens one step, not the next: 1 mm grown by 1.5 after an easy step
    assert [r["u0_mm"] for r in rows] == [0.5, 2.0]
    assert not any(k.startswith(("force", "energy", "dforce")) for k in rows[0]), list(rows[0])
    assert (tmp_path / "state_0.5mm.npz").exists() and (tmp_path / "state_2mm.npz").exists()
    assert not (tmp_path / "profile.csv").exists() and not list(tmp_path.glob("*.png"))
