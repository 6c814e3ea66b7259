"""A scene as commented TOML (``ngbet scene``): every key with its unit, allowed values and meaning.

The comments come from the scene's own definition (ngbet/scene/: each section's docstring and
the comment beside or above each key), so a key added there is documented here without a
second list to keep. Allowed values of the keys that take one of a few words are added from the
scene's tuples of choices.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import textwrap
from typing import Any

import tomli_w

from .scene.document import MODELS, SECTIONS, Scene
from .scene.numerical import FIELD_OUTPUTS, LINEAR_SOLVERS
from .scene.physical import CONSTRAINTS, PENALTY_FORMS, TESTS

__all__ = ["HEADER", "commented_toml", "key_comments"]

HEADER = """\
# ngbet scene: a bias extension test (BET) or a picture-frame test of a woven fabric. Every key is
# optional; a missing key takes the default value (that of `ngbet run` without a scene file). Run it
# with `ngbet run this.toml`,
# or change single values with `ngbet run --set section.key=value`. The model and its conventions: docs/model.md.
#
# Units: lengths in mm (keys ending in _mm), angles in degrees (_deg), stiffnesses in SI units as
# in the paper (Pa, Pa m^2, N, N m, N/m; stated beside each key). Results are in mm and N.
# "auto", -1 or 0 where a comment says so: ngbet chooses the value from the rest of the scene
# (the comment says how); any other value is used as given.
"""

_CHOICES: dict[str, tuple[Any, ...]] = {
    "model": MODELS,
    "effects.constraint": CONSTRAINTS,
    "effects.penalty_form": PENALTY_FORMS,
    "solver.linear_solver": LINEAR_SOLVERS,
    "solver.predictor": ("tangent", "clamp"),
    "solver.path_following": ("displacement", "arclength", "auto"),
    "solver.compile": ("auto", "interpret", "native"),
    "solver.branch": ("stay", "switch"),
    "outputs.fields": FIELD_OUTPUTS,
    "discrete.inter_layout": ("neighbours", "none"),
    "discrete.end_rotation": ("free", "held"),
}

# keys whose definition carries no comment
_EXTRA = {
    "specimen.name": "a label, recorded with the results",
    "discretization.mesh_size_mm": "element size of the Netgen mesh [mm]",
    "discretization.order_u": "polynomial order p of the displacement",
    "loading.u0_mm": "final clamp displacement [mm] (the picture frame: the crosshead travel)",
    "loading.max_step_mm": "largest load step [mm]",
    "loading.min_step_mm": "smallest load step [mm]: below it the run stops with an error",
    "solver.rtol": "Newton stops when the Newton decrement is below rtol times the total energy",
    "solver.max_iterations": "Newton iterations before a step is cut",
    "solver.growth": "factor of the next load step after an easy one",
    "solver.cut": "factor of the load step after a failed attempt",
}

_MODEL_DOC = (
    '"continuum": the constrained micromorphic continuum (finite elements); '
    '"discrete": the yarn network (beams and springs)'
)

_TEST_DOC = (
    '"bias_extension": a rectangular specimen clamped at its two ends ([specimen], loading.u0_mm the clamp '
    'displacement); "picture_frame": a cross clamped in a hinged square frame pulled along its diagonal '
    "([picture_frame], loading.u0_mm the crosshead travel; continuum model only)"
)

_KEY = re.compile(r"^\s{4}(\w+)\s*:\s*[^=]+=\s*(?P<default>.*)$")


def key_comments(cls: type) -> dict[str, str]:
    """{field name: its comment} of a scene section ``cls``, read from its source.

    A field's comment is the comment lines right above it and the comment beside it, joined; a
    field without either gets an empty string. Without the source (never installed) the result is
    empty, and the scene is written without key comments.
    """
    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):  # pragma: no cover - sources not installed
        return {}
    out: dict[str, str] = {}
    above: list[str] = []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#"):
            above.append(stripped.lstrip("#").strip())
            continue
        m = _KEY.match(line)
        if m:
            beside = m.group("default").partition("  #")[2].strip()
            out[m.group(1)] = " ".join(filter(None, [" ".join(above), beside]))
        above = []
    return out


def _comment(text: str, indent: str = "") -> str:
    return "".join(f"{indent}# {t}\n" for t in textwrap.wrap(text, 96)) if text else ""


def _value(key: str, value: Any) -> str:
    return tomli_w.dumps({key: value}).strip()


def commented_toml(scene: Scene) -> str:
    """The complete scene as TOML with comments; reading it back gives the same scene."""
    d = scene.to_dict()
    parts = [
        HEADER,
        "\n",
        _comment(f"{_MODEL_DOC}; one of {', '.join(map(repr, MODELS))}"),
        _value("model", d["model"]),
        "\n",
        _comment(f"{_TEST_DOC}; one of {', '.join(map(repr, TESTS))}"),
        _value("test", d["test"]),
        "\n",
    ]
    for name, cls in SECTIONS.items():
        doc = (inspect.getdoc(cls) or "").split("\n\n")[0].replace("\n", " ")
        parts += ["\n", _comment(doc), f"[{name}]\n"]
        notes = key_comments(cls)
        for f in dataclasses.fields(cls):
            if f.name not in d[name]:
                continue
            text = notes.get(f.name) or _EXTRA.get(f"{name}.{f.name}", "")
            allowed = _CHOICES.get(f"{name}.{f.name}")
            if allowed:
                text += f"{'; ' if text else ''}allowed: {', '.join(map(repr, allowed))}"
            parts += [_comment(text), _value(f.name, d[name][f.name]), "\n"]
    return "".join(parts)
