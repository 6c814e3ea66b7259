"""Entry point of the discrete model: scene -> network -> load path -> run folder.

Per converged step a row of results.csv (force on the moving clamp, energies per term, zone shear
angles, largest slip, Newton iterations, wall time, lowest tangent eigenvalue) and the mid-axis
profile; at u0 = 37 mm (when passed; the paper's intermediate shape) and at the last converged
step the state (``state_XXmm.npz``: deformed yarns, slip and angle per crossing) and its picture
(``yarns_XXmm.png``).
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..kinematics import gamma_a
from ..output import RunWriter, plot_force
from ..scene import Scene, Specimen
from . import observables as ob
from .model import ENERGY_PARTS, NetworkModel
from .network import network_from_scene
from .solver import ConvergenceError, StepControl, StepInfo, solve_path

log = logging.getLogger(__name__)

SHAPE_STATIONS_MM = (37.0,)  # the paper shows shapes at 37 mm and at the end (56 mm)


def step_control(scene: Scene) -> StepControl:
    """The solver numerics of a scene in SI units; the steps are the smaller of [loading] and [discrete]."""
    ld, so, d = scene.loading, scene.solver, scene.discrete
    max_step = min(ld.max_step_mm, d.max_step_mm)
    return StepControl(u0_final=ld.u0_mm * 1e-3, first_step=min(ld.first_step_mm, d.first_step_mm) * 1e-3,
                       max_step=max_step * 1e-3, min_step=ld.min_step_mm * 1e-3, rtol=so.rtol,
                       atol=so.atol_energy, max_iterations=so.max_iterations, grow_after=so.grow_after,
                       growth=so.growth, cut=so.cut, predictor=so.predictor, backend=so.linear_solver,
                       stations=tuple(s * 1e-3 for s in SHAPE_STATIONS_MM if s < ld.u0_mm),
                       snap_bracket=min(max(4 * ld.min_step_mm, 1.0), max_step) * 1e-3)


def step_row(model: NetworkModel, info: StepInfo, u: np.ndarray, specimen: Specimen) -> dict[str, Any]:
    """One results.csv row from a converged state (zone shears beside those of ideal BET kinematics)."""
    net = model.net
    Fx, Fy = model.reaction(info.gradient)
    parts = model.energy_parts(u)
    gz = ob.zone_means(net, ob.crossing_gamma(net, u))
    g_ideal = gamma_a(specimen, info.u0 * 1e3) if info.u0 * 1e3 < specimen.locking_u0_mm else math.nan
    slip = ob.crossing_slip(net, u)
    row: dict[str, Any] = {"step": info.step, "u0_mm": round(info.u0 * 1e3, 9), "force_N": Fx, "force_y_N": Fy,
                           "energy_J": info.energy}
    row.update({f"energy_{k}_J": parts[k] for k in ENERGY_PARTS})
    row.update({"newton_iterations": info.iterations, "step_wall_s": round(info.wall_s, 4),
                "max_slip_mm": float(slip.max(initial=0.0)) * 1e3,
                "gamma_A_deg": np.degrees(gz["A"]), "gamma_B_deg": np.degrees(gz["B"]),
                "gamma_C_deg": np.degrees(gz["C"]), "gamma_A_ideal_deg": np.degrees(g_ideal),
                "gamma_B_ideal_deg": np.degrees(g_ideal) / 2, "lambda_min": info.lambda_min, "snap": int(info.snap),
                "released_J": info.released})
    return row


@contextlib.contextmanager
def _threads(n: int) -> Iterator[None]:
    """NGSolve's threads for the sparse factorization: ``solver.threads`` (0: all cores), as in
    ``ngbet run``, also when the discrete model is run directly. Outside a TaskManager NGSolve's
    sparse Cholesky runs on all cores of its own accord; one thread is the default because the
    2-core machines are shared (bench/README.md, discrete section)."""
    import ngsolve as ngs

    before = ngs.GetNumThreads() if hasattr(ngs, "GetNumThreads") else None
    if n:
        ngs.SetNumThreads(n)
    try:
        with ngs.TaskManager():
            yield
    finally:
        if n and before:
            ngs.SetNumThreads(before)


def run(scene: Scene, out: str | Path, progress: bool = True) -> dict[str, Any]:
    """Run the discrete BET model of ``scene`` and write its run folder.

    Parameters
    ----------
    scene : the scene (``scene.discrete``, ``scene.specimen``, ``scene.loading``, ``scene.solver``)
    out : run folder (created)
    progress : show a tqdm bar over the clamp displacement

    Returns
    -------
    The summary dict (also in ``out/summary.json``).

    Raises
    ------
    ngbet.errors.ConvergenceError
        when a step cannot be completed; the converged steps and ``summary.json`` (``"status":
        "failed"``) are on disk by then.
    """
    out = Path(out)
    with RunWriter(out, scene) as writer:
        t0 = time.perf_counter()
        net = network_from_scene(scene)
        model = NetworkModel.from_scene(scene, net)
        t_build = time.perf_counter() - t0
        counts = net.counts()
        log.info("discrete network: %s", counts)
        ctl = step_control(scene)
        n_prof = scene.outputs.profile_points
        last: dict[str, Any] = {"u": np.zeros(model.n_dofs), "u0": 0.0}

        def snapshot(u: np.ndarray, u0: float) -> None:
            tag = f"{u0 * 1e3:.0f}mm"
            ob.save_state(out / f"state_{tag}.npz", net, u, u0)
            if scene.outputs.plot:
                ob.plot_state(out / f"yarns_{tag}.png", net, u, u0)

        def on_step(info: StepInfo, u: np.ndarray) -> None:
            row = step_row(model, info, u, scene.specimen)
            X, uy = ob.midline_profile(net, u, n_prof)
            writer.add_step(row, profile=list(zip((X * 1e3).tolist(), (uy * 1e3).tolist())))
            last["u"], last["u0"] = u, info.u0
            if any(abs(info.u0 - s) < 1e-12 for s in ctl.stations):
                snapshot(u, info.u0)
            log.debug("step %d u0 = %.4g mm F = %.5g N its %d", info.step, info.u0 * 1e3, row["force_N"], info.iterations)

        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=round(ctl.u0_final * 1e3, 6), unit="mm", desc="discrete BET",
                       bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} mm [{elapsed}<{remaining}]")

            class _MM:
                def update(self, h: float) -> None:
                    bar.update(h * 1e3)

        info: dict[str, Any] = {"model": "discrete", "network": counts, "dofs": model.n_dofs,
                                "free_dofs": int((~model.fixed).sum()), "t_build_s": t_build,
                                "threads": scene.solver.threads}
        status, error, failure = "ok", None, None
        try:
            with _threads(scene.solver.threads):
                stats = solve_path(model, ctl, on_step=on_step, progress=_MM() if bar is not None else None)
        except ConvergenceError as exc:
            status, error, failure = "failed", str(exc), exc
            stats = {"last_converged_u0_mm": exc.last_converged_u0 * 1e3, "attempted_u0_mm": exc.attempted_u0 * 1e3,
                     "residual_history": exc.residual_history}
        finally:
            if bar is not None:
                bar.close()
        stats.pop("u", None)
        if last["u0"] > 0:
            snapshot(last["u"], last["u0"])
        rows = writer.rows
        info.update({k: v for k, v in stats.items()})
        info["snap_event_count"] = len(stats.get("snap_events", []))
        info["newton_iterations_total"] = int(sum(r["newton_iterations"] for r in rows))
        info["max_slip_mm"] = max((r["max_slip_mm"] for r in rows), default=0.0)
        info["t_solve_s"] = time.perf_counter() - t0 - t_build
        summary = writer.summary(info, status, error)
        if scene.outputs.plot and rows:
            plot_force(out)
        if failure is not None:
            raise failure
        return summary
