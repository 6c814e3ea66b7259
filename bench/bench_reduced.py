"""Why the first-gradient model (``effects.bending = false``) costs more than the full one: a figure.

Runs the embedded scene to 56 mm with and without bending (rows every 2 mm, no estimate, no
files) and records, at every converged state, the smallest angle between the deformed yarns over
the integration points (the jamming barrier's own check) and the corrector's iterations. Without
bending nothing spreads the shear away from the clamp corners: their yarns close to the jamming
angle within the first 20 mm, where the barrier (K_jam = max(K_el, K_sh)) takes over and the
path needs cut steps and Newton iterations that the full model, whose corners stay open, does
not; without the barrier (``effects.jamming = false``, as before the barrier existed) their yarns
cross and the first-gradient path is cheap again (the force the same to 1e-6). Writes
``bench/out/reduced_scene.png`` and a JSON record; prints steps, iterations,
factorizations and CPU time of each model.

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


def one_run(bending: bool, jamming: bool = True) -> dict:
    """The path of the embedded scene (``effects.bending``, ``effects.jamming``): per state the smallest yarn angle."""
    from ngbet.continuum.problem import ContinuumProblem
    from ngbet.runner.continuum import load_path
    from ngbet.runner.settings import continuum_solver
    from ngbet.scene.document import Scene

    scene = Scene().with_changes(**{"effects.bending": bending, "effects.jamming": jamming})
    t0, c0 = time.perf_counter(), time.process_time()
    solver = continuum_solver(ContinuumProblem(scene))
    jam = solver.problem.jamming
    sine, points = _yarn_sine(solver.problem, scene)
    angles: list[tuple[float, float, bool, int]] = []
    original = solver.converged

    def watched() -> None:
        s = float(np.min(np.asarray(sine(points))))
        angle = math.degrees(math.asin(max(-1.0, min(1.0, s))))
        angles.append((solver.lam * 1e3, angle, jam.on, solver.counts["factorizations"]))
        original()

    solver.converged = watched  # type: ignore[method-assign]
    steps = []
    path = load_path(solver, scene)
    try:
        while True:
            rec = next(path)
            steps.append((rec.u0 * 1e3, rec.iterations))
    except StopIteration as done:
        res = done.value
    return {"bending": bending, "jamming": jamming, "angles": angles, "steps": steps, "u0_mm": res.u0 * 1e3,
            "cuts": res.cuts, "counts": solver.counts, "cpu_s": time.process_time() - c0,
            "wall_s": time.perf_counter() - t0,
            "jamming_angle_deg": scene.material.jamming_angle_deg}


def figure(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9.0, 3.6), constrained_layout=True)
    for r, color in zip(runs, ("tab:blue", "tab:red", "tab:gray"), strict=True):
        label = ("full model" if r["bending"] else "first gradient") + ("" if r["jamming"] else ", no jamming barrier")
        a = np.array([(u, g, on, n) for u, g, on, n in r["angles"]], dtype=float)
        ax.plot(a[:, 0], a[:, 1], "o-", ms=3, color=color, label=label)
        bx.step(a[:, 0], a[:, 3], where="post", color=color,
                label=f"{label}: {len(r['steps'])} steps, {r['cuts']} cut{'' if r['cuts'] == 1 else 's'}")
        on = a[a[:, 2] > 0]
        if on.size:
            bx.axvline(on[0, 0], color=color, lw=0.8, ls=":")
            bx.annotate("jamming barrier on", (on[0, 0], 0.5 * a[-1, 3]), xytext=(4, 0),
                        textcoords="offset points", fontsize=8, color=color)
    ax.axhline(runs[0]["jamming_angle_deg"], color="k", lw=0.8, ls="--")
    ax.text(30.0, runs[0]["jamming_angle_deg"] + 2, "jamming angle", fontsize=8)
    ax.set(xlabel="clamp displacement $u_0$ [mm]", ylabel="smallest angle between the yarns [°]", ylim=(-95, 95))
    ax.legend(fontsize=8, loc="lower left")
    bx.set(xlabel="clamp displacement $u_0$ [mm]", ylabel="factorizations so far")
    bx.legend(fontsize=8, loc="upper left")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    import sys

    if len(sys.argv) > 1:  # a record of an earlier run: its figure again
        figure(json.loads(Path(sys.argv[1]).read_text()), OUT / "reduced_scene.png")
        return
    runs = [one_run(True), one_run(False), one_run(False, jamming=False)]
    OUT.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    (OUT / f"bench_reduced_{stamp}.json").write_text(json.dumps(runs, indent=1))
    figure(runs, OUT / "reduced_scene.png")
    for r in runs:
        print(f"bending={r['bending']}, jamming={r['jamming']}: {len(r['steps'])} steps to {r['u0_mm']:.4g} mm, "
              f"{r['cuts']} cuts, "
              f"{r['counts']}, CPU {r['cpu_s']:.2f} s, wall {r['wall_s']:.2f} s; smallest yarn angle "
              f"{min(a[1] for a in r['angles']):.3g}°")
    print(f"figure: {OUT / 'reduced_scene.png'}")


if __name__ == "__main__":
    main()
