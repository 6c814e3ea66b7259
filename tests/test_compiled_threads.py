"""solver.threads: the thread policy, and a threaded assembly that gives the serial tangent."""

import ngsolve as ngs
import numpy as np
import pytest

from ngbet import run as ngbet_run
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics import linear
from ngbet.runner import threads
from ngbet.runner.settings import continuum_solver
from ngbet.scene.document import default_scene


@pytest.mark.parametrize(
    ("n", "model", "load", "expected"),
    [
        (3, "continuum", 0.0, (3, 3)),  # an integer: the run and its assemblies alike
        (1, "continuum", 0.0, (1, 1)),
        ("auto", "continuum", 0.2, (1, 2)),  # 1.8 idle cores: the assembly on both
        ("auto", "continuum", 0.6, (1, 1)),  # 1.4 idle cores: below IDLE_CORES_FOR_THREADS
        ("auto", "continuum", 3.0, (1, 1)),  # a busy machine
        ("auto", "discrete", 3.0, (2, 2)),  # the network: all cores
    ],
)
def test_thread_policy(n, model, load, expected):
    assert threads.thread_policy(n, model, cores=2, load=load) == expected


def test_auto_threads_run_serial_and_assemble_in_their_own_task_manager(monkeypatch):
    """With fewer run threads than assembly threads no TaskManager is held for the run (NGSolve's
    parallel loops then run in the calling thread), and the assembly is told its thread count."""
    monkeypatch.setattr(threads, "thread_policy", lambda n, model: (1, 2))
    seen = []
    with threads.ngsolve_threads(default_scene()):
        seen.append(linear._ASSEMBLY_THREADS.get())
    assert seen == [2]
    assert linear._ASSEMBLY_THREADS.get() == 0


def _problem() -> ContinuumSolver:
    pr = continuum_solver(
        ContinuumProblem(
            default_scene().with_changes(**{"discretization.mesh_size_mm": 20.0, "solver.compile": "interpret"})
        )
    )
    pr.state.set_load(0.02)
    free = pr.problem.free_all
    pr.x[free] += 1e-4 * np.random.default_rng(0).standard_normal(int(free.sum()))
    return pr


def test_threaded_assembly_gives_the_serial_tangent():
    """Two threads assemble the same condensed Newton matrix as one, to round-off of its entries
    (only the order of the sparse adds may differ), and the same corrections follow."""
    pr = _problem()
    r = pr.residual()
    ngs.SetNumThreads(1)
    pr.factorize()
    A1, dx1 = np.array(pr.linear.mat.AsVector()), pr.solve(r)
    try:
        ngs.SetNumThreads(2)
        with linear.assembly_threads(2):
            pr.factorize()
    finally:
        ngs.SetNumThreads(1)
    A2, dx2 = np.array(pr.linear.mat.AsVector()), pr.solve(r)
    assert np.abs(A2 - A1).max() <= 1e-14 * np.abs(A1).max()
    assert np.abs(dx2 - dx1).max() <= 1e-10 * np.abs(dx1).max()
    assert pr.counts["factorizations"] == 2


def test_a_run_with_threaded_assembly_gives_the_serial_forces(monkeypatch, tmp_path, coarse_scene):
    """The whole run with its assemblies on two threads and the rest serial: the same forces as
    one thread throughout (the tangents agree to round-off, Newton converges to the same
    tolerance), and summary.json says how the threads were used."""
    scene = coarse_scene(**{"discretization.mesh_size_mm": 20.0, "outputs.error_estimate": "off"})
    serial = ngbet_run.run(scene, tmp_path / "serial")
    monkeypatch.setattr(threads, "thread_policy", lambda n, model: (1, 2))
    split = ngbet_run.run(scene.with_changes(**{"solver.threads": "auto"}), tmp_path / "split")
    assert (serial["threads"], serial["assembly_threads"]) == (1, 1)
    assert (split["threads"], split["assembly_threads"]) == (1, 2)
    f1 = np.loadtxt(tmp_path / "serial" / "results.csv", delimiter=",", skiprows=1, usecols=_force_column(tmp_path))
    f2 = np.loadtxt(tmp_path / "split" / "results.csv", delimiter=",", skiprows=1, usecols=_force_column(tmp_path))
    assert len(f1) == len(f2) >= 2
    assert np.abs(f2 - f1).max() <= 1e-9 * np.abs(f1).max()


def _force_column(root) -> int:
    return (root / "serial" / "results.csv").read_text().splitlines()[0].split(",").index("force_N")


def test_a_run_holds_the_blas_pools_to_one_thread():
    """Inside a run every BLAS pool of the process (numpy's and NGSolve's OpenBLAS, cvxopt's where
    CHOLMOD is installed, one thread per core by default) has one thread, and gets its own count
    back afterwards."""
    import numpy  # noqa: F401  (numpy's BLAS is loaded)
    from threadpoolctl import threadpool_info

    from ngbet.runner.threads import ngsolve_threads
    from ngbet.scene.document import Scene

    before = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    assert before  # a BLAS library is loaded, so the check below checks something
    with ngsolve_threads(Scene()):
        inside = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
        assert set(before) <= set(inside) and set(inside.values()) == {1}, inside
    after = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    assert {k: after[k] for k in before} == before
