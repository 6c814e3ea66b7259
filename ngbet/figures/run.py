"""A run folder's figures, drawn from its files alone (results.csv, profile.csv, scene.toml, map data).

- ``force``: clamp force against clamp displacement (and the double force, continuum);
- ``shear_force``: (a) F_sh against the kinematic shear angle γ; (b) the shear angles against u0;
- ``profile``: the S-profile at the stations, the other rows in grey;
- ``shear_map``: the shear angle on the deformed specimen at the stations, one colour scale;
- ``yarns_XXmm`` (the network's, :data:`YARNS`): the deformed yarns of each ``state_XXmm.npz``, one
  colour scale for all.

A picture-frame run draws its own ``force`` and ``shear_force`` (:mod:`ngbet.figures.frame`; a measured curve
is a :class:`~ngbet.figures.frame.FrameMeasured`) and no profile.

Each is written in the scene's ``outputs.figure_formats`` (default PNG only). In a process without
threads (the plot process) the figures may be shared among workers: this process and forked children,
one per spare core.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

from .curves import Extra, force_figure, profile_figure, shear_force_figure, stations_of
from .data import Measured, load_maps, read_scene
from .maps import shear_map_figure
from .style import PNG_DPI, FigureWriter, can_fork, figure, in_style, put_caption, write_png

__all__ = ["NO_MATPLOTLIB", "RUN_FIGURES", "YARNS", "draw_force", "draw_run", "formats_of", "start_plot", "warm_up"]

log = logging.getLogger(__name__)

#: figure files of a run
RUN_FIGURES = ("force", "shear_force", "profile", "shear_map")
#: in ``only`` of :func:`draw_run`: the network's yarn pictures, ``yarns_XXmm`` for each ``state_XXmm.npz``
YARNS = "yarns"
#: the figures drawn from the force (none where ``outputs.reaction = false`` left it out of results.csv)
FORCE_FIGURES = ("force", "shear_force")
#: the relative cost of drawing each figure (CPU time after the warm-up, default scene and 17k network),
#: by which :func:`draw_run` shares the figures among its workers; others (the yarn pictures) cost 1
FIGURE_COST = {"force": 1.0, "shear_force": 1.1, "profile": 0.6, "shear_map": 1.2}

NO_MATPLOTLIB = "no figures: matplotlib is not installed (pip install matplotlib)"


def _short_of_load(run_dir: Path, scene: Any) -> str:
    """What a figure of a run that failed or was interrupted says first; "" otherwise.

    A complete run's figures are drawn while its summary.json still says "running" (the plot is
    asked for as soon as results.csv is whole): that status is not a stop.
    """
    import json

    try:
        s = json.loads((run_dir / "summary.json").read_text())
        status, reached = s["status"], float(s["u0_reached_mm"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    if status not in ("failed", "interrupted") or scene is None:  # ("running": drawn as the summary is written)
        return ""
    load = "d" if getattr(scene, "test", "") == "picture_frame" else "u\N{SUBSCRIPT ZERO}"
    verb = {"failed": "stopped", "interrupted": "was interrupted"}.get(status, status)
    return f"The run {verb} at {load} = {reached:.4g} mm of {scene.loading.u0_mm:g} mm"


def formats_of(scene: Any) -> tuple[str, ...]:
    """The figure formats a run's scene asks for (``outputs.figure_formats``; PNG without a scene)."""
    return tuple(getattr(getattr(scene, "outputs", None), "figure_formats", ("png",)))


def draw_run(
    run_dir: str | Path,
    extra: Extra = (),
    workers: int = 1,
    measured: Measured | None = None,
    only: Sequence[str] = (*RUN_FIGURES, YARNS),
) -> Path | None:
    """Draw the figures of ``run_dir`` (:data:`RUN_FIGURES` and :data:`YARNS`, or those in ``only``).

    Returns the force figure's file, or None when there was none to draw (no rows, or no force in
    results.csv: then the figures of :data:`FORCE_FIGURES` are left out). ``extra``: more curves (label, u0 [mm],
    force [N]) on the force figure.
    ``workers``: the figures are shared among this process and ``workers`` − 1 forked children, the
    costliest first to the least loaded (:data:`FIGURE_COST`), where the process has no other thread;
    a figure whose child failed is drawn here. A fork costs CPU time (its copied pages): as many
    workers as idle cores, not one per figure.

    Raises
    ------
    OSError
        when results.csv cannot be read.
    """
    from ..tables import read_profiles, read_rows

    run_dir = Path(run_dir)
    rows = read_rows(run_dir / "results.csv")
    curves = bool(rows) and "force_N" in rows[0]  # the force and shear-force figures need the reaction
    if not rows and not (YARNS in only and any(run_dir.glob("state_*mm.npz"))):
        return None
    scene = read_scene(run_dir)
    out = FigureWriter(formats_of(scene))
    makers: dict[str, Callable[[], Any]] = {
        "force": lambda: force_figure(rows, scene, extra, measured),
        "shear_force": lambda: shear_force_figure(rows, scene, measured),
        "profile": lambda: (
            profile_figure(read_profiles(run_dir / "profile.csv"), stations_of(rows, scene), scene)
            if (run_dir / "profile.csv").exists()
            else None
        ),
        "shear_map": lambda: shear_map_figure(load_maps(run_dir), scene),
    }
    if getattr(scene, "test", "") == "picture_frame":  # the frame's own curves; its diagonal has no S-profile
        from .frame import FrameMeasured, frame_force_figure, frame_shear_figure

        frame_measured = measured if isinstance(measured, FrameMeasured) else None
        makers.update(
            force=lambda: frame_force_figure(rows, scene),
            shear_force=lambda: frame_shear_figure(rows, scene, frame_measured),
            profile=lambda: None,
        )
    names = [n for n in RUN_FIGURES if n in only and rows and (curves or n not in FORCE_FIGURES)]
    if YARNS in only:
        yarns = _yarn_makers(run_dir, scene)
        makers.update(yarns)
        names += list(yarns)

    short = _short_of_load(run_dir, scene)

    def draw(name: str) -> None:
        with in_style():
            fig = makers[name]()
            if fig is not None:
                if short:
                    sup = getattr(fig, "_suptitle", None)
                    put_caption(fig, f"{short}. {sup.get_text().replace(chr(10), ' ') if sup else ''}".strip())
                out.save(fig, run_dir / name)

    _draw_shared(_share(names, workers if can_fork() else 1), draw)
    first = run_dir / f"force.{out.formats[0]}"
    return first if "force" in names and first.exists() else None


def _draw_shared(groups: list[list[str]], draw: Callable[[str], None]) -> None:
    """Draw the first group here and each other one in a forked child; a failed child's group here."""
    children: dict[int, int] = {}
    for k, group in enumerate(groups[1:], start=1):
        child = os.fork()
        if child == 0:  # the child: its figures, and out without running anything of the parent's
            code = 1
            try:
                for name in group:
                    draw(name)
                code = 0
            finally:
                os._exit(code)
        children[k] = child
    try:
        for name in groups[0]:
            draw(name)
    finally:  # every child waited for, also when a figure here fails
        failed = [k for k, child in children.items() if os.waitstatus_to_exitcode(os.waitpid(child, 0)[1]) != 0]
    for k in failed:
        log.info("the child drawing %s failed: drawing them here", ", ".join(groups[k]))
        for name in groups[k]:
            draw(name)


def _share(names: Sequence[str], workers: int) -> list[list[str]]:
    """``names`` in at most ``workers`` groups of about equal cost (:data:`FIGURE_COST`), costliest first."""
    groups: list[list[str]] = [[] for _ in range(max(1, min(workers, len(names))))]
    load = [0.0] * len(groups)
    for name in sorted(names, key=lambda n: -FIGURE_COST.get(n, 1.0)):
        k = load.index(min(load))
        groups[k].append(name)
        load[k] += FIGURE_COST.get(name, 1.0)
    return groups


def _yarn_makers(run_dir: Path, scene: Any) -> dict[str, Callable[[], Any]]:
    """The network's yarn pictures, ``yarns_XXmm`` for each ``state_XXmm.npz``, on one colour scale."""
    from .data import load_yarn_states
    from .maps import yarn_state_figure

    states = load_yarn_states(run_dir)
    scale = [st.gamma_deg for st in states]
    return {f"yarns_{st.tag}": functools.partial(yarn_state_figure, st, scene, scale) for st in states}


def draw_force(run_dir: Path, extra: Extra = (), workers: int = 1) -> Path | None:
    """Draw the run's figures in this process (:func:`draw_run`); None without matplotlib (logged)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        _not_installed(exc)
        return None
    return draw_run(run_dir, extra, workers)


def _not_installed(exc: ImportError) -> None:
    """Log :data:`NO_MATPLOTLIB` for an import of matplotlib that failed because it is not installed.

    An installed matplotlib whose import failed (cut short by Ctrl-C or a signal, which leaves a
    partial module behind) is not called missing: the interrupt is raised again (the run records
    "interrupted"), any other failure as it is.
    """
    import importlib.util

    try:
        installed = importlib.util.find_spec("matplotlib") is not None
    except ValueError:  # a partial module without a spec: it was being imported
        installed = True
    if not installed:
        log.warning(NO_MATPLOTLIB)
        return
    from ..numerics.engine import STOP_REQUESTED

    if STOP_REQUESTED.is_set():
        raise KeyboardInterrupt("stop requested by a signal") from exc
    raise exc


def start_plot(
    run_dir: str | Path, extra: Extra = (), service: Any = None, measured: Measured | None = None
) -> Callable[[], Path | None]:
    """Start drawing the figures of the run files in ``run_dir``; the function returned finishes it.

    ``service``: the plot process the runner started (:func:`ngbet.plot_process.active`). The
    request goes out now and the process draws while the run writes its other files; the function
    returned waits for it, and draws here if the process failed (its errors are RuntimeErrors).
    Without one, or with a ``measured`` curve to overlay, the function returned draws here.
    """
    proc = service if measured is None else None
    if proc is not None:
        try:
            proc.request(run_dir, extra)
        except RuntimeError as exc:
            log.info("the plot process did not take %s (%s): drawing it here", run_dir, exc)
            proc = None

    def finish() -> Path | None:
        if proc is not None:
            try:
                return cast("Path | None", proc.answer())
            except RuntimeError as exc:
                log.info("the plot process did not draw %s (%s): drawing it here", run_dir, exc)
        if measured is not None:
            try:
                import matplotlib  # noqa: F401
            except ImportError as exc:
                _not_installed(exc)
                return None
            return draw_run(Path(run_dir), extra, measured=measured)
        return draw_force(Path(run_dir), extra)

    return finish


def warm_up() -> None:
    """Import matplotlib and draw one small figure into memory: its fonts, Agg and the PNG writer.

    What a run's first figure costs beyond its own drawing, paid ahead; drawing throw-away copies
    of the run's figures would cost as much CPU time as drawing them, for little less waiting after.
    """
    import io

    import matplotlib.tri  # noqa: F401  (the shear map's triangulation)

    with in_style():
        fig = figure(1.0, 1.0)
        ax = fig.add_subplot()
        ax.plot([0.0, 1.0], [0.0, 1.0])
        ax.set_xlabel("u0 [mm]")
        write_png(fig, io.BytesIO(), dpi=PNG_DPI / 4)
