"""Running a continuum scene: build the problem, carry the load, record every converged step."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import ngsolve as ngs
import numpy as np

from . import observables as obs
from ..output import RunWriter, plot_force
from ..scene import Scene
from .output import write_vtk
from .solver import ConvergenceError, NewtonSettings, StepInfo, continuation

log = logging.getLogger(__name__)


def newton_settings(scene: Scene) -> NewtonSettings:
    s = scene.solver
    return NewtonSettings(rtol=s.rtol, atol=s.atol_energy, max_iterations=s.max_iterations,
                          grow_after=s.grow_after, growth=s.growth, cut=s.cut, predictor=s.predictor)


def run_continuum(scene: Scene, out: Path, progress: bool) -> dict[str, Any]:
    """Run a continuum scene into ``out`` (called by :func:`ngbet.run.run`)."""
    from .problem import ContinuumProblem
    from .estimate import RunEstimates, run_to_accuracy

    if scene.discretization.target_error > 0:  # accuracy on demand: the discretization is chosen
        return run_to_accuracy(scene, out, lambda sc, o: run_continuum(sc, o, progress))
    t0 = time.perf_counter()
    with RunWriter(out, scene) as writer:
        problem = ContinuumProblem(scene)
        estimates = RunEstimates(problem)
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
            row.update(estimates.row(info.lam, row.get("force_N")))
            state["t_prev"] = time.perf_counter()  # the estimate's time is not the next step's
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
                                "stabilization_K_Pa": list(problem.K_s_range),
                                "condensed": bool(problem.a_jac.condense), "setup_s": t_setup,
                                "threads": ngs.GetNumThreads() if hasattr(ngs, "GetNumThreads") else None}
        L = scene.loading
        t_cont = time.perf_counter()
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
        info.update(estimates.summary(time.perf_counter() - t_cont))
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


def diagnose_stability(problem: Any, k: int = 3) -> str:
    """Lowest eigenvalues of the (condensed) tangent at the last converged state, and what the
    lowest mode is.

    For minimization (and condensed mixed) formulations the tangent is the Hessian of the
    reduced energy: a non-positive eigenvalue means the equilibrium path has lost stability
    (a limit point or a bifurcation). With φ in the model the lowest mode (δu, δφ) is classified
    by r = ‖δφ − δi8‖ / ‖δi8‖, δi8 the linearized i8 of δu: r ≪ 1 is a mode of the constrained
    continuum (the model's own instability), r ≈ 1 a mode in which i8 varies inside elements and φ
    does not follow, which the constraint Λ ∈ L2(p − 2) cannot see (a mode of the discretization,
    suppressed by ``effects.stabilization_K``). Only computed after a failure: it costs seconds.
    """
    try:
        import scipy.sparse as sps
        from scipy.sparse.linalg import eigsh

        problem.factorize()
        vals, cols, ptr = problem.a_jac.mat.CSR()
        n = problem.a_jac.mat.height
        A = sps.csr_matrix((np.array(vals), np.array(cols), np.array(ptr)), shape=(n, n))
        if sps.triu(A, 1).nnz == 0:  # symmetric storage keeps the lower triangle only
            A = A + sps.tril(A, -1).T
        fd = np.flatnonzero(np.array(list(problem.freedofs), dtype=bool))
        Af = A[fd][:, fd]
        if not problem.a_jac.condense and "lam" in problem.field_names:
            return "the uncondensed saddle-point tangent is indefinite by construction: no stability test"
        # scale by the diagonal so that the eigenvalues are unit-free
        d = np.sqrt(np.abs(Af.diagonal()) + 1e-300)
        As = sps.diags(1 / d) @ Af @ sps.diags(1 / d)
        ev, V = eigsh(As, k=k, sigma=-1e-3, which="LM")
        lo = float(np.min(ev))
        state = "lost (the tangent is not positive definite)" if lo <= 0 else "kept"
        msg = (f"stability at the last converged load u0 = {problem.lam * 1e3:.4g} mm: lowest scaled "
               f"eigenvalues of the tangent {sorted(map(float, ev))}; stability {state}")
        if problem.phi is not None:
            x = np.zeros(n)
            x[fd] = V[:, int(np.argmin(ev))] / d
            r, where = mode_constraint_ratio(problem, x)
            m = problem.scene.material
            ill = ""
            for fam, alpha in ((1, m.alpha1), (2, m.alpha2)):
                area, lo_H = obs.ellipticity_loss_area(problem, fam) if alpha == 0 else (0.0, 0.0)
                if area > 0:
                    ill = (f"; alpha{fam} = 0 leaves i8 unregularized along the yarns of family {fam}, and the "
                           f"first-gradient energy has lost ellipticity for them on {area:.0f} mm² (compressed "
                           f"yarns; min eigenvalue {lo_H:.2f} K_sh): the model is ill-posed there and has no "
                           f"mesh-independent solution; give alpha{fam} > 0")
            if r > 0.5:
                kind = "a mode of the discretization: i8 varies inside the elements and phi does not follow"
                if not ill:
                    kind += (f"; raise effects.stabilization_K (now {problem.K_s_range[0]:.3g} to "
                             f"{problem.K_s_range[1]:.3g} Pa), e.g. to material.K_el = {m.K_el:.3g} Pa")
            else:
                kind = ("a mode of the constrained continuum (phi follows i8): the model's own limit point "
                        "or bifurcation")
            msg += (f"; lowest mode near (X, Y) = ({where[0]:.0f}, {where[1]:.0f}) mm with "
                    f"|dphi - di8| / |di8| = {r:.2f}: {kind}{ill}")
        return msg
    except Exception as exc:  # diagnosis must never hide the original error
        return f"stability check failed: {exc}"


def mode_constraint_ratio(problem: Any, x: Any) -> tuple[float, tuple[float, float]]:
    """r = ‖δφ − δi8‖ / ‖δi8‖ of a mode x (free dofs of the condensed tangent; the condensed local
    dofs are recovered by the harmonic extension), and the centroid [mm] of |∇δu|²."""
    mode = ngs.GridFunction(problem.X)
    mode.vec.FV().NumPy()[:] = x
    if problem.a_jac.condense:
        mode.vec.data += problem.a_jac.harmonic_extension * mode.vec
    du, dphi = mode.components[0], mode.components[1]
    F = problem.invariants().F
    G = ngs.Grad(du)
    m1, m2 = problem.m1, problem.m2
    di8 = ngs.InnerProduct(F * m1, G * m2) + ngs.InnerProduct(G * m1, F * m2)
    mesh = problem.mesh
    num = ngs.Integrate((dphi - di8) ** 2, mesh)
    den = ngs.Integrate(di8 * di8, mesh)
    dens = ngs.InnerProduct(G, G)
    tot = ngs.Integrate(dens, mesh)
    where = (1e3 * ngs.Integrate(dens * ngs.x, mesh) / tot, 1e3 * ngs.Integrate(dens * ngs.y, mesh) / tot)
    return float(np.sqrt(num / max(den, 1e-300))), where
