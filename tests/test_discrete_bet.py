"""The discrete model on the bias extension test: symmetry, ideal kinematics, identities, outputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ngbet.errors import ConvergenceError
from ngbet.run import run
from ngbet.scene.document import Scene
from ngbet.tables import read_profiles, read_rows

BASE = {"model": "discrete", "loading.u0_mm": 30.0, "loading.first_step_mm": 2.0, "loading.max_step_mm": 4.0}


@pytest.fixture(scope="module")
def unbalanced(tmp_path_factory):
    """Table 2 network (EI1 = 400 EI2), spacing 5 mm, pinned yarn ends, to u0 = 30 mm (before the snap near 45 mm)."""
    out = tmp_path_factory.mktemp("unbalanced")
    scene = Scene().with_changes(**BASE)
    return scene, out, run(scene, out, progress=False)


def test_run_completes_with_quadratic_newton(unbalanced):
    _, out, summary = unbalanced
    rows = read_rows(out / "results.csv")
    assert summary["status"] == "ok" and rows[-1]["u0_mm"] == pytest.approx(30.0), f"{summary['status']}"
    # from the tangent predictor, converged to rtol = 1e-10 in a few quadratic iterations, except
    # on a step flagged as a snap (a short pinned corner yarn turns over near 12 mm: the Newton
    # path crosses an indefinite tangent and needs more iterations)
    worst = max(r["newton_iterations"] for r in rows if not r["snap"])
    assert worst <= 8, f"a regular step needed {worst} Newton iterations"


def test_work_by_cause_accounts_for_every_factorization(unbalanced):
    # the breakdown in the summary (bench_discrete's table) covers the whole run: its rows add up
    # to the factorizations and the solves the two solver objects counted
    _, _, s = unbalanced
    rows = s["work_by_cause"]
    total = sum(r["factorizations"] for r in rows.values())
    assert total == s["factorizations"], f"rows {total} vs {s['factorizations']} factorizations"
    solves = sum(r["solves"] for r in rows.values())
    assert solves == s["timers"]["solves"], f"rows {solves} vs {s['timers']['solves']} solves"


def test_half_turn_symmetry_unbalanced(unbalanced):
    # the half-turn about the centre maps each yarn family onto itself (also for EI1 != EI2) and
    # the network onto itself, so u_y on the mid-axis is odd about X = L/2: u_y(X) = -u_y(L - X)
    _, out, _ = unbalanced
    X, uy = map(np.asarray, read_profiles(out / "profile.csv")[30.0])
    assert np.allclose(X, X[-1] - X[::-1]), "profile abscissae are not symmetric"
    odd = np.abs(uy + uy[::-1]).max()
    # the S-shape exists (the thick yarns hardly bend) and is odd up to the Newton tolerance
    assert np.abs(uy).max() > 0.5, f"no S-shape: max |u_y| = {np.abs(uy).max():.3g} mm"
    assert odd < 1e-5 * np.abs(uy).max(), f"|u_y(X) + u_y(L - X)| up to {odd:.3g} mm"


def _halves(out, u0):
    X, uy = map(np.asarray, read_profiles(out / "profile.csv")[u0])
    return uy[(X > 10) & (X < 100)], uy[(X > 120) & (X < 210)]


def test_s_shape_sign_matches_continuum(unbalanced):
    # with pinned yarn ends (the counterpart of the continuum's clamp, which prescribes u only)
    # the network bends as the continuum does for the same thick family m1 = (1, 1)/sqrt2: the
    # left half of the mid-axis sinks (u_y < 0 for X < L/2), the right half rises
    # (continuum, Table 1, h = 5 mm, 56 mm: u_y = -2.9 mm at X = 40 mm)
    _, out, _ = unbalanced
    left, right = _halves(out, 30.0)
    assert left.max() < 0 < right.min(), (
        f"left {left.min():.3g}..{left.max():.3g}, right {right.min():.3g}..{right.max():.3g}"
    )


def test_built_in_yarn_ends_turn_the_s_over(tmp_path):
    # the sense of the S is decided at the clamps: built-in ends hold the rotation of the stiff
    # thick yarns there, and the same network bends the other way (left half rises)
    scene = Scene().with_changes(
        **{**BASE, "loading.u0_mm": 20.0, "discrete.end_rotation": "held", "outputs.plot": False}
    )
    run(scene, tmp_path, progress=False)
    left, right = _halves(tmp_path, 20.0)
    assert left.min() > 0 > right.max(), (
        f"left {left.min():.3g}..{left.max():.3g}, right {right.min():.3g}..{right.max():.3g}"
    )


def test_reaction_is_energy_derivative(unbalanced):
    # envelope theorem: E(u0) = int_0^u0 F du0 - (energy released in snaps); the trapezoidal
    # rule over steps of at most 4 mm is accurate to ~1e-3 here
    _, out, summary = unbalanced
    rows = read_rows(out / "results.csv")
    u0 = np.array([0.0] + [r["u0_mm"] for r in rows]) * 1e-3
    F = np.array([0.0] + [r["force_N"] for r in rows])
    work = float(np.sum(0.5 * (F[1:] + F[:-1]) * np.diff(u0)))
    released = sum(ev.get("released_J", 0.0) for ev in summary["snap_events"])
    E = rows[-1]["energy_J"]
    assert released < 1e-3 * E and abs(work - released - E) < 2e-3 * E, (
        f"work {work:.6g} J, released {released:.3g} J, energy {E:.6g} J"
    )


def test_energy_parts_sum_to_total(unbalanced):
    _, out, _ = unbalanced
    r = read_rows(out / "results.csv")[-1]
    parts = sum(r[f"energy_{k}_J"] for k in ("axial", "bending1", "bending2", "slip", "shear_springs", "inter"))
    assert abs(parts - r["energy_J"]) < 1e-9 * r["energy_J"], f"parts {parts:.12g} vs total {r['energy_J']:.12g}"


def test_outputs_written(unbalanced):
    _, out, summary = unbalanced
    cols = set(read_rows(out / "results.csv")[0])
    need = {
        "step",
        "u0_mm",
        "force_N",
        "energy_J",
        "energy_bending1_J",
        "energy_bending2_J",
        "energy_slip_J",
        "energy_shear_springs_J",
        "energy_inter_J",
        "energy_axial_J",
        "newton_iterations",
        "step_wall_s",
        "max_slip_mm",
        "gamma_A_deg",
        "gamma_B_deg",
        "gamma_C_deg",
    }
    files = [out / n for n in ("summary.json", "profile.csv", "state_30mm.npz", "yarns_30mm.png")]
    missing = need - cols
    assert not missing and all(f.exists() for f in files), (
        f"missing columns {missing}, files {[f.name for f in files if not f.exists()]}"
    )
    with np.load(out / "state_30mm.npz") as d:
        assert d["crossing_slip_mm"].shape == (summary["network"]["crossings"],)


def test_balanced_network_has_straight_mid_axis(tmp_path):
    # EI1 = EI2, EA1 = EA2: the mirror Y -> W - Y maps m1 onto m2 and the network onto itself,
    # so the mid-axis stays straight (no S-shape)
    scene = Scene().with_changes(
        **{**BASE, "discrete.EI2": 0.4, "discrete.EA2": 5e4, "loading.u0_mm": 20.0, "outputs.plot": False}
    )
    run(scene, tmp_path, progress=False)
    uy = np.asarray(read_profiles(tmp_path / "profile.csv")[20.0][1])
    assert np.abs(uy).max() < 1e-6, f"max |u_y| on the mid-axis: {np.abs(uy).max():.3g} mm"


def test_ideal_kinematics_limit(tmp_path):
    # stiff slip springs (no slip), soft bending: the network trellises as in docs/model.md, *Ideal kinematics*,
    # gamma_A = pi/2 - 2 arccos((D + u0) / (sqrt2 D)), gamma_B = gamma_A / 2, gamma_C = 0.
    # Zone means include crossings next to the zone borders (transition layers one or two yarn
    # spacings wide), which bias A down and B, C up by a few percent at spacing 5 mm.
    u0 = 20.0
    scene = Scene().with_changes(
        **{
            **BASE,
            "loading.u0_mm": u0,
            "discrete.K_slip": 1e6,
            "discrete.EI1": 1e-6,
            "discrete.EI2": 1e-6,
            "outputs.plot": False,
        }
    )
    run(scene, tmp_path, progress=False)
    r = read_rows(tmp_path / "results.csv")[-1]
    D = scene.specimen.zone_a_length_mm
    gA = math.degrees(math.pi / 2 - 2 * math.acos((D + u0) / (math.sqrt(2) * D)))  # 16.53 deg
    assert abs(r["gamma_A_deg"] - gA) < 0.08 * gA, f"gamma_A {r['gamma_A_deg']:.3f} vs ideal {gA:.3f} deg"
    assert abs(r["gamma_B_deg"] - gA / 2) < 0.08 * gA / 2, f"gamma_B {r['gamma_B_deg']:.3f} vs ideal {gA / 2:.3f} deg"
    assert abs(r["gamma_C_deg"]) < 0.1 * gA, f"gamma_C {r['gamma_C_deg']:.3f} deg, ideal 0"
    assert r["max_slip_mm"] < 1e-3, f"slip {r['max_slip_mm']:.3g} mm with K_slip = 1e6 N/m"


def test_failed_step_reports_history(tmp_path):
    # a tolerance below round-off cannot be met: the run stops with status "failed", the last
    # converged load and the residual history in the summary
    scene = Scene().with_changes(
        **{
            **BASE,
            "solver.rtol": 1e-300,
            "solver.atol_energy": 1e-300,
            "solver.max_iterations": 2,
            "loading.min_step_mm": 1.0,
            "outputs.plot": False,
        }
    )
    with pytest.raises(ConvergenceError) as err:
        run(scene, tmp_path, progress=False)
    assert err.value.last_converged_mm == 0.0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "failed" and s["last_converged_u0_mm"] == 0.0 and len(s["residual_history"]) > 0, (
        f"status {s['status']}, error {s['error']}"
    )


def test_equivalent_network_bends_like_the_continuum(tmp_path):
    # the network with the continuum's energy per unit area (ngbet.discrete.equivalent: EA = t K_el s,
    # EI_k = t alpha_k s, K_phi = t K_sh s^2, no slip) and pinned ends reproduces the continuum's
    # mid-axis profile at 56 mm: measured correlation 0.965, amplitude ratio 0.87 (h = 10 mm);
    # the rest is discreteness (s = 5 mm against l2 = 31 mm) and large shear
    from ngbet.discrete.equivalent import continuum_equivalent
    from ngbet.run import run as run_any

    base = {
        "loading.u0_mm": 56.0,
        "loading.stops_mm": (),
        "outputs.plot": False,
        "outputs.vtk": False,
        "discretization.mesh_size_mm": 10.0,
    }
    cont = Scene().with_changes(**base)
    disc = Scene().with_changes(model="discrete", **base)
    disc = disc.with_changes(**continuum_equivalent(disc))
    run_any(cont, tmp_path / "c")
    assert run_any(disc, tmp_path / "d")["status"] == "ok"
    Xc, uc = map(np.asarray, read_profiles(tmp_path / "c" / "profile.csv")[56.0])
    Xd, ud = map(np.asarray, read_profiles(tmp_path / "d" / "profile.csv")[56.0])
    ud = np.interp(Xc, Xd, ud)
    corr = np.corrcoef(uc, ud)[0, 1]
    ratio = np.abs(ud).max() / np.abs(uc).max()
    assert corr > 0.9 and 0.7 < ratio < 1.3, f"correlation {corr:.3f}, amplitude ratio {ratio:.3f}"


def test_interrupted_run_keeps_the_solver_statistics(tmp_path, monkeypatch):
    # Ctrl-C after the third converged step: summary.json says "interrupted" at that load and
    # keeps what the solver counted until then (factorizations, work by cause, the half-turn blocks)
    import importlib

    discrete_run = importlib.import_module("ngbet.runner.discrete")
    on_step = discrete_run._Recorder.on_step
    calls = []

    def interrupting(self, rec, u):
        on_step(self, rec, u)
        calls.append(rec.u0)
        if len(calls) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(discrete_run._Recorder, "on_step", interrupting)
    with pytest.raises(KeyboardInterrupt):
        run(Scene().with_changes(**{**BASE, "outputs.plot": False}), tmp_path, progress=False)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["last_converged_mm"] == pytest.approx(calls[-1] * 1e3)
    assert s["factorizations"] >= 3 and s["half_turn_blocks"] is True
    assert s["work_by_cause"]["converged step"]["calls"] >= 3


def test_the_yarn_picture_is_drawn_from_the_state_file_alone(unbalanced, tmp_path):
    """The picture of a state is made from state_XXmm.npz: its segments are the deformed beams, coloured
    by their shear angle, exactly as the network gives them; a folder without forces still gets it."""
    import shutil

    from ngbet.discrete.network import network_from_scene
    from ngbet.discrete.observables import segment_gamma_deg
    from ngbet.figures.data import load_yarn_states
    from ngbet.figures.maps import yarn_state_figure
    from ngbet.figures.run import YARNS, draw_run

    scene, out, _ = unbalanced
    net = network_from_scene(scene)
    (st,) = load_yarn_states(out)
    with np.load(out / "state_30mm.npz") as z:
        u = np.column_stack([z["u_mm"] * 1e-3, z["theta_rad"]]).ravel()
    x = (net.X + u.reshape(-1, 3)[:, :2]) * 1e3
    fig = yarn_state_figure(st, scene)
    drawn = fig.axes[0].collections
    for fam, lc in zip((2, 1), drawn[:2], strict=True):  # thin yarns first, thick over them
        sel = net.beam_family == fam
        assert np.allclose(np.array(lc.get_segments()), x[net.beams[sel]], rtol=0, atol=1e-9)
        assert np.allclose(lc.get_array(), segment_gamma_deg(net, u)[sel], rtol=0, atol=1e-12)
    only_states = tmp_path / "run"
    only_states.mkdir()
    for name in ("scene.toml", "state_30mm.npz"):
        shutil.copy(out / name, only_states / name)
    (only_states / "results.csv").write_text("step,u0_mm\n1,30\n")
    assert draw_run(only_states, only=(YARNS,)) is None  # no force figure without forces
    assert (only_states / "yarns_30mm.png").stat().st_size > 10000
