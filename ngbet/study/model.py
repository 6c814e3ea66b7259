"""What a study is and what it wrote.

:class:`Study`: a base scene, its cases, figures and report; :class:`StudyData`: its tables and
meta.json read back.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from ..scene.document import Scene

__all__ = ["Case", "Extract", "MissingValueError", "Study", "StudyData", "same_value"]


class MissingValueError(ValueError):
    """A value a study's reference, error or front needs is missing or nan.

    Nothing is computed from it; the report says which case and value instead.
    """


@dataclass
class StudyData:
    """Everything a study wrote, read back from its folder (what figures and reports use)."""

    out: Path
    rows: list[dict[str, Any]]
    profiles: list[dict[str, Any]]
    tables: dict[str, list[dict[str, Any]]]
    meta: dict[str, Any]

    def case_rows(self, case: int) -> list[dict[str, Any]]:
        """The load-step rows of a case (rows without a load left out)."""
        return [r for r in self.rows if int(r["case"]) == case and r.get("u0_mm") not in ("", None)]

    def cases(self) -> list[dict[str, Any]]:
        """The case records of meta.json (index, parameters, key, status)."""
        return cast("list[dict[str, Any]]", self.meta["cases"])

    def at(self, case: int, u0_mm: float, col: str) -> float:
        """Value of ``col`` of a case at the load step u0 (nan when not reached)."""
        for r in self.case_rows(case):
            if isinstance(r["u0_mm"], float) and abs(r["u0_mm"] - u0_mm) < 1e-6:
                v = r.get(col)
                return float(v) if isinstance(v, (int, float)) else math.nan
        return math.nan

    def profile(self, case: int, u0_mm: float) -> tuple[list[float], list[float]]:
        """The mid-axis profile (X [mm], u_y [mm]) of a case at the load u0."""
        X, uy = [], []
        for r in self.profiles:
            if int(r["case"]) == case and abs(float(r["u0_mm"]) - u0_mm) < 1e-6:
                X.append(float(r["X_mm"]))
                uy.append(float(r["uy_mm"]))
        return X, uy

    def find(self, **params: Any) -> list[int]:
        """Indices of the cases whose parameters are exactly ``params`` (dotted keys with '.' or '__').

        Exactly: the same keys with the same values (10 and 10.0 are the same value); a case that
        sets one more key is another case, never a match.
        """
        want = {k.replace("__", "."): v for k, v in params.items()}
        return [
            c["case"]
            for c in self.cases()
            if set(c["params"]) == set(want) and all(same_value(c["params"][k], v) for k, v in want.items())
        ]

    def case(self, params: dict[str, Any]) -> int | None:
        """The index of the case whose parameters are exactly ``params`` (None when the study has none)."""
        found = self.find(**params)
        return found[0] if found else None


def same_value(a: Any, b: Any) -> bool:
    """Whether two scene values are the same: numbers equal to 1e-12 relative (10 and 10.0 alike), others by ``==``."""
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0) or a == b
    return cast(bool, a == b)


Extract = Callable[[dict[str, Any], Path, Path], dict[str, list[dict[str, Any]]]]


@dataclass
class Study:
    """A named list of scene variants over a base scene, with its figures and report.

    cases : dicts of :meth:`Scene.with_changes` keys; every key used by any case becomes a
        column of results.csv.
    extract(case_record, run_dir, out) : extra rows (by table name) read from a case's run folder
        (e.g. outlines from its VTK file); it may also copy files into ``out``.
    plot(data) : draws the figures from a :class:`StudyData`; returns their paths.
    report(data) : the study's numbers as Markdown text (written to report.md and printed).
    profile_stations : loads [mm] whose mid-axis profiles go into profiles.csv (None: all steps).
    scene_source : where the base scene came from, as the report names it ("" : ngbet's default scene).
    left_out : what a ``--quick`` version leaves out of the full study (see :func:`left_out`).
    """

    name: str
    base: Scene
    cases: list[dict[str, Any]]
    description: str = ""
    extract: Extract | None = None
    plot: Callable[[StudyData], list[Path]] | None = None
    report: Callable[[StudyData], str] | None = None
    profile_stations: tuple[float, ...] | None = None
    scene_source: str = ""
    left_out: list[str] = field(default_factory=list)

    def params_columns(self) -> list[str]:
        """The parameter keys of all cases, in the order they first appear."""
        cols: list[str] = []
        for c in self.cases:
            for k in c:
                if k not in cols:
                    cols.append(k)
        return cols


@dataclass
class Case:
    """One case of a running study: its index, parameters, scene and key (None: refused), its record."""

    index: int
    params: dict[str, Any]
    scene: Scene | None
    key: str | None
    record: dict[str, Any] = field(default_factory=dict)
