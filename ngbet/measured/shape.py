"""The shape of a measured curve as read: its signs, the order of its rows and its loading branch.

Applied by :func:`ngbet.measured.table.read_table` to the converted columns, in this order:

1. **signs** (:func:`signs`): a displacement (or shear angle) and a force that are both negative
   throughout, as a machine that counts tension negative exports them, are read with both signs
   changed, and the note says so; one of them negative throughout and the other positive is
   refused: is the sign of that column flipped? (Both tests pull the fabric.) A picture frame's
   shear angle that no frame reaches, above :data:`MAX_SHEAR_DEG` or below 0° at most rows, is
   refused naming the column, its unit and the likely cause (:func:`frame_angles`).
2. **order** (:func:`order`): rows in descending displacement (a digitised path drawn from its end)
   are read in ascending order, and the note says so, when the force is largest at the largest
   displacement; a displacement that falls while the force rises (a position counted against the
   pull) is refused.
3. **the loading branch** (:func:`loading_branch`): the rows after the largest displacement that
   fall back by more than :data:`CYCLE_TOLERANCE` of the range are an unloading, left out with a
   note; such falls before the largest displacement (several cycles) are refused, and so is a
   loading branch that would keep fewer than :data:`MIN_LOADING_SHARE` of the rows (or fewer than
   3): nearly all of a file is never dropped.

A refusal is a :class:`ngbet.scene.validate.SceneError` naming the file, the lines and what to write.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..scene.validate import SceneError
from .columns import CANONICAL, QUANTITIES, WORDS

__all__ = [
    "CYCLE_TOLERANCE",
    "MAX_SHEAR_DEG",
    "MIN_LOADING_SHARE",
    "frame_angles",
    "loading_branch",
    "order",
    "plural",
    "signs",
]

#: a fall of the displacement by more than this fraction of its range is an unloading (the vertices of
#: a digitised curve step back by up to 2.5 % of the range: data/cao2008_pf); a column whose values
#: lie below zero but for this fraction of its range is negative throughout
CYCLE_TOLERANCE = 0.05
#: the smallest share of the rows a loading branch keeps; below it the file is refused, not cut
MIN_LOADING_SHARE = 0.1
#: the largest shear angle of a picture frame [deg]: its bars folded flat
MAX_SHEAR_DEG = 90.0

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]


def plural(n: int, word: str, words: str | None = None) -> str:
    """``1 row``, ``3 rows``: a count with its noun, singular for one."""
    return f"{n} {word if n == 1 else words or word + 's'}"


def _unit(quantity: str) -> str:
    """The canonical unit of a quantity as it follows a number: ``°``, `` mm``, `` N``, `` N/mm``."""
    unit = CANONICAL[QUANTITIES[quantity][1]] if quantity in QUANTITIES else ""
    return "°" if unit == "deg" else f" {unit}" if unit else ""


def _negative(v: np.ndarray) -> bool:
    """Negative throughout: below zero, but for :data:`CYCLE_TOLERANCE` of its range at most above it."""
    return bool(v.min() < 0 and v.max() <= CYCLE_TOLERANCE * float(np.ptp(v)))


def signs(x: np.ndarray, y: np.ndarray, path: Path, xq: str, yq: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The columns with both signs changed where both are negative throughout (said); one alone refused.

    ``xq``, ``yq``: the quantities of the columns (keys of :data:`~ngbet.measured.columns.WORDS`).
    """
    if len(x) < 2:
        return x, y, []
    xn, yn = _negative(x), _negative(y)
    if xn and yn:
        return (
            -x,
            -y,
            [
                f"the {WORDS[xq]} and the {WORDS[yq]} are negative throughout (tension counted negative): "
                "read with both signs changed"
            ],
        )
    if xn or yn:
        neg, pos = (xq, yq) if xn else (yq, xq)
        low = float((x if xn else y).min())
        raise SceneError(
            f"{path}: the {WORDS[neg]} is negative throughout (down to {low:g}{_unit(neg)}) while the {WORDS[pos]} is "
            f"positive: is the sign flipped? Both tests pull the fabric: write the {WORDS[neg]} column "
            "positive under tension"
        )
    return x, y, []


def frame_angles(g: np.ndarray, lines: np.ndarray, path: Path, column: str, unit: str) -> None:
    """Refuse a picture frame's shear angles [deg] that no frame reaches, naming the column and its unit.

    Refused (SceneError): an angle above :data:`MAX_SHEAR_DEG` in magnitude (named with its line; a
    column in rad is asked whether it is in degrees, one in degrees whether it holds the shear angle
    γ), or more than half of the angles below 0°. ``column``, ``unit``: the column's name and unit as
    written in messages.
    """
    if not len(g):
        return
    j = int(np.argmax(np.abs(g)))
    if abs(g[j]) > MAX_SHEAR_DEG:
        held = f"{np.radians(g[j]):.4g} rad ({g[j]:.4g}°)" if unit == "rad" else f"{g[j]:.4g}°"
        cause = (
            "is the column in degrees rather than rad?"
            if unit == "rad"
            else "is it the shear angle γ (0° in the square frame), not the angle between the yarns (90° + γ)?"
        )
        raise SceneError(
            f"{path}, line {int(lines[j])}: the column {column!r} holds {held}: a shear angle of {g[j]:.4g}° is "
            f"impossible in a picture frame (at most {MAX_SHEAR_DEG:g}°): {cause} Write its unit in the header "
            f"(shear_angle_deg, shear_angle_rad) or give it with --columns '{column}:deg,...'"
        )
    below = g < 0
    if 2 * int(below.sum()) > len(g):
        k = int(np.argmin(g))
        raise SceneError(
            f"{path}: {below.sum()} of {plural(len(g), 'shear angle')} in the column {column!r} lie below 0° "
            f"(down to {g[k]:.4g}° at line {int(lines[k])}): a picture frame shears from 0° (the square frame) "
            f"up to {MAX_SHEAR_DEG:g}°: is it the shear angle γ, counted positive as the frame shears?"
        )


def order(x: np.ndarray, y: np.ndarray, lines: np.ndarray, path: Path, xq: str, yq: str) -> tuple[Arrays, list[str]]:
    """The rows in ascending x where the file lists them descending (said); x falling as y rises refused.

    Descending: the first x above the last and, read from the last row up, x never falls back by
    more than :data:`CYCLE_TOLERANCE` of its range. Other files are returned as they are.
    """
    tol = CYCLE_TOLERANCE * float(np.ptp(x)) if len(x) else 0.0
    rev = x[::-1]
    if len(x) < 2 or not x[0] > x[-1] + tol or float((np.maximum.accumulate(rev) - rev).max()) > tol:
        return (x, y, lines), []
    hi, lo = int(np.argmax(x)), int(np.argmin(x))
    what, unit, yu = WORDS[xq], _unit(xq), _unit(yq)
    fall = f"from {x[hi]:g}{unit} at line {int(lines[hi])} to {x[lo]:g}{unit} at line {int(lines[lo])}"
    if not y[hi] > y[lo]:
        raise SceneError(
            f"{path}: the {what} falls {fall} while the {WORDS[yq]} rises from {y[hi]:g}{yu} to {y[lo]:g}{yu}: "
            f"a {what} counted against the pull (a crosshead position measured downward, or the sign "
            f"flipped?); write the {what} increasing with the load"
        )
    note = f"the rows run down the {what}, {fall}: read in ascending order"
    return (x[::-1], y[::-1], lines[::-1]), [note]


def loading_branch(x: np.ndarray, y: np.ndarray, lines: np.ndarray, path: Path, xq: str) -> tuple[Arrays, list[str]]:
    """The rows up to the largest x when the rows after it fall back (an unloading), said (module docstring).

    Refused: a fall before the largest x (several cycles); a loading branch of fewer than
    :data:`MIN_LOADING_SHARE` of the rows or fewer than 3.
    """
    if len(x) < 2:
        return (x, y, lines), []
    i = int(np.argmax(x))
    tol = CYCLE_TOLERANCE * float(x.max() - x.min())
    what, unit = WORDS.get(xq, xq), _unit(xq)
    fall = np.maximum.accumulate(x[: i + 1]) - x[: i + 1]
    if fall.max() > tol:
        j = int(np.argmax(fall > tol))
        raise SceneError(
            f"{path}, line {int(lines[j])}: the {what} falls back to "
            f"{x[j]:g}{unit} before its largest value ({x[i]:g}{unit}, line {int(lines[i])}): several "
            "load cycles; keep one loading branch in the file"
        )
    if i == len(x) - 1 or not float(x[i] - x[i + 1 :].min()) > tol:
        return (x, y, lines), []
    n, after = len(x), len(x) - 1 - i
    if i + 1 < max(3, MIN_LOADING_SHARE * n):
        raise SceneError(
            f"{path}, line {int(lines[i])}: the {what} reaches its largest value, {x[i]:g}{unit}, in row "
            f"{i + 1} of {n} and falls back to {float(x[i + 1 :].min()):g}{unit} over the "
            f"{plural(after, 'row')} after it: a loading branch of {plural(i + 1, 'row')} is no curve to "
            "read; keep one loading branch in the file, its rows in the order of the test"
        )
    note = (
        f"a loading-unloading cycle: kept the loading branch up to the largest {what}, "
        f"{x[i]:g}{unit} (line {int(lines[i])}); the {plural(after, 'row')} after it "
        f"{'is' if after == 1 else 'are'} left out"
    )
    return (x[: i + 1], y[: i + 1], lines[: i + 1]), [note]
