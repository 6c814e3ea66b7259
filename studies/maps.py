"""Maps at 37 and 56 mm: the deformed specimen coloured by the shear angle γ, with both yarn families.

γ is 0 at rest, the change of the angle between the yarns, as in the discrete model's figures; axes in
mm; one colour scale for both loads (round ends, what lies beyond marked by the colour bar's arrows);
thick yarns (alpha1, family 1) as thick black lines, thin yarns (alpha2, family 2) as thin grey
lines. Drawn with matplotlib from the run's map data (``map_XXmm.npz``: the shear angle and the
displacement on a lattice of every element, in mm and degrees), which the study keeps beside the figure.

    python -m ngbet.studies.maps [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = ["YARN_SPACING_MM", "build", "deformed_yarns", "extract", "main", "plot", "report", "step_vtu"]

YARN_SPACING_MM = 10.0  # drawn yarns (one line per 10 mm; the fabric's yarns are denser)


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    base = C.study_scene(scene, quick, {"outputs.plot": True, **({C.H: 20.0} if quick else {})})
    return Study(
        "maps",
        base,
        [{}],
        description=__doc__ or "",
        extract=extract,
        plot=plot,
        report=lambda d: report(d, quick),
        profile_stations=C.stations(quick, base),
    )


def step_vtu(run_dir: Path, u0: float) -> Path | None:
    """The fields file of the step at ``u0`` [mm] of a run with ``outputs.vtk_every_step`` (None: no such step)."""
    from ngbet.tables import read_rows

    for r in read_rows(run_dir / "results.csv"):
        if abs(r["u0_mm"] - u0) < 1e-6:
            return run_dir / f"fields_{int(r['step']):03d}.vtu"
    return None


def extract(rec: dict[str, Any], run_dir: Path, out: Path) -> dict[str, Any]:
    from ngbet.figures.data import map_file_name

    sc = rec["scene"]
    rows = []
    for u0 in (*sc["loading"]["stops_mm"], sc["loading"]["u0_mm"]):
        src = run_dir / map_file_name(u0)
        if not src.exists():
            continue
        shutil.copyfile(src, out / src.name)
        with np.load(src) as z:
            g = z["gamma_deg"]
            rows.append(
                {"u0_mm": u0, "data": src.name, "gamma_min_deg": float(g.min()), "gamma_max_deg": float(g.max())}
            )
    return {"maps": rows}


def deformed_yarns(
    npz: Path, L_mm: float, W_mm: float, angle_deg: float, spacing_mm: float
) -> dict[int, list[np.ndarray]]:
    """Yarn polylines of both families [mm] in the deformed configuration of a map file.

    The straight reference yarns (:func:`ngbet.studies._fields.yarn_lines_reference`) moved by the
    displacement, interpolated linearly on the map's triangulation of the reference configuration.
    """
    import matplotlib.tri as mtri

    from ._fields import yarn_lines_reference

    with np.load(npz) as z:
        # each element carries its own copy of its points (the shear angle jumps between elements);
        # the displacement is continuous: one point per position for the interpolation
        _, first, index = np.unique(
            np.round(np.c_[z["X_mm"], z["Y_mm"]], 9), axis=0, return_index=True, return_inverse=True
        )
        tri = mtri.Triangulation(z["X_mm"][first], z["Y_mm"][first], index.ravel()[z["triangles"]])
        interp = [mtri.LinearTriInterpolator(tri, z[k][first]) for k in ("ux_mm", "uy_mm")]
    out: dict[int, list[np.ndarray]] = {}
    for fam, lines in yarn_lines_reference(L_mm, W_mm, angle_deg, spacing_mm).items():
        out[fam] = []
        for pl in lines:
            # a hair inside the specimen, so that no point falls between the triangles of its border
            p = np.c_[
                np.clip(pl[:, 0], 1e-6 * L_mm, L_mm * (1 - 1e-6)), np.clip(pl[:, 1], 1e-6 * W_mm, W_mm * (1 - 1e-6))
            ]
            u = np.c_[[np.ma.filled(f(p[:, 0], p[:, 1]), np.nan) for f in interp]].T
            ok = np.all(np.isfinite(u), axis=1)
            out[fam].append(p[ok] + u[ok])
    return out


def plot(data: StudyData) -> list[Path]:
    from ngbet.figures.data import MapData
    from ngbet.figures.maps import shear_map_figure

    sp = data.meta["base_scene"]["specimen"]
    maps, yarns = [], {}
    for r in data.tables.get("maps", []):
        npz = data.out / r["data"]
        with np.load(npz) as z:
            maps.append(
                MapData(
                    float(z["u0_mm"]), z["X_mm"] + z["ux_mm"], z["Y_mm"] + z["uy_mm"], z["triangles"], z["gamma_deg"]
                )
            )
        yarns[maps[-1].u0_mm] = deformed_yarns(
            npz, sp["length_mm"], sp["width_mm"], sp["yarn_angle_deg"], YARN_SPACING_MM
        )
    fig = shear_map_figure(maps, data.meta["base_scene"], yarns)
    return [] if fig is None else [savefig(fig, data.out, "map")]


def report(data: StudyData, quick: bool = False) -> str:
    L = [
        *C.header(data, "Angle maps", R.reference_text(data, quick)),
        "One colour scale for both loads: `map.png`, `map.pdf`.",
        "",
        "| u0 [mm] | smallest shear angle γ [deg] | largest [deg] | data |",
        "|---|---|---|---|",
    ]
    for r in data.tables.get("maps", []):
        L.append(f"| {r['u0_mm']:g} | {r['gamma_min_deg']:.2f} | {r['gamma_max_deg']:.2f} | {r['data']} |")
    return "\n".join(L) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.maps")


if __name__ == "__main__":
    sys.exit(main())
