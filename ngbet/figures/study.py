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
        what = (
            "the discretization"
            if k.startswith(("discretization.", "solver."))
            else "the constraint's treatment"
            if k.startswith(("effects.constraint", "effects.penalty"))
            else symbol(k)
        )
        if what not in varied:
            varied.append(what)
    if varied:
        text += "; the cases vary " + ", ".join(varied)
    return text + (f"; {extra}" if extra else "")


#: units of scene keys by name (the rest carry theirs in the name: _mm, _deg, _Pa, _N)
UNITS = {
    "K_sh": "Pa",
    "K_el": "Pa",
    "alpha1": "Pa m²",
    "alpha2": "Pa m²",
    "penalty_K": "Pa",
    "EA1": "N",
    "EA2": "N",
    "EI1": "N m²",
    "EI2": "N m²",
    "K_phi": "N m",
    "K_slip": "N/m",
    "K_inter": "N",
}
_SUFFIXES = {"_mm": "mm", "_deg": "°", "_Pa": "Pa", "_N": "N", "_s": "s"}


#: how a figure writes a scene key's name: the symbols of docs/model.md (α1, not alpha1)
SYMBOLS = {
    "alpha1": "α1",
    "alpha2": "α2",
    "K_phi": "K_φ",
    "gamma_lock_deg": "γ_lock",
    "jamming_angle_deg": "θ_jam",
    "u0_mm": "u₀",
    "mesh_size_mm": "mesh size h",
    "order_u": "order p",
    "thickness_mm": "thickness t",
    "width_mm": "width W",
    "length_mm": "length L",
    "yarn_angle_deg": "yarn angle",
}


def symbol(key: str) -> str:
    """The name a figure gives a scene key: ``material.alpha1`` → "α1", ``material.K_el`` → "K_el"."""
    name = key.rsplit(".", 1)[-1]
    return SYMBOLS.get(name, name)


def unit_of(key: str) -> str:
    """The unit of a scene key ("" when it has none): ``material.alpha1`` → "Pa m²", ``loading.u0_mm`` → "mm"."""
    name = key.rsplit(".", 1)[-1]
    if name in UNITS:
        return UNITS[name]
    return next((u for suf, u in _SUFFIXES.items() if name.endswith(suf)), "")


def key_value(key: str, value: Any) -> str:
    """``α1 = 200 Pa m²``: a scene key's value with its unit (engineering notation: 3.33 MPa), for a legend."""
    from .style import eng

    unit = unit_of(key)
    if isinstance(value, (int, float)) and not isinstance(value, bool) and unit and unit not in ("°", "mm"):
        return f"{symbol(key)} = {eng(value, unit)}".replace("\u00a0", " ")
    v = f"{value:g}" if isinstance(value, float) else str(value)
    return f"{symbol(key)} = {v}" + (f" {unit}" if unit and unit != "°" else unit)


def key_label(key: str) -> str:
    """An axis label for a scene key: ``α1 [Pa m²]``."""
    unit = unit_of(key)
    return f"{symbol(key)} [{unit}]" if unit else symbol(key)
