r"""Discretization error of a continuum run: the clamp force and the mid-axis profile.

Method (:data:`METHOD_ONE_STEP`, the default): at a converged load λ the state is carried over
to the same mesh with one order more (p + 1 for u and φ, Λ one up too), and one Newton step is
taken there at the same λ; that state is carried one order further (p + 2) and the same is done.
The error of the force is estimated by

.. math::  \eta_F = \max(\theta\,|F_p - F_{p+1}|,\ \theta_2\,|F_p - F_{p+2}|),
           \qquad \theta = 2.5,\ \theta_2 = 1.25

and that of the mid-axis profile by θ max|u_y,p − u_y,p+1|. Why these constants, and the
effectivities they give against reference-grade values (tables in tests/test_accuracy.py): the
error lives at the four singular clamp corners, where p + 1 on a fixed mesh recovers only part of
it (θ puts the effectivity in [0.5, 3]); the second level catches a p-sequence that stands still
for one order and never raises the estimate of a monotone one (θ₂(1 + q) ≤ θ for a ratio q ≤ 1);
docs/accuracy.md gives the numbers.

Guarantees: each one-step level is checked (the next simplified correction from the same
factorization is at most :data:`STEP_CONTRACTION` of the step), else Newton is run to convergence
at that level, starting from the one step's factorization and keeping one while its steps contract
by :data:`ENRICHED_REUSE` (chord steps: :mod:`ngbet.numerics.chord`). Where Newton fails at p + 1
(next to a limit point, after a snap-through, on locking or split corners) the estimate says it
cannot vouch: ``force_error_N`` is empty and ``error_estimate_unreliable`` says why. The p + 2 level
is taken by its one step only where that contracts, else the p + 1 estimate stands with a note
(``error_estimate_checks``); on graded meshes it is skipped after a p + 1 step that contracted by
more than :data:`PLATEAU_SKIP_CONTRACTION`. The estimate is paid at the load stops and the final
load only (``outputs.error_estimate``). Meshes without corner grading get the corner-refined
enrichment (:data:`METHOD_CORNER`), where p + 1 on the same mesh misses the corner error, and their
runs say in the summary that a graded mesh is more accurate for its cost.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..numerics.newton import NewtonReport, newton
from ..scene.document import Scene
from ..scene.numerical import Discretization
from ..scene.validate import AUTO
from .path_spread import RunPathSpread

__all__ = [
    "CORNER_LEVELS",
    "ENRICHED_REUSE",
    "ENRICHED_RTOL",
    "METHOD_CORNER",
    "METHOD_ONE_STEP",
    "PLATEAU_SKIP_CONTRACTION",
    "STEP_CONTRACTION",
    "THETA",
    "THETA_CORNER",
    "THETA_PLATEAU",
    "Estimate",
    "ForceErrorEstimator",
    "RunEstimates",
    "enriched_discretization",
    "estimate",
    "one_newton_step",
]

log = logging.getLogger(__name__)

#: safety factor θ: the enriched solution's own error is 30–75 % of the original's (measured)
THETA = 2.5
METHOD_ONE_STEP = "p+1 enriched, one Newton step on the same mesh, theta = 2.5"
METHOD_CORNER = "p+1 enriched, clamp corners bisected 3 times, one Newton step, theta = 2"
#: on meshes without corner grading: bisections of the corner elements in the enriched space
#: (0: the same mesh)
CORNER_LEVELS = 3
#: safety factor of the corner-refined enrichment (|F_p − F_enriched| is 0.45–0.95 of the error, measured)
THETA_CORNER = 2.0
#: Newton tolerance of the enriched solve (relative energy): the force to ~1e-7 relative
ENRICHED_RTOL = 1e-8
#: the enriched Newton keeps its factorization after a step that contracted by at most this
#: (:attr:`ngbet.numerics.newton.NewtonSettings.reuse_contraction`)
ENRICHED_REUSE = 0.25


#: factor on |F_p − F_p+2|, the plateau check: on a sequence converging monotonically with ratio
#: q ≤ 1 it is θ₂(1 + q)|F_p − F_p+1| ≤ 2.5 |F_p − F_p+1|, so it never raises the estimate there;
#: where F_p+1 ≈ F_p by chance it stands in (the error of F_p is |F_p − F_p+2| plus that of F_p+2)
THETA_PLATEAU = 1.25
#: the one enriched Newton step is trusted when the next correction (the simplified one, from the
#: same factorization) is at most this fraction of it: then the step's own error is of the order
#: of this fraction squared of the change, and F after one step is F_p+1 to a few per cent of
#: |F_p − F_p+1|; a larger contraction means the step is not in Newton's quadratic range
#: (a limit point, locking) and Newton is run to convergence at p + 1 instead
STEP_CONTRACTION = 0.1
#: on the same mesh (graded towards the corners) the p + 2 level is not tried where the one step at
#: p + 1 contracts by more than this: measured on the 12 such cases of the scenes of the effectivity
#: table (θ at p + 1 from 0.50 to 3072), the one step at p + 2 then contracted by 0.195 to 779, never
#: within :data:`STEP_CONTRACTION`, so the level only cost its factorization (0.1 s of the default
#: run's 0.75 s estimate at each load). On meshes without grading it did contract once after a
#: p + 1 step of 2.7 (bending off, h = 10 mm): there the level is always tried.
PLATEAU_SKIP_CONTRACTION = 0.5

#: an estimated force error above this fraction of the force is a run that its discretization does
#: not resolve: said as a warning (the coarse 25 mm mesh of a fabric scene: 48 %; the default
#: scene 0.2 %)
UNRESOLVED = 0.1


@dataclass(frozen=True)
class Estimate:
    """The estimated discretization error of one converged load step."""

    force_N: float  #: the run's force
    force_error_N: float  #: estimated |F_h − F| (nan: the estimate cannot vouch, see ``unreliable``)
    force_enriched_N: float  #: the force of the enriched discretization (p + 1)
    profile_error_mm: float  #: estimated max-norm error of the mid-axis u_y (nan without profile)
    method: str
    cost_s: float  #: wall time of the estimate
    newton_iterations: int
    #: the force one order further up (p + 2), the plateau check
    force_enriched2_N: float = math.nan
    #: why the estimate cannot vouch for the error ("" when it can)
    unreliable: str = ""
    path_spread_N: float = math.nan  #: the force's spread over the branches the path left (path_spread.py), in the bar

    @property
    def force_error_rel(self) -> float:
        """The estimated error relative to the force."""
        return self.force_error_N / abs(self.force_N) if self.force_N else math.nan


def enriched_discretization(disc: Discretization) -> Discretization:
    """The run's discretization one order up: u and φ at p + 1, Λ one up too (the mesh is the run's).

    Not validated as a scene is: at the highest order a scene may ask for (``MAX_ORDER``) the
    enriched space is one above it.
    """
    lam = AUTO if disc.order_lam == AUTO else int(disc.order_lam) + 1
    phi = AUTO if disc.order_phi == AUTO else int(disc.order_phi) + 1
    up = copy.copy(disc)
    for key, value in (("order_u", disc.order_u + 1), ("order_phi", phi), ("order_lam", lam), ("target_error", 0.0)):
        object.__setattr__(up, key, value)  # frozen: set on the copy, past the scene's bounds
    return up


class ForceErrorEstimator:
    """Estimates of the force (and profile) error of a run's problem at its converged loads.

    Parameters
    ----------
    solver : ngbet.continuum.solver.ContinuumSolver
        The run's solver; its problem's state is read, never changed. The enriched problems get
        solvers of their own with its settings.
    profile_points : int
        Points of the mid-axis profile (0: no profile estimate).
    """

    def __init__(self, solver: Any, profile_points: int = 0) -> None:
        self.solver, self.problem = solver, solver.problem
        self.profile_points = profile_points
        # without corner grading the error does not fall with p alone: enrich at the corners too
        self.corner = self.problem.scene.discretization.corner_mesh_size_mm <= 0 and CORNER_LEVELS > 0
        self.method = METHOD_CORNER if self.corner else METHOD_ONE_STEP
        self.theta = THETA_CORNER if self.corner else THETA
        self._enriched: Any = None  # p + 1
        self._enriched2: Any = None  # p + 2, on the same mesh as p + 1
        self.total_s = 0.0
        self.notes: dict[str, str] = {}  # load [mm] -> what the estimate there could not check
        self.last_contraction = math.nan  # of the one step of the last level

    def _build(self, up: int) -> Any:
        """The solver of the problem ``up`` orders above the run's, on the enrichment's mesh (the run's settings)."""
        from .mesh import corner_refined, singular_corners
        from .problem import ContinuumProblem
        from .solver import ContinuumSolver

        sc: Scene = self.problem.scene
        if up > 1:
            mesh = self._enriched.problem.mesh
        else:
            mesh = (
                corner_refined(self.problem.mesh, sc.specimen, CORNER_LEVELS, singular_corners(sc))
                if self.corner
                else self.problem.mesh
            )
        disc = sc.discretization
        for _ in range(up):
            disc = enriched_discretization(disc)
        return ContinuumSolver(
            ContinuumProblem(dataclasses.replace(sc, discretization=disc), mesh=mesh), self.solver.settings
        )

    def estimate(self, lam: float, force_N: float) -> Estimate:
        """The error estimate at the current (converged) state of the problem, load ``lam`` [m].

        Two enriched levels: F1 at p + 1 (from the run's state) and F2 at p + 2 (from the p + 1
        state); the estimate is max(θ|F_p − F1|, θ₂|F_p − F2|) (:data:`THETA_PLATEAU`), so that a
        p-sequence that stands still from p to p + 1 and moves on after (a plateau, or a sequence
        crossing its limit) is not read as converged. Each level takes one Newton step, checked by its contraction
        (:data:`STEP_CONTRACTION`); a step outside Newton's quadratic range is replaced by the
        converged Newton at that level, and where that fails the estimate cannot vouch for the
        error: ``force_error_N`` is nan and ``unreliable`` says why.
        """
        from . import observables as obs

        t0 = time.perf_counter()
        pb = self.problem
        if self._enriched is None:
            self._enriched = self._build(1)
        F1, its1, why = self._level(self._enriched, pb, lam)
        theta1, self.last_contraction = self.last_contraction, math.nan
        F2, its2, why2 = math.nan, 0, ""
        if not why and not self.corner and theta1 > PLATEAU_SKIP_CONTRACTION:
            self.notes[f"{lam * 1e3:g}"] = (
                f"no plateau check at p + 2: the one Newton step at p + 1 contracts by {theta1:.2g}, and on meshes "
                "graded towards the corners the step at p + 2 then does not contract either"
            )
        elif not why:
            if self._enriched2 is None:
                self._enriched2 = self._build(2)
            F2, its2, why2 = self._level(self._enriched2, self._enriched.problem, lam, converge=False)
            if why2:
                self.notes[f"{lam * 1e3:g}"] = f"no plateau check at p + 2: {why2}"
        prof = math.nan
        if self.profile_points and not why:
            _, uy = obs.midaxis_profile(pb, self.profile_points)
            _, uy_plus = obs.midaxis_profile(self._enriched.problem, self.profile_points)
            prof = self.theta * 1e3 * float(np.max(np.abs(uy - uy_plus)))
        dt = time.perf_counter() - t0
        self.total_s += dt
        if why:
            why = (
                f"no error bar: {why}; the run may stand near a limit point or a locking discretization, "
                "where the p-sequence says nothing about the error"
            )
            log.info("error estimate at u0 = %.4g mm: %s", lam * 1e3, why)
            return Estimate(force_N, math.nan, F1, prof, self.method, dt, its1 + its2, F2, why)
        err = self.theta * abs(force_N - F1)
        if math.isfinite(F2):
            err = max(err, THETA_PLATEAU * abs(force_N - F2))
        return Estimate(force_N, err, F1, prof, self.method, dt, its1 + its2, F2)

    def _level(self, enr: Any, src: Any, lam: float, converge: bool = True) -> tuple[float, int, str]:
        """The force of the solver ``enr`` at ``lam`` from the problem ``src``'s state: (F [N], iterations, why not).

        ``converge``: where the one step does not contract, run Newton to convergence (else give up:
        the p + 2 level, a check that is not worth a converged solve one order further up).
        """
        from . import observables as obs

        up = enr.problem
        for i in range(len(src.field_names)):
            up.gf.components[i].Set(src.gf.components[i])
        enr.state.set_load(lam)
        p_enr = up.scene.discretization.p_u
        x0 = enr.x.copy()
        r0 = enr.residual()
        report = one_newton_step(enr, r0)
        self.last_contraction = report.contraction
        log.debug("enriched step at p = %d: contraction %.3g", p_enr, report.contraction)
        if not report.converged or report.contraction > STEP_CONTRACTION:
            first = (
                f"one Newton step at p = {p_enr} contracts by {report.contraction:.2g}"
                if report.converged
                else f"one Newton step at p = {p_enr}: {report.reason}"
            )
            if not converge:
                return math.nan, report.iterations, f"{first} (not solved further)"
            enr.x[:] = x0
            settings = dataclasses.replace(
                self.solver.settings.newton,
                reuse_contraction=ENRICHED_REUSE,
                rtol=max(ENRICHED_RTOL, up.scene.solver.rtol),
            )
            # the one step's factorization is that at x0: Newton's first iteration reuses it
            report = newton(enr, settings, enr.energy(), factorized=True, r=r0)
            if not report.converged or report.residual is None:
                return (
                    math.nan,
                    report.iterations,
                    (
                        f"the enriched problem (p = {p_enr}) has no equilibrium that Newton reaches from the state "
                        f"one order below ({'; '.join(t for t in (first, report.reason) if t)})"
                    ),
                )
        assert report.residual is not None  # a converged report carries its residual
        return obs.reaction_force(up, report.residual) * up.scene.specimen.t, report.iterations, ""


def one_newton_step(problem: Any, r: np.ndarray | None = None) -> Any:
    """One full Newton step of ``problem`` (a Problem) from its state (whose residual is ``r`` when given).

    The report carries the new residual; ``converged`` means only that the step and the residual
    are finite. The problem's factorization is left at the starting state.
    """
    r = problem.residual() if r is None else r
    problem.factorize()
    dx = problem.solve(r)
    problem.x[:] += dx
    r = problem.residual()
    ok = bool(np.all(np.isfinite(dx)) and np.all(np.isfinite(r)))
    rep = NewtonReport(
        ok, 1, [abs(float(dx @ r))], [1.0], "one step" if ok else "not finite", residual=r if ok else None
    )
    if ok:  # the next (simplified) correction, from the same factorization: how far the step is from converged
        n = problem.state.norm(dx)
        rep.contraction = problem.state.norm(problem.solve(r)) / n if n > 0 else 0.0
    return rep


def estimate(solver: Any, lam: float, force_N: float, profile_points: int = 0) -> Estimate:
    """One-off :meth:`ForceErrorEstimator.estimate` of a run's solver (builds the enriched problem each call)."""
    return ForceErrorEstimator(solver, profile_points).estimate(lam, force_N)


class RunEstimates:
    """The estimates of one run: which steps get one, the results.csv column, the summary keys.

    ``outputs.error_estimate``: "stops" (the load stops and the final load), "every" (every
    converged step), "final", "off".
    Steps without an estimate get an empty ``force_error_N``. After a relaxation of the path the bar
    is the estimate plus the force's spread over the branches left (:mod:`ngbet.continuum.path_spread`).
    """

    def __init__(self, solver: Any) -> None:
        sc: Scene = solver.problem.scene
        self.mode = sc.outputs.error_estimate
        self.final = sc.loading.u0_mm
        self.stops = tuple(sc.loading.stops_mm) if self.mode == "stops" else ()
        self.estimator = (
            ForceErrorEstimator(solver, sc.outputs.profile_points if sc.outputs.profile else 0)
            if self.mode != "off" and sc.outputs.reaction
            else None
        )
        self.last: Estimate | None = None
        self.spread = RunPathSpread(solver)  # the path's relaxations tell it the branches they left
        self.profile_errors: dict[str, float] = {}
        self.unreliable: dict[str, str] = {}  # load [mm] -> why the estimate there cannot vouch
        self.worst: tuple[float, float, Estimate] | None = None  # (relative error, load [mm], estimate)
        d = sc.discretization
        self.note = (
            ""
            if d.corner_mesh_size_mm > 0
            else "the mesh is not graded towards the clamp corners, where most of the error lies: the "
            "estimate enriches them by bisection; a graded mesh is more accurate for its cost "
            "(set discretization.corner_mesh_size_mm, e.g. 0.25)"
        )

    def row(self, lam: float, force_N: float | None) -> dict[str, Any]:
        """``{"force_error_N": ...}`` for the results.csv row of the converged load ``lam`` [m]."""
        u0 = lam * 1e3
        due = self.mode == "every" or abs(u0 - self.final) < 1e-6 or any(abs(u0 - s) < 1e-6 for s in self.stops)
        if self.estimator is None or force_N is None or not due:
            return {"force_error_N": ""}
        e = self.last = self.spread.fold(lam, self.estimator.estimate(lam, force_N))
        if math.isfinite(e.profile_error_mm):
            self.profile_errors[f"{u0:g}"] = e.profile_error_mm
        if e.unreliable:
            self.unreliable[f"{u0:g}"] = e.unreliable
        rel = e.force_error_rel
        if math.isfinite(rel) and (self.worst is None or rel > self.worst[0]):
            self.worst = (rel, u0, e)
        spread = {"force_path_spread_N": e.path_spread_N} if math.isfinite(e.path_spread_N) else {}
        return {"force_error_N": e.force_error_N if math.isfinite(e.force_error_N) else "", **spread}

    def warnings(self) -> list[str]:
        """What the estimates say against the run: a force not resolved to :data:`UNRESOLVED` of itself.

        Said once, at the load of the largest relative error, naming the remedy.
        """
        if self.worst is None or not self.worst[0] > UNRESOLVED:
            return []
        rel, u0, e = self.worst
        return [
            f"the estimated discretization error of the force at {u0:g} mm is {rel:.0%} of it "
            f"({e.force_error_N:.2g} N of {e.force_N:.4g} N): the discretization does not resolve this run; "
            "discretization.target_error (ngbet run --accuracy 1e-2) lets ngbet choose one that does"
        ]

    def summary(self, solve_wall_s: float) -> dict[str, Any]:
        """Summary keys: the final estimate, the method, its cost and the solve time without it."""
        est_s = (self.estimator.total_s if self.estimator is not None else 0.0) + self.spread.cost_s
        out: dict[str, Any] = {"solve_s": solve_wall_s - est_s, "estimate_s": est_s}
        if self.estimator is None:
            return out
        e = self.last
        vouched = e is not None and math.isfinite(e.force_error_N)
        out.update(
            {
                "error_method": self.estimator.method,
                "force_N": e.force_N if e else math.nan,
                "force_error_N": e.force_error_N if e is not None and vouched else None,
                "force_error_rel": e.force_error_rel if e is not None and vouched else None,
                "profile_error_mm": self.profile_errors,
                "estimate_cost_fraction": est_s / max(solve_wall_s - est_s, 1e-12),
            }
        )
        if e is not None:
            out["force_enriched_N"] = [e.force_enriched_N, e.force_enriched2_N]
        if self.unreliable:
            out["error_estimate_unreliable"] = self.unreliable
        if self.estimator.notes:
            out["error_estimate_checks"] = self.estimator.notes
        if self.note:
            out["error_estimate_note"] = self.note
        out.update(self.spread.summary())
        return out
