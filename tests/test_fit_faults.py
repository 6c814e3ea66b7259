"""``ngbet fit`` on faulty or conflicting input, and stopped: what it refuses, says and keeps.

The fits here run on a stand-in for the finite-element runs (:class:`FakeRuns`, a linear model in
the parameters): the command's plumbing is tested, in a fraction of a second per model run.
"""

from __future__ import annotations

import errno
import json
import pathlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from ngbet.calibration import bands, fit_params, joint, runs
from ngbet.calibration.bands import CurvePrediction
from ngbet.calibration.command import Inputs
from ngbet.calibration.fit_params import curve_scene, value_of
from ngbet.calibration.record import FitState
from ngbet.cli import _parser, main
from ngbet.measured.curves import read_any
from ngbet.numerics.engine import request_stop
from ngbet.run_folder import FOLDER_MARKER, OutputError, OwnedFolder, acquire_run_folder
from ngbet.scene.document import Scene

ROOT = Path(__file__).resolve().parents[1]
BET_SCENE = ROOT / "geometry" / "twintex_twill_unbalanced.toml"
PF_SCENE = ROOT / "geometry" / "twintex_twill_unbalanced_pf_UN.toml"
B200 = ROOT / "data" / "cao2008" / "cao2008_twill_unbalanced_100x200_UN.csv"
B250 = ROOT / "data" / "cao2008" / "cao2008_twill_unbalanced_100x250_UN.csv"
PF30 = ROOT / "data" / "cao2008_pf" / "cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv"


#: the scene keys of the 100 x 200 mm curve's test and specimen (its header)
SPEC200 = {
    "test": "bias_extension",
    "specimen.width_mm": 100.0,
    "specimen.length_mm": 200.0,
    "specimen.thickness_mm": 3.3,
}


class FakeRuns:
    """A stand-in for :func:`ngbet.calibration.runs.curve_run`: F = 10 (1 + u) Σ_k (p_k/p0_k) (u/100)^k.

    Linear in p/p0 (p0: the values of the first run), with its exact derivatives; the estimated
    force error ``rel[rung]`` of the force (default 1e-4) where a run is checked. Keeps every job
    (``jobs``); the ``stop_at``-th run raises KeyboardInterrupt, as Ctrl-C inside a run does.
    """

    def __init__(self, rel: dict[int | None, float] | None = None, stop_at: int | None = None) -> None:
        self.jobs: list[runs.Job] = []
        self.rel, self.stop_at = rel or {}, stop_at
        self.p0: np.ndarray | None = None
        self.on_first: list[object] = []

    def __call__(self, job: runs.Job, meshes: dict) -> runs.Run:
        self.jobs.append(job)
        if self.stop_at is not None and len(self.jobs) >= self.stop_at:
            request_stop("SIGINT")  # as the signal's handler does (ngbet.interrupts)
            raise KeyboardInterrupt("SIGINT")
        for look in self.on_first if len(self.jobs) == 1 else []:
            look()  # type: ignore[operator]
        p = np.array([value_of(job.scene, n) for n in job.names])
        self.p0 = p if self.p0 is None else self.p0
        u, n = np.asarray(job.u_mm), len(job.names)
        basis = np.array([10.0 * (1.0 + u) * (u / 100.0) ** k for k in range(n)]).T
        G = basis * (p / self.p0)
        F = G.sum(axis=1)
        err = self.rel.get(job.mesh_key[1], 1e-4) * F if job.check else np.zeros(0)
        angle = 0.5 * u if job.check else np.zeros(0)
        return runs.Run(F, G, np.zeros(0), np.zeros((0, n)), np.zeros(0), np.zeros((0, n)), err, angle, 0.01, 0.01)


@pytest.fixture
def fake(monkeypatch):
    """The stand-in runs, every curve in this process."""
    f = FakeRuns()
    monkeypatch.setattr(runs, "curve_run", f)
    monkeypatch.setattr(joint, "default_workers", lambda n: 1)
    return f


@pytest.fixture
def no_runs(monkeypatch):
    """Any model run fails the test: the refusals come before the first."""

    def refuse(job, meshes):
        raise AssertionError(f"a model run of {job.label}")

    monkeypatch.setattr(runs, "curve_run", refuse)


def fit(*args: str) -> int:
    return main(["fit", *map(str, args), "--quiet"])


def files(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


# ------------------------------------------------------------------------------------------ the test of each curve
def test_each_curve_runs_the_test_its_file_names_whatever_the_scene(fake, tmp_path, capsys):
    """A bias-extension curve fitted with a picture-frame scene runs the bias-extension test on its
    header's specimen: every model run, fit.json, fit.png's column and the fitted scene say so."""
    bet, frame = read_any(B200), read_any(PF30)
    assert fit_params.test_changes(bet) == SPEC200
    assert fit_params.test_changes(frame)["test"] == "picture_frame"
    u, _ = bet.sample()
    sc = curve_scene(Scene.from_toml(PF_SCENE), bet, u)
    assert (sc.test, sc.specimen.width_mm, sc.specimen.length_mm) == ("bias_extension", 100.0, 200.0)
    out = tmp_path / "X"
    assert fit(
        B200, "--scene", PF_SCENE, "--params", "material.shear_stress_steps_Pa", "--max-runs", "2", "--out", out
    ) in (0, 1)
    assert {(j.scene.test, j.scene.specimen.length_mm) for j in fake.jobs} == {("bias_extension", 200.0)}
    doc = json.loads((out / "fit.json").read_text())
    assert doc["status"] == "done" and doc["curves"][0]["test"] == "bias_extension"
    fitted = Scene.from_toml(out / "fitted_scene.toml")
    assert (fitted.test, fitted.specimen.width_mm, fitted.specimen.length_mm) == ("bias_extension", 100.0, 200.0)


def test_a_prediction_runs_the_test_its_file_names(fake, tmp_path, monkeypatch, capsys):
    """A frame fitted with the fabric's scene, a bias-extension curve predicted: the prediction runs
    the bias-extension test on that curve's specimen (the fitted scene is the frame's)."""
    asked = []

    def predict(result, spec, u_mm):
        asked.append(spec)
        F = np.linspace(1.0, 2.0, len(u_mm))
        return CurvePrediction(u_mm, F, 0.01 * F, 0.01 * F, result.scene, np.zeros(0), "test band")

    monkeypatch.setattr(bands, "predict_specimen", predict)
    out = tmp_path / "f"
    assert fit(PF30, "--scene", BET_SCENE, "--max-runs", "2", "--predict", B200, "--out", out) in (0, 1)
    assert Scene.from_toml(out / "fitted_scene.toml").test == "picture_frame"
    assert asked == [SPEC200]


# ------------------------------------------------------------------------------------------ stopped by Ctrl-C
def test_a_fit_stopped_by_ctrl_c_keeps_the_earlier_fit_aside_and_records_its_runs(fake, tmp_path, capsys):
    """A fit into the folder of an earlier one sets that fit's files aside (earlier_NAME) and says
    "running" in fit.json while it fits; stopped by Ctrl-C in its third model run, it exits 130,
    says what it kept, and fit.json records its two runs (status interrupted). The same command
    again fits, and the set-aside files go."""
    out = tmp_path / "fit"
    args = [B200, "--scene", BET_SCENE, "--max-runs", "3", "--out", out]
    assert fit(*args) in (0, 1)
    earlier = {n: (out / n).read_bytes() for n in ("fit.json", "fitted_scene.toml", "fit.png", "shear_table.png")}
    capsys.readouterr()

    seen = []
    fake.jobs, fake.stop_at = [], 3
    fake.on_first = [lambda: seen.append((json.loads((out / "fit.json").read_text())["status"], files(out)))]
    assert fit(*args) == 130
    aside = ["earlier_fit.json", "earlier_fit.png", "earlier_fitted_scene.toml", "earlier_shear_table.png"]
    assert seen == [("running", [FOLDER_MARKER, *aside, "fit.json"])]
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == (
        f"ngbet fit: interrupted (SIGINT) after 2 model runs, before the fit ended: {out}/fit.json records them "
        f"(status interrupted; the lowest cost so far and its values, not a fit); the earlier fit is kept as "
        f"{', '.join(aside)}"
    )
    assert files(out) == [FOLDER_MARKER, *aside, "fit.json"]
    assert {n: (out / f"earlier_{n}").read_bytes() for n in earlier} == earlier
    doc = json.loads((out / "fit.json").read_text())
    assert (doc["status"], doc["why"], doc["model_runs"], doc["converged"]) == ("interrupted", "SIGINT", 2, False)
    assert doc["earlier_fit"] == aside and doc["data"] == [str(B200)]
    assert all(p["at_lowest_cost"] > 0 for p in doc["parameters"].values())
    assert json.loads((out / FOLDER_MARKER).read_text())["files"] == [*aside, "fit.json"]

    fake.jobs, fake.stop_at, fake.on_first = [], None, []
    assert fit(*args) in (0, 1)
    assert files(out) == [FOLDER_MARKER, "fit.json", "fit.png", "fitted_scene.toml", "shear_table.png"]
    assert json.loads((out / "fit.json").read_text())["status"] == "done"


def test_a_fit_stopped_during_its_predictions_is_complete_and_says_what_was_not_predicted(
    fake, tmp_path, monkeypatch, capsys
):
    """Stopped while it predicts, the fit is complete: its files are the folder's (the earlier
    fit's set-aside files go), fit.json names the curves not predicted, the exit status is 130."""

    def stop(result, spec, u_mm):
        request_stop("SIGTERM")
        raise KeyboardInterrupt("SIGTERM")

    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "2", "--out", out) in (0, 1)
    monkeypatch.setattr(bands, "predict_specimen", stop)
    capsys.readouterr()
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "2", "--predict", B250, "--out", out) == 130
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"ngbet fit: interrupted (SIGTERM) during the predictions: the fit is complete in {out}/ (fit.json, "
        f"fitted_scene.toml, fit.png); not predicted: {B250}"
    )
    assert files(out) == [FOLDER_MARKER, "fit.json", "fit.png", "fitted_scene.toml", "shear_table.png"]
    doc = json.loads((out / "fit.json").read_text())
    assert doc["status"] == "done"
    assert doc["interrupted"] == f"interrupted (SIGTERM) during the predictions; not predicted: {B250}"


def test_a_stop_while_the_fit_s_files_are_written_comes_when_they_are_whole(fake, tmp_path, monkeypatch, capsys):
    """Ctrl-C while fit.json, fitted_scene.toml and the figures are written: they are written whole,
    then the command stops (130), its fit complete and fit.json saying when it was stopped."""
    from ngbet.calibration import report

    write = report.write_fit

    def signalled(result, out):
        request_stop("SIGINT")  # the handler inside an uninterrupted block: the stop waits for its end
        return write(result, out)

    monkeypatch.setattr(report, "write_fit", signalled)
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "1", "--out", out) == 130
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"ngbet fit: interrupted (SIGINT) as the fit's files were written: the fit is complete in {out}/ "
        "(fit.json, fitted_scene.toml, fit.png)"
    )
    assert files(out) == [FOLDER_MARKER, "fit.json", "fit.png", "fitted_scene.toml", "shear_table.png"]
    doc = json.loads((out / "fit.json").read_text())
    assert (doc["status"], doc["interrupted"]) == ("done", "interrupted (SIGINT) as the fit's files were written")


def test_a_fit_that_fails_records_its_runs_and_keeps_the_earlier_fit_aside(fake, tmp_path, monkeypatch, capsys):
    """An error in a model run ends the fit (exit 70, an internal error here): fit.json says
    "failed" with the error and the runs so far; the earlier fit stays set aside, not current."""
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "2", "--out", out) in (0, 1)
    capsys.readouterr()

    def broken(job, meshes):
        raise RuntimeError("a broken run")

    monkeypatch.setattr(runs, "curve_run", broken)
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "2", "--out", out) == 70
    err = capsys.readouterr().err
    assert f"; {out}/fit.json records the fit so far (0 model runs, status failed)" in err
    doc = json.loads((out / "fit.json").read_text())
    assert (doc["status"], doc["why"], doc["model_runs"]) == ("failed", "RuntimeError: a broken run", 0)
    assert "fitted_scene.toml" not in files(out) and "earlier_fitted_scene.toml" in files(out)


def test_fit_state_records_the_lowest_cost_and_its_values():
    s = FitState(names=["material.K_sh"], start=[2.0], labels=["a"])
    s.seen(1, np.log([3.0]), 5.0, [0.1])
    s.seen(2, np.log([4.0]), 7.0, [0.2])
    doc = s.to_json()
    assert doc["model_runs"] == 2 and doc["lowest_cost"] == 5.0
    assert doc["parameters"] == {"material.K_sh": {"start": 2.0, "at_lowest_cost": pytest.approx(3.0)}}
    assert doc["rms_relative_error_at_lowest_cost"] == {"a": 0.1}


# ------------------------------------------------------------------------------------------ parameters
def test_a_parameter_the_scene_does_not_read_is_refused_before_any_run(no_runs, tmp_path, capsys):
    """K_sh with the tabulated law: the law does not read it; refused (exit 2), nothing written."""
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--params", "material.K_sh", "--out", out) == 2
    assert capsys.readouterr().err == (
        "ngbet fit: --params: parameter 'material.K_sh' has no effect on the force in this scene: the scene's "
        "shear law (effects.shear_law = 'table') does not read it; it reads material.shear_stress_steps_Pa, "
        "material.shear_table_i8_max. Fit a key the law reads, or choose the law whose key it is (--set "
        "effects.shear_law=quadratic)\n"
    )
    assert fit(B200, "--scene", BET_SCENE, "--params", "material.alpha1", "--set", "effects.bending=false") == 2
    assert (
        "'material.alpha1' has no effect on the force in this scene: effects.bending = false" in capsys.readouterr().err
    )
    assert not out.exists()


def test_a_frame_scene_without_parameters_names_the_keys_and_the_fabric_s_scene(no_runs, tmp_path, capsys):
    out = tmp_path / "fit"
    assert fit(PF30, "--scene", PF_SCENE, "--out", out) == 2
    assert capsys.readouterr().err == (
        f"ngbet fit: no parameters to fit: the scene {PF_SCENE} names none (no [calibration] params); give "
        "--params, e.g. --params material.shear_stress_steps_Pa (what its shear law 'table' reads); or fit with "
        f"--scene {BET_SCENE}, the bias-extension scene of the same material, whose [calibration] names them (a "
        "fit takes curves of either test with it)\n"
    )
    assert not out.exists()


# ------------------------------------------------------------------------------------------ the run limit
#: estimated relative force errors per rung: the first rungs miss the target (the third meets it);
#: no rung vouches (the climb ends on the first rung, below which the coarse search runs)
CLIMBS = {"climbs": {1: 0.05, 2: 0.02, 3: 0.002}, "no rung vouches": {lv: np.inf for lv in range(7)}}


@pytest.mark.parametrize("max_runs", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("climb", list(CLIMBS))
def test_max_runs_is_kept_also_while_the_rungs_are_chosen(fake, max_runs, climb):
    """Whatever the probes of the rungs take, the fit makes at most ``max_runs`` model runs, the
    last of them the check at every fitted point where it ends."""
    fake.rel = CLIMBS[climb]
    res = joint.fit_curves([read_any(B200)], Scene.from_toml(BET_SCENE), max_runs=max_runs)
    assert res.model_runs == len(fake.jobs) <= max_runs
    last = fake.jobs[-1]
    assert last.check and last.estimate_at is None and len(res.curves[0].force_error_N) == 16
    assert res.converged is False or max_runs > 3


# ------------------------------------------------------------------------------------------ error bars
def test_error_bars_are_said_and_recorded(fake, tmp_path, capsys):
    """A curve's error bars beside it weight its points: the terminal says so, fit.json names the file;
    an error-bar file that cannot weight (one bar) is said to be unused."""
    shutil.copy(B200, tmp_path / "c.csv")
    shutil.copy(B200.with_name(B200.stem + "_errorbars.csv"), tmp_path / "c_errorbars.csv")
    out = tmp_path / "fit"
    assert fit(tmp_path / "c.csv", "--scene", BET_SCENE, "--max-runs", "1", "--out", out) == 1
    bars = len(read_any(tmp_path / "c.csv").bars[0])
    assert bars > 2
    assert (
        f"ngbet fit: {tmp_path}/c.csv: the {bars} bars of {tmp_path}/c_errorbars.csv beside it weight its points\n"
        in (capsys.readouterr().err)
    )
    assert json.loads((out / "fit.json").read_text())["curves"][0]["errorbars"] == f"{tmp_path}/c_errorbars.csv"
    text = (tmp_path / "c_errorbars.csv").read_text().splitlines()
    head = [ln for ln in text if ln.startswith("#") or "force_low_N" in ln]
    (tmp_path / "c_errorbars.csv").write_text("\n".join([*head, text[-1]]) + "\n")
    inp = Inputs(_parser("fit").parse_args(["fit", str(tmp_path / "c.csv"), "--scene", str(BET_SCENE)]))
    assert f"{tmp_path}/c_errorbars.csv: not used (it holds fewer than two complete bars); the points of " in "\n".join(
        inp.notes
    )


# ------------------------------------------------------------------------------------------ --set and --predict
def test_a_set_that_no_curve_runs_with_is_refused_naming_both_values(no_runs, tmp_path, capsys):
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--set", "specimen.length_mm=300", "--out", out) == 2
    assert capsys.readouterr().err == (
        "ngbet fit: --set specimen.length_mm=300: each curve runs the test and specimen its file names "
        f"({B200}: specimen.length_mm = 200): the --set has no effect; drop it, or change the file's header\n"
    )
    assert fit(B200, "--scene", BET_SCENE, "--set", "test=picture_frame", "--out", out) == 2
    assert f"--set test=picture_frame: each curve runs the test and specimen its file names ({B200}: test = " in (
        capsys.readouterr().err
    )
    assert fit(B200, "--scene", BET_SCENE, "--set", "loading.u0_mm=30", "--out", out) == 2
    assert "--set loading.u0_mm=30: the fit loads each curve to its last fitted point" in capsys.readouterr().err
    assert not out.exists()


def test_a_set_some_curves_run_with_is_noted(tmp_path):
    """One curve without specimen keys runs on the --set length, the other on its header's: said."""
    plain = tmp_path / "plain.csv"
    plain.write_text("".join(ln + "\n" for ln in B250.read_text().splitlines() if not ln.startswith("#")))
    args = ["fit", str(plain), str(B200), "--scene", str(BET_SCENE), "--set", "specimen.length_mm=250"]
    inp = Inputs(_parser("fit").parse_args(args))
    assert (
        f"--set specimen.length_mm=250 applies to {plain}; {B200}: specimen.length_mm = 200, from its header"
        in inp.notes
    )


def test_a_fitted_scene_is_on_the_specimen_that_was_fitted(fake, tmp_path):
    """The scene's specimen is 100 x 250 mm, the curve's 100 x 200: the fitted scene is the curve's."""
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--max-runs", "1", "--out", out) == 1
    sp = Scene.from_toml(out / "fitted_scene.toml").specimen
    assert (sp.width_mm, sp.length_mm) == (100.0, 200.0)
    assert "# those of cao2008_twill_unbalanced_100x200_UN.csv (bias extension, 100 x 200 mm)" in (
        (out / "fitted_scene.toml").read_text()
    )


def test_a_prediction_of_a_fitted_curve_is_refused(no_runs, tmp_path, capsys):
    out = tmp_path / "fit"
    assert fit(B200, "--scene", BET_SCENE, "--predict", B200, "--out", out) == 2
    assert capsys.readouterr().err == (
        f"ngbet fit: --predict {B200}: a data file of the fit; a prediction is of a curve the fit does not use "
        "(the fit's own curves are in fit.json and fit.png): drop it from --predict\n"
    )
    copy = shutil.copy(B200, tmp_path / "copy.csv")
    assert fit(B200, "--scene", BET_SCENE, "--predict", copy, "--out", out) == 2
    assert f"--predict {copy}: the measured curve of the data file {B200}; a prediction" in capsys.readouterr().err
    assert not out.exists()


def test_a_curve_without_specimen_on_a_frame_scene_is_refused(no_runs, tmp_path, capsys):
    plain = tmp_path / "plain.csv"
    plain.write_text("".join(ln + "\n" for ln in B200.read_text().splitlines() if not ln.startswith("#")))
    assert fit(plain, "--scene", PF_SCENE, "--params", "material.shear_stress_steps_Pa", "--out", tmp_path / "f") == 2
    assert (
        f"{plain}: a bias-extension curve without specimen keys runs on the scene's specimen, but the scene is "
        "a picture frame's" in capsys.readouterr().err
    )


# ------------------------------------------------------------------------------------------ messages
def test_the_summary_counts_in_words_and_gives_a_frame_s_range_in_degrees(fake, tmp_path, capsys):
    """One parameter, one curve, one model run: singular; a frame's fitted range in its shear angle
    and in crosshead travel; fit.json gives the angle range too."""
    out = tmp_path / "fit"
    assert (
        fit(PF30, "--scene", BET_SCENE, "--params", "material.shear_stress_steps_Pa", "--max-runs", "1", "--out", out)
        == 1
    )
    text = capsys.readouterr().out
    assert text.startswith("ngbet fit: NOT CONVERGED (raise --max-runs): 6 parameters, 1 curve, 1 model run, ")
    doc = json.loads((out / "fit.json").read_text())["curves"][0]
    (g0, g1), (u0, u1) = doc["range_shear_angle_deg"], doc["range_mm"]
    assert f"(16 points, shear angle {g0:.3g} to {g1:.3g} deg, crosshead travel {u0:.3g} to {u1:.3g} mm)" in text
    assert fit(PF30, "--scene", BET_SCENE, "--range", "500:600", "--out", tmp_path / "r") == 2
    assert "of crosshead travel, the frame's shear angle " in capsys.readouterr().err


def test_a_predicted_frame_s_note_does_not_say_fitted(no_runs, tmp_path):
    inp = Inputs(_parser("fit").parse_args(["fit", str(B200), "--scene", str(BET_SCENE), "--predict", str(PF30)]))
    said = [n for n in inp.notes if n.startswith(f"{PF30}: picture frame")]
    assert len(said) == 1 and " read as the crosshead force" in said[0] and "fitted" not in said[0]


def test_an_output_folder_that_cannot_be_written_is_named_not_its_mark(tmp_path, monkeypatch, capsys, no_runs):
    """A folder that refuses its mark (an immutable folder: EPERM) is named as the folder (exit 3)."""
    opened = pathlib.Path.open

    def refuse(self, *a, **k):
        if self.name in (FOLDER_MARKER, ".ngbet.lock"):
            raise PermissionError(errno.EPERM, "Operation not permitted", str(self))
        return opened(self, *a, **k)

    monkeypatch.setattr(pathlib.Path, "open", refuse)
    d = tmp_path / "ro"
    with pytest.raises(OutputError) as caught:
        OwnedFolder(d, "fit", "fit")
    assert str(caught.value) == (
        f"{d}: cannot be written (Operation not permitted: {FOLDER_MARKER}); make it writable or choose another --out"
    )
    with pytest.raises(OutputError, match=r"ro: cannot be written \(Operation not permitted: \.ngbet\.lock\)"):
        acquire_run_folder(d)
    assert fit(B200, "--scene", BET_SCENE, "--out", d) == 3
    assert capsys.readouterr().err == f"ngbet fit: cannot use the output folder {str(caught.value)}\n"


STUCK_FIT = """
import signal, sys, time
sys.path.insert(0, sys.argv[1])
from test_fit_faults import FakeRuns
from ngbet.calibration import joint, runs
from ngbet.cli import main

fake = FakeRuns()

def stuck(job, meshes):
    if len(fake.jobs) == 2:  # the third run: held in one long library call, the signal cannot act
        signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
        print("ready", flush=True)
        time.sleep(60)
    return fake(job, meshes)

runs.curve_run = stuck
joint.default_workers = lambda n: 1
sys.exit(main(["fit", *sys.argv[2:], "--quiet"]))
"""


def test_a_fit_stuck_in_one_library_call_records_its_interruption(tmp_path):
    """Ctrl-C while the main thread is held in one NGSolve call: after the grace the watchdog
    writes fit.json "interrupted" with the runs made (it said "running" before) and exits 130."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "fit"
    p = subprocess.Popen(
        [
            sys.executable,
            "-c",
            STUCK_FIT,
            str(Path(__file__).parent),
            str(B200),
            "--scene",
            str(BET_SCENE),
            "--max-runs",
            "5",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: [signal.signal(s, signal.SIG_DFL) for s in (signal.SIGINT, signal.SIGTERM)],
    )
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.5)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=30)  # the grace of 2 s, not the 60 s of the call
    assert p.returncode == 130, err
    doc = json.loads((out / "fit.json").read_text())
    assert (doc["status"], doc["model_runs"], doc["converged"]) == ("interrupted", 2, False)
    assert doc["why"].startswith("interrupted (SIGINT) inside a computation")
    assert f"{out}/fit.json records the fit so far (2 model runs, status interrupted)" in err
