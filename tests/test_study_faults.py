"""Studies and sweeps that would mislead: a varied key no case reads, --plot-only of another study,
cases short of their load, reports that contradict their cases, swept values given twice.

Fast: the refusals come before any case runs; one sweep of two quick cases (one stops at its first
step) is run once for the module, in this process.
"""

from __future__ import annotations

import argparse
import importlib
import logging
from pathlib import Path

import pytest

from ngbet.cli import main
from ngbet.commands import parse_value
from ngbet.scene.document import Scene
from ngbet.scene.validate import SceneError
from ngbet.studies import STUDIES, sweep
from ngbet.studies import _common as C
from ngbet.studies import reference as R
from ngbet.study.collect import load
from ngbet.study.command import add_arguments, build_study
from ngbet.study.model import Study, StudyData
from ngbet.study.reads import case_scenes, check_cases_read, not_read
from ngbet.study.runner import run_study

ROOT = Path(__file__).resolve().parents[1]
FRAME = ROOT / "geometry" / "twintex_plain_pf_UN.toml"


def run(capsys, *argv):
    """``ngbet ARGV``: (exit status, stdout, stderr)."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


# --- a key the cases vary that none of them reads ------------------------------------------------
@pytest.mark.parametrize(
    "argv,message",
    [
        (
            ["study", "alpha1", "--set", "model=discrete"],
            "ngbet: study alpha1: bad scene: the alpha1 study varies material.alpha1 (20, 2000), but none of "
            "its cases reads it: model = 'discrete' does not read [material]; cases 0 and 1 would be the same run\n",
        ),
        (
            ["sweep", "discrete.spacing_mm=4,6"],
            "ngbet: sweep: bad scene: the sweep varies discrete.spacing_mm (4, 6), but none of its cases reads it: "
            "model = 'continuum' does not read [discrete]; cases 0 and 1 would be the same run\n",
        ),
        (
            ["sweep", "material.alpha1=20,2000", FRAME],
            "ngbet: sweep: bad scene: the sweep varies material.alpha1 (20, 2000), but none of its "
            "cases reads it: the picture frame with held arms shears the fabric homogeneously, which leaves the "
            "bending stiffnesses without a part in its result (picture_frame.arms = 'sheared' gives them one); "
            "cases 0 and 1 would be the same run\n",
        ),
        (
            ["sweep", "effects.penalty_K=1e4,1e8", "material.K_el=1e6,2e6"],
            "ngbet: sweep: bad scene: the sweep varies effects.penalty_K (10000, 1e+08), but none of its cases "
            "reads it: effects.constraint = 'lagrange' does not read effects.penalty_K: the penalty's keys act "
            "with effects.constraint = 'penalty' only; cases 0 and 2 would be the same run, and so would cases "
            "1 and 3\n",
        ),
    ],
)
def test_a_varied_key_no_case_reads_is_exit_2_before_anything_runs(tmp_path, capsys, argv, message):
    out, cache = tmp_path / "o", tmp_path / "c"
    rc, _, err = run(capsys, *argv, "--quick", "--quiet", "--out", out, "--cache", cache)
    assert (rc, err) == (2, message)
    assert not out.exists()  # the folder the command made for it is gone again
    assert [p.name for p in cache.iterdir()] == []  # no case ran


def test_the_python_api_refuses_it_before_the_folder_is_made(tmp_path):
    base = C.study_scene(None, True)
    study = Study("spacing", base, [{"discrete.spacing_mm": 4.0}, {"discrete.spacing_mm": 6.0}])
    with pytest.raises(SceneError, match=r"^the spacing study varies discrete\.spacing_mm \(4, 6\), but none of"):
        run_study(study, tmp_path / "s", cache=tmp_path / "c", progress=False)
    assert not (tmp_path / "s").exists() and not (tmp_path / "c").exists()


def test_cases_that_differ_in_what_reads_the_key_run_and_the_same_runs_are_named(caplog):
    """A grid over the model: the continuum's cases read alpha1, the network's do not (a warning names them)."""
    study = sweep.build({"model": ["continuum", "discrete"], "material.alpha1": [20.0, 2000.0]}, quick=True)
    with caplog.at_level(logging.WARNING, logger="ngbet.study.reads"):
        check_cases_read(study, case_scenes(study))
    assert [r.getMessage() for r in caplog.records] == [
        "the sweep varies material.alpha1, which some cases do not read (model = 'discrete' does not read "
        "[material]): cases 2 and 3 would be the same run"
    ]


def test_an_unread_key_that_rides_along_with_other_changes_is_no_fault(caplog):
    """Each case its own values (a study of fitted scenes, say): no two cases differ in the unread key alone."""
    base = C.study_scene(None, True)
    study = Study("own", base, [{"discrete.spacing_mm": 4.0, C.K: 1e4}, {"discrete.spacing_mm": 6.0, C.K: 1e5}])
    study.cases = [{**c, C.CON: "penalty"} for c in study.cases]
    with caplog.at_level(logging.WARNING, logger="ngbet.study.reads"):
        check_cases_read(study, case_scenes(study))
    assert caplog.records == []


@pytest.mark.parametrize("quick", [True, False])
def test_every_shipped_study_passes_the_check(quick):
    """Valid studies are never refused: the compare study varies the model, penalty_p the constraint."""
    for name in sorted(set(STUDIES) - {"validation"}):  # validation fits while it builds; its cases: scenes of fabrics
        study = build_study(importlib.import_module(f"ngbet.studies.{name}").build, quick)
        check_cases_read(study, case_scenes(study))


def _frame(**changes):
    return Scene.from_toml(FRAME).with_changes(**changes)


@pytest.mark.parametrize(
    "scene,key,why",
    [
        (lambda: Scene(), "material.alpha1", None),
        (lambda: Scene(), "model", None),
        (lambda: Scene(), "discrete.spacing_mm", "model = 'continuum' does not read [discrete]"),
        (
            lambda: Scene().with_changes(model="discrete"),
            "material.K_el",
            "model = 'discrete' does not read [material]",
        ),
        (
            lambda: Scene().with_changes(model="discrete"),
            "solver.condense",
            "model = 'discrete' does not read solver.condense",
        ),
        (lambda: _frame(), "specimen.length_mm", "test = 'picture_frame' does not read specimen.length_mm"),
        (
            lambda: Scene(),
            "effects.penalty_form",
            "effects.constraint = 'lagrange' does not read effects.penalty_form: the penalty's keys act with "
            "effects.constraint = 'penalty' only",
        ),
        (lambda: Scene().with_changes(**{"effects.constraint": "penalty"}), "effects.penalty_K", None),
        (
            lambda: Scene(),
            "material.K_sh4",
            "effects.shear_law = 'quadratic' does not read material.K_sh4 (shear_law = 'polynomial' does)",
        ),
        (lambda: Scene().with_changes(**{"effects.shear_law": "polynomial"}), "material.K_sh4", None),
        (
            lambda: Scene().with_changes(**{"effects.shear_law": "polynomial"}),
            "material.shear_table_i8_max",
            "effects.shear_law = 'polynomial' does not read material.shear_table_i8_max (shear_law = 'table' does)",
        ),
        (
            lambda: Scene().with_changes(**{"discretization.target_error": 0.01}),
            "discretization.order_u",
            "discretization.target_error = 0.01 lets ngbet choose discretization.order_u (the accuracy ladder)",
        ),
        (lambda: Scene().with_changes(**{"discretization.target_error": 0.01}), "discretization.quad_bonus", None),
        (
            lambda: _frame(),
            "material.alpha2",
            "the picture frame with held arms shears the fabric homogeneously, which leaves the bending "
            "stiffnesses without a part in its result (picture_frame.arms = 'sheared' gives them one)",
        ),
        (lambda: _frame(**{"picture_frame.arms": "sheared"}), "material.alpha1", None),
    ],
)
def test_what_a_scene_does_not_read(scene, key, why):
    assert not_read(scene(), key) == why


# --- a sweep with a case short of its load; --plot-only of the study the arguments name --------------
SHORT = [
    "sweep",
    "solver.max_iterations=1,20",
    "--set",
    "loading.first_step_mm=10",
    "--set",
    "loading.min_step_mm=10",
    "--set",
    "loading.max_step_mm=10",
    "--set",
    "loading.output_every_mm=0",
    "--quick",
]
NOT_REACHED = (
    "ngbet: study sweep: 1 of 2 cases did not reach their load: case 0 (solver.max_iterations = 1) failed "
    "(last converged load 0 mm): load step cut below the minimum 10 mm on the way from 0 mm to 20 mm; "
    "meta.json has their errors, the tables their converged steps (--retry-failed runs the failed ones again)\n"
)


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    """The folder and cache of a quick sweep whose case 0 stops at its first step (the solver may not iterate)."""
    from ngbet.cli import main

    root = tmp_path_factory.mktemp("short")
    out, cache = root / "sw", root / "cache"
    main([*SHORT, "--workers", "1", "--quiet", "--out", str(out), "--cache", str(cache)])
    return out, cache


def test_a_case_short_of_its_load_is_exit_1_after_everything_is_written(short, capsys):
    out, cache = short
    rc, _, err = run(capsys, *SHORT, "--quiet", "--out", out, "--cache", cache)
    assert (rc, err) == (1, NOT_REACHED)
    d = load(out)
    assert [c["status"] for c in d.cases()] == ["failed", "ok"]
    assert [r["u0_mm"] for r in d.case_rows(1)] == [10.0, 20.0]
    assert (out / "report.md").exists() and (out / "sweep_force.png").exists()


def test_plot_only_of_the_same_study_says_it_redrew_and_gives_its_status(short, capsys):
    out, _ = short
    rc, stdout, err = run(capsys, *SHORT, "--plot-only", "--out", out)
    # (case 1's two 10 mm steps on the quick mesh: an estimated error above a tenth of its force, said)
    assert (rc, err) == (1, "ngbet: study sweep: 1 case(s) with warnings (1): meta.json lists them\n" + NOT_REACHED)
    assert [w for w in load(out).cases()[1]["warnings"] if "does not resolve" in w]
    assert f"study sweep: redrawn from {out}/ (2 cases as they ran: 1 ok, 1 failed, 0 errors)\n" in stdout
    assert "from the cache" not in stdout


@pytest.mark.parametrize(
    "argv,holds",
    [
        (
            ["sweep", "material.alpha1=20,200", "--quick"],
            "it holds the sweep of 2 cases (solver.max_iterations = 1, 20), not of 2 cases (material.alpha1 = 20, 200)",
        ),
        (
            [*SHORT, "--set", "material.K_el=1e6"],
            "it holds the sweep on another base scene: material.K_el = 700000 (asked: 1e+06)",
        ),
        (
            [s for s in SHORT if s != "--quick"],
            "it holds the sweep on another base scene (it ran with --quick): discretization.mesh_size_mm = 20 "
            "(asked: 10), discretization.order_u = 2 (asked: 3), discretization.corner_mesh_size_mm = 0 (asked: "
            "0.25), loading.u0_mm = 20 (asked: 56), ...",
        ),
    ],
)
def test_plot_only_of_another_study_is_exit_3_naming_both(short, capsys, argv, holds):
    out, _ = short
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    rc, stdout, err = run(capsys, *argv, "--plot-only", "--out", out)
    assert (rc, stdout) == (3, "")
    assert err == (
        f"ngbet: sweep: cannot use the output folder {out}: {holds}; --plot-only redraws the study a folder "
        "holds: give the arguments it ran with, or run this one without --plot-only (into another --out)\n"
    )
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before  # nothing redrawn


# --- what the report says -------------------------------------------------------------------------
def _data(tmp_path, base, cases):
    meta = {"base_scene": base.to_dict(), "cases": cases, "params": ["loading.u0_mm"], "cache": str(tmp_path)}
    return StudyData(tmp_path, [], [], {}, meta)


def test_the_report_header_names_each_case_s_own_final_load(tmp_path):
    base = C.study_scene(None, True)
    own = _data(
        tmp_path, base, [{"case": 0, "params": {"loading.u0_mm": 30}}, {"case": 1, "params": {"loading.u0_mm": 40}}]
    )
    assert C.header(own, "t", "r")[2] == (
        "- Scene: ngbet's default scene (the paper's BET); each case loaded to its own final load (30, 40 mm)."
    )
    one = _data(tmp_path, base, [{"case": 0, "params": {"material.alpha1": 20.0}}])
    assert C.header(one, "t", "r")[2] == "- Scene: ngbet's default scene (the paper's BET); loaded to 20 mm."


@pytest.mark.parametrize("quick", [True, False])
def test_the_missing_reference_is_asked_for_with_the_study_s_own_options(tmp_path, quick):
    data = _data(tmp_path, C.study_scene(None, quick), [])
    u0, stop = (20, 10) if quick else (56, 37)
    assert R.reference_text(data, quick) == (
        f"none in the cache for this study's base scene loaded to {u0} mm (stops: {stop} mm); "
        f"`ngbet study reference{' --quick' if quick else ''}` on that scene, with this study's cache "
        f"(`--cache {tmp_path}`), computes it, and this report then names it."
    )
    bare = C.study_scene(None, quick).with_changes(**{"loading.stops_mm": []})
    assert f"loaded to {u0} mm (no stops); " in R.reference_text(_data(tmp_path, bare, []), quick)  # not "none mm"


# --- swept values and options ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "items,message",
    [
        (["material.alpha1=20,20"], "material.alpha1=20,20: the value 20 is given twice; give each value once"),
        (["material.alpha1=20,20.0"], "material.alpha1=20,20.0: the value 20.0 is given twice; give each value once"),
        (
            ["material.alpha1=20", "material.alpha1=200"],
            "material.alpha1 is given twice (material.alpha1=200 after material.alpha1=20): give each swept key "
            "once, with all its values (section.key=v1,v2,...)",
        ),
    ],
)
def test_a_swept_key_or_value_given_twice_is_exit_2_naming_it(tmp_path, capsys, items, message):
    with pytest.raises(SceneError) as exc:
        sweep.parse_items(items, parse_value)
    assert str(exc.value) == message
    rc, _, err = run(capsys, "sweep", *items, "--quick", "--out", tmp_path / "o", "--cache", tmp_path / "c")
    assert (rc, err) == (2, f"ngbet: sweep: {message}\n")
    assert not (tmp_path / "o").exists()


def test_the_help_of_data_says_what_it_does_for_a_sweep():
    """``ngbet sweep --help`` and ``ngbet study --help`` share the options: --data says what a sweep does
    with it; a command that reads no curves may leave it out."""
    offered = argparse.ArgumentParser()
    add_arguments(offered)
    help_text = " ".join(offered.format_help().split())
    assert "a sweep and the other studies read none and refuse it" in help_text
    without = argparse.ArgumentParser()
    add_arguments(without, data=False)
    assert "--data" not in without.format_help()


def test_a_sweep_of_two_keys_gives_one_key_the_colours_and_the_other_the_line_styles():
    """On one scale of six colours, α1 = 20 with K_el = 10 MPa and α1 = 2000 with K_el = 0.1 MPa looked alike."""
    from ngbet.studies.sweep import _looks

    cases = [
        {"case": f"c{i}{j}", "params": {"material.alpha1": a, "material.K_el": k}}
        for i, a in enumerate((20.0, 2000.0))
        for j, k in enumerate((1e5, 1e6, 1e7))
    ]
    looks = _looks(cases, ["material.alpha1", "material.K_el"])
    colours = {c["params"]["material.alpha1"]: set() for c in cases}
    styles = {c["params"]["material.K_el"]: set() for c in cases}
    for c in cases:
        colour, style = looks[c["case"]]
        colours[c["params"]["material.alpha1"]].add(tuple(colour))
        styles[c["params"]["material.K_el"]].add(style)
    assert all(len(s) == 1 for s in colours.values()) and len(set.union(*colours.values())) == 2
    assert [s.pop() for s in styles.values()] == ["-", "--", ":"]


# --- an interruption while the validation study makes its fits ------------------------------------
def _interrupt_second_fit(monkeypatch, VF):
    """``fit_and_predict`` keeps its first fit's record, as the real one does, and is interrupted in the second."""
    made = []

    def fit(spec, quick, start, folder, curves, live=True):
        if made:
            raise KeyboardInterrupt
        name = VF.record_name(spec, quick, VF.start_scene(spec, start), curves)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{name}.json").write_text("{}")
        made.append(spec)
        return {}

    monkeypatch.setattr(VF, "fit_and_predict", fit)
    return made


def test_an_interrupted_validation_says_which_fits_it_kept_and_where(tmp_path, monkeypatch):
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF
    from ngbet.study.executors import StudyInterrupted

    made = _interrupt_second_fit(monkeypatch, VF)
    curves = VD.find_curves()
    specs = [s for s in VF.fits_of("plain", curves) if len(s.fitted) == 1][:3]
    with pytest.raises(StudyInterrupted) as exc:
        VF.fit_all(specs, True, None, tmp_path / "fits", curves, workers=1)
    assert [s.name for s in made] == [specs[0].name]
    assert str(exc.value) == (
        f"study validation interrupted while it made its fits: 1 of its 3 fits is finished and kept in "
        f"{tmp_path / 'fits'} (plain, {specs[0].name}); run it again: a kept fit is reused, the others made"
    )


def test_an_interrupted_quick_validation_is_exit_130_naming_what_it_kept(tmp_path, monkeypatch, capsys):
    from ngbet.studies import _validation_fits as VF

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(VF, "fit_and_predict", interrupted)
    out, cache = tmp_path / "o", tmp_path / "c"
    rc, stdout, err = run(capsys, "study", "validation", "--quick", "--quiet", "--out", out, "--cache", cache)
    assert (rc, stdout) == (130, "")
    assert err == (
        "ngbet: study validation interrupted while it made its fits: none of its 1 fit was finished, nothing is "
        f"kept in {cache / VF.FITS_FOLDER}; run it again to make it\n"
    )
    assert not out.exists()  # nothing of the study was written


def test_a_curve_given_with_data_of_a_fabric_the_quick_study_does_not_fit_is_listed_with_the_reason(tmp_path):
    """--quick fits the unbalanced twill only: a plain-weave curve given with --data is named, not dropped;
    the twill's own curve given with it is a target of the quick fit, so not listed."""
    import shutil

    from ngbet.studies import _validation_data as VD
    from ngbet.studies._validation_fits import QUICK, fits_of
    from ngbet.studies.validation import not_predicted

    root = Path(__file__).resolve().parents[1]
    held = tmp_path / "mine"
    held.mkdir()
    shutil.copy(root / "data" / "cao2008" / "cao2008_plain_150x300_INSA-NU.csv", held / "plain_300.csv")
    shutil.copy(root / "data" / "cao2008" / "cao2008_twill_unbalanced_100x200_UN.csv", held / "twill_200.csv")
    curves = VD.find_curves([held])
    assert curves.given == ("plain_300.csv", "twill_200.csv")
    specs = [s for s in fits_of(QUICK[0], curves) if s.name == QUICK[1]]
    docs = [{"predictions": {t: {"u_mm": []} for t in s.targets}} for s in specs]
    assert not_predicted(curves, specs, docs, "--quick") == (
        f"{held / 'plain_300.csv'}: a curve of the fabric 'plain'; study validation --quick fits only "
        "'twill unbalanced': run the full study (no --quick, no scene) to predict it",
    )
    docs[0]["predictions"]["twill_200.csv"] = {"failed": "ConvergenceError: no step"}
    assert not_predicted(curves, specs, docs, "--quick")[1] == (
        f"{held / 'twill_200.csv'}: its prediction failed (ConvergenceError: no step)"
    )
