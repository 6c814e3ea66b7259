"""The study runner (cache, failures, parallel and dask execution, plot-only) and every study's --quick mode."""

from __future__ import annotations

import math
import shutil

import pytest

from ngbet.scene import Scene
from ngbet.studies import _common as C
from ngbet.study import Study, load, plot_only, run_study

TINY = {"outputs.vtk": False, "outputs.plot": False, "discretization.mesh_size_mm": 20.0,
        "loading.u0_mm": 10.0, "loading.stops_mm": [5.0], "loading.output_every_mm": 0.0}
# a case whose solver must give up: one Newton iteration allowed and no step cutting possible
FAILING = {"loading.first_step_mm": 10.0, "loading.min_step_mm": 10.0, "loading.max_step_mm": 10.0,
           "solver.max_iterations": 1}


def tiny_study(cases):
    return Study("tiny", Scene().with_changes(**TINY), cases,
                 plot=lambda d: [_force_plot(d)], report=lambda d: f"{len(d.rows)} rows\n")


def _force_plot(d):
    import matplotlib.pyplot as plt

    from ngbet.study import savefig

    fig, ax = plt.subplots()
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


def test_bad_scene_recorded_others_run(tmp_path, cache):
    d = run_study(tiny_study([{"material.K_el": -1.0}, {C.P: 1}]), tmp_path, cache=cache, progress=False, workers=1)
    assert d.cases()[0]["status"] == "failed" and "material.K_el" in d.cases()[0]["error"]
    assert d.cases()[1]["status"] == "ok"


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
        d = run_study(tiny_study(cases), tmp_path / "dask", cache=tmp_path / "dask_cache",
                      scheduler=cluster.scheduler_address, progress=False)
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


def run_quick(name, tmp_path, quick_cache):
    import importlib

    mod = importlib.import_module(f"ngbet.studies.{name}")
    return mod, run_study(mod.build(True), tmp_path / name, cache=quick_cache, progress=False)


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
    assert 0.5 < a["ref"]["order"] < 2.0  # singular corners: about first order in h
    for f in ("penalty_profiles", "penalty_error", "discretization_error"):
        assert (d.out / f"{f}.png").exists() and (d.out / f"{f}.pdf").exists()
    assert "slope" in (d.out / "report.md").read_text()


def test_quick_work_precision(tmp_path, quick_cache):
    mod, d = run_quick("work_precision", tmp_path, quick_cache)
    a = mod.analyse(d, mod.QUICK, True)
    pts = [p for p in a["pts"] if p["status"] == "ok"]
    assert len(pts) == len(d.cases())
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


def test_quick_compare(tmp_path, quick_cache):
    mod, d = run_quick("compare", tmp_path, quick_cache)
    assert [mod.label(c["params"]) for c in d.cases()] == ["continuum", "discrete", mod.EQUIVALENT]
    assert all(c["status"] == "ok" for c in d.cases())
    a = mod.analyse(d, True)
    assert a["continuum"]["F20"] > 0 and a["discrete"]["F20"] > 0
    # the network equivalent to the continuum bends the specimen the same way (u_y(L/4) < 0)
    assert a["continuum"]["uyq20"] < 0 and a[mod.EQUIVALENT]["uyq20"] < 0, a
    assert "Bending direction" in (d.out / "report.md").read_text()
    assert (d.out / "compare_curves.png").exists() and (d.out / "compare_maps.png").exists()


def test_cli_study(tmp_path, quick_cache, capsys):
    from ngbet.cli import main

    assert main(["study", "list"]) == 0
    assert "penalty_p" in capsys.readouterr().out
    assert main(["study", "nonsense"]) == 2
    out = tmp_path / "a1"
    assert main(["study", "alpha1", "--quick", "--quiet", "--out", str(out), "--cache", str(quick_cache)]) == 0
    assert main(["study", "alpha1", "--quick", "--plot-only", "--out", str(out)]) == 0
    assert load(out).meta["study"] == "alpha1"
