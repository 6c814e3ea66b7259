"""Geometry of the yarn network and exactness of its energy derivatives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ngbet.discrete.model import NetworkModel
from ngbet.discrete.network import build_network
from ngbet.scene.document import Scene


def small_network(**kw):
    # 20 x 10 mm at 45 deg with spacing 5/sqrt(2) mm: yarn lines y = x + b (family 1) and
    # y = -x + b' (family 2) [mm], b and b' stepping by 5 mm and passing through the centre (10, 5)
    return build_network(20e-3, 10e-3, 45.0, 5e-3 / math.sqrt(2), **kw)


def test_hand_count_small_specimen():
    # Hand count. Family 1: b in (-20, 10) -> b = -15, -10, -5, 0, 5 (b = -20 and 10 only touch
    # corners): 5 yarns; family 2: b' in (0, 30) -> 5, 10, 15, 20, 25: 5 yarns. Crossing of (b, b')
    # at x = (b' - b)/2, y = (b + b')/2, strictly inside when 0 < b + b' < 20 and 0 < b' - b < 40:
    # b = -15: b' = 20 (b' = 25 meets it at (20, 5), on the clamp: no crossing) -> 1; b = -10: 15,
    # 20, 25 -> 3; b = -5: 10, 15, 20 -> 3; b = 0: 5, 10, 15 -> 3; b = 5: 10 -> 1. Total 11.
    net = small_network()
    c = net.counts()
    assert (c["yarns_1"], c["yarns_2"], c["crossings"]) == (5, 5, 11), f"counts {c}"
    # nodes: 2 ends per yarn + 2 per crossing (one per yarn, so that the yarns can slip)
    assert c["nodes"] == 2 * 10 + 2 * 11, f"nodes {c['nodes']}"


def test_hand_count_zones_and_trusses():
    # Clamped yarns (an end on x = 0 or x = 20, corners count as clamp): family 1 b = -15, -10
    # (right), 0, 5 (left), b = -5 free; family 2 b' = 5, 10 (left), 20, 25 (right), b' = 15 free.
    # Zones of the 11 crossings: A = (-5, 15); B = (-10, 15), (-5, 10), (-5, 20), (0, 15);
    # C = (-15, 20), (-10, 20), (-10, 25), (0, 5), (0, 10), (5, 10) -> 1, 4, 6.
    c = small_network().counts()
    assert (c["crossings_A"], c["crossings_B"], c["crossings_C"], c["crossings_other"]) == (1, 4, 6, 0), f"{c}"
    # trusses: a yarn crossed by k consecutive yarns of the other family carries k - 1 of them:
    # family 2 yarns are crossed by 1, 3, 3, 3, 1 family-1 yarns -> 6; family 1 yarns by 1, 3, 3, 3, 1 -> 6
    assert c["trusses"] == 12, f"trusses {c['trusses']}"
    assert small_network(inter_layout="none").counts()["trusses"] == 0


def test_elements_per_segment_adds_interior_nodes():
    # each of the 11 * 2 + 10 = 32 yarn segments (stations: 2 ends + crossings, per yarn) gets 2 more nodes
    c1, c3 = small_network().counts(), small_network(elements_per_segment=3).counts()
    segments = c1["beams"]
    assert c3["nodes"] - c1["nodes"] == 2 * segments and c3["beams"] == 3 * segments, f"{c1} {c3}"


def test_network_is_half_turn_symmetric():
    # yarn offsets are centred: the half-turn about the centre maps the node set onto itself
    net = build_network(0.22, 0.07, 45.0, 5e-3)
    Xr = np.array([0.22, 0.07]) - net.X
    d = np.min(np.linalg.norm(net.X[None, :, :] - Xr[:, None, :], axis=2), axis=1)
    assert d.max() < 1e-12, f"largest distance of a rotated node to a node: {d.max():.3g} m"


@pytest.fixture(scope="module")
def model():
    net = build_network(40e-3, 20e-3, 45.0, 4e-3)
    return NetworkModel(net, EA1=5e4, EA2=2e4, EI1=0.4, EI2=1e-3, K_phi=2.5e-4, K_slip=11.0, K_inter=11.0)


def _random_state(model, scale, seed):
    rng = np.random.default_rng(seed)
    u = scale * rng.standard_normal(model.n_dofs)
    u[2::3] *= 50.0  # rotations of order 0.05-0.5 rad: the co-rotational terms matter
    return u


def _central_difference(f, u, scale, seed):
    """(f(u + h v) − f(u − h v)) / 2h along a random direction v, h = 1e-6 scale; returns (fd, v)."""
    v = np.random.default_rng(seed).standard_normal(len(u))
    h = 1e-6 * scale
    return (f(u + h * v) - f(u - h * v)) / (2 * h), v


@pytest.mark.parametrize("scale", [1e-4, 1e-3])
def test_gradient_matches_finite_differences(model, scale):
    u = _random_state(model, scale, 1)
    E, g, _ = model.evaluate(u)
    fd, v = _central_difference(model.energy, u, scale, seed=2)
    # central differences: truncation O(h^2) and round-off ~ 1e-16 E / h, both far below 1e-6
    assert abs(fd - g @ v) < 1e-6 * abs(g @ v), f"directional derivative {g @ v:.10g} vs FD {fd:.10g}"


@pytest.mark.parametrize("scale", [1e-4, 1e-3])
def test_hessian_matches_finite_differences(model, scale):
    u = _random_state(model, scale, 3)
    _, _, K = model.evaluate(u)
    fd, v = _central_difference(lambda w: model.evaluate(w, False)[1], u, scale, seed=4)
    err = np.linalg.norm(fd - K @ v) / np.linalg.norm(K @ v)
    assert err < 1e-6, f"relative Hessian-vector error {err:.3g}"


def test_hessian_is_symmetric(model):
    _, _, K = model.evaluate(_random_state(model, 1e-3, 5))
    asym = abs(K - K.T).max() / abs(K).max()
    assert asym < 1e-12, f"relative asymmetry {asym:.3g}"


@pytest.mark.parametrize("phi", [0.7, 2.0])
def test_energy_invariant_under_rigid_motion(model, phi):
    # translation + rotation by phi (also beyond 90 deg): u = R X + t - X, every theta = phi
    X = model.net.X
    R = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    u = np.zeros(model.n_dofs)
    u.reshape(-1, 3)[:, :2] = X @ R.T + np.array([0.013, -0.02]) - X
    u[2::3] = phi
    E, g, _ = model.evaluate(u)
    E_ref, g_ref, _ = model.evaluate(_random_state(model, 1e-4, 6), False)  # a small deformation, for scale
    assert abs(E) < 1e-12 * E_ref, f"rigid motion energy {E:.3g} J (small deformation: {E_ref:.3g} J)"
    # round-off only: |x| ~ 1e-16 relative errors times EA / L0 of the shortest (corner) elements
    ratio = np.abs(g).max() / np.abs(g_ref).max()
    assert ratio < 1e-8, f"rigid motion leaves forces {np.abs(g).max():.3g} N ({ratio:.3g} of a small deformation's)"


def test_zero_state_has_no_force():
    m = NetworkModel.from_scene(Scene(model="discrete"))
    E, g, _ = m.evaluate(np.zeros(m.n_dofs))
    assert E == 0.0 and np.abs(g).max() == 0.0 and m.reaction(g) == (0.0, 0.0), f"E {E}, |g| {np.abs(g).max()}"


def test_a_network_whose_yarns_do_not_join_the_clamps_is_refused_before_the_run(tmp_path):
    """At 51.2 mm the 70 x 220 mm specimen keeps 4 yarns per family and 3 crossings on its mid-line: no
    chain of yarns joins the clamps, and the run carried 0 N at every step, each called a snap-through.
    """
    from ngbet.cli import main
    from ngbet.discrete.network import NetworkError

    with pytest.raises(NetworkError, match="no chain of yarns and crossings joins the two clamps"):
        build_network(0.22, 0.07, 45.0, 51.2e-3)
    net = build_network(0.22, 0.07, 45.0, 45e-3)  # the coarsest that joins them: 11 crossings
    assert len(net.crossings) == 11 and not net.X.flags.writeable
    out = tmp_path / "never"
    assert main(["run", "--out", str(out), "--quiet", "--set=model=discrete", "--set=discrete.spacing_mm=51.2"]) == 2
    assert not out.exists()  # refused before the folder was made
