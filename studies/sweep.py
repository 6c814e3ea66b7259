"""A sweep from the command line: the base scene run once for every combination of the given values.

    ngbet sweep material.alpha1=20,200,2000 [scene.toml] [--set section.key=value ...] [--quick]

The table (results.csv, profiles.csv), meta.json, figures and report are those of any study:
``sweep_force`` ((a) force against the load, one curve per case; (b) the profile u_y at the
final load) and, for one numeric key, ``sweep_values`` (the final force against the swept value).
The report gives the force at every load stop and at the final load, with the run's own error
estimate where the scene asks for one. A sweep serves both tests, in each test's words
(:func:`words`): the bias extension test's clamp force against the clamp displacement u₀ and
mid-axis profile (Y = W/2); the picture frame's crosshead force F against the crosshead travel d
and profile on the loading diagonal (Y = 0), as the run's own figures name them.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.figures.study import key_label
from ngbet.scene.document import Scene, SceneWarning, default_scene
from ngbet.scene.validate import SceneError
from ngbet.study.figures import savefig
from ngbet.study.keys import grid, value_text
from ngbet.study.model import Study, StudyData, same_value

from . import _common as C
from . import reference as R

__all__ = ["Words", "build", "parse_items", "plot", "report", "words"]


def parse_items(items: list[str], parse: Callable[[str], Any]) -> tuple[dict[str, list[Any]], str | None]:
    """``["a.b=1,2", "scene.toml"]`` -> ({"a.b": [1, 2]}, "scene.toml"); values read by ``parse``.

    Commas inside brackets belong to a value (``loading.stops_mm=[10,20],[37]``). A key given in
    two items, or a value given twice for one key (20 and 20.0 alike), is a :class:`SceneError`
    naming it: the sweep would hold fewer cases than written.
    """
    axes: dict[str, list[Any]] = {}
    scene = None
    for item in items:
        key, sep, values = item.partition("=")
        if not sep:
            if scene is not None:
                raise SceneError(f"two scene files ({scene}, {item}); a swept key is written section.key=v1,v2")
            scene = item
            continue
        key = key.strip()
        if "." not in key and key != "model":
            raise SceneError(f"a swept key is section.key or model, got {key!r}")
        parts = [v.strip() for v in re.split(r",(?![^\[]*\])", values) if v.strip()]
        if not parts:
            raise SceneError(f"no values for {key}")
        if key in axes:
            raise SceneError(
                f"{key} is given twice ({key}={values.strip()} after {key}={_joined(axes[key])}): give each "
                "swept key once, with all its values (section.key=v1,v2,...)"
            )
        axis = axes[key] = []
        for text, v in zip(parts, map(parse, parts), strict=True):
            if any(same_value(v, w) for w in axis):
                raise SceneError(f"{key}={values.strip()}: the value {text} is given twice; give each value once")
            axis.append(v)
    if not axes:
        raise SceneError("nothing to sweep: give section.key=v1,v2,... (e.g. material.alpha1=20,200,2000)")
    return axes, scene


def _joined(values: list[Any]) -> str:
    return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values)


def build(axes: dict[str, list[Any]], quick: bool = False, scene: Scene | None = None) -> Study:
    """The sweep as a study; a value the scene refuses is a :class:`SceneError` naming it (before any run).

    A swept key that no case reads is refused where the study runs
    (:func:`ngbet.study.reads.check_cases_read`), also by name.
    """
    # the force figure draws whole curves: the scene's output grid (the other studies report at stops only)
    every = (scene if scene is not None else default_scene()).loading.output_every_mm
    base = C.study_scene(scene, quick, {"loading.output_every_mm": every})
    cases = grid(**axes)
    for case in cases:
        try:
            with warnings.catch_warnings():  # a key the cases do not read: refused by name when the sweep runs
                warnings.simplefilter("ignore", SceneWarning)
                base.with_changes(**case)
        except SceneError as exc:
            raise SceneError(f"{', '.join(f'{k} = {v}' for k, v in case.items())}: {exc}") from None
    # the load stops and the final load: each case's own where the sweep varies it
    finals = [float(c[U0]) for c in cases if U0 in c] or [base.loading.u0_mm]
    stations = tuple(dict.fromkeys((*base.loading.stops_mm, *finals)))
    return Study(
        "sweep",
        base,
        cases,
        description=__doc__ or "",
        plot=lambda d: plot(d, quick),
        report=lambda d: report(d, quick),
        profile_stations=stations,
    )


U0 = C.U0


@dataclass(frozen=True)
class Words:
    """What a sweep's figures and report call the load, the force and the profile of its scene's test."""

    load: str  # the load's symbol: "u₀", or "d"
    load_label: str  # the load's axis label
    force_label: str  # the force's axis label
    force: str  # the force in a title
    profile_x: str  # the profile's axis label
    profile: str  # the profile in a title or a column
    per_case: str  # each case's own final load
    at: str  # before a load in a table's column: "", or "d = "
    where: str  # where the profile is, in a table's column: "", or " on the loading diagonal"


def words(data: StudyData) -> Words:
    """The words of the sweep's test: the bias extension test's, or the picture frame's (those of its run's figures)."""
    from ngbet.figures.style import FORCE_LABEL, U0_LABEL

    if data.meta["base_scene"].get("test") == "picture_frame":
        from ngbet.figures.frame import TRAVEL_LABEL

        return Words(
            "d",
            TRAVEL_LABEL,
            "crosshead force F [N]",
            "crosshead force",
            "reference position X on the loading diagonal Y = 0 [mm]",
            "profile on the loading diagonal",
            "each case's final crosshead travel",
            "d = ",
            " on the loading diagonal",
        )
    return Words(
        "u₀",
        U0_LABEL,
        FORCE_LABEL,
        "force",
        "reference position X on the mid-axis Y = W/2 [mm]",
        "mid-axis profile",
        "each case's final load",
        "",
        "",
    )


def _stations(data: StudyData) -> list[float]:
    """The loads of the report's columns: the stops and the final load (every case's, where swept)."""
    lo = data.meta["base_scene"]["loading"]
    finals = [float(c["params"][U0]) for c in data.cases() if U0 in c["params"]] or [lo["u0_mm"]]
    return list(dict.fromkeys([*lo["stops_mm"], *sorted(finals)]))


def _last(case: dict[str, Any], st: list[float]) -> float:
    """A case's final load [mm]: its own where the sweep varies it."""
    return float(case["params"].get(U0, st[-1]))


def _name(params: dict[str, Any]) -> str:
    from ngbet.figures.study import key_value

    return ", ".join(key_value(k, v) for k, v in params.items())


def report(data: StudyData, quick: bool) -> str:
    keys = data.meta["params"]
    st = _stations(data)
    w = words(data)
    L = [
        *C.header(data, "Sweep of " + ", ".join(keys), R.reference_text(data, quick)),
        "| "
        + " | ".join(keys)
        + " | status | "
        + " | ".join(f"F({w.at}{s:g} mm) [N]" for s in st)
        + f" | max abs(u_y){w.where} at the last load [mm] | dofs | wall time [s] |",
        "|" + "---|" * (len(keys) + len(st) + 4),
    ]
    for c in data.cases():
        i = c["case"]
        cells = []
        for s in st:
            F, err = data.at(i, s, "force_N"), data.at(i, s, "force_error_N")
            cells.append(C.fmt(F, ".4f") + (f" ± {err:.2g}" if math.isfinite(err) else ""))
        _, uy = data.profile(i, _last(c, st))
        amp = float(np.max(np.abs(uy))) if uy else math.nan
        L.append(
            "| "
            + " | ".join(
                C.fmt(c["params"][k], "g") if isinstance(c["params"][k], float) else str(c["params"][k]) for k in keys
            )
            + f" | {c['status']} | "
            + " | ".join(cells)
            + f" | {C.fmt(amp, '.4g')} | "
            f"{C.fmt(C.dofs(data, i), '.0f')} | {C.fmt(C.wall(data, i), '.2f')} |"
        )
    if w.at:
        L += [
            "",
            "F: the crosshead force at the crosshead travel d; u_y on the loading diagonal Y = 0 (the pins' line).",
        ]
    if any(math.isfinite(data.at(c["case"], s, "force_error_N")) for c in data.cases() for s in st):
        L += ["", "± : the run's estimate of its discretization error (outputs.error_estimate)."]
    return "\n".join(L) + "\n"


def plot(data: StudyData, quick: bool) -> list[Path]:
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    st = _stations(data)
    w = words(data)
    cases = [c for c in data.cases() if data.case_rows(c["case"])]
    if not cases:  # nothing converged: the report says why, there is nothing to draw
        return []
    looks = _looks(cases, data.meta["params"])
    fig, axs = subplots(1, 2, size=(12, 4.5))
    for c in cases:
        rows = data.case_rows(c["case"])
        colour, style = looks[c["case"]]
        axs[0].plot(
            [0.0] + [r["u0_mm"] for r in rows],
            [0.0] + [r["force_N"] for r in rows],
            marker="o",
            ls=style,
            ms=2.5,
            color=colour,
            label=_name(c["params"]),
        )
        X, uy = data.profile(c["case"], _last(c, st))
        axs[1].plot(X, uy, color=colour, ls=style)
    axs[0].set_xlabel(w.load_label)
    axs[0].set_ylabel(w.force_label)
    axs[0].set_xlim(left=0)
    axs[0].set_title(f"(a) {w.force} (points: the output loads)")
    axs[1].set_xlabel(w.profile_x)
    axs[1].set_ylabel("vertical displacement u_y [mm]")
    axs[1].set_title(
        f"(b) {w.profile} at {w.per_case}"
        if U0 in data.meta["params"]
        else f"(b) {w.profile} at {w.load} = {st[-1]:g} mm"
    )
    axs[1].axhline(0, color="k", lw=0.5)
    legend_below(fig, ncol=min(len(cases), 4))
    put_caption(fig, study_caption(data.meta))
    out = [savefig(fig, data.out, "sweep_force")]
    keys = data.meta["params"]
    vals = [c["params"][keys[0]] for c in data.cases()]
    if len(keys) == 1 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
        out.append(_plot_values(data, keys[0], st[-1]))
    return out


#: line styles of the values of a sweep's second key (and further keys), in turn
_STYLES = ("-", "--", ":", "-.")


def _looks(cases: list[dict[str, Any]], keys: list[str]) -> dict[Any, tuple[Any, Any]]:
    """(colour, line style) of each case: the colour from the first swept key's value, the style from the others'.

    The colour stands for one key and the line style for the others, so that the cases of a sweep
    of two keys are told apart (on one scale of colours neighbouring cases of different keys look
    alike). Keys a case lacks count as one value.
    """
    cmap = C.colormap()
    firsts = list(dict.fromkeys(value_text(c["params"].get(keys[0])) for c in cases))
    rests = list(dict.fromkeys(tuple(value_text(c["params"].get(k)) for k in keys[1:]) for c in cases))
    looks = {}
    for c in cases:
        i = firsts.index(value_text(c["params"].get(keys[0])))
        j = rests.index(tuple(value_text(c["params"].get(k)) for k in keys[1:]))
        dashes = _STYLES[j] if j < len(_STYLES) else (0, (1 + j, 1, 1, 1))
        looks[c["case"]] = (cmap(i / max(len(firsts) - 1, 1)), dashes)
    return looks


def _plot_values(data: StudyData, key: str, u0: float) -> Path:
    """The final force against the swept value (log axis when the values span more than a decade)."""
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import put_caption, subplots

    own = key == U0  # each case's force at its own final load
    pts = sorted(
        (
            float(c["params"][key]),
            *(data.at(c["case"], float(c["params"][key]) if own else u0, col) for col in ("force_N", "force_error_N")),
        )
        for c in data.cases()
    )
    pts = [p for p in pts if math.isfinite(p[1])]
    fig, ax = subplots(size=(6, 4.2))
    v, F, e = (np.array(x) for x in zip(*pts, strict=True)) if pts else (np.array([]),) * 3
    if np.isfinite(e).any():
        ax.errorbar(
            v, F, yerr=np.where(np.isfinite(e), e, 0.0), fmt="o-", capsize=4, label="force ± the run's error estimate"
        )
        ax.legend(fontsize=8)
    else:
        ax.plot(v, F, "o-")
    if len(v) and v.min() > 0 and v.max() / v.min() > 10:
        ax.set_xscale("log")
    ax.set_xlabel(key_label(key))
    w = words(data)
    ax.set_ylabel(f"{w.force} at the final load [N]" if own else f"{w.force} at {w.load} = {u0:g} mm [N]")
    ax.grid(alpha=0.3, which="both")
    put_caption(fig, study_caption(data.meta))
    return savefig(fig, data.out, "sweep_values")
