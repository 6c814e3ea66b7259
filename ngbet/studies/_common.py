"""Helpers shared by the study modules: base scenes, case builders, reference solutions, fits."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ngbet.scene import Scene
from ngbet.study import MissingValueError, StudyData

H = "discretization.mesh_size_mm"
P = "discretization.order_u"
CON = "effects.constraint"
K = "effects.penalty_K"
FORM = "effects.penalty_form"


def base_scene(quick: bool = False, **changes: Any) -> Scene:
    """The paper's scene (Table 1, u0 = 56 mm, stop at 37 mm) without per-case VTK, plots and output grid.

    quick: the same specimen loaded to 20 mm with a stop at 10 mm (seconds per case).
    """
    # the studies choose their own loads (stops): no output grid
    d: dict[str, Any] = {"outputs.vtk": False, "outputs.plot": False, "loading.output_every_mm": 0.0}
    if quick:
        d.update({"loading.u0_mm": 20.0, "loading.stops_mm": [10.0]})
    d.update(changes)
    return Scene().with_changes(**d)


def stations(quick: bool) -> tuple[float, float]:
    """The two loads a study reports: (37, 56) mm, or (10, 20) mm in quick mode."""
    return (10.0, 20.0) if quick else (37.0, 56.0)


def lagrange(h: float, p: int) -> dict[str, Any]:
    return {CON: "lagrange", H: float(h), P: int(p)}


def penalty(h: float, p: int, k: float, form: str = "mixed") -> dict[str, Any]:
    return {CON: "penalty", H: float(h), P: int(p), K: float(k), FORM: form}


def unique(cases: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for c in cases:
        if c not in out:
            out.append(c)
    return out


def param(data: StudyData, case: int, key: str) -> Any:
    return data.meta["cases"][case]["params"].get(key)


def ok(data: StudyData, case: int) -> bool:
    return data.meta["cases"][case]["status"] == "ok"


def lagrange_case(data: StudyData, h: float, p: int) -> int | None:
    for c in data.find(**{CON: "lagrange", H: float(h), P: int(p)}):
        if ok(data, c):
            return c
    return None


def total_iterations(data: StudyData, case: int) -> int:
    return int(sum(float(r.get("newton_iterations") or 0) for r in data.case_rows(case)))


def wall(data: StudyData, case: int) -> float:
    w = data.meta["cases"][case].get("wall_s")
    return float(w) if w is not None else math.nan


def dofs(data: StudyData, case: int) -> float:
    d = data.meta["cases"][case].get("dofs")
    return float(d) if d is not None else math.nan


def reference(data: StudyData, u0: float, p: int, hs: Sequence[float]) -> dict[str, Any]:
    """Richardson extrapolation of the Lagrange force at ``u0`` over three meshes h, h/2, h/4 at order p.

    The observed order q = log2((F1 - F2)/(F2 - F3)) comes from the data (singular corners make it
    lower than p + 1); F_ref = F3 + (F3 - F2)/(2^q - 1); its uncertainty is taken as the size of
    the extrapolation step |F_ref - F3| (the estimate is only as good as the asymptotic range).
    The reference profile is the finest mesh's (its distance to the next mesh / (2^q - 1) is
    the estimate of its error).
    """
    cs = [lagrange_case(data, h, p) for h in hs]
    if any(c is None for c in cs):
        raise MissingValueError(f"reference cases missing or failed: p = {p}, h = {list(hs)}")
    F = [data.at(c, u0, "force_N") for c in cs]  # type: ignore[arg-type]
    if not all(math.isfinite(f) for f in F):
        raise MissingValueError(f"no reference: the force at u0 = {u0:g} mm of the reference cases {cs} "
                                f"(p = {p}, h = {list(hs)} mm) is {F}")
    d1, d2 = F[0] - F[1], F[1] - F[2]
    q = math.log2(d1 / d2) if d1 * d2 > 0 and abs(d2) > 0 else math.nan
    if math.isfinite(q) and q > 0.2:
        Fref = F[2] + (F[2] - F[1]) / (2**q - 1)
    else:
        Fref = F[2]
    X, uy = data.profile(cs[2], u0)  # type: ignore[arg-type]
    X1, uy1 = data.profile(cs[1], u0)  # type: ignore[arg-type]
    fac = 1 / (2**q - 1) if math.isfinite(q) and q > 0.2 else 1.0
    prof_unc = fac * float(np.linalg.norm(np.subtract(uy, uy1)) / max(float(np.linalg.norm(uy)), 1e-300))
    return {"force_N": Fref, "forces_N": F, "hs": list(hs), "p": p, "order": q,
            "uncertainty_N": abs(Fref - F[2]), "X_mm": X, "uy_mm": uy, "profile_uncertainty": prof_unc,
            "cases": cs}


def profile_error(X: Sequence[float], uy: Sequence[float], ref_uy: Sequence[float]) -> float:
    """Relative l2 distance of two mid-axis profiles sampled at the same X (discrete L2 norm)."""
    a, b = np.asarray(uy, float), np.asarray(ref_uy, float)
    if len(a) != len(b) or len(a) == 0:
        return math.nan
    return float(np.linalg.norm(a - b) / max(float(np.linalg.norm(b)), 1e-300))


def loglog_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log y against log x (nan with fewer than two positive points)."""
    pts = [(math.log(a), math.log(b)) for a, b in zip(x, y, strict=True) if a > 0 and b > 0 and math.isfinite(b)]
    if len(pts) < 2:
        return math.nan
    xs, ys = np.array(pts).T
    return float(np.polyfit(xs, ys, 1)[0])


def sorted_values(data: StudyData, key: str, **where: Any) -> list[Any]:
    vals = set()
    for c in data.meta["cases"]:
        p = c["params"]
        if key in p and all(p.get(k.replace("__", ".")) == v for k, v in where.items()):
            vals.add(p[key])
    return sorted(vals)


def fmt(x: float, spec: str = ".4g") -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)
