"""Shear laws, force sensitivities and the calibration (ngbet fit) on synthetic and measured data."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import ngsolve as ngs
import numpy as np
import pytest
from conftest import capabilities, carry

from ngbet.calibration.bands import predict_specimen
from ngbet.calibration.fit_params import JointFit
from ngbet.calibration.joint import fit_curves
from ngbet.cli import main
from ngbet.continuum import physics
from ngbet.measured.curves import MeasuredCurve, read_measured
from ngbet.measured.observations import Profile
from ngbet.runner.sensitivity import finite_difference, force_path
from ngbet.scene.document import Scene
from ngbet.scene.validate import SceneError

ROOT = Path(__file__).resolve().parents[1]
CAO_SCENE = ROOT / "geometry" / "cao2008_150x450.toml"
CAO_DATA = ROOT / "data" / "cao2008_glass_plain_150x450.csv"

# the synthetic truth: the Cao specimen on a 30 mm mesh, locking law, bending too weak to be seen
# (internal length sqrt(alpha / K_sh) = 3 mm, far below the mesh size)
TRUTH = {"material.K_sh": 2.5e4, "material.K_lock": 1.5e4}
U_SYN = np.linspace(10.0, 100.0, 19)


def synthetic_scene(**changes) -> Scene:
    base = {
        "discretization.mesh_size_mm": 30.0,
        "material.alpha1": 0.2,
        "material.alpha2": 0.2,
        "outputs.vtk": False,
        "outputs.plot": False,
        **TRUTH,
    }
    base.update(changes)
    return Scene.from_toml(CAO_SCENE).with_changes(**base)


@pytest.fixture(scope="module")
def truth_curve() -> np.ndarray:
    return force_path(synthetic_scene(), U_SYN).force_N


def noisy(clean: np.ndarray, seed: int, rel: float = 0.01) -> MeasuredCurve:
    rng = np.random.default_rng(seed)
    return MeasuredCurve(U_SYN, clean * (1 + rel * rng.standard_normal(len(clean))), f"synthetic seed {seed}")


def fit_own(curve: MeasuredCurve, scene: Scene, params: list[str], **kw) -> JointFit:
    """A fit on the scene's own discretization and specimen, at every point of the curve (the synthetic truth's)."""
    return fit_curves([curve], scene, params, fractions=[(0.0, 1.0)], resample=False, choose_discretization=False, **kw)


def start_scene() -> Scene:
    """The synthetic scene with start values off the truth by factors 1.6 and 0.6."""
    return synthetic_scene(**{"material.K_sh": 4e4, "material.K_lock": 0.9e4})


@pytest.fixture(scope="module")
def synthetic_fit(truth_curve) -> JointFit:
    """K_sh, K_lock fitted to the truth with 1 % noise (seed 1), from start values off by 1.6, 0.6."""
    return fit_own(noisy(truth_curve, seed=1), start_scene(), list(TRUTH))


# ------------------------------------------------------------------------------------------ shear laws
def _at(cf: ngs.CoefficientFunction) -> float:
    mesh = ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=1.0))
    return float(cf(mesh(0.5, 0.5)))


@pytest.mark.parametrize("i8v", [0.1, 0.5, 0.8])
def test_shear_laws_stress_and_reduction(i8v):
    """dW/di8 from NGSolve's differentiation equals each law's stress formula; with the extra
    coefficients 0 both laws are the quadratic one."""
    i8 = ngs.Parameter(i8v)
    Ksh, K4, K6, Kl, g = 2e4, 3e4, 5e4, 1e4, 60.0
    poly = physics.polynomial_shear_energy(i8, Ksh, K4, K6)
    assert _at(poly.Diff(i8)) == pytest.approx(Ksh * i8v + K4 * i8v**3 + K6 * i8v**5, rel=1e-12)
    lock = physics.locking_shear_energy(i8, Ksh, Kl, g)
    x = i8v**2 / math.sin(math.radians(g)) ** 2
    assert _at(lock.Diff(i8)) == pytest.approx(Ksh * i8v + Kl * i8v * x / (1 - x), rel=1e-10)
    quad = _at(physics.shear_energy(i8, Ksh))
    assert _at(physics.polynomial_shear_energy(i8, Ksh, 0.0, 0.0)) == pytest.approx(quad, rel=1e-14)
    assert _at(physics.locking_shear_energy(i8, Ksh, 0.0, g)) == pytest.approx(quad, rel=1e-14)


def test_locking_law_joins_its_continuation_smoothly():
    """Energy, stress and stiffness agree on both sides of the cutoff x = 0.95 (a C² join)."""
    s = math.sin(math.radians(50.0))
    xc = physics.LOCKING_CUTOFF
    vals = []
    for sign in (-1, 1):
        i8 = ngs.Parameter(s * math.sqrt(xc) * (1 + sign * 1e-9))
        W = physics.locking_shear_energy(i8, 0.0, 1.0, 50.0)
        vals.append([_at(W), _at(W.Diff(i8)), _at(W.Diff(i8).Diff(i8))])
    np.testing.assert_allclose(vals[0], vals[1], rtol=1e-6)
    # past the locking angle the energy stays finite and keeps growing
    far = _at(physics.locking_shear_energy(ngs.Parameter(0.99), 0.0, 1.0, 50.0))
    assert math.isfinite(far) and far > vals[1][0]


def test_shear_law_scene_keys_are_validated():
    with pytest.raises(SceneError, match="effects.shear_law"):
        Scene().with_changes(**{"effects.shear_law": "cubic"})
    with pytest.raises(SceneError, match="material.gamma_lock_deg"):
        Scene().with_changes(**{"material.gamma_lock_deg": 90.0})
    with pytest.raises(SceneError, match="material.K_sh4"):
        Scene().with_changes(**{"material.K_sh4": -1.0})
    with pytest.raises(SceneError, match="effects.shear_law"):
        Scene().with_changes(**{"effects.shear_law": "locking", "effects.shear": False})
    s = Scene.from_toml(CAO_SCENE)
    assert s.effects.shear_law == "locking" and Scene.from_toml_string(s.to_toml()) == s


def test_polynomial_law_with_zero_coefficients_is_the_quadratic_run():
    """Only the terms a scene names are built, and zero coefficients change nothing: the forces
    agree to round-off."""
    sc = synthetic_scene(**{"effects.shear_law": "quadratic"})
    a = force_path(sc, [20.0, 40.0]).force_N
    b = force_path(sc.with_changes(**{"effects.shear_law": "polynomial"}), [20.0, 40.0]).force_N
    np.testing.assert_allclose(a, b, rtol=1e-9)


# ------------------------------------------------------------------------------------------ sensitivities
def test_implicit_sensitivities_match_finite_differences():
    """dF/d ln p by the load-tangent adjoint agrees with central differences of whole runs (step
    1e-3; steps 1e-2 and 3e-3 give the same 5 digits) to 2e-5 of each column's largest value
    (measured 1.3e-7, 3.9e-8, 3.9e-6, 1.6e-7 at p = 2 with bending, 1.5e-6 without), with bending
    on and off: K_el checks that the derivative form integrates with the problem's quadrature."""
    u = [30.0, 70.0, 100.0]
    every = ["material.K_sh", "material.K_lock", "material.gamma_lock_deg", "material.K_el"]
    for sc, P in ((synthetic_scene(), every), (synthetic_scene(**{"effects.bending": False}), every[3:])):
        impl = force_path(sc, u, P).dlogp
        fd = finite_difference(sc, u, P, rel_step=1e-3)
        err = np.abs(impl - fd).max(axis=0) / np.abs(fd).max(axis=0)
        assert np.all(err < 2e-5), dict(zip(P, err, strict=True))


def capped_scene() -> Scene:
    """A scene whose stabilization cap 30 K_el holds on the elements below 6 mm (corners graded to 2 mm)."""
    return Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 10.0,
            "discretization.corner_mesh_size_mm": 2.0,
            "discretization.order_u": 2,
            "loading.u0_mm": 30.0,
            "material.alpha1": 2000.0,
            "material.alpha2": 1500.0,
            "material.K_el": 138890.0,
        }
    )


def test_sensitivities_differentiate_the_energy_that_is_solved():
    """dF/d ln p is the derivative of the problem's own energy, the capped stabilization
    K_s = min(c min(α1, α2)/h_T², 30 K_el) included: on a scene where the cap holds on the small
    elements (h_T < 6 mm, the nearest element 0.8 % away from the switch, so that neither run of a
    central difference crosses it) and not on the large ones, the implicit derivatives with
    respect to K_el, K_sh, α1, α2 (which enter K_s through the cap, through nothing, through
    nothing as the larger α, through min(α1, α2)) agree with central differences of whole runs
    (step 1e-3; step 1e-4 gives the same to 1.2e-7) to 1e-6 of each column's largest value
    (measured 6.5e-8, 7.0e-8, 4.9e-8, 2.9e-8). A derivative that leaves the cap out is off by
    2.5e-4 for K_el and 1.4e-2 for α2; one with the load tangent of Newton's last factorization by
    up to 8e-5."""
    from ngbet.continuum.problem import ContinuumProblem

    sc = capped_scene()
    cap = 30 * sc.material.K_el  # = 0.1 alpha2 / (6 mm)^2
    lo, hi = ContinuumProblem(sc).K_s_range
    assert hi == pytest.approx(cap, rel=1e-12)
    assert lo < 0.5 * cap
    u = [15.0, 30.0]
    P = ["material.K_el", "material.K_sh", "material.alpha1", "material.alpha2"]
    impl = force_path(sc, u, P).dlogp
    fd = finite_difference(sc, u, P, rel_step=1e-3)
    err = np.abs(impl - fd).max(axis=0) / np.abs(fd).max(axis=0)
    assert np.all(err < 1e-6), dict(zip(P, err, strict=True))


def test_profile_sensitivities_match_finite_differences():
    """d u_y / d ln p on the mid-axis at 30 mm of the capped scene agree with central differences
    of whole runs (step 1e-3) to 1e-4 of each column's largest value (measured 2.0e-6, 1.4e-5,
    2.3e-7, 4.0e-7 for K_el, K_sh, α1, α2); with the cap left out of ∂W/∂p and Newton's last
    factorization they were 5.2e-2, 1.4e-3, 3.3e-4, 5.6e-2 off."""
    from ngbet.continuum.sensitivity import material_value, with_material

    sc, X, u = capped_scene(), np.linspace(20.0, 200.0, 10), [15.0, 30.0]
    P = ["material.K_el", "material.K_sh", "material.alpha1", "material.alpha2"]
    impl = force_path(sc, u, P, {30.0: X}).profile_dlogp[30.0]
    cols = []
    for p in P:
        name = p.partition(".")[2]
        v = material_value(sc, name)
        up, dn = (
            force_path(with_material(sc, name, v * math.exp(s)), u, (), {30.0: X}).profiles[30.0] for s in (1e-3, -1e-3)
        )
        cols.append((up - dn) / 2e-3)
    fd = np.column_stack(cols)
    err = np.abs(impl - fd).max(axis=0) / np.abs(fd).max(axis=0)
    assert np.all(err < 1e-4), dict(zip(P, err, strict=True))


def test_centre_angle_sensitivities_match_finite_differences():
    """dγ_centre / d ln p at 30 mm of the capped scene agree with central differences of whole runs
    (step 1e-3) to 1e-3 of the largest; the angle itself is the run's own (ngbet run's gamma_centre_deg)."""
    from ngbet.continuum.sensitivity import material_value, with_material

    sc, u = capped_scene(), [15.0, 30.0]
    P = ["material.K_el", "material.K_sh", "material.alpha1", "material.alpha2"]
    r = force_path(sc, u, P, angles=[30.0])
    fd = []
    for p in P:
        name = p.partition(".")[2]
        v = material_value(sc, name)
        up, dn = (
            force_path(with_material(sc, name, v * math.exp(s)), u, (), angles=[30.0]).angles_deg[30.0]
            for s in (1e-3, -1e-3)
        )
        fd.append((up - dn) / 2e-3)
    err = np.abs(r.angle_dlogp[30.0] - np.array(fd)) / np.abs(fd).max()
    assert np.all(err < 1e-3), dict(zip(P, err, strict=True))
    assert 0 < r.angles_deg[30.0] < 90


def test_load_tangent_at_a_converged_state_is_that_of_the_tangent_there(monkeypatch):
    """The load tangent behind dF/dp is that of the tangent at the converged state: refined from
    Newton's last factorization, it agrees with the one of a factorization made there to 1e-7
    (measured 2.6e-8; Newton's own was 2.2e-6 off); when the refinement cannot reach its
    tolerance, it is that of a factorization made there."""
    from ngbet.continuum import sensitivity as S
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.runner.settings import continuum_solver, newton_settings

    sc = Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 10.0,
            "discretization.corner_mesh_size_mm": 2.0,
            "discretization.order_u": 2,
            "loading.u0_mm": 20.0,
            "effects.constraint": "penalty",
        }
    )
    pb = continuum_solver(ContinuumProblem(sc))
    carry(pb, 20e-3, 2e-3, newton_settings(sc), max_step=5e-3, min_step=1e-5, **capabilities(pb))
    x = pb.x.copy()
    stale = pb.load_tangent(1.0)
    refined = S.load_tangent_at_state(pb)
    assert np.array_equal(pb.x, x)  # the state is left as it was
    monkeypatch.setattr(S, "TANGENT_REFINEMENTS", 0)
    fallback = S.load_tangent_at_state(pb, rtol=1e-12)
    pb.factorize()
    exact = pb.load_tangent(1.0)
    n = np.linalg.norm(exact)
    assert np.linalg.norm(refined - exact) < 1e-7 * n
    assert np.linalg.norm(stale - exact) > 20 * np.linalg.norm(refined - exact)
    assert np.linalg.norm(fallback - exact) < 1e-10 * n  # two factorizations of one matrix: round-off


# ------------------------------------------------------------------------------------------ the fit
@pytest.mark.integration
def test_fit_recovers_synthetic_parameters(synthetic_fit):
    """1 % noise: each parameter within two standard errors of the truth, the residual scale (over
    what 1 % noise gives against the points' standard deviations) below the 99 % bound of s/σ for
    17 degrees of freedom (√(χ²/17) <= 1.45: the misfit is the noise), both determined."""
    res = synthetic_fit
    for k, p in enumerate(res.names):
        z = abs(math.log(res.values[k] / TRUTH[p])) / res.se_log[k]
        assert z <= 2.0, (p, res.values[k], res.se_log[k])
    c = res.curves[0]  # the points' standard deviations: 1 % of the force, floored by the reading error
    assert res.residual_scale / np.sqrt(np.mean((0.01 * c.measured_N / c.sd_N) ** 2)) < 1.45
    assert res.undetermined == {}
    assert res.curves[0].rms_relative < 0.02


@pytest.mark.integration
def test_the_checked_search_ends_at_the_optimum_of_its_rungs(truth_curve):
    """The Gauss-Newton steps on the checked rungs end where a trust-region search on the same
    discretization, started there, lowers the cost by less than 0.01 s² (the stopping rule's
    fall) and moves no parameter by more than 0.1 of its standard error (STEP_SE): the end is the
    optimum of the fit's own model, not a point on the way to it."""
    from ngbet.calibration.fit_params import FIT_LADDER, STEP_SE, with_values

    curve = noisy(truth_curve, seed=1)
    res = fit_curves([curve], start_scene(), list(TRUTH), fractions=[(0.0, 1.0)], resample=False)
    level = res.curves[0].level
    assert level is not None and res.converged and res.accuracy_met
    assert res.stages[-1]["checked"] and not res.stages[-1]["probe"]  # the reported run: every point estimated
    on = with_values(FIT_LADDER[level].apply(start_scene()), res.names, res.values)
    again = fit_curves([curve], on, list(TRUTH), fractions=[(0.0, 1.0)], resample=False, choose_discretization=False)
    s2 = max(res.residual_scale, 1.0) ** 2

    def cost(r: JointFit) -> float:
        c = r.curves[0]
        return float(np.sum(((c.model_N - c.measured_N) / c.sd_N) ** 2))

    assert cost(res) - cost(again) < STEP_SE**2 * s2, (cost(res), cost(again))
    moved = np.abs(np.log(again.values / res.values)) / res.se_log
    assert np.all(moved <= STEP_SE), moved


@pytest.mark.integration
def test_invisible_parameter_is_reported_undetermined(truth_curve):
    """alpha1 of a balanced fabric with a 3 mm internal length barely touches the clamp force
    (dF/d ln alpha1 ~ 1e-3 of dF/d ln K_sh): the fit must say so, and still determine K_sh."""
    res = fit_own(noisy(truth_curve, seed=2), synthetic_scene(), ["material.K_sh", "material.alpha1"], max_runs=5)
    assert "material.alpha1" in res.undetermined
    assert "bias-extension test of another specimen size (another aspect" in res.undetermined["material.alpha1"]
    assert "material.K_sh" not in res.undetermined
    doc = res.to_json()
    assert doc["parameters"]["material.alpha1"]["determined"] is False
    # the figure: the curves set the scale, not the band of an undetermined parameter, which is cut
    from ngbet.calibration.fit_params import band
    from ngbet.calibration.report import fit_figure

    c = res.curves[0]
    for scale, cut in ((1.0, False), (1e4, True)):  # as fitted (K_sh determined: a narrow band), and 100 times wider
        wide = dataclasses.replace(res, cov_log=scale * res.cov_log)
        sd = band(c.dlogp, wide.cov_log)
        ax = fit_figure(wide).axes[0]
        lo, hi = ax.get_ylim()
        assert lo <= 0.0 and hi >= max(c.measured_N.max(), c.model_N.max()) and hi < 1.2 * c.curve.force_N.max()
        assert bool(np.any(c.model_N + 2 * sd > hi) or np.any(c.model_N - 2 * sd < lo)) is cut
        assert ("cut at the axes" in " ".join(t.get_text() for t in ax.get_legend().get_texts())) is cut


@pytest.mark.integration
def test_fit_on_one_size_predicts_another(synthetic_fit):
    """Fitted on 150 x 450 mm, the 100 x 300 mm test is predicted within the propagated
    uncertainty: |prediction − truth| ≤ 2 sd at every point (the parameter errors are ~1 se)."""
    res = synthetic_fit
    other = synthetic_scene(
        **{"specimen.length_mm": 300.0, "specimen.width_mm": 100.0, "loading.u0_mm": 70.0, "loading.stops_mm": []}
    )
    u = np.linspace(10.0, 70.0, 7)
    truth = force_path(other, u).force_N
    pred = predict_specimen(res, {"specimen.length_mm": 300.0, "specimen.width_mm": 100.0}, u)
    assert np.all(pred.sd_param_N > 0)
    assert np.all(np.abs(pred.force_N - truth) <= 2 * pred.sd_param_N)
    # the prediction is a real one: the start values miss the truth by far more than that
    start = force_path(other.with_changes(**{"material.K_sh": 4e4, "material.K_lock": 0.9e4}), u).force_N
    assert np.all(np.abs(start - truth) > 5 * pred.sd_param_N)


@pytest.mark.integration
def test_profile_determines_what_the_force_cannot():
    """The paper's unbalanced fabric (10 mm mesh, to 37 mm): from the force alone (1 % noise) the
    fit cannot separate K_sh from alpha2; with the mid-axis profile at 37 mm (10 points, 0.05 mm
    noise) all three parameters are determined, each within two standard errors of the truth,
    and the profile's sensitivities come from the same single run per iteration."""
    truth = Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 10.0,
            "discretization.corner_mesh_size_mm": 0.0,
            "discretization.order_u": 2,
            "loading.u0_mm": 37.0,
        }
    )
    X, u = np.linspace(0.0, 220.0, 12), np.linspace(4.0, 37.0, 12)
    r = force_path(truth, u, (), {37.0: X[1:-1]})
    rng = np.random.default_rng(5)
    curve = MeasuredCurve(r.u_mm, r.force_N * (1 + 0.01 * rng.standard_normal(len(u))), "synthetic force")
    uy = np.concatenate([[0.0], r.profiles[37.0] + 0.05 * rng.standard_normal(10), [0.0]])
    prof = Profile(np.full(12, 37.0), X, uy, "synthetic profile")  # the clamp points are dropped
    start = truth.with_changes(**{"material.K_sh": 3e4, "material.alpha1": 1e3, "material.alpha2": 40.0})
    P = ["material.K_sh", "material.alpha1", "material.alpha2"]
    alone = fit_own(curve, start, P, max_runs=4)
    assert "material.alpha2" in alone.undetermined
    both = fit_own(curve, start, P, profile=prof, profile_sd_mm=0.05)
    assert both.undetermined == {} and both.to_json()["curves"][0]["profile"]["points"] == 10
    exact = {"material.K_sh": 21e3, "material.alpha1": 2e3, "material.alpha2": 20.0}
    for k, p in enumerate(P):
        assert abs(math.log(both.values[k] / exact[p])) <= 2 * both.se_log[k], (p, both.values[k])


@pytest.mark.integration
def test_measured_shear_angles_are_fitted_with_the_force():
    """The paper's scene (10 mm mesh, to 37 mm) with a soft K_el: centre shear angles at three loads
    (0.2° noise) fitted with the force (1 % noise) recover K_sh and K_el within two standard errors;
    fit.json keeps the angles measured and modelled, and the model's angle is the run's own."""
    from ngbet.measured.observations import ShearAngles

    truth = Scene().with_changes(
        **{
            "discretization.mesh_size_mm": 10.0,
            "discretization.corner_mesh_size_mm": 0.0,
            "discretization.order_u": 2,
            "loading.u0_mm": 37.0,
            "material.K_el": 2e5,
        }
    )
    u, ua = np.linspace(4.0, 37.0, 12), np.array([15.0, 25.0, 37.0])
    r = force_path(truth, u, (), angles=list(ua))
    rng = np.random.default_rng(3)
    curve = MeasuredCurve(r.u_mm, r.force_N * (1 + 0.01 * rng.standard_normal(len(u))), "synthetic force")
    ang = ShearAngles(ua, np.array([r.angles_deg[v] for v in ua]) + 0.2 * rng.standard_normal(3), "synthetic angles")
    start = truth.with_changes(**{"material.K_sh": 3e4, "material.K_el": 6e5})
    res = fit_own(curve, start, ["material.K_sh", "material.K_el"], angles=ang, angle_sd_deg=0.2)
    exact = {"material.K_sh": 21e3, "material.K_el": 2e5}
    for k, p in enumerate(res.names):
        assert abs(math.log(res.values[k] / exact[p])) <= 2 * res.se_log[k], (p, res.values[k], res.se_log[k])
    doc = res.to_json()["curves"][0]["shear_angle_data"]
    assert doc["points"] == 3 and doc["rms_deg"] < 0.5
    assert doc["model_deg"][-1] == pytest.approx(res.curves[0].angle_deg[-1], abs=1e-9)


@pytest.mark.slow
def test_standard_errors_agree_with_the_scatter(truth_curve):
    """Over 16 noise draws the spread of the fitted ln p matches the reported standard error
    within a factor 2."""
    fits = [fit_own(noisy(truth_curve, seed=10 + k), start_scene(), list(TRUTH)) for k in range(16)]
    logs = np.log([r.values for r in fits])
    scatter = logs.std(axis=0, ddof=1)
    reported = np.mean([r.se_log for r in fits], axis=0)
    assert np.all((scatter / reported > 0.5) & (scatter / reported < 2.0)), (scatter, reported)


# ------------------------------------------------------------------------------------------ CLI, files
@pytest.mark.integration
def test_cli_fit_writes_the_three_outputs(truth_curve, tmp_path):
    """One curve without specimen keys runs on the scene's specimen; fit.json records each parameter with
    its standard error, the discretization the fit chose and its largest estimated force error; the
    fitted scene carries the fitted values and that discretization; --predict writes its files."""
    data, other = tmp_path / "synthetic.csv", tmp_path / "other.csv"
    for path, seed in ((data, 4), (other, 5)):  # two measurements of the same specimen
        c = noisy(truth_curve, seed=seed)
        path.write_text(
            "displacement_mm,force_N\n" + "".join(f"{u},{f}\n" for u, f in zip(c.u_mm, c.force_N, strict=True))
        )
    scene = tmp_path / "start.toml"
    scene.write_text(synthetic_scene().to_toml())  # the CLI's plumbing, not the iteration, is tested here
    out = tmp_path / "fit"
    code = main(
        [
            "fit",
            str(data),
            str(scene),
            "--params",
            "material.K_sh,material.K_lock",
            "--out",
            str(out),
            "--range",
            "0:200",
            "--predict",
            str(other),
            "--predict-scene",
            str(scene),
            "--max-runs",
            "3",
            "--quiet",
        ]
    )
    doc = json.loads((out / "fit.json").read_text())
    assert code == (0 if doc["converged"] else 1)
    assert set(doc["parameters"]) == set(TRUTH) and doc["model_runs"] >= 2
    for p in TRUTH:
        v, se = doc["parameters"][p]["value"], doc["parameters"][p]["standard_error_log"]
        assert doc["parameters"][p]["standard_error"] == pytest.approx(v * se, rel=1e-12)
    cur = doc["curves"][0]
    assert cur["discretization"]["chosen_by_fit"] is True and cur["discretization"]["corner_mesh_size_mm"] > 0
    assert cur["force_error_rel_max"] == doc["accuracy"]["force_error_rel_max"]["150 x 450 mm"]
    assert (out / "fit.png").stat().st_size > 10_000 and (out / "predict_other.png").exists()
    # the normalisation method beside the prediction takes the specimen the scene gave the curve:
    # the fitted curve read by Eq. 18 onto another measurement of its specimen is that measurement,
    # up to the two curves' noise (1 % each)
    pj = json.loads((out / "predict_other.json").read_text())
    assert pj["normalisation_points"] == pj["points"] and pj["normalisation_rms_relative_error"] < 0.03
    fitted = Scene.from_toml(out / "fitted_scene.toml")
    assert fitted.material.K_sh == pytest.approx(doc["parameters"]["material.K_sh"]["value"])
    assert fitted.discretization.order_u == cur["discretization"]["order_u"]


def test_cli_fit_refuses_bad_input(tmp_path, capsys, monkeypatch):
    """Each bad input exits 2 with its reason, before the output folder (default out/fit) is made."""
    monkeypatch.chdir(tmp_path)
    assert main(["fit", str(CAO_DATA), str(CAO_SCENE), "--params", "loading.u0_mm"]) == 2
    assert "not a material key" in capsys.readouterr().err
    poly = ["--set", "effects.shear_law=polynomial"]
    assert main(["fit", str(CAO_DATA), str(CAO_SCENE), *poly, "--params", "material.K_sh4"]) == 2
    assert "positive start value" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "none.csv"), "--params", "material.K_sh"]) == 2
    assert "data file not found" in capsys.readouterr().err
    # the embedded 70 x 220 mm specimen locks at 62 mm: not the specimen of a 105 mm curve
    assert main(["fit", str(CAO_DATA), "--params", "material.K_sh"]) == 2
    assert "far beyond the ideal yarn locking" in capsys.readouterr().err
    assert main(["fit", str(CAO_DATA), str(CAO_SCENE), "--params", "material.K_sh", "--set", "model='discrete'"]) == 2
    assert "calibrates the continuum model" in capsys.readouterr().err
    assert main(["fit", str(CAO_DATA), str(CAO_SCENE), "--params", "material.K_sh", "--accuracy", "2"]) == 2
    assert "--accuracy 2.0: the largest relative discretization error" in capsys.readouterr().err
    assert (
        main(
            ["fit", str(CAO_DATA), str(CAO_SCENE), "--params", "material.K_sh", "--angles", str(tmp_path / "none.csv")]
        )
        == 2
    )
    assert "shear angle file not found" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_measured_data_file_is_the_cao_curve():
    """The shipped data: 59 points to 105.6 mm, 22.52 N at the end (data/README.md)."""
    c = read_measured(CAO_DATA)
    assert len(c.u_mm) == 59 and c.u_mm[-1] == pytest.approx(105.6381) and c.force_N[-1] == pytest.approx(22.5202)


def test_force_path_answers_every_requested_load_in_order(truth_curve):
    """Repeated displacements (as measured data may have) get one force each, in the caller's order:
    the same loads as a run without the repeat, to round-off."""
    u = np.array([U_SYN[3], U_SYN[7], U_SYN[7], U_SYN[12]])
    F_rep = force_path(synthetic_scene(), u).force_N
    assert F_rep.shape == (4,) and F_rep[1] == F_rep[2]
    assert F_rep[[0, 1, 3]] == pytest.approx(truth_curve[[3, 7, 12]], rel=1e-9)


@pytest.mark.integration
def test_a_fit_stopped_by_max_runs_says_so(truth_curve, tmp_path):
    """Two model runs cannot converge from start values off by 1.6 and 0.6: fit.json says
    ``converged: false`` after at most two model runs, the terminal line says NOT CONVERGED and the
    command exits 1."""
    data = tmp_path / "synthetic.csv"
    c = noisy(truth_curve, seed=4)
    data.write_text("displacement_mm,force_N\n" + "".join(f"{u},{f}\n" for u, f in zip(c.u_mm, c.force_N, strict=True)))
    scene = tmp_path / "start.toml"
    scene.write_text(start_scene().to_toml())
    out = tmp_path / "fit"
    assert (
        main(
            [
                "fit",
                str(data),
                str(scene),
                "--params",
                "material.K_sh,material.K_lock",
                "--out",
                str(out),
                "--range",
                "0:200",
                "--max-runs",
                "2",
            ]
        )
        == 1
    )
    doc = json.loads((out / "fit.json").read_text())
    assert doc["converged"] is False and doc["model_runs"] <= 2


def test_gauss_newton_direction_leaves_flat_directions_out_holds_bounds_and_stays_inside():
    """The step of the checked search on exact cases: a full-rank J gives the least-squares
    solution; a direction the data do not see (a column 1e-6 of the others) gets no step; a
    parameter at its lower bound that the step would push below is held and the rest solved
    without it; a bound in the way shortens the step to just inside it."""
    from ngbet.calibration.fit_params import gauss_newton_direction

    rng = np.random.default_rng(3)
    J = rng.standard_normal((12, 3))
    d_true = np.array([0.3, -0.2, 0.5])
    e = -J @ d_true
    wide = np.full(3, 10.0)
    d, t = gauss_newton_direction(J, e, np.zeros(3), -wide, wide)
    np.testing.assert_allclose(d, d_true, rtol=1e-12)
    assert t == 1.0
    flat = J.copy()
    flat[:, 2] = 1e-6 * rng.standard_normal(12)  # singular value ~1e-6 of the others: below FLAT_RCOND
    e_flat = -flat[:, :2] @ d_true[:2] + 1e-3 * rng.standard_normal(12)  # a misfit the model cannot remove
    d, _ = gauss_newton_direction(flat, e_flat, np.zeros(3), -wide, wide)
    assert abs(np.linalg.lstsq(flat, -e_flat, rcond=None)[0][2]) > 10.0  # what the flat direction would take
    assert abs(d[2]) < 1e-3
    np.testing.assert_allclose(d[:2], np.linalg.lstsq(flat[:, :2], -e_flat, rcond=None)[0], atol=1e-6)
    theta = np.array([0.0, -1.0, 0.0])  # the second parameter at its lower bound -1, the step pushes it down
    d, t = gauss_newton_direction(J, e, theta, np.array([-10.0, -1.0, -10.0]), wide)
    assert d[1] == 0.0
    np.testing.assert_allclose(d[[0, 2]], np.linalg.lstsq(J[:, [0, 2]], -e, rcond=None)[0], rtol=1e-12)
    d, t = gauss_newton_direction(J, e, np.zeros(3), -wide, np.array([10.0, 10.0, 0.25]))  # 0.5 up, room 0.25
    np.testing.assert_allclose(d, d_true, rtol=1e-12)
    assert t == pytest.approx(0.999 * 0.5)
