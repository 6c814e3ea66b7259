"""The version and git revision of this ngbet, as setuptools-scm recorded them at build time.

Building or installing ngbet (``pip install .``, ``pip install -e .``, ``python -m build``) lets
setuptools-scm write ``ngbet/_version.py``: the version from the git tags (``0.1.devN+g<commit>``
between releases) and the commit. An sdist carries the file. A source tree without git metadata
(a container's build context) gets the fallback version of ``pyproject.toml`` and the revision
``"unknown"``, unless ``SETUPTOOLS_SCM_PRETEND_VERSION`` gives the version (``0.1.dev0+g<commit>``).
An editable install keeps what it recorded when it was installed. Nothing here asks git or raises.
"""

from __future__ import annotations

__all__ = ["revision"]


def _recorded() -> tuple[str, str]:
    try:
        from ._version import __commit_id__, __version__
    except ImportError:  # sources on sys.path that were never built
        return "unknown", "unknown"
    version = str(__version__)
    # the local version: "+g<commit>", with ".d<date>" for a tree with uncommitted changes
    local = version.partition("+")[2].split(".")
    node = str(__commit_id__ or "") or next((p for p in local if p.startswith("g")), "")
    if not node:
        return version, "unknown"
    dirty = any(p.startswith("d") and p[1:].isdigit() for p in local)
    return version, node.removeprefix("g") + ("-dirty" if dirty else "")


__version__, __revision__ = _recorded()


def revision() -> str:
    """The git revision ngbet was built from (``-dirty``: with uncommitted changes), or ``"unknown"``."""
    return __revision__
