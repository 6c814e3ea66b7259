"""Command line: ``ngbet run [scene.toml] [--out DIR]``, ``ngbet scene``, ``ngbet study NAME``.

Exit status: 0 done, 1 the solver could not reach the final load (converged steps are on disk),
2 a bad scene or command line.
"""

from __future__ import annotations

import argparse
import ast
import logging
import sys
from pathlib import Path

from .scene import Scene, SceneError, default_scene


def _parse_value(text: str) -> object:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def load_scene(path: str | None, overrides: list[str]) -> Scene:
    """The scene file (or the default scene) with ``section.key=value`` (or ``model=...``) overrides applied."""
    scene = Scene.from_toml(path) if path else default_scene()
    changes = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or ("." not in key and key.strip() != "model"):
            raise SceneError(f"--set expects section.key=value or model=continuum|discrete, got {item!r}")
        changes[key.strip()] = _parse_value(value.strip())
    return scene.with_changes(**changes) if changes else scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ngbet", description="Bias extension tests of woven fabrics (NGSolve).")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True)
    pr = sub.add_parser("run", help="run a scene (default: the paper's BET to 56 mm)")
    pr.add_argument("scene", nargs="?", help="scene TOML file (default: the embedded scene)")
    pr.add_argument("--out", default="out/run", help="output folder (default: out/run)")
    pr.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one scene value, e.g. --set material.alpha1=20 (repeatable)")
    pr.add_argument("--accuracy", type=float, metavar="REL",
                    help="relative error of the final force to reach, e.g. 1e-3 (sets discretization.target_error)")
    pr.add_argument("--quiet", action="store_true", help="no progress bar, warnings only")
    pr.add_argument("-v", "--verbose", action="store_true", help="log every Newton step")
    ps = sub.add_parser("scene", help="print a scene as commented TOML (default: the embedded one)")
    ps.add_argument("scene", nargs="?", help="scene TOML file to validate and print in full")
    ps.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    pst = sub.add_parser("study", help="run a parameter study (see docs/studies.md); 'ngbet study list' lists them")
    pst.add_argument("name", help="study name (penalty_p, work_precision, alpha1, kel, curves, maps, compare) or 'list'")
    from .study import add_arguments

    add_arguments(pst)
    from . import fit

    fit.add_parser(sub)
    args = parser.parse_args(argv)
    if args.command == "study":
        return _study(args)
    if args.command == "fit":
        return fit.run_from_args(args)

    level = logging.WARNING if getattr(args, "quiet", False) else (
        logging.INFO if getattr(args, "verbose", False) else logging.WARNING)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        scene = load_scene(args.scene, args.overrides)
        if getattr(args, "accuracy", None) is not None:
            scene = scene.with_changes(**{"discretization.target_error": args.accuracy})
    except SceneError as exc:
        print(f"ngbet: bad scene: {exc}", file=sys.stderr)
        return 2
    if args.command == "scene":
        from .scene_doc import commented_toml

        sys.stdout.write(commented_toml(scene))
        return 0

    from .run import run
    from .errors import ConvergenceError

    out = Path(args.out)
    try:
        summary = run(scene, out, progress=not args.quiet)
    except ConvergenceError as exc:
        print(f"ngbet: the load could not be carried to the end; converged steps are in {out}\n{exc}",
              file=sys.stderr)
        return 1
    except SceneError as exc:
        print(f"ngbet: bad scene: {exc}", file=sys.stderr)
        return 2
    print(_report(summary, out))
    return 0


def _study(args: argparse.Namespace) -> int:
    """``ngbet study NAME``: the study module ngbet.studies.NAME (installed with the package)."""
    import importlib

    from . import studies

    if args.name == "list":
        for name, what in studies.STUDIES.items():
            print(f"{name:16s} {what}")
        return 0
    if args.name not in studies.STUDIES:
        print(f"ngbet study: unknown study {args.name!r}; known: {', '.join(studies.STUDIES)}", file=sys.stderr)
        return 2
    from .study import run_from_args

    module = importlib.import_module(f"ngbet.studies.{args.name}")
    return run_from_args(module.build, args)


def _version() -> str:
    from . import __revision__, __version__

    return f"ngbet {__version__} (git revision {__revision__})"


def _report(summary: dict, out: Path) -> str:
    from .output import read_rows

    rows = read_rows(out / "results.csv")
    lines = [f"ngbet: {summary['status']}: u0 = {summary['u0_reached_mm']:g} mm in {summary.get('load_steps', len(rows))} "
             f"load steps, {summary.get('newton_iterations', '?')} Newton iterations, {summary['wall_s']:.2f} s; "
             f"results in {out}/"]
    for r in rows:
        if "force_N" in r and (abs(r["u0_mm"] - 37) < 1e-9 or r is rows[-1]):
            err = r.get("force_error_N")
            bar = (f" ± {err:.2g} N (estimated discretization error)" if isinstance(err, float) and err == err
                   else " (error estimate failed)" if isinstance(err, float) else "")
            lines.append(f"  u0 = {r['u0_mm']:6.2f} mm   force = {r['force_N']:9.4f} N{bar}")
    if "accuracy" in summary:
        a, d = summary["accuracy"], summary["accuracy"]["chosen"]
        lines.append(f"  accuracy {a['target_error']:g} {'met' if a['met'] else 'NOT met'}: h = {d['mesh_size_mm']:g} mm,"
                     f" corners {d['corner_mesh_size_mm']:g} mm, p = {d['order_u']} after {len(a['attempts'])} "
                     f"attempt(s), solve {a['solve_s']:.2f} s, {a['wall_s']:.2f} s in all")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
