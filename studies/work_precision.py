"""What accuracy costs in time: error of the force and of the mid-axis profile at 56 mm vs wall time.

Settings varied: mesh size h, order p, formulation (Lagrange multiplier; mixed penalty with K =
1e8 and 1e10 Pa; the paper's pointwise ("full") penalty with K = 1e8 Pa; the uncondensed saddle-point solve) .
Reference: the reference-grade solution of :mod:`ngbet.studies.reference` (extrapolation over
p = 4, 5, 6, 8, 9, 10 on the 20 mm mesh graded to 0.25 mm at the clamp corners, with its bound;
its cases run as part of this study and are listed apart, never compared with themselves).
Errors below the reference's bound are not resolved: flagged in the tables, drawn as open markers. The profile
error is the max-norm error of the mid-axis u_y relative to max |u_y|. A second figure plots the
error against the dofs for the uniform, corner-graded and hp families of the reference study.

Wall time is the case's whole run (mesh, assembly, Newton over all load steps, outputs without
VTK), measured with one NGSolve thread per case while the cases run two at a time on the
2-core machine (other jobs share it; expect ±20 %).

    python -m ngbet.studies.work_precision [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = [
    "FULL",
    "GRADE",
    "MARKS",
    "NAMES",
    "QUICK",
    "TARGETS",
    "analyse",
    "build",
    "cheapest",
    "kind",
    "label",
    "main",
    "plot",
    "report",
]

#: the case grids: a list of (h [mm], p[, K or corner size]) per kind
FULL: dict[str, list[tuple[Any, ...]]] = {
    "lagrange": [(h, p) for h in (20.0, 10.0, 5.0) for p in (1, 2, 3, 4, 5)] + [(2.5, p) for p in (1, 2, 3, 4)],
    "penalty": [(h, p, k) for h in (10.0, 5.0) for p in (2, 3, 4) for k in (1e8, 1e10)],
    # the pointwise penalty only at K = 1e8: at 1e10 its Newton iteration needs > 50 load steps
    # (measured: h = 10 mm, p = 3 had cut its steps 52 times by u0 = 50 mm), minutes per case
    "full": [(h, p, 1e8) for h in (10.0, 5.0) for p in (2, 3)],
    "uncondensed": [(10.0, 2), (5.0, 2)],
    # Lagrange on meshes graded towards the clamp corners (discretization.corner_mesh_size_mm); the
    # 10 mm mesh with 0.25 mm corners at p = 4 … 8 reaches 0.01 % outside the reference family
    "graded": [(h, p, c) for h in (20.0, 10.0, 5.0) for p in (2, 3) for c in (0.5, 0.25)]
    + [(10.0, p, 0.25) for p in (4, 5, 6, 7, 8)],
}
QUICK: dict[str, list[tuple[Any, ...]]] = {
    "lagrange": [(20.0, 1), (20.0, 2)],
    "penalty": [(20.0, 2, 1e8)],
    "full": [(20.0, 2, 1e10)],
    "uncondensed": [(20.0, 2)],
    "graded": [(20.0, 2, 1.0)],
}
TARGETS = (0.10, 0.01, 0.001, 0.0001)
GRADE = C.GRADE


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(
        scene,
        "work_precision",
        "the errors of the force and of the specimen's mid-axis S-profile against its reference",
    )
    g = QUICK if quick else FULL
    cases = [C.lagrange(h, p) for h, p in g["lagrange"]]
    cases += [C.penalty(h, p, k) for h, p, k in g["penalty"]]
    cases += [C.penalty(h, p, k, "full") for h, p, k in g["full"]]
    cases += [{**C.lagrange(h, p), "solver.condense": False} for h, p in g["uncondensed"]]
    cases += [C.lagrange(h, p, hc) for h, p, hc in g.get("graded", [])]
    cases = [{**c, **R.OFF} for c in cases]
    cases += [c for cs in R.families(quick).values() for c in cs]
    base = C.require_continuum(C.study_scene(scene, quick, C.FREE_ORDERS), "work_precision")
    return Study(
        "work_precision",
        base,
        C.unique(cases),
        description=__doc__ or "",
        plot=lambda d: plot(d, g, quick),
        report=lambda d: report(d, g, quick),
        profile_stations=C.stations(quick, base),
    )


def label(prm: dict[str, Any]) -> str:
    s = f"h={prm[C.H]:g} p={int(prm[C.P])} "
    if prm.get(C.CON) == "penalty":
        s += f"penalty-{prm.get(C.FORM, 'mixed')} K={prm[C.K]:.0e}"
    else:
        s += "Lagrange" + (" uncondensed" if prm.get("solver.condense") is False else "")
    if prm.get(GRADE):
        s += f" graded {prm[GRADE]:g} mm"
    return s


def kind(prm: dict[str, Any]) -> str:
    """The marker family of a case: the formulation, or the mesh for Lagrange."""
    if prm.get(C.CON) == "penalty":
        return str(prm.get(C.FORM, "mixed"))
    if prm.get("solver.condense") is False:
        return "uncondensed"
    return "graded" if prm.get(GRADE) else "lagrange"


def analyse(data: StudyData, g: dict[str, Any], quick: bool) -> dict[str, Any]:
    """Error and time of every case; the reference family's cases are marked and kept off the front."""
    s2 = C.stations(quick, data)[1]
    ref = R.reference(data, quick)
    F_ref, uy_ref = ref[s2]["force_N"], ref["uy_mm"]
    pts = []
    for c in data.meta["cases"]:
        i = c["case"]
        base = {"case": i, "label": label(c["params"]), "ref_case": i in ref["cases"]}
        if c["status"] != "ok":
            pts.append({**base, "status": c["status"]})
            continue
        F = data.at(i, s2, "force_N")
        _, uy = data.profile(i, s2)
        if not math.isfinite(F) or not uy:  # never an error or a front point from a missing value
            pts.append({**base, "status": f"no value at {s2:g} mm"})
            continue
        pts.append(
            {
                **base,
                "status": "ok",
                "kind": kind(c["params"]),
                "time": C.wall(data, i),
                "dofs": C.dofs(data, i),
                "F": F,
                "err_F": abs(F - F_ref) / F_ref,
                "err_prof": R.profile_error_max(uy, uy_ref, s2),
            }
        )
    zero = C.zero_profile(uy_ref, s2)  # no relative profile error, nor a bound of one
    unc = {
        "err_F": ref[s2]["bound_N"] / F_ref,
        "err_prof": math.nan if zero else ref["profile_bound_mm"] / max(abs(u) for u in uy_ref),
    }
    good = [p for p in pts if p["status"] == "ok" and not p["ref_case"]]
    for key in ("err_F", "err_prof"):
        best = math.inf
        for p in sorted(good, key=lambda p: p["time"]):
            p[f"pareto_{key}"] = p[key] < best
            best = min(best, p[key])
        for p in good:
            p[f"below_{key}"] = p[key] < unc[key]
    return {"ref": ref, "pts": pts, "s2": s2, "F_ref": F_ref, "unc_F": unc["err_F"], "unc_prof": unc["err_prof"]}


def cheapest(a: dict[str, Any], key: str, target: float) -> dict[str, Any] | None:
    ok = [p for p in a["pts"] if p["status"] == "ok" and p[key] <= target and not p["ref_case"]]
    return min(ok, key=lambda p: p["time"]) if ok else None


def _target_rows(a: dict[str, Any]) -> list[str]:
    L = []
    s2 = a["s2"]
    for key, name, unc in (
        ("err_F", f"force at {s2:g} mm", a["unc_F"]),
        ("err_prof", f"mid-axis profile at {s2:g} mm", a["unc_prof"]),
    ):
        if not math.isfinite(unc):  # a zero reference profile: no relative error to reach
            L.append(f"| {name} | — | not measured: the reference profile is zero | | | |")
            continue
        for t in TARGETS:
            p = cheapest(a, key, t)
            flag = " (below the reference's uncertainty: not resolved)" if t < 2 * unc else ""
            if p is not None:
                L.append(
                    f"| {name} | {100 * t:g} %{flag} | {p['label']} | {100 * p[key]:.3g} % | "
                    f"{p['time']:.2f} | {p['dofs']:.0f} |"
                )
                continue
            best = min(
                (q for q in a["pts"] if q["status"] == "ok" and not q["ref_case"]), key=lambda q: q[key], default=None
            )
            L.append(
                f"| {name} | {100 * t:g} %{flag} | not reached | best {100 * best[key]:.3g} % "
                f"({best['label']}, {best['time']:.1f} s) | | |"
                if best
                else f"| {name} | {100 * t:g} %{flag} | not reached | | | |"
            )
    return L


def _err(p: dict[str, Any], key: str) -> str:
    return C.percent(p[key]) + (" (below the bound)" if p.get(f"below_{key}") else "")


def report(data: StudyData, g: dict[str, Any], quick: bool) -> str:
    a = analyse(data, g, quick)
    s2 = a["s2"]
    ref_text = (
        f"`ngbet study reference` of this scene (p = {', '.join(map(str, R.orders(quick)))} on the "
        f"corner-graded mesh, run as part of this study): F({s2:g}) = {a['F_ref']:.4f} N, bound "
        f"{100 * a['unc_F']:.2g} %; profile: the family's highest order, "
        + (
            f"bound {100 * a['unc_prof']:.2g} % of max |u_y|."
            if math.isfinite(a["unc_prof"])
            else C.zero_profile_note(a["ref"]["uy_mm"], s2, "which")
        )
    )
    L = [
        *C.header(data, f"Work-precision at u0 = {s2:g} mm", ref_text),
        "## Cheapest settings reaching a target error",
        "",
        "| quantity | target | cheapest setting | error | wall time [s] | dofs |",
        "|---|---|---|---|---|---|",
        *_target_rows(a),
        "",
        "## All cases (the reference family apart, below)",
        "",
        "| setting | dofs | F [N] | force error | profile error | wall time [s] | Pareto (force) |",
        "|---|---|---|---|---|---|---|",
    ]
    mine = [p for p in a["pts"] if not p["ref_case"]]
    for p in sorted(mine, key=lambda p: p.get("time", math.inf)):
        if p["status"] != "ok":
            L.append(f"| {p['label']} | | {p['status']} | | | | |")
            continue
        L.append(
            f"| {p['label']} | {p['dofs']:.0f} | {p['F']:.4f} | {_err(p, 'err_F')} | {_err(p, 'err_prof')} | "
            f"{p['time']:.2f} | {'*' if p['pareto_err_F'] else ''} |"
        )
    L += [
        "",
        "## The reference family (what the reference is extrapolated from; no error against itself)",
        "",
        "| setting | dofs | F [N] | wall time [s] |",
        "|---|---|---|---|",
    ]
    for p in (p for p in a["pts"] if p["ref_case"]):
        L.append(
            f"| {p['label']} | {p.get('dofs', math.nan):.0f} | {C.fmt(p.get('F', math.nan), '.5f')} | "
            f"{C.fmt(p.get('time', math.nan), '.2f')} |"
        )
    return "\n".join(L) + "\n"


MARKS = {"lagrange": "o", "mixed": "s", "full": "^", "uncondensed": "D", "graded": "*"}
NAMES = {
    "lagrange": "Lagrange",
    "mixed": "mixed penalty",
    "full": "pointwise penalty",
    "uncondensed": "Lagrange, uncondensed",
    "graded": "Lagrange, corner-graded mesh",
}


def plot(data: StudyData, g: dict[str, Any], quick: bool) -> list[Path]:
    """Error against wall time, one colour scale (dofs) for every marker family and the colour bar.

    A point below the reference's bound is drawn at its value as an open marker inside the shaded
    band: its error is not resolved (it is at most about the bound), never clipped onto the bound.
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LogNorm
    from matplotlib.lines import Line2D

    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    a = analyse(data, g, quick)
    good = [p for p in a["pts"] if p["status"] == "ok" and not p["ref_case"]]  # not the reference against itself
    norm = LogNorm(vmin=min(p["dofs"] for p in good), vmax=max(p["dofs"] for p in good) * (1 + 1e-9))
    cmap = C.colormap()
    fig, axs = subplots(1, 2, size=(13, 5.6))
    for ax, key, unc, title in (
        (axs[0], "err_F", a["unc_F"], f"force at {a['s2']:g} mm"),
        (axs[1], "err_prof", a["unc_prof"], f"mid-axis profile at {a['s2']:g} mm"),
    ):
        if not math.isfinite(unc):  # a zero reference profile: no relative error to draw
            ax.text(
                0.5,
                0.5,
                "not measured:\nthe reference profile is zero",
                ha="center",
                va="center",
                transform=ax.transAxes,
            )
            ax.set_title(title, fontsize=9)
            ax.set_axis_off()
            continue
        floor = min([p[key] for p in good if p[key] > 0] + [unc]) / 3
        handles = []
        for kind_, m in MARKS.items():
            ps = [p for p in good if p["kind"] == kind_]
            if not ps:
                continue
            for below in (False, True):
                sel = [p for p in ps if p[f"below_{key}"] == below]
                if not sel:
                    continue
                y = [max(p[key], floor) for p in sel]
                colours = cmap(norm([p["dofs"] for p in sel]))
                ax.scatter(
                    [p["time"] for p in sel],
                    y,
                    marker=m,
                    s=40,
                    zorder=3,
                    facecolors="none" if below else colours,
                    edgecolors=colours if below else "k",
                    linewidths=1.5 if below else 0.3,
                )
            handles.append(Line2D([], [], ls="", marker=m, color="grey", markeredgecolor="k", label=NAMES[kind_]))
            for p in ps:
                if kind_ in ("lagrange", "uncondensed", "graded"):
                    prm = data.meta["cases"][p["case"]]["params"]
                    ax.annotate(
                        f"{prm[C.H]:g}/{int(prm[C.P])}",
                        (p["time"], max(p[key], floor)),
                        fontsize=6,
                        xytext=(3, 2),
                        textcoords="offset points",
                    )
        front = sorted((p for p in good if p[f"pareto_{key}"]), key=lambda p: p["time"])
        (line,) = ax.step(
            [p["time"] for p in front],
            [max(p[key], floor) for p in front],
            "r-",
            where="post",
            lw=1.2,
            label="Pareto front",
        )
        for t in TARGETS:
            ax.axhline(t, color="grey", lw=0.6, ls=":")
        band = ax.axhspan(
            floor / 3, unc, color="grey", alpha=0.15, label="below the reference's bound: not resolved (open markers)"
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(floor / 3, None)
        ax.set_xlabel("wall time of the run [s]")
        ax.set_ylabel("relative error")
        ax.set_title(title + "  (labels: h [mm]/p)", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        C.short_log_axis(ax, "x")
    legend_below(fig, [*handles, line, band], ncol=4)
    fig.colorbar(
        ScalarMappable(norm=norm, cmap=cmap), ax=axs, label="dofs (one colour scale for every marker)", shrink=0.8
    )
    put_caption(fig, study_caption(data.meta, f"reference: {a['F_ref']:.4f} N ± {a['unc_F']:.2g} (relative)"))
    return [savefig(fig, data.out, "work_precision"), _plot_dofs(data, a, quick)]


def _plot_dofs(data: StudyData, a: dict[str, Any], quick: bool) -> Path:
    """Error of the force against the dofs: uniform (algebraic), corner-graded and hp (exponential).

    Below the reference's bound (shaded) a point is drawn at its value as an open marker; a zero
    error (the reference's own last order, when the extrapolation stops there) cannot be drawn on a
    log axis and is left out, which the caption says.
    """
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    fig, ax = subplots(size=(6.5, 5.0))
    F_ref, bound = a["F_ref"], a["unc_F"]
    names = {
        "uniform": "uniform, p = 2",
        "graded": "graded, p = 2",
        "hp": "hp (corner and p together)",
        "reference": "p on the graded mesh (the reference's own family)",
    }
    errs, zero = [], 0
    for j, (name, m, ls) in enumerate(
        (("uniform", "o", "-"), ("graded", "s", "-"), ("hp", "*", "-"), ("reference", "d", ":"))
    ):
        cs = [R._case(data, prm) for prm in R.families(quick)[name]]
        pts = [(C.dofs(data, c), abs(data.at(c, a["s2"], "force_N") - F_ref) / F_ref) for c in cs if c is not None]
        zero += sum(1 for _, e in pts if e == 0)
        pts = [(n, e) for n, e in pts if e > 0]
        if not pts:
            continue
        errs += [e for _, e in pts]
        ax.loglog(*zip(*pts, strict=True), ls=ls, color=f"C{j}", lw=1)
        for below in (False, True):
            sel = [(n, e) for n, e in pts if (e < bound) == below]
            if sel:
                ax.plot(
                    *zip(*sel, strict=True),
                    m,
                    color=f"C{j}",
                    ls="",
                    mfc="none" if below else f"C{j}",
                    label=None if below else names[name],
                )
    low = min([*errs, bound]) / 3
    ax.axhspan(low, bound, color="grey", alpha=0.15, label="below the reference's bound (open markers)")
    ax.set_ylim(low, None)
    ax.set_xlabel("dofs")
    ax.set_ylabel(f"relative error of the force at {a['s2']:g} mm")
    ax.grid(alpha=0.3, which="both")
    C.short_log_axis(ax, "x")
    if zero:
        ax.set_title(f"{zero} case(s) with zero error against the reference (its own last order) not drawn", fontsize=8)
    legend_below(fig, ncol=2)
    put_caption(fig, study_caption(data.meta))
    return savefig(fig, data.out, "work_precision_dofs")


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.work_precision")


if __name__ == "__main__":
    sys.exit(main())
