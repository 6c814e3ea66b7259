"""Maps at 37 and 56 mm: the deformed specimen coloured by the shear angle γ, with both yarn families.

γ is 0 at rest, the change of the angle between the yarns, as in the discrete model's figures; axes in
mm, both yarn families drawn on the specimen: thick yarns (alpha1, family 1) as thick black lines, thin
yarns (alpha2, family 2) as thin white lines; rendered off-screen with pyvista. The same for ParaView:
map_XXmm.vtu (all fields, warp by 'displacement') and yarns_XXmm.vtp (deformed yarns, cell array 'family').

    python -m ngbet.studies.maps [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from ngbet.output import read_rows
from ngbet.study import Study, StudyData, main_for

from . import _common as C

YARN_SPACING_MM = 10.0  # drawn yarns (one line per 10 mm; the fabric's yarns are denser)


def build(quick: bool = False) -> Study:
    s1, s2 = C.stations(quick)
    base = C.base_scene(quick, **{"outputs.vtk": True, "outputs.vtk_every_step": True,
                                  **({C.H: 20.0} if quick else {})})
    return Study("maps", base, [{}], description=__doc__ or "", extract=extract, plot=plot, report=report,
                 profile_stations=(s1, s2))


def step_vtu(run_dir: Path, u0: float) -> Path | None:
    for r in read_rows(run_dir / "results.csv"):
        if abs(r["u0_mm"] - u0) < 1e-6:
            return run_dir / f"fields_{int(r['step']):03d}.vtu"
    return None


def extract(rec: dict, run_dir: Path, out: Path) -> dict:
    from . import _fields as F

    sc = rec["scene"]
    sp = sc["specimen"]
    rows = []
    for u0 in (*sc["loading"]["stops_mm"], sc["loading"]["u0_mm"]):
        src = step_vtu(run_dir, u0)
        if src is None or not src.exists():
            continue
        dst = out / f"map_{u0:g}mm.vtu"
        shutil.copyfile(src, dst)
        y = F.deformed_yarns(dst, sp["length_mm"], sp["width_mm"], sp["yarn_angle_deg"], YARN_SPACING_MM)
        F.write_yarns_vtp(out / f"yarns_{u0:g}mm.vtp", y)
        import pyvista as pv

        m = pv.read(str(dst))
        a = np.asarray(m["shear_angle_deg"])
        rows.append({"u0_mm": u0, "vtu": dst.name, "gamma_min_deg": float(a.min()), "gamma_max_deg": float(a.max())})
    return {"maps": rows}


def plot(data: StudyData) -> list[Path]:
    from . import _fields as F

    sp = data.meta["base_scene"]["specimen"]
    out = []
    for r in data.tables.get("maps", []):
        vtu = data.out / r["vtu"]
        y = F.deformed_yarns(vtu, sp["length_mm"], sp["width_mm"], sp["yarn_angle_deg"], YARN_SPACING_MM)
        png = data.out / f"map_{r['u0_mm']:g}mm.png"
        F.render_map(vtu, y, png, f"continuum, u0 = {r['u0_mm']:g} mm: shear angle; "
                                  "thick yarns black, thin yarns white; x, y in mm")
        F.png_to_pdf(png, png.with_suffix(".pdf"))
        out.append(png)
    return out


def report(data: StudyData) -> str:
    L = ["# Angle maps", "", "| u0 [mm] | smallest shear angle γ [deg] | largest [deg] | files |", "|---|---|---|---|"]
    for r in data.tables.get("maps", []):
        files = f"map_{r['u0_mm']:g}mm.png/.pdf/.vtu, yarns_{r['u0_mm']:g}mm.vtp"
        L.append(f"| {r['u0_mm']:g} | {r['gamma_min_deg']:.2f} | {r['gamma_max_deg']:.2f} | {files} |")
    return "\n".join(L) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.maps")


if __name__ == "__main__":
    sys.exit(main())
