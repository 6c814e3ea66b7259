"""The whole ``ngbet run`` command: the plot process that draws the force plot beside the solve."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ngbet import plot_process
from ngbet.figures.run import draw_force, start_plot
from ngbet.run_folder import OutputError

pytest.importorskip("matplotlib")
ROWS = (
    "step,u0_mm,force_N,dforce_du0_N_per_mm,double_force_Nm,force_error_N\n"
    "1,16.0,22.15,1.589,0.908,0.05\n2,37.0,61.28,2.110,2.313,0.1\n3,56.0,107.37,2.813,4.016,0.14\n"
)


def run_folder(path: Path, scene: str = "") -> Path:
    """A run folder holding a results.csv with three steps of the default scene's columns (and ``scene``)."""
    path.mkdir(parents=True)
    (path / "results.csv").write_text(ROWS)
    if scene:
        (path / "scene.toml").write_text(scene)
    return path


def pixels(png: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(png)


def test_the_plot_process_draws_the_figure_of_the_run_itself(tmp_path, monkeypatch):
    """Same pixels as drawn in this process (one function draws both), the same PDF (written by its child)."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")  # matplotlib's PDF then has no time in it
    pdf = '[outputs]\nfigure_formats = ["png", "pdf"]\n'  # the scene asks for PDF files too
    here = draw_force(run_folder(tmp_path / "here", pdf))
    proc = plot_process.PlotProcess()
    try:
        there = proc.plot(run_folder(tmp_path / "there", pdf))
    finally:
        proc.close()
    assert there == (tmp_path / "there" / "force.png").resolve() and (tmp_path / "there" / "force.pdf").exists()
    np.testing.assert_array_equal(pixels(there), pixels(here))
    assert (tmp_path / "there" / "force.pdf").read_bytes() == (tmp_path / "here" / "force.pdf").read_bytes()
    assert not (tmp_path / "there" / "force.svg").exists()


def test_a_dead_plot_process_leaves_the_drawing_to_the_run(tmp_path, monkeypatch):
    """Nothing is lost: the process killed, the run draws the figure itself."""
    monkeypatch.setenv(plot_process.ENV, "always")
    monkeypatch.delitem(sys.modules, "ngsolve", raising=False)  # as in ngbet run before the solve
    with plot_process.plot_process(True) as proc:
        assert proc is not None and plot_process.active() is proc
        proc.proc.kill()
        proc.proc.wait()
        png = start_plot(run_folder(tmp_path / "run"), service=plot_process.active())()
    assert png == tmp_path / "run" / "force.png" and png.stat().st_size > 1000
    assert plot_process.active() is None and proc.proc.returncode is not None


def test_a_failed_drawing_is_reported_by_the_plot_process(tmp_path):
    proc = plot_process.PlotProcess()
    try:
        with pytest.raises(plot_process.PlotProcessError, match="results.csv"):
            proc.plot(tmp_path / "missing")
        assert proc.plot(run_folder(tmp_path / "run")) is not None  # and it serves the next request
    finally:
        proc.close()


def test_the_plot_process_is_forked_and_holds_no_descriptor_of_the_run(tmp_path, monkeypatch):
    """Before NGSolve is imported the plot process is a fork of the run (no second interpreter), and it
    keeps no copy of the run's pipes and sockets: a socket closed here reads as closed at once (the
    interrupt watchdog ends on that), and the process still draws."""
    import socket

    monkeypatch.delitem(sys.modules, "ngsolve", raising=False)
    r, w = socket.socketpair()
    proc = plot_process.PlotProcess()
    try:
        assert not isinstance(proc.proc, subprocess.Popen) and proc.proc.pid != os.getpid()
        w.close()
        r.settimeout(10.0)
        assert r.recv(1) == b""  # end of file: the child holds no copy of w
        assert proc.plot(run_folder(tmp_path / "run")) == (tmp_path / "run" / "force.png").resolve()
    finally:
        proc.close()
        r.close()
    assert proc.proc.returncode is not None


def test_with_ngsolve_imported_the_plot_process_is_a_new_interpreter(tmp_path, monkeypatch):
    import ngsolve  # noqa: F401

    proc = plot_process.PlotProcess()
    try:
        assert isinstance(proc.proc, subprocess.Popen)
        assert proc.plot(run_folder(tmp_path / "run")) is not None
    finally:
        proc.close()


@pytest.mark.parametrize(
    ("choice", "load", "expected"),
    [
        ("never", 0.0, False),
        ("always", 99.0, True),
        ("auto", 0.0, True),
        ("auto", 1.5, True),
        ("auto", 1.6, False),
        ("sometimes", 0.0, True),
    ],
)  # 2 cores: auto while half a core is idle; an unknown choice is auto
def test_the_plot_process_runs_as_asked_and_in_auto_only_on_an_idle_core(monkeypatch, choice, load, expected):
    monkeypatch.setenv(plot_process.ENV, choice)
    monkeypatch.delitem(sys.modules, "ngsolve", raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert plot_process.wanted(True) is expected
    assert plot_process.wanted(False) is False  # no figure, no process


def test_no_plot_process_once_ngsolve_is_imported(monkeypatch):
    """Too late to overlap the imports with the solve: the run draws itself."""
    import ngsolve  # noqa: F401

    monkeypatch.setenv(plot_process.ENV, "always")
    assert plot_process.wanted(True) is False


@pytest.mark.parametrize("choice", ["always", "never"])
def test_ngbet_run_writes_the_same_files_with_and_without_the_plot_process(tmp_path, choice):
    out = tmp_path / "run"
    env = {**os.environ, plot_process.ENV: choice, "MPLBACKEND": "Agg"}
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngbet",
            "run",
            "--quiet",
            "--out",
            str(out),
            "--set",
            "loading.u0_mm=10",
            "--set",
            "loading.stops_mm=[]",
            "--set",
            "discretization.mesh_size_mm=20",
            "--set",
            "outputs.error_estimate='off'",
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert p.returncode == 0, p.stderr
    files = set(json.loads((out / "summary.json").read_text())["files"])
    assert {"force.png", "fields.vtu", "results.csv"} <= files and "force.pdf" not in files  # PNG by default
    assert (out / "force.png").stat().st_size > 1000


@pytest.mark.parametrize("with_process", [True, False])
def test_the_plot_is_asked_for_first_and_finished_even_when_a_later_file_fails(tmp_path, monkeypatch, with_process):
    """The run asks for its figure as soon as results.csv is complete and writes the fields while the
    plot process draws; when the fields' file fails (here: a full disk) the error, naming the file,
    still reaches the caller, and the figure is waited for: complete, never half-written, asked of
    the plot process before the fields when there is one."""
    from ngbet.run import run
    from ngbet.runner import continuum as crun
    from ngbet.scene.document import Scene

    asked: list[str] = []

    def vtk_fails(problem, path):
        asked.append("vtk")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(crun, "write_vtk", vtk_fails)
    monkeypatch.setenv(plot_process.ENV, "always")
    sc = Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 20.0,
            "outputs.error_estimate": "off",
            "loading.u0_mm": 20.0,
            "loading.stops_mm": [],
        }
    )
    out = tmp_path / "r"
    if with_process:  # the run's plot process, as ngbet run starts it (before NGSolve is imported)
        proc = plot_process.PlotProcess()
        real_request = proc.request
        monkeypatch.setattr(proc, "request", lambda *a, **k: (asked.append("plot"), real_request(*a, **k)))
        monkeypatch.setattr(plot_process, "_ACTIVE", [proc])
        try:
            with pytest.raises(OutputError, match=r"fields.vtu: No space left"):
                run(sc, out)
        finally:
            proc.close()
    else:
        with pytest.raises(OutputError, match=r"fields.vtu: No space left"):
            run(sc, out)
    assert asked == (["plot", "vtk"] if with_process else ["vtk"])
    assert pixels(out / "force.png").shape[0] > 100
