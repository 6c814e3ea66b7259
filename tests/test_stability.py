"""The continuum's stability diagnosis: a data object, and the message written from it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import DoubleWell, carry

from ngbet.continuum.stability import EllipticityLoss, StabilityDiagnosis


def test_message_names_the_remedy_only_for_a_discretization_mode_of_a_well_posed_model():
    base = StabilityDiagnosis(
        54.0, (-0.01, 0.2), "discretization", 0.97, (3.0, 68.0), stabilization_K_Pa=(1.5e4, 3.3e4), K_el=1e7
    )
    msg = base.message()
    assert base.stable is False
    assert "stability lost" in msg and "a mode of the discretization" in msg
    assert "--set effects.stabilization_K=1e+07" in msg and "material.K_el =" not in msg  # the key to change
    ill = StabilityDiagnosis(
        54.8,
        (-0.01, 0.2),
        "discretization",
        0.97,
        (3.0, 68.0),
        (EllipticityLoss(2, 950.0, -0.3),),
        (1.5e4, 3.3e4),
        0.7e6,
    )
    assert "raise effects.stabilization_K" not in ill.message()  # no false remedy: the model is ill-posed
    assert "alpha2 = 0" in ill.message() and "950 mm²" in ill.message()
    cont = StabilityDiagnosis(40.0, (0.3,), "continuum", 0.01, (110.0, 35.0))
    assert cont.stable is True and "the model's own limit point" in cont.message()


def test_the_stabilization_named_is_never_the_one_in_place():
    """The remedy climbs from the stabilization in place: K_el where the smallest K_s is below it,
    then ten times the smallest, then the cap of 30 K_el, then none: a run that took the last
    advice is never told to set the value it has."""
    from ngbet.continuum.problem import STABILIZATION_CAP

    K_el = 7e5
    named = []
    ks = (1.7e4, 2.1e7)  # the default ("auto") range of the embedded scene at 30° yarns
    for _ in range(5):
        d = StabilityDiagnosis(42.4, (-1e-3,), "discretization", 0.9, (58.0, 7.0), stabilization_K_Pa=ks, K_el=K_el)
        k = d.stabilization_to_try
        if k is None:
            assert "raise effects.stabilization_K" not in d.message() and "30 material.K_el or more" in d.advice()
            break
        assert k > ks[0] and f"--set effects.stabilization_K={k:.3g}" in d.message()
        named.append(k)
        ks = (k, k)
    assert named == pytest.approx([K_el, 10 * K_el, STABILIZATION_CAP * K_el])


def test_a_skipped_test_says_why_and_classifies_nothing():
    d = StabilityDiagnosis(12.0, skipped="the uncondensed saddle-point tangent is indefinite by construction")
    assert d.stable is None and d.mode_class == "none" and math.isnan(d.ratio)
    assert d.message() == d.skipped


def test_displacement_control_snaps_through_a_fold_to_the_other_well_and_goes_on():
    """At the fold the step is relaxed to the stable state at the same load (the right well), the
    jump is recorded with the energy it released (0.75 at the fold, the exact value of the toy),
    and the path goes on to λ = 1, where the equilibrium is the real root of y³ − y = 1."""
    from ngbet.numerics.settings import NewtonSettings

    toy = DoubleWell()
    res = carry(toy, 1.0, 0.05, NewtonSettings(), min_step=1e-4, psi=np.array([1.0, 0.0]), hessian=toy)
    lam_f = 2 / (3 * math.sqrt(3))
    assert res.u0 == 1.0
    assert toy.x[1] == pytest.approx(1.3247179572, rel=1e-8)  # the plastic number
    snaps = res.path_info["snaps"]
    assert len(snaps) == 1 and [s.u0 for s in res.steps if s.snap] == [pytest.approx(snaps[0]["u0_mm"] * 1e-3)]
    jump = snaps[0]
    assert lam_f < jump["u0_mm"] * 1e-3 < lam_f + 2e-4  # the first increment past the fold, at most 2 min_step
    assert jump["released"] == pytest.approx(0.75, abs=0.01)
    assert jump["reaction_before"] > 0 > jump["reaction_after"]  # y jumped from the left well to the right one
    assert jump["lowest_eigenvalue_after"] > 0


def test_without_relaxation_displacement_control_stops_at_the_fold():
    """The same toy with ``snap = False``: displacement control cannot pass the fold."""
    from ngbet.errors import ConvergenceError
    from ngbet.numerics.settings import NewtonSettings

    with pytest.raises(ConvergenceError) as info:
        toy = DoubleWell()
        carry(toy, 1.0, 0.05, NewtonSettings(), min_step=1e-4, snap=False, hessian=toy)
    assert info.value.last_converged_mm * 1e-3 < 2 / (3 * math.sqrt(3))


def test_relaxation_leaves_an_unstable_equilibrium_along_its_mode():
    """Started on the hilltop y = 0 at λ = 0 (an equilibrium, tangent −1), :func:`relax` kicks
    along the unstable mode and finds a well bottom y = ±1, stable, reporting the eigenvalue it left."""
    from ngbet.numerics.relax import relax
    from ngbet.numerics.settings import NewtonSettings

    toy = DoubleWell(0.0)
    rep = relax(toy, NewtonSettings(), 1.0)
    assert rep.converged and abs(toy.x[1]) == pytest.approx(1.0, rel=1e-10)
    assert rep.kicked_from == -1.0 and rep.lowest_eigenvalue > 0


def test_a_spent_time_budget_stops_a_relaxation_before_its_next_factorization():
    """Inside a spent :func:`~ngbet.numerics.engine.time_budget` a relaxation factorizes nothing
    and says why: a relaxation may take hundreds of factorizations, and the path
    checks the budget only between its trials."""
    from ngbet.numerics.engine import time_budget
    from ngbet.numerics.relax import relax
    from ngbet.numerics.settings import NewtonSettings

    toy = DoubleWell(0.0)
    with time_budget(-1.0):
        rep = relax(toy, NewtonSettings(), 1.0)
    assert not rep.converged and rep.iterations == 0 and rep.history == [] and "time budget" in rep.reason
    rep = relax(toy, NewtonSettings(), 1.0)  # outside it the same relaxation goes on to a well
    assert rep.converged and abs(toy.x[1]) == pytest.approx(1.0, rel=1e-10)


class _WallAtZero(DoubleWell):
    """The double well with its right well outside the energy's domain (y > 0 inadmissible, as
    inverted material is for the continuum): past the fold there is no admissible stable state."""

    def merit(self, r):
        return math.inf if self.x[1] > 0 else self.energy()

    def admissible(self):
        return "y > 0" if self.x[1] > 0 else ""


def test_no_snap_into_an_inadmissible_state():
    """The relaxation does not cross into the inadmissible region: the run stops at the fold with
    the reason in the attempts, instead of jumping to the right well."""
    from ngbet.errors import ConvergenceError
    from ngbet.numerics.settings import NewtonSettings

    with pytest.raises(ConvergenceError) as info:
        toy = _WallAtZero()
        carry(toy, 1.0, 0.05, NewtonSettings(), min_step=1e-4, psi=np.array([1.0, 0.0]), hessian=toy)
    assert info.value.last_converged_mm * 1e-3 < 2 / (3 * math.sqrt(3))
    assert "no physical stable state" in info.value.attempts[-1].reason
    assert info.value.path_info["relaxations"] == 1 and info.value.path_info["snaps"] == []
