"""Running a scene: the one entry point behind ``ngbet run``; it dispatches on ``scene.model``."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .scene import Scene


@contextlib.contextmanager
def ngsolve_threads(scene: Scene) -> Iterator[None]:
    """NGSolve's threads as ``scene.solver.threads`` asks, inside its TaskManager.

    The one place where ngbet sets NGSolve's thread count; every entry point (a run, a fit) goes
    through it.
    """
    import ngsolve as ngs

    if scene.solver.threads != "auto":
        ngs.SetNumThreads(int(scene.solver.threads))
    with ngs.TaskManager():  # NGSolve's assembly and sparse factorizations run in its threads
        yield


def run(scene: Scene, out: str | Path, progress: bool = False) -> dict[str, Any]:
    """Run a scene into the folder ``out``; returns the summary (also in summary.json).

    Raises
    ------
    ngbet.errors.ConvergenceError
        when the load cannot be carried to the end; every converged step is on disk by then,
        and summary.json says ``"status": "failed"`` with the error.
    """
    with ngsolve_threads(scene):
        if scene.model == "discrete":
            from . import discrete

            return discrete.run(scene, out, progress=progress)
        from .continuum.run import run_continuum

        return run_continuum(scene, Path(out), progress)
