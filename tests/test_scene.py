"""The scene: defaults are the paper's, TOML round-trips, bad values are refused by name."""

import subprocess
import sys

import pytest

from ngbet.scene import Scene, SceneError, SceneWarning, default_scene


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
    s = default_scene().with_changes(**{"material.alpha1": 3.5, "effects.constraint": "penalty",
                                        "loading.stops_mm": [10.0, 37.0]})
    assert Scene.from_toml_string(s.to_toml()) == s


@pytest.mark.parametrize("key,value,fragment", [
    ("material.K_sh", -1.0, "material.K_sh"),
    ("discretization.order_u", 0, "discretization.order_u"),
    ("effects.constraint", "magic", "effects.constraint"),
    ("effects.stabilization_K", -2.0, "effects.stabilization_K"),
    ("loading.stops_mm", [60.0], "beyond the final load"),
    ("effects.elongation", False, "effects.elongation"),
    ("discretization.order_lam", 3, "discretization.order_lam"),  # not below order_phi = order_u = 3
    ("specimen.width_mm", 300.0, "zone A"),
    ("discretization.corner_mesh_size_mm", 12.0, "must not exceed discretization.mesh_size_mm"),
    ("discretization.corner_bisections", -1, "discretization.corner_bisections"),
    ("discretization.corner_bisections", 1.5, "discretization.corner_bisections"),
    ("discretization.discrete_typo", 1.0, "discretization.discrete_typo"),
    ("discrete.end_rotation", "clamped", "discrete.end_rotation"),
])
def test_bad_values_are_refused_with_their_key(key, value, fragment):
    with pytest.raises(SceneError) as err:
        default_scene().with_changes(**{key: value})
    assert fragment in str(err.value)


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
    p = subprocess.run([sys.executable, "-m", "ngbet", "run", str(bad), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True)
    assert p.returncode == 2
    assert "material.K_el" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "o").exists()  # refused before anything was meshed or written


def test_cli_scene_prints_valid_toml():
    p = subprocess.run([sys.executable, "-m", "ngbet", "scene"], capture_output=True, text=True)
    assert p.returncode == 0
    assert Scene.from_toml_string(p.stdout) == default_scene()


@pytest.mark.parametrize("key, old", [("effects.stabilization_K", -1), ("discretization.order_phi", 0),
                                      ("discretization.order_lam", -1), ("solver.threads", 0)])
def test_automatic_values_are_written_auto_and_old_sentinels_say_so(key, old):
    assert Scene().with_changes(**{key: "auto"}) == Scene() or key == "solver.threads"
    name = key.split(".")[1]
    with pytest.raises(SceneError, match=f"'{key}' = {old}: for the automatic value write {name} = \"auto\""):
        Scene().with_changes(**{key: old})


def test_auto_orders_follow_order_u():
    d = Scene().with_changes(**{"discretization.order_u": 3}).discretization
    assert (d.p_phi, d.p_lam) == (3, 1)
    d = Scene().with_changes(**{"discretization.order_u": 3, "discretization.order_lam": 0,
                                "discretization.order_phi": 4}).discretization
    assert (d.p_phi, d.p_lam) == (4, 0)


def test_the_highest_order_is_accepted_and_estimated_one_above():
    """A scene may ask for p = MAX_ORDER (the reference at 37 mm uses p = 14); its error estimate
    works one order up, beyond the scene's bound (a run at the old highest order, 10, was refused
    by its own estimate: "order_u = 11: must be an integer from 1 to 10")."""
    from ngbet.continuum.estimate import enriched_discretization
    from ngbet.scene import MAX_ORDER

    d = Scene().with_changes(**{"discretization.order_u": MAX_ORDER, "discretization.order_lam": 3}).discretization
    up = enriched_discretization(d)
    assert (up.p_u, up.p_phi, up.p_lam) == (MAX_ORDER + 1, MAX_ORDER + 1, 4)
    assert (d.p_u, d.p_lam) == (MAX_ORDER, 3)  # the run's own discretization is untouched
    with pytest.raises(SceneError, match=f"order_u' = {MAX_ORDER + 1}: must be an integer from 1 to {MAX_ORDER}"):
        Scene().with_changes(**{"discretization.order_u": MAX_ORDER + 1})


def test_keys_the_model_does_not_read_are_named_in_a_warning():
    with pytest.warns(SceneWarning, match="does not read material.alpha1"):
        s = Scene().with_changes(**{"material.alpha1": 20.0, "model": "discrete"})
    assert s.unused_keys() == ["material.alpha1"]
    with pytest.warns(SceneWarning, match="discrete.spacing_mm"):
        Scene().with_changes(**{"discrete.spacing_mm": 3.0})
    # the sections a model reads, and defaults elsewhere, are quiet
    assert Scene().with_changes(**{"model": "discrete", "loading.u0_mm": 30.0}).unused_keys() == []
    assert Scene().with_changes(**{"material.alpha1": 20.0}).unused_keys() == []
    # the embedded scene's discretization was not asked for: `ngbet run --set model=discrete` is quiet
    assert default_scene().with_changes(**{"model": "discrete"}).unused_keys() == []
    with pytest.warns(SceneWarning, match="does not read discretization.order_u"):
        default_scene().with_changes(**{"model": "discrete", "discretization.order_u": 5})
