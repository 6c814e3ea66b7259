"""The fit's curves in worker processes: the same numbers as in one process, failures reported, no orphans."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import psutil
import pytest

from ngbet.calibration import joint, runs
from ngbet.calibration.command import summary
from ngbet.calibration.fit_params import CurveFit, curve_scene
from ngbet.errors import FitWorkerError
from ngbet.measured.curves import MeasuredCurve
from ngbet.scene.document import Scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "geometry" / "cao2008_150x450.toml"
NAMES = ["material.K_sh", "material.K_lock"]
#: two specimen sizes of the paper's fabric on a 30 mm mesh, 4 loads each
SIZES = [(150.0, 450.0), (150.0, 300.0)]


def scene() -> Scene:
    return Scene.from_toml(SCENE).with_changes(
        **{
            "discretization.mesh_size_mm": 30.0,
            "material.alpha1": 0.2,
            "material.alpha2": 0.2,
            "outputs.vtk": False,
            "outputs.plot": False,
        }
    )


def curves() -> list[MeasuredCurve]:
    out = []
    for W, L in SIZES:
        u = np.linspace(5.0, 0.6 * (np.sqrt(2) - 1) * (L - W), 4)
        spec = {"specimen.width_mm": W, "specimen.length_mm": L}
        out.append(MeasuredCurve(u, 10.0 * u, f"{W:g}x{L:g}.csv", spec))
    return out


def model(workers: int) -> runs.CurveModel:
    sc = scene()
    cfs = [CurveFit(c, curve_scene(sc, c, c.u_mm), c.u_mm, c.force_N, 0.01 * c.force_N, level=None) for c in curves()]
    return runs.CurveModel(cfs, NAMES, workers)


THETA = np.log([2.5e4, 1.5e4])


def children() -> set[int]:
    """This process's living children but multiprocessing's resource tracker (one per process, it stays)."""
    out = set()
    for p in psutil.Process().children(recursive=True):
        try:
            if p.status() != psutil.STATUS_ZOMBIE and "resource_tracker" not in " ".join(p.cmdline()):
                out.add(p.pid)
        except psutil.Error:  # ended meanwhile
            pass
    return out


def stop_all(proc, workers) -> None:
    """Whatever failed in a test: its command's process group and the workers it saw, killed."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    for p in workers:
        try:
            p.kill()
        except psutil.Error:
            pass


def test_curves_in_workers_give_the_numbers_of_one_process():
    """Each curve in its own worker process (one NGSolve thread, as in one process): the forces, their
    derivatives and the discretization estimates are those of the serial runs to round-off, and a
    run already made is served from the cache (no run counted)."""
    before = children()  # other tests' processes (a plot process) are not this test's
    serial = model(1)
    parallel = model(2)
    try:
        assert parallel.parallel and not serial.parallel
        a, b = serial(THETA, check=True), parallel(THETA, check=True)
        for x, y in zip(a, b, strict=True):
            assert np.all(np.isfinite(x.F)) and np.all(x.F > 0) and np.all(np.isfinite(x.err))
            np.testing.assert_allclose(y.F, x.F, rtol=1e-10)
            np.testing.assert_allclose(y.G, x.G, rtol=1e-8, atol=1e-10 * np.abs(x.G).max())
            np.testing.assert_allclose(y.err, x.err, rtol=1e-8, atol=1e-12)
        assert parallel.runs == serial.runs == 1
        parallel(THETA)  # the checked runs serve an unchecked call
        assert parallel.runs == 1
        assert all(len(t) == 1 and t[0][1] and t[0][3] > 0 for t in parallel.timings)  # (rung, checked, wall, CPU)
    finally:
        parallel.close()
    assert not children() - before


def test_a_probe_estimates_at_its_points_only_and_a_full_check_serves_it(monkeypatch):
    """A probe estimates the force error at its points only (nan at the others, which a rung choice
    therefore cannot read as vouched for), with the numbers of the full check there (the same
    estimator at the same states); a full check serves a later probe, a probe no full check."""
    monkeypatch.setattr(runs, "PROBE_POINTS", 2)
    m = model(1)
    at = runs.probe_points(4)
    assert at == (0, 3)
    probe = m(THETA, check=True, probe=True)
    full = m(THETA, check=True)
    assert m.runs == 2
    m(THETA, check=True, probe=True)
    m(THETA)
    assert m.runs == 2
    for p, f in zip(probe, full, strict=True):
        assert np.all(np.isfinite(p.err[list(at)])) and np.all(np.isnan(p.err[[1, 2]]))
        np.testing.assert_allclose(p.err[list(at)], f.err[list(at)], rtol=1e-10)
        np.testing.assert_allclose(p.F, f.F, rtol=1e-12)
        assert runs.relative_error(p, at) == pytest.approx(np.max(f.err[list(at)] / f.F[list(at)]), rel=1e-10)
        assert runs.relative_error(p) == np.inf  # not estimated everywhere: not vouched for
        assert runs.relative_error(f) == pytest.approx(np.max(f.err / f.F), rel=1e-12)


def test_a_worker_that_dies_is_reported_and_the_others_are_ended():
    """A worker killed during the fit (out of memory, a crash) stops the fit with an error naming its
    curve; no worker is left behind."""
    before = children()
    m = model(2)
    try:
        m(THETA)
        pool = m._pools[1]
        (victim,) = pool._processes.values()
        victim.kill()
        victim.join(10)
        with pytest.raises(FitWorkerError, match="150 x 300 mm"):
            m(THETA + 0.1)
    finally:
        m.close()
    assert not children() - before


def test_an_exception_in_a_worker_reaches_the_fit():
    """An error inside a worker's run (here a curve with no load to run to) is raised in the fit's
    process with its own type, not turned into a failed model run (which would read as NaN forces)."""
    before = children()
    m = model(2)
    m.curves[0].u_mm = np.zeros(0)
    try:
        with pytest.raises(IndexError):
            m(THETA)
    finally:
        m.close()
    assert not children() - before


FIT_SCRIPT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    import time
    import numpy as np
    from test_fit_parallel import curves, scene, NAMES
    from ngbet.calibration import runs
    from ngbet.calibration.joint import fit_curves

    # every model run outlasts the test's wait for the signal (the test's coarse runs take a fraction
    # of a second: a fit of a few could end before it): in the workers too, which import this module;
    # the signal or the kill ends them inside the wait
    _curve_run = runs.curve_run
    runs.curve_run = lambda job, meshes: (time.sleep(60.0), _curve_run(job, meshes))[1]

    if __name__ == "__main__":  # the spawned workers import this module again
        print("started", flush=True)
        fit_curves(curves(), scene(), NAMES, choose_discretization=False, workers=2, max_runs=40)
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("how", ["ctrl-c", "kill"])
def test_a_stopped_fit_leaves_no_worker_behind(tmp_path, how):
    """Ctrl-C on a fit with worker processes (SIGINT to the terminal's process group, as a terminal
    sends it): the fit stops with KeyboardInterrupt and ends its workers. The fit's process killed
    (SIGKILL, no clean-up possible): its workers exit by themselves, also in the middle of a run."""
    from test_faults import signals_at_default

    script = tmp_path / "fit.py"
    script.write_text(FIT_SCRIPT.format(tests=str(Path(__file__).parent)))
    proc = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
        preexec_fn=signals_at_default,  # started as from a terminal, whatever started pytest
    )
    workers: list[psutil.Process] = []
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "started"
        parent = psutil.Process(proc.pid)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2:  # both curves' workers running
            time.sleep(0.5)
            workers = [p for p in parent.children(recursive=True) if "resource_tracker" not in " ".join(p.cmdline())]
        assert len(workers) >= 2, "the workers did not start"
        time.sleep(2.0)  # inside a model run
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
            _, err = proc.communicate(timeout=60)
            assert proc.returncode != 0 and "KeyboardInterrupt" in err
        else:
            proc.kill()
            proc.communicate(timeout=60)
        _, alive = psutil.wait_procs(workers, timeout=20)
        assert not alive, [p.pid for p in alive]
    finally:
        stop_all(proc, workers)  # whatever failed above: nothing of this test left running


@pytest.mark.integration
def test_a_fit_in_workers_is_the_serial_fit():
    """The whole search (two sizes, two parameters) with the curves in two workers ends where the
    serial one ends, to round-off, with the same model runs."""
    fits = [
        joint.fit_curves(curves(), scene(), NAMES, choose_discretization=False, workers=w, max_runs=12) for w in (1, 2)
    ]
    a, b = fits
    assert a.model_runs == b.model_runs
    np.testing.assert_allclose(b.values, a.values, rtol=1e-8)
    for x, y in zip(a.curves, b.curves, strict=True):
        np.testing.assert_allclose(y.model_N, x.model_N, rtol=1e-8)


def test_a_curve_run_past_its_time_budget_counts_as_not_converged(monkeypatch):
    """A curve's runs after its first converged one have a time budget (20 times the longest converged
    run, at least 120 s): a run past it stops and gives NaN, which the search treats as a failed
    step, instead of crawling on; the first run has none."""
    assert runs.run_budget(0.0) == np.inf
    assert runs.run_budget(3.0) == runs.RUN_BUDGET_MIN_S == 120.0
    assert runs.run_budget(10.0) == 20.0 * 10.0
    m = model(1)
    first = m(THETA)
    assert all(np.all(np.isfinite(r.F)) for r in first)
    assert all(0 < t < 60 for t in m._longest)  # noqa: SLF001 - the budget's base, per curve
    monkeypatch.setattr(runs, "RUN_BUDGET_MIN_S", 0.0)
    monkeypatch.setattr(runs, "RUN_BUDGET_FACTOR", 1e-6)  # a budget spent at the first trial
    second = m(THETA + 0.1)
    assert all(np.all(np.isnan(r.F)) for r in second) and m.runs == 2
    assert all(0 < t < 60 for t in m._longest)  # noqa: SLF001 - a run that failed does not raise it


class _RungModel:
    """A stand-in for :class:`runs.CurveModel`: each rung's estimated relative force error from a table."""

    def __init__(self, cfs: list[CurveFit], rel_by_rung: list[dict[int, float]]) -> None:
        self.cfs, self.rel_by_rung, self.calls = cfs, rel_by_rung, []

    def __call__(self, theta, check=False, probe=False):
        self.calls.append([cf.level for cf in self.cfs])
        out = []
        for cf, rel in zip(self.cfs, self.rel_by_rung, strict=True):
            F = np.ones(len(cf.u_mm))
            out.append(runs.Run(F, np.zeros((len(F), 2)), F[:0], F[:0], F[:0], F[:0], rel[cf.level] * F, F))
        return out


@pytest.mark.parametrize(
    ("rel", "stays", "probed"),
    [
        # no rung vouches (a state near a limit point): two rungs tried, the first kept, not the sixth
        ({1: np.inf, 2: np.inf, 3: np.inf, 4: np.inf, 5: np.inf}, 1, [1, 2]),
        # the estimate falls, then rises on two rungs in a row: the best one is kept
        ({1: 0.05, 2: 0.02, 3: 0.03, 4: 0.04, 5: 0.001}, 2, [1, 2, 3, 4]),
        # one rung that does not improve is let pass, and the next meets the target
        ({1: 0.05, 2: 0.06, 3: 0.005, 4: 0.001, 5: 0.001}, 3, [1, 2, 3]),
    ],
)
def test_a_curve_no_rung_vouches_for_stops_climbing_on_its_best_rung(rel, stays, probed):
    """The rung climb of a fit ends at the second rung in a row that does not improve on the best
    estimate, as the accuracy ladder of ``ngbet run`` does: finer rungs would cost a run each for
    nothing (the balanced twill's frame, fitted, cannot be vouched for at 45 degrees on any rung:
    five probes and a check of 3-9 minutes each). The curve stays on its best rung, the first tried
    where none vouched."""
    curve = MeasuredCurve(np.linspace(5.0, 50.0, 10), np.linspace(1.0, 10.0, 10), "stand-in")
    cf = CurveFit(curve, scene(), curve.u_mm, curve.force_N, np.ones(10))
    other = CurveFit(curve, scene(), curve.u_mm, curve.force_N, np.ones(10))
    m = _RungModel([cf, other], [rel, {1: 0.02, 2: 0.005}])
    levels = runs.first_levels(m, [cf, other], np.zeros(2), 0.01)  # type: ignore[arg-type]
    assert levels == [stays, 2]
    assert [c[0] for c in m.calls] == probed
    assert cf.climb.ended is (stays != 3)
    if stays == 3:
        return
    assert cf.climb.reason.endswith(f"the curve stays on rung {stays}")
    assert ("cannot vouch" in cf.climb.reason) is (rel[1] == np.inf)
    # the terminal summary says why this curve misses the target, not "raise --max-runs"
    cf.level, cf.model_N, cf.force_error_N = stays, np.ones(10), np.full(10, rel[stays])
    other.level, other.model_N, other.force_error_N = 2, np.ones(10), np.full(10, 0.005)
    result = SimpleNamespace(
        converged=True,
        names=[],
        curves=[cf, other],
        model_runs=3,
        wall_s=1.0,
        target_error=0.01,
        se_log=np.zeros(0),
        values=np.zeros(0),
        at_bound=[],
        undetermined={},
        at_zero={},
        held={},
    )
    lines = [ln for ln in summary(result, Path("out")).splitlines() if "above --accuracy" in ln]
    said = f"  {cf.label}: discretization error above --accuracy 0.01: {cf.climb.reason} (fit.json: accuracy)"
    assert lines == [said]
