"""``ngbet export``: the card read back reproduces the model's pure-shear response to its stated tolerance.

The reference is computed here from the continuum's energy density itself (NGSolve coefficient
functions of ngbet.continuum.physics on a homogeneous deformation whose yarns keep their length
and open by γ), differentiated by central differences: independent of the closed forms the
export samples.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from ngbet.cli import main
from ngbet.export import FORMATS, export, read_card, shear_card, shear_stress
from ngbet.scene.document import Scene, default_scene

ROOT = Path(__file__).resolve().parents[1]
TWILL = ROOT / "geometry" / "twintex_twill_unbalanced.toml"


def _energy_density(scene: Scene):
    """W(γ) [Pa] of the scene's continuum (shear law + elongation) in the pure shear of angle γ [rad]."""
    import ngsolve as ngs
    from netgen.geom2d import unit_square

    from ngbet.continuum import physics as ph
    from ngbet.scene.physical import SHEAR_LAW_KEYS

    mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=1.0))
    a = math.radians(scene.specimen.yarn_angle_deg)
    m1v, m2v = np.array([math.cos(a), math.sin(a)]), np.array([-math.cos(a), math.sin(a)])
    m1, m2 = ngs.CF(tuple(m1v)), ngs.CF(tuple(m2v))
    m, law = scene.material, scene.effects.shear_law
    coeffs = {k: getattr(m, k) for k in SHEAR_LAW_KEYS[law]}

    def rot(v, t):
        return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]]) @ v

    def W(g: float) -> float:
        # m1 turns by −γ/2, m2 by +γ/2: the angle between them opens by γ, both keep their length
        F = np.column_stack([rot(m1v, -g / 2), rot(m2v, g / 2)]) @ np.linalg.inv(np.column_stack([m1v, m2v]))
        grad_u = ngs.CF(tuple((F - np.eye(2)).ravel()), dims=(2, 2))
        inv = ph.invariants(grad_u, m1, m2)
        w = ph.shear_law_energy(inv.i8, law, coeffs) + ph.elongation_energy(inv.i4, inv.i6, m.K_el)
        return float(w(mesh(0.5, 0.5)))

    return W


def _reference_stress(scene: Scene, gamma: np.ndarray, h: float = 1e-5) -> np.ndarray:
    W = _energy_density(scene)
    return np.array([(W(g + h) - W(g - h)) / (2 * h) for g in gamma])


SCENES = {
    "table": Scene.from_dict(__import__("tomllib").loads(TWILL.read_text())),
    "quadratic": default_scene(),
    "polynomial": default_scene().with_changes(
        **{"effects.shear_law": "polynomial", "material.K_sh4": 2e5, "material.K_sh6": 1e6}
    ),
    "locking": default_scene().with_changes(
        **{"effects.shear_law": "locking", "material.K_lock": 5e4, "material.gamma_lock_deg": 65.0}
    ),
}


@pytest.mark.parametrize("law", list(SCENES))
def test_closed_form_stress_is_the_energy_densitys_derivative(law):
    """σ_s = dW/dγ of the sampled law equals the finite-difference derivative of ngbet's energy density.

    Central differences with h = 1e-5 rad are exact to ~1e-9 relative: 1e-6 bounds round-off.
    """
    sc = SCENES[law]
    g = np.radians([1.0, 7.0, 20.0, 35.0, 50.0, 60.0])
    ref = _reference_stress(sc, g)
    np.testing.assert_allclose(shear_stress(sc)(g), ref, rtol=1e-6)
    assert np.all(ref > 0)


@pytest.mark.parametrize("fmt", list(FORMATS))
@pytest.mark.parametrize("law", ["table", "locking"])
def test_card_read_back_reproduces_the_pure_shear_curve(tmp_path, fmt, law):
    """Each format read back and interpolated linearly is within the stated tolerance of the energy's derivative.

    Checked at 150 angles that are not the card's points, against the reference from the energy density.
    """
    sc = SCENES[law]
    src = tmp_path / "scene.toml"
    src.write_text(sc.to_toml())
    s = export(src, fmt, tmp_path / "out", plot=False)
    g, sig = read_card(tmp_path / "out" / FORMATS[fmt])
    assert g[0] == 0 and sig[0] == 0 and np.all(np.diff(g) > 0)
    assert max(map(len, (tmp_path / "out" / FORMATS[fmt]).read_text().splitlines())) <= 80  # LS-DYNA's limit
    assert s["points"] == len(g) and math.isclose(math.degrees(g[-1]), s["shear_angle_max_deg"])
    probe = np.linspace(0.0, g[-1], 151)[1:]
    ref = _reference_stress(sc, probe)
    floor = 0.01 * np.max(np.abs(ref))
    dev = np.abs(np.interp(probe, g, sig) - ref) / np.maximum(np.abs(ref), floor)
    assert dev.max() <= s["tolerance"], dev.max()
    assert s["deviation"] <= s["tolerance"]


def test_a_tighter_tolerance_takes_more_points_and_meets_it():
    """Linear interpolation converges like h²: a 10 times smaller tolerance needs about √10 times the points."""
    sc = SCENES["table"]
    coarse, fine = shear_card(sc, tolerance=1e-2), shear_card(sc, tolerance=1e-3)
    assert fine.deviation <= 0.5e-3 and coarse.deviation <= 0.5e-2
    assert 2.0 < len(fine.gamma_rad) / len(coarse.gamma_rad) < 5.0


def test_units_and_what_is_left_out_are_in_the_header(tmp_path):
    """The torque per area is t σ_s in N·mm/mm²; the quadratic law's σ_s = K_sh sin γ cos γ at ±45° (exact)."""
    sc = default_scene()
    export_dir = tmp_path / "o"
    src = tmp_path / "s.toml"
    src.write_text(sc.to_toml())
    export(src, "csv", export_dir, max_angle_deg=45.0, plot=False)
    text = (export_dir / "shear_law.csv").read_text()
    rows = np.array(
        [
            [float(v) for v in ln.split(",")]
            for ln in text.splitlines()
            if ln and not ln.startswith(("#", "shear_angle_deg"))
        ]
    )
    g = rows[:, 1]
    np.testing.assert_allclose(rows[:, 2], sc.material.K_sh * np.sin(g) * np.cos(g) * 1e-6, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(rows[:, 3], rows[:, 2] * sc.specimen.thickness_mm, rtol=1e-9)
    np.testing.assert_allclose(np.degrees(g[-1]), 45.0)
    header = " ".join(ln[1:].strip() for ln in text.splitlines() if ln.startswith("#"))
    assert "second gradient" in header and "t*alpha [N mm]: alpha1 -> 30000" in header  # 2000 Pa m² × 15 mm


def test_the_network_exports_its_crossing_spring(tmp_path):
    """The network's σ_s = K_φ γ/(t s²): with the continuum's equivalent K_φ = t K_sh s² the slope at 0 is K_sh."""
    from ngbet.discrete.equivalent import continuum_equivalent

    sc = default_scene().with_changes(model="discrete")
    sc = sc.with_changes(**continuum_equivalent(sc))
    g = np.radians([5.0, 30.0])
    np.testing.assert_allclose(shear_stress(sc)(g), sc.material.K_sh * g, rtol=1e-12)


def test_command_from_a_fit_folder_and_folder_ownership(tmp_path, monkeypatch, capsys):
    """A fit folder's fitted_scene.toml; a folder of the user's is refused (exit 3); a rerun replaces the card."""
    monkeypatch.chdir(tmp_path)
    fit = tmp_path / "fit"
    fit.mkdir()
    shutil.copy(TWILL, fit / "fitted_scene.toml")
    assert main(["export", "fit", "--format", "lsdyna", "--out", "card"]) == 0
    out = capsys.readouterr().out
    assert "lsdyna card" in out and "card/shear_law.k" in out
    summary = json.loads((tmp_path / "card" / "export.json").read_text())
    assert summary["files"] == sorted(p.name for p in (tmp_path / "card").iterdir() if not p.name.startswith("."))
    assert main(["export", "fit", "--format", "abaqus", "--out", "card"]) == 0  # the previous card goes
    assert not (tmp_path / "card" / "shear_law.k").exists() and (tmp_path / "card" / "shear_law.inp").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert main(["export", "fit", "--out", "mine"]) == 3
    assert "not written by an ngbet export" in capsys.readouterr().err
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    run = tmp_path / "run"  # a run folder is a run's: refused, its files kept
    run.mkdir()
    (run / ".ngbet.lock").write_text(json.dumps({"ngbet": "run folder", "pid": 1, "files": ["results.csv"]}))
    (run / "results.csv").write_text("u0_mm\n1\n")
    assert main(["export", "fit", "--out", "run"]) == 3
    assert "an ngbet run folder" in capsys.readouterr().err
    assert sorted(p.name for p in run.iterdir()) == [".ngbet.lock", "results.csv"]
    before = sorted(p.name for p in (tmp_path / "card").iterdir())  # and a run into the card's folder is refused
    assert main(["run", "--set", "loading.u0_mm=1", "--out", "card", "--quiet"]) == 3
    assert sorted(p.name for p in (tmp_path / "card").iterdir()) == before
    assert main(["export", "nowhere", "--out", "x"]) == 2
    assert main(["export", "fit", "--max-angle-deg", "95", "--out", "x"]) == 2
    assert "must lie between 0 and 90" in capsys.readouterr().err


def test_a_shear_stress_that_falls_is_said_with_the_angle_to_stop_at(tmp_path, caplog):
    """The paper's quadratic law: σ_s = K_sh sin γ cos γ peaks at 45° and falls after it (exact)."""
    src = tmp_path / "s.toml"
    src.write_text(default_scene().to_toml())
    s = export(src, "csv", tmp_path / "a", max_angle_deg=60.0, plot=False)
    assert s["stress_falls_beyond_deg"] == pytest.approx(45.0, abs=0.5)
    assert "falls beyond γ = 45" in caplog.text and "--max-angle-deg 4" in caplog.text
    assert export(src, "csv", tmp_path / "b", max_angle_deg=44.0, plot=False)["stress_falls_beyond_deg"] is None
