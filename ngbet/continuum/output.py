"""Fields of a continuum run as a VTU file, in the units of the CSV files (mm).

NGSolve writes the file (no pyvista needed); the coordinates, which NGSolve writes in the mesh's
unit (m), are then rescaled to mm in place, so that the coordinates and the 3-component
``displacement`` share one unit and "warp by vector" (ParaView, pyvista) shows the deformed
specimen at true scale. The arrays are listed in docs/outputs.md.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import ngsolve as ngs
import numpy as np

from . import observables as obs

__all__ = ["MM", "scale_points", "vtk_subdivision", "write_vtk"]

log = logging.getLogger(__name__)

MM = 1e3  # metres -> millimetres


def vtk_subdivision(p: int) -> int:
    """NGSolve's VTK ``subdivision`` s for order p: the smallest with 2^s ≥ p segments per edge.

    Each level halves the element edges: p = 2 gives 1, p = 3 and 4 give 2, p = 5 … 8 give 3, up
    to 16 4. Linear in p (s = p − 1, as before) the sub-triangles grew like 4^(p−1): at p = 10 the
    output of a 40 mm mesh took 24 GB and the run was killed.
    """
    return max(p - 1, 0).bit_length()


def write_vtk(problem: Any, path: Path) -> Path:
    """Write the fields of ``problem`` to ``path``.vtu (coordinates and displacement in mm)."""
    funcs = obs.field_functions(problem, problem.scene.outputs.fields)
    u = funcs.pop("displacement")
    coefs = {"displacement": ngs.CF((MM * u[0], MM * u[1], 0.0)), **funcs}
    ngs.VTKOutput(problem.mesh, coefs=list(coefs.values()), names=list(coefs), filename=str(path),
                  subdivision=vtk_subdivision(problem.scene.discretization.p_u), legacy=False).Do()
    vtu = Path(str(path) + ".vtu")
    scale_points(vtu, MM)
    return vtu


_POINTS = re.compile(rb'<Points>\s*<DataArray type="Float64" Name="Points" NumberOfComponents="3" '
                     rb'format="appended" offset="(\d+)"')


def scale_points(vtu: Path, factor: float) -> None:
    """Multiply the point coordinates of a VTU file written by NGSolve (raw appended data) by ``factor``."""
    data = bytearray(vtu.read_bytes())
    m = _POINTS.search(data)
    start = data.find(b'<AppendedData encoding="raw">')
    if m is None or start < 0:
        log.warning("%s: unexpected VTU layout; its coordinates are left in metres", vtu)
        return
    header = np.uint64 if b'header_type="UInt64"' in data[:start] else np.uint32
    base = data.index(b"_", start) + 1 + int(m.group(1))
    nbytes = int(np.frombuffer(data, dtype=header, count=1, offset=base)[0])
    first = base + np.dtype(header).itemsize
    xyz = np.frombuffer(data, dtype="<f8", count=nbytes // 8, offset=first) * factor
    data[first:first + nbytes] = xyz.astype("<f8").tobytes()
    vtu.write_bytes(bytes(data))
