r"""``ngbet export``: a scene's shear law as a table or a forming code's material card (docs/export.md).

The pure-shear response of the model: both yarn families keep their length (i4 = i6 = 1) and the
angle between them changes from its rest value θ0 by the shear angle γ, uniformly, so that
i8(γ) = cos(θ0 + γ) − cos θ0 (−sin γ for yarns at ±45°). The energy per unit volume is then the
shear energy alone, W(γ) = W_sh(i8(γ)), whatever the shear law (``effects.shear_law``), and

.. math::  σ_s(γ) = dW/dγ = -W_sh'(i8)\,\sin(θ_0 + γ)\quad [Pa],\qquad C_s(γ) = t\,σ_s(γ)\quad [N·mm/mm²]

are the shear stress conjugate to the shear angle (the work of a pure shear per unit volume is
∫σ_s dγ = W) and the shear torque per unit area of the fabric (Cao et al. 2008; for ±45° yarns the
normalised shear force is F_sh = C_s / cos γ). For the yarn network (``model = "discrete"``) the
rotational spring ½ K_φ Δθ² at each crossing, s² of fabric per crossing, gives σ_s = K_φ γ /(t s²).

The card tabulates σ_s at angles chosen so that its linear interpolation differs from σ_s by at
most ``tolerance`` × max(|σ_s(γ)|, 1 % of the largest stress) at every angle up to the card's
last one; the deviation is measured on a grid of 4001 angles after sampling and written into the
card. A card leaves out what its target has no place for: the second gradient (in-plane yarn
bending, α1 and α2, written as a comment), the jamming barrier, and the elongation of the yarns
where the format has no tension data (only the Abaqus card has).
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from .run_folder import OwnedFolder, json_text
from .scene.document import Scene
from .scene.validate import SceneError

__all__ = [
    "FLOOR",
    "FORMATS",
    "TENSION_STRAIN",
    "TOLERANCE",
    "WRITERS",
    "ShearCard",
    "add_parser",
    "default_max_angle_deg",
    "export",
    "log",
    "read_card",
    "rest_angle",
    "run_from_args",
    "sample",
    "shear_card",
    "shear_energy_slope",
    "shear_stress",
    "softening_angle_deg",
    "source_scene",
    "to_abaqus",
    "to_csv",
    "to_lsdyna",
]

log = logging.getLogger(__name__)

#: the formats ``ngbet export`` writes and each one's file
FORMATS = {"csv": "shear_law.csv", "abaqus": "shear_law.inp", "lsdyna": "shear_law.k"}
#: the default tolerance of the card's linear interpolation, relative to the local stress
TOLERANCE = 1e-3
#: the largest stress times this is the floor of the tolerance's reference (near γ = 0 the stress vanishes)
FLOOR = 0.01
#: the nominal strain up to which the Abaqus card tabulates the yarns' (linear) tension
TENSION_STRAIN = 0.05


@dataclass
class ShearCard:
    """The sampled pure-shear response of a scene and what a card says about it.

    ``gamma_rad`` from 0, ``stress_Pa`` = σ_s(γ), ``torque_N_per_mm`` = C_s(γ) = t σ_s [N·mm/mm²];
    ``deviation`` the largest measured |linear interpolation − σ_s| / max(|σ_s|, FLOOR·max σ_s).
    """

    gamma_rad: np.ndarray
    stress_Pa: np.ndarray
    torque_N_per_mm: np.ndarray
    tolerance: float
    deviation: float
    thickness_mm: float
    law: str
    name: str
    bending: dict[str, float] = field(default_factory=dict)  # t α_k [N·mm]: in-plane yarn bending per width
    K_el_Pa: float | None = None
    left_out: list[str] = field(default_factory=list)


def rest_angle(scene: Scene) -> float:
    """θ0 [rad], the angle between the yarn directions m1 and m2 at rest (90° for ±45° yarns)."""
    a = math.radians(scene.specimen.yarn_angle_deg)
    return math.acos(-math.cos(2.0 * a))


def _table_stress(m: Any) -> Callable[[np.ndarray], np.ndarray]:
    """τ(x), x = |i8| ≥ 0, of the tabulated law, continued linearly beyond its last knot (as the energy is)."""
    from .continuum.physics import table_stress_spline

    spl = table_stress_spline(m.shear_stress_steps_Pa, m.shear_table_i8_max)
    spl_e = type(spl)(spl.t, spl.c, spl.k, extrapolate=True)
    xm = m.shear_table_i8_max
    tau_m, k_m = float(spl_e(xm)), float(spl_e.derivative()(xm))
    return lambda x: np.where(x <= xm, spl_e(np.minimum(x, xm)), tau_m + k_m * (x - xm))


def shear_energy_slope(scene: Scene) -> Callable[[np.ndarray], np.ndarray]:
    """dW_sh/di8 [Pa] of the scene's continuum shear law as a function of i8 (odd in i8)."""
    from .continuum.physics import LOCKING_CUTOFF

    m, law = scene.material, scene.effects.shear_law
    if law == "polynomial":
        return lambda i8: m.K_sh * i8 + m.K_sh4 * i8**3 + m.K_sh6 * i8**5
    if law == "locking":
        s2 = math.sin(math.radians(m.gamma_lock_deg)) ** 2
        xc = LOCKING_CUTOFF

        def locking(i8: np.ndarray) -> np.ndarray:
            x = i8 * i8 / s2
            inside = x / (1.0 - np.minimum(x, xc))  # −(ln(1 − x))' − 1 = x/(1 − x)
            beyond = 1.0 / (1.0 - xc) + (x - xc) / (1.0 - xc) ** 2 - 1.0  # the same of the Taylor polynomial
            return cast(np.ndarray, m.K_sh * i8 + m.K_lock * i8 * np.where(x < xc, inside, beyond))

        return locking
    if law == "table":
        tau = _table_stress(m)
        return lambda i8: np.sign(i8) * tau(np.abs(i8))
    return lambda i8: m.K_sh * i8


def shear_stress(scene: Scene) -> Callable[[np.ndarray], np.ndarray]:
    """σ_s(γ) = dW/dγ [Pa] of the scene's pure shear, γ [rad] (see the module docstring)."""
    if scene.model == "discrete":
        d = scene.discrete
        per_area = d.K_phi / (scene.specimen.thickness_mm * 1e-3 * (d.spacing_mm * 1e-3) ** 2)
        return lambda g: per_area * np.asarray(g, dtype=float)
    if not scene.effects.shear:
        raise SceneError(
            "effects.shear = false: the scene has no shear energy, its pure-shear stress is 0 "
            "and there is no shear law to export; set effects.shear = true"
        )
    slope, th0 = shear_energy_slope(scene), rest_angle(scene)

    def sigma(g: np.ndarray) -> np.ndarray:
        g = np.asarray(g, dtype=float)
        i8 = np.cos(th0 + g) - math.cos(th0)
        return -slope(i8) * np.sin(th0 + g)

    return sigma


def default_max_angle_deg(scene: Scene) -> float:
    """The card's last angle [°]: where the law is defined by data or stays finite, at most 70°.

    A tabulated law up to the angle of its last knot (sin γ = ``shear_table_i8_max`` at ±45°); a
    locking law up to 1° before its locking angle; every other law (and the network) to 60°.
    The yarns of a ±45° fabric are parallel at 90°, and no law is meant that far.
    """
    th0 = rest_angle(scene)
    if scene.model == "continuum" and scene.effects.shear_law == "table":
        x = min(scene.material.shear_table_i8_max - math.cos(th0), 1.0)  # i8 = cos(θ0 + γ) − cos θ0 = −x
        g = math.degrees(math.acos(max(-1.0, min(1.0, -x))) - th0) if x > -1 else 70.0
        return float(min(70.0, max(g, 5.0)))
    if scene.model == "continuum" and scene.effects.shear_law == "locking":
        return float(min(70.0, scene.material.gamma_lock_deg - 1.0))
    return 60.0


def _reference(sig: np.ndarray, floor: float) -> np.ndarray:
    return cast(np.ndarray, np.maximum(np.abs(sig), floor))


def sample(
    sigma: Callable[[np.ndarray], np.ndarray], gamma_max: float, tolerance: float = TOLERANCE, max_points: int = 2000
) -> tuple[np.ndarray, float]:
    """Angles in [0, gamma_max] [rad] at which a linear interpolation of σ_s meets ``tolerance``.

    Intervals are halved where the interpolation misses σ_s at any of 7 inner points by more than
    ``tolerance`` × the reference (:data:`FLOOR`); returns the angles and the largest deviation
    measured on 4001 angles.
    """
    dense = np.linspace(0.0, gamma_max, 4001)
    sd = sigma(dense)
    floor = FLOOR * float(np.max(np.abs(sd))) or 1.0
    g = list(np.linspace(0.0, gamma_max, 9))
    while True:
        new = []
        for a, b in zip(g[:-1], g[1:], strict=True):
            inner = np.linspace(a, b, 9)[1:-1]
            sa, sb = sigma(np.array([a, b]))
            si = sigma(inner)
            lin = sa + (sb - sa) * (inner - a) / (b - a)
            if np.any(np.abs(lin - si) > tolerance * _reference(si, floor)):
                new.append(0.5 * (a + b))
        if not new or len(g) + len(new) > max_points:
            break
        g = sorted(g + new)
    gam = np.array(g)
    dev = float(np.max(np.abs(np.interp(dense, gam, sigma(gam)) - sd) / _reference(sd, floor)))
    if dev > tolerance:
        raise SceneError(
            f"the shear law could not be tabulated to {tolerance:g} with {max_points} points "
            f"(measured deviation {dev:.2g}); ask for a larger tolerance or a smaller angle"
        )
    return gam, dev


def shear_card(scene: Scene, max_angle_deg: float | None = None, tolerance: float = TOLERANCE) -> ShearCard:
    """The sampled pure-shear law of ``scene`` (:class:`ShearCard`) up to ``max_angle_deg``."""
    if not 0.0 < tolerance < 0.1:
        raise SceneError(f"--tolerance {tolerance:g}: must lie between 0 and 0.1 (a relative deviation)")
    gmax = default_max_angle_deg(scene) if max_angle_deg is None else float(max_angle_deg)
    limit = 180.0 - math.degrees(rest_angle(scene))
    if not 0.0 < gmax < limit:
        raise SceneError(f"--max-angle-deg {gmax:g}: must lie between 0 and {limit:g}° (the yarns are parallel there)")
    sigma = shear_stress(scene)
    gam, dev = sample(sigma, math.radians(gmax), 0.5 * tolerance)  # half: a margin for the check of the card read back
    sig = sigma(gam) + 0.0  # no −0
    t = scene.specimen.thickness_mm
    left = [
        "the second gradient: in-plane bending of the yarns (alpha1, alpha2; their t*alpha is given above)",
        "the jamming barrier (effects.jamming)",
        "the constraint phi = i8 and its multiplier",
        "the coupling of shear and yarn tension (the stress is that of a pure shear with inextensible yarns)",
    ]
    if scene.model == "discrete":
        d = scene.discrete
        s = d.spacing_mm * 1e-3
        bending = {"alpha1": d.EI1 / (t * 1e-3 * s), "alpha2": d.EI2 / (t * 1e-3 * s)}
        K_el: float | None = d.EA1 / (t * 1e-3 * s) if d.EA1 == d.EA2 else None
        law = "network: rotational crossing spring K_phi"
        left.append("slip and the yarn network's discreteness (K_slip, the spacing)")
    else:
        m = scene.material
        bending = {"alpha1": m.alpha1, "alpha2": m.alpha2}
        K_el = m.K_el if scene.effects.elongation else None
        law = {
            "quadratic": "quadratic 1/2 K_sh i8^2",
            "polynomial": "polynomial in i8",
            "locking": "locking (limiting angle)",
            "table": "tabulated B-spline of dW/d|i8|",
        }[scene.effects.shear_law]
    return ShearCard(
        gamma_rad=gam,
        stress_Pa=sig,
        torque_N_per_mm=sig * 1e-6 * t,
        tolerance=tolerance,
        deviation=dev,
        thickness_mm=t,
        law=law,
        name=scene.specimen.name,
        bending={k: v * t * 1e-3 * 1e3 for k, v in bending.items()},
        K_el_Pa=K_el,
        left_out=left,
    )


# ------------------------------------------------------------------------------------------------
# the cards
# ------------------------------------------------------------------------------------------------
def _header(card: ShearCard, c: str) -> list[str]:
    """The comment lines every card starts with, each prefixed by the format's comment mark ``c``."""
    lines = [
        f"shear law of '{card.name}' exported by ngbet: the model's pure-shear response, {card.law}",
        "shear angle gamma: the change of the angle between the yarns [rad] (0 at rest)",
        "shear stress sigma_s = dW/dgamma [MPa] (W the energy per unit volume), conjugate to gamma",
        f"torque per unit area C_s = t sigma_s [N mm/mm2], fabric thickness t = {card.thickness_mm:g} mm",
        f"linear interpolation of the {len(card.gamma_rad)} points reproduces the model's sigma_s within "
        f"{card.tolerance:g} of max(|sigma_s|, {FLOOR:g} x its largest value); measured: {card.deviation:.2g}",
        "units: mm, N, MPa (a consistent set with s and tonne)",
        "in-plane bending stiffness of the yarns per unit width, t*alpha [N mm]: "
        + ", ".join(f"{k} -> {v:.6g}" for k, v in card.bending.items()),
    ]
    if card.K_el_Pa is not None:
        lines.append(
            f"yarn elongation modulus K_el = {card.K_el_Pa * 1e-6:.6g} MPa (nominal stress per nominal strain)"
        )
    lines.append("left out of this card:")
    lines += [f"  - {w}" for w in card.left_out]
    # at most 80 characters a line (LS-DYNA's keyword format), continuation lines indented
    import textwrap

    return [
        f"{c} {part}".rstrip()
        for ln in lines
        for part in textwrap.wrap(ln, 78 - len(c), subsequent_indent="    ", break_on_hyphens=False) or [""]
    ]


def to_csv(card: ShearCard) -> str:
    """The table: comment lines, then shear_angle_deg, shear_angle_rad, shear_stress_MPa, torque_per_area_N_per_mm."""
    rows = ["shear_angle_deg,shear_angle_rad,shear_stress_MPa,torque_per_area_N_per_mm"]
    rows += [
        f"{math.degrees(g):.8g},{g:.10e},{s * 1e-6:.10e},{c:.10e}"
        for g, s, c in zip(card.gamma_rad, card.stress_Pa, card.torque_N_per_mm, strict=True)
    ]
    return "\n".join(_header(card, "#") + rows) + "\n"


def to_abaqus(card: ShearCard) -> str:
    """An Abaqus/Explicit ``*FABRIC`` block: shear loading data (stress, strain) and the yarns' tension."""
    name = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in card.name) or "fabric"
    lines = _header(card, "**") + [
        "** usage: *INCLUDE, INPUT=shear_law.inp after the fabric's *MATERIAL line",
        "** (with its *DENSITY); the yarn directions (fill and warp) come from the",
        "** section's *ORIENTATION",
        "*FABRIC",
    ]
    if card.K_el_Pa is not None:
        for comp in (1, 2):
            lines += [
                f"*UNIAXIAL, COMPONENT={comp}",
                "*LOADING DATA, DIRECTION=TENSION, TYPE=ELASTIC",
                "0., 0.",
                f"{card.K_el_Pa * 1e-6 * TENSION_STRAIN:.8e}, {TENSION_STRAIN:g}",
            ]
    lines += [
        "*UNIAXIAL, COMPONENT=SHEAR",
        "*LOADING DATA, TYPE=ELASTIC",
        "** shear stress [MPa], shear strain gamma [rad]",
    ]
    lines += [f"{s * 1e-6:.10e}, {g:.10e}" for g, s in zip(card.gamma_rad, card.stress_Pa, strict=True)]
    return f"** material {name}\n" + "\n".join(lines) + "\n"


def to_lsdyna(card: ShearCard, lcid: int = 1) -> str:
    """An LS-DYNA ``*DEFINE_CURVE_TITLE``: shear stress [MPa] against the shear angle [rad], curve ``lcid``."""
    lines = [
        "*KEYWORD",
        *_header(card, "$"),
        "$ usage: *INCLUDE this file; give the curve id to the fabric material's",
        "$ shear curve (SFA = 57.29578 if the material reads its angle in degrees)",
        "*DEFINE_CURVE_TITLE",
        f"ngbet shear stress {card.name}"[:80],
        "$     LCID      SIDR       SFA       SFO      OFFA      OFFO    DATTYP",
        f"{lcid:10d}{0:10d}{1.0:10.1f}{1.0:10.1f}{0.0:10.1f}{0.0:10.1f}{0:10d}",
        "$               gamma [rad]     shear stress [MPa]",
    ]
    lines += [f"{g:20.12e}{s * 1e-6:20.12e}" for g, s in zip(card.gamma_rad, card.stress_Pa, strict=True)]
    return "\n".join(lines) + "\n*END\n"


def softening_angle_deg(card: ShearCard) -> float | None:
    """The angle [°] of the card's largest shear stress when the stress falls after it, else None."""
    k = int(np.argmax(card.stress_Pa))
    return None if k == len(card.stress_Pa) - 1 else math.degrees(float(card.gamma_rad[k]))


WRITERS: dict[str, Callable[[ShearCard], str]] = {"csv": to_csv, "abaqus": to_abaqus, "lsdyna": to_lsdyna}


def read_card(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(γ [rad], σ_s [Pa]) read back from a card of any format :func:`export` writes (by its suffix)."""
    p = Path(path)
    text = p.read_text().splitlines()
    pairs: list[tuple[float, float]] = []
    if p.suffix == ".csv":
        rows = [ln for ln in text if ln and not ln.startswith("#")][1:]
        pairs = [(float(r.split(",")[1]), float(r.split(",")[2])) for r in rows]
    elif p.suffix == ".inp":
        at = next(i for i, ln in enumerate(text) if ln.upper().startswith("*UNIAXIAL, COMPONENT=SHEAR"))
        for ln in text[at + 2 :]:
            if ln.startswith("*") and not ln.startswith("**"):
                break
            if ln and not ln.startswith("**"):
                s, g = (float(v) for v in ln.split(","))
                pairs.append((g, s))
    elif p.suffix == ".k":
        at = next(i for i, ln in enumerate(text) if ln.upper().startswith("*DEFINE_CURVE"))
        body = [ln for ln in text[at + 1 :] if not ln.startswith("$")]
        sfa, sfo = float(body[1][20:30]), float(body[1][30:40])
        for ln in body[2:]:
            if ln.startswith("*"):
                break
            pairs.append((sfa * float(ln[:20]), sfo * float(ln[20:40])))
    else:
        raise ValueError(f"{p}: not a card ngbet writes (.csv, .inp, .k)")
    g, s = np.array(pairs).T
    return g, s * 1e6


# ------------------------------------------------------------------------------------------------
# the command
# ------------------------------------------------------------------------------------------------
def source_scene(source: str | Path) -> tuple[Path, Scene]:
    """The scene file of ``source``: a fit folder's fitted_scene.toml, or a scene file itself."""
    from .commands import load_scene

    p = Path(source)
    if p.is_dir():
        found = [p / n for n in ("fitted_scene.toml", "scene.toml") if (p / n).is_file()]
        if not found:
            raise SceneError(
                f"{p}: a folder without fitted_scene.toml (a fit's folder) or scene.toml (a run's); "
                "give a fit folder or a scene file"
            )
        p = found[0]
    elif not p.is_file():
        raise SceneError(f"{p}: no such file or folder; give a fit folder or a scene file")
    return p, load_scene(str(p), [])


def export(
    source: str | Path,
    fmt: str,
    out: str | Path,
    max_angle_deg: float | None = None,
    tolerance: float = TOLERANCE,
    plot: bool = True,
) -> dict[str, Any]:
    """Write the card of ``fmt`` (:data:`FORMATS`) for the scene of ``source`` into the folder ``out``.

    The folder is the export's own (:class:`ngbet.run_folder.OwnedFolder`: a run folder, another
    command's folder or one holding files ngbet did not write is refused with
    :class:`ngbet.run_folder.OutputError`; an earlier export's files it does not write again are
    removed at its successful end); every file is written under a temporary name and renamed.
    Besides the card: export.json (what was written, the tolerance and the deviation measured) and
    shear_law.png (the card on the law), unless ``plot`` is false or matplotlib is missing.
    Returns the summary written to export.json.
    """
    if fmt not in FORMATS:
        raise SceneError(f"--format {fmt}: must be one of {', '.join(FORMATS)}")
    path, scene = source_scene(source)
    card = shear_card(scene, max_angle_deg, tolerance)
    with OwnedFolder(Path(out), "export", "export") as folder:
        card_name = FORMATS[fmt]
        card_path = folder.write(card_name, functools.partial(Path.write_text, data=WRITERS[fmt](card)))
        g_back, s_back = read_card(card_path)
        figure = None
        if plot:
            try:
                from .figures.export import shear_law_figure
            except ImportError:
                figure = None
            else:
                folder.write("shear_law.png", lambda p: shear_law_figure(card, shear_stress(scene), scene, p))
                figure = "shear_law.png"
        falls = softening_angle_deg(card)
        if falls is not None:
            log.warning(
                "the exported shear stress falls beyond γ = %.3g° (the law's stiffening there does not make "
                "up for cos γ); a forming code may not take a softening shear curve: --max-angle-deg %.3g "
                "ends the card before it",
                falls,
                math.floor(falls),
            )
        summary = {
            "status": "ok",
            "source": str(path),
            "format": fmt,
            "card": card_name,
            "points": len(g_back),
            "stress_falls_beyond_deg": falls,
            "shear_angle_max_deg": math.degrees(float(g_back[-1])),
            "tolerance": tolerance,
            "deviation": card.deviation,
            "thickness_mm": card.thickness_mm,
            "law": card.law,
            "bending_t_alpha_Nmm": card.bending,
            "left_out": card.left_out,
            "K_el_MPa": None if card.K_el_Pa is None else card.K_el_Pa * 1e-6,
            "figure": figure,
            "files": sorted([card_name, *([figure] if figure else []), "export.json"]),
        }
        folder.write("export.json", functools.partial(Path.write_text, data=json_text(summary)))
        return summary


def add_parser(sub: Any, epilog: str = "") -> None:
    """The ``ngbet export`` subcommand."""
    pe = sub.add_parser(
        "export",
        epilog=epilog,
        help="a fit's (or any scene's) shear law as a table or a forming "
        "code's card: shear stress and torque per area against the shear angle (docs/export.md)",
    )
    pe.add_argument("source", help="a fit folder (its fitted_scene.toml) or a scene TOML file")
    pe.add_argument(
        "--format",
        dest="fmt",
        choices=tuple(FORMATS),
        default="csv",
        help="csv: a table; abaqus: an Abaqus/Explicit *FABRIC block; lsdyna: an LS-DYNA *DEFINE_CURVE (default: csv)",
    )
    pe.add_argument(
        "--out",
        default="out/export",
        help="output folder (default: out/export); a folder holding files ngbet did not write is refused",
    )
    pe.add_argument(
        "--max-angle-deg",
        type=float,
        default=None,
        metavar="DEG",
        help="the card's last shear angle (default: where the law is defined, at most 70°)",
    )
    pe.add_argument(
        "--tolerance",
        type=float,
        default=TOLERANCE,
        metavar="REL",
        help="largest deviation of the card's linear interpolation from the model's shear stress, "
        "relative to the local stress (default: 1e-3)",
    )


def run_from_args(args: Any) -> int:
    """``ngbet export``: one line naming the card, its points and tolerance; exit 0, 2 bad input, 3 unusable folder."""
    import sys

    from .commands import EXIT_INPUT, EXIT_IO, EXIT_OK, exit_code
    from .messages import say

    try:
        s = export(args.source, args.fmt, args.out, args.max_angle_deg, args.tolerance)
    except SceneError as exc:
        say(f"export: {exc}")
        return EXIT_INPUT
    except Exception as exc:
        code, msg = exit_code(exc, Path(args.out))
        say(f"export: {msg}")
        return code
    try:
        print(
            f"ngbet: {s['format']} card of {s['source']}: {s['points']} points to γ = "
            f"{s['shear_angle_max_deg']:.4g}°, within {s['tolerance']:g} of the model's shear stress (measured "
            f"{s['deviation']:.2g}); {args.out}/{s['card']}",
            file=sys.stdout,
            flush=True,
        )
    except OSError as exc:
        say(f"could not write the report to stdout ({exc.strerror or exc}); the card is in {args.out}/")
        return EXIT_IO
    return EXIT_OK
