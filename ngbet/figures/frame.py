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

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .curves import curve_with_jumps, error_bars, shear_angle_panel
from .data import column
from .style import caption, figure, put_caption

__all__ = [
    "FRAME_ANGLE_LABEL",
    "FRAME_DATA_COLUMNS",
    "TRAVEL_LABEL",
    "FrameMeasured",
    "frame_force_figure",
    "frame_shear_figure",
    "read_frame_measured",
]

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

#: the force columns a measured picture-frame curve may hold, after ``shear_angle_deg``
FRAME_DATA_COLUMNS = ("shear_force_N", "normalized_shear_force_N_per_mm")
TRAVEL_LABEL = "crosshead travel d [mm]"


@dataclass(frozen=True)
class FrameMeasured:
    """A measured picture-frame curve: the shear angle [deg] and F_s [N] or F_norm [N/mm] (``quantity``).

    ``frame``: the frame and fabric sides its file names (``picture_frame.frame_mm``,
    ``picture_frame.fabric_mm``; empty where it names none).
    """

    path: Path
    shear_angle_deg: np.ndarray
    values: np.ndarray
    quantity: str  # one of FRAME_DATA_COLUMNS
    notes: tuple[str, ...] = ()
    frame: dict[str, float] = field(default_factory=dict)

    def fnorm(self, frame_mm: float, fabric_mm: float) -> np.ndarray:
        """F_norm [N/mm] (Eq. 10): as measured, or from F_s with the frame and fabric sides.

        The sides are those its file names, else those given (the run's).
        """
        if self.quantity == "shear_force_N":
            frame_mm = self.frame.get("picture_frame.frame_mm", frame_mm)
            fabric_mm = self.frame.get("picture_frame.fabric_mm", fabric_mm)
            return self.values * frame_mm / fabric_mm**2
        return self.values


def read_frame_measured(path: str | Path, *, columns: str | None = None) -> FrameMeasured:
    """A measured picture-frame curve for the figures, read by the one reader of measured curves.

    The file holds the shear angle and F_s [N] or F_norm [N/mm] (units from its header, converted);
    points its ``on_frame_edge`` column marks as clipped by a printed chart are left out.

    Raises
    ------
    ngbet.scene.validate.SceneError
        naming the file and what is wrong with it (as :func:`ngbet.measured.table.read_table`).
    """
    from ..measured.table import read_table
    from ..scene.validate import SceneError

    t = read_table(path, columns=columns, expect="picture_frame")
    if t.test == "bias_extension":
        raise SceneError(
            f"{path}: a bias extension curve ({t.test_reason}), and the scene is a picture frame: a run of "
            "a bias extension scene draws it (ngbet run SCENE --data)"
        )
    if t.x_quantity != "shear_angle" or t.y_quantity not in ("shear_force", "normalised_shear_force"):
        raise SceneError(
            f"{path}: a picture-frame curve for the figures holds the shear angle and the shear force "
            "F_s [N] or the normalised shear force F_norm [N/mm], e.g. the header "
            "'shear_angle_deg,shear_force_N' (--columns: a unit of N alone is the crosshead force; "
            "e.g. --columns 1:deg,2:shear_force_N)"
        )
    if len(t.x) < 2:
        raise SceneError(f"{path}: needs at least two points")
    quantity = FRAME_DATA_COLUMNS[0] if t.y_quantity == "shear_force" else FRAME_DATA_COLUMNS[1]
    return FrameMeasured(Path(t.source), t.x, t.y, quantity, t.notes, dict(t.frame))


FRAME_ANGLE_LABEL = "shear angle of the frame γ [°] (Eqs. 1–2)"


def frame_force_figure(rows: list[dict[str, Any]], scene: Any = None) -> Figure:
    """(a) The crosshead force and (b) the shear force F_s (Eq. 3) against the crosshead travel."""
    fig = figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    d, F = column(rows, "u0_mm"), column(rows, "force_N")
    snap = column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, d, F, snap, label="computed at the output loads, joined by straight lines")
    if "force_error_N" in rows[0]:
        span = float(np.nanmax(np.abs(np.r_[F, 0.0]))) or 1.0
        error_bars(ax, d, F, column(rows, "force_error_N"), span, load="d")
    ax.set_xlabel(TRAVEL_LABEL)
    ax.set_ylabel("crosshead force F [N]")
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(a) crosshead force")
    curve_with_jumps(
        ax2, d, column(rows, "shear_force_N"), snap, color="C2", marker="s", label="computed, F_s = F / (2 cos θ)"
    )
    ax2.set_xlabel(TRAVEL_LABEL)
    ax2.set_ylabel("shear force F_s [N] (Eq. 3)")
    ax2.set_xlim(left=0)
    ax2.legend(loc="upper left")
    ax2.set_title("(b) shear force")
    put_caption(fig, caption(scene))
    return fig


def frame_shear_figure(rows: list[dict[str, Any]], scene: Any = None, measured: FrameMeasured | None = None) -> Figure:
    """(a) F_norm (Eq. 10) against the frame's shear angle; (b) the shear angles against the travel.

    ``measured``: a measured curve drawn on (a) (F_s converted with its own frame and fabric sides
    where its file names them, else the run's).
    """
    fig = figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    d, g = column(rows, "u0_mm"), column(rows, "shear_angle_deg")
    snap = column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, g, column(rows, "fnorm_N_per_mm"), snap, label="computed, F_norm = F_s L_frame / L_fabric²")
    if measured is not None and scene is not None:
        pf = scene.picture_frame
        how = "" if measured.quantity != "shear_force_N" else ", its F_s × L_frame / L_fabric²"
        own = measured.frame.get("picture_frame.frame_mm"), measured.frame.get("picture_frame.fabric_mm")
        if None not in own and own != (pf.frame_mm, pf.fabric_mm):
            how += f" (frame {own[0]:g} mm, fabric {own[1]:g} mm)"
        ax.plot(
            measured.shear_angle_deg,
            measured.fnorm(pf.frame_mm, pf.fabric_mm),
            "-",
            color="0.35",
            lw=1.2,
            label=f"measured{how}",
        )
        ax.set_ylim(top=ax.get_ylim()[1] * 1.15)  # room for the legend above the steeper curve
    ax.set_xlabel(FRAME_ANGLE_LABEL)
    ax.set_ylabel("normalised shear force F_norm [N/mm] (Eq. 10)")
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(a) normalised shear force")
    ax2.plot(np.r_[0.0, d], np.r_[0.0, g], "-", color="k", label="frame (Eqs. 1–2): the ideal test")
    shear_angle_panel(
        ax2,
        d,
        rows,
        (
            ("gamma_centre_deg", "o", "computed, centre"),
            ("gamma_fabric_deg", "s", "computed, mean over the fabric square"),
        ),
        TRAVEL_LABEL,
    )
    put_caption(fig, caption(scene))
    return fig
