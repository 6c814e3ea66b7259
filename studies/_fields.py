"""Fields of continuum runs (fields*.vtu) for the studies: outlines, yarn lines, sampled fields.

Everything here reads VTK files, so figures can be redrawn from the study folder without solving.
Coordinates and displacements in the VTK files are in millimetres, as the figures.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "deformed_yarns",
    "lines_polydata",
    "midline_field",
    "outline",
    "sample_displacement",
    "warped_mm",
    "write_yarns_vtp",
    "yarn_lines_reference",
]

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")


def _pv() -> Any:
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def sample_displacement(mesh: Any, pts_mm: np.ndarray) -> np.ndarray:
    """Displacement [mm] (n, 2) of the run's field at reference points (n, 2) [mm]."""
    pv = _pv()
    p3 = np.c_[pts_mm, np.zeros(len(pts_mm))]
    s = pv.PolyData(p3).sample(mesh, tolerance=1e-9)
    u = np.asarray(s["displacement"])[:, :2]
    bad = np.asarray(s["vtkValidPointMask"]) == 0
    if bad.any():  # points a hair outside the mesh: nearest mesh point
        idx = [mesh.find_closest_point(q) for q in p3[bad]]
        u[bad] = np.asarray(mesh["displacement"])[idx, :2]
    return u


def outline(vtu: str | Path, L_mm: float, W_mm: float, n: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Deformed boundary of the specimen, closed polyline: (reference XY [mm], deformed xy [mm])."""
    pv = _pv()
    mesh = pv.read(str(vtu))
    t = np.linspace(0, 1, n, endpoint=False)
    nw = max(n * W_mm // L_mm, 8)
    s = np.linspace(0, 1, int(nw), endpoint=False)
    ref = np.r_[
        np.c_[t * L_mm, 0 * t],
        np.c_[L_mm + 0 * s, s * W_mm],
        np.c_[L_mm - t * L_mm, W_mm + 0 * t],
        np.c_[0 * s, W_mm - s * W_mm],
        [[0.0, 0.0]],
    ]
    u = sample_displacement(mesh, ref)
    return ref, ref + u


def midline_field(vtu: str | Path, L_mm: float, W_mm: float, name: str, n: int = 111) -> tuple[np.ndarray, np.ndarray]:
    """A scalar field of the run on the mid-axis Y = W/2 (reference positions X [mm])."""
    pv = _pv()
    mesh = pv.read(str(vtu))
    X = np.linspace(0, L_mm, n)
    s = pv.PolyData(np.c_[X, np.full(n, 0.5 * W_mm), np.zeros(n)]).sample(mesh, tolerance=1e-9)
    return X, np.asarray(s[name])


def yarn_lines_reference(L: float, W: float, angle_deg: float, spacing: float) -> dict[int, list[np.ndarray]]:
    """Straight yarns of both families clipped to [0, L] x [0, W] (any unit), family -> polylines.

    Family 1 along m1 = (cos a, sin a) (thick), family 2 along m2 = (-cos a, sin a) (thin); lines
    through the points where they cross Y = 0 spaced ``spacing`` along the yarn normal.
    """
    a = math.radians(angle_deg)
    out: dict[int, list[np.ndarray]] = {1: [], 2: []}
    for fam, d in ((1, np.array([math.cos(a), math.sin(a)])), (2, np.array([-math.cos(a), math.sin(a)]))):
        nrm = np.array([-d[1], d[0]])
        corners = np.array([[0, 0], [L, 0], [L, W], [0, W]])
        c = corners @ nrm
        for off in np.arange(math.ceil(c.min() / spacing) * spacing, c.max(), spacing):
            # points x = off * nrm + s d inside the rectangle
            p0 = off * nrm
            lo, hi = -math.inf, math.inf
            for k, (mn, mx) in enumerate(((0, L), (0, W))):
                if abs(d[k]) < 1e-14:
                    if not (mn <= p0[k] <= mx):
                        lo, hi = 1, 0
                    continue
                s1, s2 = (mn - p0[k]) / d[k], (mx - p0[k]) / d[k]
                lo, hi = max(lo, min(s1, s2)), min(hi, max(s1, s2))
            if hi - lo > 1e-9 * max(L, W):
                s = np.linspace(lo, hi, max(int((hi - lo) / (spacing / 4)), 2) + 1)
                out[fam].append(p0 + np.outer(s, d))
    return out


def deformed_yarns(
    vtu: str | Path, L_mm: float, W_mm: float, angle_deg: float, spacing_mm: float
) -> dict[int, list[np.ndarray]]:
    """Yarn polylines of both families in the deformed configuration [mm]."""
    pv = _pv()
    mesh = pv.read(str(vtu))
    ref = yarn_lines_reference(L_mm, W_mm, angle_deg, spacing_mm)
    out: dict[int, list[np.ndarray]] = {}
    for fam, lines in ref.items():
        out[fam] = [pl + sample_displacement(mesh, pl) for pl in lines]
    return out


def lines_polydata(lines: list[np.ndarray], scale: float = 1.0) -> Any:
    pv = _pv()
    pts, cells = [], []
    n = 0
    for pl in lines:
        pts.append(np.c_[pl * scale, np.zeros(len(pl))])
        cells.append(np.r_[len(pl), np.arange(n, n + len(pl))])
        n += len(pl)
    poly = pv.PolyData(np.vstack(pts))
    poly.lines = np.concatenate(cells)
    return poly


def warped_mm(vtu: str | Path) -> Any:
    """The run's mesh in the deformed configuration, in mm, with all its fields."""
    pv = _pv()
    return pv.read(str(vtu)).warp_by_vector("displacement")


def write_yarns_vtp(path: str | Path, yarns_mm: dict[int, list[np.ndarray]]) -> None:
    """Deformed yarns for ParaView [mm, as the fields], a cell array 'family' (1 thick, 2 thin)."""
    polys = []
    for fam, lines in yarns_mm.items():
        if lines:
            p = lines_polydata(lines)
            p.cell_data["family"] = np.full(p.n_cells, fam, dtype=np.int32)
            polys.append(p)
    merged = polys[0].merge(polys[1:]) if len(polys) > 1 else polys[0]
    merged.save(str(path))
