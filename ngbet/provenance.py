"""What a result depends on: library versions, the git revision of ngbet, the machine (summary.json, study records)."""

from __future__ import annotations

import os
import platform
from typing import Any

__all__ = ["DISTRIBUTIONS", "git_revision", "machine", "versions"]

#: module -> the distribution that installs it
DISTRIBUTIONS = {"ngbet": "ngbet", "ngsolve": "ngsolve", "netgen": "netgen-mesher", "numpy": "numpy", "scipy": "scipy"}


def versions() -> dict[str, str]:
    """Versions of the libraries a result depends on.

    The ``__version__`` of a module already imported (ngbet itself, NGSolve in a run), else the
    installed package's metadata (no import: a study's process need not import NGSolve to name its
    version); a module installed without metadata is imported; one not installed is left out.
    """
    import sys
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str] = {"python": platform.python_version()}
    for mod, dist in DISTRIBUTIONS.items():
        try:
            m = sys.modules.get(mod)
            out[mod] = str(getattr(m, "__version__", "unknown")) if m is not None else version(dist)
        except PackageNotFoundError:
            try:
                out[mod] = str(getattr(__import__(mod), "__version__", "unknown"))
            except Exception:  # pragma: no cover - optional modules
                pass
    return out


def git_revision() -> str:
    """The git revision of ngbet (the checkout's, or the one recorded at install), or 'unknown'."""
    from .revision import revision

    return revision()


def machine() -> dict[str, Any]:
    """The machine a run ran on (node, architecture, CPUs, system), for summary.json."""
    return {
        "node": platform.node(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "system": platform.platform(),
    }
