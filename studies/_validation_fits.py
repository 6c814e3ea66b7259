"""The fits and predictions of the validation study (:mod:`ngbet.studies.validation`), kept in the study cache.

Each fabric's scene and its two measured curves (:data:`FABRICS`), the leave-one-fabric-out K_el
(:func:`pair_fit`, :func:`elongation_for`), and one fabric fitted on one size and predicted on the
other (:func:`fit_and_predict`); each result is a JSON file in ``validation-fits/`` of the study
cache, keyed by the scenes, the data and the code (:func:`fits_key`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.scene.document import Scene

__all__ = ["FABRICS", "FITS_FOLDER", "KEL", "MAX_RUNS", "QUICK", "QUICK_RUNS", "SCORE_POINTS", "TABLE", "TAIL_POINTS",
           "cached", "data_root", "elongation_for", "files_of", "fit_and_predict", "fits_folder", "fits_key",
           "pair_fit", "paths_of", "points_of"]

log = logging.getLogger(__name__)


def data_root() -> Path:
    """The source tree holding the fabric scenes (geometry/) and their measured curves (data/cao2008/).

    The clone this module is in (``studies/`` of the source tree, an editable install), else the
    copies installed with ngbet (``ngbet/geometry``, ``ngbet/data``), else the current directory.
    """
    import ngbet

    for root in (Path(__file__).resolve().parents[1], Path(ngbet.__file__).resolve().parent, Path.cwd()):
        if (root / "data" / "cao2008").is_dir() and (root / "geometry" / "twintex_plain.toml").is_file():
            return root
    from ngbet.scene.validate import SceneError

    raise SceneError("study validation reads the fabric scenes geometry/twintex_*.toml and their measured curves "
                     "data/cao2008/, installed with ngbet: not found beside the studies, in the installed package "
                     f"{Path(ngbet.__file__).resolve().parent} nor in the current directory {Path.cwd()} "
                     "(reinstall ngbet)")


#: fabric: (scene, curve A, curve B); direction 0 fits A and predicts B, direction 1 the reverse
FABRICS = {
    "plain": ("twintex_plain.toml", "cao2008_plain_150x300_INSA-NU.csv", "cao2008_plain_150x450_INSA-NU.csv"),
    "twill_balanced": ("twintex_twill_balanced.toml", "cao2008_twill_balanced_150x300_INSA-NU.csv",
                       "cao2008_twill_balanced_150x450_INSA-NU.csv"),
    "twill_unbalanced": ("twintex_twill_unbalanced.toml", "cao2008_twill_unbalanced_100x250_UN.csv",
                         "cao2008_twill_unbalanced_100x200_UN.csv"),
}
QUICK = (("twill_unbalanced", 0),)
TABLE, KEL = "material.shear_stress_steps_Pa", "material.K_el"
SCORE_POINTS = 24
#: points beyond the scored 10–90 % up to the end of the measured curve: the figure draws the
#: prediction over the whole range, the steep end included; the RMS errors stay on the scored points
TAIL_POINTS = 4
MAX_RUNS, QUICK_RUNS = 40, 3
#: the fits' folder inside the study cache (``--cache``, default out/studies/cache)
FITS_FOLDER = "validation-fits"


def paths_of(fabric: str) -> tuple[Path, Path, Path]:
    s, a, b = FABRICS[fabric]
    root = data_root()
    return root / "geometry" / s, root / "data" / "cao2008" / a, root / "data" / "cao2008" / b


def files_of(fabric: str, direction: int) -> tuple[Path, Path, Path]:
    """(scene, fitted curve, predicted curve) of a fabric in one direction."""
    s, a, b = paths_of(fabric)
    return (s, a, b) if direction == 0 else (s, b, a)


def fits_key(fabric: str, max_runs: int, scene_toml: str = "") -> str:
    """A key of everything a fabric's fits read: every fabric's scene and data, the settings, the code.

    ``scene_toml``: the scene the fabric under test starts from when it is not its own scene file.
    """
    from ngbet.study.keys import code_version

    h = hashlib.sha256(scene_toml.encode())
    for f in FABRICS:
        for p in paths_of(f):
            h.update(p.read_bytes())
            eb = p.with_name(p.stem + "_errorbars.csv")
            if eb.exists():
                h.update(eb.read_bytes())
    h.update(json.dumps([fabric, max_runs, SCORE_POINTS, TAIL_POINTS, code_version("continuum")],
                        sort_keys=True).encode())
    return f"{fabric}-{h.hexdigest()[:16]}"


def points_of(curve: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, F, scored): the scored points over 10–90 % of the curve's range, then TAIL_POINTS to its end."""
    u, _ = curve.sample(SCORE_POINTS)
    end = curve.window((0.0, 1.0))[1]
    u = np.r_[u, np.linspace(u[-1], end, TAIL_POINTS + 1)[1:]]
    return u, np.interp(u, curve.u_mm, curve.force_N), np.arange(len(u)) < SCORE_POINTS


def fits_folder(cache: Path | None = None) -> Path:
    """Where the fits are kept: ``validation-fits`` in the study cache (None: the default cache)."""
    from ngbet.study.runner import DEFAULT_ROOT

    return Path(cache if cache is not None else DEFAULT_ROOT / "cache") / FITS_FOLDER


def cached(folder: Path, name: str, make: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """The fit ``name`` kept in ``folder``, or ``make()`` kept there.

    A kept file that cannot be read (truncated, not a JSON object) is named in a warning and made
    again; a folder that cannot keep the fit is an OSError naming it before the fit runs.
    """
    path = folder / f"{name}.json"
    if path.exists():
        try:
            doc = json.loads(path.read_text())
            if isinstance(doc, dict):
                return doc
            why = "not a JSON object"
        except (OSError, ValueError) as exc:
            why = f"{type(exc).__name__}: {exc}"
        log.warning("%s is unreadable (%s): the fit is made again", path, why)
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / f".probe.{os.getpid()}"
    probe.write_text("")  # an unwritable cache fails here, before the fit, naming it
    probe.unlink()
    doc = make()
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc))
    tmp.replace(path)
    return doc


def _progress(label: str) -> Any:
    """A fit's progress on stderr: a line updating itself on a terminal, else a line at its start (and end)."""
    t0, tty = time.perf_counter(), sys.stderr.isatty()
    if not tty:
        print(f"ngbet: study validation: fitting {label}", file=sys.stderr, flush=True)

    def show(runs: int, rms: list[float], best: float) -> None:
        if tty:
            sys.stderr.write(f"\rngbet: study validation: fitting {label}: model run {runs}, RMS "
                             + ", ".join(f"{100 * r:.1f} %" for r in rms) + f", {time.perf_counter() - t0:.0f} s\x1b[K")
            sys.stderr.flush()

    return show


def _done(label: str, doc: dict[str, Any]) -> None:
    print(f"\rngbet: study validation: fitted {label} in {doc.get('wall_s', 0.0):.0f} s\x1b[K"
          if sys.stderr.isatty() else f"ngbet: study validation: fitted {label}", file=sys.stderr, flush=True)


def pair_fit(fabric: str, folder: Path) -> dict[str, Any]:
    """The table and K_el fitted to both sizes of a fabric together (cached): its K_el and se(ln K_el)."""
    from ngbet.calibration.data import read_measured
    from ngbet.calibration.joint import fit_curves
    from ngbet.scene.document import Scene

    def make() -> dict[str, Any]:
        scene_path, a, b = paths_of(fabric)
        label = f"{fabric}, both sizes (its K_el for the other fabrics)"
        res = fit_curves([read_measured(a), read_measured(b)], Scene.from_toml(scene_path),
                         params=[TABLE, KEL], max_runs=MAX_RUNS, progress=_progress(label))
        k = res.names.index(KEL)
        doc = {"fabric": fabric, "K_el": float(res.values[k]), "se_log_K_el": float(res.se_log[k]),
               "rms": [c.rms_relative for c in res.curves], "wall_s": res.wall_s, "model_runs": res.model_runs,
               "converged": res.converged}
        _done(label, doc)
        return doc

    return cached(folder, f"pair-{fits_key(fabric, MAX_RUNS)}", make)


def elongation_for(fabric: str, quick: bool, scene: Scene | None, folder: Path) -> tuple[float, float, list[str]]:
    """K_el and the variance of its ln for ``fabric`` from the two-size fits of the other fabrics.

    One size's curve does not determine K_el (it trades against the shear table); the two sizes
    of a fabric do. The fabric under test lends none of its data: its K_el is the geometric mean
    of the others', and the variance of ln K_el is their scatter plus their own variances. Quick:
    the scene's start value, with a variance of 1 (a factor e either way).
    """
    from ngbet.scene.document import Scene

    if quick:
        return (scene or Scene.from_toml(paths_of(fabric)[0])).material.K_el, 1.0, []
    others = [f for f in FABRICS if f != fabric]
    fits = [pair_fit(f, folder) for f in others]
    ln = np.log([f["K_el"] for f in fits])
    var = float(np.var(ln, ddof=1) + np.mean([f["se_log_K_el"] ** 2 for f in fits]))
    return float(np.exp(ln.mean())), var, others


def fit_and_predict(fabric: str, direction: int, quick: bool, start: Scene | None, folder: Path) -> dict[str, Any]:
    """The table fitted on one size (K_el from the other fabrics) and the other size predicted (cached).

    ``start``: the scene the fit starts from (None: the fabric's scene file); its shear table,
    bending stiffnesses, discretization and solver settings are used, the specimen is each curve's.
    """
    from ngbet.calibration.data import read_measured
    from ngbet.calibration.joint import fit_curves, predict_specimen
    from ngbet.scene.document import Scene

    runs = QUICK_RUNS if quick else MAX_RUNS

    def make() -> dict[str, Any]:
        scene_path, fitted_path, predicted_path = files_of(fabric, direction)
        fitted, predicted = read_measured(fitted_path), read_measured(predicted_path)
        K_el, var, donors = elongation_for(fabric, quick, start, folder)
        scene = (start or Scene.from_toml(scene_path)).with_changes(**{KEL: K_el})
        label = f"{fabric} on {fitted_path.stem}"
        res = fit_curves([fitted], scene, params=[TABLE], max_runs=runs, progress=_progress(label))
        _done(label, {"wall_s": res.wall_s})
        u, _, _ = points_of(predicted)
        pred = predict_specimen(res, predicted.specimen, u, {KEL: var})
        return {"fabric": fabric, "direction": direction, "max_runs": runs, "K_el": K_el, "var_log_K_el": var,
                "K_el_from": donors,
                "fit": res.to_json(), "fitted_scene": res.scene.to_toml(),
                "prediction": {"u_mm": u.tolist(), "force_N": pred.force_N.tolist(),
                               "sd_parameters_N": pred.sd_param_N.tolist(),
                               "sd_discretization_N": pred.sd_disc_N.tolist()}}

    name = f"{'quick' if quick else 'full'}{direction}-{fits_key(fabric, runs, start.to_toml() if start else '')}"
    return {**cached(folder, name, make), "cache_name": name}
