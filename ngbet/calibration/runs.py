"""A fit's model runs: each curve's force, profile and angles and their derivatives at θ = ln p.

:class:`CurveModel` runs every curve of a fit on its rung of the fit's ladder (cached by θ and the
rung; each curve's mesh made once per rung), in this process or, with ``workers`` > 1, each curve
in a worker process of its own (:func:`curve_run` there). :mod:`ngbet.calibration.joint` drives it.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ..errors import FitWorkerError
from ..runner.ladder import Climb
from ..scene.document import Scene
from ..scene.validate import SceneError
from .fit_params import FIRST_CHECKED, FIT_LADDER, CurveFit, with_values

__all__ = [
    "PROBE_POINTS",
    "RUN_BUDGET_FACTOR",
    "RUN_BUDGET_MIN_S",
    "CurveModel",
    "Job",
    "Run",
    "RunsSpent",
    "curve_run",
    "default_workers",
    "first_levels",
    "probe_points",
    "relative_error",
    "run_budget",
]

log = logging.getLogger(__name__)


class RunsSpent(Exception):
    """A model run was asked for beyond :attr:`CurveModel.limit`: the fit's runs are spent."""


@dataclass
class Run:
    """One model run of a curve: force, dF/dθ, profile, angles (at the data's loads) and their dθ."""

    F: np.ndarray
    G: np.ndarray
    P: np.ndarray
    GP: np.ndarray
    A: np.ndarray
    GA: np.ndarray
    err: np.ndarray  # the estimated force error at the fitted points (checked runs; nan where not estimated)
    angle: np.ndarray  # the centre shear angle at the fitted points (checked runs only)
    seconds: float = 0.0  # the run's wall time
    cpu_s: float = 0.0  # the CPU time of the process that ran it, during the run


@dataclass(frozen=True)
class Job:
    """One model run of one curve, everything it needs (picklable: a worker process receives it)."""

    scene: Scene  # the curve's scene on its rung, with the parameter values
    mesh_key: tuple[int, int | None]  # (curve, rung): the mesh is made once per key and reused
    u_mm: np.ndarray
    names: list[str]
    points: dict[float, np.ndarray]  # the profile's abscissae [mm] per displacement
    angle_u_mm: list[float]  # the displacements of the measured centre shear angles
    check: bool
    label: str
    #: the fitted points (indices into ``u_mm``) whose force error is estimated when ``check``; None: all
    estimate_at: tuple[int, ...] | None = None
    #: wall time [s] after which the run stops and counts as not converged (:func:`run_budget`)
    budget_s: float = math.inf


#: check modes of a cached run: a probe (the error estimated at some fitted points), full (at all)
PROBE, FULL = 1, 2
#: the fitted points a probe estimates the force error at (evenly spaced, the first and last among
#: them): enough to choose a rung, the error varying slowly along the curve (on the unbalanced
#: twill's 16 points its largest estimate lies on a plateau of 3-5 points within 10 % of it)
PROBE_POINTS = 8


#: a curve's run may take this many times the longest run of the curve that converged (at least
#: :data:`RUN_BUDGET_MIN_S`): a finer rung with the estimate costs up to 10 times a coarse run, and
#: a run whose path crawls through relaxations at a step of 0.1 mm is left for the search to avoid
RUN_BUDGET_FACTOR = 20.0
#: the smallest time budget of a curve's run [s]
RUN_BUDGET_MIN_S = 120.0


def run_budget(longest_s: float) -> float:
    """The time budget of a curve's run after its longest converged run took ``longest_s`` (0: none yet, no budget)."""
    return max(RUN_BUDGET_MIN_S, RUN_BUDGET_FACTOR * longest_s) if longest_s > 0 else math.inf


def probe_points(m: int) -> tuple[int, ...]:
    """The indices of the fitted points a probe estimates, of ``m`` (all when ``m`` <= :data:`PROBE_POINTS`)."""
    return tuple(int(i) for i in np.unique(np.round(np.linspace(0, m - 1, min(m, PROBE_POINTS)))))


#: a worker process's meshes by :attr:`Job.mesh_key` (a worker serves one curve of one fit)
_WORKER_MESHES: dict[tuple[int, int | None], Any] = {}


def _worker_run(job: Job) -> Run:
    """:func:`curve_run` in a worker process, with that process's meshes.

    The scene's keys without effect were reported by the command that started the fit: the scenes
    a run derives from the job's do not report them again.
    """
    from ..scene.document import SceneWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return curve_run(job, _WORKER_MESHES)


def curve_run(job: Job, meshes: dict[tuple[int, int | None], Any]) -> Run:
    """The force, profile and angles of ``job`` and their dθ; NaN where the model run does not converge.

    A run still going after ``job.budget_s`` stops (:func:`ngbet.numerics.engine.time_budget`) and
    counts as not converged.
    """
    from ..continuum.mesh import make_cross_mesh, make_mesh
    from ..errors import ConvergenceError
    from ..numerics.engine import time_budget
    from ..runner.sensitivity import force_path

    t0, c0 = time.perf_counter(), time.process_time()
    sc, n, pts, a_u, check = job.scene, len(job.names), job.points, job.angle_u_mm, job.check
    if job.mesh_key not in meshes:
        meshes[job.mesh_key] = (
            make_cross_mesh(sc.picture_frame, sc.specimen, sc.discretization)
            if sc.test == "picture_frame"
            else make_mesh(sc.specimen, sc.discretization)
        )
    m, kp, ka = len(job.u_mm), sum(len(x) for x in pts.values()), len(a_u)
    try:
        with time_budget(job.budget_s):
            r = force_path(
                sc,
                job.u_mm,
                job.names,
                pts,
                mesh=meshes[job.mesh_key],
                angles=sorted(set(a_u) | (set(map(float, job.u_mm)) if check else set())),
                estimate=check,
                estimate_at=None if job.estimate_at is None else [float(job.u_mm[i]) for i in job.estimate_at],
            )
        assert r.dlogp is not None
        P = np.concatenate([r.profiles[u0] for u0 in pts]) if pts else np.zeros(0)
        GP = np.vstack([r.profile_dlogp[u0] for u0 in pts]) if pts else np.zeros((0, n))
        A = np.array([r.angles_deg[float(u)] for u in a_u])
        GA = np.vstack([r.angle_dlogp[float(u)] for u in a_u]) if a_u else np.zeros((0, n))
        err = r.force_error_N if r.force_error_N is not None else np.zeros(0)
        ang = np.array([r.angles_deg[float(u)] for u in job.u_mm]) if check else np.zeros(0)
        return Run(r.force_N, r.dlogp, P, GP, A, GA, err, ang, time.perf_counter() - t0, time.process_time() - c0)
    except (ConvergenceError, SceneError) as exc:
        log.info("model run failed on %s: %s", job.label, exc)
        return Run(
            np.full(m, np.nan),
            np.zeros((m, n)),
            np.full(kp, np.nan),
            np.zeros((kp, n)),
            np.full(ka, np.nan),
            np.zeros((ka, n)),
            np.full(m if check else 0, np.nan),
            np.full(m if check else 0, np.nan),
            time.perf_counter() - t0,
            time.process_time() - c0,
        )


class CurveModel:
    """Every curve's observations and their Jacobian at θ = ln p, cached by θ and the discretizations.

    Each curve's mesh is made once per rung and reused. ``check=True`` adds the discretization
    error estimate at the fitted points and the centre shear angle there.

    ``workers`` > 1 (and more than one curve): each curve runs in a worker process of its own
    (spawned: Netgen and NGSolve's threads do not survive a fork), which keeps its meshes, on one
    NGSolve thread; the curves of one call run at the same time. A worker's exception is raised
    here, a worker that dies raises :class:`FitWorkerError`. :meth:`close` ends the workers at
    once, also when the fit stops by an exception or Ctrl-C (the workers ignore SIGINT).

    ``limit``: the model runs the caller allows (``runs`` never exceeds it): a call that would run
    a curve with ``runs`` at the limit raises :class:`RunsSpent`, nothing run.
    """

    def __init__(self, curves: list[CurveFit], names: list[str], workers: int = 1) -> None:
        self.curves, self.names = curves, names
        self.meshes: dict[tuple[int, int | None], Any] = {}
        self.runs = 0
        self.limit = math.inf
        self.parallel = workers > 1 and len(curves) > 1
        self._pools: dict[int, Any] = {}
        self._alive: Any = None  # a pipe whose write end only this process holds: the workers exit with it
        self._cache: dict[tuple[int, bytes, int | None, int], Run] = {}  # (curve, θ, rung, check mode)
        #: every run made, per curve: (rung, checked, wall time [s], CPU time [s])
        self.timings: list[list[tuple[int | None, bool, float, float]]] = [[] for _ in curves]
        self._longest = [0.0] * len(curves)  # each curve's longest converged run [s] (its runs' budget)

    def __call__(self, theta: np.ndarray, check: bool = False, probe: bool = False) -> list[Run]:
        """Each curve's run at θ on its current rung; a curve already run there (checked or as asked) is not rerun.

        ``probe`` (with ``check``): the force error estimated at :data:`PROBE_POINTS` of the fitted
        points only (:func:`probe_points`; nan at the others), enough to choose a rung; a fully
        checked run serves a probe. ``runs`` counts the calls that ran at least one curve (when done); a call
        that would run one with ``runs`` at :attr:`limit` raises :class:`RunsSpent`.
        """
        mode = (PROBE if probe else FULL) if check else 0
        t = np.asarray(theta, float).tobytes()
        todo = [k for k, c in enumerate(self.curves) if self.cached(k, theta, c.level, check, probe) is None]
        if todo and self.runs >= self.limit:
            raise RunsSpent(f"the {self.runs} model runs allowed are spent")
        jobs = {k: self._job(k, theta, check, probe) for k in todo}
        if self.parallel:
            done = self._in_workers(jobs)
        else:
            done = {k: curve_run(jobs[k], self.meshes) for k in todo}
        self.runs += bool(todo)  # a run counts once it is done (a run stopped by Ctrl-C does not)
        for k in todo:
            self._cache[k, t, self.curves[k].level, mode] = done[k]
            if np.all(np.isfinite(done[k].F)):
                self._longest[k] = max(self._longest[k], done[k].seconds)
            self.timings[k].append((self.curves[k].level, check, done[k].seconds, done[k].cpu_s))
        return [cast(Run, self.cached(k, theta, c.level, check, probe)) for k, c in enumerate(self.curves)]

    def cached(
        self, k: int, theta: np.ndarray, level: int | None, check: bool = False, probe: bool = False
    ) -> Run | None:
        """Curve ``k``'s run at θ on rung ``level`` if one made there serves (a fuller check serves), else None."""
        t = np.asarray(theta, float).tobytes()
        need = (PROBE if probe else FULL) if check else 0
        for mode in (FULL, PROBE, 0):
            if mode >= need and (k, t, level, mode) in self._cache:
                return self._cache[k, t, level, mode]
        return None

    def at(self, k: int, theta: np.ndarray, level: int | None) -> Run | None:
        """Curve ``k``'s run at θ on rung ``level`` if one was made, else one on any rung, else None."""
        t = np.asarray(theta, float).tobytes()
        made = self.cached(k, theta, level)
        return made or next((r for (j, tt, _, _), r in self._cache.items() if j == k and tt == t), None)

    def _job(self, k: int, theta: np.ndarray, check: bool, probe: bool = False) -> Job:
        c = self.curves[k]
        sc = with_values(c.run_scene(), self.names, np.exp(theta))
        if self.parallel:  # one worker per curve on its own core
            sc = sc.with_changes(**{"solver.threads": 1})
        return Job(
            sc,
            (k, c.level),
            np.asarray(c.u_mm, float),
            list(self.names),
            c.profile.points() if c.profile is not None else {},
            [float(u) for u in c.angles.u_mm] if c.angles is not None else [],
            check,
            c.label,
            probe_points(len(c.u_mm)) if check and probe else None,
            run_budget(self._longest[k]),
        )

    def _pool(self, k: int) -> Any:
        """Curve ``k``'s worker process, started on first use.

        Its start is that of a study's workers (:func:`ngbet.study.executors.worker_init`): SIGINT
        ignored, and it exits by itself when this process dies, even by SIGKILL.
        """
        import multiprocessing
        import os
        from concurrent.futures import ProcessPoolExecutor

        from ..study.executors import worker_init

        if k not in self._pools:
            ctx = multiprocessing.get_context("spawn")
            if self._alive is None:
                self._alive = ctx.Pipe(duplex=False)
            env = {key: v for key, v in os.environ.items() if key.startswith("NGBET_")}
            self._pools[k] = ProcessPoolExecutor(
                1, mp_context=ctx, initializer=worker_init, initargs=(self._alive[0], env)
            )
        return self._pools[k]

    def _in_workers(self, jobs: dict[int, Job]) -> dict[int, Run]:
        """Each job in its curve's worker, at the same time; a dead worker raises :class:`FitWorkerError`."""
        from concurrent.futures.process import BrokenProcessPool

        futures, done = {}, {}
        k = -1
        try:
            for k, job in jobs.items():
                futures[k] = self._pool(k).submit(_worker_run, job)
            for k, f in futures.items():
                done[k] = cast(Run, f.result())
        except BrokenProcessPool as exc:
            raise FitWorkerError(
                f"the worker process of {self.curves[k].label} ended without an answer "
                "(killed, out of memory or crashed); the fit stops"
            ) from exc
        return done

    def close(self) -> None:
        """End the worker processes at once (a run still going is not waited for)."""
        for pool in self._pools.values():
            # ProcessPoolExecutor has no public way to stop a running task: its processes are ended
            for proc in list((pool._processes or {}).values()):
                proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
        self._pools.clear()
        if self._alive is not None:
            for end in self._alive:
                end.close()
            self._alive = None


def default_workers(n_curves: int) -> int:
    """Worker processes for ``n_curves`` curves: one per curve up to the cores; 1 in a daemon process."""
    import multiprocessing
    import os

    if multiprocessing.current_process().daemon:  # a daemonic process may not start processes
        return 1
    return max(1, min(n_curves, os.cpu_count() or 1))


def first_levels(
    model: CurveModel,
    cfs: list[CurveFit],
    theta: np.ndarray,
    target_error: float,
    lowest: Sequence[int | None] | None = None,
) -> list[int | None]:
    """Each curve's first rung from ``lowest`` (default :data:`FIRST_CHECKED`) up meeting the target at θ.

    One probe (:meth:`CurveModel.__call__`) per rung tried, the curves at once. Probed with the start values before the
    search (stiff yarns lock the cheap rungs, with errors of tens of per cent, where a search would
    only chase the discretization), and again where the coarse search ended, from the start's
    rungs up. Each curve's climb starts afresh (``CurveFit.climb``) and ends as
    :class:`~ngbet.runner.ladder.Climb` says: a curve no rung vouches for stays on the
    climb's choice, the rung with the best estimate (or the first tried), not the last. Where the
    model's runs are spent (:class:`RunsSpent`) a curve still climbing stays on the rung it stands
    on, the next one it would have probed.
    """
    top = len(FIT_LADDER) - 1
    for k, cf in enumerate(cfs):
        lv = lowest[k] if lowest is not None else None
        cf.level = FIRST_CHECKED if lv is None else lv
        cf.climb = Climb()
    pending = list(range(len(cfs)))
    found: dict[int, int | None] = {}
    while pending:
        try:
            runs = model(theta, check=True, probe=True)
        except RunsSpent:
            found.update({i: cfs[i].level for i in pending})
            break
        for i in list(pending):
            cf = cfs[i]
            rel = relative_error(runs[i], probe_points(len(cf.u_mm)))
            if rel <= target_error or cf.level is None:
                found[i] = cf.level
            elif cf.climb.record(cf.level, rel) or cf.level >= top:
                found[i] = cf.climb.choice()
                log.warning("%s: %s, where the accuracy target is not met", cf.label, cf.climb.why(cf.level, rel))
            else:
                log.info("%s: estimated discretization error %.3g on rung %d: one rung up", cf.label, rel, cf.level)
                cf.level += 1
                continue
            pending.remove(i)
    return [found[i] for i in range(len(cfs))]


def relative_error(run: Run, at: Sequence[int] | None = None) -> float:
    """The largest estimated force error of ``run`` relative to its force, over the fitted points ``at`` (None: all).

    inf where the estimate cannot vouch at one of them (or was not made).
    """
    idx = list(range(len(run.err))) if at is None else list(at)
    e, F = run.err[idx], np.abs(run.F[idx])
    return float(np.max(e / F)) if len(e) and np.all(np.isfinite(e)) else math.inf
