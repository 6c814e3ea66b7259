"""What the commands say on the terminal: one ``ngbet:`` line per warning, nothing on stdout with
``--quiet``, and a solver failure's cause and remedy."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import warnings

import pytest

from ngbet.cli import main
from ngbet.commands import exit_code
from ngbet.continuum.stability import EllipticityLoss, StabilityDiagnosis
from ngbet.errors import ConvergenceError
from ngbet.messages import messages
from ngbet.scene.document import SceneWarning

SMALL = [
    "--set",
    "discretization.mesh_size_mm=20",
    "--set",
    "loading.u0_mm=10",
    "--set",
    "loading.stops_mm=[]",
    "--set",
    "outputs.vtk=false",
    "--set",
    "outputs.plot=false",
]


@pytest.mark.integration
def test_a_scene_warning_is_one_ngbet_line_and_quiet_prints_nothing_else(tmp_path):
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngbet",
            "run",
            "--quiet",
            "--out",
            str(tmp_path / "run"),
            *SMALL,
            "--set",
            "discrete.spacing_mm=3",
        ],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout == ""
    # said once, although the scene is built more than once; no Python source line
    assert p.stderr.splitlines() == [
        "ngbet: model = 'continuum' does not read discrete.spacing_mm: these values have no effect"
    ]


def test_without_quiet_the_results_go_to_stdout(tmp_path, capsys):
    assert main(["run", "--out", str(tmp_path / "run"), *SMALL]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("ngbet: ok: u0 = 10 mm in ") and out[1].startswith("  u0 =  10.00 mm   force =")


def test_log_records_and_warnings_are_one_line_each_and_restored_after(capsys):
    before = warnings.showwarning
    with messages():
        for _ in range(2):  # said once
            logging.getLogger("ngbet.somewhere").warning("first line\n   second line")
        logging.getLogger("ngbet.somewhere").info("not shown")
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            for _ in range(2):
                warnings.warn(SceneWarning("a key\nwithout effect"), stacklevel=1)
            warnings.warn("a library's warning", RuntimeWarning, stacklevel=1)
    assert warnings.showwarning is before
    assert capsys.readouterr().err.splitlines() == [
        "ngbet: first line second line",
        "ngbet: a key without effect",
        "ngbet: RuntimeWarning: a library's warning",
    ]


def _ill_posed() -> ConvergenceError:
    """The failure of the paper's scene with alpha2 = 0 on a 10 mm mesh, as the diagnosis describes it."""
    loss = EllipticityLoss(family=2, area_mm2=1097.0, min_eigenvalue_Ksh=-29.75)
    detail = StabilityDiagnosis(
        u0_mm=48.1377,
        eigenvalues=(-1.2e-4, 8e-7, 2.2e-6),
        mode_class="discretization",
        ratio=1.0,
        location_mm=(195.0, 66.0),
        ellipticity_loss=(loss,),
    )
    return ConvergenceError(
        "load step cut below the minimum 0.05 mm on the way from 48.1377 mm to 56 mm",
        48.1377,
        diagnosis=detail.message(),
        detail=detail,
    )


def test_a_solver_failure_says_its_cause_and_remedy():
    code, msg = exit_code(_ill_posed())
    assert code == 1
    assert msg == (
        "the solver stopped after u0 = 48.1377 mm: load step cut below the minimum 0.05 mm on the way "
        "from 48.1377 mm to 56 mm; alpha2 = 0 leaves the model ill-posed for the compressed yarns of "
        "family 2 (1097 mm² lost ellipticity): give alpha2 > 0"
    )


@pytest.mark.parametrize(
    ("detail", "remedy"),
    [
        (
            StabilityDiagnosis(
                u0_mm=30.0, eigenvalues=(-1e-3,), mode_class="discretization", stabilization_K_Pa=(10.0, 20.0), K_el=2e6
            ),
            "raise effects.stabilization_K (now 10 to 20 Pa), e.g. to material.K_el = 2e+06 Pa",
        ),
        (
            StabilityDiagnosis(u0_mm=30.0, eigenvalues=(-1e-3,), mode_class="continuum"),
            "solver.path_following = 'auto' follows the path through it",
        ),
        (StabilityDiagnosis(u0_mm=30.0, eigenvalues=(1e-3,), mode_class="none"), None),
    ],
)
def test_each_diagnosis_names_its_remedy(detail, remedy):
    advice = detail.advice()
    assert advice.endswith(remedy) if remedy else advice == ""


@pytest.mark.integration
def test_a_solver_failure_names_its_cause_and_remedy_on_the_terminal(tmp_path):
    """Nearly inextensible yarns (K_el = 1e8 Pa) without the jamming barrier fold near 54.8 mm: no physical
    stable state lies past the fold (the descent would turn material inside out); the one line says so
    and names the remedy."""
    out = tmp_path / "run"
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
            "material.K_el=1e8",
            "--set",
            "effects.jamming=false",
            "--set",
            "discretization.mesh_size_mm=10",
            "--set",
            "outputs.vtk=false",
            "--set",
            "outputs.plot=false",
        ],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 1 and p.stdout == ""
    (line,) = p.stderr.splitlines()
    assert line.startswith("ngbet: the solver stopped after u0 = 54.7")
    assert "no physical stable state" in line and "effects.shear_law = 'locking'" in line
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"


def test_the_report_line_says_what_a_user_reads_not_the_solvers_counts(tmp_path):
    """No Newton or chord iteration counts (summary.json has them); a load without its error bar is named."""
    from ngbet.cli import _report

    (tmp_path / "results.csv").write_text("u0_mm,force_N,force_error_N\n37,61.2855,0.1\n56,107.3735,\n")
    summary = {
        "status": "ok",
        "u0_reached_mm": 56.0,
        "load_steps": 29,
        "wall_s": 2.5,
        "newton_iterations": 2,
        "chord_iterations": 82,
        "error_estimate_unreliable": {"56": "the enriched problem ..."},
        "scene": {"test": "bias_extension", "loading": {"stops_mm": [37.0]}},
    }
    lines = _report(summary, tmp_path).splitlines()
    assert lines[0] == f"ngbet: ok: u0 = 56 mm in 29 load steps, 2.50 s; results in {tmp_path}/"
    assert lines[1].endswith("force =   61.2855 N ± 0.1 N (estimated discretization error)")
    assert lines[2].endswith(
        "force =  107.3735 N (no error bar: the estimate could not vouch for this force; summary.json says why)"
    )


def test_the_report_gives_the_force_at_the_scenes_own_stops_in_its_tests_load(tmp_path):
    """A picture frame stopping at 46 mm: its line there, labelled with the crosshead travel d."""
    from ngbet.cli import _report

    (tmp_path / "results.csv").write_text("u0_mm,force_N,force_error_N\n37,1.5,\n46,2.5,0.01\n67,9.5,0.02\n")
    summary = {
        "status": "ok",
        "u0_reached_mm": 67.0,
        "wall_s": 1.0,
        "scene": {"test": "picture_frame", "loading": {"stops_mm": [46.0]}},
    }
    lines = _report(summary, tmp_path).splitlines()
    assert lines[0].startswith("ngbet: ok: d = 67 mm in 3 load steps")
    assert [ln.split("force")[0].strip() for ln in lines[1:]] == ["d =  46.00 mm", "d =  67.00 mm"]


def test_a_warning_that_asks_nothing_of_the_user_stays_in_summary_json(tmp_path, capsys):
    """The fabric scene's 25 mm mesh: its stable pair's multiplier oscillates (0.71 measured at 49.7 mm),
    which the force and displacements do not need: summary.json records it, the terminal does not say it."""
    from pathlib import Path

    scene = Path(__file__).resolve().parents[1] / "geometry" / "twintex_twill_unbalanced.toml"
    assert (
        main(
            [
                "run",
                str(scene),
                "--set",
                "outputs.plot=false",
                "--set",
                "outputs.error_estimate=off",
                "--quiet",
                "--out",
                str(tmp_path / "r"),
            ]
        )
        == 0
    )
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["multiplier_oscillation"] > 0.5 and any("multiplier oscillates" in w for w in s["warnings"])
    assert "oscillates" not in capsys.readouterr().err


def test_ngsolves_own_console_messages_are_off():
    """Some thousand forms in one process (a study's worker) made NGSolve print "no more timer available
    (biform_from_py), reusing last one"; with ngbet's continuum imported nothing is printed."""
    code = (
        "import ngbet.continuum, ngsolve as ngs\n"
        "from netgen.geom2d import unit_square\n"
        "V = ngs.H1(ngs.Mesh(unit_square.GenerateMesh(maxh=0.5)))\n"
        "u, v = V.TnT()\n"
        "for i in range(9000):\n"
        "    a = ngs.BilinearForm(V)\n"
        "    a += u * v * ngs.dx\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert done.stdout == "" and "timer" not in done.stderr, (done.stdout[-300:], done.stderr[-300:])


def test_the_locking_warning_names_the_stiffness_of_the_model_that_runs():
    """The network has no K_el: its yarns stretch with EA1 and EA2."""
    from ngbet.preflight import locking_warning
    from ngbet.scene.document import Scene

    sets = {"specimen.yarn_angle_deg": 30.0, "specimen.length_mm": 250.0, "loading.u0_mm": 20.0}
    continuum = locking_warning(Scene().with_changes(**sets))
    network = locking_warning(Scene().with_changes(**sets, model="discrete"))
    assert continuum is not None and continuum.endswith("must stretch (K_el = 7e+05 Pa) and the force rises steeply")
    assert network is not None and network.endswith("(EA1 = 5e+04 N, EA2 = 5e+04 N) and the force rises steeply")


def test_data_of_another_specimen_or_frame_than_the_runs_is_said(tmp_path, capsys):
    """``run --data`` draws a curve of its own specimen (or frame) beside the run's: the note says they differ."""
    import argparse

    from ngbet.cli import _measured
    from ngbet.scene.document import Scene

    bet = tmp_path / "bet.csv"
    bet.write_text("# specimen.width_mm = 100\n# specimen.length_mm = 200\ndisplacement_mm,force_N\n0,0\n2,3\n4,6.5\n")
    frame = tmp_path / "frame.csv"
    frame.write_text(
        "# test: picture-frame\n# picture_frame.frame_mm = 145\n# picture_frame.fabric_mm = 120\n"
        "shear_angle_deg,shear_force_N\n0,0\n10,1\n20,3\n"
    )
    args = argparse.Namespace(data=str(bet), specimen=None, columns=None, quiet=False)
    scene = Scene().with_changes(**{"specimen.width_mm": 100.0, "specimen.length_mm": 250.0})
    _measured(args, scene)
    _measured(args, scene.with_changes(**{"specimen.length_mm": 200.0}))
    pf = Scene().with_changes(
        **{"test": "picture_frame", "picture_frame.frame_mm": 216.0, "picture_frame.fabric_mm": 140.0}
    )
    _measured(argparse.Namespace(data=str(frame), specimen=None, columns=None, quiet=False), pf)
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"ngbet: data {bet}: measured on a 100 x 200 mm specimen, the run's is 100 x 250 mm: the figures compare "
        "different specimens",
        f"ngbet: data {frame}: measured in a frame of 145 mm with 120 mm of fabric, the run's is 216 mm with "
        "140 mm: the figure compares F_norm (Eq. 10) of different frames",
    ]


def test_summary_json_names_the_measured_curve_a_run_draws(tmp_path):
    """``run --data``: which file, and which bytes (the figures alone did not say)."""
    import hashlib
    import json

    from ngbet.output import RunWriter
    from ngbet.scene.document import Scene

    data = tmp_path / "m.csv"
    data.write_text("displacement_mm,force_N\n0,0\n2,3\n4,6.5\n")
    with RunWriter(tmp_path / "run", Scene()) as writer:
        writer.summary({}, "ok")
    with RunWriter(tmp_path / "run2", Scene(), data) as writer:
        writer.summary({}, "ok")
    assert "data" not in json.loads((tmp_path / "run" / "summary.json").read_text())
    assert json.loads((tmp_path / "run2" / "summary.json").read_text())["data"] == {
        "file": str(data.resolve()),
        "sha256": hashlib.sha256(data.read_bytes()).hexdigest(),
    }


def test_a_frame_run_that_stops_names_its_load_d():
    """A picture frame's load is the crosshead travel d (its progress bar and report say d): so does its stop."""
    from ngbet.commands import exit_code
    from ngbet.errors import ConvergenceError
    from ngbet.scene.physical import load_symbol

    exc = ConvergenceError("load step cut below the minimum", 84.4495)
    assert exit_code(exc, None, load_symbol("picture_frame"))[1] == (
        "the solver stopped after d = 84.4495 mm: load step cut below the minimum"
    )
    assert exit_code(exc)[1].startswith("the solver stopped after u0 = 84.4495 mm")
