"""Benchmark of ``ngbet run`` against the FEniCSx script of the same scene (``bench/fenicsx_bet.py``).

Three commands, each repeat in a fresh process, interleaved (fenicsx, default, penalty, fenicsx, …),
timed from outside (wall time, and CPU time of the child and its children from its rusage):

- ``fenicsx``: ``/usr/bin/python3 bench/fenicsx_bet.py`` (dolfinx 0.5: p = 2, h = 5 mm, penalty 1e7,
  ``OMP_NUM_THREADS=1`` and the BLAS pools at one thread), its compiled forms taken from dolfinx's
  cache: one run before the repeats fills it (reported apart as ``fenicsx-first``);
- ``default``: ``ngbet run`` of the embedded scene, as shipped (estimate, VTK, figures; its own
  ``solver.threads``, 1);
- ``penalty``: ``ngbet run`` of the FEniCSx script's scene (:data:`PENALTY_SCENE`: the full penalty,
  p = 2, the structured 5 mm mesh, no jamming barrier), without estimate, VTK and figures, as the
  script computes the forces alone.

It prints the medians, the ratios to the FEniCSx script and F(37), F(56) of ``penalty`` against the
script's (the same discrete problem on the same mesh), and writes ``bench/out/bench_fenicsx_<time>.json``.

    python bench/bench_fenicsx.py --repeats 5
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
sys.path.insert(0, str(HERE))
from bench_command import OUT, _child  # noqa: E402

FENICS_PYTHON = "/usr/bin/python3"
SCRIPT = HERE / "fenicsx_bet.py"
#: the ``--set`` values that make ``ngbet run`` solve the FEniCSx script's discrete problem
PENALTY_SCENE = [
    "effects.constraint=penalty",
    "effects.penalty_K=1e7",
    "effects.penalty_form=full",
    "effects.jamming=false",
    "discretization.order_u=2",
    "discretization.mesh_size_mm=5",
    "discretization.structured=true",
    "discretization.corner_mesh_size_mm=0",
]
BARE = ["outputs.error_estimate=off", "outputs.vtk=false", "outputs.plot=false"]
ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


def check_fenicsx() -> None:
    """Exit with a message when the system Python cannot import dolfinx."""
    try:
        proc = subprocess.run(
            [FENICS_PYTHON, "-c", "import dolfinx, ufl, basix; print(dolfinx.__version__)"],
            capture_output=True,
            text=True,
            timeout=120,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SystemExit(f"bench_fenicsx: {FENICS_PYTHON} cannot run: {exc}") from exc
    if proc.returncode:
        raise SystemExit(
            f"bench_fenicsx: {FENICS_PYTHON} cannot import dolfinx, ufl and basix (FEniCSx 0.5 is needed "
            f"for the reference script):\n{proc.stderr.strip()[-800:]}"
        )
    if not proc.stdout.startswith("0.5"):
        print(f"bench_fenicsx: dolfinx {proc.stdout.strip()}, the script is written for 0.5", file=sys.stderr)


def run_fenicsx(env: dict[str, str]) -> dict:
    """One run of the FEniCSx script in a fresh process: times from outside and its own record."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "stdout"
        t0 = time.perf_counter()
        load = os.getloadavg()[0]
        with out.open("w") as fh, tempfile.TemporaryFile() as err:
            proc = subprocess.Popen(
                [FENICS_PYTHON, str(SCRIPT)], env={**env, **ONE_THREAD}, cwd=tmp, stdout=fh, stderr=err
            )
            _, status, usage = os.wait4(proc.pid, 0)
            wall = time.perf_counter() - t0
            rc = os.waitstatus_to_exitcode(status)
            if rc:
                err.seek(0)
                sys.stderr.write(err.read()[-2000:].decode(errors="replace"))
        lines = out.read_text().splitlines()
        own = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}
    return {
        "variant": "fenicsx",
        "wall_s": wall,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "peak_rss_mb": usage.ru_maxrss / 1024,
        "load": load,
        "rc": rc,
        **own,
    }


def run_ngbet(name: str, sets: list[str], env: dict[str, str]) -> dict:
    """One ``ngbet run`` in a fresh process, out to a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-m", "ngbet", "run", "--quiet", "--out", f"{tmp}/run"]
        for s in sets:
            argv += ["--set", s]
        load = os.getloadavg()[0]
        wall, rss, rc, cpu = _child(argv, env, tmp)
        rec: dict = {"variant": name, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss, "load": load, "rc": rc}
        run = Path(tmp) / "run"
        if (run / "summary.json").exists():
            s = json.loads((run / "summary.json").read_text())
            rec.update({k: s.get(k) for k in ("setup_s", "solve_s", "estimate_s", "dofs", "newton_iterations")})
        if (run / "results.csv").exists():
            lines = (run / "results.csv").read_text().splitlines()
            col = lines[0].split(",").index("force_N")
            u0 = [float(line.split(",")[1]) for line in lines[1:]]
            f = [float(line.split(",")[col]) for line in lines[1:]]
            rec.update({f"F{int(d)}_N": fi for d, fi in zip(u0, f, strict=True) if d in (37.0, 56.0)})
    return rec


def main() -> None:
    """Run the three commands interleaved, print medians and ratios, write the records."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    check_fenicsx()
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg"}
    records = [{**run_fenicsx(env), "variant": "fenicsx-first"}]  # fills dolfinx's form cache
    loads = [os.getloadavg()]
    for _ in range(args.repeats):
        for rec in (run_fenicsx(env), run_ngbet("default", [], env), run_ngbet("penalty", PENALTY_SCENE + BARE, env)):
            records.append(rec)
            print(json.dumps(rec)[:240], flush=True)
    loads.append(os.getloadavg())
    OUT.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    (OUT / f"bench_fenicsx_{stamp}.json").write_text(json.dumps({"records": records, "loadavg": loads}, indent=1))

    def med(name: str, key: str) -> float:
        vals = [r[key] for r in records if r["variant"] == name and isinstance(r.get(key), (int, float))]
        return statistics.median(vals) if vals else float("nan")

    print("\n| command | wall [s] | CPU [s] | wall / FEniCSx | CPU / FEniCSx | load | F(37) [N] | F(56) [N] |")
    print("|---|---|---|---|---|---|---|---|")
    fw, fc = med("fenicsx", "wall_s"), med("fenicsx", "cpu_s")
    for name in ("fenicsx", "default", "penalty"):
        w, c = med(name, "wall_s"), med(name, "cpu_s")
        print(
            f"| {name} | {w:.2f} | {c:.2f} | {w / fw:.3f} | {c / fc:.3f} | {med(name, 'load'):.1f} "
            f"| {med(name, 'F37_N'):.10g} | {med(name, 'F56_N'):.10g} |"
        )
    own = [r for r in records if r["variant"] == "fenicsx" and "solve_s" in r]
    if own:
        parts = {
            k: statistics.median(r[k]["cpu"] for r in own) for k in ("imports_s", "setup_jit_s", "solve_s", "total_s")
        }
        print("FEniCSx script, CPU inside it (medians):", {k: round(v, 3) for k, v in parts.items()})
    for d in ("F37_N", "F56_N"):
        a, b = med("penalty", d), med("fenicsx", d)
        print(f"{d}: ngbet {a!r}, FEniCSx {b!r}, relative difference {abs(a - b) / abs(b):.2e}")
    print(f"load average (1, 5, 15 min) before and after: {loads}")


if __name__ == "__main__":
    main()
