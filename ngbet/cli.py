"""Command line: ``ngbet run [scene.toml]``, ``ngbet scene``, ``ngbet study NAME``, ``ngbet sweep``, ``ngbet export``.

Exit status (both models, runs and studies):

====  ==================================================================================
0     done
1     the solver could not carry the load to the end (converged steps are on disk,
      summary.json says "failed"); a study with a case that did not reach its load (the
      cases are named on stderr, every result is written); a fit whose worker
      process ended without an answer (killed, out of memory)
2     a bad scene or command line (the message names the key)
3     an I/O problem: the output folder is not writable, a file is in its place, it is on
      a read-only mount, another run holds its lock, or a dask scheduler is unreachable
      (the message names the path or address)
70    an internal error of ngbet (a bug: please report it with the run folder); the message
      names the error, ``-v`` adds its traceback; summary.json says "failed"
130   interrupted by Ctrl-C (SIGINT), SIGTERM, SIGHUP or SIGUSR1/2: summary.json says "interrupted" with the
      last converged load; a study keeps its finished cases in the cache
====  ==================================================================================

Errors are one line on stderr, loads in mm; the details are in the run folder's summary.json. A
run that finished but whose report could not be written to stdout (a full device, a closed pipe)
exits 3: its run folder is complete, the message on stderr says so.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import sys
from pathlib import Path
from typing import Any

from . import commands as _commands
from .commands import EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_IO, EXIT_OK, EXIT_SOLVER, exit_code, load_scene
from .commands import parse_value as _parse_value
from .interrupts import interrupts
from .messages import messages, say
from .scene.document import Scene
from .scene.physical import load_symbol
from .scene.validate import SceneError
from .watch import SUPERVISED, watch

__all__ = ["EPILOG", "console", "main"]

EPILOG = (
    "exit status: 0 done; 1 solver failure (converged steps kept, summary.json says failed; a study: "
    "a case that did not reach its load, named on stderr); "
    "2 bad scene or command line; 3 I/O problem (output folder not writable, a file, read-only, "
    "busy with another run; scheduler unreachable; stdout not writable); 70 internal error of ngbet; "
    "130 interrupted (SIGINT/SIGTERM/SIGHUP/SIGUSR1; summary.json says interrupted, with the last converged "
    "load in mm)"
)


_say = say  # one `ngbet: ...` line on stderr (stderr itself may be gone: the exit status still says it)


def _print(text: str, what: str, utf8: bool = False) -> int:
    """Write ``text`` to stdout; EXIT_IO with a message when stdout cannot take it all (a full device).

    ``utf8``: as UTF-8 bytes whatever the locale (a TOML file is UTF-8); else in stdout's encoding,
    a character it lacks as its escape. Written to the file descriptor until every byte is taken:
    Python's buffered stdout reports a write cut short by a file size limit (``ulimit -f``) as done.
    stdout is then pointed at the null device, so that the interpreter's last flush does not fail again.
    """
    try:
        if sys.stdout is None:  # closed by the shell (>&-)
            raise OSError(9, "stdout is closed")
        try:
            fd = sys.stdout.fileno()
        except (AttributeError, ValueError, OSError):  # not a file (captured): its own write
            fd = None
        if fd is None:
            sys.stdout.write(text)
            sys.stdout.flush()
            return EXIT_OK
        sys.stdout.flush()
        data = text.encode("utf-8" if utf8 else (sys.stdout.encoding or "utf-8"), errors="backslashreplace")
        while data:
            data = data[os.write(fd, data) :]
        return EXIT_OK
    except OSError as exc:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        _say(f"could not write {what} to stdout: {exc.strerror or exc}")
        return EXIT_IO


def console() -> int:
    """The ``ngbet`` command: :func:`main`; ``ngbet run`` in a child that this process watches (:mod:`ngbet.watch`)."""
    _commands.tolerant_streams()
    argv = sys.argv[1:]
    if os.environ.get(SUPERVISED) or not argv or argv[0] != "run" or not hasattr(os, "fork"):
        return main(argv)
    return watch(argv, main, lambda: Path(_parser("run").parse_args(argv).out))


def main(argv: list[str] | None = None) -> int:
    """The ``ngbet`` command (see the module docstring for the exit status)."""
    _commands.tolerant_streams()
    words = sys.argv[1:] if argv is None else argv
    with interrupts(), messages("-v" in words or "--verbose" in words):
        try:
            return _main(argv)
        except KeyboardInterrupt:
            _say("interrupted")
            return EXIT_INTERRUPTED
        except Exception as exc:  # what no command caught: one line, never a traceback, never exit 1
            code, msg = exit_code(exc)
            if code == EXIT_INTERNAL and logging.getLogger().isEnabledFor(logging.INFO):
                logging.getLogger(__name__).exception("the traceback")
            _say(msg)
            return code


def _parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line; for ``command`` "run" or "scene" without the study and fit commands (not imported)."""
    parser = argparse.ArgumentParser(
        prog="ngbet", description="Bias extension tests of woven fabrics (NGSolve).", epilog=EPILOG
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True)
    pr = sub.add_parser("run", help="run a scene (default: the paper's BET to 56 mm)", epilog=EPILOG)
    pr.add_argument("scene", nargs="?", help="scene TOML file (default: the embedded scene)")
    pr.add_argument(
        "--out",
        default="out/run",
        help="output folder (default: out/run); the files of a previous "
        "run in it are removed, a folder that is not an ngbet run folder is refused",
    )
    pr.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one scene value, e.g. --set material.alpha1=20 (repeatable)",
    )
    pr.add_argument(
        "--accuracy",
        type=float,
        metavar="REL",
        help="relative error of the final force to reach, e.g. 1e-3 (sets discretization.target_error)",
    )
    pr.add_argument(
        "--data",
        metavar="CSV",
        help="a measured curve (header displacement_mm,force_N or with other "
        "units, e.g. 'Displacement (mm);Force (kN)'; '#' comment lines allowed) drawn on the force and "
        "normalised shear force figures; for a picture-frame scene the shear angle and F_s [N] or "
        "F_norm [N/mm], e.g. shear_angle_deg,shear_force_N, drawn as F_norm on the shear force figure)",
    )
    pr.add_argument(
        "--specimen",
        metavar="WxL",
        help="with --data: the measured specimen, width x clamp-to-clamp "
        "length in mm (e.g. 100x250), where the file's header does not give it",
    )
    pr.add_argument(
        "--columns",
        metavar="X,Y",
        help="with --data: the displacement and force columns by header "
        "name or number, each with an optional unit (e.g. 'Weg:mm,Kraft:kN'), or a quantity and its unit "
        "as a header names them (a picture frame's shear force: 1:deg,2:shear_force_N); a file without "
        "a header: by number only",
    )
    pr.add_argument(
        "--quiet", action="store_true", help="print no progress and no results; warnings and errors still go to stderr"
    )
    pr.add_argument("-v", "--verbose", action="store_true", help="log every Newton step")
    ps = sub.add_parser("scene", help="print a scene as commented TOML (default: the embedded one)")
    ps.add_argument("scene", nargs="?", help="scene TOML file to validate and print in full")
    ps.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="change one scene value before printing, e.g. --set material.alpha1=20 (repeatable)",
    )
    if command in ("run", "scene"):
        return parser
    from .studies import STUDIES
    from .study.command import add_arguments

    pst = sub.add_parser(
        "study", help="run a parameter study (see docs/studies.md); 'ngbet study list' lists them", epilog=EPILOG
    )
    pst.add_argument("name", help=f"study name ({', '.join(STUDIES)}) or 'list'")
    _scene_arguments(pst)
    add_arguments(pst)
    psw = sub.add_parser(
        "sweep",
        epilog=EPILOG,
        help="run a scene for every value of one or more keys (a study: "
        "table, figures, report), e.g. ngbet sweep material.alpha1=20,200,2000",
    )
    psw.add_argument(
        "items",
        nargs="+",
        metavar="ITEM",
        help="SECTION.KEY=V1,V2,... (one or more swept keys; the cases are every combination of "
        "their values) and at most one scene TOML file (default: ngbet's default scene)",
    )
    psw.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one value of the base scene (repeatable)",
    )
    add_arguments(psw, data=False)
    from .calibration import command as fit_command

    fit_command.add_parser(sub)
    from . import export

    export.add_parser(sub, EPILOG)
    from . import normalise

    normalise.add_parser(sub)
    return parser


def _main(argv: list[str] | None) -> int:
    words = sys.argv[1:] if argv is None else argv
    parser = _parser(words[0] if words else None)
    args = parser.parse_args(_commands.positionals_first(parser, list(words)))
    if args.command == "study":
        return _study(args)
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "fit":
        from .calibration import command as fit_command

        return fit_command.run_from_args(args)
    if args.command == "export":
        from . import export

        return export.run_from_args(args)
    if args.command == "normalise":
        from . import normalise

        return normalise.run_from_args(args)

    try:
        scene = load_scene(args.scene, args.overrides)
        if getattr(args, "accuracy", None) is not None:
            scene = scene.with_changes(**{"discretization.target_error": args.accuracy})
    except SceneError as exc:
        _say(f"bad scene: {exc}")
        return EXIT_INPUT
    measured = None
    try:
        measured = _measured(args, scene)
    except SceneError as exc:
        _say(f"bad data: {exc}")
        return EXIT_INPUT
    if args.command == "scene":
        from .scene_doc import commented_toml

        return _print(commented_toml(scene), "the scene", utf8=True)
    return _run(scene, Path(args.out), quiet=args.quiet, measured=measured)


def _measured(args: argparse.Namespace, scene: Scene) -> Any:
    """The ``--data`` curve of ``ngbet run`` (read by the one reader of measured curves), its notes said; or None."""
    if not getattr(args, "data", None):
        for flag in ("specimen", "columns"):
            if getattr(args, flag, None):
                raise SceneError(f"--{flag} goes with --data (the measured curve it describes)")
        return None
    if not scene.outputs.plot:
        raise SceneError(
            f"--data {args.data} is drawn on the run's figures, and outputs.plot = false draws none: "
            "drop --data or set outputs.plot = true"
        )
    if scene.test == "picture_frame":
        if args.specimen:
            raise SceneError(
                "--specimen describes a bias extension specimen; a picture-frame curve's frame is "
                "the scene's [picture_frame] section"
            )
        from .figures.frame import read_frame_measured

        frame = read_frame_measured(args.data, columns=args.columns)
        pf = scene.picture_frame
        own = frame.frame.get("picture_frame.frame_mm"), frame.frame.get("picture_frame.fabric_mm")
        other = (
            [
                f"measured in a frame of {own[0]:g} mm with {own[1]:g} mm of fabric, the run's is "
                f"{pf.frame_mm:g} mm with {pf.fabric_mm:g} mm: the figure compares F_norm (Eq. 10) of different frames"
            ]
            if None not in own and own != (pf.frame_mm, pf.fabric_mm)
            else []
        )
        if not args.quiet:
            for note in (*frame.notes, *other):
                _say(f"data {args.data}: {note}")
        return frame
    from .figures.data import Measured
    from .measured.table import parse_sizes

    spec = (
        parse_sizes(args.specimen, "--specimen", ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"))
        if args.specimen
        else None
    )
    measured = Measured.read(args.data, specimen=spec, columns=args.columns)
    sp = scene.specimen
    own = measured.width_mm, measured.length_mm
    other = (
        [
            f"measured on a {own[0]:g} x {own[1]:g} mm specimen, the run's is {sp.width_mm:g} x {sp.length_mm:g} mm: "
            "the figures compare different specimens"
        ]
        if None not in own and own != (sp.width_mm, sp.length_mm)
        else []
    )
    if not args.quiet:
        for note in (*measured.notes, *other):
            _say(f"data {args.data}: {note}")
    return measured


def _run(scene: Scene, out: Path, quiet: bool = False, measured: Any = None) -> int:
    """``ngbet run``: the results on stdout (none when ``quiet``); warnings and errors on stderr."""
    from .plot_process import plot_process

    try:
        # started before NGSolve is imported (see its module); it draws the network's yarn pictures too
        with plot_process(scene.outputs.plot):
            from .run import run

            summary = run(scene, out, progress=not quiet, measured=measured)
    except KeyboardInterrupt:
        _say(
            f"interrupted after {load_symbol(scene.test)} = {_last_converged_mm(out):g} mm; converged steps and "
            f"summary.json (status interrupted) are in {out}/"
        )
        return EXIT_INTERRUPTED
    except Exception as exc:
        code, msg = exit_code(exc, out, load_symbol(scene.test))
        if code == EXIT_SOLVER:
            msg += f"; converged steps and details are in {out}/ (summary.json)"
        if code == EXIT_INTERNAL and logging.getLogger().isEnabledFor(logging.INFO):
            logging.getLogger(__name__).exception("the traceback")
        _say(msg)
        return code
    if quiet:
        return EXIT_OK
    return _print(_report(summary, out) + "\n", f"the report (the run is complete in {out}/)")


def _last_converged_mm(out: Path) -> float:
    try:
        return float(json.loads((out / "summary.json").read_text()).get("last_converged_mm", 0.0))
    except (OSError, ValueError, TypeError, AttributeError):
        return 0.0


def _scene_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="?", help="scene TOML file the study starts from (default: ngbet's default scene)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one value of the study's base scene, e.g. --set material.alpha1=20 (repeatable)",
    )


def _study_scene(path: str | None, overrides: list[str]) -> tuple[Scene | None, str]:
    """The base scene of a study from the command line (None: the study's own) and how the report names it."""
    if not path and not overrides:
        return None, ""
    try:
        scene = load_scene(path, overrides)
    except (OSError, UnicodeDecodeError) as exc:  # a folder or a binary file given as the scene
        raise SceneError(f"cannot read the scene file {path}: {type(exc).__name__}: {exc}") from None
    src = f"the scene file {path}" if path else "ngbet's default scene"
    return scene, src + (f" with --set {' '.join(overrides)}" if overrides else "")


def _study(args: argparse.Namespace) -> int:
    """``ngbet study NAME [scene.toml] [--set ...]``: the study module ngbet.studies.NAME (installed with ngbet)."""
    import importlib

    from .studies import STUDIES

    if args.name == "list":
        if args.scene or args.overrides:
            extra = " ".join([*([args.scene] if args.scene else []), *(f"--set {o}" for o in args.overrides)])
            _say(f"study list takes no scene file or --set (got {extra})")
            return EXIT_INPUT
        for name, what in STUDIES.items():
            print(f"{name:16s} {what}")
        return EXIT_OK
    if args.name not in STUDIES:
        _say(f"study: unknown study {args.name!r}; known: {', '.join(STUDIES)}")
        return EXIT_INPUT
    module = importlib.import_module(f"ngbet.studies.{args.name}")
    return _run_study_command(f"study {args.name}", module.build, args, args.name)


def _sweep(args: argparse.Namespace) -> int:
    """``ngbet sweep KEY=V1,V2,... [scene.toml] [--set ...]``: a study over every combination of the values."""
    from .studies import sweep

    try:
        axes, path = sweep.parse_items(args.items, _parse_value)
    except SceneError as exc:
        _say(f"sweep: {exc}")
        return EXIT_INPUT
    args.scene = path
    n = math.prod(len(v) for v in axes.values())
    if n >= LARGE_SWEEP and not args.quiet:  # its scenes are checked before the first case runs: say so first
        _say(
            f"sweep: {n} cases ({' x '.join(f'{len(v)} values of {k}' for k, v in axes.items())}), each a run of "
            "the scene; checking their scenes, then running the cases not in the cache"
        )
    return _run_study_command("sweep", lambda quick, scene=None: sweep.build(axes, quick, scene), args, "sweep")


#: a sweep of at least this many cases says what it will do before it starts
LARGE_SWEEP = 100


def _run_study_command(what: str, build: Any, args: argparse.Namespace, name: str | None = None) -> int:
    """Run a study from the command line; every error is one line and its exit status."""
    from .study.command import run_from_args
    from .study.executors import StudyInterrupted

    try:
        scene, source = _study_scene(args.scene, args.overrides)
        if scene is not None and not _takes_scene(build):
            raise SceneError(f"{what} runs on its own scenes (it takes no scene file or --set)")
    except SceneError as exc:
        _say(f"{what}: bad scene: {exc}")
        return EXIT_INPUT
    try:
        with (
            open(os.devnull, "w") if args.quiet else contextlib.nullcontext(sys.stdout) as stdout,
            contextlib.redirect_stdout(stdout),
        ):  # --quiet: no table, no report (both are in the folder)
            return run_from_args(build, args, scene, source, name)
    except StudyInterrupted as exc:
        _say(str(exc))
        return EXIT_INTERRUPTED
    except Exception as exc:
        code, msg = exit_code(exc)
        _say(f"{what}: {msg}")
        return code


def _takes_scene(build: Any) -> bool:
    import inspect

    return "scene" in inspect.signature(build).parameters


def _version() -> str:
    from .revision import __revision__, __version__

    return f"ngbet {__version__} (git revision {__revision__})"


def _force_text(force_N: float) -> str:
    """A force with seven significant digits (107.3735, 2.345678e-07): never 0.0000 for a thin specimen."""
    return f"{force_N:9.7g}"


def _report(summary: dict[str, Any], out: Path) -> str:
    from .tables import read_rows

    rows = read_rows(out / "results.csv")
    # the solver's iteration counts are in summary.json: nothing on the terminal a user would act on
    scene = summary.get("scene") or {}
    stops = scene.get("loading", {}).get("stops_mm", ())
    load = load_symbol(scene.get("test", ""))
    lines = [
        f"ngbet: {summary['status']}: {load} = {summary['u0_reached_mm']:g} mm in "
        f"{summary.get('load_steps', len(rows))} load steps, {summary['wall_s']:.2f} s; results in {out}/"
    ]
    for r in rows:  # the force at the scene's stops and at the end
        if "force_N" in r and (any(abs(r["u0_mm"] - s) < 1e-9 for s in stops) or r is rows[-1]):
            err = r.get("force_error_N")
            failed = f"{r['u0_mm']:g}" in (summary.get("error_estimate_unreliable") or {})
            bar = (
                f" ± {err:.2g} N (estimated discretization error)"
                if isinstance(err, float) and err == err
                else " (no error bar: the estimate could not vouch for this force; summary.json says why)"
                if failed or isinstance(err, float)
                else ""
            )
            lines.append(f"  {load} = {r['u0_mm']:6.2f} mm   force = {_force_text(r['force_N'])} N{bar}")
            spread = r.get("force_path_spread_N")
            if isinstance(spread, float) and spread > 0:  # in the bar: another stable state the path left
                lines.append(f"{'':26}of which {spread:.2g} N the force's spread over the path's snaps")
    if "accuracy" in summary:
        a, d = summary["accuracy"], summary["accuracy"]["chosen"]
        lines.append(
            f"  accuracy {a['target_error']:g} {'met' if a['met'] else 'NOT met'}: "
            f"h = {d['mesh_size_mm']:g} mm, corners {d['corner_mesh_size_mm']:g} mm, "
            f"p = {d['order_u']} after {len(a['attempts'])} "
            f"attempt(s), solve {a['solve_s']:.2f} s; {a['wall_s']:.2f} s for all attempts with their "
            "estimates and files"
        )
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
