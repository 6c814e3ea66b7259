"""Curves of a run: force (and double force), F_sh against γ with the shear angles, the S-profile.

The computed rows are drawn as points joined by straight lines from (0, 0) (nothing is drawn
between them that was not computed), snap-throughs (rows with ``snap`` = 1) as dashed vertical
jumps with the line broken there, the estimated discretization error as error bars (their size
written beside them when a bar is too short to see).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .data import Measured, column, measured_fsh
from .style import FORCE_LABEL, NB, SHEAR_LABEL, U0_LABEL, caption, eng_scale, figure, put_caption

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "FSH_GAMMA_MAX_DEG",
    "Extra",
    "curve_with_jumps",
    "error_bars",
    "estimate_due",
    "force_curve",
    "force_figure",
    "profile_figure",
    "shear_angle_panel",
    "shear_force_figure",
    "stations_of",
]

#: F_sh is drawn up to this kinematic shear angle [deg]: towards yarn locking (90°) Eq. 18 divides
#: by cos γ → 0 and its values say more about the equation than about the fabric
FSH_GAMMA_MAX_DEG = 70.0

Extra = Iterable[tuple[str, Sequence[float], Sequence[float]]]


def curve_with_jumps(
    ax: Axes,
    u0: ArrayLike,
    y: ArrayLike,
    snap: ArrayLike | None = None,
    *,
    label: str | None = None,
    color: str | None = None,
    marker: str = "o",
    jump_label: str | None = "snap-through (jump)",
) -> Any:
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
        (seg,) = ax.plot(
            u[a:b],
            v[a:b],
            "-",
            marker=marker,
            color=color if line is None else line.get_color(),
            label=label if line is None else None,
            ms=3.5,
        )
        line = line or seg
    assert line is not None
    for k, i in enumerate(np.flatnonzero(s)):
        ax.plot(
            [u[i], u[i]], [v[i - 1], v[i]], "--", color=line.get_color(), lw=1.2, label=jump_label if k == 0 else None
        )
    return line


def error_bars(
    ax: Axes,
    u0: np.ndarray,
    F: np.ndarray,
    err: np.ndarray,
    span: float,
    due: np.ndarray | None = None,
    load: str = "u₀",
) -> None:
    """The estimated discretization error of the force as error bars (with caps, in red).

    One note in the lower right corner of the axes (inside them, off a rising curve) gives the sizes
    of bars too short to see (below 2 % of the axis) and names the loads where an estimate was
    ``due`` (a mask of the rows) but none vouched for the force (no bar there). ``load`` is the
    symbol of the load in the note (the picture frame's crosshead travel is d).
    """
    ok = np.isfinite(err)
    lines = []
    if ok.any():
        ax.errorbar(
            u0[ok],
            F[ok],
            yerr=err[ok],
            fmt="none",
            ecolor="C3",
            elinewidth=1.6,
            capsize=5,
            capthick=1.6,
            zorder=5,
            label="± estimated discretization error",
        )
        small = [(u, e) for u, f, e in zip(u0[ok], F[ok], err[ok], strict=True) if 2 * e < 0.02 * span]
        if small:
            lines += ["error bars shorter than the markers:", *(f"±{e:.2g} N at {load} = {u:g} mm" for u, e in small)]
    missing = u0[~ok & due] if due is not None else []
    if len(missing):
        lines += [
            f"no error bar at {load} = " + ", ".join(f"{u:g}" for u in missing) + " mm:",
            "the estimate could not vouch for the force",
        ]
    if lines:
        ax.text(0.98, 0.03, "\n".join(lines), transform=ax.transAxes, ha="right", va="bottom", fontsize=7, color="C3")


def estimate_due(u0_mm: np.ndarray, scene: Any) -> np.ndarray:
    """The rows (by ``u0_mm``) where the run's ``outputs.error_estimate`` asks for an error estimate."""
    u0_mm = np.asarray(u0_mm, dtype=float)
    if scene is None:
        return np.zeros(u0_mm.shape, dtype=bool)
    which, ld = scene.outputs.error_estimate, scene.loading
    at = np.array({"stops": (*ld.stops_mm, ld.u0_mm), "final": (ld.u0_mm,)}.get(which, ()), dtype=float)
    if which == "every":
        return np.ones(u0_mm.shape, dtype=bool)
    return (np.abs(u0_mm[:, None] - at[None, :]) < 1e-6).any(axis=1) if at.size else np.zeros(u0_mm.shape, bool)


def force_figure(
    rows: list[dict[str, Any]], scene: Any = None, extra: Extra = (), measured: Measured | None = None
) -> Figure:
    """The force figure of the rows of a results.csv (see the module docstring)."""
    has_T = "double_force_Nm" in rows[0]
    fig = figure(10 if has_T else 5.8, 4.2)
    axes = fig.subplots(1, 2 if has_T else 1, squeeze=False)[0]
    ax = axes[0]
    u0, F = column(rows, "u0_mm"), column(rows, "force_N")
    snap = column(rows, "snap") if "snap" in rows[0] else None
    curve_with_jumps(ax, u0, F, snap, label="computed at the output loads, joined by straight lines")
    if measured is not None:
        ax.plot(
            measured.displacement_mm,
            measured.force_N,
            "-",
            color="0.35",
            lw=1.2,
            label=_measured_label(measured),
        )
    for label, x, y in extra:
        ax.plot(x, y, "--", label=label)
    span = float(np.nanmax(np.abs(np.r_[F, 0.0]))) or 1.0
    # a model that estimates its error writes the column (the network does not: nothing is due there)
    due = estimate_due(u0, scene) if "force_error_N" in rows[0] else None
    error_bars(ax, u0, F, column(rows, "force_error_N"), span, due)
    ax.set_xlabel(U0_LABEL)
    ax.set_ylabel(FORCE_LABEL)
    ax.set_xlim(left=0)
    if measured is not None or extra:  # a curve that rises more steeply: room above the curves for the legend
        ax.set_ylim(top=ax.get_ylim()[1] * 1.3)
    ax.legend(loc="upper left")  # rising curves leave the upper left free
    ax.set_title("(a) force" if has_T else "")
    if has_T:
        ax2 = axes[1]
        T = column(rows, "double_force_Nm")
        # a prefixed unit instead of an offset ("1e−5" above the axis): µN m, mN m, N m, ...
        k, unit = eng_scale(float(np.nanmax(np.abs(np.r_[T, 0.0]))) or 1.0, "N")
        curve_with_jumps(ax2, u0, T * k, snap, color="C2", marker="s", label="computed, joined by straight lines")
        ax2.set_xlabel(U0_LABEL)
        ax2.set_ylabel(f"double force on the moving clamp [{unit}{NB}m]")
        ax2.set_xlim(left=0)
        ax2.legend(loc="upper left")
        ax2.set_title("(b) double force")
    put_caption(fig, caption(scene))
    return fig


def _measured_label(m: Measured) -> str:
    """The measured curve's legend entry: "measured", with its specimen where the file gives it (no file name)."""
    known = m.width_mm is not None and m.length_mm is not None
    return f"measured, specimen {m.width_mm:g} × {m.length_mm:g} mm" if known else "measured"


def shear_force_figure(
    rows: list[dict[str, Any]], scene: Any = None, measured: Measured | None = None
) -> Figure | None:
    """(a) F_sh against the kinematic γ, (b) shear angles against u0; None without the columns.

    Yarns not at ±45° have no ideal test (Eqs. 13 and 18 are the ±45° bias test's): the figure is
    then panel (b) alone, the computed shear angles, and says why.
    """
    if "gamma_kinematic_deg" not in rows[0]:
        return None
    u0 = column(rows, "u0_mm")
    g_kin, fsh = column(rows, "gamma_kinematic_deg"), column(rows, "fsh_N_per_mm")
    if not np.isfinite(g_kin).any():
        return _shear_angles_only(rows, u0, scene)
    fig = figure(10, 4.2)
    ax, ax2 = fig.subplots(1, 2)
    ok = np.isfinite(g_kin) & np.isfinite(fsh)
    shown = ok & (g_kin <= FSH_GAMMA_MAX_DEG)
    left_out = bool(np.any(ok & ~shown))
    if shown.any():
        snap = column(rows, "snap")[shown] if "snap" in rows[0] else None
        curve_with_jumps(ax, g_kin[shown], fsh[shown], snap, label="computed (Eq. 18 on the run's force)")
    if measured is not None and scene is not None:
        g_m, f_m = measured_fsh(measured, scene.specimen.width_mm, scene.specimen.length_mm)
        keep = g_m <= FSH_GAMMA_MAX_DEG
        left_out = left_out or bool(np.any(~keep))
        if keep.any():
            ax.plot(
                np.r_[0.0, g_m[keep]],
                np.r_[0.0, f_m[keep]],
                "-",
                color="0.35",
                lw=1.2,
                label=_measured_label(measured),
            )
    ax.set_xlabel("kinematic shear angle γ of the ideal test [°] (Eq. 13)")
    ax.set_ylabel("normalised shear force F_sh [N/mm]")
    ax.set_xlim(0, FSH_GAMMA_MAX_DEG if left_out else None)
    ax.set_title("(a) normalised shear force")
    if ok.any() or (measured is not None and scene is not None):
        ax.legend(loc="best")  # the F_sh curves of fabrics stiffen (upper left free) or soften (lower right free)
    if left_out:
        ax.text(
            0.98,
            0.03,
            f"beyond γ = {FSH_GAMMA_MAX_DEG:g}° (near yarn locking, where Eq. 18\ndivides by cos γ → 0): not drawn",
            transform=ax.transAxes,
            ha="right",
            va="bottom",
            fontsize=7,
        )
    ax2.plot(np.r_[0.0, u0], np.r_[0.0, g_kin], "-", color="k", label="ideal test, zone A: γ (Eq. 13)")
    ax2.plot(np.r_[0.0, u0], np.r_[0.0, g_kin / 2], ":", color="k", label="ideal test, zones B: γ/2")
    shear_angle_panel(ax2, u0, rows, _COMPUTED_ANGLES, U0_LABEL)
    put_caption(fig, caption(scene))
    return fig


_COMPUTED_ANGLES = (
    ("gamma_centre_deg", "o", "computed, centre"),
    ("gamma_A_deg", "s", "computed, mean over zone A"),
    ("gamma_B_deg", "^", "computed, mean over zones B"),
)


def _shear_angles_only(rows: list[dict[str, Any]], u0: np.ndarray, scene: Any) -> Figure:
    """The computed shear angles against u0, for yarns at which the ideal test does not apply."""
    fig = figure(6.4, 4.2)
    ax = fig.subplots()
    shear_angle_panel(ax, u0, rows, _COMPUTED_ANGLES, U0_LABEL)
    angle = getattr(getattr(scene, "specimen", None), "yarn_angle_deg", None)
    at = f"yarns at ±{angle:g}°" if angle is not None else "these yarns"
    ax.set_title(f"shear angles ({at}: no ideal test, whose Eqs. 13 and 18 are for ±45°)", fontsize=9)
    put_caption(fig, caption(scene))
    return fig


def shear_angle_panel(
    ax: Axes, x: np.ndarray, rows: list[dict[str, Any]], series: tuple[tuple[str, str, str], ...], xlabel: str
) -> None:
    """Panel (b) of a shear-force figure: the computed shear angles (column, marker, label) against ``x``.

    The ideal test's curves are drawn by the caller; the rows' columns that a run lacks are skipped.
    """
    for key, style, label in series:
        if key in rows[0]:
            ax.plot(np.r_[0.0, x], np.r_[0.0, column(rows, key)], style, ms=3.5, mfc="none", label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(SHEAR_LABEL)
    ax.set_xlim(left=0)
    ax.legend(loc="upper left")
    ax.set_title("(b) shear angles")


def stations_of(rows: list[dict[str, Any]], scene: Any) -> list[float]:
    """The loads [mm] shown as stations: the load stops reached and the last row."""
    u0 = [float(r["u0_mm"]) for r in rows]
    stops = list(scene.loading.stops_mm) if scene is not None else []
    st = [u for u in u0 if any(abs(u - s) < 1e-6 for s in stops)]
    return sorted(set(st + u0[-1:]))


def profile_figure(
    profiles: dict[float, tuple[list[float], list[float]]], stations: Sequence[float], scene: Any = None
) -> Figure | None:
    """Mid-axis vertical displacement: the stations in colour, the other rows in light grey."""
    if not profiles:
        return None
    fig = figure(6.4, 3.8)
    ax = fig.subplots()
    grey = True
    for u0, (X, uy) in sorted(profiles.items()):
        if not any(abs(u0 - s) < 1e-6 for s in stations):
            ax.plot(X, uy, "-", color="0.8", lw=0.8, label="the other output loads" if grey else None)
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
    put_caption(fig, caption(scene))
    return fig


def force_curve(
    ax: Axes, u0: ArrayLike, force: ArrayLike, label: str | None = None, color: str | None = None, **kwargs: Any
) -> Any:
    """Draw a force–displacement curve on ``ax`` (:meth:`ngbet.Result.plot`): lines from (0, 0), steps marked."""
    u = np.r_[0.0, np.asarray(u0, dtype=float)]
    F = np.r_[0.0, np.asarray(force, dtype=float)]
    (line,) = ax.plot(
        u, F, "-", color=color, label=f"{label + ': ' if label else ''}straight lines between steps", **kwargs
    )
    ax.plot(u, F, "o", ms=3.5, color=line.get_color(), label="converged steps")
    return line
