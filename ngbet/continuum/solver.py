r"""The numerics of a continuum problem: its energy forms, linear solver, native code and timers.

A :class:`~ngbet.continuum.problem.ContinuumProblem` is the mathematics of one scene: the spaces,
the energy integrand E(x) (in parts), the Dirichlet data x_D = λ ψ_D on the clamps with the load λ
(u0 [m]), the state x and what a state means physically (reactions, admissibility). A
:class:`ContinuumSolver` is built from a problem and its :class:`~ngbet.numerics.settings.SolverSettings`
(made from the scene by :func:`ngbet.runner.settings.solver_settings`, the one translation) and
owns everything that is numerics, as NGSolve's ``NewtonSolver`` owns its inverse and Firedrake's
``NonlinearVariationalSolver(problem, solver_parameters=...)`` its linear algebra:

* the energy forms. NGSolve's ``BilinearForm`` is the owner of the Newton matrix: whether it
  condenses the element-local dofs (Λ), whether it stores the lower triangle only (for the sparse
  LDLᵀ, :func:`~ngbet.numerics.linear.energy_form`) and whether its integrand runs as native code
  (:mod:`ngbet.numerics.compiled`) are fixed when it is built, and all three are numerics. The
  problem hands over the integrand; the solver builds the form a(x; ·) = δE(x)[·] from it (and for
  the condensed exact Lagrangian the augmented form of the Newton matrix,
  :mod:`ngbet.numerics.linear`), and adds the problem's jamming barrier to them;
* the linear solver (:class:`~ngbet.numerics.linear.NewtonLinearSolver`: condensation, the sparse
  inverse, factorizations and solves) and the wall time and count of every assembly,
  factorization, solve and residual (``timers``, ``counts``).

The solver, not the problem, is the :class:`~ngbet.numerics.newton.Problem` that Newton
(:mod:`ngbet.numerics.newton`), the chord rows, the relaxation, the arc length and the
estimates drive: the protocol asks for factorizations and solves, which the problem does not
serve, and those modules talk to the protocol alone, as NGSolve's Newton to a form:

.. math::  r(x) = a(x; \cdot),\quad E(x),\quad J(x) = \partial r/\partial x,\quad
           dx = -J^{-1} r \text{ on the free dofs},\quad
           \partial x/\partial\lambda = (\psi_D, -J_{ff}^{-1} J_{fD}\,\psi_D)

The state x, the load λ (``set_load``), the unit-free norm, the clamp predictor, the watch of a
converged state and what is admissible are the problem's: the numerics reach them as
``solver.state`` (the problem itself, an :class:`~ngbet.numerics.newton.AdmissibleState`), and
``x`` is the same numpy view in both; physical queries (forces, observables, fields) go to the
problem too (``solver.problem``). An
enriched problem of the error estimate and a branch copy of the path spread get a solver of
their own with the same settings.
"""

from __future__ import annotations

import time
from typing import cast

import numpy as np

from ..numerics.compiled import add_energy
from ..numerics.linear import LinearSolver, NewtonLinearSolver, energy_form, pick_inverse
from ..numerics.settings import SolverSettings
from .patch import BarrierPatch
from .problem import ContinuumProblem

__all__ = ["ContinuumSolver"]


class ContinuumSolver:
    """The energy forms and linear algebra of a :class:`~ngbet.continuum.problem.ContinuumProblem`.

    Implements :class:`ngbet.numerics.newton.Problem`; where :attr:`can_relax` (its Newton matrix
    is a Hessian) also :class:`~ngbet.numerics.newton.Relaxable`.

    Parameters
    ----------
    problem : ContinuumProblem
        Spaces, energy, boundary conditions, load and state.
    settings : SolverSettings
        Its numerics (:func:`ngbet.runner.settings.solver_settings`); the linear algebra is read here,
        Newton's and the path's are kept for the problems derived from this one.
    """

    def __init__(self, problem: ContinuumProblem, settings: SolverSettings) -> None:
        self.problem, self.settings = problem, settings
        X, saddle = problem.X, problem.augmented_energy
        lin = settings.linear
        condense = lin.condense
        inverse = pick_inverse(
            lin.linear_solver, saddle is not None and not condense, condense, X.FreeDofs(condense).NumSet()
        )
        # Λ is element-local and its diagonal block is zero only for the exact Lagrangian
        self.a = energy_form(X, inverse, condense=condense and saddle is None)
        # the energy form is linearized unless the augmented Newton matrix of linear.py replaces it
        linearized = not (condense and saddle is not None)
        self.compile_mode = add_energy(self.a, problem.energy_parts, problem.dx, lin.compile, X.ndof, linearized)
        self.linear: LinearSolver = NewtonLinearSolver(
            self.a,
            condense,
            lin.linear_solver,
            saddle,
            problem.K_ref,
            problem.dx,
            lin.compile if self.compile_mode == "native" else "interpret",
        )
        forms = [(self.a, linearized)] if self.linear.form is self.a else [(self.a, False), (self.linear.form, True)]
        problem.jamming.add_to(forms)
        #: Newton on the barrier's elements with the rest held, before each linearization
        #: (:meth:`settle`): for a problem with the barrier and without a multiplier, else None
        jamming = problem.scene.effects.jamming
        self.patch = BarrierPatch(problem) if jamming and "lam" not in problem.field_names else None
        #: the problem as the numerics see it (:class:`~ngbet.numerics.newton.AdmissibleState`): the
        #: load, the Dirichlet entries, the norm, what is admissible
        self.state = problem
        self.x = problem.x  # the problem's state (a view of its GridFunction)
        self.dirichlet = problem.dirichlet  # its Dirichlet entries
        self._vec = problem.gf.vec
        self._r = self._vec.CreateVector()
        self._w = self._vec.CreateVector()
        self._w2 = self._vec.CreateVector()
        self._t_residual = 0.0
        self._n_residual = 0

    # --------------------------------------------------------------------------- what the run reports
    @property
    def timers(self) -> dict[str, float]:
        """Wall time [s] by kind: assembly, factorization, solve, residual."""
        return {**self.linear.timers, "residual_s": self._t_residual}

    @property
    def counts(self) -> dict[str, int]:
        """Factorizations, solves, residual evaluations."""
        return {**self.linear.counts, "residuals": self._n_residual}

    def ndofs(self) -> dict[str, int]:
        """Degrees of freedom per field, in all, and those left after condensation ("factorized")."""
        return {**self.problem.ndofs(), "factorized": int(sum(self.linear.freedofs))}

    # --------------------------------------------------------------------------- the forms
    def residual(self) -> np.ndarray:
        """r(x), full length (Dirichlet rows hold the reactions)."""
        t0 = time.perf_counter()
        self.a.Apply(self._vec, self._r)
        self._t_residual += time.perf_counter() - t0
        self._n_residual += 1
        return cast(np.ndarray, self._r.FV().NumPy().copy())

    def energy(self) -> float:
        """The total energy (Lagrangian) per unit thickness at x [J/m]."""
        return float(self.a.Energy(self._vec))

    def merit(self, r: np.ndarray) -> float:
        """The energy plus ½ρ‖Π(φ − i8)‖² at the state whose residual is ``r``: a merit for descent.

        Infinite where the material is inverted somewhere (det F ≤ 0): the descent stays among
        physical states. The Lagrangian alone is no merit off the constraint (Λ(φ − i8) can fall
        without bound); ‖Π(φ − i8)‖² is :meth:`ContinuumProblem.constraint_moments`, ρ the
        augmentation of the Newton matrix (or the penalty K).
        """
        pb = self.problem
        if pb.admissible():  # outside the energy's domain: the material would turn inside out
            return float("inf")
        E = self.energy()
        if "lam" not in pb.field_names:
            return E
        rho = self.linear.K_aug or pb.scene.effects.penalty_K
        return E + 0.5 * rho * pb.constraint_moments(r)

    def settle(self, tol: float, r: np.ndarray) -> int:
        """The residual on the unknowns of the barrier's elements solved, the rest held; the iterations (0: none).

        ``r`` (the residual at the current state) is brought to the state settled in place:
        :meth:`BarrierPatch.settle` (:class:`~ngbet.numerics.newton.Settling`); 0 without a patch.
        """
        return self.patch.settle(tol, r) if self.patch is not None else 0

    # --------------------------------------------------------------------------- linear algebra
    def factorize(self, shift: float = 0.0) -> float:
        """Linearize at the current state and factorize.

        ``shift`` > 0: the diagonal raised by s |diag|, s ≥ shift enough for a positive definite
        matrix where that can be tested (:meth:`NewtonLinearSolver.factorize`); returns s.
        """
        return self.linear.factorize(self._vec, shift)

    def solve(self, r: np.ndarray) -> np.ndarray:
        """The correction −J⁻¹ r on the free entries, 0 on Dirichlet entries (last factorization)."""
        self._w.FV().NumPy()[:] = r
        self.linear.solve_into(self._w, self._w2)
        dx = -self._w2.FV().NumPy()
        dx[self.dirichlet] = 0.0
        return cast(np.ndarray, dx)

    def load_tangent(self, dlam: float) -> np.ndarray:
        """The load tangent times dlam: Dirichlet entries moved by dlam, the others −J⁻¹ J_fd dlam."""
        dirichlet = self.dirichlet
        d = dlam * self.problem.load_direction
        self._w2.FV().NumPy()[:] = d
        self._w.data = self.linear.mat * self._w2
        dx = self.solve(self._w.FV().NumPy())
        dx[dirichlet] = d[dirichlet]
        if self.linear.condensed:  # local dofs follow the Dirichlet move through the extension
            self._w2.FV().NumPy()[:] = np.where(dirichlet, d, 0.0)
            self._w.data = self.linear.form.harmonic_extension * self._w2
            dx += self._w.FV().NumPy() * ~dirichlet
        return dx

    def load_derivative(self, psi: np.ndarray, tangent: np.ndarray) -> float:
        """psi·(J tangent) with the Jacobian at hand: dR/dλ of the reaction R = psi·r along ∂x/∂λ."""
        self._w2.FV().NumPy()[:] = tangent
        self._w.data = self.linear.mat * self._w2
        return float(psi @ self._w.FV().NumPy())

    @property
    def can_relax(self) -> bool:
        """Whether the Newton matrix is a Hessian (condensed, or no multiplier).

        Then energy descent and the stability test work (:func:`ngbet.numerics.relax.relax`).
        """
        return self.linear.condensed or "lam" not in self.problem.field_names

    def lowest_mode(self) -> tuple[float, np.ndarray]:
        """The lowest eigenvalue of the scaled tangent at the current state and its mode (full length)."""
        from .stability import lowest_eigenpair

        mu, mode = lowest_eigenpair(self)
        self._w.FV().NumPy()[:] = mode
        self.linear.extend(self._w)  # the condensed local dofs follow
        full = self._w.FV().NumPy().copy()
        full[self.dirichlet] = 0.0
        return mu, full
