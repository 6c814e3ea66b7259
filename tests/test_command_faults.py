"""Faults around whole commands and the API, each ending clear with nothing lost.

Folders that studies, sweeps and fits write into; the API's Results and their folders (copies,
pickles, worker processes); full disks and file size limits; signals a terminal sends; ASCII
terminals; a deleted working folder. The scenes are tiny (20 mm mesh, u0 = 10 mm).
"""

from __future__ import annotations

import copy
import gc
import json
import os
import pickle
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import ngbet
from ngbet.cli import main
from ngbet.run import run
from ngbet.run_folder import OutputError
from ngbet.scene.document import Scene

pytestmark = pytest.mark.integration

TINY = {
    "outputs.vtk": False,
    "outputs.plot": False,
    "discretization.mesh_size_mm": 20.0,
    "discretization.corner_mesh_size_mm": 0.0,
    "discretization.order_u": 2,
    "loading.u0_mm": 10.0,
    "loading.stops_mm": [5.0],
}
TINY_SET = [f"--set={k}={v}" for k, v in TINY.items()]
SLOW_SET = [
    "--set=discretization.mesh_size_mm=20",
    "--set=discretization.corner_mesh_size_mm=0",
    "--set=discretization.order_u=2",
    "--set=outputs.vtk=false",
    "--set=outputs.plot=false",
    "--set=loading.first_step_mm=0.2",
    "--set=loading.max_step_mm=0.2",
    "--set=solver.grow_after=0",
]
ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg"}


def files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def ngbet_cli(*args: str, env: dict[str, str] | None = None, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ngbet", *args],
        capture_output=True,
        text=True,
        env={**ENV, **(env or {})},
        timeout=300,
        **kw,
    )


# ------------------------------------------------------------------------- folders of commands
@pytest.mark.parametrize("command", [["sweep", "material.alpha1=20,200"], ["study", "alpha1"]])
def test_a_study_into_the_users_folder_is_refused_before_anything_is_written(tmp_path, capsys, command):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.csv").write_text("u0_mm,force_N\n10,3.1\n")
    (mine / "report.md").write_text("# measured on Monday\n")
    before = files(mine)
    assert main([*command, "--quick", "--quiet", "--out", str(mine), "--cache", str(tmp_path / "c")]) == 3
    err = capsys.readouterr().err
    assert str(mine) in err and "not empty and not written by an ngbet study" in err and err.count("\n") == 1
    assert files(mine) == before and not (tmp_path / "c").exists()  # refused before the cache is touched


def test_a_sweep_into_a_run_folder_is_refused_and_the_run_reads_back_whole(tmp_path, capsys):
    out = tmp_path / "run"
    run(Scene().with_changes(**TINY), out)
    before = files(out)
    assert (
        main(["sweep", "material.alpha1=20", "--quick", "--quiet", "--out", str(out), "--cache", str(tmp_path / "c")])
        == 3
    )
    assert "an ngbet run folder" in capsys.readouterr().err
    assert files(out) == before
    r = ngbet.load_result(out)
    assert r.status == "ok" and list(r.u0_mm) == [2.0, 4.0, 5.0, 6.0, 8.0, 10.0]


def test_plot_only_on_another_studys_folder_is_refused(tmp_path, capsys):
    from ngbet.run_folder import OwnedFolder

    d = tmp_path / "alpha1"
    with OwnedFolder(d, "study", "alpha1"):
        (d / "meta.json").write_text(json.dumps({"study": "alpha1", "cases": []}))
        (d / "report.md").write_text("# alpha1's report\n")
    before = files(d)
    assert main(["sweep", "material.alpha1=20,200", "--quick", "--plot-only", "--out", str(d)]) == 3
    assert "the folder of the study 'alpha1', not of the study 'sweep'" in capsys.readouterr().err
    assert files(d) == before


def test_a_fit_into_a_folder_with_the_users_fit_is_refused_before_the_fit(tmp_path, capsys):
    d = tmp_path / "fit"
    d.mkdir()
    (d / "fit.json").write_text('{"mine": true}')
    (d / "fitted_scene.toml").write_text("# my scene\n")
    data = ROOT / "data" / "cao2008" / "cao2008_twill_unbalanced_100x200_UN.csv"
    scene = ROOT / "geometry" / "twintex_twill_unbalanced.toml"
    assert main(["fit", str(data), "--scene", str(scene), "--out", str(d), "--max-runs", "1", "--quiet"]) == 3
    assert "not empty and not written by an ngbet fit" in capsys.readouterr().err
    assert files(d) == {"fit.json": b'{"mine": true}', "fitted_scene.toml": b"# my scene\n"}


def test_a_fit_again_into_its_folder_removes_only_the_earlier_fits_figures(tmp_path, capsys):
    """A tabulated fit draws shear_table.png; a quadratic fit into the same folder draws none: the
    earlier fit's table figure goes (it would stand beside a fit it does not belong to), the user's
    notes stay."""
    d = tmp_path / "fit"
    data = str(ROOT / "data" / "cao2008" / "cao2008_twill_unbalanced_100x200_UN.csv")
    scene = str(ROOT / "geometry" / "twintex_twill_unbalanced.toml")
    main(["fit", data, "--scene", scene, "--out", str(d), "--max-runs", "1", "--quiet"])
    assert (d / "shear_table.png").exists()
    (d / "notes.md~").write_text("mine")
    main(
        [
            "fit",
            data,
            "--scene",
            scene,
            "--set",
            "effects.shear_law=quadratic",
            "--params",
            "material.K_sh",
            "--out",
            str(d),
            "--max-runs",
            "1",
            "--quiet",
        ]
    )
    assert "cannot use the output folder" not in capsys.readouterr().err  # its own folder: taken again
    assert sorted(p.name for p in d.iterdir()) == [
        ".ngbet-folder.json",
        "fit.json",
        "fit.png",
        "fitted_scene.toml",
        "notes.md~",
    ]
    assert Scene.from_toml(d / "fitted_scene.toml").effects.shear_law == "quadratic"


def test_a_set_of_the_key_a_study_varies_is_refused_before_any_case(tmp_path, capsys):
    assert (
        main(
            [
                "study",
                "alpha1",
                "--quick",
                "--quiet",
                "--set",
                "material.alpha1=5",
                "--out",
                str(tmp_path / "o"),
                "--cache",
                str(tmp_path / "c"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "material.alpha1 is what the alpha1 study varies (its cases set it to 20, 2000)" in err
    assert not list((tmp_path / "c").glob("*/case.json"))


def test_a_study_from_a_deleted_working_folder_names_it(tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    code = (
        "import os, sys\nos.chdir(sys.argv[1]); os.rmdir(sys.argv[1])\nfrom ngbet.cli import main\n"
        "sys.exit(main(['study', 'alpha1', '--quick', '--quiet']))"
    )
    p = subprocess.run([sys.executable, "-c", code, str(gone)], capture_output=True, text=True, env=ENV, timeout=120)
    assert p.returncode == 3, p.stderr
    assert "the current folder no longer exists" in p.stderr and p.stderr.count("\n") == 1


# ------------------------------------------------------------------------------ run folders
def test_a_file_that_cannot_be_removed_leaves_the_previous_run_whole(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    run(Scene().with_changes(**{**TINY, "outputs.vtk": True}), out)
    before = files(out)
    rename = os.rename

    def immutable(src, dst):  # chattr +i on one figure: it can be neither renamed nor removed
        if Path(src).name == "results.csv":
            raise PermissionError(1, "Operation not permitted")
        rename(src, dst)

    monkeypatch.setattr(os, "rename", immutable)
    assert main(["run", "--out", str(out), *TINY_SET, "--quiet"]) == 3
    assert "results.csv: cannot be removed" in capsys.readouterr().err
    assert files(out) == before and summary(out)["status"] == "ok"


def test_an_out_path_too_long_for_the_runs_files_is_refused_before_the_solve(tmp_path, capsys):
    deep = tmp_path
    while len(str(deep)) < 4000:
        deep = deep / ("d" * 200)
    deep = Path(str(deep)[:4040].rstrip("/"))
    assert main(["run", "--out", str(deep), *TINY_SET, "--quiet"]) == 3
    assert "choose a shorter --out" in capsys.readouterr().err
    assert not (deep / "results.csv").exists()


def test_a_file_size_limit_leaves_no_cut_file_and_says_failed(tmp_path):
    """ulimit -f 40 (kB): NGSolve's VTU writer stops at the limit without a word; the cut file is
    neither renamed into place nor listed, and the run says what happened (exit 3)."""
    out = tmp_path / "run"

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (40 * 1024, resource.RLIM_INFINITY))

    p = subprocess.run(
        [sys.executable, "-m", "ngbet", "run", "--out", str(out), *TINY_SET, "--set=outputs.vtk=true", "--quiet"],
        capture_output=True,
        text=True,
        env=ENV,
        preexec_fn=limit,
        timeout=300,
    )
    assert p.returncode == 3, p.stderr
    assert "fields.vtu: written incomplete" in p.stderr and "ulimit -f" in p.stderr
    s = summary(out)
    assert s["status"] == "failed" and "fields.vtu" in s["error"] and "fields.vtu" not in s["files"]
    assert not (out / "fields.vtu").exists() and all((out / n).is_file() for n in s["files"])
    assert len((out / "results.csv").read_text().splitlines()) == 1 + s["steps"]  # every converged step kept


def test_a_failed_run_keeps_the_warnings_its_scene_was_given(tmp_path, capsys):
    """order_u = 1 locks under the constraint phi = i8 (warned before the solve); on the default
    scene's corners, graded to 0.25 mm, its first load step finds no equilibrium. The failed run's
    summary.json keeps that warning, as a finished run's does: it is the reason of the failure."""
    out = tmp_path / "p1"
    assert main(["run", "--set", "discretization.order_u=1", "--out", str(out), "--quiet"]) == 1
    assert "order_u = 1 locks under the constraint" in capsys.readouterr().err
    s = summary(out)
    assert s["status"] == "failed" and s["last_converged_mm"] == 0.0
    assert [w for w in s["warnings"] if "order_u = 1 locks" in w] == [
        "order_u = 1 locks under the constraint phi = i8 (the force converges very slowly from above and the "
        "multiplier grows like 1/h); use order_u >= 2"
    ]


# ------------------------------------------------------------------------------- signals
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGUSR1])
def test_a_closed_terminal_or_a_user_signal_leaves_a_true_summary(tmp_path, sig):
    """A run started from a terminal (SIGHUP at its default, whatever the test runner's own, e.g.
    under nohup) stops at the signal: exit 130, summary.json interrupted and naming the signal, its
    steps those written to results.csv."""
    out = tmp_path / "run"
    p = subprocess.Popen(
        [sys.executable, "-m", "ngbet", "run", "--out", str(out), "--quiet", *SLOW_SET],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL),
    )
    try:
        t = 0.0
        while not (out / "results.csv").exists() or len((out / "results.csv").read_text().splitlines()) < 4:
            assert p.poll() is None and t < 120
            t += 0.05
            __import__("time").sleep(0.05)
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, err
    s = summary(out)
    assert s["status"] == "interrupted" and signal.Signals(sig).name in s["error"]
    rows = len((out / "results.csv").read_text().splitlines()) - 1
    assert s["steps"] == rows and s["last_converged_mm"] > 0


def test_a_run_under_nohup_goes_on_when_the_terminal_closes(tmp_path):
    """nohup ignores SIGHUP for the run it starts: the run keeps ignoring it (no interruption)."""
    out = tmp_path / "run"
    p = subprocess.Popen(
        [sys.executable, "-m", "ngbet", "run", "--out", str(out), "--quiet", *SLOW_SET, "--set=loading.u0_mm=10"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN),
    )
    try:
        while not (out / "results.csv").exists() or len((out / "results.csv").read_text().splitlines()) < 4:
            assert p.poll() is None
            __import__("time").sleep(0.02)
        p.send_signal(signal.SIGHUP)
        _, err = p.communicate(timeout=120)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert summary(out)["status"] == "ok" and summary(out)["u0_reached_mm"] == 10.0


def test_ctrl_c_right_after_a_snap_through_keeps_the_snap_in_the_summary(tmp_path, monkeypatch):
    """K_el = 1e7 Pa on a 10 mm mesh snaps at 53.0 mm; an interrupt while that row is written keeps it."""
    from ngbet.runner import continuum as continuum_run

    write = continuum_run._StepWriter.on_step

    def then_interrupt(self, info):
        write(self, info)
        if info.snap:
            raise KeyboardInterrupt("SIGINT")

    monkeypatch.setattr(continuum_run._StepWriter, "on_step", then_interrupt)
    scene = Scene().with_changes(
        **{
            **TINY,
            "discretization.mesh_size_mm": 10.0,
            "loading.stops_mm": [],
            "material.K_el": 1e7,
            "outputs.error_estimate": "off",
            "outputs.profile": False,
            "loading.u0_mm": 54.0,
            "solver.threads": 1,
        }
    )
    with pytest.raises(KeyboardInterrupt):
        run(scene, tmp_path / "r")
    s = summary(tmp_path / "r")
    assert s["status"] == "interrupted" and len(s["snaps"]) == 1
    assert s["snaps"][0]["u0_mm"] == pytest.approx(s["last_converged_mm"]) == pytest.approx(53.0, abs=0.1)
    assert s["snaps"][0]["energy_released_J"] > 0


# ------------------------------------------------------------------------------ terminals
def test_an_ascii_terminal_never_fails_a_run_and_the_scene_goes_to_its_file(tmp_path):
    for env in ({"PYTHONIOENCODING": "ascii"}, {"LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0"}):
        p = ngbet_cli("run", "--out", str(tmp_path / "r"), *TINY_SET, env=env)
        assert p.returncode == 0, p.stderr
        assert "force =" in p.stdout and "\\xb1" in p.stdout  # the ± as its escape
        with (tmp_path / "scene.toml").open("w") as fh:
            p = subprocess.run(
                [sys.executable, "-m", "ngbet", "scene"],
                stdout=fh,
                stderr=subprocess.PIPE,
                text=True,
                env={**ENV, **env},
                timeout=120,
            )
        assert p.returncode == 0, p.stderr
        text = (tmp_path / "scene.toml").read_text(encoding="utf-8")
        assert "½ K_s" in text and Scene.from_toml(tmp_path / "scene.toml") == Scene()


# ------------------------------------------------------------------------------------ the API
@pytest.fixture(scope="module")
def tiny_result():
    return ngbet.simulate(Scene().with_changes(**{**TINY, "outputs.vtk": True}))


def test_the_folder_of_a_live_result_is_never_run_into(tiny_result):
    with pytest.raises(OutputError, match="the temporary folder of a live Result"):
        ngbet.simulate(Scene().with_changes(**TINY), out=tiny_result.out)
    assert tiny_result.fields().n_points > 0 and tiny_result.scene.outputs.vtk


def test_a_copy_keeps_the_folder_for_as_long_as_it_lives(tiny_result):
    r = ngbet.simulate(Scene().with_changes(**{**TINY, "outputs.vtk": True}))
    out, n = r.out, r.fields().n_points
    deep, shallow = copy.deepcopy(r), copy.copy(r)
    del r
    gc.collect()
    assert deep.fields().n_points == n
    del deep
    gc.collect()
    assert shallow.fields().n_points == n
    del shallow
    gc.collect()
    assert not out.exists()  # the last copy took it


def test_a_pickled_result_brings_its_files_into_a_folder_of_its_own(tiny_result):
    back = pickle.loads(pickle.dumps(tiny_result))
    assert back.out != tiny_result.out and back.fields().n_points == tiny_result.fields().n_points
    assert list(back.force_N) == list(tiny_result.force_N)
    out = back.out
    del back
    gc.collect()
    assert not out.exists() and tiny_result.out.exists()


def test_process_pool_map_of_simulate_returns_results_whose_folders_exist(tmp_path):
    """The default (fork) pool after a scene ran in the parent: Netgen's mesher would hang the worker."""
    code = f"""
import sys, json
from concurrent.futures import ProcessPoolExecutor
import ngbet
s = ngbet.default_scene().with_changes(**{dict(TINY, **{"outputs.vtk": True})!r})
first = ngbet.simulate(s)
with ProcessPoolExecutor(2) as ex:
    rs = list(ex.map(ngbet.simulate, [s, s.with_changes(**{{"material.alpha1": 200.0}})]))
got = [[r.out.exists(), r.fields().n_points, float(r.force_N[-1])] for r in rs]
print(json.dumps([*got, float(first.force_N[-1])]))
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=240)
    assert p.returncode == 0, p.stderr
    (a, b, first) = json.loads(p.stdout)
    assert a[0] and b[0] and a[1] > 0 and a[2] == first and b[2] != first


def test_simulate_takes_a_scene_file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(Scene().with_changes(**TINY).to_toml())
    assert ngbet.simulate(path).scene == ngbet.simulate(str(path)).scene == Scene().with_changes(**TINY)
    with pytest.raises(TypeError, match="a Scene or the path of a scene file, not int"):
        ngbet.simulate(3)
