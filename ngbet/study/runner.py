"""Running a study: its cases from the cache or computed, then its folder, figures and report.

A :class:`~ngbet.study.model.Study` is a base scene, a list of cases (each a dict of
:meth:`Scene.with_changes` keys: ``{"discretization.order_u": 3, "effects.penalty_K": 1e9}``) and
the functions that turn the cases' results into tables, figures and a short report;
:func:`run_study` runs it (cache layout: :mod:`ngbet.study.cache`; study folder:
:mod:`ngbet.study.collect`). Execution: in this process (``workers = 1``), in local processes
(default: one per core) or on a dask.distributed cluster given its scheduler address. A study
with a case whose scene validation refuses is refused before any case runs
(:func:`~ngbet.study.reads.case_scenes`). A reference, error or Pareto front
is never computed from a missing or nan value (:class:`MissingValueError`: the report says what
is missing, the command exits 1).
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from pathlib import Path
from typing import Any

from ..run_folder import OwnedFolder
from .cache import cached, clean_debris, run_dir, study_lock
from .cluster import run_dask
from .collect import collect
from .executors import Bar, StudyInterrupted, accept, execute_case, run_processes
from .figures import finish
from .keys import case_key
from .model import Case, Study, StudyData
from .reads import case_scenes, check_cases_read

__all__ = ["DEFAULT_ROOT", "default_out", "execute", "run_study"]

log = logging.getLogger(__name__)

DEFAULT_ROOT = Path("out/studies")


def default_out(name: str, quick: bool) -> Path:
    """The default folder of a study: out/studies/NAME, or NAME-quick."""
    return DEFAULT_ROOT / (f"{name}-quick" if quick else name)


def run_study(
    study: Study,
    out: str | Path | None = None,
    cache: str | Path | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    retry_failed: bool = False,
    threads: int | None = None,
    folder: OwnedFolder | None = None,
) -> StudyData:
    """Run the missing cases of ``study``, then write its tables, meta.json, figures and report.

    A case whose scene validation refuses, and a key the cases vary that none of them reads, are
    refused (:class:`SceneError`, before the folder is touched): the first is no run, the cases of
    the second would be the same run (:func:`~ngbet.study.reads.case_scenes`,
    :func:`~ngbet.study.reads.check_cases_read`).

    The study folder ``out`` is owned as ``ngbet run`` owns its run folder (:class:`OwnedFolder`):
    refused when it is a run folder, another command's, or holds files of the user's with the names
    a study writes; the files of the study's earlier run there that this one does not write again
    (an earlier figure) are removed at the end, nothing else.

    workers : local worker processes (default: one per core, at most one per missing case);
        1 runs the cases in this process.
    scheduler : address of a dask.distributed scheduler ("tcp://host:8786"); overrides workers.
    threads : NGSolve threads per case (default: all cores in this process, 1 in parallel).
    folder : ``out`` already taken by the caller (its ownership passes to this call, which releases it).
    """
    t_start = time.perf_counter()
    out = Path(out) if out is not None else default_out(study.name, False)
    cache = Path(cache) if cache is not None else DEFAULT_ROOT / "cache"
    try:  # a case ngbet refuses, a key the cases vary and none reads: refused before the folder is touched
        cases = _cases(study)
        check_cases_read(study, [c.scene for c in cases])
    except BaseException:
        if folder is not None:
            folder.release()
        raise
    with folder or OwnedFolder(out, "study", study.name) as own:
        own.remove("report.md", "meta.json")  # written again at the end; never left from an older run
        cache.mkdir(parents=True, exist_ok=True)
        return _locked(study, cases, out, cache, workers, scheduler, progress, retry_failed, threads, t_start)


def _locked(
    study: Study,
    cases: list[Case],
    out: Path,
    cache: Path,
    workers: int | None,
    scheduler: str | None,
    progress: bool,
    retry_failed: bool,
    threads: int | None,
    t_start: float,
) -> StudyData:
    with study_lock(cache) as token:  # an unwritable cache fails here, naming it, whatever the workers
        if clean_debris(cache):
            log.info("removed the unfinished case folders of ended studies from %s", cache)
        try:
            return _run(study, cases, out, cache, token, workers, scheduler, progress, retry_failed, threads, t_start)
        finally:  # this study's unfinished folders (an interrupt, a lost cluster): nobody else may remove them
            for d in [*cache.glob(f".run-*-{token}"), *cache.glob(f".tmp-*-{token}-*")]:
                shutil.rmtree(d, ignore_errors=True)


def _run(
    study: Study,
    cases: list[Case],
    out: Path,
    cache: Path,
    token: str,
    workers: int | None,
    scheduler: str | None,
    progress: bool,
    retry_failed: bool,
    threads: int | None,
    t_start: float,
) -> StudyData:
    todo, seen = _to_run(cases, cache, retry_failed)
    mode, nworkers, threads = _executor(todo, workers, scheduler, threads)
    executor_info = {
        "mode": mode,
        "workers": nworkers,
        "scheduler": scheduler,
        "threads_per_case": threads,
        "cases_run": len(todo),
        "cases_cached": sum(1 for c in cases if c.record.get("cached")),
    }
    log.info("study %s: %d cases, %d to run (%s)", study.name, len(cases), len(todo), mode)

    if todo:
        execute(todo, cache, token, mode, nworkers, scheduler, threads, progress, study.name)
    for c in cases:  # duplicates of a scene share its record
        if c.key in seen and c is not seen[c.key]:
            c.record = dict(seen[c.key].record)

    data = collect(study, cases, cache, out, executor_info, time.perf_counter() - t_start)
    finish(study, data)
    return data


def _cases(study: Study) -> list[Case]:
    """The study's cases with their scenes and cache keys.

    A case whose scene validation refuses is refused with the study (:func:`~ngbet.study.reads.case_scenes`,
    a :class:`SceneError`). A case's scene is not warned about keys its model does not read: the
    cases of one study share a base scene across models (the base itself was warned about where it
    was read); a key the cases vary that none of them reads is refused
    (:func:`~ngbet.study.reads.check_cases_read`).
    """
    scenes = case_scenes(study)
    return [Case(i, params, sc, case_key(sc)) for i, (params, sc) in enumerate(zip(study.cases, scenes, strict=True))]


def _to_run(cases: list[Case], cache: Path, retry_failed: bool) -> tuple[list[Case], dict[str, Case]]:
    """The cases to run (cached ones get their record; a scene twice runs once) and those by key."""
    todo: list[Case] = []
    seen: dict[str, Case] = {}
    for c in cases:
        if c.key is None:
            continue
        rec = cached(cache / c.key)
        if rec is not None and (rec.get("status") == "ok" or not retry_failed):
            c.record = {**rec, "cached": True}
            continue
        if c.key in seen:  # the same scene twice in one study: run once
            continue
        seen[c.key] = c
        todo.append(c)
    return todo, seen


def _executor(
    todo: list[Case], workers: int | None, scheduler: str | None, threads: int | None
) -> tuple[str, int | None, int]:
    """(mode, worker processes, NGSolve threads per case) for the cases to run."""
    ncpu = os.cpu_count() or 1
    if scheduler:
        mode, nworkers = "dask", None
    else:
        nworkers = max(1, min(workers or ncpu, len(todo) or 1))
        mode = "process" if nworkers > 1 else "inprocess"
        if not todo:
            mode, nworkers = "cache", 0
    if threads is None:
        threads = ncpu if mode == "inprocess" else 1
    return mode, nworkers, threads


def execute(
    todo: list[Case],
    cache: Path,
    token: str,
    mode: str,
    nworkers: int | None,
    scheduler: str | None,
    threads: int,
    progress: bool,
    name: str,
) -> None:
    """Run the cases; each is stored as soon as it finishes and verified before it counts.

    Ctrl-C (or SIGTERM in the CLI) keeps the finished ones, cancels the others and stops the workers
    (the caller removes the study's unfinished folders).
    """
    wds = {c.key: run_dir(cache, c.key, token) for c in todo}  # type: ignore[arg-type]
    running: dict[str, tuple[Path, float]] = {}
    bar = Bar(len(todo), name, running, progress)
    finished_keys: set[str] = set()

    def finished(c: Case, rec: dict[str, Any], wd: Path | None) -> None:
        c.record = accept(cache, token, c, rec, wd)
        with bar.lock:
            running.pop(c.key or "", None)
            bar.done += 1
            finished_keys.add(c.key or "")
        bar.tick(f"case {c.index} {c.record['status']} {c.record.get('wall_s', 0):.1f} s")

    if mode != "dask":
        bar.start_polling()
    try:
        if mode == "inprocess":
            for c in todo:
                with bar.lock:
                    running[c.key] = (wds[c.key], c.scene.loading.u0_mm)  # type: ignore[index,union-attr]
                rec = execute_case(c.scene.to_dict(), threads, str(wds[c.key]), str(cache), c.key, token)  # type: ignore[union-attr]
                finished(c, rec, wds[c.key])
        elif mode == "process":
            run_processes(todo, wds, nworkers, threads, running, bar.lock, finished, cache, token)
        else:
            run_dask(todo, scheduler, threads, finished)  # type: ignore[arg-type]
    except KeyboardInterrupt:
        raise StudyInterrupted(
            f"study {name} interrupted: {len(finished_keys)} finished cases are kept in "
            f"{cache}, {len(todo) - len(finished_keys)} cancelled; run it again to "
            "compute those"
        ) from None
    finally:
        bar.close()
