"""The constrained micromorphic continuum (second gradient through the micro-variable φ = i8) on NGSolve.

problem      spaces, energy, boundary conditions, load and state of one scene
numerics     the problem's solver: energy forms, linear solver, native code, timers
physics      the energy terms, each written once
observables  reactions (volume-integral method), profiles, fields
solver       damped Newton and load stepping
relax        a stable equilibrium at a fixed clamp displacement where Newton failed
estimate     the estimated discretization error of the force
ladder       finer settings until that error meets the target
run          a continuum scene into a run folder
"""

import ngsolve as _ngs

# NGSolve's own console messages ask nothing of a user ("no more timer available (biform_from_py),
# reusing last one" after some thousand forms in one process, a study's worker): ngbet says what matters
_ngs.ngsglobals.msg_level = 0

__all__: list[str] = []
