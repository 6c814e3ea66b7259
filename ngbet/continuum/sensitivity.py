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
from dataclasses import dataclass
from typing import Any

import ngsolve as ngs
import numpy as np

from ..scene import Scene, SceneError
from . import physics

log = logging.getLogger(__name__)

#: material keys whose derivative the forms below know (the energy terms that read them)
DIFFERENTIABLE = ("K_el", "K_sh", "K_sh4", "K_sh6", "K_lock", "gamma_lock_deg", "alpha1", "alpha2")


@dataclass
class ForcePath:
    """Force at the requested clamp displacements; ``dlogp[i, k]`` = dF_i / d ln p_k [N]."""

    u_mm: np.ndarray
    force_N: np.ndarray
    dlogp: np.ndarray | None
    reached_mm: float


def _energy_derivative(problem: Any, name: str, value: float) -> ngs.CoefficientFunction:
    """∂W/∂p of the terms that read material key ``name``, at the trial functions of ``problem``."""
    scene: Scene = problem.scene
    mat, eff = vars(scene.material).copy(), scene.effects
    P = ngs.Parameter(value)
    mat[name] = P
    trial = problem.X.TrialFunction()
    inv = physics.invariants(ngs.Grad(trial[0]), problem.m1, problem.m2)
    if name == "K_el":
        W = physics.elongation_energy(inv.i4, inv.i6, P)
    elif name in ("alpha1", "alpha2"):
        if not eff.bending:
            return ngs.CoefficientFunction(0.0)
        W = physics.bending_energy(ngs.Grad(trial[1]), problem.m1, problem.m2, mat["alpha1"], mat["alpha2"])
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
    """u enters the energy through ∇u only; φ and Λ (when there) also as themselves."""
    g = ngs.Grad(trial[0])
    return _SAME_RULE * sum((ngs.InnerProduct(t, t) for t in list(trial)[1:]), ngs.InnerProduct(g, g))


def _check_params(scene: Scene, params: Sequence[str]) -> list[str]:
    names = []
    for p in params:
        section, _, key = p.partition(".")
        if section != "material" or key not in DIFFERENTIABLE:
            raise SceneError(f"cannot differentiate with respect to '{p}': known are "
                             f"{', '.join('material.' + k for k in DIFFERENTIABLE)}")
        names.append(key)
    return names


def force_path(scene: Scene, u_mm: Sequence[float] | np.ndarray, params: Sequence[str] = ()) -> ForcePath:
    """Run ``scene`` (continuum) with a load step landing on each of ``u_mm`` and return the
    force there, with dF/d ln p for each material key in ``params`` (``"material.K_sh"``, ...).

    Nothing is written to disk. Raises :class:`ngbet.errors.ConvergenceError` when the path
    cannot be followed to max(u_mm).
    """
    from .problem import ContinuumProblem
    from .run import newton_settings
    from .solver import continuation

    names = _check_params(scene, params)
    u = np.asarray(sorted(set(float(v) for v in u_mm if v > 0)))
    L = scene.loading
    scene = scene.with_changes(**{"loading.u0_mm": float(u[-1]), "loading.stops_mm": list(u[:-1])})
    if scene.solver.threads:
        ngs.SetNumThreads(scene.solver.threads)
    with ngs.TaskManager():
        problem = ContinuumProblem(scene)
        forms = []
        for n in names:
            f = ngs.BilinearForm(problem.X, symmetric=True)
            f += ngs.Variation(_energy_derivative(problem, n, getattr(scene.material, n)).Compile() * problem.dx)
            forms.append(f)
        g = problem.gf.vec.CreateVector()
        rows: dict[float, tuple[float, list[float]]] = {}
        t = scene.specimen.t

        def on_step(info: Any) -> None:
            key = round(info.lam * 1e3, 9)
            r = info.report.residual if info.report.residual is not None else problem.residual()
            F = float(r @ problem.psi_u.vec.FV().NumPy()) * t
            d = []
            if forms:
                psi = problem.load_tangent(1.0)  # ψ*: ψ on the clamps, H-orthogonal to the free dofs
                for n, f in zip(names, forms, strict=True):
                    f.Apply(problem.gf.vec, g)
                    d.append(getattr(scene.material, n) * float(psi @ g.FV().NumPy()) * t)
            rows[key] = (F, d)

        continuation(problem, u[-1] * 1e-3, L.first_step_mm * 1e-3, newton_settings(scene),
                     max_step=L.max_step_mm * 1e-3, min_step=L.min_step_mm * 1e-3,
                     stops=[s * 1e-3 for s in u], on_step=on_step)
    keys = np.array(sorted(rows))
    idx = [int(np.argmin(np.abs(keys - v))) for v in u]
    F = np.array([rows[keys[i]][0] for i in idx])
    D = np.array([rows[keys[i]][1] for i in idx]) if names else None
    return ForcePath(u, F, D, float(keys[-1]) if len(keys) else 0.0)


def finite_difference(scene: Scene, u_mm: Sequence[float] | np.ndarray, params: Sequence[str],
                      rel_step: float = 1e-4) -> np.ndarray:
    """dF/d ln p by central differences of :func:`force_path` (2 runs per parameter): the check
    of the implicit derivative, and its cost to compare with."""
    cols = []
    for p in params:
        value = getattr(scene.material, p.partition(".")[2])
        up = force_path(scene.with_changes(**{p: value * math.exp(rel_step)}), u_mm).force_N
        dn = force_path(scene.with_changes(**{p: value * math.exp(-rel_step)}), u_mm).force_N
        cols.append((up - dn) / (2 * rel_step))
    return np.column_stack(cols)
