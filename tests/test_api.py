"""The Python API (ngbet.simulate, Result), the example script, the commented scene, the version."""

from __future__ import annotations

import gc
import re
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ngbet
from ngbet.scene.document import Scene
from ngbet.scene_doc import commented_toml
from ngbet.tables import read_profiles, read_rows

ROOT = Path(__file__).resolve().parent.parent
SMALL = {"loading.u0_mm": 20.0, "loading.stops_mm": [10.0], "discretization.mesh_size_mm": 20.0}


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "run"
    return ngbet.simulate(ngbet.default_scene().with_changes(**SMALL), out), out


def test_result_holds_the_run_folder(small_run):
    r, out = small_run
    rows = read_rows(out / "results.csv")
    assert r.status == "ok" and r.out == out
    # the arrays are the files' numbers, step by step
    np.testing.assert_array_equal(r.u0_mm, [row["u0_mm"] for row in rows])
    np.testing.assert_array_equal(r.force_N, [row["force_N"] for row in rows])
    np.testing.assert_array_equal(r.double_force_Nm, [row["double_force_Nm"] for row in rows])
    np.testing.assert_array_equal(r.energy_J, [row["energy_J"] for row in rows])
    assert r.u0_mm[-1] == 20.0 and 10.0 in r.u0_mm
    assert r.gamma_centre_deg.shape == r.u0_mm.shape  # any column is an attribute
    with pytest.raises(AttributeError, match="force_N_per_m"):
        r.no_such_column  # noqa: B018
    X, uy = read_profiles(out / "profile.csv")[20.0]
    np.testing.assert_array_equal(r.profiles[20.0][0], X)
    np.testing.assert_array_equal(r.profiles[20.0][1], uy)
    assert r.scene == ngbet.default_scene().with_changes(**SMALL)


def test_run_csv_files_have_lf_line_endings(small_run):
    _, out = small_run
    for name in ("results.csv", "profile.csv"):
        text = (out / name).read_bytes()
        assert b"\r" not in text and text.count(b"\n") > 2


@pytest.mark.integration
def test_run_without_matplotlib_writes_everything_but_the_plot(tmp_path):
    """The core needs neither matplotlib nor pyvista: without them the run says so in one line."""
    code = (
        "import sys\n"
        "for m in ('matplotlib', 'pyvista'): sys.modules[m] = None\n"
        "from ngbet.cli import main\n"
        f"sys.exit(main(['run', '--quiet', '--out', {str(tmp_path / 'run')!r}, '--set', 'loading.u0_mm=10', "
        "'--set', 'loading.stops_mm=[]', '--set', 'discretization.mesh_size_mm=20']))"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0
    assert "no figures: matplotlib is not installed" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    files = {f.name for f in (tmp_path / "run").iterdir()}
    assert {"results.csv", "profile.csv", "summary.json", "fields.vtu", "scene.toml"} <= files
    assert "force.png" not in files


def test_result_to_csv_round_trip_with_lf(small_run, tmp_path):
    r, _ = small_run
    p = r.to_csv(tmp_path / "t.csv")
    assert b"\r\n" not in p.read_bytes()
    back = read_rows(p)
    np.testing.assert_array_equal([row["force_N"] for row in back], r.force_N)  # repr: no digits lost


def test_fields_in_mm_warp_to_the_clamp_displacement(small_run):
    """Coordinates and displacement share the unit mm: the warped moving clamp sits at L + u0."""
    pytest.importorskip("pyvista")
    r, _ = small_run
    m = r.fields()
    x0, x1, y0, y1, _, _ = m.bounds
    assert (x0, x1) == pytest.approx((0.0, 220.0), abs=1e-9) and (y0, y1) == pytest.approx((0.0, 70.0), abs=1e-9)
    u = np.asarray(m["displacement"])
    assert u.shape[1] == 3 and np.all(u[:, 2] == 0.0)
    clamp = np.isclose(np.asarray(m.points)[:, 0], 220.0)
    np.testing.assert_allclose(u[clamp, 0], 20.0, atol=1e-9)  # prescribed on the moving clamp
    assert m.warp_by_vector("displacement").bounds[1] == pytest.approx(240.0, abs=1e-9)
    assert "shear_angle_deg" in m.array_names


def test_simulate_without_out_keeps_its_folder_while_the_result_lives():
    r = ngbet.simulate(ngbet.default_scene().with_changes(**{**SMALL, "loading.stops_mm": []}))
    folder = r.out
    assert (folder / "fields.vtu").exists() and not (folder / "force.png").exists()
    assert r.force_N[-1] > 0
    del r
    gc.collect()
    assert not folder.exists()


def test_plot_draws_the_curve_and_the_steps(small_run):
    pytest.importorskip("matplotlib")
    r, _ = small_run
    ax = r.plot()
    curve, steps = ax.lines[:2]
    np.testing.assert_array_equal(steps.get_xdata(), np.r_[0.0, r.u0_mm])
    assert "converged steps" in steps.get_label()


def test_example_sweep(capsys):
    """examples/sweep.py: the S-shape grows with alpha1 (alpha2 = 20 Pa m^2: nearly none at alpha1 = alpha2)."""
    runpy.run_path(str(ROOT / "examples" / "sweep.py"), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    cases = [
        re.match(r"alpha1 = +(\S+) Pa m\^2: force +(\S+) N, max \|u_y\| on the mid-axis (\S+) mm", x)
        for x in lines[:-1]
    ]
    assert all(cases) and len(cases) == 3
    assert [float(m.group(1)) for m in cases] == [20.0, 200.0, 2000.0]
    amp = [float(m.group(3)) for m in cases]
    assert amp[0] < 0.1 * amp[1] < amp[1] < amp[2]
    assert lines[-1].startswith("table, figures and report:")


def test_commented_scene_reads_back_and_says_units_and_choices():
    discrete = {"model": "discrete", **{k: v for k, v in SMALL.items() if not k.startswith("discretization.")}}
    for scene in (ngbet.default_scene(), ngbet.default_scene().with_changes(**discrete)):
        text = commented_toml(scene)
        assert Scene.from_toml_string(text) == scene
    assert "allowed: 'lagrange', 'penalty'" in text and "Units: lengths in mm" in text and '"auto"' in text


def test_cli_scene_and_version():
    scene = subprocess.run([sys.executable, "-m", "ngbet", "scene"], capture_output=True, text=True, check=True)
    assert scene.stdout.startswith("# ngbet scene") and Scene.from_toml_string(scene.stdout) == ngbet.default_scene()
    v = subprocess.run([sys.executable, "-m", "ngbet", "--version"], capture_output=True, text=True, check=True)
    assert v.stdout.startswith(f"ngbet {ngbet.__version__} (git revision ")
    assert isinstance(ngbet.__revision__, str) and ngbet.__revision__


def test_every_result_array_carries_its_unit(small_run):
    """The arrays a Result offers by name end in a unit, as the columns of results.csv do."""
    r, _ = small_run
    units = ("_mm", "_N", "_Nm", "_J", "_deg", "_s", "_N_per_m", "_J_per_m", "_N_per_mm")
    named = [n for n, v in vars(type(r)).items() if isinstance(v, property) and n not in ("status",)]
    assert named and {n for n in named if not n.endswith(units)} == set()
