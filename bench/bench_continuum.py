"""Benchmark of the continuum model: where the time of a BET run goes, case by case.

Every repeat of every case runs in a fresh Python process (so that the peak memory from
``resource.getrusage`` belongs to that run alone and nothing is warm from the previous one),
carries the load to u0 with :func:`ngbet.run.run` (no VTK, no plot) and reports

- total wall time of the run (mesh, spaces, continuation, observables, files) and its CPU time;
- load steps, Newton iterations, step cuts, degrees of freedom (total / factorized);
- time per Newton iteration split into assembly, factorization, solve and residual, and the cost
  of one iteration against one assembly plus one factorization (target: within 2x);
- peak resident memory, the force at the final load, the machine's load average.

Medians over ``--repeats`` are printed as a table; every single run is appended as one JSON line
to ``bench/out/bench_continuum.jsonl`` and the invocation's records to
``bench/out/bench_continuum_<time>.json`` (bench/out is ignored by git).

    python bench/bench_continuum.py                         # default scene, 3 repeats
    python bench/bench_continuum.py --cases all --repeats 5
    python bench/bench_continuum.py --cases default,penalty-full,h2.5 --set solver.threads=1
    python bench/bench_continuum.py --list

Bench-only keys: ``newton.<field>`` sets a NewtonSettings field; ``bench.assembly_threads=n`` runs
serially with each linearization on n threads whatever the load (``solver.threads = "auto"``
on an idle machine).

The machine is shared: wall times are noisy, compare medians of the same invocation and look at
``load`` (1-minute load average before each run) and at the CPU time.
"""

from __future__ import annotations

import argparse
import ast
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

#: name -> (scene changes, what it shows)
CASES: dict[str, tuple[dict, str]] = {
    "default": ({}, "paper scene: Lagrange (condensed), h = 5 mm, p = 2, u0 = 56 mm"),
    "penalty-mixed": (
        {"effects.constraint": "penalty", "effects.penalty_K": 1e8, "effects.penalty_form": "mixed"},
        "mixed penalty K = 1e8 Pa (Λ condensed)",
    ),
    "penalty-full": (
        {"effects.constraint": "penalty", "effects.penalty_K": 1e8, "effects.penalty_form": "full"},
        "full penalty K = 1e8 Pa (solved in its mixed form, Λ condensed)",
    ),
    "penalty-full-1e7": (
        {"effects.constraint": "penalty", "effects.penalty_K": 1e7, "effects.penalty_form": "full"},
        "K = 1e7 Pa, full penalty",
    ),
    "h10": ({"discretization.mesh_size_mm": 10.0}, "coarse mesh 10 mm"),
    "h2.5": ({"discretization.mesh_size_mm": 2.5}, "fine mesh 2.5 mm"),
    "h2": ({"discretization.mesh_size_mm": 2.0}, "fine mesh 2 mm (62 851 dofs; native code from the cache)"),
    "h2-interpret": (
        {"discretization.mesh_size_mm": 2.0, "solver.compile": "interpret"},
        "fine mesh 2 mm, interpreted",
    ),
    "h2-no-estimate": (
        {"discretization.mesh_size_mm": 2.0, "outputs.error_estimate": "off"},
        "fine mesh 2 mm without the error estimate (the solve alone)",
    ),
    "h2-auto-threads": (
        {"discretization.mesh_size_mm": 2.0, "solver.threads": "auto"},
        "fine mesh 2 mm, solver.threads = auto (assembly threads on idle cores)",
    ),
    "h2-threads2": (
        {"discretization.mesh_size_mm": 2.0, "solver.threads": 2, "outputs.error_estimate": "off"},
        "fine mesh 2 mm, two threads throughout, no estimate",
    ),
    "h2-split": (
        {"discretization.mesh_size_mm": 2.0, "bench.assembly_threads": 2, "outputs.error_estimate": "off"},
        "fine mesh 2 mm, no estimate, the run serial and each linearization on two threads "
        "(what solver.threads = auto does on an idle machine)",
    ),
    "p1": ({"discretization.order_u": 1}, "p = 1 (Λ order 0)"),
    "p3": ({"discretization.order_u": 3}, "p = 3"),
    "p4": ({"discretization.order_u": 4}, "p = 4"),
    "umfpack": ({"solver.linear_solver": "umfpack"}, "default scene, UMFPACK (LU) on the condensed matrix"),
    "pardiso": ({"solver.linear_solver": "pardiso"}, "default scene, PARDISO (MKL) on the condensed matrix"),
    "uncondensed": (
        {"solver.condense": False, "solver.linear_solver": "umfpack"},
        "exact saddle point, Λ not condensed, UMFPACK",
    ),
    "threads1": ({"solver.threads": 1}, "default scene on one thread"),
    "no-simplified-exit": (
        {"newton.simplified_theta": 0.0},
        "default scene without the simplified-Newton exit (a last linearization per step)",
    ),
    "steps28": (
        {"loading.first_step_mm": 16.0, "loading.max_step_mm": 28.0},
        "default scene, first step 16 mm, steps up to 28 mm (3 load steps: 16, 37, 56)",
    ),
    "recommended": (
        {"loading.first_step_mm": 16.0, "loading.max_step_mm": 28.0, "solver.threads": 1},
        "default scene with the proposed settings: steps28 on one thread",
    ),
    "recommended-penalty": (
        {
            "loading.first_step_mm": 16.0,
            "loading.max_step_mm": 28.0,
            "solver.threads": 1,
            "effects.constraint": "penalty",
            "effects.penalty_K": 1e8,
        },
        "mixed penalty K = 1e8 Pa with the proposed settings",
    ),
    "penalty-full-1e10-h10": (
        {
            "effects.constraint": "penalty",
            "effects.penalty_K": 1e10,
            "effects.penalty_form": "full",
            "discretization.mesh_size_mm": 10.0,
        },
        "full penalty K = 1e10 Pa, h = 10 mm (solved in its mixed form)",
    ),
    "penalty-full-1e10-h10-uncondensed": (
        {
            "effects.constraint": "penalty",
            "effects.penalty_K": 1e10,
            "effects.penalty_form": "full",
            "solver.condense": False,
            "discretization.mesh_size_mm": 10.0,
        },
        "full penalty K = 1e10 Pa, h = 10 mm, Λ not condensed (same solution)",
    ),
}
DEFAULT_CASES = ["default"]


def _child(case: str, extra: dict) -> dict:
    """One run in this process; returns its record."""
    import resource

    t_import = time.perf_counter()
    from ngbet.errors import ConvergenceError
    from ngbet.run import run
    from ngbet.scene.document import Scene

    t_import = time.perf_counter() - t_import
    changes = {"outputs.vtk": False, "outputs.plot": False}
    changes.update(CASES[case][0] if case in CASES else {})
    changes.update(extra)
    # "newton.*" keys are NewtonSettings fields the scene does not expose (bench-only switches)
    newton = {k.partition(".")[2]: changes.pop(k) for k in list(changes) if k.startswith("newton.")}
    split = changes.pop("bench.assembly_threads", None)
    if split:  # the run serial, each linearization on `split` threads, whatever the load
        import ngbet.runner.threads as ngbet_run_module

        ngbet_run_module.thread_policy = lambda threads, model: (1, int(split))
    if newton:
        import dataclasses

        import ngbet.runner.settings as ngbet_run

        plain = ngbet_run.newton_settings
        ngbet_run.newton_settings = lambda sc: dataclasses.replace(plain(sc), **newton)
    known = Scene().to_dict()  # an older tree (--before) lacks some keys: they are left out
    changes = {k: v for k, v in changes.items() if k.partition(".")[2] in known.get(k.partition(".")[0], {})}
    scene = Scene().with_changes(**changes)
    out = tempfile.mkdtemp(prefix="bench_continuum_")
    load = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    status, error = "ok", None
    try:
        s = run(scene, out)
    except ConvergenceError as exc:
        status, error = "failed", str(exc).splitlines()[0]
        s = json.loads((Path(out) / "summary.json").read_text())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rows = (Path(out) / "results.csv").read_text().splitlines()
    force = None
    if len(rows) > 1:
        head, last = rows[0].split(","), rows[-1].split(",")
        force = float(last[head.index("force_N")]) if "force_N" in head else None
    tm, cn = s.get("timers", {}), s.get("counts", {})
    its = max(1, s.get("newton_iterations") or 0)
    nfac = max(1, cn.get("factorizations", 1))
    per_lin = (tm.get("assembly_s", 0) + tm.get("factorization_s", 0)) / nfac
    newton_s = sum(tm.get(k, 0.0) for k in ("assembly_s", "factorization_s", "solve_s", "residual_s"))
    return {
        "case": case,
        "changes": {**changes, **{f"newton.{k}": v for k, v in newton.items()}},
        "status": status,
        "error": error,
        "wall_s": wall,
        "cpu_s": cpu,
        "import_s": t_import,
        "setup_s": s.get("setup_s"),
        "load_steps": s.get("load_steps", s.get("steps")),
        "newton_iterations": s.get("newton_iterations"),
        "step_cuts": s.get("step_cuts"),
        "u0_reached_mm": s.get("u0_reached_mm"),
        "force_N": force,
        "dofs": s.get("dofs", {}).get("total"),
        "dofs_factorized": s.get("dofs", {}).get("factorized"),
        "linear_solver": s.get("linear_solver"),
        "threads": s.get("threads"),
        "newton_s": newton_s,
        "timers": tm,
        "counts": cn,
        "per_iteration_s": {k.removesuffix("_s"): v / its for k, v in tm.items()},
        "assembly_per_linearization_s": tm.get("assembly_s", 0) / nfac,
        "factorization_per_linearization_s": tm.get("factorization_s", 0) / nfac,
        "iteration_over_linearization": (newton_s / its) / per_lin if per_lin > 0 else None,
        "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "load_avg_1min": load,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "git": s.get("git_revision"),
        "versions": s.get("versions"),
    }


def _parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def _med(records: list[dict], key: str, sub: str | None = None):
    vals = [(r[key][sub] if sub else r[key]) for r in records]
    vals = [v for v in vals if v is not None]
    return statistics.median(vals) if vals else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default=",".join(DEFAULT_CASES), help="comma-separated case names, or 'all'")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra scene change applied to every case (e.g. solver.threads=1)",
    )
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--before", metavar="DIR", help="also run each case in an older source tree (case 'before:NAME')")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    extra = _parse_sets(args.set)
    if args.child:
        print("BENCH " + json.dumps(_child(args.child, extra)), flush=True)
        return
    if args.list:
        for name, (ch, what) in CASES.items():
            print(f"{name:18s} {what}  {ch}")
        return
    names = list(CASES) if args.cases == "all" else [c.strip() for c in args.cases.split(",") if c.strip()]
    for n in names:
        if n not in CASES:
            sys.exit(f"unknown case {n!r}; known: {', '.join(CASES)}")
    OUT.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    records: list[dict] = []
    # interleave the repeats (case a, b, c, a, b, c, ...) so that a burst of load hits all cases alike
    runs = [(name, None) for name in names] + ([(name, args.before) for name in names] if args.before else [])
    for rep in range(args.repeats):
        for name, tree in runs:
            sets = [a for s in args.set for a in ("--set", s)]
            cmd = [sys.executable, str(Path(__file__).resolve()), "--child", name, *sets]
            env = {**os.environ, "PYTHONPATH": tree} if tree else None
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
            line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH ")), None)
            if line is None:
                print(f"{name}: the run crashed\n{proc.stderr[-2000:]}", file=sys.stderr)
                continue
            rec = json.loads(line[6:])
            rec["repeat"] = rep
            if tree:
                rec["case"], rec["tree"] = f"before:{name}", tree
            records.append(rec)
            with (OUT / "bench_continuum.jsonl").open("a") as fh:
                fh.write(json.dumps(rec) + "\n")
            print(
                f"  [{rep + 1}/{args.repeats}] {name}: {rec['status']} wall {rec['wall_s']:.2f} s, "
                f"newton {rec['newton_s']:.2f} s, load {rec['load_avg_1min']:.1f}",
                file=sys.stderr,
                flush=True,
            )
    (OUT / f"bench_continuum_{stamp}.json").write_text(json.dumps(records, indent=1))
    print(table(records, names + [f"before:{n}" for n in names if args.before]))


def table(records: list[dict], names: list[str]) -> str:
    head = (
        "| case | status | wall [s] | CPU [s] | Newton [s] | steps | its | it/step | dofs (fact.) | "
        "assembly/it [ms] | factor/it [ms] | solve/it [ms] | residual/it [ms] | it / (asm+fact) | "
        "peak RSS [MB] | F(u0) [N] | load |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for n in names:
        rs = [r for r in records if r["case"] == n]
        if not rs:
            continue
        st = "ok" if all(r["status"] == "ok" for r in rs) else ",".join(sorted({r["status"] for r in rs}))
        steps, its = _med(rs, "load_steps"), _med(rs, "newton_iterations")
        lines.append(
            f"| {n} | {st} | {_med(rs, 'wall_s'):.2f} | {_med(rs, 'cpu_s'):.2f} | {_med(rs, 'newton_s'):.2f} | "
            f"{steps:.0f} | {its:.0f} | {its / steps:.1f} | {rs[0]['dofs']} ({rs[0]['dofs_factorized']}) | "
            f"{1e3 * _med(rs, 'per_iteration_s', 'assembly'):.0f} | "
            f"{1e3 * _med(rs, 'per_iteration_s', 'factorization'):.0f} | "
            f"{1e3 * _med(rs, 'per_iteration_s', 'solve'):.0f} | {1e3 * _med(rs, 'per_iteration_s', 'residual'):.0f} | "
            f"{_med(rs, 'iteration_over_linearization'):.2f} | {_med(rs, 'peak_rss_MB'):.0f} | "
            f"{_med(rs, 'force_N'):.3f} | {_med(rs, 'load_avg_1min'):.1f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
