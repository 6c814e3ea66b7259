"""Fields of a continuum run, and the mode of an instability, as VTU files in the units of the CSV files (mm).

NGSolve writes the file (no pyvista needed); the coordinates, which NGSolve writes in the mesh's
unit (m), are then rescaled to mm in place, so that the coordinates and the 3-component
``displacement`` share one unit and "warp by vector" (ParaView, pyvista) shows the deformed
specimen at true scale. The arrays are listed in docs/outputs.md.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import ngsolve as ngs
import numpy as np

from ..continuum import observables as obs

if TYPE_CHECKING:
    from ..continuum.stability import TangentSolver

__all__ = ["MM", "scale_points", "vtk_subdivision", "write_mode", "write_vtk"]

log = logging.getLogger(__name__)

MM = 1e3  # metres -> millimetres


def vtk_subdivision(p: int) -> int:
    """NGSolve's VTK ``subdivision`` s for order p: the smallest with 2^s ≥ p segments per edge.

    Each level halves the element edges: p = 2 gives 1, p = 3 and 4 give 2, p = 5 … 8 give 3, up
    to 16 4. Why not s = p − 1: the sub-triangles grow like 4^s, so the file would grow
    exponentially in p instead of like p².
    """
    return max(p - 1, 0).bit_length()


def write_vtk(problem: Any, path: Path) -> Path:
    """Write the fields of ``problem`` to ``path``.vtu (coordinates and displacement in mm)."""
    funcs = obs.field_functions(problem, problem.scene.outputs.fields)
    u = funcs.pop("displacement")
    coefs = {"displacement": ngs.CF((MM * u[0], MM * u[1], 0.0)), **funcs}
    return _write_vtu(problem, coefs, path)


def _write_vtu(problem: Any, coefs: dict[str, Any], path: Path) -> Path:
    """Write the coefficient functions ``coefs`` on the mesh of ``problem`` to ``path``.vtu.

    Subdivided for the displacement order (:func:`vtk_subdivision`); the coordinates are rescaled to
    mm (:func:`scale_points`). Returns the file written.
    """
    ngs.VTKOutput(
        problem.mesh,
        coefs=list(coefs.values()),
        names=list(coefs),
        filename=str(path),
        subdivision=vtk_subdivision(problem.scene.discretization.p_u),
        legacy=False,
    ).Do()
    vtu = Path(str(path) + ".vtu")
    scale_points(vtu, MM)
    return vtu


_POINTS = re.compile(
    rb'<Points>\s*<DataArray type="Float64" Name="Points" NumberOfComponents="3" '
    rb'format="appended" offset="(\d+)"'
)


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
    data[first : first + nbytes] = xyz.astype("<f8").tobytes()
    vtu.write_bytes(bytes(data))


def write_mode(solver: TangentSolver, mode: np.ndarray, path: Path, title: str = "") -> list[Path]:
    """The mode (δu, δφ) of an instability as ``path``.vtu and ``path``.png, δu scaled to 1 mm at most.

    ``mode`` holds the free dofs of the (condensed) tangent (:func:`ngbet.continuum.stability.lowest_eigenpair`).

    The VTU holds ``mode_displacement`` [mm] (3 components, for "warp by vector") and ``mode_phi``
    on the reference specimen [mm]; the picture shows |δu| on the specimen with the arrows of δu
    (drawn 10 times longer).
    Returns the files written (the picture is left out without matplotlib).
    """
    problem = solver.problem
    gf = ngs.GridFunction(problem.X)
    gf.vec.FV().NumPy()[:] = mode
    solver.linear.extend(gf.vec)
    du = gf.components[0]
    pts = np.array([p.point[:2] for p in problem.mesh.vertices])
    vals = np.array([du(problem.mesh(*p)) for p in pts])
    scale = 1e-3 / max(float(np.max(np.hypot(vals[:, 0], vals[:, 1]))), 1e-300)  # 1 mm at most
    coefs = {"mode_displacement": ngs.CF((MM * scale * du[0], MM * scale * du[1], 0.0))}
    if problem.phi is not None:
        coefs["mode_phi"] = scale * gf.components[1]
    written = [_write_vtu(problem, coefs, path)]
    try:
        import matplotlib.pyplot as plt
        from matplotlib.tri import Triangulation
    except ImportError:  # pragma: no cover - matplotlib is a dependency of the plots
        return written
    tris = np.array([[v.nr for v in el.vertices] for el in problem.mesh.Elements(ngs.VOL)])
    X, Y, U = pts[:, 0] * MM, pts[:, 1] * MM, vals * scale * MM
    fig, ax = plt.subplots(figsize=(9, 4))
    c = ax.tripcolor(Triangulation(X, Y, tris), np.hypot(U[:, 0], U[:, 1]), shading="gouraud", cmap="viridis")
    ax.quiver(X, Y, U[:, 0], U[:, 1], color="w", width=0.002, angles="xy", scale_units="xy", scale=0.1)
    fig.colorbar(c, ax=ax, label="|δu| [mm] (mode scaled to 1 mm)")
    ax.set(aspect="equal", xlabel="X [mm]", ylabel="Y [mm]", title=title)
    png = Path(str(path) + ".png")
    fig.savefig(png, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return [*written, png]
