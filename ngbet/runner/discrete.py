"""A discrete scene into a run folder: network, load path, one loop writing each converged step.

The network (:mod:`ngbet.discrete`) yields its converged steps
(:func:`ngbet.discrete.solver.load_steps`); the one ``for`` loop of :func:`run_discrete`
consumes them, as :mod:`ngbet.runner.continuum` does the continuum's. The threads (NGSolve's and
the BLAS pools') are those of :func:`ngbet.runner.threads.ngsolve_threads`, around the run.

Per converged step a row of results.csv (force on the moving clamp and its slope dF/du0, energies
per term, centre and zone shear angles, the kinematic shear angle and the normalised shear force
of the ideal test, largest slip, Newton iterations, wall time, lowest tangent eigenvalue)
and the mid-axis profile (as ``[outputs]`` asks), at every multiple of ``loading.output_every_mm``
and wherever the step control lands; at each of ``loading.stops_mm`` (37 mm by
default: the paper's intermediate shape) and at the last converged step the state
(``state_XXmm.npz``: deformed yarns, slip and angle per crossing), and its picture
(``yarns_XXmm.png``, with ``outputs.plot``), drawn from that file with the run's other figures
(:func:`ngbet.figures.run.draw_run`, in the plot process where one runs).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..discrete import observables as ob
from ..discrete.model import ENERGY_PARTS, NetworkModel
from ..discrete.network import network_from_scene
from ..discrete.solver import load_steps
from ..errors import ConvergenceError
from ..figures.run import start_plot
from ..kinematics import BetColumns, gamma_a
from ..numerics.engine import PathResult, StepRecord, progress_bar
from ..output import RunWriter
from ..plot_process import active as plot_service
from ..scene.document import Scene
from .settings import step_control

__all__ = ["run_discrete", "step_row"]

log = logging.getLogger(__name__)


def step_row(model: NetworkModel, info: StepRecord, u: np.ndarray, scene: Scene) -> dict[str, Any]:
    """One results.csv row from a converged state (zone shears beside those of ideal BET kinematics).

    The force and energy columns follow ``outputs.reaction`` and ``outputs.energy``.
    """
    net, specimen, o = model.net, scene.specimen, scene.outputs
    gc = ob.crossing_gamma(net, u)
    gz = ob.zone_means(net, gc)
    g_ideal = gamma_a(specimen, info.u0 * 1e3) if info.u0 * 1e3 < specimen.locking_u0_mm else math.nan
    slip = ob.crossing_slip(net, u)
    row: dict[str, Any] = {"step": info.step, "u0_mm": round(info.u0 * 1e3, 9)}
    if o.reaction:
        assert info.residual is not None
        row["force_N"], row["force_y_N"] = model.reaction(info.residual)
        row["dforce_du0_N_per_mm"] = info.dforce_du0 * 1e-3
    if o.energy:
        parts = model.energy_parts(u)
        row["energy_J"] = info.energy
        row.update({f"energy_{k}_J": parts[k] for k in ENERGY_PARTS})
    row.update(
        {
            "newton_iterations": info.iterations,
            "step_wall_s": round(info.wall_s, 4),
            "max_slip_mm": float(slip.max(initial=0.0)) * 1e3,
            "gamma_centre_deg": math.degrees(ob.centre_mean(net, gc)),
            "gamma_A_deg": np.degrees(gz["A"]),
            "gamma_B_deg": np.degrees(gz["B"]),
            "gamma_C_deg": np.degrees(gz["C"]),
            "gamma_A_ideal_deg": np.degrees(g_ideal),
            "gamma_B_ideal_deg": np.degrees(g_ideal) / 2,
            "lambda_min": info.lambda_min,
            "snap": int(info.snap),
            "released_J": info.released,
        }
    )
    return row


def run_discrete(scene: Scene, out: str | Path, progress: bool = True, measured: Any = None) -> dict[str, Any]:
    """Run the discrete BET model of ``scene`` and write its run folder.

    Parameters
    ----------
    scene : Scene
        The scene (``scene.discrete``, ``scene.specimen``, ``scene.loading``, ``scene.solver``,
        ``scene.outputs``).
    out : str or Path
        Run folder (created).
    progress : bool
        Show a tqdm bar over the clamp displacement.
    measured : ngbet.figures.data.Measured, optional
        A measured curve drawn on the force and normalised-shear-force figures.

    Returns
    -------
    dict
        The summary (also in ``out/summary.json``).

    Raises
    ------
    ngbet.errors.ConvergenceError
        when a step cannot be completed; the converged steps and ``summary.json`` (``"status":
        "failed"``) are on disk by then.
    """
    out = Path(out)
    with RunWriter(out, scene, getattr(measured, "path", None)) as writer:
        t0 = time.perf_counter()
        net = network_from_scene(scene)
        model = NetworkModel.from_scene(scene, net)
        t_build = time.perf_counter() - t0
        log.info("discrete network: %s", net.counts())
        ctl = step_control(scene)
        rec = _Recorder(scene, model, writer, out, tuple(s * 1e-3 for s in scene.loading.stops_mm))
        info: dict[str, Any] = {
            "model": "discrete",
            "network": net.counts(),
            "dofs": model.n_dofs,
            "free_dofs": int((~model.fixed).sum()),
            "t_build_s": t_build,
            "threads": scene.solver.threads,
        }
        failure = None
        res = PathResult(0.0)  # its path_info: the solver's statistics as of the last step
        # closed on the way out: the solver's hold on the BLAS threads ends with the path
        with (
            progress_bar(progress, ctl.path.target * 1e3, "discrete BET") as bar,
            contextlib.closing(load_steps(model, ctl, res)) as steps,
        ):
            try:
                for step in steps:
                    assert step.state is not None
                    rec.on_step(step, step.state)
                    if bar is not None:
                        bar(step.u0)
                stats = res.path_info
            except KeyboardInterrupt as exc:  # Ctrl-C / SIGTERM while writing a step: the statistics so far
                if not hasattr(exc, "path_info"):
                    exc.path_info = dict(res.path_info)  # type: ignore[attr-defined]
                raise
            except ConvergenceError as exc:
                failure = exc
                stats = {
                    **exc.path_info,
                    "last_converged_u0_mm": exc.last_converged_mm,
                    "attempted_u0_mm": exc.attempts[-1].u0_to * 1e3 if exc.attempts else math.nan,
                    "residual_history": exc.attempts[-1].history if exc.attempts else [],
                }
        rec.final_snapshot()
        info.update(_run_info(stats, writer.rows))
        info["t_solve_s"] = time.perf_counter() - t0 - t_build
        summary = writer.summary(info, "ok" if failure is None else "failed", None if failure is None else str(failure))
        if scene.outputs.plot and writer.rows:
            writer.plot(functools.partial(start_plot, service=plot_service(), measured=measured))()
        if failure is not None:
            raise failure
        return summary


def _run_info(stats: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The summary's solver statistics and totals over the written rows."""
    info = dict(stats)
    # the solver's loads are in m; the summary's, like every other load ngbet reports, in mm
    info["snap_events"] = [
        {
            (f"{k}_mm" if k in ("u0", "u0_before") else k): (v * 1e3 if k in ("u0", "u0_before") else v)
            for k, v in e.items()
        }
        for e in stats.get("snap_events", [])
    ]
    info["snap_event_count"] = len(stats.get("snap_events", []))
    info["newton_iterations_total"] = int(sum(r["newton_iterations"] for r in rows))
    info["max_slip_mm"] = max((r["max_slip_mm"] for r in rows), default=0.0)
    return info


class _Recorder:
    """Writes each converged step (row, profile) and the states at the stops and at the end."""

    def __init__(
        self, scene: Scene, model: NetworkModel, writer: RunWriter, out: Path, stops: tuple[float, ...]
    ) -> None:
        self.scene, self.model, self.writer, self.out, self.stops = scene, model, writer, out, stops
        self.last_u: np.ndarray = np.zeros(model.n_dofs)
        self.last_u0 = 0.0
        sp = scene.specimen
        self.bet = BetColumns(sp.length_mm, sp.width_mm, sp.yarn_angle_deg)

    def on_step(self, info: StepRecord, u: np.ndarray) -> None:
        """One converged step: its row, its profile, its state at a stop."""
        o, net = self.scene.outputs, self.model.net
        row = step_row(self.model, info, u, self.scene)
        row.update(self.bet.row(row["u0_mm"], row.get("force_N")))
        profile = None
        if o.profile:
            X, uy = ob.midline_profile(net, u, o.profile_points)
            profile = list(zip((X * 1e3).tolist(), (uy * 1e3).tolist(), strict=True))
        self.writer.add_step(row, profile=profile)
        self.last_u, self.last_u0 = u, info.u0
        if any(abs(info.u0 - s) < 1e-12 for s in self.stops):
            self.snapshot(u, info.u0)
        log.debug("step %d u0 = %.4g mm, %d iterations", info.step, info.u0 * 1e3, info.iterations)

    def snapshot(self, u: np.ndarray, u0: float) -> None:
        """The state (``state_XXmm.npz``); its picture is drawn from the file with the run's figures."""
        tag = f"{u0 * 1e3:g}mm"  # 37mm, 0.5mm
        self.writer.write(f"state_{tag}.npz", lambda tmp: ob.save_state(tmp, self.model.net, u, u0))

    def final_snapshot(self) -> None:
        """The last converged state (if any step converged): its file, as at a stop."""
        if self.last_u0 > 0:
            self.snapshot(self.last_u, self.last_u0)
