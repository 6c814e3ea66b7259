"""The command line of a study: ``ngbet study NAME`` and ``python -m ngbet.studies.NAME``.

Options every study takes (:func:`add_arguments`); what ``--quick`` leaves out of the full study
(:func:`left_out`), said in the report and on the terminal; the exit status of a study.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import inspect
import logging
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..run_folder import FOLDER_MARKER, OutputError, OwnedFolder
from ..scene.document import Scene
from .collect import StudyFolderError
from .figures import plot_only
from .keys import as_floats, flat, value_text
from .model import Study, same_value
from .reads import case_scenes, check_cases_read
from .runner import DEFAULT_ROOT, default_out, run_study

__all__ = ["add_arguments", "build_options", "build_study", "left_out", "main_for", "run_from_args"]


def at_least_one(text: str) -> int:
    """An argument that counts processes or threads: a whole number of at least 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n} must be at least 1")
    return n


def add_arguments(p: argparse.ArgumentParser, *, data: bool = True) -> None:
    """The command-line options every study takes.

    ``data``: with ``--data`` (measured curves), for a command that may read them (a sweep reads
    none: without it, ``--data`` is an unknown option).
    """
    p.add_argument("--quick", action="store_true", help="a small version of the study (seconds; what the tests run)")
    p.add_argument(
        "--out",
        help="study folder (default: out/studies/NAME, or NAME-quick; on a scene file or with "
        "--set, NAME-scene-DIGEST, DIGEST the scene's)",
    )
    p.add_argument("--cache", help="case cache folder (default: out/studies/cache)")
    p.add_argument(
        "--workers", type=at_least_one, help="local worker processes (default: one per core; 1 = in this process)"
    )
    p.add_argument("--scheduler", help="dask.distributed scheduler address, e.g. tcp://host:8786")
    p.add_argument(
        "--threads", type=at_least_one, help="NGSolve threads per case (default: 1 in parallel, all cores otherwise)"
    )
    p.add_argument(
        "--plot-only",
        action="store_true",
        help="redraw figures and report from the CSV files of the study these arguments name (nothing runs)",
    )
    p.add_argument("--retry-failed", action="store_true", help="rerun cases whose solver failed before")
    p.add_argument("--quiet", action="store_true", help="one line: no progress bar, no report on the terminal")
    if not data:
        return
    p.add_argument(
        "--data",
        action="append",
        default=[],
        metavar="PATH",
        help="a folder (its *.csv) or a file of measured curves, for a study that compares with measured "
        "curves: the validation study predicts each curve of its fabrics there (repeatable); a sweep and "
        "the other studies read none and refuse it",
    )


def main_for(build: Callable[[bool], Study], argv: list[str] | None = None, prog: str | None = None) -> int:
    """Command line of one study module: ``python -m ngbet.studies.NAME [--quick] [...]``."""
    doc = sys.modules[build.__module__].__doc__ if build.__module__ in sys.modules else None
    p = argparse.ArgumentParser(prog=prog, description=(doc or "").split("\n")[0])  # no build: it may fit
    add_arguments(p)
    return run_from_args(build, p.parse_args(argv), name=build.__module__.rsplit(".", 1)[-1])


def _refuse_set_of_varied_keys(study: Study, overrides: list[str]) -> None:
    """A ``--set`` of a key the study's cases set themselves would be overridden by every case: refused."""
    from ..scene.validate import SceneError

    varied = set(study.params_columns())
    for item in overrides:
        key = item.partition("=")[0].strip()
        if key in varied:
            values = list(dict.fromkeys(value_text(c[key]) for c in study.cases if key in c))
            raise SceneError(
                f"--set {item}: {key} is what the {study.name} study varies (its cases set it to "
                f"{', '.join(values[:6])}{', ...' if len(values) > 6 else ''}), so the value would not "
                "be used; leave it out, or sweep the values you want (ngbet sweep)"
            )


def _remove_if_empty(folder: Path) -> None:
    """Remove ``folder`` when it holds nothing but the mark of a study folder (nothing else is touched)."""
    with contextlib.suppress(OSError):
        if [p.name for p in folder.iterdir()] == [FOLDER_MARKER]:
            (folder / FOLDER_MARKER).unlink()
            folder.rmdir()


def _check_working_folder(args: argparse.Namespace) -> None:
    """A relative --out or --cache (or their defaults) needs the current folder: refuse a deleted one by name."""
    try:
        os.getcwd()
    except FileNotFoundError:
        if not (args.out and os.path.isabs(args.out) and args.cache and os.path.isabs(args.cache)):
            raise OutputError(
                os.environ.get("PWD", "."),
                "the current folder no longer exists (deleted or moved), "
                "and the study's folder or cache is relative to it: change to a folder that "
                "exists, or give --out and --cache as absolute paths",
            ) from None


def _probe_cache(cache: Path) -> None:
    """Create the case cache and write into it once: an unusable one is an OSError naming it, before any work."""
    try:
        cache.mkdir(parents=True, exist_ok=True)
        probe = cache / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OSError(
            exc.errno, f"{exc.strerror} (a study keeps its cases and fits in its cache folder)", str(cache)
        ) from None


def left_out(full: Study, quick: Study) -> list[str]:
    """What ``quick`` leaves out of ``full``: changed base-scene values and case values not run.

    A base value the cases set themselves is not named (the cases say what runs).
    """
    varied = {k for k in full.params_columns() if all(k in c for c in full.cases)}
    fb, qb = flat(as_floats(full.base.to_dict())), flat(as_floats(quick.base.to_dict()))
    notes = [
        f"{k} = {value_text(fb[k])} (runs {value_text(qb.get(k))})"
        for k in fb
        if fb[k] != qb.get(k) and k not in varied and k != "solver.threads"
    ]
    for k in full.params_columns():
        ran = [c[k] for c in quick.cases if k in c]
        gone = [c[k] for c in full.cases if k in c and not any(same_value(c[k], v) for v in ran)]
        with contextlib.suppress(TypeError):  # numbers in order; other values as they come
            gone.sort()
        if gone:
            notes.append(f"{k} = {', '.join(dict.fromkeys(value_text(v) for v in gone))}")
    if len(quick.cases) < len(full.cases):
        notes.append(f"{len(full.cases) - len(quick.cases)} of the full study's {len(full.cases)} cases")
    return notes


def build_options(
    build: Callable[..., Study], cache: Path | None, data: Sequence[str], workers: int | None = None
) -> dict[str, Any]:
    """The keyword arguments ``build`` takes of ``cache``, ``data`` (``--data``) and ``workers`` (``--workers``).

    ``data`` given to a ``build`` without a ``data`` parameter is refused (SceneError), as it would
    be ignored. ``workers`` reaches a ``build`` that runs work of its own in worker processes (the
    validation study's fits); None: its default.
    """
    params = inspect.signature(build).parameters
    kw: dict[str, Any] = {"cache": cache} if "cache" in params else {}
    if workers is not None and "workers" in params:
        kw["workers"] = workers
    if data:
        if "data" not in params:
            from ..scene.validate import SceneError

            raise SceneError(f"--data {data[0]}: this study reads no measured curves (study validation does)")
        kw["data"] = tuple(data)
    return kw


def build_study(
    build: Callable[..., Study],
    quick: bool,
    scene: Scene | None = None,
    source: str = "",
    cache: Path | None = None,
    data: Sequence[str] = (),
    workers: int | None = None,
) -> Study:
    """The study ``build`` gives, on ``scene`` (None: the study's default), with what ``quick`` leaves out.

    ``cache``: the study cache, handed to a ``build`` that keeps work of its own there (a ``cache``
    parameter: the validation study's fits). ``data``: measured curves (``--data``), handed to a
    ``build`` with a ``data`` parameter; refused for another (SceneError: it would be ignored).
    ``workers`` (``--workers``): to a ``build`` with a ``workers`` parameter.
    """
    kw = build_options(build, cache, data, workers)
    study = build(quick, scene, **kw) if scene is not None else build(quick, **kw)
    study.scene_source = source
    if quick and not study.left_out:  # a study whose full build is costly (fits) says it itself
        study.left_out = left_out(build(False, scene, **kw) if scene is not None else build(False, **kw), study)
    return study


def _prepare(
    build: Callable[..., Study], args: argparse.Namespace, scene: Scene | None, source: str, name: str | None
) -> tuple[Study, Path, OwnedFolder | None]:
    """The study, its folder and (when its name is known before it is built) the folder, owned first.

    A study on another scene than its default, or with ``--data``, has a folder of its own (the
    scene's digest, the data paths' digest in its name), so the default study's folder stays as it
    is. The folder and the cache are checked before the study is built: a study may fit before it
    runs its cases.
    """
    data = getattr(args, "data", None) or []
    build_options(build, None, data)  # refused before the folder is made

    def folder_name(n: str) -> str:  # a study on another scene, or on more data, has a folder of its own
        n = n if scene is None else f"{n}-scene-{scene.digest()[:8]}"
        if data:
            paths = sorted(str(Path(d).resolve()) for d in data)
            n += "-data-" + hashlib.sha256("\n".join(paths).encode()).hexdigest()[:8]
        return n

    folder, made = None, False
    if name is not None and not args.plot_only:
        _check_working_folder(args)
        where = Path(args.out) if args.out else default_out(folder_name(name), args.quick)
        made = not where.exists()
        folder = OwnedFolder(where, "study", name)
    try:
        if not args.plot_only:
            _probe_cache(Path(args.cache) if args.cache else DEFAULT_ROOT / "cache")
        cache = Path(args.cache) if args.cache else None
        study = build_study(build, args.quick, scene, source, cache, data, getattr(args, "workers", None))
        _refuse_set_of_varied_keys(study, getattr(args, "overrides", None) or [])
        if not args.plot_only:  # a redraw draws the study its folder holds, checked against these arguments
            check_cases_read(study, case_scenes(study))
    except BaseException:
        if folder is not None:
            folder.release()
            if made:  # refused: the folder this command made goes again, when it holds nothing but its mark
                _remove_if_empty(folder.out)
        raise
    out = Path(args.out) if args.out else default_out(folder_name(study.name), args.quick)
    return study, out, folder


def run_from_args(
    build: Callable[..., Study],
    args: argparse.Namespace,
    scene: Scene | None = None,
    source: str = "",
    name: str | None = None,
) -> int:
    """Run (or with ``--plot-only`` redraw) the study ``build`` gives for the options; the exit status.

    scene : the base scene (None: the study's own, on ngbet's default scene); source names it.
    name : the study's name, when known before it is built: its folder and cache are then checked
        first (a study may fit before it runs its cases; an unusable folder is refused before that).

    Exit status 0 when every case reached its final load; 1, after the folder, figures and report
    are written, when a case did not (status "failed": its solver gave up; "error": it crashed),
    one line on stderr naming those cases, or when the report could not be made. ``--plot-only``
    gives the status of the study it redraws, and says that nothing ran. Refused before anything
    runs (exceptions: the command line maps them): a bad scene, a scene of a test the study is not
    made for, a case whose scene validation refuses, a key the cases vary that none of them reads,
    a ``--set`` of a key they vary (SceneError); with
    ``--plot-only``, a folder that holds another study or this one run with other arguments
    (OutputError).
    """
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    study, out, folder = _prepare(build, args, scene, source, name)
    if args.plot_only:
        try:
            data = plot_only(study, out)
        except StudyFolderError as exc:
            print(f"ngbet: study {study.name}: {exc}", file=sys.stderr)
            return 2
    else:
        data = run_study(
            study,
            out,
            cache=args.cache,
            workers=args.workers,
            scheduler=args.scheduler,
            progress=not args.quiet,
            retry_failed=args.retry_failed,
            threads=args.threads,
            folder=folder,
        )
    st = [c["status"] for c in data.cases()]
    warned = [c["case"] for c in data.cases() if c.get("warnings")]
    if warned and not args.quiet:
        print(
            f"ngbet: study {study.name}: {len(warned)} case(s) with warnings ({', '.join(map(str, warned[:8]))}"
            f"{', ...' if len(warned) > 8 else ''}): meta.json lists them",
            file=sys.stderr,
        )
    if data.meta.get("figures_skipped"):
        print(
            f"ngbet: study {study.name}: figures skipped: {data.meta['figures_skipped']}; the tables and "
            "the report are written",
            file=sys.stderr,
        )
    quick = data.meta.get("quick_left_out") or []
    if quick and not args.quiet:
        print(f"study {study.name} --quick leaves out: " + "; ".join(quick))
    counts = f"{st.count('ok')} ok, {st.count('failed')} failed, {st.count('error')} errors"
    if args.plot_only:  # nothing ran: the cases as the study's run left them
        ran = f"redrawn from {out}/ ({len(st)} cases as they ran: {counts})"
    else:
        ex = data.meta["executor"]
        ran = (
            f"{len(st)} cases ({counts}; {ex['cases_run']} run, {ex['cases_cached']} from the cache) "
            f"in {data.meta['wall_s']:.1f} s -> {out}/"
        )
    print(
        f"study {study.name}{' (--quick: what it leaves out is in report.md)' if quick and args.quiet else ''}: {ran}"
    )
    if (out / "report.md").exists() and not args.quiet:  # --quiet: the one line above, the report in its file
        print((out / "report.md").read_text())
    short = [c for c in data.cases() if c["status"] != "ok"]
    if short:
        print(f"ngbet: study {study.name}: {_not_reached(short, len(st))}", file=sys.stderr)
    return 1 if short or data.meta.get("report_error") else 0


def _not_reached(cases: list[dict[str, Any]], n: int) -> str:
    """One line naming the cases (meta.json records) that did not reach their load, and why."""

    def one(c: dict[str, Any]) -> str:
        what = ", ".join(f"{k} = {value_text(v)}" for k, v in c["params"].items())
        error = " ".join(str(c.get("error") or "").split("\n", 1)[0].split())
        at = c.get("u0_reached_mm")
        where = f" (last converged load {value_text(float(at))} mm)" if isinstance(at, (int, float)) else ""
        return f"case {c['case']} ({what}) {c['status']}{where}" + (f": {error[:160]}" if error else "")

    shown = "; ".join(one(c) for c in cases[:4]) + (f"; {len(cases) - 4} more" if len(cases) > 4 else "")
    again = " (--retry-failed runs the failed ones again)" if any(c["status"] == "failed" for c in cases) else ""
    return (
        f"{len(cases)} of {n} cases did not reach their load: {shown}; meta.json has their errors, the tables "
        f"their converged steps{again}"
    )
