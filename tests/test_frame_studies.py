"""Studies on a picture-frame scene, and what a study says of cases that did not run or measure nothing.

Fast: the refusals come before any case runs; the figures and reports are drawn from small tables
made here; two coarse runs of the frame check the rule that K_el has no part in its result.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ngbet.cli import main
from ngbet.scene.document import Scene
from ngbet.scene.validate import SceneError
from ngbet.studies import _common as C
from ngbet.studies import compare, kel, maps, sweep
from ngbet.studies import reference as R
from ngbet.study.model import Study, StudyData
from ngbet.study.reads import not_read
from ngbet.study.runner import run_study

ROOT = Path(__file__).resolve().parents[1]
FRAME = ROOT / "geometry" / "twintex_plain_pf_UN.toml"
#: what the refusal of a study made for the bias extension test says after its reason
SERVE = "; the studies that serve a picture frame: study maps and ngbet sweep KEY=V1,V2,...\n"


def run(capsys, *argv):
    """``ngbet ARGV``: (exit status, stdout, stderr)."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def frame(**changes) -> Scene:
    return Scene.from_toml(FRAME).with_changes(**changes)


# --- a study made for the bias extension test, on a frame ------------------------------------------
@pytest.mark.parametrize(
    "name,why",
    [
        ("compare", "the yarn network, which has no frame, beside the continuum"),
        ("kel", "the deformed outline of the specimen, its width at X = L/2"),
        ("curves", "the double force on the clamp, the estimate of ideal BET kinematics"),
        ("alpha1", "the mid-axis S-profile of the specimen, its symmetries about X = L/2"),
        ("penalty_p", "the penalty's effect on the mid-axis S-profile of the specimen, the paper's appendix A"),
        ("work_precision", "the errors of the force and of the specimen's mid-axis S-profile against its reference"),
        ("reference", "meshes graded at the specimen's four clamp corners, the mid-axis S-profile"),
    ],
)
def test_a_study_made_for_the_bias_extension_test_refuses_a_frame_before_anything_runs(tmp_path, capsys, name, why):
    out, cache = tmp_path / "o", tmp_path / "c"
    rc, stdout, err = run(capsys, "study", name, FRAME, "--quick", "--out", out, "--cache", cache)
    assert (rc, stdout) == (2, "")
    assert err == (
        f"ngbet: study {name}: bad scene: test = 'picture_frame': study {name} is made for the bias extension "
        f"test only ({why}){SERVE}"
    )
    assert not out.exists() and [p.name for p in cache.iterdir()] == []


def test_study_list_says_which_tests_each_study_serves(capsys):
    rc, out, _ = run(capsys, "study", "list")
    lines = {line.split()[0]: line for line in out.splitlines()}
    assert rc == 0 and lines["kel"].endswith("K_el sweep at 37 mm: deformed outlines (bias extension)")
    assert lines["maps"].endswith("(37 and 56 mm; bias extension and picture frame)")


# --- a case ngbet refuses; a report's conclusions --------------------------------------------------
def test_a_study_with_a_case_validation_refuses_is_refused_before_the_folder_is_made(tmp_path):
    base = C.study_scene(None, True)
    study = Study("own", base, [{"material.K_el": -1.0}, {C.P: 1}, {"material.K_el": -2.0}, {"model": "discrete"}])
    with pytest.raises(SceneError) as exc:
        run_study(study, tmp_path / "s", cache=tmp_path / "c", progress=False)
    assert str(exc.value) == (
        "the own study has a case ngbet refuses: case 0 (material.K_el = -1): scene key 'material.K_el' = -1.0: "
        "must be a finite number >= 0; case 2 is refused too"
    )
    assert not (tmp_path / "s").exists() and not (tmp_path / "c").exists()


def _row(status, uy, reached=20.0):
    return {"case": 1, "status": status, "u0_reached": reached, "uyq20": uy}


@pytest.mark.parametrize(
    "other,sentence",
    [
        (_row("ok", -0.4), "the same."),
        (_row("ok", 0.4), "OPPOSITE: the two models bend the specimen in opposite directions."),
        (_row("failed", math.nan, None), "not compared: the discrete case failed before its first load step."),
        (_row("failed", math.nan, 12.5), "not compared: the discrete case failed (last converged load 12.5 mm)."),
        (
            _row("ok", 3e-12),
            "not compared: the discrete model leaves the mid-axis straight there (|u_y(L/4)| at most 1e-06 of "
            "the load).",
        ),
    ],
)
def test_the_bending_direction_is_compared_between_cases_that_ran_and_bend(other, sentence):
    cont = {"case": 0, "status": "ok", "u0_reached": 20.0, "uyq20": -0.3}
    assert compare.bending_direction(cont, other, "discrete", 20.0) == (
        "Bending direction at 20 mm (sign of u_y at X = L/4 on the mid-axis), continuum and discrete: " + sentence
    )


# --- K_el and the frame with held arms ---------------------------------------------------------------
HELD = (
    "the picture frame with held arms and the yarns along its bars shears the fabric without stretching the "
    "yarns, which leaves material.K_el without a part in its result"
)


@pytest.mark.parametrize(
    "changes,why",
    [
        (
            {},
            f"{HELD}: the jamming barrier, the one term that reads it there, acts from the frame's shear angle 85° "
            "(90° less material.jamming_angle_deg) on, and loading.u0_mm = 67 shears the frame to 49.5°",
        ),
        (
            {"effects.jamming": False, "loading.u0_mm": 84.89},
            f"{HELD} (effects.jamming is off: no jamming barrier reads it)",
        ),
        ({"loading.u0_mm": 84.89}, None),  # 87.9°: the jamming barrier reads K_el
        ({"picture_frame.misalignment_deg": 2.0}, None),  # the frame stretches yarns out of line with its bars
        ({"specimen.yarn_angle_deg": 40.0}, None),
        ({"picture_frame.arms": "sheared"}, None),
    ],
)
def test_what_reads_k_el_in_a_picture_frame(changes, why):
    assert not_read(frame(**changes), "material.K_el") == why


def test_a_sweep_of_k_el_on_the_frame_with_held_arms_is_exit_2_before_anything_runs(tmp_path, capsys):
    out, cache = tmp_path / "o", tmp_path / "c"
    rc, _, err = run(capsys, "sweep", "material.K_el=1e6,1e8", FRAME, "--quick", "--out", out, "--cache", cache)
    assert (rc, err) == (
        2,
        "ngbet: sweep: bad scene: the sweep varies material.K_el (1e+06, 1e+08), but none of its cases reads it: "
        f"{HELD}: the jamming barrier, the one term that reads it there, acts from the frame's shear angle 85° "
        "(90° less material.jamming_angle_deg) on, and loading.u0_mm = 20 shears the frame to 11.8°; cases 0 "
        "and 1 would be the same run\n",
    )
    assert not out.exists() and [p.name for p in cache.iterdir()] == []


def test_k_el_leaves_the_force_of_the_frame_with_held_arms_as_it_is(tmp_path):
    """The rule's ground: K_el = 1e6 and 1e8 Pa give the same force at every row, to round-off."""
    from ngbet import simulate

    coarse = {
        "loading.u0_mm": 20.0,
        "loading.stops_mm": [],
        "discretization.mesh_size_mm": 20.0,
        "discretization.corner_mesh_size_mm": 0.0,
        "outputs.plot": False,
        "outputs.profile": False,
        "outputs.error_estimate": "off",
    }
    runs = [
        simulate(frame(**coarse, **{"material.K_el": k}), out=tmp_path / f"{k:g}", progress=False) for k in (1e6, 1e8)
    ]
    assert list(runs[0].u0_mm) == list(runs[1].u0_mm) and len(runs[0].u0_mm) == 10
    np.testing.assert_allclose(runs[0].force_N, runs[1].force_N, rtol=1e-12, atol=0)


# --- a sweep and the maps on a frame, in the frame's words ------------------------------------------
def _frame_sweep_data(tmp_path) -> StudyData:
    base = C.study_scene(Scene.from_toml(FRAME), True)
    cases = [{"picture_frame.misalignment_deg": m} for m in (0.0, 2.0)]
    rows = [
        {"case": i, "u0_mm": u, "force_N": (1 + i) * u / 10, "force_error_N": math.nan}
        for i in (0, 1)
        for u in (10.0, 20.0)
    ]
    profiles = [
        {"case": i, "u0_mm": 20.0, "X_mm": x, "uy_mm": 1e-3 * i * math.sin(x / 20)}
        for i in (0, 1)
        for x in np.linspace(17.7, 187.4, 5)
    ]
    meta = {
        "base_scene": base.to_dict(),
        "scene_source": "the scene file geometry/twintex_plain_pf_UN.toml",
        "params": ["picture_frame.misalignment_deg"],
        "cases": [{"case": i, "params": p, "status": "ok", "dofs": 663, "wall_s": 1.0} for i, p in enumerate(cases)],
    }
    return StudyData(tmp_path, rows, profiles, {}, meta)


def test_a_sweep_on_a_frame_names_the_crosshead_travel_force_and_loading_diagonal(tmp_path, monkeypatch):
    figs = {}
    monkeypatch.setattr(sweep, "savefig", lambda fig, out, name: figs.setdefault(name, fig) and out / name)
    data = _frame_sweep_data(tmp_path)
    sweep.plot(data, True)
    a, b = figs["sweep_force"].axes[:2]
    assert (a.get_xlabel(), a.get_ylabel(), a.get_title()) == (
        "crosshead travel d [mm]",
        "crosshead force F [N]",
        "(a) crosshead force (points: the output loads)",
    )
    assert (b.get_xlabel(), b.get_title()) == (
        "reference position X on the loading diagonal Y = 0 [mm]",
        "(b) profile on the loading diagonal at d = 20 mm",
    )
    values = figs["sweep_values"].axes[0]
    assert values.get_ylabel() == "crosshead force at d = 20 mm [N]"
    text = sweep.report(data, True)
    assert (
        "| picture_frame.misalignment_deg | status | F(d = 10 mm) [N] | F(d = 20 mm) [N] | max abs(u_y) on the "
        "loading diagonal at the last load [mm] | dofs | wall time [s] |" in text
    )
    assert "- Scene: the scene file geometry/twintex_plain_pf_UN.toml; loaded to a crosshead travel of 20 mm." in text
    assert "- Reference: none: the reference study is made for the bias extension test." in text
    assert (
        "F: the crosshead force at the crosshead travel d; u_y on the loading diagonal Y = 0 (the pins' line)." in text
    )


def test_a_sweep_of_the_bias_extension_test_keeps_its_words(tmp_path, monkeypatch):
    figs = {}
    monkeypatch.setattr(sweep, "savefig", lambda fig, out, name: figs.setdefault(name, fig) and out / name)
    data = _frame_sweep_data(tmp_path)
    data.meta["base_scene"] = C.study_scene(None, True).to_dict()
    sweep.plot(data, True)
    a, b = figs["sweep_force"].axes[:2]
    assert (a.get_xlabel(), a.get_ylabel(), b.get_xlabel(), b.get_title()) == (
        "clamp displacement u₀ [mm]",
        "force on the moving clamp [N]",
        "reference position X on the mid-axis Y = W/2 [mm]",
        "(b) mid-axis profile at u₀ = 20 mm",
    )


@pytest.mark.parametrize(
    "changes,corners",
    [
        (None, "the four clamp corners"),
        ({}, "the four corners of the fabric square"),
        ({"picture_frame.arms": "sheared"}, "the corners of the cross (the arms' ends and the cuts' corners)"),
        ({"picture_frame.fabric_mm": 145.0}, "the four pins"),
    ],
)
def test_the_report_names_the_corners_the_mesh_is_graded_at(changes, corners):
    scene = Scene() if changes is None else frame(**changes)
    d = scene.to_dict()
    assert (
        C.describe_discretization(d) == f"Netgen mesh of {d['discretization']['mesh_size_mm']:g} mm graded to "
        f"{d['discretization']['corner_mesh_size_mm']:g} mm at {corners}, p = {d['discretization']['order_u']}"
    )


def _diamond_map(path: Path, n: int = 12) -> Path:
    """A map file of the frame's fabric square (side 120 mm, turned 45°, centre (102.5, 0)), at rest."""
    s = np.linspace(0.0, 120.0, n + 1)
    xi, eta = (a.ravel() for a in np.meshgrid(s, s, indexing="ij"))
    X = (xi + eta) / math.sqrt(2) + 102.5 - 120 / math.sqrt(2)
    Y = (xi - eta) / math.sqrt(2)
    k = lambda i, j: i * (n + 1) + j  # noqa: E731
    tri = [[k(i, j), k(i + 1, j), k(i + 1, j + 1)] for i in range(n) for j in range(n)]
    tri += [[k(i, j), k(i + 1, j + 1), k(i, j + 1)] for i in range(n) for j in range(n)]
    zero = np.zeros_like(X)
    np.savez(path, u0_mm=0.0, X_mm=X, Y_mm=Y, triangles=np.array(tri), gamma_deg=zero, ux_mm=zero, uy_mm=zero)
    return path


def test_the_maps_draw_the_yarns_over_the_whole_fabric_square_of_a_frame(tmp_path):
    npz = _diamond_map(tmp_path / "map.npz")
    yarns = maps.map_yarns(npz, maps.yarn_directions(frame().to_dict()), 10.0)
    half = 120 / math.sqrt(2)
    for fam in (1, 2):
        pts = np.vstack(yarns[fam])
        # every yarn runs from edge to edge of the square: |x - centre| + |y| = half at both its ends
        ends = np.array([pl[[0, -1]] for pl in yarns[fam]]).reshape(-1, 2)
        np.testing.assert_allclose(np.abs(ends[:, 0] - 102.5) + np.abs(ends[:, 1]), half, atol=1e-3)
        assert len(yarns[fam]) == 12 and pts[:, 1].min() < -0.9 * half and pts[:, 1].max() > 0.9 * half
    assert maps.yarn_directions(frame(**{"picture_frame.misalignment_deg": 5.0}).to_dict()) == (50.0, 140.0)


# --- the kel figure: the caption above the title, the legend below the x-label ------------------------
def test_the_kel_figure_keeps_its_caption_title_legend_and_label_apart(tmp_path, monkeypatch):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ngbet.figures.style import in_style

    base = C.study_scene(None, True, {"loading.u0_mm": 20.0, "loading.stops_mm": []})
    outline = [(0.0, 0.0), (220.0, 0.0), (110.0, 0.0), (220.0, 70.0), (110.0, 70.0), (0.0, 70.0)]
    outlines = [
        {"case": i, "X_mm": X, "Y_mm": Y, "x_mm": X * (1 + 0.1 * i), "y_mm": Y} for i in (0, 1) for X, Y in outline
    ]
    meta = {
        "base_scene": base.to_dict(),
        "params": [kel.KEL],
        "cases": [{"case": i, "params": {kel.KEL: k}, "status": "ok"} for i, k in enumerate((2e5, 2e6))],
    }
    data = StudyData(tmp_path, [], [], {"outlines": outlines, "midline_shear": []}, meta)
    figs = []
    monkeypatch.setattr(kel, "savefig", lambda fig, out, name: figs.append(fig) or out / name)
    with in_style():
        kel.plot(data)
    fig = figs[0]
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    ax = fig.axes[0]
    box = {
        "caption": fig._suptitle.get_window_extent(r),
        "title": ax.title.get_window_extent(r),
        "legend": fig.legends[0].get_window_extent(r),
        "x-label": ax.xaxis.label.get_window_extent(r),
    }
    assert not box["caption"].overlaps(box["title"]) and box["caption"].y0 >= box["title"].y1
    assert not box["legend"].overlaps(box["x-label"]) and box["legend"].y1 <= box["x-label"].y0


# --- a profile that is zero in the reference ---------------------------------------------------------
def test_no_relative_error_is_measured_against_a_zero_profile():
    zero, wavy = [0.0, 5e-12, -3e-12], [0.0, 0.2, -0.1]
    assert math.isnan(C.profile_error(wavy, zero, 20.0)) and math.isnan(R.profile_error_max(wavy, zero, 20.0))
    assert C.profile_error([0.0, 0.1, -0.1], wavy, 20.0) == pytest.approx(math.sqrt(0.01 / 0.05))
    assert R.profile_error_max([0.0, 0.1, -0.1], wavy, 20.0) == pytest.approx(0.5)
    assert (C.percent(math.nan), C.percent(0.01234)) == ("—", "1.23 %")
    assert C.zero_profile_note(zero, 20.0) == (
        "The reference profile at 20 mm is zero (max |u_y| = 5e-12 mm, at most 1e-06 of the load; the mid-axis "
        "stays straight, as for a balanced fabric): no profile error is measured relative to it."
    )
    assert C.zero_profile_note(wavy, 20.0) == ""


def _penalty_data(tmp_path, profile: float) -> StudyData:
    """Tables of the quick penalty_p study: Lagrange forces converging in p, penalties off by 1/K; one profile shape."""
    from ngbet.studies import penalty_p

    study = penalty_p.build(True)
    rows, profiles, cases = [], [], []
    for i, prm in enumerate(study.cases):
        p, graded = int(prm[C.P]), bool(prm.get(C.GRADE))
        pen = 1e3 / prm[C.K] if prm[C.CON] == "penalty" else 0.0
        for u in (10.0, 20.0):
            F = u * (1.5 + 0.5**p * (0.5 if graded else 1.0) + pen)
            rows.append({"case": i, "u0_mm": u, "force_N": F, "newton_iterations": 5, "constraint_rms": 1e-9})
            profiles += [
                {"case": i, "u0_mm": u, "X_mm": x, "uy_mm": profile * math.sin(x / 35) * (1 + 0.1 / p)}
                for x in np.linspace(0, 220, 12)
            ]
        cases.append({"case": i, "params": prm, "status": "ok", "dofs": 100.0 * p, "wall_s": 0.5})
    meta = {"base_scene": study.base.to_dict(), "params": study.params_columns(), "cases": cases}
    return StudyData(tmp_path, rows, profiles, {}, meta)


def test_penalty_p_gives_no_profile_error_against_a_zero_reference_profile(tmp_path):
    from ngbet.studies import penalty_p

    text = penalty_p.report(_penalty_data(tmp_path, 1e-12), penalty_p.QUICK, True)
    lagrange = [line for line in text.splitlines() if line.startswith("| 20 | ") and line.count("|") == 10]
    assert [line.split(" | ")[6] for line in lagrange] == ["—", "—"]
    assert (
        "\nThe reference profile at 20 mm is zero (max |u_y| = 1e-12 mm, at most 1e-06 of the load; the mid-axis "
        "stays straight, as for a balanced fabric): no profile error is measured relative to it.\n" in text
    )
    wavy = penalty_p.report(_penalty_data(tmp_path, 1.0), penalty_p.QUICK, True)
    assert "is zero" not in wavy
    assert [
        line.split(" | ")[6] for line in wavy.splitlines() if line.startswith("| 20 | ") and line.count("|") == 10
    ] == ["7.32 %", "2.44 %"]  # |1.1 - 1.025| / 1.025 and |1.05 - 1.025| / 1.025 (p = 1, 2 against p = 4)
