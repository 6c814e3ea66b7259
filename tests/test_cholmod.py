"""CHOLMOD's LLᵀ for the continuum's Newton matrix (ngbet.cholmod, ngbet.numerics.linear).

The LLᵀ must give the sparse LDLᵀ's solutions, hand a matrix that is not positive definite to the
LDLᵀ, and leave a run's answers where they were. (The discrete model's use: test_discrete_solver
and test_discrete_symmetry.)
"""

import csv

import numpy as np
import pytest

from ngbet import cholmod
from ngbet.continuum.mesh import corner_refined
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics.linear import CHOLMOD_MIN_DOFS, pick_inverse
from ngbet.run import run
from ngbet.runner.settings import continuum_solver
from ngbet.scene.document import default_scene
from ngbet.scene.validate import SceneError


def _scene(**changes):
    return default_scene().with_changes(
        **{"discretization.mesh_size_mm": 20.0, "solver.compile": "interpret", **changes}
    )


def _problem(linear_solver: str, refined: bool) -> ContinuumSolver:
    sc = _scene(**{"solver.linear_solver": linear_solver})
    mesh = corner_refined(ContinuumProblem(sc).mesh, sc.specimen, 2) if refined else None
    return continuum_solver(ContinuumProblem(sc, mesh=mesh))


@pytest.mark.parametrize("refined", [False, True])
def test_the_llt_solves_as_the_ldlt(refined):
    """The unloaded state, where the Newton matrix is positive definite: the LLᵀ holds it, and its
    solve is the LDLᵀ's (to the round-off the augmented matrix amplifies, as between LDLᵀ and
    UMFPACK). The refined mesh stores the whole matrix, the other its lower triangle."""
    pr = {ls: _problem(ls, refined) for ls in ("cholmod", "sparsecholesky")}
    for p in pr.values():
        p.state.set_load(0.0)
        p.factorize()
    ch, ld = pr["cholmod"], pr["sparsecholesky"]
    assert ch.linear.inverse_type == "cholmod" and ch.counts["factorizations_ldlt"] == 0 and ch.linear._use_llt
    A, _ = ld.linear.free_matrix()
    assert np.linalg.eigvalsh(A.toarray()).min() > 0
    r = np.zeros_like(ld.x)
    free = ld.problem.free_all
    r[free] = np.random.default_rng(0).standard_normal(int(free.sum()))
    dx_ch, dx_ld = ch.solve(r.copy()), ld.solve(r.copy())
    assert np.abs(dx_ch - dx_ld).max() <= 1e-8 * np.abs(dx_ld).max()


def test_a_matrix_that_is_not_positive_definite_goes_to_the_ldlt():
    """The clamp moved by 0.3 of the load with the specimen left behind: the Newton matrix there
    has negative eigenvalues (checked densely), the LLᵀ stops, and the LDLᵀ gives the solve."""
    pr = {ls: _problem(ls, False) for ls in ("cholmod", "sparsecholesky")}
    for p in pr.values():
        p.state.set_load(0.3)
        p.factorize()
    ch, ld = pr["cholmod"], pr["sparsecholesky"]
    A, _ = ld.linear.free_matrix()
    assert np.linalg.eigvalsh(A.toarray()).min() < 0
    assert ch.counts["factorizations_ldlt"] == 1
    r = ld.residual()
    dx_ch, dx_ld = ch.solve(r), ld.solve(r)
    assert np.abs(dx_ch - dx_ld).max() <= 1e-8 * np.abs(dx_ld).max()
    # and back to the LLᵀ at a positive definite state
    ch.state.set_load(0.0)
    ch.x[:] = 0.0
    ch.factorize()
    assert ch.counts["factorizations_ldlt"] == 1 and ch.linear._use_llt


def test_auto_picks_cholmod_for_large_condensed_matrices(monkeypatch):
    assert pick_inverse("auto", True, False, 10**6) == "umfpack"  # the uncondensed exact saddle point
    assert pick_inverse("auto", False, False, 10**6) == "sparsecholesky"  # uncondensed mixed penalty
    assert pick_inverse("auto", False, True, CHOLMOD_MIN_DOFS - 1) == "sparsecholesky"
    assert pick_inverse("auto", False, True, CHOLMOD_MIN_DOFS) == "cholmod"
    assert pick_inverse("pardiso", False, True, 10) == "pardiso"
    monkeypatch.setattr(cholmod, "available", lambda: False)
    assert pick_inverse("auto", False, True, 10**6) == "sparsecholesky"


def test_cholmod_without_cvxopt_is_a_scene_error(monkeypatch, tmp_path):
    monkeypatch.setattr(cholmod, "available", lambda: False)
    for model in ("continuum", "discrete"):
        sc = _scene(**{"solver.linear_solver": "cholmod", "model": model})
        with pytest.raises(SceneError, match=r"needs cvxopt.*ngbet\[cholmod\]"):
            run(sc, tmp_path / model)
        assert not (tmp_path / model).exists()  # refused before anything is written


def test_the_default_scene_keeps_its_forces_with_the_llt(tmp_path):
    """The embedded scene to 56 mm with either factorization: the same steps and forces to 1e-9
    (measured: identical to 12 digits)."""
    forces = {}
    for ls in ("cholmod", "sparsecholesky"):
        sc = default_scene().with_changes(
            **{"solver.linear_solver": ls, "outputs.vtk": False, "outputs.plot": False, "outputs.error_estimate": "off"}
        )
        s = run(sc, tmp_path / ls)
        assert s["linear_solver"] == ls
        with open(tmp_path / ls / "results.csv") as f:
            forces[ls] = {float(r["u0_mm"]): float(r["force_N"]) for r in csv.DictReader(f)}
    assert forces["cholmod"].keys() == forces["sparsecholesky"].keys()
    for u0, f in forces["sparsecholesky"].items():
        assert forces["cholmod"][u0] == pytest.approx(f, rel=1e-9), u0
