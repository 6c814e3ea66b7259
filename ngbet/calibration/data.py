"""Measured curves as laboratories write them: the one reader of every command (fit, run --data, normalise).

A data file is a table of text: ``#`` comment lines, then a header line naming the columns, then
rows of numbers. :func:`read_table` understands

- **columns by name**, in any order: the displacement (``displacement``, ``extension``,
  ``crosshead``, ``stroke``, ...), the force (``force``, ``load``), for the picture frame also the
  shear angle, the shear force and the normalised shear force; other columns (``time_s``) are
  ignored. Or chosen with ``columns`` (``--columns``): two header names or 1-based numbers, each
  with an optional unit, ``"Weg:mm,Kraft:kN"``. Two columns without names it understands are
  refused, never taken by position.
- **units in the header**: ``force_kN``, ``Force (kN)``, ``Force [kN]``, a row of units under the
  header; lengths mm, cm, m; forces N, kN; angles deg, rad; normalised forces N/mm, N/m. Values
  are converted to mm, N, degrees and N/mm, and every conversion is said (:attr:`CurveTable.notes`).
  A column it needs without a unit is refused.
- **separators**: commas; semicolons or tabs, then with decimal commas (``0,5``) as Excel writes
  them; quoted cells; a UTF-8 byte order mark; Windows-1252 text.
- **the specimen** from comment lines ``# specimen.width_mm = 100`` (also ``= 100 mm``,
  ``# width_mm = 100``, ``# specimen.width = 0.1 m``; ``thickness_mm`` and ``yarn_angle_deg``
  too) or from the command line (``--specimen 100x250``, width x clamp-to-clamp length [x
  thickness] in mm). Both given and different, only one of width and length, a width or length
  not > 0, a length not above the width: refused.
- **the test**: ``# test: picture-frame`` or ``bias_extension`` (or ``--test``), and the picture
  frame's sizes from ``# Table 3 (UN): frame 145 mm, fabric 120 mm`` or
  ``# picture_frame.frame_mm = 145`` and ``# picture_frame.fabric_mm = 120`` (or ``--frame 145x120``).
- **a loading–unloading cycle**: the rows after the largest displacement that fall back by more
  than :data:`CYCLE_TOLERANCE` of the range are the unloading; the loading branch is kept and the
  note says so. Falls of that size before the largest displacement (several cycles) are refused.

Everything is checked before any model run, and a refusal names the file and the line and says
what to write (:class:`ngbet.scene.SceneError`, exit status 2).

:func:`read_measured` reads a bias extension curve (clamp displacement [mm], force [N]) for the
calibration and the run figures. A file ``NAME_errorbars.csv`` beside ``NAME.csv`` with the
columns ``displacement_mm``, ``force_low_N``, ``force_high_N`` gives the printed error bars.

The fitted points: curves extracted from vector graphics hold thousands of vertices, some at the
same displacement and some stepping back; the curve is sorted, points of equal displacement are
averaged, and it is sampled at :data:`POINTS_PER_CURVE` equally spaced displacements over 10–90 %
of its displacement range (linear interpolation: the paper's dashed lines have gaps). The first
tenth holds slack and friction that no elastic law describes; the last tenth reaches ideal yarn
locking, where the kinematics of the test change.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..scene import SceneError

#: the points of a curve that enter a fit
POINTS_PER_CURVE = 16
#: the part of a curve's displacement range that is fitted and scored (fractions)
RANGE = (0.1, 0.9)
#: the reading error of the extracted curves [N]: the floor of a point's standard deviation
READING_ERROR_N = 0.03
#: the smallest standard deviation of a point, relative to its force: an error bar printed with no
#: height (several are) does not make a point exact
MIN_RELATIVE_SD = 0.01
#: a fall of the displacement by more than this fraction of its range is an unloading (the vertices of
#: a digitised curve step back by up to 2.5 % of the range: data/cao2008_pf)
CYCLE_TOLERANCE = 0.05

TESTS = ("bias_extension", "picture_frame")

#: units → (kind, factor to the canonical unit: mm, N, deg, N/mm, s)
UNITS: dict[str, tuple[str, float]] = {
    "mm": ("length", 1.0), "cm": ("length", 10.0), "m": ("length", 1000.0),
    "n": ("force", 1.0), "kn": ("force", 1000.0),
    "deg": ("angle", 1.0), "°": ("angle", 1.0), "degree": ("angle", 1.0), "degrees": ("angle", 1.0),
    "rad": ("angle", 180.0 / math.pi),
    "n/mm": ("force/length", 1.0), "n/m": ("force/length", 1e-3), "kn/m": ("force/length", 1.0),
    "n_per_mm": ("force/length", 1.0), "n_per_m": ("force/length", 1e-3),
    "s": ("time", 1.0), "ms": ("time", 1e-3), "min": ("time", 60.0), "h": ("time", 3600.0),
}
#: how a unit is written in messages
PRETTY = {"n": "N", "kn": "kN", "n/mm": "N/mm", "n/m": "N/m", "kn/m": "kN/m", "n_per_mm": "N/mm", "n_per_m": "N/m"}
CANONICAL = {"length": "mm", "force": "N", "angle": "deg", "force/length": "N/mm", "time": "s"}
#: quantities: their words in a header (the more specific first) and the unit kind they take
QUANTITIES: dict[str, tuple[tuple[str, ...], str]] = {
    "normalised_shear_force": (("normalised shear force", "normalized shear force", "fsh", "f sh", "fnorm",
                                "f norm", "fnormalized"), "force/length"),
    "shear_force": (("shear force", "fs"), "force"),
    "shear_angle": (("shear angle", "gamma", "angle"), "angle"),
    "force": (("standard force", "force", "load", "kraft"), "force"),
    "displacement": (("displacement", "extension", "elongation", "crosshead", "stroke", "travel", "position",
                      "deflection", "deformation", "weg"), "length"),
    "time": (("time", "zeit"), "time"),
}
X_QUANTITIES = ("displacement", "shear_angle")
Y_QUANTITIES = ("force", "shear_force", "normalised_shear_force")
WORDS = {"displacement": "displacement", "shear_angle": "shear angle", "force": "force",
         "shear_force": "shear force", "normalised_shear_force": "normalised shear force", "time": "time"}

_SPECIMEN_KEYS = {"width": "specimen.width_mm", "length": "specimen.length_mm",
                  "thickness": "specimen.thickness_mm", "yarn_angle": "specimen.yarn_angle_deg"}
_FRAME_KEYS = {"frame": "picture_frame.frame_mm", "fabric": "picture_frame.fabric_mm"}
_KEY_LINE = re.compile(r"^#\s*((?:specimen|picture_frame)\.[\w.]+|width_mm|length_mm|thickness_mm|yarn_angle_deg)"
                       r"\s*=\s*(.*?)\s*$")
_TEST_LINE = re.compile(r"^#\s*test\s*[:=]\s*[\"']?([^;,\"']*)", re.IGNORECASE)
_TABLE3 = re.compile(r"frame\s+([0-9.]+)\s*mm\s*,\s*fabric\s+([0-9.]+)\s*mm", re.IGNORECASE)
_VALUE = re.compile(r"^([+-]?[0-9.]+(?:[eE][+-]?\d+)?)\s*([A-Za-z°]*)$")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
_UNIT_IN_BRACKETS = re.compile(r"^(.*?)\s*[(\[]\s*([^)\]]*?)\s*[)\]]\s*$")


@dataclass(frozen=True)
class MeasuredCurve:
    """A checked bias extension curve: displacement [mm] increasing, force [N], its specimen keys, error bars.

    ``notes`` says what the reader did beyond reading numbers (units converted, columns chosen, an
    unloading branch left out, the specimen from the command line); ``test`` is "bias_extension".
    """

    u_mm: np.ndarray
    force_N: np.ndarray
    source: str
    specimen: dict[str, float] = field(default_factory=dict)  # "specimen.width_mm": 150.0, ...
    bars: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # u [mm], low [N], high [N]
    notes: tuple[str, ...] = ()
    test: str = "bias_extension"
    #: the picture frame's keys (``picture_frame.frame_mm``, ``picture_frame.fabric_mm``) of a picture-frame curve
    frame: dict[str, float] = field(default_factory=dict)
    #: the quantity the file holds: "force" (BET), "shear_force" or "normalised_shear_force" (picture frame)
    quantity: str = "force"

    @property
    def label(self) -> str:
        """"W x L mm" from the header (a picture frame: "frame F/f mm"), else the file name."""
        if self.test == "picture_frame":
            return (f"frame {self.frame['picture_frame.frame_mm']:g}/{self.frame['picture_frame.fabric_mm']:g} mm")
        w, L = self.specimen.get("specimen.width_mm"), self.specimen.get("specimen.length_mm")
        return f"{w:g} x {L:g} mm" if w and L else Path(self.source).stem

    @property
    def locking_mm(self) -> float | None:
        """The ideal yarn locking displacement (√2 − 1)(L − W) [mm] of the specimen (45° yarns), or None."""
        w, L = self.specimen.get("specimen.width_mm"), self.specimen.get("specimen.length_mm")
        if not (w and L) or self.specimen.get("specimen.yarn_angle_deg", 45.0) != 45.0:
            return None
        return (math.sqrt(2.0) - 1.0) * (L - w)

    def in_file_units(self, u_mm: np.ndarray, force_N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of crosshead travels and forces in the file's own quantities.

        Bias extension: unchanged. Picture frame: the frame's shear angle [deg] (Eqs. 1–2) and the
        shear force F_s [N] (Eq. 3) or the normalised shear force F_norm [N/mm] (Eq. 10), as the file holds.
        """
        if self.test != "picture_frame":
            return np.asarray(u_mm, float), np.asarray(force_N, float)
        from ..kinematics import frame_normalised_force, frame_shear_angle_rad, shear_force

        L, Lf = self.frame["picture_frame.frame_mm"], self.frame["picture_frame.fabric_mm"]
        fs = shear_force(force_N, u_mm, L)
        y = frame_normalised_force(fs, L, Lf) if self.quantity == "normalised_shear_force" else fs
        return np.degrees(frame_shear_angle_rad(u_mm, L)), y

    def window(self, fraction: tuple[float, float] = RANGE) -> tuple[float, float]:
        """The displacements [mm] between the fractions of the curve's displacement range."""
        lo, hi = float(self.u_mm.min()), float(self.u_mm.max())
        return lo + fraction[0] * (hi - lo), lo + fraction[1] * (hi - lo)

    def sample(self, n: int = POINTS_PER_CURVE, fraction: tuple[float, float] = RANGE) -> tuple[np.ndarray, np.ndarray]:
        """(u, F) at n equally spaced displacements over ``fraction`` of the range."""
        a, b = self.window(fraction)
        u = np.linspace(a, b, n)
        return u, np.interp(u, self.u_mm, self.force_N)

    def check_window(self, fraction: tuple[float, float], n: int = POINTS_PER_CURVE) -> str | None:
        """Refuse a fitted window that the measurement cannot carry; a note when it is thin.

        Refused (SceneError): fewer than 3 measured points in the window (the fitted points would
        be interpolated from one or two), or a window reaching the ideal yarn locking of the
        specimen. Returns a note when the window holds fewer measured points than the ``n`` the
        fit samples (the sampled points are then not independent measurements), else None.
        """
        a, b = self.window(fraction)
        raw = int(np.count_nonzero((self.u_mm >= a) & (self.u_mm <= b)))
        if raw < 3:
            raise SceneError(f"{self.source}: the fitted range {a:.4g} to {b:.4g} mm holds {raw} measured point(s); "
                             f"at least 3 are needed (the fit samples {n} points between them): widen --range")
        lock = self.locking_mm
        if lock is not None and b >= lock:
            raise SceneError(f"{self.source}: the fitted range reaches {b:.4g} mm, at or beyond the ideal yarn locking "
                             f"of the {self.label} specimen ({lock:.4g} mm): give --range FROM:TO with TO below "
                             f"{lock:.4g} mm, or check the specimen")
        if raw < n:
            return (f"{self.source}: the fitted range {a:.4g} to {b:.4g} mm holds {raw} measured points; the fit "
                    f"samples {n} points interpolated between them (not {n} independent measurements)")
        return None

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


@dataclass(frozen=True)
class CurveTable:
    """A measured curve as read, in file order, converted to mm, N, degrees and N/mm.

    ``x`` is the displacement [mm] or the shear angle [deg] (``x_quantity``), ``y`` the force or
    shear force [N] or the normalised shear force [N/mm] (``y_quantity``); ``lines`` the file
    line of each row; ``specimen`` the scene keys of the specimen, ``frame`` the picture frame's
    ``picture_frame.frame_mm`` and ``picture_frame.fabric_mm``; ``test`` one of :data:`TESTS` or
    "" when neither the file nor the caller names it.
    """

    source: str
    x_quantity: str
    y_quantity: str
    x: np.ndarray
    y: np.ndarray
    lines: np.ndarray
    specimen: dict[str, float]
    frame: dict[str, float]
    test: str
    notes: tuple[str, ...]


# --- text ---------------------------------------------------------------------------------------------------------

def _text(path: Path, what: str) -> tuple[str, list[str]]:
    if path.is_dir():
        raise SceneError(f"{what} file {path} is a directory")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise SceneError(f"{what} file {path} cannot be read: {exc.strerror or exc}") from None
    if b"\x00" in raw:
        raise SceneError(f"{what} file {path} is not a text file (holds NUL bytes)")
    notes = []
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        try:
            text = raw.decode("cp1252")
        except UnicodeDecodeError:
            raise SceneError(f"{what} file {path} is not a text file (neither UTF-8 nor Windows-1252)") from None
        notes.append("read as Windows-1252 text (not UTF-8)")
    return text, notes


def _number(text: str, path: Path | str, line: int, column: str, comma: bool) -> float:
    t = text.strip()
    if comma and _DECIMAL_COMMA.match(t):
        t = t.replace(",", ".")
    elif "," in t:
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is ambiguous (a thousands separator or a decimal "
                         "comma?): write numbers without thousands separators, with a decimal point, or with "
                         "decimal commas and semicolons between the columns")
    try:
        v = float(t)
    except ValueError:
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a number") from None
    if not math.isfinite(v):
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a finite number")
    return v


def _is_number(text: str) -> bool:
    try:
        float(text.strip().replace(",", ".", 1) if _DECIMAL_COMMA.match(text.strip()) else text)
    except ValueError:
        return False
    return True


def _unit_key(unit: str) -> str:
    u = unit.strip().lower().replace(" ", "").rstrip(".")
    return {"degrees": "deg", "degree": "deg", "°": "deg", "n/m": "n/m", "sec": "s"}.get(u, u)


# --- header ------------------------------------------------------------------------------------------------------

@dataclass
class _Column:
    index: int
    name: str
    quantity: str | None
    unit: str | None  # a key of UNITS, or the unknown unit as written


def _split_name(cell: str) -> tuple[str, str | None]:
    """(name, unit) of a header cell: ``Force (kN)``, ``Force [kN]``, ``force_kN``, ``force``."""
    c = cell.strip().strip("\"'").strip()
    m = _UNIT_IN_BRACKETS.match(c)
    if m and m.group(2):
        return m.group(1), m.group(2)
    low = c.lower()
    for u in sorted(UNITS, key=len, reverse=True):
        if low.endswith("_" + u) and len(low) > len(u) + 1:
            return c[:-len(u) - 1], u
    return c, None


def _quantity(name: str) -> str | None:
    words = " " + re.sub(r"[_\-.]+", " ", name.lower()).strip() + " "
    for q, (names, _) in QUANTITIES.items():
        if any(f" {n} " in words for n in names):
            return q
    return None


def _header(cells: list[str]) -> list[_Column]:
    cols = []
    for j, cell in enumerate(cells):
        name, unit = _split_name(cell)
        cols.append(_Column(j, cell.strip(), _quantity(name), _unit_key(unit) if unit else None))
    return cols


def _units_row(cells: list[str]) -> bool:
    return bool(cells) and all(not c.strip() or _unit_key(c.strip("()[] ")) in UNITS for c in cells) and any(
        c.strip() for c in cells)


def _parse_columns(spec: str | Sequence[str]) -> list[tuple[str, str | None]]:
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    if len(items) != 2 or not all(items):
        raise SceneError(f"--columns {spec!r}: give two columns, the displacement (or shear angle) and the force, "
                         "by header name or number, each with an optional unit: --columns 'Weg:mm,Kraft:kN'")
    out: list[tuple[str, str | None]] = []
    for s in items:
        name, sep, unit = s.rpartition(":")
        out.append((name.strip(), _unit_key(unit)) if sep and _unit_key(unit) in UNITS else (s, None))
    return out


def _pick(cols: list[_Column], spec: tuple[str, str | None], path: Path, line: int) -> _Column:
    name, unit = spec
    if name.isdigit():
        j = int(name) - 1
        if not 0 <= j < len(cols):
            raise SceneError(f"--columns: column {name} does not exist; the header (line {line} of {path}) has "
                             f"{len(cols)}")
        col = cols[j]
    else:
        hits = [c for c in cols if c.name.strip("\"' ").lower() == name.lower()]
        if not hits:
            raise SceneError(f"--columns: {path} has no column {name!r}; its header (line {line}) names "
                             f"{', '.join(repr(c.name) for c in cols)}")
        col = hits[0]
    picked = _Column(col.index, col.name, col.quantity, unit or col.unit)
    if unit:
        kind = UNITS[unit][0]
        if picked.quantity is None or QUANTITIES[picked.quantity][1] != kind:
            picked.quantity = {"length": "displacement", "angle": "shear_angle", "force": "force",
                               "force/length": "normalised_shear_force"}.get(kind)
    return picked


def _choose(cols: list[_Column], columns: str | Sequence[str] | None, path: Path, line: int
            ) -> tuple[_Column, _Column]:
    """The x and y columns: by ``columns``, else by their names (one of each, or refused)."""
    if columns:
        x, y = (_pick(cols, s, path, line) for s in _parse_columns(columns))
        if x.quantity is None and x.unit in UNITS:
            x.quantity = "displacement" if UNITS[x.unit][0] == "length" else "shear_angle"
        if y.quantity is None and y.unit in UNITS:
            y.quantity = "force" if UNITS[y.unit][0] == "force" else "normalised_shear_force"
        for c, role, allowed in ((x, "first", X_QUANTITIES), (y, "second", Y_QUANTITIES)):
            if c.quantity not in allowed:
                raise SceneError(f"--columns: the {role} column {c.name!r} of {path} must be a "
                                 f"{' or '.join(WORDS[q] for q in allowed)} with its unit, "
                                 f"e.g. --columns '{c.name}:{'mm' if role == 'first' else 'N'}'")
        return x, y
    names = ", ".join(repr(c.name) for c in cols)
    xs = [c for c in cols if c.quantity in X_QUANTITIES]
    ys = [c for c in cols if c.quantity in Y_QUANTITIES]
    if not xs or not ys:
        lack = " and ".join(w for w, cs in (("a displacement", xs), ("a force", ys)) if not cs)
        raise SceneError(f"{path}, line {line}: the header names the columns {names}, none of which is {lack} "
                         "this reader knows; name them with their units (displacement_mm,force_N or "
                         "'Displacement (mm);Force (N)') or choose them with --columns NAME:UNIT,NAME:UNIT")
    for cs, what in ((xs, "displacement (or shear angle)"), (ys, "force")):
        if len(cs) > 1:
            raise SceneError(f"{path}, line {line}: {len(cs)} columns could be the {what}: "
                             f"{', '.join(repr(c.name) for c in cs)}; choose with --columns, e.g. "
                             f"--columns '{xs[0].name},{ys[0].name}'")
    return xs[0], ys[0]


def _check_unit(c: _Column, path: Path, line: int) -> float:
    """The factor to the canonical unit of the column's quantity; refused without a unit it knows."""
    assert c.quantity is not None
    kind = QUANTITIES[c.quantity][1]
    known = ", ".join(k for k, (kk, _) in UNITS.items() if kk == kind and "_" not in k)
    example = {"length": "displacement_mm", "force": "force_N", "angle": "shear_angle_deg",
               "force/length": "normalised_shear_force_N_per_mm"}[kind]
    if c.unit is None:
        raise SceneError(f"{path}, line {line}: the column {c.name!r} ({WORDS[c.quantity]}) gives no unit: write it "
                         f"into the header ({example} or '{WORDS[c.quantity].capitalize()} "
                         f"({CANONICAL[kind]})'; units {known}) or with --columns '{c.name}:{CANONICAL[kind]},...'")
    if c.unit not in UNITS or UNITS[c.unit][0] != kind:
        raise SceneError(f"{path}, line {line}: the column {c.name!r} ({WORDS[c.quantity]}) is in {c.unit!r}, "
                         f"not a unit of a {WORDS[c.quantity]} this reader knows ({known})")
    return UNITS[c.unit][1]


# --- comment lines ------------------------------------------------------------------------------------------------

def _key_value(key: str, value: str, path: Path, line: int) -> tuple[str, float, str | None]:
    """(scene key, value in mm or deg, a note on a converted unit) of a ``# key = value [unit]`` line."""
    bare = key.split(".", 1)[1] if "." in key else key
    section = "picture_frame" if key.startswith("picture_frame.") else "specimen"
    table = _FRAME_KEYS if section == "picture_frame" else _SPECIMEN_KEYS
    stem, _, suffix = bare.rpartition("_")
    if suffix not in ("mm", "deg"):
        stem, suffix = bare, ""
    if stem not in table:
        raise SceneError(f"{path}, line {line}: unknown key {key!r}; the {section} keys are "
                         f"{', '.join(table.values())}")
    full = table[stem]
    m = _VALUE.match(value)
    if not m:
        raise SceneError(f"{path}, line {line}: {key} = {value!r} is not a number (with an optional unit: = 100 mm)")
    v = _number(m.group(1), path, line, key, False)
    unit = _unit_key(m.group(2)) if m.group(2) else (suffix or None)
    want = "angle" if full.endswith("_deg") else "length"
    if unit is None:
        raise SceneError(f"{path}, line {line}: {key} = {value!r} gives no unit: write {full} = {value} "
                         f"{'deg' if want == 'angle' else 'mm'}")
    if unit not in UNITS or UNITS[unit][0] != want:
        raise SceneError(f"{path}, line {line}: {key} = {value!r}: {m.group(2) or suffix!r} is not a unit of "
                         f"{'an angle' if want == 'angle' else 'a length'}")
    note = None
    if UNITS[unit][1] != 1.0:
        v *= UNITS[unit][1]
        note = f"{key} = {value} read as {full} = {v:g}"
    return full, v, note


def _test_name(text: str, where: str) -> str:
    t = re.sub(r"[\s\-]+", "_", text.strip().lower())
    t = {"bet": "bias_extension", "bias_extension_test": "bias_extension", "pf": "picture_frame",
         "picture_frame_test": "picture_frame"}.get(t, t)
    if t not in TESTS:
        raise SceneError(f"{where}: unknown test {text.strip()!r}; write bias_extension or picture_frame")
    return t


class _Header:
    """What the comment lines say: specimen and frame keys, the test."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.keys: dict[str, float] = {}
        self.where: dict[str, int] = {}
        self.test = ""
        self.notes: list[str] = []

    def _set(self, key: str, v: float, line: int) -> None:
        if key in self.keys and self.keys[key] != v:
            raise SceneError(f"{self.path}, line {line}: {key} = {v:g}, but line {self.where[key]} says "
                             f"{self.keys[key]:g}: give it once")
        self.keys[key], self.where[key] = v, line

    def comment(self, text: str, line: int) -> None:
        m = _KEY_LINE.match(text)
        if m:
            key, v, note = _key_value(m.group(1), m.group(2), self.path, line)
            self._set(key, v, line)
            if note:
                self.notes.append(note)
            return
        t = _TEST_LINE.match(text)
        if t:
            name = _test_name(t.group(1), f"{self.path}, line {line}")
            if self.test and self.test != name:
                raise SceneError(f"{self.path}, line {line}: test {name}, but an earlier line says {self.test}")
            self.test = name
        f = _TABLE3.search(text)
        if f:
            self._set("picture_frame.frame_mm", float(f.group(1)), line)
            self._set("picture_frame.fabric_mm", float(f.group(2)), line)


# --- the table ------------------------------------------------------------------------------------------------------

def parse_sizes(text: str, what: str, names: Sequence[str]) -> dict[str, float]:
    """``"100x250"`` (or ``100 x 250 x 3.3``, ``100×250``, mm) as the scene keys ``names``, each > 0.

    At least two values; the third of ``names`` is optional.
    """
    parts = [p.strip() for p in re.split(r"[x×X*]", text.strip().removesuffix("mm"))]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if not 2 <= len(vals) <= len(names) or not all(math.isfinite(v) for v in vals):
        example = "x".join(("100", "250", "3.3")[:len(names)])
        raise SceneError(f"{what} {text!r}: write sizes in mm joined by x, e.g. {what} {example} "
                         f"({' x '.join(n.split('.')[-1].removesuffix('_mm') for n in names)})")
    bad = [f"{n.split('.')[-1].removesuffix('_mm')} {v:g}" for n, v in zip(names, vals, strict=False) if not v > 0]
    if bad:
        raise SceneError(f"{what} {text!r}: {', '.join(bad)}: sizes must be > 0 mm")
    return dict(zip(names, vals, strict=False))


def _merge(path: Path, header: dict[str, float], given: dict[str, float] | None, what: str, flag: str
           ) -> tuple[dict[str, float], list[str]]:
    out, notes = dict(header), []
    for k, v in (given or {}).items():
        if k in header and not math.isclose(header[k], v, rel_tol=1e-9):
            raise SceneError(f"{path}: its header says {k} = {header[k]:g}, {flag} says {v:g}: drop one")
        if k not in header:
            out[k] = v
            notes.append(f"{k} = {v:g} from {flag}")
    return out, notes


def _specimen(path: Path, keys: dict[str, float], given: dict[str, float] | None) -> tuple[dict[str, float], list[str]]:
    header = {k: v for k, v in keys.items() if k.startswith("specimen.")}
    spec, notes = _merge(path, header, given, "specimen", "--specimen")
    for k in ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"):
        if k in spec and not spec[k] > 0:
            raise SceneError(f"{path}: {k} = {spec[k]:g} must be > 0")
    has = [k for k in ("specimen.width_mm", "specimen.length_mm") if k in spec]
    if spec and len(has) < 2:
        lack = ({"specimen.width_mm", "specimen.length_mm"} - set(has)).pop()
        raise SceneError(f"{path}: an incomplete specimen: {', '.join(sorted(spec))} but no {lack}; add "
                         f"'# {lack} = ...' to the header or give --specimen WIDTHxLENGTH (mm)")
    if len(has) == 2 and not spec["specimen.length_mm"] > spec["specimen.width_mm"]:
        raise SceneError(f"{path}: specimen {spec['specimen.width_mm']:g} x {spec['specimen.length_mm']:g} mm: the "
                         "clamp-to-clamp length must exceed the width (--specimen and the header give width x length)")
    return spec, notes


def _frame(path: Path, keys: dict[str, float], given: dict[str, float] | None) -> tuple[dict[str, float], list[str]]:
    header = {k: v for k, v in keys.items() if k.startswith("picture_frame.")}
    frame, notes = _merge(path, header, given, "picture_frame", "--frame")
    for k, v in frame.items():
        if not v > 0:
            raise SceneError(f"{path}: {k} = {v:g} must be > 0")
    return frame, notes


def _rows(text: str, path: Path, header: _Header) -> tuple[list[str], int, list[tuple[int, list[str]]], str]:
    """The header cells and line, the data rows (line, cells) and the column separator."""
    head: list[str] | None = None
    head_line, sep = 0, ","
    rows: list[tuple[int, list[str]]] = []
    for k, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if head is None:
                header.comment(line, k)
            continue
        if head is None:
            sep = ";" if ";" in line else "\t" if "\t" in line else ","
            head = next(csv.reader([line], delimiter=sep))
            if all(_is_number(c) for c in head if c.strip()):
                raise SceneError(f"{path}, line {k}: a row of numbers where the header should be: the first line "
                                 "that is not a # comment must name the columns (displacement_mm,force_N)")
            head_line = k
            continue
        rows.append((k, next(csv.reader([line], delimiter=sep))))
    if head is None:
        raise SceneError(f"data file {path}: no header line and no data")
    return head, head_line, rows, sep


def read_table(path: str | Path, *, test: str | None = None, columns: str | Sequence[str] | None = None,
               specimen: dict[str, float] | None = None, frame: dict[str, float] | None = None) -> CurveTable:
    """Read a measured curve as laboratories write it (module docstring): the one reader of measured curves.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    test : str, optional
        "bias_extension" or "picture_frame" (``--test``); refused where the file's header names the other.
    columns : str or sequence of str, optional
        ``--columns``: the x and y columns by header name or 1-based number, ``NAME[:UNIT]``.
    specimen, frame : dict, optional
        Scene keys from the command line (``--specimen``, ``--frame``); refused where the header differs.

    Returns
    -------
    CurveTable
        The rows in file order up to the largest x (the unloading branch of a cycle left out), converted.
    """
    path = Path(path)
    text, notes = _text(path, "data")
    header = _Header(path)
    head, head_line, rows, sep = _rows(text, path, header)
    cols = _header(head)
    if rows and _units_row(rows[0][1]):  # a row of units under the names (testing machines write one)
        for c, u in zip(cols, rows[0][1], strict=False):
            if u.strip() and c.unit is None:
                c.unit = _unit_key(u.strip("()[] "))
        rows = rows[1:]
    x, y = _choose(cols, columns, path, head_line)
    fx, fy = _check_unit(x, path, head_line), _check_unit(y, path, head_line)
    comma = sep != ","
    data, lines = [], []
    for k, cells in rows:
        if len(cells) <= max(x.index, y.index):
            hint = " (decimal commas need semicolons or tabs between the columns)" if not comma and "," in "".join(
                cells) else ""
            raise SceneError(f"{path}, line {k}: {len(cells)} cells, the header (line {head_line}) has {len(head)}"
                             + hint)
        data.append((_number(cells[x.index], path, k, x.name, comma),
                     _number(cells[y.index], path, k, y.name, comma)))
        lines.append(k)
    arr = np.array(data, dtype=float).reshape(-1, 2)
    xs, ys, ls = fx * arr[:, 0], fy * arr[:, 1], np.array(lines, dtype=int)
    if sep != ",":
        notes.append(f"columns separated by {'semicolons' if sep == ';' else 'tabs'}"
                     + (", decimal commas" if any("," in c for _, r in rows for c in r) else ""))
    notes += [f"column {c.name!r} read as the {WORDS[c.quantity or '']} in {PRETTY.get(c.unit, c.unit)}, converted to "
              f"{CANONICAL[UNITS[c.unit][0]]} (x {f:g})" for c, f in ((x, fx), (y, fy))
              if c.unit is not None and f != 1.0]
    ignored = [c.name for c in cols if c.index not in (x.index, y.index)]
    if ignored or columns:
        notes.append(f"columns: {x.name!r} as the {WORDS[x.quantity or '']}, {y.name!r} as the "
                     f"{WORDS[y.quantity or '']}" + (f"; ignored: {', '.join(map(repr, ignored))}" if ignored else ""))
    beyond = _clipped(cols, rows)
    if beyond.any():
        notes.append(f"{int(beyond.sum())} point(s) marked on_frame_edge top or right left out (the chart "
                     "clipped them: their true value lies beyond its axis)")
        xs, ys, ls = xs[~beyond], ys[~beyond], ls[~beyond]
    xs, ys, ls, cut = _loading_branch(xs, ys, ls, path, x.quantity or "")
    if cut:
        notes.append(cut)
    ftest = header.test
    if test is not None:
        given = _test_name(test, "--test")
        if ftest and ftest != given:
            raise SceneError(f"{path}: its header says test {ftest}, --test says {given}: drop one")
        ftest = given
    spec, n1 = _specimen(path, header.keys, specimen)
    frm, n2 = _frame(path, header.keys, frame)
    return CurveTable(str(path), x.quantity or "", y.quantity or "", xs, ys, ls, spec, frm, ftest,
                      tuple(notes + header.notes + n1 + n2))


def _clipped(cols: list[_Column], rows: list[tuple[int, list[str]]]) -> np.ndarray:
    """Rows an ``on_frame_edge`` column marks "top" or "right": a printed chart clipped them there."""
    clip = next((c for c in cols if c.name.lower() == "on_frame_edge"), None)
    if clip is None:
        return np.zeros(len(rows), dtype=bool)
    return np.array([len(cells) > clip.index and bool({"top", "right"} & set(cells[clip.index].strip().lower()
                                                                          .split("+"))) for _, cells in rows],
                    dtype=bool)


def _loading_branch(x: np.ndarray, y: np.ndarray, lines: np.ndarray, path: Path, quantity: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The rows up to the largest x when the rows after it fall back (an unloading); several cycles refused."""
    if len(x) < 2:
        return x, y, lines, ""
    i = int(np.argmax(x))
    tol = CYCLE_TOLERANCE * float(x.max() - x.min())
    unit = "°" if quantity == "shear_angle" else " mm"
    fall = np.maximum.accumulate(x[:i + 1]) - x[:i + 1]
    if fall.max() > tol:
        j = int(np.argmax(fall > tol))
        raise SceneError(f"{path}, line {int(lines[j])}: the {WORDS.get(quantity, quantity)} falls back to "
                         f"{x[j]:g}{unit} before its largest value ({x[i]:g}{unit}, line {int(lines[i])}): several "
                         "load cycles; keep one loading branch in the file")
    if i < len(x) - 1 and float(x[i] - x[i + 1:].min()) > tol:
        what = WORDS.get(quantity, quantity)
        note = (f"a loading-unloading cycle: kept the loading branch up to the largest {what}, "
                f"{x[i]:g}{unit} (line {int(lines[i])}); the {len(x) - 1 - i} rows after it are left out")
        return x[:i + 1], y[:i + 1], lines[:i + 1], note
    return x, y, lines, ""


# --- bias extension curves -----------------------------------------------------------------------------------------

def errorbar_path(path: str | Path) -> Path:
    """``NAME_errorbars.csv`` beside ``NAME.csv``."""
    p = Path(path)
    return p.with_name(p.stem + "_errorbars" + p.suffix)


def _errorbars(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    ep = errorbar_path(path)
    if not ep.exists():
        return None
    text, _ = _text(ep, "error bar")
    head, head_line, rows, sep = _rows(text, ep, _Header(ep))
    names = [h.strip().strip("\"'") for h in head]
    need = ("displacement_mm", "force_low_N", "force_high_N")
    missing = [n for n in need if n not in names]
    if missing:
        raise SceneError(f"{ep}, line {head_line}: the header lacks the column(s) {', '.join(missing)}")
    idx = [names.index(n) for n in need]
    vals, lines = [], []
    for k, cells in rows:
        if len(cells) <= max(idx):
            raise SceneError(f"{ep}, line {k}: {len(cells)} cells, the header (line {head_line}) has {len(head)}")
        vals.append([math.nan if cells[j].strip() == "" and n != "displacement_mm"
                     else _number(cells[j], ep, k, n, sep != ",") for j, n in zip(idx, need, strict=True)])
        lines.append(k)
    e = np.array(vals, dtype=float).reshape(-1, 3)
    ok = np.isfinite(e[:, 1]) & np.isfinite(e[:, 2])
    if ok.sum() < 2:
        return None
    bu, bl, bh = e[ok, 0], e[ok, 1], e[ok, 2]
    wrong = bh < bl
    if wrong.any():
        j = int(np.argmax(wrong))
        raise SceneError(f"{ep}, line {np.array(lines)[ok][j]}: force_high_N {bh[j]:g} is below force_low_N {bl[j]:g}")
    o = np.argsort(bu)
    return bu[o], bl[o], bh[o]


def read_measured(path: str | Path, fraction: tuple[float, float] = RANGE, *,
                  columns: str | Sequence[str] | None = None,
                  specimen: dict[str, float] | None = None) -> MeasuredCurve:
    """Read and check a bias extension curve (module docstring); its error bars too when the file is there.

    Refused besides what :func:`read_table` refuses: a picture-frame file, fewer than three
    rows or distinct displacements, no positive displacement, a force or displacement that is
    not positive in the fitted range ``fraction``.
    """
    path = Path(path)
    t = read_table(path, test=None, columns=columns, specimen=specimen)
    if t.test == "picture_frame" or t.x_quantity != "displacement" or t.y_quantity != "force":
        what = ("a picture-frame curve (its header says test: picture-frame)" if t.test == "picture_frame"
                else f"a curve of the {WORDS[t.y_quantity]} against the {WORDS[t.x_quantity]}")
        raise SceneError(f"{path}: {what}; this command takes a bias extension test's clamp displacement and force "
                         "(ngbet normalise --test picture_frame reads picture-frame curves)")
    u, F, lines = t.x, t.y, t.lines
    if len(u) < 3:
        raise SceneError(f"data file {path}: {len(u)} rows of numbers; at least 3 are needed")
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
    return MeasuredCurve(uu, FF, str(path), t.specimen, _errorbars(path), t.notes, "bias_extension")


def frame_travel_mm(gamma_deg: np.ndarray, frame_mm: float) -> np.ndarray:
    """The crosshead travel d [mm] at which the frame's shear angle is γ: Eqs. 1–2 inverted.

    γ = π/2 − 2θ and cos θ = (√2 L + d)/(2 L), so d = 2 L cos((π/2 − γ)/2) − √2 L.
    """
    theta = 0.5 * (np.pi / 2 - np.radians(np.asarray(gamma_deg, float)))
    return 2.0 * frame_mm * np.cos(theta) - math.sqrt(2.0) * frame_mm


def read_frame_curve(path: str | Path, *, columns: str | Sequence[str] | None = None,
                     frame: dict[str, float] | None = None) -> MeasuredCurve:
    """Read a picture-frame curve for the fit: as a crosshead travel [mm] and crosshead force [N].

    The file holds the shear force F_s [N] or the normalised shear force F_norm [N/mm] against the
    frame's shear angle [deg] (its header names the test and the frame). Each point is converted
    exactly: d from γ (:func:`frame_travel_mm`), F = 2 cos θ F_s (Eq. 3) with F_s = F_norm L_fabric²/L_frame
    (Eq. 10). A residual (model − measured)/sd is the same in either quantity, as the conversion is
    linear at each point. :meth:`MeasuredCurve.in_file_units` converts back. Refused: a file without
    frame sizes, a curve of the displacement or of the crosshead force, fewer than 3 distinct angles.
    """
    path = Path(path)
    t = read_table(path, test="picture_frame", columns=columns, frame=frame)
    if t.x_quantity != "shear_angle" or t.y_quantity not in ("shear_force", "normalised_shear_force"):
        raise SceneError(f"{path}: a picture-frame curve of the {WORDS[t.y_quantity]} against the "
                         f"{WORDS[t.x_quantity]}; ngbet fit takes the shear force [N] or the normalised shear "
                         "force [N/mm] against the frame's shear angle [deg]")
    lack = [k for k in _FRAME_KEYS.values() if k not in t.frame]
    if lack:
        raise SceneError(f"{path}: the picture frame's {' and '.join(lack)} are not in its header "
                         "(# picture_frame.frame_mm = 145, # picture_frame.fabric_mm = 120)")
    L, Lf = t.frame["picture_frame.frame_mm"], t.frame["picture_frame.fabric_mm"]
    g, y = t.x, t.y
    keep = (g > 0) & (g < 90)
    g, y = g[keep], y[keep]
    gg, inv = np.unique(g, return_inverse=True)
    yy = np.bincount(inv, weights=y) / np.bincount(inv)
    if len(gg) < 3:
        raise SceneError(f"data file {path}: fewer than 3 distinct shear angles between 0 and 90 deg")
    from ..kinematics import frame_angle_rad

    d = frame_travel_mm(gg, L)
    fs = yy * Lf ** 2 / L if t.y_quantity == "normalised_shear_force" else yy
    F = 2.0 * np.cos(frame_angle_rad(d, L)) * fs
    note = (f"picture frame {L:g}/{Lf:g} mm: its {WORDS[t.y_quantity]} against the shear angle fitted as the "
            "crosshead force against the travel (Eqs. 1-3, 10; exact at each point)")
    return MeasuredCurve(d, F, str(path), {}, None, (*t.notes, note), "picture_frame", dict(t.frame), t.y_quantity)


def read_any(path: str | Path, fraction: tuple[float, float] = RANGE, *, columns: str | Sequence[str] | None = None,
             specimen: dict[str, float] | None = None) -> MeasuredCurve:
    """A bias-extension curve (:func:`read_measured`), or a picture-frame curve (:func:`read_frame_curve`).

    The file's header (``# test: picture-frame``) decides.
    """
    if read_table(path, columns=columns).test == "picture_frame":
        if specimen:
            raise SceneError(f"{path}: a picture-frame curve (its header says so); --specimen does not apply to it")
        return read_frame_curve(path, columns=columns)
    return read_measured(path, fraction, columns=columns, specimen=specimen)


def read_all(paths: Sequence[str | Path], fraction: tuple[float, float] = RANGE, *,
             columns: str | Sequence[str] | None = None,
             specimens: Sequence[dict[str, float]] | None = None) -> list[MeasuredCurve]:
    """:func:`read_any` for several files; the same file (or the same numbers) given twice is refused.

    ``specimens``: one ``--specimen`` for every file, or one per file in order.
    """
    specs = _per_file(paths, specimens, "--specimen")
    curves = [read_any(p, fraction, columns=columns, specimen=s) for p, s in zip(paths, specs, strict=True)]
    refuse_duplicates(curves)
    return curves


def _per_file(paths: Sequence[str | Path], given: Sequence[dict[str, float]] | None, flag: str
              ) -> list[dict[str, float] | None]:
    if not given:
        return [None] * len(paths)
    if len(given) == 1:
        return [given[0]] * len(paths)
    if len(given) != len(paths):
        raise SceneError(f"{len(given)} {flag} for {len(paths)} data files: give one for all, or one per file in order")
    return list(given)


def refuse_duplicates(curves: Sequence[MeasuredCurve | CurveTable]) -> None:
    """Refuse a file given twice, or two files with the same numbers (each would count twice)."""
    seen: dict[object, str] = {}
    for c in curves:
        x = c.u_mm if isinstance(c, MeasuredCurve) else c.x
        y = c.force_N if isinstance(c, MeasuredCurve) else c.y
        for key in (Path(c.source).resolve(), (x.tobytes(), y.tobytes())):
            if key in seen:
                raise SceneError(f"{c.source} and {seen[key]}: the same "
                                 f"{'file' if isinstance(key, Path) else 'measured curve'} twice; give each curve "
                                 "once (a curve given twice counts twice and makes the uncertainties too small)")
            seen[key] = c.source
