"""The two-size fit of each Twintex fabric on specimen sizes that data/ has no curve of, against Eq. 18.

For each fabric, ``ngbet fit`` on its two bias-extension sizes in data/cao2008/ (into
``out/other_sizes/<fabric>/``, skipped where a fitted scene is already there), then the fitted
scene on other sizes (100 x 300 mm for each fabric, 115 x 230 mm for the plain weave) at 16
displacements over 10-90 % of the range where the ideal test stays below the largest shear
angle both fitted curves reach. Against it: the normalisation method (Eq. 18) from each fitted
curve, and their mean. No measured curve is compared: this says how far the model's size effect
takes a prediction from the method's, and how far the method's answers from the two sizes lie
apart.

    python docs/research/other_sizes.py [FABRIC ...]    # plain, twill_balanced, twill_unbalanced
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

from ngbet.kinematics import shear_angle_rad
from ngbet.measured.curves import read_measured
from ngbet.normalise import force_by_normalisation, normalised_curve
from ngbet.runner.sensitivity import force_path
from ngbet.scene.document import Scene

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data" / "cao2008"
OUT = Path("out") / "other_sizes"
FABRICS = {
    "plain": (["plain_150x300_INSA-NU", "plain_150x450_INSA-NU"], [(100.0, 300.0), (115.0, 230.0)]),
    "twill_balanced": (["twill_balanced_150x300_INSA-NU", "twill_balanced_150x450_INSA-NU"], [(100.0, 300.0)]),
    "twill_unbalanced": (["twill_unbalanced_100x250_UN", "twill_unbalanced_100x200_UN"], [(100.0, 300.0)]),
}


def fitted_scene(fabric: str, files: list[Path]) -> Scene:
    """The fabric's two-size fit (made once)."""
    out = OUT / fabric
    if not (out / "fitted_scene.toml").exists():
        scene = ROOT / "geometry" / f"twintex_{fabric}.toml"
        subprocess.run(["ngbet", "fit", str(scene), *map(str, files), "--out", str(out), "--quiet"], check=True)
    return Scene.from_toml(out / "fitted_scene.toml")


def main(fabrics: list[str]) -> None:
    for fabric in fabrics:
        names, sizes = FABRICS[fabric]
        files = [DATA / f"cao2008_{n}.csv" for n in names]
        scene = fitted_scene(fabric, files)
        curves = [read_measured(p) for p in files]
        largest = min(float(np.max(normalised_curve(c)[0])) for c in curves)
        for W, L in sizes:
            spec = {"specimen.width_mm": W, "specimen.length_mm": L}
            on = scene.with_changes(**spec)
            travel = np.linspace(1.0, 0.99 * on.specimen.locking_u0_mm, 400)
            reach = float(travel[np.searchsorted(shear_angle_rad(travel, L, W), largest) - 1])
            u = np.linspace(0.1 * reach, 0.9 * reach, 16)
            loaded = on.with_changes(**{"loading.u0_mm": float(u[-1]), "loading.stops_mm": []})
            run = force_path(loaded, u, estimate=True)
            method = [
                force_by_normalisation(*normalised_curve(c), dataclasses.replace(c, specimen={**c.specimen, **spec}), u)
                for c in curves
            ]
            mean = np.mean(method, axis=0)
            F, err = run.force_N, run.force_error_N
            assert err is not None
            print(
                f"{fabric}, {W:g} x {L:g} mm, {u[0]:.1f} to {u[-1]:.1f} mm: ngbet against Eq. 18's mean "
                f"{100 * np.sqrt(np.mean(((F - mean) / mean) ** 2)):.1f} % RMS "
                f"({100 * np.sqrt(np.mean((F - mean) ** 2)) / mean.max():.1f} % of its largest value), "
                + ", ".join(
                    f"against Eq. 18 from {c.label} {100 * np.sqrt(np.mean(((F - m) / m) ** 2)):.1f} %"
                    for c, m in zip(curves, method, strict=True)
                )
                + f"; Eq. 18's two answers apart {100 * np.sqrt(np.mean(((method[0] - method[1]) / mean) ** 2)):.1f} %"
                f"; ngbet's estimated discretization error at most {100 * np.max(err / np.abs(F)):.2f} %"
            )


if __name__ == "__main__":
    main(sys.argv[1:] or list(FABRICS))
