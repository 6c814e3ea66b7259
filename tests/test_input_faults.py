"""Faults of input, folders and terminals that need no solve: each ends in a clear message or in the
valid input read, and nothing of the user's is lost.

The folder tests use :class:`ngbet.run_folder.OwnedFolder` (the folders of studies, sweeps and fits)
directly; the commands that use it are run in tests/test_command_faults.py.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

import ngbet
from ngbet.cli import _force_text, _parser, main
from ngbet.commands import parse_value
from ngbet.commands import positionals_first as _positionals_first
from ngbet.run_folder import FOLDER_MARKER, OutputError, OwnedFolder, _remove_all_or_none
from ngbet.scene.document import Scene, SceneWarning


# ------------------------------------------------------------------------------------------ scenes
def test_a_scene_saved_with_a_bom_and_crlf_is_read(tmp_path):
    """Notepad's UTF-8 (a byte-order mark) with Windows line ends: the same scene as without them."""
    text = "# my fabric\n[material]\nalpha1 = 200.0\n[loading]\nu0_mm = 37.0\n"
    plain, windows = tmp_path / "plain.toml", tmp_path / "windows.toml"
    plain.write_text(text)
    windows.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    assert Scene.from_toml(windows) == Scene.from_toml(plain)
    assert Scene.from_toml(windows).material.alpha1 == 200.0


def test_numpy_scalars_and_arrays_are_accepted_as_their_values():
    """np.int64, np.float32, np.bool_ and arrays: the values they hold, as Python numbers and lists."""
    s = ngbet.default_scene().with_changes(
        **{
            "loading.u0_mm": np.int64(20),
            "material.alpha1": np.float32(200.0),
            "loading.stops_mm": np.array([10.0]),
            "outputs.vtk": np.bool_(False),
        }
    )
    assert s.loading.u0_mm == 20 and type(s.loading.u0_mm) is int
    assert s.material.alpha1 == 200.0 and type(s.material.alpha1) is float
    assert s.loading.stops_mm == (10.0,) and s.outputs.vtk is False
    assert Scene.from_toml_string(s.to_toml()) == s  # and it writes as TOML


def test_a_shear_law_coefficient_under_another_law_is_warned_about():
    """A fitted scene whose ``shear_law = "table"`` was deleted: its rises would go unused in silence.

    So would a polynomial's K_sh4 under the quadratic law, or any law's coefficient with shear off;
    K_sh is read by every continuum (it scales the multiplier and the barrier) and is never named.
    """
    with pytest.warns(SceneWarning, match=r"shear_law = 'quadratic' does not read material.shear_stress_steps_Pa"):
        Scene().with_changes(**{"material.shear_stress_steps_Pa": [1e3, 2e3, 4e3]})
    with pytest.warns(SceneWarning, match=r"'quadratic' does not read material.K_sh4 \(shear_law = 'polynomial'"):
        Scene().with_changes(**{"material.K_sh4": 5e3})
    with pytest.warns(SceneWarning, match=r"effects.shear = false does not read material.K_lock"):
        Scene().with_changes(**{"material.K_lock": 5e3, "effects.shear": False})
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        Scene().with_changes(**{"material.K_sh": 5e3, "effects.shear_law": "locking", "material.K_lock": 5e3})
    with pytest.warns(SceneWarning) as said:  # the network reads no material key: said once, by its model
        Scene().with_changes(**{"material.K_sh4": 5e3, "model": "discrete"})
    assert [str(w.message) for w in said] == [
        "model = 'discrete' does not read material.K_sh4: these values have no effect"
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # with the law: nothing to say
        Scene().with_changes(**{"material.shear_stress_steps_Pa": [1e3, 2e3, 4e3], "effects.shear_law": "table"})


@pytest.mark.parametrize(
    "force, text", [(107.37351234, "107.3735"), (61.2118, "61.2118"), (2.3456789e-7, "2.345679e-07"), (0.0, "0")]
)
def test_the_printed_force_has_seven_significant_digits(force, text):
    """A 1e-6 mm thick specimen printed "force = 0.0000 N"; its digits are kept."""
    assert _force_text(force).strip() == text


# -------------------------------------------------------------------------------- command lines
def test_a_scene_file_may_follow_the_options_of_a_study_or_sweep():
    parser = _parser("study")
    got = _positionals_first(parser, ["study", "alpha1", "--quick", "my.toml", "--out", "o", "--set", "x.y=-1"])
    assert got == ["study", "alpha1", "my.toml", "--quick", "--out", "o", "--set", "x.y=-1"]
    args = parser.parse_args(got)
    assert (args.name, args.scene, args.quick, args.out, args.overrides) == ("alpha1", "my.toml", True, "o", ["x.y=-1"])
    got = _positionals_first(parser, ["sweep", "--quick", "material.alpha1=20", "--workers", "2", "my.toml"])
    assert parser.parse_args(got).items == ["material.alpha1=20", "my.toml"]


def test_a_sweep_key_given_twice_is_refused_naming_both_items():
    """Its values are neither lost (the last item won) nor merged into a sweep other than the one written."""
    from ngbet.scene.validate import SceneError
    from ngbet.studies.sweep import parse_items

    with pytest.raises(SceneError, match=r"material.alpha1 is given twice \(material.alpha1=200,20 after material"):
        parse_items(["material.alpha1=20", "material.alpha1=200,20", "s.toml"], parse_value)


def test_a_large_sweep_says_what_it_will_do_before_it_checks_its_scenes(tmp_path, capsys, monkeypatch):
    import ngbet.studies.sweep as sweep

    said_first = []
    build = sweep.build
    monkeypatch.setattr(sweep, "build", lambda *a, **k: said_first.append(capsys.readouterr().err) or build(*a, **k))
    values = ",".join(str(20 + k) for k in range(150))
    assert main(["sweep", f"material.alpha1={values}", "--quick", "--plot-only", "--out", str(tmp_path / "s")]) == 2
    assert said_first and "sweep: 150 cases (150 values of material.alpha1)" in said_first[0]


@pytest.mark.parametrize("flag, value", [("--workers", "0"), ("--workers", "-3"), ("--threads", "x")])
def test_a_count_of_processes_or_threads_below_one_is_refused(tmp_path, capsys, flag, value):
    """--workers 0 or -3 would have run the cases in one process or on every core without a word."""
    with pytest.raises(SystemExit) as exc:
        main(["study", "alpha1", "--quick", flag, value, "--out", str(tmp_path / "s")])
    assert exc.value.code == 2 and f"argument {flag}:" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


# ---------------------------------------------------------------------------- the folders commands own
def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def test_a_folder_with_the_users_files_is_refused_untouched(tmp_path):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "results.csv").write_text("u0_mm,force_N\n1,2\n")
    (d / "report.md").write_text("# my notes\n")
    with pytest.raises(OutputError, match="not empty and not written by an ngbet study.*report.md, results.csv"):
        OwnedFolder(d, "study", "sweep")
    assert _files(d) == {"results.csv": b"u0_mm,force_N\n1,2\n", "report.md": b"# my notes\n"}


def test_a_run_folder_and_another_commands_folder_are_refused(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / ".ngbet.lock").write_text("{}")
    (run / "results.csv").write_text("x\n")
    with pytest.raises(OutputError, match="an ngbet run folder"):
        OwnedFolder(run, "study", "sweep")
    with OwnedFolder(tmp_path / "a", "study", "alpha1") as f:
        (f.out / "results.csv").write_text("alpha1's\n")
    for kind, name in (("study", "sweep"), ("fit", "fit")):
        with pytest.raises(OutputError, match="the folder of the study 'alpha1'"):
            OwnedFolder(tmp_path / "a", kind, name)
    assert (tmp_path / "a" / "results.csv").read_text() == "alpha1's\n"


def test_stale_files_go_only_when_this_command_wrote_them_and_only_at_a_successful_end(tmp_path):
    d = tmp_path / "fit"
    with OwnedFolder(d, "fit", "fit") as f:  # the first fit: a table, hence its figure
        for n in ("fit.json", "fitted_scene.toml", "shear_table.png"):
            (f.out / n).write_text("first")
    (d / "notes.md~").write_text("the user's")  # not a name a fit writes: kept, never registered
    with pytest.raises(RuntimeError):
        with OwnedFolder(d, "fit", "fit") as f:  # a fit that fails after writing fit.json: nothing removed
            (f.out / "fit.json").write_text("second, partial")
            raise RuntimeError("the search failed")
    assert {"fit.json", "fitted_scene.toml", "shear_table.png", "notes.md~"} <= set(_files(d))
    with OwnedFolder(d, "fit", "fit") as f:  # a fit without a table: the earlier table's figure goes
        for n in ("fit.json", "fitted_scene.toml"):
            (f.out / n).write_text("third")
    assert sorted(_files(d)) == [FOLDER_MARKER, "fit.json", "fitted_scene.toml", "notes.md~"]
    assert json.loads((d / FOLDER_MARKER).read_text())["files"] == ["fit.json", "fitted_scene.toml"]
    (d / "fit.png").write_text("the user's own figure")  # a name a fit writes, not written by one
    with pytest.raises(OutputError, match="holds fit.png, which no ngbet fit wrote there"):
        OwnedFolder(d, "fit", "fit")
    assert (d / "fit.png").read_text() == "the user's own figure"


def test_a_redraw_keeps_every_earlier_file(tmp_path):
    d = tmp_path / "s"
    with OwnedFolder(d, "study", "alpha1") as f:
        for n in ("results.csv", "meta.json", "alpha1_profiles.png"):
            (f.out / n).write_text("1")
    f = OwnedFolder(d, "study", "alpha1")
    (d / "alpha1_profiles.png").write_text("redrawn")
    assert f.finish(stale=False) == []
    f.release()
    assert {"results.csv", "meta.json", "alpha1_profiles.png"} <= set(_files(d))


def test_a_busy_folder_is_refused(tmp_path):
    with OwnedFolder(tmp_path / "s", "study", "kel"):
        with pytest.raises(OutputError, match="busy"):
            OwnedFolder(tmp_path / "s", "study", "kel")


def test_removing_the_previous_runs_files_is_all_or_none(tmp_path, monkeypatch):
    """One file that cannot be removed (an immutable figure): every other stays where it was."""
    files = {n: n.encode() for n in ("fields.vtu", "force.png", "profile.csv", "profile.png", "results.csv")}
    for n, b in files.items():
        (tmp_path / n).write_bytes(b)
    rename = os.rename

    def refuse(src, dst):
        if Path(src).name == "profile.png":
            raise PermissionError(1, "Operation not permitted")
        rename(src, dst)

    monkeypatch.setattr(os, "rename", refuse)
    with pytest.raises(OutputError, match=r"profile.png: cannot be removed \(Operation not permitted\).*nothing was"):
        _remove_all_or_none(tmp_path, sorted(tmp_path / n for n in files))
    assert _files(tmp_path) == files


# --------------------------------------------------------------------------------- figures
def test_an_interrupted_import_of_an_installed_matplotlib_is_not_called_missing(monkeypatch, caplog):
    from ngbet.figures import run as fr
    from ngbet.numerics.engine import STOP_REQUESTED

    cut = ImportError("cannot import name 'pyplot' from partially initialized module 'matplotlib'")
    STOP_REQUESTED.set()
    try:
        with pytest.raises(KeyboardInterrupt):
            fr._not_installed(cut)
    finally:
        STOP_REQUESTED.clear()
    with pytest.raises(ImportError, match="partially initialized"):  # no interrupt: the failure as it is
        fr._not_installed(cut)
    monkeypatch.setitem(__import__("sys").modules, "matplotlib", None)  # not installed: said once
    with caplog.at_level("WARNING"):
        fr._not_installed(ImportError("No module named 'matplotlib'"))
    assert fr.NO_MATPLOTLIB in caplog.text


# ------------------------------------------------------------------------- the validation fits
def test_a_truncated_validation_fit_is_named_and_made_again(tmp_path, caplog):
    from ngbet.studies import _validation_fits as VF

    (tmp_path / "pair-x.json").write_text('{"fabric": "plain", "K_el": 2.9')  # cut short
    with caplog.at_level("WARNING"):
        doc = VF.cached(tmp_path, "pair-x", lambda: {"fabric": "plain", "K_el": 3.0})
    assert doc["K_el"] == 3.0 and str(tmp_path / "pair-x.json") in caplog.text and "made again" in caplog.text
    assert json.loads((tmp_path / "pair-x.json").read_text())["K_el"] == 3.0


def test_an_unusable_fit_cache_is_found_before_the_fit(tmp_path):
    from ngbet.studies import _validation_fits as VF

    (tmp_path / "cache").write_text("a file where the cache folder should be")
    made = []
    with pytest.raises(OSError):
        VF.cached(tmp_path / "cache" / "validation-fits", "pair-x", lambda: made.append(1) or {})
    assert made == []


def test_study_list_takes_no_scene_or_set(capsys):
    assert main(["study", "list", "extra"]) == 2
    assert capsys.readouterr().err == "ngbet: study list takes no scene file or --set (got extra)\n"
    assert main(["study", "list", "--set", "material.alpha1=2"]) == 2
    assert "(got --set material.alpha1=2)" in capsys.readouterr().err
    assert main(["study", "list"]) == 0 and "alpha1" in capsys.readouterr().out
