"""Files and figures of a joint fit and of its predictions (each file written whole, then renamed)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..measured.curves import MeasuredCurve
from ..measured.shape import plural
from .bands import CurvePrediction, model_error
from .fit_params import TABLE_KEY, CurveFit, JointFit, band

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "FRAME_X_LABEL",
    "QUANTITY_LABEL",
    "band_label",
    "fit_figure",
    "plot_fit",
    "plot_table",
    "prediction_band",
    "prediction_json",
    "table_band",
    "write_fit",
    "within_band",
    "write_prediction",
]


def _atomic(path: Path, text: str) -> Path:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def write_fit(result: JointFit, out: str | Path) -> list[Path]:
    """fit.json (status "done"), fitted_scene.toml and fit.png in ``out`` (shear_table.png with a table).

    fitted_scene.toml is the fitted scene (:attr:`JointFit.scene`): the first curve's test and
    specimen (or frame), loaded to 0.8 of its locking; its header names them.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"status": "done", **result.to_json()}  # (the record of a fit that did not end: ngbet.calibration.record)
    doc["prediction_band"] = prediction_band(result)
    rms = ", ".join(f"{c.label} {100 * c.rms_relative:.1f} %" for c in result.curves)
    first = result.curves[0]
    header = (
        f"# ngbet fit of {', '.join(result.params)} to {plural(len(result.curves), 'curve')}: "
        f"{', '.join(Path(c.curve.source).name for c in result.curves)}\n"
        f"# RMS relative error {rms}; fit.json holds the uncertainties. The test and specimen are\n"
        f"# those of {Path(first.curve.source).name} ({first.curve.test.replace('_', ' ')}, {first.label}); "
        "run it on another\n# specimen with --set specimen.width_mm=..., --set specimen.length_mm=..., "
        "--set loading.u0_mm=...\n# (and --set test=... for the other test)\n"
    )
    paths = [
        _atomic(out / "fit.json", json.dumps(doc, indent=2)),
        _atomic(out / "fitted_scene.toml", header + result.scene.to_toml()),
    ]
    paths.append(plot_fit(result, out / "fit.png"))
    if result.scene.effects.shear_law == "table":
        paths.append(plot_table(result, out / "shear_table.png"))
    return paths


def prediction_band(result: JointFit) -> dict[str, dict[str, Any]]:
    """Per test: what the band of a prediction of another specimen holds, and its relative model error.

    fit.json's ``prediction_band``: {test: {"model_error_relative": σ_m, "holds": words}}
    (:func:`ngbet.calibration.bands.model_error`).
    """
    out = {}
    for test in ("bias_extension", "picture_frame"):
        sigma, words = model_error(result, test)
        out[test] = {"model_error_relative": sigma, "holds": words}
    return out


def plot_table(result: JointFit, path: Path) -> Path:
    """The tabulated shear stress against the shear angle: start, fitted, and each curve by the normalisation method.

    The table is a law in |i8|; it is drawn against γ = arcsin |i8|, the shear angle of
    inextensible yarns, the axis of the measured curves and of the normalisation method.

    The normalisation method's points are τ(sin γ) = F_sh(γ)/t along each measured curve
    (:func:`ngbet.calibration.table.shear_stress_points`): what the fitted table differs from them
    by is what the continuum (yarn elongation, bending, the real kinematics) adds.
    """
    from matplotlib.figure import Figure

    from ..continuum.physics import table_stress_spline
    from .table import shear_stress_points

    fitted = result.scene.material
    steps0 = np.array(fitted.shear_stress_steps_Pa, dtype=float)
    for k, n in enumerate(result.names):  # the start table: the fitted one with the start values put back
        if n.startswith(TABLE_KEY):
            steps0[int(n[len(TABLE_KEY) + 1 : -1])] = result.start[k]
    x = np.linspace(0.01 * fitted.shear_table_i8_max, min(fitted.shear_table_i8_max, 0.999), 200)

    def deg(i8: np.ndarray) -> np.ndarray:
        return np.asarray(np.degrees(np.arcsin(np.clip(i8, 0.0, 1.0))))

    fig = Figure(figsize=(6.0, 4.2))
    ax = fig.subplots()
    t = result.scene.specimen.thickness_mm
    for k, c in enumerate(result.curves):
        xs, tau = shear_stress_points(c.measured_on_specimen(), t)
        ax.plot(deg(xs), tau / 1e3, "o", ms=3, color=f"C{k}", label=f"{c.label}: normalisation method, F_sh / t")
    ax.plot(
        deg(x), table_stress_spline(steps0, fitted.shear_table_i8_max)(x) / 1e3, ":", color="0.3", label="start table"
    )
    tau = table_stress_spline(fitted.shear_stress_steps_Pa, fitted.shear_table_i8_max)(x)
    ax.plot(deg(x), tau / 1e3, "-", color="k", lw=1.6, label="fitted table (continuum)")
    ax.set_yscale("log")
    lo, hi = ax.get_ylim()  # the band does not set the scale: where a rise is undetermined it spans decades
    rel = table_band(result, x) / np.maximum(tau, 1e-300)
    ax.fill_between(
        deg(x),
        tau * np.exp(-np.minimum(2 * rel, 50)) / 1e3,
        tau * np.exp(np.minimum(2 * rel, 50)) / 1e3,
        color="k",
        alpha=0.12,
        lw=0,
        label="fitted table ± 2 sd (first order in ln τ)",
    )
    ax.set_ylim(lo, hi)
    ax.set_xlabel("shear angle γ = arcsin |i8| [°] (inextensible yarns)")
    ax.set_ylabel("shear stress τ = dW/d|i8| [kPa] (log scale)")
    from ..figures.style import eng

    how = "fitted" if "material.K_el" in result.names else "held"
    ax.set_title(
        f"{result.scene.specimen.name.rsplit('-', 1)[0]}, t = {t:g} mm; K_el = "
        f"{eng(result.scene.material.K_el, 'Pa')} ({how})",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def table_band(result: JointFit, x: np.ndarray) -> np.ndarray:
    """The standard deviation [Pa] of the fitted table's stress τ(x) from the covariance of its fitted rises.

    τ is linear in the rises s_i, so ∂τ/∂ln s_i = s_i τ_i(x) with τ_i the table of the unit rise i
    (:func:`ngbet.continuum.physics.table_stress_spline`); rises not fitted contribute nothing.
    """
    from ..continuum.physics import table_stress_spline

    mat = result.scene.material
    steps = np.asarray(mat.shear_stress_steps_Pa, dtype=float)
    fitted = [(k, int(n[len(TABLE_KEY) + 1 : -1])) for k, n in enumerate(result.names) if n.startswith(TABLE_KEY)]
    if not fitted:
        return np.zeros_like(x)
    G = np.column_stack(
        [
            steps[i] * np.nan_to_num(table_stress_spline(np.eye(len(steps))[i], mat.shear_table_i8_max)(x))
            for _, i in fitted
        ]
    )
    rows = [k for k, _ in fitted]
    return band(G, result.cov_log[np.ix_(rows, rows)])


#: the axis quantity of a file's force column (a picture frame: as its file holds it)
QUANTITY_LABEL = {
    "force": "clamp force [N]",
    "shear_force": "shear force F_s [N] (Eq. 3)",
    "normalised_shear_force": "normalised shear force F_norm [N/mm] (Eq. 10)",
}
FRAME_X_LABEL = "shear angle of the frame γ [°] (Eqs. 1–2)"


def plot_fit(result: JointFit, path: Path) -> Path:
    """:func:`fit_figure` written to ``path`` (PNG); returns ``path``."""
    fit_figure(result).savefig(path, dpi=110)
    return path


def fit_figure(result: JointFit) -> Figure:  # noqa: C901 - one panel after the other
    """Each curve's data, start and fitted model (±2 sd), residuals, and centre shear angle.

    One column per test: bias-extension curves as the clamp force against the clamp displacement,
    picture-frame curves in the quantities of their files (F_norm or F_s against the frame's shear
    angle, the paper's), converted exactly from the crosshead force and travel they are fitted in.

    The centre shear angle of the fitted model is drawn against the ideal test's (inextensible
    yarns; for a frame, the frame's angle) and, where given, the measured angles: where the model's
    falls short, the crosshead travel goes into yarn elongation. The curves set each column's
    force scale; a band wider than that is cut at the axes, and its legend says so.
    """
    from matplotlib.figure import Figure

    tests = list(dict.fromkeys(c.curve.test for c in result.curves))
    fig = Figure(figsize=(6.4 * len(tests), 8.6))
    axes = fig.subplots(3, len(tests), sharex="col", height_ratios=(3, 1.3, 2), squeeze=False)
    # the band does not set the scale (where a parameter is undetermined it spans decades, and a
    # linearised band may pass below zero): the curves do, and a wider band is cut at the axes
    span: dict[str, list[float]] = {t: [0.0, 0.0] for t in tests}
    bands: dict[str, list[np.ndarray]] = {t: [] for t in tests}
    for k, c in enumerate(result.curves):
        col = f"C{k}"
        ax, ar, ag = axes[:, tests.index(c.curve.test)]

        def file(v: np.ndarray, c: CurveFit = c) -> np.ndarray:
            return c.curve.in_file_units(c.u_mm, v)[1]

        x = c.curve.in_file_units(c.u_mm, c.measured_N)[0]
        ok = c.curve.u_mm >= 0
        ax.plot(*c.curve.in_file_units(c.curve.u_mm[ok], c.curve.force_N[ok]), "-", color=col, lw=0.8, alpha=0.5)
        ax.errorbar(
            x, file(c.measured_N), yerr=file(c.sd_N), fmt="o", ms=3, color=col, label=f"{c.label}: data (±1 sd)"
        )
        sd = file(band(c.dlogp, result.cov_log))
        lo, hi = file(c.model_N) - 2 * sd, file(c.model_N) + 2 * sd
        shown = np.concatenate(
            [
                file(c.measured_N + c.sd_N),
                file(c.model_N),
                file(c.start_N),
                c.curve.in_file_units(c.curve.u_mm[ok], c.curve.force_N[ok])[1],
            ]
        )
        span[c.curve.test] = [
            min(span[c.curve.test][0], float(np.min(shown))),
            max(span[c.curve.test][1], float(np.max(shown))),
        ]
        ax.fill_between(x, lo, hi, color=col, alpha=0.2, lw=0)
        ax.plot(
            x, file(c.model_N), "-", color=col, lw=1.6, label=f"{c.label}: fitted, RMS {100 * c.rms_relative:.1f} %"
        )
        ax.plot(x, file(c.start_N), ":", color=col, lw=1.0)
        ar.plot(x, 100 * (c.model_N - c.measured_N) / c.measured_N, "o-", ms=3, color=col)
        if len(c.angle_deg):
            ag.plot(x, c.angle_deg, "-", color=col, lw=1.6, label=f"{c.label}: fitted model")
        ag.plot(x, c.ideal_angle_deg(), "--", color=col, lw=1.0, label=f"{c.label}: ideal test")
        if c.angles is not None:
            ag.plot(c.angles.u_mm, c.angles.angle_deg, "s", ms=4, color=col, mfc="none", label=f"{c.label}: measured")
        bands[c.curve.test] += [lo, hi]
    for j, test in enumerate(tests):
        ax, ar, ag = axes[:, j]
        frame = test == "picture_frame"
        bottom, top = span[test]
        pad = 0.06 * (top - bottom)
        ax.set_ylim(bottom - pad, top + pad)
        wide = np.concatenate(bands[test])
        cut = bool(np.any(wide < bottom - pad) or np.any(wide > top + pad))
        ax.plot([], [], ":", color="0.4", label="start values")
        ax.fill_between(
            [],
            [],
            [],
            color="0.4",
            alpha=0.2,
            lw=0,
            label="fitted ± 2 sd (from the parameters)" + (", cut at the axes" if cut else ""),
        )
        ax.plot([], [], "-", color="0.4", lw=0.8, alpha=0.5, label="measured curve, whole")
        quantities = {c.curve.quantity for c in result.curves if c.curve.test == test}
        ax.set_ylabel(" or ".join(QUANTITY_LABEL[q] for q in sorted(quantities)))
        ax.set_title("picture frame" if frame else "bias extension", fontsize=10)
        ax.legend(fontsize=7, loc="upper left")
        ar.axhline(0, color="0.5", lw=0.8)
        ar.set_ylabel("model − data [%]")
        ag.set_ylabel("centre shear angle [°]")
        ag.set_xlabel(FRAME_X_LABEL if frame else "clamp displacement [mm]")
        ag.legend(fontsize=7, loc="upper left")
    stopped = "" if result.converged else " (stopped at the run limit, not converged)"
    from ..figures.style import caption, put_caption

    material = caption(result.scene).partition("; material: ")[2]
    held = [{"material.alpha1": "α1", "material.alpha2": "α2"}.get(p, p.rpartition(".")[2]) for p in result.held]
    held_text = f"; held at the scene's values: {', '.join(held)}" if held else ""
    put_caption(
        fig,
        f"{result.scene.specimen.name.rsplit('-', 1)[0]}: {plural(len(result.names), 'parameter')} fitted to "
        f"{plural(len(result.curves), 'curve')}, {plural(result.model_runs, 'model run')}{stopped}; material: "
        f"{material}{held_text}",
    )
    fig.tight_layout()
    return fig


def band_label(pred: CurvePrediction) -> str:
    """The legend of a prediction's ±2 sd band: what it holds, in a few words."""
    if pred.sd_model_N.size and np.any(pred.sd_model_N > 0):
        return "±2 sd: parameters, discretization, model error between specimens"
    return "±2 sd: parameters and discretization only (no model error)"


def within_band(pred_N: np.ndarray, sd_N: np.ndarray, measured: np.ndarray, sd_measured: np.ndarray) -> float:
    """The fraction of measured points within ±2 sd of the prediction, the measurement's own sd included.

    A measured point deviates from the force the model predicts by the model's uncertainty and by
    its own scatter (half its error bar, floored: :meth:`MeasuredCurve.sd`), independent of each
    other: the point is inside where |F − F_meas| ≤ 2 √(sd² + sd_meas²).
    """
    return float(np.mean(np.abs(pred_N - measured) <= 2 * np.sqrt(sd_N**2 + sd_measured**2)))


def prediction_json(
    pred: CurvePrediction, curve: MeasuredCurve, measured: np.ndarray, normalisation: np.ndarray
) -> dict[str, Any]:
    """The content of predict_NAME.json.

    ``band``: what the band holds; ``within_2sd``: the fraction of measured points within ±2 sd of
    the prediction and of the measured point's own scatter (:func:`within_band`);
    ``normalisation_N``: the normalisation method's prediction from the fitted curves at the same
    points (null where it has none), its RMS relative error on them and ngbet's on the same points.
    """
    rel = (pred.force_N - measured) / measured
    sd_meas = curve.sd(pred.u_mm, measured)
    has = np.isfinite(normalisation)

    def rms(a: np.ndarray) -> float | None:
        return float(np.sqrt(np.mean(a**2))) if a.size else None

    return {
        "data": curve.source,
        "specimen": curve.specimen,
        "points": len(pred.u_mm),
        "rms_relative_error": float(np.sqrt(np.mean(rel**2))),
        "band": pred.band,
        "within_2sd": within_band(pred.force_N, pred.sd_N, measured, sd_meas),
        "u_mm": pred.u_mm.tolist(),
        "measured_N": measured.tolist(),
        "sd_measured_N": sd_meas.tolist(),
        "force_N": pred.force_N.tolist(),
        "sd_parameters_N": pred.sd_param_N.tolist(),
        "sd_discretization_N": pred.sd_disc_N.tolist(),
        "sd_model_error_N": (pred.sd_model_N if pred.sd_model_N.size else np.zeros_like(pred.force_N)).tolist(),
        "normalisation_N": [float(v) if ok else None for v, ok in zip(normalisation, has, strict=True)],
        "normalisation_points": int(has.sum()),
        "normalisation_rms_relative_error": rms(((normalisation - measured) / measured)[has]),
        "rms_relative_error_on_normalisation_points": rms(rel[has]),
    }


def write_prediction(
    pred: CurvePrediction, curve: MeasuredCurve, measured: np.ndarray, out: Path, normalisation: np.ndarray
) -> tuple[Path, dict[str, Any]]:
    """predict_NAME.json and predict_NAME.png in ``out``; returns the PNG and the JSON's content.

    The figure: the measured curve with its points' ±2 sd (their own scatter), the prediction with
    its ±2 sd band, the normalisation method's prediction from the fitted curves (dashed), and
    under the axes what the band holds.
    """
    stem = Path(curve.source).stem
    doc = prediction_json(pred, curve, measured, normalisation)
    _atomic(out / f"predict_{stem}.json", json.dumps(doc, indent=2))
    from matplotlib.figure import Figure

    from ..figures.style import put_caption

    fig = Figure(figsize=(6.4, 4.6))
    ax = fig.subplots()
    ok = curve.u_mm >= 0
    ax.plot(
        *curve.in_file_units(curve.u_mm[ok], curve.force_N[ok]),
        "-",
        color="k",
        lw=1.0,
        label=f"measured, {curve.label}",
    )
    xm, Fm = curve.in_file_units(pred.u_mm, measured)
    sm = curve.in_file_units(pred.u_mm, np.asarray(doc["sd_measured_N"]))[1]
    ax.errorbar(xm, Fm, yerr=2 * sm, fmt="o", ms=2.5, color="k", lw=0.8, label="measured points ±2 sd (scatter)")
    x, F = curve.in_file_units(pred.u_mm, pred.force_N)  # a frame in its file's quantities (linear in the force)
    sd = curve.in_file_units(pred.u_mm, pred.sd_N)[1]
    xn, Fn = curve.in_file_units(pred.u_mm, normalisation)
    # the band does not set the scale (where a parameter is open it spans more than the curves, below
    # zero force too: a first-order band): the measured curve, the prediction and the method's do
    shown = np.concatenate([curve.in_file_units(curve.u_mm[ok], curve.force_N[ok])[1], Fm + 2 * sm, F, Fn])
    shown = shown[np.isfinite(shown)]
    bottom, top = min(0.0, float(shown.min())), float(shown.max())
    lo, hi = F - 2 * sd, F + 2 * sd
    cut = bool(np.any(lo < bottom - 0.06 * (top - bottom)) or np.any(hi > top + 0.06 * (top - bottom)))
    label = band_label(pred) + (", cut at the axes" if cut else "")
    ax.fill_between(x, lo, hi, color="tab:orange", alpha=0.3, lw=0, label=label)
    ax.plot(x, F, "-", color="tab:orange", label="ngbet prediction")
    if np.isfinite(normalisation).any():
        ax.plot(xn, Fn, "--", color="tab:blue", lw=1.0, label="normalisation method from the fitted curves")
    ax.set_ylim(bottom - 0.06 * (top - bottom), top + 0.06 * (top - bottom))
    frame = curve.test == "picture_frame"
    ax.set_xlabel(FRAME_X_LABEL if frame else "clamp displacement [mm]")
    ax.set_ylabel(QUANTITY_LABEL[curve.quantity])
    ax.legend(fontsize=8, loc="upper left")
    put_caption(
        fig,
        f"Band: {pred.band}. Within the band and the measured scatter: {100 * doc['within_2sd']:.0f} % of "
        f"{doc['points']} points; RMS relative error {100 * doc['rms_relative_error']:.1f} %"
        + (
            f"; the normalisation method's {100 * doc['normalisation_rms_relative_error']:.1f} % on its "
            f"{doc['normalisation_points']} points (ngbet "
            f"{100 * doc['rms_relative_error_on_normalisation_points']:.1f} % there)."
            if doc["normalisation_points"]
            else "; the normalisation method has no value at these points."
        ),
    )
    fig.tight_layout()
    png = out / f"predict_{stem}.png"
    fig.savefig(png, dpi=110)
    return png, doc
