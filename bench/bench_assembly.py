"""Benchmark of one linearization of the continuum problem: interpreted against native code.

For each case (mesh size, order) and each ``solver.compile`` mode, a fresh process builds the
default scene's problem, sets a perturbed state at u0 = 30 mm and times ``AssembleLinearization``
of the Newton matrix and the residual (``Apply``), medians of ``--repeats``; the processes are
interleaved. It saves the free block of the Newton matrix and the residual, and compares every
mode with the first one: max |ΔA| / max |A| and max |Δr| / max |r|. ``before`` runs the same in
an older source tree (``--before DIR``; its energy as that tree compiles it). Records:
``bench/out/bench_assembly_<time>.json``.

    python bench/bench_assembly.py                                  # h 10 p 3 and h 2 p 2
    python bench/bench_assembly.py --cases 10:3 --modes interpret,native --before /tmp/before

The "native" mode compiles C++ on its first use (``$NGBET_CACHE_DIR``), reported as ``setup_s``.
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


def child(mode: str, h: float, p: int, repeats: int, save: str) -> dict:
    """In a fresh process: build, assemble, apply; save the matrix and residual to ``save``."""
    import dataclasses

    import ngsolve as ngs
    import numpy as np
    import scipy.sparse as sps

    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.scene import default_scene

    ngs.SetNumThreads(1)
    sc = default_scene()
    disc = dataclasses.replace(sc.discretization, mesh_size_mm=h, order_u=p)
    solver = dataclasses.replace(sc.solver, compile=mode) if mode != "before" else sc.solver
    sc = dataclasses.replace(sc, discretization=disc, solver=solver)
    with ngs.TaskManager():
        t0 = time.perf_counter()
        pr = ContinuumProblem(sc)
        setup = time.perf_counter() - t0
        pr.set_load(0.03)
        pr.x[pr.free_all] += 1e-4 * np.random.default_rng(0).standard_normal(int(pr.free_all.sum()))
        ta, tr = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            pr.linear.form.AssembleLinearization(pr.gf.vec)
            ta.append(time.perf_counter() - t)
            t = time.perf_counter()
            r = pr.residual()
            tr.append(time.perf_counter() - t)
        A, _ = pr.linear.free_matrix()
    np.save(save + ".npy", r)
    sps.save_npz(save + ".npz", A.tocsr())
    return {"mode": mode, "used": getattr(pr, "compile_mode", "interpret"), "h_mm": h, "p": p,
            "dofs": int(pr.X.ndof), "setup_s": setup, "assembly_s": statistics.median(ta),
            "residual_s": statistics.median(tr)}


def compare(ref: str, other: str) -> tuple[float, float]:
    """The largest |ΔA| / max |A| and |Δr| / max |r| of two saved runs."""
    import numpy as np
    import scipy.sparse as sps

    A0, A1 = sps.load_npz(ref + ".npz"), sps.load_npz(other + ".npz")
    r0, r1 = np.load(ref + ".npy"), np.load(other + ".npy")
    return float(abs(A1 - A0).max() / abs(A0).max()), float(np.abs(r1 - r0).max() / np.abs(r0).max())


def main() -> None:
    """Interleave modes and cases in fresh processes; print medians, ratios and differences."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="10:3,2:2", help="h_mm:p, comma separated")
    ap.add_argument("--modes", default="interpret,native")
    ap.add_argument("--before", help="an older source tree: its problem as a mode 'before' (first)")
    ap.add_argument("--repeats", type=int, default=5, help="linearizations per process")
    ap.add_argument("--runs", type=int, default=2, help="processes per mode and case")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        mode, h, p, rep, save = args.child
        print("BENCH " + json.dumps(child(mode, float(h), int(p), int(rep), save)), flush=True)
        return
    modes = (["before"] if args.before else []) + args.modes.split(",")
    cases = [(float(c.split(":")[0]), int(c.split(":")[1])) for c in args.cases.split(",")]
    recs: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            for h, p in cases:
                for mode in modes:
                    env = dict(os.environ)
                    if mode == "before":
                        env["PYTHONPATH"] = args.before
                    save = f"{tmp}/{mode}_{h}_{p}"
                    proc = subprocess.run([sys.executable, __file__, "--child", mode, str(h), str(p),
                                           str(args.repeats), save], capture_output=True, text=True, env=env)
                    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH ")), None)
                    if line is None:
                        sys.stderr.write(proc.stderr[-2000:])
                        continue
                    rec = {**json.loads(line[6:]), "run": run, "load": os.getloadavg()[0]}
                    rec["dA_rel"], rec["dr_rel"] = compare(f"{tmp}/{modes[0]}_{h}_{p}", save)
                    recs.append(rec)
                    print(json.dumps(rec), flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / f"bench_assembly_{time.strftime('%Y%m%dT%H%M%S')}.json").write_text(json.dumps(recs, indent=1))
    print(f"\n| h [mm] | p | dofs | mode (used) | assembly [s] | ratio to {modes[0]} | residual [s] | ratio | "
          "max dA/A | max dr/r |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for h, p in cases:
        rs = [r for r in recs if (r["h_mm"], r["p"]) == (h, p)]
        med = {m: {k: statistics.median(r[k] for r in rs if r["mode"] == m) for k in ("assembly_s", "residual_s")}
               for m in modes if any(r["mode"] == m for r in rs)}
        for m, v in med.items():
            r0 = med[modes[0]]
            last = [r for r in rs if r["mode"] == m][-1]
            print(f"| {h:g} | {p} | {last['dofs']} | {m} ({last['used']}) | {v['assembly_s']:.4f} | "
                  f"{r0['assembly_s'] / v['assembly_s']:.2f} | {v['residual_s']:.4f} | "
                  f"{r0['residual_s'] / v['residual_s']:.2f} | {last['dA_rel']:.1e} | {last['dr_rel']:.1e} |")


if __name__ == "__main__":
    main()
