"""Regenerate the figures of docs/calibration.md from fresh fits and the validation study.

- calibration_fit.png (and calibration_fit.json): the locking shear law fitted to the Cao et al.
  (2008) glass plain weave 150 × 450 mm curve, the single-curve command of docs/calibration.md run
  from Python;
- calibration_twill_unbalanced_fit.png and calibration_table.png: ``ngbet fit`` on the two sizes of
  the unbalanced Twintex twill at once (its fit.png and shear_table.png);
- validation.png: ``ngbet study validation`` (every measured curve a fit did not use, predicted).

    python docs/calibration_figure.py            # all of them (the validation study takes minutes)
    python docs/calibration_figure.py --no-study # the fits only
    python docs/calibration_figure.py --out DIR  # into DIR instead of docs/
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

from ngbet.calibration.command import summary
from ngbet.calibration.joint import fit_curves
from ngbet.calibration.report import plot_fit
from ngbet.cli import main as ngbet
from ngbet.measured.curves import read_measured
from ngbet.scene.document import Scene

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs"
PARAMS = ["material.K_sh", "material.K_lock", "material.gamma_lock_deg"]
TWILL = ["data/cao2008/cao2008_twill_unbalanced_100x250_UN.csv", "data/cao2008/cao2008_twill_unbalanced_100x200_UN.csv"]


def single_curve(out: Path) -> None:
    """The locking law fitted to one curve: calibration_fit.png and its record, in ``out``."""
    scene = Scene.from_toml(ROOT / "geometry" / "cao2008_150x450.toml")
    curve = read_measured(ROOT / "data" / "cao2008_glass_plain_150x450.csv")
    result = fit_curves([curve], scene, PARAMS)
    plot_fit(result, out / "calibration_fit.png")
    doc = result.to_json()
    for c in doc["curves"]:
        c["data"] = "data/cao2008_glass_plain_150x450.csv"
    (out / "calibration_fit.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(summary(result, out))


def run(argv: list[str], accept: tuple[int, ...] = (0,)) -> None:
    """One ngbet command from the repository root; stops the script if it exits otherwise than ``accept``."""
    code = ngbet(argv)
    if code not in accept:
        raise SystemExit(f"ngbet {' '.join(argv)} exited with status {code}")


def main(argv: list[str] | None = None) -> None:
    """Fit, draw and copy the figures into docs/ (or ``--out DIR``); ``--no-study``: without validation.png."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT, help="folder of the figures (default docs/)")
    parser.add_argument("--no-study", action="store_true", help="the fits only, not the validation study")
    args = parser.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    single_curve(out)
    with tempfile.TemporaryDirectory() as tmp:
        fitted = Path(tmp) / "fit"
        scene = ROOT / "geometry" / "twintex_twill_unbalanced.toml"
        run(
            ["fit", *(str(ROOT / f) for f in TWILL), "--scene", str(scene), "--out", str(fitted)], accept=(0, 1)
        )  # 1: stopped at --max-runs, said in the figure's record
        shutil.copyfile(fitted / "fit.png", out / "calibration_twill_unbalanced_fit.png")
        shutil.copyfile(fitted / "shear_table.png", out / "calibration_table.png")
        if not args.no_study:
            study = Path(tmp) / "validation"
            run(["study", "validation", "--out", str(study), "--cache", str(Path(tmp) / "cache"), "--quiet"])
            shutil.copyfile(study / "validation.png", out / "validation.png")


if __name__ == "__main__":
    main()
