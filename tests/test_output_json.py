"""summary.json is strict JSON: what is not a number is null, which every language's JSON reader takes."""

from __future__ import annotations

import json
import math

import numpy as np

from ngbet.output import RunWriter
from ngbet.run_folder import json_text, strict
from ngbet.scene.document import default_scene


def _reject(name: str) -> None:
    raise ValueError(f"not strict JSON: {name}")


def test_non_finite_numbers_become_null():
    data = {"a": math.nan, "b": [1.0, math.inf, np.float32(2.5), np.array([np.nan, 3.0])], "c": (np.float64(-np.inf),)}
    assert strict(data) == {"a": None, "b": [1.0, None, 2.5, [None, 3.0]], "c": [None]}
    assert json.loads(json_text(data), parse_constant=_reject)["b"][3] == [None, 3.0]


def test_a_run_folders_summary_with_nan_is_strict(tmp_path):
    with RunWriter(tmp_path / "run", default_scene()) as w:
        w.summary({"force_enriched_N": [107.3, math.nan], "ratio": float("inf")}, "ok")
    s = json.loads((tmp_path / "run" / "summary.json").read_text(), parse_constant=_reject)
    assert s["force_enriched_N"] == [107.3, None] and s["ratio"] is None
