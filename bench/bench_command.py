"""Benchmark of the whole ``ngbet run`` command: where the seconds of one run go.

Each repeat of each variant is one ``python -m ngbet run`` in a fresh process (start-up, imports,
mesh, setup, continuation, error estimate, VTK, plot, summary), timed from outside; variants are
interleaved (a, b, c, a, b, c, …) so that load on the shared machine hits them alike. Two more
processes measure the imports alone (``import ngbet.cli``; ``import ngsolve``). Per run the record
holds the wall time, peak RSS of the child (``resource.getrusage``), the 1-minute load average
before it, and from its summary.json: setup, solve and estimate time, the solver timers, the force.
The differences between variants give the cost of the VTK file, the plot, the estimate. The table
gives medians and, for a machine that other jobs load, the shortest wall time of each variant too
(the repeat that met the least load).

    python bench/bench_command.py                          # all variants, 3 repeats
    python bench/bench_command.py --variants default,no-estimate --repeats 5
    python bench/bench_command.py --list
    python bench/bench_command.py --variants default,no-bending,accuracy-1e-3,network-17k --repeats 3
    git archive REV | tar -x -C /tmp/before                 # an older tree, for before/after in one sitting
    python bench/bench_command.py --variants default,bare --before /tmp/before
    python bench/bench_command.py --variants default --before /tmp/before --pycache /tmp/pyc   # with bytecode

Records: ``bench/out/bench_command_<time>.json`` (bench/out is ignored by git). The compiled-code
cache of ``solver.compile`` is ``$NGBET_CACHE_DIR`` (``--cache`` sets it; the "native" variant fills
it on its first run, which is then reported apart as ``cold``).
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

#: name -> (``--set`` values, what it shows); the plot process variants set NGBET_PLOT_PROCESS
VARIANTS: dict[str, tuple[list[str], str]] = {
    "default": ([], "ngbet run, the embedded scene, as shipped (NGBET_PLOT_PROCESS as set, else auto)"),
    "plot-process": ([], "default, the plot drawn by the plot process (NGBET_PLOT_PROCESS=always)"),
    "plot-here": ([], "default, the plot drawn in the run's process (NGBET_PLOT_PROCESS=never)"),
    "no-estimate": (["outputs.error_estimate=off"], "without the error estimate"),
    "no-estimate-vtk": (["outputs.error_estimate=off", "outputs.vtk=false"], "… and without the VTK file"),
    "bare": (
        ["outputs.error_estimate=off", "outputs.vtk=false", "outputs.plot=false"],
        "… and without the plot: start-up, imports, mesh, setup, solve, CSV/JSON",
    ),
    "interpret": (["solver.compile=interpret"], "default with the interpreted energy"),
    "native": (["solver.compile=native"], "default with the native energy (cached objects)"),
    "no-bending": (["effects.bending=false"], "the first-gradient model (fewer effects: should cost less)"),
    "accuracy-1e-2": (["discretization.target_error=1e-2"], "ngbet run --accuracy 1e-2 (the accuracy ladder)"),
    "accuracy-1e-3": (["discretization.target_error=1e-3"], "ngbet run --accuracy 1e-3 (target: 2x default)"),
    "accuracy-1e-4": (["discretization.target_error=1e-4"], "ngbet run --accuracy 1e-4 (target: 15x default)"),
    "network-17k": (
        ["model=discrete", "discrete.spacing_mm=2.4"],
        "the yarn network of 16 890 unknowns to 56 mm, with its figures (target: 4 s)",
    ),
    "fabric-1e-2": (
        ["discretization.target_error=1e-2"],
        "the unbalanced twill's scene file at --accuracy 1e-2 (target: 3 s of solve)",
    ),
}
#: variants that run a scene file of this tree's geometry/ rather than the embedded scene
SCENE_FILES = {"fabric-1e-2": "geometry/twintex_twill_unbalanced.toml"}
#: the variants run when none are named (the others are the targets' variants, named explicitly)
DEFAULT_VARIANTS = [
    "default",
    "plot-process",
    "plot-here",
    "no-estimate",
    "no-estimate-vtk",
    "bare",
    "interpret",
    "native",
]
PLOT_PROCESS = {"plot-process": "always", "plot-here": "never"}


def _child(argv: list[str], env: dict[str, str], cwd: str) -> tuple[float, float, int, float]:
    """Wall time [s], peak RSS [MB], exit code and CPU time [s] (user + system) of the child.

    It runs in ``cwd``, an empty folder: ``python -m`` puts the working folder first on
    ``sys.path``, so a run started in a source tree would import that tree's ngbet, not the one
    its PYTHONPATH names.

    From the child's rusage, which holds its own processes too (the plot process): the peak RSS is
    the largest of them, the CPU time their sum.
    """
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = rc = os.waitstatus_to_exitcode(status)
        if rc:
            err.seek(0)
            sys.stderr.write(err.read()[-2000:].decode(errors="replace"))
    return wall, usage.ru_maxrss / 1024, rc, usage.ru_utime + usage.ru_stime


def run_variant(name: str, env: dict[str, str], python: str = sys.executable) -> dict:
    """One ``ngbet run`` of a variant in a fresh process (``before:NAME``: with the older tree's ngbet)."""
    base = name.removeprefix("before:")
    sets = VARIANTS[base][0]
    if base in PLOT_PROCESS:
        env = {**env, "NGBET_PLOT_PROCESS": PLOT_PROCESS[base]}
    with tempfile.TemporaryDirectory() as tmp:
        argv = [python, "-m", "ngbet", "run", "--quiet", "--out", f"{tmp}/run"]
        if base in SCENE_FILES:
            argv.insert(4, str(HERE.parent / SCENE_FILES[base]))
        for s in sets:
            argv += ["--set", s]
        load = os.getloadavg()[0]
        wall, rss, rc, cpu = _child(argv, env, tmp)
        rec: dict = {"variant": name, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss, "load": load, "rc": rc}
        summary = Path(tmp) / "run" / "summary.json"
        if summary.exists():
            s = json.loads(summary.read_text())
            rec.update(
                {
                    k: s.get(k)
                    for k in (
                        "setup_s",
                        "solve_s",
                        "estimate_s",
                        "wall_s",
                        "timers",
                        "counts",
                        "newton_iterations",
                        "dofs",
                        "force_N",
                        "compile_mode",
                    )
                }
            )
            rec["run_wall_s"] = rec.pop("wall_s")
            rec["wall_s"] = wall
            rec["forces"] = _forces(Path(tmp) / "run" / "results.csv")
    return rec


def _forces(path: Path) -> list[float]:
    if not path.exists():
        return []
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    col = next(i for i, h in enumerate(head) if h.startswith("force_N"))
    return [float(line.split(",")[col]) for line in lines[1:]]


def imports(env: dict[str, str]) -> dict:
    """Wall time of ``python -c 'import ngbet.cli'`` and ``'import ngsolve'`` (fresh processes)."""
    out = {}
    for label, code in (
        ("python", "pass"),
        ("ngbet.cli", "import ngbet.cli"),
        ("ngsolve", "import ngsolve"),
        ("matplotlib.pyplot", "import matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot"),
    ):
        with tempfile.TemporaryDirectory() as tmp:
            out[label] = _child([sys.executable, "-c", code], env, tmp)[0]
    return out


def _python_of(tree: str) -> str:
    """The tree's own .venv/bin/python when it has one, else this interpreter."""
    venv = Path(tree) / ".venv" / "bin" / "python"
    return str(venv) if venv.exists() else sys.executable


def _median(recs: list[dict], key: str) -> float:
    vals = [r[key] for r in recs if isinstance(r.get(key), (int, float))]
    return statistics.median(vals) if vals else float("nan")


def _ratios_to_default(records: list[dict], names: list[str]) -> None:
    """Print each variant's median wall and CPU time over the default command's of the same sitting."""
    if "default" not in names:
        return
    base = [r for r in records if r["variant"] == "default"]
    for name in [n for n in names if n != "default" and not n.startswith("before:")]:
        a = [r for r in records if r["variant"] == name]
        print(
            f"{name} / default: wall {_median(a, 'wall_s') / _median(base, 'wall_s'):.2f}, "
            f"CPU {_median(a, 'cpu_s') / _median(base, 'cpu_s'):.2f} (exit codes {sorted({r['rc'] for r in a})})"
        )


def _compiled(env: dict[str, str], pycache: str, before: str | None) -> None:
    """Point ``env`` at the bytecode folder ``pycache`` and compile this tree (and ``before``) into it."""
    env["PYTHONPYCACHEPREFIX"] = str(Path(pycache).resolve())
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for tree, python in ((HERE.parent, sys.executable), *(((Path(before), _python_of(before)),) if before else ())):
        trees = [str(tree / d) for d in ("ngbet", "studies") if (tree / d).is_dir()]
        subprocess.run([python, "-m", "compileall", "-q", *trees], env=env, check=False, stdout=subprocess.DEVNULL)


def main() -> None:
    """Run the variants interleaved, print medians, write the records."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variants", default=",".join(DEFAULT_VARIANTS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", help="NGBET_CACHE_DIR for the runs (default: as set, else ngbet's)")
    ap.add_argument(
        "--before",
        help="a source tree of ngbet: each variant also runs with it (PYTHONPATH; "
        "with the tree's own .venv/bin/python when it has one)",
    )
    ap.add_argument(
        "--pycache",
        help="a folder for the bytecode of both trees (PYTHONPYCACHEPREFIX, PYTHONDONTWRITEBYTECODE unset, "
        "compiled before the first run): as an installed ngbet runs, without compiling its sources in every process",
    )
    ap.add_argument("--list", action="store_true")
    args = ap.parse_args()
    if args.list:
        for k, (sets, what) in VARIANTS.items():
            print(f"{k:18s} {what}  {sets}")
        return
    names = args.variants.split(",")
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg"}
    if args.cache:
        env["NGBET_CACHE_DIR"] = args.cache
    if args.pycache:
        _compiled(env, args.pycache, args.before)
    envs = {name: env for name in names}
    pythons = dict.fromkeys(names, sys.executable)
    if args.before:
        envs.update(
            {
                f"before:{n}": {**env, "PYTHONPATH": args.before}
                for n in names
                if n != "native" and n not in PLOT_PROCESS
            }
        )  # the older tree has neither
        pythons.update({f"before:{n}": _python_of(args.before) for n in names})
        names = [n for pair in zip(names, [f"before:{n}" for n in names], strict=True) for n in pair if n in envs]
    records: list[dict] = []
    if "native" in names:  # the first native run may compile: reported apart
        records.append({**run_variant("native", env), "variant": "native-first"})
    for _ in range(args.repeats):
        records.append({"variant": "imports", **imports(env)})
        for name in names:
            records.append(run_variant(name, envs[name], pythons[name]))
            print(json.dumps(records[-1])[:240], flush=True)
    OUT.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    (OUT / f"bench_command_{stamp}.json").write_text(json.dumps(records, indent=1))
    print(
        "\n| variant | wall [s] | min wall [s] | CPU [s] | setup [s] | solve [s] | estimate [s] | assembly [s] "
        "| peak RSS [MB] | load | F(56) [N] |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in names + (["native-first"] if "native" in names else []):
        rs = [r for r in records if r["variant"] == name]
        asm = statistics.median([r["timers"]["assembly_s"] for r in rs if r.get("timers")] or [float("nan")])
        f = rs[-1].get("force_N")
        print(
            f"| {name} | {_median(rs, 'wall_s'):.2f} | {min(r['wall_s'] for r in rs):.2f} | "
            f"{_median(rs, 'cpu_s'):.2f} | {_median(rs, 'setup_s'):.2f} | "
            f"{_median(rs, 'solve_s'):.2f} | {_median(rs, 'estimate_s'):.2f} | {asm:.3f} | "
            f"{_median(rs, 'peak_rss_mb'):.0f} | {_median(rs, 'load'):.1f} | {f} |"
        )
    for name in [n for n in names if f"before:{n}" in names] + [n for n in PLOT_PROCESS if n in names]:
        ref = f"before:{name}" if f"before:{name}" in names else "before:default"
        if ref in names:
            a, b = ([r for r in records if r["variant"] == v] for v in (name, ref))
            print(
                f"{name} / {ref}: wall {_median(a, 'wall_s') / _median(b, 'wall_s'):.2f}, "
                f"CPU {_median(a, 'cpu_s') / _median(b, 'cpu_s'):.2f}"
            )
    _ratios_to_default(records, names)
    imp = [r for r in records if r["variant"] == "imports"]
    print(
        "imports (median wall of a fresh process):",
        {k: round(statistics.median(r[k] for r in imp), 3) for k in imp[0] if k != "variant"},
    )


if __name__ == "__main__":
    main()
