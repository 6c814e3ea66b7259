"""Validation on measured data: every curve a fit did not use, predicted, against the normalisation methods.

For each Twintex fabric of Cao et al. (2008) (data/cao2008/, data/cao2008_pf/, geometry/twintex_*.toml)
the study makes the fits a user would make with ``ngbet fit`` and the scene's own ``[calibration]``
(:func:`ngbet.studies._validation_fits.fits_of`): each bias-extension size alone (the bending
stiffnesses held), both sizes together, and each laboratory's picture frame alone. Each fitted
scene then predicts every curve of the fabric its fit did not use: the other size, the other
test, the other laboratory's frame, and every other curve of the fabric in data/ or given with
``--data`` (:func:`ngbet.studies._validation_data.find_curves`: a user's own tests, other sizes and
laboratories); each prediction with its band of one standard deviation from
the parameters' covariance, the discretization and, where the fit used two or more specimens of
the predicted test, the model error between them (:func:`ngbet.calibration.bands.predict_specimen`);
a measured point is inside where it lies within ±2 sd of the band and of its own scatter.

Against each prediction stands the normalisation method's, made from the same fitted curves
(:func:`ngbet.normalise.force_by_normalisation`): Eq. 18 between bias-extension sizes, Eq. 10
between frames, and across tests the bias extension's F_sh read as the frame's F_norm (and the
reverse), the paper's comparison of the two tests; from two fitted curves, the mean of their
predictions. For a frame with another laboratory's frame of the same fabric, that frame read by
Eq. 10 gives the scatter between laboratories (for a bias-extension curve, the other
laboratories' curves of the fabric by Eq. 18).

Errors at :data:`~ngbet.studies._validation_fits.SCORE_POINTS` equally spaced displacements (crosshead
travels) over 10–90 % of the predicted curve's range: the RMS of (prediction − measured)/measured,
and the RMS of (prediction − measured) over the curve's largest measured value; a picture-frame
curve in its file's quantity (F_s or F_norm against the shear angle). Both methods are scored on
the points where the normalisation method has a value (it has none beyond the fitted curves'
largest shear angle); ngbet's score on all points is in the tables too. The last column scores
ngbet's prediction against the normalisation method's answer in the same way: where a user's own
curve agrees with the method (another laboratory's frame that agrees with the bias extension's
F_sh), ngbet's error is at most the method's plus about this (the triangle inequality).

The fits and the predictions' bands run when the study is built and are kept in the study cache
(``validation-fits/`` in ``--cache``, default ``out/studies/cache``; a fit keyed by the scene, the
curves it fits and the code: a change of any refits; a prediction by its fit and its curve's file,
so that a curve added later costs its prediction, not the fit); the study's cases are then ordinary runs of each fitted
scene on each predicted curve's specimen or frame, whose forces the report scores.
``--quick``: the unbalanced twill fitted on one size, 3 model runs.

    python -m ngbet.studies.validation [--quick] [--workers N] [--plot-only] [--data PATH ...]
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.calibration.report import within_band
from ngbet.figures.style import legend_below, put_caption
from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from ._validation_data import FABRICS, Curves, data_root, find_curves
from ._validation_fits import MAX_RUNS, QUICK, QUICK_RUNS, fit_all, fits_folder, fits_of, kind_of, points_of

__all__ = [
    "build",
    "extract",
    "fabric_of",
    "main",
    "not_predicted",
    "plot",
    "report",
    "rms",
    "rms_of_max",
    "summary",
]

log = logging.getLogger(__name__)

#: the scene sections a case takes from its fitted scene (the rest is the study's base scene)
CASE_SECTIONS = ("material", "effects", "discretization")
SEP = "|"
QUANTITY = {"normalised_shear_force": "F_norm", "shear_force": "F_s", "force": "F"}


def fabric_of(scene: Scene) -> str:
    """The fabric of :data:`FABRICS` a scene is for, by its ``specimen.name`` (its size left out).

    Raises
    ------
    SceneError
        naming the key when the scene is for none of them.
    """
    from ngbet.scene.validate import SceneError

    def stem(name: str) -> str:
        return name.rsplit("-", 1)[0] if "x" in name.rsplit("-", 1)[-1] else name

    known = {stem(Scene.from_toml(data_root() / "geometry" / FABRICS[f][0]).specimen.name): f for f in FABRICS}
    fabric = known.get(stem(scene.specimen.name))
    if fabric is None:
        raise SceneError(
            f"scene key 'specimen.name' = {scene.specimen.name!r}: study validation needs measured "
            f"curves of the fabric, which ngbet has for {', '.join(known)} "
            "(geometry/twintex_*.toml, data/cao2008/, data/cao2008_pf/); for another fabric fit its "
            "curves with ngbet fit A.csv B.csv --scene S.toml --predict C.csv"
        )
    return fabric


def _case(doc: dict[str, Any], target: str, curves: Curves) -> dict[str, Any]:
    """The fitted scene on the target's specimen or frame, stopping at the scored points."""
    from ngbet.calibration.fit_params import test_changes

    sc = Scene.from_toml_string(doc["fitted_scene"])
    curve = curves.read(target)
    u, _ = points_of(curve)
    d = sc.to_dict()
    keys = {f"{s}.{k}": v for s in CASE_SECTIONS for k, v in d.get(s, {}).items()}
    keys["specimen.thickness_mm"] = sc.specimen.thickness_mm
    return {
        "specimen.name": SEP.join((doc["fabric"], doc["fit_name"], target, doc["cache_name"])),
        **keys,
        **test_changes(curve),
        "loading.u0_mm": float(u[-1]),
        "loading.stops_mm": [float(x) for x in u[:-1]],
    }


def build(
    quick: bool = False,
    scene: Scene | None = None,
    cache: Path | None = None,
    data: Sequence[str | Path] = (),
    workers: int | None = None,
) -> Study:
    """The study on the three fabrics, or with ``scene`` on the fabric it is for (:func:`fabric_of`), from it.

    ``cache``: the study cache (``--cache``; None: the default), whose ``validation-fits`` keeps the fits.
    ``data``: folders or files of measured curves besides data/'s (``--data``): every curve of a
    fabric among them is predicted by each of the fabric's fits (:func:`find_curves`).
    ``workers`` (``--workers``): processes for the fits of one curve, side by side
    (:func:`fit_all`; None: one per core, 1: in this process).
    """
    folder = fits_folder(cache)
    curves = find_curves(data)
    if quick:
        fabric = fabric_of(scene) if scene is not None else QUICK[0]
        specs = (
            [s for s in fits_of(fabric, curves) if s.kind == "one size"][:1]
            if scene is not None
            else [s for s in fits_of(fabric, curves) if s.name == QUICK[1]]
        )
    else:
        fabrics = [fabric_of(scene)] if scene is not None else list(FABRICS)
        specs = [s for f in fabrics for s in fits_of(f, curves)]
    docs = fit_all(specs, quick, scene, folder, curves, workers)
    base = Scene.from_toml_string(docs[0]["fitted_scene"]).with_changes(
        **{"outputs.vtk": False, "outputs.plot": False, "outputs.profile": False, "outputs.error_estimate": "off"}
    )
    cases = [
        _case(d, t, curves)
        for d, s in zip(docs, specs, strict=True)
        for t in s.targets
        if "failed" not in d["predictions"].get(t, {"failed": ""})
    ]
    kept = {d["cache_name"]: d for d in docs}
    left = not_predicted(curves, specs, docs, "--quick" if quick else "from a scene" if scene is not None else "")
    for s in left:
        log.warning("study validation does not predict %s", s)
    study = Study(
        "validation",
        base,
        cases,
        description=__doc__ or "",
        extract=functools.partial(extract, docs=kept, curves=curves),
        plot=functools.partial(plot, curves=curves),
        report=functools.partial(report, skipped=curves.skipped + left),
    )
    if quick:  # said here: comparing with the full study would make its fits (minutes)
        full = sum(len(fits_of(f, curves)) for f in ([fabric_of(scene)] if scene is not None else FABRICS))
        study.left_out = [
            f"{full - len(specs)} of the full study's {full} fits (each size alone, both sizes, "
            "each laboratory's frame)",
            f"{MAX_RUNS} model runs per fit ({QUICK_RUNS} instead)",
        ]
    return study


def not_predicted(curves: Curves, specs: Sequence[Any], docs: Sequence[dict[str, Any]], limit: str) -> tuple[str, ...]:
    """The ``--data`` curves that no fit of the study as run predicts, each with the reason.

    A curve of a fabric none of ``specs`` fits (``limit``: what narrowed the study to one fabric,
    "--quick" or "from a scene"; "" for none), or whose every prediction failed (the first failure named).
    """
    fabric_of_curve = {n: f for f, names in curves.of.items() for n in names}
    fitted = ", ".join(dict.fromkeys(s.fabric.replace("_", " ") for s in specs))
    out = []
    for n in curves.given:
        runs = [d["predictions"].get(n, {"failed": ""}) for d, s in zip(docs, specs, strict=True) if n in s.targets]
        if any("failed" not in r for r in runs) or any(n in s.fitted for s in specs):
            continue
        fabric = fabric_of_curve[n].replace("_", " ")
        out.append(
            f"{curves.paths[n]}: its prediction failed ({runs[0]['failed'] or 'none made'})"
            if runs
            else f"{curves.paths[n]}: a curve of the fabric {fabric!r}; study validation {limit} fits only "
            f"{fitted!r}: run the full study (no --quick, no scene) to predict it"
            if limit
            else f"{curves.paths[n]}: a curve of the fabric {fabric!r} that no fit of the study predicts"
        )
    return tuple(out)


def _normalisation(fitted: Sequence[str], target: Any, u: np.ndarray, curves: Curves) -> np.ndarray:
    """The normalisation method's prediction at ``u`` from the fitted curves (:func:`predict_by_normalisation`)."""
    from ngbet.normalise import predict_by_normalisation

    return predict_by_normalisation([curves.read(n) for n in fitted], target, u)


def _other_lab(fabric: str, target_name: str, target: Any, u: np.ndarray, curves: Curves) -> np.ndarray:
    """The target read from the other laboratories' curves of its test and fabric (NaN: there are none).

    Bias extension: Eq. 18 from each other laboratory's sizes; picture frame: Eq. 10 from each other
    laboratory's frame in its normalised-force figure (one figure per test). The mean where any has a value.
    """
    lab = curves.lab(target_name)
    others = [
        f
        for f in curves.of[fabric]
        if curves.lab(f) != lab
        and curves.read(f).test == target.test
        and (target.test == "bias_extension" or curves.read(f).quantity == "normalised_shear_force")
    ]
    if not others:
        return np.full(len(u), np.nan)
    return _normalisation(others, target, u, curves)


def extract(
    rec: dict[str, Any], run_dir: Path, out: Path, docs: dict[str, dict[str, Any]], curves: Curves
) -> dict[str, list[dict[str, Any]]]:
    """Measured, ngbet's and the normalisation method's value at the scored points of one prediction."""
    from ngbet.tables import read_rows

    fabric, fit_name, target, name = rec["params"]["specimen.name"].split(SEP)
    doc = docs[name]
    curve = curves.read(target)
    u, F = points_of(curve)
    rows = read_rows(run_dir / "results.csv")
    Fr = np.array([float(r["force_N"]) for r in rows])
    ur = np.array([float(r["u0_mm"]) for r in rows])
    model = np.array([Fr[int(np.argmin(np.abs(ur - x)))] if np.min(np.abs(ur - x)) < 1e-6 else np.nan for x in u])
    pr = doc["predictions"][target]
    parts = [np.array(pr[k], float) for k in ("sd_parameters_N", "sd_discretization_N", "sd_model_error_N")]
    sd = np.sqrt(sum(v**2 for v in parts))
    model_rel = float(np.nanmax(parts[2] / np.abs(np.array(pr["force_N"], float)))) if len(u) else 0.0
    norm = _normalisation(doc["fitted"], curve, u, curves)
    lab = _other_lab(fabric, target, curve, u, curves)

    def file(v: np.ndarray) -> np.ndarray:  # a frame in its file's quantity (F_s or F_norm), linear in the force
        return curve.in_file_units(u, v)[1]  # type: ignore[no-any-return]

    x, meas = curve.in_file_units(u, F)
    fit = doc["fit"]
    kind = kind_of(doc["fitted"], curves)
    what = _what(curve.test, kind, curves.lab(target) in {curves.lab(f) for f in doc["fitted"]})
    tables: dict[str, list[dict[str, Any]]] = {}
    tables["points"] = [
        {
            "fabric": fabric,
            "fit": fit_name,
            "target": target,
            "x": float(a),
            "measured": float(m),
            "ngbet": float(p),
            "ngbet_sd": float(d),
            "measured_sd": float(ms),
            "normalisation": float(n),
            "other_lab": float(o),
        }
        for a, m, p, d, ms, n, o in zip(
            x, meas, file(model), file(sd), file(curve.sd(u, F)), file(norm), file(lab), strict=True
        )
    ]
    tables["predictions"] = [
        {
            "fabric": fabric,
            "fit": fit_name,
            "fit_kind": kind,
            "target": target,
            "predicted": curve.label
            + (
                f" ({curves.lab(target)})"
                if curve.test == "bias_extension"
                else f" ({curves.lab(target)}, {QUANTITY[curve.quantity]})"
            ),
            "what": what,
            "band": pr["band"],
            "model_error_relative": model_rel,
            # (at full precision: the report rounds once, to 0.1 %)
            "fit_rms": " ".join(repr(float(c["rms_relative_error"])) for c in fit["curves"]),
            "fit_runs": int(fit["model_runs"]),
            "fit_wall_s": float(fit["wall_s"]),
            "fit_converged": bool(fit["converged"]),
            "accuracy_met": bool(fit["accuracy"]["met"]),
        }
    ]
    return tables


def _what(test: str, kind: str, same_lab: bool) -> str:
    """What a prediction is: another size, another laboratory's curve of the fitted test, another test."""
    if (test == "bias_extension") != (kind == "frame"):
        return "other size" if test == "bias_extension" and same_lab else "other laboratory"
    return "other test"


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of (a − b)/b where both are finite (NaN: no such point)."""
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean(((a[ok] - b[ok]) / b[ok]) ** 2))) if ok.any() else float("nan")


def rms_of_max(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of (a − b) over the largest finite |b| (the measured curve's largest value), where both are finite."""
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean(((a[ok] - b[ok]) / np.nanmax(np.abs(b))) ** 2))) if ok.any() else float("nan")


def summary(data: StudyData) -> list[dict[str, Any]]:
    """Per prediction: ngbet's and the normalisation method's errors, the laboratories' scatter, band coverage."""
    pts = data.tables.get("points", [])
    out = []
    for p in data.tables.get("predictions", []):
        sel = [q for q in pts if q["fit"] == p["fit"] and q["target"] == p["target"] and q["fabric"] == p["fabric"]]

        def col(key: str, sel: list[dict[str, Any]] = sel) -> np.ndarray:
            return np.array([float(q[key]) for q in sel])

        meas, pred, norm, lab, sd, msd = (
            col("measured"),
            col("ngbet"),
            col("normalisation"),
            col("other_lab"),
            col("ngbet_sd"),
            col("measured_sd"),
        )
        common = np.isfinite(norm)
        on = np.where(common, pred, np.nan)
        out.append(
            {
                **p,
                "points": len(meas),
                "normalisation_points": int(common.sum()),
                "ngbet_rms": rms(pred, meas),
                "ngbet_rms_of_max": rms_of_max(pred, meas),
                "ngbet_rms_common": rms(on, meas),
                "ngbet_rms_of_max_common": rms_of_max(on, meas),
                "normalisation_rms": rms(norm, meas),
                "normalisation_rms_of_max": rms_of_max(norm, meas),
                "lab_rms": rms(lab, meas),
                "lab_rms_of_max": rms_of_max(lab, meas),
                # ngbet's prediction against the normalisation method's answer from the same fitted
                # curves: how far the model's prediction is from the method's, whatever the measurement
                "agreement_rms": rms(on, norm),
                "agreement_rms_of_max": rms_of_max(on, norm),
                "within_2sd": within_band(pred, sd, meas, msd) if len(meas) else float("nan"),
                "end_ratio": float(pred[-1] / meas[-1]) if len(meas) else float("nan"),
            }
        )
    return out


def _pct(v: float) -> str:
    return "–" if not np.isfinite(v) else f"{100 * v:.1f} %"


def _holds(r: dict[str, Any]) -> str:
    """The band's content in a table cell: its parts, and the model error's size where the fit estimates it."""
    if str(r["band"]).startswith("parameters and discretization only"):
        return "parameters, discretization"
    sigma = float(r["model_error_relative"])
    return f"parameters, discretization, model error {_pct(sigma)}" + (
        " (sizes agree within their noise)" * (sigma == 0)
    )


def report(data: StudyData, skipped: Sequence[str] = ()) -> str:
    """The validation table (every prediction), the means by kind, the fits' records, the files not read."""
    rows = summary(data)
    L = [
        "# Validation: every curve a fit did not use, predicted",
        "",
        "Errors at 24 points over 10–90 % of the predicted curve's range: RMS of (prediction − measured)/measured, "
        "in brackets the RMS of (prediction − measured) over the curve's largest value; both methods on the points "
        "where the normalisation method has a value (ngbet on all points in the last column but two). "
        "A frame is scored in its file's quantity. Inside ±2 sd: the measured points within ±2 sd of the "
        "prediction's band and of the point's own scatter (half its error bar, floored); the band holds what its "
        "column says (a fit estimates the model error between specimens only from two or more specimens of the "
        "predicted test). ngbet against the method: RMS of (ngbet − method)/method, in brackets over the method's "
        "largest value: how far ngbet's prediction is from the normalisation method's answer from the same curves.",
        "",
        "| fabric | fitted | predicted | what | ngbet | normalisation method | other laboratory | ngbet, all points "
        "| band holds | inside ±2 sd | ngbet/measured at 90 % | ngbet against the method |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        n, m = r["normalisation_points"], r["points"]
        L.append(
            f"| {r['fabric'].replace('_', ' ')} | {r['fit']} | {r['predicted']} | {r['what']} | "
            f"{_pct(r['ngbet_rms_common'])} ({_pct(r['ngbet_rms_of_max_common'])}) | "
            f"{_pct(r['normalisation_rms'])} ({_pct(r['normalisation_rms_of_max'])})"
            f"{'' if n == m else f' on {n} of {m} points'} | "
            f"{_pct(r['lab_rms'])} ({_pct(r['lab_rms_of_max'])}) | "
            f"{_pct(r['ngbet_rms'])} ({_pct(r['ngbet_rms_of_max'])}) | {_holds(r)} | {100 * r['within_2sd']:.0f} % | "
            f"{r['end_ratio']:.2f} | {_pct(r['agreement_rms'])} ({_pct(r['agreement_rms_of_max'])}) |"
        )
    L += ["", "What each band holds:", ""]
    L += sorted({f"- {r['fit']} predicting {r['what']}: {r['band']}." for r in rows})
    L += [
        "",
        "Means over the predictions (the normalisation method's points):",
        "",
        "| predictions | count | ngbet | normalisation method | ngbet better on | ngbet against the method |",
        "|---|---|---|---|---|---|",
    ]
    for what in ("other size", "other test", "other laboratory", "all"):
        sel = [r for r in rows if what == "all" or r["what"] == what]
        if not sel:
            continue

        def mean(key: str, sel: list[dict[str, Any]] = sel) -> float:
            v = np.array([r[key] for r in sel], float)
            return float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")

        better = sum(r["ngbet_rms_of_max_common"] <= r["normalisation_rms_of_max"] for r in sel)
        L.append(
            f"| {what} | {len(sel)} | {_pct(mean('ngbet_rms_common'))} ({_pct(mean('ngbet_rms_of_max_common'))})"
            f" | {_pct(mean('normalisation_rms'))} ({_pct(mean('normalisation_rms_of_max'))}) | "
            f"{better} of {len(sel)} (error over the largest value) | "
            f"{_pct(mean('agreement_rms'))} ({_pct(mean('agreement_rms_of_max'))}) |"
        )
    L += [
        "",
        "The fits:",
        "",
        "| fabric | fitted | RMS per fitted curve | model runs | wall time [s] | converged | "
        "discretization error within the target |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in {(r["fabric"], r["fit"]): r for r in rows}.values():
        L.append(
            f"| {r['fabric'].replace('_', ' ')} | {r['fit']} | "
            f"{', '.join(_pct(float(x)) for x in str(r['fit_rms']).split())} | {int(float(r['fit_runs']))} | "
            f"{float(r['fit_wall_s']):.0f} | {r['fit_converged']} | {r['accuracy_met']} |"
        )
    if skipped:
        L += [
            "",
            "Data files not predicted (not read, of none of the study's fabrics, of a fabric this run does not "
            "fit, or failed):",
            "",
        ]
        L += [f"- {s}" for s in skipped]
    return "\n".join(L) + "\n"


def plot(data: StudyData, curves: Curves) -> list[Path]:
    """One panel per predicted curve: measured, and each fit's prediction with the normalisation method's.

    Bias extension: force against clamp displacement; picture frame: its file's quantity against
    the shear angle. Each fit has one colour: solid ngbet (its ±2 sd band shaded), dashed the
    normalisation method from the same curves.
    """
    from matplotlib.lines import Line2D

    from ngbet.figures.style import FORCE_LABEL, U0_LABEL, subplots

    rows = summary(data)
    pts = data.tables.get("points", [])
    targets = list(dict.fromkeys((r["fabric"], r["target"]) for r in rows))
    fits = list(dict.fromkeys(r["fit_kind"] for r in rows))
    colours = dict(zip(("one size", "two sizes", "frame"), ("tab:orange", "tab:red", "tab:blue"), strict=True))
    ncol = min(4, len(targets))
    nrow = -(-len(targets) // ncol)
    fig, axes = subplots(nrow, ncol, size=(4.0 * ncol + 0.6, 3.3 * nrow + 1.6), squeeze=False)
    for ax, (fabric, target) in zip(axes.ravel(), targets, strict=False):
        curve = curves.read(target)
        frame = curve.test == "picture_frame"
        x, y = curve.in_file_units(curve.u_mm, curve.force_N)
        ax.plot(x, y, "-", color="k", lw=1.2)
        top = float(np.nanmax(y))  # the band does not set the scale: where a parameter is open it spans decades
        title = (
            f"{fabric.replace('_', ' ')}: {curves.lab(target)} frame {curve.label.split(' ', 1)[1]}"
            if frame
            else f"{fabric.replace('_', ' ')}: {curves.lab(target)} {curve.label.replace(' x ', ' × ')}"
        )
        for r in (r for r in rows if r["fabric"] == fabric and r["target"] == target):
            sel = [q for q in pts if q["fit"] == r["fit"] and q["target"] == target and q["fabric"] == fabric]
            xs = np.array([float(q["x"]) for q in sel])
            m, sd = np.array([float(q["ngbet"]) for q in sel]), np.array([float(q["ngbet_sd"]) for q in sel])
            c = colours[r["fit_kind"]]
            ax.fill_between(xs, m - 2 * sd, m + 2 * sd, color=c, alpha=0.12, lw=0)
            ax.plot(xs, m, "-", color=c, lw=1.0)
            nm = np.array([float(q["normalisation"]) for q in sel])
            ax.plot(xs, nm, "--", color=c, lw=0.9)
            top = max(top, float(np.nanmax(m)), float(np.nanmax(nm)) if np.isfinite(nm).any() else 0.0)
        if frame:
            ax.set_xlabel("shear angle γ [°]")
            ax.set_ylabel("F_norm [N/mm]" if curve.quantity == "normalised_shear_force" else "shear force F_s [N]")
        else:
            ax.set_xlabel(U0_LABEL)
            ax.set_ylabel(FORCE_LABEL)
        ax.set_title(title, fontsize=9)
        ax.set_xlim(left=0)
        ax.set_ylim(0, 1.1 * top)
    for ax in axes.ravel()[len(targets) :]:
        ax.set_visible(False)
    names = {
        "one size": "fitted on one bias-extension size",
        "two sizes": "fitted on both sizes",
        "frame": "fitted on a picture frame",
    }
    handles = [Line2D([], [], color="k", lw=1.2, label="measured")]
    handles += [Line2D([], [], color=colours[k], label=f"ngbet, {names[k]} (±2 sd shaded)") for k in fits]
    handles += [Line2D([], [], color="0.4", ls="--", label="normalisation method from the same curves")]
    legend_below(fig, handles, ncol=3)
    put_caption(
        fig,
        "Twintex fabrics of Cao et al. (2008): each measured curve predicted by every fit that did not "
        "use it (ngbet fit with the fabric's scene) and by the normalisation method from the fitted "
        "curves (Eq. 18 between sizes, Eq. 10 between frames, F_sh read as F_norm across tests); "
        "the ±2 sd band holds the parameters and the discretization, and the model error between specimens "
        "only where the fit used two or more specimens of the predicted test (the study's table says which); "
        "a band wider than the axes is cut",
    )
    return [savefig(fig, data.out, "validation")]


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.validation")


if __name__ == "__main__":
    sys.exit(main())
