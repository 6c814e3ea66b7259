"""The constrained micromorphic continuum (second gradient through the micro-variable φ = i8) on NGSolve.

problem      spaces, forms, boundary conditions and load of one scene
physics      the energy terms, each written once
observables  reactions (volume-integral method), profiles, fields
solver       damped Newton and load stepping
run          a continuum scene into a run folder
"""
