"""The picture-frame test: frame kinematics (Cao et al. 2008, Eqs. 1-3, 10), scene, cross mesh, exact solutions."""

import math
import warnings
from pathlib import Path

import ngsolve as ngs
import numpy as np
import pytest

from ngbet.api import simulate
from ngbet.continuum import physics
from ngbet.continuum.mesh import CLAMPED_ARMS, cross_outline, make_cross_mesh
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.kinematics import (
    PictureFrameColumns,
    frame_normalised_force,
    frame_shear_angle_rad,
    frame_stretches,
    shear_force,
)
from ngbet.runner.continuum import load_path
from ngbet.runner.settings import solver_settings
from ngbet.scene.document import Scene, SceneWarning
from ngbet.scene.numerical import Discretization
from ngbet.scene.physical import PictureFrame, Specimen
from ngbet.scene.validate import SceneError


def frame_scene(**changes) -> Scene:
    """A picture frame of side 100 mm on a coarse mesh (25 mm, p = 2): a second or two."""
    base = {
        "test": "picture_frame",
        "picture_frame.frame_mm": 100.0,
        "picture_frame.fabric_mm": 100.0,
        "discretization.mesh_size_mm": 25.0,
        "discretization.corner_mesh_size_mm": 0.0,
        "discretization.order_u": 2,
        "loading.u0_mm": 30.0,
        "loading.stops_mm": [20.0],
        "loading.first_step_mm": 5.0,
        "loading.max_step_mm": 10.0,
        "loading.output_every_mm": 10.0,
        "outputs.vtk": False,
        "outputs.plot": False,
    }
    base.update(changes)
    return Scene().with_changes(**base)


def homogeneous_invariants(scene: Scene, d_mm: float) -> tuple[float, float, float]:
    """(i4, i6, i8) of the frame's affine map F = diag(A, B) at travel d, the yarns turned by the misalignment."""
    A, B, _, _ = frame_stretches(d_mm * 1e-3, scene.picture_frame.frame_mm * 1e-3)
    a, turn = math.radians(scene.specimen.yarn_angle_deg), math.radians(scene.picture_frame.misalignment_deg)
    # (cos a, sin a) and (−cos a, sin a) turned counter-clockwise by the misalignment
    m1, m2 = np.array([math.cos(a + turn), math.sin(a + turn)]), np.array([-math.cos(a - turn), math.sin(a - turn)])
    F = np.diag([A, B])
    return (F @ m1) @ (F @ m1), (F @ m2) @ (F @ m2), (F @ m1) @ (F @ m2) - m1 @ m2


def homogeneous_energy(scene: Scene, d_mm: float) -> float:
    """W [Pa] of the homogeneous state at travel d: the quadratic shear law and the yarn elongation.

    (Its φ = i8 is constant, so the bending energy is 0.)
    """
    i4, i6, i8 = homogeneous_invariants(scene, d_mm)
    mat = scene.material
    return 0.5 * mat.K_el * ((math.sqrt(i4) - 1) ** 2 + (math.sqrt(i6) - 1) ** 2) + 0.5 * mat.K_sh * i8**2


def homogeneous_elongation(scene: Scene, d_mm: float) -> float:
    """The larger yarn strain |√i − 1| of the two families in the homogeneous state at travel d."""
    i4, i6, _ = homogeneous_invariants(scene, d_mm)
    return max(abs(math.sqrt(i4) - 1), abs(math.sqrt(i6) - 1))


def homogeneous_force(scene: Scene, d_mm: float, h_mm: float = 1e-4) -> float:
    """F = t A dW/dd [N] of the homogeneous state (the whole square clamped), by a central difference."""
    area = (scene.picture_frame.frame_mm * 1e-3) ** 2
    dW = (homogeneous_energy(scene, d_mm + h_mm) - homogeneous_energy(scene, d_mm - h_mm)) / (2 * h_mm * 1e-3)
    return scene.specimen.t * area * dW


# --------------------------------------------------------------------------- kinematics
def test_frame_shear_angle_at_rest_30_degrees_and_flat():
    # cos θ = (√2 L + d)/(2L): θ = 30° (γ = 30°) at d = (√3 − √2) L; flat (γ = 90°) at d = (2 − √2) L
    L = 145.0
    g = np.degrees(frame_shear_angle_rad([0.0, (math.sqrt(3) - math.sqrt(2)) * L, (2 - math.sqrt(2)) * L], L))
    assert g == pytest.approx([0.0, 30.0, 90.0], abs=1e-9)
    with pytest.raises(ValueError, match="closes flat"):
        frame_shear_angle_rad([0.9 * L], L)


def test_frame_stretches_are_the_rhombus_and_their_rates_the_derivatives():
    # F = diag(√2 cos θ, √2 sin θ) maps the bar directions (1, ±1)/√2 to unit vectors at ±θ
    L, d, h = 0.145, 0.04, 1e-7
    A, B, dA, dB = frame_stretches(d, L)
    theta = math.acos((math.sqrt(2) * L + d) / (2 * L))
    assert (A, B) == pytest.approx((math.sqrt(2) * math.cos(theta), math.sqrt(2) * math.sin(theta)), rel=1e-14)
    assert (A / math.sqrt(2)) ** 2 + (B / math.sqrt(2)) ** 2 == pytest.approx(1.0, rel=1e-14)  # bars keep their length
    up, down = frame_stretches(d + h, L), frame_stretches(d - h, L)
    assert (dA, dB) == pytest.approx(((up[0] - down[0]) / (2 * h), (up[1] - down[1]) / (2 * h)), rel=1e-7)


def test_shear_force_and_normalised_force_by_hand():
    # at γ = 30° (θ = 30°), F = 10 N: F_s = 10 / (2 cos 30°) = 5.773503 N (Eq. 3);
    # F_norm = F_s 145 / 120² = 0.0581360 N/mm (Eq. 10)
    d = (math.sqrt(3) - math.sqrt(2)) * 145.0
    fs = float(shear_force(10.0, d, 145.0))
    assert fs == pytest.approx(10 / math.sqrt(3), rel=1e-12)
    assert float(frame_normalised_force(fs, 145.0, 120.0)) == pytest.approx(5.773503 * 145 / 120**2, rel=1e-6)
    row = PictureFrameColumns(145.0, 120.0).row(d, 10.0)
    assert row["shear_angle_deg"] == pytest.approx(30.0, abs=1e-9)
    assert row["shear_force_N"] == pytest.approx(fs, rel=1e-14)
    assert row["fnorm_N_per_mm"] == pytest.approx(fs * 145 / 120**2, rel=1e-14)
    assert PictureFrameColumns(145.0, 120.0).row(d, None)["fnorm_N_per_mm"] == ""


# --------------------------------------------------------------------------- scene
def test_the_scene_refuses_what_a_frame_cannot_do():
    with pytest.raises(SceneError, match="picture_frame.fabric_mm.*fit in the frame"):
        frame_scene(**{"picture_frame.fabric_mm": 120.0})
    with pytest.raises(SceneError, match="loading.u0_mm.*closes flat"):
        frame_scene(**{"loading.u0_mm": 60.0})  # (2 − √2) 100 = 58.6 mm
    with pytest.raises(SceneError, match="model.*continuum model only"):
        frame_scene(model="discrete")
    with pytest.raises(SceneError, match="misalignment_deg.*the misalignment 90 degrees less"):
        frame_scene(**{"picture_frame.misalignment_deg": 45.5})
    with pytest.raises(SceneError, match="'test' = 'tension'"):
        frame_scene(test="tension")


def test_keys_the_test_does_not_read_are_named():
    with pytest.warns(SceneWarning, match="test = 'picture_frame' does not read specimen.length_mm"):
        frame_scene(**{"specimen.length_mm": 300.0})
    with pytest.warns(SceneWarning, match="discretization.structured"):  # Netgen meshes the cross
        frame_scene(**{"discretization.structured": True})
    with pytest.warns(SceneWarning, match="picture_frame.frame_mm"):
        Scene().with_changes(**{"picture_frame.frame_mm": 216.0})


def test_a_frame_scene_reads_back_from_its_toml():
    sc = frame_scene(**{"picture_frame.misalignment_deg": 2.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        assert Scene.from_toml_string(sc.to_toml()) == sc
    assert Scene().test == "bias_extension"


# --------------------------------------------------------------------------- mesh
def test_the_cross_is_the_frame_square_less_its_corners_with_the_arms_clamped():
    disc = Discretization(mesh_size_mm=20.0, corner_mesh_size_mm=0.0)
    # arms clamped over their length (the default) move with the bars: the fabric that deforms is
    # the inner square, its whole edge on the frame
    held = make_cross_mesh(PictureFrame(frame_mm=145.0, fabric_mm=120.0), Specimen(), disc)
    assert ngs.Integrate(1.0, held) * 1e6 == pytest.approx(120.0**2, rel=1e-12)
    assert ngs.Integrate(1.0, held.Boundaries(CLAMPED_ARMS)) * 1e3 == pytest.approx(4 * 120.0, rel=1e-12)
    pf = PictureFrame(frame_mm=145.0, fabric_mm=120.0, arms="sheared")
    mesh = make_cross_mesh(pf, Specimen(), disc)
    c = 12.5
    assert ngs.Integrate(1.0, mesh) * 1e6 == pytest.approx(145**2 - 4 * c**2, rel=1e-12)
    # the four arms' ends on the bars, each as long as the fabric square
    assert ngs.Integrate(1.0, mesh.Boundaries(CLAMPED_ARMS)) * 1e3 == pytest.approx(4 * 120.0, rel=1e-12)
    pts = np.array([p for p, _ in cross_outline(pf)]) * 1e3
    # the pins (0, 0) and (√2 L, 0) are cut away with their corners: the cross spans c/√2 ... √2 L − c/√2
    assert pts[:, 0].min() == pytest.approx(c / math.sqrt(2), rel=1e-12)
    assert pts[:, 0].max() == pytest.approx(math.sqrt(2) * 145 - c / math.sqrt(2), rel=1e-12)


# --------------------------------------------------------------------------- exact solutions
@pytest.mark.parametrize("bending", [False, True])
def test_the_clamped_square_shears_homogeneously_with_the_force_of_its_energy(bending):
    # fabric_mm = frame_mm: affine Dirichlet data on the whole boundary and a homogeneous material,
    # so the affine map of the frame is the solution (φ = i8 constant: no bending energy, Λ = 0); it
    # lies in the finite element space, so the computed force is t A dW/dd to the solver's tolerance
    sc = frame_scene(**{"effects.bending": bending})
    r = simulate(sc)
    assert r.summary["status"] == "ok"
    d = r.u0_mm
    exact = np.array([homogeneous_force(sc, x) for x in d])
    assert r.force_N == pytest.approx(exact, rel=1e-8)  # the central difference of W: ~1e-9
    gamma = np.degrees(frame_shear_angle_rad(d, 100.0))
    assert r.shear_angle_deg == pytest.approx(gamma, abs=1e-12)
    assert r.gamma_centre_deg == pytest.approx(gamma, abs=1e-6)
    assert r.gamma_fabric_deg == pytest.approx(gamma, abs=1e-6)
    assert np.max(r.elongation_max) < 1e-8  # the yarns run along the bars: not stretched
    theta = np.arccos((math.sqrt(2) * 100 + d) / 200)
    assert r.shear_force_N == pytest.approx(r.force_N / (2 * np.cos(theta)), rel=1e-14)  # Eq. 3
    assert r.fnorm_N_per_mm == pytest.approx(r.shear_force_N * 100 / 100**2, rel=1e-14)  # Eq. 10
    # Λ = 0 exactly: its round-off is not called an oscillating multiplier (ratio ~0.96 of noise to noise)
    assert r.summary.get("multiplier_oscillation") == (0.0 if bending else None)
    assert not any("multiplier" in w for w in r.summary["warnings"])


def test_the_shear_angle_field_of_the_clamped_square_is_the_frames_everywhere():
    sc = frame_scene(**{"loading.u0_mm": 40.0, "loading.stops_mm": []})
    solver = ContinuumSolver(ContinuumProblem(sc), solver_settings(sc))
    for _ in load_path(solver, sc):
        pass
    p = solver.problem
    inv = p.invariants()
    g = physics.shear_angle(inv.i4, inv.i6, inv.i8, sc.specimen.cos0)
    pts = p.mesh.MapToAllElements(ngs.IntegrationRule(ngs.TRIG, 4), ngs.VOL)
    values = np.degrees(np.asarray(g(pts)).ravel())
    assert values == pytest.approx(math.degrees(frame_shear_angle_rad(40.0, 100.0)), abs=1e-6)
    assert np.asarray(p.phi(pts)).ravel() == pytest.approx(np.asarray(inv.i8(pts)).ravel(), abs=1e-10)


@pytest.mark.parametrize("misalignment", [3.0, -45.0])
def test_misaligned_yarns_stretch_and_the_force_is_still_that_of_the_energy(misalignment):
    # the fabric turned 3° in the frame: still a homogeneous state (affine data, homogeneous
    # material), but its yarns no longer follow the bars and stretch (Eq. 1's frame then carries
    # K_el); the crosshead force is t A dW/dd with W now holding the elongation energy. At 45° the
    # yarns run along the frame's diagonals, one family along the crosshead: the stiffest case
    sc = frame_scene(**{"picture_frame.misalignment_deg": misalignment, "effects.bending": False})
    r = simulate(sc)
    exact = np.array([homogeneous_force(sc, x) for x in r.u0_mm])
    assert r.force_N == pytest.approx(exact, rel=1e-7)
    # (at 45° the chord rows stop 2.8e-7 short in the elongation, at the force's 1e-7: the test of a
    # row weighs the stiff family along the crosshead)
    tol = 1e-8 if abs(misalignment) < 45 else 1e-6
    assert r.elongation_max == pytest.approx([homogeneous_elongation(sc, x) for x in r.u0_mm], rel=tol)
    assert np.all(r.elongation_max > 1e-3)


def test_cutting_the_corners_only_lowers_the_energy():
    # the affine map of the frame is admissible for the cross too (its arms follow the bars); the
    # solution minimises the energy, so E <= t A_cross W(d), and strictly below: the free edges of
    # the cut corners carry no traction, which the homogeneous stress would put on them
    sc = frame_scene(**{"picture_frame.fabric_mm": 80.0, "picture_frame.arms": "sheared", "effects.bending": False})
    r = simulate(sc)
    area = (100.0**2 - 4 * 10.0**2) * 1e-6
    bound = np.array([sc.specimen.t * area * homogeneous_energy(sc, x) for x in r.u0_mm])
    assert np.all(r.energy_J < bound * (1 - 1e-4))
    assert np.all(r.energy_J > 0.5 * bound)


@pytest.mark.parametrize("misalignment", [0.0, 3.0])
def test_held_arms_shear_the_inner_square_alone_with_the_force_of_its_energy(misalignment):
    # arms held over their length move with the frame: the inner square has the frame's affine data on
    # its whole edge, so the affine map is the solution there and the crosshead force is t L_fabric² dW/dd;
    # its F_norm (Eq. 10) is then that of the whole square in the same frame, for any fabric_mm
    keys = {"effects.bending": False, "picture_frame.misalignment_deg": misalignment}
    held = frame_scene(**keys, **{"picture_frame.fabric_mm": 70.0})  # the default: arms held
    r = simulate(held)
    assert r.summary["status"] == "ok"
    exact = np.array([homogeneous_force(held, x) for x in r.u0_mm]) * 0.7**2
    assert r.force_N == pytest.approx(exact, rel=1e-7)
    whole = simulate(frame_scene(**keys))
    common = np.isin(r.u0_mm, whole.u0_mm)
    assert common.sum() >= 3
    assert r.fnorm_N_per_mm[common] == pytest.approx(whole.fnorm_N_per_mm[np.isin(whole.u0_mm, r.u0_mm)], rel=1e-9)
    # the yarns' angle change of the homogeneous state (the frame's shear angle when aligned)
    inv = np.array([homogeneous_invariants(held, x) for x in r.u0_mm])
    gamma = np.degrees(np.arccos(inv[:, 2] / np.sqrt(inv[:, 0] * inv[:, 1]))) - 90.0
    assert r.gamma_fabric_deg == pytest.approx(gamma, abs=1e-6)
    # the same cross with its arms sheared carries the arms' energy too: nearly the cross's area over
    # the inner square's, (100² − 30²)/70² = 1.857, a little less where the cut edges go free (its
    # energy stays below t A_cross W: test_cutting_the_corners_only_lowers_the_energy)
    sheared = simulate(frame_scene(**keys, **{"picture_frame.fabric_mm": 70.0, "picture_frame.arms": "sheared"}))
    ratio = sheared.fnorm_N_per_mm[np.isin(sheared.u0_mm, r.u0_mm)] / r.fnorm_N_per_mm[np.isin(r.u0_mm, sheared.u0_mm)]
    assert np.all((ratio > 0.95 * (100**2 - 30**2) / 70**2) & (ratio < (100**2 - 30**2) / 70**2))
    with pytest.raises(SceneError, match="picture_frame.arms"):
        frame_scene(**{"picture_frame.arms": "glued"})


# --------------------------------------------------------------------------- shipped scenes, figures
GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


def test_the_shipped_frame_scenes_are_the_benchmarks_frames():
    # Cao et al. 2008, Table 3: UN 145 / 120 mm, UML 216 / 140 mm; every key read
    files = sorted(GEOMETRY.glob("twintex_*_pf_*.toml"))
    assert len(files) == 4
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter("error", SceneWarning)
            sc = Scene.from_toml(f)
        frame = {"UN": (145.0, 120.0), "UML": (216.0, 140.0)}[f.stem.rsplit("_", 1)[1]]
        assert (sc.test, sc.picture_frame.frame_mm, sc.picture_frame.fabric_mm) == ("picture_frame", *frame)
        assert sc.picture_frame.arms == "held"  # the benchmark's cross: arms clamped over their length
        assert math.degrees(frame_shear_angle_rad(sc.loading.u0_mm, frame[0])) == pytest.approx(49.5, abs=0.2)


def test_the_frame_figures_are_drawn_inside_their_canvas(tmp_path):
    from ngbet.figures.data import load_maps, read_scene
    from ngbet.figures.frame import frame_force_figure, frame_shear_figure
    from ngbet.figures.maps import shear_map_figure
    from ngbet.figures.style import in_style, texts_outside
    from ngbet.tables import read_rows

    sc = frame_scene(**{"picture_frame.fabric_mm": 80.0, "picture_frame.misalignment_deg": 1.0, "outputs.plot": True})
    simulate(sc, out=tmp_path / "run")
    rows, scene = read_rows(tmp_path / "run" / "results.csv"), read_scene(tmp_path / "run")
    with in_style():
        maps = shear_map_figure(load_maps(tmp_path / "run"), scene)
        for fig in (frame_force_figure(rows, scene), frame_shear_figure(rows, scene), maps):
            assert texts_outside(fig) == []
            words = " ".join(t.get_text() for t in fig.findobj(match=lambda a: hasattr(a, "get_text")))
            assert not any(f in words for f in (".csv", ".json", "u₀")), words  # no file names; the travel is d
            assert "picture-frame test, frame 100 mm pin to pin, fabric square 80 mm" in fig.get_suptitle().replace(
                "\u00a0", " "
            ).replace("\n", " ")
    # the caption names the arms only where they are not the benchmark's (held over their length)
    from ngbet.figures.style import caption

    assert "(arms" not in caption(sc)
    assert "80\u00a0mm (arms sheared)" in caption(sc.with_changes(**{"picture_frame.arms": "sheared"}))


@pytest.mark.integration
def test_a_shipped_frame_scene_runs_with_its_figures_and_an_ideal_centre(tmp_path):
    # the plain weave in the UN frame: the inner square shears with the frame (bending stiffness
    # 1 Pa m², internal lengths < 1 mm): the centre's shear angle within 0.1° of Eqs. 1-2
    r = simulate(Scene.from_toml(GEOMETRY / "twintex_plain_pf_UN.toml"), out=tmp_path / "run")
    assert r.summary["status"] == "ok"
    assert np.max(np.abs(r.gamma_centre_deg - r.shear_angle_deg)) < 0.1
    for name in ("force", "shear_force", "shear_map"):
        assert (tmp_path / "run" / f"{name}.png").exists()
    assert not (tmp_path / "run" / "profile.png").exists()


def test_a_measured_frame_curve_is_read_without_its_clipped_points(tmp_path):
    from ngbet.figures.frame import read_frame_measured

    m = read_frame_measured(
        Path(__file__).resolve().parents[1]
        / "data"
        / "cao2008_pf"
        / "cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv"
    )
    # the chart's top edge (0.3 N/mm) clips the curve near 40°: those points are not values
    assert m.quantity == "normalized_shear_force_N_per_mm" and m.values.max() < 0.29996
    assert m.fnorm(145.0, 120.0) is m.values
    f = tmp_path / "fs.csv"
    f.write_text("# a frame\nshear_angle_deg,shear_force_N\n0,0\n30,5.7735\n")
    assert read_frame_measured(f).fnorm(145.0, 120.0)[1] == pytest.approx(5.7735 * 145 / 120**2, rel=1e-14)
    f.write_text(
        "# picture_frame.frame_mm = 216\n# picture_frame.fabric_mm = 140\n"
        "shear_angle_deg,shear_force_N\n0,0\n30,5.7735\n"
    )
    # F_s of a frame its file names is normalised with that frame, not the run's
    assert read_frame_measured(f).fnorm(145.0, 120.0)[1] == pytest.approx(5.7735 * 216 / 140**2, rel=1e-14)
    f.write_text("displacement_mm,force_N\n0,0\n1,1\n")
    with pytest.raises(ValueError, match="shear_angle_deg,shear_force_N"):
        read_frame_measured(f)
    f.write_text("# specimen.width_mm = 100\n# specimen.length_mm = 200\ndisplacement_mm,force_N\n0,0\n1,1\n2,3\n")
    with pytest.raises(ValueError, match="a bias extension curve .it names a specimen and no picture frame., and the"):
        read_frame_measured(f)
