"""K_el sweep at 37 mm: deformed outlines of the specimen for each yarn elongation stiffness.

Stiffer yarns (larger K_el) let the specimen contract less: the central part stays wider. The
outline is the deformed boundary, sampled from each run's fields.vtu; the report gives the
width at X = L/2, the shear angle at the centre and the length along the mid-axis of the central
zone (shear angle at least 90 % of the centre's), from the same file.

    python -m ngbet.studies.kel [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.figures.style import eng
from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = ["FULL", "KEL", "QUICK", "build", "extract", "main", "plot", "report", "widths"]

KEL = "material.K_el"
FULL = (0.1e6, 0.3e6, 0.7e6, 2e6, 7e6)
QUICK = (0.2e6, 2e6)


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(scene, "kel", "the deformed outline of the specimen, its width at X = L/2")
    u0 = 20.0 if quick else 37.0
    base = C.study_scene(scene, quick, {"loading.u0_mm": u0, "loading.stops_mm": [], "outputs.vtk": True})
    return Study(
        "kel",
        base,
        [{KEL: k} for k in (QUICK if quick else FULL)],
        description=__doc__ or "",
        extract=extract,
        plot=plot,
        report=lambda d: report(d, quick),
        profile_stations=(u0,),
    )


def extract(rec: dict[str, Any], run_dir: Path, out: Path) -> dict[str, Any]:
    sp = rec["scene"]["specimen"]
    F = _fields()
    ref, xy = F.outline(run_dir / "fields.vtu", sp["length_mm"], sp["width_mm"])
    X, g = F.midline_field(run_dir / "fields.vtu", sp["length_mm"], sp["width_mm"], "shear_angle_deg")
    return {
        "outlines": [{"X_mm": a[0], "Y_mm": a[1], "x_mm": b[0], "y_mm": b[1]} for a, b in zip(ref, xy, strict=True)],
        "midline_shear": [{"X_mm": x, "gamma_deg": v} for x, v in zip(X, g, strict=True)],
    }


def _fields() -> Any:  # imported lazily: pyvista is only needed to extract
    from . import _fields as F

    return F


def widths(data: StudyData) -> list[dict[str, Any]]:
    L = data.meta["base_scene"]["specimen"]["length_mm"]
    W = data.meta["base_scene"]["specimen"]["width_mm"]
    u0 = data.meta["base_scene"]["loading"]["u0_mm"]
    out = []
    for c in data.meta["cases"]:
        pts = [r for r in data.tables.get("outlines", []) if int(r["case"]) == c["case"]]
        top = [r for r in pts if abs(r["Y_mm"] - W) < 1e-9 and abs(r["X_mm"] - L / 2) < 1e-6]
        bot = [r for r in pts if abs(r["Y_mm"]) < 1e-9 and abs(r["X_mm"] - L / 2) < 1e-6]
        w = top[0]["y_mm"] - bot[0]["y_mm"] if top and bot else float("nan")
        mid = [r for r in data.tables.get("midline_shear", []) if int(r["case"]) == c["case"]]
        Xs = np.array([r["X_mm"] for r in mid])
        gs = np.array([r["gamma_deg"] for r in mid])
        g_c = float(np.interp(L / 2, Xs, gs)) if len(mid) else float("nan")
        zone = Xs[gs >= 0.9 * g_c] if len(mid) else np.array([])
        out.append(
            {
                "case": c["case"],
                "K_el": c["params"][KEL],
                "width_mm": w,
                "gamma_c": g_c,
                "zone_mm": float(zone.max() - zone.min()) if len(zone) else float("nan"),
                "F": data.at(c["case"], u0, "force_N"),
                "status": c["status"],
            }
        )
    return out


def report(data: StudyData, quick: bool = False) -> str:
    u0 = data.meta["base_scene"]["loading"]["u0_mm"]
    L = [
        *C.header(data, f"K_el sweep at u0 = {u0:g} mm", R.reference_text(data, quick)),
        "| K_el [MPa] | width at X = L/2 [mm] | shear angle at the centre [deg] | "
        "length of the central zone, shear >= 90 % of the centre's [mm] | F [N] |",
        "|---|---|---|---|---|",
    ]
    for r in widths(data):
        L.append(
            f"| {r['K_el'] / 1e6:g} | {r['width_mm']:.3f} | {r['gamma_c']:.2f} | {r['zone_mm']:.1f} "
            f"| {C.fmt(r['F'], '.4f')} |"
        )
    return "\n".join(L) + "\n"


def plot(data: StudyData) -> list[Path]:
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    u0 = data.meta["base_scene"]["loading"]["u0_mm"]
    # the constrained layout makes room for the caption above the title and the legend below the x-label
    fig, ax = subplots(size=(10, 4.4))
    for j, r in enumerate(widths(data)):
        pts = [q for q in data.tables.get("outlines", []) if int(q["case"]) == r["case"]]
        if pts:
            ax.plot(
                [q["x_mm"] for q in pts],
                [q["y_mm"] for q in pts],
                color=f"C{j}",
                label=f"K_el = {eng(r['K_el'], 'Pa')} (width at centre {r['width_mm']:.1f} mm)",
            )
    L = data.meta["base_scene"]["specimen"]["length_mm"]
    W = data.meta["base_scene"]["specimen"]["width_mm"]
    ax.plot([0, L, L, 0, 0], [0, 0, W, W, 0], "k:", lw=0.8, label="undeformed specimen")
    ax.set_aspect("equal")
    ax.set_xlabel("x (deformed) [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(f"deformed outlines at u₀ = {u0:g} mm")
    legend_below(fig, ncol=2)
    put_caption(fig, study_caption(data.meta))
    return [savefig(fig, data.out, "kel_outlines")]


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.kel")


if __name__ == "__main__":
    sys.exit(main())
