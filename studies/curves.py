"""Load-displacement and double-force-displacement curves (forces in N with the thickness t = 15 mm).

Small load steps (2 mm) so that the curves are smooth. Beside the force: the ideal-kinematics
estimate dE_id/du0 (inextensible yarns, no slip, no bending: shear energy of zones A and B,
docs/model.md, *Ideal kinematics*) and the envelope-theorem check dE/du0 of the computed energy (central
differences between steps), an independent second value of the reaction.

    python -m ngbet.studies.curves [--quick] [--workers N] [--scheduler ADDR] [--plot-only]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from ngbet.kinematics import ideal_force
from ngbet.scene.document import Scene
from ngbet.study.command import main_for
from ngbet.study.figures import savefig
from ngbet.study.model import Study, StudyData

from . import _common as C
from . import reference as R

__all__ = ["analyse", "build", "main", "plot", "report"]


def build(quick: bool = False, scene: Scene | None = None) -> Study:
    C.made_for_bias_extension(scene, "curves", "the double force on the clamp, the estimate of ideal BET kinematics")
    step = 2.5 if quick else 2.0
    base = C.study_scene(scene, quick, {"loading.first_step_mm": step, "loading.max_step_mm": step})
    return Study("curves", base, [{}], description=__doc__ or "", plot=plot, report=lambda d: report(d, quick))


def analyse(data: StudyData) -> dict[str, Any]:
    rows = data.case_rows(0)
    u0 = np.array([r["u0_mm"] for r in rows])
    F = np.array([r["force_N"] for r in rows])
    T = np.array([r.get("double_force_Nm", np.nan) for r in rows])
    E = np.array([r["energy_J"] for r in rows])
    scene = Scene.from_dict(data.meta["base_scene"])
    Fid = np.array([ideal_force(scene, u) for u in u0])
    # envelope theorem: dE/du0 by central differences on the (possibly uneven) steps
    uu, EE = np.r_[0.0, u0], np.r_[0.0, E]
    dE = np.gradient(EE, uu * 1e-3)[1:]
    inner = slice(1, len(u0) - 1)
    env = float(np.max(np.abs(dE[inner] - F[inner]) / np.abs(F[inner]))) if len(u0) > 2 else np.nan
    snap = np.array([float(r.get("snap") or 0.0) for r in rows])
    return {"u0": u0, "F": F, "T": T, "Fid": Fid, "dE": dE, "envelope_max_rel": env, "snap": snap}


def report(data: StudyData, quick: bool = False) -> str:
    a = analyse(data)
    L = [
        *C.header(data, "Load-displacement and double-force-displacement curves", R.reference_text(data, quick)),
        f"Envelope check: max |dE/du0 - F| / F over the interior steps (central differences, "
        f"O(step^2)) = {a['envelope_max_rel']:.2g}",
        "",
        "| u0 [mm] | force [N] | ideal kinematics [N] | dE/du0 [N] | double force [N m] |",
        "|---|---|---|---|---|",
    ]
    for u, f, fi, de, t in zip(a["u0"], a["F"], a["Fid"], a["dE"], a["T"], strict=True):
        L.append(f"| {u:g} | {f:.4f} | {fi:.4f} | {de:.4f} | {t:.5g} |")
    return "\n".join(L) + "\n"


def plot(data: StudyData) -> list[Path]:
    from ngbet.figures.curves import curve_with_jumps
    from ngbet.figures.study import study_caption
    from ngbet.figures.style import FORCE_LABEL, U0_LABEL, put_caption, subplots

    a = analyse(data)
    fig, axs = subplots(1, 2, size=(12, 4.3))
    ax = axs[0]
    curve_with_jumps(ax, a["u0"], a["F"], a.get("snap"), label="reaction (volume integral)")
    inner = slice(1, len(a["u0"]) - 1)  # central differences: the interior steps, as in the report
    ax.plot(a["u0"][inner], a["dE"][inner], "x", ms=5, label="dE/du₀ (envelope theorem, interior steps)")
    ax.plot(np.r_[0, a["u0"]], np.r_[0, a["Fid"]], "k--", label="ideal BET kinematics (shear only)")
    ax.set_xlabel(U0_LABEL)
    ax.set_ylabel(FORCE_LABEL)
    ax.set_xlim(left=0)
    ax.set_title("(a) force")
    ax.legend(loc="upper left")
    ax = axs[1]
    curve_with_jumps(ax, a["u0"], a["T"], a.get("snap"), color="C3", marker="s", label="double force")
    ax.set_xlabel(U0_LABEL)
    ax.set_ylabel("double force on the moving clamp [N m]")
    ax.set_xlim(left=0)
    ax.set_title("(b) double force (no ideal-kinematics estimate: it has no bending)")
    put_caption(fig, study_caption(data.meta))
    return [savefig(fig, data.out, "curves")]


def main(argv: list[str] | None = None) -> int:
    return main_for(build, argv, prog="python -m ngbet.studies.curves")


if __name__ == "__main__":
    sys.exit(main())
