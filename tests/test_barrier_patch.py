"""The jamming barrier in contact: Newton's tangent, and the barrier's elements solved first.

Without bending the clamp corners close onto the barrier at about 19.8 mm of the embedded scene.
There Newton's tangent is the derivative of the residual (checked against differences), yet its
full steps contract the residual only by 0.1–0.4 per iteration, the residual left on the unknowns
of the barrier's few elements alone; the local solve of those unknowns before each linearization
(:class:`ngbet.continuum.patch.BarrierPatch`) leaves one or two linearizations per increment, at
the same equilibria.
"""

import math

import ngsolve as ngs
import numpy as np
import pytest
from conftest import coarse

from ngbet.continuum.jamming import JAMMING_SET_MARGIN
from ngbet.numerics.chord import TANGENT_RTOL
from ngbet.scene.document import Scene

S_JAM = math.sin(math.radians(5.0))


def _sheared_first_gradient():
    """A coarse first-gradient problem (p = 2) sheared by 40° at one end and by 86°
    at the other (yarns 4° apart, past the 5° threshold), the barrier on the elements near."""
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.runner.settings import continuum_solver

    pb = ContinuumProblem(coarse(**{"discretization.mesh_size_mm": 20.0, "effects.bending": False}))
    m1, m2 = np.array(pb.scene.specimen.m1), np.array(pb.scene.specimen.m2)

    def grad(gamma_deg):
        b = math.radians(45.0 - gamma_deg / 2)
        a1, a2 = np.array([math.cos(b), math.sin(b)]), np.array([-math.cos(b), math.sin(b)])
        return np.column_stack([a1, a2]) @ np.linalg.inv(np.column_stack([m1, m2])) - np.eye(2)

    xs = [v.point[0] for v in pb.mesh.vertices]
    xi = (ngs.x - min(xs)) / (max(xs) - min(xs))
    G = [(1 - xi) * a + xi * b for a, b in zip(grad(40.0).ravel(), grad(86.0).ravel(), strict=True)]
    pb.u.Set(ngs.CF((G[0] * ngs.x + G[1] * ngs.y, G[2] * ngs.x + G[3] * ngs.y)))
    solver = continuum_solver(pb)
    pb.converged()  # the watch puts the barrier on the elements near
    assert 0 < pb.jamming.elements.NumSet() < pb.mesh.ne and solver.patch is not None
    assert pb.jamming.patch is not None and np.array_equal(
        pb.jamming.patch, pb.jamming._smallest() < JAMMING_SET_MARGIN * S_JAM
    )
    return solver


def test_the_newton_step_solves_the_linearized_residual_with_the_barrier_in_contact():
    """At the sheared state the barrier's energy holds the yarns that close past the threshold: the
    Newton step dx = −J⁻¹ r (the condensed matrix of the energy form with the barrier's integrator on
    the elements near) satisfies J dx = −r with J by central differences of the residual along dx,
    to the differences' own error (O(ε²): 4e-6 at ε = 1e-4, 4e-8 at 1e-5 measured, with the barrier's
    share of J dx 7e-3 of r)."""
    solver = _sheared_first_gradient()
    free = ~solver.dirichlet
    r = solver.residual()
    solver.factorize()
    dx = solver.solve(r)
    x0 = solver.x.copy()
    errors = []
    for eps in (1e-4, 1e-5):
        solver.x[:] = x0 + eps * dx
        rp = solver.residual()
        solver.x[:] = x0 - eps * dx
        rm = solver.residual()
        solver.x[:] = x0
        Jdx = (rp - rm) / (2 * eps)
        errors.append(np.linalg.norm((Jdx + r)[free]) / np.linalg.norm(r[free]))
    assert errors[1] < 1e-6 and errors[1] < 0.05 * errors[0]


def test_the_local_solve_zeroes_the_residual_on_the_barriers_unknowns_and_holds_the_rest():
    """The patch's residual is the global one on its rows (to round-off); settling drives it below the
    tolerance on those rows, leaves every other entry of the state as it was and brings the global
    residual handed to it along to the state settled (to round-off)."""
    solver = _sheared_first_gradient()
    patch = solver.patch
    assert patch is not None
    x0 = solver.x.copy()
    r0 = solver.residual()
    r = r0.copy()
    assert solver.settle(1e-12, r) > 0
    rows = patch.rows
    assert rows.size > 0 and not np.any(solver.dirichlet[rows])
    local = patch.residual()
    r1 = solver.residual()
    assert np.max(np.abs(local[rows] - r1[rows])) <= 1e-10 * np.max(np.abs(r1))
    assert np.max(np.abs(r - r1)) <= 1e-10 * np.max(np.abs(r0))  # the residual brought along
    assert np.linalg.norm(r1[rows]) < 1e-6 * np.linalg.norm(r0[rows])
    others = np.ones(x0.size, bool)
    others[rows] = False
    assert np.array_equal(solver.x[others], x0[others])


def _first_gradient_to(u0_mm: float, local: bool):
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.numerics.engine import Steps
    from ngbet.runner.continuum import load_path
    from ngbet.runner.settings import continuum_solver

    scene = Scene().with_changes(**{"effects.bending": False, "loading.u0_mm": u0_mm})
    solver = continuum_solver(ContinuumProblem(scene))
    if not local:
        solver.patch = None
    steps = Steps(load_path(solver, scene))
    rows, made = {}, {}  # the step records and the factorizations made up to each, by load [mm]
    for rec in steps:
        rows[round(rec.u0 * 1e3, 9)] = rec
        made[round(rec.u0 * 1e3, 9)] = solver.counts["factorizations"]
    assert steps.result is not None and steps.result.u0 == pytest.approx(u0_mm * 1e-3)
    return rows, np.diff([made[u] for u in sorted(made)], prepend=0), solver


def test_after_the_corner_closes_each_increment_takes_one_or_two_linearizations():
    """The embedded scene without bending to 28 mm: past the snap (19.8 mm) every increment solved by
    Newton converges in at most two iterations with the barrier's unknowns solved first, and from
    22.5 mm on no increment takes more than three factorizations (Newton's, a chord row's
    refactorization, a tangent's); without, Newton takes 3 to 7 iterations from 24 to 28 mm, as
    many factorizations and one more. The equilibria are the same: the forces of the rows both paths
    have agree to 1e-7. Their dF/du0 agree to TANGENT_RTOL (1e-3): a chord row's tangent is refined
    to that (2.9e-4 off the tangent of a linearization at the state at 26 mm), a Newton row's is that
    of the factorization at hand, refined where the local solves moved the state since (2e-8 off at
    28 mm), without them that of Newton's last iterate (up to 2.5e-4 off at 19 mm)."""
    rows, made, solver = _first_gradient_to(28.0, local=True)
    plain, plain_made, plain_solver = _first_gradient_to(28.0, local=False)
    assert solver.patch is not None and solver.patch.iterations > 0
    newton_rows = [rec for u, rec in rows.items() if u > 20.5 and "chord" not in rec.reason]
    assert newton_rows and max(rec.iterations for rec in newton_rows) <= 2
    late = np.array(sorted(rows)) > 22.5
    assert late.any() and made[late].max() <= 3
    assert max(rec.iterations for u, rec in plain.items() if u > 23.5) >= 3
    assert plain_made[np.array(sorted(plain)) > 22.5].max() >= 5
    psi = solver.problem.psi_u.vec.FV().NumPy()
    common = sorted(set(rows) & set(plain))
    assert len(common) >= 15
    for u in common:
        a, b = rows[u], plain[u]
        Ra, Rb = float(psi @ a.residual), float(psi @ b.residual)
        assert Ra == pytest.approx(Rb, rel=1e-7, abs=1e-9)
        assert a.dforce_du0 == pytest.approx(b.dforce_du0, rel=TANGENT_RTOL)
    assert solver.counts["factorizations"] < plain_solver.counts["factorizations"]
    # the last row's dF/du0 against the tangent of a linearization at its state
    solver.factorize()
    exact = solver.load_derivative(psi, solver.load_tangent(1.0))
    assert rows[max(rows)].dforce_du0 == pytest.approx(exact, rel=1e-6)
