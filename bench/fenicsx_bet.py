"""The bias-extension test of the constrained micromorphic continuum in FEniCSx (dolfinx 0.5): a reference.

A standalone script, independent of ngbet, of the scene that ``ngbet run`` solves with
``effects.constraint = "penalty"``, ``effects.penalty_form = "full"``, ``effects.jamming = false``:
unknowns u (vector, P_p) and φ (scalar, P_p), energy per unit reference volume [Pa]

    W = ½K_el[(√i4 − 1)² + (√i6 − 1)²] + ½K_sh i8² + ½α1(∇φ·m1)² + ½α2(∇φ·m2)² + ½K(φ − i8)²

with F = I + ∇u, i4 = |F m1|², i6 = |F m2|², i8 = F m1·F m2 − m1·m2, m1 = (cos a, sin a),
m2 = (−cos a, sin a); u = 0, φ = 0 on X = 0 and u = (u0, 0), φ = 0 on X = L. The reaction force
is the residual tested with ψ = (X/L, 0) (e1 on the moving clamp, 0 on the fixed one) times the
thickness [N]. The mesh is dolfinx's ``create_rectangle`` with every square cut along the same
diagonal, from its lower right to its upper left corner (``DiagonalType.left``): the triangles of
ngbet's ``discretization.structured = true``. Newton (PETSc LU) starts at each load from the
previous load's solution, the loads 2, 4, …, 36, 37, 38, …, 56 mm.

Run with a Python that has dolfinx (not the ngbet venv)::

    OMP_NUM_THREADS=1 /usr/bin/python3 bench/fenicsx_bet.py [--h-mm 5] [--order 2] [--quad-degree 4]

It prints F(37), F(56) and the wall and CPU times of its parts as one JSON line, and writes
nothing else (the forms' compiled code goes to dolfinx's cache, ~/.cache/fenics).
"""

from __future__ import annotations

import time

T0_WALL, T0_CPU = time.perf_counter(), time.process_time()

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402

import numpy as np  # noqa: E402
import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from dolfinx.fem.petsc import NonlinearProblem  # noqa: E402
from dolfinx.nls.petsc import NewtonSolver  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

# the default scene's material (Table 1) and specimen
L, W_SPEC, THICKNESS = 0.220, 0.070, 0.015
K_EL, K_SH, ALPHA1, ALPHA2 = 7.0e5, 2.1e4, 2000.0, 20.0
LOADS_MM = [*range(2, 37, 2), 37, *range(38, 57, 2)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h-mm", type=float, default=5.0, help="mesh size [mm] (squares of this side, cut in two)")
    ap.add_argument("--order", type=int, default=2, help="polynomial order of u and φ")
    ap.add_argument("--penalty-K", type=float, default=1e7, help="penalty modulus K [Pa]")
    ap.add_argument("--quad-degree", type=int, default=0, help="quadrature degree (0: 2 × order)")
    ap.add_argument("--yarn-angle-deg", type=float, default=45.0)
    ap.add_argument("--rtol", type=float, default=1e-10, help="Newton's relative tolerance on the correction")
    ap.add_argument("--lu", default="mumps", help="PETSc's LU factorization package (mumps, petsc, superlu, umfpack)")
    args = ap.parse_args()
    t_imp = (time.perf_counter() - T0_WALL, time.process_time() - T0_CPU)

    # ---------------------------------------------------------------- mesh and setup (with the JIT)
    w1, c1 = time.perf_counter(), time.process_time()
    h = args.h_mm * 1e-3
    nx, ny = max(1, round(L / h)), max(1, round(W_SPEC / h))
    msh = mesh.create_rectangle(
        MPI.COMM_WORLD,
        [np.array([0.0, 0.0]), np.array([L, W_SPEC])],
        [nx, ny],
        mesh.CellType.triangle,
        diagonal=mesh.DiagonalType.left,
    )
    p = args.order
    cell = msh.ufl_cell()
    el_u = ufl.VectorElement("Lagrange", cell, p)
    el_phi = ufl.FiniteElement("Lagrange", cell, p)
    V = fem.FunctionSpace(msh, ufl.MixedElement([el_u, el_phi]))
    w = fem.Function(V)
    u, phi = ufl.split(w)

    a = math.radians(args.yarn_angle_deg)
    m1 = ufl.as_vector([math.cos(a), math.sin(a)])
    m2 = ufl.as_vector([-math.cos(a), math.sin(a)])
    F = ufl.Identity(2) + ufl.grad(u)
    Fm1, Fm2 = F * m1, F * m2
    i4, i6 = ufl.dot(Fm1, Fm1), ufl.dot(Fm2, Fm2)
    i8 = ufl.dot(Fm1, Fm2) - ufl.dot(m1, m2)
    gphi = ufl.grad(phi)
    energy = (
        0.5 * K_EL * ((ufl.sqrt(i4) - 1) ** 2 + (ufl.sqrt(i6) - 1) ** 2)
        + 0.5 * K_SH * i8**2
        + 0.5 * ALPHA1 * ufl.dot(gphi, m1) ** 2
        + 0.5 * ALPHA2 * ufl.dot(gphi, m2) ** 2
        + 0.5 * args.penalty_K * (phi - i8) ** 2
    )
    qdeg = args.quad_degree or 2 * p
    dx = ufl.dx(metadata={"quadrature_degree": qdeg})
    Pi = energy * dx
    residual = ufl.derivative(Pi, w, ufl.TestFunction(V))
    jacobian = ufl.derivative(residual, w, ufl.TrialFunction(V))

    # Dirichlet data: u and φ on both clamps
    fdim = msh.topology.dim - 1
    left = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[0], 0.0))
    right = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[0], L))
    Vu, _ = V.sub(0).collapse()
    Vphi, _ = V.sub(1).collapse()
    u_left, u_right, phi_zero = fem.Function(Vu), fem.Function(Vu), fem.Function(Vphi)
    bcs = []
    for facets, g in ((left, u_left), (right, u_right)):
        dofs_u = fem.locate_dofs_topological((V.sub(0), Vu), fdim, facets)
        bcs.append(fem.dirichletbc(g, dofs_u, V.sub(0)))
        dofs_phi = fem.locate_dofs_topological((V.sub(1), Vphi), fdim, facets)
        bcs.append(fem.dirichletbc(phi_zero, dofs_phi, V.sub(1)))

    problem = NonlinearProblem(residual, w, bcs=bcs, J=jacobian)
    solver = NewtonSolver(MPI.COMM_WORLD, problem)
    solver.convergence_criterion = "incremental"
    solver.rtol = args.rtol
    solver.atol = 1e-14
    solver.max_it = 25
    ksp = solver.krylov_solver
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType(args.lu)

    # the reaction's test field ψ = (X/L, 0) in the mixed space, and the residual form without Dirichlet rows
    psi = fem.Function(V)
    psi.sub(0).interpolate(lambda x: np.vstack([x[0] / L, np.zeros_like(x[0])]))
    psi.x.scatter_forward()
    residual_form = fem.form(residual)
    r_vec = fem.petsc.create_vector(residual_form)
    t_setup = (time.perf_counter() - w1, time.process_time() - c1)

    # ---------------------------------------------------------------- load path
    w2, c2 = time.perf_counter(), time.process_time()
    forces: dict[str, float] = {}
    iterations = 0
    for load_mm in LOADS_MM:
        u_right.x.array[0::2] = load_mm * 1e-3  # (u0, 0) at every node (block size 2)
        n, converged = solver.solve(w)
        if not converged:
            raise SystemExit(f"Newton did not converge at u0 = {load_mm} mm")
        iterations += n
        w.x.scatter_forward()
        if load_mm in (37, 56):
            with r_vec.localForm() as loc:
                loc.set(0.0)
            fem.petsc.assemble_vector(r_vec, residual_form)
            r_vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            forces[f"F{load_mm}_N"] = THICKNESS * float(r_vec.dot(psi.vector))
    t_solve = (time.perf_counter() - w2, time.process_time() - c2)

    record = {
        **forces,
        "h_mm": args.h_mm,
        "order": p,
        "quad_degree": qdeg,
        "penalty_K": args.penalty_K,
        "cells": int(msh.topology.index_map(2).size_global),
        "dofs": int(V.dofmap.index_map.size_global * V.dofmap.index_map_bs),
        "loads": len(LOADS_MM),
        "newton_iterations": iterations,
        "imports_s": {"wall": t_imp[0], "cpu": t_imp[1]},
        "setup_jit_s": {"wall": t_setup[0], "cpu": t_setup[1]},
        "solve_s": {"wall": t_solve[0], "cpu": t_solve[1]},
        "total_s": {"wall": time.perf_counter() - T0_WALL, "cpu": time.process_time() - T0_CPU},
    }
    print(json.dumps(record))


if __name__ == "__main__":
    main()
