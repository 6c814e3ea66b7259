"""Measured BET curves for the calibration: read, checked line by line, reduced to the fitted points.

A data file is a CSV with ``#`` comment lines, then a header line naming the columns, then rows of
numbers: the clamp displacement [mm] (first column, or ``displacement_mm``) and the force [N]
(``force_N``, or the second column). Comment lines of the form ``# specimen.width_mm = 150`` give
the specimen the curve was measured on (``# thickness_mm = 1.2`` is ``specimen.thickness_mm``).
A file ``NAME_errorbars.csv`` beside ``NAME.csv`` with the columns ``displacement_mm``,
``force_low_N``, ``force_high_N`` gives the printed error bars.

Everything is checked before any model run, and a refusal names the file and the line
(:class:`ngbet.scene.validate.SceneError`, exit status 2): a file without a header (a first line of numbers
would otherwise be taken for column names), text in a number's place, NaN or inf, fewer than
three points, a force or displacement that is not positive in the fitted range.

The fitted points: curves extracted from vector graphics hold thousands of vertices, some at the
same displacement and some stepping back; the curve is sorted, points of equal displacement are
averaged, and it is sampled at :data:`POINTS_PER_CURVE` equally spaced displacements over 10–90 %
of its displacement range (linear interpolation: the paper's dashed lines have gaps). The first
tenth holds slack and friction that no elastic law describes; the last tenth reaches ideal yarn
locking, where the kinematics of the test change.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..scene.validate import SceneError

__all__ = ["MIN_RELATIVE_SD", "POINTS_PER_CURVE", "RANGE", "READING_ERROR_N", "MeasuredCurve", "errorbar_path",
           "read_measured"]

#: the points of a curve that enter a fit
POINTS_PER_CURVE = 16
#: the part of a curve's displacement range that is fitted and scored (fractions)
RANGE = (0.1, 0.9)
#: the reading error of the extracted curves [N]: the floor of a point's standard deviation
READING_ERROR_N = 0.03
#: the smallest standard deviation of a point, relative to its force: an error bar printed with no
#: height (several are) does not make a point exact
MIN_RELATIVE_SD = 0.01

_HEADER_KEY = re.compile(r"^#\s*(specimen\.)?(width_mm|length_mm|thickness_mm|yarn_angle_deg)\s*=\s*(\S+)\s*$")


@dataclass(frozen=True)
class MeasuredCurve:
    """A checked measured curve: displacement [mm] increasing, force [N], its specimen keys, error bars."""

    u_mm: np.ndarray
    force_N: np.ndarray
    source: str
    specimen: dict[str, float] = field(default_factory=dict)  # "specimen.width_mm": 150.0, ...
    bars: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # u [mm], low [N], high [N]

    @property
    def label(self) -> str:
        """"W x L mm" from the header, else the file name."""
        w, L = self.specimen.get("specimen.width_mm"), self.specimen.get("specimen.length_mm")
        return f"{w:g} x {L:g} mm" if w and L else Path(self.source).stem

    def window(self, fraction: tuple[float, float] = RANGE) -> tuple[float, float]:
        """The displacements [mm] between the fractions of the curve's displacement range."""
        lo, hi = float(self.u_mm.min()), float(self.u_mm.max())
        return lo + fraction[0] * (hi - lo), lo + fraction[1] * (hi - lo)

    def sample(self, n: int = POINTS_PER_CURVE, fraction: tuple[float, float] = RANGE) -> tuple[np.ndarray, np.ndarray]:
        """(u, F) at n equally spaced displacements over ``fraction`` of the range."""
        a, b = self.window(fraction)
        u = np.linspace(a, b, n)
        return u, np.interp(u, self.u_mm, self.force_N)

    def sd(self, u: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Standard deviation of the force at u [N]: half the error bar (interpolated), floored.

        The floor is the larger of the reading error and :data:`MIN_RELATIVE_SD` of the force;
        without error bars the floor alone (a constant relative error).
        """
        floor = np.maximum(READING_ERROR_N, MIN_RELATIVE_SD * np.abs(F))
        if self.bars is None:
            return floor
        bu, lo, hi = self.bars
        half = np.interp(u, bu, 0.5 * (hi - lo))
        return np.maximum(half, floor)


def _rows(path: Path, what: str) -> list[tuple[int, str]]:
    if path.is_dir():
        raise SceneError(f"{what} file {path} is a directory")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise SceneError(f"{what} file {path} cannot be read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise SceneError(f"{what} file {path} is not a text file (not UTF-8)") from None
    if "\x00" in text:
        raise SceneError(f"{what} file {path} is not a text file (holds NUL bytes)")
    return [(k + 1, line.strip()) for k, line in enumerate(text.splitlines())]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _number(text: str, path: Path, line: int, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a number") from None
    if not math.isfinite(v):
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a finite number")
    return v


def _table(path: Path, what: str, need: tuple[str, ...]  # noqa: C901 - one check after the other
           ) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Header keys from the comments and the named numeric columns (empty cells: NaN) of a CSV."""
    keys: dict[str, float] = {}
    head: list[str] | None = None
    head_line = 0
    cols: dict[str, list[float]] = {}
    lines: list[int] = []
    for k, line in _rows(path, what):
        if not line:
            continue
        if line.startswith("#"):
            m = _HEADER_KEY.match(line)
            if m and head is None:
                keys[f"specimen.{m.group(2)}"] = _number(m.group(3), path, k, f"specimen.{m.group(2)}")
            continue
        cells = [c.strip() for c in line.split(",")]
        if head is None:
            if not _is_number(cells[0]):
                head, head_line = cells, k
                missing = [n for n in need if n not in head]
                if missing and need != ("displacement_mm", "force_N"):
                    raise SceneError(f"{path}, line {k}: the header lacks the column(s) {', '.join(missing)}")
                if len(head) < 2:
                    raise SceneError(f"{path}, line {k}: the header names one column; two are needed "
                                     "(displacement_mm,force_N)")
                continue
            raise SceneError(f"{path}, line {k}: a row of numbers where the header should be: the first line "
                             "that is not a # comment must name the columns (displacement_mm,force_N)")
        idx = {n: (head.index(n) if n in head else j) for j, n in enumerate(need)}
        if len(cells) <= max(idx.values()):
            raise SceneError(f"{path}, line {k}: {len(cells)} cells, the header (line {head_line}) has {len(head)}")
        for n, j in idx.items():
            if cells[j] == "" and n not in ("displacement_mm", "force_N"):
                cols.setdefault(n, []).append(math.nan)  # an error bar not drawn
            else:
                cols.setdefault(n, []).append(_number(cells[j], path, k, head[j]))
        lines.append(k)
    if head is None:
        raise SceneError(f"{what} file {path}: no header line and no data")
    cols_np = {n: np.array(v) for n, v in cols.items()}
    cols_np["_line"] = np.array(lines, dtype=float)
    return keys, cols_np


def errorbar_path(path: str | Path) -> Path:
    """``NAME_errorbars.csv`` beside ``NAME.csv``."""
    p = Path(path)
    return p.with_name(p.stem + "_errorbars" + p.suffix)


def read_measured(path: str | Path, fraction: tuple[float, float] = RANGE) -> MeasuredCurve:
    """Read and check a measured curve (module docstring); its error bars too when the file is there."""
    path = Path(path)
    keys, c = _table(path, "data", ("displacement_mm", "force_N"))
    u, F, lines = c.get("displacement_mm", np.zeros(0)), c.get("force_N", np.zeros(0)), c["_line"]
    if len(u) < 3:
        raise SceneError(f"data file {path}: {len(u)} rows of numbers; at least 3 are needed")
    for k in ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"):
        if k in keys and not keys[k] > 0:
            raise SceneError(f"{path}: header {k} = {keys[k]:g} must be > 0")
    order = np.argsort(u, kind="stable")
    u, F, lines = u[order], F[order], lines[order]
    lo, hi = float(u.min()), float(u.max())
    if not hi > 0:
        raise SceneError(f"{path}: no positive displacement (the largest is {hi:g} mm); the column "
                         "displacement_mm is the clamp displacement in mm, increasing with the load")
    a, b = lo + fraction[0] * (hi - lo), lo + fraction[1] * (hi - lo)
    inside = (u >= a) & (u <= b)
    bad = inside & ((F <= 0) | (u <= 0))
    if bad.any():
        j = int(np.argmax(bad))
        raise SceneError(f"{path}, line {int(lines[j])}: displacement {u[j]:g} mm, force {F[j]:g} N in the fitted "
                         f"range {a:.3g} to {b:.3g} mm: forces and displacements must be > 0 there (a tensile test "
                         "pulls; is the sign of a column flipped?)")
    # equal displacements averaged (vertices of a vector path)
    uu, inv = np.unique(u, return_inverse=True)
    FF = np.bincount(inv, weights=F) / np.bincount(inv)
    if len(uu) < 3:
        raise SceneError(f"data file {path}: fewer than 3 distinct displacements")
    bars = None
    ep = errorbar_path(path)
    if ep.exists():
        _, e = _table(ep, "error bar", ("displacement_mm", "force_N", "force_low_N", "force_high_N"))
        ok = np.isfinite(e["force_low_N"]) & np.isfinite(e["force_high_N"])
        if ok.sum() >= 2:
            bu, bl, bh = e["displacement_mm"][ok], e["force_low_N"][ok], e["force_high_N"][ok]
            wrong = bh < bl
            if wrong.any():
                j = int(np.argmax(wrong))
                raise SceneError(f"{ep}, line {int(e['_line'][ok][j])}: force_high_N {bh[j]:g} is below force_low_N "
                                 f"{bl[j]:g}")
            o = np.argsort(bu)
            bars = (bu[o], bl[o], bh[o])
    return MeasuredCurve(uu, FF, str(path), keys, bars)
