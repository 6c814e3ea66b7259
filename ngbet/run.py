"""Running a scene: the one entry point behind ``ngbet run``; it dispatches on ``scene.model``."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from .runner.threads import ngsolve_threads
from .scene.document import Scene
from .scene.validate import SceneError

__all__ = ["run"]

log = logging.getLogger(__name__)


def run(scene: Scene, out: str | Path, progress: bool = False, measured: Any = None) -> dict[str, Any]:
    """Run a scene into the folder ``out``; returns the summary (also in summary.json).

    Raises
    ------
    ngbet.errors.ConvergenceError
        when the load cannot be carried to the end; every converged step is on disk by then,
        and summary.json says ``"status": "failed"`` with the error.
    ngbet.scene.validate.SceneError
        when the scene asks for what this installation lacks (``solver.linear_solver = "cholmod"``
        without cvxopt), before anything is written.
    """
    if scene.solver.linear_solver == "cholmod":
        from . import cholmod

        if not cholmod.available():
            raise SceneError(
                "scene key 'solver.linear_solver' = 'cholmod': needs cvxopt, which is not installed "
                "here: pip install \"ngbet[cholmod]\" (or choose 'auto', which falls back to "
                "'sparsecholesky')"
            )
    if scene.model == "discrete":
        from .runner.discrete import run_discrete

        with ngsolve_threads(scene):
            return run_discrete(scene, out, progress=progress, measured=measured)
    from .runner.continuum import run_continuum

    if scene.discretization.target_error > 0:  # the accuracy ladder: each rung sets its own threads
        return run_continuum(scene, Path(out), progress, measured)
    with ngsolve_threads(scene):
        return run_continuum(scene, Path(out), progress, measured)
