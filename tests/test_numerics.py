"""The continuum problem apart from its solver (ngbet.continuum.solver): one translation of the
scene's linear algebra, reused by the error estimate's enriched problems and the path spread's copies."""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from conftest import capabilities, carry, coarse

from ngbet.continuum.estimate import ForceErrorEstimator
from ngbet.continuum.path_spread import RunPathSpread
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics.settings import LinearSettings
from ngbet.runner.settings import continuum_solver, linear_settings, newton_settings, solver_settings


def _scene(**changes):
    return coarse(**{"discretization.mesh_size_mm": 20.0, "solver.compile": "interpret", **changes})


def test_the_scene_is_translated_once_into_frozen_settings():
    sc = _scene(**{"solver.linear_solver": "umfpack", "solver.condense": False})
    s = linear_settings(sc)
    assert s == LinearSettings(linear_solver="umfpack", condense=False, compile="interpret")
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.condense = True  # type: ignore[misc]
    assert continuum_solver(ContinuumProblem(sc)).settings.linear == s


def test_a_continuum_run_does_not_import_the_networks_sparse_solvers():
    # scipy.sparse.linalg is the network's (its step control lives beside its solver); importing it
    # costs a continuum run about 0.2 s of CPU for nothing
    code = (
        "import sys, ngbet.cli, ngbet.run, ngbet.runner.continuum, ngbet.runner.settings; "
        "print('scipy.sparse.linalg' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_a_network_run_imports_scipys_sparse_solvers_only_for_their_fallbacks():
    # the network factorizes with CHOLMOD or NGSolve; scipy.sparse.linalg (ARPACK, SuperLU) serves
    # the stability check's fallback and the "splu" backend alone, and costs about 0.1 s to import
    code = "import sys, ngbet.cli, ngbet.run, ngbet.runner.discrete; print('scipy.sparse.linalg' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_the_solver_counts_what_it_does_and_the_problem_nothing():
    """A new solver has assembled nothing; one residual and one factorization are counted as such,
    with the summary's keys (timers in seconds, never negative)."""
    solver = continuum_solver(ContinuumProblem(_scene()))
    assert solver.counts == {"factorizations": 0, "solves": 0, "residuals": 0}
    solver.state.set_load(0.01)
    r = solver.residual()
    solver.factorize()
    solver.solve(r)
    assert solver.counts == {"factorizations": 1, "solves": 1, "residuals": 1}
    assert list(solver.timers) == ["assembly_s", "factorization_s", "solve_s", "residual_s"]
    assert min(solver.timers.values()) >= 0.0
    assert not hasattr(solver.problem, "factorize") and not hasattr(solver.problem, "timers")
    dofs = solver.ndofs()
    assert dofs["total"] == solver.problem.X.ndof and 0 < dofs["factorized"] < dofs["total"]  # Λ condensed


def test_the_enriched_problems_and_branch_copies_get_solvers_of_the_runs_settings():
    """Settings other than the scene's (UMFPACK where the scene asks for the sparse LDLᵀ) reach the
    p + 1 and p + 2 problems of the error estimate and the path spread's copy unchanged: no second
    translation of the scene. The estimate is that of the run with the scene's own settings, since
    both inverses solve the same systems (to the round-off the augmented matrix amplifies)."""
    sc = _scene(**{"loading.u0_mm": 10.0})
    mine = dataclasses.replace(
        solver_settings(sc), linear=LinearSettings(linear_solver="umfpack", condense=True, compile="interpret")
    )
    forces = []
    for settings in (mine, solver_settings(sc)):
        solver = ContinuumSolver(ContinuumProblem(sc), settings)
        res = carry(solver, 0.01, 0.005, newton_settings(sc), **capabilities(solver))
        est = ForceErrorEstimator(solver)
        F = float(solver.problem.psi_u.vec.FV().NumPy() @ res.steps[-1].residual) * sc.specimen.t
        forces.append((F, est.estimate(0.01, F).force_enriched_N))
        if settings is mine:
            enriched = [est._enriched, est._enriched2]
            assert [e.settings for e in enriched] == [mine, mine]
            assert [e.linear.inverse_type for e in enriched] == ["umfpack", "umfpack"]
            assert [e.problem.scene.discretization.p_u for e in enriched] == [3, 4]
            spread = RunPathSpread(solver)
            spread.left(0.005, solver.x, snap=True)
            copy = spread._copy()
            assert copy.settings is mine and copy.problem is not solver.problem
            assert copy.problem.mesh is solver.problem.mesh
    assert np.allclose(forces[0], forces[1], rtol=1e-8, atol=0.0)
