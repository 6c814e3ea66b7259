"""Why the first-gradient model (``effects.bending = false``) costs more than the full one: a figure.

Runs the embedded scene to 56 mm with and without bending (rows every 2 mm, no estimate, no
files) and records, at every converged state, the smallest angle between the deformed yarns over
the integration points (the jamming barrier's own check), the factorizations and the CPU time so
far. Without bending nothing spreads the shear away from the clamp corners: their yarns close
past 45°, where the shear stress of the quadratic law (∝ sin 2θ at fixed stretches) falls as
they close, and at 19.8 mm the corner snaps shut (a limit point of the displacement-controlled
path: from 18.4° to the jamming angle, where the barrier, K_jam = max(K_el, K_sh), holds it;
without the barrier, ``effects.jamming = false``, to -37°, yarns crossed). The increments cut
towards the limit point, the relaxation past it and the Newton iterations of the corner in
contact are the extra cost; the full model, whose corners stay open, has none. Two more runs of
the first-gradient model: without the local solve of the barrier's unknowns before each
linearization (:mod:`ngbet.continuum.patch`), for what it saves, and with the barrier, once on,
on every element, for the cost of that alone. Writes ``bench/out/reduced_scene.png`` and a JSON
record; prints steps, iterations, factorizations, local iterations and CPU time of each run. All runs
are in one process: the stability module, which the first relaxation imports (0.3 s with scipy's
sparse eigen-solver), is imported before them.

    python bench/bench_reduced.py
    python bench/bench_reduced.py bench/out/bench_reduced_<time>.json   # the figure of a record again
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "out"


def _yarn_sine(problem, scene):  # the barrier's own check, built also where jamming is off
    import ngsolve as ngs

    from ngbet.continuum import physics

    sp, disc = scene.specimen, scene.discretization
    orientation = math.copysign(1.0, sp.m1[0] * sp.m2[1] - sp.m1[1] * sp.m2[0])
    sine = physics.yarn_angle_sine(ngs.Id(2) + ngs.Grad(problem.u), problem.m1, problem.m2, orientation).Compile()
    rule = ngs.IntegrationRule(ngs.TRIG, 2 * max(disc.p_u, 1) + disc.quad_bonus)
    return sine, problem.mesh.MapToAllElements(rule, ngs.VOL)


def one_run(bending: bool, jamming: bool = True, everywhere: bool = False, local: bool = True) -> dict:
    """The path of the embedded scene (``effects.bending``, ``effects.jamming``): per state the smallest yarn angle.

    ``everywhere``: the barrier, once on, on every element for good (not on those near the threshold);
    ``local``: the barrier's unknowns solved first before each linearization (``ContinuumSolver.patch``).
    In NGSolve's threads as the command sets them (``solver.threads``, one BLAS thread).
    """
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.runner.continuum import load_path
    from ngbet.runner.settings import continuum_solver
    from ngbet.runner.threads import ngsolve_threads
    from ngbet.scene.document import Scene

    scene = Scene().with_changes(**{"effects.bending": bending, "effects.jamming": jamming})
    t0, c0 = time.perf_counter(), time.process_time()
    solver = continuum_solver(ContinuumProblem(scene))
    if not local:
        solver.patch = None
    jam = solver.problem.jamming
    if everywhere:
        watch = jam.watch

        def watch_all() -> None:
            watch()
            if jam.on:
                jam.switch_on()

        jam.watch = watch_all  # type: ignore[method-assign]
    sine, points = _yarn_sine(solver.problem, scene)
    angles: list[tuple[float, float, bool, int, float, int]] = []
    problem = solver.problem
    original = problem.converged

    def watched() -> None:
        s = float(np.min(np.asarray(sine(points))))
        angle = math.degrees(math.asin(max(-1.0, min(1.0, s))))
        angles.append(
            (
                problem.lam * 1e3,
                angle,
                jam.on,
                solver.counts["factorizations"],
                time.process_time() - c0,
                int(jam.elements.NumSet()),
            )
        )
        original()

    problem.converged = watched  # type: ignore[method-assign]
    steps = []
    path = load_path(solver, scene)
    with ngsolve_threads(scene):
        try:
            while True:
                rec = next(path)
                steps.append((rec.u0 * 1e3, rec.iterations, rec.reason))
        except StopIteration as done:
            res = done.value
    return {
        "bending": bending,
        "jamming": jamming,
        "everywhere": everywhere,
        "without_local": not local,
        "local_iterations": solver.patch.iterations if solver.patch is not None else 0,
        "angles": angles,
        "relaxed_mm": [u for u, _, why in steps if why.startswith("relaxed")],
        "steps": steps,
        "u0_mm": res.u0 * 1e3,
        "cuts": res.cuts,
        "counts": solver.counts,
        "cpu_s": time.process_time() - c0,
        "wall_s": time.perf_counter() - t0,
        "jamming_angle_deg": scene.material.jamming_angle_deg,
    }


def _label(r: dict) -> str:
    if r["bending"]:
        return "full model"
    if not r["jamming"]:
        return "first gradient, no jamming barrier"
    if r.get("everywhere"):
        return "first gradient, barrier on every element"
    return "first gradient" + (", without the local solve" if r.get("without_local") else "")


def figure(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(14.5, 4.4), constrained_layout=True)
    colors = ("tab:blue", "tab:red", "tab:purple", "tab:orange", "tab:gray")
    for r, color in zip(runs, colors, strict=False):
        label = _label(r)
        a = np.array([[*row[:4], row[4] if len(row) > 4 else np.nan] for row in r["angles"]], dtype=float)
        style = "--" if r.get("everywhere") or r.get("without_local") else "-"
        if not r.get("everywhere") and not r.get("without_local"):
            ax.plot(a[:, 0], a[:, 1], "o-", ms=3, color=color, label=label)
        bx.step(
            a[:, 0],
            a[:, 3],
            style,
            where="post",
            color=color,
            label=f"{label}: {len(r['steps'])} steps, {r['cuts']} cut{'' if r['cuts'] == 1 else 's'}, "
            f"{r['counts']['factorizations']} factorizations",
        )
        cx.step(a[:, 0], a[:, 4], style, where="post", color=color, label=f"{label}: {r['cpu_s']:.2f} s")
        for u in r.get("relaxed_mm", []) if not r.get("everywhere") and not r.get("without_local") else []:
            ax.annotate(
                f"corner snaps shut at {u:.3g} mm\n(relaxed to a stable state)",
                (u, 4.0),
                xytext=(23.0, 15.0),
                textcoords="data",
                fontsize=8,
                color=color,
                arrowprops={"arrowstyle": "->", "color": color, "lw": 0.8},
            )
    ax.axhline(runs[0]["jamming_angle_deg"], color="k", lw=0.8, ls="--")
    ax.text(30.0, runs[0]["jamming_angle_deg"] + 2, "jamming angle", fontsize=8)
    ax.axhline(45.0, color="k", lw=0.6, ls=":")
    ax.text(56.0, 47.0, "45°", fontsize=8, ha="right")
    ax.set(xlabel="clamp displacement $u_0$ [mm]", ylabel="smallest angle between the yarns [°]", ylim=(-60, 95))
    ax.legend(fontsize=8, loc="lower right")
    bx.set(xlabel="clamp displacement $u_0$ [mm]", ylabel="factorizations so far")
    bx.set_ylim(0.0, 1.3 * max(r["counts"]["factorizations"] for r in runs))
    bx.legend(fontsize=6.5, loc="upper left")
    cx.set(xlabel="clamp displacement $u_0$ [mm]", ylabel="CPU time of the path so far [s]")
    cx.set_ylim(0.0, 1.4 * max(r["cpu_s"] for r in runs))
    cx.legend(fontsize=8, loc="upper left")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    import sys

    if len(sys.argv) > 1:  # a record of an earlier run: its figure again
        figure(json.loads(Path(sys.argv[1]).read_text()), OUT / "reduced_scene.png")
        return
    import ngbet.continuum.stability  # noqa: F401  (the relaxation's eigen-solver: imported before, no run pays for it)

    runs = [
        one_run(True),
        one_run(False),
        one_run(False, local=False),
        one_run(False, everywhere=True),
        one_run(False, jamming=False),
    ]
    OUT.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    (OUT / f"bench_reduced_{stamp}.json").write_text(json.dumps(runs, indent=1))
    figure(runs, OUT / "reduced_scene.png")
    for r in runs:
        print(
            f"{_label(r)}: {len(r['steps'])} steps to {r['u0_mm']:.4g} mm, "
            f"{r['cuts']} cuts, "
            f"{r['counts']}, {r.get('local_iterations', 0)} local iterations, CPU {r['cpu_s']:.2f} s, "
            f"wall {r['wall_s']:.2f} s; smallest yarn angle "
            f"{min(a[1] for a in r['angles']):.3g}°"
        )
    print(f"figure: {OUT / 'reduced_scene.png'}")


if __name__ == "__main__":
    main()
