"""ngbet: bias extension tests of (unbalanced) woven fabrics on NGSolve.

The constrained micromorphic continuum and the discrete yarn model of Madeo, Barbagallo,
D'Agostino & Boisse (2016); conventions and equations in docs/model.md.

    >>> import ngbet
    >>> r = ngbet.simulate(ngbet.default_scene())   # doctest: +SKIP
    >>> r.force_N[-1]                                # doctest: +SKIP
"""

__version__ = "0.1.0"

from .api import Result, load_result, simulate  # noqa: E402
from .errors import ConvergenceError  # noqa: E402
from .scene import Scene, SceneError, default_scene  # noqa: E402

__all__ = ["ConvergenceError", "Result", "Scene", "SceneError", "default_scene", "load_result", "simulate",
           "__version__", "__revision__"]


def __getattr__(name: str) -> str:
    if name == "__revision__":  # computed on first use: it may ask git
        from .revision import revision

        return revision()
    raise AttributeError(f"module 'ngbet' has no attribute {name!r}")
