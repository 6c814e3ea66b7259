"""Curves of a picture-frame run: the crosshead force, and the normalised shear force against the shear angle.

- ``force``: (a) the crosshead force F and (b) the shear force F_s = F / (2 cos θ) (Eq. 3), both
  against the crosshead travel d;
- ``shear_force``: (a) F_norm = F_s L_frame / L_fabric² (Eq. 10) against the frame's shear angle
  γ (Eqs. 1–2); (b) the frame's shear angle and the computed ones (centre, mean over the fabric
  square) against d: in an ideal test they coincide.

The computed rows are drawn as points joined by straight lines from (0, 0), as for the bias
extension test (:mod:`ngbet.figures.curves`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .curves import curve_with_jumps, error_bars
from .data import column
from .style import SHEAR_LABEL, caption, figure, put_caption

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

TRAVEL_LABEL = "crosshead travel d [mm]"
FRAME_ANGLE_LABEL = "shear angle of the frame γ [°] (Eqs. 1–2)"


def frame_force_figure(rows: list[dict[str, Any]], scene: Any = None) -> Figure:
    """(a) The crosshead force and (b) the shear force F_s (Eq. 3) against the crosshead travel."""
    fig = figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    d, F = column(rows, "u0_mm"), column(rows, "force_N")
    snap = column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, d, F, snap, label="computed (rows of results.csv), joined by straight lines")
    if "force_error_N" in rows[0]:
        span = float(np.nanmax(np.abs(np.r_[F, 0.0]))) or 1.0
        error_bars(ax, d, F, column(rows, "force_error_N"), span)
    ax.set_xlabel(TRAVEL_LABEL)
    ax.set_ylabel("crosshead force F [N]")
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(a) crosshead force")
    curve_with_jumps(ax2, d, column(rows, "shear_force_N"), snap, color="C2", marker="s",
                     label="computed, F_s = F / (2 cos θ)")
    ax2.set_xlabel(TRAVEL_LABEL)
    ax2.set_ylabel("shear force F_s [N] (Eq. 3)")
    ax2.set_xlim(left=0)
    ax2.legend(loc="upper left")
    ax2.set_title("(b) shear force")
    put_caption(fig, caption(scene))
    return fig


def frame_shear_figure(rows: list[dict[str, Any]], scene: Any = None) -> Figure:
    """(a) F_norm (Eq. 10) against the frame's shear angle; (b) the shear angles against the travel."""
    fig = figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    d, g = column(rows, "u0_mm"), column(rows, "shear_angle_deg")
    snap = column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, g, column(rows, "fnorm_N_per_mm"), snap,
                     label="computed, F_norm = F_s L_frame / L_fabric²")
    ax.set_xlabel(FRAME_ANGLE_LABEL)
    ax.set_ylabel("normalised shear force F_norm [N/mm] (Eq. 10)")
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(a) normalised shear force")
    ax2.plot(np.r_[0.0, d], np.r_[0.0, g], "-", color="k", label="frame (Eqs. 1–2): the ideal test")
    for key, style, label in (("gamma_centre_deg", "o", "computed, centre"),
                              ("gamma_fabric_deg", "s", "computed, mean over the fabric square")):
        if key in rows[0]:
            ax2.plot(np.r_[0.0, d], np.r_[0.0, column(rows, key)], style, ms=3.5, mfc="none", label=label)
    ax2.set_xlabel(TRAVEL_LABEL)
    ax2.set_ylabel(SHEAR_LABEL)
    ax2.set_xlim(left=0)
    ax2.legend(loc="upper left")
    ax2.set_title("(b) shear angles")
    put_caption(fig, caption(scene))
    return fig
