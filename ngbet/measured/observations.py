"""Measured observations besides the clamp force: a mid-axis profile and the centre shear angle.

Both are fitted together with the force of one specimen by ``ngbet fit`` (:mod:`ngbet.calibration`),
their derivatives with respect to the parameters coming from the same model run.

- A profile file has the columns ``u0_mm``, ``X_mm``, ``uy_mm``: the displacement u_y [mm] of the
  mid-axis Y = W/2 at X [mm] (0 at one clamp) at the clamp displacement u0 [mm]; other columns,
  such as the ``step`` of ngbet's own profile.csv, are ignored.
- A shear-angle file has the columns ``displacement_mm`` and ``shear_angle_deg``: the change of the
  angle between the yarns [deg] at the specimen's centre (optical or DIC measurement) against the
  clamp displacement [mm].

Lines starting with ``#`` are comments. A refusal names the file and the line
(:class:`ngbet.scene.validate.SceneError`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..scene.validate import SceneError
from .header import parse_number
from .table import read_text

__all__ = ["Profile", "ShearAngles", "read_angles", "read_profile"]


def _columns(path: Path, what: str, need: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named numeric columns of a CSV with a header line and ``#`` comments, checked line by line.

    The file's text and its numbers are read as every measured curve's are
    (:func:`ngbet.measured.table.read_text`, :func:`ngbet.measured.table.parse_number`).
    """
    text, _ = read_text(path, what)
    head: list[str] | None = None
    rows: list[list[float]] = []
    for k, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if head is None:
            head = cells
            missing = [n for n in need if n not in head]
            if missing:
                raise SceneError(
                    f"{what} file {path}, line {k}: needs the columns {', '.join(need)} (missing {', '.join(missing)})"
                )
            continue
        if len(cells) < len(head):
            raise SceneError(f"{what} file {path}, line {k}: {len(cells)} cells, the header has {len(head)}")
        row = []
        for n in need:
            row.append(parse_number(cells[head.index(n)], f"{what} file {path}", k, n, False))
        rows.append(row)
    if not rows:
        raise SceneError(f"{what} file {path}: no rows of numbers under a header naming {', '.join(need)}")
    a = np.array(rows)
    return {n: a[:, j] for j, n in enumerate(need)}


@dataclass(frozen=True)
class Profile:
    """A measured mid-axis profile: u_y [mm] at X [mm] on Y = W/2, at clamp displacement(s) u0 [mm]."""

    u0_mm: np.ndarray
    X_mm: np.ndarray
    uy_mm: np.ndarray
    source: str = ""

    def points(self) -> dict[float, np.ndarray]:
        """{u0: X} in the order of :meth:`measured`."""
        return {float(u0): self.X_mm[self.u0_mm == u0] for u0 in np.unique(self.u0_mm)}

    def measured(self) -> np.ndarray:
        """The measured u_y [mm], grouped by load in the order of :meth:`points`."""
        return np.concatenate([self.uy_mm[self.u0_mm == u0] for u0 in np.unique(self.u0_mm)])

    def inside(self, length_mm: float) -> Profile:
        """The points strictly between the clamps (on them u_y = 0 holds by construction)."""
        m = (self.X_mm > 1e-9 * length_mm) & (self.X_mm < length_mm * (1 - 1e-9))
        return Profile(self.u0_mm[m], self.X_mm[m], self.uy_mm[m], self.source)


def read_profile(path: str | Path) -> Profile:
    """Read a profile file (module docstring)."""
    c = _columns(Path(path), "profile", ("u0_mm", "X_mm", "uy_mm"))
    return Profile(c["u0_mm"], c["X_mm"], c["uy_mm"], str(path))


@dataclass(frozen=True)
class ShearAngles:
    """Measured centre shear angles [deg] at clamp displacements [mm] (increasing, distinct, > 0)."""

    u_mm: np.ndarray
    angle_deg: np.ndarray
    source: str = ""


def read_angles(path: str | Path) -> ShearAngles:
    """Read a shear-angle file (module docstring); points of equal displacement are averaged."""
    c = _columns(Path(path), "shear angle", ("displacement_mm", "shear_angle_deg"))
    u, g = c["displacement_mm"], c["shear_angle_deg"]
    keep = u > 0
    if keep.sum() < 1:
        raise SceneError(f"shear angle file {path}: no point at a positive displacement")
    uu, inv = np.unique(u[keep], return_inverse=True)
    gg = np.bincount(inv, weights=g[keep]) / np.bincount(inv)
    return ShearAngles(uu, gg, str(path))
