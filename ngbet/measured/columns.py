"""The columns of a measured curve's table: which quantity each is, in which unit, which two are read.

A column is known by its name (``displacement``, ``extension``, ``force``, ``load``, the picture
frame's shear angle and shear forces) and its unit, written in the name (``force_kN``, ``Force (kN)``,
``Force [kN]``) or in a row of units under the header; ``columns`` (``--columns``) chooses two by name
or 1-based number. Read by :func:`ngbet.measured.table.read_table`; a refusal is a
:class:`ngbet.scene.validate.SceneError` naming the file and the line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..scene.validate import SceneError

__all__ = [
    "CANONICAL",
    "PRETTY",
    "QUANTITIES",
    "UNITS",
    "WORDS",
    "X_QUANTITIES",
    "Y_QUANTITIES",
    "Column",
    "check_unit",
    "choose_columns",
    "header_columns",
    "is_units_row",
    "parse_columns",
    "pick_column",
    "quantity_of",
    "split_name",
    "unit_key",
]


#: units → (kind, factor to the canonical unit: mm, N, deg, N/mm, s)
UNITS: dict[str, tuple[str, float]] = {
    "mm": ("length", 1.0),
    "cm": ("length", 10.0),
    "m": ("length", 1000.0),
    "n": ("force", 1.0),
    "kn": ("force", 1000.0),
    "deg": ("angle", 1.0),
    "°": ("angle", 1.0),
    "degree": ("angle", 1.0),
    "degrees": ("angle", 1.0),
    "rad": ("angle", 180.0 / math.pi),
    "n/mm": ("force/length", 1.0),
    "n/m": ("force/length", 1e-3),
    "kn/m": ("force/length", 1.0),
    "n_per_mm": ("force/length", 1.0),
    "n_per_m": ("force/length", 1e-3),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "min": ("time", 60.0),
    "h": ("time", 3600.0),
}
#: how a unit is written in messages
PRETTY = {"n": "N", "kn": "kN", "n/mm": "N/mm", "n/m": "N/m", "kn/m": "kN/m", "n_per_mm": "N/mm", "n_per_m": "N/m"}
CANONICAL = {"length": "mm", "force": "N", "angle": "deg", "force/length": "N/mm", "time": "s"}
#: quantities: their words in a header (the more specific first) and the unit kind they take
QUANTITIES: dict[str, tuple[tuple[str, ...], str]] = {
    "normalised_shear_force": (
        ("normalised shear force", "normalized shear force", "fsh", "f sh", "fnorm", "f norm", "fnormalized"),
        "force/length",
    ),
    "shear_force": (("shear force", "fs"), "force"),
    "shear_angle": (("shear angle", "gamma", "angle"), "angle"),
    "force": (("standard force", "force", "load", "kraft"), "force"),
    "displacement": (
        (
            "displacement",
            "extension",
            "elongation",
            "crosshead",
            "stroke",
            "travel",
            "position",
            "deflection",
            "deformation",
            "weg",
        ),
        "length",
    ),
    "time": (("time", "zeit"), "time"),
}
X_QUANTITIES = ("displacement", "shear_angle")
Y_QUANTITIES = ("force", "shear_force", "normalised_shear_force")
WORDS = {
    "displacement": "displacement",
    "shear_angle": "shear angle",
    "force": "force",
    "shear_force": "shear force",
    "normalised_shear_force": "normalised shear force",
    "time": "time",
}


_UNIT_IN_BRACKETS = re.compile(r"^(.*?)\s*[(\[]\s*([^)\]]*?)\s*[)\]]\s*$")


def unit_key(unit: str) -> str:
    """The key of :data:`UNITS` for a unit as written (case, spaces and a final dot ignored; ° as deg)."""
    u = unit.strip().lower().replace(" ", "").rstrip(".")
    return {"degrees": "deg", "degree": "deg", "°": "deg", "n/m": "n/m", "sec": "s"}.get(u, u)


# --- header ------------------------------------------------------------------------------------------------------


@dataclass
class Column:
    """A column of the header, as far as its name tells.

    Its 0-based index, the name as written, its quantity (a key of :data:`QUANTITIES`, or None) and
    its unit (a key of :data:`UNITS`, the unknown unit as written, or None).
    """

    index: int
    name: str
    quantity: str | None
    unit: str | None  # a key of UNITS, or the unknown unit as written


def split_name(cell: str) -> tuple[str, str | None]:
    """(name, unit) of a header cell: ``Force (kN)``, ``Force [kN]``, ``force_kN``, ``force``."""
    c = cell.strip().strip("\"'").strip()
    m = _UNIT_IN_BRACKETS.match(c)
    if m and m.group(2):
        return m.group(1), m.group(2)
    low = c.lower()
    for u in sorted(UNITS, key=len, reverse=True):
        if low.endswith("_" + u) and len(low) > len(u) + 1:
            return c[: -len(u) - 1], u
    return c, None


def quantity_of(name: str) -> str | None:
    """The quantity (a key of :data:`QUANTITIES`) whose words the column name holds, or None."""
    words = " " + re.sub(r"[_\-.]+", " ", name.lower()).strip() + " "
    for q, (names, _) in QUANTITIES.items():
        if any(f" {n} " in words for n in names):
            return q
    return None


def header_columns(cells: list[str]) -> list[Column]:
    """The columns of a header line, each with its quantity and unit as far as the name tells them."""
    cols = []
    for j, cell in enumerate(cells):
        name, unit = split_name(cell)
        cols.append(Column(j, cell.strip(), quantity_of(name), unit_key(unit) if unit else None))
    return cols


def is_units_row(cells: list[str]) -> bool:
    """True when a line under the header holds units only (``mm, kN``, ``(mm), [N]``), some cells empty."""
    return (
        bool(cells)
        and all(not c.strip() or unit_key(c.strip("()[] ")) in UNITS for c in cells)
        and any(c.strip() for c in cells)
    )


def parse_columns(spec: str | Sequence[str]) -> list[tuple[str, str | None]]:
    """``--columns``: two (name or 1-based number, unit key or None); anything else refused (SceneError)."""
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    if len(items) != 2 or not all(items):
        raise SceneError(
            f"--columns {spec!r}: give two columns, the displacement (or shear angle) and the force, "
            "by header name or number, each with an optional unit: --columns 'Weg:mm,Kraft:kN'"
        )
    out: list[tuple[str, str | None]] = []
    for s in items:
        name, sep, unit = s.rpartition(":")
        out.append((name.strip(), unit_key(unit)) if sep and unit_key(unit) in UNITS else (s, None))
    return out


def pick_column(cols: list[Column], spec: tuple[str, str | None], path: Path, line: int) -> Column:
    """The column ``spec`` (from :func:`parse_columns`) names, with its given unit; a missing one refused."""
    name, unit = spec
    if name.isdigit():
        j = int(name) - 1
        if not 0 <= j < len(cols):
            raise SceneError(
                f"--columns: column {name} does not exist; the header (line {line} of {path}) has {len(cols)}"
            )
        col = cols[j]
    else:
        hits = [c for c in cols if c.name.strip("\"' ").lower() == name.lower()]
        if not hits:
            raise SceneError(
                f"--columns: {path} has no column {name!r}; its header (line {line}) names "
                f"{', '.join(repr(c.name) for c in cols)}"
            )
        col = hits[0]
    picked = Column(col.index, col.name, col.quantity, unit or col.unit)
    if unit:
        kind = UNITS[unit][0]
        if picked.quantity is None or QUANTITIES[picked.quantity][1] != kind:
            picked.quantity = {
                "length": "displacement",
                "angle": "shear_angle",
                "force": "force",
                "force/length": "normalised_shear_force",
            }.get(kind)
    return picked


def choose_columns(
    cols: list[Column], columns: str | Sequence[str] | None, path: Path, line: int
) -> tuple[Column, Column]:
    """The x and y columns: by ``columns``, else by their names (one of each, or refused)."""
    if columns:
        x, y = (pick_column(cols, s, path, line) for s in parse_columns(columns))
        if x.quantity is None and x.unit in UNITS:
            x.quantity = "displacement" if UNITS[x.unit][0] == "length" else "shear_angle"
        if y.quantity is None and y.unit in UNITS:
            y.quantity = "force" if UNITS[y.unit][0] == "force" else "normalised_shear_force"
        for c, role, allowed in ((x, "first", X_QUANTITIES), (y, "second", Y_QUANTITIES)):
            if c.quantity not in allowed:
                raise SceneError(
                    f"--columns: the {role} column {c.name!r} of {path} must be a "
                    f"{' or '.join(WORDS[q] for q in allowed)} with its unit, "
                    f"e.g. --columns '{c.name}:{'mm' if role == 'first' else 'N'}'"
                )
        return x, y
    names = ", ".join(repr(c.name) for c in cols)
    xs = [c for c in cols if c.quantity in X_QUANTITIES]
    ys = [c for c in cols if c.quantity in Y_QUANTITIES]
    if not xs or not ys:
        lack = " and ".join(w for w, cs in (("a displacement", xs), ("a force", ys)) if not cs)
        raise SceneError(
            f"{path}, line {line}: the header names the columns {names}, none of which is {lack} "
            "this reader knows; name them with their units (displacement_mm,force_N or "
            "'Displacement (mm);Force (N)') or choose them with --columns NAME:UNIT,NAME:UNIT"
        )
    for cs, what in ((xs, "displacement (or shear angle)"), (ys, "force")):
        if len(cs) > 1:
            raise SceneError(
                f"{path}, line {line}: {len(cs)} columns could be the {what}: "
                f"{', '.join(repr(c.name) for c in cs)}; choose with --columns, e.g. "
                f"--columns '{xs[0].name},{ys[0].name}'"
            )
    return xs[0], ys[0]


def check_unit(c: Column, path: Path, line: int) -> float:
    """The factor to the canonical unit of the column's quantity; refused without a unit it knows."""
    assert c.quantity is not None
    kind = QUANTITIES[c.quantity][1]
    known = ", ".join(k for k, (kk, _) in UNITS.items() if kk == kind and "_" not in k)
    example = {
        "length": "displacement_mm",
        "force": "force_N",
        "angle": "shear_angle_deg",
        "force/length": "normalised_shear_force_N_per_mm",
    }[kind]
    if c.unit is None:
        raise SceneError(
            f"{path}, line {line}: the column {c.name!r} ({WORDS[c.quantity]}) gives no unit: write it "
            f"into the header ({example} or '{WORDS[c.quantity].capitalize()} "
            f"({CANONICAL[kind]})'; units {known}) or with --columns '{c.name}:{CANONICAL[kind]},...'"
        )
    if c.unit not in UNITS or UNITS[c.unit][0] != kind:
        raise SceneError(
            f"{path}, line {line}: the column {c.name!r} ({WORDS[c.quantity]}) is in {c.unit!r}, "
            f"not a unit of a {WORDS[c.quantity]} this reader knows ({known})"
        )
    return UNITS[c.unit][1]


# --- comment lines ------------------------------------------------------------------------------------------------
