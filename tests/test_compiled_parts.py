"""The energy in parts (one integrator each): the tangent, residual and energy of the whole."""

import ngsolve as ngs
import numpy as np
import pytest
import scipy.sparse as sps

from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.numerics import compiled
from ngbet.runner.settings import continuum_solver
from ngbet.scene.document import default_scene


def _problem(p: int) -> ContinuumSolver:
    pr = continuum_solver(
        ContinuumProblem(
            default_scene().with_changes(
                **{
                    "discretization.mesh_size_mm": 20.0,
                    "discretization.order_u": p,
                    "solver.compile": "interpret",
                    # the parts of the energy alone (the jamming
                    # barrier is an integrator of its own)
                    "effects.jamming": False,
                }
            )
        )
    )
    pr.state.set_load(0.02)
    free = pr.problem.free_all
    pr.x[free] += 1e-4 * np.random.default_rng(0).standard_normal(int(free.sum()))
    return pr


def _whole(pr: ContinuumSolver, parts, condense: bool) -> ngs.BilinearForm:
    """The sum of the parts as one integrand (one integrator), stored in full."""
    form = ngs.BilinearForm(pr.problem.X, symmetric=True, condense=condense)
    compiled.add_energy(form, sum(parts[1:], parts[0]), pr.problem.dx, "interpret")
    return form


@pytest.mark.parametrize("p", [2, 3])
def test_the_energy_in_parts_is_the_whole_energy(p):
    """The bending energy is an integrator of its own, integrated by a rule of lower order than
    the rest (NGSolve's choice for an integrand in ∇φ alone), exactly on affine triangles: the
    energy, residual and uncondensed Hessian of the parts are those of their sum as one
    integrand to round-off, and so is the condensed Newton matrix of the augmented energy."""
    pr = _problem(p)
    parts, saddle = pr.problem.energy_parts, pr.problem.augmented_energy
    assert len(parts) == 2 and len(list(pr.a.integrators)) == 2
    assert len(list(pr.linear.form.integrators)) == 2
    whole = _whole(pr, parts, condense=False)
    vec = pr.problem.gf.vec
    assert pr.energy() == pytest.approx(whole.Energy(vec), rel=1e-13)
    r = vec.CreateVector()
    whole.Apply(vec, r)
    assert np.abs(pr.residual() - r.FV().NumPy()).max() <= 1e-13 * np.abs(r.FV().NumPy()).max()
    for mine, theirs in ((pr.a, whole), (pr.linear.form, _whole(pr, saddle(pr.linear.K_aug), condense=True))):
        mine.AssembleLinearization(vec)
        theirs.AssembleLinearization(vec)
        fd = np.flatnonzero(np.array(list(pr.problem.X.FreeDofs(mine.condense)), dtype=bool))
        A, B = _full(mine.mat)[fd][:, fd], _full(theirs.mat)[fd][:, fd]
        assert abs(A - B).max() <= 1e-13 * abs(B).max()


def _full(mat: ngs.BaseMatrix) -> sps.csr_matrix:
    """A sparse matrix in full (a stored lower triangle mirrored)."""
    vals, cols, ptr = mat.CSR()
    A = sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(mat.height, mat.height))
    return (A + sps.tril(A, -1).T).tocsr() if sps.triu(A, 1).nnz == 0 else A


def test_parts_are_native_throughout_or_interpreted(monkeypatch):
    """A part whose native code cannot be had ("auto" and not in the cache) leaves every part
    interpreted: the form reports one mode, and has an integrator per part."""
    mesh = ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=0.5))
    fes = ngs.H1(mesh, order=2)
    u = fes.TrialFunction()
    parts = [u * u, ngs.Grad(u) * ngs.Grad(u)]
    seen = []

    def first_native(cf, mode, ndof=0):
        seen.append(mode)
        return cf.Compile(), "native" if len(seen) == 1 else "interpret"

    monkeypatch.setattr(compiled, "compile_energy", first_native)
    form = ngs.BilinearForm(fes, symmetric=True)
    assert compiled.add_energy(form, parts, ngs.dx, "auto", 10**6) == "interpret"
    assert seen == ["auto", "auto"] and len(list(form.integrators)) == 2
    g = ngs.GridFunction(fes)
    g.Set(ngs.x)
    assert form.Energy(g.vec) == pytest.approx(1 / 3 + 1, rel=1e-12)  # ∫ x² + |∇x|² over the unit square
