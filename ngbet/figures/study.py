"""What the studies' figures share: the caption of the base scene and what the cases vary."""

from __future__ import annotations

from typing import Any

from .style import caption


def study_caption(meta: dict[str, Any], extra: str = "") -> str:
    """The caption line of a study's figure: specimen and material of its base scene, what the cases vary.

    ``meta``: the study's meta.json (``base_scene``, ``params``); ``extra`` is appended.
    """
    text = caption(meta.get("base_scene"))
    varied = [str(k).split(".", 1)[-1] for k in meta.get("params", [])]
    if varied:
        text += "; the cases vary " + ", ".join(varied)
    return text + (f"; {extra}" if extra else "")
