"""The study runner (cache, failures, parallel and dask execution, plot-only) and every study's --quick mode."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from ngbet.scene.document import Scene
from ngbet.studies import _common as C
from ngbet.study.collect import load
from ngbet.study.figures import plot_only
from ngbet.study.model import Study
from ngbet.study.runner import run_study

TINY = {
    "outputs.vtk": False,
    "outputs.plot": False,
    "discretization.mesh_size_mm": 20.0,
    "discretization.corner_mesh_size_mm": 0.0,
    "discretization.order_u": 2,
    "loading.u0_mm": 10.0,
    "loading.stops_mm": [5.0],
    "loading.output_every_mm": 0.0,
}
# a case whose solver must give up: one Newton iteration allowed and no step cutting possible
FAILING = {
    "loading.first_step_mm": 10.0,
    "loading.min_step_mm": 10.0,
    "loading.max_step_mm": 10.0,
    "solver.max_iterations": 1,
}


def tiny_study(cases):
    return Study(
        "tiny",
        Scene().with_changes(**TINY),
        cases,
        plot=lambda d: [_force_plot(d)],
        report=lambda d: f"{len(d.rows)} rows\n",
    )


def _force_plot(d):
    from ngbet.figures.style import subplots
    from ngbet.study.figures import savefig

    fig, ax = subplots()
    for c in d.cases():
        rows = d.case_rows(c["case"])
        ax.plot([r["u0_mm"] for r in rows], [r["force_N"] for r in rows])
    return savefig(fig, d.out, "force")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def test_cache_failure_and_added_case(tmp_path, cache):
    cases = [{C.P: 1}, {C.P: 2}, FAILING]
    d = run_study(tiny_study(cases), tmp_path / "a", cache=cache, progress=False)
    st = [c["status"] for c in d.cases()]
    assert st == ["ok", "ok", "failed"], d.cases()
    assert "minimum" in d.cases()[2]["error"]  # the solver's own message is kept
    assert d.meta["executor"]["mode"] == "process" and d.meta["executor"]["threads_per_case"] == 1
    assert d.meta["executor"]["cases_run"] == 3
    # every case has its rows; the failed one a row with its error, the varied keys are columns
    assert {int(r["case"]) for r in d.rows} == {0, 1, 2}
    assert C.P in d.rows[0] and "solver.max_iterations" in d.rows[0]
    assert math.isclose(d.at(1, 10.0, "force_N"), d.at(1, 10.0, "force_N_per_m") * 0.015, rel_tol=1e-12)
    # rerun: nothing computed, same numbers (the failed case is a cached result too)
    d2 = run_study(tiny_study(cases), tmp_path / "b", cache=cache, progress=False)
    assert d2.meta["executor"]["cases_run"] == 0 and d2.meta["executor"]["cases_cached"] == 3
    assert d2.at(1, 10.0, "force_N") == d.at(1, 10.0, "force_N")
    # one more case: one computed
    d3 = run_study(tiny_study(cases + [{C.P: 3}]), tmp_path / "c", cache=cache, progress=False)
    assert d3.meta["executor"]["cases_run"] == 1 and d3.meta["executor"]["cases_cached"] == 3
    # retry_failed reruns only the failed case
    d4 = run_study(tiny_study(cases), tmp_path / "d", cache=cache, progress=False, retry_failed=True, workers=1)
    assert d4.meta["executor"]["cases_run"] == 1 and d4.cases()[2]["status"] == "failed"
    # the same scene written with an int mesh size is the same case
    d5 = run_study(tiny_study([{C.P: 1, C.H: 20}]), tmp_path / "e", cache=cache, progress=False)
    assert d5.meta["executor"]["cases_run"] == 0


def test_a_case_validation_refuses_refuses_the_study_before_any_case_runs(tmp_path):
    from ngbet.scene.validate import SceneError

    with pytest.raises(SceneError) as exc:
        run_study(tiny_study([{C.P: 1}, {"material.K_el": -1.0}]), tmp_path / "s", cache=tmp_path / "c", workers=1)
    assert str(exc.value) == (
        "the tiny study has a case ngbet refuses: case 1 (material.K_el = -1): scene key 'material.K_el' = -1.0: "
        "must be a finite number >= 0"
    )
    assert not (tmp_path / "s").exists() and not (tmp_path / "c").exists()


def test_plot_only_redraws_from_csv_without_cache(tmp_path, cache):
    own_cache = tmp_path / "cache"
    shutil.copytree(cache, own_cache)
    out = tmp_path / "s"
    run_study(tiny_study([{C.P: 1}, {C.P: 2}]), out, cache=own_cache, progress=False)
    (out / "force.png").unlink()
    (out / "report.md").unlink()
    shutil.rmtree(own_cache)  # nothing to solve from: plot-only must use the CSV files alone
    d = plot_only(tiny_study([{C.P: 1}, {C.P: 2}]), out)
    assert (out / "force.png").stat().st_size > 1000 and (out / "force.pdf").exists()
    assert (out / "report.md").read_text() == f"{len(d.rows)} rows\n"


def test_dask_local_cluster_gives_the_local_results(tmp_path, cache):
    from distributed import LocalCluster

    cases = [{C.P: 1}, {C.P: 2}, FAILING]
    local = run_study(tiny_study(cases), tmp_path / "local", cache=cache, progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        d = run_study(
            tiny_study(cases),
            tmp_path / "dask",
            cache=tmp_path / "dask_cache",
            scheduler=cluster.scheduler_address,
            progress=False,
        )
    assert d.meta["executor"]["mode"] == "dask" and d.meta["executor"]["cases_run"] == 3
    assert [c["status"] for c in d.cases()] == [c["status"] for c in local.cases()]
    for i in (0, 1):
        for u0 in (5.0, 10.0):  # one NGSolve thread per case in both: the same numbers
            assert math.isclose(d.at(i, u0, "force_N"), local.at(i, u0, "force_N"), rel_tol=1e-10)
    # the run folders came back from the workers into the client's cache
    assert all((tmp_path / "dask_cache" / c["key"] / "case.json").exists() for c in d.cases())
    assert all((tmp_path / "dask_cache" / c["key"] / "results.csv").exists() for c in d.cases()[:2])


# --- the studies' quick modes -------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("quick_cache")


@pytest.fixture(autouse=True)
def every_figure_inside_its_canvas(monkeypatch):
    """Every figure a study writes in these tests has every text inside its canvas (renderer boxes)."""
    pytest.importorskip("matplotlib")
    from ngbet.figures import style  # the style module (its context manager is in_style)
    from ngbet.figures.style import texts_outside

    written = {}
    real = style.FigureWriter.save

    def save(self, fig, stem):
        written[Path(stem).name] = texts_outside(fig)
        return real(self, fig, stem)

    monkeypatch.setattr(style.FigureWriter, "save", save)
    yield written
    assert {name: bad for name, bad in written.items() if bad} == {}


def run_quick(name, tmp_path, quick_cache):
    import importlib

    from ngbet.study.command import build_study

    mod = importlib.import_module(f"ngbet.studies.{name}")
    return mod, run_study(
        build_study(mod.build, True, cache=quick_cache), tmp_path / name, cache=quick_cache, progress=False
    )


def test_quick_penalty_p(tmp_path, quick_cache):
    mod, d = run_quick("penalty_p", tmp_path, quick_cache)
    assert all(c["status"] == "ok" for c in d.cases())
    a = mod.analyse(d, mod.QUICK, True)
    for p in (1, 2):
        pen = sorted((r for r in a["rows"] if r["p"] == p and r["method"] == "penalty"), key=lambda r: r["K"])
        errs = [r["err_pen"] for r in pen]
        assert all(e2 < e1 for e1, e2 in zip(errs[:-1], errs[1:], strict=True)), errs  # monotone in K
        # the mixed penalty converges like 1/K once K >> alpha1/h^2 = 5e6 Pa (h = 20 mm)
        e9, e10 = (r["err_pen"] for r in pen if r["K"] in (1e9, 1e10))
        assert -1.05 < math.log10(e10 / e9) < -0.95
    # discretization error: p = 2 is better than p = 1 against the Richardson reference
    lag = {r["p"]: r["err_ref"] for r in a["rows"] if r["method"] == "lagrange"}
    assert lag[2] < 0.3 * lag[1]
    assert {r["case"] for r in a["rows"]}.isdisjoint(a["ref_cases"])  # the reference family is not a (h, p) row
    # p = 1 locks under the constraint: its runs warn, and meta.json keeps the warnings per case
    p1 = d.case(C.lagrange(20.0, 1))
    assert any("locks" in w for w in d.cases()[p1]["warnings"])
    for f in ("penalty_profiles", "penalty_error", "discretization_error"):
        assert (d.out / f"{f}.png").exists() and (d.out / f"{f}.pdf").exists()
    text = (d.out / "report.md").read_text()
    assert "slope" in text
    # one mesh size in the quick grid: the order in h is said to be unavailable, no sentence left open
    assert "Observed order in h: none, the grid has one mesh size (h = 20 mm)." in text
    assert not any(line.rstrip().endswith(":") for line in text.splitlines() if not line.startswith("#"))


def test_quick_work_precision(tmp_path, quick_cache):
    mod, d = run_quick("work_precision", tmp_path, quick_cache)
    a = mod.analyse(d, mod.QUICK, True)
    pts = [p for p in a["pts"] if p["status"] == "ok"]
    assert len(pts) == len(d.cases())
    pts = [p for p in pts if not p["ref_case"]]  # the front is of the study's own settings
    front = [p for p in pts if p["pareto_err_F"]]
    # the Pareto front: each point is cheaper than any other point at least as accurate
    for p in front:
        assert not any(q["time"] < p["time"] and q["err_F"] <= p["err_F"] for q in pts if q is not p)
    assert mod.cheapest(a, "err_F", 0.10) is not None
    assert "Cheapest settings" in (d.out / "report.md").read_text()
    assert (d.out / "work_precision.png").exists()


def test_quick_alpha1(tmp_path, quick_cache):
    mod, d = run_quick("alpha1", tmp_path, quick_cache)
    rows = {r["alpha1"]: r for r in mod.analyse(d, True)}
    # alpha1 = alpha2: mirror symmetry about Y = W/2, no S-shape; alpha1 = 100 alpha2: the S-shape
    assert rows[20.0]["max_uy"] < 1e-4 and rows[2000.0]["max_uy"] > 1.0
    # half-turn symmetry: u_y odd about X = L/2 (to the mesh's asymmetry)
    assert rows[2000.0]["odd_residual"] < 0.1 * rows[2000.0]["max_uy"]


def test_quick_kel(tmp_path, quick_cache):
    mod, d = run_quick("kel", tmp_path, quick_cache)
    w = sorted(mod.widths(d), key=lambda r: r["K_el"])
    # softer yarns stretch instead of shearing: less shear at the centre, a wider centre
    assert w[0]["gamma_c"] < w[1]["gamma_c"] and w[0]["width_mm"] > w[1]["width_mm"]
    assert all(0 < r["width_mm"] < 70 for r in w)
    assert (d.out / "kel_outlines.png").exists() and len(d.tables["outlines"]) > 400


def test_quick_curves(tmp_path, quick_cache):
    mod, d = run_quick("curves", tmp_path, quick_cache)
    a = mod.analyse(d)
    assert len(a["u0"]) == 8 and all(f2 > f1 for f1, f2 in zip(a["F"][:-1], a["F"][1:], strict=True))
    # reaction = dE/du0 (envelope theorem) to the O(step^2) error of the central difference
    assert a["envelope_max_rel"] < 0.02
    assert (d.out / "curves.png").exists()


def test_quick_maps(tmp_path, quick_cache):
    mod, d = run_quick("maps", tmp_path, quick_cache)
    rows = d.tables["maps"]
    assert [r["u0_mm"] for r in rows] == [10.0, 20.0]
    assert 0.0 < rows[0]["gamma_max_deg"] < rows[1]["gamma_max_deg"] < 90.0  # the shear grows with the load
    assert (d.out / "map.png").stat().st_size > 20000 and (d.out / "map.pdf").exists()
    assert all((d.out / f"map_{u}mm.npz").exists() for u in ("10", "20"))


def test_quick_compare(tmp_path, quick_cache, monkeypatch, figures):
    from ngbet.studies import compare

    capture(monkeypatch, compare, figures)
    mod, d = run_quick("compare", tmp_path, quick_cache)
    assert [mod.label(c["params"]) for c in d.cases()] == ["continuum", "discrete", mod.EQUIVALENT]
    assert all(c["status"] == "ok" for c in d.cases())
    a = mod.analyse(d, True)
    assert a["continuum"]["F20"] > 0 and a["discrete"]["F20"] > 0
    # the network equivalent to the continuum bends the specimen the same way (u_y(L/4) < 0)
    assert a["continuum"]["uyq20"] < 0 and a[mod.EQUIVALENT]["uyq20"] < 0, a
    assert "Bending direction" in (d.out / "report.md").read_text()
    assert (d.out / "compare_curves.png").exists() and (d.out / "compare_maps.png").exists()
    # one colour scale for the continuum's maps and the networks': the same norm, symmetric when signed
    norms = {
        (c.norm.vmin, c.norm.vmax)
        for ax in figures["compare_maps"].axes[:4]
        for c in ax.collections
        if c.get_array() is not None
    }
    assert len(norms) == 1
    lo, hi = norms.pop()
    assert lo == 0.0 or lo == -hi


def test_cli_study(tmp_path, quick_cache, capsys):
    from ngbet.cli import main

    assert main(["study", "list"]) == 0
    assert "penalty_p" in capsys.readouterr().out
    assert main(["study", "nonsense"]) == 2
    out = tmp_path / "a1"
    capsys.readouterr()
    assert main(["study", "alpha1", "--quick", "--quiet", "--out", str(out), "--cache", str(quick_cache)]) == 0
    quiet = capsys.readouterr()
    assert quiet.out == "" and not quiet.err  # --quiet: nothing; what --quick leaves out is in report.md
    assert main(["study", "alpha1", "--quick", "--plot-only", "--out", str(out)]) == 0
    assert "# alpha1 sweep" in capsys.readouterr().out  # without --quiet: the report too
    assert load(out).meta["study"] == "alpha1"


# --- study outputs right by construction ---------------------------------------------------------
def test_find_is_exact_a_case_with_one_more_key_is_another_case(tmp_path):
    from ngbet.study.model import StudyData

    uniform = C.lagrange(20.0, 2)
    graded = C.lagrange(20.0, 2, 0.5)
    extra = {**uniform, "outputs.error_estimate": "off"}
    data = StudyData(
        tmp_path,
        [],
        [],
        {},
        {"cases": [{"case": 0, "params": graded}, {"case": 1, "params": extra}, {"case": 2, "params": uniform}]},
    )
    assert data.find(**uniform) == [2] and data.case(uniform) == 2
    assert data.case(graded) == 0 and data.case(extra) == 1
    assert data.case({**uniform, C.H: 20}) == 2  # 20 and 20.0 are one value
    assert data.case(C.lagrange(10.0, 2)) is None


@pytest.fixture(scope="module")
def figures():
    """The figures a study draws, kept open (savefig closes them) to be measured."""
    return {}


def capture(monkeypatch, mod, figures):
    from ngbet.study.figures import savefig

    def keep(fig, out, name):
        figures[name] = fig
        return savefig(fig, out, name)

    monkeypatch.setattr(mod, "savefig", keep)


def labels_inside(fig):
    """Every text of the figure inside its canvas, measured with the renderer's bounding boxes."""
    from ngbet.figures.style import texts_outside

    assert texts_outside(fig) == []


def test_quick_reference_rows_are_their_own_cases(tmp_path, quick_cache, monkeypatch, figures):
    from ngbet.studies import reference as R

    capture(monkeypatch, R, figures)
    mod, d = run_quick("reference", tmp_path, quick_cache)
    a = mod.analyse(d, True)
    (uniform,) = a["fam"]["uniform"]
    # the uniform 20 mm mesh at p = 2, not the 0.5 mm-graded case whose parameters contain its own
    assert d.cases()[uniform["case"]]["params"] == {**C.lagrange(20.0, 2), **R.OFF}
    assert uniform["dofs"] < min(p["dofs"] for p in a["fam"]["reference"])
    F0 = a["ref"][20.0]["force_N"]
    assert uniform["err"] == pytest.approx(abs(d.at(uniform["case"], 20.0, "force_N") - F0) / F0, rel=1e-12)
    assert uniform["err"] > 0.02  # a coarse uniform mesh is percent-level off, far from the graded 0.35 %
    labels_inside(figures["reference_convergence"])


def test_quick_work_precision_colours_marks_and_report(tmp_path, quick_cache, monkeypatch, figures):
    from matplotlib.collections import PathCollection

    from ngbet.studies import work_precision as W

    capture(monkeypatch, W, figures)
    mod, d = run_quick("work_precision", tmp_path, quick_cache)
    a = mod.analyse(d, mod.QUICK, True)
    own = [p for p in a["pts"] if p["status"] == "ok" and not p["ref_case"]]
    refs = [p for p in a["pts"] if p["ref_case"]]
    assert len(refs) == 3 and all("pareto_err_F" not in p for p in refs)  # never on the front
    text = (d.out / "report.md").read_text()
    all_cases = text.split("## All cases")[1].split("## The reference family")[0]
    assert all_cases.count("\n| h=") == len(own)  # the reference cases are listed apart, not as 0 % errors
    assert "- Discretization:" in text and "- Reference:" in text and "Quick mode, leaves out:" in text
    fig = figures["work_precision"]
    ax = fig.axes[0]
    norm = fig.axes[-1]._colorbar.mappable.norm  # the colour bar's own scale
    dofs = [p["dofs"] for p in own]
    assert norm.vmin == pytest.approx(min(dofs)) and norm.vmax == pytest.approx(max(dofs), rel=1e-6)
    cmap = W.C.colormap()
    for coll in (c for c in ax.collections if isinstance(c, PathCollection)):
        for (t, y), fc, ec in zip(coll.get_offsets(), coll.get_facecolors(), coll.get_edgecolors(), strict=False):
            p = next(q for q in own if q["time"] == pytest.approx(t) and max(q["err_F"], 0) == pytest.approx(y))
            colour = fc if fc[3] > 0 else ec  # filled above the bound, open below it
            assert colour[:3] == pytest.approx(cmap(norm(p["dofs"]))[:3], abs=1e-6)  # one scale for all families
            assert (fc[3] == 0) == (p["err_F"] < a["unc_F"])
    below = [p for p in own if p["err_F"] < a["unc_F"]]
    assert below  # the graded 1 mm case: its error is below the reference's bound, drawn at its value
    ys = [y for c in ax.collections if isinstance(c, PathCollection) for _, y in c.get_offsets()]
    assert not any(y == pytest.approx(a["unc_F"], rel=1e-9) for y in ys)
    labels_inside(fig)
    labels_inside(figures["work_precision_dofs"])


def test_one_reference_per_scene_across_studies(tmp_path, quick_cache):
    _, ref = run_quick("reference", tmp_path, quick_cache)
    mod, pen = run_quick("penalty_p", tmp_path, quick_cache)
    from ngbet.studies import reference as R

    a = mod.analyse(pen, mod.QUICK, True)
    assert a["ref"]["force_N"] == R.reference(ref, True)[20.0]["force_N"]
    assert a["ref1"]["force_N"] == R.reference(ref, True)[10.0]["force_N"]
    # and a study that does not run the family finds the same value in the cache
    _, al = run_quick("alpha1", tmp_path, quick_cache)
    text = (al.out / "report.md").read_text()
    F_ref = R.reference(ref, True)[20.0]["force_N"]
    assert f"F(20 mm) = {F_ref:.4f} N" in text
    # its own case of the base scene (alpha1 = 2000, the default) measured against it
    dev = 100 * (al.at(1, 20.0, "force_N") - F_ref) / F_ref
    assert "(case 1) is off by" in text and f"{dev:+.2g} % at 20 mm" in text


def test_studies_start_from_the_default_scene_and_quick_says_what_it_leaves_out():
    from ngbet import default_scene
    from ngbet.studies import alpha1
    from ngbet.study.command import build_study

    full = alpha1.build(False)
    assert full.base.discretization == default_scene().discretization
    q = build_study(alpha1.build, True)
    notes = "; ".join(q.left_out)
    assert "material.alpha1 = 200, 20000" in notes and "loading.u0_mm = 56 (runs 20)" in notes
    assert "discretization.mesh_size_mm = 10 (runs 20)" in notes


# --- studies on any scene, sweeps from the command line ------------------------------------------
def test_a_study_on_another_scene_leaves_the_default_studys_folder(quick_cache, capsys):
    """Without --out, the study on a changed scene writes into a folder named by the scene's digest."""
    from pathlib import Path

    from ngbet.cli import main
    from ngbet.commands import load_scene

    default = Path("out/studies/alpha1-quick")
    default.mkdir(parents=True)
    (default / "kept.txt").write_text("the default study's")
    assert (
        main(["study", "alpha1", "--set", "material.alpha2=30", "--quick", "--quiet", "--cache", str(quick_cache)]) == 0
    ), capsys.readouterr().err
    assert [p.name for p in default.iterdir()] == ["kept.txt"]
    digest = load_scene(None, ["material.alpha2=30"]).digest()[:8]
    assert (Path("out/studies") / f"alpha1-scene-{digest}-quick" / "report.md").exists()


def test_study_on_a_scene_file_with_set(tmp_path, quick_cache, capsys):
    from ngbet.cli import main

    scene = tmp_path / "my.toml"
    scene.write_text("[material]\nK_el = 1.0e6\n")
    out = tmp_path / "a1"
    rc = main(
        [
            "study",
            "alpha1",
            str(scene),
            "--set",
            "material.alpha2=30",
            "--quick",
            "--out",
            str(out),
            "--cache",
            str(quick_cache),
        ]
    )
    assert rc == 0, capsys.readouterr().err
    meta = load(out).meta
    assert meta["base_scene"]["material"]["K_el"] == 1.0e6 and meta["base_scene"]["material"]["alpha2"] == 30
    text = (out / "report.md").read_text()
    assert f"the scene file {scene} with --set material.alpha2=30" in text
    assert "study alpha1 --quick leaves out:" in capsys.readouterr().out  # said on the terminal too


def test_sweep_is_a_study_with_whole_force_curves(tmp_path, quick_cache, capsys):
    from ngbet.cli import main

    out = tmp_path / "sw"
    assert (
        main(["sweep", "material.alpha1=20,2000", "--quick", "--quiet", "--out", str(out), "--cache", str(quick_cache)])
        == 0
    )
    d = load(out)
    assert d.meta["params"] == ["material.alpha1"]
    assert [c["params"]["material.alpha1"] for c in d.cases()] == [20, 2000]
    # the scene's output grid (every 2 mm to the quick 20 mm), not the stops alone: whole force curves
    assert [r["u0_mm"] for r in d.case_rows(0)] == [2.0 * k for k in range(1, 11)]
    assert (out / "sweep_force.png").exists() and (out / "sweep_values.png").exists()
    text = (out / "report.md").read_text()
    assert "| material.alpha1 | status |" in text and "- Discretization: Netgen mesh of 20 mm, p = 2." in text


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["sweep", "material.nonsense=1,2"], "nonsense"),
        (["sweep", "material.alpha1=-5,20"], "material.alpha1"),
        (["sweep", "alpha1=20"], "section.key"),
        (["study", "alpha1", "missing.toml"], "missing.toml"),
        (["study", "reference", "--set", "model=discrete"], "model = 'discrete'"),
    ],
)
def test_bad_sweep_or_study_scene_is_exit_2_naming_it(tmp_path, capsys, argv, needle):
    from ngbet.cli import main

    assert main([*argv, "--quick", "--quiet", "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and "Traceback" not in err


def test_sweep_values_with_brackets():
    from ngbet.commands import parse_value as _parse_value
    from ngbet.studies.sweep import parse_items

    axes, scene = parse_items(["loading.stops_mm=[10,20],[37]", "s.toml", "material.K_el=1e6,2e6"], _parse_value)
    assert axes == {"loading.stops_mm": [[10, 20], [37]], "material.K_el": [1e6, 2e6]} and scene == "s.toml"


# --- cache faults -------------------------------------------------------------------------------
def test_a_live_studys_finished_unstored_case_survives_another_studys_start(tmp_path):
    """A study whose case has finished (its run lock released) but is not yet stored, e.g. stopped by
    SIGSTOP: a second study on the same cache must not take that folder for debris; stored later,
    it verifies."""
    from ngbet.study.cache import run_dir, study_lock
    from ngbet.study.executors import accept, execute_case
    from ngbet.study.keys import case_key
    from ngbet.study.model import Case

    cache = tmp_path / "cache"
    cache.mkdir()
    scene = Scene().with_changes(**{**TINY, C.P: 3})
    key = case_key(scene)
    with study_lock(cache) as token:
        wd = run_dir(cache, key, token)
        rec = execute_case(scene.to_dict(), 1, str(wd))  # finished, not stored
        assert rec["status"] == "ok" and (wd / "results.csv").exists()
        other = run_study(tiny_study([{C.P: 1}]), tmp_path / "b", cache=cache, progress=False, workers=1)
        assert other.cases()[0]["status"] == "ok"
        assert (wd / "results.csv").exists()  # the live study's folder is still there
        c = Case(0, {C.P: 3}, scene, key)
        assert accept(cache, token, c, rec, wd)["status"] == "ok"
    from ngbet.study.cache import verify_case

    assert verify_case(cache / key)["status"] == "ok"


@pytest.mark.parametrize("stop", [KeyboardInterrupt, SystemExit])
def test_a_case_in_a_temporary_folder_leaves_none_however_it_ends(tmp_path, monkeypatch, stop):
    """A dask worker's case runs in a temporary folder whose files are returned; interrupted (Ctrl-C,
    the worker shut down) the folder goes all the same."""
    import tempfile

    import ngbet.run
    from ngbet.study.executors import execute_case

    def interrupted(scene, out, **kw):
        (out / "results.csv").write_text("u0_mm\n")
        raise stop()

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(ngbet.run, "run", interrupted)
    with pytest.raises(stop):
        execute_case(Scene().with_changes(**TINY).to_dict(), 1)
    assert list(tmp_path.iterdir()) == []


def test_a_case_is_never_ok_without_its_data(tmp_path, monkeypatch, caplog):
    from ngbet.study import executors

    real = executors.store

    def lossy(cache, key, rec, token, workdir=None, files=None):
        final = real(cache, key, rec, token, workdir=workdir, files=files)
        (final / "results.csv").unlink()  # the data lost between the store and the count
        return final

    monkeypatch.setattr(executors, "store", lossy)
    d = run_study(tiny_study([{C.P: 1}]), tmp_path / "o", cache=tmp_path / "c", progress=False, workers=1)
    (case,) = d.cases()
    assert case["status"] == "error" and "results.csv" in case["error"] and "not stored" in case["error"]


def test_swapped_cache_folders_are_caught_by_their_own_keys(tmp_path, caplog):
    cases = [{"material.alpha1": 20.0}, {"material.alpha1": 2000.0}]
    d = run_study(tiny_study(cases), tmp_path / "a", cache=tmp_path / "c", progress=False, workers=1)
    k0, k1 = (c["key"] for c in d.cases())
    cache = tmp_path / "c"
    (cache / k0).rename(cache / "swap")
    (cache / k1).rename(cache / k0)
    (cache / "swap").rename(cache / k1)
    with caplog.at_level(logging.WARNING):
        d2 = run_study(tiny_study(cases), tmp_path / "b", cache=cache, progress=False, workers=1)
    warned = [r.getMessage() for r in caplog.records if "recomputed" in r.getMessage()]
    assert len(warned) == 2 and all("swapped" in w for w in warned)
    assert d2.meta["executor"]["cases_run"] == 2
    for i in (0, 1):  # the right force under the right alpha1
        assert d2.at(i, 10.0, "force_N") == pytest.approx(d.at(i, 10.0, "force_N"), rel=1e-10)
    assert d2.at(0, 10.0, "force_N") < 0.8 * d2.at(1, 10.0, "force_N")


def test_plot_only_on_a_truncated_meta_json_is_exit_2_one_line(tmp_path, quick_cache, capsys):
    from ngbet.cli import main

    out = tmp_path / "a1"
    assert main(["study", "alpha1", "--quick", "--quiet", "--out", str(out), "--cache", str(quick_cache)]) == 0
    meta = out / "meta.json"
    meta.write_text(meta.read_text()[:200])
    capsys.readouterr()
    assert main(["study", "alpha1", "--quick", "--plot-only", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(meta) in err and err.count("\n") == 1 and "Traceback" not in err


def _immutable(folder):
    """Make ``folder`` unwritable also for root (chattr +i); False where the file system cannot."""
    folder.chmod(0o500)
    return os.geteuid() != 0 or subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode == 0


@pytest.mark.parametrize("workers", ["1", "2"])
def test_read_only_cache_is_exit_3_naming_it_with_any_workers(tmp_path, capsys, workers):
    from ngbet.cli import main

    cache = tmp_path / "ro"
    cache.mkdir()
    if not _immutable(cache):
        pytest.skip("this file system cannot make a folder unwritable for root")
    try:
        rc = main(
            [
                "study",
                "alpha1",
                "--quick",
                "--quiet",
                "--workers",
                workers,
                "--out",
                str(tmp_path / "o"),
                "--cache",
                str(cache),
            ]
        )
        err = capsys.readouterr().err
        assert rc == 3 and str(cache) in err and err.count("\n") == 1, err
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(cache)], check=True)
        cache.chmod(0o700)


def test_a_scheduler_without_workers_is_an_error_in_bounded_time(tmp_path, monkeypatch, capsys):
    from distributed import LocalCluster

    from ngbet.cli import main

    monkeypatch.setenv("NGBET_DASK_WORKER_TIMEOUT_S", "2")
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None) as cluster:
        t0 = time.monotonic()
        rc = main(
            [
                "study",
                "alpha1",
                "--quick",
                "--quiet",
                "--out",
                str(tmp_path / "o"),
                "--cache",
                str(tmp_path / "c"),
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
        assert rc == 3 and time.monotonic() - t0 < 30
    err = capsys.readouterr().err
    assert "no dask worker" in err and cluster.scheduler_address in err and err.count("\n") == 1


def test_a_killed_dask_worker_ends_the_study_in_bounded_time_keeping_finished_cases(tmp_path, monkeypatch):
    """The scheduler and one worker (no nanny to restart it) as separate processes; the worker is
    SIGKILLed after the first case is stored, during the second, which is slow."""
    from ngbet.study.cache import verify_case
    from ngbet.study.cluster import SchedulerError

    monkeypatch.setenv("NGBET_DASK_WORKER_TIMEOUT_S", "3")
    sfile = tmp_path / "scheduler.json"
    (tmp_path / "tmp").mkdir()  # the killed worker's temporary case folder stays there, not in /tmp
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg", "TMPDIR": str(tmp_path / "tmp")}
    sched = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "distributed.cli.dask_scheduler",
            "--scheduler-file",
            str(sfile),
            "--port",
            "0",
            "--dashboard-address",
            ":0",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    worker = None
    try:
        wait_until(sfile.exists)
        worker = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "distributed.cli.dask_worker",
                "--scheduler-file",
                str(sfile),
                "--no-nanny",
                "--nthreads",
                "1",
                "--dashboard-address",
                ":0",
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        address = json.loads(sfile.read_text())["address"]
        cache = tmp_path / "c"
        slow = {"loading.first_step_mm": 0.1, "loading.max_step_mm": 0.1, "solver.grow_after": 0}
        study = tiny_study([{C.P: 1}, {C.P: 2, **slow}])
        killer = threading.Thread(target=_kill_after_first_case, args=(cache, worker), daemon=True)
        killer.start()
        t0 = time.monotonic()
        with pytest.raises(SchedulerError, match="1 finished cases are kept in the cache, 1 not run"):
            run_study(study, tmp_path / "o", cache=cache, scheduler=address, progress=False)
        assert time.monotonic() - t0 < 120
        kept = [d for d in cache.iterdir() if not d.name.startswith(".")]
        assert len(kept) == 1 and verify_case(kept[0])["status"] == "ok"
        assert not [d for d in cache.iterdir() if d.name.startswith((".run", ".tmp"))]
    finally:
        for p in (worker, sched):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()


def _kill_after_first_case(cache, worker):
    wait_until(lambda: cache.exists() and any(not d.name.startswith(".") for d in cache.iterdir()), 120)
    time.sleep(0.5)
    os.kill(worker.pid, signal.SIGKILL)


def wait_until(cond, timeout=60.0):
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, "timed out"
        time.sleep(0.05)


# --- layout (the import graph: tests/test_layout.py) -------------------------------------------
def test_every_package_is_installed_and_the_studies_come_from_the_top_level_folder():
    """pyproject.toml lists the packages (discovery does not follow package-dir): a new subpackage
    missing from the list would be left out of a plain ``pip install .`` without a word."""
    import tomllib

    repo = Path(__file__).resolve().parent.parent
    conf = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {".".join(p.parent.relative_to(repo).parts) for p in (repo / "ngbet").rglob("__init__.py")}
    shipped = {"ngbet.data", "ngbet.data.cao2008", "ngbet.data.cao2008_pf", "ngbet.geometry"}  # data, installed
    assert set(conf["packages"]) == found | {"ngbet.studies"} | shipped
    assert conf["package-dir"] == {"ngbet.studies": "studies", "ngbet.data": "data", "ngbet.geometry": "geometry"}
    assert (repo / "studies" / "__init__.py").exists()
    for pkg in shipped:  # every data file of the folders is in the package data
        folder = repo / conf["package-dir"].get(pkg, "data/" + pkg.rsplit(".", 1)[-1])
        kinds = {"*" + f.suffix for f in folder.iterdir() if f.is_file()}
        assert kinds <= set(conf["package-data"][pkg]), (pkg, kinds)
    assert not (repo / "ngbet" / "studies").exists()


def test_without_matplotlib_the_tables_and_report_are_written_and_one_line_says_so(
    tmp_path, quick_cache, monkeypatch, capsys
):
    import importlib.util

    from ngbet.cli import main

    out = tmp_path / "a1"
    assert main(["study", "alpha1", "--quick", "--quiet", "--out", str(out), "--cache", str(quick_cache)]) == 0
    for f in out.glob("*.p*"):
        f.unlink()
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else real(name, *a))
    capsys.readouterr()
    assert main(["study", "alpha1", "--quick", "--plot-only", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    warned = "ngbet: study alpha1: 1 case(s) with warnings (1): meta.json lists them\n"  # α1 = 2000 on the quick mesh
    assert err == (
        f"{warned}ngbet: study alpha1: figures skipped: matplotlib is not installed (pip install matplotlib); the "
        "tables and the report are written\n"
    )
    assert (out / "report.md").exists() and not list(out.glob("*.png"))
    assert "matplotlib" in load(out).meta["figures_skipped"]


def test_stations_and_the_split_corner_family_follow_the_scenes_loading():
    from ngbet.studies import reference

    scene = Scene().with_changes(**{"loading.u0_mm": 40.0, "loading.stops_mm": [30.0]})
    assert C.stations(False, scene) == (30.0, 40.0) and C.stations(True) == (10.0, 20.0)
    study = reference.build(False, scene)
    split = [c for c in study.cases if c.get(C.BISECT)]
    assert split and all(c["loading.u0_mm"] == 30.0 and c["loading.stops_mm"] == [] for c in split)
    assert study.profile_stations == (30.0, 40.0)


@pytest.mark.slow
def test_a_stopped_study_keeps_its_cases_when_another_starts_on_the_same_cache(tmp_path):
    """The fault as an operator meets it: study A (2 workers) is stopped by SIGSTOP while its cases
    run; study B runs to its end on the same cache; A, continued, ends "ok" with every case's data."""
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg"}
    cache = tmp_path / "cache"
    slow = ["--set", "loading.first_step_mm=0.25", "--set", "loading.max_step_mm=0.25", "--set", "solver.grow_after=0"]
    a = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ngbet",
            "study",
            "alpha1",
            "--quick",
            "--quiet",
            "--workers",
            "2",
            "--out",
            str(tmp_path / "a"),
            "--cache",
            str(cache),
            *slow,
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_until(lambda: cache.exists() and any((d / "results.csv").exists() for d in cache.glob(".run-*")), 120)
        os.kill(a.pid, signal.SIGSTOP)
        running = [d.name for d in cache.glob(".run-*")]
        # A's workers go on: B starts once they have finished their cases (no run lock held), the
        # moment a study that stores its cases late would have them lying about unstored
        from ngbet.run_folder import RUN_LOCK
        from ngbet.study.cache import held

        wait_until(lambda: not any(held(d / RUN_LOCK) for d in cache.glob(".run-*")), 300)
        b = subprocess.run(
            [
                sys.executable,
                "-m",
                "ngbet",
                "study",
                "alpha1",
                "--quick",
                "--quiet",
                "--workers",
                "1",
                "--out",
                str(tmp_path / "b"),
                "--cache",
                str(cache),
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert b.returncode == 0, b.stderr
        for name in running:  # each of A's folders is still there, or its case is stored
            assert (cache / name).exists() or (cache / name.split("-")[1]).exists(), name
    finally:
        os.kill(a.pid, signal.SIGCONT)
    out, err = a.communicate(timeout=300)
    assert a.returncode == 0, err
    d = load(tmp_path / "a")
    assert [c["status"] for c in d.cases()] == ["ok", "ok"]
    assert all(math.isfinite(d.at(c["case"], 20.0, "force_N")) for c in d.cases())


def test_the_studies_draw_through_ngbet_figures_without_pyplot():
    """One plotting package: no study module keeps pyplot state or saves a figure itself."""
    import ngbet.studies

    for p in Path(ngbet.studies.__file__).parent.glob("*.py"):
        text = p.read_text()
        assert "pyplot" not in text and "plt." not in text and ".savefig(" not in text, p.name


def test_validation_takes_the_scene_of_a_fabric_and_refuses_another_naming_the_key():
    from ngbet.scene.document import default_scene
    from ngbet.scene.validate import SceneError
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import validation as V

    repo = Path(__file__).resolve().parent.parent
    for fabric, (scene, _, _) in VD.FABRICS.items():
        sc = Scene.from_toml(repo / "geometry" / scene)
        assert V.fabric_of(sc) == fabric
        # another specimen size of the same fabric is the same fabric
        other = sc.specimen.name.rsplit("-", 1)[0] + "-80x250"
        assert V.fabric_of(sc.with_changes(**{"specimen.name": other})) == fabric
    with pytest.raises(SceneError, match="specimen.name"):
        V.fabric_of(default_scene())


def test_quick_validation_makes_only_its_own_fit_and_says_what_it_leaves_out(monkeypatch):
    """The quick study fits one fabric on one size; what it leaves out of the full study is said
    by the study itself, without building the full one (whose thirteen fits take minutes)."""
    from ngbet.studies import _validation_fits as VF
    from ngbet.studies import validation as V
    from ngbet.study.command import build_study

    made = []

    def fit_stub(spec, quick, start, folder, curves):
        made.append((spec.fabric, spec.name, quick))
        return {"fitted_scene": Scene().to_toml(), "cache_name": spec.name, "predictions": {}}

    monkeypatch.setattr(VF, "fit_and_predict", fit_stub)
    monkeypatch.setattr(V, "_case", lambda doc, target, curves: {"specimen.name": target})
    study = build_study(V.build, True)
    assert made == [(*VF.QUICK, True)]
    assert study.left_out == [
        "12 of the full study's 13 fits (each size alone, both sizes, each laboratory's frame)",
        f"{VF.MAX_RUNS} model runs per fit ({VF.QUICK_RUNS} instead)",
    ]


def test_validation_fits_predict_every_curve_they_do_not_use():
    """Each fit's targets are every curve of its fabric in data/ that it does not fit, except the same
    frame test in another figure; each data file is a target of some fit; data/ holds no other curve."""
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF

    curves = VD.find_curves()
    assert curves.skipped == ()
    for fabric, (_, bet, pf) in VD.FABRICS.items():
        assert curves.of[fabric] == (*bet, *pf)
        specs = VF.fits_of(fabric, curves)
        assert {s.kind for s in specs} == {"one size", "two sizes", "frame"}
        for s in specs:
            assert not set(s.fitted) & set(s.targets)
            same_test = {f for f in pf if curves.lab(f) in {curves.lab(g) for g in s.fitted if g in pf}}
            assert set(s.fitted) | set(s.targets) | same_test == {*bet, *pf}
        assert set().union(*(s.targets for s in specs)) == {*bet, *pf}


def _relabelled(src: Path, dst: Path, old: str, new: str) -> None:
    """A copy of a shipped curve (and its error bars) whose header names another laboratory."""
    for a, b in ((src, dst), (src.with_name(src.stem + "_errorbars.csv"), dst.with_name(dst.stem + "_errorbars.csv"))):
        if a.exists():
            text = a.read_text()
            assert old in text
            b.write_text(text.replace(old, new))


def test_every_curve_of_a_fabric_given_with_data_is_a_target_of_each_of_its_fits(tmp_path):
    """Curves given with --data (a user's own tests, held-out sizes, other laboratories) are sorted by
    the fabric and laboratory their headers name and predicted by every fit of that fabric; files that
    cannot be read or name no fabric are not predicted and said; a fit's key holds what it fits only."""
    from ngbet.scene.validate import SceneError
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF
    from ngbet.studies import validation as V

    data = Path(__file__).resolve().parents[1] / "data"
    held = tmp_path / "held"
    held.mkdir()
    un = "cao2008_twill_unbalanced_100x200_UN.csv"
    _relabelled(data / "cao2008" / un, held / "twill_100x200_LABX.csv", "laboratory: UN;", "laboratory: LABX;")
    uml = "cao2008_pf_plain_UML_fig28_normalized_energy.csv"
    _relabelled(data / "cao2008_pf" / uml, held / "plain_frame_KUL.csv", 'legend label "UML"', 'legend label "KUL"')
    (held / "plain_frame_KUL.csv").write_text((held / "plain_frame_KUL.csv").read_text().replace("(UML)", "(KUL)"))
    (held / "broken.csv").write_text("# fabric: Twintex TPEET22XXX\ndisplacement_mm,force_N\n1,x\n")
    (held / "nofabric.csv").write_text("displacement_mm,force_N\n1,1\n2,2\n3,3\n")
    base = VD.find_curves()
    curves = VD.find_curves([held, data / "cao2008"])  # a shipped folder given again adds nothing
    assert curves.of["twill_unbalanced"] == (*base.of["twill_unbalanced"], "twill_100x200_LABX.csv")
    assert curves.of["plain"] == (*base.of["plain"], "plain_frame_KUL.csv")
    assert curves.of["twill_balanced"] == base.of["twill_balanced"]
    assert (curves.lab("twill_100x200_LABX.csv"), curves.lab("plain_frame_KUL.csv")) == ("LABX", "KUL")
    assert len(curves.skipped) == 2
    assert f"{held / 'broken.csv'}, line 3" in curves.skipped[0] and "nofabric.csv" in curves.skipped[1]
    for fabric, added in (("twill_unbalanced", "twill_100x200_LABX.csv"), ("plain", "plain_frame_KUL.csv")):
        before = {s.name: s for s in VF.fits_of(fabric, base)}
        for s in VF.fits_of(fabric, curves):  # every fit, frames of other laboratories included
            assert s.targets == (*before[s.name].targets, added)
            # the fit is the same (its key holds what it fits), the added curve a prediction of its own
            assert VF.fits_key(s, 3, "x", curves) == VF.fits_key(before[s.name], 3, "x", base)
    # a prediction's key follows its curve's file: the same file, the same key; a changed number, another
    labx = held / "twill_100x200_LABX.csv"
    key = VF.target_key(labx.name, curves)
    assert VF.target_key(labx.name, VD.find_curves([held])) == key
    labx.write_text(labx.read_text().replace("\n10.", "\n10.5", 1))
    assert VF.target_key(labx.name, curves) != key
    assert V._what("bias_extension", "one size", same_lab=False) == "other laboratory"
    assert V._what("bias_extension", "two sizes", same_lab=True) == "other size"
    assert V._what("picture_frame", "frame", same_lab=False) == "other laboratory"
    assert V._what("picture_frame", "one size", same_lab=True) == "other test"
    assert V._what("bias_extension", "frame", same_lab=True) == "other test"
    # a fabric line without the style code: the weave in words; neither, or two codes: no fabric
    words = {
        "Twintex TPEET22XXX plain weave": "plain",
        "balanced 2/2 twill, glass/PP": "twill_balanced",
        "unbalanced 2/2 twill": "twill_unbalanced",
        "a glass twill": None,
        "TPEET22XXX or TPEET44XXX": None,
        "": None,
    }
    for text, fabric in words.items():
        assert VD._fabric(SimpleNamespace(fabric=text)) == fabric
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / un).write_text("# fabric: Twintex TPECU53XXX\ndisplacement_mm,force_N\n1,1\n2,2\n3,3\n")
    with pytest.raises(SceneError, match=f"two data files named {un}"):
        VD.find_curves([tmp_path / "other"])
    with pytest.raises(SceneError, match="--data .*nowhere: no such file or folder"):
        VD.find_curves([tmp_path / "nowhere"])


class _KeptFit:
    """A stand-in for a fit's result: what the validation fits keep of it."""

    wall_s = 0.0

    def __init__(self, n: int) -> None:
        self.n, self.scene = n, Scene()

    def to_json(self) -> dict[str, int]:
        return {"n": self.n}


def test_a_kept_fit_predicts_a_curve_added_later_without_fitting_again(tmp_path, monkeypatch, caplog):
    """The fits are keyed by what they fit, not by what they predict: a curve added to the study is
    predicted by the kept fit, the kept predictions are read back; a kept fit that cannot be read
    back is made again, said in a warning."""
    from ngbet.calibration import joint
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF

    fits, predicted = [], []
    monkeypatch.setattr(
        joint, "fit_curves", lambda curves, scene, **kw: fits.append(len(fits) + 1) or _KeptFit(len(fits))
    )
    monkeypatch.setattr(
        VF, "_predict", lambda res, curve: predicted.append(Path(curve.source).name) or {"fit": res.n, "band": "b"}
    )
    data = Path(__file__).resolve().parents[1] / "data" / "cao2008"
    un = "cao2008_twill_unbalanced_100x200_UN.csv"

    def run(*held):
        curves = VD.find_curves(held)
        spec = next(s for s in VF.fits_of("twill_unbalanced", curves) if s.name == "100 x 250 mm")
        return spec, VF.fit_and_predict(spec, True, None, tmp_path, curves)

    spec, d0 = run()
    assert fits == [1] and predicted == list(spec.targets) and set(d0["predictions"]) == set(spec.targets)
    h1, h2 = tmp_path / "h1", tmp_path / "h2"
    h1.mkdir()
    _relabelled(data / un, h1 / "LAB1.csv", "laboratory: UN;", "laboratory: LAB1;")
    predicted.clear()
    _, d1 = run(h1)
    assert fits == [1] and predicted == ["LAB1.csv"] and d1["cache_name"] == d0["cache_name"]
    assert d1["predictions"]["LAB1.csv"] == {"fit": 1, "band": "b"}
    (tmp_path / f"{d0['cache_name']}.pickle").unlink()
    h2.mkdir()
    _relabelled(data / un, h2 / "LAB2.csv", "laboratory: UN;", "laboratory: LAB2;")
    predicted.clear()
    with caplog.at_level("WARNING"):
        _, d2 = run(h1, h2)
    assert fits == [1, 2] and predicted == ["LAB2.csv"] and "the fit is made again" in caplog.text
    assert d2["predictions"]["LAB2.csv"]["fit"] == 2 and d2["fit"] == {"n": 2}
    assert json.loads((tmp_path / f"{d0['cache_name']}.json").read_text())["fit"] == {"n": 2}


def test_one_curve_fits_run_side_by_side_with_the_records_of_one_process(tmp_path, monkeypatch):
    """The study's fits of one curve run in two worker processes at once; each record (the fitted
    scene, every prediction with its band) is the one a fit made in this process keeps, to the bit,
    and no worker is left. Fits already kept start no worker."""
    from test_fit_parallel import children

    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF

    curves = VD.find_curves()
    specs = [s for s in VF.fits_of("twill_unbalanced", curves) if s.kind == "one size"]
    assert len(specs) == 2
    before = children()
    both = VF.fit_all(specs, True, None, tmp_path / "both", curves, workers=2)
    assert not children() - before
    here = VF.fit_and_predict(specs[0], True, None, tmp_path / "here", curves)  # (100 x 250 mm: the shorter fit)
    assert both[0]["fitted_scene"] == here["fitted_scene"]
    assert both[0]["predictions"] == here["predictions"] and set(here["predictions"]) == set(specs[0].targets)
    assert both[1]["fit_name"] == specs[1].name and set(both[1]["predictions"]) == set(specs[1].targets)

    def no_workers(*args, **kw):
        raise AssertionError("a kept fit started a worker")

    monkeypatch.setattr(VF, "_in_workers", no_workers)
    assert VF.fit_all(specs, True, None, tmp_path / "both", curves, workers=2) == both


def test_an_error_in_a_fit_s_worker_reaches_the_study_and_ends_the_workers(tmp_path):
    """A fitted curve its worker cannot read: the reader's error is raised by the study, naming the
    file, and both workers are ended."""
    from dataclasses import replace

    from test_fit_parallel import children

    from ngbet.scene.validate import SceneError
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF

    curves = VD.find_curves()
    specs = [s for s in VF.fits_of("twill_unbalanced", curves) if s.kind == "one size"]
    bad = tmp_path / "unreadable.csv"
    bad.write_text("# fabric: Twintex TPECU53XXX\ndisplacement_mm,force_N\n1,x\n")
    broken = replace(curves, paths={**curves.paths, specs[0].fitted[0]: bad})
    before = children()
    with pytest.raises((SceneError, ValueError), match="unreadable.csv"):
        VF.fit_all(specs, True, None, tmp_path / "fits", broken, workers=2)
    assert not children() - before


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("how", ["ctrl-c", "a worker killed"])
def test_a_stopped_study_leaves_none_of_its_fits_workers(tmp_path, how):
    """Ctrl-C (SIGINT to the terminal's process group) while two fits run in workers: the study
    exits 130. One worker killed (out of memory, say): the study stops with one line naming the
    fits not made, the other worker ended. Either way no worker is left running."""
    import psutil

    root = Path(__file__).resolve().parents[1]
    scene = root / "geometry" / "twintex_twill_unbalanced.toml"
    cmd = [sys.executable, "-m", "ngbet", "study", "validation", str(scene)]
    cmd += ["--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out")]
    from test_faults import signals_at_default  # (started as from a terminal, whatever started pytest)
    from test_fit_parallel import stop_all

    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=signals_at_default,
    )
    workers: list[psutil.Process] = []
    try:
        parent = psutil.Process(proc.pid)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2 and proc.poll() is None:
            time.sleep(0.5)
            workers = [p for p in parent.children(recursive=True) if "resource_tracker" not in " ".join(p.cmdline())]
        assert len(workers) >= 2, "the fits' workers did not start"
        time.sleep(3.0)  # inside the fits
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
            _, err = proc.communicate(timeout=60)
            assert proc.returncode == 130, err
        else:
            workers[-1].kill()
            _, err = proc.communicate(timeout=60)
            assert proc.returncode == 1 and "ended without an answer" in err and "not made: twill unbalanced" in err
            assert "Traceback" not in err
        _, alive = psutil.wait_procs(workers, timeout=20)
        assert not alive, [p.pid for p in alive]
    finally:
        stop_all(proc, workers)


def test_data_is_refused_by_a_study_that_reads_no_curves(tmp_path, capsys):
    """--data on a study without measured curves would be ignored: refused before anything runs."""
    from ngbet.cli import main

    assert main(["study", "alpha1", "--quick", "--data", str(tmp_path), "--out", str(tmp_path / "s")]) == 2
    assert "this study reads no measured curves" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
