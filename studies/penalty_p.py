"""Penalty K together with p- and h-refinement (paper, appendix A, and beyond).

For each mesh size h and order p: the Lagrange-multiplier solution and the (mixed) penalty
solution for K from about 10 K_sh to 1e12 Pa, all against the scene's reference: the one of
``ngbet study reference`` (its p-family on the corner-graded mesh runs as part of this study and is
left out of the tables), the same value every study compares with.

Two error sources, measured apart:
- penalty error: |F_K(h, p) - F_Lagrange(h, p)| on the same mesh and order (expected ∝ 1/K);
- discretization error: |F_Lagrange(h, p) - F_ref| (observed order in h, rate in dofs for p).
The total error |F_K(h, p) - F_ref| follows the penalty error until it meets the
discretization error and stays there: beyond that K, raising K buys nothing.

    python -m ngbet.studies.penalty_p [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from ngbet.figures.style import eng
from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = ["FIT_K", "FULL", "QUICK", "Grid", "analyse", "build", "main", "own_cases", "plot", "report"]


class Grid(TypedDict):
    """The cases of the study: mesh sizes, orders, penalties and the profiled case."""

    h: tuple[float, ...]
    p: tuple[int, ...]
    K: tuple[float, ...]
    profile_case: tuple[float, int]


FULL: Grid = {
    "h": (10.0, 5.0),
    "p": (1, 2, 3, 4, 5),
    "K": (2e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12),
    "profile_case": (5.0, 2),
}
QUICK: Grid = {"h": (20.0,), "p": (1, 2), "K": (1e6, 1e8, 1e9, 1e10), "profile_case": (20.0, 2)}
# penalty slopes are fitted where the penalty error is asymptotic and above round-off
FIT_K = (1e8, 1e11)


def own_cases(g: Grid) -> list[dict[str, Any]]:
    """The study's own cases: Lagrange and penalty on each (h, p)."""
    cases = []
    for h in g["h"]:
        for p in g["p"]:
            cases.append(C.lagrange(h, p))
            cases += [C.penalty(h, p, k) for k in g["K"]]
    return cases


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(
        scene, "penalty_p", "the penalty's effect on the mid-axis S-profile of the specimen, the paper's appendix A"
    )
    g = QUICK if quick else FULL
    cases = own_cases(g) + R.families(quick)["reference"]
    base = C.require_continuum(C.study_scene(scene, quick, C.FREE_ORDERS), "penalty_p")
    return Study(
        "penalty_p",
        base,
        C.unique(cases),
        description=__doc__ or "",
        plot=lambda d: plot(d, g, quick),
        report=lambda d: report(d, g, quick),
        profile_stations=C.stations(quick, base),
    )


def analyse(data: StudyData, g: Grid, quick: bool) -> dict[str, Any]:
    s1, s2 = C.stations(quick, data)
    R_ = R.reference(data, quick)
    ref = {**R_[s2], "uy_mm": R_["uy_mm"]}
    ref1 = R_[s1]
    own = own_cases(g)
    rows = []
    for c in data.meta["cases"]:
        i, prm = c["case"], c["params"]
        if prm not in own:  # the reference family: not one of the study's (h, p, K)
            continue
        h, p = prm[C.H], int(prm[C.P])
        lag_i = C.lagrange_case(data, h, p)
        F1, F2 = data.at(i, s1, "force_N"), data.at(i, s2, "force_N")
        K = prm.get(C.K, math.inf) if prm[C.CON] == "penalty" else math.inf
        r = {
            "case": i,
            "h": h,
            "p": p,
            "method": prm[C.CON],
            "K": K,
            "status": c["status"],
            "F1": F1,
            "F2": F2,
            "dofs": C.dofs(data, i),
            "its": C.total_iterations(data, i),
            "time": C.wall(data, i),
            "constraint": data.at(i, s2, "constraint_rms"),
            "err_ref": abs(F2 - ref["force_N"]) / ref["force_N"],
        }
        if lag_i is not None:
            FL = data.at(lag_i, s2, "force_N")
            r["err_pen"] = abs(F2 - FL) / FL
            r["prof_pen"] = C.profile_error(data.profile(i, s2)[1], data.profile(lag_i, s2)[1], s2)
        r["prof_ref"] = C.profile_error(data.profile(i, s2)[1], ref["uy_mm"], s2)
        rows.append(r)
    slopes, orders_h, rates_p, kstar = {}, {}, {}, {}
    for h in g["h"]:
        for p in g["p"]:
            pen = [r for r in rows if r["h"] == h and r["p"] == p and r["method"] == "penalty" and r["status"] == "ok"]
            fit = [r for r in pen if FIT_K[0] <= r["K"] <= FIT_K[1] and r.get("err_pen", 0) > 1e-10]
            slopes[(h, p)] = C.loglog_slope([r["K"] for r in fit], [r["err_pen"] for r in fit])
            lag_hp = [r for r in rows if r["h"] == h and r["p"] == p and r["method"] == "lagrange"]
            if lag_hp:
                disc = lag_hp[0]["err_ref"]
                hidden = [r["K"] for r in sorted(pen, key=lambda r: r["K"]) if r.get("err_pen", math.inf) <= 0.1 * disc]
                kstar[(h, p)] = hidden[0] if hidden else math.nan
    lag = {(r["h"], r["p"]): r for r in rows if r["method"] == "lagrange"}
    for p in g["p"]:
        hs = [h for h in g["h"] if (h, p) in lag]
        if len(hs) >= 2:
            orders_h[p] = C.loglog_slope(hs, [lag[(h, p)]["err_ref"] for h in hs])
    for h in g["h"]:
        ps = [p for p in g["p"] if (h, p) in lag]
        rates_p[h] = {
            "dofs_slope": C.loglog_slope([lag[(h, p)]["dofs"] for p in ps], [lag[(h, p)]["err_ref"] for p in ps]),
            "successive": [
                math.log(lag[(h, a)]["err_ref"] / lag[(h, b)]["err_ref"]) / math.log(b / a)
                if lag[(h, b)]["err_ref"] > 0
                else math.nan
                for a, b in itertools.pairwise(ps)
            ],
        }
    return {
        "ref": ref,
        "ref1": ref1,
        "ref1_split": "fine" in R_,
        "ref_cases": R_["cases"],
        "rows": rows,
        "slopes": slopes,
        "orders_h": orders_h,
        "rates_p": rates_p,
        "kstar": kstar,
        "stations": (s1, s2),
    }


def report(data: StudyData, g: Grid, quick: bool) -> str:
    a = analyse(data, g, quick)
    s1, s2 = a["stations"]
    ref = a["ref"]
    text = (
        f"`ngbet study reference` of this scene (p = {', '.join(map(str, R.orders(quick)))} on the "
        f"corner-graded mesh, run as part of this study): F({s1:g}) = {a['ref1']['force_N']:.4f} N "
        f"± {a['ref1']['bound_N']:.2g} N"
        + (" (the split-corner family's, from the cache)" if a["ref1_split"] else "")
        + f", F({s2:g}) = {ref['force_N']:.4f} N ± {ref['bound_N']:.2g} N."
    )
    L = [
        *C.header(data, f"Penalty K x p (x h) at u0 = {s1:g} and {s2:g} mm", text),
        "## Lagrange solutions (discretization error)",
        "",
        f"| h [mm] | p | dofs | F({s1:g}) [N] | F({s2:g}) [N] | error vs ref | profile error vs ref "
        "| Newton its | time [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted((r for r in a["rows"] if r["method"] == "lagrange"), key=lambda r: (-r["h"], r["p"])):
        L.append(
            f"| {r['h']:g} | {r['p']} | {r['dofs']:.0f} | {C.fmt(r['F1'], '.4f')} | "
            f"{C.fmt(r['F2'], '.4f')} | "
            f"{100 * r['err_ref']:.3g} % | {C.percent(r['prof_ref'])} | {r['its']} | {r['time']:.2f} |"
        )
    zero = C.zero_profile_note(ref["uy_mm"], s2)
    L += [
        *(["", zero] if zero else []),
        "",
        (
            "Observed order of the force error in h (slope of log error vs log h, per p): "
            + ", ".join(f"p={p}: {C.fmt(q, '.2f')}" for p, q in a["orders_h"].items())
            + "."
            if a["orders_h"]
            else "Observed order in h: none, the grid has one mesh size "
            f"(h = {', '.join(f'{h:g}' for h in g['h'])} mm)."
        ),
        "",
        "Rate in p (slope of log error vs log dofs at fixed h; "
        "successive p-orders log(e_p/e_p+1)/log((p+1)/p)): "
        + "; ".join(
            f"h={h:g}: {C.fmt(v['dofs_slope'], '.2f')} ({', '.join(C.fmt(x, '.2f') for x in v['successive'])})"
            for h, v in a["rates_p"].items()
        ),
        "",
        f"## Penalty error |F_K - F_Lagrange| / F_Lagrange at {s2:g} mm (same mesh and order)",
        "",
    ]
    keys = [(h, p) for h in g["h"] for p in g["p"]]
    L.append("| K [Pa] | " + " | ".join(f"h={h:g} p={p}" for h, p in keys) + " |")
    L.append("|---|" + "---|" * len(keys))
    for k in g["K"]:
        cells = []
        for h, p in keys:
            r = next((r for r in a["rows"] if r["h"] == h and r["p"] == p and r["K"] == k), None)
            cells.append("failed" if r is None or r["status"] != "ok" else f"{r.get('err_pen', math.nan):.2e}")
        L.append(f"| {k:.0e} | " + " | ".join(cells) + " |")
    L.append("| slope (K in [1e8, 1e11]) | " + " | ".join(C.fmt(a["slopes"][hp], ".3f") for hp in keys) + " |")
    L.append(
        "| K beyond which the penalty error < 1/10 of the discretization error | "
        + " | ".join(C.fmt(a["kstar"].get(hp, math.nan), ".0e") for hp in keys)
        + " |"
    )
    L += [
        "",
        f"## Constraint violation ||phi - i8|| (RMS) at {s2:g} mm, Newton iterations, time",
        *(["", "A profile error against a zero profile of the Lagrange solution is left out (—)."] if zero else []),
        "",
        "| h | p | K | ||phi-i8|| | profile err vs Lagrange | Newton its | time [s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sorted(a["rows"], key=lambda r: (-r["h"], r["p"], r["K"])):
        L.append(
            f"| {r['h']:g} | {r['p']} | {'Lagrange' if r['method'] == 'lagrange' else format(r['K'], '.0e')} | "
            f"{C.fmt(r['constraint'], '.2e')} | {C.fmt(r.get('prof_pen', math.nan), '.2e')} | {r['its']} | "
            f"{r['time']:.2f} |"
        )
    return "\n".join(L) + "\n"


def plot(data: StudyData, g: Grid, quick: bool) -> list[Path]:
    a = analyse(data, g, quick)
    styles = {h: ls for h, ls in zip(g["h"], ("-", "--", ":"), strict=False)}
    return [
        _plot_profiles(data, g, a),
        _plot_penalty_error(data, g, a, styles),
        _plot_discretization_error(data, g, a, styles),
    ]


def _plot_profiles(data: StudyData, g: Grid, a: dict[str, Any]) -> Path:
    """Mid-axis u_y at the second station for several K (the paper's figure)."""
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import colormap, legend_below, put_caption, subplots

    s2 = a["stations"][1]
    h0, p0 = g["profile_case"]
    fig, ax = subplots(size=(7, 4))
    cmap = colormap()
    pen = sorted(
        (r for r in a["rows"] if r["h"] == h0 and r["p"] == p0 and r["method"] == "penalty" and r["status"] == "ok"),
        key=lambda r: r["K"],
    )
    for j, r in enumerate(pen):
        X, uy = data.profile(r["case"], s2)
        ax.plot(X, uy, color=cmap(j / max(len(pen) - 1, 1)), label=f"penalty K = {eng(r['K'], 'Pa')}")
    lag = C.lagrange_case(data, h0, p0)
    if lag is not None:
        ax.plot(*data.profile(lag, s2), "k--", lw=2, label="Lagrange multiplier")
    ax.set_xlabel("reference position X on the mid-axis Y = W/2 [mm]")
    ax.set_ylabel("vertical displacement u_y [mm]")
    ax.set_title(f"penalty → Lagrange multiplier: mid-axis profile at u₀ = {s2:g} mm (h = {h0:g} mm, p = {p0})")
    legend_below(fig, ncol=3)
    put_caption(fig, study_caption(data.meta))
    return savefig(fig, data.out, "penalty_profiles")


def _plot_penalty_error(data: StudyData, g: Grid, a: dict[str, Any], styles: dict[float, str]) -> Path:
    """Penalty error, total error and constraint violation against K, one line per (h, p)."""
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import legend_below, put_caption, subplots

    fig, axs = subplots(1, 3, size=(15, 4.3))
    for h in g["h"]:
        for p in g["p"]:
            rs = sorted(
                (
                    r
                    for r in a["rows"]
                    if r["h"] == h and r["p"] == p and r["method"] == "penalty" and r["status"] == "ok"
                ),
                key=lambda r: r["K"],
            )
            if not rs:
                continue
            K = [r["K"] for r in rs]
            kw = {"color": f"C{p - 1}", "marker": "o", "ms": 3, "label": f"h = {h:g} mm, p = {p}"}
            axs[0].loglog(K, [max(r.get("err_pen", math.nan), 1e-16) for r in rs], styles[h], **kw)
            axs[1].loglog(K, [max(r["err_ref"], 1e-16) for r in rs], styles[h], **kw)
            lr = [r for r in a["rows"] if r["h"] == h and r["p"] == p and r["method"] == "lagrange"]
            if lr:
                axs[1].axhline(lr[0]["err_ref"], color=kw["color"], ls=styles[h], lw=0.8, alpha=0.6)
            axs[2].loglog(K, [r["constraint"] for r in rs], styles[h], **kw)
    k = np.array([1e8, 1e11])
    axs[0].loglog(k, 1e-3 * (k / 1e8) ** -1.0, "k:", lw=1, label="slope -1")
    axs[0].set_title("(a) penalty error |F_K − F_Lagrange| / F_Lagrange")
    axs[1].set_title("(b) total error |F_K − F_ref| / F_ref\n(lines: Lagrange on the same mesh = discretization error)")
    axs[2].set_title("(c) constraint violation ‖φ − i8‖ (RMS)")
    for ax in axs:
        ax.set_xlabel("penalty K [Pa]")
        ax.grid(alpha=0.3, which="both")
    axs[0].set_ylabel("relative error of the force")
    axs[1].set_ylabel("relative error of the force")
    axs[2].set_ylabel("RMS of φ − i8 [−]")
    legend_below(fig, ncol=8)
    put_caption(fig, study_caption(data.meta))
    return savefig(fig, data.out, "penalty_error")


def _plot_discretization_error(data: StudyData, g: Grid, a: dict[str, Any], styles: dict[float, str]) -> Path:
    """Discretization error of the Lagrange solutions against dofs (and against h with two mesh sizes)."""
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import put_caption, subplots

    s2 = a["stations"][1]
    # the convergence in h needs two mesh sizes (the quick grid has one: a single panel then)
    two = len(g["h"]) > 1
    fig, axs = subplots(1, 2 if two else 1, size=(11 if two else 5.5, 4.2), squeeze=False)
    axs = axs[0]
    lag = [r for r in a["rows"] if r["method"] == "lagrange" and r["status"] == "ok"]
    for h in g["h"]:
        rs = sorted((r for r in lag if r["h"] == h), key=lambda r: r["p"])
        axs[0].loglog(
            [r["dofs"] for r in rs],
            [r["err_ref"] for r in rs],
            "o" + styles[h],
            label=f"h = {h:g} mm, p = " + ", ".join(str(r["p"]) for r in rs),
        )
        for r in rs:
            axs[0].annotate(f"p{r['p']}", (r["dofs"], r["err_ref"]), fontsize=7)
    for p in g["p"] if two else ():
        rs = sorted((r for r in lag if r["p"] == p), key=lambda r: r["h"])
        if len(rs) > 1:
            axs[1].loglog(
                [r["h"] for r in rs],
                [r["err_ref"] for r in rs],
                "o-",
                color=f"C{p - 1}",
                label=f"p = {p}: order {C.fmt(a['orders_h'].get(p, math.nan), '.2f')}",
            )
    axs[0].set_xlabel("dofs")
    axs[-1].set_xlabel("h [mm]" if two else "dofs")
    for ax in axs:
        ax.set_ylabel(f"|F_Lagrange - F_ref| / F_ref at {s2:g} mm")
        ax.grid(alpha=0.3, which="both")
        ax.legend(loc="best")
    put_caption(
        fig,
        study_caption(
            data.meta,
            f"discretization error against the reference {a['ref']['force_N']:.4f} N ± {a['ref']['bound_N']:.2g} N",
        ),
    )
    return savefig(fig, data.out, "discretization_error")


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.penalty_p")


if __name__ == "__main__":
    sys.exit(main())
