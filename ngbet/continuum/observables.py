"""Observables of a converged state: reactions, energy, mid-axis profile, fields.

Reactions by the paper's volume-integral method (docs/model.md, *Reactions*): the residual of the full
Lagrangian tested with ψ_u = (X/L, 0) gives the force R per unit thickness [N/m] on the moving
clamp; with ψ_φ = X/L it gives the double force T per unit thickness [N m/m = N]. At equilibrium
only the Dirichlet rows of the residual are non-zero, and ψ is 1 on Σ2 and 0 on Σ1, so
R = Σ_{d ∈ Σ2} r_d ψ_d: the same number as any other test field with those traces.
"""

from __future__ import annotations

import math
from typing import Any

import ngsolve as ngs
import numpy as np

from . import physics
from .problem import ContinuumProblem


def reaction_force(problem: ContinuumProblem, r: np.ndarray) -> float:
    """R = r·ψ_u [N/m]: reaction force per unit thickness on Σ2 along e1."""
    return float(r @ problem.psi_u.vec.FV().NumPy())


def reaction_double_force(problem: ContinuumProblem, r: np.ndarray) -> float:
    """T = r·ψ_φ [N m/m]: reaction double force per unit thickness on Σ2."""
    assert problem.psi_phi is not None
    return float(r @ problem.psi_phi.vec.FV().NumPy())


def midaxis_profile(problem: ContinuumProblem, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertical displacement u_y on the mid-axis Y = W/2 at n equispaced X [m]."""
    sp = problem.scene.specimen
    X = np.linspace(0.0, sp.L, n)
    pts = problem.mesh(X, np.full(n, 0.5 * sp.W))
    uy = problem.u(pts)[:, 1]
    return X, np.asarray(uy)


def centre_shear_angle_deg(problem: ContinuumProblem) -> float:
    """γ at the specimen centre [deg] (zone A of ideal BET kinematics)."""
    sp = problem.scene.specimen
    inv = problem.invariants()
    g = physics.shear_angle(inv.i4, inv.i6, inv.i8, sp.cos0)
    return math.degrees(float(g(problem.mesh(0.5 * sp.L, 0.5 * sp.W))))


def constraint_l2(problem: ContinuumProblem) -> float:
    """‖φ − i8‖_L2 / √|B|: the RMS violation of the constraint (dimensionless)."""
    inv = problem.invariants()
    sp = problem.scene.specimen
    v = ngs.Integrate((problem.phi - inv.i8) ** 2, problem.mesh, order=2 * problem.scene.discretization.p_u)
    return math.sqrt(max(v, 0.0) / (sp.L * sp.W))


def multiplier_oscillation(problem: ContinuumProblem, margin: float = 0.18) -> float | None:
    """‖Λ − Π Λ‖ / ‖Λ‖ on margin·L < X < (1 − margin)·L, Π the L2 projection onto continuous
    fields of Λ's order (``problem.p_lam``, at least 1); None without a multiplier.

    A multiplier that converges is smooth away from the clamp corners, and this ratio falls with
    h; an unstable pair leaves O(1) element-to-element oscillations (ratio ~0.85, not falling).
    """
    lam = problem.lam_field
    if lam is None:
        return None
    mesh, L = problem.mesh, problem.scene.specimen.L
    V = ngs.H1(mesh, order=max(1, problem.p_lam))
    w, v = V.TnT()
    mass = ngs.BilinearForm(w * v * ngs.dx).Assemble()
    rhs = ngs.LinearForm(lam * v * ngs.dx).Assemble()
    proj = ngs.GridFunction(V)
    proj.vec.data = mass.mat.Inverse(inverse="sparsecholesky") * rhs.vec
    inner = ngs.IfPos((ngs.x - margin * L) * ((1 - margin) * L - ngs.x), 1.0, 0.0)
    order = 2 * max(1, problem.p_lam)
    norm = ngs.Integrate(inner * lam * lam, mesh, order=order)
    if norm <= 0:
        return 0.0
    return math.sqrt(max(ngs.Integrate(inner * (lam - proj) ** 2, mesh, order=order), 0.0) / norm)


def ellipticity_loss_area(problem: ContinuumProblem, family: int) -> tuple[float, float]:
    """Where the model has no second-gradient regularization across yarn family ``family``.

    With α_k = 0 (k = ``family``, 1 or 2) the bending energy does not see variations of φ = i8
    along m_k; a band mode δu = a f(X·n) with n ⊥ m_j (j the other family) changes F m_k only, and
    costs (n·m_k)² a·H a f'² with H = ∂²W/∂(F m_k)² of the first-gradient energy:

        H = K_el [v̂ v̂ + (1 − 1/|v|)(I − v̂ v̂)] + K_sh w w,   v = F m_k, w = F m_j.

    Where H is not positive definite (yarns of family k compressed, |v| < 1, by more than about
    K_sh/K_el) the continuum loses ellipticity: nothing bounds how fine such bands get, and the
    discrete answer depends on the mesh. Returns (area [mm²] where λ_min(H) < 0, min λ(H)/K_sh).
    """
    m = problem.scene.material
    F = problem.invariants().F
    mk, mj = (problem.m1, problem.m2) if family == 1 else (problem.m2, problem.m1)
    v, w = F * mk, F * mj
    nv = ngs.sqrt(ngs.InnerProduct(v, v))
    vh = v / nv
    t = ngs.CF((-vh[1], vh[0]))
    wv, wt = ngs.InnerProduct(w, vh), ngs.InnerProduct(w, t)
    a = m.K_el + m.K_sh * wv * wv
    b = m.K_sh * wv * wt
    c = m.K_el * (1 - 1 / nv) + m.K_sh * wt * wt
    lmin = 0.5 * (a + c) - ngs.sqrt(0.25 * (a - c) ** 2 + b * b)
    area = ngs.Integrate(ngs.IfPos(-lmin, 1.0, 0.0), problem.mesh)
    return float(area * 1e6), min_at_points(lmin / max(m.K_sh, 1e-300), problem)


def min_at_points(cf: Any, problem: ContinuumProblem) -> float:
    """The smallest value of a scalar CF over the integration points of order 2p of all elements."""
    mesh = problem.mesh
    ir = ngs.IntegrationRule(ngs.TRIG, 2 * problem.scene.discretization.p_u)
    pts = mesh.MapToAllElements(ir, ngs.VOL)
    return float(np.min(cf(pts)))


def field_functions(problem: ContinuumProblem, wanted: tuple[str, ...]) -> dict[str, Any]:
    """CoefficientFunctions of the requested fields, for VTK output and maps."""
    inv = problem.invariants()
    out: dict[str, Any] = {"displacement": problem.u}
    if "shear_angle" in wanted:
        gamma = physics.shear_angle(inv.i4, inv.i6, inv.i8, problem.scene.specimen.cos0)
        out["shear_angle_deg"] = gamma * (180.0 / math.pi)  # the change of the angle between the yarns
    if "elongation" in wanted:
        out["elongation_1"] = ngs.sqrt(inv.i4) - 1
        out["elongation_2"] = ngs.sqrt(inv.i6) - 1
    if "constraint" in wanted and problem.phi is not None:
        out["phi"] = problem.phi
        out["phi_minus_i8"] = problem.phi - inv.i8
        if problem.lam_field is not None:
            out["Lambda"] = problem.lam_field
    return out
