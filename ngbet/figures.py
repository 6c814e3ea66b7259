"""Every figure of a run: one style, object-oriented matplotlib (``Figure``, ``Axes``; no pyplot state).

A run folder's figures are drawn from its files alone (results.csv, profile.csv, scene.toml and
the map data), so that they can be redrawn without solving:

- ``force.png``/``.pdf``: clamp force against clamp displacement, the computed rows as points
  joined by straight lines, estimated discretization errors as error bars, snap-throughs (rows
  with ``snap`` = 1) as dashed vertical jumps; the double force in a second panel (continuum);
- ``shear_force.png``/``.pdf``: (a) the normalised shear force F_sh against the kinematic shear
  angle γ of the ideal test; (b) the shear angles against the clamp displacement: γ (Eq. 13),
  γ/2, the simulated centre and zone means;
- ``profile.png``/``.pdf``: the S-profile, mid-axis vertical displacement at the stations (the
  load stops and the last load), the other rows in grey;
- ``shear_map.png``/``.pdf``: the shear angle on the deformed specimen at the stations, one
  colour scale for all panels.

Every figure carries a caption line naming the specimen (W × H mm, yarn angle) and the material.
A measured curve (:func:`read_measured`) is drawn on the force and F_sh figures.

matplotlib is imported inside the drawing functions only: importing this module costs nothing,
so that the run can write its map data through it (:func:`save_map`).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

log = logging.getLogger(__name__)

PNG_DPI = 130
#: resolution of the rasterized parts of a PDF (the map's colour field; lines and text stay vector)
PDF_RASTER_DPI = 200
#: zlib level of the PNG files: 1 writes them 3-4 times faster than the default 6, 20 % larger
PNG_COMPRESSION = 1

#: one style for every figure
STYLE: Any = {  # matplotlib's rcParams (typed as its literal keys)
    "font.size": 9, "axes.titlesize": 9, "axes.labelsize": 9, "legend.fontsize": 8, "xtick.labelsize": 8,
    "ytick.labelsize": 8, "axes.grid": True, "grid.alpha": 0.3, "lines.linewidth": 1.4, "lines.markersize": 4,
    "legend.frameon": True, "legend.framealpha": 0.9, "figure.dpi": 100,
}

#: one angle convention in every figure of both models: the shear angle γ, the change of the
#: angle between the yarns (0 at rest; 90° − γ between the yarns of a ±45° fabric)
SHEAR_LABEL = "shear angle γ [°] (0 at rest)"
U0_LABEL = "clamp displacement u₀ [mm]"

#: F_sh is drawn up to this kinematic shear angle [deg]: towards yarn locking (90°) Eq. 18 divides
#: by cos γ → 0 and its values say more about the equation than about the fabric
FSH_GAMMA_MAX_DEG = 70.0

#: figure files of a run (each as .png and .pdf)
RUN_FIGURES = ("force", "shear_force", "profile", "shear_map")

Extra = Iterable[tuple[str, Sequence[float], Sequence[float]]]

NO_MATPLOTLIB = "no figures: matplotlib is not installed (pip install matplotlib)"


# ------------------------------------------------------------------------------------------------
# data of a run folder
# ------------------------------------------------------------------------------------------------
def map_file_name(u0_mm: float) -> str:
    """The continuum's map data at a station: ``map_37mm.npz``."""
    return f"map_{u0_mm:g}mm.npz"


def save_map(path: Path, samples: dict[str, np.ndarray], u0_mm: float) -> None:
    """Write the map data of one station (:func:`ngbet.continuum.observables.map_samples`) [mm, deg]."""
    data: dict[str, Any] = {"u0_mm": np.float64(u0_mm), **samples}
    np.savez_compressed(path, **data)


@dataclass
class MapData:
    """A triangulated shear-angle field on the deformed specimen at one clamp displacement [mm, deg]."""

    u0_mm: float
    x_mm: np.ndarray  #: deformed positions
    y_mm: np.ndarray
    triangles: np.ndarray
    gamma_deg: np.ndarray
    what: str = "continuum"


def load_maps(run_dir: Path) -> list[MapData]:
    """The run's maps at its stations, by increasing u0: the continuum's map_*.npz or the network's state_*.npz.

    The network's map triangulates its crossings (Delaunay on the reference positions, drawn at the
    deformed ones), coloured by the shear angle at each crossing.
    """
    import matplotlib.tri as mtri

    maps = []
    for f in run_dir.glob("map_*mm.npz"):
        with np.load(f) as z:
            maps.append(MapData(float(z["u0_mm"]), z["X_mm"] + z["ux_mm"], z["Y_mm"] + z["uy_mm"],
                                z["triangles"], z["gamma_deg"]))
    for f in run_dir.glob("state_*mm.npz"):
        with np.load(f) as z:
            nodes = z["crossing_nodes"][:, 0]
            X, u = z["X_mm"][nodes], z["u_mm"][nodes]
            tri = mtri.Triangulation(X[:, 0], X[:, 1])
            # the crossings lie on a lattice: its Delaunay triangles are half cells (longest edge √2
            # times the shortest); longer ones span the gaps along the edges and are left out
            t = tri.triangles
            edges = np.stack([np.hypot(*(X[t[:, i]] - X[t[:, (i + 1) % 3]]).T) for i in range(3)], axis=1)
            keep = edges.max(axis=1) <= 1.5 * edges.min()
            maps.append(MapData(float(f.stem[len("state_"):-2]), X[:, 0] + u[:, 0], X[:, 1] + u[:, 1],
                                t[keep], z["crossing_gamma_deg"], "crossings"))
    return sorted(maps, key=lambda m: m.u0_mm)


@dataclass
class Measured:
    """A measured force–displacement curve (``displacement_mm,force_N``) and the specimen its header names."""

    path: Path
    displacement_mm: np.ndarray
    force_N: np.ndarray
    width_mm: float | None = None
    length_mm: float | None = None
    label: str = field(default="")

    def specimen(self, width_mm: float, length_mm: float) -> tuple[float, float]:
        """(W, H) of the measured specimen: its header's, else the run's."""
        return (self.width_mm or width_mm, self.length_mm or length_mm)


def read_measured(path: str | Path) -> Measured:
    """Read a measured curve: CSV with the header ``displacement_mm,force_N``; ``#`` lines are comments.

    Comment lines ``# specimen.width_mm = 150`` and ``# specimen.length_mm = 300`` name the
    measured specimen (its F_sh is computed with them).

    Raises
    ------
    ValueError
        naming the file and what is wrong with it.
    """
    import csv

    p = Path(path)
    try:
        lines = p.read_text().splitlines()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the measured curve ({exc.strerror or exc})") from exc
    header: dict[str, float] = {}
    for line in lines:
        if line.lstrip().startswith("#") and "=" in line:
            key, _, value = line.lstrip("# ").partition("=")
            try:
                header[key.strip()] = float(value.strip())
            except ValueError:
                pass
    data = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(data))
    if not rows or [c.strip() for c in rows[0][:2]] != ["displacement_mm", "force_N"]:
        raise ValueError(f"{p}: the first line that is not a comment must be the header 'displacement_mm,force_N'")
    try:
        values = np.array([[float(r[0]), float(r[1])] for r in rows[1:]], dtype=float)
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{p}: every data line must hold two numbers, displacement_mm,force_N ({exc})") from exc
    if len(values) < 2 or not np.all(np.isfinite(values)):
        raise ValueError(f"{p}: needs at least two finite points (displacement_mm,force_N)")
    return Measured(p, values[:, 0], values[:, 1], header.get("specimen.width_mm"), header.get("specimen.length_mm"),
                    f"measured ({p.name})")


def increasing_curve(d: ArrayLike, F: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """A curve with strictly increasing displacement: points at the same displacement are averaged."""
    d, F = np.asarray(d, dtype=float), np.asarray(F, dtype=float)
    u, inv = np.unique(d, return_inverse=True)
    return u, np.bincount(inv, weights=F) / np.bincount(inv)


def measured_fsh(m: Measured, width_mm: float, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(γ [deg], F_sh [N/mm]) of a measured curve by Eq. 18, below yarn locking of its specimen."""
    from .kinematics import normalised_shear_force

    W, H = m.specimen(width_mm, length_mm)
    d, F = increasing_curve(m.displacement_mm, m.force_N)
    keep = (d > 0) & (d < (math.sqrt(2.0) - 1.0) * (H - W) * (1 - 1e-9))
    if keep.sum() < 1:
        return np.array([]), np.array([])
    g, f = normalised_shear_force(d[keep], F[keep], H, W)
    return np.degrees(g), f


# ------------------------------------------------------------------------------------------------
# captions
# ------------------------------------------------------------------------------------------------
def _q(name: str, value: float, unit: str = "") -> str:
    """``name = value unit`` held together (no-break spaces) when the caption is broken into lines."""
    nb = "\u00a0"
    return f"{name}{nb}={nb}{value:g}" + (f"{nb}{unit}" if unit else "")


def caption(scene: Any) -> str:
    """One line naming the specimen (W × H mm, yarn angle) and the material of a scene."""
    if scene is None:
        return ""
    sp = scene.specimen
    nb = "\u00a0"
    spec = (f"specimen {sp.width_mm:g}{nb}×{nb}{sp.length_mm:g}{nb}mm (W{nb}×{nb}H), yarns{nb}±{sp.yarn_angle_deg:g}°, "
            f"{_q('t', sp.thickness_mm, 'mm')}")
    if scene.model == "discrete":
        d = scene.discrete
        return (f"{spec}; yarn network: {_q('EI1', d.EI1, f'N{nb}m²')}, {_q('EI2', d.EI2, f'N{nb}m²')}, "
                f"{_q('EA', d.EA1, 'N')}, {_q('K_φ', d.K_phi, f'N{nb}m')}, {_q('K_slip', d.K_slip, 'N/m')}, "
                f"spacing{nb}{d.spacing_mm:g}{nb}mm")
    m = scene.material
    return (f"{spec}; material: {_q('K_sh', m.K_sh / 1e3, 'kPa')}, {_q('α1', m.alpha1 / 1e3, f'kPa{nb}m²')}, "
            f"{_q('α2', m.alpha2 / 1e3, f'kPa{nb}m²')}, {_q('K_el', m.K_el / 1e6, 'MPa')}")


def _read_scene(run_dir: Path) -> Any:
    from .scene import Scene, SceneError

    try:
        return Scene.from_toml(run_dir / "scene.toml")
    except (OSError, SceneError) as exc:
        log.info("%s: no caption (%s)", run_dir, exc)
        return None


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _caption(fig: Figure, text: str) -> None:
    """The caption line(s) above the panels, broken at the figure's width (8 pt: about 17 characters an inch)."""
    import textwrap

    if text:
        fig.suptitle(textwrap.fill(text, width=int(fig.get_figwidth() * 17)), fontsize=8)


class FigureWriter:
    """Writes each figure as PNG and PDF.

    With ``fork_pdf`` a forked child writes each PDF while this process goes on with the next
    figure (for a process without threads, such as the plot process; a PDF whose child failed is
    written here at :meth:`finish`).

    The constrained layout is solved once, for the PNG, then frozen: the PDF gets the same layout,
    whichever process writes it (solving it again would cost as much as drawing).
    """

    def __init__(self, fork_pdf: bool = False) -> None:
        self.fork_pdf = fork_pdf and hasattr(os, "fork")
        self.pending: list[tuple[int, Figure, Path]] = []

    def save(self, fig: Figure, stem: Path) -> Path:
        """Write ``stem``.png now and ``stem``.pdf now or in a child; returns the PNG."""
        png, pdf = stem.with_suffix(".png"), stem.with_suffix(".pdf")
        fig.savefig(png, dpi=PNG_DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
        fig.set_layout_engine("none")
        child = os.fork() if self.fork_pdf else -1
        if child == 0:  # the child: the PDF, and out without running anything of the parent's
            code = 1
            try:
                fig.savefig(pdf, dpi=PDF_RASTER_DPI)
                code = 0
            finally:
                os._exit(code)
        if child < 0:
            fig.savefig(pdf, dpi=PDF_RASTER_DPI)
        else:
            self.pending.append((child, fig, pdf))
        return png

    def finish(self) -> None:
        """Wait for the children; write here any PDF a child did not."""
        for child, fig, pdf in self.pending:
            if os.waitstatus_to_exitcode(os.waitpid(child, 0)[1]) != 0:
                fig.savefig(pdf, dpi=PDF_RASTER_DPI)
        self.pending = []


def nice_ceil(x: float) -> float:
    """The smallest of 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10^k not below x (x > 0): a round scale end."""
    if not x > 0:
        return 1.0
    k = math.floor(math.log10(x))
    for m in (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10**k >= x * (1 - 1e-12):
            return m * 10**k
    return 10.0 ** (k + 1)  # pragma: no cover


# ------------------------------------------------------------------------------------------------
# the force figure
# ------------------------------------------------------------------------------------------------
def _column(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    """A column as floats (empty cells and missing keys as nan)."""
    return np.array([r[key] if isinstance(r.get(key), float) else math.nan for r in rows], dtype=float)


def curve_with_jumps(ax: Axes, u0: ArrayLike, y: ArrayLike, snap: ArrayLike | None = None, *,
                     label: str | None = None, color: str | None = None, marker: str = "o",
                     jump_label: str | None = "snap-through (jump)") -> Any:
    """The computed points joined by straight lines from (0, 0), with snap-throughs drawn as jumps.

    At rows marked as a snap (``snap`` = 1) the line breaks and a dashed vertical segment at the
    snap row's u0 joins the value before and after the jump (the solver brackets a snap to ≤ 1 mm,
    so the jump lies between the two rows).
    """
    u = np.r_[0.0, np.asarray(u0, dtype=float)]
    v = np.r_[0.0, np.asarray(y, dtype=float)]
    s = np.r_[0, np.asarray(snap, dtype=float)] if snap is not None else np.zeros(len(u))
    s = np.nan_to_num(s) > 0
    starts = [0, *np.flatnonzero(s)]
    ends = [*np.flatnonzero(s), len(u)]
    line = None
    for a, b in zip(starts, ends, strict=True):
        (seg,) = ax.plot(u[a:b], v[a:b], "-", marker=marker, color=color if line is None else line.get_color(),
                         label=label if line is None else None, ms=3.5)
        line = line or seg
    assert line is not None
    for k, i in enumerate(np.flatnonzero(s)):
        ax.plot([u[i], u[i]], [v[i - 1], v[i]], "--", color=line.get_color(), lw=1.2,
                label=jump_label if k == 0 else None)
    return line


def _error_bars(ax: Axes, u0: np.ndarray, F: np.ndarray, err: np.ndarray, span: float) -> None:
    """The estimated discretization error of the force as error bars.

    Each bar's size is written beside it when the bar is too short to see (below 2 % of the axis).
    """
    ok = np.isfinite(err)
    if not ok.any():
        return
    ax.errorbar(u0[ok], F[ok], yerr=err[ok], fmt="none", ecolor="C3", elinewidth=1.6, capsize=5, capthick=1.6,
                zorder=5, label="± estimated discretization error")
    small = [(u, f, e) for u, f, e in zip(u0[ok], F[ok], err[ok], strict=True) if 2 * e < 0.02 * span]
    for k, (u, f, e) in enumerate(small):  # below right and above left in turn: neighbours do not overlap
        ax.annotate(f"±{e:.2g} N", (u, f), xytext=(6, -11) if k % 2 == 0 else (-6, 7), textcoords="offset points",
                    fontsize=7, color="C3", ha="left" if k % 2 == 0 else "right")


def force_figure(rows: list[dict[str, Any]], scene: Any = None, extra: Extra = (),
                 measured: Measured | None = None) -> Figure:
    """The force figure of the rows of a results.csv (see the module docstring)."""
    has_T = "double_force_Nm" in rows[0]
    fig = _figure(10 if has_T else 5.8, 4.2)
    axes = fig.subplots(1, 2 if has_T else 1, squeeze=False)[0]
    ax = axes[0]
    u0, F = _column(rows, "u0_mm"), _column(rows, "force_N")
    snap = _column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, u0, F, snap, label="computed (rows of results.csv), joined by straight lines")
    if measured is not None:
        ax.plot(measured.displacement_mm, measured.force_N, "-", color="0.35", lw=1.2,
                label=_measured_label(measured, scene))
    for label, x, y in extra:
        ax.plot(x, y, "--", label=label)
    span = float(np.nanmax(np.abs(np.r_[F, 0.0]))) or 1.0
    _error_bars(ax, u0, F, _column(rows, "force_error_N"), span)
    ax.set_xlabel(U0_LABEL)
    ax.set_ylabel("force on the moving clamp [N]")
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(a) force" if has_T else "")
    if has_T:
        ax2 = axes[1]
        curve_with_jumps(ax2, u0, _column(rows, "double_force_Nm"), snap, color="C2", marker="s",
                         label="computed, joined by straight lines")
        ax2.set_xlabel(U0_LABEL)
        ax2.set_ylabel("double force on the moving clamp [N m]")
        ax2.set_xlim(left=0)
        ax2.legend(loc="upper left")
        ax2.set_title("(b) double force")
    _caption(fig, caption(scene))
    return fig


def _measured_label(m: Measured, scene: Any) -> str:
    if scene is None or m.width_mm is None or m.length_mm is None:
        return m.label
    sp = scene.specimen
    if (m.width_mm, m.length_mm) == (sp.width_mm, sp.length_mm):
        return m.label
    return f"{m.label}, specimen {m.width_mm:g} × {m.length_mm:g} mm"


# ------------------------------------------------------------------------------------------------
# F_sh and the shear angles
# ------------------------------------------------------------------------------------------------
def shear_force_figure(rows: list[dict[str, Any]], scene: Any = None,
                       measured: Measured | None = None) -> Figure | None:
    """(a) F_sh against the kinematic γ, (b) shear angles against u0; None without the columns."""
    if "gamma_kinematic_deg" not in rows[0]:
        return None
    u0 = _column(rows, "u0_mm")
    g_kin, fsh = _column(rows, "gamma_kinematic_deg"), _column(rows, "fsh_N_per_mm")
    fig = _figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    ok = np.isfinite(g_kin) & np.isfinite(fsh)
    shown = ok & (g_kin <= FSH_GAMMA_MAX_DEG)
    left_out = bool(np.any(ok & ~shown))
    if shown.any():
        snap = _column(rows, "snap")[shown] if "snap" in rows[0] else None
        curve_with_jumps(ax, g_kin[shown], fsh[shown], snap, label="computed (Eq. 18 on the run's force)")
    if measured is not None and scene is not None:
        g_m, f_m = measured_fsh(measured, scene.specimen.width_mm, scene.specimen.length_mm)
        keep = g_m <= FSH_GAMMA_MAX_DEG
        left_out = left_out or bool(np.any(~keep))
        if keep.any():
            ax.plot(np.r_[0.0, g_m[keep]], np.r_[0.0, f_m[keep]], "-", color="0.35", lw=1.2,
                    label=_measured_label(measured, scene))
    ax.set_xlabel("kinematic shear angle γ of the ideal test [°] (Eq. 13)")
    ax.set_ylabel("normalised shear force F_sh [N/mm]")
    ax.set_xlim(0, FSH_GAMMA_MAX_DEG if left_out else None)
    ax.set_title("(a) normalised shear force")
    if not ok.any():
        ax.text(0.5, 0.5, "F_sh: 45° yarns only (Eq. 18)", transform=ax.transAxes, ha="center")
    else:
        ax.legend(loc="upper left")
    if left_out:
        ax.text(0.98, 0.03, f"beyond γ = {FSH_GAMMA_MAX_DEG:g}° (near yarn locking, where Eq. 18\n"
                "divides by cos γ → 0): not drawn", transform=ax.transAxes, ha="right", va="bottom", fontsize=7)
    ax2.plot(np.r_[0.0, u0], np.r_[0.0, g_kin], "-", color="k", label="ideal test, zone A: γ (Eq. 13)")
    ax2.plot(np.r_[0.0, u0], np.r_[0.0, g_kin / 2], ":", color="k", label="ideal test, zones B: γ/2")
    for key, style, label in (("gamma_centre_deg", "o", "computed, centre"),
                              ("gamma_A_deg", "s", "computed, mean over zone A"),
                              ("gamma_B_deg", "^", "computed, mean over zones B")):
        if key in rows[0]:
            ax2.plot(np.r_[0.0, u0], np.r_[0.0, _column(rows, key)], style, ms=3.5, mfc="none", label=label)
    ax2.set_xlabel(U0_LABEL)
    ax2.set_ylabel(SHEAR_LABEL)
    ax2.set_xlim(left=0)
    ax2.legend(loc="upper left")
    ax2.set_title("(b) shear angles")
    _caption(fig, caption(scene))
    return fig


# ------------------------------------------------------------------------------------------------
# the S-profile
# ------------------------------------------------------------------------------------------------
def stations_of(rows: list[dict[str, Any]], scene: Any) -> list[float]:
    """The loads [mm] shown as stations: the load stops reached and the last row."""
    u0 = [float(r["u0_mm"]) for r in rows]
    stops = list(scene.loading.stops_mm) if scene is not None else []
    st = [u for u in u0 if any(abs(u - s) < 1e-6 for s in stops)]
    return sorted(set(st + u0[-1:]))


def profile_figure(profiles: dict[float, tuple[list[float], list[float]]], stations: Sequence[float],
                   scene: Any = None) -> Figure | None:
    """Mid-axis vertical displacement: the stations in colour, the other rows in light grey."""
    if not profiles:
        return None
    fig = _figure(6.4, 3.8)
    ax = fig.subplots()
    grey = True
    for u0, (X, uy) in sorted(profiles.items()):
        if not any(abs(u0 - s) < 1e-6 for s in stations):
            ax.plot(X, uy, "-", color="0.8", lw=0.8, label="other rows" if grey else None)
            grey = False
    for k, s in enumerate(stations):
        hit = [u for u in profiles if abs(u - s) < 1e-6]
        if hit:
            X, uy = profiles[hit[0]]
            ax.plot(X, uy, "-", color=f"C{k}", lw=1.8, label=f"u₀ = {s:g} mm")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("reference position X on the mid-axis Y = W/2 [mm]")
    ax.set_ylabel("vertical displacement u_y [mm]")
    ax.legend(loc="best")
    _caption(fig, caption(scene))
    return fig


# ------------------------------------------------------------------------------------------------
# the shear-angle map
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ColourScale:
    """One colour scale for all panels of a map: its norm's ends, colour map, and what lies beyond."""

    vmin: float
    vmax: float
    cmap: str
    extend: str  #: "neither", "min", "max", "both": values beyond the ends (drawn in the end colours)
    data_min: float
    data_max: float


def colour_scale(values: Sequence[np.ndarray], quantile: float = 0.995) -> ColourScale:
    """A shared, round colour scale for maps of the shear angle.

    The ends are round numbers (:func:`nice_ceil`) above the ``quantile`` of |γ| over all panels,
    so that the singular clamp corners do not set the scale; what lies beyond is drawn in the end
    colours and marked by the colour bar's arrows. Where negative angles matter (below −2 % of the
    scale) the scale is diverging and symmetric about 0, else sequential from 0.
    """
    v = np.concatenate([np.asarray(a, dtype=float).ravel() for a in values])
    v = v[np.isfinite(v)]
    lo, hi = float(np.quantile(v, 1 - quantile)), float(np.quantile(v, quantile))
    dmin, dmax = float(v.min()), float(v.max())
    if lo < -0.02 * max(abs(hi), 1e-12):
        top = nice_ceil(max(abs(lo), abs(hi)))
        vmin, vmax, cmap = -top, top, "RdBu_r"
    else:
        vmin, vmax, cmap = 0.0, nice_ceil(hi), "viridis"
    below, above = dmin < vmin - 1e-9 * vmax, dmax > vmax * (1 + 1e-9)
    extend = "both" if below and above else "min" if below else "max" if above else "neither"
    return ColourScale(vmin, vmax, cmap, extend, dmin, dmax)


def _deg(v: float) -> str:
    """An angle for a label, with a true minus sign."""
    return f"{v:.1f}°".replace("-", "\u2212")


def shear_map_figure(maps: Sequence[MapData], scene: Any = None,
                     yarns: dict[float, dict[int, list[np.ndarray]]] | None = None) -> Figure | None:
    """The shear angle on the deformed specimen, one panel per station, one colour scale (see :func:`colour_scale`).

    ``yarns``: deformed yarn polylines [mm] per station and family (1 thick, drawn black; 2 thin, grey).
    """
    if not maps:
        return None
    import matplotlib.tri as mtri
    from matplotlib.colors import Normalize
    from matplotlib.ticker import MaxNLocator

    cs = colour_scale([m.gamma_deg for m in maps])
    norm = Normalize(cs.vmin, cs.vmax, clip=False)
    xs = np.concatenate([m.x_mm for m in maps])
    ys = np.concatenate([m.y_mm for m in maps])
    width = float(xs.max() - xs.min())
    height = float(ys.max() - ys.min())
    panel_h = max(1.2, 6.2 * height / max(width, 1e-9))
    fig = _figure(7.4, 0.9 + len(maps) * (panel_h + 0.45))
    axes = fig.subplots(len(maps), 1, squeeze=False)[:, 0]
    art = None
    for ax, m in zip(axes, maps, strict=True):
        tri = mtri.Triangulation(m.x_mm, m.y_mm, m.triangles)
        art = ax.tripcolor(tri, m.gamma_deg, shading="gouraud", cmap=cs.cmap, norm=norm, rasterized=True)
        for fam, (colour, lw) in ((1, ("k", 1.4)), (2, ("0.4", 0.7))):
            for pl in (yarns or {}).get(m.u0_mm, {}).get(fam, []):
                ax.plot(pl[:, 0], pl[:, 1], "-", color=colour, lw=lw)
        ax.set_aspect("equal")
        ax.set_xlim(xs.min() - 2, xs.max() + 2)
        ax.set_ylim(ys.min() - 2, ys.max() + 2)
        ax.grid(False)
        ax.xaxis.set_major_locator(MaxNLocator(steps=[1, 2, 5, 10], integer=True))
        ax.yaxis.set_major_locator(MaxNLocator(nbins=4, steps=[1, 2, 5, 10], integer=True))
        ax.set_ylabel("y [mm]")
        ax.set_title(f"u₀ = {m.u0_mm:g} mm: shear angle from {_deg(m.gamma_deg.min())} to {_deg(m.gamma_deg.max())}"
                     + (" (at the crossings)" if m.what == "crossings" else ""))
    axes[-1].set_xlabel("x (deformed) [mm]")
    assert art is not None
    cb = fig.colorbar(art, ax=list(axes), extend=cs.extend, shrink=0.9, aspect=25)
    cb.set_label(SHEAR_LABEL)
    cb.locator = MaxNLocator(nbins=6, steps=[1, 2, 2.5, 5, 10])
    cb.update_ticks()
    note = ""
    if cs.extend != "neither":
        note = (f"; colour scale {cs.vmin:g}° to {cs.vmax:g}°: values beyond it (data {_deg(cs.data_min)} "
                f"to {_deg(cs.data_max)}) in the end colours (arrows)")
    if yarns:
        note += "; thick yarns black, thin yarns grey"
    _caption(fig, caption(scene) + note)
    return fig


# ------------------------------------------------------------------------------------------------
# a run folder's figures
# ------------------------------------------------------------------------------------------------
def draw_run(run_dir: str | Path, extra: Extra = (), fork_pdf: bool = False,
             measured: Measured | None = None, only: Sequence[str] = RUN_FIGURES) -> Path | None:
    """Draw the figures of ``run_dir`` (:data:`RUN_FIGURES`, or those in ``only``) in this process.

    Returns force.png, or None when there was nothing to draw (no force in results.csv) or
    matplotlib is missing (logged). ``extra``: more curves (label, u0 [mm], force [N]) on the
    force figure. ``fork_pdf``: each PDF is written by a forked child while the PNG is written
    here (for a process without threads, such as the plot process).

    Raises
    ------
    OSError
        when results.csv cannot be read.
    """
    import matplotlib as mpl

    from .output import read_profiles, read_rows

    run_dir = Path(run_dir)
    rows = read_rows(run_dir / "results.csv")
    if not rows or "force_N" not in rows[0]:
        return None
    scene = _read_scene(run_dir)
    png = None
    out = FigureWriter(fork_pdf)
    try:
        with mpl.rc_context(STYLE):
            if "force" in only:
                png = out.save(force_figure(rows, scene, extra, measured), run_dir / "force")
            figs = {"shear_force": lambda: shear_force_figure(rows, scene, measured),
                    "profile": lambda: (profile_figure(read_profiles(run_dir / "profile.csv"), stations_of(rows, scene),
                                                       scene) if (run_dir / "profile.csv").exists() else None),
                    "shear_map": lambda: shear_map_figure(load_maps(run_dir), scene)}
            for name, make in figs.items():
                fig = make() if name in only else None
                if fig is not None:
                    out.save(fig, run_dir / name)
    finally:
        out.finish()
    return png


def draw_force(run_dir: Path, extra: Extra = (), fork_pdf: bool = False) -> Path | None:
    """Draw the run's figures in this process (:func:`draw_run`); None without matplotlib (logged)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        log.warning(NO_MATPLOTLIB)
        return None
    return draw_run(run_dir, extra, fork_pdf)


def start_plot(run_dir: str | Path, extra: Extra = (), service: Any = None,
               measured: Measured | None = None) -> Callable[[], Path | None]:
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
                return proc.answer()
            except RuntimeError as exc:
                log.info("the plot process did not draw %s (%s): drawing it here", run_dir, exc)
        if measured is not None:
            try:
                import matplotlib  # noqa: F401
            except ImportError:
                log.warning(NO_MATPLOTLIB)
                return None
            return draw_run(Path(run_dir), extra, measured=measured)
        return draw_force(Path(run_dir), extra)

    return finish


def warm_up() -> None:
    """Draw throw-away figures into memory: loads matplotlib's fonts, mathtext, tri and PDF backend."""
    import io

    import matplotlib as mpl

    rows = [{"u0_mm": u, "force_N": u * u, "force_error_N": 0.1, "double_force_Nm": 0.1 * u, "snap": 0.0,
             "gamma_kinematic_deg": u, "fsh_N_per_mm": 0.1 * u, "gamma_centre_deg": u} for u in (1.0, 2.0)]
    tri = MapData(1.0, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([[0, 1, 2]]),
                  np.array([0.0, 1.0, 2.0]))
    with mpl.rc_context(STYLE):
        for fig in (force_figure(rows, None, [("extra", [0.0, 2.0], [0.0, 4.0])]), shear_force_figure(rows),
                    shear_map_figure([tri])):
            assert fig is not None
            fig.savefig(io.BytesIO(), format="png", dpi=PNG_DPI)
            fig.savefig(io.BytesIO(), format="pdf")


# ------------------------------------------------------------------------------------------------
# shared drawing helpers (the API's and the studies' figures)
# ------------------------------------------------------------------------------------------------
def force_curve(ax: Axes, u0: ArrayLike, force: ArrayLike, dforce: ArrayLike | None = None,
                label: str | None = None, color: str | None = None, **kwargs: Any) -> Any:
    """Draw a force–displacement curve on ``ax``: the converged steps (markers) joined by straight lines from (0, 0).

    ``dforce`` is accepted and not drawn (the slopes are not data between the steps).
    """
    u = np.r_[0.0, np.asarray(u0, dtype=float)]
    F = np.r_[0.0, np.asarray(force, dtype=float)]
    (line,) = ax.plot(u, F, "-", color=color, label=f"{label + ': ' if label else ''}straight lines between steps",
                      **kwargs)
    ax.plot(u, F, "o", ms=3.5, color=line.get_color(), label="converged steps")
    ax.grid(alpha=0.3)
    return line
