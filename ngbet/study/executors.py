"""Running the cases of a study: in this process, in local worker processes, or on a dask cluster.

Each case runs into ``cache/.run-<key>-<token>`` and is stored into ``cache/<key>`` by the process
that ran it, the moment it finishes (:func:`execute_case`); the study then verifies the stored
folder before it counts the case (a case whose folder does not verify is an error, never "ok").
A case whose solver fails (ngbet.errors.ConvergenceError, both models) is a result: it is cached
with its error and converged steps. A case that crashes otherwise (a bug, a killed worker) is
recorded with its error in the study but not cached, so that the next run retries it.

Local workers are forked by a fork server that has imported ngbet and NGSolve once; they ignore
SIGINT (the parent decides) and exit by themselves when the parent dies, even by SIGKILL.
Ctrl-C (SIGINT, or SIGTERM through the CLI) keeps the finished cases, cancels the others and stops
the workers at once. Dask: see :mod:`ngbet.study.cluster`.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import math
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from .._env import environ
from ..errors import ConvergenceError
from ..provenance import machine
from ..scene.document import Scene
from .cache import CacheError, reached, store, verify_case
from .model import Case

__all__ = [
    "PRELOAD",
    "Bar",
    "Finished",
    "StudyInterrupted",
    "accept",
    "execute_case",
    "run_processes",
    "stop_pool",
    "worker_context",
    "worker_init",
]


class StudyInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a study: its finished cases are in the cache, the others cancelled."""


Finished = Callable[[Case, dict[str, Any], Path | None], None]


def execute_case(
    scene_dict: dict[str, Any],
    threads: int,
    workdir: str | None = None,
    cache: str | None = None,
    key: str | None = None,
    token: str | None = None,
) -> dict[str, Any]:
    """Run one scene into ``workdir`` (or a temporary folder whose files are returned).

    With ``cache`` (and the case's ``key``, the study's ``token``) a finished case is stored into
    ``cache/<key>`` here, at once (``"stored": True``). Returns the case record: status ("ok",
    "failed": the solver gave up, "error": anything else), error text, wall time, threads, and with
    no ``workdir`` the run folder's files as ``{"files": {name: bytes}}`` (for dask workers on
    other machines).
    """
    scene = Scene.from_dict(scene_dict)
    if threads > 0:  # ngbet.run.run sets NGSolve's threads from the scene
        scene = scene.with_changes(**{"solver.threads": threads})
    tmp = workdir is None
    wd = Path(tempfile.mkdtemp(prefix="ngbet-case-")) if tmp else Path(workdir)  # type: ignore[arg-type]
    wd.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rec: dict[str, Any] = {
        "status": "ok",
        "error": None,
        "threads": threads,
        "host": machine()["node"],
        "pid": os.getpid(),
    }
    try:
        _run_case(scene, wd, threads, rec)
        rec["wall_s"] = time.perf_counter() - t0
        if tmp:
            rec["files"] = {p.relative_to(wd).as_posix(): p.read_bytes() for p in wd.rglob("*") if p.is_file()}
        elif cache is not None and key is not None and token is not None and rec["status"] in ("ok", "failed"):
            store(Path(cache), key, rec, token, workdir=wd)
            rec["stored"] = True
    finally:  # a temporary folder goes however the case ends (an interrupt, the worker shut down)
        if tmp:
            shutil.rmtree(wd, ignore_errors=True)
    return rec


def _run_case(scene: Scene, wd: Path, threads: int, rec: dict[str, Any]) -> None:
    """Run ``scene`` into ``wd``; a failure goes into ``rec`` (status, error, error_type), never out."""
    from ..run import run  # imports NGSolve: only where a case runs

    try:
        from ..runner.threads import cores_for_runs

        # a case's warnings go to its summary.json (and the study's meta.json), not the terminal; the
        # case keeps to its threads (the cases beside it have theirs)
        with _quiet_logs(), cores_for_runs(threads) if threads > 0 else contextlib.nullcontext():
            summary = run(scene, wd, progress=False)
        if summary.get("status") != "ok":
            rec.update(status="failed", error=str(summary.get("error")), error_type="solver")
    except ConvergenceError as exc:
        rec.update(status="failed", error=str(exc), error_type="ConvergenceError")
    except Exception as exc:  # recorded, never fatal for the study
        rec.update(
            status="error",
            error=f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}",
            error_type=type(exc).__name__,
        )


@contextlib.contextmanager
def _quiet_logs() -> Iterator[None]:
    """Hold back ngbet's warnings below ERROR while a case runs (the run records them itself)."""
    logger = logging.getLogger("ngbet")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def accept(cache: Path, token: str, c: Case, rec: dict[str, Any], wd: Path | None) -> dict[str, Any]:
    """The record a study keeps of a finished case: stored (when not yet) and verified.

    A case whose stored folder does not verify is an "error" naming the file: a study never counts
    a case as "ok" without its data.
    """
    files = rec.pop("files", None)
    if rec.get("status") in ("ok", "failed"):
        try:
            if not rec.pop("stored", False):
                store(cache, c.key, rec, token, workdir=wd, files=files)  # type: ignore[arg-type]
            verify_case(cache / c.key)  # type: ignore[operator]
        except (CacheError, OSError) as exc:
            rec = {
                **rec,
                "status": "error",
                "error": f"the case finished ({rec['status']}) but was not stored: {exc}",
                "error_type": type(exc).__name__,
            }
    elif wd is not None:
        shutil.rmtree(wd, ignore_errors=True)
    return {**rec, "cached": False}


def worker_init(parent_alive: Any, ngbet_env: dict[str, str]) -> None:
    """Start of a local worker process: Ctrl-C is for the parent, and the worker exits when the parent dies.

    The parent keeps the finished cases and stops the workers; the worker exits by itself even when the
    parent dies by SIGKILL: ``parent_alive`` is the read end of a pipe whose only write end the parent
    holds, so that it reads end-of-file when the parent is gone (whoever the worker's own parent is,
    and whether or not the dead one is reaped). ``ngbet_env``: the parent's ``NGBET_*`` variables now
    (the fork server's environment is the one it started with).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from ..messages import install

    install()  # the case's warnings as one `ngbet:` line each, as the command's
    for k in [k for k in os.environ if k.startswith("NGBET_") and k not in ngbet_env]:
        del os.environ[k]
    os.environ.update(ngbet_env)
    threading.Thread(target=_exit_with_parent, args=(parent_alive,), daemon=True, name="ngbet-parent-watch").start()


def _exit_with_parent(parent_alive: Any) -> None:
    with contextlib.suppress(EOFError, OSError):
        while True:
            parent_alive.recv()  # nothing is ever sent: returns by EOFError
    os._exit(1)


class Bar:
    """Progress over cases: finished ones and the part of the load the running ones reached."""

    def __init__(self, total: int, name: str, running: dict[str, tuple[Path, float]], enabled: bool) -> None:
        self.running, self.done, self.lock = running, 0, threading.Lock()
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(
                total=total,
                desc=f"study {name}",
                unit="case",
                bar_format="{l_bar}{bar}| {n:.2f}/{total} cases [{elapsed}<{remaining}]{postfix}",
            )
        self.stop = threading.Event()
        self.poller: threading.Thread | None = None

    def start_polling(self) -> None:
        """Refresh the bar twice a second with the load the running cases reached."""
        if self.bar is None:
            return

        def poll() -> None:
            while not self.stop.wait(0.5):
                self.tick()

        self.poller = threading.Thread(target=poll, daemon=True)
        self.poller.start()

    def tick(self, note: str | None = None) -> None:
        """Redraw the bar (with ``note`` after it)."""
        if self.bar is None:
            return
        if note:
            self.bar.set_postfix_str(note, refresh=False)
        with self.lock:
            part = sum(min(reached(wd) / u0, 0.999) for wd, u0 in self.running.values())
            self.bar.n = min(round(self.done + part, 2), self.bar.total)
        self.bar.refresh()

    def close(self) -> None:
        """Stop polling and close the bar at the finished count."""
        self.stop.set()
        if self.poller is not None:
            self.poller.join(timeout=2)
        if self.bar is not None:
            self.bar.n = self.done
            self.bar.refresh()
            self.bar.close()


def run_processes(
    todo: list[Case],
    wds: dict[Any, Path],
    nworkers: int | None,
    threads: int,
    running: dict[str, tuple[Path, float]],
    lock: threading.Lock,
    finished: Finished,
    cache: Path,
    token: str,
) -> None:
    """Run the cases on a pool of local worker processes; an interrupt keeps the finished ones.

    The workers are forked by a fork server and exit with this process (see :func:`worker_init`);
    each uses ``threads`` BLAS threads.
    """
    # one BLAS thread per worker too (inherited by the fork server when it starts, and by its workers)
    with environ({k: str(threads) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}):
        ctx = worker_context(todo)
        alive_r, alive_w = ctx.Pipe(duplex=False)  # closed when this process ends: see worker_init
        ex = cf.ProcessPoolExecutor(
            max_workers=nworkers,
            mp_context=ctx,
            initializer=worker_init,
            initargs=(alive_r, {k: v for k, v in os.environ.items() if k.startswith("NGBET_")}),
        )
        try:
            _submit_and_collect(ex, todo, wds, threads, running, lock, finished, (str(cache), token))
        finally:
            alive_w.close()
            alive_r.close()


def _submit_and_collect(
    ex: Any,
    todo: list[Case],
    wds: dict[Any, Path],
    threads: int,
    running: dict[str, tuple[Path, float]],
    lock: threading.Lock,
    finished: Finished,
    store_in: tuple[str, str],
) -> None:
    """Submit the cases to the pool ``ex`` and record each as it finishes; an interrupt keeps the finished ones."""
    futs: dict[Any, tuple[Case, Path]] = {}
    consumed: set[Any] = set()

    def take(fut: Any) -> None:
        c, wd = futs[fut]
        consumed.add(fut)
        try:
            rec = fut.result()
        except Exception as exc:  # a worker died: record, do not cache
            rec = {
                "status": "error",
                "error": f"{type(exc).__name__}: {exc}",
                "error_type": type(exc).__name__,
                "wall_s": math.nan,
            }
        finished(c, rec, wd)

    try:
        for c in todo:
            fut = ex.submit(
                execute_case,
                c.scene.to_dict(),  # type: ignore[union-attr]
                threads,
                str(wds[c.key]),
                store_in[0],
                c.key,
                store_in[1],
            )
            futs[fut] = (c, wds[c.key])
            with lock:
                running[c.key] = (wds[c.key], c.scene.loading.u0_mm)  # type: ignore[index,union-attr]
        for fut in cf.as_completed(futs):
            take(fut)
        ex.shutdown(wait=True)
    except BaseException:
        for fut in futs:  # cases that finished while the interrupt came in are kept
            if fut.done() and not fut.cancelled() and fut not in consumed:
                take(fut)
        stop_pool(ex)
        raise


#: what the fork server imports, once for all its workers, by the model of the cases ("plot": cases
#: that draw their figures)
PRELOAD = {
    "continuum": ["ngbet.study.executors", "ngbet.run", "ngbet.runner.continuum"],
    "discrete": ["ngbet.study.executors", "ngbet.run", "ngbet.runner.discrete"],
    "plot": ["matplotlib.figure", "matplotlib.backends.backend_agg", "matplotlib.backends.backend_pdf"],
}


def worker_context(todo: list[Case]) -> Any:
    """The start method of the local workers: a fork server that has imported ngbet and NGSolve.

    The server is a fresh process (no threads, NGSolve's task manager not started) that imports
    :data:`PRELOAD` once and forks each worker from there, so that a worker starts in milliseconds
    with everything imported. It serves the studies of this process until it exits, with the
    environment it started with (one BLAS thread per worker). Where there is no fork server, the
    workers are spawned.
    """
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    kinds = sorted({c.scene.model for c in todo if c.scene is not None})
    kinds += ["plot"] if any(c.scene.outputs.plot for c in todo if c.scene is not None) else []
    ctx.set_forkserver_preload(list(dict.fromkeys(m for kind in kinds for m in PRELOAD[kind])))
    return ctx


def stop_pool(ex: Any) -> None:
    """Cancel the pending cases and end the worker processes now (not after their running case)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)
        if p.is_alive():
            p.kill()
