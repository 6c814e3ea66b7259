"""A parameter sweep with the Python API: the S-shape grows with the thick yarns' bending stiffness α1.

A coarse mesh and 20 mm of clamp displacement, so that it runs in seconds.
"""

import ngbet

base = ngbet.default_scene().with_changes(**{"loading.u0_mm": 20.0, "loading.stops_mm": [],
                                             "discretization.mesh_size_mm": 20.0, "outputs.vtk": False})
rows = []
for alpha1 in (20.0, 200.0, 2000.0):  # Pa m^2; alpha2 = 20: the first one is a balanced fabric
    r = ngbet.simulate(base.with_changes(**{"material.alpha1": alpha1}))
    X_mm, uy_mm = r.profiles[r.u0_mm[-1]]
    rows.append((alpha1, r.force_N[-1], abs(uy_mm).max()))
    print(f"alpha1 = {alpha1:6g} Pa m^2: force {r.force_N[-1]:6.2f} N, max |u_y| on the mid-axis {rows[-1][2]:.3f} mm")
