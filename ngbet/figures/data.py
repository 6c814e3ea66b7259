"""The data a run folder's figures are drawn from: map files, measured curves, table columns.

Nothing here imports matplotlib at import time: the run writes its map data through
:func:`save_map` without it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "MapData",
    "Measured",
    "YarnState",
    "column",
    "increasing_curve",
    "load_maps",
    "load_yarn_states",
    "map_file_name",
    "measured_fsh",
    "read_scene",
    "save_map",
]

log = logging.getLogger(__name__)


def map_file_name(u0_mm: float) -> str:
    """The continuum's map data at a station: ``map_37mm.npz``."""
    return f"map_{u0_mm:g}mm.npz"


def save_map(path: Path, samples: dict[str, np.ndarray], u0_mm: float) -> None:
    """Write the map data of one station (:func:`ngbet.continuum.observables.map_samples`) [mm, deg]."""
    data: dict[str, Any] = {"u0_mm": np.float64(u0_mm), **samples}
    np.savez_compressed(path, **data)


@dataclass
class MapData:
    """A triangulated shear-angle field on the deformed specimen at one clamp displacement [mm, deg]."""

    u0_mm: float
    x_mm: np.ndarray  #: deformed positions
    y_mm: np.ndarray
    triangles: np.ndarray
    gamma_deg: np.ndarray
    what: str = "continuum"


@dataclass
class YarnState:
    """The network's yarns at one clamp displacement, as its picture draws them [mm, deg].

    ``tag``: the state file's (``state_37mm.npz``: "37mm"); ``beams``: node pairs, ``family``
    and ``gamma_deg`` per beam; ``clamped``: the clamped yarn ends' node numbers.
    """

    tag: str
    u0_mm: float
    x_mm: np.ndarray  #: deformed node positions (n, 2)
    beams: np.ndarray
    family: np.ndarray
    gamma_deg: np.ndarray
    clamped: np.ndarray


def load_yarn_states(run_dir: Path) -> list[YarnState]:
    """The network's states in ``run_dir`` (its ``state_*.npz``), by increasing u0.

    A state file without the beams (written by an older ngbet) has no picture and is left out.
    """
    states = []
    for f in run_dir.glob("state_*mm.npz"):
        with np.load(f) as z:
            if "beams" not in z:
                continue
            states.append(
                YarnState(
                    f.stem[len("state_") :],
                    float(z["u0_mm"]),
                    z["X_mm"] + z["u_mm"],
                    z["beams"],
                    z["beam_family"],
                    z["segment_gamma_deg"],
                    z["clamped_nodes"],
                )
            )
    return sorted(states, key=lambda s: s.u0_mm)


def load_maps(run_dir: Path) -> list[MapData]:
    """The run's maps at its stations, by increasing u0: the continuum's map_*.npz or the network's state_*.npz.

    The network's map triangulates its crossings (Delaunay on the reference positions, drawn at the
    deformed ones), coloured by the shear angle at each crossing; crossings that all lie on one line
    (a network of a few yarns) have no triangles, and the map shows them as points.
    """
    import matplotlib.tri as mtri

    maps = []
    for f in run_dir.glob("map_*mm.npz"):
        with np.load(f) as z:
            maps.append(
                MapData(
                    float(z["u0_mm"]), z["X_mm"] + z["ux_mm"], z["Y_mm"] + z["uy_mm"], z["triangles"], z["gamma_deg"]
                )
            )
    for f in run_dir.glob("state_*mm.npz"):
        with np.load(f) as z:
            nodes = z["crossing_nodes"][:, 0]
            X, u = z["X_mm"][nodes], z["u_mm"][nodes]
            t = np.zeros((0, 3), dtype=int)  # crossings on one line (a network of a few yarns): no area
            if len(X) >= 3 and np.linalg.matrix_rank(X - X.mean(axis=0), tol=1e-9 * np.ptp(X)) == 2:
                t = mtri.Triangulation(X[:, 0], X[:, 1]).triangles
            # the crossings lie on a lattice: its Delaunay triangles are half cells (longest edge √2
            # times the shortest); longer ones span the gaps along the edges and are left out
            edges = np.stack([np.hypot(*(X[t[:, i]] - X[t[:, (i + 1) % 3]]).T) for i in range(3)], axis=1)
            keep = edges.max(axis=1) <= 1.5 * edges.min(initial=np.inf)
            maps.append(
                MapData(
                    float(f.stem[len("state_") : -2]),
                    X[:, 0] + u[:, 0],
                    X[:, 1] + u[:, 1],
                    t[keep],
                    z["crossing_gamma_deg"],
                    "crossings",
                )
            )
    return sorted(maps, key=lambda m: m.u0_mm)


@dataclass
class Measured:
    """A measured force–displacement curve for the figures, and the specimen it was measured on.

    Read by :meth:`read` through :func:`ngbet.measured.curves.read_measured`, the one reader of
    measured curves (units, columns, separators, the specimen from the header or the command line).
    """

    path: Path
    displacement_mm: np.ndarray
    force_N: np.ndarray
    width_mm: float | None = None
    length_mm: float | None = None
    notes: tuple[str, ...] = ()

    @classmethod
    def read(
        cls, path: str | Path, *, specimen: dict[str, float] | None = None, columns: str | None = None
    ) -> Measured:
        """Read a measured bias extension curve; a bad file raises :class:`ngbet.scene.validate.SceneError` naming it.

        ``specimen`` (``--specimen``) gives the scene keys of a file whose header has none.
        """
        from ..measured.curves import read_measured

        c = read_measured(path, columns=columns, specimen=specimen)
        return cls(
            Path(c.source),
            c.u_mm,
            c.force_N,
            c.specimen.get("specimen.width_mm"),
            c.specimen.get("specimen.length_mm"),
            c.notes,
        )

    def specimen(self, width_mm: float, length_mm: float) -> tuple[float, float]:
        """(W, H) of the measured specimen: its header's, else the run's."""
        return (self.width_mm or width_mm, self.length_mm or length_mm)


def increasing_curve(d: ArrayLike, F: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """A curve with strictly increasing displacement: points at the same displacement are averaged."""
    d, F = np.asarray(d, dtype=float), np.asarray(F, dtype=float)
    u, inv = np.unique(d, return_inverse=True)
    return u, np.bincount(inv, weights=F) / np.bincount(inv)


def measured_fsh(m: Measured, width_mm: float, length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(γ [deg], F_sh [N/mm]) of a measured curve by Eq. 18, below yarn locking of its specimen."""
    from ..kinematics import normalised_shear_force

    W, H = m.specimen(width_mm, length_mm)
    d, F = increasing_curve(m.displacement_mm, m.force_N)
    keep = (d > 0) & (d < (math.sqrt(2.0) - 1.0) * (H - W) * (1 - 1e-9))
    if keep.sum() < 1:
        return np.array([]), np.array([])
    g, f = normalised_shear_force(d[keep], F[keep], H, W)
    return np.degrees(g), f


def column(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    """A column of results.csv rows as floats (empty cells and missing keys as nan)."""
    return np.array([r[key] if isinstance(r.get(key), float) else math.nan for r in rows], dtype=float)


def read_scene(run_dir: Path) -> Any:
    """The scene of a run folder (its scene.toml), or None (logged) when it cannot be read."""
    from ..scene.document import Scene
    from ..scene.validate import SceneError

    try:
        return Scene.from_toml(run_dir / "scene.toml")
    except (OSError, SceneError) as exc:
        log.info("%s: no caption (%s)", run_dir, exc)
        return None
