"""Benchmark of a study's per-case overhead: what a case costs beyond its own run.

A study of ``--cases`` small continuum scenes (h = 20 mm, p = 2, u0 = 10 mm, no estimate, by
default no VTK and no plot; each case differs in α1 so that none is cached) runs with ``--workers``
local worker processes into a fresh cache. Per case, the overhead is

    (study wall time × workers − Σ case run time) / cases

where a case's run time is the ``wall_s`` of its own summary.json (mesh to summary): it holds the
process start and imports of the workers (paid once per worker, spread over its cases), sending the
scene, the cache store with its checksums, the collection and the study's tables. Printed and
written to ``bench/out/bench_study_<time>.json``.

    python bench/bench_study.py                        # 8 cases, 2 workers
    python bench/bench_study.py --cases 16 --workers 1 --outputs
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE / "out"


def main() -> None:
    """Run the study once per repeat; print the overhead per case."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--outputs", action="store_true", help="cases write their VTK file and plot too")
    args = ap.parse_args()
    os.environ.setdefault("MPLBACKEND", "Agg")
    from ngbet.scene import default_scene
    from ngbet.study import Study, run_study

    base = default_scene().with_changes(**{
        "discretization.mesh_size_mm": 20.0, "discretization.order_u": 2, "discretization.corner_mesh_size_mm": 0.0,
        "loading.u0_mm": 10.0, "loading.stops_mm": [], "outputs.error_estimate": "off",
        "outputs.vtk": args.outputs, "outputs.plot": args.outputs})
    records = []
    for rep in range(args.repeats):
        cases = [{"material.alpha1": 2000.0 + rep + i / 64} for i in range(args.cases)]
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            data = run_study(Study("bench", base, cases), out=Path(tmp) / "out", cache=Path(tmp) / "cache",
                             workers=args.workers, progress=False)
            wall = time.perf_counter() - t0
            runs = [json.loads((Path(tmp) / "cache" / c["key"] / "summary.json").read_text())["wall_s"]
                    for c in data.meta["cases"]]
        rec = {"cases": args.cases, "workers": args.workers, "outputs": args.outputs, "study_wall_s": wall,
               "case_run_s_median": statistics.median(runs), "case_run_s_sum": sum(runs),
               "overhead_per_case_s": (wall * args.workers - sum(runs)) / args.cases,
               "load": os.getloadavg()[0], "mode": data.meta.get("executor", {}).get("mode")}
        records.append(rec)
        print(json.dumps(rec), flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / f"bench_study_{time.strftime('%Y%m%dT%H%M%S')}.json").write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
