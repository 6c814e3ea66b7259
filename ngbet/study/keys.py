"""Cache keys of the cases of a study.

``key = sha256(complete scene without solver.threads, code version)``. The code version is a hash
of the ngbet sources a run executes (every ``ngbet/**/*.py`` except the study runner, the studies
and the entry points; for the continuum model without ``ngbet/discrete/``, which it never imports)
together with the versions of ngsolve, netgen, numpy and scipy. A source hash rather than the git
revision: the revision changes with every commit, also of README or tests (needless
recomputation), does not change with uncommitted edits (stale results silently reused) and does
not exist outside a checkout; the source hash has none of these faults. The thread count is left
out of the key: it changes the wall time, not the result (beyond round-off of parallel assembly),
and the runner sets it (1 per case when cases run in parallel).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..provenance import versions
from ..scene.document import Scene

__all__ = ["as_floats", "case_key", "code_version", "flat", "grid", "key_of_scene_dict", "value_text"]

_CODE_VERSION: dict[str, dict[str, str]] = {}
# modules a case's run does not execute: the runner and entry points, and the build-time revision
# (a reinstall at another commit must not invalidate the cache when no code changed)
_NOT_IN_KEY = ("cli.py", "api.py", "fit.py", "scene_doc.py", "revision.py", "_revision.py")
_DIRS_NOT_IN_KEY = ("study/", "studies/")


def code_version(model: str = "continuum") -> dict[str, str]:
    """The code a run of ``model`` executes: a hash of its ngbet sources and the library versions.

    Computed once per process, so that a study sees one consistent version even when the
    sources are edited while it runs.
    """
    if model not in _CODE_VERSION:
        pkg = Path(__file__).resolve().parent.parent
        h = hashlib.sha256()
        for path in sorted(pkg.rglob("*.py")):
            rel = path.relative_to(pkg).as_posix()
            if (
                rel in _NOT_IN_KEY
                or rel.startswith(_DIRS_NOT_IN_KEY)
                or (model != "discrete" and rel.startswith("discrete/"))
            ):
                continue
            h.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
        v = versions()
        _CODE_VERSION[model] = {
            "sources_sha256": h.hexdigest()[:16],
            "ngbet": v.get("ngbet", "?"),
            **{k: v.get(k, "?") for k in ("ngsolve", "netgen", "numpy", "scipy")},
        }
    return _CODE_VERSION[model]


def case_key(scene: Scene) -> str:
    """Cache key of a case: the complete scene (threads aside) and the code version."""
    d = scene.to_dict()
    d["solver"]["threads"] = 0
    blob = json.dumps({"scene": as_floats(d), "code": code_version(scene.model)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def key_of_scene_dict(d: dict[str, Any]) -> str:
    """:func:`case_key` of a scene given as its dict (as a case folder stores it)."""
    with warnings.catch_warnings():  # a discrete scene's unused keys were warned about when it ran
        warnings.simplefilter("ignore")
        return case_key(Scene.from_dict(d))


def as_floats(v: Any) -> Any:
    """10 and 10.0 are the same scene value: hash every number as a float."""
    if isinstance(v, dict):
        return {k: as_floats(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [as_floats(x) for x in v]
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    return v


def flat(d: dict[str, Any], pre: str = "") -> dict[str, Any]:
    """Nested tables as one table of dotted keys: ``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flat(v, f"{pre}{k}."))
        else:
            out[f"{pre}{k}"] = v
    return out


def grid(**axes: Iterable[Any]) -> list[dict[str, Any]]:
    """The cartesian product of value lists: ``grid(**{"a.b": [1, 2], "c.d": [3]})``."""
    names = list(axes)
    return [dict(zip(names, values, strict=True)) for values in itertools.product(*(list(axes[n]) for n in names))]


def value_text(v: Any) -> str:
    """A case's value as messages and reports write it: floats by ``:g``, lists in brackets, others by ``str``."""
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list):
        return "[" + ", ".join(value_text(x) for x in v) + "]"
    return str(v)
