"""Which keys a study's cases read: a key the cases vary that none of them reads is refused.

Cases that differ only in a key their scenes do not read are the same run: a study of them
measures nothing, under a table that says otherwise. A case's scene does not read a key when its
model or its test leaves the key out (:data:`~ngbet.scene.document.NOT_READ_BY`,
:data:`~ngbet.scene.document.NOT_READ_BY_TEST`, what :meth:`Scene.unused_keys` reports), or when
the scene's choices leave it without a part in the result (:func:`not_read`). The rules depend on
the model, the test and the effects of the case's scene, never on the key's own value.

A case whose scene validation refuses is no run at all: :func:`case_scenes` refuses the study
before any case runs, naming the case, the key and why.
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from collections.abc import Sequence
from typing import Any

from ..scene.document import NOT_READ_BY, NOT_READ_BY_TEST, TOP_LEVEL, Scene, SceneWarning
from ..scene.numerical import CHOSEN_BY_TARGET
from ..scene.physical import law_leaves_unread
from ..scene.validate import SceneError
from .keys import as_floats, value_text
from .model import Study, same_value

__all__ = ["case_scenes", "check_cases_read", "elongation_not_read", "not_read"]

log = logging.getLogger(__name__)

#: the penalty's keys: read with ``effects.constraint = "penalty"`` only
PENALTY = ("effects.penalty_K", "effects.penalty_form")
#: the bending stiffnesses: no part in a homogeneous shear (the picture frame with held arms)
BENDING = ("material.alpha1", "material.alpha2")
#: the yarns' elongation stiffness: no part in a shear that does not stretch the yarns (the
#: aligned picture frame with held arms), but for the jamming barrier close to the frame's locking
ELONGATION = "material.K_el"


def not_read(scene: Scene, key: str) -> str | None:
    """Why ``scene`` does not read ``key`` (``"section.key"``), in words; None when it reads it.

    Not read: a key its model or test leaves out (as :meth:`Scene.unused_keys`); in the continuum,
    the penalty's keys under the Lagrange multiplier, a shear law's coefficients under another law,
    the discretization that ``discretization.target_error`` chooses itself, and the bending
    stiffnesses in the picture frame with held arms (the fabric in the frame shears homogeneously:
    the bending energy, made of the shear's gradient, is zero whatever their values). ``model``
    and ``test`` are always read.
    """
    if key in TOP_LEVEL:
        return None
    section, _, name = key.partition(".")
    for who, table in (
        (f"model = {scene.model!r}", NOT_READ_BY.get(scene.model, {})),
        (f"test = {scene.test!r}", NOT_READ_BY_TEST.get(scene.test, {})),
    ):
        if section in table:
            keys = table[section]
            if keys is None:
                return f"{who} does not read [{section}]"
            if name in keys:
                return f"{who} does not read {key}"
    if scene.model != "continuum":
        return None
    eff = scene.effects
    if key in PENALTY and eff.constraint != "penalty":
        return (
            f"effects.constraint = {eff.constraint!r} does not read {key}: the penalty's keys act with "
            "effects.constraint = 'penalty' only"
        )
    law = law_leaves_unread(eff, name) if section == "material" else None
    if law:
        return law
    target = scene.discretization.target_error
    if section == "discretization" and target and name in CHOSEN_BY_TARGET:
        return f"discretization.target_error = {target:g} lets ngbet choose {key} (the accuracy ladder)"
    if key in BENDING and scene.test == "picture_frame" and scene.picture_frame.arms == "held":
        return (
            "the picture frame with held arms shears the fabric homogeneously, which leaves the bending "
            "stiffnesses without a part in its result (picture_frame.arms = 'sheared' gives them one)"
        )
    if key == ELONGATION:
        return elongation_not_read(scene)
    return None


def elongation_not_read(scene: Scene) -> str | None:
    """Why the picture frame of ``scene`` leaves ``material.K_el`` without a part in its result; None otherwise.

    The frame with held arms shears its fabric homogeneously; with the yarns along the bars
    (``specimen.yarn_angle_deg`` = 45, ``picture_frame.misalignment_deg`` = 0) that shear turns
    the yarns without stretching them, so their elongation energy is zero whatever K_el. K_el
    still scales the jamming barrier (K_jam = max(K_el, K_sh)), which acts once the yarns close to
    within ``material.jamming_angle_deg`` of each other: at the frame's shear angle 90° minus that
    angle. A scene loaded to a smaller shear angle (or with ``effects.jamming`` off) does not read
    K_el; one loaded beyond, or of another test, arms or yarn angles, does (None).
    """
    if scene.model != "continuum" or scene.test != "picture_frame":
        return None
    from ..kinematics import frame_shear_angle_rad

    pf, sp, m = scene.picture_frame, scene.specimen, scene.material
    if pf.arms != "held" or pf.misalignment_deg != 0 or not math.isclose(sp.yarn_angle_deg, 45.0, abs_tol=1e-12):
        return None
    reached = math.degrees(float(frame_shear_angle_rad(scene.loading.u0_mm, pf.frame_mm)))
    jams = 90.0 - m.jamming_angle_deg
    if scene.effects.jamming and reached >= jams:
        return None
    barrier = (
        " (effects.jamming is off: no jamming barrier reads it)"
        if not scene.effects.jamming
        else f": the jamming barrier, the one term that reads it there, acts from the frame's shear angle {jams:g}° "
        f"(90° less material.jamming_angle_deg) on, and loading.u0_mm = {scene.loading.u0_mm:g} shears the "
        f"frame to {reached:.1f}°"
    )
    return (
        "the picture frame with held arms and the yarns along its bars shears the fabric without "
        f"stretching the yarns, which leaves material.K_el without a part in its result{barrier}"
    )


def case_scenes(study: Study) -> list[Scene]:
    """The scenes of the cases of ``study``, in order; a case whose scene validation refuses is refused here.

    A case ngbet cannot run would leave a hole in every table and figure of the study (and a
    report drawing conclusions from the cases that ran): a :class:`SceneError` names the first
    such case, its changes, the key and why (validation's own words), and how many more there
    are, before any case runs. Not warned about keys their model does not read, as the runner
    builds them.
    """
    out: list[Scene] = []
    refused: list[tuple[int, str]] = []
    for i, params in enumerate(study.cases):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                out.append(study.base.with_changes(**params))
        except SceneError as exc:
            refused.append((i, str(exc)))
    if refused:
        i, why = refused[0]
        what = ", ".join(f"{k} = {value_text(v)}" for k, v in study.cases[i].items()) or "the base scene"
        more = [str(j) for j, _ in refused[1:]]
        others = (
            f"; {'case' if len(more) == 1 else 'cases'} {', '.join(more[:8])}{', ...' if len(more) > 8 else ''} "
            f"{'is' if len(more) == 1 else 'are'} refused too"
            if more
            else ""
        )
        raise SceneError(f"{_who(study)} has a case ngbet refuses: case {i} ({what}): {why}{others}")
    return out


def _who(study: Study) -> str:
    """The study in words: "the sweep", or "the NAME study"."""
    return "the sweep" if study.name == "sweep" else f"the {study.name} study"


def check_cases_read(study: Study, scenes: Sequence[Scene | None]) -> None:
    """Refuse a key the cases of ``study`` vary that none of the cases setting it reads.

    ``scenes``: the cases' scenes, in the order of ``study.cases`` (None: a scene refused by
    validation, left out). Cases that do not read a key (:func:`not_read`) and differ in it alone
    are the same run. When none of the cases that set the key reads it and such cases exist: a
    :class:`SceneError` naming the key, its values, why and those cases. When some of the cases
    read it (a grid over the model, say), a warning names the cases that are the same run; a key
    that rides along with other changes (each case its own specimen) is not named.
    """
    who = _who(study)
    for key in study.params_columns():
        setting = [
            (i, sc) for i, (p, sc) in enumerate(zip(study.cases, scenes, strict=True)) if key in p and sc is not None
        ]
        why = {i: reason for i, sc in setting if (reason := not_read(sc, key)) is not None}
        same = _same_runs(study.cases, key, list(why))
        if not same:
            continue
        reasons = "; ".join(dict.fromkeys(why.values()))
        runs = _groups_text(same)
        if len(why) == len(setting):
            values = list(dict.fromkeys(value_text(study.cases[i][key]) for i in why))
            shown = ", ".join(values[:6]) + (", ..." if len(values) > 6 else "")
            raise SceneError(f"{who} varies {key} ({shown}), but none of its cases reads it: {reasons}; {runs}")
        log.warning("%s varies %s, which some cases do not read (%s): %s", who, key, reasons, runs)


def _groups_text(groups: list[list[int]]) -> str:
    """``[[0, 2], [1, 3]]`` -> "cases 0 and 2 would be the same run, and so would cases 1 and 3"."""

    def one(g: list[int]) -> str:
        shown = [str(i) for i in g[:8]] + (["..."] if len(g) > 8 else [])
        return f"cases {', '.join(shown[:-1])} and {shown[-1]}"

    more = "".join(f", and so would {one(g)}" for g in groups[1:3]) + (", ..." if len(groups) > 3 else "")
    return f"{one(groups[0])} would be the same run{more}"


def _same_runs(cases: list[dict[str, Any]], key: str, unread: list[int]) -> list[list[int]]:
    """The groups of the cases ``unread`` that differ from each other in ``key`` alone (each in order)."""
    groups: dict[str, list[int]] = {}
    for i in unread:
        rest = {k: v for k, v in cases[i].items() if k != key}
        groups.setdefault(json.dumps(as_floats(rest), sort_keys=True, default=str), []).append(i)
    out: list[list[int]] = []
    for members in groups.values():
        values: list[Any] = []
        for i in members:
            if not any(same_value(cases[i][key], v) for v in values):
                values.append(cases[i][key])
        if len(values) > 1:
            out.append(members)
    return out
