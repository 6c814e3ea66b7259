"""A parameter sweep with the Python API: the S-shape grows with the thick yarns' bending stiffness α1.

The same study as ``ngbet sweep material.alpha1=20,200,2000 --quick``: its cases go into the
shared cache (a second run computes nothing), its table, figures and report into
out/examples/sweep. ``quick``: a coarse mesh and 20 mm of clamp displacement, seconds per case.
"""

import math

from ngbet.studies import sweep
from ngbet.study.runner import run_study


def main() -> None:
    """Run the sweep (or read it from the cache) and print a line per case."""
    study = sweep.build({"material.alpha1": [20.0, 200.0, 2000.0]}, quick=True)  # Pa m^2; alpha2 = 20
    data = run_study(study, "out/examples/sweep", cache="out/studies/cache", progress=False)
    u0 = data.meta["base_scene"]["loading"]["u0_mm"]
    for case in data.cases():
        i = case["case"]
        _, uy_mm = data.profile(i, u0)
        amp = max((abs(u) for u in uy_mm), default=math.nan)
        print(
            f"alpha1 = {case['params']['material.alpha1']:6g} Pa m^2: force {data.at(i, u0, 'force_N'):6.2f} N, "
            f"max |u_y| on the mid-axis {amp:.3f} mm"
        )
    print(f"table, figures and report: {data.out}/")


if __name__ == "__main__":  # the study's worker processes import this file: they must not run it again
    main()
