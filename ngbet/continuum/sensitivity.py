r"""The clamp force along a load path, and its derivatives with respect to material parameters.

At a converged state the free rows of the residual vanish, r_f(x(p), p) = 0, and the clamp force
is R = ψ·r(x, p) for any test field ψ with ψ = 1 on the moving clamp and 0 on the fixed one
(:mod:`ngbet.continuum.observables`). Differentiating,

.. math::

    \frac{dR}{dp} = \psi\cdot\frac{\partial r}{\partial p} + \psi\cdot H\,\frac{dx}{dp},
    \qquad H_{ff}\frac{dx_f}{dp} = -\frac{\partial r_f}{\partial p}.

Choosing ψ* with (Hψ*)_f = 0 removes the second term: ψ* is the load tangent ∂x/∂u0 (Dirichlet
values of ψ, free values −H_ff⁻¹ H_fD ψ_D), one back-substitution with the factorization the
Newton solver already holds. Then dR/dp = ψ*·∂r/∂p for every parameter at once, and ∂r/∂p is the
residual of the energy's derivative ∂W/∂p: the problem's own energy, which reads the material
values as ``ngsolve.Parameter``\ s (:mod:`ngbet.continuum.parameters`), differentiated by NGSolve
(``CoefficientFunction.Diff``), every term that reads p included. Per converged step
this costs two back-substitutions and two residual evaluations plus one residual evaluation per
parameter, against a whole extra load path per parameter for finite differences.

H is the tangent at the converged state itself: Newton's last factorization belongs to an
earlier iterate, and the load tangent it gives is corrected by a Richardson step with the
residual's difference quotient (:func:`load_tangent_at_state`); Newton's own factorization, the
refactorized augmented matrix of the exact Lagrangian or a ∂W/∂p without the stabilization's cap
are each visibly less accurate. The derivatives agree with central differences of whole runs to
the accuracy those have (asserted in tests/test_fit.py and tests/test_calibration.py; the numbers
are in docs/calibration.md). min(α1, α2) has a kink at α1 = α2: there the derivative is the
one-sided one where K_s follows α1. The derivative form must integrate with the quadrature of the problem's energy
(:func:`_same_rule`); with NGSolve's default for the form alone, dF/d ln K_el was 1.3 % off.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import ngsolve as ngs
import numpy as np

from ..scene.document import Scene
from ..scene.validate import SceneError
from . import physics
from .parameters import PARAMETERS

__all__ = [
    "DIFFERENTIABLE",
    "TABLE",
    "TANGENT_CONTRACTION",
    "TANGENT_REFINEMENTS",
    "ForcePath",
    "Recorder",
    "check_params",
    "load_tangent_at_state",
    "material_value",
    "solve_at_state",
    "table_index",
    "with_material",
]

log = logging.getLogger(__name__)

#: material keys the force can be differentiated with respect to: the energy's Parameters, and
#: the tabulated shear law's rises one by one: "shear_stress_steps_Pa[j]"
DIFFERENTIABLE = (*PARAMETERS, "shear_stress_steps_Pa[j]")
TABLE = "shear_stress_steps_Pa"


def table_index(name: str) -> int | None:
    """The index of a rise "shear_stress_steps_Pa[j]", else None."""
    if name.startswith(TABLE + "[") and name.endswith("]") and name[len(TABLE) + 1 : -1].isdigit():
        return int(name[len(TABLE) + 1 : -1])
    return None


def material_value(scene: Scene, name: str) -> float:
    """The value of a material key, or of one rise of the tabulated law ("shear_stress_steps_Pa[j]")."""
    j = table_index(name)
    if j is None:
        return float(getattr(scene.material, name))
    return float(scene.material.shear_stress_steps_Pa[j])


@dataclass
class ForcePath:
    """Force at the requested clamp displacements; ``dlogp[i, k]`` = dF_i / d ln p_k [N].

    ``profiles[u0]`` (mm): the mid-axis displacement u_y at the requested X when a profile was
    asked for at load u0, and ``profile_dlogp[u0][j, k]`` = d u_y(X_j) / d ln p_k [mm].
    """

    u_mm: np.ndarray
    force_N: np.ndarray
    dlogp: np.ndarray | None
    reached_mm: float
    profiles: dict[float, np.ndarray] = field(default_factory=dict)
    profile_dlogp: dict[float, np.ndarray] = field(default_factory=dict)
    #: the estimated discretization error of ``force_N`` [N] (``estimate=True``; nan where it cannot vouch)
    force_error_N: np.ndarray | None = None
    #: ``angles``: {u0: centre shear angle [deg]} and {u0: its d/d ln p_k [deg]}
    angles_deg: dict[float, float] = field(default_factory=dict)
    angle_dlogp: dict[float, np.ndarray] = field(default_factory=dict)


def _energy_derivative(problem: Any, name: str) -> ngs.CoefficientFunction:
    """∂W/∂p of the problem's own energy with respect to material key ``name``, at its trial functions.

    The energy is the one the problem solves (:attr:`ContinuumProblem.energy_parts`), differentiated
    with respect to its Parameter (:mod:`ngbet.continuum.parameters`): every term that reads the
    value contributes, the stabilization K_s = min(c min(α1, α2)/h_T², 30 K_el) included. The energy
    is linear in the rises of the tabulated shear law: ∂W/∂(rise j) is that law with the unit rise e_j.
    """
    scene: Scene = problem.scene
    trial = problem.X.TrialFunction()
    j = table_index(name)
    if j is not None:
        eff = scene.effects
        if not eff.shear or eff.shear_law != "table":
            return ngs.CoefficientFunction(0.0)
        inv = physics.invariants(ngs.Grad(trial[0]), problem.m1, problem.m2)
        unit = np.zeros(len(scene.material.shear_stress_steps_Pa))
        unit[j] = 1.0
        return physics.table_shear_energy(inv.i8, unit, scene.material.shear_table_i8_max) + _same_rule(trial)
    W = sum(problem.energy_parts[1:], problem.energy_parts[0])
    # NGSolve chooses the quadrature from the proxies in the integrand (the polynomial order of
    # φ, Λ themselves is higher than that of ∇u): a term of negligible size in each of them makes
    # this form integrate with the rule of the problem's energy
    return W.Diff(problem.parameters[name]) + _same_rule(trial)


#: coefficient of the terms that only align the quadrature (their residual is < 1e-290)
_SAME_RULE = 1e-300


def _same_rule(trial: Any) -> ngs.CoefficientFunction:
    """The displacement u enters the energy through ∇u only; φ and Λ (when there) also as themselves."""
    g = ngs.Grad(trial[0])
    return _SAME_RULE * sum((ngs.InnerProduct(t, t) for t in list(trial)[1:]), ngs.InnerProduct(g, g))


def check_params(scene: Scene, params: Sequence[str]) -> list[str]:
    """The material names of the scene keys ``params`` ("material.K_sh" -> "K_sh").

    Raises SceneError for a key that cannot be differentiated.
    """
    names = []
    for p in params:
        section, _, key = p.partition(".")
        j = table_index(key)
        if j is not None and j < len(scene.material.shear_stress_steps_Pa):
            names.append(key)
            continue
        if section != "material" or key not in DIFFERENTIABLE:
            raise SceneError(
                f"cannot differentiate with respect to '{p}': known are "
                f"{', '.join('material.' + k for k in DIFFERENTIABLE)}"
            )
        names.append(key)
    return names


#: refinements of the load tangent at most, and the contraction each must reach (else: factorize anew)
TANGENT_REFINEMENTS = 3
TANGENT_CONTRACTION = 0.5


def load_tangent_at_state(solver: Any, residual: np.ndarray | None = None, rtol: float = 1e-5) -> np.ndarray:
    """ψ* = ∂x/∂u0 at the current, converged state: ψ on the clamps, (H ψ*)_f = 0 with H the tangent here.

    ``solver``: the problem's :class:`~ngbet.continuum.solver.ContinuumSolver`.

    Newton's last factorization belongs to the iterate before its last correction (or an earlier
    one, after a simplified Newton step); its load tangent made dF/dp differ from central
    differences of whole runs by up to 8e-5 of the value. It is corrected by
    :func:`solve_at_state`; ``residual``: r at this state, when at hand.

    H is the Jacobian of the residual itself, also for the exact Lagrangian, whose Newton matrix
    is augmented (K_aug, :mod:`ngbet.numerics.linear`): a load tangent of the augmented matrix
    leaves an O(1/K_aug) error (measured 1e-5 of dF/dK_sh).
    """
    r0 = residual if residual is not None else solver.residual()
    psi = solve_at_state(solver, solver.load_tangent(1.0), None, r0, rtol)
    if psi is None:
        solver.factorize()
        psi = solver.load_tangent(1.0)
    return psi


def solve_at_state(
    solver: Any, y: np.ndarray, g: np.ndarray | None, residual: np.ndarray, rtol: float = 1e-5
) -> np.ndarray | None:
    """The solution of (H y + g)_f = 0 (g None: 0) from a start y of Newton's last factorization.

    H is the tangent at the current, converged state.

    Richardson steps y ← y − H_old⁻¹ (H y + g)_f, with H y the difference quotient of the residual
    along y (one residual evaluation, against an assembly and a factorization for H itself; y's
    Dirichlet entries stay), until (H y + g)_f is below ``rtol`` of g's free rows (g None: of
    H y's Dirichlet rows). Measured: 1e-3–6e-3 from the start, ~1e-6 after one step (the level of
    the difference quotient). None where a step does not contract by :data:`TANGENT_CONTRACTION`
    within :data:`TANGENT_REFINEMENTS` steps (then H must be factorized here). The state is left
    as it was.
    """
    pb, dirichlet = solver, solver.problem.dirichlet
    x0 = pb.x.copy()
    scale = float(np.linalg.norm(x0))
    ref = None if g is None else float(np.linalg.norm(np.where(dirichlet, 0.0, g)))
    last = math.inf
    for _ in range(TANGENT_REFINEMENTS + 1):
        if not np.any(y):
            return y if g is None or ref == 0 else None
        h = 1e-7 * scale / float(np.linalg.norm(y))
        pb.x[:] = x0 + h * y
        rho = (pb.residual() - residual) / h
        pb.x[:] = x0
        if g is not None:
            rho += g
        size_ref = float(np.linalg.norm(rho[dirichlet])) if ref is None else ref
        rho[dirichlet] = 0.0
        size = float(np.linalg.norm(rho))
        if size <= rtol * size_ref:
            return y
        if size > TANGENT_CONTRACTION * last:
            return None
        last = size
        y = y + pb.solve(rho)
    return None


class Recorder:
    """What :func:`force_path` records at each converged step (called with each step record of the path)."""

    def __init__(
        self,
        solver: Any,
        names: list[str],
        profile: dict[float, np.ndarray],
        loads: Sequence[float] = (),
        angles: Sequence[float] = (),
        estimate: bool = False,
        estimate_loads: Sequence[float] | None = None,
    ) -> None:
        self.solver, self.problem = solver, solver.problem
        self.names, self.profile = names, profile
        self.angle_loads = [float(v) for v in angles]
        self.angles: dict[float, float] = {}
        self.angle_dlogp: dict[float, np.ndarray] = {}
        self.errors: dict[float, float] = {}
        self.estimator = None
        if estimate:
            from .estimate import ForceErrorEstimator

            self.estimator = ForceErrorEstimator(solver)
        problem = solver.problem
        self.loads = [float(v) for v in loads]  # [mm]: the loads whose derivatives are wanted
        # [mm]: the loads whose force error is estimated (``estimate``; None: every one of ``loads``)
        self.estimate_loads = self.loads if estimate_loads is None else [float(v) for v in estimate_loads]
        scene = problem.scene
        self.forms = []
        for n in names:
            f = ngs.BilinearForm(problem.X, symmetric=True)
            f += ngs.Variation(_energy_derivative(problem, n).Compile() * problem.dx)
            self.forms.append(f)
        self.values = [material_value(scene, n) for n in names]
        self.g = problem.gf.vec.CreateVector()
        self.dgf = ngs.GridFunction(problem.X)
        self.rows: dict[float, tuple[float, list[float]]] = {}
        self.profiles: dict[float, np.ndarray] = {}
        self.profile_dlogp: dict[float, np.ndarray] = {}

    def __call__(self, info: Any) -> None:
        """Record the force (and what else is asked) at the converged step ``info``."""
        pb, solver, t = self.problem, self.solver, self.problem.scene.specimen.t
        key = round(info.u0 * 1e3, 9)
        r = info.residual if info.residual is not None else solver.residual()
        F = float(r @ pb.psi_u.vec.FV().NumPy()) * t
        want = next((u0 for u0 in self.profile if abs(u0 - key) < 1e-6), None)
        pts = None
        if want is not None:
            sp = pb.scene.specimen
            X = self.profile[want] * 1e-3
            pts = pb.mesh(X, np.full(len(X), 0.5 * sp.W))
            self.profiles[want] = 1e3 * np.asarray(pb.u(pts))[:, 1]
        angle = next((u0 for u0 in self.angle_loads if abs(u0 - key) < 1e-6), None)
        if angle is not None:
            from .observables import centre_shear_angle_deg

            self.angles[angle] = centre_shear_angle_deg(pb)
        d, dprof, dang = [], [], []
        psi = None
        if self.forms and (want is not None or angle is not None or any(abs(v - key) < 1e-6 for v in self.loads)):
            psi = load_tangent_at_state(solver, r)
        for f, p in zip(self.forms if psi is not None else (), self.values, strict=False):
            f.Apply(pb.gf.vec, self.g)
            gv = self.g.FV().NumPy()
            d.append(p * float(psi @ gv) * t)
            if angle is not None:  # dγ/dp along dx/dp: a central difference of γ(x), the state put back
                dang.append(p * _angle_derivative(pb, solver, gv, r))
            if pts is not None:  # dx/dp = −J⁻¹ ∂r/∂p (solve returns −J⁻¹ r), J at this state
                dx = solve_at_state(solver, solver.solve(gv.copy()), gv, r)
                if dx is None:
                    solver.factorize()
                    dx = solver.solve(gv.copy())
                self.dgf.vec.FV().NumPy()[:] = dx
                dprof.append(1e3 * p * np.asarray(self.dgf.components[0](pts))[:, 1])
        if want is not None and dprof:
            self.profile_dlogp[want] = np.column_stack(dprof)
        if angle is not None and dang:
            self.angle_dlogp[angle] = np.array(dang)
        if self.estimator is not None and any(abs(v - key) < 1e-6 for v in self.estimate_loads):
            self.errors[key] = self.estimator.estimate(info.u0, F).force_error_N
        self.rows[key] = (F, d)


def _angle_derivative(problem: Any, solver: Any, gv: np.ndarray, r: np.ndarray) -> float:
    """dγ_centre/dp [deg] with dx/dp = −J⁻¹ ∂r/∂p (``gv``): a central difference along dx, the state put back."""
    from .observables import centre_shear_angle_deg

    if not float(np.linalg.norm(gv)) > 0:
        return 0.0  # the energy does not read p here (a rise of the table beyond the shear reached)
    dx = solve_at_state(solver, solver.solve(gv.copy()), gv, r)
    if dx is None:
        solver.factorize()
        dx = solver.solve(gv.copy())
    x0 = solver.x.copy()
    h = 1e-6 * max(float(np.linalg.norm(x0)), 1e-12) / max(float(np.linalg.norm(dx)), 1e-300)
    solver.x[:] = x0 + h * dx
    up = centre_shear_angle_deg(problem)
    solver.x[:] = x0 - h * dx
    down = centre_shear_angle_deg(problem)
    solver.x[:] = x0
    return (up - down) / (2 * h)


def with_material(scene: Scene, name: str, value: float) -> Scene:
    """``scene`` with one material key (or one rise "shear_stress_steps_Pa[j]") set to ``value``."""
    j = table_index(name)
    if j is None:
        return scene.with_changes(**{f"material.{name}": value})
    steps = list(scene.material.shear_stress_steps_Pa)
    steps[j] = value
    return scene.with_changes(**{f"material.{TABLE}": steps})
