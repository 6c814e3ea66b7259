"""Running a continuum scene: build the problem, carry the load, record every converged step.

The load path is a generator of step records (:func:`load_path`); the loop of
:func:`run_continuum` alone decides what to write of each step.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import Any

import ngsolve as ngs

from ..continuum import observables as obs
from ..continuum.estimate import RunEstimates
from ..continuum.problem import ContinuumProblem
from ..continuum.solver import ContinuumSolver
from ..errors import ConvergenceError
from ..figures.data import map_file_name, save_map
from ..figures.run import start_plot
from ..kinematics import BetColumns, PictureFrameColumns
from ..numerics.engine import PathResult, StepRecord, Steps, progress_bar
from ..numerics.linear import assembly_thread_count
from ..numerics.path import load_steps
from ..output import RunWriter
from ..plot_process import active as plot_service
from ..scene.document import Scene
from ..scene.physical import load_symbol
from .arclength import MODE_KEY, arclength_runner
from .fields import write_vtk
from .ladder import run_to_accuracy
from .settings import solver_settings
from .threads import ngsolve_threads

#: each element of the shear-angle map is split into this many² triangles (p = 2 fields: enough)
MAP_SUBDIVISION = 2

log = logging.getLogger(__name__)

__all__ = ["load_path", "run_continuum"]


def _run_rung(scene: Scene, out: Path, progress: bool, measured: Any) -> dict[str, Any]:
    """One rung of the accuracy ladder, on the NGSolve threads its scene asks for (:mod:`.threads`)."""
    with ngsolve_threads(scene):
        return run_continuum(scene, out, progress, measured)


def _run_to_accuracy(scene: Scene, out: Path, progress: bool, measured: Any) -> dict[str, Any]:
    """:func:`ngbet.runner.ladder.run_to_accuracy` into ``out``, its record added to summary.json.

    Also where the target is not reached (status failed) and where the climb is interrupted or
    stops on an error (that setting's converged steps are in ``out``, the settings before it in the
    record). The folder's scene.toml is ``scene`` as asked, with its target (the discretization
    that ran: ``accuracy.chosen``): run again, it gives the same results.
    """
    try:
        acc = run_to_accuracy(scene, out, functools.partial(_run_rung, progress=progress, measured=measured))
    except ConvergenceError as err:  # the target not reached: its record, then the failure
        if "accuracy" in err.path_info:
            record = {"accuracy": err.path_info["accuracy"], "status": "failed", "error": str(err)}
            RunWriter.amend(out, record, scene)
        raise
    except BaseException as exc:  # interrupted, or an error: the climb so far beside that setting's steps
        if isinstance(getattr(exc, "accuracy", None), dict) and (out / "summary.json").is_file():
            RunWriter.amend(out, {"accuracy": exc.accuracy}, scene)  # type: ignore[attr-defined]
        raise
    return RunWriter.amend(out, {k: acc[k] for k in ("accuracy", "warnings") if k in acc}, scene)


def run_continuum(scene: Scene, out: Path, progress: bool, measured: Any = None) -> dict[str, Any]:
    """Run a continuum scene into ``out`` (called by :func:`ngbet.run.run`).

    Raises
    ------
    ngbet.errors.ConvergenceError
        when the load cannot be carried to the end (the converged steps are on disk).
    """
    if scene.discretization.target_error > 0:  # accuracy on demand: the discretization is chosen
        return _run_to_accuracy(scene, out, progress, measured)
    t0 = time.perf_counter()
    draw = functools.partial(start_plot, service=plot_service(), measured=measured)
    with RunWriter(out, scene, getattr(measured, "path", None)) as writer:
        solver = ContinuumSolver(ContinuumProblem(scene), solver_settings(scene))
        estimates = RunEstimates(solver)
        info = _setup_info(solver, time.perf_counter() - t0)
        warnings: list[str] = []  # found at the end of the path (the scene's own: the writer's preflight)
        with progress_bar(progress, scene.loading.u0_mm, load_symbol(scene.test)) as bar:
            recorder = _StepWriter(solver, writer, out, estimates)
            t_cont = time.perf_counter()
            path = load_path(solver, scene)
            steps = Steps(path)
            walk = iter(steps)  # held: the path stays open for an interrupt to reach (below)
            try:
                for rec in walk:
                    if rec.left is not None:  # before the row: its estimate continues the branch left
                        estimates.spread.left(*rec.left, rec.snap)
                    recorder.on_step(rec)
                    if bar is not None:
                        bar(max(rec.u0, 0.0))
                assert steps.result is not None
                res = steps.result
                _write_mode(solver, res.path_info, writer)
            except KeyboardInterrupt as exc:  # the summary ("interrupted") keeps the path's snaps so far
                if not hasattr(exc, "path_info"):  # raised while a step was written: the path attaches them
                    with contextlib.suppress(BaseException):
                        path.throw(exc)
                exc.path_info = {  # type: ignore[attr-defined]
                    **_solver_info(solver, None),
                    **snaps_in_units(getattr(exc, "path_info", {}), scene.specimen.t),
                }
                raise
            except ConvergenceError as err:
                _write_mode(solver, err.path_info, writer)
                info.update(_solver_info(solver, None), **snaps_in_units(err.path_info, scene.specimen.t))
                info.update(estimates.spread.summary())  # the branches left before the failure
                writer.summary(info, "failed", str(err))
                if writer.rows and scene.outputs.plot:
                    writer.plot(draw)()
                raise
        info.update(estimates.summary(time.perf_counter() - t_cont))
        for said in estimates.warnings():
            warnings.append(said)
            log.warning("%s", said)
        return _finish(solver, scene, writer, res, info, warnings, draw)


def _write_mode(problem: ContinuumSolver, path_info: dict[str, Any], writer: RunWriter) -> None:
    """Write the instability mode that path following found (if any) and name its files in ``path_info``."""
    found = path_info.pop(MODE_KEY, None)
    if found is None:
        return
    from .fields import write_mode

    mode, name, title = found
    saved = problem.x.copy()
    files = writer.write_group(name, lambda stem: write_mode(problem, mode, stem, title))
    problem.x[:] = saved
    path_info["instability_mode_files"] = [f.name for f in files]


def load_path(problem: ContinuumSolver, scene: Scene) -> Generator[StepRecord, None, PathResult]:
    """The load path of the scene: a generator of its step records (nothing written; the caller decides).

    Arc length follows where ``solver.path_following`` asks for it; the mode of an instability it
    found is left in ``path_info`` (under :data:`~ngbet.numerics.arclength.MODE_KEY`) for the
    runner to write.
    """
    arclength = None if scene.solver.path_following == "displacement" else arclength_runner(problem)
    # the picture frame's reaction test field follows the load (ContinuumProblem): the path gets none
    psi = None if problem.problem.frame else problem.problem.psi_u.vec.FV().NumPy().copy()
    return load_steps(
        problem,
        problem.settings.path,
        problem.settings.newton,
        hessian=problem if problem.can_relax else None,
        watch=problem.problem,
        locate=problem.problem,
        settle=problem if problem.patch is not None else None,
        diagnose=lambda: _diagnose(problem),
        psi=psi,
        arclength=arclength,
    )


def _diagnose(problem: ContinuumSolver) -> Any:
    from ..continuum.stability import diagnose_stability  # scipy's eigensolver: imported when a run fails

    return diagnose_stability(problem)


def _setup_info(solver: ContinuumSolver, t_setup: float) -> dict[str, Any]:
    return {
        "model": "continuum",
        "dofs": solver.ndofs(),
        "linear_solver": solver.linear.inverse_type,
        "stabilization_K_Pa": list(solver.problem.K_s_range),
        "condensed": solver.linear.condensed,
        "setup_s": t_setup,
        "compile_mode": solver.compile_mode,
        "threads": ngs.GetNumThreads(),
        "assembly_threads": assembly_thread_count(),
    }


class _StepWriter:
    """Writes the row, profile and (if asked) fields of each converged step, as ``[outputs]`` asks."""

    def __init__(self, solver: ContinuumSolver, writer: RunWriter, out: Path, estimates: Any) -> None:
        self.solver, self.problem = solver, solver.problem
        self.writer, self.out, self.estimates = writer, out, estimates
        problem = solver.problem
        sp, ld = problem.scene.specimen, problem.scene.loading
        pf = problem.scene.picture_frame
        self.zones = None if problem.frame else obs.ZoneShearMeans(problem)
        self.bet = (
            PictureFrameColumns(pf.frame_mm, pf.fabric_mm)
            if problem.frame
            else BetColumns(sp.length_mm, sp.width_mm, sp.yarn_angle_deg)
        )
        # the map's stations: the load stops and the final load
        self.stations = (*ld.stops_mm, ld.u0_mm)
        self.t_prev = time.perf_counter()
        self.timers = dict(solver.timers)

    def on_step(self, info: StepRecord) -> None:
        """Record one converged step."""
        p, o = self.problem, self.problem.scene.outputs
        row: dict[str, Any] = {"step": len(self.writer.rows) + 1, "u0_mm": round(info.u0 * 1e3, 9)}
        row.update(self._observables(info))
        row.update(self.bet.row(row["u0_mm"], row.get("force_N")))
        # a snap-through ended at this step (1), and the energy it released [J] (as the network's rows)
        row.update(snap=int(info.snap), released_J=info.released * p.scene.specimen.t if info.snap else 0.0)
        now = time.perf_counter()
        row["newton_iterations"] = info.iterations
        row["step_wall_s"] = now - self.t_prev
        timers = self.solver.timers
        row.update({k: v - self.timers[k] for k, v in timers.items()})
        self.timers = dict(timers)
        row.update(self.estimates.row(info.u0, row.get("force_N")))
        self.t_prev = time.perf_counter()  # the estimate's time is not the next step's
        profile = None
        if o.profile:
            X, uy = obs.midaxis_profile(p, o.profile_points)
            profile = list(zip(X * 1e3, uy * 1e3, strict=True))
        self.writer.add_step(row, profile)
        if o.plot and any(abs(row["u0_mm"] - s) < 1e-6 for s in self.stations):
            samples, u0 = obs.map_samples(p, MAP_SUBDIVISION), row["u0_mm"]
            self.writer.write(map_file_name(u0), lambda tmp: save_map(tmp, samples, u0))
        if o.vtk and o.vtk_every_step:
            self.writer.write(f"fields_{row['step']:03d}.vtu", lambda tmp: write_vtk(p, tmp.with_suffix("")))

    def _observables(self, info: StepRecord) -> dict[str, Any]:
        """Force, double force, energy, centre shear and constraint error of the state."""
        p, o, t = self.problem, self.problem.scene.outputs, self.problem.scene.specimen.t
        r = info.residual if info.residual is not None else self.solver.residual()
        row: dict[str, Any] = {}
        if o.reaction:
            R = obs.reaction_force(p, r)
            row.update(force_N_per_m=R, force_N=R * t)
            if not p.frame:  # the frame's path has no fixed reaction test field to differentiate (load_path)
                row["dforce_du0_N_per_mm"] = info.dforce_du0 * t * 1e-3
        if o.double_force and p.psi_phi is not None:
            T = obs.reaction_double_force(p, r)
            row.update(double_force_N=T, double_force_Nm=T * t)
        if o.energy:
            E = self.solver.energy()
            row.update(energy_J_per_m=E, energy_J=E * t)
        row["gamma_centre_deg"] = obs.centre_shear_angle_deg(p)
        if self.zones is not None:
            row.update({f"gamma_{z}_deg": g for z, g in self.zones().items()})
        else:
            row.update(obs.frame_fabric_means(p))
        if "constraint" in o.fields and p.phi is not None:
            row["constraint_rms"] = obs.constraint_l2(p)
        return row


def _finish(
    solver: ContinuumSolver,
    scene: Scene,
    writer: RunWriter,
    res: PathResult,
    info: dict[str, Any],
    warnings: list[str],
    draw: Callable[[Path], Callable[[], Path | None]],
) -> dict[str, Any]:
    """Final fields, statistics, the multiplier check, summary and plot.

    results.csv is complete here, so the plot is asked for first and drawn (by the plot process)
    while the rest is written; it is waited for in any case, so that no half-written figure is
    left behind by an error in between.
    """
    plotted = writer.plot(draw) if scene.outputs.plot else None
    try:
        summary = _final_files(solver, scene, writer, res, info, warnings)
    except BaseException:
        if plotted is not None:
            with contextlib.suppress(Exception):
                plotted()
        raise
    if plotted is not None:
        plotted()
    return summary


def _final_files(
    solver: ContinuumSolver, scene: Scene, writer: RunWriter, res: PathResult, info: dict[str, Any], warnings: list[str]
) -> dict[str, Any]:
    """Final fields, statistics, the multiplier check and the summary."""
    problem = solver.problem
    if scene.outputs.vtk:
        writer.write("fields.vtu", lambda tmp: write_vtk(problem, tmp.with_suffix("")))
    info.update(_solver_info(solver, res))
    problem.inverted_allowed = 0.0
    inverted = problem.admissible()
    if inverted:  # the energy has no barrier against it: say so rather than report the state as physical
        warnings.append(
            f"at the final load {inverted}: the yarn invariants do not see the orientation of the "
            "material, so the model lets the specimen fold over itself there; the force there is "
            "not that of a physical state"
        )
        log.warning("%s", warnings[-1])
    info["warnings"] = warnings
    osc = obs.multiplier_oscillation(problem)
    if osc is not None:
        info["multiplier_oscillation"] = osc
        if osc > 0.5:
            disc = scene.discretization
            orders = f"(u, phi, lam) = ({disc.p_u}, {disc.p_phi}, {problem.p_lam})"
            if problem.full_as_mixed:
                why = "the pointwise penalty locks (use effects.constraint = 'lagrange' or penalty_form = 'mixed')"
            elif problem.p_lam == max(disc.p_u - 2, 0) and disc.p_phi == disc.p_u and disc.p_u >= 2:
                # measured on a Twintex fabric scene at its final load: 0.86, 0.60, 0.42 on h = 25, 12.5, 6.25 mm
                why = (
                    f"the orders {orders} are the stable pair, whose oscillation falls as the mesh is refined: "
                    f"the mesh (h = {disc.mesh_size_mm:g} mm) is too coarse to resolve the multiplier "
                    "(the force and the displacements do not need it)"
                )
            else:
                why = (
                    f"the orders {orders} are not a stable pair (order_phi and order_lam = 'auto' give one for "
                    "order_u >= 2)"
                )
            warnings.append(
                f"the multiplier oscillates (‖Λ − ΠΛ‖/‖Λ‖ = {osc:.2f} away from the clamps, Π the L2 "
                f"projection onto continuous fields): {why}"
            )
            # the stable pair on a coarse mesh needs no action (force and displacements are fine): summary.json only
            (log.info if "do not need it" in why else log.warning)("%s", warnings[-1])
    return writer.summary(info, "ok")


def snaps_in_units(path_info: dict[str, Any], t: float) -> dict[str, Any]:
    """``path_info`` with its snap-throughs in N, J and mm (the solver's are per unit thickness)."""
    snaps = path_info.get("snaps")
    if not snaps:
        return path_info
    out = []
    for s in snaps:
        out.append(
            {
                "u0_mm": s["u0_mm"],
                "u0_before_mm": s["u0_before_mm"],
                "force_before_N": s["reaction_before"] * t,
                "force_after_N": s["reaction_after"] * t,
                "energy_released_J": s["released"] * t,
                "clamp_work_J": s["work"] * t,
                "energy_before_J": s["energy_before"] * t,
                "energy_after_J": s["energy_after"] * t,
                "lowest_eigenvalue_after": s["lowest_eigenvalue_after"],
                "relaxation_iterations": s["relaxation_iterations"],
                **{k: s[k] for k in ("location_mm", "spread_mm", "max_du_mm") if k in s},
            }
        )
    return {**path_info, "snaps": out}


def _solver_info(solver: ContinuumSolver, res: PathResult | None) -> dict[str, Any]:
    d: dict[str, Any] = {"timers": dict(solver.timers), "counts": dict(solver.counts)}
    if res is not None:
        d.update(snaps_in_units(res.path_info, solver.problem.scene.specimen.t))
        d["load_steps"] = len(res.steps)
        d["step_cuts"] = res.cuts
        chord = sum(s.iterations for s in res.steps if "(chord)" in s.reason)  # the grid rows' (chord module)
        d["newton_iterations"] = (
            sum(s.iterations for s in res.steps) - chord + sum(a.iterations for a in res.attempts if not a.converged)
        )
        if chord:
            d["chord_iterations"] = chord
    return d
