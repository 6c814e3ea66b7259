"""What the studies' figures share: the caption of the base scene and what the cases vary."""

from __future__ import annotations

from typing import Any

from .style import caption

__all__ = ["UNITS", "key_label", "key_value", "study_caption", "unit_of"]


def study_caption(meta: dict[str, Any], extra: str = "") -> str:
    """The caption line of a study's figure: specimen and material of its base scene, what the cases vary.

    ``meta``: the study's meta.json (``base_scene``, ``params``; what the cases write, ``outputs.*``,
    is not named); ``extra`` is appended.
    """
    text = caption(meta.get("base_scene"))
    varied: list[str] = []
    for k in map(str, meta.get("params", [])):
        if k.startswith("outputs."):  # what the cases write, not what they are
            continue
        what = ("the discretization" if k.startswith(("discretization.", "solver."))
                else "the constraint's treatment" if k.startswith(("effects.constraint", "effects.penalty"))
                else k.split(".", 1)[-1])
        if what not in varied:
            varied.append(what)
    if varied:
        text += "; the cases vary " + ", ".join(varied)
    return text + (f"; {extra}" if extra else "")


#: units of scene keys by name (the rest carry theirs in the name: _mm, _deg, _Pa, _N)
UNITS = {"K_sh": "Pa", "K_el": "Pa", "alpha1": "Pa m²", "alpha2": "Pa m²", "penalty_K": "Pa", "EA1": "N",
         "EA2": "N", "EI1": "N m²", "EI2": "N m²", "K_phi": "N m", "K_slip": "N/m", "K_inter": "N"}
_SUFFIXES = {"_mm": "mm", "_deg": "°", "_Pa": "Pa", "_N": "N", "_s": "s"}


def unit_of(key: str) -> str:
    """The unit of a scene key ("" when it has none): ``material.alpha1`` → "Pa m²", ``loading.u0_mm`` → "mm"."""
    name = key.rsplit(".", 1)[-1]
    if name in UNITS:
        return UNITS[name]
    return next((u for suf, u in _SUFFIXES.items() if name.endswith(suf)), "")


def key_value(key: str, value: Any) -> str:
    """``alpha1 = 200 Pa m²``: a scene key's value with its unit, for a legend."""
    unit = unit_of(key)
    v = f"{value:g}" if isinstance(value, float) else str(value)
    return f"{key.rsplit('.', 1)[-1]} = {v}" + (f" {unit}" if unit and unit != "°" else unit)


def key_label(key: str) -> str:
    """An axis label for a scene key: ``material.alpha1 [Pa m²]``."""
    unit = unit_of(key)
    return f"{key} [{unit}]" if unit else key
