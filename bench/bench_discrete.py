"""Benchmark of the discrete model: time per Newton iteration, split into assembly and factorization.

For a BET network (default spacing 2.4 mm: about 17,000 unknowns) at a deformed state (a converged
u0 = 20 mm solution), time over ``--repeats`` repeats (medians reported):

- assembly: energy, gradient and Hessian (element kernels + bincount into the fixed CSR pattern);
- factorization + one solve of the free block with each linear solver backend: CHOLMOD's
  supernodal LL^T through cvxopt (``cholmod``, when installed), NGSolve
  sparsecholesky with the pattern analysed once and values updated in place (``Update()``) on one
  and on two NGSolve threads (TaskManager), NGSolve umfpack / pardiso when available (one thread),
  scipy SuperLU (``splu``) from scratch;
- the stability check (block shift-invert Lanczos with the factorization already made, cold start
  and warm start from the modes of a nearby state, against ARPACK's shift-invert ``eigsh``);
- the time per Newton iteration = assembly + factorization + solve (sparsecholesky, 1 and 2 threads);
- optionally (``--run``) complete BET runs to u0 = 56 mm, one per entry of ``--threads`` and
  repeat, interleaved (1, 2, 1, 2, ...: a burst of load on the shared machine hits both alike):
  wall time, steps, Newton iterations, factorizations, snap events, F(37), F(56), largest slip,
  and where the factorizations, the solves and the time went (converged steps, failed attempts,
  steps cut at an indefinite tangent, snap bracketing, relaxations, escapes, stability checks);
  ``--run-only`` skips the per-iteration part; ``--linear-solver`` sets ``solver.linear_solver``
  of the full runs (default "auto": CHOLMOD where cvxopt is installed).

All backends must give the same solution (relative difference reported). A JSON record goes to
bench/out/ (ignored by git).

    python bench/bench_discrete.py [--spacing 2.4] [--repeats 5] [--run [--threads 1,2] [--run-repeats 1]
                                   [--linear-solver auto]]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import time
from functools import partial
from pathlib import Path

import ngsolve as ngs
import numpy as np

from ngbet.discrete.eigen import lowest_eigenvalues, lowest_eigenvalues_arpack
from ngbet.discrete.linsolve import FreeBlockSolver, LinearSolverError
from ngbet.discrete.model import NetworkModel
from ngbet.discrete.solver import load_steps
from ngbet.provenance import machine, versions
from ngbet.runner.settings import step_control
from ngbet.runner.threads import single_threaded_blas
from ngbet.scene.document import Scene
from ngbet.tables import read_rows


def median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def per_iteration(scene: Scene, args: argparse.Namespace, rec: dict) -> None:
    """Assembly, factorization and solve at a converged 20 mm state; stability check."""
    t = time.perf_counter()
    model = NetworkModel.from_scene(scene)
    rec["t_build_s"] = time.perf_counter() - t
    ngs.SetNumThreads(1)
    with ngs.TaskManager():
        u = [rec.state.copy() for rec in load_steps(model, step_control(scene))][-1]
    rec.update({"dofs": model.n_dofs, "free_dofs": int((~model.fixed).sum()), "nnz": model.pattern.nnz})
    rec["t_assembly_s"] = median_time(lambda: model.evaluate(u, True), args.repeats)
    rec["t_gradient_only_s"] = median_time(lambda: model.evaluate(u, False), args.repeats)
    _, g, K = model.evaluate(u, True)
    b = g[~model.fixed]
    ref = None
    rec["backends"] = {}
    cases = [("cholmod", 1), ("sparsecholesky", 1), ("sparsecholesky", 2), ("umfpack", 1), ("pardiso", 1), ("splu", 1)]
    for backend, threads in cases:
        name = f"{backend} ({threads} thread{'s' if threads > 1 else ''})"
        ngs.SetNumThreads(threads)
        try:
            with ngs.TaskManager(), single_threaded_blas():
                lin = FreeBlockSolver(K, ~model.fixed, backend)
                t = time.perf_counter()
                lin.factor(K)  # first factorization: includes the symbolic analysis
                t_first = time.perf_counter() - t
                t_fac = median_time(partial(lin.factor, K), args.repeats)
                t_sol = median_time(partial(lin.solve, b), args.repeats)
                x = lin.solve(b)
                if (backend, threads) == ("sparsecholesky", 1):
                    lam, V = lowest_eigenvalues(lin, 2)
                    # warm start as in the run: the modes of the previous step, here perturbed by 1 %
                    X0 = V + 1e-2 * np.abs(V).max() * np.random.default_rng(1).standard_normal(V.shape)
                    rec["t_stability_s"] = median_time(partial(lowest_eigenvalues, lin, 2), max(1, args.repeats // 2))
                    rec["t_stability_warm_s"] = median_time(
                        partial(lowest_eigenvalues, lin, 2, X0), max(1, args.repeats // 2)
                    )
                    rec["t_stability_arpack_s"] = median_time(partial(lowest_eigenvalues_arpack, lin, 2), 1)
                    lam_ref = lowest_eigenvalues_arpack(lin, 2)[0]
                    rec["lambda_min"], rec["lambda_min_arpack"] = float(lam[0]), float(lam_ref[0])
        except (LinearSolverError, Exception) as exc:  # noqa: BLE001 - a backend NGSolve lacks
            rec["backends"][name] = {"error": str(exc)[:200]}
            continue
        ref = x if ref is None else ref
        rec["backends"][name] = {
            "t_first_factor_s": t_first,
            "t_factor_s": t_fac,
            "t_solve_s": t_sol,
            "rel_diff_to_first": float(np.linalg.norm(x - ref) / np.linalg.norm(ref)),
        }
        if backend == "sparsecholesky":
            rec[f"t_iteration_{threads}thread_s"] = rec["t_assembly_s"] + t_fac + t_sol
    ngs.SetNumThreads(1)


def full_run(scene: Scene, threads: int, tag: str, linear_solver: str = "auto") -> dict:
    from ngbet.runner.discrete import run_discrete as run

    folder = Path(__file__).parent / "out" / f"run_{tag}"
    full = scene.with_changes(
        **{"loading.u0_mm": 56.0, "solver.threads": threads, "solver.linear_solver": linear_solver}
    )
    load = os.getloadavg()[0]
    t = time.perf_counter()
    c = time.process_time()
    ngs.SetNumThreads(threads)  # as ``ngbet run`` does (also for an older ngbet whose run() did not)
    with ngs.TaskManager(), single_threaded_blas():  # as ``ngbet run`` (idle BLAS threads spin otherwise)
        s = run(full, folder, progress=False)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    F = {round(r["u0_mm"], 6): r["force_N"] for r in read_rows(folder / "results.csv")}
    return {
        "threads": threads,
        "wall_s": wall,
        "cpu_s": cpu,
        "load": load,
        "status": s["status"],
        "steps": s.get("steps"),
        "newton_iterations": s["newton_iterations_total"],
        "snap_events": s["snap_event_count"],
        "t_stability_s": s.get("t_stability_s"),
        "factorizations": s.get("factorizations"),
        "failed_steps": s.get("failed_steps"),
        "backend": s.get("backend"),
        "factorizations_ldlt": s.get("factorizations_ldlt"),
        "work_by_cause": s.get("work_by_cause"),
        "timers": s.get("timers"),
        "snap_events_list": s.get("snap_events"),
        "max_slip_mm": s.get("max_slip_mm"),
        "F37_N": F.get(37.0),
        "F56_N": F.get(56.0),
    }


def print_run(fr: dict) -> None:
    print(
        f"full run to 56 mm, {fr['threads']} thread(s), load {fr['load']:.2f}: wall {fr['wall_s']:.1f} s "
        f"(CPU {fr['cpu_s']:.1f} s), {fr['status']}, steps {fr['steps']}, Newton iterations "
        f"{fr['newton_iterations']}, factorizations {fr['factorizations']} ({fr.get('backend')}; "
        f"{fr.get('factorizations_ldlt')} by the LDL^T), failed steps {fr['failed_steps']}, "
        f"snap events {fr['snap_events']}, largest slip {fr['max_slip_mm']:.3f} mm, "
        f"F(37) {fr['F37_N']:.6f} N, F(56) {fr['F56_N']:.6f} N"
    )
    for ev in fr.get("snap_events_list") or []:
        print(
            f"  snap: {ev.get('u0_before_mm', float('nan')):.3f} -> {ev['u0_mm']:.3f} mm, {ev['kind']}, "
            f"released {ev.get('released_J', float('nan')):.3g} J"
        )
    print(f"  {'cause':50s} {'calls':>5s} {'fact':>5s} {'shift':>5s} {'solves':>6s} {'its':>5s} {'time [s]':>8s}")
    for cause, r in (fr.get("work_by_cause") or {}).items():
        print(
            f"  {cause:50s} {r['calls']:5d} {r['factorizations']:5d} {r['shift_factorizations']:5d} "
            f"{r.get('solves', -1):6d} {r['iterations']:5d} {r['time_s']:8.2f}"
        )
    t = fr.get("timers") or {}
    if t:
        print(
            f"  timers: assembly {t['assembly_s']:.2f} s / {t['assemblies']} "
            f"({1e3 * t['assembly_s'] / max(t['assemblies'], 1):.1f} ms), "
            f"gradient only {t['gradient_only_s']:.2f} s, "
            f"factorization {t['factor_s']:.2f} s ({1e3 * t['factor_s'] / max(fr['factorizations'], 1):.1f} ms), "
            f"solve {t['solve_s']:.2f} s / {t['solves']} ({1e3 * t['solve_s'] / max(t['solves'], 1):.1f} ms)"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spacing", type=float, default=2.4, help="yarn spacing [mm]")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--run", action="store_true", help="also time full BET runs to 56 mm")
    ap.add_argument("--run-only", action="store_true", help="only the full runs")
    ap.add_argument("--threads", default="1", help="NGSolve threads of the full runs, comma-separated (e.g. 1,2)")
    ap.add_argument("--run-repeats", type=int, default=1, help="repeats of each full run (interleaved)")
    ap.add_argument("--linear-solver", default="auto", help="solver.linear_solver of the full runs")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    scene = Scene().with_changes(
        **{"model": "discrete", "discrete.spacing_mm": args.spacing, "loading.u0_mm": 20.0, "outputs.plot": False}
    )
    rec: dict = {"spacing_mm": args.spacing, "repeats": args.repeats}
    if not args.run_only:
        per_iteration(scene, args, rec)
    if args.run or args.run_only:
        rec["full_runs"] = []
        for rep in range(args.run_repeats):
            for th in (int(x) for x in args.threads.split(",")):
                rec["full_runs"].append(full_run(scene, th, f"{args.spacing}mm_{th}t_{rep}", args.linear_solver))
                print_run(rec["full_runs"][-1])
    rec["versions"] = versions()
    rec["machine"] = machine()
    out = Path(__file__).parent / "out"
    out.mkdir(exist_ok=True)
    path = out / f"bench_discrete_{time.strftime('%Y%m%d-%H%M%S')}.json"
    path.write_text(json.dumps(rec, indent=2))
    if "dofs" in rec:
        print(f"{rec['dofs']} dofs ({rec['free_dofs']} free), nnz {rec['nnz']}")
        print(
            f"assembly (E, g, K): {rec['t_assembly_s'] * 1e3:.1f} ms   "
            f"(E, g only: {rec['t_gradient_only_s'] * 1e3:.1f} ms)"
        )
        for name, r in rec["backends"].items():
            if "error" in r:
                print(f"{name:28s} unavailable: {r['error'][:80]}")
            else:
                print(
                    f"{name:28s} factor {r['t_factor_s'] * 1e3:7.1f} ms (first {r['t_first_factor_s'] * 1e3:7.1f}) "
                    f"solve {r['t_solve_s'] * 1e3:6.2f} ms  rel.diff {r['rel_diff_to_first']:.1e}"
                )
        for th in (1, 2):
            b = rec["backends"].get(f"sparsecholesky ({th} thread{'s' if th > 1 else ''})", {})
            if f"t_iteration_{th}thread_s" in rec:
                print(
                    f"Newton iteration (sparsecholesky, {th} thread{'s' if th > 1 else ''}): "
                    f"{rec[f't_iteration_{th}thread_s'] * 1e3:.1f} ms = assembly {rec['t_assembly_s'] * 1e3:.1f} "
                    f"+ factorization {b['t_factor_s'] * 1e3:.1f} + solve {b['t_solve_s'] * 1e3:.1f}"
                )
        if "t_stability_s" in rec:
            print(
                f"stability check: {rec['t_stability_s'] * 1e3:.1f} ms cold, "
                f"{rec['t_stability_warm_s'] * 1e3:.1f} ms warm, ARPACK {rec['t_stability_arpack_s'] * 1e3:.1f} ms; "
                f"lambda_min {rec['lambda_min']:.6g} "
                f"(ARPACK {rec['lambda_min_arpack']:.6g})"
            )
    print(f"record: {path}")


if __name__ == "__main__":
    main()
