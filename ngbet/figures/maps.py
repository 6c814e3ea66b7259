"""Maps: a field on the deformed specimen, triangulated, one colour scale for every panel of a figure.

The colour scale (:func:`colour_scale`) has round ends above the 99.5 % quantile of |value| over all
panels, so that the singular clamp corners do not set it; what lies beyond is drawn in the end
colours, marked by the colour bar's arrows and said in the caption. Where the sign matters
(negative values beyond 2 % of the scale) the scale is diverging and symmetric about 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .data import MapData, YarnState
from .style import SHEAR_LABEL, caption, figure, nice_ceil, put_caption

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "ColourScale",
    "colour_bar",
    "colour_scale",
    "limits_of",
    "map_panel",
    "shear_map_figure",
    "yarn_network_figure",
    "yarn_state_figure",
]


@dataclass(frozen=True)
class ColourScale:
    """One colour scale for all panels of a map: its norm's ends, colour map, and what lies beyond."""

    vmin: float
    vmax: float
    cmap: str
    extend: str  #: "neither", "min", "max", "both": values beyond the ends (drawn in the end colours)
    data_min: float
    data_max: float

    def norm(self) -> Any:
        """The one :class:`matplotlib.colors.Normalize` of every panel."""
        from matplotlib.colors import Normalize

        return Normalize(self.vmin, self.vmax, clip=False)

    def note(self, unit: str = "°") -> str:
        """What the caption says of the values beyond the scale ("" when none)."""
        if self.extend == "neither":
            return ""
        return (
            f"colour scale {_num(self.vmin)}{unit} to {_num(self.vmax)}{unit}: values beyond it (data "
            f"{_num(self.data_min, '.1f')}{unit} to {_num(self.data_max, '.1f')}{unit}) in the end colours "
            "(arrows)"
        )


def _num(v: float, spec: str = "g") -> str:
    """A number for a label, with a true minus sign."""
    return format(v, spec).replace("-", "\u2212")


def colour_scale(values: Sequence[np.ndarray], quantile: float = 0.995, signed: bool | None = None) -> ColourScale:
    """A shared, round colour scale for maps (see the module docstring).

    ``signed``: True forces a symmetric diverging scale, False a sequential one from 0; None decides
    from the data (diverging when negative values go beyond 2 % of the scale).
    """
    v = np.concatenate([np.asarray(a, dtype=float).ravel() for a in values])
    v = v[np.isfinite(v)]
    if v.size == 0:
        return ColourScale(0.0, 1.0, "viridis", "neither", 0.0, 0.0)
    lo, hi = float(np.quantile(v, 1 - quantile)), float(np.quantile(v, quantile))
    dmin, dmax = float(v.min()), float(v.max())
    if signed is None:
        signed = lo < -0.02 * max(abs(hi), 1e-12)
    if signed:
        top = nice_ceil(max(abs(lo), abs(hi)))
        vmin, vmax, cmap = -top, top, "RdBu_r"
    else:
        vmin, vmax, cmap = 0.0, nice_ceil(hi), "viridis"
    below, above = dmin < vmin - 1e-9 * vmax, dmax > vmax * (1 + 1e-9)
    extend = "both" if below and above else "min" if below else "max" if above else "neither"
    return ColourScale(vmin, vmax, cmap, extend, dmin, dmax)


def map_panel(
    ax: Axes,
    m: MapData,
    cs: ColourScale,
    norm: Any,
    yarns: dict[int, list[np.ndarray]] | None = None,
    limits: tuple[float, float, float, float] | None = None,
) -> Any:
    """One map on ``ax``: the field (Gouraud-shaded, rasterized in vector files), yarns drawn on it, axes in mm.

    A map without triangles (points spanning no area) is drawn as coloured points.

    ``yarns``: deformed polylines per family (1 thick, drawn black; 2 thin, grey). ``limits``:
    (xmin, xmax, ymin, ymax) shared by the panels. Returns the coloured artist (for the colour bar).
    """
    import matplotlib.tri as mtri
    from matplotlib.ticker import MaxNLocator

    art: Any
    if len(m.triangles):
        tri = mtri.Triangulation(m.x_mm, m.y_mm, m.triangles)
        art = ax.tripcolor(tri, m.gamma_deg, shading="gouraud", cmap=cs.cmap, norm=norm, rasterized=True)
    else:  # points that span no area (crossings on one line): each coloured by its value
        art = ax.scatter(m.x_mm, m.y_mm, c=m.gamma_deg, cmap=cs.cmap, norm=norm, s=40, zorder=3)
    for fam, (colour, lw) in ((1, ("k", 1.2)), (2, ("0.45", 0.6))):
        for pl in (yarns or {}).get(fam, []):
            ax.plot(pl[:, 0], pl[:, 1], "-", color=colour, lw=lw)
    ax.set_aspect("equal")
    if limits is not None:
        ax.set_xlim(limits[0] - 2, limits[1] + 2)
        ax.set_ylim(limits[2] - 2, limits[3] + 2)
    ax.grid(False)
    ax.xaxis.set_major_locator(MaxNLocator(steps=[1, 2, 5, 10], integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=4, steps=[1, 2, 5, 10], integer=True))
    ax.set_ylabel("y [mm]")
    return art


def colour_bar(fig: Figure, axes: Any, art: Any, cs: ColourScale, label: str = SHEAR_LABEL) -> Any:
    """The one colour bar of the panels, round ticks, arrows where values lie beyond the scale."""
    from matplotlib.ticker import MaxNLocator

    cb = fig.colorbar(art, ax=list(np.ravel(axes)), extend=cs.extend, shrink=0.9, aspect=25)
    cb.set_label(label)
    cb.locator = MaxNLocator(nbins=6, steps=[1, 2, 2.5, 5, 10])
    cb.update_ticks()
    return cb


def limits_of(maps: Sequence[MapData]) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the deformed specimen over all maps [mm]."""
    xs = np.concatenate([m.x_mm for m in maps])
    ys = np.concatenate([m.y_mm for m in maps])
    return float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max())


def shear_map_figure(
    maps: Sequence[MapData], scene: Any = None, yarns: dict[float, dict[int, list[np.ndarray]]] | None = None
) -> Figure | None:
    """The shear angle on the deformed specimen, one panel per station, one colour scale (:func:`colour_scale`).

    ``yarns``: deformed yarn polylines [mm] per station and family (1 thick, drawn black; 2 thin, grey).
    """
    if not maps:
        return None
    cs = colour_scale([m.gamma_deg for m in maps])
    norm = cs.norm()
    lim = limits_of(maps)
    panel_h = max(1.2, 6.2 * (lim[3] - lim[2]) / max(lim[1] - lim[0], 1e-9))
    fig = figure(7.4, 0.9 + len(maps) * (panel_h + 0.45))
    axes = fig.subplots(len(maps), 1, squeeze=False)[:, 0]
    art = None
    load = "d" if getattr(scene, "test", "bias_extension") == "picture_frame" else "u₀"  # the crosshead travel
    for ax, m in zip(axes, maps, strict=True):
        art = map_panel(ax, m, cs, norm, (yarns or {}).get(m.u0_mm), lim)
        ax.set_title(
            f"{load} = {m.u0_mm:g} mm: shear angle from {_num(m.gamma_deg.min(), '.1f')}° to "
            f"{_num(m.gamma_deg.max(), '.1f')}°" + (" (at the crossings)" if m.what == "crossings" else "")
        )
    axes[-1].set_xlabel("x (deformed) [mm]")
    colour_bar(fig, axes, art, cs)
    note = cs.note()
    note = f"; {note}" if note else ""
    if yarns:
        note += "; thick yarns black, thin yarns grey"
    put_caption(fig, caption(scene) + note)
    return fig


def yarn_network_figure(
    x_mm: np.ndarray,
    beams: np.ndarray,
    family: np.ndarray,
    gamma_deg: np.ndarray,
    ends_mm: np.ndarray,
    u0_mm: float,
    scene: Any = None,
    scale_over: Sequence[np.ndarray] | None = None,
) -> Figure:
    """The deformed yarn network coloured by the shear angle γ of each segment, on a round colour scale.

    ``x_mm``: deformed node positions (n, 2); ``beams``: node pairs; ``family``: 1 (thick, drawn
    thick and solid) or 2 (thin, dashed) per beam; ``gamma_deg``: per beam; ``ends_mm``: the
    clamped yarn ends, marked. Axes in mm, legend below the panel. ``scale_over``: the angles of
    every picture of the run (default: this one's), so that the pictures of one run share one colour scale.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    # a shared scale covers every picture's whole range: no picture clips what another shows
    cs = colour_scale([gamma_deg, *scale_over], quantile=1.0) if scale_over else colour_scale([gamma_deg])
    norm = cs.norm()
    span_x = float(np.ptp(x_mm[:, 0])) or 1.0
    span_y = float(np.ptp(x_mm[:, 1])) or 1.0
    fig = figure(9.0, 1.4 + 7.4 * span_y / span_x, layout="compressed")
    ax = fig.subplots()
    lc = None
    for fam, lw, ls in ((2, 0.6, (0, (3, 1))), (1, 1.8, "solid")):
        sel = family == fam
        lc = LineCollection(x_mm[beams[sel]], linewidths=lw, linestyles=ls, cmap=cs.cmap, norm=norm)
        lc.set_array(gamma_deg[sel])
        ax.add_collection(lc)
    ax.plot(ends_mm[:, 0], ends_mm[:, 1], "k|", ms=4)
    ax.set_aspect("equal")
    ax.autoscale()
    ax.grid(False)
    ax.set_xlabel("x (deformed) [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(
        f"yarn network at u₀ = {u0_mm:g} mm: shear angle from {_num(gamma_deg.min(), '.1f')}° to "
        f"{_num(gamma_deg.max(), '.1f')}°"
    )
    colour_bar(fig, [ax], lc, cs)
    fig.legend(
        handles=[
            Line2D([], [], color="0.2", lw=1.8, label="thick yarns (family 1)"),
            Line2D([], [], color="0.2", lw=0.6, ls=(0, (3, 1)), label="thin yarns (family 2)"),
            Line2D([], [], color="k", ls="", marker="|", label="clamped yarn ends"),
        ],
        loc="outside lower center",
        ncol=3,
    )
    note = cs.note()
    put_caption(fig, caption(scene) + (f"; {note}" if note else ""))
    return fig


def yarn_state_figure(state: YarnState, scene: Any = None, scale_over: Sequence[np.ndarray] | None = None) -> Figure:
    """The picture of a state file of the network (:func:`yarn_network_figure`); ``scale_over`` as there."""
    x = state.x_mm
    return yarn_network_figure(
        x, state.beams, state.family, state.gamma_deg, x[state.clamped], state.u0_mm, scene, scale_over=scale_over
    )
