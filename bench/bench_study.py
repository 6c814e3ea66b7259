"""Benchmark of a study's per-case overhead: what a case costs beyond its own run.

A study of ``--cases`` small continuum scenes (h = 20 mm, p = 2, u0 = 10 mm, no estimate, by
default no VTK and no plot; each case differs in α1 so that none is cached) runs with ``--workers``
local worker processes into a fresh cache. Per case, the overhead is

    (study wall time × workers − Σ case run time) / cases

where a case's run time is the ``wall_s`` of its own summary.json (mesh to summary): it holds the
process start and imports of the workers (paid once per worker, spread over its cases), sending the
scene, the cache store with its checksums, the collection and the study's tables. Printed and
written to ``bench/out/bench_study_<time>.json``.

Each repeat runs one study in a fresh process (as ``ngbet study`` does: its worker processes
start with it), so that the cost of starting the workers is in every repeat; with ``--tree
NAME=PATH`` the same study also runs with the ngbet of another source tree (on PYTHONPATH, with the
tree's own ``.venv/bin/python`` when it has one), interleaved with this one (a, b, a, b, ...).

    python bench/bench_study.py                        # 8 cases, 2 workers
    python bench/bench_study.py --cases 16 --workers 1 --outputs
    git archive REV | tar -x -C /tmp/before
    python bench/bench_study.py --repeats 5 --tree before=/tmp/before
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE / "out"


def one(args: argparse.Namespace) -> dict:
    """One study in this process; its record."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    from ngbet.scene.document import default_scene
    from ngbet.scene.validate import SceneError
    from ngbet.study.model import Study
    from ngbet.study.runner import run_study

    changes = {
        "discretization.mesh_size_mm": 20.0,
        "discretization.order_u": 2,
        "discretization.corner_mesh_size_mm": 0.0,
        "loading.u0_mm": 10.0,
        "loading.stops_mm": [],
        "outputs.vtk": args.outputs,
        "outputs.plot": args.outputs,
    }
    try:
        base = default_scene().with_changes(**changes, **{"outputs.error_estimate": "off"})
    except SceneError:  # an older tree, without the error estimate
        base = default_scene().with_changes(**changes)
    cases = [{"material.alpha1": 2000.0 + args.seed + i / 64} for i in range(args.cases)]
    with tempfile.TemporaryDirectory() as tmp:
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        data = run_study(
            Study("bench", base, cases),
            out=Path(tmp) / "out",
            cache=Path(tmp) / "cache",
            workers=args.workers,
            progress=False,
        )
        wall = time.perf_counter() - t0
        runs = [
            json.loads((Path(tmp) / "cache" / c["key"] / "summary.json").read_text())["wall_s"]
            for c in data.meta["cases"]
        ]
    return {
        "cases": args.cases,
        "workers": args.workers,
        "outputs": args.outputs,
        "study_wall_s": wall,
        "case_run_s_median": statistics.median(runs),
        "case_run_s_sum": sum(runs),
        "overhead_per_case_s": (wall * args.workers - sum(runs)) / args.cases,
        "load": load,
        "mode": data.meta.get("executor", {}).get("mode"),
    }


def main() -> None:
    """Run the study once per repeat (and tree), each in a fresh process; print the medians."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--outputs", action="store_true", help="cases write their VTK file and plot too")
    ap.add_argument(
        "--tree",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="also run the study with the ngbet of this source tree (repeatable)",
    )
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child: one study, a JSON line
    ap.add_argument("--seed", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args)), flush=True)
        return
    trees = {"this": (sys.executable, None)}
    for item in args.tree:
        name, _, path = item.partition("=")
        venv = Path(path) / ".venv" / "bin" / "python"
        trees[name] = (str(venv) if venv.exists() else sys.executable, path)
    records = []
    argv = [__file__, "--one", "--cases", str(args.cases), "--workers", str(args.workers)]
    argv += ["--outputs"] if args.outputs else []
    for rep in range(args.repeats):
        for name, (python, path) in trees.items():
            env = {**os.environ, **({"PYTHONPATH": path} if path else {})}
            out = subprocess.run(
                [python, *argv, "--seed", str(rep)], env=env, capture_output=True, text=True, check=True
            ).stdout
            records.append({"tree": name, **json.loads(out.strip().splitlines()[-1])})
            print(json.dumps(records[-1]), flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / f"bench_study_{time.strftime('%Y%m%dT%H%M%S')}.json").write_text(json.dumps(records, indent=1))
    print("\n| tree | study wall [s] | case run [s] | overhead per case [s] | load |\n|---|---|---|---|---|")
    for name in trees:
        rs = [r for r in records if r["tree"] == name]
        med = {
            k: statistics.median(r[k] for r in rs)
            for k in ("study_wall_s", "case_run_s_median", "overhead_per_case_s", "load")
        }
        print(
            f"| {name} | {med['study_wall_s']:.2f} | {med['case_run_s_median']:.3f} | "
            f"{med['overhead_per_case_s']:.3f} | {med['load']:.1f} |"
        )


if __name__ == "__main__":
    main()
