"""The constrained micromorphic BET problem on NGSolve: spaces, forms, boundary conditions, load.

Only the effects the scene asks for are built (:class:`ngbet.scene.physical.Effects`):

=========================  ==================================  ===============================
effects                    unknowns                            energy
=========================  ==================================  ===============================
shear (+ elongation)       u ∈ VectorH1(p)                      W_sh + W_el (first gradient)
+ bending, lagrange        u, φ ∈ H1(p_φ), Λ ∈ L2(p − 2)         + W_b + Λ(φ − i8) + ½K_s(φ − i8)²
+ bending, penalty mixed   u, φ, Λ (condensed out)              + W_b + Λ(φ − i8) − Λ²/2K + ½K_s(φ − i8)²
+ bending, penalty full    u, φ (+ Λ, see below)                + W_b + ½K(φ − i8)²
=========================  ==================================  ===============================

The energy is written once as an integrand in parts (the bending energy and the rest:
:meth:`ContinuumProblem._energy` says why); its solver (:class:`ngbet.continuum.solver.ContinuumSolver`)
hands it to ``Variation`` and compiles it, and NGSolve differentiates it for the residual and the
linearization. The problem holds no form, inverse or timer: those are numerics, the solver's.

The multiplier lives in L2 of order max(p − 2, 0) (discontinuous, element-local, so it can be
eliminated element by element): one order higher, L2(p − 1), it oscillates from element to element
and does not converge though u, φ and the force do; in L2(p − 2) it converges with the force
(docs/formulations.md gives the numbers; every run reports ``multiplier_oscillation``). p = 1
locks: use p ≥ 2. For the exact Lagrange method with ``condense`` the
Newton matrix is augmented (:mod:`ngbet.numerics.linear`, which owns condensation and the sparse
inverse): the problem gives the augmented integrand (``augmented_energy``) for it.

Stabilization. Λ ∈ L2(p − 2) ties φ to i8 only in the element moments of degree p − 2; the rest
of i8 inside an element is held by the first-gradient energy alone, and where the yarns are
compressed (√i6 − 1 down to −0.5 at the singular clamp corners of a 0.25 mm corner mesh at
52.6 mm, −0.18 on the default mesh at 56 mm) that energy is not convex:
small corner elements (0.25 mm) then lose stability at 51–53 mm (p = 2) and 34 mm (p = 3) in a
mode with ‖δφ − δi8‖ = ‖δi8‖ at the corner (:func:`ngbet.continuum.stability.diagnose_stability` names it). The
exact constraint would charge such a variation of i8 about α/h_T² of bending energy. The
Lagrangian therefore carries ½K_s(φ − i8)² with K_s = c min(α1, α2)/h_T² element by element
(c = 0.1, :data:`STABILIZATION_C`): it vanishes with its variation where φ = i8, so the exact
solution is unchanged; it is large only on small elements, where the unstable modes live.

The paper's pointwise penalty ("full") is always solved in its mixed form Λ(φ − i8) − Λ²/2K
with Λ ∈ L2 of the degree of φ − i8 itself (max(p_φ, 2p − 2) on affine triangles): the same
discrete solution, since the L2 projection onto that space is the identity on φ − i8, but Newton
linearizes around the iterate's Λ instead of K(φ − i8), which the predictor makes huge for large
K (K = 1e10: 56 load steps pointwise, 6 in this form). The formulation follows the effects alone;
``solver.condense`` eliminates Λ, like every element-local unknown, or keeps it in the factorized
matrix, to the same solution (a choice of the solver, not of the problem).

Dirichlet data (docs/model.md, *Boundary conditions*): u = 0, φ = 0 on Σ1 (``left``); u = (u0, 0), φ = 0 on Σ2
(``right``). The load parameter λ of the solver is u0 in metres.

The picture frame (``test = "picture_frame"``, docs/model.md, *Picture frame*): the arms of the cross
(``clamp``) move with the bars of the hinged frame, u = (F(λ) − I) X with F = diag(A, B), A = 1 + λ/(√2 L),
B = √(2 − A²) (:func:`ngbet.kinematics.frame_stretches`), λ the crosshead travel [m], and φ = i8 of that
F (the yarns clamped in the bars turn with them). The data are not linear in λ: the reaction's test
field ψ_u = ∂x_D/∂λ (the affine lift (A' X, B' Y) and φ's ∂i8/∂λ) is that of the current load, and
the load direction with it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import cast

import ngsolve as ngs
import numpy as np
from ngsolve import CoefficientFunction as CF

from ..kinematics import frame_stretches
from ..scene.document import Scene
from ..scene.physical import Specimen
from ..scene.validate import AUTO
from . import physics
from .jamming import JammingBarrier
from .mesh import CLAMPED_ARMS, make_cross_mesh, make_mesh
from .parameters import material_parameters

log = logging.getLogger(__name__)

DIRICHLET = "left|right"

__all__ = ["K_REF_EL_FRACTION", "ContinuumProblem", "STABILIZATION_C", "stabilization_modulus"]


#: c in the default K_s = c min(α1, α2) / h_T². Measured (Table 1, 56 mm): the corner meshes that
#: stop without stabilization (0.25 mm corners, p = 2 and 3) pass with c = 0.01 already, i.e.
#: K_s ≈ 2e6 Pa on the corner elements (a constant 7e5 Pa also passes); c = 0.1 keeps a factor 10
#: on that while shifting the force on uniform meshes by 0.065 N at h = 10 mm (c = 1: 0.34 N).
STABILIZATION_C = 0.1

#: K_s is capped at this multiple of K_el: beyond, it only hurts the conditioning. Measured with
#: α1 = α2 = 2000 Pa m² on the 10 mm mesh graded to 0.5 mm corners, p = 3 (K_s up to 5.7e8 Pa):
#: uncapped 9 steps and 5 cuts; cap 100 K_el: 5 steps, 2 cuts; 30 K_el: 3 steps, no cut, force
#: 294.771 N against 294.791 N uncapped (0.020 N, below its estimated discretization error 0.030 N);
#: 10 K_el: 294.761 N (0.030 N, above the estimate 0.018 N). On the default scene (0.25 mm corners,
#: K_s up to 2.3e7 Pa) the cap moves the force at 56 mm by 6e-8 N (107.3735 N).
STABILIZATION_CAP = 30.0


#: the stiffness scale K_ref of the multiplier (its unit-free norm, and K_aug = 1e6 K_ref of the
#: condensed Newton matrix, :mod:`ngbet.numerics.linear`) is max(K_sh, K_REF_EL_FRACTION K_el).
#: K_aug has a window. Too small against K_el, the Newton matrix is too far from the exact one: the
#: default scene with K_sh = 1 Pa and K_aug = 1e6 Pa (K_ref = K_sh) found no equilibrium past
#: u0 = 0, 3e7 Pa stopped at 53 mm, 7e7 Pa reached 56 mm in 403 Newton iterations, 1.4e8 Pa (this
#: fraction) in 435, 7e8 Pa in 576. Too large, the conditioning suffers: K_el = 1e8 Pa with
#: K_sh = 21000 Pa reaches 56 mm with K_aug = 2.1e10 Pa and stopped at 54.8 mm with 1e11 Pa
#: (a fraction of 1e-3). Shipped and default scenes (K_sh = 21000 Pa, K_el up to 1e8 Pa) keep
#: K_ref = K_sh, to the bit.
K_REF_EL_FRACTION = 2e-4

#: inverted material (det F ≤ 0) on more than this fraction of the specimen makes a state
#: inadmissible for the relaxation to a stable state (a few integration points at a singular clamp
#: corner may invert without meaning anything)
INVERTED_AREA_FRACTION = 1e-4


def stabilization_modulus(scene: Scene, parameters: dict[str, ngs.Parameter] | None = None) -> CF | float:
    """K_s of ``effects.stabilization_K``: the constant, or ("auto") c min(α1, α2)/h_T², at most 30 K_el.

    The cap is :data:`STABILIZATION_CAP` (none when K_el = 0). ``parameters``: α1, α2 and K_el as
    the energy's Parameters (:mod:`ngbet.continuum.parameters`), so that K_s follows them.
    """
    k = scene.effects.stabilization_K
    if k != AUTO:
        return float(k)
    m = scene.material
    if parameters is None:
        alpha_min: CF | float = min(m.alpha1, m.alpha2)
        K_el: CF | float = m.K_el
    else:
        a1, a2 = parameters["alpha1"], parameters["alpha2"]
        alpha_min, K_el = ngs.IfPos(a1 - a2, a2, a1), parameters["K_el"]
    k_h = STABILIZATION_C * alpha_min / (ngs.specialcf.mesh_size**2)
    if m.K_el <= 0:
        return k_h
    cap = STABILIZATION_CAP * K_el
    return ngs.IfPos(k_h - cap, cap, k_h)


def _turned(m: tuple[float, float], deg: float) -> tuple[float, float]:
    """The direction ``m`` turned counter-clockwise by ``deg`` degrees."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return (c * m[0] - s * m[1], s * m[0] + c * m[1])


def _range_over_elements(k: CF | float, mesh: ngs.Mesh) -> tuple[float, float]:
    if not isinstance(k, CF):
        return (float(k), float(k))
    g = ngs.GridFunction(ngs.L2(mesh, order=0))
    g.Set(k)
    v = g.vec.FV().NumPy()
    return (float(v.min()), float(v.max()))


class ContinuumProblem:
    """Spaces, energy, boundary conditions, load and state of one scene.

    The energy integrand is ``energy_parts`` (and ``augmented_energy`` for the Newton matrix of the
    condensed exact Lagrangian); the state is ``gf`` with its numpy view ``x``; the load λ = u0 [m]
    moves the Dirichlet entries (:meth:`set_load`). Newton, the path and the estimates drive it
    through its solver (:class:`ngbet.continuum.solver.ContinuumSolver`, the
    :class:`~ngbet.numerics.newton.Problem`), which owns the forms and linear algebra.
    """

    def __init__(self, scene: Scene, mesh: ngs.Mesh | None = None, dirichlet: str = DIRICHLET) -> None:
        self.scene = scene
        sp, disc = scene.specimen, scene.discretization
        self.frame = scene.test == "picture_frame"
        if self.frame:
            pf = scene.picture_frame
            self.mesh = mesh if mesh is not None else make_cross_mesh(pf, sp, disc)
            dirichlet = CLAMPED_ARMS if dirichlet == DIRICHLET else dirichlet
            #: the length scale [m] (the loading diagonal) and the reference area [m²]
            self.length, self.area = math.sqrt(2.0) * pf.frame_mm * 1e-3, pf.fabric_area_mm2 * 1e-6
            self.yarns = _turned(sp.m1, pf.misalignment_deg), _turned(sp.m2, pf.misalignment_deg)
        else:
            self.mesh = mesh if mesh is not None else make_mesh(sp, disc)
            self.length, self.area = sp.L, sp.L * sp.W
            self.yarns = sp.m1, sp.m2
        self._spaces(scene, dirichlet)
        self.m1, self.m2 = CF(self.yarns[0]), CF(self.yarns[1])
        mat = scene.material
        self.K_ref = max(mat.K_sh, K_REF_EL_FRACTION * mat.K_el)
        self.dx = ngs.dx(bonus_intorder=disc.quad_bonus)
        #: the energy integrand in parts (differentiated with respect to self.parameters in
        #: sensitivity.py), and for the exact Lagrangian K_aug -> the augmented one (else None)
        self.energy_parts, self.augmented_energy = self._energy(scene)
        self.gf = ngs.GridFunction(self.X)
        # an energy term of its own, added to the solver's forms (ContinuumSolver)
        self.jamming = JammingBarrier(scene, self.mesh, self.X, self.u, self.m1, self.m2)
        self.x = self.gf.vec.FV().NumPy()
        self.free_all = np.array(list(self.X.FreeDofs()), dtype=bool)
        self.dirichlet = ~self.free_all
        self._load_fields(sp)
        self.weights = self._norm_weights()
        self.lam = 0.0
        self._lam_mass: tuple[slice, np.ndarray] | None = None  # Λ's rows and the diagonal of its mass matrix
        self._det_F: ngs.CoefficientFunction | None = None
        self.inverted_allowed = 0.0  # inverted area [m²] a state may have and be admissible

    def _spaces(self, scene: Scene, dirichlet: str) -> None:
        """The compound space of the fields the effects call for."""
        eff, disc = scene.effects, scene.discretization
        self.field_names = eff.fields
        # the full penalty in its exactly equivalent mixed form (module docstring), condensed or not
        self.full_as_mixed = eff.bending and eff.constraint == "penalty" and eff.penalty_form == "full"
        self.p_lam = max(disc.p_phi, 2 * disc.p_u - 2) if self.full_as_mixed else disc.p_lam
        if self.full_as_mixed:
            self.field_names = ("u", "phi", "lam")
        spaces = [ngs.VectorH1(self.mesh, order=disc.p_u, dirichlet=dirichlet)]
        if "phi" in self.field_names:
            spaces.append(ngs.H1(self.mesh, order=disc.p_phi, dirichlet=dirichlet))
        if "lam" in self.field_names:
            spaces.append(ngs.L2(self.mesh, order=self.p_lam))
        self.X = ngs.FESpace(spaces)

    def _energy(self, scene: Scene) -> tuple[tuple[CF, ...], Callable[[float], tuple[CF, ...]] | None]:
        """The energy integrand in parts, and for the exact Lagrangian the augmented one (K_aug -> parts).

        The parts sum to the energy, and each is an integrator of its own (:func:`add_energy`):
        the bending energy, the only term in ∇φ, apart from the rest. NGSolve's energy
        integrator finds which pairs of trial functions (∇u, φ, ∇φ, Λ) couple from a nonzero
        pattern that does not tell a second derivative in ∇φ alone from one in ∇φ and another
        function, so with the bending energy inside, the (zero) blocks of ∇φ with ∇u, φ and Λ were
        computed in every element. Apart, a linearization costs less (bench/README.md), with the
        same tangent to round-off: on affine triangles
        the bending energy, of degree 2p_φ − 2, is integrated exactly both by the rule of order
        2p − 2 NGSolve picks for an integrand in ∇φ alone and by the rule of order 2p of the rest
        (p the largest order of the spaces).

        The material values calibration varies are the Parameters ``self.parameters``
        (:mod:`ngbet.continuum.parameters`).
        """
        mat, eff = scene.material, scene.effects
        par = self.parameters = material_parameters(mat)
        trial = self.X.TrialFunction()
        inv = physics.invariants(ngs.Grad(trial[0]), self.m1, self.m2)
        base = physics.elongation_energy(inv.i4, inv.i6, par["K_el"])
        if eff.shear:
            base = base + physics.shear_law_energy(inv.i8, eff.shear_law, {**vars(mat), **par})
        self.K_s: CF | float = 0.0  # the stabilization modulus (a CF when element-wise)
        self.K_s_range = (0.0, 0.0)  # its smallest and largest value over the elements [Pa]
        if not eff.bending:
            return (base,), None
        phi = trial[1]
        bending = physics.bending_energy(ngs.Grad(phi), self.m1, self.m2, par["alpha1"], par["alpha2"])
        if eff.constraint == "lagrange" or eff.penalty_form == "mixed":
            self.K_s = stabilization_modulus(scene, par)
        self.K_s_range = _range_over_elements(self.K_s, self.mesh)
        if self.K_s_range[1] > 0:
            base = base + physics.penalty_constraint(phi, inv.i8, self.K_s)
        if eff.constraint == "lagrange":
            lam = trial[2]
            return (
                (base + physics.lagrange_constraint(phi, inv.i8, lam), bending),
                lambda K_aug: (base + physics.mixed_penalty_constraint(phi, inv.i8, lam, K_aug), bending),
            )
        if eff.penalty_form == "mixed" or self.full_as_mixed:
            return (base + physics.mixed_penalty_constraint(phi, inv.i8, trial[2], eff.penalty_K), bending), None
        return (base + physics.penalty_constraint(phi, inv.i8, eff.penalty_K), bending), None

    @property
    def jamming_on(self) -> bool:
        """Whether the jamming barrier is evaluated (a state came near it, or a relaxation began)."""
        return self.jamming.on

    def _load_fields(self, sp: Specimen) -> None:
        """Reaction test fields (ψ_u = (X/L, 0), ψ_φ = X/L; exact in the spaces) and the load direction."""
        if self.frame:
            self._frame_fields()
            return
        self.psi_u = ngs.GridFunction(self.X)
        self.psi_u.components[0].Set(CF((ngs.x / sp.L, 0)))
        self.psi_phi = None
        if "phi" in self.field_names:
            self.psi_phi = ngs.GridFunction(self.X)
            self.psi_phi.components[1].Set(ngs.x / sp.L)
        #: ψ_D: the Dirichlet entries' change per unit load (0 on the free entries)
        self.load_direction = np.where(self.dirichlet, self.psi_u.vec.FV().NumPy(), 0.0)
        self._clamp_dir = self.psi_u.vec.FV().NumPy().copy()

    def _frame_fields(self) -> None:
        """The picture frame's lifts (X, 0), (0, Y) and φ = 1 (exact in the spaces); ψ_u follows the load."""
        lifts = []
        for i, cf in ((0, CF((ngs.x, 0))), (0, CF((0, ngs.y))), (1, CF(1.0))):
            g = ngs.GridFunction(self.X)
            if i < len(g.components) and (i == 0 or "phi" in self.field_names):
                g.components[i].Set(cf)
            lifts.append(g.vec.FV().NumPy().copy())
        self._frame_lifts = lifts
        self.psi_u = ngs.GridFunction(self.X)
        self.psi_phi = None  # the frame applies no double force of its own
        self._set_frame(0.0)

    def frame_data(self, lam: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """The frame's prescribed (A − 1, B − 1, φ) at crosshead travel λ [m] and their derivatives in λ."""
        A, B, dA, dB = frame_stretches(lam, self.scene.picture_frame.frame_mm * 1e-3)
        (a1, a2), (b1, b2) = self.yarns
        # i8 = F m1 · F m2 − m1 · m2 with F = diag(A, B)
        phi = a1 * b1 * A * A + a2 * b2 * B * B - (a1 * b1 + a2 * b2)
        dphi = 2 * a1 * b1 * A * dA + 2 * a2 * b2 * B * dB
        return (A - 1.0, B - 1.0, phi), (dA, dB, dphi)

    def _set_frame(self, lam: float) -> None:
        """The Dirichlet entries of x at the frame's travel λ, and ψ_u and the load direction there."""
        values, rates = self.frame_data(lam)
        lx, ly, lp = self._frame_lifts
        self.x[self.dirichlet] = (values[0] * lx + values[1] * ly + values[2] * lp)[self.dirichlet]
        psi = rates[0] * lx + rates[1] * ly + rates[2] * lp
        self.psi_u.vec.FV().NumPy()[:] = psi
        self.load_direction = np.where(self.dirichlet, psi, 0.0)
        self._clamp_dir = psi

    # --------------------------------------------------------------------------- bookkeeping
    def ndofs(self) -> dict[str, int]:
        """Degrees of freedom per field and in all (those factorized: :meth:`ContinuumSolver.ndofs`)."""
        out = {name: int(self.X.components[i].ndof) for i, name in enumerate(self.field_names)}
        out["total"] = int(self.X.ndof)
        return out

    def _norm_weights(self) -> np.ndarray:
        """Scale each field to be unit-free: u by 1/L, φ by 1, Λ by 1/K_ref."""
        w = np.zeros(self.X.ndof)
        scale = {"u": 1.0 / self.length, "phi": 1.0, "lam": 1.0 / self.K_ref}
        for i, name in enumerate(self.field_names):
            rng = self.X.Range(i)
            w[rng.start : rng.stop] = scale[name]
        return cast(np.ndarray, w * self.free_all)

    # --------------------------------------------------------------------------- load, state, admissibility
    def set_load(self, lam: float) -> None:
        """Set the load λ = u0 [m]: the Dirichlet entries of x follow it."""
        self.lam = lam
        if self.frame:
            self._set_frame(lam)
            return
        self.x[self.dirichlet] = lam * self.load_direction[self.dirichlet]

    def converged(self) -> None:
        """The current state is an equilibrium the path keeps: the jamming barrier watches it.

        Only solved states are watched, not predictors or trial iterates, which may cross the yarns
        at a clamp for a moment without meaning anything (:meth:`JammingBarrier.watch`).
        """
        self.jamming.watch()

    def jamming_missed(self) -> bool:
        """The state was solved without the jamming barrier where it holds: switch it on and say so.

        True when the yarns are closer than the jamming angle on an element the barrier was off on
        (:meth:`~ngbet.continuum.jamming.JammingBarrier.missed`): the state is no equilibrium, the
        barrier is on from now on and the increment is to be solved again
        (:class:`~ngbet.numerics.newton.JammingWatch`).
        """
        if not self.jamming.missed():
            return False
        self.jamming.switch_on()
        return True

    def constraint_moments(self, r: np.ndarray) -> float:
        """‖Π(φ − i8)‖²: the squared element moments of the constraint at the state whose residual is ``r``.

        From the residual's Λ rows r_Λ = ∫ δΛ (φ − i8 − Λ/K) with the diagonal of Λ's mass matrix
        (L2-orthogonal basis): Σ r_Λ² / m_ΛΛ (the merit of :meth:`ContinuumSolver.merit`).
        """
        if self._lam_mass is None:
            V = self.X.components[2]
            m = ngs.BilinearForm(V, symmetric=True)
            m += V.TrialFunction() * V.TestFunction() * ngs.dx
            m.Assemble()
            rng = self.X.Range(2)
            self._lam_mass = (slice(rng.start, rng.stop), np.array([m.mat[i, i] for i in range(V.ndof)]))
        rows, mass = self._lam_mass
        return float(np.sum(r[rows] ** 2 / mass))

    def inverted_area(self) -> float:
        """The area [m²] where det F ≤ 0 (the material turned inside out; the yarn invariants do not see it)."""
        if self._det_F is None:
            self._det_F = ngs.Det(ngs.Id(2) + ngs.Grad(self.u))
        return float(ngs.Integrate(ngs.IfPos(-self._det_F, 1.0, 0.0), self.mesh))

    def admissible(self) -> str:
        """Why the current state is not a physical one ("" when it is).

        Material inverted (det F ≤ 0) on more than :data:`INVERTED_AREA_FRACTION` of the specimen
        beyond ``inverted_allowed`` [m²] (what there was where the relaxation began).
        """
        a = self.inverted_area()
        if a <= self.inverted_allowed + INVERTED_AREA_FRACTION * self.area:
            return ""
        return f"det F <= 0 on {a * 1e6:.3g} mm² (the material turned inside out)"

    @property
    def inadmissible_hint(self) -> str:
        """What keeps the specimen out of inverted states (the relaxation's advice when it meets them)."""
        eff = self.scene.effects
        if eff.jamming or (eff.shear and eff.shear_law == "locking" and self.scene.material.K_lock > 0):
            return ""
        return (
            "the shear energy falls again once the yarns turn past parallel; the jamming barrier "
            "(effects.jamming = true) or a shear law that locks before (effects.shear_law = 'locking' with "
            "material.K_lock > 0) keeps the yarns from crossing"
        )

    def begin_relaxation(self) -> None:
        """A relaxation starts from the current state: it may not invert more material than there is now.

        The descent may close the yarns anywhere: the jamming barrier is on from now on.
        """
        self.inverted_allowed = self.inverted_area()
        self.jamming.switch_on()

    def locate(self, dx: np.ndarray) -> dict[str, object]:
        """Where a change of state ``dx`` (full length) lives: centroid and spread of |∇δu|², and its size.

        Returns ``location_mm`` (X, Y), ``spread_mm`` (the root-mean-square distance from the centroid,
        weighted by |∇δu|²: small for a local jump, about the specimen's size for a global one) and
        ``max_du_mm`` (the largest nodal |δu|).
        """
        gf = ngs.GridFunction(self.X)
        gf.vec.FV().NumPy()[:] = dx
        du = gf.components[0]
        G = ngs.Grad(du)
        mesh = self.mesh
        dens = ngs.InnerProduct(G, G)
        tot = max(ngs.Integrate(dens, mesh), 1e-300)
        cx = ngs.Integrate(dens * ngs.x, mesh) / tot
        cy = ngs.Integrate(dens * ngs.y, mesh) / tot
        spread = math.sqrt(max(ngs.Integrate(dens * ((ngs.x - cx) ** 2 + (ngs.y - cy) ** 2), mesh) / tot, 0.0))
        vals = [du(mesh(*v.point[:2])) for v in mesh.vertices]
        big = max((math.hypot(*v) for v in vals), default=0.0)
        return {"location_mm": [1e3 * cx, 1e3 * cy], "spread_mm": 1e3 * spread, "max_du_mm": 1e3 * big}

    def clamp_predictor(self, dlam: float) -> np.ndarray:
        """The clamp's linear field (X/L, 0) dlam (the picture frame: its affine map's rate ψ_u dlam)."""
        return cast(np.ndarray, dlam * self._clamp_dir)

    def norm(self, dx: np.ndarray) -> float:
        """A unit-free norm of a correction (u by 1/L, φ by 1, Λ by 1/K_ref)."""
        return float(np.linalg.norm(self.weights * dx))

    # --------------------------------------------------------------------------- fields
    @property
    def u(self) -> ngs.GridFunction:
        """The displacement."""
        return self.gf.components[0]

    @property
    def phi(self) -> ngs.GridFunction | None:
        """The micro-variable φ (None without bending)."""
        return self.gf.components[1] if "phi" in self.field_names else None

    @property
    def lam_field(self) -> ngs.GridFunction | None:
        """The multiplier Λ (None without it)."""
        return self.gf.components[2] if "lam" in self.field_names else None

    def invariants(self) -> physics.Invariants:
        """F and the yarn invariants of the current displacement."""
        return physics.invariants(ngs.Grad(self.u), self.m1, self.m2)
