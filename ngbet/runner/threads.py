"""NGSolve's and the BLAS pools' threads for a run: the one thread policy.

:func:`thread_policy` decides, :func:`ngsolve_threads` sets them for the time of a run; every
entry point (a run, a fit, a force path) goes through it.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from contextvars import ContextVar

from ..scene.document import Scene

__all__ = [
    "IDLE_CORES_FOR_THREADS",
    "cores_for_runs",
    "ngsolve_threads",
    "run_cores",
    "single_threaded_blas",
    "thread_policy",
]

log = logging.getLogger(__name__)


#: "auto" threads the assembly when at least this many cores are idle (cores minus the load average)
IDLE_CORES_FOR_THREADS = 1.5


#: the cores a run of this context may use (None: the machine's); set by whoever runs runs side by side
_RUN_CORES: ContextVar[int | None] = ContextVar("run_cores", default=None)


@contextlib.contextmanager
def cores_for_runs(n: int) -> Iterator[None]:
    """Inside: a run may use at most ``n`` cores (a study's case among others running at the same time).

    What a run chooses for itself (the accuracy ladder's threads at high order) stays within it;
    a scene's own ``solver.threads`` is not capped.
    """
    token = _RUN_CORES.set(max(1, int(n)))
    try:
        yield
    finally:
        _RUN_CORES.reset(token)


def run_cores() -> int:
    """The cores a run may use: the machine's, or fewer inside :func:`cores_for_runs`."""
    cores = os.cpu_count() or 1
    cap = _RUN_CORES.get()
    return cores if cap is None else min(cores, cap)


def thread_policy(
    threads: int | str, model: str = "continuum", cores: int | None = None, load: float | None = None
) -> tuple[int, int]:
    """NGSolve threads for a run and for the assembly of each of its linearizations.

    An integer n gives n to both. ``"auto"`` for the continuum: the run on one thread (the
    solves and residuals are many short parallel regions that lose when a thread waits for a
    core), each linearization's assembly (one long parallel region) on the cores the 1-minute
    load average leaves idle, when at least :data:`IDLE_CORES_FOR_THREADS` are, else one.
    ``"auto"`` for the discrete network: all cores for everything.

    Parameters
    ----------
    threads : int or "auto"
        ``solver.threads``.
    model : str
        ``scene.model``.
    cores, load : optional
        The machine's cores and load average (default: ``os.cpu_count()``, ``os.getloadavg()[0]``).

    Returns
    -------
    (run_threads, assembly_threads)
    """
    if threads != "auto":
        return int(threads), int(threads)
    cores = cores or os.cpu_count() or 1
    if model == "discrete":
        return cores, cores
    load = os.getloadavg()[0] if load is None else load
    idle = cores - load
    return 1, (max(1, min(cores, round(idle))) if idle >= IDLE_CORES_FOR_THREADS else 1)


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context holding every BLAS/OpenMP pool of the process to one thread (threadpoolctl).

    A limit reaches only the libraries loaded when it is set: NGSolve's BLAS and MKL and, where
    CHOLMOD is used, cvxopt's own OpenBLAS are loaded first. Used by :func:`ngsolve_threads` for
    every run; benchmarks and tests that drive a solver directly enter it themselves.
    """
    import ngsolve.la  # noqa: F401
    from threadpoolctl import threadpool_limits

    from .. import cholmod

    if cholmod.available():
        import cvxopt.cholmod  # noqa: F401
    with threadpool_limits(limits=1):
        yield


@contextlib.contextmanager
def ngsolve_threads(scene: Scene) -> Iterator[None]:
    """NGSolve's threads as ``scene.solver.threads`` asks (:func:`thread_policy`).

    The one place where ngbet sets NGSolve's thread count; every entry point (a run, a fit) goes
    through it. With as many threads for the assembly as for the run, the run is inside one
    TaskManager; otherwise the run is serial (no TaskManager) and each assembly enters its own
    (:func:`ngbet.numerics.linear.assembly_threads`).

    The BLAS pools of the process (numpy's and NGSolve's OpenBLAS, each with a thread per core by
    default) are held to one thread meanwhile: the run's dense operations are vector-sized, and
    idle BLAS threads that spin between them, or on top of NGSolve's own threads, take the cores
    the run needs (docs/numerics.md).
    """
    import ngsolve as ngs

    run_threads, asm_threads = thread_policy(scene.solver.threads, scene.model)
    log.debug("NGSolve threads: %d for the run, %d for the assembly", run_threads, asm_threads)
    with single_threaded_blas():
        if run_threads == asm_threads:
            ngs.SetNumThreads(run_threads)
            with ngs.TaskManager():  # NGSolve's assembly and sparse factorizations run in its threads
                yield
            return
        from ..numerics.linear import assembly_threads

        ngs.SetNumThreads(asm_threads)
        with assembly_threads(asm_threads):
            yield
