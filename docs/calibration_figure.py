"""Regenerate docs/calibration_fit.png, the fit of the locking shear law to a measured BET curve.

The curve is the Cao et al. (2008) glass plain weave; this is the command of docs/calibration.md, run from Python.

    python docs/calibration_figure.py
"""

from __future__ import annotations

import json
from pathlib import Path

from ngbet import fit
from ngbet.calibration.fit_files import plot_fit, summary_text
from ngbet.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ["material.K_sh", "material.K_lock", "material.gamma_lock_deg"]


def main() -> None:
    """Fit, draw the figure and write the fit's record beside it."""
    scene = Scene.from_toml(ROOT / "geometry" / "cao2008_150x450.toml")
    result = fit.fit(ROOT / "data" / "cao2008_glass_plain_150x450.csv", scene, PARAMS, u_range=(10.0, 106.0))
    out = ROOT / "docs"
    plot_fit(result, out / "calibration_fit.png")
    doc = result.to_json()
    doc["data"] = "data/cao2008_glass_plain_150x450.csv"
    (out / "calibration_fit.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(summary_text(result, out))


if __name__ == "__main__":
    main()
