r"""Discretization error of a continuum run: the clamp force and the mid-axis profile.

Method (:data:`METHOD_ONE_STEP`, the default): at a converged load λ the state is carried over
to the same mesh with one order more (p + 1 for u and φ, Λ one up too), and one Newton step is
taken there at the same λ (the linearization of the enriched problem at the carried state: a
one-step, dual-weighted-residual-like estimate of F_p+1). The error of the force is estimated by

.. math::  \eta_F = \theta\,|F_p - F_{p+1}|,\qquad \theta = 2.5

and that of the mid-axis profile by θ max|u_y,p − u_y,p+1|. With ``one_step=False``
(:data:`METHOD`) Newton is run to convergence at p + 1 instead. Why (measured against
reference-grade values, :mod:`ngbet.studies.reference`, table in tests/test_accuracy.py):

* the error lives at the four singular clamp corners, where raising p on a fixed mesh gains
  slowly: the enriched error is 30–75 % of the original's, so |F_p − F_p+1| is 0.25–0.7 of the
  error and θ = 2.5 puts the effectivity at 0.56–2.9 on the 17 scenes of the table (one step;
  converged enriched Newton: 0.56–2.7);
* one step instead of the converged enriched Newton: the same estimate within 3 % on uniform
  meshes and 30 % lower on the graded p = 3 meshes (the enriched Newton needs 2–4 iterations
  there), at 0.13–0.57 of the run's solve per estimated load instead of 0.4–2.9; and a step
  always exists (the converged enriched Newton fails at p = 6 → 7 at 56 mm);
* an enriched solve on a mesh refined at the corners sees the corner error better, but Newton
  from the carried-over state does not converge there (the corner solution of the finer mesh is
  too far from the coarse one at 37–56 mm); only a full load continuation would do, at 2–4
  times the cost of the run;
* a dual-weighted residual needs the same enriched space (the dual solution in the run's own
  space is orthogonal to the residual), so it costs the same factorization;
* it is paid at the load stops and the final load only (``outputs.error_estimate``), not at the
  intermediate steps (``cost_s``).

Limitation: where the error does not fall with p at all on a fixed mesh, the estimate misses it,
and where the p-sequence crosses the limit it overshoots. Measured with α1 = 200 Pa m² (an error
of 0.28 %): on the uniform h = 10 mm mesh F = 66.76 N at p = 2 and 66.78 N at p = 3 against
66.577 N (effectivity 0.11); graded to 0.5 mm the same scene gives 2.9. A run
without corner grading says in its summary that the estimate may miss the corner error.

Failure of the enriched step or Newton (a non-finite result) gives an estimate of ``nan`` with
a warning; the run's result is kept.
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

from ..scene import AUTO, Discretization, Scene

log = logging.getLogger(__name__)

METHOD = "p+1 enriched Newton on the same mesh, theta = 2.5"
#: safety factor θ: the enriched solution's own error is 30–75 % of the original's (measured)
THETA = 2.5
METHOD_ONE_STEP = "p+1 enriched, one Newton step on the same mesh, theta = 2.5"
#: one linearized step at p + 1 instead of the converged enriched Newton (see the module docstring)
ONE_STEP = True
METHOD_CORNER = "p+1 enriched, clamp corners bisected 3 times, one Newton step, theta = 2"
#: on meshes without corner grading: bisections of the corner elements in the enriched space
#: (0: the same mesh)
CORNER_LEVELS = 3
#: safety factor of the corner-refined enrichment (|F_p − F_enriched| is 0.45–0.95 of the error, measured)
THETA_CORNER = 2.0
#: Newton tolerance of the enriched solve (relative energy): the force to ~1e-7 relative
ENRICHED_RTOL = 1e-8


@dataclass(frozen=True)
class Estimate:
    """The estimated discretization error of one converged load step."""

    force_N: float  #: the run's force
    force_error_N: float  #: estimated |F_h − F|
    force_enriched_N: float  #: the force of the enriched discretization
    profile_error_mm: float  #: estimated max-norm error of the mid-axis u_y (nan without profile)
    method: str
    cost_s: float  #: wall time of the estimate
    newton_iterations: int

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
    """Estimates of the force (and profile) error of ``problem`` at its converged loads.

    Parameters
    ----------
    problem : ngbet.continuum.problem.ContinuumProblem
        The run's problem; its state is read, never changed.
    profile_points : int
        Points of the mid-axis profile (0: no profile estimate).
    """

    def __init__(self, problem: Any, profile_points: int = 0, one_step: bool = ONE_STEP) -> None:
        self.problem = problem
        self.profile_points = profile_points
        self.one_step = one_step
        # without corner grading the error does not fall with p alone: enrich at the corners too
        self.corner = problem.scene.discretization.corner_mesh_size_mm <= 0 and one_step and CORNER_LEVELS > 0
        self.method = METHOD_CORNER if self.corner else METHOD_ONE_STEP if one_step else METHOD
        self.theta = THETA_CORNER if self.corner else THETA
        self._enriched: Any = None
        self.total_s = 0.0

    def _build(self) -> Any:
        from .mesh import corner_refined
        from .problem import ContinuumProblem

        sc: Scene = self.problem.scene
        mesh = corner_refined(self.problem.mesh, sc.specimen, CORNER_LEVELS) if self.corner else self.problem.mesh
        return ContinuumProblem(dataclasses.replace(sc, discretization=enriched_discretization(sc.discretization)),
                                mesh=mesh)

    def estimate(self, lam: float, force_N: float) -> Estimate:
        """The error estimate at the current (converged) state of the problem, load ``lam`` [m]."""
        from . import observables as obs
        from .run import newton_settings
        from .solver import newton

        t0 = time.perf_counter()
        if self._enriched is None:
            self._enriched = self._build()
        enr, pb = self._enriched, self.problem
        for i in range(len(pb.field_names)):
            enr.gf.components[i].Set(pb.gf.components[i])
        enr.set_load(lam)
        if self.one_step:
            report = one_newton_step(enr)
        else:
            settings = dataclasses.replace(newton_settings(pb.scene), rtol=max(ENRICHED_RTOL, pb.scene.solver.rtol))
            report = newton(enr, settings, enr.energy())
        if not report.converged or report.residual is None:
            log.warning("error estimate at u0 = %.4g mm: the enriched Newton did not converge (%s)",
                        lam * 1e3, report.reason)
            dt = time.perf_counter() - t0
            self.total_s += dt
            return Estimate(force_N, math.nan, math.nan, math.nan, self.method, dt, report.iterations)
        F_plus = obs.reaction_force(enr, report.residual) * pb.scene.specimen.t
        prof = math.nan
        if self.profile_points:
            _, uy = obs.midaxis_profile(pb, self.profile_points)
            _, uy_plus = obs.midaxis_profile(enr, self.profile_points)
            prof = self.theta * 1e3 * float(np.max(np.abs(uy - uy_plus)))
        dt = time.perf_counter() - t0
        self.total_s += dt
        return Estimate(force_N, self.theta * abs(force_N - F_plus), F_plus, prof, self.method, dt, report.iterations)


def one_newton_step(problem: Any) -> Any:
    """One full Newton step of ``problem`` from its state.

    The report carries the new residual; ``converged`` means only that the step and the residual
    are finite.
    """
    from .solver import NewtonReport

    r = problem.residual()
    problem.factorize()
    dx = problem.solve(r)
    problem.x[:] += dx
    r = problem.residual()
    ok = bool(np.all(np.isfinite(dx)) and np.all(np.isfinite(r)))
    return NewtonReport(ok, 1, [abs(float(dx @ r))], [1.0], "one step" if ok else "not finite",
                        residual=r if ok else None)


def estimate(problem: Any, lam: float, force_N: float, profile_points: int = 0) -> Estimate:
    """One-off :meth:`ForceErrorEstimator.estimate` (builds the enriched problem each call)."""
    return ForceErrorEstimator(problem, profile_points).estimate(lam, force_N)


# ------------------------------------------------------------------------------------------------
# accuracy on demand
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Rung:
    """One candidate discretization of :data:`LADDER`."""

    mesh_size_mm: float
    corner_mesh_size_mm: float
    order_u: int
    #: relative force error at 56 mm on the paper's scene against the reference (measured)
    expected_error: float

    def apply(self, scene: Scene) -> Scene:
        """``scene`` on this rung's discretization, with the estimate at the final load."""
        d = dataclasses.replace(scene.discretization, mesh_size_mm=self.mesh_size_mm, order_u=self.order_u,
                                order_phi=AUTO, order_lam=AUTO, corner_mesh_size_mm=self.corner_mesh_size_mm,
                                corner_bisections=0, structured=False, target_error=0.0)
        return dataclasses.replace(scene, discretization=d,
                                   outputs=dataclasses.replace(scene.outputs, error_estimate="final"))


#: Candidate discretizations, cheapest first, all graded to 0.25 mm at the clamp corners: h = 10 mm
#: at p = 2 and 3, then h = 20 mm at p = 4, 5, 6, 8 and 10 (at p >= 4 the bulk error of the 20 mm
#: mesh is negligible: 107.24349 N against 107.24387 N on the 10 mm mesh at p = 8, at a quarter of
#: the time), then h = 10 mm at p = 8 should those not converge (h = 20 mm, p = 7 stops at 55.7 mm).
#: Expected errors: the paper's scene at 56 mm against the reference 107.2365 N
#: (ngbet.studies.reference). Whole-run times there (2-core machine, loaded): 0.3, 0.5, 0.4–0.7,
#: 0.8–1.4, 1.4, 6–8, 34, 56–70 s. Finer corners do not help: 0.1 mm at p = 5, 0.125 mm at p = 6
#: and 0.0625 mm at p = 4 stop before 56 mm.
LADDER = tuple(Rung(h, 0.25, p, e) for h, p, e in (
    (10.0, 2, 1.6e-3), (10.0, 3, 1.3e-3), (20.0, 4, 6.7e-4), (20.0, 5, 3.5e-4), (20.0, 6, 1.8e-4),
    (20.0, 8, 6.5e-5), (20.0, 10, 2.5e-5), (10.0, 8, 6.9e-5)))
#: a rung is expected to meet a target if its error is below this fraction of it: the estimate
#: (θ |F_p − F_p+1|, the differences shrinking by 0.5–0.7 per order) is 0.75–1.25 times the error,
#: so that 0.7 of the target leaves the estimate below it
EXPECTED_MARGIN = 0.7


def first_rung(target: float) -> int:
    """The cheapest rung whose expected error is below :data:`EXPECTED_MARGIN` times the target.

    The last rung when none is.
    """
    for i, r in enumerate(LADDER):
        if r.expected_error <= EXPECTED_MARGIN * target:
            return i
    return len(LADDER) - 1


def run_to_accuracy(scene: Scene, out: Any, run_one: Any) -> dict[str, Any]:
    """Run ``scene`` on the cheapest rung of :data:`LADDER` that meets ``discretization.target_error``.

    The estimated force error at the final load decides; the run climbs the ladder while it is above
    the target.

    ``run_one(scene, out) -> summary`` runs one discretization into ``out`` (the last attempt's
    files stay there). The returned summary (the runner adds it to summary.json) gains
    ``accuracy``: the target, the chosen discretization, whether it was met, and every attempt
    with its estimate and times.
    """
    target = scene.discretization.target_error
    attempts: list[dict[str, Any]] = []
    summary: dict[str, Any] = {}
    from ..errors import ConvergenceError

    rungs = LADDER[first_rung(target):]
    for k, rung in enumerate(rungs):
        t0 = time.perf_counter()
        try:
            summary = run_one(rung.apply(scene), out)
        except ConvergenceError as e:
            if k == len(rungs) - 1:
                raise
            log.warning("%s: %s; trying the next setting", rung, str(e).splitlines()[0])
            attempts.append({"discretization": dataclasses.asdict(rung), "force_error_rel": math.nan,
                             "force_N": None, "wall_s": time.perf_counter() - t0, "solve_s": None,
                             "estimate_s": None, "failed": str(e).splitlines()[0]})
            continue
        rel = summary.get("force_error_rel", math.nan)
        attempts.append({"discretization": dataclasses.asdict(rung), "force_error_rel": rel,
                         "force_N": summary.get("force_N"), "wall_s": time.perf_counter() - t0,
                         "solve_s": summary.get("solve_s"), "estimate_s": summary.get("estimate_s")})
        if math.isfinite(rel) and rel <= target:
            break
        log.info("estimated error %.3g above the target %.3g: refining", rel, target)
    met = bool(attempts and math.isfinite(attempts[-1]["force_error_rel"])
               and attempts[-1]["force_error_rel"] <= target)
    summary["accuracy"] = {"target_error": target, "met": met, "chosen": attempts[-1]["discretization"],
                           "attempts": attempts, "wall_s": sum(a["wall_s"] for a in attempts),
                           "solve_s": sum(a["solve_s"] or 0.0 for a in attempts)}
    if not met:
        msg = (f"discretization.target_error = {target:g} not reached: the finest setting ngbet offers "
               f"estimates {attempts[-1]['force_error_rel']:.2g}")
        summary.setdefault("warnings", []).append(msg)
        log.warning("%s", msg)
    return summary


class RunEstimates:
    """The estimates of one run: which steps get one, the results.csv column, the summary keys.

    ``outputs.error_estimate``: "stops" (the load stops and the final load), "every" (every
    converged step), "final", "off".
    Steps without an estimate get an empty ``force_error_N``.
    """

    def __init__(self, problem: Any) -> None:
        sc: Scene = problem.scene
        self.mode = sc.outputs.error_estimate
        self.final = sc.loading.u0_mm
        self.stops = tuple(sc.loading.stops_mm) if self.mode == "stops" else ()
        self.estimator = (ForceErrorEstimator(problem, sc.outputs.profile_points if sc.outputs.profile else 0,
                                              one_step=ONE_STEP)
                          if self.mode != "off" and sc.outputs.reaction else None)
        self.last: Estimate | None = None
        self.profile_errors: dict[str, float] = {}
        d = sc.discretization
        self.note = ("" if d.corner_mesh_size_mm > 0 else
                     "the mesh is not graded towards the clamp corners, where most of the error lies: the "
                     "estimate enriches them by bisection; a graded mesh is more accurate for its cost "
                     "(set discretization.corner_mesh_size_mm, e.g. 0.25)")

    def row(self, lam: float, force_N: float | None) -> dict[str, Any]:
        """``{"force_error_N": ...}`` for the results.csv row of the converged load ``lam`` [m]."""
        u0 = lam * 1e3
        due = (self.mode == "every" or abs(u0 - self.final) < 1e-6
               or any(abs(u0 - s) < 1e-6 for s in self.stops))
        if self.estimator is None or force_N is None or not due:
            return {"force_error_N": ""}
        e = self.estimator.estimate(lam, force_N)
        self.last = e
        if math.isfinite(e.profile_error_mm):
            self.profile_errors[f"{u0:g}"] = e.profile_error_mm
        return {"force_error_N": e.force_error_N}

    def summary(self, solve_wall_s: float) -> dict[str, Any]:
        """Summary keys: the final estimate, the method, its cost and the solve time without it."""
        est_s = self.estimator.total_s if self.estimator is not None else 0.0
        out: dict[str, Any] = {"solve_s": solve_wall_s - est_s, "estimate_s": est_s}
        if self.estimator is None:
            return out
        e = self.last
        out.update({"error_method": self.estimator.method, "force_N": e.force_N if e else math.nan,
                    "force_error_N": e.force_error_N if e else math.nan,
                    "force_error_rel": e.force_error_rel if e else math.nan,
                    "profile_error_mm": self.profile_errors,
                    "estimate_cost_fraction": est_s / max(solve_wall_s - est_s, 1e-12)})
        if self.note:
            out["error_estimate_note"] = self.note
        return out
