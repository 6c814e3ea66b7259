"""Ideal BET kinematics and the normalised shear force (Cao et al. 2008, Eqs. 13 and 18)."""

import math

import numpy as np
import pytest

from ngbet.kinematics import force_from_normalised, normalised_shear_force, shear_angle_rad


def test_shear_angle_matches_the_tabulated_ideal_test():
    # zone A of the 70 x 220 mm specimen (D = 150 mm), tabulated to 0.01 degree
    g = np.degrees(shear_angle_rad([10, 20, 37, 56, 60], 220.0, 70.0))
    assert np.allclose(g, [7.92, 16.53, 33.65, 62.38, 73.74], atol=0.006)


def test_shear_angle_refuses_locked_displacements():
    with pytest.raises(ValueError, match="locking"):
        shear_angle_rad([70.0], 220.0, 70.0)  # locking at (sqrt 2 - 1) 150 = 62.1 mm


def test_the_method_has_no_force_at_or_beyond_locking():
    """A measured curve may go past the ideal locking (a prediction's points there): the method gives
    NaN there and its force below it, instead of refusing the whole curve."""
    table = np.linspace(1e-3, 1.4, 50)
    lock = (math.sqrt(2) - 1) * 150.0
    F = force_from_normalised(table, 0.3 * table, np.array([10.0, 37.0, lock, 70.0]), 220.0, 70.0)
    assert np.all(np.isfinite(F[:2])) and np.all(F[:2] > 0) and np.all(np.isnan(F[2:]))
    assert F[1] == force_from_normalised(table, 0.3 * table, np.array([37.0]), 220.0, 70.0)[0]


def test_a_linear_shear_law_is_recovered_exactly():
    # F from F_sh = k gamma through Eq. 18 solved for F; the recursion interpolates F_sh linearly,
    # so a law linear in gamma comes back to round-off
    H, W, k = 450.0, 150.0, 0.3
    d = np.linspace(1.0, 60.0, 40)
    table = np.linspace(1e-3, 1.4, 200)
    F = force_from_normalised(table, k * table, d, H, W)
    gamma, fsh = normalised_shear_force(d, F, H, W)
    assert np.max(np.abs(fsh - k * gamma)) < 1e-12


def test_one_point_by_hand():
    # H = 450, W = 150, d = 30 mm: g = pi/2 - 2 acos(330 / (sqrt 2 * 300)) = 0.211575 rad;
    # with F_sh(g/2) = F_sh(g)/2 (linear through 0) Eq. 18 gives, at F = 10 N,
    # F_sh = 2 (cos g/2 - sin g/2) F / (450 cos g + 150 cos(g/2) / 2) = 17.7764 / 514.546 N/mm
    g = math.pi / 2 - 2 * math.acos(330 / (math.sqrt(2) * 300))
    by_hand = 2 * (math.cos(g / 2) - math.sin(g / 2)) * 10 / (450 * math.cos(g) + 75 * math.cos(g / 2))
    gamma, fsh = normalised_shear_force([30.0], [10.0], 450.0, 150.0)
    assert gamma[0] == pytest.approx(0.211575, abs=1e-6)
    assert fsh[0] == pytest.approx(by_hand, rel=1e-12)
    assert fsh[0] == pytest.approx(17.7764 / 514.546, rel=1e-4)
