"""ngbet: bias extension tests of (unbalanced) woven fabrics on NGSolve.

The constrained micromorphic continuum and the discrete yarn model of Madeo, Barbagallo,
D'Agostino & Boisse (2016); conventions and equations in docs/model.md.

    >>> import ngbet
    >>> r = ngbet.simulate(ngbet.default_scene())   # doctest: +SKIP
    >>> r.force_N[-1]                                # doctest: +SKIP
"""

import importlib.util as _importlib_util
import sys as _sys
from pathlib import Path as _Path


def _studies_of_a_source_checkout() -> None:
    """``ngbet.studies`` where ngbet runs from a source checkout rather than an install.

    An install places the top-level ``studies/`` folder at ``ngbet/studies``; in a checkout (the
    tests and docs scripts run from its root import this folder's ngbet) the same scripts are
    found in ``studies/`` beside it.
    """
    here = _Path(__file__).resolve().parent
    src = here.parent / "studies"
    if (here / "studies").exists() or not (src / "__init__.py").is_file() or "ngbet.studies" in _sys.modules:
        return
    spec = _importlib_util.spec_from_file_location(
        __name__ + ".studies", src / "__init__.py", submodule_search_locations=[str(src)]
    )
    if spec is None or spec.loader is None:
        return
    module = _importlib_util.module_from_spec(spec)
    _sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    globals()["studies"] = module  # as the import system binds a subpackage it imported


_studies_of_a_source_checkout()

from typing import TYPE_CHECKING as _TYPE_CHECKING  # noqa: E402

from .errors import ConvergenceError  # noqa: E402
from .revision import __revision__, __version__  # noqa: E402  (written by setuptools-scm at build time)
from .scene.document import Scene, default_scene  # noqa: E402
from .scene.validate import SceneError  # noqa: E402

__all__ = [
    "ConvergenceError",
    "Result",
    "Scene",
    "SceneError",
    "default_scene",
    "load_result",
    "simulate",
    "__version__",
    "__revision__",
]


if _TYPE_CHECKING:
    from .api import Result, load_result, simulate


def __getattr__(name: str) -> object:
    """The API (``simulate``, ``load_result``, ``Result``), imported on first use.

    So the process of the ``ngbet`` command that watches a run imports neither numpy nor the API.
    """
    if name in ("Result", "load_result", "simulate"):
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
