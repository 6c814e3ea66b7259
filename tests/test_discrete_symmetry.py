"""The half-turn symmetry of the BET network and the block factorization it gives (ngbet.discrete.symmetry).

The half-turn about the specimen's centre maps the network, its clamps and the prescribed motion
onto themselves. Checked here: the energy is invariant under u -> c u0 + S u (the identity the
block form rests on); a tangent of a symmetric state is block diagonal and its block solves equal
the whole factorization's to round-off; a state off the symmetric path is factorized whole; and
the path with blocks is the path without them (same steps, iterations, snap, forces to the
pinned tolerance of 1e-6).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from ngbet.discrete.eigen import OTHER_BLOCK_TOL, lowest_eigenvalues
from ngbet.discrete.linsolve import FreeBlockSolver
from ngbet.discrete.model import NetworkModel
from ngbet.discrete.newton import newton
from ngbet.discrete.solver import load_steps
from ngbet.discrete.symmetry import COUPLING_TOL, Blocks, HalfTurn, half_turn
from ngbet.numerics.engine import Steps
from ngbet.runner.settings import step_control
from ngbet.scene.document import Scene

SCENE = {"model": "discrete", "discrete.spacing_mm": 5.0, "loading.u0_mm": 56.0, "outputs.plot": False}


@pytest.fixture(scope="module")
def model() -> NetworkModel:
    return NetworkModel.from_scene(Scene().with_changes(**SCENE))


def _ramp_state(model: NetworkModel, u0: float, seed: int = 0) -> np.ndarray:
    """A state of the symmetric path's kind: the clamp ramp plus a symmetric random field."""
    ht = model.half_turn()
    assert ht is not None
    rng = np.random.default_rng(seed)
    w = 1e-3 * rng.standard_normal(model.n_dofs)
    w[model.fixed] = 0.0
    u = u0 * model.ramp + 0.5 * (w + ht.sign * w[ht.perm])
    u[model.fixed] = u0 * model.load[model.fixed]
    return u


def test_half_turn_is_an_involution_and_leaves_the_energy_invariant(model):
    ht = model.half_turn()
    assert ht is not None
    assert np.array_equal(ht.perm[ht.perm], np.arange(model.n_dofs))
    u0 = 0.02
    u = np.random.default_rng(1).standard_normal(model.n_dofs) * 1e-3
    u[model.fixed] = u0 * model.load[model.fixed]
    v = u0 * ht.shift + ht.sign * u[ht.perm]  # c u0 + S u: the half-turned state
    assert np.array_equal(v[model.fixed], u[model.fixed])  # the prescribed motion is mapped onto itself
    E, g, _ = model.evaluate(u, False)
    Ev, gv, _ = model.evaluate(v, False)
    assert Ev == pytest.approx(E, rel=1e-12)
    # the gradient is carried along: g(c u0 + S u) = S g(u)
    np.testing.assert_allclose(gv, ht.sign * g[ht.perm], rtol=0, atol=1e-9 * np.abs(g).max())


def test_half_turn_is_refused_where_the_model_lacks_it(model):
    assert half_turn(model) is not None
    broken = NetworkModel(model.net, **model.stiffness, end_rotation=model.end_rotation)
    broken.load = broken.load.copy()
    broken.load[3 * broken.fixed_nodes[0]] = 0.5  # one fixed-clamp node dragged along: not symmetric
    assert half_turn(broken) is None
    grp = broken.groups[0]
    broken.load = model.load
    broken.groups[0] = dataclasses.replace(grp, dofs=grp.dofs[1:])  # one beam left out
    assert half_turn(broken) is None


def test_projection_onto_the_symmetric_path(model):
    ht = model.half_turn()
    u = _ramp_state(model, 0.03)
    np.testing.assert_allclose(ht.project(u, 0.03), u, rtol=0, atol=1e-16)
    kick = np.zeros(model.n_dofs)
    kick[~model.fixed] = np.random.default_rng(2).standard_normal((~model.fixed).sum())
    anti = 0.5 * (kick - ht.sign * kick[ht.perm])  # S anti = -anti
    assert ht.project(u + 1e-12 * anti, 0.03) is not None  # round-off: projected back
    assert ht.project(u + 1e-3 * np.abs(u).max() * anti, 0.03) is None  # left the path: kept


def test_blocks_are_orthonormal_and_reproduce_the_free_block(model):
    ht = model.half_turn()
    u = _ramp_state(model, 0.02)
    K = model.evaluate(u, True)[2]
    lin = FreeBlockSolver(K, ~model.fixed, "auto", ht)
    maps = Blocks(ht, lin.free, lin.rows, lin.cols)
    B = sp.hstack([maps.B_s, maps.B_a]).tocsr()
    assert abs(B.T @ B - sp.eye(lin.nf)).max() <= 1e-15
    Kff = lin.free_block(K)
    Ks = maps.B_s.T @ Kff @ maps.B_s
    Ka = maps.B_a.T @ Kff @ maps.B_a
    assert abs(maps.B_s @ Ks @ maps.B_s.T + maps.B_a @ Ka @ maps.B_a.T - Kff).max() <= 1e-12 * abs(Kff).max()
    # the blocks' values come from K_ff's by the precomputed maps
    vals = Kff.data
    assert (
        abs(sp.csr_matrix((maps.M_s @ vals, (maps.rows_s, maps.cols_s)), shape=Ks.shape) - Ks).max()
        <= 1e-12 * abs(Kff).max()
    )
    assert (
        abs(sp.csr_matrix((maps.M_a @ vals, (maps.rows_a, maps.cols_a)), shape=Ka.shape) - Ka).max()
        <= 1e-12 * abs(Kff).max()
    )


@pytest.mark.parametrize("symmetric", [True, False])
def test_block_solves_equal_the_whole_factorization(model, symmetric):
    ht = model.half_turn()
    u = _ramp_state(model, 0.02)
    if not symmetric:  # a state off the path: an antisymmetric kick of 1e-6 of the state
        kick = np.random.default_rng(3).standard_normal(model.n_dofs)
        kick[model.fixed] = 0.0
        u = u + 1e-6 * np.abs(u).max() * 0.5 * (kick - ht.sign * kick[ht.perm])
    E, g, K = model.evaluate(u, True)
    blocks = FreeBlockSolver(K, ~model.fixed, "auto", ht)
    whole = FreeBlockSolver(K, ~model.fixed, "auto", None)
    blocks.factor(K)
    whole.factor(K)
    assert blocks.in_blocks is symmetric
    coupling = blocks._blocks.coupling
    # measured 2e-13 on the path and 1e-5 for the kick; the threshold sits between
    assert (coupling < 1e-3 * COUPLING_TOL) if symmetric else (coupling > 1e3 * COUPLING_TOL), coupling
    b = np.random.default_rng(4).standard_normal(blocks.nf)
    x_whole = whole.solve(b)
    np.testing.assert_allclose(blocks.solve(b), x_whole, rtol=0, atol=1e-9 * np.abs(x_whole).max())
    assert blocks.n_factor_antisymmetric == int(symmetric)  # factorized on demand, once
    r = g[blocks.free]  # a residual: symmetric on the path, its solve needs the symmetric block only
    x_whole = whole.solve(r)
    np.testing.assert_allclose(blocks.solve(r, symmetric_rhs=True), x_whole, rtol=0, atol=1e-9 * np.abs(x_whole).max())


def forces_on_the_path(model: NetworkModel, ctl) -> tuple[dict, dict[float, float]]:
    """The path's statistics and its force at each load [mm] (the runner's loop over the step records)."""
    steps = Steps(load_steps(model, ctl))
    F = {round(rec.u0 * 1e3, 6): model.reaction(rec.residual)[0] for rec in steps}
    assert steps.result is not None
    return steps.result.path_info, F


def test_path_with_blocks_is_the_path_without(model):
    sc = Scene().with_changes(**SCENE)
    forces = {}
    stats = {}
    for on in (True, False):
        stats[on], forces[on] = forces_on_the_path(model, dataclasses.replace(step_control(sc), half_turn=on))
    on, off = stats[True], stats[False]
    assert on["half_turn_blocks"] and not off["half_turn_blocks"]
    for key in ("steps", "newton_iterations", "factorizations"):
        assert on[key] == off[key], key
    brackets = {k: [(e["u0_before"], e["u0"]) for e in st["snap_events"]] for k, st in stats.items()}
    assert brackets[True] == brackets[False] and len(brackets[True]) == 1, brackets
    for u0 in (37.0, 56.0):
        assert forces[True][u0] == pytest.approx(forces[False][u0], rel=1e-6)
    # the antisymmetric block is factorized for the stability check only: once per converged state
    assert on["factorizations_antisymmetric"] == on["steps"]
    assert off["factorizations_antisymmetric"] == 0


def test_path_with_cholmod_is_the_path_with_the_ldlt(model):
    """CHOLMOD's LL^T, with the LDL^T for the indefinite tangents, follows the LDL^T's path.

    The two factorizations differ in round-off only: the same steps, iterations, factorizations
    and snap bracket, and forces within 1e-6 of the peak force (measured: at most 1.7e-7 here, 2e-9
    at 16 890 dofs). Newton stops each step within its tolerance, whose own error in F(37) is
    1.2e-5 on this network (against rtol = 1e-14), and the round-off moves where in that band it
    stops. Some Newton tangents of the path are indefinite (a step started across a limit point),
    so both kinds of factorization are met.
    """
    sc = Scene().with_changes(**SCENE)
    forces, stats = {}, {}
    for backend in ("cholmod", "sparsecholesky"):
        stats[backend], forces[backend] = forces_on_the_path(
            model, dataclasses.replace(step_control(sc), backend=backend)
        )
    ch, ld = stats["cholmod"], stats["sparsecholesky"]
    assert ch["backend"] == "cholmod" and ld["backend"] == "sparsecholesky"
    for key in ("steps", "newton_iterations", "factorizations", "factorizations_antisymmetric"):
        assert ch[key] == ld[key], key
    assert [(e["u0_before"], e["u0"]) for e in ch["snap_events"]] == [
        (e["u0_before"], e["u0"]) for e in ld["snap_events"]
    ]
    assert forces["cholmod"].keys() == forces["sparsecholesky"].keys()
    peak = max(abs(f) for f in forces["sparsecholesky"].values())
    for u0, f in forces["sparsecholesky"].items():
        assert abs(forces["cholmod"][u0] - f) <= 1e-6 * peak, u0
    assert 0 < ch["factorizations_ldlt"] < ch["factorizations"] / 2, ch["factorizations_ldlt"]
    assert ld["factorizations_ldlt"] == 0


def test_mirrored_assembly_equals_the_element_by_element_sum(model):
    """On the symmetric path half the element kernels and their images give E, g and K to round-off."""
    u = _ramp_state(model, 0.02)
    assert model._on_symmetric_path(u)
    E, g, K = model.evaluate(u, True)
    whole = NetworkModel(model.net, **model.stiffness, end_rotation=model.end_rotation)
    whole._on_symmetric_path = lambda u: False  # element by element
    E1, g1, K1 = whole.evaluate(u, True)
    assert E == pytest.approx(E1, rel=1e-13)
    np.testing.assert_allclose(g, g1, rtol=0, atol=1e-12 * np.abs(g1).max())
    assert abs(K - K1).max() <= 1e-12 * abs(K1).max()
    # a state 1e-9 off the path is evaluated element by element
    kick = np.random.default_rng(5).standard_normal(model.n_dofs)
    kick[model.fixed] = 0.0
    assert not model._on_symmetric_path(u + 1e-9 * np.abs(u).max() * kick)


@pytest.mark.integration
def test_the_17k_network_keeps_its_forces_and_snaps():
    """The 16 890-dof network (spacing 2.4 mm) with the half-turn blocks, against the whole factorization.

    Reference: F(37) = 13.176711539 N, F(56) = 26.688239758 N and the three snap brackets,
    from the run that factorized every tangent whole (bench/bench_discrete.py --run-only).
    """
    sc = Scene().with_changes(**{**SCENE, "discrete.spacing_mm": 2.4, "loading.output_every_mm": 0.0})
    net_model = NetworkModel.from_scene(sc)
    st, F = forces_on_the_path(net_model, step_control(sc))
    assert st["half_turn_blocks"] and st["n_free"] == 16_730
    assert F[37.0] == pytest.approx(13.176711539, rel=1e-6)
    assert F[56.0] == pytest.approx(26.688239758, rel=1e-6)
    brackets = [(round(e["u0_before"] * 1e3, 3), round(e["u0"] * 1e3, 3)) for e in st["snap_events"]]
    assert brackets == [(28.5, 29.5), (50.922, 51.922), (51.922, 52.922)], brackets
    assert st["factorizations_antisymmetric"] == st["steps"]
    # a step of the snap bracket's length stops at its first tangent that needs a shift and is
    # relaxed from there: no shifted Newton in a failed attempt (measured: 107 factorizations on
    # this path; 113 with shifted Newton in the failed attempts, 7 of their 19 shifted)
    assert st["work_by_cause"]["failed attempt"]["shift_factorizations"] == 0
    assert st["factorizations"] <= 110, st["factorizations"]


def test_a_state_off_the_symmetric_path_is_solved_whole(model):
    """Newton from a state kicked along an antisymmetric field: whole factorizations, the whole solver's answer."""
    sc = Scene().with_changes(**{**SCENE, "loading.u0_mm": 10.0})
    u = [rec.state.copy() for rec in load_steps(model, step_control(sc))][-1]
    ht = model.half_turn()
    kick = np.random.default_rng(6).standard_normal(model.n_dofs)
    kick[model.fixed] = 0.0
    start = u + 1e-6 * np.abs(u).max() * 0.5 * (kick - ht.sign * kick[ht.perm])
    assert ht.project(start, 0.01) is None and not model._on_symmetric_path(start)
    K = model.evaluate(start, True)[2]
    ctl = step_control(sc)
    lins = {
        "blocks": FreeBlockSolver(K, ~model.fixed, "auto", ht),
        "whole": FreeBlockSolver(K, ~model.fixed, "auto", None),
    }
    ends = {name: newton(model, start, lin, ctl, max_iterations=40, line_search=True)[0] for name, lin in lins.items()}
    blocks = lins["blocks"]  # every tangent met has a coupling block: factorized whole
    assert blocks.n_factor_whole == blocks.n_factor > 0 and not blocks.in_blocks
    # the same iterates as the whole solver's (measured 1.5e-15 apart), back on the path's equilibrium
    # (stable at 10 mm; measured 2.6e-12 from it, from a kick of 2.5e-6)
    scale = np.abs(u).max()
    np.testing.assert_allclose(ends["blocks"], ends["whole"], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(ends["blocks"], u, rtol=0, atol=1e-9 * scale)


def _block_spectra(lin: FreeBlockSolver, K: sp.csr_matrix, k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The k lowest eigenvalues of K_b y = lambda D_b y in each half-turn block, dense (reference)."""
    import scipy.linalg as sla

    Kff = lin.free_block(K).toarray()
    d = np.abs(np.diag(Kff))
    maps = lin._blocks.maps
    out = []
    for B in (maps.B_s.toarray(), maps.B_a.toarray()):
        out.append(sla.eigh(B.T @ Kff @ B, B.T @ (d[:, None] * B), eigvals_only=True)[:k])
    return out[0], out[1]


def test_stability_check_sees_the_symmetric_block_from_antisymmetric_modes():
    # A chain of 40 dofs on soft ground springs, symmetric under reversal (the half-turn of a
    # line): its softest mode is symmetric (the near-translation), the softest antisymmetric one
    # is a tilt. A tangent that commutes with the half-turn keeps a Krylov space grown from
    # antisymmetric vectors antisymmetric: the check, started from the softest antisymmetric
    # modes (as the network's checks are after the first step), must still find the symmetric
    # eigenvalue below them, and report both blocks' lowest.
    n = 40
    D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    springs = 1.0 + 0.5 * np.sin(np.linspace(0, np.pi, n - 1))  # symmetric under reversal
    ground = 1e-4 * (1.0 + np.cos(np.linspace(0, 2 * np.pi, n)))
    K = (D.T @ sp.diags(springs) @ D + sp.diags(ground + 1e-6)).tocsr()
    ht = HalfTurn(perm=np.arange(n)[::-1].copy(), sign=np.ones(n), shift=np.zeros(n))
    lin = FreeBlockSolver(K, np.ones(n, bool), "auto", ht)
    lin.factor(K)
    assert lin.in_blocks
    sym, anti = _block_spectra(lin, K)
    assert sym[0] < anti[0]  # the setting: the softest mode is symmetric
    Ba = lin._blocks.maps.B_a.toarray()
    import scipy.linalg as sla

    d = np.abs(K.diagonal())
    _, Ya = sla.eigh(Ba.T @ K.toarray() @ Ba, Ba.T @ (d[:, None] * Ba))
    X0 = Ba @ Ya[:, :2]  # the two softest antisymmetric modes, as from the last check
    lam, V = lowest_eigenvalues(lin, 2, X0)
    assert lam[0] == pytest.approx(sym[0], rel=1e-6), (lam, sym, anti)
    assert np.any(np.isclose(lam, anti[0], rtol=1e-6)), (lam, anti)
    assert V.shape == (n, len(lam))


def test_stability_check_of_the_network_reports_both_blocks(model):
    # At the converged 4 mm state of the 4 086-dof network: the lowest eigenvalue to the Lanczos
    # tolerance (its Ritz value to ~1e-6), each block's lowest among those returned, the other
    # block's within the residual it is resolved to; started cold and from antisymmetric modes.
    ht = model.half_turn()
    states = {}
    ctl = step_control(Scene().with_changes(**SCENE))
    ctl = dataclasses.replace(ctl, path=dataclasses.replace(ctl.path, target=4e-3), stability=False)
    states.update({rec.u0: rec.state.copy() for rec in load_steps(model, ctl)})
    u = states[max(states)]
    K = model.evaluate(u, True)[2]
    lin = FreeBlockSolver(K, ~model.fixed, "auto", ht)
    lin.factor(K)
    sym, anti = _block_spectra(lin, K)
    # measured: antisymmetric 3.14e-8, 4.86e-8, symmetric 5.47e-8
    ref = np.sort(np.concatenate([sym, anti]))
    maps = lin._blocks.maps

    def check(lam: np.ndarray, V: np.ndarray) -> None:
        assert lam[0] == pytest.approx(ref[0], rel=1e-6), (lam, ref)
        for B, low in ((maps.B_s, sym[0]), (maps.B_a, anti[0])):  # a mode of each block, near its lowest
            part = np.linalg.norm(B.T @ V, axis=0) / np.linalg.norm(V, axis=0)
            assert np.any((part > 0.99) & (np.abs(lam / low - 1) <= OTHER_BLOCK_TOL)), (lam, part, sym, anti)

    lam, V = lowest_eigenvalues(lin, 2)
    check(lam, V)
    pure_anti = maps.B_a @ (maps.B_a.T @ V)
    lam2, V2 = lowest_eigenvalues(lin, 2, pure_anti[:, np.linalg.norm(pure_anti, axis=0) > 1e-3])
    check(lam2, V2)
