"""Measured curves as laboratories write them: the table reader of every command (fit, run --data, normalise).

A data file is a table of text: ``#`` comment lines, then a header line naming the columns, then
rows of numbers. :func:`read_table` understands

- **columns by name**, in any order: the displacement (``displacement``, ``extension``,
  ``crosshead``, ``stroke``, ...), the force (``force``, ``load``), for the picture frame also the
  shear angle, the shear force and the normalised shear force; other columns (``time_s``) are
  ignored. Or chosen with ``columns`` (``--columns``): two header names or 1-based numbers, each
  with an optional unit, ``"Weg:mm,Kraft:kN"``, or a quantity and its unit as a header names them,
  ``"1:deg,2:shear_force_N"`` (a unit alone gives the kind: a force in N is the crosshead force).
  Two columns without names it understands are refused, never taken by position.
- **a file without a header**: a first line (not a ``#`` comment) holding a number is a row of data,
  never a header; its columns are chosen by number with their units (``--columns 1:mm,2:N``,
  ``--columns 1:deg,2:shear_force_N``), else refused with the header or the ``--columns`` that name
  the columns of the test the curve is read for (``test``, the header's test line or frame, else
  the caller's ``expect``; both tests' where none is known).
- **units in the header**: ``force_kN``, ``Force (kN)``, ``Force [kN]``, a row of units under the
  header (``s;mm;%;N``: a row of no numbers, never read as data; only the columns read need a unit
  it knows); lengths mm, cm, m; forces N, kN; angles deg, rad; normalised forces N/mm, N/m. Values
  are converted to mm, N, degrees and N/mm, and every conversion is said (:attr:`CurveTable.notes`).
  A column it needs without a unit, or with a unit it does not know (``force_lbf``), is refused
  naming the unit and the units it knows.
- **separators**: commas; semicolons, tabs or spaces (a header of several words whose first line
  has none of them), then with decimal commas (``0,5``) as Excel writes them; quoted cells; a UTF-8
  byte order mark; Windows-1252 and UTF-16 text. A spreadsheet workbook (``.xlsx``) is refused:
  export it as CSV.
- **the specimen** from comment lines ``# specimen.width_mm = 100`` (also ``= 100 mm``,
  ``# width_mm = 100``, ``# specimen.width = 0.1 m``; ``thickness_mm`` and ``yarn_angle_deg``
  too) or from the command line (``--specimen 100x250``, width x clamp-to-clamp length [x
  thickness] in mm). Both given and different, only one of width and length, a width or length
  not > 0, a length not above the width: refused.
- **the test** (:attr:`CurveTable.test`, the one rule of every command): ``--test``, else the
  header's ``# test: picture-frame`` or ``bias_extension``; else a picture frame when the file holds a
  picture frame's quantities (a shear angle, a shear force, a normalised shear force) or names a
  frame and no specimen, a bias extension test when it names a specimen and no frame; "" when it
  names neither (``fit`` and ``run --data`` then read a bias extension curve on the scene's
  specimen, ``normalise`` refuses it); both a specimen and a frame: refused. The picture frame's
  sizes from ``# Table 3 (UN): frame 145 mm, fabric 120 mm`` or ``# picture_frame.frame_mm = 145``
  and ``# picture_frame.fabric_mm = 120`` (or ``--frame 145x120``).
- **what the curve is of**: ``# laboratory: UN`` (or ``# Table 3 (UN): ...``, ``legend label "UN"``)
  and ``# fabric: ...`` (also after a semicolon, ``# test: picture-frame; fabric: ...``), kept as
  text for the studies that sort curves by fabric and laboratory (:attr:`CurveTable.laboratory`,
  :attr:`CurveTable.fabric`; "" where the header says nothing).
- **the shape of the curve** (:mod:`ngbet.measured.shape`): a displacement and a force negative
  throughout are read with their signs changed, one of them alone is refused; a picture frame's
  shear angle above 90° (or mostly below 0°) is refused naming its column and unit; rows in descending
  displacement are read in ascending order; of a loading–unloading cycle the loading branch is
  kept. Each said in a note; several cycles, or a loading branch of a small share of the rows,
  refused.

Everything is checked before any model run, and a refusal names the file and the line and says
what to write (:class:`ngbet.scene.validate.SceneError`, exit status 2).


A file ``NAME_errorbars.csv`` beside ``NAME.csv`` with the columns ``displacement_mm``,
``force_low_N``, ``force_high_N`` gives the printed error bars (:func:`read_errorbars`). Given among
the data files with its curve (a shell pattern such as ``data/*.csv`` gives both), it is left out
of the curves (:func:`curve_files`); given without its curve, it is refused with the file to give.
"""

from __future__ import annotations

import codecs
import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..scene.validate import SceneError
from .columns import (
    CANONICAL,
    UNITS,
    WORDS,
    Column,
    check_unit,
    choose_columns,
    header_columns,
    is_number,
    is_units_row,
    numbered_columns,
    pretty_unit,
    set_units,
)
from .header import Header, name_of_test, parse_number
from .shape import frame_angles, loading_branch, order, plural, signs

__all__ = [
    "CurveTable",
    "curve_files",
    "errorbar_path",
    "parse_sizes",
    "per_file",
    "read_errorbars",
    "read_table",
    "read_text",
]


#: the separators of columns besides commas, as notes name them
_SEPARATORS = {";": "semicolons", "\t": "tabs", " ": "spaces"}
#: the quantities only a picture frame's curve holds
_FRAME_QUANTITIES = ("shear_angle", "shear_force", "normalised_shear_force")


@dataclass(frozen=True)
class CurveTable:
    """A measured curve as read, in file order, converted to mm, N, degrees and N/mm.

    ``x`` is the displacement [mm] or the shear angle [deg] (``x_quantity``), ``y`` the force or
    shear force [N] or the normalised shear force [N/mm] (``y_quantity``); ``lines`` the file
    line of each row; ``specimen`` the scene keys of the specimen, ``frame`` the picture frame's
    ``picture_frame.frame_mm`` and ``picture_frame.fabric_mm``; ``test`` one of
    :data:`~ngbet.measured.header.TESTS` by the one rule of every command (module docstring), or ""
    when the file names neither a specimen nor a frame nor the test; ``test_reason`` says why, in
    words for messages ("its header says test: picture-frame").
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
    laboratory: str = ""
    fabric: str = ""
    test_reason: str = ""


# --- text ---------------------------------------------------------------------------------------------------------


def read_text(path: Path, what: str) -> tuple[str, list[str]]:
    """The text of the file ``path`` (a ``what`` file in messages) and notes on its decoding.

    UTF-8 (a byte order mark dropped), else Windows-1252 with a note, or UTF-16 with its byte order
    mark (a note); a directory, a missing or unreadable file, a spreadsheet workbook, other NUL bytes
    or neither encoding: refused (SceneError naming the file; a binary file is to be exported as CSV).
    """
    if path.is_dir():
        raise SceneError(f"{what} file {path} is a directory")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise SceneError(f"{what} file {path} cannot be read: {exc.strerror or exc}") from None
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return raw.decode("utf-16"), ["read as UTF-16 text"]
        except UnicodeDecodeError:
            raise SceneError(f"{what} file {path} is not a text file (broken UTF-16)") from None
    if b"\x00" in raw:
        kind = (
            "is a spreadsheet workbook, not a text file"
            if raw.startswith((b"PK\x03\x04", b"\xd0\xcf\x11\xe0"))
            else "is not a text file (holds NUL bytes)"
        )
        raise SceneError(f"{what} file {path} {kind}: export it as CSV (comma- or semicolon-separated text)")
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
        example = "x".join(("100", "250", "3.3")[: len(names)])
        raise SceneError(
            f"{what} {text!r}: write sizes in mm joined by x, e.g. {what} {example} "
            f"({' x '.join(n.split('.')[-1].removesuffix('_mm') for n in names)})"
        )
    bad = [f"{n.split('.')[-1].removesuffix('_mm')} {v:g}" for n, v in zip(names, vals, strict=False) if not v > 0]
    if bad:
        raise SceneError(f"{what} {text!r}: {', '.join(bad)}: sizes must be > 0 mm")
    return dict(zip(names, vals, strict=False))


def _merge(
    path: Path, header: dict[str, float], given: dict[str, float] | None, flag: str
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
    spec, notes = _merge(path, header, given, "--specimen")
    for k in ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"):
        if k in spec and not spec[k] > 0:
            raise SceneError(f"{path}: {k} = {spec[k]:g} must be > 0")
    has = [k for k in ("specimen.width_mm", "specimen.length_mm") if k in spec]
    if spec and len(has) < 2:
        lack = ({"specimen.width_mm", "specimen.length_mm"} - set(has)).pop()
        raise SceneError(
            f"{path}: an incomplete specimen: {', '.join(sorted(spec))} but no {lack}; add "
            f"'# {lack} = ...' to the header or give --specimen WIDTHxLENGTH (mm)"
        )
    if len(has) == 2 and not spec["specimen.length_mm"] > spec["specimen.width_mm"]:
        raise SceneError(
            f"{path}: specimen {spec['specimen.width_mm']:g} x {spec['specimen.length_mm']:g} mm: the "
            "clamp-to-clamp length must exceed the width (--specimen and the header give width x length)"
        )
    return spec, notes


def _frame(path: Path, keys: dict[str, float], given: dict[str, float] | None) -> tuple[dict[str, float], list[str]]:
    header = {k: v for k, v in keys.items() if k.startswith("picture_frame.")}
    frame, notes = _merge(path, header, given, "--frame")
    for k, v in frame.items():
        if not v > 0:
            raise SceneError(f"{path}: {k} = {v:g} must be > 0")
    return frame, notes


def _split(line: str, sep: str) -> list[str]:
    """The cells of a line: by ``sep`` (quoted cells kept whole), or by spaces (``sep`` " ").

    Between spaces, a cell in brackets joins the one before it (``Force (N)``).
    """
    if sep != " ":
        return next(csv.reader([line], delimiter=sep))
    cells: list[str] = []
    for word in re.findall(r'"[^"]*"|\S+', line):
        if cells and word[0] in "([":
            cells[-1] += " " + word
        else:
            cells.append(word.strip('"'))
    return cells


def _separator(line: str) -> str:
    """The column separator of a header line: semicolon, tab, comma, else spaces between several words."""
    return next((s for s in (";", "\t", ",") if s in line), " " if len(line.split()) > 1 else ",")


def _rows(text: str, path: Path, header: Header) -> tuple[list[str] | None, int, list[tuple[int, list[str]]], str]:
    """The header cells and line, the data rows (line, cells) and the column separator.

    A first line holding a number is a row of data, never a header: the header cells are then None,
    the line that of the first row, which is among the rows.
    """
    head: list[str] | None = None
    head_line, sep = 0, ","
    rows: list[tuple[int, list[str]]] = []
    for k, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if not head_line:
                header.comment(line, k)
            continue
        if not head_line:
            sep, head_line = _separator(line), k
            head = _split(line, sep)
            if any(is_number(c) for c in head if c.strip()):
                head = None  # a row of data
            else:
                continue
        rows.append((k, _split(line, sep)))
    if not head_line:
        raise SceneError(f"data file {path}: no header line and no data")
    return head, head_line, rows, sep


def read_table(
    path: str | Path,
    *,
    test: str | None = None,
    columns: str | Sequence[str] | None = None,
    specimen: dict[str, float] | None = None,
    frame: dict[str, float] | None = None,
    expect: str = "",
) -> CurveTable:
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
    expect : str, optional
        The test the caller reads the curve for (a picture-frame scene's ``run --data``): the advice
        of a refusal names its columns where ``test``, the header and ``frame`` name no test. It does
        not decide the curve's test (the one rule does).

    Returns
    -------
    CurveTable
        The rows in file order (a file in descending x reversed), up to the largest x (the unloading
        branch of a cycle left out), converted, with both signs changed where both are negative
        (:mod:`ngbet.measured.shape`); the test by the one rule (module docstring).
    """
    path = Path(path)
    text, notes = read_text(path, "data")
    header = Header(path)
    head, head_line, rows, sep = _rows(text, path, header)
    hint = _hint(test, header, frame) or expect
    cols = header_columns(head) if head else numbered_columns(rows[0][1], columns, path, head_line, hint)
    units = rows[0] if rows and is_units_row(rows[0][1]) else None  # testing machines write one
    if units:
        set_units(cols, units[1], units[0], path)
        rows = rows[1:]
    _refuse_errorbars(path, cols, columns)
    x, y = choose_columns(cols, columns, path, head_line, hint)
    if not head:
        notes.append(f"no header: line {head_line} is a row of numbers, read as data with the columns of --columns")
    if units and units[0] not in (x.unit_line, y.unit_line):
        notes.append(f"line {units[0]} holds no number: read as a row of units ({';'.join(units[1])}), not as data")
    fx, fy = check_unit(x, path, head_line), check_unit(y, path, head_line)
    comma = sep != ","
    data, lines = [], []
    for k, cells in rows:
        if len(cells) <= max(x.index, y.index):
            advice = {
                ",": " (decimal commas need semicolons or tabs between the columns)" if "," in "".join(cells) else "",
                " ": " (columns separated by spaces: write each column name as one word, displacement_mm force_N)",
            }.get(sep, "")
            first = "the header" if head else "the first row"
            raise SceneError(
                f"{path}, line {k}: {plural(len(cells), 'cell')}, {first} (line {head_line}) has {len(cols)}" + advice
            )
        data.append(
            (parse_number(cells[x.index], path, k, x.name, comma), parse_number(cells[y.index], path, k, y.name, comma))
        )
        lines.append(k)
    arr = np.array(data, dtype=float).reshape(-1, 2)
    xs, ys, ls = fx * arr[:, 0], fy * arr[:, 1], np.array(lines, dtype=int)
    if sep != ",":
        notes.append(
            f"columns separated by {_SEPARATORS[sep]}"
            + (", decimal commas" if any("," in c for _, r in rows for c in r) else "")
        )
    notes += [
        f"column {c.name!r} read as the {WORDS[c.quantity or '']} in {pretty_unit(c.unit)}, converted to "
        f"{CANONICAL[UNITS[c.unit][0]]} (x {f:g})"
        for c, f in ((x, fx), (y, fy))
        if c.unit is not None and f != 1.0
    ]
    ignored = [c.name for c in cols if c.index not in (x.index, y.index)]
    if ignored or columns:
        notes.append(
            f"columns: {x.name!r} as the {WORDS[x.quantity or '']}, {y.name!r} as the "
            f"{WORDS[y.quantity or '']}" + (f"; ignored: {', '.join(map(repr, ignored))}" if ignored else "")
        )
    beyond = _clipped(cols, rows)
    if beyond.any():
        notes.append(
            f"{plural(int(beyond.sum()), 'point')} marked on_frame_edge top or right left out (the chart "
            "clipped them: their true value lies beyond its axis)"
        )
        xs, ys, ls = xs[~beyond], ys[~beyond], ls[~beyond]
    xq, yq = x.quantity or "", y.quantity or ""
    xs, ys, flipped = signs(xs, ys, path, xq, yq)
    if xq == "shear_angle":
        frame_angles(xs, ls, path, x.name, pretty_unit(x.unit or ""))
    (xs, ys, ls), turned = order(xs, ys, ls, path, xq, yq)
    (xs, ys, ls), cut = loading_branch(xs, ys, ls, path, xq)
    notes += flipped + turned + cut
    spec, n1 = _specimen(path, header.keys, specimen)
    frm, n2 = _frame(path, header.keys, frame)
    ftest, why = _which_test(path, header.test, test, (xq, yq), bool(spec), bool(frm), (bool(specimen), bool(frame)))
    return CurveTable(
        str(path),
        xq,
        yq,
        xs,
        ys,
        ls,
        spec,
        frm,
        ftest,
        tuple(notes + header.notes + n1 + n2),
        header.laboratory,
        header.fabric,
        why,
    )


def _hint(test: str | None, header: Header, frame: dict[str, float] | None) -> str:
    """The test a refusal's advice is for; "" where nothing says.

    ``test``, else the header's test line, else the test of the one kind of sizes the header (or
    ``frame``) names: a frame or a specimen.
    """
    if test:
        return name_of_test(test, "--test")
    sizes = {k.split(".")[0] for k in header.keys} | ({"picture_frame"} if frame else set())
    return header.test or {"picture_frame": "picture_frame", "specimen": "bias_extension"}.get(
        "".join(sizes) if len(sizes) == 1 else "", ""
    )


def _which_test(
    path: Path,
    header: str,
    given: str | None,
    quantities: tuple[str, str],
    has_spec: bool,
    has_frame: bool,
    from_flags: tuple[bool, bool] = (False, False),
) -> tuple[str, str]:
    """(test, why) by the one rule of every command (module docstring); a specimen and a frame refused.

    ``from_flags``: whether the specimen and the frame came from ``--specimen`` and ``--frame``
    (the refusal then says which came from where).
    """
    if given is not None:
        name = name_of_test(given, "--test")
        if header and header != name:
            raise SceneError(f"{path}: its header says test {header}, --test says {name}: drop one")
        return name, f"--test {name}"
    if header:
        return header, f"its header says test: {header.replace('_', '-')}"
    pf = [q for q in quantities if q in _FRAME_QUANTITIES]
    if pf:
        return "picture_frame", f"its columns hold the {WORDS[pf[0]]}, a picture frame's quantity"
    if has_spec and has_frame and from_flags[0] != from_flags[1]:
        flag, other = ("--specimen", "a picture frame") if from_flags[0] else ("--frame", "a specimen")
        raise SceneError(
            f"{path}: which test? {flag} gives {'a specimen' if from_flags[0] else 'a picture frame'} and its "
            f"header {other}: drop {flag}, or add '# test: bias_extension' or '# test: picture_frame' to its header"
        )
    if has_spec and has_frame:
        raise SceneError(
            f"{path}: which test? it names both a specimen and a picture frame: add '# test: bias_extension' "
            "or '# test: picture_frame' to its header (ngbet normalise: or give --test)"
        )
    if has_frame:
        return "picture_frame", "it names a picture frame and no specimen"
    if has_spec:
        return "bias_extension", "it names a specimen and no picture frame"
    return "", "it names neither a specimen nor a picture frame and has no '# test:' line"


def _clipped(cols: list[Column], rows: list[tuple[int, list[str]]]) -> np.ndarray:
    """Rows an ``on_frame_edge`` column marks "top" or "right": a printed chart clipped them there."""
    clip = next((c for c in cols if c.name.lower() == "on_frame_edge"), None)
    if clip is None:
        return np.zeros(len(rows), dtype=bool)
    return np.array(
        [
            len(cells) > clip.index and bool({"top", "right"} & set(cells[clip.index].strip().lower().split("+")))
            for _, cells in rows
        ],
        dtype=bool,
    )


# --- bias extension curves -----------------------------------------------------------------------------------------


def errorbar_path(path: str | Path) -> Path:
    """``NAME_errorbars.csv`` beside ``NAME.csv``."""
    p = Path(path)
    return p.with_name(p.stem + "_errorbars" + p.suffix)


def _refuse_errorbars(path: Path, cols: Sequence[Column], columns: str | Sequence[str] | None) -> None:
    """Refuse an error-bar file (by its name and columns) read as a curve, unless ``--columns`` chose from it."""
    curve = curve_of_errorbars(path)
    if curve is not None and columns is None and {"force_low_N", "force_high_N"} <= {c.name for c in cols}:
        raise SceneError(
            f"{path} holds the error bars of {curve.name} (force_low_N, force_high_N), not a curve: "
            f"give {curve}; the bars beside it go with it"
        )


def curve_of_errorbars(path: str | Path) -> Path | None:
    """``NAME.csv`` for a file named ``NAME_errorbars.csv`` (the inverse of :func:`errorbar_path`), else None."""
    p = Path(path)
    stem = p.stem.removesuffix("_errorbars")
    return p.with_name(stem + p.suffix) if stem and stem != p.stem else None


def curve_files(paths: Sequence[str | Path]) -> tuple[list[str | Path], list[tuple[str | Path, Path]]]:
    """The curves among data files given together, and the error-bar files left out of them.

    An error-bar file whose curve is also given (``data/*.csv`` names both) is not a curve: it is
    left out, returned as (file, its curve) for the caller's note; its bars are read with the curve
    (:func:`read_errorbars`). One given without its curve stays, for :func:`read_table` to refuse
    with the file to give. The order of the curves is kept.
    """
    given = {Path(p).resolve() for p in paths}
    kept: list[str | Path] = []
    left: list[tuple[str | Path, Path]] = []
    for p in paths:
        curve = curve_of_errorbars(p)
        if curve is not None and curve.resolve() in given:
            left.append((p, curve))
        else:
            kept.append(p)
    return kept, left


def per_file(given: Sequence[dict[str, float]], n: int, flag: str) -> list[dict[str, float] | None]:
    """Command-line values (``--specimen``, ``--frame``) for ``n`` data files: none, one for all, or one per file."""
    if not given:
        return [None] * n
    if len(given) == 1:
        return [given[0]] * n
    if len(given) != n:
        raise SceneError(f"{len(given)} {flag} for {n} data files: give one for all, or one per file in order")
    return list(given)


def read_errorbars(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The error bars of the curve in ``path`` (u [mm], low [N], high [N], sorted by u), or None.

    Read from ``NAME_errorbars.csv`` beside it (:func:`errorbar_path`); None when that file is
    missing or holds fewer than two complete bars. Refused (SceneError): a missing column, a
    short row, text in a number's place, a high force below the low one.
    """
    ep = errorbar_path(path)
    if not ep.exists():
        return None
    text, _ = read_text(ep, "error bar")
    head, head_line, rows, sep = _rows(text, ep, Header(ep))
    names = [h.strip().strip("\"'") for h in head or ()]
    need = ("displacement_mm", "force_low_N", "force_high_N")
    missing = [n for n in need if n not in names]
    if missing:
        raise SceneError(f"{ep}, line {head_line}: the header lacks the column(s) {', '.join(missing)}")
    idx = [names.index(n) for n in need]
    vals, lines = [], []
    for k, cells in rows:
        if len(cells) <= max(idx):
            raise SceneError(f"{ep}, line {k}: {len(cells)} cells, the header (line {head_line}) has {len(names)}")
        vals.append(
            [
                math.nan
                if cells[j].strip() == "" and n != "displacement_mm"
                else parse_number(cells[j], ep, k, n, sep != ",")
                for j, n in zip(idx, need, strict=True)
            ]
        )
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
