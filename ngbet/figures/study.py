"""What the studies' figures share: the caption of the base scene and what the cases vary."""

from __future__ import annotations

from typing import Any

from .style import caption


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
