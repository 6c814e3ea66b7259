"""``ngbet fit``: the command line of the calibration.

``ngbet fit A.csv [B.csv ...] [--scene S.toml] [--params KEYS] --out DIR``

Every input is checked before the first model run (data files line by line, error-bar files,
``--predict`` files and ``--predict-scene``, ``--params``, ``--max-runs``, ``--range``, the output
folder); a refusal exits with 2 (3 for the output folder) and names the file, line or key. The fit
is written as soon as it is done, before any prediction, so that a prediction that fails keeps it.

Every data file is fitted by :func:`ngbet.calibration.joint.fit_curves`, on the specimen its
header gives (``# specimen.width_mm = ...``), else on the scene's. A measured mid-axis profile
(``--profile``) and centre shear angles (``--angles``) belong to the first data file's specimen.
A file whose header says ``# test: picture-frame`` is a picture-frame curve, fitted (or, with
``--predict``, predicted) in the frame of its header (:func:`ngbet.measured.curves.read_frame_curve`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..measured.curves import MeasuredCurve
from ..run_folder import OwnedFolder
from ..scene.document import Scene, SceneWarning
from ..scene.validate import SceneError

__all__ = ["Inputs", "add_parser", "run_from_args", "summary"]


def add_parser(sub: Any) -> None:
    """The ``ngbet fit`` subcommand."""
    p = sub.add_parser(
        "fit", help="fit material parameters to measured force-displacement curves (one or several specimen sizes)"
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="DATA.csv",
        help="measured curves: CSV with a header (displacement_mm,force_N); '# specimen.width_mm = ...' "
        "comment lines give each curve's specimen; NAME_errorbars.csv beside NAME.csv weights the points. "
        "A .toml among them is the scene (as --scene)",
    )
    p.add_argument("--scene", help="scene TOML of the fabric (default: the embedded scene)")
    p.add_argument(
        "--params",
        help="comma-separated material keys, e.g. material.K_sh,material.K_el "
        "(default: the scene's [calibration] params)",
    )
    p.add_argument("--out", default="out/fit", help="output folder (default: out/fit)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one scene value (also the start values), repeatable",
    )
    p.add_argument(
        "--range",
        dest="u_range",
        metavar="FROM:TO",
        help="fit the points between FROM and TO mm (default: 10 to 90 %% of each curve's displacement range)",
    )
    p.add_argument("--max-runs", type=int, default=40, help="at most this many model runs (default 40)")
    p.add_argument(
        "--accuracy",
        type=float,
        default=0.01,
        metavar="REL",
        help="largest estimated discretization error of the model force at a fitted point, relative "
        "to it (default 0.01); ngbet chooses each curve's mesh and order to meet it",
    )
    p.add_argument(
        "--profile",
        metavar="PROFILE.csv",
        help="a measured mid-axis profile (u0_mm,X_mm,uy_mm) of the "
        "first data file's specimen, fitted together with the force",
    )
    p.add_argument("--profile-sd", type=float, default=1.0, help="with --profile: its standard deviation [mm]")
    p.add_argument(
        "--angles",
        metavar="ANGLES.csv",
        help="measured centre shear angles (displacement_mm,"
        "shear_angle_deg) of the first data file's specimen, fitted together with the force",
    )
    p.add_argument(
        "--angle-sd", type=float, default=1.0, help="with --angles: their standard deviation [deg] (default 1)"
    )
    p.add_argument(
        "--predict",
        metavar="OTHER.csv",
        action="append",
        default=[],
        help="another measured curve to predict with the fitted values (repeatable)",
    )
    p.add_argument(
        "--predict-scene",
        metavar="OTHER.toml",
        help="the scene of a --predict curve without specimen keys (default: the fitted one)",
    )
    p.add_argument(
        "--specimen",
        action="append",
        default=[],
        metavar="WxL[xT]",
        help="the measured specimen where a file's header does not give it: width x clamp-to-clamp length "
        "[x thickness] in mm, e.g. 100x250; once for every file, or once per file in order",
    )
    p.add_argument(
        "--columns",
        metavar="X,Y",
        help="the displacement and force columns by header name or number, "
        "each with an optional unit (e.g. 'Weg:mm,Kraft:kN'); default: by their names",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line")


def _range(text: str | None) -> tuple[float, float] | None:
    if not text:
        return None
    a, sep, b = text.partition(":")
    try:
        lo, hi = (float(a), float(b)) if sep else (float(a), math.inf)
    except ValueError:
        raise SceneError(f"--range expects FROM:TO in mm, got {text!r}") from None
    if not (math.isfinite(lo) and lo < hi):
        raise SceneError(f"--range {text!r}: FROM must be a number below TO")
    return lo, hi


def _out_folder(out: Path) -> OwnedFolder:
    """Take the output folder now, so that an unusable one is refused before the fit (exit 3).

    Owned as ``ngbet run`` owns its run folder (:class:`~ngbet.run_folder.OwnedFolder`): a run
    folder, a study's, or a folder holding the user's fit.json or fitted_scene.toml is refused; an
    earlier fit's files that this fit does not write again (its shear_table.png) go at the end.
    """
    from ..run_folder import OwnedFolder

    return OwnedFolder(out, "fit", "fit")


class Inputs:
    """Everything ``ngbet fit`` reads, read and checked before the first model run."""

    def __init__(self, args: argparse.Namespace) -> None:  # noqa: C901 - one check after the other
        from ..commands import load_scene

        tomls = [a for a in args.inputs if a.lower().endswith(".toml")]
        self.data = [a for a in args.inputs if not a.lower().endswith(".toml")]
        if len(tomls) + bool(args.scene) > 1:
            raise SceneError(f"one scene only: got {', '.join(tomls + ([args.scene] if args.scene else []))}")
        if not self.data:
            raise SceneError("no data file: give at least one CSV of displacement_mm,force_N")
        from ..measured.curves import read_all, read_any
        from ..measured.table import curve_files, parse_sizes

        self.data, left = curve_files(self.data)  # error-bar files given with their curves (data/*.csv)

        sizes = ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm")
        specs = [parse_sizes(t, "--specimen", sizes) for t in getattr(args, "specimen", [])]
        columns = getattr(args, "columns", None)
        self.curves = read_all(self.data, columns=columns, specimens=specs)
        self.predict = [read_any(p, columns=columns) for p in args.predict]
        # the scene serves every test among the curves: a key one of them reads has an effect
        tests = sorted({c.test for c in self.curves + self.predict})
        self.scene = load_scene(args.scene or (tomls[0] if tomls else None), args.overrides, tests)
        if self.scene.model != "continuum":
            raise SceneError(
                f"model = {self.scene.model!r}: ngbet fit calibrates the continuum model (model = 'continuum')"
            )
        if args.params is not None:
            self.params = [p.strip() for p in args.params.split(",") if p.strip()]
            if not self.params:
                raise SceneError(f"--params {args.params!r} names no key (e.g. --params material.K_sh,material.K_el)")
        else:
            self.params = list(self.scene.calibration.params)
            if not self.params:
                raise SceneError(
                    "no parameters to fit: give --params (e.g. material.K_sh) or name them in the "
                    "scene's [calibration] params"
                )
        if not args.max_runs >= 1:
            raise SceneError(f"--max-runs {args.max_runs}: must be at least 1")
        self.u_range = _range(args.u_range)
        self.notes = [f"{eb}: the error bars of {curve}, read with it" for eb, curve in left]
        self.notes += [f"{c.source}: {n}" for c in self.curves + self.predict for n in c.notes]
        self.predict_scene = Scene.from_toml(args.predict_scene) if args.predict_scene else None
        from ..measured.observations import read_angles, read_profile
        from .fit_params import curve_scene, expand_params, value_of

        self.profile = read_profile(args.profile) if args.profile else None
        self.angles = read_angles(args.angles) if args.angles else None
        if not (args.profile_sd > 0 and args.angle_sd > 0):
            raise SceneError(f"--profile-sd = {args.profile_sd}, --angle-sd = {args.angle_sd}: both must be > 0")
        if not 0 < args.accuracy < 1:
            raise SceneError(
                f"--accuracy {args.accuracy}: the largest relative discretization error of the force, "
                "between 0 and 1 (e.g. 0.01)"
            )
        names = expand_params(self.scene, self.params)
        bad = [n for n in names if not value_of(self.scene, n) > 0]
        if bad:
            raise SceneError(
                f"--params: {', '.join(bad)} must have a positive start value (the fit works on "
                "ln p; give one with --set)"
            )
        for c in self.curves:
            note = c.check_window(self._fraction(c))
            self.notes += [note] if note else []
            with warnings.catch_warnings():  # checked for errors; its keys without effect are the scene's, said above
                warnings.simplefilter("ignore", SceneWarning)
                curve_scene(self.scene, c, c.sample(fraction=self._fraction(c))[0])
        for c in self.predict:
            if not c.specimen and c.test != "picture_frame" and self.predict_scene is None:
                raise SceneError(
                    f"--predict {c.source}: its header gives no specimen "
                    "(# specimen.width_mm = ..., # specimen.length_mm = ...) and no --predict-scene"
                )

    def _fraction(self, c: MeasuredCurve) -> tuple[float, float]:
        from ..measured.curves import RANGE

        if self.u_range is None:
            return RANGE
        lo, hi = float(c.u_mm.min()), float(c.u_mm.max())
        a, b = max(self.u_range[0], lo), min(self.u_range[1], hi)
        if not a < b:
            raise SceneError(
                f"--range {self.u_range[0]:g}:{self.u_range[1]:g} mm holds no point of {c.source} ({lo:g} to {hi:g} mm)"
            )
        return (a - lo) / (hi - lo), (b - lo) / (hi - lo)


def run_from_args(args: argparse.Namespace) -> int:
    """``ngbet fit``: exit 0 done, 1 a model run or the search failed, 2 bad input, 3 unusable output folder."""
    from ..commands import exit_code

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    folder = None
    stack = contextlib.ExitStack()
    try:
        inp = Inputs(args)
        # the scene's keys without effect were reported once (Inputs): the scenes the fit derives
        # for each curve's test and specimen would report them again, each in its own words
        stack.enter_context(warnings.catch_warnings())
        warnings.simplefilter("ignore", SceneWarning)
        folder = _out_folder(out)
        for note in inp.notes:
            print(f"ngbet fit: {note}", file=sys.stderr)
        from .joint import fit_curves, terminal_progress

        fractions = [inp._fraction(c) for c in inp.curves]
        result = fit_curves(
            inp.curves,
            inp.scene,
            inp.params if args.params is not None else None,
            args.max_runs,
            None if args.quiet else terminal_progress(),
            fractions=fractions,
            target_error=args.accuracy,
            profile=inp.profile,
            profile_sd_mm=args.profile_sd,
            angles=inp.angles,
            angle_sd_deg=args.angle_sd,
        )
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write("\n")
        from .report import write_fit

        write_fit(result, out)
        print(summary(result, out))
        code = 0 if result.converged else 1
        for c in inp.predict:
            code = max(code, _predict_one(result, c, inp.predict_scene, out))
        folder.finish()
        return code
    except SceneError as exc:
        print(f"ngbet fit: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # the command's exit-code contract (1 solver, 3 I/O), one line
        code, msg = exit_code(exc, out)
        print(f"ngbet fit: {msg}", file=sys.stderr)
        return code
    finally:
        stack.close()
        if folder is not None:
            folder.release()


def _predict_one(result: Any, c: MeasuredCurve, scene: Scene | None, out: Path) -> int:
    """Predict one curve; a solver failure is reported and leaves the fit's files in place."""
    from ..errors import ConvergenceError
    from ..normalise import predict_by_normalisation
    from .bands import predict_specimen
    from .fit_params import test_changes
    from .report import write_prediction

    u, F = c.sample(24)
    spec = test_changes(c)
    if scene is not None and not spec:
        sp = scene.specimen
        spec = {
            "specimen.width_mm": sp.width_mm,
            "specimen.length_mm": sp.length_mm,
            "specimen.thickness_mm": sp.thickness_mm,
        }
    try:
        pred = predict_specimen(result, spec, u)
    except ConvergenceError as exc:
        print(f"ngbet fit: prediction of {c.source} failed (the fit is kept in {out}/): {exc}", file=sys.stderr)
        return 1
    # the method needs every curve's specimen: a curve without specimen keys ran on its scene's
    fitted = [_with_specimen(f.curve, f.scene.specimen) for f in result.curves]
    norm = predict_by_normalisation(fitted, _with_specimen(c, None, spec), u)
    path, doc = write_prediction(pred, c, F, out, norm)
    method = "the normalisation method from the fitted curves"
    n, total = doc["normalisation_points"], doc["points"]
    if not n:
        method += " has no value there (beyond their shear angles)"
    else:
        method += f" {100 * doc['normalisation_rms_relative_error']:.1f} %"
        if n < total:
            there = 100 * doc["rms_relative_error_on_normalisation_points"]
            method += f" on its {n} of {total} points (ngbet {there:.1f} % there)"
    print(
        f"  prediction of {c.source}: RMS relative error {100 * doc['rms_relative_error']:.1f} % over {u[0]:.3g} to "
        f"{u[-1]:.3g} mm; {method} -> {path.name}"
    )
    return 0


def _with_specimen(c: MeasuredCurve, specimen: Any, keys: dict[str, Any] | None = None) -> MeasuredCurve:
    """``c`` with its specimen keys: its header's, else ``keys``, else the scene specimen ``specimen``'s.

    A picture-frame curve is returned as it is (its frame is in its header).
    """
    if c.test == "picture_frame" or c.specimen:
        return c
    if keys is None:
        keys = {"specimen.width_mm": specimen.width_mm, "specimen.length_mm": specimen.length_mm}
    return dataclasses.replace(c, specimen={k: float(v) for k, v in keys.items() if k.startswith("specimen.")})


def summary(result: Any, out: Path) -> str:
    """A few lines for the terminal."""
    head = "" if result.converged else "NOT CONVERGED (raise --max-runs): "
    lines = [
        f"ngbet fit: {head}{len(result.names)} parameters, {len(result.curves)} curve(s), "
        f"{result.model_runs} model runs, {result.wall_s:.1f} s; results in {out}/"
    ]
    for c in result.curves:
        err = c.error_rel_max
        est = f"{100 * err:.2g} %" if math.isfinite(err) else "not vouched for"
        lines.append(
            f"  {c.label:>16s}: RMS relative error {100 * c.rms_relative:5.1f} % "
            f"({len(c.u_mm)} points, {c.u_mm[0]:.3g} to {c.u_mm[-1]:.3g} mm); discretization error {est}"
        )
    weighed = {
        c.curve.test: float(np.max(c.model_sd_N / np.abs(c.measured_N))) for c in result.curves if len(c.model_sd_N)
    }
    for test, sigma in weighed.items():
        if sigma > 0:
            lines.append(
                f"  the {test.replace('_', ' ')} curves disagree beyond their error bars: each point weighted "
                f"also with the model error between specimens, {100 * sigma:.1f} % of its force"
            )
    from .fit_params import FIT_LADDER

    for c in result.curves:
        if not c.error_rel_max <= result.target_error:
            why = c.climb.reason or (
                "the scene's own discretization"
                if c.level is None
                else "even on the finest rung"
                if c.level == len(FIT_LADDER) - 1
                else "the model runs were spent: raise --max-runs"
            )
            lines.append(
                f"  {c.label}: discretization error above --accuracy {result.target_error:g}: {why} "
                "(fit.json: accuracy)"
            )
    se = result.se_log
    for k, n in enumerate(result.names):
        flag = (
            "  at its bound"
            if n in result.at_bound
            else "  undetermined"
            if n in result.undetermined
            else "  at zero"
            if n in result.at_zero
            else ""
        )
        lines.append(f"  {n:36s} = {result.values[k]:11.5g}   se(ln p) = {se[k]:.3g}{flag}")
    for n, why in result.undetermined.items():
        lines.append(f"  {n} undetermined: {why}")
    for n, why in result.at_zero.items():
        lines.append(f"  {n} {why}")
    for n, why in result.held.items():
        lines.append(f"  {n} held: {why}")
    return "\n".join(lines)
