"""Arc length in a continuum run: the continuation handed to the load path, its record for the summary.

:func:`arclength_runner` sets the model-free continuation (:func:`ngbet.numerics.arclength.arclength_steps`)
to a continuum problem and its scene: the arc length's step control, the reaction's test vector,
the stability test (none for an uncondensed saddle-point tangent) and, when the target is not
reached, the diagnosis; the instabilities found go to ``path_info`` with their mode's class.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Generator
from typing import Any

import numpy as np

from ..continuum.solver import ContinuumSolver
from ..errors import ConvergenceError
from ..numerics.arclength import Instability, arclength_steps
from ..numerics.engine import PathResult, StepRecord, Steps
from ..scene.validate import SceneError
from .settings import arclength_settings

__all__ = ["MODE_KEY", "arclength_runner"]


def arclength_runner(problem: ContinuumSolver) -> Callable[[PathResult], Generator[StepRecord, None, PathResult]]:
    """The continuation the continuum's run hands to :func:`ngbet.numerics.path.load_steps`.

    Follows the path of ``problem`` (a :class:`~ngbet.continuum.solver.ContinuumSolver`) from
    its converged state to ``loading.u0_mm``, yielding each step's record and appending it to the
    result it is given; fills ``path_info`` (instabilities with kind, load, force and mode class;
    the first one's mode as mode to picture under :data:`MODE_KEY`, for the runner to write and
    pop) and raises :class:`~ngbet.errors.ConvergenceError` with it when the target is not reached.
    """
    from ..continuum.stability import diagnose_stability, indefinite_by_construction, lowest_eigenpair

    scene = problem.problem.scene
    ctl = arclength_settings(scene)  # arc length lands on the stops, not on the output grid
    psi = problem.problem.psi_u.vec.FV().NumPy().copy()
    # an uncondensed saddle-point tangent has no stability test: no instability by eigenvalue then
    indefinite = indefinite_by_construction(problem)
    if indefinite and scene.solver.branch == "switch":
        raise SceneError(
            "solver.branch = 'switch' needs the critical mode, and the uncondensed saddle-point "
            "tangent (solver.condense = false) has no stability test: set solver.condense = true"
        )

    def run(res: PathResult) -> Generator[StepRecord, None, PathResult]:
        start_mm = problem.problem.lam * 1e3
        c = ctl
        if len(res.steps) >= 2:  # after displacement control: start with its last step
            h = res.steps[-1].u0 - res.steps[-2].u0
            c = dataclasses.replace(
                ctl, first_step=h, max_step=min(ctl.max_step, 8 * h), min_step=min(ctl.min_step, h / 64)
            )
        found: list[Instability] = []
        steps = Steps(
            arclength_steps(
                problem,
                c,
                problem.settings.newton,
                weights=problem.problem.weights,
                length=scene.specimen.L,
                psi=psi,
                lowest_eigenpair=None if indefinite else lambda: lowest_eigenpair(problem),
                result=res,
                branch=scene.solver.branch,
            )
        )
        for rec in steps:
            found += rec.instabilities
            yield rec
        assert steps.result is not None
        res = steps.result
        res.path_info = _path_info(problem, found, start_mm)
        if res.steps:
            t = scene.specimen.t
            F = [float(psi @ s.residual) * t if s.residual is not None else math.nan for s in res.steps]
            k = int(np.nanargmax(F))
            res.path_info["force_maximum"] = {"u0_mm": res.steps[k].u0 * 1e3, "force_N": F[k]}
        if res.u0 < ctl.target * (1 - 1e-9):
            d = diagnose_stability(problem)
            kinds = ", ".join(f"{i.kind} at {i.u0_mm:.4g} mm" for i in found) or "none detected"
            raise ConvergenceError(
                f"arc-length continuation from {start_mm:.6g} mm did not reach {ctl.target * 1e3:.6g} mm "
                f"(instabilities passed: {kinds})",
                res.u0 * 1e3,
                res.attempts,
                d.message(),
                d,
                path_info=res.path_info,
            )
        return res

    return run


#: the key of ``path_info`` that holds the mode to picture, (mode, name, title), not for the summary:
#: the runner writes the files and pops it (numerics write no files)
MODE_KEY = "_instability_mode"


def _path_info(problem: ContinuumSolver, found: list[Instability], start_mm: float) -> dict[str, Any]:
    """The summary's record of the path: each instability with its mode's class and place; the first mode."""
    from ..continuum.stability import DISCRETIZATION_MODE_RATIO, mode_constraint_ratio

    saved = problem.x.copy()
    for ins in found:
        if ins.mode is not None and problem.problem.phi is not None:
            r, where = mode_constraint_ratio(problem, ins.mode)
            ins.details.update(
                mode_ratio=r,
                mode_class="discretization" if r > DISCRETIZATION_MODE_RATIO else "continuum",
                mode_location_mm=list(where),
            )
    scene = problem.problem.scene
    info: dict[str, Any] = {
        "path_following": scene.solver.path_following,
        "arclength_from_mm": start_mm,
        "branch": scene.solver.branch,
        "instabilities": [i.as_dict(scene.specimen.t) for i in found],
    }
    # the mode pictured: that of the first switch to a bifurcated branch, else of the first instability
    switched = [i for i in found if i.details.get("branch") == "switched"]
    first = next((i for i in switched + found if i.mode is not None), None)
    if first is not None and first.mode is not None:
        info[MODE_KEY] = (
            first.mode,
            "instability_mode",
            f"{first.kind} at u0 = {first.u0_mm:.4g} mm: lowest mode of the tangent",
        )
        info["instability_mode_of"] = {"kind": first.kind, "u0_mm": first.u0_mm}
    problem.x[:] = saved
    return info
