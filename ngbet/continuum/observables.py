"""Observables of a converged state: reactions, energy, mid-axis profile, fields.

Reactions by the paper's volume-integral method (docs/model.md, *Reactions*): the residual of the full
Lagrangian tested with ψ_u = (X/L, 0) gives the force R per unit thickness [N/m] on the moving
clamp; with ψ_φ = X/L it gives the double force T per unit thickness [N m/m = N]. At equilibrium
only the Dirichlet rows of the residual are non-zero, and ψ is 1 on Σ2 and 0 on Σ1, so
R = Σ_{d ∈ Σ2} r_d ψ_d: the same number as any other test field with those traces.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import ngsolve as ngs
import numpy as np

from . import physics

if TYPE_CHECKING:  # for the annotations only: the problem's diagnosis uses these observables
    from .problem import ContinuumProblem

__all__ = [
    "ZoneShearMeans",
    "centre_shear_angle_deg",
    "constraint_l2",
    "ellipticity_loss_area",
    "field_functions",
    "map_samples",
    "midaxis_profile",
    "min_at_points",
    "multiplier_oscillation",
    "reaction_double_force",
    "reaction_force",
    "zone_indicators",
]


def reaction_force(problem: ContinuumProblem, r: np.ndarray) -> float:
    """R = r·ψ_u [N/m]: reaction force per unit thickness on Σ2 along e1."""
    return float(r @ problem.psi_u.vec.FV().NumPy())


def reaction_double_force(problem: ContinuumProblem, r: np.ndarray) -> float:
    """T = r·ψ_φ [N m/m]: reaction double force per unit thickness on Σ2."""
    assert problem.psi_phi is not None
    return float(r @ problem.psi_phi.vec.FV().NumPy())


def midaxis_profile(problem: ContinuumProblem, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertical displacement u_y on the mid-axis Y = W/2 at n equispaced X [m].

    The picture frame: on its loading diagonal Y = 0, across the fabric between the cut corners.
    """
    sp = problem.scene.specimen
    if problem.frame:
        c = math.sqrt(2.0) * problem.scene.picture_frame.arm_mm * 1e-3
        X = np.linspace(c, problem.length - c, n)
        pts = problem.mesh(X, np.zeros(n))
        return X, np.asarray(problem.u(pts)[:, 1])
    X = np.linspace(0.0, sp.L, n)
    pts = problem.mesh(X, np.full(n, 0.5 * sp.W))
    uy = problem.u(pts)[:, 1]
    return X, np.asarray(uy)


def centre_shear_angle_deg(problem: ContinuumProblem) -> float:
    """γ at the specimen centre [deg] (zone A of ideal BET kinematics; the picture frame's centre)."""
    sp = problem.scene.specimen
    inv = problem.invariants()
    g = physics.shear_angle(inv.i4, inv.i6, inv.i8, sp.cos0)
    centre = (0.5 * problem.length, 0.0) if problem.frame else (0.5 * sp.L, 0.5 * sp.W)
    return math.degrees(float(g(problem.mesh(*centre))))


def zone_indicators(problem: ContinuumProblem) -> tuple[Any, Any, Any]:
    """Indicator CoefficientFunctions of the ideal zones A, B, C on the reference configuration.

    The rule of :func:`ngbet.kinematics.zone_index`: a point's yarn of family k is held when it
    ends on a clamp; A holds neither, B one, C both.
    """
    sp = problem.scene.specimen
    L, W, t = sp.L, sp.W, math.tan(math.radians(sp.yarn_angle_deg))
    X, Y = ngs.x, ngs.y

    def either(a: Any, b: Any) -> Any:  # 1 where a > 0 or b > 0 (the borders have no area)
        return ngs.IfPos(a, 1.0, ngs.IfPos(b, 1.0, 0.0))

    held_1 = either(Y - X * t, W - Y - (L - X) * t)
    held_2 = either(W - Y - X * t, Y - (L - X) * t)
    return (1 - held_1) * (1 - held_2), held_1 + held_2 - 2 * held_1 * held_2, held_1 * held_2


class ZoneShearMeans:
    """Mean shear angle γ [deg] over each ideal zone (A, B, C), integrated on the reference configuration.

    ∫_Z γ dX / ∫_Z dX with the indicators of :func:`zone_indicators`. The zone borders cut the
    elements, so the quadrature is of a high order (2 p_u + 6: the zone areas within 0.5 %) and
    the area is integrated with the same rule (the mean of a constant is exact). The points, their
    weights and the indicators are set up once per mesh; each call evaluates γ there (a few ms
    on the default mesh, where ``ngs.Integrate`` of the same integrands takes ten times longer).
    """

    def __init__(self, problem: ContinuumProblem) -> None:
        self.problem = problem
        ir = ngs.IntegrationRule(ngs.TRIG, 2 * problem.scene.discretization.p_u + 6)
        mesh = problem.mesh
        self.points = mesh.MapToAllElements(ir, ngs.VOL)
        ref_w = np.array([ip.weight for ip in ir])
        # |det J| of each element by the same rule: ∫ 1 over the element = Σ w |det J| (affine elements)
        area = np.array([ngs.Integrate(ngs.CF(1.0), mesh, order=0, element_wise=True)]).ravel()
        w = (area[:, None] * ref_w[None, :] / ref_w.sum()).ravel()
        ind = np.asarray(ngs.CF(tuple(zone_indicators(problem)))(self.points)).reshape(-1, 3)
        self.weights = ind * w[:, None]  # (points, zones)
        self.areas = self.weights.sum(axis=0)
        sp = problem.scene.specimen
        inv = problem.invariants()
        self.gamma = physics.shear_angle(inv.i4, inv.i6, inv.i8, sp.cos0).Compile()

    def __call__(self) -> dict[str, float]:
        """{"A": mean γ_A, "B": mean γ_B, "C": mean γ_C} [deg] of the current state (nan: an empty zone)."""
        g = np.asarray(self.gamma(self.points)).ravel()
        sums = g @ self.weights
        return {
            z: (math.degrees(sums[i] / self.areas[i]) if self.areas[i] > 0 else math.nan) for i, z in enumerate("ABC")
        }


def map_samples(problem: ContinuumProblem, subdivision: int) -> dict[str, np.ndarray]:
    """The shear angle and the displacement on a lattice of each element, for a triangulated map.

    Each element is split into ``subdivision``² triangles of its reference lattice (its own
    vertices: the shear angle may jump between elements). Returns, in mm and degrees,
    ``X_mm``, ``Y_mm`` (reference positions), ``ux_mm``, ``uy_mm`` and ``gamma_deg`` per point and
    ``triangles`` (indices into them).
    """
    n = max(1, subdivision)
    lattice = [(i / n, j / n) for j in range(n + 1) for i in range(n + 1 - j)]
    index = {p: k for k, p in enumerate(lattice)}
    local = []
    for j in range(n):
        for i in range(n - j):
            a, b, c = index[(i / n, j / n)], index[((i + 1) / n, j / n)], index[(i / n, (j + 1) / n)]
            local.append((a, b, c))
            if i + j < n - 1:
                local.append((b, index[((i + 1) / n, (j + 1) / n)], c))
    ir = ngs.IntegrationRule(points=lattice, weights=[0.0] * len(lattice))
    pts = problem.mesh.MapToAllElements(ir, ngs.VOL)
    inv = problem.invariants()
    g = physics.shear_angle(inv.i4, inv.i6, inv.i8, problem.scene.specimen.cos0)
    vals = np.asarray(ngs.CF((ngs.x, ngs.y, problem.u[0], problem.u[1], g))(pts)).reshape(-1, 5)
    ne = len(vals) // len(lattice)
    tri = (np.asarray(local)[None, :, :] + len(lattice) * np.arange(ne)[:, None, None]).reshape(-1, 3)
    return {
        "X_mm": vals[:, 0] * 1e3,
        "Y_mm": vals[:, 1] * 1e3,
        "ux_mm": vals[:, 2] * 1e3,
        "uy_mm": vals[:, 3] * 1e3,
        "gamma_deg": np.degrees(vals[:, 4]),
        "triangles": tri.astype(np.int32),
    }


def constraint_l2(problem: ContinuumProblem) -> float:
    """‖φ − i8‖_L2 / √|B|: the RMS violation of the constraint (dimensionless)."""
    inv = problem.invariants()
    sp = problem.scene.specimen
    v = ngs.Integrate((problem.phi - inv.i8) ** 2, problem.mesh, order=2 * problem.scene.discretization.p_u)
    return math.sqrt(max(v, 0.0) / (sp.L * sp.W))


#: a multiplier whose RMS is below this fraction of the stiffness scale K_ref is zero to round-off
#: (measured: held-arms frame of the Twintex plain weave 2.3e-7 K_ref; the coarsest fabric BET 0.12,
#: the default scene 2.6)
LAM_ZERO = 1e-5


def multiplier_oscillation(problem: ContinuumProblem, margin: float = 0.18) -> float | None:
    """‖Λ − Π Λ‖ / ‖Λ‖ on margin·L < X < (1 − margin)·L; None without a multiplier.

    Π is the L2 projection onto continuous fields of Λ's order (``problem.p_lam``, at least 1).

    A multiplier that converges is smooth away from the clamp corners, and this ratio falls with
    h; an unstable pair leaves O(1) element-to-element oscillations (ratio ~0.85, not falling).
    0 where the multiplier is zero to round-off (RMS below :data:`LAM_ZERO` of the stiffness scale
    ``problem.K_ref``: a homogeneous shear, the picture frame with held arms, has Λ = 0 exactly,
    and the ratio of its round-off to itself says nothing).
    """
    lam = problem.lam_field
    if lam is None:
        return None
    mesh, L = problem.mesh, problem.length
    V = ngs.H1(mesh, order=max(1, problem.p_lam))
    w, v = V.TnT()
    mass = ngs.BilinearForm(w * v * ngs.dx).Assemble()
    rhs = ngs.LinearForm(lam * v * ngs.dx).Assemble()
    proj = ngs.GridFunction(V)
    proj.vec.data = mass.mat.Inverse(inverse="sparsecholesky") * rhs.vec
    inner = ngs.IfPos((ngs.x - margin * L) * ((1 - margin) * L - ngs.x), 1.0, 0.0)
    order = 2 * max(1, problem.p_lam)
    norm = ngs.Integrate(inner * lam * lam, mesh, order=order)
    if norm <= (LAM_ZERO * problem.K_ref) ** 2 * ngs.Integrate(inner, mesh, order=order):
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


def frame_fabric_means(problem: ContinuumProblem) -> dict[str, float]:
    """The picture frame's inner fabric square: mean shear angle [deg] and largest yarn strain there.

    Means over the square of side L_fabric between the arms (the area that F_norm, Eq. 10,
    divides by), on the reference configuration: ``gamma_fabric_deg`` = ∫ γ / area, and
    ``elongation_max`` = the largest |√i4 − 1|, |√i6 − 1| at the integration points of order 2p
    of all elements (the whole cross).
    """
    pf, p = problem.scene.picture_frame, problem.scene.discretization.p_u
    c, L = pf.arm_mm * 1e-3, pf.frame_mm * 1e-3
    r = 1.0 / math.sqrt(2.0)
    xi, eta = (ngs.x + ngs.y) * r, (ngs.x - ngs.y) * r  # the frame's coordinates along the bars
    inside = ngs.IfPos((xi - c) * (L - c - xi), ngs.IfPos((eta - c) * (L - c - eta), 1.0, 0.0), 0.0)
    inv = problem.invariants()
    g = physics.shear_angle(inv.i4, inv.i6, inv.i8, problem.scene.specimen.cos0)
    order = 2 * p + 4
    area = ngs.Integrate(inside, problem.mesh, order=order)
    mean = ngs.Integrate(inside * g, problem.mesh, order=order) / area if area > 0 else math.nan
    ir = ngs.IntegrationRule(ngs.TRIG, 2 * p)
    pts = problem.mesh.MapToAllElements(ir, ngs.VOL)
    strain = np.abs(np.asarray(ngs.CF((ngs.sqrt(inv.i4) - 1, ngs.sqrt(inv.i6) - 1))(pts)))
    return {"gamma_fabric_deg": math.degrees(float(mean)), "elongation_max": float(strain.max())}
