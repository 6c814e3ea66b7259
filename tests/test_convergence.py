"""The continuum's finite elements converge at the rate of their order: a manufactured solution.

The first-gradient model (``effects.bending = false``: only u, the energy of
:class:`~ngbet.continuum.problem.ContinuumProblem`, elongation and shear of the two yarn families
at ±45°) on the paper's specimen, with a manufactured solution u*: a biaxial stretch of 10 %
with a smooth perturbation of 0.5 mm, so that both yarn families are in tension everywhere (a
yarn in compression makes (√i4 − 1)² non-convex: no unique discrete solution, no rate). The load
that makes u* the solution is l(v) = ∫ P(∇u*) : ∇v dx with P = ∂W/∂F (NGSolve's symbolic
derivative of the problem's own energy density): a body force and the tractions on the free edges.
u = u* on the clamps. Newton from the interpolant of u* solves the problem to round-off.

For a smooth solution the error of P_p elements is O(h^p) in the H1 seminorm and O(h^{p+1}) in L2
(Céa, Aubin–Nitsche). Measured on the structured meshes of 10 and 5 mm: H1 rates 2.03 (p = 2) and
3.00 (p = 3), L2 rates 3.00 and 4.01; asserted within 0.15 of the theory.
"""

from __future__ import annotations

import math

import ngsolve as ngs
import pytest
from ngsolve import x, y

from ngbet.continuum import physics
from ngbet.continuum.problem import ContinuumProblem
from ngbet.scene.document import default_scene

#: the margin of an observed rate around the theoretical one
RATE_MARGIN = 0.15


def manufactured_errors(h_mm: float, p: int) -> tuple[float, float, float]:
    """(h, L2 error, H1 seminorm error) [m] of the first-gradient problem with the manufactured solution."""
    sc = default_scene().with_changes(
        **{
            "effects.bending": False,
            "discretization.mesh_size_mm": h_mm,
            "discretization.corner_mesh_size_mm": 0.0,
            "discretization.structured": True,
            "discretization.order_u": p,
            "outputs.vtk": False,
        }
    )
    pb = ContinuumProblem(sc)
    L, W = sc.specimen.length_mm * 1e-3, sc.specimen.width_mm * 1e-3
    A, eps = 0.5e-3, 0.1
    exact = ngs.CF((eps * x + A * ngs.sin(3 * x / L + y / W), eps * y + A * ngs.cos(2 * y / W - x / L)))
    G = ngs.CF((exact[0].Diff(x), exact[0].Diff(y), exact[1].Diff(x), exact[1].Diff(y)), dims=(2, 2))
    inv = physics.invariants(G, pb.m1, pb.m2)
    par = pb.parameters
    W_exact = physics.elongation_energy(inv.i4, inv.i6, par["K_el"]) + physics.shear_law_energy(
        inv.i8, sc.effects.shear_law, {**vars(sc.material), **par}
    )
    assert len(pb.energy_parts) == 1  # only u: the energy density is W(∇u)
    u = pb.X.TrialFunction()[0]
    a = ngs.BilinearForm(pb.X)
    a += ngs.Variation((pb.energy_parts[0] - ngs.InnerProduct(W_exact.Diff(G), ngs.Grad(u))) * pb.dx)
    gf = ngs.GridFunction(pb.X)
    uh = gf.components[0]
    uh.Set(exact)  # the clamps keep these values; the rest is a start inside Newton's range
    r, du = gf.vec.CreateVector(), gf.vec.CreateVector()
    for _ in range(8):
        a.AssembleLinearization(gf.vec)
        a.Apply(gf.vec, r)
        du.data = a.mat.Inverse(pb.X.FreeDofs(), inverse="sparsecholesky") * r
        gf.vec.data -= du
        if du.Norm() < 1e-13 * gf.vec.Norm():
            break
    else:
        pytest.fail(f"Newton did not converge at h = {h_mm} mm, p = {p}")
    e, ge = uh - exact, ngs.Grad(uh) - G
    l2 = math.sqrt(ngs.Integrate(ngs.InnerProduct(e, e), pb.mesh, order=2 * p + 4))
    h1 = math.sqrt(ngs.Integrate(ngs.InnerProduct(ge, ge), pb.mesh, order=2 * p + 4))
    return math.sqrt(L * W / pb.mesh.ne), l2, h1


@pytest.mark.parametrize("p", [2, 3])
def test_manufactured_solution_converges_at_the_rate_of_the_element_order(p):
    (h1_, l2_1, s1), (h2_, l2_2, s2) = manufactured_errors(10.0, p), manufactured_errors(5.0, p)
    assert h2_ == pytest.approx(h1_ / 2, rel=0.05)  # the structured mesh halves
    rate = math.log(h1_ / h2_)
    assert math.log(s1 / s2) / rate == pytest.approx(p, abs=RATE_MARGIN)
    assert math.log(l2_1 / l2_2) / rate == pytest.approx(p + 1, abs=RATE_MARGIN)
