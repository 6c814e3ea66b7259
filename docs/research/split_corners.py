"""Clamp corners split by bisection against Netgen's corner size: the force at 37 mm in p.

    python docs/research/split_corners.py [P ...]      (default: 8 9 10 11 12 13 14)

Netgen's ``corner_mesh_size_mm`` bounds the size of the elements at a corner, but the element that
holds a corner is not that small, and it is always a single triangle spanning the whole 90-degree
corner. The script prints that element's diameter at the corner (0, 0) for corner sizes 1, 0.5,
0.25 and 0.125 mm, as Netgen makes it and bisected twice. Then it solves the default scene
(Lagrange constraint, error estimate off) on the 20 mm mesh graded to 1 mm, with the elements at
the four clamp corners bisected twice (``discretization.corner_bisections = 2``; the corner is
then shared by two elements), at each
order P, loaded from 0 to 37 mm by the load path of ``ngbet run``. It prints the force at each
order and the limit of the sequence by :func:`ngbet.studies.reference.extrapolate`; last, the same
split on the mesh graded to 0.5 mm at P = 10. One NGSolve thread; about 5 minutes with the defaults.
"""

from __future__ import annotations

import sys
import time

import ngsolve as ngs

from ngbet.continuum import observables as obs
from ngbet.continuum.mesh import corner_elements, make_mesh
from ngbet.continuum.problem import ContinuumProblem
from ngbet.numerics.engine import Steps
from ngbet.runner.continuum import load_path
from ngbet.runner.settings import continuum_solver
from ngbet.studies import _common as C
from ngbet.studies.reference import extrapolate

ORDERS = [int(a) for a in sys.argv[1:]] or list(range(8, 15))
U0_MM = 37.0
BISECTIONS = 2


def scene(corner_mm: float, p: int, bisections: int = BISECTIONS):  # noqa: ANN201 - a Scene
    return C.base_scene(False).with_changes(
        **C.mesh(20.0, p, corner_mm, bisections),
        **{
            "effects.constraint": "lagrange",
            "outputs.error_estimate": "off",
            "loading.u0_mm": U0_MM,
            "loading.stops_mm": [],
        },
    )


def force(corner_mm: float, p: int) -> tuple[float | None, int, float]:
    """F(37 mm) [N] (None if the load path stops), dofs and seconds on the split mesh."""
    t0 = time.perf_counter()
    sc = scene(corner_mm, p)
    prob = continuum_solver(ContinuumProblem(sc))
    for _ in Steps(load_path(prob, sc)):
        pass
    reached = abs(prob.state.lam * 1e3 - U0_MM) < 1e-9
    F = obs.reaction_force(prob.problem, prob.residual()) * sc.specimen.t if reached else None
    if F is None:
        print(f"  the load path stops at {prob.state.lam * 1e3:.2f} mm")
    return F, prob.problem.X.ndof, time.perf_counter() - t0


def main() -> None:
    ngs.SetNumThreads(1)
    for c in (1.0, 0.5, 0.25, 0.125):
        n, d = corner_elements(make_mesh(scene(c, 2, 0).specimen, scene(c, 2, 0).discretization))
        n2, d2 = corner_elements(make_mesh(scene(c, 2).specimen, scene(c, 2).discretization))
        print(
            f"corner size {c:g} mm: {n} element(s) at the corner, diameter {d:.3f} mm; "
            f"bisected twice: {n2}, {d2:.3f} mm"
        )
    done: list[tuple[int, float]] = []
    for p in ORDERS:
        F, ndof, s = force(1.0, p)
        print(
            f"1 mm corners bisected twice, p = {p}: {ndof} dofs, "
            + (f"F(37) = {F:.7f} N" if F is not None else "no force")
            + f", {s:.0f} s",
            flush=True,
        )
        if F is not None:
            done.append((p, F))
    if len(done) >= 3:
        lim, bound = extrapolate([F for _, F in done], [p for p, _ in done])
        print(f"extrapolated over p = {', '.join(str(p) for p, _ in done)}: {lim:.5f} N +- {bound:.5f} N")
    F, ndof, s = force(0.5, 10)
    print(
        f"0.5 mm corners bisected twice, p = 10: {ndof} dofs, "
        + (f"F(37) = {F:.7f} N" if F is not None else "no force")
        + f", {s:.0f} s"
    )


if __name__ == "__main__":
    main()
