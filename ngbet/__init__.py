"""ngbet: bias extension tests of (unbalanced) woven fabrics on NGSolve.

The constrained micromorphic continuum and the discrete yarn model of Madeo, Barbagallo,
D'Agostino & Boisse (2016); conventions and equations in docs/model.md.

    >>> import ngbet
    >>> r = ngbet.simulate(ngbet.default_scene())   # doctest: +SKIP
    >>> r.force_N[-1]                                # doctest: +SKIP
"""

from .api import Result, load_result, simulate  # noqa: E402
from .errors import ConvergenceError  # noqa: E402
from .revision import __revision__, __version__  # noqa: E402  (written by setuptools-scm at build time)
from .scene import Scene, SceneError, default_scene  # noqa: E402

__all__ = ["ConvergenceError", "Result", "Scene", "SceneError", "default_scene", "load_result", "simulate",
           "__version__", "__revision__"]

