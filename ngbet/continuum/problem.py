"""The constrained micromorphic BET problem on NGSolve: spaces, forms, boundary conditions, load.

Only the effects the scene asks for are built (:class:`ngbet.scene.Effects`):

=========================  ==================================  ===============================
effects                    unknowns                            energy
=========================  ==================================  ===============================
shear (+ elongation)       u ∈ VectorH1(p)                      W_sh + W_el (first gradient)
+ bending, lagrange        u, φ ∈ H1(p_φ), Λ ∈ L2(p − 2)         + W_b + Λ(φ − i8) + ½K_s(φ − i8)²
+ bending, penalty mixed   u, φ, Λ (condensed out)              + W_b + Λ(φ − i8) − Λ²/2K + ½K_s(φ − i8)²
+ bending, penalty full    u, φ (+ Λ condensed, see below)      + W_b + ½K(φ − i8)²
=========================  ==================================  ===============================

The energy is written once, handed to ``Variation`` and compiled; NGSolve differentiates it for
the residual and the linearization. The multiplier lives in L2 of order max(p − 2, 0)
(discontinuous, element-local, so it can be eliminated element by element). Measured with
:func:`ngbet.continuum.observables.multiplier_oscillation` (the part of Λ that a continuous field cannot
represent, away from the clamps) on the default scene at 37 mm: with Λ ∈ L2(p − 1) it stays at
0.84–0.86 on h = 10, 5, 2.5 mm for p = 2 (also with φ of order 3): the multiplier oscillates
from element to element and does not converge, though u, φ and the force do; with Λ ∈ L2(p − 2)
it falls as O(h) for p = 2 (0.093, 0.048, 0.025) and as O(h²) for p = 3 (0.0061, 0.0015), with
the same force (Richardson limit 61.2 N for both pairs at p = 2). p = 1 locks (84 N against
62 N at h = 10 mm with Λ ∈ L2(0)); use p ≥ 2. For the exact Lagrange method with ``condense`` the
Newton matrix is that of the mixed penalty with a very large K_aug (so that Λ can be condensed),
while the residual stays the exact Lagrangian's: Newton then converges to the exact saddle point,
the O(1/K_aug) Jacobian error only slows the last digits.

Stabilization. Λ ∈ L2(p − 2) ties φ to i8 only in the element moments of degree p − 2; the rest
of i8 inside an element is held by the first-gradient energy alone, and where the yarns are
compressed (√i6 − 1 down to −0.5 at the singular clamp corners of a 0.25 mm corner mesh at
52.6 mm, −0.18 on the default mesh at 56 mm) that energy is not convex:
small corner elements (0.25 mm) then lose stability at 51–53 mm (p = 2) and 34 mm (p = 3) in a
mode with ‖δφ − δi8‖ = ‖δi8‖ at the corner (:func:`ngbet.continuum.run.diagnose_stability` names it). The
exact constraint would charge such a variation of i8 about α/h_T² of bending energy. The
Lagrangian therefore carries ½K_s(φ − i8)² with K_s = c min(α1, α2)/h_T² element by element
(c = 0.1, :data:`STABILIZATION_C`): it vanishes with its variation where φ = i8, so the exact
solution is unchanged; it is large only on small elements, where the unstable modes live.

The paper's pointwise penalty ("full") is solved, with ``condense``, in its mixed form
Λ(φ − i8) − Λ²/2K with Λ ∈ L2 of the degree of φ − i8 itself (max(p_φ, 2p − 2) on affine
triangles), condensed: the same discrete solution, since the L2 projection onto that space is
the identity on φ − i8, but Newton linearizes around the iterate's Λ instead of K(φ − i8), which
the predictor makes huge for large K (K = 1e10: 56 load steps pointwise, 6 in this form).

Dirichlet data (docs/model.md, *Boundary conditions*): u = 0, φ = 0 on Σ1 (``left``); u = (u0, 0), φ = 0 on Σ2
(``right``). The load parameter λ of the solver is u0 in metres.
"""

from __future__ import annotations

import logging
import time

import ngsolve as ngs
import numpy as np
from ngsolve import CoefficientFunction as CF

from . import physics
from .mesh import make_mesh
from ..scene import Scene

log = logging.getLogger(__name__)

DIRICHLET = "left|right"

#: K_aug / K_sh for the condensed Newton matrix of the exact Lagrange method: large enough that
#: the Jacobian error (relative size ~ K_sh / K_aug) leaves Newton quadratic to the tolerance,
#: small enough that the condensed matrix keeps ~8 correct digits.
LAGRANGE_AUGMENTATION = 1e6


#: c in the default K_s = c min(α1, α2) / h_T². Measured (Table 1, 56 mm): the corner meshes that
#: stop without stabilization (0.25 mm corners, p = 2 and 3) pass with c = 0.01 already, i.e.
#: K_s ≈ 2e6 Pa on the corner elements (a constant 7e5 Pa also passes); c = 0.1 keeps a factor 10
#: on that while shifting the force on uniform meshes by 0.065 N at h = 10 mm (c = 1: 0.34 N).
STABILIZATION_C = 0.1


def stabilization_modulus(scene: Scene, mesh: ngs.Mesh) -> CF | float:
    """K_s of ``effects.stabilization_K``: the constant, or (default, -1) c min(α1, α2)/h_T²."""
    k = scene.effects.stabilization_K
    if k >= 0:
        return k
    m = scene.material
    return STABILIZATION_C * min(m.alpha1, m.alpha2) / (ngs.specialcf.mesh_size ** 2)


def _range_over_elements(k: CF | float, mesh: ngs.Mesh) -> tuple[float, float]:
    if not isinstance(k, CF):
        return (float(k), float(k))
    g = ngs.GridFunction(ngs.L2(mesh, order=0))
    g.Set(k)
    v = g.vec.FV().NumPy()
    return (float(v.min()), float(v.max()))


class ContinuumProblem:
    """Spaces, forms and load of one scene; implements :class:`ngbet.continuum.solver.NonlinearProblem`."""

    def __init__(self, scene: Scene, mesh: ngs.Mesh | None = None, dirichlet: str = DIRICHLET) -> None:
        self.scene = scene
        sp, mat, eff, disc = scene.specimen, scene.material, scene.effects, scene.discretization
        self.mesh = mesh if mesh is not None else make_mesh(sp, disc)
        self.field_names = eff.fields
        # the full penalty in its mixed form (module docstring); condense = false keeps it pointwise
        self.full_as_mixed = (eff.bending and eff.constraint == "penalty" and eff.penalty_form == "full"
                              and scene.solver.condense)
        self.p_lam = max(disc.p_phi, 2 * disc.p_u - 2) if self.full_as_mixed else disc.p_lam
        if self.full_as_mixed:
            self.field_names = ("u", "phi", "lam")
        spaces = [ngs.VectorH1(self.mesh, order=disc.p_u, dirichlet=dirichlet)]
        if "phi" in self.field_names:
            spaces.append(ngs.H1(self.mesh, order=disc.p_phi, dirichlet=dirichlet))
        if "lam" in self.field_names:
            spaces.append(ngs.L2(self.mesh, order=self.p_lam))
        self.X = ngs.FESpace(spaces)
        self.m1, self.m2 = CF(sp.m1), CF(sp.m2)
        trial = self.X.TrialFunction()
        u = trial[0]
        inv = physics.invariants(ngs.Grad(u), self.m1, self.m2)
        base = physics.elongation_energy(inv.i4, inv.i6, mat.K_el)
        if eff.shear:
            base = base + physics.shear_law_energy(inv.i8, eff.shear_law, vars(mat))
        self.K_ref = mat.K_sh if mat.K_sh > 0 else mat.K_el
        constraint = jac_constraint = None
        self.K_s: CF | float = 0.0  # the stabilization modulus (a CF when element-wise)
        self.K_s_range = (0.0, 0.0)  # its smallest and largest value over the elements [Pa]
        if eff.bending:
            phi = trial[1]
            base = base + physics.bending_energy(ngs.Grad(phi), self.m1, self.m2, mat.alpha1, mat.alpha2)
            if eff.constraint == "lagrange":
                constraint = physics.lagrange_constraint(phi, inv.i8, trial[2])
                self.K_aug = LAGRANGE_AUGMENTATION * self.K_ref
                jac_constraint = physics.mixed_penalty_constraint(phi, inv.i8, trial[2], self.K_aug)
            elif eff.penalty_form == "mixed" or self.full_as_mixed:
                constraint = physics.mixed_penalty_constraint(phi, inv.i8, trial[2], eff.penalty_K)
            else:
                constraint = physics.penalty_constraint(phi, inv.i8, eff.penalty_K)
            if eff.constraint == "lagrange" or eff.penalty_form == "mixed":
                self.K_s = stabilization_modulus(scene, self.mesh)
            self.K_s_range = _range_over_elements(self.K_s, self.mesh)
            if self.K_s_range[1] > 0:
                stab = physics.penalty_constraint(phi, inv.i8, self.K_s)
                constraint = constraint + stab
                if jac_constraint is not None:
                    jac_constraint = jac_constraint + stab
        energy = base if constraint is None else base + constraint
        self.dx = ngs.dx(bonus_intorder=disc.quad_bonus)
        # Λ is element-local and its diagonal block is zero only for the exact Lagrangian
        self.condense = scene.solver.condense
        exact_saddle = eff.bending and eff.constraint == "lagrange"
        self.a = ngs.BilinearForm(self.X, symmetric=True, condense=self.condense and not exact_saddle)
        self.a += ngs.Variation(energy.Compile() * self.dx)
        if exact_saddle and self.condense:
            self.a_jac = ngs.BilinearForm(self.X, symmetric=True, condense=True)
            self.a_jac += ngs.Variation((base + jac_constraint).Compile() * self.dx)
        else:
            self.a_jac = self.a
        self.gf = ngs.GridFunction(self.X)
        self.x = self.gf.vec.FV().NumPy()
        self._r = self.gf.vec.CreateVector()
        self._w = self.gf.vec.CreateVector()
        self._w2 = self.gf.vec.CreateVector()
        self.free_all = np.array(list(self.X.FreeDofs()), dtype=bool)
        self.freedofs = self.X.FreeDofs(self.a_jac.condense)
        self.dirichlet = ~self.free_all
        # reaction test fields (docs/model.md, *Reactions*): ψ_u = (X/L, 0), ψ_φ = X/L; exact in the spaces
        self.psi_u = ngs.GridFunction(self.X)
        self.psi_u.components[0].Set(CF((ngs.x / sp.L, 0)))
        self.psi_phi = None
        if "phi" in self.field_names:
            self.psi_phi = ngs.GridFunction(self.X)
            self.psi_phi.components[1].Set(ngs.x / sp.L)
        self._load_dir = np.where(self.dirichlet, self.psi_u.vec.FV().NumPy(), 0.0)
        self._clamp_dir = self.psi_u.vec.FV().NumPy().copy()
        self._weights = self._norm_weights()
        self.inverse_type = self._pick_solver(scene.solver.linear_solver, exact_saddle and not self.condense)
        self._inv = None
        self.lam = 0.0
        self.timers = {"assembly_s": 0.0, "factorization_s": 0.0, "solve_s": 0.0, "residual_s": 0.0}
        self.counts = {"factorizations": 0, "solves": 0, "residuals": 0}

    # --------------------------------------------------------------------------- bookkeeping
    def ndofs(self) -> dict[str, int]:
        """Degrees of freedom per field, and those left after condensation."""
        out = {name: int(self.X.components[i].ndof) for i, name in enumerate(self.field_names)}
        out["total"] = int(self.X.ndof)
        out["factorized"] = int(sum(self.freedofs))
        return out

    def _norm_weights(self) -> np.ndarray:
        """Scale each field to be unit-free: u by 1/L, φ by 1, Λ by 1/K_ref."""
        w = np.zeros(self.X.ndof)
        scale = {"u": 1.0 / self.scene.specimen.L, "phi": 1.0, "lam": 1.0 / self.K_ref}
        for i, name in enumerate(self.field_names):
            rng = self.X.Range(i)
            w[rng.start:rng.stop] = scale[name]
        return w * self.free_all

    @staticmethod
    def _pick_solver(choice: str, indefinite: bool) -> str:
        if choice != "auto":
            return choice
        # sparse LDLᵀ needs no zero pivots: fine for the condensed or minimization matrices,
        # not for the uncondensed saddle point (zero Λ-Λ block)
        return "umfpack" if indefinite else "sparsecholesky"

    # --------------------------------------------------------------------------- solver interface
    def set_load(self, lam: float) -> None:
        self.lam = lam
        self.x[self.dirichlet] = lam * self._load_dir[self.dirichlet]

    def residual(self) -> np.ndarray:
        t0 = time.perf_counter()
        self.a.Apply(self.gf.vec, self._r)
        self.timers["residual_s"] += time.perf_counter() - t0
        self.counts["residuals"] += 1
        return self._r.FV().NumPy().copy()

    def energy(self) -> float:
        return float(self.a.Energy(self.gf.vec))

    def factorize(self) -> None:
        t0 = time.perf_counter()
        self.a_jac.AssembleLinearization(self.gf.vec)
        t1 = time.perf_counter()
        if self._inv is None:
            self._inv = self.a_jac.mat.Inverse(self.freedofs, inverse=self.inverse_type)
        else:
            self._inv.Update()
        self.timers["assembly_s"] += t1 - t0
        self.timers["factorization_s"] += time.perf_counter() - t1
        self.counts["factorizations"] += 1

    def _solve_into(self, r: ngs.BaseVector, out: ngs.BaseVector) -> None:
        """out = J⁻¹ r (free dofs), condensation handled; r is overwritten."""
        t0 = time.perf_counter()
        a = self.a_jac
        if a.condense:
            r.data += a.harmonic_extension_trans * r
            out.data = self._inv * r
            out.data += a.harmonic_extension * out
            out.data += a.inner_solve * r
        else:
            out.data = self._inv * r
        self.timers["solve_s"] += time.perf_counter() - t0
        self.counts["solves"] += 1

    def solve(self, r: np.ndarray) -> np.ndarray:
        self._w.FV().NumPy()[:] = r
        self._solve_into(self._w, self._w2)
        dx = -self._w2.FV().NumPy()
        dx[self.dirichlet] = 0.0
        return dx

    def load_tangent(self, dlam: float) -> np.ndarray:
        d = dlam * self._load_dir
        self._w2.FV().NumPy()[:] = d
        self._w.data = self.a_jac.mat * self._w2
        dx = self.solve(self._w.FV().NumPy())
        dx[self.dirichlet] = d[self.dirichlet]
        if self.a_jac.condense:  # local dofs follow the Dirichlet move through the extension
            self._w2.FV().NumPy()[:] = np.where(self.dirichlet, d, 0.0)
            self._w.data = self.a_jac.harmonic_extension * self._w2
            dx += self._w.FV().NumPy() * ~self.dirichlet
        return dx

    def clamp_predictor(self, dlam: float) -> np.ndarray:
        return dlam * self._clamp_dir

    def norm(self, dx: np.ndarray) -> float:
        return float(np.linalg.norm(self._weights * dx))

    # --------------------------------------------------------------------------- fields
    @property
    def u(self) -> ngs.GridFunction:
        return self.gf.components[0]

    @property
    def phi(self) -> ngs.GridFunction | None:
        return self.gf.components[1] if "phi" in self.field_names else None

    @property
    def lam_field(self) -> ngs.GridFunction | None:
        return self.gf.components[2] if "lam" in self.field_names else None

    def invariants(self) -> physics.Invariants:
        return physics.invariants(ngs.Grad(self.u), self.m1, self.m2)
