"""Continuum and discrete model side by side on the same specimen.

The same scene runs once with model = "continuum" (Lagrange, h = 5 mm, p = 2) and once with
model = "discrete" (paper Table 2, yarn spacing from the scene), and a third time as the network
equivalent to the continuum (its energy per unit area; ngbet.discrete.equivalent). Figures: the
force-displacement curves (with the ideal-kinematics estimate), the mid-axis profiles at 37
and 56 mm, and the maps (continuum, Table 2 network) of the shear angle γ at 37 and 56 mm (0 at
rest, the change of the angle between the yarns; the same convention in both models). The study shows whatever the
models give; the report states whether they bend the specimen the same way (sign of u_y at
X = L/4 on the mid-axis).

    python -m ngbet.studies.compare [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import math
import shutil
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.kinematics import ideal_force
from ngbet.scene.document import Scene, SceneWarning
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = [
    "CASES",
    "EQUIVALENT",
    "LABELS",
    "STRAIGHT",
    "analyse",
    "bending_direction",
    "build",
    "extract",
    "label",
    "main",
    "plot",
    "report",
]

CASES: list[dict[str, Any]] = [
    {"model": "continuum", "outputs.vtk": True, "outputs.vtk_every_step": True},
    {"model": "discrete"},
]
# the network with the continuum's energy per unit area (ngbet.discrete.equivalent): the check
# that the two models agree where their physics is the same
EQUIVALENT = "discrete, continuum-equivalent"
LABELS = ("continuum", "discrete", EQUIVALENT)


def label(params: dict[str, Any]) -> str:
    """Which of the three models a case is (its changes over the base scene)."""
    if params.get("model") == "continuum":
        return "continuum"
    return EQUIVALENT if "discrete.K_phi" in params else "discrete"


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    from ngbet.discrete.equivalent import continuum_equivalent

    C.made_for_bias_extension(scene, "compare", "the yarn network, which has no frame, beside the continuum")

    with warnings.catch_warnings():  # a base for both models: each reads its own keys
        warnings.simplefilter("ignore", SceneWarning)
        base = C.study_scene(scene, quick, {"discrete.spacing_mm": 10.0} if quick else {})
    equivalent = {"model": "discrete", **continuum_equivalent(base)}
    return Study(
        "compare",
        base,
        [*CASES, equivalent],
        description=__doc__ or "",
        extract=extract,
        plot=lambda d: plot(d, quick),
        report=lambda d: report(d, quick),
        profile_stations=C.stations(quick, base),
    )


def extract(rec: dict[str, Any], run_dir: Path, out: Path) -> dict[str, Any]:
    sc = rec["scene"]
    rows = []
    for u0 in (*sc["loading"]["stops_mm"], sc["loading"]["u0_mm"]):
        if sc["model"] == "continuum":
            from .maps import step_vtu

            src = step_vtu(run_dir, u0)
            name = f"continuum_{u0:g}mm.vtu"
        else:
            src = run_dir / f"state_{u0:.0f}mm.npz"
            tag = "equivalent" if sc["discrete"]["K_inter"] == 0 else "discrete"
            name = f"{tag}_{u0:g}mm.npz"
        if src is not None and src.exists():
            shutil.copyfile(src, out / name)
            rows.append({"model": name.split("_")[0], "u0_mm": u0, "file": name})
    return {"fields": rows}


def _case(data: StudyData, model: str) -> int | None:
    for c in data.meta["cases"]:
        if label(c["params"]) == model:
            return int(c["case"])
    return None


def analyse(data: StudyData, quick: bool) -> dict[str, Any]:
    s1, s2 = C.stations(quick, data)
    L = data.meta["base_scene"]["specimen"]["length_mm"]
    res = {}
    for m in LABELS:
        i = _case(data, m)
        if i is None:
            continue
        r = {
            "case": i,
            "status": data.meta["cases"][i]["status"],
            "wall_s": C.wall(data, i),
            "u0_reached": data.meta["cases"][i].get("u0_reached_mm"),
        }
        for s in (s1, s2):
            X, uy = data.profile(i, s)
            r[f"F{s:g}"] = data.at(i, s, "force_N")
            r[f"uyq{s:g}"] = float(np.interp(L / 4, X, uy)) if X else math.nan
            r[f"maxuy{s:g}"] = float(np.max(np.abs(uy))) if X else math.nan
        rows = data.case_rows(i)
        slips = [q["max_slip_mm"] for q in rows if isinstance(q.get("max_slip_mm"), float)]
        if slips:
            r["max_slip_mm"] = max(slips)
        res[m] = r
    return res


def report(data: StudyData, quick: bool) -> str:
    s1, s2 = C.stations(quick, data)
    a = analyse(data, quick)
    L = [
        *C.header(data, "Continuum and discrete model side by side", R.reference_text(data, quick)),
        f"| model | status | F({s1:g}) [N] | F({s2:g}) [N] | u_y(L/4) at {s1:g} mm [mm] "
        f"| u_y(L/4) at {s2:g} mm [mm] | max abs(u_y) at {s2:g} mm [mm] | largest slip [mm] | wall time [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m, r in a.items():
        L.append(
            f"| {m} | {r['status']} (to {C.fmt(r['u0_reached'], 'g')} mm) | {C.fmt(r[f'F{s1:g}'], '.3f')} | "
            f"{C.fmt(r[f'F{s2:g}'], '.3f')} | {C.fmt(r[f'uyq{s1:g}'], '.3f')} | {C.fmt(r[f'uyq{s2:g}'], '.3f')} | "
            f"{C.fmt(r[f'maxuy{s2:g}'], '.3f')} | "
            f"{C.fmt(r.get('max_slip_mm', math.nan), '.3f')} | {r['wall_s']:.1f} |"
        )
    if "continuum" in a:
        for m in ("discrete", EQUIVALENT):
            if m in a:
                L += ["", bending_direction(a["continuum"], a[m], m, s2)]
    L += [
        "",
        f"'{EQUIVALENT}': the network whose stiffnesses give the continuum's energy per unit area "
        "(EA = t K_el s, EI_k = t alpha_k s, K_phi = t K_sh s^2, no slip, no trusses; ngbet.discrete.equivalent).",
    ]
    return "\n".join(L) + "\n"


#: |u_y(L/4)| below this fraction of the load: no bending of the mid-axis to compare
STRAIGHT = 1e-6


def bending_direction(cont: dict[str, Any], other: dict[str, Any], model: str, s2: float) -> str:
    """The report's sentence on the bending direction at ``s2`` of the continuum and ``model`` (:func:`analyse` rows).

    A direction is compared only between two cases that reached ``s2`` (status ok, a finite u_y at
    X = L/4) and both bend the mid-axis (|u_y(L/4)| above :data:`STRAIGHT` times the load); the
    sentence says otherwise which case did not run or does not bend, and draws no conclusion.
    """
    head = f"Bending direction at {s2:g} mm (sign of u_y at X = L/4 on the mid-axis), continuum and {model}: "
    rows = (("continuum", cont), (model, other))
    missing = [n for n, r in rows if r["status"] != "ok" or not math.isfinite(r[f"uyq{s2:g}"])]
    if missing:
        return (
            head
            + "not compared: "
            + " and ".join(f"the {n} case {_status_words(r)}" for n, r in rows if n in missing)
            + "."
        )
    straight = [n for n, r in rows if abs(r[f"uyq{s2:g}"]) <= STRAIGHT * s2]
    if straight:
        return head + (
            f"not compared: {' and '.join(f'the {n} model' for n in straight)} "
            f"{'leave' if len(straight) > 1 else 'leaves'} the mid-axis straight there "
            f"(|u_y(L/4)| at most {STRAIGHT:g} of the load)."
        )
    same = np.sign(cont[f"uyq{s2:g}"]) == np.sign(other[f"uyq{s2:g}"])
    return head + ("the same." if same else "OPPOSITE: the two models bend the specimen in opposite directions.")


def _status_words(r: dict[str, Any]) -> str:
    """What became of a case (a row of :func:`analyse`) that has no u_y at the station, in words."""
    at = r.get("u0_reached")
    if r["status"] == "ok":
        return "has no profile at this load"
    if isinstance(at, (int, float)) and at > 0:
        return f"{r['status']} (last converged load {at:g} mm)"
    return f"{r['status']} before its first load step"


def _discrete_segments(npz: Path) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Deformed yarn segments [mm], their family, and the shear angle γ there [deg]."""
    d = np.load(npz)
    x = d["X_mm"] + d["u_mm"]
    g = np.full(len(x), np.nan)
    cn = d["crossing_nodes"]
    g[cn[:, 0]] = d["crossing_gamma_deg"]
    g[cn[:, 1]] = d["crossing_gamma_deg"]
    ptr, nodes = d["yarn_ptr"], d["yarn_nodes"]
    segs, fam, ang = [], [], []
    for k in range(len(ptr) - 1):
        ch = nodes[ptr[k] : ptr[k + 1]]
        gk = g[ch]
        ok = np.isfinite(gk)
        if ok.any():
            idx = np.arange(len(ch))
            gk = np.interp(idx, idx[ok], gk[ok])
        else:
            gk = np.zeros(len(ch))
        for j in range(len(ch) - 1):
            segs.append(x[[ch[j], ch[j + 1]]])
            fam.append(int(d["yarn_family"][k]))
            ang.append(0.5 * (gk[j] + gk[j + 1]))
    return segs, np.array(fam), np.array(ang)


def plot(data: StudyData, quick: bool) -> list[Path]:
    out = [_plot_curves(data, quick)]
    files = {(r["model"], float(r["u0_mm"])): data.out / r["file"] for r in data.tables.get("fields", [])}
    if files:
        out.append(_plot_maps(data, files))
    return out


def _plot_curves(data: StudyData, quick: bool) -> Path:
    """Force curves of the three models and their mid-axis profiles at the two stations."""
    from matplotlib.lines import Line2D

    from ngbet.figures.curves import curve_with_jumps
    from ngbet.figures.style import FORCE_LABEL, U0_LABEL, caption, legend_below, put_caption, subplots

    s1, s2 = C.stations(quick, data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = Scene.from_dict(data.meta["base_scene"])
    fig, axs = subplots(1, 3, size=(14, 4.6))
    snapped = False
    for m, col in zip(LABELS, ("C0", "C1", "C2"), strict=True):
        i = _case(data, m)
        if i is None:
            continue
        rows = data.case_rows(i)
        snap = [float(r.get("snap") or 0.0) for r in rows] if rows and "snap" in rows[0] else None
        snapped = snapped or bool(snap and any(snap))
        curve_with_jumps(
            axs[0], [r["u0_mm"] for r in rows], [r["force_N"] for r in rows], snap, label=m, color=col, jump_label=None
        )
        for ax, s in ((axs[1], s1), (axs[2], s2)):
            X, uy = data.profile(i, s)
            if X:
                ax.plot(X, uy, color=col, label=m)
    u = np.linspace(0.5, scene.loading.u0_mm, 60)
    axs[0].plot(u, [ideal_force(scene, x) for x in u], "k--", lw=1, label="ideal kinematics (shear only)")
    axs[0].set_xlabel(U0_LABEL)
    axs[0].set_ylabel(FORCE_LABEL)
    axs[0].set_xlim(left=0)
    for ax, s in ((axs[1], s1), (axs[2], s2)):
        ax.set_title(f"mid-axis profile at u₀ = {s:g} mm")
        ax.set_xlabel("reference position X on the mid-axis [mm]")
        ax.set_ylabel("vertical displacement u_y [mm]")
        ax.axhline(0, color="k", lw=0.5)
    axs[0].set_title("force (points: converged steps, joined by straight lines)")
    handles = [
        Line2D([], [], color=col, marker="o", ms=3.5, label=m)
        for m, col in zip(LABELS, ("C0", "C1", "C2"), strict=True)
        if _case(data, m) is not None
    ]
    handles.append(Line2D([], [], color="k", ls="--", lw=1, label="ideal kinematics (shear only)"))
    if snapped:
        handles.append(Line2D([], [], color="0.3", ls="--", lw=1.2, label="snap-through (vertical dashed jump)"))
    legend_below(fig, handles, ncol=len(handles))
    put_caption(fig, caption(data.meta["base_scene"]) + "; the three models of the legend")
    return savefig(fig, data.out, "compare_curves")


def _plot_maps(data: StudyData, files: dict[tuple[str, float], Path]) -> Path:
    """Shear-angle maps of the continuum beside the deformed network, one row per saved load, one colour scale."""
    from ngbet.figures.maps import colour_bar, colour_scale, map_panel
    from ngbet.figures.style import caption, put_caption, subplots

    sp = data.meta["base_scene"]["specimen"]
    loads = sorted({u for _, u in files})
    cont = {u: _continuum_map(files[("continuum", u)], sp) for u in loads if ("continuum", u) in files}
    disc = {u: _discrete_segments(files[("discrete", u)]) for u in loads if ("discrete", u) in files}
    cs = colour_scale([m.gamma_deg for m, _ in cont.values()] + [a for _, _, a in disc.values()])
    norm = cs.norm()
    L, W = float(sp["length_mm"]), float(sp["width_mm"])
    fig, axs = subplots(
        len(loads), 2, size=(11, 0.7 + len(loads) * (0.85 + 3.2 * min(W / L, 1.0))), squeeze=False, layout="compressed"
    )
    art = None
    for row, u0 in enumerate(loads):
        if u0 in cont:
            m, yarns = cont[u0]
            art = map_panel(axs[row, 0], m, cs, norm, yarns)
        axs[row, 0].set_title(f"continuum, u₀ = {u0:g} mm (thick yarns black, thin grey)")
        if u0 in disc:
            lc = _map_discrete(axs[row, 1], disc[u0], cs, norm)
            art = art if art is not None else lc
        else:
            axs[row, 1].text(
                0.5,
                0.5,
                "no state of the network saved at this load\n(states: the load stops and the last load)",
                ha="center",
                va="center",
                transform=axs[row, 1].transAxes,
                fontsize=8,
            )
        axs[row, 1].set_title(f"yarn network, u₀ = {u0:g} mm (thick yarns solid, thin dashed)")
        for ax in axs[row]:
            ax.set_aspect("equal")
            ax.grid(False)
            ax.set_ylabel("y [mm]")
    for ax in axs[-1]:
        ax.set_xlabel("x (deformed) [mm]")
    if art is not None:
        colour_bar(fig, axs, art, cs)
    put_caption(
        fig,
        caption(data.meta["base_scene"]) + " (the continuum's); the network of the same "
        "specimen with its own parameters (paper Table 2)" + (f"; {cs.note()}" if cs.note() else ""),
    )
    return savefig(fig, data.out, "compare_maps")


def _continuum_map(vtu: Path, sp: dict[str, Any]) -> tuple[Any, dict[int, list[np.ndarray]]]:
    """The continuum's shear angle on the deformed specimen (a triangulated map) and its yarns."""
    from ngbet.figures.data import MapData

    from . import _fields as F

    surf = F.warped_mm(vtu).extract_surface(algorithm="dataset_surface").triangulate()
    tri = np.asarray(surf.faces).reshape(-1, 4)[:, 1:]
    m = MapData(
        0.0, np.asarray(surf.points[:, 0]), np.asarray(surf.points[:, 1]), tri, np.asarray(surf["shear_angle_deg"])
    )
    return m, F.deformed_yarns(vtu, sp["length_mm"], sp["width_mm"], sp["yarn_angle_deg"], 10.0)


def _map_discrete(ax: Any, network: tuple[list[np.ndarray], np.ndarray, np.ndarray], cs: Any, norm: Any) -> Any:
    """The deformed network coloured by γ; thick yarns solid, thin yarns dashed. Returns a coloured artist."""
    from matplotlib.collections import LineCollection

    segs, fam, ang = network
    lc = None
    for fm, lw, ls in ((2, 0.6, (0, (3, 1))), (1, 1.8, "solid")):
        sel = fam == fm
        lc = LineCollection(
            [segs[k] for k in np.flatnonzero(sel)], linewidths=lw, linestyles=ls, cmap=cs.cmap, norm=norm
        )
        lc.set_array(ang[sel])
        ax.add_collection(lc)
    ax.autoscale()
    return lc


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.compare")


if __name__ == "__main__":
    sys.exit(main())
