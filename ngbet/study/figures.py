"""A study's figures (PNG + PDF, by :mod:`ngbet.figures`) and report.md, drawn from its folder's CSV files alone."""

from __future__ import annotations

import importlib.util
import json
import logging
from pathlib import Path
from typing import Any

from .collect import load, write_text
from .model import MissingValueError, Study, StudyData

__all__ = ["finish", "plot_only", "savefig"]

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

    The folder must be this study's (:class:`~ngbet.run_folder.OwnedFolder`: another study's or a
    run folder is refused, :class:`~ngbet.run_folder.OutputError`); nothing in it is removed.
    """
    from ..run_folder import OwnedFolder

    if not Path(out).is_dir():
        load(out)  # names what is missing; nothing is created
    own = OwnedFolder(out, "study", study.name)
    try:
        data = load(out)
        finish(study, data)
        own.finish(stale=False)
    finally:
        own.release()
    return data


def savefig(fig: Any, out: Path, name: str) -> Path:
    """Write a study's figure as PNG and PDF (:func:`ngbet.figures.style.save`); returns the PNG path."""
    from ..figures.style import STUDY_FORMATS, save

    return save(fig, out, name, STUDY_FORMATS)
