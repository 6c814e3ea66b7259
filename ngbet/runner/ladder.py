"""Accuracy on demand: a continuum scene run on finer settings until its force error meets the target.

:data:`LADDER` holds the settings (mesh size, order), coarse to fine; :func:`run_to_accuracy` climbs
it towards ``discretization.target_error``, each run's error estimated by
:mod:`ngbet.continuum.estimate`, each setting within a time budget.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, cast

from ..numerics.engine import time_budget
from ..scene.document import Scene
from ..scene.validate import AUTO
from .threads import run_cores

__all__ = [
    "EXPECTED_MARGIN",
    "LADDER",
    "RUNG_BUDGET_FACTOR",
    "RUNG_BUDGET_MIN_S",
    "THREADED_ORDER",
    "Climb",
    "Rung",
    "first_rung",
    "reachable_accuracy",
    "run_to_accuracy",
]

log = logging.getLogger(__name__)


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
        d = dataclasses.replace(
            scene.discretization,
            mesh_size_mm=self.mesh_size_mm,
            order_u=self.order_u,
            order_phi=AUTO,
            order_lam=AUTO,
            corner_mesh_size_mm=self.corner_mesh_size_mm,
            corner_bisections=0,
            structured=False,
            target_error=0.0,
        )
        return dataclasses.replace(
            scene, discretization=d, outputs=dataclasses.replace(scene.outputs, error_estimate="final")
        )


def _rung_scene(rung: Rung, scene: Scene) -> Scene:
    """The scene on ``rung``, estimating where the scene asks (at its stops too), at least at the final load."""
    on = rung.apply(scene)
    if scene.outputs.error_estimate in ("stops", "every"):
        on = dataclasses.replace(on, outputs=scene.outputs)
    return on


@dataclass
class Climb:
    """A climb of a ladder of discretizations: its best estimate so far, the rungs in a row not improving on it.

    The one rule of both climbs, :func:`run_to_accuracy`'s and a fit's curve's
    (:data:`ngbet.calibration.fit_params.FIT_LADDER`): the climb ends at the second rung in a row
    whose estimated error is no better than the best so far; an estimate that cannot vouch (nan or
    inf: the state stands near a limit point, where every order fails alike) is no better than any,
    the first rung's included. Finer rungs would then cost more for no gain. ``level`` is the rung's
    index in the ladder climbed; a rung that did not run (skipped, or its path failed) is not
    recorded.
    """

    best_rel: float = math.inf
    best_level: int | None = None
    first_level: int | None = None
    worse: int = 0
    ended: bool = False
    reason: str = ""  # why the climb ended (empty while it goes on)
    last_level: int | None = None  # the rung recorded last, and its estimate
    last_rel: float = math.nan

    def record(self, level: int, rel: float) -> bool:
        """Take rung ``level``'s estimate ``rel`` (above the target); True when the climb ends here."""
        if self.first_level is None:
            self.first_level = level
        self.last_level, self.last_rel = level, rel
        if math.isfinite(rel) and rel < self.best_rel:
            self.best_rel, self.best_level, self.worse = rel, level, 0
            return False
        self.worse += 1
        self.ended = self.worse >= 2
        if self.ended:
            self.reason = self.why(level, rel)
        return self.ended

    def why(self, level: int, rel: float) -> str:
        """Why the climb ended at rung ``level`` (estimate ``rel``), and the rung it stays on."""
        if not self.ended:
            said = f"estimated error {rel:.3g} on rung {level}, the finest"
        elif self.best_level is None:
            said = f"the error estimate cannot vouch for the force on rungs {self.first_level}-{level}"
        else:
            said = (
                f"estimated error {rel:.3g} on rung {level}, no better than {self.best_rel:.3g} "
                f"on rung {self.best_level}"
            )
        return f"{said}; the curve stays on rung {self.choice()}"

    def choice(self) -> int | None:
        """The rung to stay on: the best estimate's, else (none vouched) the first tried, the cheapest."""
        return self.best_level if self.best_level is not None else self.first_level


#: Candidate discretizations, coarse to fine, all graded to 0.25 mm at the clamp corners: h = 20 mm
#: at p = 3, h = 10 mm at p = 2 and 3, then h = 20 mm at p = 4, 5, 6, 8 and 10 (at p >= 4 the bulk
#: error of the 20 mm mesh is negligible: 107.24349 N against 107.24387 N on the 10 mm mesh at
#: p = 8, at a quarter of the time), then h = 10 mm at p = 8 should those not converge (h = 20 mm,
#: p = 7 stops at 55.7 mm). Expected errors: the paper's scene at 56 mm against the reference
#: 107.2365 N (ngbet.studies.reference). The first rung is the cheapest for a 1 % target on the
#: fabric scenes too, whose error lives in the bulk as much as at the corners: at p = 3 on the 20 mm
#: mesh they estimate 0.47-0.67 % in a solve of 1.5-2.1 s, where h = 10 mm, p = 2 estimates 1.0 % on
#: the unbalanced twill (docs/accuracy.md). Finer corners reach 56 mm but cost more for the same
#: accuracy (the rungs' times and the finer corners' results: docs/numerics.md).
LADDER = tuple(
    Rung(h, 0.25, p, e)
    for h, p, e in (
        (20.0, 3, 2.2e-3),
        (10.0, 2, 1.6e-3),
        (10.0, 3, 1.3e-3),
        (20.0, 4, 6.7e-4),
        (20.0, 5, 3.5e-4),
        (20.0, 6, 1.8e-4),
        (20.0, 8, 6.5e-5),
        (20.0, 10, 2.5e-5),
        (10.0, 8, 6.9e-5),
    )
)
#: a rung is expected to meet a target if its error is below this fraction of it: the estimate
#: (θ |F_p − F_p+1|, the differences shrinking by 0.5–0.7 per order) is 0.75–1.25 times the error,
#: so that 0.7 of the target leaves the estimate below it
EXPECTED_MARGIN = 0.7
#: a setting after the first may take this many times the wall time of the setting before it (but
#: at least :data:`RUNG_BUDGET_MIN_S`): one order up costs 1.5-5x (the times above), and a setting
#: that cuts its step again and again is left when its budget is spent
RUNG_BUDGET_FACTOR = 10.0
#: the smallest time budget of a setting after the first [s]
RUNG_BUDGET_MIN_S = 30.0


#: rungs of this order and above run on two cores where the run may use them
#: (:func:`ngbet.runner.threads.run_cores`) and the scene leaves ``solver.threads`` at its default
#: 1: their assembly, factorizations and solves are long parallel regions. Measured on the default
#: scene, 2-core machine, quiet: at h = 20 mm two threads take 0.55 of one thread's solve time at
#: p = 4, 0.56 at p = 6, and `--accuracy 1e-4` (p = 8) 27.7 s against 46.4 s of wall time for the
#: same CPU time (49.8 against 48.0 s), forces equal to 2e-15. At p = 2 (the default scene) the
#: whole command takes 1.15 times the CPU time on two threads.
THREADED_ORDER = 4


def _on_cores(scene: Scene) -> Scene:
    """``scene`` (on a rung) with two threads where :data:`THREADED_ORDER` says so, else as it is."""
    cores = min(run_cores(), 2)
    if scene.discretization.order_u < THREADED_ORDER or scene.solver.threads != 1 or cores < 2:
        return scene
    return scene.with_changes(**{"solver.threads": cores})


def first_rung(target: float) -> int:
    """The cheapest rung whose expected error is below :data:`EXPECTED_MARGIN` times the target.

    The last rung when none is.
    """
    for i, r in enumerate(LADDER):
        if r.expected_error <= EXPECTED_MARGIN * target:
            return i
    return len(LADDER) - 1


def reachable_accuracy() -> float:
    """The smallest relative force error the ladder expects to reach (its finest rung, the paper's scene)."""
    return min(r.expected_error for r in LADDER)


def run_to_accuracy(scene: Scene, out: Any, run_one: Any) -> dict[str, Any]:
    """Run ``scene`` on the cheapest rung of :data:`LADDER` that meets ``discretization.target_error``.

    The estimated force error at the final load decides; the run climbs the ladder while it is above
    the target, and stops at the second rung in a row that does not improve on the best estimate so
    far (the finer rungs would cost more for no gain; one rung is let pass because an estimate of
    one order can rise before the orders above it fall: on a fitted fabric scene 3.4e-3, 4.3e-3,
    1.6e-3 and 3.5e-4 at p = 4, 5, 6 and 8), an estimate that cannot vouch counting as no better
    (:class:`Climb`, the rule of the fits' climbs too): then the best rung is run again into
    ``out`` (unless it was the last one run; when none vouched, the last one run stays) and
    :class:`ngbet.errors.ConvergenceError` says that the target was not reached and what was.

    Settings of order :data:`THREADED_ORDER` and above run on two cores where the run may use
    them and the scene leaves ``solver.threads`` at 1 (the same numbers to rounding, in about 0.6
    of the wall time).

    A setting that cannot carry the load is left for the next (its attempt says why), and so are
    the higher orders on its mesh, which fail alike; each setting after the first has a time
    budget, :data:`RUNG_BUDGET_FACTOR` times the last one's wall time (at least
    :data:`RUNG_BUDGET_MIN_S`), after which its path stops (:func:`ngbet.numerics.engine.time_budget`).

    ``run_one(scene, out) -> summary`` runs one discretization into ``out`` (the last attempt's
    files stay there). The returned summary (the runner adds it to summary.json) gains
    ``accuracy``: the target, the chosen discretization, whether it was met, and every attempt
    with its estimate and times (a failed attempt's solve time is its wall time).

    Raises
    ------
    ngbet.scene.validate.SceneError
        before solving, when the target is below :func:`reachable_accuracy`.
    ngbet.errors.ConvergenceError
        when the target is not met (the best rung's files are in ``out``).
    """
    from ..errors import ConvergenceError
    from ..scene.validate import SceneError

    target = scene.discretization.target_error
    best_reachable = reachable_accuracy()
    if target < best_reachable:
        finest = min(LADDER, key=lambda r: r.expected_error)
        raise SceneError(
            f"discretization.target_error = {target:g} is below what ngbet can reach: the best "
            f"reachable accuracy is about {best_reachable:.2g} (h = {finest.mesh_size_mm:g} mm, "
            f"corners {finest.corner_mesh_size_mm:g} mm, p = {finest.order_u}, measured on the "
            f"paper's scene); ask for {best_reachable:.1g} or more"
        )
    attempts: list[dict[str, Any]] = []
    summary: dict[str, Any] = {}
    rungs = LADDER[first_rung(target) :]
    climb = Climb()  # levels: indices in rungs and in attempts (one attempt per rung)
    met_at: int | None = None
    failed_meshes: set[tuple[float, float]] = set()  # meshes on which a setting did not carry the load
    last_wall = math.inf  # the wall time of the last setting run (the first is not bounded)
    for k, rung in enumerate(rungs):
        mesh = (rung.mesh_size_mm, rung.corner_mesh_size_mm)
        if mesh in failed_meshes and k < len(rungs) - 1:
            log.warning("%s: skipped (a lower order on the same mesh did not carry the load)", rung)
            attempts.append(
                {
                    "discretization": dataclasses.asdict(rung),
                    "force_error_rel": math.nan,
                    "force_N": None,
                    "wall_s": 0.0,
                    "solve_s": 0.0,
                    "estimate_s": None,
                    "failed": "skipped: a lower order on the same mesh did not carry the load",
                }
            )
            continue
        t0 = time.perf_counter()
        budget = max(RUNG_BUDGET_MIN_S, RUNG_BUDGET_FACTOR * last_wall)
        try:
            with time_budget(budget):
                summary = run_one(_on_cores(_rung_scene(rung, scene)), out)
        except ConvergenceError as e:
            if k == len(rungs) - 1 and climb.best_level is None:
                raise
            log.warning("%s: %s; trying the next setting", rung, str(e).splitlines()[0])
            wall = last_wall = time.perf_counter() - t0
            failed_meshes.add(mesh)
            attempts.append(
                {
                    "discretization": dataclasses.asdict(rung),
                    "force_error_rel": math.nan,
                    "force_N": None,
                    "wall_s": wall,
                    "solve_s": wall,
                    "estimate_s": None,
                    "failed": str(e).splitlines()[0],
                }
            )
            continue
        except BaseException as exc:  # an interrupt (or an error): the climb so far goes with it to summary.json
            attempts.append(
                {
                    "discretization": dataclasses.asdict(rung),
                    "force_error_rel": math.nan,
                    "force_N": None,
                    "wall_s": time.perf_counter() - t0,
                    "solve_s": None,
                    "estimate_s": None,
                    "failed": (
                        f"interrupted ({type(exc).__name__})"
                        if isinstance(exc, KeyboardInterrupt)
                        else f"{type(exc).__name__}: {exc}"
                    ),
                }
            )
            exc.accuracy = _record(target, False, attempts[-1], attempts)  # type: ignore[attr-defined]
            raise
        last_wall = time.perf_counter() - t0
        rel = summary.get("force_error_rel")
        rel = math.nan if rel is None else rel
        attempts.append(
            {
                "discretization": dataclasses.asdict(rung),
                "force_error_rel": rel,
                "force_N": summary.get("force_N"),
                "wall_s": time.perf_counter() - t0,
                "solve_s": summary.get("solve_s"),
                "estimate_s": summary.get("estimate_s"),
            }
        )
        if math.isfinite(rel) and rel <= target:
            met_at = k
            break
        if climb.record(k, rel):
            break
        log.info("estimated error %.3g above the target %.3g: refining", rel, target)
    best = met_at if met_at is not None else climb.best_level
    if best is not None and best != len(attempts) - 1:  # the best setting's files in out
        t0 = time.perf_counter()
        summary = run_one(_on_cores(_rung_scene(rungs[best], scene)), out)
        attempts[best]["rerun_s"] = time.perf_counter() - t0
    chosen = attempts[best] if best is not None else attempts[-1]
    met = met_at is not None
    summary["accuracy"] = _record(target, met, chosen, attempts)
    msg = ""
    if not met:
        why = _why_not_met(climb, rungs, chosen)
        msg = f"discretization.target_error = {target:g} not reached: {why}"
        summary["status"], summary["error"] = "failed", msg
        log.warning("%s", msg)
        raise ConvergenceError(
            msg, float(summary.get("u0_reached_mm", scene.loading.u0_mm)), path_info={"accuracy": summary["accuracy"]}
        )
    return summary


def _setting(rung: Rung) -> str:
    return f"p = {rung.order_u} (h = {rung.mesh_size_mm:g} mm)"


def _why_not_met(climb: Climb, rungs: tuple[Rung, ...], chosen: dict[str, Any]) -> str:
    """Why :func:`run_to_accuracy` ends without meeting its target, for its error message."""
    if not climb.ended:
        return (
            f"the finest setting ngbet offers estimates {chosen['force_error_rel']:.2g}"
            if math.isfinite(chosen["force_error_rel"])
            else "no setting gave an error estimate"
        )
    last = rungs[cast(int, climb.last_level)]
    if climb.best_level is None:
        return (
            f"the error estimate could not vouch for the force at two settings in a row, the last "
            f"{_setting(last)}: the state stands near a limit point or a locking discretization (summary.json: "
            "error_estimate_unreliable), where every order tends to fail alike; finer settings are not tried"
        )
    rel = climb.last_rel
    estimates = f"estimates {rel:.2g}" if math.isfinite(rel) else "gives no estimate it can vouch for"
    return (
        f"{_setting(last)} {estimates}, the second setting in a row no better than "
        f"{climb.best_rel:.2g} at {_setting(rungs[climb.best_level])}"
    )


def _record(target: float, met: bool, chosen: dict[str, Any], attempts: list[dict[str, Any]]) -> dict[str, Any]:
    """The ``accuracy`` record of summary.json.

    The target, whether it was met, the setting whose files are in the run folder, every attempt,
    and their times.
    """
    return {
        "target_error": target,
        "met": met,
        "chosen": chosen["discretization"],
        "attempts": attempts,
        "wall_s": sum(a["wall_s"] + a.get("rerun_s", 0.0) for a in attempts),
        "solve_s": sum(a["solve_s"] or 0.0 for a in attempts),
    }
