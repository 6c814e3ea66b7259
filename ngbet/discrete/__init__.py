"""Discrete model of the bias extension test (paper section 3; docs/discrete.md).

Two families of co-rotational Euler-Bernoulli beams (thick yarns along m1 with EA1, EI1; thin
yarns along m2 with EA2, EI2), joined at each crossing by a slip spring K_slip (relative
displacement of the two yarns' nodes) and a rotational spring K_phi (change of the angle between
the yarns), plus trusses K_inter between adjacent parallel yarns. Equilibrium states minimize

    E(u) = sum_beams psi_beam + sum_crossings (1/2 K_slip |u_a - u_b|^2 + 1/2 K_phi (theta_b - theta_a)^2)
           + sum_trusses 1/2 K_inter (l - L0)^2 / L0

under the clamps u = 0, theta = 0 on X = 0 and u = (u0, 0), theta = 0 on X = L.

Modules: :mod:`.network` (geometry), :mod:`.elements` (element energies), :mod:`.model`
(assembly), :mod:`.linsolve` (factorization), :mod:`.solver` (Newton, load stepping, stability),
:mod:`.observables` (slip, angles, profile, pictures), :mod:`.run` (entry point).
"""

__all__: list[str] = []
