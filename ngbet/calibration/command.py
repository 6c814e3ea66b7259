"""``ngbet fit``: the command line of the calibration.

``ngbet fit A.csv [B.csv ...] [--scene S.toml] [--params KEYS] --out DIR``

Every input is checked before the first model run (data files line by line, error-bar files,
``--predict`` files and ``--predict-scene``, ``--params``, ``--max-runs``, ``--range``, the output
folder); a refusal exits with 2 (3 for the output folder) and names the file, line or key. The fit
is written as soon as it is done, before any prediction, so that a prediction that fails keeps it.

Every data file is fitted by :func:`ngbet.calibration.joint.fit_curves`, in the test its file
names (whatever the scene's test), on the specimen its header gives (``# specimen.width_mm =
...``), else on the scene's; a ``--set`` that no curve runs with is refused
(:mod:`ngbet.calibration.checks`). A measured mid-axis profile (``--profile``) and centre shear
angles (``--angles``) belong to the first data file's specimen. A picture-frame file (by the
reader's rule, :func:`ngbet.measured.curves.read_any`) is a picture-frame curve, fitted (or, with
``--predict``, predicted) in the frame of its header (:func:`ngbet.measured.curves.read_frame_curve`),
in crosshead travel [mm] and force: ``--range`` and fit.json's ``range_mm`` are crosshead travel for it.
A frame curve whose header names no frame is fitted in the scene's (after ``--set``), said in a note,
where the scene names one (:func:`ngbet.calibration.checks.scene_frame`); where neither does, it is refused.

The folder says at every moment what the command has done (:mod:`ngbet.calibration.record`): an
earlier fit's files are set aside (earlier_NAME) while the fit runs, and a fit ended by Ctrl-C or
an error leaves fit.json "interrupted" or "failed" with its model runs so far (exit 130 after
Ctrl-C, with a line naming what was kept).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import logging
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..interrupts import recorded_if_stuck
from ..measured.curves import MeasuredCurve
from ..run_folder import OutputError, OwnedFolder
from ..scene.document import Scene, SceneWarning
from ..scene.validate import SceneError
from .checks import (
    errorbar_notes,
    no_params,
    refuse_fitted_predictions,
    refuse_unsized,
    scene_frame,
    set_conflicts,
)
from .record import FitState, begin, unfinished

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
        help="fit the points between FROM and TO mm of clamp displacement (a picture frame's: of crosshead "
        "travel, not degrees) (default: 10 to 90 %% of each curve's displacement range)",
    )
    p.add_argument(
        "--max-runs",
        type=int,
        default=40,
        help="at most this many model runs, the last the check where the fit ends (default 40; a model "
        "run: every curve run once)",
    )
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
        "each with an optional unit (e.g. 'Weg:mm,Kraft:kN') or a quantity and its unit as a header names them "
        "(a picture frame's shear force: 1:deg,2:shear_force_N; a file without a header: by number only); "
        "default: by their names",
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
        from ..measured.curves import curve_tests, read_all, read_any
        from ..measured.table import curve_files, parse_sizes

        self.data, left = curve_files(self.data)  # error-bar files given with their curves (data/*.csv)

        sizes = ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm")
        specs = [parse_sizes(t, "--specimen", sizes) for t in getattr(args, "specimen", [])]
        columns = getattr(args, "columns", None)
        # the scene serves every test among the curves: a key one of them reads has an effect
        tests = sorted(set(curve_tests([*self.data, *args.predict], columns)))
        path = args.scene or (tomls[0] if tomls else None)
        self.scene = load_scene(path, args.overrides, tests)
        frame = scene_frame(self.scene, args.overrides)  # for the frame curves whose header names none
        self.curves = read_all(self.data, columns=columns, specimens=specs, frame=frame)
        self.predict = [read_any(p, columns=columns, frame=frame) for p in args.predict]
        refuse_fitted_predictions(self.curves, self.predict)
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
                raise SceneError(no_params(self.scene, path))
        if not args.max_runs >= 1:
            raise SceneError(f"--max-runs {args.max_runs}: must be at least 1")
        self.u_range = _range(args.u_range)
        self.notes = [f"{c.source}: {n}" for c in self.curves for n in c.notes]
        self.notes += [f"{c.source}: {n}" for c in self.predict for n in c.notes]
        self.notes += errorbar_notes(self.curves, self.predict, left)
        self.notes += set_conflicts(args.overrides, self.scene, self.curves)
        refuse_unsized(self.scene, self.curves)
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
        try:
            names = expand_params(self.scene, self.params)
        except SceneError as exc:
            origin = "--params" if args.params is not None else "the scene's [calibration] params"
            raise SceneError(f"{origin}: {exc}") from None
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
            travel = ""
            if c.test == "picture_frame":
                g = c.in_file_units(np.array([lo, hi]), np.ones(2))[0]
                travel = f" of crosshead travel, the frame's shear angle {g[0]:.3g} to {g[1]:.3g} deg"
            raise SceneError(
                f"--range {self.u_range[0]:g}:{self.u_range[1]:g} mm holds no point of {c.source} "
                f"({lo:g} to {hi:g} mm{travel})"
            )
        return (a - lo) / (hi - lo), (b - lo) / (hi - lo)


def run_from_args(args: argparse.Namespace) -> int:
    """``ngbet fit``: exit 0 done, 1 a run or the search failed, 2 bad input, 3 unusable output folder, 130 stopped.

    Stopped by Ctrl-C (or another stop signal) it says what is kept, on a line of its own: before
    the fit ended, fit.json "interrupted" with its model runs so far and the earlier fit set aside
    (:mod:`ngbet.calibration.record`); during the predictions, the complete fit, its fit.json
    naming the curves not predicted. The fit's files are written whole before a stop takes effect.
    """
    from ..commands import EXIT_INTERRUPTED, exit_code
    from ..numerics.engine import uninterrupted

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    folder = None
    stack = contextlib.ExitStack()
    state, aside, predicted, written, recorded = FitState(), [], [], False, False
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

        aside = begin(folder, [str(d) for d in inp.data])
        stack.enter_context(recorded_if_stuck(functools.partial(_record_stuck, folder, state, inp.data, out)))
        try:
            result = fit_curves(
                inp.curves,
                inp.scene,
                inp.params if args.params is not None else None,
                args.max_runs,
                None if args.quiet else terminal_progress(),
                fractions=[inp._fraction(c) for c in inp.curves],
                target_error=args.accuracy,
                profile=inp.profile,
                profile_sd_mm=args.profile_sd,
                angles=inp.angles,
                angle_sd_deg=args.angle_sd,
                state=state,
            )
        except BaseException as exc:
            recorded = _record(folder, state, [str(d) for d in inp.data], exc)
            raise
        _end_line(args)
        from .report import write_fit

        with uninterrupted():  # a stop meanwhile comes when the fit's files are whole
            write_fit(result, out)
            written = True
        print(summary(result, out))
        code = 0 if result.converged else 1
        for c in inp.predict:
            code = max(code, _predict_one(result, c, inp.predict_scene, out))
            predicted.append(c.source)
        folder.finish()
        return code
    except KeyboardInterrupt as exc:
        _end_line(args)
        said = _stopped(exc, out, folder if recorded or written else None, state, aside, written, predicted, args)
        print(f"ngbet fit: {said}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SceneError as exc:
        print(f"ngbet fit: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # the command's exit-code contract (1 solver, 3 I/O), one line
        code, msg = exit_code(exc, out)
        if recorded:
            msg += f"; {out}/fit.json records the fit so far ({_count(state.runs, 'model run')}, status failed)"
        print(f"ngbet fit: {msg}", file=sys.stderr)
        return code
    finally:
        stack.close()
        if folder is not None:
            folder.release()


def _count(n: int, word: str) -> str:
    """``1 model run``, ``3 model runs``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def _end_line(args: argparse.Namespace) -> None:
    """End the progress line (a terminal's: it stays on one line)."""
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")


def _record(folder: OwnedFolder, state: FitState, data: list[str], exc: BaseException) -> bool:
    """fit.json of a fit ended by ``exc`` before its results: "interrupted" (a stop) or "failed"; whether written.

    (Not in an uninterrupted block: its end would raise the stop that ended the fit once more.)
    """
    stop = isinstance(exc, KeyboardInterrupt)
    why = (str(exc) or "SIGINT") if stop else f"{type(exc).__name__}: {exc}"
    try:
        unfinished(folder, state, data, "interrupted" if stop else "failed", why)
        return True
    except Exception as err:  # the fit's own end is the one to report
        logging.getLogger(__name__).error("%s: could not record the unfinished fit: %s", folder.out, err)
        return False


def _record_stuck(folder: OwnedFolder, state: FitState, data: list[Path], out: Path, reason: str) -> str:
    """fit.json "interrupted" for a stop the main thread cannot act on (:func:`ngbet.interrupts.recorded_if_stuck`)."""
    unfinished(folder, state, [str(d) for d in data], "interrupted", reason)
    return f"{out}/fit.json records the fit so far ({_count(state.runs, 'model run')}, status interrupted)"


def _stopped(
    exc: KeyboardInterrupt,
    out: Path,
    folder: OwnedFolder | None,
    state: FitState,
    aside: list[str],
    written: bool,
    predicted: list[str],
    args: argparse.Namespace,
) -> str:
    """What a stop kept, in one line; during the predictions the complete fit stays, its fit.json saying so."""
    import json

    how = f"interrupted ({str(exc) or 'SIGINT'})"
    if folder is None:  # (or its record could not be written: said above)
        return f"{how} before the fit ended: nothing of it written"
    if not written:
        kept = f"; the earlier fit is kept as {', '.join(aside)}" if aside else ""
        return (
            f"{how} after {_count(state.runs, 'model run')}, before the fit ended: {out}/fit.json records them "
            f"(status interrupted; the lowest cost so far and its values, not a fit){kept}"
        )
    done = {Path(p).resolve() for p in predicted}
    left = [p for p in args.predict if Path(p).resolve() not in done]
    when = f"during the predictions; not predicted: {', '.join(left)}" if left else "as the fit's files were written"
    try:
        doc = json.loads((out / "fit.json").read_text())
        doc["interrupted"] = f"{how} {when}"
        folder.write("fit.json", lambda p: p.write_text(json.dumps(doc, indent=2)))
        folder.finish()
    except (OSError, ValueError, OutputError) as err:
        logging.getLogger(__name__).error("%s: could not record the stop: %s", out, err)
    head, _, tail = when.partition("; ")
    return f"{how} {head}: the fit is complete in {out}/ (fit.json, fitted_scene.toml, fit.png)" + (
        f"; {tail}" if tail else ""
    )


def _predict_one(result: Any, c: MeasuredCurve, scene: Scene | None, out: Path) -> int:
    """Predict one curve; a solver failure is reported and leaves the fit's files in place."""
    from ..errors import ConvergenceError
    from ..normalise import predict_by_normalisation
    from .bands import predict_specimen
    from .fit_params import test_changes
    from .report import write_prediction

    u, F = c.sample(24)
    spec = test_changes(c)  # the test the file names, on its header's specimen or frame
    if scene is not None and c.test != "picture_frame" and not c.specimen:
        sp = scene.specimen
        spec |= {
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
        f"ngbet fit: {head}{_count(len(result.names), 'parameter')}, {_count(len(result.curves), 'curve')}, "
        f"{_count(result.model_runs, 'model run')}, {result.wall_s:.1f} s; results in {out}/"
    ]
    for c in result.curves:
        err = c.error_rel_max
        est = f"{100 * err:.2g} %" if math.isfinite(err) else "not vouched for"
        span = f"{c.u_mm[0]:.3g} to {c.u_mm[-1]:.3g} mm"
        if c.curve.test == "picture_frame":  # fitted in crosshead travel, measured in the frame's shear angle
            g = c.curve.in_file_units(c.u_mm[[0, -1]], c.measured_N[[0, -1]])[0]
            span = f"shear angle {g[0]:.3g} to {g[1]:.3g} deg, crosshead travel {span}"
        lines.append(
            f"  {c.label:>16s}: RMS relative error {100 * c.rms_relative:5.1f} % "
            f"({_count(len(c.u_mm), 'point')}, {span}); discretization error {est}"
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
