"""The Newton matrix's storage: the lower triangle for the sparse LDLᵀ, the same matrix as in full."""

import ngsolve as ngs
import numpy as np
import scipy.sparse as sps

from ngbet.continuum.mesh import corner_refined
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics.linear import NewtonLinearSolver
from ngbet.runner.settings import continuum_solver
from ngbet.scene.document import default_scene


def _scene(**changes):
    return default_scene().with_changes(
        **{"discretization.mesh_size_mm": 20.0, "solver.compile": "interpret", **changes}
    )


def _solver(scene, mesh=None) -> ContinuumSolver:
    return continuum_solver(ContinuumProblem(scene, mesh=mesh))


def _perturb(pr: ContinuumSolver, seed: int) -> None:
    pr.state.set_load(0.02)
    free = pr.problem.free_all
    pr.x[free] += 1e-4 * np.random.default_rng(seed).standard_normal(int(free.sum()))


def _stored(pr: ContinuumSolver) -> sps.csr_matrix:
    vals, cols, ptr = pr.linear.mat.CSR()
    n = pr.linear.mat.height
    return sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(n, n))


def test_the_lower_triangle_is_the_full_newton_matrix():
    """The condensed Newton matrix for the sparse LDLᵀ is stored as its lower triangle; with
    UMFPACK (full storage) the same element matrices are added: the same free block, entry by
    entry, and the same correction (to the round-off the augmented matrix amplifies)."""
    lower = _solver(_scene())
    full = _solver(_scene(**{"solver.linear_solver": "umfpack"}))
    for pr in (lower, full):
        _perturb(pr, 0)
        pr.factorize()
    assert (lower.linear.inverse_type, full.linear.inverse_type) == ("sparsecholesky", "umfpack")
    stored = _stored(lower)
    assert sps.triu(stored, 1).nnz == 0
    assert stored.nnz < 0.52 * _stored(full).nnz  # half the off-diagonal entries
    A_lower, _ = lower.linear.free_matrix()
    A_full, _ = full.linear.free_matrix()
    assert abs(A_lower - A_full).max() <= 1e-15 * abs(A_full).max()
    r = lower.residual()
    dx_lower, dx_full = lower.solve(r), full.solve(r)
    assert np.abs(dx_lower - dx_full).max() <= 1e-8 * np.abs(dx_full).max()


def test_a_refined_mesh_keeps_the_full_matrix():
    """On a mesh with levels (corner refinement, as the error estimate uses) the Newton matrix is
    stored in full, one matrix for every linearization (its factorization is updated)."""
    sc = _scene()
    pr = _solver(sc, mesh=corner_refined(ContinuumProblem(sc).mesh, sc.specimen, 2))
    _perturb(pr, 0)
    pr.factorize()
    first = pr.linear.mat
    pr.factorize()
    assert pr.linear.mat is first
    assert sps.triu(_stored(pr), 1).nnz > 0


def test_a_new_matrix_is_factorized_anew():
    """A form stored as its lower triangle on a refined mesh gets a new matrix at each assembly
    until it holds one per mesh level (NGSolve): the second linearization's correction is the
    one of a fresh factorization of that state, not an update of the first matrix's."""
    sc = _scene()
    pr = _solver(sc, mesh=corner_refined(ContinuumProblem(sc).mesh, sc.specimen, 2))
    form = ngs.BilinearForm(pr.problem.X, symmetric=True, symmetric_storage=True, condense=True)
    for integrator in pr.linear.form.integrators:
        form += integrator
    pr.linear = NewtonLinearSolver(form, condense=True, choice="sparsecholesky")
    _perturb(pr, 0)
    pr.factorize()
    first = pr.linear.mat
    r = pr.residual()
    _perturb(pr, 1)
    pr.factorize()
    assert pr.linear.mat is not first
    second = pr.solve(r)
    pr.linear = NewtonLinearSolver(form, condense=True, choice="sparsecholesky")  # fresh, at the same state
    pr.factorize()
    expected = pr.solve(r)
    assert np.abs(second - expected).max() <= 1e-8 * np.abs(expected).max()
