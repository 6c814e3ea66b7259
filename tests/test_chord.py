"""Rows between load steps by a chord correction: convergence, hand-over, the tangent it leaves, a run."""

import math

import numpy as np
import pytest
from conftest import coarse

from ngbet.numerics import chord as C
from ngbet.numerics.settings import NewtonSettings
from ngbet.run import run
from ngbet.tables import read_rows


class Hardening:
    """E(λ, y) = ½(λ − y)² + ¼y⁴ with the load λ prescribed: r = (λ − y, y³ + y − λ).

    On the path y³ + y = λ: the reaction R = λ − y and dR/dλ = 3y²/(3y² + 1) exactly. ``factorize``
    sets the matrix J₀ = 3y² + 1 at the current y, which the solves keep until the next call.
    """

    dirichlet = np.array([True, False])

    def __init__(self, lam: float, y: float) -> None:
        self.state = self
        self.x = np.array([lam, y])
        self.J0 = 1.0
        self.factorizations = 0

    def residual(self):
        lam, y = self.x
        return np.array([lam - y, y**3 + y - lam])

    def factorize(self, shift: float = 0.0) -> float:
        self.J0 = 3 * self.x[1] ** 2 + 1
        self.factorizations += 1
        return 0.0

    def solve(self, r):
        return np.array([0.0, -r[1] / self.J0])

    def load_tangent(self, dlam):
        return np.array([dlam, dlam / self.J0])

    def norm(self, dx):
        return abs(dx[1])


def _on_path(lam: float) -> float:
    """y with y³ + y = λ."""
    return float(np.real([r for r in np.roots([1.0, 0.0, 1.0, -lam]) if abs(r.imag) < 1e-12][0]))


SETTINGS = NewtonSettings(rtol=1e-10, atol=1e-16)


def test_chord_converges_to_newtons_tolerance_with_an_earlier_factorization():
    """From a state off the path at λ = 2 with the factorization of λ = 1.9: linear convergence,
    and the state passes Newton's own test (decrement r·J⁻¹r with the true J below the tolerance)."""
    toy = Hardening(1.9, _on_path(1.9))
    toy.factorize()
    y2 = _on_path(2.0)
    toy.x[:] = [2.0, y2 + 0.01]
    rep = C.chord(toy, SETTINGS, e_ref=1.0, refactorizations=0)
    assert rep.converged and rep.iterations >= 2 and toy.factorizations == 1
    r = toy.residual()
    assert r[1] ** 2 / (3 * toy.x[1] ** 2 + 1) <= SETTINGS.rtol + SETTINGS.atol
    assert abs(toy.x[1] - y2) < 1e-7
    assert 0 < rep.contraction < C.CHORD_CONTRACTION


def test_a_step_that_passes_the_test_is_taken_without_linearizing_again():
    """With the factorization of λ = 1.9 at λ = 2 the chord contracts by |1 − J/J₀| ≈ 0.05; judged
    by a bound of 0.02 it would linearize again at its second step, but that step's decrement
    (θ² times the first, 1e-10 from a state 5e-6 off the path) already passes the test, so it is taken."""
    toy = Hardening(1.9, _on_path(1.9))
    toy.factorize()
    y2 = _on_path(2.0)
    toy.x[:] = [2.0, y2 + 5e-6]
    rep = C.chord(toy, SETTINGS, e_ref=1.0, max_contraction=0.02)
    assert rep.converged and rep.iterations == 2 and toy.factorizations == 1
    assert 0.02 < rep.contraction < 0.1
    r = toy.residual()  # Newton's own test, with the true J
    assert r[1] ** 2 / (3 * toy.x[1] ** 2 + 1) <= SETTINGS.rtol + SETTINGS.atol


def test_a_chord_that_does_not_contract_linearizes_again_or_hands_over():
    """With the factorization of λ = 1 at λ = 2 the chord contracts by |1 − J/J₀| ≈ 0.7: it fails
    when it may not linearize again (Newton takes over), and converges after doing so once."""
    y2 = _on_path(2.0)
    for refactorizations, converged in ((0, False), (1, True)):
        toy = Hardening(1.0, _on_path(1.0))
        toy.factorize()
        toy.x[:] = [2.0, y2 + 0.01]
        rep = C.chord(toy, SETTINGS, e_ref=1.0, refactorizations=refactorizations)
        assert rep.converged is converged and toy.factorizations == 1 + refactorizations
    assert "contraction" not in rep.reason and abs(toy.x[1] - y2) < 1e-7


@pytest.mark.parametrize("lam_factorized,refinements", [(1.9, C.TANGENT_REFINEMENTS), (1.0, 30)])
def test_tangent_at_hand_gives_the_exact_load_derivative(lam_factorized, refinements):
    """dR/dλ at λ = 2 from the factorization of an earlier load is 3y²/(3y² + 1) to 1e-6, where the
    earlier tangent alone (ψ·J₀t₀) is off by 2 % (λ = 1.9) to 30 % (λ = 1.0, where the refinement
    contracts by 0.4 and needs more than the default number of refinements: it says so)."""
    toy = Hardening(lam_factorized, _on_path(lam_factorized))
    toy.factorize()
    y = _on_path(2.0)
    toy.x[:] = [2.0, y]
    exact = 3 * y * y / (3 * y * y + 1)
    stale = 1.0 - 1.0 / toy.J0  # ψ·J₀t₀ with J₀ from the earlier load
    assert abs(stale - exact) > 1e-2 * exact
    psi = np.array([1.0, 0.0])
    found = C.tangent_at_hand(toy, psi, 1e-8, toy.residual(), rel=1e-7, max_refinements=refinements)
    assert found is not None
    t, dR = found
    assert dR == pytest.approx(exact, rel=1e-6)
    assert t[1] == pytest.approx(1 / (3 * y * y + 1), rel=1e-3)  # dR/dλ is second order in its error
    if refinements > C.TANGENT_REFINEMENTS:
        assert C.tangent_at_hand(toy, psi, 1e-8, toy.residual(), rel=1e-7) is None


def test_the_load_derivative_needs_the_reaction_conjugate_to_the_load():
    toy = Hardening(1.0, _on_path(1.0))
    with pytest.raises(ValueError, match="prescribed entries"):
        C.tangent_at_hand(toy, np.array([2.0, 0.0]), 1e-8)


def test_extrapolation_is_exact_for_a_cubic():
    loads = [0.0, 2.0, 3.0, 5.0]
    f = lambda s: np.array([s**3 - 2 * s, 1.0 + s * s])  # noqa: E731
    states = [(s, f(s)) for s in loads]
    np.testing.assert_allclose(C.extrapolate(states, 7.0), f(7.0), rtol=1e-12)


def test_output_rows_by_chord_match_newton_and_save_linearizations(tmp_path, monkeypatch):
    """The coarse scene to 20 mm with a row every 2 mm: the rows agree with Newton's on every row
    (force to 1e-7, dF/du0 to 2e-3, Newton's own being taken with the matrix of the predicted
    state), the stop and the final load to 1e-9, with fewer linearizations than rows; the chord's
    slopes satisfy the trapezoid rule over each 2 mm step, (F1 − F0)/h = (F0' + F1')/2 + O(h²)."""
    scene = coarse(
        **{
            "loading.u0_mm": 20.0,
            "loading.stops_mm": [11.0],
            "loading.output_every_mm": 2.0,
            "outputs.error_estimate": "off",
        }
    )
    s = run(scene, tmp_path / "chord", progress=False)
    monkeypatch.setattr(C.ChordRows, "due", lambda self, lam: False)  # Newton on every row
    n = run(scene, tmp_path / "newton", progress=False)
    rows, ref = read_rows(tmp_path / "chord" / "results.csv"), read_rows(tmp_path / "newton" / "results.csv")
    assert [r["u0_mm"] for r in rows] == [r["u0_mm"] for r in ref] == [2, 4, 6, 8, 10, 11, 12, 14, 16, 18, 20]
    for a, b in zip(rows, ref, strict=True):
        assert a["force_N"] == pytest.approx(b["force_N"], rel=1e-9 if a["u0_mm"] in (11, 20) else 1e-7)
        assert a["dforce_du0_N_per_mm"] == pytest.approx(b["dforce_du0_N_per_mm"], rel=2e-3)
    assert s["counts"]["factorizations"] < len(rows) <= n["counts"]["factorizations"]
    for a, b in zip(rows[:-1], rows[1:], strict=True):
        fd = (b["force_N"] - a["force_N"]) / (b["u0_mm"] - a["u0_mm"])
        assert math.isclose(fd, 0.5 * (a["dforce_du0_N_per_mm"] + b["dforce_du0_N_per_mm"]), rel_tol=2e-3)


def test_the_polynomial_predicts_only_from_states_spaced_like_the_step():
    """After cut steps (states 0.125 mm apart) a 0.3 mm step is predicted by the tangent, not by a
    cubic through them (which amplifies their differences ~30 times); states 2 mm apart predict 2 mm."""
    rows = C.ChordRows([0.002, 0.004, 0.0192, 0.02, 0.023])
    x = np.zeros(2)
    rows.states = [(lam, x) for lam in (0.0185, 0.019, 0.019125, 0.01925)]
    assert rows.predictor(x, 0.01925, 0.00075) is None
    rows.states = [(lam, np.full(2, lam)) for lam in (0.012, 0.014, 0.016, 0.018)]
    np.testing.assert_allclose(rows.predictor(x, 0.018, 0.002), [0.02, 0.02])
    assert rows.predictor(x, 0.016, 0.004) is None and rows.predictor(x, 0.018, 0.005) is None
    assert rows.predictor(x, 0.018, 0.001) is None  # 19 mm is not a row of the grid


def test_rows_between_uneven_stops_keep_the_tangents_prescribed_entries_those_of_the_load(tmp_path):
    """A fabric scene to 95 mm with stops every 3.68 mm between rows every 2 mm: each chord row's tangent
    starts from the extrapolation of the last two, whose ratio of steps is up to 1.8. Extrapolated,
    the prescribed entries' round-off grew from row to row until the reaction's test vector no longer
    matched the tangent (1.9e-5 at 80 mm, and the run stopped there); copied, every row's dF/du0 is
    the load derivative: it matches the central differences of the forces."""
    from pathlib import Path

    from ngbet.scene.document import Scene

    scene = Scene.from_toml(Path(__file__).resolve().parents[1] / "geometry" / "twintex_plain.toml").with_changes(
        **{
            "specimen.width_mm": 150.0,
            "specimen.length_mm": 450.0,
            "material.K_el": 2.91e6,
            "material.shear_stress_steps_Pa": [2341.5, 1085.4, 7799.9, 31360.0, 598807.0, 346423.0],
            "loading.u0_mm": 95.27,
            "loading.stops_mm": [round(10.68373 + 3.67775 * k, 5) for k in range(23)],
            "loading.output_every_mm": 2.0,
            "outputs.plot": False,
            "outputs.vtk": False,
            "outputs.error_estimate": "off",
        }
    )
    s = run(scene, tmp_path / "r")
    rows = read_rows(tmp_path / "r" / "results.csv")
    assert s["status"] == "ok" and rows[-1]["u0_mm"] == pytest.approx(95.27) and s["chord_rows"] > 20
    u, F, dF = (np.array([r[k] for r in rows]) for k in ("u0_mm", "force_N", "dforce_du0_N_per_mm"))
    central = (F[2:] - F[:-2]) / (u[2:] - u[:-2])
    assert np.allclose(dF[1:-1], central, rtol=0.1), np.max(np.abs(dF[1:-1] / central - 1))
