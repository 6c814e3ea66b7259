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
residual of the energy's derivative ∂W/∂p, which NGSolve forms from the same physics functions
with the parameter as an ``ngsolve.Parameter`` (``CoefficientFunction.Diff``). Per converged step
this costs one back-substitution plus one residual evaluation per parameter, against a whole
extra load path per parameter for finite differences.

Accuracy, measured against central differences of whole runs (tests/test_fit.py): 5e-4 of the
largest derivative at p = 2, 1e-5 at p = 3, for the shear-law coefficients and K_el, with and
without bending. The derivative form must integrate with the quadrature of the problem's energy
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

from ..scene import AUTO, Scene, SceneError
from . import physics

log = logging.getLogger(__name__)

#: material keys whose derivative the forms below know (the energy terms that read them); the
#: tabulated shear law's rises are named one by one: "shear_stress_steps_Pa[j]"
DIFFERENTIABLE = ("K_el", "K_sh", "K_sh4", "K_sh6", "K_lock", "gamma_lock_deg", "alpha1", "alpha2",
                  "shear_stress_steps_Pa[j]")
TABLE = "shear_stress_steps_Pa"


def _table_index(name: str) -> int | None:
    """The index of a rise "shear_stress_steps_Pa[j]", else None."""
    if name.startswith(TABLE + "[") and name.endswith("]") and name[len(TABLE) + 1:-1].isdigit():
        return int(name[len(TABLE) + 1:-1])
    return None


def material_value(scene: Scene, name: str) -> float:
    """The value of a material key, or of one rise of the tabulated law ("shear_stress_steps_Pa[j]")."""
    j = _table_index(name)
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


def _energy_derivative(problem: Any, name: str, value: float) -> ngs.CoefficientFunction:
    """∂W/∂p of the terms that read material key ``name``, at the trial functions of ``problem``."""
    scene: Scene = problem.scene
    mat, eff = vars(scene.material).copy(), scene.effects
    P = ngs.Parameter(value)
    trial = problem.X.TrialFunction()
    inv = physics.invariants(ngs.Grad(trial[0]), problem.m1, problem.m2)
    j = _table_index(name)
    if j is not None:  # the energy is linear in the rises: dW/d(rise j) is the law with the unit rise e_j
        if not eff.shear or eff.shear_law != "table":
            return ngs.CoefficientFunction(0.0)
        unit = np.zeros(len(scene.material.shear_stress_steps_Pa))
        unit[j] = 1.0
        return physics.table_shear_energy(inv.i8, unit, scene.material.shear_table_i8_max) + _same_rule(trial)
    mat[name] = P
    if name == "K_el":
        W = physics.elongation_energy(inv.i4, inv.i6, P)
    elif name in ("alpha1", "alpha2"):
        if not eff.bending:
            return ngs.CoefficientFunction(0.0)
        W = physics.bending_energy(ngs.Grad(trial[1]), problem.m1, problem.m2, mat["alpha1"], mat["alpha2"])
        if eff.stabilization_K == AUTO and problem.K_s_range[1] > 0:  # K_s = c min(α1, α2)/h_T² follows α
            from .problem import STABILIZATION_C

            a1, a2 = mat["alpha1"], mat["alpha2"]
            K_s = STABILIZATION_C * ngs.IfPos(a1 - a2, a2, a1) / ngs.specialcf.mesh_size ** 2
            W = W + physics.penalty_constraint(trial[1], inv.i8, K_s)
    else:
        if not eff.shear or name not in physics.SHEAR_LAWS[eff.shear_law]:
            return ngs.CoefficientFunction(0.0)
        W = physics.shear_law_energy(inv.i8, eff.shear_law, mat)
    # NGSolve chooses the quadrature from the proxies in the integrand (the polynomial order of
    # φ, Λ themselves is higher than that of ∇u): a term of negligible size in each of them makes
    # this form integrate with the rule of the problem's energy
    return W.Diff(P) + _same_rule(trial)


#: coefficient of the terms that only align the quadrature (their residual is < 1e-290)
_SAME_RULE = 1e-300


def _same_rule(trial: Any) -> ngs.CoefficientFunction:
    """The displacement u enters the energy through ∇u only; φ and Λ (when there) also as themselves."""
    g = ngs.Grad(trial[0])
    return _SAME_RULE * sum((ngs.InnerProduct(t, t) for t in list(trial)[1:]), ngs.InnerProduct(g, g))


def _check_params(scene: Scene, params: Sequence[str]) -> list[str]:
    names = []
    for p in params:
        section, _, key = p.partition(".")
        j = _table_index(key)
        if j is not None and j < len(scene.material.shear_stress_steps_Pa):
            names.append(key)
            continue
        if section != "material" or key not in DIFFERENTIABLE:
            raise SceneError(f"cannot differentiate with respect to '{p}': known are "
                             f"{', '.join('material.' + k for k in DIFFERENTIABLE)}")
        names.append(key)
    return names


class _Recorder:
    """What :func:`force_path` records at each converged step (an ``on_step`` callback)."""

    def __init__(self, problem: Any, names: list[str], profile: dict[float, np.ndarray]) -> None:
        self.problem, self.names, self.profile = problem, names, profile
        scene = problem.scene
        self.forms = []
        for n in names:
            f = ngs.BilinearForm(problem.X, symmetric=True)
            f += ngs.Variation(_energy_derivative(problem, n, material_value(scene, n)).Compile() * problem.dx)
            self.forms.append(f)
        self.values = [material_value(scene, n) for n in names]
        self.g = problem.gf.vec.CreateVector()
        self.dgf = ngs.GridFunction(problem.X)
        self.rows: dict[float, tuple[float, list[float]]] = {}
        self.profiles: dict[float, np.ndarray] = {}
        self.profile_dlogp: dict[float, np.ndarray] = {}

    def __call__(self, info: Any) -> None:
        pb, t = self.problem, self.problem.scene.specimen.t
        key = round(info.u0 * 1e3, 9)
        r = info.residual if info.residual is not None else pb.residual()
        F = float(r @ pb.psi_u.vec.FV().NumPy()) * t
        want = next((u0 for u0 in self.profile if abs(u0 - key) < 1e-6), None)
        pts = None
        if want is not None:
            sp = pb.scene.specimen
            X = self.profile[want] * 1e-3
            pts = pb.mesh(X, np.full(len(X), 0.5 * sp.W))
            self.profiles[want] = 1e3 * np.asarray(pb.u(pts))[:, 1]
        d, dprof = [], []
        psi = pb.load_tangent(1.0) if self.forms else None  # ψ*: ψ on the clamps, H-orthogonal to free dofs
        for f, p in zip(self.forms, self.values, strict=True):
            f.Apply(pb.gf.vec, self.g)
            gv = self.g.FV().NumPy()
            d.append(p * float(psi @ gv) * t)
            if pts is not None:  # dx/dp = −J⁻¹ ∂r/∂p (solve returns −J⁻¹ r)
                self.dgf.vec.FV().NumPy()[:] = pb.solve(gv.copy())
                dprof.append(1e3 * p * np.asarray(self.dgf.components[0](pts))[:, 1])
        if want is not None and dprof:
            self.profile_dlogp[want] = np.column_stack(dprof)
        self.rows[key] = (F, d)


def force_path(scene: Scene, u_mm: Sequence[float] | np.ndarray, params: Sequence[str] = (),
               profile: dict[float, np.ndarray] | None = None, mesh: Any = None) -> ForcePath:
    """The force at each of ``u_mm`` and its derivatives dF/d ln p for the material keys ``params``.

    ``scene`` (continuum) runs with a load step landing on each of ``u_mm``; ``params`` are keys
    such as ``"material.K_sh"``.

    ``profile``: {u0 [mm]: X [mm]}: also the mid-axis u_y at those X at load u0 (and its
    derivatives, one more back-substitution per parameter). ``mesh``: a mesh of the scene's
    specimen made before (:func:`ngbet.continuum.mesh.make_mesh`), reused instead of meshing
    again. Nothing is written to disk. Raises
    :class:`ngbet.errors.ConvergenceError` when the path cannot be followed to the last load.
    """
    from .problem import ContinuumProblem
    from .solver import continuation, newton_settings

    names = _check_params(scene, params)
    profile = {float(k): np.asarray(v, float) for k, v in (profile or {}).items()}
    u = np.asarray(sorted(set(float(v) for v in u_mm if v > 0) | set(profile)))
    L = scene.loading
    scene = scene.with_changes(**{"loading.u0_mm": float(u[-1]), "loading.stops_mm": list(u[:-1])})
    from ..run import ngsolve_threads

    with ngsolve_threads(scene):
        rec = _Recorder(ContinuumProblem(scene, mesh), names, profile)
        continuation(rec.problem, u[-1] * 1e-3, L.first_step_mm * 1e-3, newton_settings(scene),
                     max_step=L.max_step_mm * 1e-3, min_step=L.min_step_mm * 1e-3,
                     stops=[s * 1e-3 for s in u], on_step=rec)
    keys = np.array(sorted(rec.rows))
    # the force (and its derivatives) at each requested load, in the caller's order, repeats
    # included; the unloaded state carries none; loads only asked for by the profile are left out
    want = np.asarray(u_mm, dtype=float)
    zero = (0.0, np.zeros(len(names)))
    at = [rec.rows[keys[int(np.argmin(np.abs(keys - v)))]] if v > 0 else zero for v in want]
    F = np.array([a[0] for a in at])
    D = np.array([a[1] for a in at]) if names else None
    return ForcePath(want, F, D, float(keys[-1]) if len(keys) else 0.0, rec.profiles, rec.profile_dlogp)


def with_material(scene: Scene, name: str, value: float) -> Scene:
    """``scene`` with one material key (or one rise "shear_stress_steps_Pa[j]") set to ``value``."""
    j = _table_index(name)
    if j is None:
        return scene.with_changes(**{f"material.{name}": value})
    steps = list(scene.material.shear_stress_steps_Pa)
    steps[j] = value
    return scene.with_changes(**{f"material.{TABLE}": steps})


def finite_difference(scene: Scene, u_mm: Sequence[float] | np.ndarray, params: Sequence[str],
                      rel_step: float = 1e-4) -> np.ndarray:
    """The derivatives dF/d ln p by central differences of :func:`force_path` (2 runs per parameter).

    The check of the implicit derivative, and its cost to compare with.
    """
    cols = []
    for p in params:
        name = p.partition(".")[2]
        value = material_value(scene, name)
        up = force_path(with_material(scene, name, value * math.exp(rel_step)), u_mm).force_N
        dn = force_path(with_material(scene, name, value * math.exp(-rel_step)), u_mm).force_N
        cols.append((up - dn) / (2 * rel_step))
    return np.column_stack(cols)
