"""Two stable equilibria of one discretization at 37 mm: the load path against orders raised at the load.

    python docs/research/two_equilibria.py [CORNER_MM] [P_START] [P_END]      (defaults 0.125 10 12)

The default scene on the 20 mm mesh graded to CORNER_MM at the clamp corners (Lagrange constraint,
error estimate off). State L: order P_END loaded from 0 to 37 mm by the load path of ``ngbet run``.
State C: order P_START loaded to 37 mm, then the order raised by one at a time at 37 mm, each
Newton solve started from the lower order's state (NGSolve's ``Set`` into the higher-order space).
Both states belong to the same finite element space; the script prints for each the force, the
energy and the stability diagnosis (lowest scaled eigenvalues of the tangent), and where their
displacements differ most on a 0.5 mm grid. One NGSolve thread; about 2.5 minutes with the defaults.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import ngsolve as ngs
import numpy as np

from ngbet.continuum import observables as obs
from ngbet.continuum.problem import ContinuumProblem
from ngbet.continuum.solver import ContinuumSolver
from ngbet.continuum.stability import diagnose_stability
from ngbet.numerics.engine import Steps
from ngbet.numerics.newton import newton
from ngbet.runner.continuum import load_path
from ngbet.runner.settings import continuum_solver, newton_settings
from ngbet.studies import _common as C

ARGS = sys.argv[1:]
CORNER = float(ARGS[0]) if ARGS else 0.125
P_START = int(ARGS[1]) if len(ARGS) > 1 else 10
P_END = int(ARGS[2]) if len(ARGS) > 2 else 12
U0_MM = 37.0


def scene(p: int):  # noqa: ANN201 - a Scene
    return C.base_scene(False).with_changes(
        **C.lagrange(20.0, p, CORNER),
        **{"outputs.error_estimate": "off", "loading.u0_mm": U0_MM, "loading.stops_mm": []},
    )


def loaded(p: int) -> ContinuumSolver:
    sc = scene(p)
    prob = continuum_solver(ContinuumProblem(sc))
    for _ in Steps(load_path(prob, sc)):
        pass
    if abs(prob.state.lam * 1e3 - U0_MM) > 1e-9:
        sys.exit(f"p = {p}: the load path stops at {prob.state.lam * 1e3:.3f} mm")
    return prob


def describe(name: str, prob: ContinuumSolver) -> None:
    pb = prob.problem
    t = pb.scene.specimen.t
    print(
        f"{name}: p = {pb.scene.discretization.order_u}, {pb.X.ndof} dofs, "
        f"F = {obs.reaction_force(pb, prob.residual()) * t:.7f} N, energy = {prob.energy() * t:.10e} J"
    )
    print(f"  {diagnose_stability(prob).message()[:240]}", flush=True)


def main() -> None:
    ngs.SetNumThreads(1)
    t0 = time.perf_counter()
    L = loaded(P_END)
    describe("load path", L)
    A = loaded(P_START)
    for p in range(P_START + 1, P_END + 1):
        B = continuum_solver(ContinuumProblem(scene(p)))
        for k in range(len(B.problem.field_names)):
            B.problem.gf.components[k].Set(A.problem.gf.components[k])
        B.state.set_load(U0_MM * 1e-3)
        st = dataclasses.replace(newton_settings(scene(p)), max_iterations=60, min_damping=1 / 1024)
        rep = newton(B, st, B.energy())
        if not rep.converged:
            sys.exit(f"p = {p} at {U0_MM} mm from p = {p - 1}: Newton failed ({rep.reason})")
        A = B
    describe(f"orders raised at the load from p = {P_START}", A)
    du = L.problem.gf.components[0] - A.problem.gf.components[0]
    sp = L.problem.scene.specimen
    diffs = []
    for x in np.linspace(0.0, sp.length_mm * 1e-3, int(sp.length_mm / 0.5) + 1):
        for y in np.linspace(0.0, sp.width_mm * 1e-3, int(sp.width_mm / 0.5) + 1):
            mp = L.problem.mesh(x, y)
            if mp.nr >= 0:
                diffs.append((float(np.hypot(*du(mp))), x * 1e3, y * 1e3))
    diffs.sort(reverse=True)
    print(
        "largest |u_L - u_C| [m] at (X, Y) [mm]:", ", ".join(f"{v:.2e} at ({x:.1f}, {y:.1f})" for v, x, y in diffs[:4])
    )
    print(f"wall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
