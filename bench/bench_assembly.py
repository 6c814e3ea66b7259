"""Benchmark of one linearization of the continuum problem: automatic differentiation, interpreted, native.

For each case (mesh size, order, corner mesh size 0.25 mm as in the default scene), each mode
and each thread count, a fresh process builds the problem, sets a perturbed state at u0 = 30 mm
and times the assembly of the Newton matrix (``AssembleLinearization`` of the form Newton
factorizes, in a TaskManager of ``threads`` threads) and the residual (``Apply``, one thread),
medians of ``--repeats``; the processes are interleaved. It saves the free block of the Newton
matrix (condensed, as factorized, and the same integrators not condensed) and the residual, and
compares every record with the first mode of this tree (one thread): max |ΔA| / max |A| of
both matrices, ‖Δx‖ / ‖x‖ of x = A⁻¹ b with the condensed ones, and max |Δr| / max |r|. Time
ratios are to the first mode (``before`` when given).

Modes: ``ad`` (this tree, interpreted, the Hessian by automatic differentiation of the
integrand: NGSolve's default), ``interpret`` (symbolic first derivatives), ``native`` (compiled
code, ``solver.compile = "native"``), ``bfi`` (a linear constant-coefficient form over the same
spaces and proxy pairs, condensed: what NGSolve's element loop alone costs), and ``before``
(``--before DIR``: an older source tree, its problem as that tree builds it; both package
layouts are read). Records, with dofs, setup time, peak RSS of the process and the 1-minute
load: ``bench/out/bench_assembly_<time>.json``.

    python bench/bench_assembly.py                                  # h 10 p 3 and h 2 p 2
    python bench/bench_assembly.py --modes ad,native,bfi --runs 3   # against the element loop alone
    python bench/bench_assembly.py --cases 10:3 --modes ad,native --threads 1,2 --before BASELINE

The "native" mode compiles C++ on its first use (``$NGBET_CACHE_DIR``), reported as ``setup_s``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
OUT = HERE / "out"


def _problem(mode: str, h: float, p: int) -> Any:
    """The problem of the default scene at (h, p), corners 0.25 mm, as ``mode`` builds it."""
    import dataclasses

    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.scene.document import default_scene

    sc = default_scene()
    disc = dataclasses.replace(sc.discretization, mesh_size_mm=h, order_u=p, corner_mesh_size_mm=0.25)
    if mode != "before":
        sc = dataclasses.replace(
            sc, solver=dataclasses.replace(sc.solver, compile="native" if mode == "native" else "interpret")
        )
    if mode == "ad":  # NGSolve's default linearization of the interpreted integrand
        from ngbet.numerics import compiled

        plain = compiled._add_variation
        compiled._add_variation = lambda form, cf, dx, symbolic: plain(form, cf, dx, False)  # type: ignore
    pr = ContinuumProblem(dataclasses.replace(sc, discretization=disc))
    try:
        from ngbet.runner.settings import continuum_solver
    except ImportError:  # an older tree: the problem holds its forms and linear algebra
        return pr
    return continuum_solver(pr)


def _free_block(form: Any) -> Any:
    """The free block of an assembled form's matrix, in full (a lower triangle stored is mirrored), scipy CSR."""
    import numpy as np
    import scipy.sparse as sps

    vals, cols, ptr = form.mat.CSR()
    n = form.mat.height
    A = sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(n, n))
    if sps.triu(A, 1).nnz == 0:  # symmetric storage: the lower triangle
        A = (A + sps.tril(A, -1).T).tocsr()
    fd = np.flatnonzero(np.array(list(form.space.FreeDofs(form.condense)), dtype=bool))
    return A[fd][:, fd].tocsr()


def _plain_form(X: Any) -> Any:
    """A linear bilinear form as large as the Newton matrix: NGSolve's element loop alone.

    Constant coefficients over the spaces and proxy pairs of the energy's Hessian (∇u–∇u, φ–φ,
    φ–∇u, ∇φ–∇φ, Λ–∇u, Λ–φ, Λ–Λ), condensed, stored as the Newton matrix is (its lower triangle).
    """
    import ngsolve as ngs

    (u, phi, lam), (v, psi, mu) = X.TnT()
    G, Gv = ngs.Grad(u), ngs.Grad(v)
    m = ngs.CF((1, 0.3, 0.2, 1), dims=(2, 2))
    bf = ngs.BilinearForm(X, symmetric=True, symmetric_storage=True, condense=True)
    bf += (
        ngs.InnerProduct(G, Gv)
        + ngs.InnerProduct(m * G, Gv)
        + phi * psi
        + phi * ngs.Trace(Gv)
        + psi * ngs.Trace(G)
        + ngs.Grad(phi) * ngs.Grad(psi)
        + lam * (psi - ngs.Trace(Gv))
        + mu * (phi - ngs.Trace(G))
        - 1e-3 * lam * mu
    ) * ngs.dx
    return bf


def child(mode: str, h: float, p: int, threads: int, repeats: int, save: str) -> dict:
    """In a fresh process: build, assemble, apply; save the matrix and residual to ``save``."""
    import ngsolve as ngs
    import numpy as np
    import scipy.sparse as sps

    ngs.SetNumThreads(1)
    t0 = time.perf_counter()
    pr = _problem(mode, h, p)
    setup = time.perf_counter() - t0
    pb = getattr(pr, "problem", pr)  # spaces and state (the solver's problem, or an older tree's problem)
    form = pr.linear.form if hasattr(pr, "linear") else getattr(pr, "a_jac", pr.a)
    if mode == "bfi":
        form = _plain_form(pb.X)
    assemble = form.Assemble if mode == "bfi" else (lambda: form.AssembleLinearization(pb.gf.vec))
    pr.state.set_load(0.03)
    pr.x[pb.free_all] += 1e-4 * np.random.default_rng(0).standard_normal(int(pb.free_all.sum()))
    ngs.SetNumThreads(threads)
    ta, tr = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        with ngs.TaskManager():
            assemble()
        ta.append(time.perf_counter() - t)
        t = time.perf_counter()
        r = pr.residual()
        tr.append(time.perf_counter() - t)
    np.save(save + ".npy", r)
    if mode == "bfi":  # another matrix: nothing to compare
        return {
            "mode": mode,
            "used": "interpret",
            "h_mm": h,
            "p": p,
            "threads": threads,
            "dofs": int(pb.X.ndof),
            "setup_s": setup,
            "assembly_s": statistics.median(ta),
            "residual_s": statistics.median(tr),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        }
    sps.save_npz(save + ".npz", _free_block(form))
    plain = ngs.BilinearForm(form.space, symmetric=True)  # the same integrators, nothing condensed
    for integrator in form.integrators:
        plain += integrator
    plain.AssembleLinearization(pb.gf.vec)
    sps.save_npz(save + "_plain.npz", _free_block(plain))
    return {
        "mode": mode,
        "used": getattr(pr, "compile_mode", "interpret"),
        "h_mm": h,
        "p": p,
        "threads": threads,
        "dofs": int(pb.X.ndof),
        "setup_s": setup,
        "assembly_s": statistics.median(ta),
        "residual_s": statistics.median(tr),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _solve(A: Any, b: Any) -> Any:
    """A⁻¹ b (A in full, as :func:`_free_block` gives it)."""
    import scipy.sparse.linalg as spla

    return spla.spsolve(A.tocsc(), b)


def compare(ref: str, other: str) -> tuple[float, float, float, float]:
    """The differences of two saved runs: matrices, residuals, solutions.

    Max |ΔA| / max |A| (condensed Newton matrix, and not condensed), max |Δr| / max |r|, and
    ‖Δx‖ / ‖x‖ of x = A⁻¹ b with the condensed matrices (b fixed, random); NaN where the
    matrices differ in size (another mesh or space).
    """
    import numpy as np
    import scipy.sparse as sps

    out = []
    for suffix in (".npz", "_plain.npz"):
        A0, A1 = sps.load_npz(ref + suffix), sps.load_npz(other + suffix)
        out.append(float(abs(A1 - A0).max() / abs(A0).max()) if A0.shape == A1.shape else float("nan"))
    r0, r1 = np.load(ref + ".npy"), np.load(other + ".npy")
    A0, A1 = sps.load_npz(ref + ".npz"), sps.load_npz(other + ".npz")
    dx = float("nan")
    if A0.shape == A1.shape:
        b = np.random.default_rng(1).standard_normal(A0.shape[0])
        x0, x1 = _solve(A0, b), _solve(A1, b)
        dx = float(np.linalg.norm(x1 - x0) / np.linalg.norm(x0))
    return out[0], out[1], float(np.abs(r1 - r0).max() / np.abs(r0).max()), dx


nan = float("nan")


def _table(recs: list[dict], cases: list[tuple[float, int]], variants: list[tuple[str, int]]) -> None:
    """Medians per case and variant, ratios to the first variant, differences to its matrix."""
    ref = variants[0]
    print(
        f"\n| h [mm] | p | dofs | mode (used) | threads | assembly [s] | ratio to {ref[0]} | residual [s] | ratio | "
        "max dA/A | (not condensed) | dx/x | max dr/r | peak RSS [MB] |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for h, p in cases:
        rs = [r for r in recs if (r["h_mm"], r["p"]) == (h, p)]
        med = {
            v: {
                k: statistics.median(r[k] for r in rs if (r["mode"], r["threads"]) == v)
                for k in ("assembly_s", "residual_s", "peak_rss_mb")
            }
            for v in variants
            if any((r["mode"], r["threads"]) == v for r in rs)
        }
        if ref not in med:
            continue
        r0 = med[ref]
        for v, m in med.items():
            last = {
                "dA_rel": nan,
                "dA_plain_rel": nan,
                "dx_rel": nan,
                "dr_rel": nan,
                **[r for r in rs if (r["mode"], r["threads"]) == v][-1],
            }
            print(
                f"| {h:g} | {p} | {last['dofs']} | {v[0]} ({last['used']}) | {v[1]} | {m['assembly_s']:.4f} | "
                f"{r0['assembly_s'] / m['assembly_s']:.2f} | {m['residual_s']:.4f} | "
                f"{r0['residual_s'] / m['residual_s']:.2f} | {last['dA_rel']:.1e} | {last['dA_plain_rel']:.1e} | "
                f"{last['dx_rel']:.1e} | "
                f"{last['dr_rel']:.1e} | "
                f"{m['peak_rss_mb']:.0f} |"
            )


def main() -> None:
    """Interleave variants and cases in fresh processes; print medians, ratios and differences."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="10:3,2:2", help="h_mm:p, comma separated")
    ap.add_argument("--modes", default="ad,interpret,native", help="ad, interpret, native (comma separated)")
    ap.add_argument("--threads", default="1", help="NGSolve threads of the assembly, comma separated")
    ap.add_argument("--before", help="an older source tree: its problem as a mode 'before' (first)")
    ap.add_argument("--repeats", type=int, default=5, help="linearizations per process")
    ap.add_argument("--runs", type=int, default=2, help="processes per variant and case")
    ap.add_argument(
        "--blas-free",
        action="store_true",
        help="leave the BLAS pools at their default thread counts (a run holds them to one)",
    )
    ap.add_argument("--child", nargs=6, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        mode, h, p, nt, rep, save = args.child
        print("BENCH " + json.dumps(child(mode, float(h), int(p), int(nt), int(rep), save)), flush=True)
        return
    modes = (["before"] if args.before else []) + args.modes.split(",")
    variants = [(m, int(t)) for m in modes for t in args.threads.split(",") if m != "before" or t == "1"]
    cases = [(float(c.split(":")[0]), int(c.split(":")[1])) for c in args.cases.split(",")]
    recs: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            for h, p in cases:
                for mode, nt in variants:
                    # BLAS pools at one thread, as in a run (runner.threads.ngsolve_threads); --blas-free leaves them
                    env = (
                        dict(os.environ)
                        if args.blas_free
                        else {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
                    )
                    if mode == "before":
                        env["PYTHONPATH"] = args.before
                    save = f"{tmp}/{mode}_{nt}_{h}_{p}_{run}"
                    load = os.getloadavg()[0]
                    proc = subprocess.run(
                        [sys.executable, __file__, "--child", mode, str(h), str(p), str(nt), str(args.repeats), save],
                        capture_output=True,
                        text=True,
                        env=env,
                    )
                    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH ")), None)
                    if line is None:
                        sys.stderr.write(proc.stderr[-2000:])
                        continue
                    recs.append({**json.loads(line[6:]), "run": run, "load": load, "save": save})
                    print(json.dumps(recs[-1]), flush=True)
        ref = next(v for v in variants if v[0] != "before")  # the same energy: this tree's
        for rec in recs:
            refsave, save = f"{tmp}/{ref[0]}_{ref[1]}_{rec['h_mm']}_{rec['p']}_{rec['run']}", rec.pop("save")
            if Path(refsave + ".npz").exists() and Path(save + ".npz").exists():
                rec["dA_rel"], rec["dA_plain_rel"], rec["dr_rel"], rec["dx_rel"] = compare(refsave, save)
    OUT.mkdir(exist_ok=True)
    (OUT / f"bench_assembly_{time.strftime('%Y%m%dT%H%M%S')}.json").write_text(json.dumps(recs, indent=1))
    _table(recs, cases, variants)


if __name__ == "__main__":
    main()
