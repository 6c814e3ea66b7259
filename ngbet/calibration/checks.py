"""Checks of ``ngbet fit``'s inputs against each other, before the first model run.

Each refusal is a :class:`~ngbet.scene.validate.SceneError` naming what is wrong (exit 2); each
note a line the command prints. Read by :class:`ngbet.calibration.command.Inputs`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..measured.curves import MeasuredCurve
from ..measured.shape import plural
from ..measured.table import errorbar_path
from ..scene.document import Scene
from ..scene.physical import SHEAR_LAW_KEYS, Specimen
from ..scene.validate import SceneError
from .fit_params import test_changes

__all__ = [
    "PER_CURVE",
    "errorbar_notes",
    "no_params",
    "refuse_fitted_predictions",
    "refuse_unsized",
    "scene_frame",
    "set_conflicts",
]

#: keys the fit sets for every curve, whatever the scene says: a --set of one has no effect
PER_CURVE = {
    "loading.u0_mm": "the fit loads each curve to its last fitted point",
    "loading.stops_mm": "the fit stops each curve's load at its fitted points",
}


def no_params(scene: Scene, path: str | None) -> str:
    """The refusal of a scene that names no parameters (no ``[calibration] params``) and no ``--params``.

    It names the keys the scene's shear law reads, and a scene beside it of the same material
    whose ``[calibration]`` names parameters (a fabric's bias-extension scene, which fits frames too).
    """
    from ..continuum.sensitivity import DIFFERENTIABLE, TABLE

    law = scene.effects.shear_law
    keys = [f"material.{k}" for k in SHEAR_LAW_KEYS[law] if k in DIFFERENTIABLE or k == TABLE]
    text = (
        f"no parameters to fit: {f'the scene {path}' if path else 'the embedded scene'} names none "
        f"(no [calibration] params); give --params, e.g. --params {','.join(keys)} (what its shear "
        f"law {law!r} reads)"
    )
    for other in sorted(Path(path).parent.glob("*.toml")) if path else []:
        if other.resolve() == Path(path or "").resolve():
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sc = Scene.from_toml(other)
        except (SceneError, OSError, ValueError):
            continue
        if sc.calibration.params and sc.material == scene.material:
            return (
                f"{text}; or fit with --scene {other}, the {sc.test.replace('_', '-')} scene of the same material, "
                "whose [calibration] names them (a fit takes curves of either test with it)"
            )
    return text


def _reads(curve: MeasuredCurve, key: str) -> bool:
    """Whether the curve's test reads the scene key ``key`` (a frame reads no specimen length or width)."""
    if key.startswith("picture_frame."):
        return curve.test == "picture_frame"
    if key in ("specimen.length_mm", "specimen.width_mm"):
        return curve.test == "bias_extension"
    return True


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b), rel_tol=1e-9)
    return bool(a == b)


def set_conflicts(overrides: Sequence[str], scene: Scene, curves: Sequence[MeasuredCurve]) -> list[str]:
    """Refuse a ``--set`` that no curve runs with; a note where some curves run with it and others not.

    Each curve runs the test its file names and the specimen (or frame) of its header
    (:func:`~ngbet.calibration.fit_params.test_changes`): a ``--set`` of the test, a specimen or a
    frame key gives way to them, and the fit sets each curve's load (:data:`PER_CURVE`). A
    ``--set`` whose value no curve runs with is refused naming both values.
    """
    notes = []
    for item in overrides:
        key = item.partition("=")[0].strip()
        if key in PER_CURVE:
            raise SceneError(f"--set {item}: {PER_CURVE[key]}; the --set has no effect: drop it")
        if key != "test" and not key.startswith(("specimen.", "picture_frame.")):
            continue
        section, _, name = key.partition(".")
        value = scene.test if key == "test" else getattr(getattr(scene, section), name)
        uses, given = [], []
        for c in curves:
            own = test_changes(c)
            if key in own and not _same(own[key], value) and _reads(c, key):
                given.append(f"{c.source}: {key} = {own[key]:g}" if key != "test" else f"{c.source}: test = {own[key]}")
            elif _reads(c, key):
                uses.append(c.source)
        if given and not uses:
            raise SceneError(
                f"--set {item}: each curve runs the test and specimen its file names ({'; '.join(given[:3])}): "
                "the --set has no effect; drop it, or change the file's header"
            )
        if given:
            notes.append(f"--set {item} applies to {', '.join(uses)}; {'; '.join(given[:3])}, from its header")
    return notes


def refuse_unsized(scene: Scene, curves: Sequence[MeasuredCurve]) -> None:
    """Refuse a bias-extension curve without specimen keys where the scene (a frame's) has no specimen length, width."""
    sp, default = scene.specimen, Specimen()
    unsized = (sp.length_mm, sp.width_mm) == (default.length_mm, default.width_mm) and scene.test == "picture_frame"
    for c in curves:
        if unsized and c.test == "bias_extension" and not c.specimen:
            raise SceneError(
                f"{c.source}: a bias-extension curve without specimen keys runs on the scene's specimen, but "
                "the scene is a picture frame's (test = 'picture_frame'), whose specimen has no clamp-to-clamp "
                "length or width: give them in its header (# specimen.width_mm = ..., # specimen.length_mm = ...) "
                "or with --specimen WxL, or use the fabric's bias-extension scene"
            )


def scene_frame(scene: Scene, overrides: Sequence[str]) -> dict[str, float] | None:
    """The picture frame the scene names, for the frame curves whose header names none; None where it names none.

    A scene names its frame when it is a picture frame's (``test = "picture_frame"``), or when
    ``--set`` gives both ``picture_frame.frame_mm`` and ``picture_frame.fabric_mm``: its
    ``[picture_frame]`` after the overrides. (A bias-extension scene's frame is the defaults.)
    """
    keys = {"picture_frame.frame_mm", "picture_frame.fabric_mm"}
    given = {item.partition("=")[0].strip() for item in overrides}
    if scene.test != "picture_frame" and not keys <= given:
        return None
    pf = scene.picture_frame
    return {"picture_frame.frame_mm": float(pf.frame_mm), "picture_frame.fabric_mm": float(pf.fabric_mm)}


def refuse_fitted_predictions(curves: Sequence[MeasuredCurve], predict: Sequence[MeasuredCurve]) -> None:
    """Refuse a ``--predict`` curve that is one of the fitted curves (the same file, or the same numbers)."""
    for p in predict:
        for c in curves:
            same_file = Path(p.source).resolve() == Path(c.source).resolve()
            if same_file or (np.array_equal(p.u_mm, c.u_mm) and np.array_equal(p.force_N, c.force_N)):
                what = "a data file of the fit" if same_file else f"the measured curve of the data file {c.source}"
                raise SceneError(
                    f"--predict {p.source}: {what}; a prediction is of a curve the fit does not use "
                    "(the fit's own curves are in fit.json and fit.png): drop it from --predict"
                )


def errorbar_notes(
    curves: Sequence[MeasuredCurve], predict: Sequence[MeasuredCurve], left: Sequence[tuple[Any, Path]]
) -> list[str]:
    """A note for each curve whose error bars are read (the file and the bars), or whose error-bar file is not used.

    ``left``: the error-bar files given among the data files, with their curves.
    """
    given = {Path(curve).resolve(): eb for eb, curve in left}
    notes = []
    for k, c in enumerate([*curves, *predict]):
        eb = errorbar_path(c.source)
        role = "weight its points" if k < len(curves) else "give its points' scatter in the prediction"
        if c.bars is not None:
            bars = plural(len(c.bars[0]), "bar")
            named = given.get(Path(c.source).resolve())
            if named is not None:
                notes.append(f"{named}: the error bars of {c.source}, read with it: {bars}; they {role}")
            else:
                notes.append(f"{c.source}: the {bars} of {eb} beside it {role}")
        elif eb.is_file():
            why = (
                "a picture-frame curve's error bars are not read"
                if c.test == "picture_frame"
                else "it holds fewer than two complete bars"
            )
            notes.append(
                f"{eb}: not used ({why}); the points of {c.source} are weighted by the reading error "
                "and 1 % of the force"
            )
    return notes
