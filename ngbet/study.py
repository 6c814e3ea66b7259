"""Parameter studies: a list (or grid) of scene variants, each run once into a cache.

A :class:`Study` is a base scene, a list of cases (each a dict of :meth:`Scene.with_changes`
keys: ``{"discretization.order_u": 3, "effects.penalty_K": 1e9}``) and the functions that turn
the cases' results into tables, figures and a short report. :func:`run_study` runs it::

    cache/<key>/            one run folder per case (ngbet.run.run's layout) + case.json
    <out>/results.csv       one row per case and converged load step; the varied keys are columns
    <out>/profiles.csv      mid-axis u_y per case and load step (at the study's profile stations)
    <out>/<table>.csv       extra tables of the study (outlines, ...), extracted from the cache
    <out>/meta.json         scenes, versions, git revision, machine, threads, wall times, errors
    <out>/report.md         the study's numbers (slopes, orders, tables)
    <out>/*.png, *.pdf      figures

Cache key
---------
``key = sha256(complete scene without solver.threads, code version)``. The code version is a
hash of the ngbet sources a run executes (every ``ngbet/**/*.py`` except this runner and the
CLI; for the continuum model without ``ngbet/discrete/``, which it never imports) together with
the versions of ngsolve, netgen, numpy and scipy. A source hash rather than the git revision:
the revision changes with every commit, also of README or tests (needless recomputation), does
not change with uncommitted edits (stale results silently reused) and does not exist outside a
checkout; the source hash has none of these faults. The thread count is left out of the key: it
changes the wall time, not the result (beyond round-off of parallel assembly), and the runner
sets it (1 per case when cases run in parallel).

A case whose solver fails (ngbet.errors.ConvergenceError, both models)
is a result: it is cached with its error and its converged steps and is not retried unless
``retry_failed``. A case that crashes otherwise (a bug, a killed worker) is recorded with its
error in the study but not cached, so that the next run retries it. A scene refused by
validation is recorded as failed without running.

Trust: case.json records the sha256 of every file of the case; each cached case is verified
on every read (checksums, summary.json's status against case.json's, its step count and last
load against results.csv) and a damaged one is recomputed with a warning naming the file. A
reference, error or Pareto front is never computed from a missing or nan value
(:class:`MissingValueError`: the report says what is missing, the command exits 1).
Ctrl-C (SIGINT, or SIGTERM through the CLI) keeps the finished cases in the cache, cancels the
others, stops the local workers at once and removes their unfinished ``.run-*`` folders; the
workers ignore SIGINT (the parent decides) and exit by themselves when the parent dies, even by
SIGKILL, whose leftover folders the next study removes. An unreachable dask scheduler is a
:class:`SchedulerError` after at most 5 s.

Execution: in this process (``workers = 1``), in local processes (default: one per core,
``concurrent.futures``, forked by a fork server that has imported ngbet and NGSolve once) or on
a dask.distributed cluster given its scheduler address (``distributed.Client.submit``; the workers
need ngbet installed, they return the run folder's files to the client, so no shared file system
is needed).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import fcntl
import hashlib
import itertools
import json
import logging
import math
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import NgbetError
from .output import RUN_LOCK, git_revision, machine, read_profiles, read_rows, versions
from .scene import Scene, SceneError

log = logging.getLogger(__name__)

DEFAULT_ROOT = Path("out/studies")
_CODE_VERSION: dict[str, dict[str, str]] = {}
# modules a case's run does not execute: the runner and entry points, and the build-time revision
# (a reinstall at another commit must not invalidate the cache when no code changed)
_NOT_IN_KEY = ("study.py", "cli.py", "api.py", "fit.py", "scene_doc.py", "revision.py", "_revision.py")


# ---------------------------------------------------------------------------------------------
# cache keys
# ---------------------------------------------------------------------------------------------
def code_version(model: str = "continuum") -> dict[str, str]:
    """The code a run of ``model`` executes: a hash of its ngbet sources and the library versions.

    Computed once per process, so that a study sees one consistent version even when the
    sources are edited while it runs.
    """
    if model not in _CODE_VERSION:
        pkg = Path(__file__).resolve().parent
        h = hashlib.sha256()
        for path in sorted(pkg.rglob("*.py")):
            rel = path.relative_to(pkg).as_posix()
            if (rel in _NOT_IN_KEY or rel.startswith("studies/")
                    or (model != "discrete" and rel.startswith("discrete/"))):
                continue
            h.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
        v = versions()
        _CODE_VERSION[model] = {"sources_sha256": h.hexdigest()[:16], "ngbet": v.get("ngbet", "?"),
                                **{k: v.get(k, "?") for k in ("ngsolve", "netgen", "numpy", "scipy")}}
    return _CODE_VERSION[model]


def case_key(scene: Scene) -> str:
    """Cache key of a case: the complete scene (threads aside) and the code version."""
    d = scene.to_dict()
    d["solver"]["threads"] = 0
    blob = json.dumps({"scene": _floats(d), "code": code_version(scene.model)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def _floats(v: Any) -> Any:
    """10 and 10.0 are the same scene value: hash every number as a float."""
    if isinstance(v, dict):
        return {k: _floats(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_floats(x) for x in v]
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    return v


def grid(**axes: Iterable[Any]) -> list[dict[str, Any]]:
    """The cartesian product of value lists: ``grid(**{"a.b": [1, 2], "c.d": [3]})``."""
    names = list(axes)
    return [dict(zip(names, values, strict=True)) for values in itertools.product(*(list(axes[n]) for n in names))]


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
@dataclass
class StudyData:
    """Everything a study wrote, read back from its folder (what figures and reports use)."""

    out: Path
    rows: list[dict[str, Any]]
    profiles: list[dict[str, Any]]
    tables: dict[str, list[dict[str, Any]]]
    meta: dict[str, Any]

    def case_rows(self, case: int) -> list[dict[str, Any]]:
        """The load-step rows of a case (rows without a load left out)."""
        return [r for r in self.rows if int(r["case"]) == case and r.get("u0_mm") not in ("", None)]

    def cases(self) -> list[dict[str, Any]]:
        """The case records of meta.json (index, parameters, key, status)."""
        return self.meta["cases"]

    def at(self, case: int, u0_mm: float, col: str) -> float:
        """Value of ``col`` of a case at the load step u0 (nan when not reached)."""
        for r in self.case_rows(case):
            if isinstance(r["u0_mm"], float) and abs(r["u0_mm"] - u0_mm) < 1e-6:
                v = r.get(col)
                return float(v) if isinstance(v, (int, float)) else math.nan
        return math.nan

    def profile(self, case: int, u0_mm: float) -> tuple[list[float], list[float]]:
        """The mid-axis profile (X [mm], u_y [mm]) of a case at the load u0."""
        X, uy = [], []
        for r in self.profiles:
            if int(r["case"]) == case and abs(float(r["u0_mm"]) - u0_mm) < 1e-6:
                X.append(float(r["X_mm"]))
                uy.append(float(r["uy_mm"]))
        return X, uy

    def find(self, **params: Any) -> list[int]:
        """Indices of the cases whose parameters contain ``params`` (dotted keys with '.' or '__')."""
        want = {k.replace("__", "."): v for k, v in params.items()}
        out = []
        for c in self.cases():
            p = c["params"]
            if all(k in p and _same(p[k], v) for k, v in want.items()):
                out.append(c["case"])
        return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0) or a == b
    return a == b


Extract = Callable[[dict[str, Any], Path, Path], dict[str, list[dict[str, Any]]]]


@dataclass
class Study:
    """A named list of scene variants over a base scene, with its figures and report.

    cases : dicts of :meth:`Scene.with_changes` keys; every key used by any case becomes a
        column of results.csv.
    extract(case_record, run_dir, out) : extra rows (by table name) read from a case's run folder
        (e.g. outlines from its VTK file); it may also copy files into ``out``.
    plot(data) : draws the figures from a :class:`StudyData`; returns their paths.
    report(data) : the study's numbers as Markdown text (written to report.md and printed).
    profile_stations : loads [mm] whose mid-axis profiles go into profiles.csv (None: all steps).
    """

    name: str
    base: Scene
    cases: list[dict[str, Any]]
    description: str = ""
    extract: Extract | None = None
    plot: Callable[[StudyData], list[Path]] | None = None
    report: Callable[[StudyData], str] | None = None
    profile_stations: tuple[float, ...] | None = None

    def params_columns(self) -> list[str]:
        """The parameter keys of all cases, in the order they first appear."""
        cols: list[str] = []
        for c in self.cases:
            for k in c:
                if k not in cols:
                    cols.append(k)
        return cols


@dataclass
class _Case:
    index: int
    params: dict[str, Any]
    scene: Scene | None
    key: str | None
    record: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# running one case (in a worker)
# ---------------------------------------------------------------------------------------------
def execute_case(scene_dict: dict[str, Any], threads: int, workdir: str | None = None) -> dict[str, Any]:
    """Run one scene into ``workdir`` (or a temporary folder whose files are returned).

    Returns the case record: status ("ok", "failed": the solver gave up, "error": anything
    else), error text, wall time, threads, and with no ``workdir`` the run folder's files as
    ``{"files": {name: bytes}}`` (for dask workers on other machines).
    """
    from .errors import ConvergenceError
    from .run import run

    scene = Scene.from_dict(scene_dict)
    if threads > 0:  # ngbet.run.run sets NGSolve's threads from the scene
        scene = scene.with_changes(**{"solver.threads": threads})
    tmp = workdir is None
    wd = Path(tempfile.mkdtemp(prefix="ngbet-case-")) if tmp else Path(workdir)  # type: ignore[arg-type]
    wd.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rec: dict[str, Any] = {"status": "ok", "error": None, "threads": threads, "host": machine()["node"],
                           "pid": os.getpid()}
    try:
        summary = run(scene, wd, progress=False)
        if summary.get("status") != "ok":
            rec.update(status="failed", error=str(summary.get("error")), error_type="solver")
    except ConvergenceError as exc:
        rec.update(status="failed", error=str(exc), error_type="ConvergenceError")
    except Exception as exc:  # recorded, never fatal for the study
        rec.update(status="error", error=f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}",
                   error_type=type(exc).__name__)
    rec["wall_s"] = time.perf_counter() - t0
    if tmp:
        rec["files"] = {p.relative_to(wd).as_posix(): p.read_bytes() for p in wd.rglob("*") if p.is_file()}
        shutil.rmtree(wd, ignore_errors=True)
    return rec


def _store(cache: Path, key: str, rec: dict[str, Any], workdir: Path | None) -> None:
    """Move a finished case into cache/<key> atomically (a rename).

    Its case.json lists the sha256 of every file (what :func:`verify_case` checks on every read).
    """
    files = rec.pop("files", None)
    tmp = cache / f".tmp-{key}-{uuid.uuid4().hex[:8]}-{os.getpid()}-{_host_tag()}"
    try:
        _fill(tmp, rec, files, workdir)
        final = cache / key
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)
    except BaseException:  # an interrupt or a full disk: no half-stored case is left behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fill(tmp: Path, rec: dict[str, Any], files: dict[str, bytes] | None, workdir: Path | None) -> None:
    """The case folder ``tmp``: the run folder and case.json with the checksums.

    The run folder is moved, or written from the files a dask worker returned.
    """
    if workdir is not None and workdir.exists():
        workdir.rename(tmp)
    else:
        tmp.mkdir(parents=True)
    for name, data in (files or {}).items():
        (tmp / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp / name).write_bytes(data)
    (tmp / RUN_LOCK).unlink(missing_ok=True)
    rec["files_sha256"] = {p.relative_to(tmp).as_posix(): _sha256(p) for p in sorted(tmp.rglob("*"))
                           if p.is_file() and p.name != "case.json"}
    (tmp / "case.json").write_text(json.dumps(rec, indent=2, default=str))


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class MissingValueError(ValueError):
    """A value a study's reference, error or front needs is missing or nan.

    Nothing is computed from it; the report says which case and value instead.
    """


class CacheError(ValueError):
    """A cached case that cannot be trusted; the message names the file and what is wrong."""


def verify_case(run_dir: Path) -> dict[str, Any]:
    """The record of a cached case after checking it; :class:`CacheError` naming the file otherwise.

    Checked: case.json is complete JSON with a status and the sha256 of each file; every file is
    there with that checksum; summary.json agrees with case.json (status) and with results.csv
    (number of steps, last load).
    """
    case_json = run_dir / "case.json"
    rec = _json_file(case_json)
    sums = rec.get("files_sha256")
    if rec.get("status") not in ("ok", "failed") or not isinstance(sums, dict) or not sums:
        raise CacheError(f"{case_json}: no status or no checksums (incomplete, or written by an older ngbet)")
    for name, digest in sums.items():
        f = run_dir / name
        if not f.is_file():
            raise CacheError(f"{f}: missing")
        if _sha256(f) != digest:
            raise CacheError(f"{f}: checksum mismatch (changed or truncated since it was cached)")
    summary = _json_file(run_dir / "summary.json")
    if summary.get("status") != rec["status"]:
        raise CacheError(f"{run_dir / 'summary.json'}: status {summary.get('status')!r} but case.json "
                         f"says {rec['status']!r}")
    steps = read_rows(run_dir / "results.csv") if (run_dir / "results.csv").exists() else []
    if len(steps) != summary.get("steps") or (steps and not math.isclose(
            float(steps[-1].get("u0_mm", math.nan)), float(summary.get("u0_reached_mm", math.nan)), abs_tol=1e-9)):
        raise CacheError(f"{run_dir / 'results.csv'}: {len(steps)} steps do not match summary.json")
    return rec


def _json_file(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise CacheError(f"{path}: missing") from None
    except (OSError, ValueError) as exc:
        raise CacheError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise CacheError(f"{path}: not a JSON object")
    return data


def clean_debris(cache: Path) -> int:
    """Remove the folders that killed studies left behind; returns how many.

    The ``.run-*`` folders whose run lock is free (a running study's are locked), and the
    ``.tmp-*`` folders of a store (a store lasts milliseconds) whose process is gone: those written
    on this machine by a process that no longer exists, any other older than 10 minutes (another
    machine's, sharing the cache, or one named before the storing process was part of the name).
    """
    n = 0
    old = time.time() - 600
    tmps = [t for t in cache.glob(".tmp-*") if _store_orphaned(t.name) or t.stat().st_mtime < old]
    for d in list(cache.glob(".run-*")) + tmps:
        if d.is_dir() and not _locked(d / RUN_LOCK):
            shutil.rmtree(d, ignore_errors=True)
            n += 1
    return n


def _host_tag() -> str:
    """The machine, as a store's folder name gives it (a hash of the host name: no separators in it)."""
    return hashlib.sha256(machine()["node"].encode()).hexdigest()[:8]


def _store_orphaned(name: str) -> bool:
    """Whether the ``.tmp-<key>-<random>-<pid>-<host>`` folder's storing process, on this machine, is gone."""
    parts = name.split("-")
    if len(parts) < 5 or parts[-1] != _host_tag() or not parts[-2].isdigit():
        return False
    try:
        os.kill(int(parts[-2]), 0)
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        return False
    return False


def _locked(lock: Path) -> bool:
    if not lock.exists():
        return False
    with lock.open("a") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return False


def _cached(run_dir: Path) -> dict[str, Any] | None:
    """The verified record of a cached case, or None (absent, or damaged: then a warning names the file)."""
    if not run_dir.exists():
        return None
    try:
        return verify_case(run_dir)
    except CacheError as exc:
        log.warning("cached case not trusted, it is recomputed: %s", exc)
        return None


def _reached(workdir: Path) -> float:
    """Last converged u0 [mm] of a running case (read from its results.csv)."""
    p = workdir / "results.csv"
    try:
        lines = p.read_text().strip().splitlines()
        if len(lines) < 2:
            return 0.0
        head = lines[0].split(",")
        return float(lines[-1].split(",")[head.index("u0_mm")])
    except (OSError, ValueError, IndexError):
        return 0.0


# ---------------------------------------------------------------------------------------------
# running a study
# ---------------------------------------------------------------------------------------------
def default_out(name: str, quick: bool) -> Path:
    """The default folder of a study: out/studies/NAME, or NAME-quick."""
    return DEFAULT_ROOT / (f"{name}-quick" if quick else name)


def run_study(study: Study, out: str | Path | None = None, cache: str | Path | None = None,
              workers: int | None = None, scheduler: str | None = None, progress: bool = True,
              retry_failed: bool = False, threads: int | None = None) -> StudyData:
    """Run the missing cases of ``study``, then write its tables, meta.json, figures and report.

    workers : local worker processes (default: one per core, at most one per missing case);
        1 runs the cases in this process.
    scheduler : address of a dask.distributed scheduler ("tcp://host:8786"); overrides workers.
    threads : NGSolve threads per case (default: all cores in this process, 1 in parallel).
    """
    t_start = time.perf_counter()
    out = Path(out) if out is not None else default_out(study.name, False)
    cache = Path(cache) if cache is not None else DEFAULT_ROOT / "cache"
    out.mkdir(parents=True, exist_ok=True)
    cache.mkdir(parents=True, exist_ok=True)
    for stale in ("report.md", "meta.json"):  # written again at the end; never left from an older run
        (out / stale).unlink(missing_ok=True)
    if clean_debris(cache):
        log.info("removed the unfinished case folders of an interrupted study from %s", cache)

    cases = _cases(study)
    todo, seen = _to_run(cases, cache, retry_failed)
    mode, nworkers, threads = _executor(todo, workers, scheduler, threads)
    executor_info = {"mode": mode, "workers": nworkers, "scheduler": scheduler, "threads_per_case": threads,
                     "cases_run": len(todo), "cases_cached": sum(1 for c in cases if c.record.get("cached"))}
    log.info("study %s: %d cases, %d to run (%s)", study.name, len(cases), len(todo), mode)

    if todo:
        _execute(todo, cache, mode, nworkers, scheduler, threads, progress, study.name)
    for c in cases:  # duplicates of a scene share its record
        if c.key in seen and c is not seen[c.key]:
            c.record = dict(seen[c.key].record)

    data = _collect(study, cases, cache, out, executor_info, time.perf_counter() - t_start)
    finish(study, data)
    return data


def _cases(study: Study) -> list[_Case]:
    """The study's cases with their scenes and cache keys (a bad scene is a failed case)."""
    cases: list[_Case] = []
    for i, params in enumerate(study.cases):
        try:
            sc = study.base.with_changes(**params)
            cases.append(_Case(i, params, sc, case_key(sc)))
        except SceneError as exc:
            cases.append(_Case(i, params, None, None, {"status": "failed", "error": f"bad scene: {exc}",
                                                       "error_type": "SceneError", "wall_s": 0.0}))
    return cases


def _to_run(cases: list[_Case], cache: Path, retry_failed: bool) -> tuple[list[_Case], dict[str, _Case]]:
    """The cases to run (cached ones get their record; a scene twice runs once) and those by key."""
    todo: list[_Case] = []
    seen: dict[str, _Case] = {}
    for c in cases:
        if c.key is None:
            continue
        rec = _cached(cache / c.key)
        if rec is not None and (rec.get("status") == "ok" or not retry_failed):
            c.record = {**rec, "cached": True}
            continue
        if c.key in seen:  # the same scene twice in one study: run once
            continue
        seen[c.key] = c
        todo.append(c)
    return todo, seen


def _executor(todo: list[_Case], workers: int | None, scheduler: str | None,
              threads: int | None) -> tuple[str, int | None, int]:
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


class StudyInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a study: its finished cases are in the cache, the others cancelled."""


class SchedulerError(NgbetError):
    """The dask scheduler could not be reached; ``address`` names it."""

    def __init__(self, address: str, why: str) -> None:
        super().__init__(f"cannot reach the dask scheduler at {address}: {why}")
        self.address = address


SCHEDULER_TIMEOUT_S = 5.0


def _worker_init(parent_alive: Any, ngbet_env: dict[str, str]) -> None:
    """Start of a local worker process: Ctrl-C is for the parent, and the worker exits when the parent dies.

    The parent keeps the finished cases and stops the workers; the worker exits by itself even when the
    parent dies by SIGKILL: ``parent_alive`` is the read end of a pipe whose only write end the parent
    holds, so that it reads end-of-file when the parent is gone (whoever the worker's own parent is,
    and whether or not the dead one is reaped). ``ngbet_env``: the parent's ``NGBET_*`` variables now
    (the fork server's environment is the one it started with).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from .messages import install

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


class _Bar:
    """Progress over cases: finished ones and the part of the load the running ones reached."""

    def __init__(self, total: int, name: str, running: dict[str, tuple[Path, float]], enabled: bool) -> None:
        self.running, self.done, self.lock = running, 0, threading.Lock()
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=f"study {name}", unit="case",
                            bar_format="{l_bar}{bar}| {n:.2f}/{total} cases [{elapsed}<{remaining}]{postfix}")
        self.stop = threading.Event()
        self.poller: threading.Thread | None = None

    def start_polling(self) -> None:
        if self.bar is None:
            return

        def poll() -> None:
            while not self.stop.wait(0.5):
                self.tick()
        self.poller = threading.Thread(target=poll, daemon=True)
        self.poller.start()

    def tick(self, note: str | None = None) -> None:
        if self.bar is None:
            return
        if note:
            self.bar.set_postfix_str(note, refresh=False)
        with self.lock:
            part = sum(min(_reached(wd) / u0, 0.999) for wd, u0 in self.running.values())
            self.bar.n = min(round(self.done + part, 2), self.bar.total)
        self.bar.refresh()

    def close(self) -> None:
        self.stop.set()
        if self.poller is not None:
            self.poller.join(timeout=2)
        if self.bar is not None:
            self.bar.n = self.done
            self.bar.refresh()
            self.bar.close()


def _execute(todo: list[_Case], cache: Path, mode: str, nworkers: int | None, scheduler: str | None,
             threads: int, progress: bool, name: str) -> None:
    """Run the cases; each is cached as soon as it finishes.

    Ctrl-C (or SIGTERM in the CLI) keeps the finished ones, cancels the others, stops the workers and
    removes their unfinished folders.
    """
    wds = {c.key: cache / f".run-{c.key}-{uuid.uuid4().hex[:8]}" for c in todo}
    running: dict[str, tuple[Path, float]] = {}
    bar = _Bar(len(todo), name, running, progress)
    finished_keys: set[str] = set()

    def finished(c: _Case, rec: dict[str, Any], wd: Path | None) -> None:
        if rec.get("status") in ("ok", "failed"):
            _store(cache, c.key, rec, wd)  # type: ignore[arg-type]
        elif wd is not None:
            shutil.rmtree(wd, ignore_errors=True)
        rec.pop("files", None)
        c.record = {**rec, "cached": False}
        with bar.lock:
            running.pop(c.key or "", None)
            bar.done += 1
            finished_keys.add(c.key or "")
        bar.tick(f"case {c.index} {rec['status']} {rec.get('wall_s', 0):.1f} s")

    if mode != "dask":
        bar.start_polling()
    try:
        if mode == "inprocess":
            for c in todo:
                with bar.lock:
                    running[c.key] = (wds[c.key], c.scene.loading.u0_mm)  # type: ignore[index,union-attr]
                finished(c, execute_case(c.scene.to_dict(), threads, str(wds[c.key])), wds[c.key])  # type: ignore[union-attr]
        elif mode == "process":
            _run_processes(todo, wds, nworkers, threads, running, bar.lock, finished)
        else:
            _run_dask(todo, scheduler, threads, finished)  # type: ignore[arg-type]
    except KeyboardInterrupt:
        for c in todo:
            if c.key not in finished_keys:
                shutil.rmtree(wds[c.key], ignore_errors=True)
        raise StudyInterrupted(f"study {name} interrupted: {len(finished_keys)} finished cases are kept in "
                               f"{cache}, {len(todo) - len(finished_keys)} cancelled; run it again to "
                               "compute those") from None
    finally:
        bar.close()


def _run_processes(todo: list[_Case], wds: dict[Any, Path], nworkers: int | None, threads: int,
                   running: dict[str, tuple[Path, float]], lock: threading.Lock,
                   finished: Callable[[_Case, dict[str, Any], Path | None], None]) -> None:
    """Local worker processes (forked by a fork server; they exit with this process, see :func:`_worker_init`)."""
    from ._env import environ

    # one BLAS thread per worker too (inherited by the fork server when it starts, and by its workers)
    with environ({k: str(threads) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}):
        _run_pool(todo, wds, nworkers, threads, running, lock, finished)


def _run_pool(todo: list[_Case], wds: dict[Any, Path], nworkers: int | None, threads: int,
              running: dict[str, tuple[Path, float]], lock: threading.Lock,
              finished: Callable[[_Case, dict[str, Any], Path | None], None]) -> None:
    """Run the cases on a pool of local worker processes; an interrupt keeps the finished ones."""
    import concurrent.futures as cf

    ctx = _worker_context(todo)
    alive_r, alive_w = ctx.Pipe(duplex=False)  # closed when this process ends: see _worker_init
    ex = cf.ProcessPoolExecutor(max_workers=nworkers, mp_context=ctx, initializer=_worker_init,
                                initargs=(alive_r, {k: v for k, v in os.environ.items() if k.startswith("NGBET_")}))
    try:
        _submit_and_collect(ex, todo, wds, threads, running, lock, finished)
    finally:
        alive_w.close()
        alive_r.close()


def _submit_and_collect(ex: Any, todo: list[_Case], wds: dict[Any, Path], threads: int,
                        running: dict[str, tuple[Path, float]], lock: threading.Lock,
                        finished: Callable[[_Case, dict[str, Any], Path | None], None]) -> None:
    """Submit the cases to the pool ``ex`` and record each as it finishes; an interrupt keeps the finished ones."""
    import concurrent.futures as cf

    futs: dict[Any, tuple[_Case, Path]] = {}
    consumed: set[Any] = set()

    def take(fut: Any) -> None:
        c, wd = futs[fut]
        consumed.add(fut)
        try:
            rec = fut.result()
        except Exception as exc:  # a worker died: record, do not cache
            rec = {"status": "error", "error": f"{type(exc).__name__}: {exc}",
                   "error_type": type(exc).__name__, "wall_s": math.nan}
        finished(c, rec, wd)

    try:
        for c in todo:
            futs[ex.submit(execute_case, c.scene.to_dict(), threads, str(wds[c.key]))] = (c, wds[c.key])  # type: ignore[union-attr]
            with lock:
                running[c.key] = (wds[c.key], c.scene.loading.u0_mm)  # type: ignore[index,union-attr]
        for fut in cf.as_completed(futs):
            take(fut)
        ex.shutdown(wait=True)
    except BaseException:
        for fut in futs:  # cases that finished while the interrupt came in are kept
            if fut.done() and not fut.cancelled() and fut not in consumed:
                take(fut)
        _stop_pool(ex)
        raise


#: what the fork server imports, once for all its workers, by the model of the cases ("plot": cases
#: that draw their figures)
PRELOAD = {"continuum": ["ngbet.study", "ngbet.run", "ngbet.continuum.run"],
           "discrete": ["ngbet.study", "ngbet.run", "ngbet.discrete"],
           "plot": ["matplotlib.figure", "matplotlib.backends.backend_agg", "matplotlib.backends.backend_pdf"]}


def _worker_context(todo: list[_Case]) -> Any:
    """The start method of the local workers: a fork server that has imported ngbet and NGSolve.

    The server is a fresh process (no threads, NGSolve's task manager not started) that imports
    :data:`PRELOAD` once and forks each worker from there, so that a worker starts in milliseconds
    with everything imported. It serves the studies of this process until it exits, with the
    environment it started with (one BLAS thread per worker). Where there is no fork server, the
    workers are spawned.
    """
    import multiprocessing as mp

    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    kinds = sorted({c.scene.model for c in todo if c.scene is not None})
    kinds += ["plot"] if any(c.scene.outputs.plot for c in todo if c.scene is not None) else []
    ctx.set_forkserver_preload(list(dict.fromkeys(m for kind in kinds for m in PRELOAD[kind])))
    return ctx


def _stop_pool(ex: Any) -> None:
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


def _run_dask(todo: list[_Case], scheduler: str, threads: int,
              finished: Callable[[_Case, dict[str, Any], Path | None], None]) -> None:
    """A dask.distributed cluster; an unreachable scheduler is a SchedulerError within seconds."""
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S:g}s")
    except Exception as exc:  # refused, timed out, or something that does not speak dask answered
        raise SchedulerError(scheduler, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}") from None
    with client:
        futs = {client.submit(execute_case, c.scene.to_dict(), threads, None,  # type: ignore[union-attr]
                              key=f"ngbet-case-{c.key}-{uuid.uuid4().hex[:6]}", pure=False): c for c in todo}
        consumed = set()
        try:
            for fut in as_completed(list(futs)):
                consumed.add(fut)
                c = futs[fut]
                try:
                    rec = fut.result()
                except Exception as exc:
                    rec = {"status": "error", "error": f"{type(exc).__name__}: {exc}",
                           "error_type": type(exc).__name__, "wall_s": math.nan}
                finished(c, rec, None)
        except KeyboardInterrupt:
            client.cancel([f for f in futs if f not in consumed and not f.done()])
            for f in futs:
                if f not in consumed and f.status == "finished":
                    finished(futs[f], f.result(), None)
            raise


# ---------------------------------------------------------------------------------------------
# collecting, writing, reading back
# ---------------------------------------------------------------------------------------------
CASE_COLUMNS = ("case", "key", "status")
TAIL_COLUMNS = ("dofs", "case_wall_s", "threads", "error")


def _collect(study: Study, cases: list[_Case], cache: Path, out: Path, executor_info: dict[str, Any],
             wall_s: float) -> StudyData:
    """Gather every case's rows, profiles, extracted tables and record; write the study folder."""
    pcols = study.params_columns()
    rows: list[dict[str, Any]] = []
    profiles: list[dict[str, Any]] = []
    tables: dict[str, list[dict[str, Any]]] = {}
    metas = []
    run_cols: list[str] = []
    for c in cases:
        run_dir = cache / c.key if c.key else None
        summary, steps = _read_case(run_dir)
        record = _case_record(c, summary, run_dir)
        rows.extend(_case_rows(c, pcols, steps, record, run_cols))
        if run_dir is not None:
            profiles.extend(_case_profiles(study, c, run_dir))
        metas.append(record)
        if study.extract is not None and run_dir is not None and record["status"] in ("ok", "failed"):
            _extract(study, c, record, run_dir, out, tables)
    _write_csv(out / "results.csv", rows, [*CASE_COLUMNS, *pcols, *run_cols, *TAIL_COLUMNS])
    _write_csv(out / "profiles.csv", profiles, ["case", "u0_mm", "X_mm", "uy_mm"])
    for name, trs in tables.items():
        _write_csv(out / f"{name}.csv", trs, _columns(trs))
    meta = {"study": study.name, "description": study.description, "params": pcols,
            "tables": sorted(tables), "base_scene": study.base.to_dict(), "cases": metas,
            "executor": executor_info, "versions": versions(), "git_revision": git_revision(),
            "code_version": {m: code_version(m) for m in sorted({c.scene.model for c in cases if c.scene})},
            "machine": machine(), "wall_s": wall_s,
            "cpu_s_of_cases": sum(float(m["wall_s"] or 0) for m in metas if m["wall_s"] == m["wall_s"]),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
    return load(out)


def _read_case(run_dir: Path | None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The summary and the step rows of a case's run folder (empty when absent)."""
    summary: dict[str, Any] = {}
    steps: list[dict[str, Any]] = []
    if run_dir is not None and (run_dir / "summary.json").exists():
        summary = json.loads((run_dir / "summary.json").read_text())
    if run_dir is not None and (run_dir / "results.csv").exists():
        steps = read_rows(run_dir / "results.csv")
    return summary, steps


def _case_record(c: _Case, summary: dict[str, Any], run_dir: Path | None) -> dict[str, Any]:
    """The case's entry of meta.json."""
    rec = c.record
    dofs = summary.get("dofs")
    dofs = dofs.get("total") if isinstance(dofs, dict) else dofs
    return {"case": c.index, "params": c.params, "key": c.key, "status": rec.get("status", "error"),
            "error": rec.get("error"), "error_type": rec.get("error_type"), "cached": rec.get("cached", False),
            "wall_s": summary.get("wall_s", rec.get("wall_s")), "threads": rec.get("threads"),
            "host": rec.get("host"), "dofs": dofs, "u0_reached_mm": summary.get("u0_reached_mm"),
            "run_dir": str(run_dir) if run_dir else None,
            "scene": c.scene.to_dict() if c.scene is not None else None}


def _case_rows(c: _Case, pcols: list[str], steps: list[dict[str, Any]], record: dict[str, Any],
               run_cols: list[str]) -> list[dict[str, Any]]:
    """The case's rows of the study's results.csv (one per step; ``run_cols`` gains new columns)."""
    base = {"case": c.index, "key": c.key or "", "status": record["status"],
            **{k: _cell(c.params.get(k, "")) for k in pcols}}
    tail = {"dofs": record["dofs"] if record["dofs"] is not None else "",
            "case_wall_s": record["wall_s"] if record["wall_s"] is not None else "",
            "threads": c.record.get("threads", ""), "error": _short(c.record.get("error"))}
    for s in steps:
        run_cols.extend(k for k in s if k not in run_cols)
    return [{**base, **s, **tail} for s in steps or [{}]]


def _case_profiles(study: Study, c: _Case, run_dir: Path) -> list[dict[str, Any]]:
    """The case's mid-axis profiles at the study's stations."""
    if not (run_dir / "profile.csv").exists():
        return []
    out: list[dict[str, Any]] = []
    for u0, (X, uy) in read_profiles(run_dir / "profile.csv").items():
        if study.profile_stations is None or any(abs(u0 - s) < 1e-6 for s in study.profile_stations):
            out.extend({"case": c.index, "u0_mm": u0, "X_mm": x, "uy_mm": y} for x, y in zip(X, uy, strict=True))
    return out


def _extract(study: Study, c: _Case, record: dict[str, Any], run_dir: Path, out: Path,
             tables: dict[str, list[dict[str, Any]]]) -> None:
    """The study's own tables from one case; a failure is recorded, never fatal."""
    assert study.extract is not None
    try:
        for name, trs in study.extract(record, run_dir, out).items():
            tables.setdefault(name, []).extend({"case": c.index, **r} for r in trs)
    except Exception as exc:
        record["extract_error"] = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, ImportError) and exc.name:  # pyvista reads the fields
            log.warning("study %s case %d: no tables from the fields: %s is not installed (pip install %s)",
                        study.name, c.index, exc.name, exc.name)
        else:
            log.warning("study %s case %d: extraction failed: %s", study.name, c.index, exc)


def _cell(v: Any) -> Any:
    return json.dumps(v) if isinstance(v, (list, tuple, dict)) else v


def _short(err: Any, n: int = 400) -> str:
    if not err:
        return ""
    s = " ".join(str(err).split())
    return s if len(s) <= n else s[: n - 3] + "..."


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    return cols


def _write_csv(path: Path, rows: list[dict[str, Any]], columns: list[str]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(v) for k, v in r.items()})


def _fmt(v: Any) -> Any:
    if isinstance(v, bool):
        return v
    if isinstance(v, float) or type(v).__module__ == "numpy":
        try:
            f = float(v)
        except (TypeError, ValueError):
            return v
        return repr(int(f)) if type(v).__name__.startswith(("int", "uint")) else repr(f)
    return v


def _read_csv(path: Path) -> list[dict[str, Any]]:
    """A study CSV as rows of numbers (text kept), or no rows when the file is absent."""
    return read_rows(path) if path.exists() else []


def load(out: str | Path) -> StudyData:
    """Read a study folder back (no solving): results.csv, profiles.csv, tables, meta.json."""
    out = Path(out)
    meta = json.loads((out / "meta.json").read_text())
    tables = {name: _read_csv(out / f"{name}.csv") for name in meta.get("tables", [])}
    return StudyData(out, _read_csv(out / "results.csv"), _read_csv(out / "profiles.csv"), tables, meta)


def finish(study: Study, data: StudyData) -> list[Path]:
    """Figures (PNG + PDF) and report.md from the study folder's CSV files."""
    from importlib.util import find_spec

    figs: list[Path] = []
    if study.plot is not None and find_spec("matplotlib") is None:
        log.warning("study %s: no figures: matplotlib is not installed (pip install matplotlib)", study.name)
    elif study.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        try:
            figs = list(study.plot(data) or [])
        except MissingValueError as exc:
            data.meta["report_error"] = str(exc)
            log.error("study %s: no figures: %s", study.name, exc)
    if study.report is not None:
        try:
            text = study.report(data)
        except MissingValueError as exc:  # no report from incomplete data, and no figure either
            text = f"# {study.name}: no report\n\n{exc}\n"
            data.meta["report_error"] = str(exc)
            log.error("study %s: no report: %s", study.name, exc)
        (data.out / "report.md").write_text(text)
    if data.meta.get("report_error"):  # meta.json says so too (the command exits 1)
        (data.out / "meta.json").write_text(json.dumps(data.meta, indent=2, default=str))
    return figs


def plot_only(study: Study, out: str | Path) -> StudyData:
    """Redraw figures and report from the CSV files of a finished study, without solving."""
    data = load(out)
    finish(study, data)
    return data


def savefig(fig: Any, out: Path, name: str) -> Path:
    """Save a matplotlib figure as PNG and PDF; returns the PNG path."""
    png = out / f"{name}.png"
    fig.savefig(png, dpi=140)
    fig.savefig(out / f"{name}.pdf")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return png


# ---------------------------------------------------------------------------------------------
# command line (python -m ngbet.studies.NAME, ngbet study NAME)
# ---------------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command-line options every study takes."""
    p.add_argument("--quick", action="store_true", help="a small version of the study (seconds; what the tests run)")
    p.add_argument("--out", help="study folder (default: out/studies/NAME, or NAME-quick)")
    p.add_argument("--cache", help="case cache folder (default: out/studies/cache)")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; 1 = in this process)")
    p.add_argument("--scheduler", help="dask.distributed scheduler address, e.g. tcp://host:8786")
    p.add_argument("--threads", type=int, help="NGSolve threads per case (default: 1 in parallel, all cores otherwise)")
    p.add_argument("--plot-only", action="store_true", help="redraw figures and report from the CSV files")
    p.add_argument("--retry-failed", action="store_true", help="rerun cases whose solver failed before")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def main_for(build: Callable[[bool], Study], argv: list[str] | None = None, prog: str | None = None) -> int:
    """Command line of one study module: ``python -m ngbet.studies.NAME [--quick] [...]``."""
    p = argparse.ArgumentParser(prog=prog, description=(build(False).description or "").split("\n")[0])
    add_arguments(p)
    return run_from_args(build, p.parse_args(argv))


def run_from_args(build: Callable[[bool], Study], args: argparse.Namespace) -> int:
    """Run (or with ``--plot-only`` redraw) the study ``build`` gives for the options; the exit status."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    study = build(args.quick)
    out = Path(args.out) if args.out else default_out(study.name, args.quick)
    if args.plot_only:
        if not (out / "meta.json").exists():
            print(f"ngbet study: no finished study in {out} (meta.json missing)", file=sys.stderr)
            return 2
        data = plot_only(study, out)
    else:
        data = run_study(study, out, cache=args.cache, workers=args.workers, scheduler=args.scheduler,
                         progress=not args.quiet, retry_failed=args.retry_failed, threads=args.threads)
    st = [c["status"] for c in data.cases()]
    ex = data.meta["executor"]
    print(f"study {study.name}: {len(st)} cases ({st.count('ok')} ok, {st.count('failed')} failed, "
          f"{st.count('error')} errors; {ex['cases_run']} run, {ex['cases_cached']} from the cache) "
          f"in {data.meta['wall_s']:.1f} s -> {out}/")
    if (out / "report.md").exists():
        print((out / "report.md").read_text())
    if data.meta.get("report_error"):
        return 1
    return 0 if st.count("error") == 0 else 1
