"""The jamming barrier: the yarns of a woven fabric cannot cross.

W_jam = K_jam s_jam² (1 − t)³/t for t = s/s_jam < 1 (s the sine of the angle between the deformed
yarns), 0 beyond, continued below t = JAMMING_CUTOFF by its second-order Taylor polynomial in t
(ngbet.continuum.physics.jamming_energy). Checked here: zero above the threshold, value and first
two derivatives zero at it exactly, C² at the cutoff, s = det F sin θ0 / √(i4 i6), no inverted
homogeneous state below the energy of the unjammed ones, and invisible to an ordinary run.
"""

import math

import ngsolve as ngs
import numpy as np
import pytest
from conftest import coarse
from netgen.geom2d import unit_square

from ngbet.continuum import physics
from ngbet.continuum.jamming import JAMMING_MARGIN, JAMMING_SET_MARGIN
from ngbet.run import run
from ngbet.scene.document import Scene
from ngbet.scene.validate import SceneError

K = 7e5  # Pa
S_JAM = math.sin(math.radians(5.0))
MESH = ngs.Mesh(unit_square.GenerateMesh(maxh=1.0))
POINT = MESH(0.3, 0.3)


def _at(cf):
    return float(cf(POINT))


def _energy_and_derivatives(s_value):
    """W_jam, dW/ds and d²W/ds² at s (NGSolve differentiates the CoefficientFunction)."""
    s = ngs.Parameter(s_value)
    W = physics.jamming_energy(s, K, S_JAM)
    return _at(W), _at(W.Diff(s)), _at(W.Diff(s).Diff(s))


def test_zero_above_the_threshold_and_c2_at_it_exactly():
    """Above s_jam the energy is exactly 0 (the IfPos branch), and at s = s_jam the value and both
    derivatives of (1 − t)³/t vanish exactly (the factor (1 − t)³ is 0 there): the tangent is
    continuous, so Newton stays quadratic across the threshold; just below, the energy is positive
    and of order (1 − t)³."""
    for s in (S_JAM * (1 + 1e-12), 0.5, 1.0):
        assert _energy_and_derivatives(s) == (0.0, 0.0, 0.0)
    assert _energy_and_derivatives(S_JAM) == (0.0, 0.0, 0.0)
    W, dW, d2W = _energy_and_derivatives(0.9 * S_JAM)
    # t = 0.9: K s_jam² (0.1)³/0.9, dW/ds = K s_jam (−3 (0.1)²/0.9 − (0.1)³/0.81) < 0
    assert W == pytest.approx(K * S_JAM**2 * 1e-3 / 0.9, rel=1e-12)
    assert dW == pytest.approx(K * S_JAM * (-3e-2 / 0.9 - 1e-3 / 0.81), rel=1e-12) and dW < 0 < d2W


def test_taylor_continuation_at_the_cutoff_is_c2():
    """At t = JAMMING_CUTOFF the rational branch hands over to its Taylor polynomial: value, slope and
    curvature agree from both sides (to the ε of the two evaluation points)."""
    sc = physics.JAMMING_CUTOFF * S_JAM
    eps = 1e-9
    above, below = _energy_and_derivatives(sc * (1 + eps)), _energy_and_derivatives(sc * (1 - eps))
    for a, b in zip(above, below, strict=True):
        assert a == pytest.approx(b, rel=1e-6)


def test_decreasing_and_convex_in_s_down_to_crossed_yarns():
    """Below the threshold the energy rises as the yarns close and keeps rising past s = 0 (crossed
    yarns, det F < 0): dW/ds < 0 and d²W/ds² > 0 on the whole range."""
    for s in np.linspace(-1.0, 0.999 * S_JAM, 200):
        _, dW, d2W = _energy_and_derivatives(float(s))
        assert dW < 0 < d2W, s


def test_the_sine_is_det_F_over_the_stretches():
    """s = (Fm1 × Fm2)/(|Fm1| |Fm2|) = det F sin θ0/√(i4 i6) at any F, for ±45° and ±30° yarns;
    negative exactly when det F < 0."""
    rng = np.random.default_rng(1)
    for a in (45.0, 30.0):
        r = math.radians(a)
        m1, m2 = (math.cos(r), math.sin(r)), (-math.cos(r), math.sin(r))
        orient = math.copysign(1.0, m1[0] * m2[1] - m1[1] * m2[0])
        sin0 = abs(m1[0] * m2[1] - m1[1] * m2[0])
        for _ in range(5):
            F = np.eye(2) + 0.8 * rng.standard_normal((2, 2))
            s = _at(physics.yarn_angle_sine(ngs.CF(tuple(F.ravel()), dims=(2, 2)), ngs.CF(m1), ngs.CF(m2), orient))
            i4, i6 = np.sum((F @ m1) ** 2), np.sum((F @ m2) ** 2)
            assert s == pytest.approx(np.linalg.det(F) * sin0 / math.sqrt(i4 * i6), rel=1e-12)


def _homogeneous_energy(gamma_deg, jamming):
    """Energy density [Pa] of inextensible ±45° yarns sheared by γ: the deformed yarns are unit vectors
    at 90° + γ, so i4 = i6 = 1, i8 = −sin γ and det F = cos γ (< 0 past γ = 90°: the yarns crossed)."""
    m1, m2 = np.array([1.0, 1.0]) / math.sqrt(2), np.array([-1.0, 1.0]) / math.sqrt(2)
    b = math.radians(45.0 - gamma_deg / 2)  # a1 at 45° − γ/2, a2 at 135° + γ/2
    a1, a2 = np.array([math.cos(b), math.sin(b)]), np.array([-math.cos(b), math.sin(b)])
    F = np.column_stack([a1, a2]) @ np.linalg.inv(np.column_stack([m1, m2]))
    Fc, m1c, m2c = ngs.CF(tuple(F.ravel()), dims=(2, 2)), ngs.CF(tuple(m1)), ngs.CF(tuple(m2))
    inv = physics.invariants(Fc - ngs.Id(2), m1c, m2c)
    W = physics.shear_energy(inv.i8, 21e3) + physics.elongation_energy(inv.i4, inv.i6, K)
    if jamming:
        W = W + physics.jamming_energy(physics.yarn_angle_sine(Fc, m1c, m2c), K, S_JAM)
    return _at(W), float(np.linalg.det(F))


def test_it_forbids_inversion():
    """Without the barrier the quadratic shear energy ½K_sh sin²γ falls again past γ = 90° and the
    inverted state γ = 180° (det F = −1, the specimen mirrored in its plane) has the energy of the rest
    state: nothing keeps the material from turning inside out. With the barrier the energy rises
    monotonically from the threshold (γ = 85°) through γ = 90° (det F = 0) to 180°, and every state with
    det F <= 0 lies above the largest energy the shear can store (½K_sh) by a factor of 50 at least."""
    W0, _ = _homogeneous_energy(180.0, jamming=False)
    assert W0 == pytest.approx(0.0, abs=1e-9)  # the mirror image of the rest state
    gammas = np.linspace(85.0, 179.9, 400)
    W = np.array([_homogeneous_energy(g, jamming=True)[0] for g in gammas])
    J = np.array([_homogeneous_energy(g, jamming=True)[1] for g in gammas])
    assert np.all(np.diff(W) > 0)
    # at det F = 0 the barrier holds K s_jam² h(0) = 57.0 K s_jam² (h continued below the cutoff):
    # 67 times ½K_sh here
    assert np.min(W[J <= 0]) > 50 * 0.5 * 21e3
    ordinary = [_homogeneous_energy(g, jamming=True) for g in np.linspace(0.0, 84.9, 50)]
    assert all(
        w == _homogeneous_energy(g, jamming=False)[0]
        for (w, _), g in zip(ordinary, np.linspace(0.0, 84.9, 50), strict=True)
    )


def test_an_ordinary_run_never_reaches_it(tmp_path, made_problems):
    """The default material to 56 mm (coarse mesh): the yarns never come within twice the jamming
    angle (the smallest angle between them is 35° on the embedded scene, measured), so the barrier is
    never even evaluated, and the forces and Newton iterations are those without it, bit for bit."""
    from ngbet.tables import read_rows

    made = made_problems
    ch = {"solver.threads": 1, "outputs.profile": False, "outputs.error_estimate": "off"}
    on = run(coarse(**ch), tmp_path / "on")
    assert len(made) == 1 and not made[0].jamming_on
    off = run(coarse(**ch, **{"effects.jamming": False}), tmp_path / "off")
    F_on = [(r["u0_mm"], r["force_N"], r["newton_iterations"]) for r in read_rows(tmp_path / "on" / "results.csv")]
    F_off = [(r["u0_mm"], r["force_N"], r["newton_iterations"]) for r in read_rows(tmp_path / "off" / "results.csv")]
    assert F_on == F_off and on["load_steps"] == off["load_steps"]


def _sheared_problem(gamma_deg):
    """The solver of a coarse problem (p = 2, no Dirichlet data) in the homogeneous state of inextensible ±45°
    yarns sheared by γ."""
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.runner.settings import continuum_solver

    pb = ContinuumProblem(coarse(**{"discretization.mesh_size_mm": 20.0}), dirichlet="")
    m1, m2 = np.array(pb.scene.specimen.m1), np.array(pb.scene.specimen.m2)
    b = math.radians(45.0 - gamma_deg / 2)
    a1, a2 = np.array([math.cos(b), math.sin(b)]), np.array([-math.cos(b), math.sin(b)])
    G = np.column_stack([a1, a2]) @ np.linalg.inv(np.column_stack([m1, m2])) - np.eye(2)
    pb.u.Set(ngs.CF((G[0, 0] * ngs.x + G[0, 1] * ngs.y, G[1, 0] * ngs.x + G[1, 1] * ngs.y)))
    return continuum_solver(pb), ngs.Id(2) + ngs.Grad(pb.u)


def test_the_barrier_is_switched_on_where_the_yarns_come_near():
    """At a new load the state is checked: yarns 30° apart (γ = 60°) leave the barrier off; 6° apart
    (γ = 84°, within JAMMING_MARGIN times the 5° threshold's sine) switch it on, for good, yet add
    exactly 0 to the energy (above the threshold); 4° apart (γ = 86°) the energy holds ∫W_jam at the
    energy's own quadrature order 2p."""
    K, s_jam = 7e5, S_JAM
    assert math.sin(math.radians(30.0)) > JAMMING_MARGIN * S_JAM
    pb, _ = _sheared_problem(60.0)
    pb.problem.converged()
    assert not pb.problem.jamming_on
    pb, _ = _sheared_problem(84.0)
    E_before = pb.energy()
    pb.problem.converged()
    assert pb.problem.jamming_on and pb.energy() == E_before
    pb, F = _sheared_problem(86.0)
    pb.problem.converged()
    assert pb.problem.jamming_on
    E_on = pb.energy()
    pb.problem.jamming.elements.Clear()
    W = physics.jamming_energy(physics.yarn_angle_sine(F, pb.problem.m1, pb.problem.m2), K, s_jam)
    assert E_on - pb.energy() == pytest.approx(ngs.Integrate(W, pb.problem.mesh, order=4), rel=1e-10)


def test_the_barrier_is_on_only_where_the_yarns_come_near_and_the_energy_is_the_same():
    """A state sheared by 40° at one end of the specimen and by 86° at the other (yarns 4° apart,
    past the 5° threshold): the watch puts the barrier on the elements whose yarns come within
    JAMMING_SET_MARGIN times the threshold's sine and on no other; energy and residual are those of the barrier on
    every element, bit for bit (elsewhere it is exactly 0). With the barrier off where the yarns
    close past the threshold the state is a miss."""
    pb, _ = _sheared_problem(40.0)
    G40 = ngs.Grad(pb.problem.u)(pb.problem.mesh(0.0, 0.0))
    G86 = ngs.Grad(_sheared_problem(86.0)[0].problem.u)(pb.problem.mesh(0.0, 0.0))
    xs = [v.point[0] for v in pb.problem.mesh.vertices]
    xi = (ngs.x - min(xs)) / (max(xs) - min(xs))
    G = [(1 - xi) * a + xi * b for a, b in zip(G40, G86, strict=True)]  # row-major 2x2
    pb.problem.u.Set(ngs.CF((G[0] * ngs.x + G[1] * ngs.y, G[2] * ngs.x + G[3] * ngs.y)))
    jam = pb.problem.jamming
    pb.problem.converged()
    assert 0 < jam.elements.NumSet() < pb.problem.mesh.ne and not jam.missed()
    assert np.array_equal(jam._where, jam._smallest() < JAMMING_SET_MARGIN * S_JAM)
    E_near, r_near = pb.energy(), pb.residual()
    jam.switch_on()
    assert pb.energy() == E_near and np.array_equal(pb.residual(), r_near)
    jam.elements.Clear()
    jam._where[:] = False
    assert jam.missed()


@pytest.mark.parametrize(
    "changes, key",
    [
        ({"material.jamming_angle_deg": 0.0}, "material.jamming_angle_deg"),
        ({"material.jamming_angle_deg": 90.0}, "material.jamming_angle_deg"),
        ({"effects.jamming": "yes"}, "effects.jamming"),
        # ±84° yarns are 12° apart at rest (as lines): a jamming angle of 15° would jam them at rest
        ({"specimen.yarn_angle_deg": 84.0, "material.jamming_angle_deg": 15.0}, "material.jamming_angle_deg"),
    ],
)
def test_bad_jamming_keys_are_refused_by_name(changes, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        Scene().with_changes(**changes)


def test_jamming_off_is_accepted_at_any_angle():
    s = Scene().with_changes(
        **{"specimen.yarn_angle_deg": 84.0, "material.jamming_angle_deg": 15.0, "effects.jamming": False}
    )
    assert s.effects.jamming is False


def test_no_state_of_the_path_has_crossed_yarns_that_the_barrier_missed():
    """Without bending the shear concentrates at the clamp corners (smallest yarn angle 32° at
    16 mm on the embedded scene, 77° with bending) and one increment from 16 to 22 mm lands, with
    the barrier off (its watch switches it on within JAMMING_MARGIN times the jamming angle's sine,
    about 29°), on a state whose
    yarns cross (-30°): no equilibrium of the energy. Such a state is solved again with the
    barrier on: in every state kept, each element the barrier was off on has its yarns more open
    than the jamming angle at the barrier's integration points, and none has crossed yarns at the
    points of the order-2p rule (with the barrier, they may close into it, not past it; at the
    barrier's finer rule its continuation below t = 0.05 lets a corner point cross by less than
    1 % of the threshold's sine: -0.9 % measured)."""
    import ngsolve as ngs

    from ngbet.continuum import physics
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.numerics.engine import Steps
    from ngbet.runner.continuum import load_path
    from ngbet.runner.settings import continuum_solver

    scene = Scene().with_changes(**{"effects.bending": False, "loading.u0_mm": 22.0, "loading.output_every_mm": 0.0})
    solver = continuum_solver(ContinuumProblem(scene))
    pb, jam = solver.problem, solver.problem.jamming
    coarse = physics.yarn_angle_sine(ngs.Id(2) + ngs.Grad(pb.u), pb.m1, pb.m2).Compile()
    points = pb.mesh.MapToAllElements(ngs.IntegrationRule(ngs.TRIG, 2 * scene.discretization.p_u), ngs.VOL)
    kept = []  # (smallest sine where the barrier was off, at its rule; smallest at its rule; at the order-2p rule)
    original = solver.problem.converged

    def watched() -> None:
        fine, off = jam._smallest(), ~jam._where
        kept.append((fine[off].min() if off.any() else np.inf, fine.min(), float(np.min(np.asarray(coarse(points))))))
        original()

    solver.problem.converged = watched
    steps = Steps(load_path(solver, scene))
    for _ in steps:
        pass
    res = steps.result
    assert res is not None
    assert res.u0 == pytest.approx(0.022)
    assert jam.on and any(
        a.reason == "the yarns close past the jamming angle in the state found without the "
        "barrier; solved again with it"
        for a in res.attempts
    )
    off, fine, order_2p = np.array(kept).T
    assert off.min() > S_JAM and order_2p.min() > 0.0 and fine.min() > -0.01 * S_JAM


def test_the_corner_that_snaps_shut_has_the_barrier_on_before_it_snaps():
    """Without bending the clamp corner's yarns close to 25° at 18 mm and 22° at 19 mm on the
    embedded scene, and the next increment snaps the corner shut onto the barrier (a limit point
    near 19.8 mm). The watch puts the corner's elements in the barrier's set from the state at
    18 mm on (within JAMMING_SET_MARGIN times the threshold's sine, about 29°), so no increment
    of the path to 20 mm lands on crossed yarns with the barrier off: no trial is a miss solved
    again (with a set margin of 4, about 20°, the increments 19 -> 20 and 19.5 -> 20 mm were)."""
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.numerics.engine import Steps
    from ngbet.numerics.path import JAMMING_MISSED
    from ngbet.runner.continuum import load_path
    from ngbet.runner.settings import continuum_solver

    scene = Scene().with_changes(**{"effects.bending": False, "loading.u0_mm": 20.0})
    solver = continuum_solver(ContinuumProblem(scene))
    steps = Steps(load_path(solver, scene))
    for _ in steps:
        pass
    res = steps.result
    assert res is not None and res.u0 == pytest.approx(0.020)
    assert solver.problem.jamming.on
    assert not any(a.reason == JAMMING_MISSED for a in res.attempts)
    assert any(not a.converged for a in res.attempts)  # the limit point is on the way
