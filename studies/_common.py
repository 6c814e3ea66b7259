"""Helpers shared by the study modules: base scenes, case builders, reference solutions, fits."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ngbet.scene.document import Scene, SceneWarning, default_scene
from ngbet.scene.validate import SceneError
from ngbet.study.model import MissingValueError, StudyData

__all__ = [
    "BISECT",
    "CON",
    "FORM",
    "FREE_ORDERS",
    "GRADE",
    "H",
    "K",
    "P",
    "U0",
    "QUICK",
    "ZERO_PROFILE",
    "base_scene",
    "colormap",
    "describe_discretization",
    "describe_mesh",
    "dofs",
    "fmt",
    "graded_corners",
    "header",
    "lagrange",
    "lagrange_case",
    "loaded_to",
    "loglog_slope",
    "made_for_bias_extension",
    "mesh",
    "ok",
    "param",
    "penalty",
    "percent",
    "profile_error",
    "reference",
    "require_continuum",
    "short_log_axis",
    "sorted_values",
    "stations",
    "study_scene",
    "total_iterations",
    "unique",
    "wall",
    "zero_profile",
    "zero_profile_note",
]

H = "discretization.mesh_size_mm"
P = "discretization.order_u"
GRADE = "discretization.corner_mesh_size_mm"
BISECT = "discretization.corner_bisections"
CON = "effects.constraint"
K = "effects.penalty_K"
U0 = "loading.u0_mm"
FORM = "effects.penalty_form"

#: what ``--quick`` changes in every study's base scene: a coarse uniform mesh at p = 2, loaded
#: to 20 mm with a stop at 10 mm (seconds per case)
QUICK: dict[str, Any] = {"loading.u0_mm": 20.0, "loading.stops_mm": [10.0], H: 20.0, P: 2, GRADE: 0.0, BISECT: 0}
#: the discretization keys a study that varies the discretization sets in its base scene, so that
#: its cases (which set h, p, the corner size and bisections) are the same on any scene
FREE_ORDERS: dict[str, Any] = {
    "discretization.order_phi": "auto",
    "discretization.order_lam": "auto",
    "discretization.structured": False,
    "discretization.target_error": 0.0,
}


def base_scene(quick: bool = False, **changes: Any) -> Scene:
    """:func:`study_scene` on ngbet's default scene."""
    return study_scene(None, quick, changes)


def study_scene(scene: Scene | None, quick: bool = False, changes: dict[str, Any] | None = None) -> Scene:
    """A study's base scene.

    ``scene`` (None: :func:`ngbet.default_scene`, the paper's BET on the accurate default
    discretization) without per-case VTK, plots and output grid, with :data:`QUICK` when ``quick`` (a coarse
    mesh, loaded to 20 mm), then ``changes``.
    """
    # the studies choose their own loads (stops): no output grid
    d: dict[str, Any] = {"outputs.vtk": False, "outputs.plot": False, "loading.output_every_mm": 0.0}
    if quick:
        d.update(QUICK)
    d.update(changes or {})
    with warnings.catch_warnings():  # the study's own changes (a quick mesh on a network scene, say)
        warnings.simplefilter("ignore", SceneWarning)
        return (scene if scene is not None else default_scene()).with_changes(**d)


def stations(quick: bool, base: Scene | StudyData | None = None) -> tuple[float, float]:
    """The two loads a study reports: the base scene's first load stop and its final load.

    Without ``base``: the default scene's (37, 56) mm, or (10, 20) mm in quick mode. A scene without
    a stop below its final load reports the final load twice.
    """
    if base is None:
        return (10.0, 20.0) if quick else (37.0, 56.0)
    if isinstance(base, StudyData):
        lo = base.meta["base_scene"]["loading"]
        u0, stops = float(lo["u0_mm"]), [float(x) for x in lo["stops_mm"]]
    else:
        u0, stops = float(base.loading.u0_mm), [float(x) for x in base.loading.stops_mm]
    below = [x for x in stops if x < u0]
    return (below[0] if below else u0, u0)


def mesh(h: float, p: int, corner: float = 0.0, bisections: int = 0) -> dict[str, Any]:
    """The whole mesh of a case: size h, order p, corner grading and bisections (0: none)."""
    return {H: float(h), P: int(p), GRADE: float(corner), BISECT: int(bisections)}


def lagrange(h: float, p: int, corner: float = 0.0) -> dict[str, Any]:
    return {CON: "lagrange", **mesh(h, p, corner)}


def penalty(h: float, p: int, k: float, form: str = "mixed") -> dict[str, Any]:
    return {CON: "penalty", **mesh(h, p), K: float(k), FORM: form}


def unique(cases: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for c in cases:
        if c not in out:
            out.append(c)
    return out


def param(data: StudyData, case: int, key: str) -> Any:
    return data.meta["cases"][case]["params"].get(key)


def ok(data: StudyData, case: int) -> bool:
    return bool(data.meta["cases"][case]["status"] == "ok")


def lagrange_case(data: StudyData, h: float, p: int) -> int | None:
    """The uniform-mesh Lagrange case (h, p) when it finished ok."""
    c = data.case(lagrange(h, p))
    return c if c is not None and ok(data, c) else None


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
        raise MissingValueError(
            f"no reference: the force at u0 = {u0:g} mm of the reference cases {cs} (p = {p}, h = {list(hs)} mm) is {F}"
        )
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
    return {
        "force_N": Fref,
        "forces_N": F,
        "hs": list(hs),
        "p": p,
        "order": q,
        "uncertainty_N": abs(Fref - F[2]),
        "X_mm": X,
        "uy_mm": uy,
        "profile_uncertainty": prof_unc,
        "cases": cs,
    }


#: a profile whose largest |u_y| is at most this fraction of its load is zero (to round-off, or to
#: the mesh's asymmetry: the balanced fabric's straight mid-axis): no error is measured relative to it
ZERO_PROFILE = 1e-6


def zero_profile(ref_uy: Sequence[float] | np.ndarray, load_mm: float) -> bool:
    """Whether a profile [mm] at the load ``load_mm`` is zero: max |u_y| at most :data:`ZERO_PROFILE` of the load."""
    b = np.asarray(ref_uy, float)
    return len(b) > 0 and float(np.max(np.abs(b))) <= ZERO_PROFILE * abs(load_mm)


def zero_profile_note(ref_uy: Sequence[float], load_mm: float, what: str = "The reference profile") -> str:
    """The report's sentence for a zero profile (:func:`zero_profile`), naming its size; "" for another."""
    if not zero_profile(ref_uy, load_mm):
        return ""
    amp = float(np.max(np.abs(np.asarray(ref_uy, float))))
    return (
        f"{what} at {load_mm:g} mm is zero (max |u_y| = {amp:.2g} mm, at most {ZERO_PROFILE:g} of the load; "
        "the mid-axis stays straight, as for a balanced fabric): no profile error is measured relative to it."
    )


def profile_error(uy: Sequence[float], ref_uy: Sequence[float], load_mm: float) -> float:
    """Relative l2 distance of two mid-axis profiles at the load ``load_mm`` [mm], sampled at the same stations.

    nan when their lengths differ, they are empty, or the reference is zero (:func:`zero_profile`):
    a distance relative to a zero profile measures nothing.
    """
    a, b = np.asarray(uy, float), np.asarray(ref_uy, float)
    if len(a) != len(b) or len(a) == 0 or zero_profile(b, load_mm):
        return math.nan
    return float(np.linalg.norm(a - b) / float(np.linalg.norm(b)))


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


def percent(x: float, spec: str = ".3g") -> str:
    """A relative error as a percentage ("1.2 %"); "—" for a missing one (nan: nothing to measure it against)."""
    return "—" if x is None or not math.isfinite(x) else f"{100 * x:{spec}} %"


def describe_mesh(d: dict[str, Any], scene: dict[str, Any] | None = None) -> str:
    """A scene's discretization in words (``d``: its ``discretization`` table; ``scene``: the whole scene).

    The corners the mesh is graded at are the test's (:func:`graded_corners`; without ``scene``:
    the bias extension test's).
    """
    s = f"{'structured' if d.get('structured') else 'Netgen'} mesh of {d['mesh_size_mm']:g} mm"
    if d.get("corner_mesh_size_mm"):
        s += f" graded to {d['corner_mesh_size_mm']:g} mm at {graded_corners(scene)}"
    if d.get("corner_bisections"):
        s += f", corner elements bisected {d['corner_bisections']} times"
    return s + f", p = {d['order_u']}"


def graded_corners(scene: dict[str, Any] | None) -> str:
    """The corners a scene's mesh is graded at, in words (``discretization.corner_mesh_size_mm``).

    The bias extension specimen: its four clamp corners. The picture frame
    (:func:`ngbet.continuum.mesh.make_cross_mesh`): the four corners of the fabric square with
    held arms, every corner of the cross (the arms' ends, the cuts' corners) with sheared arms,
    the four pins when nothing is cut.
    """
    if not scene or scene.get("test") != "picture_frame":
        return "the four clamp corners"
    pf = scene["picture_frame"]
    if pf["fabric_mm"] >= pf["frame_mm"]:
        return "the four pins"
    if pf["arms"] == "held":
        return "the four corners of the fabric square"
    return "the corners of the cross (the arms' ends and the cuts' corners)"


def describe_discretization(scene: dict[str, Any], varied: Sequence[str] = ()) -> str:
    """The discretization of a study's base scene; ``varied``: the keys its cases change."""
    if scene.get("model") == "discrete":
        return f"yarn network, spacing {scene['discrete']['spacing_mm']:g} mm"
    mine = [k for k in varied if k.startswith("discretization.")]
    if mine:
        return (
            "varied by the cases ("
            + ", ".join(k.split(".", 1)[1] for k in mine)
            + "; each row of the tables names its own)"
        )
    return describe_mesh(scene["discretization"], scene)


def loaded_to(data: StudyData) -> str:
    """The final load of a study's cases in words: the base scene's, or each case's own where the cases set it.

    A picture frame's load is the crosshead travel.
    """
    base = float(data.meta["base_scene"]["loading"]["u0_mm"])
    finals = sorted({float(c["params"].get(U0, base)) for c in data.meta["cases"]})
    frame = data.meta["base_scene"].get("test") == "picture_frame"
    if len(finals) == 1:
        return f"loaded to {'a crosshead travel of ' if frame else ''}{finals[0]:g} mm"
    own = "crosshead travel" if frame else "final load"
    return f"each case loaded to its own {own} ({', '.join(f'{u:g}' for u in finals)} mm)"


def header(data: StudyData, title: str, reference: str) -> list[str]:
    """The first lines of every report.

    Title, scene and final load (:func:`loaded_to`), discretization, reference value, and what a
    quick study leaves out.
    """
    m = data.meta
    src = m.get("scene_source") or "ngbet's default scene (the paper's BET)"
    L = [
        f"# {title}",
        "",
        f"- Scene: {src}; {loaded_to(data)}.",
        f"- Discretization: {describe_discretization(m['base_scene'], m.get('params', []))}.",
        f"- Reference: {reference}",
    ]
    if m.get("quick_left_out"):
        L.append("- Quick mode, leaves out: " + "; ".join(m["quick_left_out"]) + ".")
    return [*L, ""]


def short_log_axis(ax: Any, axis: str = "x") -> None:
    """:func:`ngbet.figures.style.short_log_axis`."""
    from ngbet.figures.style import short_log_axis as sla

    sla(ax, axis)


def colormap(name: str = "viridis") -> Any:
    """:func:`ngbet.figures.style.colormap`: a sequential colour map without its palest end."""
    from ngbet.figures.style import colormap as cm

    return cm(name)


def require_continuum(base: Scene, study: str) -> Scene:
    """``base`` when it is a continuum scene; a SceneError naming the key otherwise.

    The studies that vary the mesh and the orders have nothing to vary in the yarn network.
    """
    if base.model != "continuum":
        raise SceneError(
            f"model = {base.model!r}: study {study} varies the continuum's discretization "
            "(mesh size, orders, corner grading); give model = 'continuum'"
        )
    return base


def made_for_bias_extension(scene: Scene | None, study: str, why: str) -> None:
    """Refuse ``scene`` (None: the default scene, a bias extension test) for a study made for the bias extension test.

    ``why``: what of the bias extension test the study reads, in words. A SceneError names the
    study, the scene's test, ``why`` and the studies that serve a picture frame
    (:data:`ngbet.studies.PICTURE_FRAME` and ``ngbet sweep``), before any case runs or any fit is made.
    """
    if scene is None or scene.test == "bias_extension":
        return
    from ngbet.studies import PICTURE_FRAME

    raise SceneError(
        f"test = {scene.test!r}: study {study} is made for the bias extension test only ({why}); "
        f"the studies that serve a picture frame: {', '.join(f'study {n}' for n in PICTURE_FRAME)} "
        "and ngbet sweep KEY=V1,V2,..."
    )
