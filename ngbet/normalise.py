r"""``ngbet normalise``: measured shear tests as the normalised shear force against the shear angle.

``ngbet normalise FILE.csv ... [--test bias_extension|picture_frame] [--specimen WxL] [--frame FxL] --out DIR``

Every file is read by the one reader of measured curves (:func:`ngbet.measured.table.read_table`:
units, columns by name, separators, the specimen and the frame from the header or the command line),
and its test decided by the one rule of every command (:attr:`ngbet.measured.table.CurveTable.test`:
``--test``, the header's test line, a picture frame's columns, a specimen or a frame named alone); a
file that names neither a specimen nor a frame nor its test is refused.

Bias extension (45° yarns, specimen W × H, H the clamp-to-clamp length; Cao et al. 2008):

- the kinematic shear angle γ(d) of the ideal test, Eq. 13 (:func:`ngbet.kinematics.shear_angle_rad`);
- F_sh(γ) by Eq. 18, the power balance of the ideal zones solved along the curve
  (:func:`ngbet.kinematics.normalised_shear_force`);
- the energy method (Harrison et al. 2004 derive Eq. 18 from it): the work of the clamp force,
  W(d) = ∫ F dd, equals the shear energy of the ideal zones, A_A w(γ) + A_B w(γ/2) with
  A_A = (2HW − 3W²)/2 and A_B = W²; solved along the curve for the energy per unit area w(γ)
  [N/mm = mJ/mm²] (w piecewise linear in γ through 0, as F_sh in Eq. 18), and
  F_sh = (dw/dγ) / cos γ. Both are the same balance: they agree where the measurement is smooth,
  and their difference shows what the differentiation of a measured curve costs.

Points at or beyond yarn locking, d ≥ (√2 − 1)(H − W), are left out (Eq. 13 has no angle there).

Picture frame (frame side L_frame pin to pin, free fabric square L_fabric; Cao et al. 2008 Eqs. 1–3, 10):
cos θ = (√2 L_frame + d) / (2 L_frame), γ = 90° − 2θ, F_s = F / (2 cos θ), and the normalised
shear force F_norm = F_s L_frame / L_fabric², the quantity compared with the bias extension test's
F_sh. A file may give the crosshead displacement or the shear angle, and the crosshead force, the
shear force F_s or F_norm itself; the rest follows.

Writes into ``--out`` (a folder it owns as ``ngbet run`` owns its folder: refused when it holds
files that ngbet did not write there, files written complete under a temporary name first): a
table per curve (``NAME_normalised.csv``, units in the column names), the collapse figure of the
measurements (``collapse.png``) and ``normalise.json`` with the spread between the curves.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .measured.curves import MeasuredCurve, read_measured, refuse_duplicates
from .measured.header import fabric_names
from .measured.shape import plural
from .measured.table import CurveTable, curve_files, parse_sizes, per_file, read_table
from .run_folder import OwnedFolder
from .scene.validate import SceneError

__all__ = [
    "FIGURE",
    "SPREAD_FROM_DEG",
    "SPREAD_POINTS",
    "SUMMARY",
    "TABLE_SUFFIX",
    "Normalised",
    "add_parser",
    "energy_method",
    "force_by_normalisation",
    "normalise_bet",
    "normalised_curve",
    "normalise_pf",
    "predict_by_normalisation",
    "read_inputs",
    "run_from_args",
    "spread",
    "spread_text",
    "spreads",
]

#: the spread between curves is measured from this shear angle [deg] on (below it F_sh is small and
#: its relative spread says little) to the largest angle every curve reaches
SPREAD_FROM_DEG = 10.0
#: ... on this many equally spaced angles
SPREAD_POINTS = 50
TABLE_SUFFIX = "_normalised.csv"
FIGURE = "collapse"
SUMMARY = "normalise.json"


@dataclass
class Normalised:
    """One measured curve normalised: its columns (name with unit → values) and the collapse quantity.

    ``fsh`` is F_sh by Eq. 18 (bias extension) or F_norm by Eq. 10 (picture frame) [N/mm] at
    ``gamma_deg``; ``fsh_energy`` the bias extension's energy method (None for a picture frame).
    """

    source: str
    test: str
    label: str
    gamma_deg: np.ndarray
    fsh: np.ndarray
    fsh_energy: np.ndarray | None
    columns: dict[str, np.ndarray]
    header: list[str]
    notes: list[str] = field(default_factory=list)
    #: the fabric and the laboratory as the file's header names them ("" where it does not)
    fabric: str = ""
    laboratory: str = ""
    #: the quantity the file gives: "force" (a bias extension test, or a frame's crosshead force),
    #: "shear_force" or "normalised_shear_force" (a picture frame)
    given: str = "force"


def _points(n: Any) -> str:
    return plural(int(n), "point")


# --- bias extension ------------------------------------------------------------------------------------------------


def _half_angle_solve(gamma: np.ndarray, rhs: np.ndarray, own: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The f at each γ_i from own_i f(γ_i) + half_i f(γ_i / 2) = rhs_i, f piecewise linear in γ through (0, 0).

    f(γ_i / 2) is interpolated between earlier points (or involves f(γ_i) itself where γ_i / 2
    lies beyond γ_{i−1}): each equation is linear in its own unknown, solved in order.
    """
    g = np.r_[0.0, gamma]
    f = np.zeros(len(g))
    for i in range(1, len(g)):
        h = g[i] / 2
        j = max(int(np.searchsorted(g[: i + 1], h, side="right")), 1)
        w = (h - g[j - 1]) / (g[j] - g[j - 1]) if g[j] > g[j - 1] else 0.0
        known = (1.0 - w) * f[j - 1] + (w * f[j] if j < i else 0.0)
        share = w if j == i else 0.0
        f[i] = (rhs[i - 1] - half[i - 1] * known) / (own[i - 1] + half[i - 1] * share)
    return f[1:]


def energy_method(
    d_mm: np.ndarray, force_N: np.ndarray, H_mm: float, W_mm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(γ [rad], shear energy per unit area w [N/mm], F_sh = (dw/dγ)/cos γ [N/mm]) of a BET curve (module docstring).

    ``d_mm`` strictly increasing, positive and below yarn locking; the work is integrated by the
    trapezoidal rule from the unloaded state (0, 0).
    """
    from scipy.integrate import cumulative_trapezoid

    from .kinematics import shear_angle_rad

    gamma = shear_angle_rad(d_mm, H_mm, W_mm)
    work = cumulative_trapezoid(np.r_[0.0, force_N], np.r_[0.0, d_mm])  # N mm at each point
    A_A, A_B = (2 * H_mm * W_mm - 3 * W_mm**2) / 2, W_mm**2
    n = len(gamma)
    w = _half_angle_solve(gamma, work, np.full(n, A_A), np.full(n, A_B))
    return gamma, w, np.gradient(w, gamma) / np.cos(gamma)


def normalised_curve(curve: MeasuredCurve) -> tuple[np.ndarray, np.ndarray]:
    """(γ [rad], normalised shear force [N/mm]) along a measured curve of either test.

    Bias extension: F_sh by Eq. 18 at its points of positive displacement below yarn locking.
    Picture frame: F_norm by Eqs. 1–3 and 10 at its points of positive travel. The two are the
    quantities the normalisation methods carry from one specimen or test to another
    (:func:`force_by_normalisation`).
    """
    from .kinematics import frame_normalised_force, frame_shear_angle_rad, normalised_shear_force, shear_force

    ok = curve.u_mm > 0
    d, F = curve.u_mm[ok], np.maximum(curve.force_N[ok], 0.0)
    if curve.test == "picture_frame":
        L, Lf = curve.frame["picture_frame.frame_mm"], curve.frame["picture_frame.fabric_mm"]
        return frame_shear_angle_rad(d, L), frame_normalised_force(shear_force(F, d, L), L, Lf)
    H, W = curve.specimen["specimen.length_mm"], curve.specimen["specimen.width_mm"]
    lock = curve.locking_mm
    if lock is not None:
        d, F = d[d < lock], F[d < lock]
    return normalised_shear_force(d, F, H, W)


def force_by_normalisation(
    gamma_rad: np.ndarray, fn_N_per_mm: np.ndarray, target: MeasuredCurve, u_mm: np.ndarray
) -> np.ndarray:
    """The force [N] at ``u_mm`` of the target's test that a normalised shear force curve predicts.

    Bias extension: Eq. 18 solved for the clamp force of the target's specimen
    (:func:`ngbet.kinematics.force_from_normalised`). Picture frame: the crosshead force
    F = 2 cos θ F_s, F_s = F_norm L_fabric² / L_frame at the frame's shear angle (Eqs. 1–3, 10).
    Across tests the bias extension's F_sh is read as the frame's F_norm, the paper's comparison.
    F_n is interpolated linearly in γ through (0, 0); beyond its last angle the force is NaN.
    """
    from .kinematics import force_from_normalised, frame_angle_rad

    u = np.asarray(u_mm, dtype=float)
    if target.test == "picture_frame":
        L, Lf = target.frame["picture_frame.frame_mm"], target.frame["picture_frame.fabric_mm"]
        theta = frame_angle_rad(u, L)
        fn = np.interp(np.pi / 2 - 2 * theta, np.r_[0.0, gamma_rad], np.r_[0.0, fn_N_per_mm], right=np.nan)
        return 2.0 * np.cos(theta) * fn * Lf**2 / L  # type: ignore[no-any-return]
    return force_from_normalised(
        gamma_rad, fn_N_per_mm, u, target.specimen["specimen.length_mm"], target.specimen["specimen.width_mm"]
    )


def predict_by_normalisation(fitted: Sequence[MeasuredCurve], target: MeasuredCurve, u_mm: np.ndarray) -> np.ndarray:
    """The normalisation method's prediction of ``target`` at ``u_mm`` from the curves ``fitted``.

    Each fitted curve's normalised shear force (:func:`normalised_curve`) carried to the target's
    specimen or frame (:func:`force_by_normalisation`: Eq. 18, Eq. 10, or across the tests F_sh
    read as F_norm); at each point the mean of those that have a value there, NaN where none has
    (beyond every fitted curve's largest shear angle). What ``ngbet fit --predict`` and the
    validation study set beside ngbet's prediction.
    """
    P = np.array([force_by_normalisation(*normalised_curve(c), target, u_mm) for c in fitted], dtype=float)
    with np.errstate(invalid="ignore"):
        n = np.sum(np.isfinite(P), axis=0)
        return np.where(n > 0, np.nansum(P, axis=0) / np.maximum(n, 1), np.nan)


def normalise_bet(
    path: str | Path, specimen: dict[str, float] | None = None, columns: str | Sequence[str] | None = None
) -> Normalised:
    """A bias extension curve by Eq. 18 and by the energy method (module docstring)."""
    from .kinematics import normalised_shear_force

    c = read_measured(path, columns=columns, specimen=specimen, test="bias_extension")
    sp = c.specimen
    if "specimen.width_mm" not in sp:
        raise SceneError(
            f"{path}: a bias extension curve needs its specimen: add '# specimen.width_mm = ...' and "
            "'# specimen.length_mm = ...' to the header or give --specimen WIDTHxLENGTH (mm)"
        )
    W, H = sp["specimen.width_mm"], sp["specimen.length_mm"]
    if sp.get("specimen.yarn_angle_deg", 45.0) != 45.0:
        raise SceneError(
            f"{path}: specimen.yarn_angle_deg = {sp['specimen.yarn_angle_deg']:g}: Eqs. 13 and 18 are "
            "the ±45° bias extension test's"
        )
    if not 2 * H > 3 * W:
        raise SceneError(
            f"{path}: specimen {W:g} x {H:g} mm: Eq. 18 needs a clamp-to-clamp length above 1.5 times "
            "the width (the central zone A has the area (2HW − 3W²)/2)"
        )
    lock = (math.sqrt(2.0) - 1.0) * (H - W)
    keep = (c.u_mm > 0) & (c.u_mm < lock * (1 - 1e-9))
    notes = list(c.notes)
    if np.count_nonzero(c.u_mm >= lock * (1 - 1e-9)):
        notes.append(
            f"{_points(np.count_nonzero(c.u_mm >= lock * (1 - 1e-9)))} at or beyond the ideal yarn locking "
            f"({lock:.4g} mm) left out"
        )
    if np.count_nonzero(c.u_mm <= 0):
        notes.append(f"{_points(np.count_nonzero(c.u_mm <= 0))} at zero or negative displacement left out (γ = 0)")
    if keep.sum() < 3:
        raise SceneError(
            f"{path}: {_points(keep.sum())} between 0 and the yarn locking ({lock:.4g} mm) of the "
            f"{W:g} x {H:g} mm specimen; at least 3 are needed (is the specimen right?)"
        )
    d, F = c.u_mm[keep], c.force_N[keep]
    gamma, fsh = normalised_shear_force(d, F, H, W)
    _, w, fsh_e = energy_method(d, F, H, W)
    g = np.degrees(gamma)
    cols = {
        "displacement_mm": d,
        "force_N": F,
        "shear_angle_deg": g,
        "fsh_eq18_N_per_mm": fsh,
        "fsh_energy_N_per_mm": fsh_e,
        "shear_energy_N_per_mm": w,
    }
    header = [
        f"bias extension test, specimen {W:g} x {H:g} mm (width x clamp-to-clamp length), 45° yarns",
        "displacement_mm: clamp displacement; force_N: clamp force (equal displacements averaged)",
        "shear_angle_deg: kinematic shear angle of the ideal test (Cao et al. 2008, Eq. 13)",
        "fsh_eq18_N_per_mm: normalised shear force by Eq. 18 (power balance of the ideal zones)",
        "fsh_energy_N_per_mm: the same by the energy method, (dw/dgamma)/cos(gamma)",
        "shear_energy_N_per_mm: shear energy per unit area w (N mm / mm^2) of the energy method",
    ]
    return Normalised(
        c.source, "bias_extension", f"{W:g} × {H:g} mm", g, fsh, fsh_e, cols, header, notes, c.fabric, c.laboratory
    )


# --- picture frame ---------------------------------------------------------------------------------------------------


def normalise_pf(t: CurveTable) -> Normalised:
    """A picture-frame curve by Eqs. 1–3 and 10 (module docstring)."""
    fr = t.frame
    if "picture_frame.frame_mm" not in fr or "picture_frame.fabric_mm" not in fr:
        lack = [k for k in ("picture_frame.frame_mm", "picture_frame.fabric_mm") if k not in fr]
        raise SceneError(
            f"{t.source}: a picture-frame curve needs the frame and the fabric square: add "
            f"{', '.join(repr('# ' + k + ' = ...') for k in lack)} to the header or give "
            "--frame FRAMExFABRIC (mm, e.g. 145x120)"
        )
    L, Lf = fr["picture_frame.frame_mm"], fr["picture_frame.fabric_mm"]
    if Lf > L:
        raise SceneError(f"{t.source}: the fabric square ({Lf:g} mm) is larger than the frame ({L:g} mm)")
    order = np.argsort(t.x, kind="stable")
    x, y = t.x[order], t.y[order]
    ux, inv = np.unique(x, return_inverse=True)
    y = np.bincount(inv, weights=y) / np.bincount(inv)
    cols: dict[str, np.ndarray] = {}
    notes = list(t.notes)
    if t.x_quantity == "displacement":
        c = (math.sqrt(2.0) * L + ux) / (2 * L)
        ok = (ux >= 0) & (c < 1)
        ux, y = ux[ok], y[ok]
        theta = np.arccos((math.sqrt(2.0) * L + ux) / (2 * L))
        cols["displacement_mm"] = ux
        domain = f"displacements from 0 to {(2 - math.sqrt(2.0)) * L:.4g} mm (Eq. 1)"
    else:
        ok = (ux >= 0) & (ux < 90)
        ux, y = ux[ok], y[ok]
        theta = np.radians(90.0 - ux) / 2
        domain = "shear angles from 0 to 90°"
    if not ok.all():
        notes.append(f"{_points(np.count_nonzero(~ok))} outside the frame's {domain} left out")
    gamma = 90.0 - 2 * np.degrees(theta)
    cols["shear_angle_deg"] = gamma
    if t.y_quantity == "force":
        cols["force_N"] = y
        fs = y / (2 * np.cos(theta))
    elif t.y_quantity == "shear_force":
        fs = y
    else:
        fs = y * Lf**2 / L
    cols["shear_force_N"] = fs
    cols["fnorm_N_per_mm"] = fs * L / Lf**2
    if len(gamma) < 3:
        raise SceneError(
            f"{t.source}: {_points(len(gamma))} with a shear angle between 0 and 90°; at least 3 are needed"
        )
    header = [
        f"picture-frame test, frame {L:g} mm (pin to pin), fabric square {Lf:g} mm",
        "shear_angle_deg: shear angle, 90° - 2 theta (Cao et al. 2008, Eqs. 1-2)",
        "shear_force_N: shear force F_s = F / (2 cos theta) (Eq. 3)",
        "fnorm_N_per_mm: normalised shear force F_s L_frame / L_fabric^2 (Eq. 10)",
    ]
    if "force_N" in cols:
        header.insert(1, "displacement_mm, force_N: crosshead displacement and force (less the empty frame's)")
    return Normalised(
        t.source,
        "picture_frame",
        f"frame {L:g} mm, fabric {Lf:g} mm",
        gamma,
        cols["fnorm_N_per_mm"],
        None,
        cols,
        header,
        notes,
        t.fabric,
        t.laboratory,
        t.y_quantity,
    )


# --- the collapse -------------------------------------------------------------------------------------------------


def spread(curves: Sequence[Normalised]) -> dict[str, Any] | None:
    """The spread between the curves' F_sh: (max − min)/mean [%] over the angles all reach; None for one curve.

    On :data:`SPREAD_POINTS` angles from :data:`SPREAD_FROM_DEG` (or the largest first angle) to the
    smallest last angle, drawn up to ``FSH_GAMMA_MAX_DEG``; None also when the curves share no range.
    """
    from .figures.curves import FSH_GAMMA_MAX_DEG

    if len(curves) < 2:
        return None
    a = max(SPREAD_FROM_DEG, *(float(c.gamma_deg.min()) for c in curves))
    b = min(FSH_GAMMA_MAX_DEG, *(float(c.gamma_deg.max()) for c in curves))
    if not a < b:
        return None
    g = np.linspace(a, b, SPREAD_POINTS)
    f = np.array([np.interp(g, c.gamma_deg, c.fsh) for c in curves])
    mean = np.abs(f.mean(axis=0))
    rel = 100 * (f.max(axis=0) - f.min(axis=0)) / np.where(mean > 0, mean, np.nan)
    ok = np.isfinite(rel)
    if not ok.any():
        return None
    k = int(np.nanargmax(rel))
    return {
        "max_percent": float(np.nanmax(rel)),
        "median_percent": float(np.nanmedian(rel)),
        "at_max_deg": float(g[k]),
        "from_deg": float(a),
        "to_deg": float(b),
        "curves": len(curves),
    }


def spreads(curves: Sequence[Normalised]) -> list[tuple[str, dict[str, Any] | None]]:
    """The spread between the bias extension sizes, between the picture frames, and between the tests where both are.

    Each as (what, :func:`spread`), for every group of at least two curves; of each fabric apart
    where the curves name several (:func:`ngbet.measured.header.fabric_names`): fabrics differ by more
    than sizes do.
    """
    names = fabric_names([c.fabric for c in curves])
    out = []
    for fabric in dict.fromkeys(names):
        mine = [c for c, n in zip(curves, names, strict=True) if n == fabric]
        bet = [c for c in mine if c.test == "bias_extension"]
        pf = [c for c in mine if c.test == "picture_frame"]
        of = f" of {fabric}" if fabric else ""
        out += [
            (what + of, spread(group))
            for what, group in (
                ("the bias extension sizes", bet),
                ("the picture frames", pf),
                ("the tests", mine if bet and pf else []),
            )
            if len(group) > 1
        ]
    return out


def spread_text(groups: list[tuple[str, dict[str, Any] | None]]) -> str:
    """One sentence on the spreads (figure caption and terminal)."""
    if not groups:
        return "no two curves of one fabric and test: no spread to state"
    parts = []
    for what, s in groups:
        if s is None:
            parts.append(f"{what} share no shear angle range above {SPREAD_FROM_DEG:g}°: no spread stated")
        else:
            parts.append(
                f"between {what}, the normalised shear force differs by up to {s['max_percent']:.0f} % "
                f"(at γ = {s['at_max_deg']:.0f}°; median {s['median_percent']:.0f} %) over γ = "
                f"{s['from_deg']:.0f}–{s['to_deg']:.0f}°"
            )
    return "; ".join(parts) + "; spread = (max − min)/mean"


# --- the folder --------------------------------------------------------------------------------------------------


def _table_text(n: Normalised) -> str:
    lines = [f"# {h}" for h in [f"ngbet normalise of {n.source}", *n.header, *n.notes]]
    names = list(n.columns)
    lines.append(",".join(names))
    for i in range(len(n.gamma_deg)):
        lines.append(",".join("" if not math.isfinite(v) else f"{v:.6g}" for v in (n.columns[k][i] for k in names)))
    return "\n".join(lines) + "\n"


def _names(curves: Sequence[Normalised]) -> list[str]:
    out, seen = [], set()
    for c in curves:
        stem, k = Path(c.source).stem, 2
        name = stem + TABLE_SUFFIX
        while name in seen:
            name, k = f"{stem}_{k}{TABLE_SUFFIX}", k + 1
        seen.add(name)
        out.append(name)
    return out


# --- the command ---------------------------------------------------------------------------------------------------


def add_parser(sub: Any) -> None:
    """The ``ngbet normalise`` subcommand."""
    p = sub.add_parser(
        "normalise",
        help="measured bias-extension or picture-frame curves as the normalised shear "
        "force against the shear angle: a table per curve and a collapse figure",
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="DATA.csv",
        help="measured curves (any units and separators the reader understands; see docs/normalise.md)",
    )
    p.add_argument(
        "--test",
        choices=("bias_extension", "picture_frame"),
        help="the test of every file (default: each file's header, or its specimen or frame keys)",
    )
    p.add_argument(
        "--specimen",
        action="append",
        default=[],
        metavar="WxL",
        help="bias extension: width x clamp-to-clamp length in mm (e.g. 100x250) where a header does "
        "not give it; once for every file or once per file in order",
    )
    p.add_argument(
        "--frame",
        action="append",
        default=[],
        metavar="FRAMExFABRIC",
        help="picture frame: frame side and fabric square in mm (e.g. 145x120); once or once per file",
    )
    p.add_argument(
        "--columns",
        metavar="X,Y",
        help="the two columns by header name or number, each with an optional unit (e.g. 'Weg:mm,Kraft:kN'), "
        "or a quantity and its unit as a header names them (1:deg,2:shear_force_N); a file without a header: "
        "by number only",
    )
    p.add_argument("--out", default="out/normalise", help="output folder (default: out/normalise)")
    p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")


def read_inputs(args: argparse.Namespace) -> tuple[list[Normalised], list[str]]:
    """Every file read, checked and normalised (before anything is written), and notes on files left out.

    An error-bar file given with its curve is no curve: left out, with a note.
    """
    paths, left = curve_files(args.inputs)
    sizes = ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm")
    specs = per_file([parse_sizes(t, "--specimen", sizes) for t in args.specimen], len(paths), "--specimen")
    frames = per_file(
        [parse_sizes(t, "--frame", ("picture_frame.frame_mm", "picture_frame.fabric_mm")) for t in args.frame],
        len(paths),
        "--frame",
    )
    tables = [
        read_table(p, test=args.test, columns=args.columns, specimen=s, frame=f)
        for p, s, f in zip(paths, specs, frames, strict=True)
    ]
    refuse_duplicates(tables)
    out = []
    for t, s in zip(tables, specs, strict=True):
        if not t.test:
            raise SceneError(
                f"{t.source}: which test? {t.test_reason}: give --test bias_extension or picture_frame, "
                "--specimen WIDTHxLENGTH or --frame FRAMExFABRIC (or '# test: bias_extension' in the header)"
            )
        out.append(normalise_bet(t.source, s, args.columns) if t.test == "bias_extension" else normalise_pf(t))
    for c, name in zip(out, fabric_names([c.fabric for c in out]), strict=True):
        if name and not c.fabric:
            c.notes.append(
                "its header names no fabric ('# fabric: ...'), the other files' do: compared with none of "
                "their curves (a panel 'fabric not named'); name its fabric to compare it"
            )
    return out, [f"{eb}: the error bars of {curve}, not a curve: left out" for eb, curve in left]


def run_from_args(args: argparse.Namespace) -> int:
    """``ngbet normalise``: exit 0 done, 2 bad input (nothing written), 3 an unusable output folder."""
    from .commands import exit_code

    out = Path(args.out)
    try:
        curves, left_out = read_inputs(args)
        names = _names(curves)
        groups = spreads(curves)
        text = spread_text(groups)
        with OwnedFolder(out, "normalise", "normalise") as folder:
            for c, name in zip(curves, names, strict=True):
                folder.write(name, functools.partial(Path.write_text, data=_table_text(c)))
            figure = _figure(folder, curves, text)
            summary = {
                "curves": [
                    {
                        "source": c.source,
                        "test": c.test,
                        "label": c.label,
                        "table": name,
                        "shear_angle_deg": [float(c.gamma_deg.min()), float(c.gamma_deg.max())],
                        "notes": c.notes,
                    }
                    for c, name in zip(curves, names, strict=True)
                ],
                "spread": {what: s for what, s in groups},
                "spread_text": text,
                "figure": figure,
                "files": sorted({*names, *([FIGURE + ".png", FIGURE + ".pdf"] if figure else []), SUMMARY}),
            }
            folder.write(SUMMARY, lambda p: p.write_text(json.dumps(summary, indent=2, allow_nan=False)))
    except SceneError as exc:
        print(f"ngbet normalise: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        code, msg = exit_code(exc, out)
        print(f"ngbet normalise: {msg}", file=sys.stderr)
        return code
    for note in left_out + [f"{c.source}: {note}" for c in curves for note in c.notes]:
        print(f"ngbet normalise: {note}", file=sys.stderr)
    if not args.quiet:
        print(_report(curves, names, text, out, figure))
    return 0


def _figure(folder: OwnedFolder, curves: Sequence[Normalised], text: str) -> str | None:
    """Draw the collapse figure into the folder (PNG and PDF); None (said) without matplotlib."""
    try:
        from .figures.collapse import collapse_figure
        from .figures.style import PNG_DPI, VECTOR_RASTER_DPI
    except ImportError:
        print(
            "ngbet normalise: matplotlib is not installed: no collapse figure (the tables are written)", file=sys.stderr
        )
        return None
    names = fabric_names([c.fabric for c in curves])
    panels = [
        (fabric, mine, spread_text(spreads(mine)))
        for fabric in dict.fromkeys(names)
        for mine in [[c for c, n in zip(curves, names, strict=True) if n == fabric]]
    ]
    fig = collapse_figure(panels, text)
    for fmt in ("png", "pdf"):
        folder.write(
            f"{FIGURE}.{fmt}",
            functools.partial(fig.savefig, format=fmt, dpi=PNG_DPI if fmt == "png" else VECTOR_RASTER_DPI),
        )
    return FIGURE + ".png"


def _report(curves: Sequence[Normalised], names: Sequence[str], text: str, out: Path, figure: str | None) -> str:
    lines = [f"ngbet normalise: {plural(len(curves), 'curve')}; tables{' and ' + figure if figure else ''} in {out}/"]
    for c, name, fabric in zip(curves, names, fabric_names([c.fabric for c in curves]), strict=True):
        g = c.gamma_deg
        at = [x for x in (20.0, 40.0) if g.min() <= x <= g.max()]
        sym = "F_sh" if c.test == "bias_extension" else "F_norm"
        vals = ", ".join(f"{sym}({x:g}°) = {np.interp(x, g, c.fsh):.3g} N/mm" for x in at)
        method = "Eq. 18" if c.test == "bias_extension" else "Eq. 10"
        label = (fabric + ", " if fabric else "") + c.label
        lines.append(
            f"  {label:>28s} ({c.test.replace('_', ' ')}): γ {g.min():.3g}–{g.max():.3g}°"
            f"{', ' + vals + ' (' + method + ')' if vals else ''} -> {name}"
        )
    lines.append(f"  {text}")
    return "\n".join(lines)
