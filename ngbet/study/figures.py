"""A study's figures (PNG + PDF, by :mod:`ngbet.figures`) and report.md, drawn from its folder's CSV files alone."""

from __future__ import annotations

import importlib.util
import json
import logging
from pathlib import Path
from typing import Any

from .collect import load, write_text
from .keys import as_floats, flat, value_text
from .model import MissingValueError, Study, StudyData

__all__ = ["finish", "held_elsewhere", "plot_only", "savefig"]

log = logging.getLogger(__name__)


def finish(study: Study, data: StudyData) -> list[Path]:
    """Figures (PNG + PDF) and report.md from the study folder's CSV files.

    Without matplotlib the figures are skipped and meta.json says so (``figures_skipped``); the
    tables and the report are written all the same.
    """
    figs: list[Path] = []
    if study.plot is not None and importlib.util.find_spec("matplotlib") is None:
        data.meta["figures_skipped"] = "matplotlib is not installed (pip install matplotlib)"
        log.info("study %s: figures skipped: %s", study.name, data.meta["figures_skipped"])
    elif study.plot is not None:
        from ..figures.style import in_style

        try:
            with in_style():  # the one style of ngbet's figures
                figs = list(study.plot(data) or [])
        except MissingValueError as exc:
            data.meta["report_error"] = str(exc)
            log.error("study %s: no figures: %s", study.name, exc)
    if study.report is not None:
        try:
            text = study.report(data)
        except MissingValueError as exc:  # no report from incomplete data, and no figure either
            text = f"# {study.name}: no report\n\n{exc}\n"
            data.meta["report_error"] = str(exc)
            log.error("study %s: no report: %s", study.name, exc)
        write_text(data.out / "report.md", text)
    if data.meta.get("report_error") or data.meta.get("figures_skipped"):  # meta.json says so too
        write_text(data.out / "meta.json", json.dumps(data.meta, indent=2, default=str))
    return figs


def plot_only(study: Study, out: str | Path) -> StudyData:
    """Redraw figures and report from the CSV files of a finished study, without solving.

    The folder must hold ``study`` itself: another study's folder or a run folder is refused
    (:class:`~ngbet.run_folder.OwnedFolder`), and so is the folder of this study run with other
    cases or on another base scene (:func:`held_elsewhere`); both are an
    :class:`~ngbet.run_folder.OutputError` naming what the folder holds, before anything is drawn.
    Nothing in the folder is removed.
    """
    from ..run_folder import OutputError, OwnedFolder

    if not Path(out).is_dir():
        load(out)  # names what is missing; nothing is created
    own = OwnedFolder(out, "study", study.name)
    try:
        data = load(out)
        other = held_elsewhere(study, data.meta)
        if other:
            raise OutputError(
                out,
                f"{other}; --plot-only redraws the study a folder holds: give the arguments it ran with, or "
                "run this one without --plot-only (into another --out)",
            )
        finish(study, data)
        own.finish(stale=False)
    finally:
        own.release()
    return data


def held_elsewhere(study: Study, meta: dict[str, Any]) -> str:
    """How the study recorded in ``meta`` (a study folder's meta.json) differs from ``study``; "" when it is it.

    A study is its name, its cases (their scene changes, in order) and its base scene: together
    they make every case's scene. Numbers compare as numbers (10 and 10.0 alike); a base-scene key
    the folder's study does not record (written by an older ngbet) and ``solver.threads`` are not
    compared.
    """
    name = meta.get("study")
    if name != study.name:
        return f"it holds the study {name!r}, not {study.name!r}"
    who = "the sweep" if name == "sweep" else f"the {name} study"
    quick = bool(meta.get("quick_left_out"))
    hint = f" (it ran {'with' if quick else 'without'} --quick)" if quick != bool(study.left_out) else ""
    there = [as_floats(c.get("params")) for c in meta["cases"]]
    asked = [as_floats(c) for c in study.cases]
    if there != asked:
        return f"it holds {who} of {_cases_text(there)}{hint}, not of {_cases_text(asked)}"
    mine, theirs = flat(as_floats(study.base.to_dict())), flat(as_floats(meta.get("base_scene") or {}))
    diff = [k for k in mine if k in theirs and k != "solver.threads" and mine[k] != theirs[k]]
    if diff:
        shown = ", ".join(f"{k} = {value_text(theirs[k])} (asked: {value_text(mine[k])})" for k in diff[:4])
        return f"it holds {who} on another base scene{hint}: {shown}{', ...' if len(diff) > 4 else ''}"
    return ""


def _cases_text(cases: list[Any]) -> str:
    """The cases of a study in words: how many, and the values each key takes."""
    keys = list(dict.fromkeys(k for c in cases if isinstance(c, dict) for k in c))
    values = {k: list(dict.fromkeys(value_text(c[k]) for c in cases if isinstance(c, dict) and k in c)) for k in keys}
    varied = "; ".join(f"{k} = {', '.join(v[:6])}{', ...' if len(v) > 6 else ''}" for k, v in values.items())
    return f"{len(cases)} case{'s' if len(cases) != 1 else ''}" + (f" ({varied})" if varied else "")


def savefig(fig: Any, out: Path, name: str) -> Path:
    """Write a study's figure as PNG and PDF (:func:`ngbet.figures.style.save`); returns the PNG path."""
    from ..figures.style import STUDY_FORMATS, save

    return save(fig, out, name, STUDY_FORMATS)
