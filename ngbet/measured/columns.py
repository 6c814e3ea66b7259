"""The columns of a measured curve's table: which quantity each is, in which unit, which two are read.

A column is known by its name (``displacement``, ``extension``, ``force``, ``load``, the picture
frame's shear angle and shear forces) and its unit, written in the name (``force_kN``, ``Force (kN)``,
``Force [kN]``) or in a row of units under the header (:func:`is_units_row`); ``columns``
(``--columns``) chooses two by name or 1-based number, each with a unit (``2:kN``) or a quantity and its
unit as a header names them (``2:shear_force_N``: a unit alone says the kind, and a force in N alone is
the crosshead force). A file without a header has its columns chosen by number only
(:func:`numbered_columns`). A unit it does not know is kept as written and refused by
:func:`check_unit` naming it and the units it knows. Read by
:func:`ngbet.measured.table.read_table`; a refusal is a :class:`ngbet.scene.validate.SceneError`
naming the file and the line.
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
    "is_number",
    "is_units_row",
    "known_units",
    "naming_advice",
    "numbered_columns",
    "parse_columns",
    "pick_column",
    "pretty_unit",
    "set_units",
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
#: how a unit is written in messages (the keys of UNITS are lower case)
PRETTY = {"n": "N", "kn": "kN", "n/mm": "N/mm", "n/m": "N/m", "kn/m": "kN/m", "n_per_mm": "N/mm", "n_per_m": "N/m"}
#: a word after the last underscore of a column name that may be a unit (``force_lbf``, ``displacement_in``)
_UNIT_WORD = re.compile(r"^(?:[A-Za-zµ°/]{1,3}|inch|inches)$")
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


def pretty_unit(unit: str) -> str:
    """A unit as users write it: a key of :data:`UNITS` in its usual case (``kN``, ``N/mm``), another unchanged."""
    return PRETTY.get(unit, unit)


def _as_unit(unit: str) -> str:
    """The key of :data:`UNITS` for a unit as written, or (a unit it does not know) the unit as written."""
    key = unit_key(unit)
    return key if key in UNITS else unit.strip()


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
    #: the line of the row of units that gave the unit (0: the header gave it, or none)
    unit_line: int = 0


def split_name(cell: str) -> tuple[str, str | None]:
    """(name, unit as written) of a header cell: ``Force (kN)``, ``Force [kN]``, ``force_kN``, ``force``.

    A unit after the last underscore is one of :data:`UNITS`, or a short word after the name of a
    quantity (``force_lbf``, ``displacement_in``: an unknown unit, for :func:`check_unit` to name).
    """
    c = cell.strip().strip("\"'").strip()
    m = _UNIT_IN_BRACKETS.match(c)
    if m and m.group(2):
        return m.group(1), m.group(2)
    low = c.lower()
    for u in sorted(UNITS, key=len, reverse=True):
        if low.endswith("_" + u) and len(low) > len(u) + 1:
            return c[: -len(u) - 1], c[-len(u) :]
    name, _, word = c.rpartition("_")
    if name and _UNIT_WORD.match(word) and quantity_of(name) and not quantity_of(word):
        return name, word
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
        cols.append(Column(j, cell.strip(), quantity_of(name), _as_unit(unit) if unit else None))
    return cols


def is_number(cell: str) -> bool:
    """True when the cell is a number, with a decimal point or a decimal comma."""
    try:
        float(cell.strip().replace(",", ".", 1))
    except ValueError:
        return False
    return True


def is_units_row(cells: list[str]) -> bool:
    """True when the first line under the header is a row of units: cells, some empty, none a number.

    Testing machines write one (``s;mm;%;N``, ``(s),(mm),(N)``); a cell may hold a unit this reader
    does not know (``%``, ``-``): only the columns read need one (:func:`set_units`), and the row is
    never read as numbers.
    """
    return any(c.strip() for c in cells) and not any(is_number(c) for c in cells if c.strip())


def set_units(cols: list[Column], cells: list[str], line: int, path: Path) -> None:
    """Give each column without a unit in its name the unit of the row of units (line ``line``).

    A unit it does not know is kept as written (:func:`check_unit` refuses it where the column is
    read); a column whose name gives one unit and the row another is refused (SceneError).
    """
    for c, cell in zip(cols, cells, strict=False):
        u = cell.strip().strip("\"'").strip("()[] ")
        if not u:
            continue
        if c.unit is None:
            c.unit, c.unit_line = _as_unit(u), line
        elif c.unit != _as_unit(u) and _as_unit(u) in UNITS:
            raise SceneError(
                f"{path}, line {line}: the column {c.name!r} is in {pretty_unit(c.unit)} by its name and in "
                f"{pretty_unit(_as_unit(u))} by the row of units: correct one"
            )


def parse_columns(spec: str | Sequence[str]) -> list[tuple[str, str | None, str | None]]:
    """``--columns``: two (name or 1-based number, unit key or None, quantity or None).

    Each item is ``NAME``, ``NAME:UNIT`` or ``NAME:QUANTITY_UNIT``, the quantity and unit written as a
    header names them (``2:shear_force_N``, ``1:shear_angle_deg``). Anything else, a unit it does not
    know, or a quantity with a unit of another kind (``shear_force_mm``) is refused (SceneError).
    """
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    if len(items) != 2 or not all(items):
        raise SceneError(
            f"--columns {spec!r}: give two columns, the displacement (or shear angle) and the force, "
            "by header name or number, each with an optional unit: --columns 'Weg:mm,Kraft:kN'"
        )
    out: list[tuple[str, str | None, str | None]] = []
    for s in items:
        name, sep, unit = s.rpartition(":")
        if not (sep and name.strip() and unit.strip()):
            out.append((s, None, None))
            continue
        what, written = split_name(unit)
        quantity = None if unit_key(unit) in UNITS or written is None else quantity_of(what)
        u = unit_key(written) if quantity and written else unit_key(unit)
        if u not in UNITS:
            known = "; ".join(known_units(k) for k in ("length", "angle", "force", "force/length"))
            raise SceneError(f"--columns {spec!r}: unknown unit {unit.strip()!r} (known: {known})")
        if quantity and QUANTITIES[quantity][1] != UNITS[u][0]:
            kind = QUANTITIES[quantity][1]
            raise SceneError(
                f"--columns {spec!r}: {unit.strip()!r}: a {WORDS[quantity]} in {pretty_unit(u)}? give it in "
                f"{known_units(kind)}, e.g. {name.strip()}:{what}_{CANONICAL[kind].replace('/', '_per_')}"
            )
        out.append((name.strip(), u, quantity))
    return out


def pick_column(cols: list[Column], spec: tuple[str, str | None, str | None], path: Path, line: int) -> Column:
    """The column ``spec`` (from :func:`parse_columns`) names, with its given unit and quantity; a missing one refused.

    A unit without a quantity makes the column a quantity of the unit's kind where its name says none
    or another (``N``: the force, ``N/mm``: the normalised shear force).
    """
    name, unit, quantity = spec
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
    picked = Column(col.index, col.name, col.quantity, unit or col.unit, 0 if unit else col.unit_line)
    if unit:
        kind = UNITS[unit][0]
        if picked.quantity is None or QUANTITIES[picked.quantity][1] != kind:
            picked.quantity = {
                "length": "displacement",
                "angle": "shear_angle",
                "force": "force",
                "force/length": "normalised_shear_force",
            }.get(kind)
    picked.quantity = quantity or picked.quantity
    return picked


def choose_columns(
    cols: list[Column], columns: str | Sequence[str] | None, path: Path, line: int, test: str = ""
) -> tuple[Column, Column]:
    """The x and y columns: by ``columns``, else by their names (one of each, or refused).

    ``test``: the test the curve is read for, "" if unknown: a refusal's advice names its columns.
    """
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
        frame = test == "picture_frame"
        words = ("a shear angle", "a shear force") if frame else ("a displacement", "a force")
        lack = " and ".join(w for w, cs in zip(words, (xs, ys), strict=True) if not cs)
        how = (
            f"({naming_advice(test)[0]}) or choose them with --columns NAME:deg,NAME:shear_force_N"
            if frame
            else "(displacement_mm,force_N or 'Displacement (mm);Force (N)'"
            + ("" if test else "; a picture frame's shear_angle_deg,shear_force_N")
            + ") or choose them with --columns NAME:UNIT,NAME:UNIT"
        )
        raise SceneError(
            f"{path}, line {line}: the header names the columns {names}, none of which is {lack} "
            f"this reader knows; name them with their units {how}"
        )
    for cs, what in ((xs, "displacement (or shear angle)"), (ys, "force")):
        if len(cs) > 1:
            raise SceneError(
                f"{path}, line {line}: {len(cs)} columns could be the {what}: "
                f"{', '.join(repr(c.name) for c in cs)}; choose with --columns, e.g. "
                f"--columns '{xs[0].name},{ys[0].name}'"
            )
    return xs[0], ys[0]


#: the header and the ``--columns`` of each test's curve, for the advice of a refusal
_NAMING = {
    "bias_extension": ("displacement_mm,force_N", "--columns 1:mm,2:N"),
    "picture_frame": (
        "shear_angle_deg,shear_force_N or shear_angle_deg,normalised_shear_force_N_per_mm",
        "--columns 1:deg,2:shear_force_N",
    ),
    "": (
        "displacement_mm,force_N; a picture frame's shear_angle_deg,shear_force_N",
        "--columns 1:mm,2:N (a picture frame's: --columns 1:deg,2:shear_force_N)",
    ),
}


def naming_advice(test: str) -> tuple[str, str]:
    """(header, ``--columns``) that name the columns of a curve of ``test`` ("" if unknown: both tests')."""
    return _NAMING.get(test, _NAMING[""])


def numbered_columns(
    cells: list[str], columns: str | Sequence[str] | None, path: Path, line: int, test: str
) -> list[Column]:
    """The columns of a file without a header, its first row (line ``line``, ``cells``) a row of data.

    Named by their 1-based numbers, without a quantity or unit: ``columns`` (``--columns``) gives
    both, by number. No ``columns``, or a column chosen by name or without a unit: refused
    (SceneError) with the header or the ``--columns`` that names the columns of a ``test`` curve.
    """
    header, by_number = naming_advice(test)
    if not columns:
        raise SceneError(
            f"{path}, line {line}: a row of numbers where the header should be: name the columns in a header "
            f"line above it, with their units ({header}), or give them by number with their units: {by_number}"
        )
    bare = [n for n, unit, _ in parse_columns(columns) if not (n.isdigit() and unit)]
    if bare:
        raise SceneError(
            f"--columns {columns!r}: {path} has no header (line {line} is a row of numbers): give each column "
            f"by its number with its unit, {by_number}"
        )
    return [Column(j, str(j + 1), None, None) for j in range(len(cells))]


_KINDS = {
    "length": "a length",
    "force": "a force",
    "angle": "an angle",
    "force/length": "a force per length",
    "time": "a time",
}


def known_units(kind: str) -> str:
    """The units of a kind (``length``, ``force``, ...) this reader knows, as users write them: ``N, kN``."""
    seen = dict.fromkeys(
        pretty_unit(k) for k, (kk, _) in UNITS.items() if kk == kind and k not in ("degree", "degrees")
    )
    return ", ".join(seen)


def check_unit(c: Column, path: Path, line: int) -> float:
    """The factor to the canonical unit of the column's quantity; refused without a unit it knows.

    No unit, a unit it does not know (named as written, with the units it knows) or a unit of
    another quantity: refused (SceneError naming the file and the line of the header, or of the row
    of units that gave the unit).
    """
    assert c.quantity is not None
    kind = QUANTITIES[c.quantity][1]
    known = known_units(kind)
    what = WORDS[c.quantity]
    example = {
        "length": "displacement_mm",
        "force": "force_N",
        "angle": "shear_angle_deg",
        "force/length": "normalised_shear_force_N_per_mm",
    }[kind]
    if c.unit is None:
        raise SceneError(
            f"{path}, line {line}: the column {c.name!r} ({what}) gives no unit: write it "
            f"into the header ({example} or '{what.capitalize()} "
            f"({CANONICAL[kind]})'; units {known}) or with --columns '{c.name}:{CANONICAL[kind]},...'"
        )
    where = f"{path}, line {c.unit_line or line}: the column {c.name!r} ({what})"
    if c.unit not in UNITS:
        raise SceneError(
            f"{where}: unknown unit {c.unit!r} (known: {known}); convert the column to one of them "
            f"or choose the unit with --columns '{c.name}:{CANONICAL[kind]},...'"
        )
    if UNITS[c.unit][0] != kind:
        raise SceneError(
            f"{where} is in {pretty_unit(c.unit)}, a unit of {_KINDS[UNITS[c.unit][0]]}, not of a {what} "
            f"(known: {known})"
        )
    return UNITS[c.unit][1]
