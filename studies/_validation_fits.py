"""The fits and predictions of the validation study (:mod:`ngbet.studies.validation`), kept in the study cache.

The fits of a fabric (:func:`fits_of`: each bias-extension size alone, both sizes together, each
laboratory's picture frame alone, of the fabric's own curves: :mod:`._validation_data`) and the
curves of the fabric each does not use (its targets); one fit with the fitted scene's predictions
of its targets (:func:`fit_and_predict`), kept in ``validation-fits/`` of the study cache: the fit
keyed by the scene, the curves it fits and the code (:func:`fits_key`), each prediction by the fit
and its curve's file (:func:`target_key`). :func:`fit_all` makes a study's fits, those of one curve
side by side in worker processes.

The fits are ``ngbet fit``'s own (:func:`ngbet.calibration.joint.fit_curves` with the scene's
``[calibration]`` parameters, bounds and rules: one size holds the bending stiffnesses): the study
validates what a user of the command gets.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.measured.table import errorbar_path
from ngbet.scene.document import Scene

from ._validation_data import FABRICS, Curves, data_root

__all__ = [
    "FITS_FOLDER",
    "MAX_RUNS",
    "QUICK",
    "QUICK_RUNS",
    "SCORE_POINTS",
    "FitSpec",
    "cached",
    "fit_all",
    "fit_and_predict",
    "fits_folder",
    "fits_key",
    "fits_of",
    "interrupted_text",
    "keep",
    "kind_of",
    "points_of",
    "target_key",
]

log = logging.getLogger(__name__)


#: the quick study: the unbalanced twill fitted on its 100 x 250 mm curve
QUICK = ("twill_unbalanced", "100 x 250 mm")
#: scored points per predicted curve, equally spaced over 10-90 % of its displacement (travel) range
SCORE_POINTS = 24
MAX_RUNS, QUICK_RUNS = 40, 3
#: the fits' folder inside the study cache (``--cache``, default out/studies/cache)
FITS_FOLDER = "validation-fits"


@dataclass(frozen=True)
class FitSpec:
    """One fit of a fabric: its name, the files it fits, the files it predicts, what it used.

    ``kind``: "one size", "two sizes" (bias extension) or "frame" (:func:`kind_of`).
    """

    fabric: str
    name: str
    fitted: tuple[str, ...]
    targets: tuple[str, ...]
    kind: str


def kind_of(fitted: Sequence[str], curves: Curves) -> str:
    """What a fit of the curves ``fitted`` used: "frame", else "two sizes" or "one size"."""
    if curves.is_frame(fitted[0]):
        return "frame"
    return "two sizes" if len(fitted) > 1 else "one size"


def fits_of(fabric: str, curves: Curves) -> list[FitSpec]:
    """The fits of a fabric and their targets.

    Each bias-extension size of :data:`FABRICS` alone, both together, and each laboratory's picture
    frame alone (its normalised-force figure). A fit predicts every curve of the fabric in
    ``curves`` it does not use, except a frame of the laboratory whose frame it fitted (a
    laboratory's frame as F_s and as F_norm is one test).
    """
    _, bet, pf = FABRICS[fabric]

    def spec(name: str, fitted: tuple[str, ...]) -> FitSpec:
        labs = {curves.lab(f) for f in fitted if curves.is_frame(f)}
        targets = tuple(
            f for f in curves.of[fabric] if f not in fitted and not (curves.is_frame(f) and curves.lab(f) in labs)
        )
        return FitSpec(fabric, name, fitted, targets, kind_of(fitted, curves))

    out = [spec(str(curves.read(b).label), (b,)) for b in bet]
    out.append(spec(" + ".join(str(curves.read(b).label) for b in bet), tuple(bet)))
    seen: set[str] = set()
    for f in pf:
        if curves.read(f).quantity == "normalised_shear_force" and curves.lab(f) not in seen:
            seen.add(curves.lab(f))
            out.append(spec(f"frame {curves.lab(f)}", (f,)))
    return out


def _file_hash(h: Any, p: Path) -> None:
    h.update(p.read_bytes())
    eb = errorbar_path(p)
    if eb.exists():
        h.update(eb.read_bytes())


def fits_key(spec: FitSpec, max_runs: int, scene_toml: str, curves: Curves) -> str:
    """A key of everything a fit reads: the scene, the fitted curves, the fit, the settings, the code.

    Not the curves it predicts: a curve added to the study is predicted by the kept fit (:func:`fit_and_predict`).
    """
    from ngbet.study.keys import code_version

    h = hashlib.sha256(scene_toml.encode())
    for name in spec.fitted:
        _file_hash(h, curves.paths[name])
    h.update(json.dumps([spec.fabric, spec.fitted, max_runs, code_version("continuum")], sort_keys=True).encode())
    return h.hexdigest()[:16]


def target_key(name: str, curves: Curves) -> str:
    """A key of a predicted curve: its file (and error bars), its name and the scored points."""
    h = hashlib.sha256(json.dumps([name, SCORE_POINTS]).encode())
    _file_hash(h, curves.paths[name])
    return h.hexdigest()[:16]


def points_of(curve: Any) -> tuple[np.ndarray, np.ndarray]:
    """(u, F): the scored points, :data:`SCORE_POINTS` over 10–90 % of the curve's displacement (travel) range."""
    return curve.sample(SCORE_POINTS)  # type: ignore[no-any-return]


def fits_folder(cache: Path | None = None) -> Path:
    """Where the fits are kept: ``validation-fits`` in the study cache (None: the default cache)."""
    from ngbet.study.runner import DEFAULT_ROOT

    return Path(cache if cache is not None else DEFAULT_ROOT / "cache") / FITS_FOLDER


def cached(folder: Path, name: str, make: Any) -> dict[str, Any]:
    """The record ``name`` (a fit, a prediction) kept in ``folder``, or ``make()`` kept there.

    A kept file that cannot be read (truncated, not a JSON object) is named in a warning and made
    again; a folder that cannot keep the record is an OSError naming it before ``make`` runs.
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
    keep(path, json.dumps(doc, allow_nan=False).encode())
    return doc  # type: ignore[no-any-return]


def keep(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (a temporary file renamed)."""
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def _progress(label: str, live: bool = True) -> Any:
    """A fit's progress on stderr: a line updating itself on a terminal (``live``), else a line at its start."""
    t0, tty = time.perf_counter(), live and sys.stderr.isatty()
    if not tty:
        print(f"ngbet: study validation: fitting {label}", file=sys.stderr, flush=True)

    def show(runs: int, rms: list[float], best: float) -> None:
        if tty:
            sys.stderr.write(
                f"\rngbet: study validation: fitting {label}: model run {runs}, RMS "
                + ", ".join(f"{100 * r:.1f} %" for r in rms)
                + f", {time.perf_counter() - t0:.0f} s\x1b[K"
            )
            sys.stderr.flush()

    return show


def _finite(a: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in np.asarray(a, float)]


def _predict(res: Any, curve: Any) -> dict[str, Any]:
    """The fitted scene's prediction of ``curve`` at its scored points, with its band (a record of the fit)."""
    from ngbet.calibration.bands import predict_specimen
    from ngbet.calibration.fit_params import test_changes

    u, _ = points_of(curve)
    try:
        p = predict_specimen(res, test_changes(curve), u)
    except Exception as exc:  # noqa: BLE001 - a failed prediction is a row of the report, not the end
        return {"u_mm": u.tolist(), "failed": f"{type(exc).__name__}: {exc}"}
    return {
        "u_mm": u.tolist(),
        "force_N": _finite(p.force_N),
        "sd_parameters_N": _finite(p.sd_param_N),
        "sd_discretization_N": _finite(p.sd_disc_N),
        "sd_model_error_N": _finite(p.sd_model_N),
        "band": p.band,
    }


def record_name(spec: FitSpec, quick: bool, scene: Scene, curves: Curves) -> str:
    """The name under which ``spec``'s fit from ``scene`` is kept (its predictions: NAME-TARGETKEY)."""
    runs = QUICK_RUNS if quick else MAX_RUNS
    return f"{'quick' if quick else 'full'}-{spec.fabric}-{fits_key(spec, runs, scene.to_toml(), curves)}"


def start_scene(spec: FitSpec, start: Scene | None) -> Scene:
    """The scene a fit starts from: ``start``, or the fabric's scene file."""
    return start or Scene.from_toml(data_root() / "geometry" / FABRICS[spec.fabric][0])


def fit_and_predict(
    spec: FitSpec, quick: bool, start: Scene | None, folder: Path, curves: Curves, live: bool = True
) -> dict[str, Any]:
    """``spec`` fitted as ``ngbet fit`` fits it, and each of its targets predicted with its band (cached).

    ``start``: the scene the fit starts from (None: the fabric's scene file). The record holds the
    fit (fit.json's content), the fitted scene and per target the scored points, the predicted
    force and its standard deviation from the parameters, from the discretization and from the model error
    the fit's curves estimate (:func:`ngbet.calibration.bands.model_error`), and in words what the band holds.
    ``live``: the fit's progress as a line updating itself where stderr is a terminal (in a worker
    process beside others: a line at its start and one at its end).

    Kept in ``folder``: the fit's record (``NAME.json``), the fit itself (``NAME.pickle``, what a
    prediction needs) and each prediction (``NAME-TARGETKEY.json``, :func:`target_key`), so that
    a curve added to the study costs its prediction, not the fit. A kept fit without its pickle
    (removed, unreadable) is made again when a new curve needs it.
    """
    from ngbet.calibration.joint import fit_curves

    runs = QUICK_RUNS if quick else MAX_RUNS
    scene = start_scene(spec, start)
    name = record_name(spec, quick, scene, curves)
    made: list[Any] = []  # the fit made in this process

    def make() -> dict[str, Any]:
        label = f"{spec.fabric.replace('_', ' ')}, {spec.name}"
        res = fit_curves([curves.read(f) for f in spec.fitted], scene, max_runs=runs, progress=_progress(label, live))
        if live and sys.stderr.isatty():
            sys.stderr.write(f"\rngbet: study validation: fitted {label} in {res.wall_s:.0f} s\x1b[K\n")
        elif not live:
            print(f"ngbet: study validation: fitted {label} in {res.wall_s:.0f} s", file=sys.stderr, flush=True)
        made.append(res)
        keep(folder / f"{name}.pickle", pickle.dumps(res))
        return {
            "fabric": spec.fabric,
            "fit_name": spec.name,
            "fitted": list(spec.fitted),
            "max_runs": runs,
            "fit": res.to_json(),
            "fitted_scene": res.scene.to_toml(),
        }

    def fit() -> Any:
        if not made:
            try:
                made.append(pickle.loads((folder / f"{name}.pickle").read_bytes()))
            except Exception as exc:  # noqa: BLE001 - a fit not read back whatever the cause is made again
                log.warning("the kept fit %s cannot be read (%s): the fit is made again", folder / name, exc)
                doc.update(make())
                keep(folder / f"{name}.json", json.dumps(doc, allow_nan=False).encode())
        return made[-1]

    doc = cached(folder, name, make)
    preds = {
        t: cached(folder, f"{name}-{target_key(t, curves)}", lambda t=t: _predict(fit(), curves.read(t)))
        for t in spec.targets
    }
    return {**doc, "predictions": preds, "cache_name": name}


def _kept(spec: FitSpec, quick: bool, start: Scene | None, folder: Path, curves: Curves) -> bool:
    """Whether ``spec``'s fit and every prediction of it are kept in ``folder`` (nothing to make)."""
    name = record_name(spec, quick, start_scene(spec, start), curves)
    return (folder / f"{name}.json").exists() and all(
        (folder / f"{name}-{target_key(t, curves)}.json").exists() for t in spec.targets
    )


def fit_all(
    specs: Sequence[FitSpec],
    quick: bool,
    start: Scene | None,
    folder: Path,
    curves: Curves,
    workers: int | None = None,
) -> list[dict[str, Any]]:
    """:func:`fit_and_predict` of each spec, the records in the order of ``specs``.

    The fits of one curve with something to make (:func:`_kept`) run side by side, each in a worker
    process of its own (spawned; ``workers``, default one per core: on 2 cores two one-size fits
    take the time of one), and the fits of two or more curves after them here, where each runs its
    curves in workers of its own (:class:`ngbet.calibration.runs.CurveModel`). Every record is the
    one this process would make: a fit is a function of its scene and curves, and each worker
    keeps its own files in ``folder`` under its own names. A worker's exception is raised here; a
    worker that dies stops the study (:class:`~ngbet.errors.FitWorkerError`) naming the
    fits not made; either ends the other workers, and Ctrl-C ends them all (they ignore it
    themselves, and exit when this process dies). The fits made are kept: an interruption is a
    :class:`~ngbet.study.executors.StudyInterrupted` saying how many fits of ``specs`` are kept
    and where, which a rerun reuses (:func:`interrupted_text`).
    """
    from ngbet.calibration.runs import default_workers
    from ngbet.study.executors import StudyInterrupted

    try:
        todo = [k for k, s in enumerate(specs) if len(s.fitted) == 1 and not _kept(s, quick, start, folder, curves)]
        n = default_workers(len(todo)) if workers is None else max(1, min(workers, len(todo)))
        docs: dict[int, dict[str, Any]] = _in_workers(specs, todo, n, quick, start, folder, curves) if n > 1 else {}
        return [docs[k] if k in docs else fit_and_predict(s, quick, start, folder, curves) for k, s in enumerate(specs)]
    except KeyboardInterrupt as exc:
        if isinstance(exc, StudyInterrupted):
            raise
        raise StudyInterrupted(interrupted_text(specs, quick, start, folder, curves)) from None


def interrupted_text(specs: Sequence[FitSpec], quick: bool, start: Scene | None, folder: Path, curves: Curves) -> str:
    """What an interrupted :func:`fit_all` kept, in words: the fits of ``specs`` with their record in ``folder``.

    A kept fit is reused by the next run of the study (its record, keyed by its scene, curves and
    code); the others are made then.
    """
    kept = [s for s in specs if (folder / f"{record_name(s, quick, start_scene(s, start), curves)}.json").exists()]
    names = "; ".join(f"{s.fabric.replace('_', ' ')}, {s.name}" for s in kept[:4]) + ("; ..." if len(kept) > 4 else "")
    n, k = len(specs), len(kept)
    if not kept:
        return (
            f"study validation interrupted while it made its fits: none of its {n} fit{'s' if n != 1 else ''} "
            f"was finished, nothing is kept in {folder}; run it again to make {'them' if n != 1 else 'it'}"
        )
    which = (
        ("its fit is" if n == 1 else f"all its {n} fits are")
        if k == n
        else f"{k} of its {n} fits {'are' if k != 1 else 'is'}"
    )
    return (
        f"study validation interrupted while it made its fits: {which} finished and kept in {folder} ({names}); "
        f"run it again: a kept fit is reused{', the others made' if k < n else ''}"
    )


def _in_workers(
    specs: Sequence[FitSpec],
    todo: Sequence[int],
    n: int,
    quick: bool,
    start: Scene | None,
    folder: Path,
    curves: Curves,
) -> dict[int, dict[str, Any]]:
    """The fits ``todo`` of ``specs`` on ``n`` worker processes (:func:`fit_all`)."""
    import concurrent.futures as cf
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool

    from ngbet.errors import FitWorkerError
    from ngbet.study.executors import stop_pool, worker_init

    ctx = multiprocessing.get_context("spawn")  # Netgen and NGSolve's threads do not survive a fork
    alive_r, alive_w = ctx.Pipe(duplex=False)
    env = {k: v for k, v in os.environ.items() if k.startswith("NGBET_")}
    ex = cf.ProcessPoolExecutor(n, mp_context=ctx, initializer=worker_init, initargs=(alive_r, env))
    docs: dict[int, dict[str, Any]] = {}
    try:
        futures = {ex.submit(fit_and_predict, specs[k], quick, start, folder, curves, False): k for k in todo}
        for f in cf.as_completed(futures):
            try:
                docs[futures[f]] = f.result()
            except BrokenProcessPool as exc:  # every fit still running has lost its worker
                lost = "; ".join(f"{specs[k].fabric.replace('_', ' ')}, {specs[k].name}" for k in todo if k not in docs)
                raise FitWorkerError(
                    "a worker process ended without an answer (killed, out of memory or crashed); the study "
                    f"stops with these fits not made: {lost} (the fits made are kept)"
                ) from exc
        ex.shutdown(wait=True)
    finally:
        stop_pool(ex)
        alive_w.close()
        alive_r.close()
    return docs
