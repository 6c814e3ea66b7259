"""ngbet: bias extension tests of (unbalanced) woven fabrics on NGSolve.

The constrained micromorphic continuum and the discrete yarn model of Madeo, Barbagallo,
D'Agostino & Boisse (2016), with the conventions of MODEL.md.
"""

__version__ = "0.1.0"

from .scene import Scene, SceneError, default_scene  # noqa: E402,F401
