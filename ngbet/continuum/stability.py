r"""Stability diagnosis of the continuum at the last converged load, after a failed increment.

For minimization (and condensed mixed) formulations the tangent is the Hessian of the reduced
energy: a non-positive eigenvalue means the equilibrium path has lost stability (a limit point or
a bifurcation). With φ in the model the lowest mode (δu, δφ) is classified by
r = ‖δφ − δi8‖ / ‖δi8‖, δi8 the linearization of i8 in the direction δu (NGSolve's ``Diff`` of
the i8 coefficient function): r ≪ 1 is a mode of the constrained continuum (the model's own
instability), r ≈ 1 a mode in which i8 varies inside elements and φ does not follow, which the
constraint Λ ∈ L2(p − 2) cannot see (a mode of the discretization, suppressed by
``effects.stabilization_K``). With α_i = 0 the diagnosis also measures where the first-gradient
energy has lost ellipticity for family i (the model is ill-posed there).

:func:`diagnose_stability` returns a :class:`StabilityDiagnosis`; the error message is written
from it (:meth:`StabilityDiagnosis.message`). It costs seconds: only computed after a failure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol

import ngsolve as ngs
import numpy as np
import scipy.sparse as sps
from scipy.sparse.linalg import eigsh

from . import observables as obs
from . import physics

if TYPE_CHECKING:
    from ..numerics.linear import LinearSolver
    from .problem import ContinuumProblem

__all__ = [
    "DISCRETIZATION_MODE_RATIO",
    "EllipticityLoss",
    "ModeClass",
    "StabilityDiagnosis",
    "TangentSolver",
    "diagnose_stability",
    "indefinite_by_construction",
    "lowest_eigenpair",
    "mode_constraint_ratio",
]

#: r above which the lowest mode is one of the discretization (φ does not follow i8)
DISCRETIZATION_MODE_RATIO = 0.5

ModeClass = Literal["discretization", "continuum", "none"]


class TangentSolver(Protocol):
    """What the diagnosis reads of a solver (:class:`~ngbet.continuum.solver.ContinuumSolver`).

    Its problem, its linear solver and the factorization of the tangent at the current state.
    """

    problem: ContinuumProblem
    linear: LinearSolver

    def factorize(self, shift: float = 0.0) -> float:
        """Linearize at the current state and factorize, the diagonal raised by >= ``shift``; returns the shift."""
        ...


@dataclass(frozen=True)
class EllipticityLoss:
    """Where the first-gradient energy is not elliptic for the yarns of a family without bending stiffness."""

    family: int
    area_mm2: float
    min_eigenvalue_Ksh: float  # lowest eigenvalue of its Hessian there, in units of K_sh


@dataclass(frozen=True)
class StabilityDiagnosis:
    """What the tangent at the last converged state says.

    Attributes
    ----------
    u0_mm : float
        The load of the state [mm].
    eigenvalues : tuple of float
        The lowest eigenvalues of the diagonally scaled (unit-free) tangent, ascending; empty
        when no test was made (see ``skipped``).
    mode_class : {"discretization", "continuum", "none"}
        The class of the lowest mode by ``ratio`` ("none": the model has no φ, or no test).
    ratio : float
        r = ‖δφ − δi8‖ / ‖δi8‖ of the lowest mode (NaN without φ).
    location_mm : tuple of float or None
        The centroid (X, Y) [mm] of |∇δu|² of the lowest mode.
    ellipticity_loss : tuple of EllipticityLoss
        Families with α = 0 whose first-gradient energy has lost ellipticity somewhere.
    stabilization_K_Pa : tuple of float
        The smallest and largest K_s over the elements.
    K_el : float
        material.K_el [Pa] (the remedy names it).
    skipped : str
        Why no test was made ("" when it was).
    """

    u0_mm: float
    eigenvalues: tuple[float, ...] = ()
    mode_class: ModeClass = "none"
    ratio: float = math.nan
    location_mm: tuple[float, float] | None = None
    ellipticity_loss: tuple[EllipticityLoss, ...] = ()
    stabilization_K_Pa: tuple[float, float] = (0.0, 0.0)
    K_el: float = 0.0
    skipped: str = ""

    @property
    def stable(self) -> bool | None:
        """Whether the tangent is positive definite (None: not tested)."""
        return None if not self.eigenvalues else self.eigenvalues[0] > 0

    @property
    def stabilization_to_try(self) -> float | None:
        """The ``effects.stabilization_K`` [Pa] to try against a mode of the discretization, or None.

        K_el where the smallest K_s is below it (the mildest that suppressed the modes measured:
        stiff yarns, no shear energy); else ten times the smallest K_s, at most
        :data:`~ngbet.continuum.problem.STABILIZATION_CAP` K_el (±30° yarns needed 10 K_el after
        K_el); None at that cap, beyond which K_s only hurts the conditioning, or without K_el.
        """
        from .problem import STABILIZATION_CAP

        lo = self.stabilization_K_Pa[0]
        cap = STABILIZATION_CAP * self.K_el
        if self.K_el <= 0 or lo >= cap * (1 - 1e-9):
            return None
        return self.K_el if lo < self.K_el * (1 - 1e-9) else min(10.0 * lo, cap)

    def _stabilization_text(self, command: bool) -> str:
        """The remedy of a mode of the discretization: the K_s to try, or why none is named."""
        from .problem import STABILIZATION_CAP

        lo, hi = self.stabilization_K_Pa
        k = self.stabilization_to_try
        cap = f"{STABILIZATION_CAP:g} material.K_el"
        if k is None:
            return (
                f"effects.stabilization_K (now {lo:.3g} to {hi:.3g} Pa) is at {cap} or more, beyond which it only "
                "hurts the conditioning"
            )
        if k == self.K_el:
            to = (
                f" to about the yarns' elongation modulus: --set effects.stabilization_K={k:.3g} (material.K_el "
                "stays as it is)"
                if command
                else f", e.g. to material.K_el = {k:.3g} Pa"
            )
        else:
            lead = " " if command else ", e.g. "
            to = f"{lead}to {k:.3g} Pa (--set effects.stabilization_K={k:.3g}; at most {cap})"
        return f"raise effects.stabilization_K (now {lo:.3g} to {hi:.3g} Pa){to}"

    def advice(self) -> str:
        """Cause and remedy in one sentence for the terminal ("" when the diagnosis names no remedy)."""
        if self.ellipticity_loss:
            e = self.ellipticity_loss[0]
            return (
                f"alpha{e.family} = 0 leaves the model ill-posed for the compressed yarns of family "
                f"{e.family} ({e.area_mm2:.0f} mm² lost ellipticity): give alpha{e.family} > 0"
            )
        if self.mode_class == "discretization":
            remedy = self._stabilization_text(False)
            return f"an unstable mode of the discretization at u0 = {self.u0_mm:.4g} mm: {remedy}"
        if self.mode_class == "continuum" and self.stable is False:
            return (
                f"the model's own limit point or bifurcation at u0 = {self.u0_mm:.4g} mm: "
                "solver.path_following = 'auto' follows the path through it"
            )
        return ""

    def message(self) -> str:
        """The diagnosis in words (for the error message)."""
        if self.skipped:
            return self.skipped
        state = "lost (the tangent is not positive definite)" if not self.stable else "kept"
        msg = (
            f"stability at the last converged load u0 = {self.u0_mm:.4g} mm: lowest scaled eigenvalues of "
            f"the tangent {list(self.eigenvalues)}; stability {state}"
        )
        if self.mode_class == "none":
            return msg
        ill = "".join(
            f"; alpha{e.family} = 0 leaves i8 unregularized along the yarns of family {e.family}, and the "
            f"first-gradient energy has lost ellipticity for them on {e.area_mm2:.0f} mm² (compressed yarns; "
            f"min eigenvalue {e.min_eigenvalue_Ksh:.2f} K_sh): the model is ill-posed there and has no "
            f"mesh-independent solution; give alpha{e.family} > 0"
            for e in self.ellipticity_loss
        )
        if self.mode_class == "discretization":
            kind = "a mode of the discretization: i8 varies inside the elements and phi does not follow"
            if not self.ellipticity_loss:
                kind += f"; {self._stabilization_text(True)}"
        else:
            kind = (
                "a mode of the constrained continuum (phi follows i8): the model's own limit point or "
                "bifurcation; solver.path_following = 'auto' follows the path through it and reports its kind"
            )
        x, y = self.location_mm or (math.nan, math.nan)
        return (
            f"{msg}; lowest mode near (X, Y) = ({x:.0f}, {y:.0f}) mm with |dphi - di8| / |di8| = "
            f"{self.ratio:.2f}: {kind}{ill}"
        )


def diagnose_stability(solver: TangentSolver, k: int = 3) -> StabilityDiagnosis:
    """The lowest eigenvalues of the (condensed) tangent at the current state and what its lowest mode is.

    ``solver``: the problem's (:class:`~ngbet.continuum.solver.ContinuumSolver`), whose tangent is
    analysed. Never raises: a failed eigenvalue computation is reported in ``skipped`` (the diagnosis
    must not hide the error it explains).
    """
    problem = solver.problem
    u0_mm = problem.lam * 1e3
    try:
        if indefinite_by_construction(solver):
            return StabilityDiagnosis(
                u0_mm, skipped="the uncondensed saddle-point tangent is indefinite by construction: no stability test"
            )
        ev, V, d, fd = _lowest_scaled(solver, k)
        eigenvalues = tuple(sorted(map(float, ev)))
        base = StabilityDiagnosis(
            u0_mm,
            eigenvalues,
            stabilization_K_Pa=tuple(problem.K_s_range),  # type: ignore[arg-type]
            K_el=problem.scene.material.K_el,
        )
        if problem.phi is None:
            return base
        x = np.zeros(problem.X.ndof)
        x[fd] = V[:, int(np.argmin(ev))] / d
        r, where = mode_constraint_ratio(solver, x)
        mode: ModeClass = "discretization" if r > DISCRETIZATION_MODE_RATIO else "continuum"
        return StabilityDiagnosis(
            u0_mm, eigenvalues, mode, r, where, _ellipticity_losses(problem), base.stabilization_K_Pa, base.K_el
        )
    except Exception as exc:  # noqa: BLE001 - the diagnosis must never hide the original error
        return StabilityDiagnosis(u0_mm, skipped=f"stability check failed: {exc}")


def lowest_eigenpair(solver: TangentSolver) -> tuple[float, np.ndarray]:
    """The lowest eigenvalue of the diagonally scaled tangent at the current state and its mode (full length).

    The mode holds the free dofs of the (condensed) tangent, scaled to unit maximum norm (the
    condensed local dofs are 0: :func:`mode_constraint_ratio` and :func:`ngbet.runner.fields.write_mode` extend it).
    """
    if indefinite_by_construction(solver):
        raise ValueError("the uncondensed saddle-point tangent is indefinite by construction: no stability test")
    ev, V, d, fd = _lowest_scaled(solver, 1)
    x = np.zeros(solver.problem.X.ndof)
    x[fd] = V[:, 0] / d
    return float(ev[0]), x / max(float(np.max(np.abs(x))), 1e-300)


def indefinite_by_construction(solver: TangentSolver) -> bool:
    """True when the tangent keeps the multiplier Λ (uncondensed): a saddle point, no stability test."""
    return not solver.linear.condensed and "lam" in solver.problem.field_names


def _lowest_scaled(solver: TangentSolver, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The k lowest eigenpairs of the diagonally scaled (unit-free) tangent at the current state.

    Returns (eigenvalues, eigenvectors of the scaled matrix, the scaling d, the free dofs).
    """
    solver.factorize()
    A, fd = solver.linear.free_matrix()
    d = np.sqrt(np.abs(A.diagonal()) + 1e-300)
    # a fixed start vector: ARPACK's default is random, and a relaxation kicked along the mode would
    # make runs that snap differ in their last digits from one run to the next
    ev, V = eigsh(sps.diags(1 / d) @ A @ sps.diags(1 / d), k=k, sigma=-1e-3, which="LM", v0=np.ones(A.shape[0]))
    return ev, V, d, fd


def _ellipticity_losses(problem: ContinuumProblem) -> tuple[EllipticityLoss, ...]:
    m = problem.scene.material
    out = []
    for fam, alpha in ((1, m.alpha1), (2, m.alpha2)):
        if alpha == 0:
            area, lo_H = obs.ellipticity_loss_area(problem, fam)
            if area > 0:
                out.append(EllipticityLoss(fam, float(area), float(lo_H)))
    return tuple(out)


def mode_constraint_ratio(solver: TangentSolver, x: np.ndarray) -> tuple[float, tuple[float, float]]:
    """R = ‖δφ − δi8‖ / ‖δi8‖ of a mode x, and the centroid [mm] of |∇δu|².

    ``x`` holds the free dofs of the (condensed) tangent; the condensed local dofs are recovered by
    the harmonic extension (``solver``'s). δi8 is NGSolve's derivative of i8(∇u) in the direction ∇δu.
    """
    problem = solver.problem
    mode = ngs.GridFunction(problem.X)
    mode.vec.FV().NumPy()[:] = x
    solver.linear.extend(mode.vec)
    du, dphi = mode.components[0], mode.components[1]
    grad = ngs.CoefficientFunction(ngs.Grad(problem.u)).MakeVariable()
    G = ngs.Grad(du)
    di8 = physics.invariants(grad, problem.m1, problem.m2).i8.Diff(grad, G)
    mesh = problem.mesh
    num = ngs.Integrate((dphi - di8) ** 2, mesh)
    den = ngs.Integrate(di8 * di8, mesh)
    dens = ngs.InnerProduct(G, G)
    tot = ngs.Integrate(dens, mesh)
    where = (1e3 * ngs.Integrate(dens * ngs.x, mesh) / tot, 1e3 * ngs.Integrate(dens * ngs.y, mesh) / tot)
    return float(np.sqrt(num / max(den, 1e-300))), where
