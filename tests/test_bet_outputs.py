"""The BET-standard columns of results.csv (both models): kinematic shear angle, normalised shear force, zone means.

docs/model.md, *Zones* and *Ideal kinematics*; Cao et al. 2008, Eqs. 13 and 18.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import coarse

from ngbet.kinematics import normalised_shear_force, shear_angle_rad, zone_index
from ngbet.run import run
from ngbet.scene.document import Scene
from ngbet.tables import read_rows


def _columns(rows, *keys):
    return [np.array([r[k] for r in rows], dtype=float) for k in keys]


@pytest.fixture(scope="module")
def continuum_rows(tmp_path_factory):
    """The paper's scene on the coarse mesh to 40 mm: a row every 2 mm and at the 37 mm stop."""
    out = tmp_path_factory.mktemp("bet")
    run(coarse(**{"loading.u0_mm": 40.0, "outputs.error_estimate": "off"}), out)
    return read_rows(out / "results.csv")


def eq18_by_fixed_point(d, F, H, W):
    """Eq. 18 solved on the whole curve at once by fixed-point iteration (not the row-by-row solve).

    F_sh = [(H/W − 1) F (cos γ/2 − sin γ/2) − W F_sh(γ/2) cos γ/2] / [(2H − 3W) cos γ], with F_sh
    piecewise linear in γ through (0, 0); the map contracts by about W/(2H − 3W) < 1.
    """
    g = np.pi / 2 - 2 * np.arccos((H - W + d) / (np.sqrt(2) * (H - W)))
    f = np.zeros_like(g)
    for _ in range(200):
        half = np.interp(g / 2, np.r_[0.0, g], np.r_[0.0, f])
        f = ((H / W - 1) * F * (np.cos(g / 2) - np.sin(g / 2)) - W * half * np.cos(g / 2)) / (
            (2 * H - 3 * W) * np.cos(g)
        )
    return g, f


def test_a_row_every_two_millimetres_and_at_the_stop(continuum_rows):
    u0 = [r["u0_mm"] for r in continuum_rows]
    assert u0 == sorted({*(2.0 * k for k in range(1, 21)), 37.0})


def test_kinematic_shear_angle_column_is_eq13_and_the_tabulated_values(continuum_rows):
    u0, g = _columns(continuum_rows, "u0_mm", "gamma_kinematic_deg")
    assert np.allclose(g, np.degrees(shear_angle_rad(u0, 220.0, 70.0)), rtol=1e-12, atol=0)
    tab = {10.0: 7.92, 20.0: 16.53, 37.0: 33.65}  # docs/model.md, *Ideal kinematics*, to 0.01 degree
    assert all(abs(g[u0 == u][0] - v) < 0.006 for u, v in tab.items())


def test_fsh_column_is_eq18_on_the_runs_own_force(continuum_rows):
    u0, F, fsh = _columns(continuum_rows, "u0_mm", "force_N", "fsh_N_per_mm")
    assert np.allclose(fsh, normalised_shear_force(u0, F, 220.0, 70.0)[1], rtol=1e-12, atol=0)
    _, independent = eq18_by_fixed_point(u0, F, 220.0, 70.0)
    assert np.allclose(fsh, independent, rtol=1e-10, atol=0)
    # the first row by hand: F_sh(γ/2) = F_sh(γ)/2 on the line through (0, 0)
    g = math.pi / 2 - 2 * math.acos(152 / (math.sqrt(2) * 150))
    by_hand = (22 / 7 - 1) * F[0] * (math.cos(g / 2) - math.sin(g / 2)) / (230 * math.cos(g) + 35 * math.cos(g / 2))
    assert fsh[0] == pytest.approx(by_hand, rel=1e-12)


def test_zone_means_order_as_the_ideal_zones(continuum_rows):
    """Zone A shears most, zones B about half as much, the clamp triangles C hardly: at every row."""
    A, B, C = _columns(continuum_rows, "gamma_A_deg", "gamma_B_deg", "gamma_C_deg")
    assert np.all(A > 1.5 * B) and np.all(B > 3 * np.abs(C))


def test_zone_regions_have_the_ideal_areas():
    """A_A = L W − 1.5 W², A_B = W², A_C = W²/2 (docs/model.md), counted on a 0.1 mm grid (shifted off the
    45° zone borders, so that no point lies on one)."""
    X, Y = np.meshgrid(np.arange(0.03, 220.0, 0.1), np.arange(0.07, 70.0, 0.1))
    counts = np.bincount(zone_index(X, Y, 220.0, 70.0).ravel(), minlength=3) * 0.01
    assert np.allclose(counts, [220 * 70 - 1.5 * 70**2, 70**2, 0.5 * 70**2], rtol=2e-3)


def test_zone_quadrature_integrates_the_ideal_areas():
    """The zone borders cut the elements: the high-order rule still gets the areas within 0.5 %."""
    from ngbet.continuum.observables import ZoneShearMeans
    from ngbet.continuum.problem import ContinuumProblem

    means = ZoneShearMeans(ContinuumProblem(coarse()))
    assert np.allclose(means.areas * 1e6, [8050.0, 4900.0, 2450.0], rtol=5e-3)


def test_other_yarn_angles_leave_the_bet_columns_empty(tmp_path):
    """Eqs. 13 and 18 are those of the ±45° bias test: at 40° both columns are empty, the zone means are not."""
    run(
        coarse(
            **{
                "specimen.yarn_angle_deg": 40.0,
                "loading.u0_mm": 6.0,
                "loading.stops_mm": [],
                "outputs.error_estimate": "off",
            }
        ),
        tmp_path,
    )
    rows = read_rows(tmp_path / "results.csv")
    assert len(rows) == 3 and all(r["gamma_kinematic_deg"] == "" and r["fsh_N_per_mm"] == "" for r in rows)
    assert all(isinstance(r["gamma_A_deg"], float) and r["gamma_A_deg"] > 0 for r in rows)


def test_centre_and_zone_shear_tend_to_the_ideal_test_as_the_yarns_stiffen(tmp_path):
    """Ideal kinematics is the limit of inextensible yarns without bending (docs/model.md): with
    α1 = α2 = 0.2 Pa m² (ℓ = 3 mm) and K_el/K_sh = 48, 480, 4800, the yarns' stretch that lets the
    specimen deviate from the ideal zones costs more and more, and at u0 = 20 mm (γ = 16.53°) the
    centre, zone A and zone B angles approach γ, γ, γ/2 and zone C approaches 0, each more closely
    at each step. Measured (p = 3, h = 10 mm): centre/γ 0.73, 0.83, 0.88; zone A/γ 0.79, 0.94,
    0.99; zone B/(γ/2) 1.16, 1.09, 1.02; zone C 3.2°, 1.0°, 0.25°. The sequence stops at 4800: on
    this mesh the two stiff yarn families lock beyond (K_el/K_sh = 48 000 overshoots, zone A 1.03 γ)."""
    err = []
    for K_el in (1e6, 1e7, 1e8):
        out = tmp_path / f"{K_el:g}"
        run(
            coarse(
                **{
                    "material.K_el": K_el,
                    "material.alpha1": 0.2,
                    "material.alpha2": 0.2,
                    "loading.u0_mm": 20.0,
                    "loading.stops_mm": [],
                    "loading.output_every_mm": 10.0,
                    "loading.first_step_mm": 10.0,
                    "outputs.error_estimate": "off",
                    "discretization.order_u": 3,
                }
            ),
            out,
        )
        r = read_rows(out / "results.csv")[-1]
        g = r["gamma_kinematic_deg"]
        err.append(
            (
                abs(r["gamma_centre_deg"] / g - 1),
                abs(r["gamma_A_deg"] / g - 1),
                abs(r["gamma_B_deg"] / (g / 2) - 1),
                abs(r["gamma_C_deg"] / g),
            )
        )
    e = np.array(err)
    assert np.all(np.diff(e, axis=0) < 0), f"deviations from the ideal test do not all fall with K_el:\n{e}"
    assert np.all(e[-1] < [0.15, 0.03, 0.05, 0.03]), f"at K_el/K_sh = 4800: {e[-1]}"


def test_discrete_bet_columns(tmp_path):
    """The network writes the same columns: F_sh from its own force by Eq. 18, γ by Eq. 13, the centre angle."""
    run(
        Scene().with_changes(
            **{
                "model": "discrete",
                "loading.u0_mm": 8.0,
                "loading.stops_mm": [],
                "outputs.plot": False,
                "discrete.spacing_mm": 10.0,
            }
        ),
        tmp_path,
        progress=False,
    )
    rows = read_rows(tmp_path / "results.csv")
    u0, F, g, fsh, centre = _columns(
        rows, "u0_mm", "force_N", "gamma_kinematic_deg", "fsh_N_per_mm", "gamma_centre_deg"
    )
    assert list(u0) == [2.0, 4.0, 6.0, 8.0]
    assert np.allclose(g, np.degrees(shear_angle_rad(u0, 220.0, 70.0)), rtol=1e-12, atol=0)
    assert np.allclose(fsh, eq18_by_fixed_point(u0, F, 220.0, 70.0)[1], rtol=1e-10, atol=0)
    assert np.all((centre > 0.5 * g) & (centre < 1.5 * g))


def test_the_path_lands_on_the_output_grid_and_the_stops_below_the_final_load():
    from ngbet.scene.numerical import Loading
    from ngbet.scene.validate import SceneError

    assert Loading(u0_mm=10.0, stops_mm=(5.0,), output_every_mm=3.0).path_stops_mm == (3.0, 5.0, 6.0, 9.0)
    assert Loading(u0_mm=10.0, stops_mm=(5.0,), output_every_mm=0.0).path_stops_mm == (5.0,)
    assert Loading(u0_mm=4.0, output_every_mm=2.0).path_stops_mm == (2.0,)  # 4 is the final load, 37 not reached
    with pytest.raises(SceneError, match="loading.output_every_mm"):
        Loading(output_every_mm=-1.0)
    # a grid finer than the smallest step is landed on all the same (a landing step is not a cut)
    fine = Loading(u0_mm=1.0, min_step_mm=0.5, first_step_mm=0.5, output_every_mm=0.25)
    assert fine.path_stops_mm == (0.25, 0.5, 0.75)
