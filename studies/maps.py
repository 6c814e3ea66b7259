"""Maps at 37 and 56 mm: the deformed specimen coloured by the shear angle γ, with both yarn families.

Made for both tests: the bias extension specimen, and the picture frame's fabric (its fabric
square with held arms, the cross with sheared arms) at its load stop and crosshead travel.

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

__all__ = [
    "YARN_SPACING_MM",
    "build",
    "deformed_yarns",
    "extract",
    "main",
    "map_yarns",
    "plot",
    "report",
    "step_vtu",
    "yarn_directions",
]

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
    """Yarn polylines of both families [mm] in the deformed configuration of a bias extension specimen's map file.

    The specimen is [0, L_mm] x [0, W_mm] (:func:`map_yarns` clips the yarns to any map's own domain).
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


def yarn_directions(scene: dict[str, Any]) -> tuple[float, float]:
    """The directions [deg from e1] of the thick and the thin yarns of a scene (its dictionary), at rest.

    m1 = (cos a, sin a), m2 = (−cos a, sin a) with a = ``specimen.yarn_angle_deg``; in the picture
    frame both turned by ``picture_frame.misalignment_deg``.
    """
    a = float(scene["specimen"]["yarn_angle_deg"])
    turned = float(scene["picture_frame"]["misalignment_deg"]) if scene.get("test") == "picture_frame" else 0.0
    return a + turned, 180.0 - a + turned


def map_yarns(npz: Path, directions_deg: tuple[float, float], spacing_mm: float) -> dict[int, list[np.ndarray]]:
    """Yarn polylines of both families [mm] in the deformed configuration of a map file, over its whole domain.

    Family k runs along ``directions_deg[k - 1]`` [deg from e1]: straight lines ``spacing_mm``
    apart (along their normal, at its multiples) clipped to the map's reference domain, the union of
    its triangles (the bias extension specimen, a picture frame's fabric square or cross): each
    piece of a line inside it a polyline, from boundary to boundary. The points are moved by the
    displacement, interpolated linearly on the map's triangulation of the reference configuration.
    """
    import matplotlib.tri as mtri

    with np.load(npz) as z:
        # each element carries its own copy of its points (the shear angle jumps between elements);
        # the displacement is continuous: one point per position for the interpolation
        _, first, index = np.unique(
            np.round(np.c_[z["X_mm"], z["Y_mm"]], 9), axis=0, return_index=True, return_inverse=True
        )
        X, Y = z["X_mm"][first], z["Y_mm"][first]
        tri = mtri.Triangulation(X, Y, index.ravel()[z["triangles"]])
        interp = [mtri.LinearTriInterpolator(tri, z[k][first]) for k in ("ux_mm", "uy_mm")]
    inside = tri.get_trifinder()
    edge = tri.neighbors == -1  # the domain's boundary: edges of one triangle only
    A = np.c_[X[tri.triangles[edge]], Y[tri.triangles[edge]]]
    B = np.c_[X[np.roll(tri.triangles, -1, axis=1)[edge]], Y[np.roll(tri.triangles, -1, axis=1)[edge]]]
    size = float(max(np.ptp(X), np.ptp(Y)))
    box = np.array([[X.min(), Y.min()], [X.max(), Y.min()], [X.max(), Y.max()], [X.min(), Y.max()]])
    out: dict[int, list[np.ndarray]] = {}
    for fam, deg in enumerate(directions_deg, start=1):
        d = np.array([np.cos(np.radians(deg)), np.sin(np.radians(deg))])
        nrm = np.array([-d[1], d[0]])
        c = box @ nrm
        out[fam] = []
        for off in np.arange(np.ceil(c.min() / spacing_mm) * spacing_mm, c.max(), spacing_mm):
            p0 = off * nrm
            for s1, s2 in _pieces(p0, d, A, B, size, inside):
                s = np.linspace(s1, s2, max(int((s2 - s1) / (spacing_mm / 4)), 2) + 1)
                p = p0 + np.outer(s, d)
                u = np.c_[[np.ma.filled(f(p[:, 0], p[:, 1]), np.nan) for f in interp]].T
                ok = np.all(np.isfinite(u), axis=1)
                if ok.sum() > 1:
                    out[fam].append(p[ok] + u[ok])
    return out


def _pieces(p0: np.ndarray, d: np.ndarray, A: np.ndarray, B: np.ndarray, size: float, inside: Any) -> list[Any]:
    """The parameter intervals (s1, s2) of the line p0 + s d inside the domain whose boundary edges are A[i]–B[i].

    Each end a hair (1e-6 of the domain's ``size``) inside, where the interpolation finds a triangle.
    """
    E = B - A
    den = d[0] * E[:, 1] - d[1] * E[:, 0]
    hit = np.abs(den) > 1e-12 * np.hypot(E[:, 0], E[:, 1])
    w = A[hit] - p0
    s = (w[:, 0] * E[hit, 1] - w[:, 1] * E[hit, 0]) / den[hit]
    r = (w[:, 0] * d[1] - w[:, 1] * d[0]) / den[hit]
    ends = np.unique(np.round(s[(r >= -1e-12) & (r <= 1 + 1e-12)] / size, 12)) * size
    eps = 1e-6 * size
    out = []
    for s1, s2 in zip(ends[:-1], ends[1:], strict=True):
        mid = p0 + 0.5 * (s1 + s2) * d
        if s2 - s1 > 4 * eps and inside(mid[0], mid[1]) >= 0:
            out.append((s1 + eps, s2 - eps))
    return out


def plot(data: StudyData) -> list[Path]:
    import warnings

    from ngbet.figures.data import MapData
    from ngbet.figures.maps import shear_map_figure
    from ngbet.scene.document import SceneWarning

    directions = yarn_directions(data.meta["base_scene"])
    maps, yarns = [], {}
    for r in data.tables.get("maps", []):
        npz = data.out / r["data"]
        with np.load(npz) as z:
            maps.append(
                MapData(
                    float(z["u0_mm"]), z["X_mm"] + z["ux_mm"], z["Y_mm"] + z["uy_mm"], z["triangles"], z["gamma_deg"]
                )
            )
        yarns[maps[-1].u0_mm] = map_yarns(npz, directions, YARN_SPACING_MM)
    with warnings.catch_warnings():  # the figure names the scene's test and specimen; its keys were warned about
        warnings.simplefilter("ignore", SceneWarning)
        scene = Scene.from_dict(data.meta["base_scene"])
    fig = shear_map_figure(maps, scene, yarns)
    return [] if fig is None else [savefig(fig, data.out, "map")]


def report(data: StudyData, quick: bool = False) -> str:
    L = [
        *C.header(data, "Angle maps", R.reference_text(data, quick)),
        "One colour scale for both loads: `map.png`, `map.pdf`.",
        "",
        f"| {'d' if data.meta['base_scene'].get('test') == 'picture_frame' else 'u0'} [mm] "
        "| smallest shear angle γ [deg] | largest [deg] | data |",
        "|---|---|---|---|",
    ]
    for r in data.tables.get("maps", []):
        L.append(f"| {r['u0_mm']:g} | {r['gamma_min_deg']:.2f} | {r['gamma_max_deg']:.2f} | {r['data']} |")
    return "\n".join(L) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.maps")


if __name__ == "__main__":
    sys.exit(main())
