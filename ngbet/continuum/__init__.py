"""The constrained micromorphic continuum (second gradient through the micro-variable φ = i8) on NGSolve.

problem      spaces, energy, boundary conditions, load and state of one scene
solver       the problem's energy forms and linear algebra (on :mod:`ngbet.numerics`), timers
physics      the energy terms, each written once
observables  reactions (volume-integral method), profiles, fields
stability    the lowest modes of the tangent and what they say about a failure (writes no files)
estimate     the estimated discretization error of the force
sensitivity  derivatives of the force with respect to the material parameters
path_spread  the path's own spread where two equilibria compete

The numerics (Newton, load stepping, arc length) are model-free: :mod:`ngbet.numerics`; running
a scene into a run folder is the runner's: :mod:`ngbet.runner`.
"""

import ngsolve as _ngs

# NGSolve's own console messages ask nothing of a user ("no more timer available (biform_from_py),
# reusing last one" after some thousand forms in one process, a study's worker): ngbet says what matters
_ngs.ngsglobals.msg_level = 0

__all__: list[str] = []
