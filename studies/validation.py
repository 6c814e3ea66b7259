"""Validation on measured data: each Twintex fabric fitted on one specimen size, the other predicted.

For each fabric of Cao et al. (2008) (data/cao2008/, geometry/twintex_*.toml), in both directions
(the first size fitted and the second predicted, then the reverse), the tabulated shear law's
rises are fitted to the curve of one specimen size
(:func:`ngbet.calibration.joint.fit_curves`), and the fitted scene predicts the other size, with a
band of one standard deviation from the parameters' covariance, the uncertainty of K_el and the
discretization (:func:`ngbet.calibration.joint.predict_specimen`).

K_el cannot come from the fitted curve: on one size it trades against the shear table (its
se(ln K_el) is 8–17 when fitted with it). It is taken from the other two fabrics (leave one fabric
out): each of them is fitted on both its sizes together (table and K_el), and the fabric under
test gets the geometric mean of their K_el, with the variance of ln K_el from their scatter and
standard errors. The fabric under test lends none of its predicted curve to anything. alpha1 and
alpha2 stay at the scene's values: the clamp force alone does not determine them.

The normalisation method predicts the same points from the fitted size's curve (Cao's Eq. 18
solved along it and inverted for the other size: :func:`ngbet.kinematics.force_from_normalised`).
Errors are RMS of (prediction − measured)/measured at 24 equally spaced displacements over
10–90 % of each curve's displacement range.

The fits and the predictions' bands run when the study is built and are kept in the study cache
(``validation-fits/`` in ``--cache``, default ``out/studies/cache``; keyed by the scenes, the data
and the code: a change of any refits); the
study's cases are then ordinary runs of each fitted scene on both sizes, whose forces the report
compares. ``--quick``: one fabric in one direction, K_el at the scene's value, 3 model runs.

    python -m ngbet.studies.validation [--quick] [--workers N] [--plot-only]
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.figures.style import legend_below, put_caption
from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from ._validation_fits import (
    FABRICS,
    MAX_RUNS,
    QUICK,
    QUICK_RUNS,
    files_of,
    fit_and_predict,
    fits_folder,
    pair_fit,
    paths_of,
    points_of,
)

__all__ = ["build", "extract", "fabric_of", "main", "plot", "report", "summary"]

log = logging.getLogger(__name__)





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

    known = {stem(Scene.from_toml(paths_of(f)[0]).specimen.name): f for f in FABRICS}
    fabric = known.get(stem(scene.specimen.name))
    if fabric is None:
        raise SceneError(f"scene key 'specimen.name' = {scene.specimen.name!r}: study validation needs measured "
                         f"curves of two specimen sizes of the fabric, which ngbet has for {', '.join(known)} "
                         "(geometry/twintex_*.toml, data/cao2008/); for another fabric fit its curves with "
                         "ngbet fit A.csv B.csv --scene S.toml")
    return fabric


def _case(doc: dict[str, Any], which: str) -> dict[str, Any]:
    """The fitted scene's material on the fitted or the predicted specimen, stopping at the scored points."""
    from ngbet.calibration.data import read_measured
    from ngbet.scene.document import Scene

    sc = Scene.from_toml_string(doc["fitted_scene"])
    _, a, b = files_of(doc["fabric"], doc["direction"])
    curve = read_measured(a if which == "fitted" else b)
    u, _, _ = points_of(curve)
    m = sc.material
    return {"specimen.name": f"{doc['fabric']}:{doc['direction']}:{which}:{doc['cache_name']}", **curve.specimen,
            "material.K_el": m.K_el, "material.alpha1": m.alpha1, "material.alpha2": m.alpha2,
            "material.shear_stress_steps_Pa": list(m.shear_stress_steps_Pa),
            "material.shear_table_i8_max": m.shear_table_i8_max,
            "loading.u0_mm": float(u[-1]), "loading.stops_mm": [float(x) for x in u[:-1]]}


def build(quick: bool = False, scene: Scene | None = None, cache: Path | None = None) -> Study:
    """The study on the three fabrics, or with ``scene`` on the fabric it is for (:func:`fabric_of`), from it.

    ``cache``: the study cache (``--cache``; None: the default), whose ``validation-fits`` keeps the fits.
    """
    import functools

    from ngbet.scene.document import Scene

    folder = fits_folder(cache)
    if scene is not None:
        fabric = fabric_of(scene)
        runs: tuple[tuple[str, int], ...] = ((fabric, 0),) if quick else ((fabric, 0), (fabric, 1))
    else:
        runs = QUICK if quick else tuple((f, d) for d in (0, 1) for f in FABRICS)
    docs = [fit_and_predict(f, d, quick, scene, folder) for f, d in runs]
    base = Scene.from_toml_string(docs[0]["fitted_scene"]).with_changes(
        **{"outputs.vtk": False, "outputs.plot": False, "outputs.profile": False, "outputs.error_estimate": "off"})
    cases = [_case(d, w) for d in docs for w in ("fitted", "predicted")]
    kept = {d["cache_name"]: d for d in docs}
    study = Study("validation", base, cases, description=__doc__ or "",
                  extract=functools.partial(extract, docs=kept, folder=folder), plot=plot, report=report)
    if quick:  # said here: comparing with the full study would make its fits (minutes)
        full = 2 if scene is not None else 2 * len(FABRICS)
        study.left_out = [f"{full - len(runs)} of the full study's {full} fits (each fabric in both directions)",
                          "K_el from the other fabrics' two-size fits (the scene's value instead)",
                          f"{MAX_RUNS} model runs per fit ({QUICK_RUNS} instead)"]
    return study


def extract(rec: dict[str, Any], run_dir: Path, out: Path, docs: dict[str, dict[str, Any]],
            folder: Path) -> dict[str, Any]:
    """Measured, ngbet and (for the predicted size) the normalisation method's force at the scored points.

    ``docs``: the study's fits and predictions by name; ``folder``: where the two-size fits are kept.
    """
    from ngbet.calibration.data import read_measured
    from ngbet.kinematics import force_from_normalised, normalised_shear_force
    from ngbet.tables import read_rows

    fabric, d, which, name = rec["params"]["specimen.name"].split(":")
    direction = int(d)
    doc = docs[name]
    _, a, b = files_of(fabric, direction)
    fitted, curve = read_measured(a), read_measured(a if which == "fitted" else b)
    pair = f"{fitted.label} → {read_measured(b).label}"
    u, F, scored = points_of(curve)
    rows = read_rows(run_dir / "results.csv")
    Fr = np.array([float(r["force_N"]) for r in rows])
    ur = np.array([float(r["u0_mm"]) for r in rows])
    model = np.array([Fr[int(np.argmin(np.abs(ur - x)))] if np.min(np.abs(ur - x)) < 1e-6 else np.nan for x in u])
    norm, sd = np.full(len(u), np.nan), np.full(len(u), np.nan)
    tables: dict[str, list[dict[str, Any]]] = {}
    if which == "fitted":
        fit = doc["fit"]
        tables["fits"] = [{"fabric": fabric, "pair": pair, "wall_s": fit["wall_s"],
                           "model_runs": int(fit["model_runs"]),
                           "converged": fit["converged"], "noise_scale": fit["noise_scale"],
                           "material.K_el": doc["K_el"], "se_log K_el (held)": doc["var_log_K_el"] ** 0.5,
                           "K_el_from": " ".join(doc["K_el_from"]),
                           **{k: v["value"] for k, v in fit["parameters"].items()},
                           **{f"se_log {k}": v["standard_error_log"] for k, v in fit["parameters"].items()}}]
        if doc["K_el_from"] and direction == 0:  # full study: the fabric's two-size fit was a donor for others
            pf = pair_fit(fabric, folder)
            tables["pair_fits"] = [{**{k: pf[k] for k in ("fabric", "K_el", "se_log_K_el", "model_runs", "wall_s")},
                                    "rms": " ".join(f"{x:.4f}" for x in pf["rms"])}]
    if which == "predicted":
        pr = doc["prediction"]
        sd = np.hypot(np.interp(u, pr["u_mm"], pr["sd_parameters_N"]),
                      np.interp(u, pr["u_mm"], pr["sd_discretization_N"]))
        H, W = fitted.specimen["specimen.length_mm"], fitted.specimen["specimen.width_mm"]
        uf = fitted.u_mm[fitted.u_mm > 0]
        g, fsh = normalised_shear_force(uf, np.maximum(np.interp(uf, fitted.u_mm, fitted.force_N), 0.0), H, W)
        sp = curve.specimen
        norm = force_from_normalised(g, fsh, u, sp["specimen.length_mm"], sp["specimen.width_mm"])
    tables["points"] = [{"fabric": fabric, "pair": pair, "size": which, "u_mm": float(x), "measured_N": float(f),
                         "ngbet_N": float(m), "ngbet_sd_N": float(d), "normalisation_N": float(n), "scored": int(k)}
                        for x, f, m, d, n, k in zip(u, F, model, sd, norm, scored, strict=True)]
    return tables


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean(((a[ok] - b[ok]) / b[ok]) ** 2))) if ok.any() else float("nan")


def _rms_of_max(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of (a − b) over the largest |b| (the measured curve's largest force)."""
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean(((a[ok] - b[ok]) / np.max(np.abs(b))) ** 2))) if ok.any() else float("nan")


def summary(data: StudyData) -> list[dict[str, Any]]:
    """Per fabric and direction: fitted RMS, ngbet's and the normalisation's prediction RMS, band coverage."""
    pts = data.tables.get("points", [])
    out = []
    for fabric, pair in dict.fromkeys((str(p["fabric"]), str(p["pair"])) for p in pts):
        def col(which: str, key: str, fabric: str = fabric, pair: str = pair) -> np.ndarray:
            return np.array([float(p[key]) for p in pts if p["fabric"] == fabric and p["pair"] == pair
                             and p["size"] == which and float(p.get("scored", 1)) > 0])

        meas, pred = col("predicted", "measured_N"), col("predicted", "ngbet_N")
        norm = col("predicted", "normalisation_N")
        sd = col("predicted", "ngbet_sd_N")
        common = np.isfinite(norm)
        out.append({"fabric": fabric, "pair": pair,
                    "fitted_rms": _rms(col("fitted", "ngbet_N"), col("fitted", "measured_N")),
                    "ngbet_rms": _rms(pred, meas), "ngbet_rms_common": _rms(np.where(common, pred, np.nan), meas),
                    "normalisation_rms": _rms(norm, meas),
                    "ngbet_rms_of_max": _rms_of_max(pred, meas), "normalisation_rms_of_max": _rms_of_max(norm, meas),
                    "normalisation_points": int(common.sum()), "points": len(meas),
                    "within_2sd": float(np.mean(np.abs(pred - meas) <= 2 * sd)),
                    "fit": next((f for f in data.tables.get("fits", [])
                                 if f["fabric"] == fabric and f["pair"] == pair), {})})
    return out


def report(data: StudyData) -> str:
    """The validation table, the fits' records and the two-size fits that gave K_el."""
    L = ["# Validation: fitted on one specimen size, predicted on the other", "",
         "RMS of (prediction − measured)/measured at 24 points over 10–90 % of the predicted curve's displacement "
         "range; in brackets the RMS of (prediction − measured) over the curve's largest force.", "",
         "| fabric | fitted → predicted | fitted size: RMS | ngbet prediction: RMS | normalisation method: RMS | "
         "ngbet better? | measured inside ngbet's ±2 sd |", "|---|---|---|---|---|---|---|"]
    rows = summary(data)
    for r in rows:
        better = "yes" if r["ngbet_rms_common"] <= r["normalisation_rms"] else "**no**"
        n, m = r["normalisation_points"], r["points"]
        nn = "" if n == m else (f" ({n} of {m} points, where the fitted curve's shear angles reach; ngbet on "
                                f"them: {100 * r['ngbet_rms_common']:.1f} %)")
        L.append(f"| {r['fabric']} | {r['pair']} | {100 * r['fitted_rms']:.1f} % | {100 * r['ngbet_rms']:.1f} % "
                 f"({100 * r['ngbet_rms_of_max']:.1f} %) | {100 * r['normalisation_rms']:.1f} % "
                 f"({100 * r['normalisation_rms_of_max']:.1f} %){nn} | {better} | {100 * r['within_2sd']:.0f} % |")
    L += ["", "| fitted → predicted | table fit: model runs | wall time [s] | converged | K_el [Pa] (held) | "
          "se(ln K_el) | K_el from |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["fit"]
        L.append(f"| {r['fabric']} {r['pair']} | {int(float(f.get('model_runs', 0)))} | "
                 f"{float(f.get('wall_s', 'nan')):.1f} | {f.get('converged', '')} | "
                 f"{float(f.get('material.K_el', 'nan')):.3g} | {float(f.get('se_log K_el (held)', 'nan')):.2f} | "
                 f"{f.get('K_el_from') or 'the scene (quick)'} |")
    pairs = data.tables.get("pair_fits") or []
    if pairs:
        L += ["", "Two-size fits (table and K_el on both sizes of a fabric), the source of K_el:", "",
              "| fabric | K_el [Pa] | se(ln K_el) | RMS per size | model runs | wall time [s] |",
              "|---|---|---|---|---|---|"]
        for p in pairs:
            L.append(f"| {p['fabric']} | {float(p['K_el']):.3g} | {float(p['se_log_K_el']):.2f} | "
                     f"{', '.join(f'{100 * float(x):.1f} %' for x in str(p['rms']).split())} | "
                     f"{int(float(p['model_runs']))} | {float(p['wall_s']):.0f} |")
    return "\n".join(L) + "\n"


def plot(data: StudyData) -> list[Path]:
    """One panel per fabric and direction: measured curves, fit, prediction with its band, normalisation.

    The measured curves carry their printed error bars; the RMS errors are in each panel's title,
    one legend below the panels.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from ngbet.calibration.data import read_measured
    from ngbet.figures.style import FORCE_LABEL, U0_LABEL, subplots

    rows = summary(data)
    pts = data.tables.get("points", [])
    fabrics = list(dict.fromkeys(r["fabric"] for r in rows))
    ndir = max(sum(r["fabric"] == f for r in rows) for f in fabrics)
    size = (max(6.4, 4.4 * len(fabrics) + 0.6), 3.4 * ndir + 1.5)
    fig, axes = subplots(ndir, len(fabrics), size=size, squeeze=False)
    used = {f: 0 for f in fabrics}
    for r in rows:
        j = fabrics.index(r["fabric"])
        ax = axes[used[r["fabric"]], j]
        used[r["fabric"]] += 1
        sel = {w: [p for p in pts if p["fabric"] == r["fabric"] and p["pair"] == r["pair"] and p["size"] == w]
               for w in ("fitted", "predicted")}
        for which, col in (("fitted", "tab:green"), ("predicted", "k")):
            c = read_measured(_curve_path(r["fabric"], r["pair"], which))
            ax.plot(c.u_mm, c.force_N, "-", color=col, lw=0.9)
            if c.bars is not None:  # the printed error bars of the measured curve
                bu, lo, hi = c.bars
                mid = np.interp(bu, c.u_mm, c.force_N)
                ax.errorbar(bu, mid, yerr=[np.maximum(mid - lo, 0.0), np.maximum(hi - mid, 0.0)], fmt="none",
                            ecolor=col, elinewidth=0.8, capsize=2.5, alpha=0.8)
        u = np.array([float(p["u_mm"]) for p in sel["fitted"]])
        ax.plot(u, [float(p["ngbet_N"]) for p in sel["fitted"]], "o", ms=3, color="tab:green")
        u = np.array([float(p["u_mm"]) for p in sel["predicted"]])
        Fm = np.array([float(p["ngbet_N"]) for p in sel["predicted"]])
        sd = np.array([float(p["ngbet_sd_N"]) for p in sel["predicted"]])
        ax.fill_between(u, Fm - 2 * sd, Fm + 2 * sd, color="tab:orange", alpha=0.25, lw=0)
        ax.plot(u, Fm, "-", color="tab:orange")
        ax.plot(u, [float(p["normalisation_N"]) for p in sel["predicted"]], "--", color="tab:blue")
        pair = r["pair"].replace(" x ", " × ")
        ax.set_title(f"{r['fabric'].replace('_', ' ')}: {pair}\nRMS: fit {100 * r['fitted_rms']:.1f} %, "
                     f"ngbet {100 * r['ngbet_rms']:.1f} %, normalisation {100 * r['normalisation_rms']:.1f} %")
        ax.set_xlabel(U0_LABEL)
        ax.set_ylabel(FORCE_LABEL)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
    for ax in axes.ravel()[len(rows):]:
        ax.set_visible(False)
    handles = [Line2D([], [], color="tab:green", lw=0.9, marker="|", label="measured, fitted size (error bars)"),
               Line2D([], [], color="k", lw=0.9, marker="|", label="measured, predicted size (error bars)"),
               Line2D([], [], color="tab:green", ls="", marker="o", ms=3, label="ngbet, fitted"),
               Line2D([], [], color="tab:orange", label="ngbet, predicted"),
               Patch(color="tab:orange", alpha=0.25, lw=0, label="ngbet ±2 sd"),
               Line2D([], [], color="tab:blue", ls="--", label="normalisation method (Cao Eq. 18)")]
    legend_below(fig, handles, ncol=3 if len(fabrics) > 1 else 2)
    put_caption(fig, "Twintex fabrics of Cao et al. (2008), yarns ±45°, each on its ngbet scene: "
                   "tabulated shear law fitted on one specimen size, K_el held, "
                   "α1 and α2 of the scene; the other size predicted (band: parameters, K_el and discretization); "
                   "RMS of (prediction − measured)/measured "
                   "over 10–90 % of the displacement range")
    return [savefig(fig, data.out, "validation")]


def _curve_path(fabric: str, pair: str, which: str) -> Path:
    """The data file of the fitted or the predicted curve of a pair ("W x L mm → W x L mm")."""
    from ngbet.calibration.data import read_measured

    _, a, b = paths_of(fabric)
    fitted_label = pair.split(" → ")[0]
    first = read_measured(a).label == fitted_label
    return (a if first else b) if which == "fitted" else (b if first else a)


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.validation")


if __name__ == "__main__":
    sys.exit(main())
