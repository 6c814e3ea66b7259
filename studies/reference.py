"""Reference-grade force and profile of the paper's scene, and how fast the discretizations converge.

Reference: on the 20 mm mesh graded to 0.25 mm at the four clamp corners, the orders p = 4, 5,
6, 8, 9, 10 (:data:`REF_FAMILY`; p = 7 stops at 55.7 mm on this mesh, Newton failing near a mode
at the corner). The coarse bulk costs nothing in accuracy at these orders (the 10 mm mesh at
p = 8 gives 107.24387 N against 107.24349 N) and a quarter of the time, which is what lets the
family reach p = 10 (35 s; p = 9 stops at 48 mm on the 10 mm mesh). The differences first halve
from p to p + 1 (ratios 0.51 at 56 mm from 4 to 6) and then shrink more slowly (0.0022 N from 8
to 9 and from 9 to 10): the singular corner element turns the geometric convergence into an
algebraic one in p, and quadrature moves the force at p = 10 by 0.0006 N
(``discretization.quad_bonus = 2``). No single model of the sequence is therefore trusted:
:func:`extrapolate` fits F∞ + C r^p (geometric) and F∞ + C p^(−β) (algebraic) to the whole
sequence and to its tails from the second and third order on, and returns the middle of the
range of those limits, with half the range plus the largest fit residual as the bound.
Finer corners do not extend it: 0.1 mm at p = 5 and 0.125 mm at p = 6 stop at 46–56 mm, 0.0625 mm
at p = 4 at 38 mm, in a snap-back at the corner that arc-length continuation finds too; a larger or
p²-scaled stabilization (K_s up to 25 times the default, uncapped) does not remove it. The
reference profile is the highest order's, with the bound max|u_y,p − u_y,p−1| of the two highest.

At 37 mm the reference comes from the same 20 mm mesh graded to 1 mm, with the elements at the
four clamp corners bisected twice (``discretization.corner_bisections = 2``; :data:`FINE_FAMILY`),
at p = 6 … 14, loaded to 37 mm only (p = 10 stops at 44.9 mm on its way to 56 mm). Netgen leaves a
single triangle at each 90-degree corner, two of whose edges lie on the boundary; its size does
not follow ``corner_mesh_size_mm`` below 0.5 mm (0.41 mm at 0.25, 0.30 mm at 0.125) and the
p-sequences on such meshes end in a slow algebraic tail (0.125 mm corners: 0.00058 N from p = 12
to 14, extrapolated to 61.2123 N ± 0.0021 N). Bisected, the corner is shared by two elements of
0.53 mm, and the force at p = 12 is already below the 0.125 mm corners' at p = 14 (61.21213 N
against 61.21261 N, with 99 759 dofs against 145 449); from p = 11 on the orders differ by less
than 0.0002 N. :func:`extrapolate` gives 61.2118 N ± 0.0005 N, inside the bounds of the 0.125 mm
and 0.25 mm families. Corners split more finely stop before 37 mm at all orders tried but one
(bisected three times: 27.4 mm at p = 14; the 0.5 mm grading bisected twice: 36.0 and 27.6 mm at
p = 8 and 12, 61.21181 N at p = 10). The bound holds the 1.5e-4 N between the two corner states
one discretization can have at 37 mm: the split family's p = 14 loaded in 2 mm steps, the
unsplit p = 12 and 14 raised one order at a time at the load (docs/research/two_equilibria.py).

Checks, not part of the study: the 10 mm mesh with 0.25 mm corners at p = 4 … 8 (the family
this one replaces) extrapolates to 107.2375 N (its own bound 0.0052 N); at p = 6 halving the
corner from 1 to 0.5 to 0.25 mm halves the change of the force, but 0.125 mm changes it by a
seventh only (37 mm: 61.2248, 61.2432, 61.2243, 61.2218 N), so the corner size is no better a
convergence parameter than p.

Convergence (error against the reference, vs dofs): uniform meshes at p = 2 (h = 20, 10, 5 mm:
algebraic, the force like h^1.1), corner-graded at p = 2 (corner 2.5 … 0.25 mm: saturates at
the bulk error), and hp (corner and order together: (2.5 mm, 2), (1, 3), (0.5, 4), (0.25, 5)),
whose error falls exponentially in the cube root of the dofs: the report fits log e against
N^(1/3) and against log N and says which fits better.

    python -m ngbet.studies.reference [--quick] [--workers N] [--plot-only]
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.scene.document import Scene, SceneWarning
from ngbet.study.cache import CacheError, verify_case
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.keys import case_key
from ngbet.study.model import MissingValueError, Study, StudyData
from ngbet.tables import read_rows

from . import _common as C

__all__ = [
    "BISECT",
    "FINE_BISECTIONS",
    "FINE_FAMILY",
    "GRADE",
    "GRADED_P2",
    "HP_FAMILY",
    "OFF",
    "QUICK_REF",
    "REF_FAMILY",
    "REF_H",
    "UNIFORM_P2",
    "aitken",
    "analyse",
    "build",
    "extrapolate",
    "families",
    "fine_family",
    "fits",
    "graded",
    "main",
    "of_scene",
    "orders",
    "plot",
    "profile_error_max",
    "reference",
    "reference_text",
    "report",
]

GRADE = C.GRADE
BISECT = C.BISECT
OFF = {"outputs.error_estimate": "off"}
#: (corner size [mm], p) on the :data:`REF_H` mesh (p = 7 stops at 55.7 mm there)
REF_FAMILY = tuple((0.25, p) for p in (4, 5, 6, 8, 9, 10))
REF_H = 20.0
#: (corner size [mm], p) on the :data:`REF_H` mesh with the corners bisected :data:`FINE_BISECTIONS`
#: times, loaded to the first station only, where it gives the reference (it stops before 56 mm)
FINE_FAMILY = tuple((1.0, p) for p in range(6, 15))
FINE_BISECTIONS = 2
HP_FAMILY = ((2.5, 2), (1.0, 3), (0.5, 4), (0.25, 5))
GRADED_P2 = ((2.5, 2), (1.0, 2), (0.5, 2), (0.25, 2))
UNIFORM_P2 = (20.0, 10.0, 5.0)
QUICK_REF = ((0.5, 2), (0.5, 3), (0.5, 4))


def graded(c: float, p: int, h: float = 10.0) -> dict[str, Any]:
    return {**C.lagrange(h, p, c), **OFF}


def families(quick: bool) -> dict[str, list[dict[str, Any]]]:
    if quick:
        return {
            "reference": [graded(c, p, 20.0) for c, p in QUICK_REF],
            "uniform": [{**C.lagrange(20.0, 2), **OFF}],
            "graded": [],
            "hp": [graded(2.5, 2, 20.0)],
        }
    return {
        "reference": [graded(c, p, REF_H) for c, p in REF_FAMILY],
        "uniform": [{**C.lagrange(h, 2), **OFF} for h in UNIFORM_P2],
        "graded": [graded(c, p) for c, p in GRADED_P2],
        "hp": [graded(c, p) for c, p in HP_FAMILY],
    }


def fine_family(quick: bool, s1: float = 37.0) -> list[dict[str, Any]]:
    """The cases of :data:`FINE_FAMILY`, loaded to the first station ``s1`` only (none in quick mode)."""
    to_s1 = {"loading.u0_mm": float(s1), "loading.stops_mm": []}
    return [] if quick else [{**graded(c, p, REF_H), BISECT: FINE_BISECTIONS, **to_s1} for c, p in FINE_FAMILY]


def orders(quick: bool) -> list[int]:
    """The orders p of the reference family."""
    return [p for _, p in (QUICK_REF if quick else REF_FAMILY)]


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(
        scene, "reference", "meshes graded at the specimen's four clamp corners, the mid-axis S-profile"
    )
    base = C.require_continuum(C.study_scene(scene, quick, C.FREE_ORDERS), "reference")
    fam = families(quick)
    cases = C.unique([c for cs in fam.values() for c in cs] + fine_family(quick, C.stations(quick, base)[0]))
    return Study(
        "reference",
        base,
        cases,
        description=__doc__ or "",
        plot=lambda d: plot(d, quick),
        report=lambda d: report(d, quick),
        profile_stations=C.stations(quick, base),
    )


def aitken(F: Sequence[float]) -> tuple[float, float]:
    """Limit of a geometrically converging sequence from its last three terms, and a bound.

    The bound is 2 |F∞ − F_last|; when the differences do not shrink, the last term itself and
    |F_last − F_prev| are returned.
    """
    f1, f2, f3 = (float(x) for x in F[-3:])
    d1, d2 = f2 - f1, f3 - f2
    if d1 == 0 or d2 / d1 <= 0 or abs(d2 / d1) >= 1:
        return f3, abs(d2)
    lim = f3 - d2 * d2 / (d2 - d1)
    return lim, 2 * abs(lim - f3)


def extrapolate(F: Sequence[float], orders: Sequence[int] | None = None) -> tuple[float, float]:
    """The limit of a p-sequence of forces and its bound, from every extrapolation it supports.

    With four terms or more: least-squares fits of F∞ + C r^p (geometric) and F∞ + C p^(−β)
    (algebraic in p) to the whole sequence, to its tails from the second and third term on, and
    to its last five and last four terms (the orders need not be consecutive). Returns the middle
    of the range of their limits and half that range plus the largest fit residual; with three
    terms, Aitken's limit and bound (:func:`aitken`). The last terms matter for long sequences:
    a fixed corner mesh turns geometric convergence in p into algebraic convergence, which only
    the highest orders show.
    """
    F = [float(x) for x in F]
    if len(F) < 4:
        return aitken(F)
    p = np.asarray(orders if orders is not None else range(1, len(F) + 1), float)
    lims: list[float] = []
    resid = 0.0
    starts = sorted({s for s in (0, 1, 2, len(F) - 5, len(F) - 4) if 0 <= s <= len(F) - 4})
    for start in starts:
        for lim, res in _fits(p[start:], F[start:]):
            lims.append(lim)
            resid = max(resid, res)
    if not lims:
        return aitken(F)
    lo, hi = min(lims), max(lims)
    return 0.5 * (lo + hi), 0.5 * (hi - lo) + resid


def _fits(p: np.ndarray, F: Sequence[float]) -> list[tuple[float, float]]:
    """(limit, largest residual) of the geometric and of the algebraic least-squares fit.

    Each model is started from several rates (r = 0.3, 0.5, 0.7; β = 1 … 4) and its best fit kept.
    """
    import warnings

    from scipy.optimize import OptimizeWarning, curve_fit

    y = np.asarray(F, float)
    out = []
    models: tuple[tuple[Callable[..., Any], tuple[float, ...]], ...] = (
        (lambda q, a, c, r: a + c * r**q, (0.3, 0.5, 0.7)),
        (lambda q, a, c, b: a + c * q ** (-b), (1.0, 2.0, 3.0, 4.0)),
    )
    for f, rates in models:
        best: tuple[float, float] | None = None
        for rate in rates:
            c0 = (y[0] - y[-1]) / max(abs(f(p[0], 0.0, 1.0, rate) - f(p[-1], 0.0, 1.0, rate)), 1e-300)
            try:
                with warnings.catch_warnings():  # only the coefficients are used, not their covariance
                    warnings.simplefilter("ignore", OptimizeWarning)
                    coef, _ = curve_fit(f, p, y, p0=(y[-1], c0, rate), maxfev=20000)
            except RuntimeError:
                continue
            res = float(np.max(np.abs(f(p, *coef) - y)))
            if np.all(np.isfinite(coef)) and (best is None or res < best[1]):
                best = (float(coef[0]), res)
        if best is not None:
            out.append(best)
    return out


def _case(data: StudyData, prm: dict[str, Any]) -> int | None:
    """The case with exactly the parameters ``prm``, when it finished ok."""
    c = data.case(prm)
    return c if c is not None and C.ok(data, c) else None


def reference(data: StudyData, quick: bool = False) -> dict[Any, Any]:
    """The scene's reference force at both stations with its bound, and the reference profile.

    ``out[s]`` is the reference at the station ``s``: the corner-graded p-family's extrapolation,
    at the first station that of the split-corner family (:data:`FINE_FAMILY`) when its cases are in
    the study or in the cache (the same value whichever study asks). ``out["family"][s]``: the
    corner-graded family's own extrapolation at every station.
    """
    fam = families(quick)["reference"]
    cs = [_case(data, p) for p in fam]
    missing = [p for p, c in zip(fam, cs, strict=True) if c is None]
    if missing:
        raise MissingValueError(
            "reference cases missing or failed (no reference from an incomplete family): "
            + "; ".join(", ".join(f"{k}={v}" for k, v in p.items()) for p in missing)
        )
    out: dict[Any, Any] = {"cases": cs, "family": {}}
    for s in C.stations(quick, data):
        forces = [data.at(c, s, "force_N") for c in cs]  # type: ignore[arg-type]
        if not all(math.isfinite(f) for f in forces):
            raise MissingValueError(
                f"no reference: the force at u0 = {s:g} mm of the reference cases {cs} is "
                f"{forces} (a case stopped before that load)"
            )
        F, bound = extrapolate(forces, orders(quick))
        out["family"][s] = out[s] = {"force_N": F, "bound_N": bound, "forces_N": forces}
    s1, s2 = C.stations(quick, data)
    X, uy = data.profile(cs[-1], s2)  # type: ignore[arg-type]
    _, uy5 = data.profile(cs[-2], s2)  # type: ignore[arg-type]
    out["X_mm"], out["uy_mm"] = list(X), list(uy)
    out["profile_bound_mm"] = float(np.max(np.abs(np.subtract(uy, uy5))))
    fine = [_case(data, p) for p in fine_family(quick, s1)]
    if fine and all(c is not None for c in fine):  # the reference study runs them
        forces = [data.at(c, s1, "force_N") for c in fine]  # type: ignore[arg-type]
    else:  # the other studies find them in the cache when the reference study ran on this scene
        forces = _cached_forces(data, fine_family(quick, s1), (s1,)).get(s1, [])
    if forces and all(math.isfinite(f) for f in forces):
        F, bound = extrapolate(forces, [p for _, p in FINE_FAMILY])
        out["fine"] = out[s1] = {"force_N": F, "bound_N": bound, "forces_N": forces, "station": s1}
    return out


def _cached_forces(data: StudyData, cases: list[dict[str, Any]], stations: Sequence[float]) -> dict[float, list[Any]]:
    """The forces of ``cases`` over the study's base scene at ``stations``, from the cache; {} if one is missing.

    Found by their cache keys and verified like any cached case: a reference is never computed
    from an incomplete or damaged family.
    """
    cache = data.meta.get("cache")
    if not cache or not cases:
        return {}
    with warnings.catch_warnings():  # the base was warned about where it was read
        warnings.simplefilter("ignore", SceneWarning)
        base = Scene.from_dict(data.meta["base_scene"]).with_changes(**C.FREE_ORDERS)
        dirs = [Path(cache) / case_key(base.with_changes(**prm)) for prm in cases]
    forces: dict[float, list[float]] = {s: [] for s in stations}
    for run_dir in dirs:
        try:
            if verify_case(run_dir)["status"] != "ok":
                return {}
        except CacheError:
            return {}
        rows = read_rows(run_dir / "results.csv")
        for s in stations:
            forces[s] += [float(r["force_N"]) for r in rows if abs(float(r["u0_mm"]) - s) < 1e-6]
    return forces if all(len(v) == len(cases) for v in forces.values()) else {}


def of_scene(data: StudyData, quick: bool) -> dict[float, dict[str, float]] | None:
    """The reference of a study's base scene from the reference cases in its cache, or None.

    The cases are those :func:`build` runs for the same scene, the values those of :func:`reference`
    (at the first station the split-corner family's when it is cached). None when a case of the
    corner-graded family is missing, failed or damaged.
    """
    s1, s2 = C.stations(quick, data)
    forces = _cached_forces(data, families(quick)["reference"], (s1, s2))
    if not forces:
        return None
    out = {}
    for s, F in forces.items():
        f, bound = extrapolate(F, orders(quick))
        out[s] = {"force_N": f, "bound_N": bound}
    fine = _cached_forces(data, fine_family(quick, s1), (s1,))
    if fine:
        f, bound = extrapolate(fine[s1], [p for _, p in FINE_FAMILY])
        out[s1] = {"force_N": f, "bound_N": bound}
    return out


def reference_text(data: StudyData, quick: bool) -> str:
    """The reference line of a report for a study that does not compute the reference itself.

    With the reference found, the deviation of the study's own case of the base scene (the case
    whose changes leave the base as it is), when it has one: the error of its discretization. A
    picture frame has none (the reference study is made for the bias extension test).
    """
    if data.meta["base_scene"].get("test") == "picture_frame":
        return "none: the reference study is made for the bias extension test."
    ref = of_scene(data, quick)
    if ref is None:
        lo = data.meta["base_scene"]["loading"]
        stops = ", ".join(f"{x:g}" for x in lo["stops_mm"])
        cache = data.meta.get("cache")
        return (
            f"none in the cache for this study's base scene loaded to {lo['u0_mm']:g} mm "
            f"({f'stops: {stops} mm' if stops else 'no stops'}); "
            f"`ngbet study reference{' --quick' if quick else ''}` on that scene, with this study's cache"
            f"{f' (`--cache {cache}`)' if cache else ''}, computes it, and this report then names it."
        )
    text = (
        "`ngbet study reference` of this scene (from the cache): "
        + ", ".join(f"F({s:g} mm) = {r['force_N']:.4f} N ± {r['bound_N']:.2g} N" for s, r in ref.items())
        + "."
    )
    if data.meta["base_scene"].get("effects", {}).get("constraint") != "lagrange":
        text += " It is the limit of the exact constraint (Lagrange multiplier), which the reference family uses."
    base = _base_case(data)
    if base is not None:
        devs = [(s, data.at(base, s, "force_N"), r["force_N"]) for s, r in ref.items()]
        devs = [(s, F, R0) for s, F, R0 in devs if math.isfinite(F)]
        if devs:
            text += (
                f" The base scene's case of this study (case {base}) is off by "
                + ", ".join(f"{100 * (F - R0) / R0:+.2g} % at {s:g} mm" for s, F, R0 in devs)
                + "."
            )
    return text


def _base_case(data: StudyData) -> int | None:
    """The ok case whose parameters are the base scene's own values (None when no case is)."""
    base = data.meta["base_scene"]
    for c in data.cases():
        if c["status"] != "ok":
            continue
        same = True
        for key, v in c["params"].items():
            section, _, name = key.partition(".")
            have = base.get(section, {}).get(name) if name else base.get(section)
            same = (
                same
                and have is not None
                and (
                    have == v
                    or (
                        isinstance(v, (int, float))
                        and not isinstance(v, bool)
                        and isinstance(have, (int, float))
                        and math.isclose(float(have), float(v), rel_tol=1e-12)
                    )
                )
            )
        if same:
            return int(c["case"])
    return None


def profile_error_max(uy: Sequence[float], ref: Sequence[float], load_mm: float) -> float:
    """max|u_y − u_y,ref| / max|u_y,ref| on the mid-axis at the load ``load_mm`` [mm].

    nan when the lengths differ, or the reference is zero (:func:`~ngbet.studies._common.zero_profile`).
    """
    a, b = np.asarray(uy, float), np.asarray(ref, float)
    if len(a) != len(b) or len(a) == 0 or C.zero_profile(b, load_mm):
        return math.nan
    return float(np.max(np.abs(a - b)) / float(np.max(np.abs(b))))


def fits(dofs: Sequence[float], err: Sequence[float]) -> dict[str, float]:
    """Least-squares fits of log e against N^(1/3) (exponential) and against log N (algebraic).

    Returns the rate and the RMS residual of each.
    """
    N, e = np.asarray(dofs, float), np.log(np.asarray(err, float))
    out: dict[str, float] = {}
    for name, x in (("root", N ** (1 / 3)), ("log", np.log(N))):
        coef, res, *_ = np.polyfit(x, e, 1, full=True)
        out[f"{name}_rate"] = float(coef[0])
        out[f"{name}_rms"] = float(math.sqrt(res[0] / len(e))) if len(res) else 0.0
    return out


def analyse(data: StudyData, quick: bool) -> dict[str, Any]:
    ref = reference(data, quick)
    s2 = C.stations(quick, data)[1]
    F0 = ref[s2]["force_N"]
    fam: dict[str, list[dict[str, Any]]] = {}
    for name, cases in families(quick).items():
        pts = []
        for prm in cases:
            c = _case(data, prm)
            if c is None:
                continue
            F = data.at(c, s2, "force_N")
            _, uy = data.profile(c, s2)
            pts.append(
                {
                    "case": c,
                    "dofs": C.dofs(data, c),
                    "F": F,
                    "err": abs(F - F0) / F0,
                    "time": C.wall(data, c),
                    "err_prof": profile_error_max(uy, ref["uy_mm"], s2),
                    "corner": prm.get(GRADE, 0.0),
                    "h": prm[C.H],
                    "p": prm[C.P],
                }
            )
        fam[name] = pts
    hp = [p for p in fam["hp"] if p["case"] not in ref["cases"]]
    return {
        "ref": ref,
        "fam": fam,
        "s2": s2,
        "hp_fit": fits([p["dofs"] for p in hp], [p["err"] for p in hp]) if len(hp) >= 3 else {},
    }


def report(data: StudyData, quick: bool) -> str:
    a = analyse(data, quick)
    ref = a["ref"]
    orders = [p for _, p in (QUICK_REF if quick else REF_FAMILY)]
    L = [
        *C.header(
            data,
            "Reference-grade solution of the scene",
            "computed here (below): "
            + ", ".join(
                f"F({s:g} mm) = {ref[s]['force_N']:.4f} N ± {ref[s]['bound_N']:.2g} N" for s in C.stations(quick, data)
            )
            + ".",
        ),
        f"The {REF_H if not quick else 20.0:g} mm mesh graded at the clamp corners, "
        f"p = {', '.join(map(str, orders))}: the middle of the "
        "range of the extrapolations (geometric and algebraic fits in p to the sequence and its tails); "
        "bound = half that range plus the largest fit residual.",
        "",
        "| u0 [mm] | " + " | ".join(f"F(p={p}) [N]" for p in orders) + " | reference [N] | bound [N] | bound [%] |",
        "|---|" + "---|" * len(orders) + "---|---|---|",
    ]
    for s in C.stations(quick, data):
        r = ref["family"][s]
        L.append(
            f"| {s:g} | "
            + " | ".join(f"{f:.5f}" for f in r["forces_N"])
            + f" | {r['force_N']:.5f} | {r['bound_N']:.2g} | {100 * r['bound_N'] / r['force_N']:.2g} |"
        )
    fine = ref.get("fine")
    if fine:
        L += [
            "",
            f"At {fine['station']:g} mm the reference is that of 1 mm corners bisected {FINE_BISECTIONS} "
            f"times (two elements share each corner), loaded to {fine['station']:g} mm only, p = "
            f"{', '.join(str(p) for _, p in FINE_FAMILY)}: "
            + ", ".join(f"{f:.5f}" for f in fine["forces_N"])
            + f" N: **{fine['force_N']:.5f} N ± {fine['bound_N']:.2g} N** "
            f"(the 0.25 mm family above: {ref['family'][fine['station']]['force_N']:.5f} N ± "
            f"{ref['family'][fine['station']]['bound_N']:.2g} N).",
        ]
    L += [
        "",
        f"Reference profile (p = {orders[-1]}) at {a['s2']:g} mm: "
        f"max |u_y| = {np.max(np.abs(ref['uy_mm'])):.4f} mm, bound {ref['profile_bound_mm']:.2g} mm."
        + (f" {zero}" if (zero := C.zero_profile_note(ref["uy_mm"], a["s2"])) else ""),
        "",
        "## Convergence at the second station",
        "",
        "| family | h [mm] | corner [mm] | p | dofs | F [N] | force error | profile error (max) | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, pts in a["fam"].items():
        for p in pts:
            L.append(
                f"| {name} | {p['h']:g} | {p['corner']:g} | {p['p']} | {p['dofs']:.0f} | {p['F']:.4f} | "
                f"{100 * p['err']:.3g} % | {C.percent(p['err_prof'])} | {p['time']:.2f} |"
            )
    f = a["hp_fit"]
    if f:
        better = "N^(1/3) (exponential)" if f["root_rms"] < f["log_rms"] else "log N (algebraic)"
        L += [
            "",
            f"hp family (reference cases excluded): log e against N^(1/3): rate {f['root_rate']:.3f}, "
            f"RMS residual "
            f"{f['root_rms']:.3f}; against log N: rate {f['log_rate']:.2f}, RMS residual {f['log_rms']:.3f}. "
            f"Better fit: {better}.",
        ]
    return "\n".join(L) + "\n"


def plot(data: StudyData, quick: bool) -> list[Path]:
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    a = analyse(data, quick)
    fig, ax = subplots(size=(6.5, 5.0))
    r2 = a["ref"][a["s2"]]
    bound = r2["bound_N"] / r2["force_N"]
    names = {"uniform": "uniform mesh, p = 2", "graded": "corner-graded, p = 2", "hp": "hp (corner and p together)"}
    for j, (name, m) in enumerate((("uniform", "o"), ("graded", "s"), ("hp", "*"))):
        pts = [p for p in a["fam"][name] if p["err"] > 0]
        if not pts:
            continue
        ax.loglog([p["dofs"] for p in pts], [p["err"] for p in pts], "-", color=f"C{j}", lw=1)
        for below in (False, True):  # below the bound: open markers, the error is not resolved there
            sel = [p for p in pts if (p["err"] < bound) == below]
            ax.plot(
                [p["dofs"] for p in sel],
                [p["err"] for p in sel],
                m,
                color=f"C{j}",
                ls="",
                mfc="none" if below else f"C{j}",
                label=None if below else names[name],
            )
    low = min([p["err"] for name in names for p in a["fam"][name] if p["err"] > 0] + [bound]) / 3
    ax.axhspan(low, bound, color="grey", alpha=0.15, label="below the reference's bound (open markers: not resolved)")
    ax.set_ylim(low, None)
    ax.set_title(f"reference F({a['s2']:g} mm) = {r2['force_N']:.4f} N ± {r2['bound_N']:.2g} N", fontsize=9)
    ax.set_xlabel("dofs")
    ax.set_ylabel(f"relative error of the force at {a['s2']:g} mm")
    ax.grid(alpha=0.3, which="both")
    legend_below(fig, ncol=2)
    put_caption(fig, study_caption(data.meta))
    return [savefig(fig, data.out, "reference_convergence")]


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.reference")


if __name__ == "__main__":
    sys.exit(main())
