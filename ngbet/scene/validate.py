"""Scene errors and the checks every section runs on construction (each names the key, value and reason)."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["AUTO", "SceneError", "auto_or", "boolean", "check", "choice", "integer", "nonnegative", "positive"]


class SceneError(ValueError):
    """A scene value is missing, unknown or out of range; the message names the key."""


def check(cond: bool, key: str, value: Any, why: str) -> None:
    """Raise a :class:`SceneError` naming ``key``, ``value`` and ``why`` unless ``cond`` holds."""
    if not cond:
        raise SceneError(f"scene key '{key}' = {value!r}: {why}")


def positive(section: str, obj: Any, *names: str) -> None:
    """Require each ``obj.<name>`` to be a finite number > 0 (a bool is not a number here)."""
    for n in names:
        v = getattr(obj, n)
        check(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0,
            f"{section}.{n}",
            v,
            "must be a finite number > 0",
        )


def nonnegative(section: str, obj: Any, *names: str) -> None:
    """Require each ``obj.<name>`` to be a finite number >= 0 (a bool is not a number here)."""
    for n in names:
        v = getattr(obj, n)
        check(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
            f"{section}.{n}",
            v,
            "must be a finite number >= 0",
        )


def boolean(section: str, obj: Any, *names: str) -> None:
    """Require each ``obj.<name>`` to be ``True`` or ``False``."""
    for n in names:
        v = getattr(obj, n)
        check(isinstance(v, bool), f"{section}.{n}", v, "must be true or false")


def integer(section: str, obj: Any, name: str, lo: int, hi: int) -> None:
    """Require ``obj.name`` to be an integer (not a bool) from ``lo`` to ``hi``, both included."""
    v = getattr(obj, name)
    check(
        isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi,
        f"{section}.{name}",
        v,
        f"must be an integer from {lo} to {hi}",
    )


AUTO = "auto"


def auto_or(section: str, obj: Any, name: str, accept: Any, what: str) -> None:
    """Require ``obj.name`` to be ``"auto"`` or a value ``accept`` takes, described by ``what``."""
    v = getattr(obj, name)
    if v == AUTO:
        return
    check(not isinstance(v, (bool, str)) and accept(v), f"{section}.{name}", v, f'must be "auto" or {what}')


def choice(section: str, obj: Any, name: str, choices: tuple[str, ...]) -> None:
    """Require ``obj.name`` to be one of ``choices``; the message lists them."""
    v = getattr(obj, name)
    check(v in choices, f"{section}.{name}" if section else name, v, f"must be one of {', '.join(map(repr, choices))}")
