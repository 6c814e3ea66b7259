"""Fabric scenes, the tabulated shear law, measured-data checks and the joint fit of several specimen sizes."""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path
from types import SimpleNamespace

import ngsolve as ngs
import numpy as np
import pytest

from ngbet.calibration import bands, fit_params, joint
from ngbet.calibration.statistics import fit_statistics
from ngbet.calibration.table import shear_stress_points, start_table
from ngbet.cli import main
from ngbet.continuum import physics
from ngbet.kinematics import ideal_force
from ngbet.measured.curves import read_any, read_measured
from ngbet.runner.sensitivity import finite_difference, force_path
from ngbet.scene.document import Scene
from ngbet.scene.validate import SceneError

ROOT = Path(__file__).resolve().parents[1]
GEO = ROOT / "geometry"
DATA = ROOT / "data" / "cao2008"
FABRICS = {
    "plain": ("plain_150x300_INSA-NU", 1.2),
    "twill_balanced": ("twill_balanced_150x300_INSA-NU", 2.0),
    "twill_unbalanced": ("twill_unbalanced_100x250_UN", 3.3),
}


# ------------------------------------------------------------------------------------------ fabric scenes
@pytest.mark.parametrize("fabric", FABRICS)
def test_fabric_scene_is_the_data_specimen(fabric):
    """Each fabric scene is the specimen of its fitted curve (the data file's header keys), with
    the fabric's thickness, and names the parameters a fit adjusts with a bound for each."""
    stem, t = FABRICS[fabric]
    sc = Scene.from_toml(GEO / f"twintex_{fabric}.toml")
    c = read_measured(DATA / f"cao2008_{stem}.csv")
    assert sc.specimen.width_mm == c.specimen["specimen.width_mm"]
    assert sc.specimen.length_mm == c.specimen["specimen.length_mm"]
    assert sc.specimen.thickness_mm == c.specimen["specimen.thickness_mm"] == t
    assert sc.effects.shear_law == "table"
    cal = sc.calibration
    assert len(cal.lower) == len(cal.upper) == len(cal.params) >= 2
    names = fit_params.expand_params(sc, cal.params)
    start = np.array([fit_params.value_of(sc, n) for n in names])
    lo, hi = fit_params.bounds(sc, cal.params, names, start)
    assert np.all((lo < start) & (start < hi))
    assert "warp" in cal.yarns_m1 and "weft" in cal.yarns_m2


#: the densest yarn counts of data/cao2008/README.md (Cao et al. 2008, Table 1), per cm: warp ends, weft picks
YARN_COUNTS = {"plain": (1.95, 1.95), "twill_balanced": (5.56, 3.75), "twill_unbalanced": (3.39, 1.52)}


@pytest.mark.parametrize("fabric", FABRICS)
def test_fabric_scene_bending_bounds_are_an_internal_length_of_one_crossing_spacing(fabric):
    """The lower bound of α_k is τ'(0) s², s the spacing of the yarns crossing family k (the picks for
    the warp's α1, the ends for the weft's α2) and τ'(0) the start table's initial shear modulus: an
    internal length √(α_k/τ'(0)) below one crossing spacing is finer than the yarns can bend. Within
    the two digits the scene gives it."""
    from ngbet.continuum.physics import table_stress_spline

    sc = Scene.from_toml(GEO / f"twintex_{fabric}.toml")
    m, cal = sc.material, sc.calibration
    k0 = float(table_stress_spline(m.shear_stress_steps_Pa, m.shear_table_i8_max)(0.0, 1))
    ends, picks = YARN_COUNTS[fabric]
    for key, per_cm in (("material.alpha1", picks), ("material.alpha2", ends)):
        bound = cal.lower[cal.params.index(key)]
        assert bound == pytest.approx(k0 * (1e-2 / per_cm) ** 2, rel=0.03)


def test_unbalanced_twill_warp_is_the_stiffer_family():
    """3.39 warp ends/cm against 1.52 weft picks/cm: the warp runs along m1 and bends more stiffly."""
    sc = Scene.from_toml(GEO / "twintex_twill_unbalanced.toml")
    assert "3.39" in sc.calibration.yarns_m1 and "1.52" in sc.calibration.yarns_m2
    assert sc.material.alpha1 > sc.material.alpha2
    bal = Scene.from_toml(GEO / "twintex_twill_balanced.toml")
    assert bal.material.alpha1 == bal.material.alpha2


def test_calibration_section_is_validated():
    with pytest.raises(SceneError, match="calibration.params"):
        Scene().with_changes(**{"calibration.params": ["loading.u0_mm"]})
    with pytest.raises(SceneError, match="calibration.lower"):
        Scene().with_changes(**{"calibration.params": ["material.K_sh"], "calibration.lower": [1.0, 2.0]})
    with pytest.raises(SceneError, match="calibration.lower"):
        Scene().with_changes(
            **{"calibration.params": ["material.K_sh"], "calibration.lower": [5.0], "calibration.upper": [1.0]}
        )
    with pytest.raises(SceneError, match="calibration.table_smoothness_sd"):
        Scene().with_changes(**{"calibration.table_smoothness_sd": -1.0})
    sc = Scene.from_toml(GEO / "twintex_plain.toml")
    assert Scene.from_toml_string(sc.to_toml()) == sc


def test_smoothness_prior_rows_are_second_differences_of_consecutive_fitted_rises():
    key = fit_params.TABLE_KEY
    names = [f"{key}[0]", "material.alpha1", f"{key}[1]", f"{key}[2]", f"{key}[4]", f"{key}[5]", f"{key}[6]"]
    P = fit_params.smoothness_rows(names, 0.5)
    # rises 0-1-2 and 4-5-6 are consecutive, 2 and 4 are not: two rows
    assert P.shape == (2, len(names))
    assert np.all(P[:, 1] == 0)
    # a geometric sequence of rises costs nothing: its ln has no second difference
    theta = np.log([10.0, 3.0, 10.0 * 4, 10.0 * 16, 7.0 * 2**4, 7.0 * 2**5, 7.0 * 2**6])
    assert np.allclose(P @ theta, 0.0, atol=1e-12)
    # one rise doubled: its row moves by ln 2 / sd
    theta[3] += math.log(2.0)
    assert P @ theta == pytest.approx([math.log(2.0) / 0.5, 0.0], abs=1e-12)
    assert fit_params.smoothness_rows(names, 0.0).shape == (0, len(names))


def test_the_prior_holds_what_the_data_leave_open_and_the_report_says_the_data_leave_it():
    # a linear model whose data do not see the third rise: the covariance with the prior is the
    # Gaussian posterior s^2 (J^T J + P^T P)^-1, while the third rise is reported undetermined by the data
    key = fit_params.TABLE_KEY
    names = [f"{key}[{j}]" for j in range(3)]
    rng = np.random.default_rng(3)
    Jd = np.column_stack([rng.normal(size=20), rng.normal(size=20), np.zeros(20)])
    P = fit_params.smoothness_rows(names, 1.0)
    e = np.concatenate([rng.normal(size=20) * 2.0, [0.3]])
    st = fit_statistics(e, np.vstack([Jd, P]), names, len(P))
    s2 = float(e[:20] @ e[:20]) / (20 - 3)
    assert s2 > 1
    assert st["cov"] == pytest.approx(s2 * np.linalg.inv(Jd.T @ Jd + P.T @ P), rel=1e-9)
    assert list(st["undetermined"]) == [f"{key}[2]"]
    assert "smoothness prior" in st["undetermined"][f"{key}[2]"]


def test_a_rise_at_zero_where_the_data_determine_the_law_is_not_reported_undetermined():
    """A linear table (τ piecewise linear through the knots' control values c_j = Σ_{i<=j} r_i) seen at
    30 points below the last knot: the second rise, at 1 Pa between rises of kilopascals, is on a
    flat direction of ln r (the 0.5 rule and the flat-direction test name it), but the data fix
    τ at its knot, so it is at zero; the last rise, also at 1 Pa but beyond every point, leaves τ
    at its knot unknown and stays undetermined."""
    key = fit_params.TABLE_KEY
    r = np.array([3000.0, 1.0, 2000.0, 1.0])
    names = [f"{key}[{j}]" for j in range(4)]
    knots = np.linspace(0.0, 1.0, 5)
    x = np.linspace(0.02, 0.7, 30)
    hats = np.array([np.interp(x, knots, np.eye(5)[k]) for k in range(1, 5)]).T  # N_1..N_4 at x
    J_lin = np.cumsum(hats[:, ::-1], axis=1)[:, ::-1]  # dτ/dr_j = Σ_{k>=j+1} N_k
    sd = 50.0
    e = np.random.default_rng(5).normal(size=len(x))
    st = fit_statistics(e, J_lin * r / sd, names)
    assert {f"{key}[1]", f"{key}[3]"} <= set(st["undetermined"])
    zero = fit_params.rises_at_zero(names, r, st["cov_data"], r, st["undetermined"])
    assert list(zero) == [f"{key}[1]"]
    assert "shear stress at its knot is 3e+03 Pa" in zero[f"{key}[1]"]
    # the linear standard error of the rise, from the linearized fit, is what the message states
    seen = J_lin[:, :3]  # the last rise has no column the data see
    se_r1 = math.sqrt(float(np.linalg.inv(seen.T @ seen)[1, 1])) * sd * st["noise_scale"]
    assert f"± {se_r1:.2g} Pa" in zero[f"{key}[1]"]


# ------------------------------------------------------------------------------------------ tabulated law
_MESH: list[ngs.Mesh] = []


def _at(cf: ngs.CoefficientFunction) -> float:
    if not _MESH:
        _MESH.append(ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=1.0)))
    return float(cf(_MESH[0](0.5, 0.5)))


def quadratic_table(K: float, n: int, x_max: float) -> list[float]:
    """The rises that make the tabulated stress K |i8|: K times the steps of the Greville abscissae."""
    return list(K * np.diff(physics.table_greville(n, x_max)))


@pytest.mark.parametrize("i8v", [0.05, -0.4, 0.93, 1.2])
def test_table_of_the_quadratic_law_is_the_quadratic_law(i8v):
    """A spline reproduces a straight line from its values at the Greville abscissae: energy,
    stress and stiffness equal ½K i8², K i8, K to round-off, inside the table and beyond it."""
    K, i8 = 2.1e4, ngs.Parameter(i8v)
    W = physics.table_shear_energy(i8, quadratic_table(K, 6, 0.95), 0.95)
    assert _at(W) == pytest.approx(0.5 * K * i8v**2, rel=1e-12)
    assert _at(W.Diff(i8)) == pytest.approx(K * i8v, rel=1e-12)
    assert _at(W.Diff(i8).Diff(i8)) == pytest.approx(K, rel=1e-10)


def test_tabulated_law_reproduces_the_quadratic_run():
    """On a coarse mesh (25 mm, p = 2, the plain-weave specimen to 50 mm), the table of the
    quadratic law gives the quadratic law's forces to 1e-8 (the energies agree to round-off)."""
    sc = Scene.from_toml(GEO / "twintex_plain.toml").with_changes(
        **{"effects.shear_law": "quadratic", "material.K_sh": 2e4, "loading.u0_mm": 50.0}
    )
    u = [10.0, 30.0, 50.0]
    quad = force_path(sc, u).force_N
    tab = force_path(
        sc.with_changes(
            **{"effects.shear_law": "table", "material.shear_stress_steps_Pa": quadratic_table(2e4, 6, 0.95)}
        ),
        u,
    ).force_N
    np.testing.assert_allclose(tab, quad, rtol=1e-8)


def test_tabulated_energy_is_convex_for_a_monotone_table():
    """Random non-negative rises (a monotone table): W'' = dτ/d|i8| >= 0 at 400 points from −1.3
    to 1.3 (in and beyond the table), and the energy is even in i8. A falling table is refused."""
    rng = np.random.default_rng(3)
    x = np.linspace(-1.3, 1.3, 401)
    for _ in range(5):
        steps = list(rng.exponential(1e4, 7) * (rng.random(7) > 0.3))
        i8 = ngs.Parameter(0.0)
        W = physics.table_shear_energy(i8, steps, 0.9)
        H = W.Diff(i8).Diff(i8)
        curv, energy = [], []
        for v in x:
            i8.Set(v)
            curv.append(_at(H))
            energy.append(_at(W))
        assert min(curv) >= -1e-9 * max(curv)
        np.testing.assert_allclose(energy, energy[::-1], rtol=1e-12, atol=1e-9)
    with pytest.raises(SceneError, match="shear_stress_steps_Pa"):
        Scene().with_changes(**{"material.shear_stress_steps_Pa": [1e4, -10.0, 1e4]})
    with pytest.raises(SceneError, match="shear_stress_steps_Pa"):
        Scene().with_changes(**{"effects.shear_law": "table"})


def test_tabulated_energy_is_twice_continuously_differentiable():
    """Newton needs a continuous tangent: W'' = dτ/d|i8| agrees on both sides of every knot (and
    of the end of the table) to 1e-5 of its size for a step of 1e-7 (its third derivative is finite)."""
    steps, x_max = [3e3, 500.0, 8e3, 2e4, 6e4, 1e4], 0.95
    knots = np.unique(physics.table_stress_spline(steps, x_max).t)
    i8 = ngs.Parameter(0.0)
    H = physics.table_shear_energy(i8, steps, x_max).Diff(i8).Diff(i8)
    for k in knots[1:]:
        vals = []
        for v in (k - 1e-7, k + 1e-7):
            i8.Set(v)
            vals.append(_at(H))
        assert abs(vals[1] - vals[0]) <= 1e-5 * max(abs(vals[0]), 1.0), (k, vals)


def test_table_sensitivities_match_finite_differences():
    """dF/d ln(rise) of the table (its energy is linear in the rises) and dF/d ln K_el agree with
    central differences of whole runs to 1e-6 of each column's largest value (measured 1.6e-7,
    7e-8, 4e-8 on this 25 mm p = 2 mesh); dF/d ln alpha1 to 2e-3 (measured 1.0e-3): the scene has
    alpha1 = alpha2, where K_s = c min(alpha1, alpha2)/h_T² has a kink; the implicit derivative
    takes the side where K_s follows alpha1, the central difference the mean of both sides (the
    sum of the alpha1 and alpha2 derivatives agrees to 2e-6)."""
    sc = Scene.from_toml(GEO / "twintex_plain.toml").with_changes(**{"loading.u0_mm": 45.0})
    u = [15.0, 30.0, 45.0]
    P = ["material.shear_stress_steps_Pa[0]", "material.shear_stress_steps_Pa[3]", "material.K_el", "material.alpha1"]
    impl = force_path(sc, u, P).dlogp
    fd = finite_difference(sc, u, P, rel_step=1e-3)
    err = np.abs(impl - fd).max(axis=0) / np.abs(fd).max(axis=0)
    assert np.all(err < [1e-6, 1e-6, 1e-6, 2e-3]), dict(zip(P, err, strict=True))


def test_band_of_the_fitted_table_is_the_covariance_of_its_rises_through_the_spline():
    """τ is linear in the rises: one fitted rise s_i with se σ of ln s_i gives sd τ = σ s_i τ_i(x);
    two independent ones add in quadrature; a parameter that is not a rise adds nothing."""
    from types import SimpleNamespace

    from ngbet.calibration.report import table_band

    steps, x_max = [2.0e3, 5.0e3, 8.0e3, 1.0e4], 0.9
    x = np.linspace(0.05, 0.85, 9)
    unit = [np.nan_to_num(physics.table_stress_spline(np.eye(4)[i], x_max)(x)) for i in range(4)]
    material = SimpleNamespace(shear_stress_steps_Pa=steps, shear_table_i8_max=x_max)
    names = ["material.shear_stress_steps_Pa[1]", "material.K_el", "material.shear_stress_steps_Pa[3]"]
    cov = np.diag([0.3**2, 7.0, 0.1**2])
    result = SimpleNamespace(names=names, cov_log=cov, scene=SimpleNamespace(material=material))
    expected = np.hypot(0.3 * steps[1] * unit[1], 0.1 * steps[3] * unit[3])
    assert np.allclose(table_band(result, x), expected, rtol=1e-12, atol=0.0)
    assert expected.min() > 0  # the rises reach every x here: the test compares nonzero values


def test_start_table_from_the_ideal_quadratic_curve(tmp_path):
    """The ideal-kinematics force of the quadratic law (K = 2e4 Pa, 150 x 300 mm, t = 1.2 mm),
    normalised by Cao's Eq. 18 and turned into a stress, is τ = K sin γ = K |i8|: the points agree
    to 1 % and the fitted table's rises to 3 % of the quadratic law's."""
    sc = Scene().with_changes(
        **{"specimen.width_mm": 150.0, "specimen.length_mm": 300.0, "specimen.thickness_mm": 1.2, "material.K_sh": 2e4}
    )
    u = np.linspace(0.5, 56.0, 200)
    F = np.array([ideal_force(sc, v) for v in u])
    path = tmp_path / "ideal.csv"
    path.write_text(
        "# specimen.width_mm = 150\n# specimen.length_mm = 300\ndisplacement_mm,force_N\n"
        + "".join(f"{a},{b}\n" for a, b in zip(u, F, strict=True))
    )
    c = read_measured(path)
    x, tau = shear_stress_points(c, 1.2)
    np.testing.assert_allclose(tau, 2e4 * x, rtol=0.01)
    steps = start_table(c, 1.2, 4, 0.95)
    np.testing.assert_allclose(steps, quadratic_table(2e4, 4, 0.95), rtol=0.03)


# ------------------------------------------------------------------------------------------ input checks
def _csv(path: Path, body: str, header: str = "# specimen.width_mm = 150\n# specimen.length_mm = 300\n") -> Path:
    path.write_text(header + body)
    return path


GOOD = "displacement_mm,force_N\n" + "".join(f"{u},{0.02 * u + 0.001 * u * u}\n" for u in range(1, 41))


@pytest.mark.parametrize(
    "body, message",
    [
        ("".join(f"{u},{u * 0.1}\n" for u in range(1, 20)), "line 3: a row of numbers where the header should be"),
        (GOOD.replace("20,0.8", "20,nan"), "line 23: force_N = 'nan' is not a finite number"),
        (GOOD.replace("20,0.8", "20,inf"), "line 23: force_N = 'inf' is not a finite number"),
        (GOOD.replace("20,0.8", "20,0.8x"), "line 23: force_N = '0.8x' is not a number"),
        (GOOD.replace("20,0.8", "20,-0.8"), "line 23: displacement 20 mm, force -0.8 N"),
        ("displacement_mm,force_N\n1,2\n", "at least 3 are needed"),
    ],
)
def test_bad_data_is_refused_before_any_model_run(tmp_path, capsys, body, message):
    """Each fault of a data file ends with exit 2 and a message naming the file and the line;
    nothing is fitted (no fit.json)."""
    bad = _csv(tmp_path / "bad.csv", body)
    out = tmp_path / "fit"
    assert main(["fit", str(bad), "--scene", str(GEO / "twintex_plain.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and message in err
    assert not (out / "fit.json").exists()


def test_bad_options_and_predict_inputs_are_refused_first(tmp_path, capsys):
    """--predict files and scenes, --max-runs, --params, two scenes: refused with exit 2 before the fit."""
    good = _csv(tmp_path / "good.csv", GOOD)
    other = _csv(tmp_path / "other.csv", GOOD.replace("20,0.8", "20,0.81"), header="")
    scene = str(GEO / "twintex_plain.toml")
    out = tmp_path / "fit"
    cases = [
        (["--predict", str(tmp_path / "missing.csv")], "data file not found"),
        (["--predict", str(_csv(tmp_path / "p.csv", "displacement_mm,force_N\n1,x\n2,3\n3,4\n"))], "line 4"),
        (["--predict", str(other), "--predict-scene", str(tmp_path / "none.toml")], "scene file not found"),
        (["--max-runs", "0"], "--max-runs 0"),
        (["--params", ","], "--params ',' names no key"),
        (["--params", "material.K_lock", "--set", "effects.shear_law=locking"], "positive start value"),
        (["--params", "loading.u0_mm"], "not a material key"),
    ]
    for extra, message in cases:
        assert main(["fit", str(good), "--scene", scene, "--out", str(out), *extra]) == 2, extra
        err = capsys.readouterr().err
        assert message in err, (extra, err)
    assert main(["fit", str(good), str(GEO / "bet_100x300.toml"), "--scene", scene, "--out", str(out)]) == 2
    assert "one scene only" in capsys.readouterr().err
    assert not (out / "fit.json").exists()


def test_errorbars_are_read_and_floored():
    """The printed bars give the points' standard deviations (half a bar), never below the reading
    error or 1 % of the force; a bar of zero height (printed so) is floored."""
    c = read_measured(DATA / "cao2008_twill_balanced_150x450_INSA-NU.csv")
    assert c.bars is not None and len(c.bars[0]) == 38  # every bar of the file
    u = np.array([5.3565, 104.3585])
    sd = c.sd(u, np.interp(u, c.u_mm, c.force_N))
    assert sd[0] == pytest.approx(max(0.03, 0.01 * np.interp(5.3565, c.u_mm, c.force_N)))
    assert sd[1] == pytest.approx(0.5 * (38.3214 - 35.6856), rel=1e-6)


# ------------------------------------------------------------------------------------------ joint fit
SYN_TRUTH = {"material.K_sh": 2.5e4, "material.K_el": 3e6}
SYN_SIZES = [(150.0, 300.0), (150.0, 450.0)]


def synthetic_scene(**changes) -> Scene:
    """The plain-weave scene, quadratic law, bending too weak to see, a 30 mm mesh."""
    base = {
        "effects.shear_law": "quadratic",
        "material.alpha1": 0.05,
        "material.alpha2": 0.05,
        "discretization.mesh_size_mm": 30.0,
        "calibration.params": list(SYN_TRUTH),
        "calibration.lower": [1e3, 1e5],
        "calibration.upper": [1e6, 1e9],
        **SYN_TRUTH,
    }
    base.update(changes)
    return Scene.from_toml(GEO / "twintex_plain.toml").with_changes(**base)


def write_synthetic(
    folder: Path,
    seed: int = 7,
    rel: float = 0.02,
    points: int = 40,
    scales: tuple[float, float] = (1.0, 1.0),
    bars: tuple[float, float] | None = None,
) -> list[Path]:
    """Two sizes of the truth, each force times its ``scales`` entry with ``rel`` noise, ``points``
    points each, and error bars of ± ``bars`` (default ± ``rel``) of the force."""
    rng = np.random.default_rng(seed)
    paths = []
    for (W, L), scale, bar in zip(SYN_SIZES, scales, bars or (rel, rel), strict=True):
        sc = synthetic_scene(**{"specimen.width_mm": W, "specimen.length_mm": L})
        u = np.linspace(2.0, 0.85 * sc.specimen.locking_u0_mm, points)
        F = scale * force_path(sc.with_changes(**{"loading.u0_mm": float(u[-1])}), u).force_N
        F = F * (1 + rel * rng.standard_normal(len(F)))
        head = f"# synthetic\n# specimen.width_mm = {W:g}\n# specimen.length_mm = {L:g}\n"
        p = folder / f"syn_{W:g}x{L:g}.csv"
        p.write_text(head + "displacement_mm,force_N\n" + "".join(f"{a},{b}\n" for a, b in zip(u, F, strict=True)))
        p.with_name(p.stem + "_errorbars.csv").write_text(
            head
            + "displacement_mm,force_N,force_low_N,force_high_N\n"
            + "".join(f"{a},{b},{b * (1 - bar)},{b * (1 + bar)}\n" for a, b in zip(u, F, strict=True))
        )
        paths.append(p)
    return paths


@pytest.fixture(scope="module")
def synthetic_joint(tmp_path_factory):
    folder = tmp_path_factory.mktemp("syn")
    paths = write_synthetic(folder)
    start = synthetic_scene(**{"material.K_sh": 4e4, "material.K_el": 1e6})
    # on the truth's own discretization: the misfit is the noise alone
    return folder, paths, joint.fit_curves([read_measured(p) for p in paths], start, choose_discretization=False)


@pytest.mark.integration
def test_joint_fit_recovers_the_truth_within_two_standard_errors(synthetic_joint):
    """Two sizes, start values off by 1.6 and 0.33: K_sh and K_el within 2 se of the truth, each
    curve at the noise level (2 % noise: RMS 1-3 %)."""
    _, _, res = synthetic_joint
    for k, n in enumerate(res.names):
        z = abs(math.log(res.values[k] / SYN_TRUTH[n])) / res.se_log[k]
        assert z <= 2.0, (n, res.values[k], res.se_log[k])
        assert res.se_log[k] < 0.5
    assert all(0.01 < c.rms_relative < 0.03 for c in res.curves)


@pytest.mark.integration
def test_prediction_of_a_third_size_lies_in_its_band(synthetic_joint):
    """The fitted model on 100 x 300 mm: |prediction − truth| ≤ 2 sd (parameters and
    discretization) at every point, and the parameters' band is not vacuous: the start values miss
    by more (the 30 mm mesh's discretization part, estimated at up to 14 % of the force, is larger)."""
    _, _, res = synthetic_joint
    spec = {"specimen.width_mm": 100.0, "specimen.length_mm": 300.0}
    u = np.linspace(10.0, 65.0, 6)
    truth_scene = synthetic_scene(**spec, **{"loading.u0_mm": 65.0})
    truth = force_path(truth_scene, u).force_N
    pred = bands.predict_specimen(res, spec, u)
    assert np.all(np.abs(pred.force_N - truth) <= 2 * pred.sd_N)
    start = force_path(truth_scene.with_changes(**{"material.K_sh": 4e4, "material.K_el": 1e6}), u).force_N
    assert np.all(np.abs(start - truth) > 2 * pred.sd_param_N)


def _misfit_fit(curves: list[tuple[str, str, float, float]], n: int, m: int = 10) -> SimpleNamespace:
    """A fit's record as :func:`joint.model_error` reads it: per curve (test, label, a, b) m points
    of force F, standard deviation a F and residual ±b F (alternating), and n fitted parameters."""
    F = np.linspace(1.0, 20.0, m)
    sign = np.where(np.arange(m) % 2, 1.0, -1.0)
    return SimpleNamespace(
        names=[f"p{k}" for k in range(n)],
        curves=[
            SimpleNamespace(
                curve=SimpleNamespace(test=t), label=lab, model_N=F, measured_N=F - sign * b * F, sd_N=a * F
            )
            for t, lab, a, b in curves
        ],
    )


def test_model_error_is_the_misfit_between_specimens_beyond_their_noise():
    """Two sizes, 20 points with residuals ±b F and standard deviations a F, 2 parameters:
    Σ e²/(sd² + σ²F²) = m − n gives σ² = m b²/(m − n) − a² exactly (a = 2 %, b = 5 %: σ = 4.876 %);
    residuals within the noise (b = 0.9 a: Σe²/sd² = 16.2 < m − n = 18) give σ = 0; one size, or a
    fit of the other test only, give σ = 0 and words that name the data that would estimate it."""
    sizes = [("bias_extension", "100 x 250 mm", 0.02, 0.05), ("bias_extension", "100 x 200 mm", 0.02, 0.05)]
    sigma, words = bands.model_error(_misfit_fit(sizes, 2), "bias_extension")
    assert sigma == pytest.approx(math.sqrt(20 * 0.05**2 / 18 - 0.02**2), rel=1e-9)
    assert "model error between specimen sizes" in words and "4.9 %" in words
    within = [(t, lab, 0.02, 0.018) for t, lab, _, _ in sizes]
    sigma, words = bands.model_error(_misfit_fit(within, 2), "bias_extension")
    assert sigma == 0.0 and "agree within their noise" in words
    one = [("bias_extension", "100 x 250 mm", 0.02, 0.05)] * 2  # two curves of one size
    sigma, words = bands.model_error(_misfit_fit(one, 2), "bias_extension")
    assert sigma == 0.0 and "one specimen size" in words and "two or more specimen sizes" in words
    sigma, words = bands.model_error(_misfit_fit(sizes, 2), "picture_frame")
    assert sigma == 0.0 and "no model error between the tests" in words and "both tests" in words


def test_points_are_weighted_with_the_model_error_between_specimens():
    """The weights' model error is :func:`bands.model_error`'s σ (two sizes, a = 2 %, b = 5 %:
    4.876 %) times each measured force; weighing again at the same forces moves nothing (a fixed
    point, so the search is not repeated); a point without a model force is left out; one specimen
    size, or residuals within the noise, leave the points' own standard deviations alone."""
    sizes = [("bias_extension", "100 x 250 mm", 0.02, 0.05), ("bias_extension", "100 x 200 mm", 0.02, 0.05)]
    fit = _misfit_fit(sizes, 2)
    for c in fit.curves:
        c.model_sd_N = np.zeros(0)
    forces = [c.model_N for c in fit.curves]
    assert bands.weigh_model_error(fit.curves, forces, 2)
    sigma = math.sqrt(20 * 0.05**2 / 18 - 0.02**2)
    assert sigma == pytest.approx(bands.model_error(fit, "bias_extension")[0], rel=1e-12)
    for c in fit.curves:
        np.testing.assert_allclose(c.model_sd_N, sigma * np.abs(c.measured_N), rtol=1e-9)
    assert not bands.weigh_model_error(fit.curves, forces, 2)
    # a point whose run failed (no force) is left out, not a failure of the weights
    failed = [f.copy() for f in forces]
    failed[0][3] = np.inf
    bands.weigh_model_error(fit.curves, failed, 2)
    assert np.all(np.isfinite(fit.curves[0].model_sd_N)) and fit.curves[0].model_sd_N[0] > 0
    one_size = [("bias_extension", "100 x 250 mm", 0.02, 0.05)] * 2
    for case in (one_size, [(t, lab, 0.02, 0.018) for t, lab, _, _ in sizes]):
        fit = _misfit_fit(case, 2)
        for c in fit.curves:
            c.model_sd_N = np.zeros(0)
        bands.weigh_model_error(fit.curves, [c.model_N for c in fit.curves], 2)
        assert all(not np.any(c.model_sd_N) for c in fit.curves)


@pytest.mark.integration
def test_two_sizes_the_model_cannot_reconcile_are_missed_alike_not_by_their_error_bars(tmp_path, monkeypatch):
    """Two sizes made by the model, the 150 x 450 mm one's force times 1.3 (a model error between
    the sizes of 30 %) and its error bars ten times wider (±10 % against ±1 %), K_sh fitted alone.
    Weighted by their error bars only, the narrow curve decides: it is met (RMS < 2 %) and the
    other missed by 1 − 1/1.3 = 23 %. Weighted also with the model error σ the misfit shows, the
    fit is that of a scale k of the force (the force is nearly linear in K_sh): k minimises
    (k − 1)²/(0.01² + σ²) + (k/1.3 − 1)²/(0.1² + σ²), σ solves 16 Σ_curves r²/(rel² + σ²) = 31
    (m − n) at the fitted misses r; at that fixed point the misses are 7.6 % and 17.2 %, and the
    fit's are those to a percentage point (measured 7.7 % and 16.9 %); the weights' model error
    is the fitted curves' own (bands.model_error) to 10 %."""
    paths = write_synthetic(tmp_path, seed=3, rel=0.002, points=16, scales=(1.0, 1.3), bars=(0.01, 0.10))
    curves = [read_measured(p) for p in paths]

    def fit() -> fit_params.JointFit:
        return joint.fit_curves(
            curves, synthetic_scene(), ["material.K_sh"], choose_discretization=False, resample=False, workers=1
        )

    monkeypatch.setattr(joint, "REWEIGHTS", 0)
    own = fit()
    monkeypatch.undo()
    weighed = fit()
    a, b = (c.rms_relative for c in own.curves)
    assert a < 0.02 and b == pytest.approx(1 - 1 / 1.3, abs=0.02), (a, b)
    assert all(len(c.model_sd_N) == 0 for c in own.curves)
    from scipy.optimize import brentq, minimize_scalar

    def scale(sigma: float) -> float:
        w = np.array([1e-4, 1e-2]) + sigma**2
        return float(minimize_scalar(lambda k: (k - 1) ** 2 / w[0] + (k / 1.3 - 1) ** 2 / w[1]).x)

    def model_error_at(k: float) -> float:
        r = np.array([k - 1, k / 1.3 - 1]) * np.array([1.0, 1.3])  # the misses over the model force / k
        return float(brentq(lambda s: 16 * np.sum(r**2 / (np.array([1e-4, 1.69e-2]) + (s * k) ** 2)) - 31, 0, 5))

    k = scale(0.0)
    for _ in range(50):  # the fixed point of the weights and the scale
        k = scale(model_error_at(k))
    np.testing.assert_allclose([c.rms_relative for c in weighed.curves], [k - 1, 1 - k / 1.3], atol=0.01)
    sigma = float(np.max(weighed.curves[0].model_sd_N / weighed.curves[0].measured_N))
    assert sigma == pytest.approx(bands.model_error(weighed, "bias_extension")[0], rel=0.1)


def test_a_measured_point_is_inside_by_the_band_and_its_own_scatter():
    """Band sd 3 and the point's own sd 4 add as √(3² + 4²) = 5: a point 9.99 off is inside ±2 sd,
    10.01 off is not (neither would be by the band alone)."""
    from ngbet.calibration.report import within_band

    pred, sd = np.full(2, 10.0), np.full(2, 3.0)
    meas = np.array([19.99, 20.01])
    assert within_band(pred, sd, meas, np.full(2, 4.0)) == 0.5
    assert within_band(pred, sd, meas, np.zeros(2)) == 0.0


@pytest.mark.integration
def test_the_band_of_a_prediction_covers_the_truth_at_its_claimed_rate(tmp_path):
    """Data made by the model (two sizes, 2 % independent noise, error bars ±2 %), fitted on its
    own 30 mm mesh (no discretization error) at its own points, for 8 noise seeds: the truth of a
    third size (100 x 300 mm) against the prediction's band from the parameters. If the band is
    right, z = (prediction − truth)/sd is standard normal at each point and the mean of z² over
    the seeds (each seed's mean over its points, one χ²₁-like draw at most) lies within the 0.1 %
    and 99.9 % quantiles of χ²₈/8 (0.107, 3.27); 16 seeds measured 1.06, 92 % of the points
    within ±2 sd. The model error the fit estimates is nil (the two sizes agree within their noise)."""
    spec = {"specimen.width_mm": 100.0, "specimen.length_mm": 300.0}
    u = np.linspace(10.0, 65.0, 6)
    truth = force_path(synthetic_scene(**spec, **{"loading.u0_mm": 65.0}), u).force_N
    z2 = []
    for seed in range(1, 9):
        folder = tmp_path / f"seed{seed}"
        folder.mkdir()
        curves = [read_measured(p) for p in write_synthetic(folder, seed=seed)]
        res = joint.fit_curves(curves, synthetic_scene(), choose_discretization=False, resample=False, workers=1)
        pred = bands.predict_specimen(res, spec, u)
        z2.append(np.mean(((pred.force_N - truth) / pred.sd_param_N) ** 2))
        assert np.all(pred.sd_model_N == 0.0), pred.band
    assert 0.107 <= np.mean(z2) <= 3.27, z2


@pytest.mark.integration
def test_cli_joint_fit_and_the_fitted_scene_on_another_specimen(synthetic_joint, tmp_path, capsys):
    """`ngbet fit A.csv B.csv --scene S` without --params (the scene names them) writes fit.json
    with each curve's RMS, fit.png and a fitted scene that `ngbet run` takes on another specimen
    with only the specimen and the load changed; a --predict file (another measurement of the first
    size, not fitted) says what its band holds."""
    _, paths, res = synthetic_joint
    (tmp_path / "other").mkdir()
    other = write_synthetic(tmp_path / "other", seed=8)[0]
    scene = tmp_path / "syn.toml"
    scene.write_text(synthetic_scene().to_toml())
    out = tmp_path / "fit"
    code = main(
        [
            "fit",
            *map(str, paths),
            "--scene",
            str(scene),
            "--out",
            str(out),
            "--max-runs",
            "3",
            "--quiet",
            "--predict",
            str(other),
        ]
    )
    assert code in (0, 1)  # 3 runs may stop the search early; the files are what is tested here
    text = capsys.readouterr().out
    assert "150 x 300 mm: RMS relative error" in text and "150 x 450 mm: RMS relative error" in text
    doc = json.loads((out / "fit.json").read_text())
    assert [c["specimen"]["specimen.length_mm"] for c in doc["curves"]] == [300.0, 450.0]
    assert set(doc["parameters"]) == set(SYN_TRUTH) and doc["model_runs"] <= 3
    assert (out / "fit.png").stat().st_size > 10_000 and (out / f"predict_{other.stem}.json").exists()
    # the prediction says what its band holds, as fit.json does for its test, and counts a measured
    # point inside by the band and the point's own scatter
    pj = json.loads((out / f"predict_{other.stem}.json").read_text())
    assert pj["band"] == doc["prediction_band"]["bias_extension"]["holds"]
    assert doc["prediction_band"]["picture_frame"]["model_error_relative"] == 0.0
    assert "both tests" in doc["prediction_band"]["picture_frame"]["holds"]
    sd2 = sum(np.array(pj[k]) ** 2 for k in ("sd_parameters_N", "sd_discretization_N", "sd_model_error_N"))
    miss = np.abs(np.array(pj["force_N"]) - np.array(pj["measured_N"]))
    assert pj["within_2sd"] == np.mean(miss <= 2 * np.sqrt(sd2 + np.array(pj["sd_measured_N"]) ** 2))
    # beside it the normalisation method's prediction from the fitted curves (the validation study's),
    # its RMS and ngbet's on the points where it has a value, also on the terminal
    from ngbet.normalise import predict_by_normalisation

    u = np.array(pj["u_mm"])
    norm = predict_by_normalisation([read_measured(p) for p in paths], read_measured(other), u)
    got = np.array([np.nan if v is None else v for v in pj["normalisation_N"]])
    np.testing.assert_allclose(got, norm, rtol=1e-12)
    has, meas = np.isfinite(norm), np.array(pj["measured_N"])
    assert pj["normalisation_points"] == has.sum() > 0
    rms_norm = np.sqrt(np.mean(((norm[has] - meas[has]) / meas[has]) ** 2))
    assert pj["normalisation_rms_relative_error"] == pytest.approx(rms_norm, rel=1e-12)
    assert f"the normalisation method from the fitted curves {100 * rms_norm:.1f} %" in text
    run = tmp_path / "run"
    assert (
        main(
            [
                "run",
                str(out / "fitted_scene.toml"),
                "--set",
                "specimen.width_mm=100",
                "--set",
                "specimen.length_mm=300",
                "--set",
                "loading.u0_mm=80",
                "--set",
                "outputs.plot=false",
                "--out",
                str(run),
                "--quiet",
            ]
        )
        == 0
    )
    assert json.loads((run / "summary.json").read_text())["u0_reached_mm"] == pytest.approx(80.0)


@pytest.mark.integration
def test_a_failed_prediction_keeps_the_fit(synthetic_joint, tmp_path, capsys, monkeypatch):
    """A prediction whose model run fails exits 1 and leaves fit.json and fitted_scene.toml."""
    from ngbet.errors import ConvergenceError

    _, paths, _ = synthetic_joint

    def fail(*a, **k):
        raise ConvergenceError("step too small", last_converged_mm=3.0)

    monkeypatch.setattr(bands, "predict_specimen", fail)
    out = tmp_path / "fit"
    scene = tmp_path / "syn.toml"
    scene.write_text(synthetic_scene().to_toml())
    assert (
        main(
            [
                "fit",
                str(paths[0]),
                "--scene",
                str(scene),
                "--out",
                str(out),
                "--max-runs",
                "1",
                "--quiet",
                "--predict",
                str(paths[1]),
            ]
        )
        == 1
    )
    assert "the fit is kept" in capsys.readouterr().err
    assert (out / "fit.json").exists() and (out / "fitted_scene.toml").exists()


# ------------------------------------------------------------------------------------------ the study
@pytest.mark.integration
def test_validation_study_quick(tmp_path, monkeypatch):
    """`ngbet study validation --quick`: one fabric fitted on one size (3 model runs), the other size
    and the frame predicted; the normalisation column equals an independent computation from the
    measured curves (Eq. 18 between the sizes; across tests F_sh read as F_norm, Eqs. 1–3, 10).
    A curve given with --data (here the other size as another laboratory would send it) is
    predicted as the same specimen is, and is the other laboratory's curve of the other size."""
    from ngbet.kinematics import force_from_normalised, frame_angle_rad, normalised_shear_force
    from ngbet.studies import _validation_data as VD
    from ngbet.studies import _validation_fits as VF
    from ngbet.studies import validation as V
    from ngbet.study.collect import load

    out = tmp_path / "study"
    held = tmp_path / "held" / "twill_unbalanced_100x200_LABX.csv"
    held.parent.mkdir()
    held.write_text(
        (DATA / "cao2008_twill_unbalanced_100x200_UN.csv").read_text().replace("laboratory: UN", "laboratory: LABX")
    )
    assert (
        main(
            [
                "study",
                "validation",
                "--quick",
                "--workers",
                "1",
                "--quiet",
                "--out",
                str(out),
                "--cache",
                str(tmp_path / "cache"),
                "--data",
                str(held),
            ]
        )
        == 0
    )
    # the fit is kept in the study cache that --cache names: its record, itself, a prediction per target
    kept = tmp_path / "cache" / VF.FITS_FOLDER
    (fit_pickle,) = kept.glob("*.pickle")
    assert fit_pickle.name.startswith("quick-twill_unbalanced-")
    assert len(list(kept.glob(f"{fit_pickle.stem}*.json"))) == 1 + 3  # the other size, the frame, the held curve
    # the kept fit predicts as the fit did (what a curve added later gets)
    res = pickle.loads(fit_pickle.read_bytes())
    again = VF._predict(res, read_measured(held))
    pred = kept / f"{fit_pickle.stem}-{VF.target_key(held.name, VD.find_curves([held.parent]))}.json"
    assert json.loads(pred.read_text()) == again and "band" in again
    text = (out / "report.md").read_text()
    assert "| twill unbalanced | 100 x 250 mm | 100 x 200 mm (UN) | other size |" in text
    assert "| twill unbalanced | 100 x 250 mm | 100 x 200 mm (LABX) | other laboratory |" in text
    assert (out / "validation.png").exists()
    fitted = read_measured(DATA / "cao2008_twill_unbalanced_100x250_UN.csv")
    other_name = "cao2008_twill_unbalanced_100x200_UN.csv"
    other = read_measured(DATA / other_name)
    uf = fitted.u_mm[fitted.u_mm > 0]
    # the slack's negative forces (−0.0065 N at 0.0085 mm) count as 0, as in the study
    g, f = normalised_shear_force(uf, np.maximum(np.interp(uf, fitted.u_mm, fitted.force_N), 0.0), 250.0, 100.0)
    u, F = other.sample(24)
    rms = float(np.sqrt(np.mean(((force_from_normalised(g, f, u, 200.0, 100.0) - F) / F) ** 2)))
    rows = {r["what"]: r for r in V.summary(load(out))}
    assert rows["other size"]["normalisation_rms"] == pytest.approx(rms, rel=1e-9)
    assert rows["other laboratory"]["normalisation_rms"] == pytest.approx(rms, rel=1e-9)
    assert f"{100 * rms:.1f} %" in text
    pts = load(out).tables["points"]
    ngbet_of = {t: [q["ngbet"] for q in pts if q["target"] == t] for t in (other_name, held.name)}
    # the same scene on the same specimen, run as another case: equal to round-off
    assert ngbet_of[held.name] == pytest.approx(ngbet_of[other_name], rel=1e-12) and len(ngbet_of[other_name]) == 24
    # the other laboratory's column: the other size read by Eq. 18 from the other laboratory's curve of it
    uo = other.u_mm[other.u_mm > 0]
    go, fo = normalised_shear_force(uo, np.maximum(np.interp(uo, other.u_mm, other.force_N), 0.0), 200.0, 100.0)
    lab = float(np.sqrt(np.mean(((force_from_normalised(go, fo, u, 200.0, 100.0) - F) / F) ** 2)))
    assert rows["other size"]["lab_rms"] == pytest.approx(lab, rel=1e-9) and lab < 0.01
    # across tests: F_sh(γ) read as the frame's F_norm(γ), the frame 145/120 mm of the file's header
    frame = read_any(PF_UN)
    u, F = frame.sample(24)
    gam = np.pi / 2 - 2 * frame_angle_rad(u, 145.0)
    Fn_meas = frame.in_file_units(u, F)[1]
    Fn_norm = np.interp(gam, np.r_[0.0, g], np.r_[0.0, f])
    rms = float(np.sqrt(np.mean(((Fn_norm - Fn_meas) / Fn_meas) ** 2)))
    assert rows["other test"]["normalisation_rms"] == pytest.approx(rms, rel=1e-9)
    # ngbet against the method: ngbet's frame against that F_sh, at the same points
    ngbet = np.array([float(q["ngbet"]) for q in load(out).tables["points"] if q["target"] == PF_UN.name])
    agree = float(np.sqrt(np.mean(((ngbet - Fn_norm) / Fn_norm) ** 2)))
    assert rows["other test"]["agreement_rms"] == pytest.approx(agree, rel=1e-9)
    assert f"{100 * agree:.1f} %" in text


def test_progress_line_names_runs_and_each_curves_rms():
    """The progress of a fit on a stream that is not a terminal: one line per model run."""
    import io

    stream = io.StringIO()
    show = joint.terminal_progress(stream)
    show(3, [0.123, 0.045], 12.5)
    show(4, [0.1, 0.04], 11.0)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("ngbet fit: model run 3, RMS 12.3 %, 4.5 %")


def test_shear_angle_file_is_read_and_checked(tmp_path):
    """Measured centre shear angles: comments skipped, equal displacements averaged, the non-positive
    displacement (the unloaded state) left out; a missing column and text in a number's place name the line."""
    from ngbet.measured.observations import read_angles

    p = tmp_path / "angles.csv"
    p.write_text("# DIC, centre of the specimen\ndisplacement_mm,shear_angle_deg\n0,0\n10,8\n20,15\n20,17\n")
    a = read_angles(p)
    assert a.u_mm.tolist() == [10.0, 20.0] and a.angle_deg.tolist() == [8.0, 16.0]
    p.write_text("displacement_mm,angle\n10,8\n")
    with pytest.raises(SceneError, match="line 1: needs the columns displacement_mm, shear_angle_deg"):
        read_angles(p)
    p.write_text("displacement_mm,shear_angle_deg\n10,8\n20,x\n")
    with pytest.raises(SceneError, match="line 3: shear_angle_deg = 'x' is not a number"):
        read_angles(p)
    p.write_text("displacement_mm,shear_angle_deg\n10,8\n20,inf\n")
    with pytest.raises(SceneError, match="line 3: shear_angle_deg = 'inf' is not a finite number"):
        read_angles(p)


def test_profiles_and_angles_are_read_as_measured_curves_are(tmp_path):
    """The files of measured angles and profiles go through the measured curves' reader of text:
    Windows-1252 text is read, a directory or a binary file is refused naming the file."""
    from ngbet.measured.observations import read_angles, read_profile

    p = tmp_path / "angles.csv"
    p.write_bytes("# Winkel gemessen \xb0\ndisplacement_mm,shear_angle_deg\n10,8\n".encode("cp1252"))
    assert read_angles(p).angle_deg.tolist() == [8.0]
    with pytest.raises(SceneError, match=f"shear angle file {tmp_path} is a directory"):
        read_angles(tmp_path)
    q = tmp_path / "profile.csv"
    q.write_bytes(b"u0_mm,X_mm,uy_mm\n37,10,\x00\n")
    with pytest.raises(SceneError, match="profile file .*profile.csv is not a text file"):
        read_profile(q)


@pytest.mark.integration
def test_a_held_parameter_widens_the_band_by_its_own_term(synthetic_joint):
    """K_el held fixed with var(ln K_el) = 0.09: the parameter part of the band becomes
    √(sd² + (dF/d ln K_el)² · 0.09), the derivative from central differences of whole runs (to
    2e-3 of the largest value: the two derivatives differ by that much on this 30 mm mesh)."""
    _, paths, _ = synthetic_joint
    res = joint.fit_curves(
        [read_measured(p) for p in paths],
        synthetic_scene(),
        params=["material.K_sh"],
        max_runs=3,
        choose_discretization=False,
    )
    spec = {"specimen.width_mm": 100.0, "specimen.length_mm": 300.0}
    u = np.array([20.0, 50.0])
    plain = bands.predict_specimen(res, spec, u)
    held = bands.predict_specimen(res, spec, u, {"material.K_el": 0.09})
    sc = res.scene.with_changes(**spec, **{"loading.u0_mm": 50.0})
    g = finite_difference(sc, u, ["material.K_el"], rel_step=1e-3)[:, 0]
    want = np.sqrt(plain.sd_param_N**2 + 0.09 * g**2)
    np.testing.assert_allclose(held.sd_param_N, want, rtol=0, atol=2e-3 * want.max())  # measured 2.3e-4 N, band 0.14 N
    assert np.all(held.sd_param_N > 1.5 * plain.sd_param_N)
    np.testing.assert_allclose(held.force_N, plain.force_N, rtol=1e-12)


@pytest.mark.slow
def test_a_refit_on_a_finer_discretization_moves_no_parameter_beyond_its_standard_error(synthetic_joint):
    """The two sizes fitted on the discretization the fit chooses (its force error estimated below
    1 % at every fitted point) and again two rungs finer (h = 20 mm graded to 0.25 mm, p = 4): each
    parameter moves by less than its standard error, so the values belong to the data, not to the mesh."""
    _, paths, _ = synthetic_joint
    curves = [read_measured(p) for p in paths]
    start = synthetic_scene(**{"material.K_sh": 4e4, "material.K_el": 1e6})
    chosen = joint.fit_curves(curves, start, max_runs=20)
    assert chosen.accuracy_met and all(c.error_rel_max <= 0.01 for c in chosen.curves)
    finer = joint.fit_curves(curves, fit_params.FIT_LADDER[3].apply(start), max_runs=20, choose_discretization=False)
    assert all(c.level < 3 for c in chosen.curves)  # the finer fit is finer than every curve of the chosen one
    moved = np.abs(np.log(finer.values / chosen.values))
    assert np.all(moved <= chosen.se_log), (moved, chosen.se_log)


@pytest.mark.integration
def test_one_size_with_a_fabric_scene_fits_and_holds_the_bending_stiffnesses(tmp_path, capsys):
    """A single curve with a fabric scene and no --params: the scene's parameters without the
    bending stiffnesses, which fit.json lists as held with their values and why; the centre
    shear angle of the fitted model and of the ideal test are recorded at every fitted point."""
    data = ROOT / "data" / "cao2008" / "cao2008_twill_unbalanced_100x250_UN.csv"
    out = tmp_path / "fit"
    code = main(
        [
            "fit",
            str(data),
            "--scene",
            str(GEO / "twintex_twill_unbalanced.toml"),
            "--out",
            str(out),
            "--max-runs",
            "3",
            "--quiet",
        ]
    )
    doc = json.loads((out / "fit.json").read_text())
    assert code == (0 if doc["converged"] else 1)
    # the bending stiffnesses by the one size, K_el by the scene (not among its [calibration] params)
    assert set(doc["held"]) == {"material.alpha1", "material.alpha2", "material.K_el"}
    assert doc["held"]["material.alpha1"]["value"] == pytest.approx(10.0)
    assert "one specimen size" in doc["held"]["material.alpha2"]["why"]
    assert doc["held"]["material.K_el"]["value"] == pytest.approx(2e7)
    assert "--angles" in doc["held"]["material.K_el"]["why"]
    assert not any(k.startswith("material.alpha") for k in doc["parameters"])
    c = doc["curves"][0]
    assert len(c["shear_angle_deg"]) == len(c["u_mm"]) == len(c["shear_angle_ideal_deg"])
    assert "held" in capsys.readouterr().out


def test_validation_scores_errors_over_the_curve_s_largest_force():
    """Beside the relative RMS, the study scores the RMS of the error over the measured curve's largest
    force: a 10 % miss at the small force (1 N of a curve reaching 2 N) counts 0.1/2 at that point."""
    from ngbet.studies import validation as V

    pred, meas = np.array([1.1, 2.0]), np.array([1.0, 2.0])
    assert V.rms_of_max(pred, meas) == pytest.approx(math.sqrt((0.05**2 + 0.0) / 2), rel=1e-12)
    assert V.rms(pred, meas) == pytest.approx(math.sqrt((0.1**2 + 0.0) / 2), rel=1e-12)
    # a curve without a value at some points (the normalisation method beyond its fitted angles)
    # is scored on the others, over its largest value there
    assert V.rms_of_max(np.array([1.1, 2.0, 3.0]), np.array([1.0, 2.0, np.nan])) == pytest.approx(
        math.sqrt(0.05**2 / 2), rel=1e-12
    )


# ------------------------------------------------------------------------------------------ picture frame
PF_UN = ROOT / "data" / "cao2008_pf" / "cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv"


def test_frame_curve_converts_exactly_to_crosshead_travel_and_force():
    """A picture-frame file's F_norm against γ becomes crosshead force against travel by Eqs. 1–3, 10, and back.

    At γ = 0 the travel is 0; the travel is (2 − √2) L at γ = 90°; converting back reproduces the
    file's angles and F_norm (the residual of a fit is then the same in either quantity)."""
    from ngbet.measured.curves import frame_travel_mm, read_any, read_frame_curve
    from ngbet.measured.table import read_table

    assert frame_travel_mm(np.array([0.0]), 145.0)[0] == pytest.approx(0.0, abs=1e-12)
    assert frame_travel_mm(np.array([90.0]), 145.0)[0] == pytest.approx((2 - math.sqrt(2)) * 145.0)
    c = read_frame_curve(PF_UN)
    assert c.test == "picture_frame" and c.quantity == "normalised_shear_force"
    assert c.frame == {"picture_frame.frame_mm": 145.0, "picture_frame.fabric_mm": 120.0}
    assert read_any(PF_UN).frame == c.frame and c.label == "frame 145/120 mm"
    g, fn = c.in_file_units(c.u_mm, c.force_N)
    t = read_table(PF_UN)
    inside = (t.x > 0) & (t.x < 90)
    gg = np.unique(t.x[inside])
    np.testing.assert_allclose(g, gg, rtol=1e-12, atol=1e-12)
    # F = 2 cos θ F_s, F_s = F_norm L_fabric²/L_frame: at 45° frame angle (γ = 0) F = √2 F_norm 120²/145
    k = int(np.argmin(gg))
    expect = np.mean(t.y[inside][t.x[inside] == gg[k]])
    assert fn[k] == pytest.approx(expect, rel=1e-12)


def test_frame_curve_scene_is_the_picture_frame_of_its_header():
    """A picture-frame curve runs the fabric's material in the picture-frame test with its header's frame."""
    from ngbet.measured.curves import read_frame_curve

    sc = Scene.from_toml(GEO / "twintex_twill_unbalanced.toml")
    c = read_frame_curve(PF_UN)
    u, _ = c.sample()
    s = joint.curve_scene(sc, c, u)
    assert s.test == "picture_frame"
    assert (s.picture_frame.frame_mm, s.picture_frame.fabric_mm) == (145.0, 120.0)
    assert s.picture_frame.arms == "held"  # the benchmark's cross, as Eq. 10 of the file assumes
    assert s.material == sc.material and s.loading.u0_mm == pytest.approx(u.max())
    # a frame and one bias-extension size are two tests: the bending stiffnesses are fitted
    bet = read_measured(DATA / "cao2008_twill_unbalanced_100x250_UN.csv")
    assert joint.held_parameters([bet, c], sc, list(sc.calibration.params), None) == {}
    assert set(joint.held_parameters([bet], sc, list(sc.calibration.params), None)) == set(joint.SIZE_PARAMS)
    # frames alone, of one size or two, leave them to the scene, saying why (not "one specimen size")
    uml = read_frame_curve(ROOT / "data" / "cao2008_pf" / "cao2008_pf_plain_UML_fig28_normalized_energy.csv")
    for frames in ([c], [c, uml]):
        held = joint.held_parameters(frames, sc, list(sc.calibration.params), None)
        assert set(held) == set(joint.SIZE_PARAMS)
        assert all(why.startswith("picture-frame tests alone") for why in held.values())


@pytest.mark.integration
def test_frame_fit_reports_the_file_quantities_and_the_frame_s_shear(tmp_path):
    """A picture-frame curve fitted by ``ngbet fit``: fit.json gives it in the file's quantities
    (F_norm against γ, as measured: the interpolated file values) and the fabric shears with the
    frame (the model's centre shear angle is the frame's, Eqs. 1–2, within 0.1°)."""
    out = tmp_path / "fit"
    code = main(
        [
            "fit",
            str(PF_UN),
            "--scene",
            str(GEO / "twintex_twill_unbalanced.toml"),
            "--out",
            str(out),
            "--max-runs",
            "2",
            "--quiet",
        ]
    )
    doc = json.loads((out / "fit.json").read_text())
    assert code == (0 if doc["converged"] else 1)
    c = doc["curves"][0]
    assert c["test"] == "picture_frame" and c["frame"]["picture_frame.frame_mm"] == 145.0
    fq = c["file_quantities"]
    assert fq["quantity"] == "normalised_shear_force"
    from ngbet.measured.table import read_table

    t = read_table(PF_UN)
    order = np.argsort(t.x)
    np.testing.assert_allclose(fq["measured"], np.interp(fq["shear_angle_deg"], t.x[order], t.y[order]), rtol=0.05)
    np.testing.assert_allclose(c["shear_angle_deg"], fq["shear_angle_deg"], atol=0.1)
    np.testing.assert_allclose(c["shear_angle_ideal_deg"], fq["shear_angle_deg"], rtol=1e-9)


def test_default_bounds_stay_inside_a_key_s_domain():
    """Without bounds in the scene a parameter may move a factor 1e4 either way, but an angle stays
    inside (0, 90) degrees, which the scene requires: the locking angle's bounds are clipped to [1, 89]."""
    sc = Scene().with_changes(
        **{"effects.shear_law": "locking", "material.K_lock": 1e3, "material.gamma_lock_deg": 80.0}
    )
    names = ["material.K_lock", "material.gamma_lock_deg"]
    lo, hi = fit_params.bounds(sc, names, names, np.array([1e3, 80.0]))
    assert lo[0] == pytest.approx(1e3 / fit_params.BOUND_FACTOR) and hi[0] == pytest.approx(
        1e3 * fit_params.BOUND_FACTOR
    )
    assert (lo[1], hi[1]) == fit_params.DOMAINS["material.gamma_lock_deg"] == (1.0, 89.0)
    sc.with_changes(**{"material.gamma_lock_deg": hi[1]})  # the bound itself is a valid scene
