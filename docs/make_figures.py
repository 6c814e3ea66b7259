"""Regenerate the figures of the documentation (docs/figures/*.png) from fresh runs.

    python docs/make_figures.py          # a few seconds

bet_default.png: the default scene (the paper's BET to 56 mm): the deformed specimen coloured
by the shear angle with the yarns drawn on it, and the force-displacement curve.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import ngbet  # noqa: E402
from ngbet.plotting import SHEAR_LABEL  # noqa: E402
from ngbet.studies import _fields  # noqa: E402

HERE = Path(__file__).resolve().parent
YARN_SPACING_MM = 10.0


def specimen_map(ax: plt.Axes, r: ngbet.Result) -> None:
    """The deformed specimen coloured by γ, thick yarns black, thin yarns white, axes in mm."""
    surf = r.fields().warp_by_vector("displacement").extract_surface(algorithm="dataset_surface").triangulate()
    tri = np.asarray(surf.faces).reshape(-1, 4)[:, 1:]
    pts = np.asarray(surf.points)
    tpc = ax.tripcolor(pts[:, 0], pts[:, 1], tri, np.asarray(surf["shear_angle_deg"]), shading="gouraud",
                       cmap="viridis", rasterized=True)
    sp = r.scene.specimen
    yarns = _fields.deformed_yarns(r.out / "fields.vtu", sp.length_mm, sp.width_mm, sp.yarn_angle_deg,
                                   YARN_SPACING_MM)
    for fam, lw, color in ((1, 1.4, "k"), (2, 0.5, "w")):
        for line in yarns[fam]:
            ax.plot(line[:, 0], line[:, 1], color=color, lw=lw)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(f"u0 = {r.u0_mm[-1]:g} mm: thick yarns black, thin yarns white", fontsize=9)
    plt.colorbar(tpc, ax=ax, label=SHEAR_LABEL, orientation="horizontal", fraction=0.08, pad=0.25)


def main() -> int:
    """Run the scenes and write the figures into docs/figures."""
    out = HERE / "figures"
    out.mkdir(exist_ok=True)
    r = ngbet.simulate(ngbet.default_scene())
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4), gridspec_kw={"width_ratios": [2.1, 1]})
    specimen_map(a1, r)
    r.plot(ax=a2, label="force")
    handles, labels = a2.get_legend_handles_labels()
    a2.legend(handles, [textwrap.fill(t, 30) for t in labels], fontsize=7, loc="upper left")
    a2.set_title("force on the moving clamp", fontsize=9)
    fig.tight_layout()
    path = out / "bet_default.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"{path}: {path.stat().st_size / 1024:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
