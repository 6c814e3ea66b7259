"""What the folder of ``ngbet fit`` says while a fit runs, and after one that did not end.

A fit into a folder that holds an earlier complete fit first sets that fit's files aside under
:data:`EARLIER` + their names (earlier_fit.json, earlier_fitted_scene.toml, ...) and writes a
fit.json of status "running" (:func:`begin`): at every moment the folder's fit.json is this
command's, and no earlier result stands under the name of a current one, also where the process
is killed. The fit done, its files replace the record and the set-aside files go
(:meth:`ngbet.run_folder.OwnedFolder.finish`). Ended by Ctrl-C or an error before its results,
fit.json says "interrupted" or "failed" with what the fit had done (:func:`unfinished`: the model
runs, the lowest cost so far and its values), and the earlier fit stays set aside.

An earlier fit whose fit.json says "running", "interrupted" or "failed" left no results: its
record is replaced, and the earlier complete fit it had set aside stays so.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..run_folder import OwnedFolder, json_text

__all__ = ["EARLIER", "UNFINISHED", "FitState", "begin", "unfinished"]

#: the prefix of an earlier complete fit's files, set aside while a fit runs
EARLIER = "earlier_"
#: the statuses of a fit.json that holds no results (a fit that did not end)
UNFINISHED = ("running", "interrupted", "failed")


@dataclass
class FitState:
    """What a fit has done so far: kept up to date at each evaluation of its residuals.

    ``runs`` model runs; the lowest cost Σe² evaluated (``cost``, under the weights and on the
    rungs of its moment) at the parameter values ``values`` (of ``names``; ``start`` the start
    values), with each curve's (``labels``) RMS relative error ``rms`` there. Not a fit: no search
    ended there, and no estimate vouches for its discretization.
    """

    names: list[str] = field(default_factory=list)
    start: list[float] = field(default_factory=list)
    labels: list[str] = field(default_factory=list)
    runs: int = 0
    cost: float = math.inf
    values: list[float] = field(default_factory=list)
    rms: list[float] = field(default_factory=list)
    t0: float = field(default_factory=time.perf_counter)

    def seen(self, runs: int, theta: np.ndarray, cost: float, rms: list[float]) -> None:
        """Record an evaluation: ``runs`` so far, the cost at θ = ln p and each curve's RMS relative error there."""
        self.runs = runs
        if cost < self.cost:
            self.cost, self.values, self.rms = cost, np.exp(theta).tolist(), list(rms)

    def to_json(self) -> dict[str, Any]:
        """The record of the fit so far (part of an unfinished fit's fit.json)."""
        seen = bool(self.values)
        return {
            "model_runs": self.runs,
            "wall_s": time.perf_counter() - self.t0,
            "lowest_cost": self.cost if seen else None,
            "parameters": {
                n: {"start": s, "at_lowest_cost": self.values[k] if seen else None}
                for k, (n, s) in enumerate(zip(self.names, self.start, strict=True))
            },
            "rms_relative_error_at_lowest_cost": dict(zip(self.labels, self.rms, strict=False)),
            "note": "not a fit: the search did not end, and no estimate vouches for the discretization there",
        }


def _status(out: Path) -> str:
    """The status of the fit.json in ``out``: "done" for a complete fit (and for one that names no status)."""
    try:
        doc = json.loads((out / "fit.json").read_text())
    except (OSError, ValueError):
        return "done"  # unreadable: kept as the earlier fit's, as it is
    return str(doc.get("status", "done")) if isinstance(doc, dict) else "done"


def begin(folder: OwnedFolder, data: list[str]) -> list[str]:
    """Set an earlier complete fit's files aside and write fit.json "running" (the data files ``data``).

    Returns the names the earlier fit's files now have (none where the folder held no complete fit).
    """
    out = folder.out
    aside: list[str] = []
    if "fit.json" in folder.previous and (out / "fit.json").is_file() and _status(out) not in UNFINISHED:
        folder.remove(*(n for n in folder.previous if n.startswith(EARLIER)))  # an older fit's: superseded
        aside = folder.set_aside([n for n in folder.previous if not n.startswith(EARLIER)], EARLIER)
    else:
        aside = sorted(n for n in folder.previous if n.startswith(EARLIER) and (out / n).is_file())
    _write(folder, {"status": "running", "pid": os.getpid(), "data": data, "earlier_fit": aside})
    return aside


def unfinished(folder: OwnedFolder, state: FitState, data: list[str], status: str, why: str) -> None:
    """fit.json of a fit ended before its results: ``status`` ("interrupted", "failed"), ``why``, the fit so far."""
    aside = sorted(n for n in folder.previous if n.startswith(EARLIER) and (folder.out / n).is_file())
    doc = {"status": status, "why": why, "converged": False, "data": data, **state.to_json(), "earlier_fit": aside}
    _write(folder, doc)


def _write(folder: OwnedFolder, doc: dict[str, Any]) -> None:
    folder.write("fit.json", lambda p: p.write_text(json_text(doc)))
    folder.register()
