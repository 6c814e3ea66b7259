"""Regenerate the figures of the documentation (docs/figures/*.png) from fresh runs.

    python docs/make_figures.py              # a few seconds
    python docs/make_figures.py --out DIR    # into DIR instead of docs/figures

bet_default.png: the default scene (the paper's BET to 56 mm): the deformed specimen at the last
load coloured by the shear angle with the yarns drawn on it, and the force-displacement curve,
drawn by ngbet's plotting package (ngbet.figures) from the run's files.

normalise_twill_unbalanced.png: the collapse figure of ``ngbet normalise`` on the two shipped sizes
of the unbalanced Twintex twill (docs/normalise.md).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

import ngbet
from ngbet.figures.curves import curve_with_jumps, error_bars
from ngbet.figures.data import column, load_maps, map_file_name
from ngbet.figures.maps import colour_bar, colour_scale, map_panel
from ngbet.figures.style import FORCE_LABEL, U0_LABEL, caption, figure, in_style, put_caption
from ngbet.studies.maps import YARN_SPACING_MM, deformed_yarns
from ngbet.tables import read_rows

HERE = Path(__file__).resolve().parent


def main(argv: list[str] | None = None) -> int:
    """Run the default scene and write bet_default.png into docs/figures (or ``--out DIR``)."""
    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--out", type=Path, default=HERE / "figures", help="folder of the figure (default docs/figures)")
    out = args.parse_args(argv).out
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:  # a run folder of its own: it writes the map data
        code = _draw(ngbet.simulate(ngbet.default_scene(), out=Path(tmp) / "run"), out)
        return code or _collapse(Path(tmp) / "normalise", out)


def _collapse(folder: Path, out: Path) -> int:
    """``ngbet normalise`` on the unbalanced twill's two sizes; its collapse figure copied to ``out``."""
    from ngbet.cli import main as ngbet_main

    data = HERE.parent / "data" / "cao2008"
    files = [str(data / f"cao2008_twill_unbalanced_{size}_UN.csv") for size in ("100x200", "100x250")]
    code = ngbet_main(["normalise", *files, "--out", str(folder), "--quiet"])
    if code:
        return code
    path = out / "normalise_twill_unbalanced.png"
    shutil.copyfile(folder / "collapse.png", path)
    print(f"{path}: {path.stat().st_size / 1024:.0f} kB")
    return 0


def _draw(r: ngbet.Result, out: Path) -> int:
    sp = r.scene.specimen
    last = load_maps(r.out)[-1]
    npz = r.out / map_file_name(last.u0_mm)
    yarns = deformed_yarns(npz, sp.length_mm, sp.width_mm, sp.yarn_angle_deg, YARN_SPACING_MM)
    rows = read_rows(r.out / "results.csv")
    with in_style():
        fig = figure(10, 3.6)
        a1, a2 = fig.subplots(1, 2, width_ratios=[2.1, 1])
        cs = colour_scale([last.gamma_deg])
        art = map_panel(a1, last, cs, cs.norm(), yarns)
        a1.set_xlabel("x (deformed) [mm]")
        a1.set_title(f"u₀ = {last.u0_mm:g} mm: thick yarns black, thin yarns grey")
        colour_bar(fig, [a1], art, cs)
        u0, F = column(rows, "u0_mm"), column(rows, "force_N")
        curve_with_jumps(a2, u0, F, column(rows, "snap") if "snap" in rows[0] else None, label="computed")
        error_bars(a2, u0, F, column(rows, "force_error_N"), float(np.nanmax(F)))
        a2.set_xlabel(U0_LABEL)
        a2.set_ylabel(FORCE_LABEL)
        a2.set_xlim(left=0)
        a2.legend(loc="upper left")
        put_caption(fig, caption(r.scene) + ("; " + cs.note() if cs.note() else ""))
        path = out / "bet_default.png"
        fig.savefig(path, dpi=110)  # zlib's default level: a smaller file for the repository
    print(f"{path}: {path.stat().st_size / 1024:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
