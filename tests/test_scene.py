"""The scene: defaults are the paper's, TOML round-trips, bad values are refused by name."""

import subprocess
import sys
from pathlib import Path

import pytest

from ngbet.scene.document import Scene, SceneWarning, default_scene
from ngbet.scene.validate import SceneError


def test_default_is_paper_table1():
    s = default_scene()
    m = s.material
    assert (m.K_el, m.K_sh, m.alpha1, m.alpha2) == (0.7e6, 21e3, 2e3, 20.0)
    assert (s.specimen.length_mm, s.specimen.width_mm, s.specimen.thickness_mm) == (220.0, 70.0, 15.0)
    assert s.loading.u0_mm == 56.0


def test_internal_lengths_and_locking_match_model_md():
    s = default_scene()
    l1, l2 = s.material.internal_lengths_mm()
    assert abs(l1 - 308.6) < 0.1 and abs(l2 - 30.86) < 0.01
    assert abs(s.specimen.locking_u0_mm - 62.132) < 1e-3


def test_toml_round_trip_is_identity():
    s = default_scene().with_changes(
        **{"material.alpha1": 3.5, "effects.constraint": "penalty", "loading.stops_mm": [10.0, 37.0]}
    )
    assert Scene.from_toml_string(s.to_toml()) == s


@pytest.mark.parametrize(
    "key,value,fragment",
    [
        ("material.K_sh", -1.0, "material.K_sh"),
        ("discretization.order_u", 0, "discretization.order_u"),
        ("effects.constraint", "magic", "effects.constraint"),
        ("effects.stabilization_K", -2.0, "effects.stabilization_K"),
        ("loading.stops_mm", [60.0], "beyond the final load"),
        ("effects.elongation", False, "effects.elongation"),
        ("discretization.order_lam", 3, "discretization.order_lam"),  # not below order_phi = order_u = 3
        ("discretization.order_phi", 1, "'discretization.order_phi' = 1: the multiplier's order (1, order_lam = auto"),
        ("loading.stops_mm", 37, "'loading.stops_mm' = 37: must be a list of loads [mm], e.g. [37]"),
        ("outputs.fields", "shear_angle", "'outputs.fields' = 'shear_angle': must be a list of field names"),
        ("specimen.name", 5, "'specimen.name' = 5: must be a text"),
        ("specimen.width_mm", 300.0, "zone A"),
        ("discretization.corner_mesh_size_mm", 12.0, "must not exceed discretization.mesh_size_mm"),
        ("discretization.corner_bisections", -1, "discretization.corner_bisections"),
        ("discretization.corner_bisections", 1.5, "discretization.corner_bisections"),
        ("discretization.discrete_typo", 1.0, "discretization.discrete_typo"),
        ("discrete.end_rotation", "clamped", "discrete.end_rotation"),
        ("discrete.EI2", 0.0, "the network is a mechanism"),  # its first tangent would be singular
    ],
)
def test_bad_values_are_refused_with_their_key(key, value, fragment):
    with pytest.raises(SceneError) as err:
        default_scene().with_changes(**{key: value})
    assert fragment in str(err.value)


def test_a_stop_beyond_a_shortened_run_says_how_to_shorten_it():
    """A scene file's stop beyond a shortened final load is refused with the two ways out, and the
    change the message names is taken."""
    scene = Scene.from_toml(Path(__file__).parent.parent / "geometry" / "twintex_plain_pf_UN.toml")
    assert scene.loading.stops_mm == (46.0,)
    with pytest.raises(SceneError) as err:
        scene.with_changes(**{"loading.u0_mm": 10.0})
    assert "raise loading.u0_mm" in str(err.value) and "loading.stops_mm=[]" in str(err.value)
    assert scene.with_changes(**{"loading.u0_mm": 10.0, "loading.stops_mm": []}).loading.path_stops_mm[-1] == 8.0


def test_graded_structured_mesh_is_refused():
    with pytest.raises(SceneError, match="structured"):
        default_scene().with_changes(**{"discretization.structured": True, "discretization.corner_mesh_size_mm": 1.0})


def test_unknown_keys_are_refused_by_name():
    with pytest.raises(SceneError, match="material.K_shear"):
        Scene.from_toml_string("[material]\nK_shear = 1.0\n")
    with pytest.raises(SceneError, match="'meterial'"):
        Scene.from_toml_string("[meterial]\nK_sh = 1.0\n")


def test_cli_bad_scene_gives_a_message_not_a_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[material]\nK_el = -5\n")
    p = subprocess.run(
        [sys.executable, "-m", "ngbet", "run", str(bad), "--out", str(tmp_path / "o")], capture_output=True, text=True
    )
    assert p.returncode == 2
    assert "material.K_el" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "o").exists()  # refused before anything was meshed or written


def test_cli_scene_prints_valid_toml():
    p = subprocess.run([sys.executable, "-m", "ngbet", "scene"], capture_output=True, text=True)
    assert p.returncode == 0
    assert Scene.from_toml_string(p.stdout) == default_scene()


@pytest.mark.parametrize(
    "key, old",
    [
        ("effects.stabilization_K", -1),
        ("discretization.order_phi", 0),
        ("discretization.order_lam", -1),
        ("solver.threads", 0),
    ],
)
def test_automatic_values_are_written_auto_and_a_value_out_of_range_says_what_is_allowed(key, old):
    assert Scene().with_changes(**{key: "auto"}) == Scene() or key == "solver.threads"
    with pytest.raises(SceneError, match=f"'{key}' = {old}: must be \"auto\" or "):
        Scene().with_changes(**{key: old})


def test_auto_orders_follow_order_u():
    d = Scene().with_changes(**{"discretization.order_u": 3}).discretization
    assert (d.p_phi, d.p_lam) == (3, 1)
    d = (
        Scene()
        .with_changes(**{"discretization.order_u": 3, "discretization.order_lam": 0, "discretization.order_phi": 4})
        .discretization
    )
    assert (d.p_phi, d.p_lam) == (4, 0)


def test_the_highest_order_is_accepted_and_estimated_one_above():
    """A scene may ask for p = MAX_ORDER (the reference at 37 mm uses p = 14); its error estimate
    works one order up, beyond the scene's bound (a run at the old highest order, 10, was refused
    by its own estimate: "order_u = 11: must be an integer from 1 to 10")."""
    from ngbet.continuum.estimate import enriched_discretization
    from ngbet.scene.numerical import MAX_ORDER

    d = Scene().with_changes(**{"discretization.order_u": MAX_ORDER, "discretization.order_lam": 3}).discretization
    up = enriched_discretization(d)
    assert (up.p_u, up.p_phi, up.p_lam) == (MAX_ORDER + 1, MAX_ORDER + 1, 4)
    assert (d.p_u, d.p_lam) == (MAX_ORDER, 3)  # the run's own discretization is untouched
    with pytest.raises(SceneError, match=f"order_u' = {MAX_ORDER + 1}: must be an integer from 1 to {MAX_ORDER}"):
        Scene().with_changes(**{"discretization.order_u": MAX_ORDER + 1})


def test_a_scene_that_serves_both_tests_names_only_what_neither_reads(recwarn):
    # a fit of bias-extension and picture-frame curves runs the fabric scene in both tests: the
    # frame's keys have an effect there, a key of the other model has none
    from ngbet.commands import load_scene

    keys = ["picture_frame.arms=sheared", "discrete.EA1=5"]
    alone = load_scene(None, keys)
    assert alone.unused_keys() == ["discrete.EA1", "picture_frame.arms"]
    assert [str(w.message) for w in recwarn if w.category is SceneWarning] == [
        "model = 'continuum' with test = 'bias_extension' does not read discrete.EA1, picture_frame.arms: "
        "these values have no effect"
    ]
    recwarn.clear()
    both = load_scene(None, keys, tests=["bias_extension", "picture_frame"])
    assert both.unused_keys(["bias_extension", "picture_frame"]) == ["discrete.EA1"]
    assert [str(w.message) for w in recwarn if w.category is SceneWarning] == [
        "model = 'continuum' does not read discrete.EA1: these values have no effect"
    ]
    recwarn.clear()
    load_scene(None, ["picture_frame.arms=sheared"], tests=["picture_frame"])
    assert not [w for w in recwarn if w.category is SceneWarning]


def test_the_discretization_a_target_replaces_is_named_in_a_warning(recwarn):
    """With discretization.target_error the accuracy ladder sets mesh, grading and orders on each of
    its settings (Rung.apply sets exactly CHOSEN_BY_TARGET): the scene's own values there are named
    as having no effect; defaults, other keys and a scene without a target are quiet."""
    import dataclasses

    from ngbet.runner.ladder import LADDER
    from ngbet.scene.numerical import CHOSEN_BY_TARGET

    with pytest.warns(
        SceneWarning,
        match=r"target_error = 0.01 lets ngbet choose .*: the scene's "
        r"discretization.mesh_size_mm, discretization.order_u have no effect",
    ):
        s = Scene().with_changes(
            **{"discretization.order_u": 5, "discretization.mesh_size_mm": 20.0, "discretization.target_error": 1e-2}
        )
    assert s.discretization.chosen_by_target() == ["discretization.mesh_size_mm", "discretization.order_u"]
    recwarn.clear()
    Scene().with_changes(**{"discretization.target_error": 1e-2, "discretization.quad_bonus": 1})
    Scene().with_changes(**{"discretization.order_u": 5})
    assert not [w for w in recwarn if w.category is SceneWarning]
    # the keys a rung sets are those named: every one of them differs from an odd scene's
    odd = Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 7.0,
            "discretization.order_u": 6,
            "discretization.order_phi": 5,
            "discretization.order_lam": 1,
            "discretization.corner_mesh_size_mm": 0.0,
            "discretization.corner_bisections": 2,
            "discretization.target_error": 0.5,
        }
    )
    on = LADDER[0].apply(odd).discretization
    changed = {f.name for f in dataclasses.fields(on) if getattr(on, f.name) != getattr(odd.discretization, f.name)}
    assert changed == {*CHOSEN_BY_TARGET, "target_error"} - {"structured"}
    assert on.structured is False and "structured" in CHOSEN_BY_TARGET


def test_keys_the_model_does_not_read_are_named_in_a_warning():
    with pytest.warns(SceneWarning, match="does not read material.alpha1"):
        s = Scene().with_changes(**{"material.alpha1": 20.0, "model": "discrete"})
    assert s.unused_keys() == ["material.alpha1"]
    with pytest.warns(SceneWarning, match="discrete.spacing_mm"):
        Scene().with_changes(**{"discrete.spacing_mm": 3.0})
    # the sections a model reads, and defaults elsewhere, are quiet
    assert Scene().with_changes(**{"model": "discrete", "loading.u0_mm": 30.0}).unused_keys() == []
    assert Scene().with_changes(**{"material.alpha1": 20.0}).unused_keys() == []
    # the default discretization was not asked for: `ngbet run --set model=discrete` is quiet
    assert default_scene().with_changes(**{"model": "discrete"}).unused_keys() == []
    with pytest.warns(SceneWarning, match="does not read discretization.order_u"):
        default_scene().with_changes(**{"model": "discrete", "discretization.order_u": 5})


def test_one_default_scene_file_keys_take_the_defaults_of_ngbet_run(tmp_path):
    """Scene() is default_scene(), and a scene file with only [material] differs from the default
    only there: its missing [discretization] is the accurate default, not another mesh."""
    from ngbet.commands import load_scene

    assert Scene() == default_scene()
    f = tmp_path / "m.toml"
    f.write_text("[material]\nalpha1 = 200.0\n")
    from_file = load_scene(str(f), [])
    assert from_file == Scene.from_toml(f) == default_scene().with_changes(**{"material.alpha1": 200.0})
    assert from_file == load_scene(None, ["material.alpha1=200.0"])


def test_set_takes_every_top_level_key_and_names_what_it_takes():
    """``--set`` sets the keys outside the sections as a scene file does (``model``, ``test``); another
    word without a section is refused, naming what --set takes."""
    from ngbet.commands import load_scene

    frame = load_scene(None, ["test=picture_frame", "picture_frame.frame_mm=216", "picture_frame.fabric_mm=140"])
    assert frame.test == "picture_frame" and frame.picture_frame.frame_mm == 216.0
    assert load_scene(None, ["model=discrete"]).model == "discrete"
    with pytest.raises(SceneError, match="model=continuum.discrete or test=bias_extension.picture_frame, got 'tset=x'"):
        load_scene(None, ["tset=x"])
    with pytest.raises(SceneError, match="test"):
        load_scene(None, ["test=tensile"])


@pytest.mark.parametrize(
    "sets,why",
    [
        (["discretization.mesh_size_mm=0.2"], "finer than the default corners"),
        (["discretization.structured=true"], "a structured mesh cannot be graded"),
    ],
)
def test_a_default_the_user_never_set_gives_way_with_one_note(capsys, sets, why):
    """The default corner grading (0.25 mm) contradicts a finer mesh or a structured one: when the
    user sets only those, the grading is switched off with one note instead of a refusal."""
    from ngbet.cli import main
    from ngbet.commands import load_scene
    from ngbet.scene.document import SceneNote

    with pytest.warns(SceneNote, match=why):  # from Python the note is a warning (below: one line from the command)
        assert load_scene(None, sets).discretization.corner_mesh_size_mm == 0.0
    capsys.readouterr()
    assert main(["scene", *[f"--set={s}" for s in sets]]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("ngbet: note: discretization.corner_mesh_size_mm = 0") and why in err[0]
    # the same from a Scene
    with pytest.warns(SceneNote, match=why):
        key, value = sets[0].split("=")
        Scene().with_changes(**{key: 0.2 if "mesh" in key else True})


def test_a_default_the_user_set_does_not_give_way(tmp_path):
    """The user's own corner size, in the file or on the command line, is checked as given."""
    from ngbet.commands import load_scene

    with pytest.raises(SceneError, match="must not exceed discretization.mesh_size_mm"):
        load_scene(None, ["discretization.mesh_size_mm=0.2", "discretization.corner_mesh_size_mm=0.25"])
    f = tmp_path / "s.toml"
    f.write_text("[discretization]\ncorner_mesh_size_mm = 0.25\n")
    with pytest.raises(SceneError, match="a structured mesh cannot be graded"):
        load_scene(str(f), ["discretization.structured=true"])


@pytest.mark.integration
def test_a_scene_with_only_material_gives_the_default_runs_force(tmp_path):
    """The force of a scene file with only [material] equals that of the same physics by --set
    (38.2693 N against 38.2143 N when a file's missing keys took another mesh)."""
    from ngbet.cli import main
    from ngbet.tables import read_rows

    f = tmp_path / "m.toml"
    f.write_text("[material]\nalpha1 = 2000.0\n")
    short = [
        "--set=loading.u0_mm=16",
        "--set=outputs.vtk=false",
        "--set=outputs.plot=false",
        "--set=outputs.error_estimate=off",
        "--quiet",
    ]
    assert main(["run", str(f), "--out", str(tmp_path / "file"), *short]) == 0
    assert main(["run", "--out", str(tmp_path / "set"), "--set=material.alpha1=2000.0", *short]) == 0
    F_file, F_set = (read_rows(tmp_path / n / "results.csv")[-1]["force_N"] for n in ("file", "set"))
    assert F_file == F_set
    assert F_set == pytest.approx(22.1535, abs=1e-4)  # the default discretization's force at 16 mm


def test_the_default_smallest_step_gives_way_to_the_users_smaller_steps():
    """loading.min_step_mm = 0.05 by default; a first (or largest) step below it, set alone, was
    refused ("must not exceed loading.first_step_mm"): the default now becomes that step, with a note."""
    from ngbet.scene.document import SceneNote

    for key in ("loading.first_step_mm", "loading.max_step_mm"):
        with pytest.warns(SceneNote, match="loading.min_step_mm = 0.01 instead of the default 0.05"):
            s = Scene().with_changes(**{key: 0.01})
        assert s.loading.min_step_mm == 0.01
    with pytest.raises(SceneError, match="must not exceed loading.first_step_mm"):  # the user's own value stays
        Scene().with_changes(**{"loading.first_step_mm": 0.01, "loading.min_step_mm": 0.05})


def test_a_problem_is_refused_unless_one_and_a_half_times_its_estimate_fits(monkeypatch):
    """The memory estimate is fitted on small problems (a 15-million-dof mesh, estimated 19.1 GB, was
    killed at 23.6 GB): a problem is refused before meshing when 1.5 times its estimate does not fit."""
    from ngbet import preflight

    scene = Scene().with_changes(**{"discretization.mesh_size_mm": 2.0})
    _, mem = preflight.estimate_size(scene)
    monkeypatch.setattr(preflight, "available_memory", lambda: 1.4 * mem)
    with pytest.raises(SceneError, match="1.5 times its estimate"):
        preflight.check_size(scene)
    monkeypatch.setattr(preflight, "available_memory", lambda: 1.6 * mem)
    preflight.check_size(scene)  # fits: no error
