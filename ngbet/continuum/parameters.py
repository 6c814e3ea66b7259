"""The material values of the energy that calibration varies, as NGSolve ``Parameter`` objects.

The continuum energy is built once per problem (:meth:`ngbet.continuum.problem.ContinuumProblem._energy`)
with these values as ``ngsolve.Parameter`` objects instead of number literals. Two things follow:

their derivatives are those of the energy itself: ``W.Diff(parameter)`` is ∂W/∂p of every term
that reads p, the stabilization K_s = min(c min(α1, α2)/h_T², 30 K_el) included
(:mod:`ngbet.continuum.sensitivity`), and the compiled code of the energy reads them at run time
instead of carrying them as literals.

Which terms exist (the shear law, bending, the constraint, whether K_s is capped) is decided
when the energy is built, from the scene; only the values are parameters. A problem is built for
one scene: its Newton norm and the augmentation of its Newton matrix take their scales from the
material too, so a new parameter set is a new problem (its construction is small against a load
path: bench/README.md). The tabulated shear
law's rises stay numbers in the energy: the energy is linear in them, and its derivative with
respect to one rise is the same law with a unit rise (:func:`ngbet.continuum.physics.table_shear_energy`).
"""

from __future__ import annotations

from typing import Any

import ngsolve as ngs

__all__ = ["PARAMETERS", "material_parameters"]

#: the material keys the energy reads through a Parameter
PARAMETERS = ("K_el", "K_sh", "K_sh4", "K_sh6", "K_lock", "gamma_lock_deg", "alpha1", "alpha2")


def material_parameters(material: Any) -> dict[str, ngs.Parameter]:
    """One ``ngsolve.Parameter`` per key of :data:`PARAMETERS`, holding the value of ``material``."""
    return {k: ngs.Parameter(float(getattr(material, k))) for k in PARAMETERS}
