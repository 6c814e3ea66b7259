"""The comment lines of a measured curve's file: the specimen, the frame, the test, the laboratory, the fabric.

:class:`Header` reads them line by line for :func:`ngbet.measured.table.read_table` (whose docstring
says what each line may hold); :func:`parse_number` reads a number as the tables write them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

from ..scene.validate import SceneError
from .columns import UNITS, unit_key

__all__ = ["DECIMAL_COMMA", "FRAME_KEYS", "TESTS", "Header", "fabric_names", "parse_number", "name_of_test"]

TESTS = ("bias_extension", "picture_frame")
_SPECIMEN_KEYS = {
    "width": "specimen.width_mm",
    "length": "specimen.length_mm",
    "thickness": "specimen.thickness_mm",
    "yarn_angle": "specimen.yarn_angle_deg",
}
FRAME_KEYS = {"frame": "picture_frame.frame_mm", "fabric": "picture_frame.fabric_mm"}
_KEY_LINE = re.compile(
    r"^#\s*((?:specimen|picture_frame)\.[\w.]+|width_mm|length_mm|thickness_mm|yarn_angle_deg)"
    r"\s*=\s*(.*?)\s*$"
)
_TEST_LINE = re.compile(r"^#\s*test\s*[:=]\s*[\"']?([^;,\"']*)", re.IGNORECASE)
_TABLE3 = re.compile(r"frame\s+([0-9.]+)\s*mm\s*,\s*fabric\s+([0-9.]+)\s*mm", re.IGNORECASE)
#: where a header names the laboratory, most explicit first: "# laboratory: UN", "Table 3 (UN): ...",
#: 'legend label "UN"'
_LAB = (
    re.compile(r"^#\s*laborator(?:y|ies)\s*[:=]\s*([^;,]+)", re.IGNORECASE),
    re.compile(r"Table\s*3\s*\(([^)]+)\)", re.IGNORECASE),
    re.compile(r"legend\s+label\s*[\"']([^\"']+)[\"']", re.IGNORECASE),
)
_FABRIC = re.compile(r"(?:^#|;)\s*fabric\s*[:=]\s*([^;]+)", re.IGNORECASE)
_VALUE = re.compile(r"^([+-]?[0-9.]+(?:[eE][+-]?\d+)?)\s*([A-Za-z°]*)$")
DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")


def parse_number(text: str, path: Path | str, line: int, column: str, comma: bool) -> float:
    """The number ``text`` of ``column`` on ``line`` of ``path``; ``comma``: decimal commas allowed.

    A comma that could be a thousands separator, text that is no number or a number that is not
    finite: refused (SceneError naming the file, the line and the column).
    """
    t = text.strip()
    if comma and DECIMAL_COMMA.match(t):
        t = t.replace(",", ".")
    elif "," in t:
        raise SceneError(
            f"{path}, line {line}: {column} = {text!r} is ambiguous (a thousands separator or a decimal "
            "comma?): write numbers without thousands separators, with a decimal point, or with "
            "decimal commas and semicolons between the columns"
        )
    try:
        v = float(t)
    except ValueError:
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a number") from None
    if not math.isfinite(v):
        raise SceneError(f"{path}, line {line}: {column} = {text!r} is not a finite number")
    return v


def _key_value(key: str, value: str, path: Path, line: int) -> tuple[str, float, str | None]:
    """(scene key, value in mm or deg, a note on a converted unit) of a ``# key = value [unit]`` line."""
    bare = key.split(".", 1)[1] if "." in key else key
    section = "picture_frame" if key.startswith("picture_frame.") else "specimen"
    table = FRAME_KEYS if section == "picture_frame" else _SPECIMEN_KEYS
    stem, _, suffix = bare.rpartition("_")
    if suffix not in ("mm", "deg"):
        stem, suffix = bare, ""
    if stem not in table:
        raise SceneError(
            f"{path}, line {line}: unknown key {key!r}; the {section} keys are {', '.join(table.values())}"
        )
    full = table[stem]
    m = _VALUE.match(value)
    if not m:
        raise SceneError(f"{path}, line {line}: {key} = {value!r} is not a number (with an optional unit: = 100 mm)")
    v = parse_number(m.group(1), path, line, key, False)
    unit = unit_key(m.group(2)) if m.group(2) else (suffix or None)
    want = "angle" if full.endswith("_deg") else "length"
    if unit is None:
        raise SceneError(
            f"{path}, line {line}: {key} = {value!r} gives no unit: write {full} = {value} "
            f"{'deg' if want == 'angle' else 'mm'}"
        )
    if unit not in UNITS or UNITS[unit][0] != want:
        raise SceneError(
            f"{path}, line {line}: {key} = {value!r}: {m.group(2) or suffix!r} is not a unit of "
            f"{'an angle' if want == 'angle' else 'a length'}"
        )
    note = None
    if UNITS[unit][1] != 1.0:
        v *= UNITS[unit][1]
        note = f"{key} = {value} read as {full} = {v:g}"
    return full, v, note


def name_of_test(text: str, where: str) -> str:
    """The test ``text`` names ("bias_extension" or "picture_frame"; BET, PF, with spaces or hyphens).

    Another name is refused (SceneError naming ``where``).
    """
    t = re.sub(r"[\s\-]+", "_", text.strip().lower())
    t = {
        "bet": "bias_extension",
        "bias_extension_test": "bias_extension",
        "pf": "picture_frame",
        "picture_frame_test": "picture_frame",
    }.get(t, t)
    if t not in TESTS:
        raise SceneError(f"{where}: unknown test {text.strip()!r}; write bias_extension or picture_frame")
    return t


#: a fabric's style code in its header's text (letters and digits in one word: "TPEET22XXX"), by
#: which two texts name one fabric ("Twintex TPEET22XXX plain weave ..." and "plain weave, Twintex
#: TPEET22XXX ...")
_STYLE_CODE = re.compile(r"\b(?=\w*\d)(?=\w*[A-Za-z])\w{6,}\b")


def _fabric_key(text: str) -> str:
    code = _STYLE_CODE.search(text)
    return code.group(0) if code else " ".join(text.lower().split())


def fabric_names(fabrics: Sequence[str]) -> list[str]:
    """The fabric of each curve in a few words, from its header's fabric text; "" for all when they name one.

    Two headers name one fabric when they give the same style code (a word of letters and digits,
    "TPEET22XXX"), else the same text. The name is the text of the fabric's first curve up to its
    first comma, semicolon or bracket ("Twintex TPEET22XXX plain weave (commingled ...), 743 g/m^2"
    -> "Twintex TPEET22XXX plain weave"); "fabric not named" for curves whose header names none.
    """
    keys = [_fabric_key(f) for f in fabrics]
    if len(set(keys)) < 2:
        return [""] * len(fabrics)
    first = {k: f for k, f in reversed(list(zip(keys, fabrics, strict=True)))}
    return [re.split(r"[,;(]", first[k], maxsplit=1)[0].strip() or "fabric not named" for k in keys]


class Header:
    """What the comment lines say: specimen and frame keys, the test, the laboratory, the fabric.

    Fed one comment line at a time (:meth:`comment`); a key or a test given twice differently is
    refused (SceneError naming both lines). The laboratory and the fabric are text, kept as the
    first line that names them says them.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.keys: dict[str, float] = {}
        self.where: dict[str, int] = {}
        self.test = ""
        self.notes: list[str] = []
        self.labs: list[str] = ["", "", ""]  # what each pattern of _LAB found first
        self.fabric = ""

    def _set(self, key: str, v: float, line: int) -> None:
        if key in self.keys and self.keys[key] != v:
            raise SceneError(
                f"{self.path}, line {line}: {key} = {v:g}, but line {self.where[key]} says "
                f"{self.keys[key]:g}: give it once"
            )
        self.keys[key], self.where[key] = v, line

    @property
    def laboratory(self) -> str:
        """The laboratory the most explicit line names ("" if none)."""
        return next((lab for lab in self.labs if lab), "")

    def comment(self, text: str, line: int) -> None:
        """Take what the comment line ``text`` (line number ``line``) says; a key given twice differently is refused."""
        for i, pat in enumerate(_LAB):
            lab = pat.search(text)
            if lab and not self.labs[i]:
                self.labs[i] = lab.group(1).strip()
        fab = _FABRIC.search(text)
        if fab and not self.fabric:
            self.fabric = fab.group(1).strip()
        m = _KEY_LINE.match(text)
        if m:
            key, v, note = _key_value(m.group(1), m.group(2), self.path, line)
            self._set(key, v, line)
            if note:
                self.notes.append(note)
            return
        t = _TEST_LINE.match(text)
        if t:
            name = name_of_test(t.group(1), f"{self.path}, line {line}")
            if self.test and self.test != name:
                raise SceneError(f"{self.path}, line {line}: test {name}, but an earlier line says {self.test}")
            self.test = name
        f = _TABLE3.search(text)
        if f:
            self._set("picture_frame.frame_mm", float(f.group(1)), line)
            self._set("picture_frame.fabric_mm", float(f.group(2)), line)
