"""Running a scene: build the problem, carry the load, record every converged step.

:func:`run` is the one entry point behind ``ngbet run``; it dispatches on ``scene.model``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import ngsolve as ngs

from . import observables as obs
from .output import RunWriter, plot_force
from .scene import Scene
from .solver import ConvergenceError, NewtonSettings, StepInfo, continuation

log = logging.getLogger(__name__)


def newton_settings(scene: Scene) -> NewtonSettings:
    s = scene.solver
    return NewtonSettings(rtol=s.rtol, atol=s.atol_energy, max_iterations=s.max_iterations,
                          grow_after=s.grow_after, growth=s.growth, cut=s.cut, predictor=s.predictor)


def run(scene: Scene, out: str | Path, progress: bool = False) -> dict[str, Any]:
    """Run a scene into the folder ``out``; returns the summary (also in summary.json).

    Raises
    ------
    ngbet.solver.ConvergenceError
        when the load cannot be carried to the end; every converged step is on disk by then,
        and summary.json says ``"status": "failed"`` with the error.
    """
    threads = scene.solver.threads or None
    if threads:
        ngs.SetNumThreads(threads)
    with ngs.TaskManager():  # NGSolve's assembly and sparse factorizations run in its threads
        if scene.model == "discrete":
            from . import discrete

            return discrete.run(scene, out, progress=progress)
        return _run_continuum(scene, Path(out), progress)


def _run_continuum(scene: Scene, out: Path, progress: bool) -> dict[str, Any]:
    from .problem import ContinuumProblem

    t0 = time.perf_counter()
    writer = RunWriter(out, scene)
    problem = ContinuumProblem(scene)
    t_setup = time.perf_counter() - t0
    sp, o = scene.specimen, scene.outputs
    warnings = []
    if scene.effects.bending and scene.discretization.p_u == 1:
        # measured, default scene at 37 mm: 84.4, 80.3, 76.3 N on h = 10, 5, 2.5 mm against 61.2 N
        # (p = 2, 3 extrapolated), with ‖Λ‖ doubling at each refinement: P1 locks
        warnings.append("order_u = 1 locks under the constraint phi = i8 (the force converges very slowly "
                        "from above and the multiplier grows like 1/h); use order_u >= 2")
        log.warning("%s", warnings[-1])
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=scene.loading.u0_mm, unit="mm", desc="u0", bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} mm [{elapsed}<{remaining}]")
    state = {"t_prev": time.perf_counter(), "timers": dict(problem.timers)}

    def on_step(info: StepInfo) -> None:
        r = info.report.residual if info.report.residual is not None else problem.residual()
        row: dict[str, Any] = {"step": len(writer.rows) + 1, "u0_mm": round(info.lam * 1e3, 9)}
        if o.reaction:
            R = obs.reaction_force(problem, r)
            row["force_N_per_m"] = R
            row["force_N"] = R * sp.t
        if o.double_force and problem.psi_phi is not None:
            T = obs.reaction_double_force(problem, r)
            row["double_force_N"] = T
            row["double_force_Nm"] = T * sp.t
        if o.energy:
            E = problem.energy()
            row["energy_J_per_m"] = E
            row["energy_J"] = E * sp.t
        row["gamma_centre_deg"] = obs.centre_shear_angle_deg(problem)
        if "constraint" in o.fields and problem.phi is not None:
            row["constraint_rms"] = obs.constraint_l2(problem)
        now = time.perf_counter()
        row["newton_iterations"] = info.iterations
        row["step_wall_s"] = now - state["t_prev"]
        for k, v in problem.timers.items():
            row[k] = v - state["timers"][k]
        state["t_prev"], state["timers"] = now, dict(problem.timers)
        profile = None
        if o.profile:
            X, uy = obs.midaxis_profile(problem, o.profile_points)
            profile = list(zip(X * 1e3, uy * 1e3))
        writer.add_step(row, profile)
        if o.vtk and o.vtk_every_step:
            write_vtk(problem, out / f"fields_{row['step']:03d}")
        if bar is not None:
            bar.update(row["u0_mm"] - bar.n)

    info: dict[str, Any] = {"model": "continuum", "dofs": problem.ndofs(), "linear_solver": problem.inverse_type,
                            "condensed": bool(problem.a_jac.condense), "setup_s": t_setup,
                            "threads": ngs.GetNumThreads() if hasattr(ngs, "GetNumThreads") else None}
    L = scene.loading
    try:
        res = continuation(problem, L.u0_mm * 1e-3, L.first_step_mm * 1e-3, newton_settings(scene),
                           max_step=L.max_step_mm * 1e-3, min_step=L.min_step_mm * 1e-3,
                           stops=[s * 1e-3 for s in L.stops_mm], on_step=on_step,
                           diagnose=lambda: diagnose_stability(problem))
    except ConvergenceError as err:
        if bar is not None:
            bar.close()
        info.update(_solver_info(problem, None))
        writer.summary(info, "failed", str(err))
        if writer.rows and o.plot:
            plot_force(out)
        raise
    if bar is not None:
        bar.close()
    if o.vtk:
        write_vtk(problem, out / "fields")
    info.update(_solver_info(problem, res))
    info["warnings"] = warnings
    osc = obs.multiplier_oscillation(problem)
    if osc is not None:
        info["multiplier_oscillation"] = osc
        if osc > 0.5:
            why = ("the pointwise penalty locks (use effects.constraint = 'lagrange' or penalty_form = 'mixed')"
                   if problem.full_as_mixed else
                   f"the orders (u, phi, lam) = ({scene.discretization.p_u}, {scene.discretization.p_phi}, "
                   f"{problem.p_lam}) are not a stable pair (the default orders are, for order_u >= 2)")
            warnings.append(f"the multiplier oscillates ({osc:.2f} of its L2 norm is not continuous): {why}")
            log.warning("%s", warnings[-1])
    summary = writer.summary(info, "ok")
    if o.plot:
        plot_force(out)
    return summary


def _solver_info(problem: Any, res: Any) -> dict[str, Any]:
    d: dict[str, Any] = {"timers": dict(problem.timers), "counts": dict(problem.counts)}
    if res is not None:
        d["load_steps"] = len(res.steps)
        d["step_cuts"] = res.cuts
        d["newton_iterations"] = sum(s.iterations for s in res.steps) + sum(
            a.report.iterations for a in res.attempts if not a.report.converged)
    return d


def write_vtk(problem: Any, path: Path) -> None:
    """Final fields for ParaView (``path``.vtu); warp by 'displacement' to see the shape."""
    funcs = obs.field_functions(problem, problem.scene.outputs.fields)
    ngs.VTKOutput(problem.mesh, coefs=list(funcs.values()), names=list(funcs), filename=str(path),
                  subdivision=max(0, problem.scene.discretization.p_u - 1), legacy=False).Do()


def diagnose_stability(problem: Any, k: int = 3) -> str:
    """Lowest eigenvalues of the (condensed) tangent at the last converged state.

    For minimization (and condensed mixed) formulations the tangent is the Hessian of the
    reduced energy: a non-positive eigenvalue means the equilibrium path has lost stability
    (a limit point or a bifurcation). Only computed after a failure: it costs seconds.
    """
    try:
        import numpy as np
        import scipy.sparse as sps
        from scipy.sparse.linalg import eigsh

        problem.factorize()
        vals, cols, ptr = problem.a_jac.mat.CSR()
        n = problem.a_jac.mat.height
        A = sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(n, n))
        if sps.triu(A, 1).nnz == 0:  # symmetric storage keeps the lower triangle only
            A = A + sps.tril(A, -1).T
        fd = np.array(list(problem.freedofs), dtype=bool)
        Af = A[fd][:, fd]
        if not problem.a_jac.condense and "lam" in problem.field_names:
            return "the uncondensed saddle-point tangent is indefinite by construction: no stability test"
        # scale by the diagonal so that the eigenvalues are unit-free
        d = np.sqrt(np.abs(Af.diagonal()) + 1e-300)
        As = sps.diags(1 / d) @ Af @ sps.diags(1 / d)
        ev = eigsh(As, k=k, sigma=-1e-3, which="LM", return_eigenvectors=False)
        lo = float(np.min(ev))
        state = "lost (the tangent is not positive definite)" if lo <= 0 else "kept"
        return (f"stability at the last converged load u0 = {problem.lam * 1e3:.4g} mm: lowest scaled "
                f"eigenvalues of the tangent {sorted(map(float, ev))}; stability {state}")
    except Exception as exc:  # diagnosis must never hide the original error
        return f"stability check failed: {exc}"
