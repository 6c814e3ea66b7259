"""Scene errors and the checks every section runs on construction (each names the key, value and reason)."""

from __future__ import annotations

import math
from typing import Any


class SceneError(ValueError):
    """A scene value is missing, unknown or out of range; the message names the key."""


def _check(cond: bool, key: str, value: Any, why: str) -> None:
    if not cond:
        raise SceneError(f"scene key '{key}' = {value!r}: {why}")


def _positive(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0,
               f"{section}.{n}", v, "must be a finite number > 0")


def _nonnegative(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
               f"{section}.{n}", v, "must be a finite number >= 0")


def _boolean(section: str, obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(isinstance(v, bool), f"{section}.{n}", v, "must be true or false")


def _integer(section: str, obj: Any, name: str, lo: int, hi: int) -> None:
    v = getattr(obj, name)
    _check(isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi,
           f"{section}.{name}", v, f"must be an integer from {lo} to {hi}")


AUTO = "auto"


def _auto_or(section: str, obj: Any, name: str, check: Any, what: str, old: tuple[Any, ...]) -> None:
    """``"auto"`` or a value passing ``check``; the former numeric sentinels ``old`` get a clear error."""
    v = getattr(obj, name)
    if v == AUTO:
        return
    if not isinstance(v, bool) and v in old:
        raise SceneError(f"scene key '{section}.{name}' = {v!r}: for the automatic value write "
                         f"{name} = \"auto\"; otherwise give {what}")
    _check(not isinstance(v, (bool, str)) and check(v), f"{section}.{name}", v, f"must be \"auto\" or {what}")


def _choice(section: str, obj: Any, name: str, choices: tuple[str, ...]) -> None:
    v = getattr(obj, name)
    _check(v in choices, f"{section}.{name}" if section else name, v, f"must be one of {', '.join(map(repr, choices))}")
