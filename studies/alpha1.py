"""alpha1 sweep at 56 mm: the mid-axis vertical displacement for each bending stiffness of the thick yarns.

alpha1 = alpha2 = 20 Pa m^2 is the balanced fabric: mirror symmetry about Y = W/2, no S-shape
(u_y = 0 on the mid-axis). The paper's value is alpha1 = 2000 Pa m^2 (l1 = 309 mm). Every profile
is odd about X = L/2 (half-turn symmetry); the report gives that residual as a check.

    python -m ngbet.studies.alpha1 [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import math
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

__all__ = ["A1", "FULL", "QUICK", "analyse", "build", "main", "plot", "report"]

A1 = "material.alpha1"
FULL = (20.0, 200.0, 2000.0, 20000.0)
QUICK = (20.0, 2000.0)


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(scene, "alpha1", "the mid-axis S-profile of the specimen, its symmetries about X = L/2")
    base = C.study_scene(scene, quick)
    cases = [{A1: a} for a in (QUICK if quick else FULL)]
    return Study(
        "alpha1",
        base,
        cases,
        description=__doc__ or "",
        plot=lambda d: plot(d, quick),
        report=lambda d: report(d, quick),
        profile_stations=C.stations(quick, base),
    )


def analyse(data: StudyData, quick: bool) -> list[dict[str, Any]]:
    s2 = C.stations(quick, data)[1]
    a2 = data.meta["base_scene"]["material"]["alpha2"]
    out = []
    for c in data.meta["cases"]:
        i = c["case"]
        X, prof = data.profile(i, s2)
        uy = np.asarray(prof)
        amp = float(np.max(np.abs(uy))) if len(uy) else math.nan
        odd = float(np.max(np.abs(uy + uy[::-1]))) if len(uy) else math.nan
        out.append(
            {
                "case": i,
                "alpha1": c["params"][A1],
                "balanced": c["params"][A1] == a2,
                "status": c["status"],
                "F": data.at(i, s2, "force_N"),
                "max_uy": amp,
                "odd_residual": odd,
                "uy_quarter": float(np.interp(0.25 * X[-1], X, uy)) if len(uy) else math.nan,
            }
        )
    return out


def report(data: StudyData, quick: bool) -> str:
    s2 = C.stations(quick, data)[1]
    rows = analyse(data, quick)
    L = [
        *C.header(
            data,
            f"alpha1 sweep at u0 = {s2:g} mm (alpha2 = {data.meta['base_scene']['material']['alpha2']:g} Pa m^2)",
            R.reference_text(data, quick),
        ),
        "| alpha1 [Pa m^2] | l1 = sqrt(alpha1/K_sh) [mm] | F [N] | max abs(u_y) on the mid-axis [mm] "
        "| u_y(L/4) [mm] | odd-symmetry residual [mm] |",
        "|---|---|---|---|---|---|",
    ]
    ksh = data.meta["base_scene"]["material"]["K_sh"]
    for r in rows:
        L.append(
            f"| {r['alpha1']:g}{' (= alpha2, balanced)' if r['balanced'] else ''} "
            f"| {1e3 * math.sqrt(r['alpha1'] / ksh):.0f} | "
            f"{C.fmt(r['F'], '.4f')} | {r['max_uy']:.4g} | {r['uy_quarter']:.4g} | {r['odd_residual']:.2g} |"
        )
    return "\n".join(L) + "\n"


def plot(data: StudyData, quick: bool) -> list[Path]:
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    s2 = C.stations(quick, data)[1]
    fig, ax = subplots(size=(7, 4))
    for j, r in enumerate(analyse(data, quick)):
        X, uy = data.profile(r["case"], s2)
        ax.plot(
            X,
            uy,
            color=f"C{j}",
            lw=2.5 if r["balanced"] else 1.5,
            label=f"α1 = {eng(r['alpha1'], 'Pa m²')}" + (" = α2 (balanced)" if r["balanced"] else ""),
        )
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("reference position X on the mid-axis Y = W/2 [mm]")
    ax.set_ylabel("vertical displacement u_y [mm]")
    ax.set_title(f"mid-axis profile at u₀ = {s2:g} mm")
    legend_below(fig, ncol=2)
    put_caption(fig, study_caption(data.meta))
    return [savefig(fig, data.out, "alpha1_profiles")]


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.alpha1")


if __name__ == "__main__":
    sys.exit(main())
