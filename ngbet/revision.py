"""The git revision ngbet was built from.

- Run from a git checkout (an editable install, or the source tree on ``sys.path``): the
  checkout's current revision, with ``-dirty`` when tracked files are modified.
- Installed with ``pip install .`` from a clone: the revision recorded at build time in
  ``ngbet/_revision.py`` (written by the in-tree build backend, ``_build/backend.py``).
- Otherwise ``"unknown"``; finding the revision never raises.
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


def _git(*args: str, cwd: Path = PACKAGE) -> str | None:
    try:
        p = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def from_checkout(root: Path | None = None) -> str | None:
    """The revision of the checkout that holds ngbet's sources (``root``: the repository), or None.

    None when the package is not a tracked folder of a checkout (e.g. installed into a venv inside one).
    """
    pkg = (root / "ngbet") if root is not None else PACKAGE
    if _git("rev-parse", "--show-prefix", cwd=pkg) != "ngbet/":
        return None
    rev = _git("rev-parse", "--short=12", "HEAD", cwd=pkg)
    if rev is None:
        return None
    dirty = _git("status", "--porcelain", "--untracked-files=no", cwd=pkg)
    return rev + ("-dirty" if dirty else "")


@functools.lru_cache(maxsize=1)
def revision() -> str:
    """The git revision of this ngbet (see the module docstring), or ``"unknown"``."""
    rev = from_checkout()
    if rev:
        return rev
    try:
        from ._revision import REVISION

        return str(REVISION)
    except ImportError:
        return "unknown"
