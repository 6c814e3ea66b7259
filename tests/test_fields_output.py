"""``outputs.vtk_every_step`` and :meth:`ngbet.Result.fields`: a fields file per step, each the state of its row.

The clamps are the exact check: on the moving clamp (X = L) the displacement is (u0, 0) of the
step's row of results.csv, on the fixed clamp (0, 0); the last step's file is the final one.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import coarse

import ngbet

pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def every_step(tmp_path_factory):
    scene = coarse(
        **{
            "outputs.vtk": True,
            "outputs.vtk_every_step": True,
            "loading.u0_mm": 6.0,
            "loading.output_every_mm": 2.0,
            "loading.stops_mm": [],
            "outputs.error_estimate": "off",
        }
    )
    return ngbet.simulate(scene, tmp_path_factory.mktemp("fields") / "run")


def test_every_step_has_its_fields_file_with_the_clamps_at_its_load(every_step):
    r = every_step
    steps = [int(s) for s in r.columns["step"]]
    assert r.status == "ok" and len(steps) >= 3 and r.u0_mm[-1] == 6.0
    assert sorted(p.name for p in r.out.glob("fields_*.vtu")) == [f"fields_{s:03d}.vtu" for s in steps]
    L = r.scene.specimen.length_mm
    final = r.fields()
    for s, u0 in zip(steps, r.u0_mm, strict=True):
        mesh = r.fields(s)
        assert mesh.n_points == final.n_points  # one mesh for the whole path
        X, u = mesh.points[:, 0], mesh.point_data["displacement"]
        moving, fixed = np.isclose(X, L, atol=1e-9), np.isclose(X, 0.0, atol=1e-9)
        assert moving.sum() > 2 and fixed.sum() > 2
        np.testing.assert_allclose(u[moving, 0], u0, rtol=1e-9)  # mm, as results.csv
        np.testing.assert_allclose(u[moving, 1:], 0.0, atol=1e-12)
        np.testing.assert_allclose(u[fixed], 0.0, atol=1e-12)
    np.testing.assert_array_equal(r.fields(steps[-1]).point_data["displacement"], final.point_data["displacement"])


def test_a_step_without_its_file_names_the_key_that_writes_it(every_step):
    with pytest.raises(FileNotFoundError, match="outputs.vtk_every_step is true"):
        every_step.fields(999)


def test_without_vtk_every_step_only_the_final_fields_are_written(tmp_path):
    r = ngbet.simulate(
        coarse(**{"outputs.vtk": True, "loading.u0_mm": 2.0, "outputs.error_estimate": "off"}), tmp_path / "run"
    )
    assert (r.out / "fields.vtu").exists() and not list(r.out.glob("fields_*.vtu"))
    with pytest.raises(FileNotFoundError, match="outputs.vtk_every_step"):
        r.fields(1)
