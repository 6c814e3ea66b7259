"""Collecting a study: every case's rows, profiles and extracted tables into the study folder.

    <out>/results.csv       one row per case and converged load step; the varied keys are columns
    <out>/profiles.csv      mid-axis u_y per case and load step (at the study's profile stations)
    <out>/<table>.csv       extra tables of the study (outlines, ...), extracted from the cache
    <out>/meta.json         scenes, versions, git revision, machine, threads, wall times, errors

and reading it back (:func:`load`, what figures and reports use).
"""

from __future__ import annotations

import csv
import json
import logging
import time
from pathlib import Path
from typing import Any

from ..errors import NgbetError
from ..provenance import git_revision, machine, versions
from ..tables import read_profiles, read_rows
from .keys import code_version
from .model import Case, Study, StudyData

__all__ = ["CASE_COLUMNS", "TAIL_COLUMNS", "StudyFolderError", "collect", "load", "write_text"]

log = logging.getLogger(__name__)


class StudyFolderError(NgbetError):
    """A study folder that cannot be read back (meta.json missing, truncated or not a study's)."""


CASE_COLUMNS = ("case", "key", "status")
TAIL_COLUMNS = ("dofs", "case_wall_s", "threads", "error")


def collect(
    study: Study, cases: list[Case], cache: Path, out: Path, executor_info: dict[str, Any], wall_s: float
) -> StudyData:
    """Gather every case's rows, profiles, extracted tables and record; write the study folder."""
    pcols = study.params_columns()
    rows: list[dict[str, Any]] = []
    profiles: list[dict[str, Any]] = []
    tables: dict[str, list[dict[str, Any]]] = {}
    metas = []
    run_cols: list[str] = []
    for c in cases:
        run_dir = cache / c.key if c.key else None
        summary, steps = _read_case(run_dir)
        record = _case_record(c, summary, run_dir)
        rows.extend(_case_rows(c, pcols, steps, record, run_cols))
        if run_dir is not None:
            profiles.extend(_case_profiles(study, c, run_dir))
        metas.append(record)
        if study.extract is not None and run_dir is not None and record["status"] in ("ok", "failed"):
            _extract(study, c, record, run_dir, out, tables)
    _write_csv(out / "results.csv", rows, [*CASE_COLUMNS, *pcols, *run_cols, *TAIL_COLUMNS])
    _write_csv(out / "profiles.csv", profiles, ["case", "u0_mm", "X_mm", "uy_mm"])
    for name, trs in tables.items():
        _write_csv(out / f"{name}.csv", trs, _columns(trs))
    meta = {
        "study": study.name,
        "description": study.description,
        "params": pcols,
        "tables": sorted(tables),
        "base_scene": study.base.to_dict(),
        "scene_source": study.scene_source,
        "quick_left_out": study.left_out,
        "cache": str(cache.resolve()),
        "cases": metas,
        "executor": executor_info,
        "versions": versions(),
        "git_revision": git_revision(),
        "code_version": {m: code_version(m) for m in sorted({c.scene.model for c in cases if c.scene})},
        "machine": machine(),
        "wall_s": wall_s,
        "cpu_s_of_cases": sum(float(m["wall_s"] or 0) for m in metas if m["wall_s"] == m["wall_s"]),
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_text(out / "meta.json", json.dumps(meta, indent=2, default=str))
    return load(out)


def write_text(path: Path, text: str) -> None:
    """Write a file complete under a temporary name, then rename it into place (never half-written)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _read_case(run_dir: Path | None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The summary and the step rows of a case's run folder (empty when absent)."""
    summary: dict[str, Any] = {}
    steps: list[dict[str, Any]] = []
    if run_dir is not None and (run_dir / "summary.json").exists():
        summary = json.loads((run_dir / "summary.json").read_text())
    if run_dir is not None and (run_dir / "results.csv").exists():
        steps = read_rows(run_dir / "results.csv")
    return summary, steps


def _case_record(c: Case, summary: dict[str, Any], run_dir: Path | None) -> dict[str, Any]:
    """The case's entry of meta.json."""
    rec = c.record
    dofs = summary.get("dofs")
    dofs = dofs.get("total") if isinstance(dofs, dict) else dofs
    return {
        "case": c.index,
        "params": c.params,
        "key": c.key,
        "status": rec.get("status", "error"),
        "error": rec.get("error"),
        "error_type": rec.get("error_type"),
        "cached": rec.get("cached", False),
        "wall_s": summary.get("wall_s", rec.get("wall_s")),
        "threads": rec.get("threads"),
        "host": rec.get("host"),
        "dofs": dofs,
        "u0_reached_mm": summary.get("u0_reached_mm"),
        "run_dir": str(run_dir) if run_dir else None,
        "warnings": list(summary.get("warnings") or []),
        "scene": c.scene.to_dict() if c.scene is not None else None,
    }


def _case_rows(
    c: Case, pcols: list[str], steps: list[dict[str, Any]], record: dict[str, Any], run_cols: list[str]
) -> list[dict[str, Any]]:
    """The case's rows of the study's results.csv (one per step; ``run_cols`` gains new columns)."""
    base = {
        "case": c.index,
        "key": c.key or "",
        "status": record["status"],
        **{k: _cell(c.params.get(k, "")) for k in pcols},
    }
    tail = {
        "dofs": record["dofs"] if record["dofs"] is not None else "",
        "case_wall_s": record["wall_s"] if record["wall_s"] is not None else "",
        "threads": c.record.get("threads", ""),
        "error": _short(c.record.get("error")),
    }
    for s in steps:
        run_cols.extend(k for k in s if k not in run_cols)
    return [{**base, **s, **tail} for s in steps or [{}]]


def _case_profiles(study: Study, c: Case, run_dir: Path) -> list[dict[str, Any]]:
    """The case's mid-axis profiles at the study's stations."""
    if not (run_dir / "profile.csv").exists():
        return []
    out: list[dict[str, Any]] = []
    for u0, (X, uy) in read_profiles(run_dir / "profile.csv").items():
        if study.profile_stations is None or any(abs(u0 - s) < 1e-6 for s in study.profile_stations):
            out.extend({"case": c.index, "u0_mm": u0, "X_mm": x, "uy_mm": y} for x, y in zip(X, uy, strict=True))
    return out


def _extract(
    study: Study, c: Case, record: dict[str, Any], run_dir: Path, out: Path, tables: dict[str, list[dict[str, Any]]]
) -> None:
    """The study's own tables from one case; a failure is recorded, never fatal."""
    assert study.extract is not None
    try:
        for name, trs in study.extract(record, run_dir, out).items():
            tables.setdefault(name, []).extend({"case": c.index, **r} for r in trs)
    except Exception as exc:
        record["extract_error"] = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, ImportError) and exc.name:  # pyvista reads the fields
            log.warning(
                "study %s case %d: no tables from the fields: %s is not installed (pip install %s)",
                study.name,
                c.index,
                exc.name,
                exc.name,
            )
        else:
            log.warning("study %s case %d: extraction failed: %s", study.name, c.index, exc)


def _cell(v: Any) -> Any:
    return json.dumps(v) if isinstance(v, (list, tuple, dict)) else v


def _short(err: Any, n: int = 400) -> str:
    if not err:
        return ""
    s = " ".join(str(err).split())
    return s if len(s) <= n else s[: n - 3] + "..."


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    return cols


def _write_csv(path: Path, rows: list[dict[str, Any]], columns: list[str]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(v) for k, v in r.items()})
    tmp.replace(path)


def _fmt(v: Any) -> Any:
    if isinstance(v, bool):
        return v
    if isinstance(v, float) or type(v).__module__ == "numpy":
        try:
            f = float(v)
        except (TypeError, ValueError):
            return v
        return repr(int(f)) if type(v).__name__.startswith(("int", "uint")) else repr(f)
    return v


def _read_csv(path: Path) -> list[dict[str, Any]]:
    """A study CSV as rows of numbers (text kept), or no rows when the file is absent."""
    return read_rows(path) if path.exists() else []


def load(out: str | Path) -> StudyData:
    """Read a study folder back (no solving): results.csv, profiles.csv, tables, meta.json.

    A folder without a readable meta.json is a :class:`StudyFolderError` naming the file.
    """
    out = Path(out)
    path = out / "meta.json"
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError:
        raise StudyFolderError(f"no finished study in {out} ({path.name} missing)") from None
    except (OSError, ValueError) as exc:
        raise StudyFolderError(
            f"{path} is unreadable ({type(exc).__name__}: {exc}); run the study again (without --plot-only) to write it"
        ) from None
    if not isinstance(meta, dict) or not isinstance(meta.get("cases"), list):
        raise StudyFolderError(f"{path} is not a study's meta.json (no list of cases)")
    tables = {name: _read_csv(out / f"{name}.csv") for name in meta.get("tables", [])}
    return StudyData(out, _read_csv(out / "results.csv"), _read_csv(out / "profiles.csv"), tables, meta)
