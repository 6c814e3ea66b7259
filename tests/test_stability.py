"""The continuum's stability diagnosis: a data object, and the message written from it."""

from __future__ import annotations

import math

from ngbet.continuum.stability import EllipticityLoss, StabilityDiagnosis


def test_message_names_the_remedy_only_for_a_discretization_mode_of_a_well_posed_model():
    base = StabilityDiagnosis(54.0, (-0.01, 0.2), "discretization", 0.97, (3.0, 68.0),
                              stabilization_K_Pa=(1.5e4, 3.3e4), K_el=1e7)
    msg = base.message()
    assert base.stable is False
    assert "stability lost" in msg and "a mode of the discretization" in msg and "material.K_el = 1e+07 Pa" in msg
    ill = StabilityDiagnosis(54.8, (-0.01, 0.2), "discretization", 0.97, (3.0, 68.0),
                             (EllipticityLoss(2, 950.0, -0.3),), (1.5e4, 3.3e4), 0.7e6)
    assert "raise effects.stabilization_K" not in ill.message()  # no false remedy: the model is ill-posed
    assert "alpha2 = 0" in ill.message() and "950 mm²" in ill.message()
    cont = StabilityDiagnosis(40.0, (0.3,), "continuum", 0.01, (110.0, 35.0))
    assert cont.stable is True and "the model's own limit point" in cont.message()


def test_a_skipped_test_says_why_and_classifies_nothing():
    d = StabilityDiagnosis(12.0, skipped="the uncondensed saddle-point tangent is indefinite by construction")
    assert d.stable is None and d.mode_class == "none" and math.isnan(d.ratio)
    assert d.message() == d.skipped
