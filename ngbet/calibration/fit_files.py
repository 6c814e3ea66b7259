"""The files of a single-curve fit (:func:`ngbet.fit.fit`): fit.json, fitted_scene.toml, its figures and summary."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..fit import FitResult, Prediction, band

__all__ = ["plot_fit", "plot_prediction", "plot_profile", "summary_text", "write_outputs"]

log = logging.getLogger(__name__)


def write_outputs(result: FitResult, out: str | Path, prediction: Prediction | None = None) -> list[Path]:
    """fit.json, fitted_scene.toml and fit.png (and predict.json, predict.png) in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = result.to_json()
    if prediction is not None:
        doc["prediction"] = {k: v for k, v in prediction.to_json().items() if k not in ("u_mm", "force_N", "sd_N")}
        (out / "predict.json").write_text(json.dumps(prediction.to_json(), indent=2))
    (out / "fit.json").write_text(json.dumps(doc, indent=2))
    header = (f"# ngbet fit of {', '.join(result.params)} to {result.data.source}\n"
              f"# RMS relative error {result.rms_relative_error:.4f} over {doc['range_mm'][0]:g} to "
              f"{doc['range_mm'][1]:g} mm; see fit.json for the uncertainties\n")
    (out / "fitted_scene.toml").write_text(header + result.scene.to_toml())
    paths = [out / "fit.json", out / "fitted_scene.toml"]
    from importlib.util import find_spec

    if find_spec("matplotlib") is None:
        log.warning("no figures of the fit: matplotlib is not installed (pip install matplotlib)")
        return paths
    paths.append(plot_fit(result, out / "fit.png"))
    if "profile" in result.extra:
        paths.append(plot_profile(result.extra["profile"], out / "fit_profile.png"))
    if prediction is not None:
        paths += [out / "predict.json", plot_prediction(prediction, out / "predict.png")]
    return paths


def plot_fit(result: FitResult, path: Path) -> Path:
    """Data, start and fitted curves with the ±2 sd band, and the relative residuals."""
    import matplotlib.pyplot as plt

    d, m = result.data, result.used
    u, F = d.u_mm[m], d.force_N[m]
    sd = band(result.model_dlogp, result.cov_log)
    fig, (ax, ar) = plt.subplots(2, 1, figsize=(6.4, 6.0), sharex=True, height_ratios=(3, 1.4))
    ax.plot(d.u_mm[~m], d.force_N[~m], "o", mfc="none", color="0.6", ms=4, label="data (not fitted)")
    ax.plot(u, F, "o", color="k", ms=4, label="data (fitted)")
    ax.plot(u, result.start_N, "--", color="tab:gray", label="model, start values")
    ax.fill_between(u, result.model_N - 2 * sd, result.model_N + 2 * sd, color="tab:blue", alpha=0.25, lw=0)
    ax.plot(u, result.model_N, "-", color="tab:blue", label="model, fitted (±2 sd of the parameters)")
    ax.set_ylabel("clamp force [N]")
    ax.legend(loc="upper left", fontsize=8)
    pairs = zip(result.params, result.values, strict=True)
    ax.set_title(", ".join(f"{p.partition('.')[2]} = {v:.3g}" for p, v in pairs), fontsize=9)
    ar.axhline(0, color="0.5", lw=0.8)
    ar.plot(u, 100 * (result.model_N - F) / F, "o-", color="tab:blue", ms=3)
    ar.set_ylabel("model − data [%]")
    ar.set_xlabel("clamp displacement [mm]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_profile(prof: dict[str, Any], path: Path) -> Path:
    """Measured and fitted mid-axis profiles (the ``profile`` entry of fit.json)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    u0, X = np.array(prof["u0_mm"]), np.array(prof["X_mm"])
    for k, v in enumerate(np.unique(u0)):
        m = u0 == v
        c = f"C{k}"
        ax.plot(X[m], np.array(prof["measured_mm"])[m], "o", color=c, ms=4, label=f"data, u0 = {v:g} mm")
        ax.plot(X[m], np.array(prof["model_mm"])[m], "-", color=c, label="model, fitted")
    ax.set_xlabel("X [mm]")
    ax.set_ylabel("u_y on the mid-axis [mm]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_prediction(pred: Prediction, path: Path) -> Path:
    """The prediction with its ±2 sd band against the second data set."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(pred.data.u_mm, pred.data.force_N, "o", color="k", ms=4, label="data")
    ax.fill_between(pred.u_mm, pred.force_N - 2 * pred.sd_N, pred.force_N + 2 * pred.sd_N, color="tab:orange",
                    alpha=0.3, lw=0)
    ax.plot(pred.u_mm, pred.force_N, "-", color="tab:orange", label="prediction, fitted parameters (±2 sd)")
    sp = pred.scene.specimen
    ax.set_title(f"{sp.name}: {sp.width_mm:g} x {sp.length_mm:g} mm", fontsize=9)
    ax.set_xlabel("clamp displacement [mm]")
    ax.set_ylabel("clamp force [N]")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def summary_text(result: FitResult, out: Path, pred: Prediction | None = None) -> str:
    """A few lines for the terminal."""
    ci = result.interval95()
    head = "" if result.extra.get("converged", True) else "NOT CONVERGED (raise --max-runs): "
    lines = [f"ngbet fit: {head}{len(result.params)} parameters, {int(result.used.sum())} points, "
             f"{result.model_runs} model runs, {result.wall_s:.1f} s; RMS relative error "
             f"{100 * result.rms_relative_error:.2f} %; results in {out}/"]
    for k, p in enumerate(result.params):
        flag = "  UNDETERMINED" if p in result.undetermined else ""
        lines.append(f"  {p:24s} = {result.values[k]:11.5g}   95 % [{ci[k, 0]:.4g}, {ci[k, 1]:.4g}]{flag}")
    for p, why in result.undetermined.items():
        lines.append(f"  {p}: {why}")
    for a, b, c in result.correlated:
        lines.append(f"  {a} and {b} are strongly correlated ({c:+.3f})")
    if pred is not None:
        j = pred.to_json()
        lines.append(f"  prediction of {pred.data.source}: RMS relative error {100 * j['rms_relative_error']:.2f} %")
    return "\n".join(lines)
