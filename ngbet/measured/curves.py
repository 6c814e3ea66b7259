"""Bias extension curves for the calibration and the run figures, read by :mod:`ngbet.measured.table`.

:func:`read_measured` reads a bias extension curve (clamp displacement [mm], force [N]) and its
printed error bars (:func:`ngbet.measured.table.read_errorbars`); everything is checked
before any model run (:class:`ngbet.scene.validate.SceneError`, exit status 2).

The fitted points: curves extracted from vector graphics hold thousands of vertices, some at the
same displacement and some stepping back; the curve is sorted, points of equal displacement are
averaged, and it is sampled at :data:`POINTS_PER_CURVE` equally spaced displacements over 10–90 %
of its displacement range (linear interpolation: the paper's dashed lines have gaps). The first
tenth holds slack and friction that no elastic law describes; the last tenth reaches ideal yarn
locking, where the kinematics of the test change.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from ..scene.validate import SceneError
from .columns import WORDS
from .header import FRAME_KEYS
from .shape import plural
from .table import CurveTable, per_file, read_errorbars, read_table

__all__ = [
    "MIN_RELATIVE_SD",
    "POINTS_PER_CURVE",
    "RANGE",
    "READING_ERROR_N",
    "SAME_CURVE",
    "MeasuredCurve",
    "curve_tests",
    "read_all",
    "read_measured",
    "refuse_duplicates",
]


#: the points of a curve that enter a fit
POINTS_PER_CURVE = 16
#: the part of a curve's displacement range that is fitted and scored (fractions)
RANGE = (0.1, 0.9)
#: the reading error of the extracted curves [N]: the floor of a point's standard deviation
READING_ERROR_N = 0.03
#: the smallest standard deviation of a point, relative to its force: an error bar printed with no
#: height (several are) does not make a point exact
MIN_RELATIVE_SD = 0.01
#: two files hold the same measured curve when their forces agree to this fraction of the force range
#: at the same displacements (a re-export rounds; two measurements differ by far more)
SAME_CURVE = 1e-3


@dataclass(frozen=True)
class MeasuredCurve:
    """A checked bias extension curve: displacement [mm] increasing, force [N], its specimen keys, error bars.

    ``notes`` says what the reader did beyond reading numbers (units converted, columns chosen, an
    unloading branch left out, the specimen from the command line); ``test`` is "bias_extension".
    """

    u_mm: np.ndarray
    force_N: np.ndarray
    source: str
    specimen: dict[str, float] = field(default_factory=dict)  # "specimen.width_mm": 150.0, ...
    bars: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # u [mm], low [N], high [N]
    notes: tuple[str, ...] = ()
    test: str = "bias_extension"
    #: the picture frame's keys (``picture_frame.frame_mm``, ``picture_frame.fabric_mm``) of a picture-frame curve
    frame: dict[str, float] = field(default_factory=dict)
    #: the quantity the file holds: "force" (BET), "shear_force" or "normalised_shear_force" (picture frame)
    quantity: str = "force"
    #: the laboratory and the fabric as the file's header names them ("" where it does not)
    laboratory: str = ""
    fabric: str = ""

    @property
    def label(self) -> str:
        """The label "W x L mm" from the header (a picture frame: "frame F/f mm"), else the file name."""
        if self.test == "picture_frame":
            return f"frame {self.frame['picture_frame.frame_mm']:g}/{self.frame['picture_frame.fabric_mm']:g} mm"
        w, L = self.specimen.get("specimen.width_mm"), self.specimen.get("specimen.length_mm")
        return f"{w:g} x {L:g} mm" if w and L else Path(self.source).stem

    @property
    def locking_mm(self) -> float | None:
        """The ideal yarn locking displacement (√2 − 1)(L − W) [mm] of the specimen (45° yarns), or None."""
        w, L = self.specimen.get("specimen.width_mm"), self.specimen.get("specimen.length_mm")
        if not (w and L) or self.specimen.get("specimen.yarn_angle_deg", 45.0) != 45.0:
            return None
        return (math.sqrt(2.0) - 1.0) * (L - w)

    def in_file_units(self, u_mm: np.ndarray, force_N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of crosshead travels and forces in the file's own quantities.

        Bias extension: unchanged. Picture frame: the frame's shear angle [deg] (Eqs. 1–2) and the
        shear force F_s [N] (Eq. 3) or the normalised shear force F_norm [N/mm] (Eq. 10), as the file holds.
        """
        if self.test != "picture_frame":
            return np.asarray(u_mm, float), np.asarray(force_N, float)
        from ..kinematics import frame_normalised_force, frame_shear_angle_rad, shear_force

        L, Lf = self.frame["picture_frame.frame_mm"], self.frame["picture_frame.fabric_mm"]
        fs = shear_force(force_N, u_mm, L)
        y = frame_normalised_force(fs, L, Lf) if self.quantity == "normalised_shear_force" else fs
        return np.degrees(frame_shear_angle_rad(u_mm, L)), y

    def window(self, fraction: tuple[float, float] = RANGE) -> tuple[float, float]:
        """The displacements [mm] between the fractions of the curve's displacement range."""
        lo, hi = float(self.u_mm.min()), float(self.u_mm.max())
        return lo + fraction[0] * (hi - lo), lo + fraction[1] * (hi - lo)

    def sample(self, n: int = POINTS_PER_CURVE, fraction: tuple[float, float] = RANGE) -> tuple[np.ndarray, np.ndarray]:
        """(u, F) at n equally spaced displacements over ``fraction`` of the range."""
        a, b = self.window(fraction)
        u = np.linspace(a, b, n)
        return u, np.interp(u, self.u_mm, self.force_N)

    def check_window(self, fraction: tuple[float, float], n: int = POINTS_PER_CURVE) -> str | None:
        """Refuse a fitted window that the measurement cannot carry; a note when it is thin.

        Refused (SceneError): fewer than 3 measured points in the window (the fitted points would
        be interpolated from one or two), or a window reaching the ideal yarn locking of the
        specimen. Returns a note when the window holds fewer measured points than the ``n`` the
        fit samples (the sampled points are then not independent measurements), else None.
        """
        a, b = self.window(fraction)
        raw = int(np.count_nonzero((self.u_mm >= a) & (self.u_mm <= b)))
        if raw < 3:
            raise SceneError(
                f"{self.source}: the fitted range {a:.4g} to {b:.4g} mm holds {plural(raw, 'measured point')}; "
                f"at least 3 are needed (the fit samples {n} points between them): widen --range"
            )
        lock = self.locking_mm
        if lock is not None and b >= lock:
            raise SceneError(
                f"{self.source}: the fitted range reaches {b:.4g} mm, at or beyond the ideal yarn locking "
                f"of the {self.label} specimen ({lock:.4g} mm): give --range FROM:TO with TO below "
                f"{lock:.4g} mm, or check the specimen"
            )
        if raw < n:
            return (
                f"{self.source}: the fitted range {a:.4g} to {b:.4g} mm holds {raw} measured points; the fit "
                f"samples {n} points interpolated between them (not {n} independent measurements)"
            )
        return None

    def sd(self, u: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Standard deviation of the force at u [N]: half the error bar (interpolated), floored.

        The floor is the larger of the reading error and :data:`MIN_RELATIVE_SD` of the force;
        without error bars the floor alone (a constant relative error).
        """
        floor = np.maximum(READING_ERROR_N, MIN_RELATIVE_SD * np.abs(F))
        if self.bars is None:
            return cast(np.ndarray, floor)
        bu, lo, hi = self.bars
        half = np.interp(u, bu, 0.5 * (hi - lo))
        return cast(np.ndarray, np.maximum(half, floor))


def read_measured(
    path: str | Path,
    fraction: tuple[float, float] = RANGE,
    *,
    columns: str | Sequence[str] | None = None,
    specimen: dict[str, float] | None = None,
    test: str | None = None,
) -> MeasuredCurve:
    """Read and check a bias extension curve (module docstring); its error bars too when the file is there.

    ``test`` (``--test``) overrides the one rule's other grounds, as in :func:`read_table`.

    Refused besides what :func:`read_table` refuses: a picture-frame file (by the one rule of
    :attr:`ngbet.measured.table.CurveTable.test`), fewer than three rows or distinct displacements,
    no positive displacement, a force or displacement that is not positive in the fitted range
    ``fraction``.
    """
    path = Path(path)
    t = read_table(path, test=test, columns=columns, specimen=specimen, expect="bias_extension")
    if t.test == "picture_frame":
        raise SceneError(
            f"{path}: a picture-frame curve ({t.test_reason}), not a bias extension curve: a run of a "
            "picture-frame scene draws it (ngbet run SCENE --data), ngbet fit fits it and ngbet normalise "
            "normalises it"
        )
    if t.x_quantity != "displacement" or t.y_quantity != "force":
        raise SceneError(
            f"{path}: a curve of the {WORDS[t.y_quantity]} against the {WORDS[t.x_quantity]}; a bias "
            "extension curve is the clamp displacement and force"
        )
    u, F, lines = t.x, t.y, t.lines
    if len(u) < 3:
        raise SceneError(f"data file {path}: {plural(len(u), 'row')} of numbers; at least 3 are needed")
    order = np.argsort(u, kind="stable")
    u, F, lines = u[order], F[order], lines[order]
    lo, hi = float(u.min()), float(u.max())
    if not hi > 0:
        raise SceneError(
            f"{path}: no positive displacement (the largest is {hi:g} mm); the column "
            "displacement_mm is the clamp displacement in mm, increasing with the load"
        )
    a, b = lo + fraction[0] * (hi - lo), lo + fraction[1] * (hi - lo)
    inside = (u >= a) & (u <= b)
    bad = inside & ((F <= 0) | (u <= 0))
    if bad.any():
        j = int(np.argmax(bad))
        raise SceneError(
            f"{path}, line {int(lines[j])}: displacement {u[j]:g} mm, force {F[j]:g} N in the fitted "
            f"range {a:.3g} to {b:.3g} mm: forces and displacements must be > 0 there (a tensile test "
            "pulls; is the sign of a column flipped?)"
        )
    # equal displacements averaged (vertices of a vector path)
    uu, inv = np.unique(u, return_inverse=True)
    FF = np.bincount(inv, weights=F) / np.bincount(inv)
    if len(uu) < 3:
        raise SceneError(f"data file {path}: fewer than 3 distinct displacements")
    return MeasuredCurve(
        uu,
        FF,
        str(path),
        t.specimen,
        read_errorbars(path),
        t.notes,
        "bias_extension",
        laboratory=t.laboratory,
        fabric=t.fabric,
    )


def frame_travel_mm(gamma_deg: np.ndarray, frame_mm: float) -> np.ndarray:
    """The crosshead travel d [mm] at which the frame's shear angle is γ: Eqs. 1–2 inverted.

    γ = π/2 − 2θ and cos θ = (√2 L + d)/(2 L), so d = 2 L cos((π/2 − γ)/2) − √2 L.
    """
    theta = 0.5 * (np.pi / 2 - np.radians(np.asarray(gamma_deg, float)))
    return cast(np.ndarray, 2.0 * frame_mm * np.cos(theta) - math.sqrt(2.0) * frame_mm)


def read_frame_curve(
    path: str | Path,
    *,
    columns: str | Sequence[str] | None = None,
    frame: dict[str, float] | None = None,
    scene_frame: dict[str, float] | None = None,
) -> MeasuredCurve:
    """Read a picture-frame curve for the fit: as a crosshead travel [mm] and crosshead force [N].

    The file holds the shear force F_s [N] or the normalised shear force F_norm [N/mm] against the
    frame's shear angle [deg] (its header names the test and the frame). Each point is converted
    exactly: d from γ (:func:`frame_travel_mm`), F = 2 cos θ F_s (Eq. 3) with F_s = F_norm L_fabric²/L_frame
    (Eq. 10). A residual (model − measured)/sd is the same in either quantity, as the conversion is
    linear at each point. :meth:`MeasuredCurve.in_file_units` converts back.

    ``frame``: frame keys from the command line (refused where the header differs, as in
    :func:`read_table`); ``scene_frame``: the frame of the scene the curve is fitted with, for the
    keys its header does not name (said in a note). Refused: a frame named by neither (the message
    names both remedies), a curve of the displacement or of the crosshead force, fewer than 3
    distinct angles between 0 and 90°. Points at 0° or 90° and beyond are left out, and said.
    """
    path = Path(path)
    t = read_table(path, test="picture_frame", columns=columns, frame=frame)
    if t.x_quantity != "shear_angle" or t.y_quantity not in ("shear_force", "normalised_shear_force"):
        raise SceneError(
            f"{path}: a picture-frame curve of the {WORDS[t.y_quantity]} against the "
            f"{WORDS[t.x_quantity]}; ngbet fit takes the shear force [N] or the normalised shear "
            "force [N/mm] against the frame's shear angle [deg] (--columns: a unit of N alone is the "
            "crosshead force; name the shear force with its unit, e.g. --columns 1:deg,2:shear_force_N)"
        )
    lack = [k for k in FRAME_KEYS.values() if k not in t.frame]
    if lack and not scene_frame:
        raise SceneError(
            f"{path}: a picture-frame curve whose header names no {' and no '.join(lack)}, fitted with a "
            "scene of no picture frame: add the frame to its header (# picture_frame.frame_mm = 145, "
            "# picture_frame.fabric_mm = 120), or fit with the scene of its frame (--scene of a picture-frame "
            "scene, or --set picture_frame.frame_mm=145 --set picture_frame.fabric_mm=120)"
        )
    own = {**{k: (scene_frame or {})[k] for k in lack}, **t.frame}
    notes = list(t.notes)
    if lack:
        notes.append(f"its header names no frame: {', '.join(f'{k} = {own[k]:g}' for k in lack)} from the scene")
    L, Lf = own["picture_frame.frame_mm"], own["picture_frame.fabric_mm"]
    g, y = t.x, t.y
    keep = (g > 0) & (g < 90)
    g, y = g[keep], y[keep]
    gg, inv = np.unique(g, return_inverse=True)
    yy = np.bincount(inv, weights=y) / np.bincount(inv)
    if len(gg) < 3:
        raise SceneError(f"data file {path}: fewer than 3 distinct shear angles between 0 and 90 deg")
    from ..kinematics import frame_angle_rad

    d = frame_travel_mm(gg, L)
    fs = yy * Lf**2 / L if t.y_quantity == "normalised_shear_force" else yy
    F = 2.0 * np.cos(frame_angle_rad(d, L)) * fs
    if not keep.all():
        notes.append(f"{plural(int((~keep).sum()), 'point')} at a shear angle of 0° or 90° and beyond left out")
    note = (
        f"picture frame {L:g}/{Lf:g} mm: its {WORDS[t.y_quantity]} against the shear angle read as the "
        "crosshead force against the travel (Eqs. 1-3, 10; exact at each point)"
    )
    return MeasuredCurve(
        d,
        F,
        str(path),
        {},
        None,
        (*notes, note),
        "picture_frame",
        own,
        t.y_quantity,
        laboratory=t.laboratory,
        fabric=t.fabric,
    )


def read_any(
    path: str | Path,
    fraction: tuple[float, float] = RANGE,
    *,
    columns: str | Sequence[str] | None = None,
    specimen: dict[str, float] | None = None,
    frame: dict[str, float] | None = None,
) -> MeasuredCurve:
    """A bias-extension curve (:func:`read_measured`), or a picture-frame curve (:func:`read_frame_curve`).

    The one rule of every command decides (:attr:`ngbet.measured.table.CurveTable.test`: the
    header's test line, a picture frame's columns, a frame without a specimen); a file that names
    no test, specimen or frame is a bias extension curve on the scene's specimen. ``frame``: the
    frame of the scene, for a picture-frame curve whose header names none (``scene_frame`` of
    :func:`read_frame_curve`).
    """
    t = read_table(path, columns=columns)
    if t.test == "picture_frame":
        if specimen:
            raise SceneError(f"{path}: a picture-frame curve ({t.test_reason}); --specimen does not apply to it")
        return read_frame_curve(path, columns=columns, scene_frame=frame)
    return read_measured(path, fraction, columns=columns, specimen=specimen)


def curve_tests(paths: Sequence[str | Path], columns: str | Sequence[str] | None = None) -> list[str]:
    """The test of each curve as :func:`read_any` reads it: "picture_frame" or "bias_extension".

    Read before the scene is (its frame is for the picture-frame curves whose header names none);
    refused as :func:`read_table` refuses (SceneError).
    """
    return [
        "picture_frame" if read_table(p, columns=columns).test == "picture_frame" else "bias_extension" for p in paths
    ]


def read_all(
    paths: Sequence[str | Path],
    fraction: tuple[float, float] = RANGE,
    *,
    columns: str | Sequence[str] | None = None,
    specimens: Sequence[dict[str, float]] | None = None,
    frame: dict[str, float] | None = None,
) -> list[MeasuredCurve]:
    """:func:`read_any` for several files; the same file (or the same numbers) given twice is refused.

    ``specimens``: one ``--specimen`` for every file, or one per file in order; ``frame``: the
    scene's frame, for the picture-frame curves whose header names none.
    """
    specs = per_file(specimens or (), len(paths), "--specimen")
    curves = [
        read_any(p, fraction, columns=columns, specimen=s, frame=frame) for p, s in zip(paths, specs, strict=True)
    ]
    refuse_duplicates(curves)
    return curves


def refuse_duplicates(curves: Sequence[MeasuredCurve | CurveTable]) -> None:
    """Refuse a file given twice, or two files of the same measured curve (each would count twice).

    Two files hold the same curve when they are of the same test and quantities, their specimens
    and frames do not differ, and their forces agree to :data:`SAME_CURVE` of the force range at
    the same displacements (row by row, or interpolated): a curve re-exported in other units, with
    other separators or rounded, is the same curve. Refused naming both files (SceneError).
    """
    seen: list[tuple[Path, MeasuredCurve | CurveTable]] = []
    for c in curves:
        here = Path(c.source).resolve()
        for where, other in seen:
            same = where == here
            if same or _same_curve(c, other):
                raise SceneError(
                    f"{c.source} and {other.source}: the same "
                    f"{'file' if same else 'measured curve'} twice"
                    + (
                        ""
                        if same
                        else f" (one test and specimen; the forces agree to within {100 * SAME_CURVE:g} % of "
                        "their range at the same displacements)"
                    )
                    + "; give each curve once (a curve given twice counts twice and makes the uncertainties "
                    "too small)"
                )
        seen.append((here, c))


def _xy(c: MeasuredCurve | CurveTable) -> tuple[np.ndarray, np.ndarray, tuple[str, str, str]]:
    if isinstance(c, MeasuredCurve):
        return c.u_mm, c.force_N, (c.test, "displacement", c.quantity)
    return c.x, c.y, (c.test, c.x_quantity, c.y_quantity)


def _same_curve(a: MeasuredCurve | CurveTable, b: MeasuredCurve | CurveTable) -> bool:
    """Whether two curves are one measurement (:func:`refuse_duplicates`)."""
    (xa, ya, ka), (xb, yb, kb) = _xy(a), _xy(b)
    sizes = {**a.specimen, **a.frame}, {**b.specimen, **b.frame}
    if ka != kb or any(not math.isclose(v, sizes[1][k]) for k, v in sizes[0].items() if k in sizes[1]):
        return False
    if min(len(xa), len(xb)) < 3:
        return bool(np.array_equal(xa, xb) and np.array_equal(ya, yb))
    tx = SAME_CURVE * max(float(np.ptp(xa)), float(np.ptp(xb)))
    ty = SAME_CURVE * max(float(np.ptp(ya)), float(np.ptp(yb)))
    if len(xa) == len(xb) and np.all(np.abs(xa - xb) <= tx) and np.all(np.abs(ya - yb) <= ty):
        return True
    oa, ob = np.argsort(xa, kind="stable"), np.argsort(xb, kind="stable")
    xa, ya, xb, yb = xa[oa], ya[oa], xb[ob], yb[ob]
    if abs(xa[0] - xb[0]) > tx or abs(xa[-1] - xb[-1]) > tx:
        return False
    return bool(np.all(np.abs(np.interp(xa, xb, yb) - ya) <= ty) and np.all(np.abs(np.interp(xb, xa, ya) - yb) <= ty))
