"""Build backend: setuptools, plus the git revision recorded in ngbet/_revision.py.

``pip install .`` from a git clone builds in the clone, so ``git rev-parse`` sees the checkout
and the installed package knows its revision (``ngbet --version``, ``summary.json``). Outside a
checkout (an sdist, a tarball) the file says ``"unknown"``. Nothing here can fail a build.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from setuptools import build_meta as _orig
from setuptools.build_meta import *  # noqa: F401,F403

ROOT = Path(__file__).resolve().parent.parent


def _record_revision() -> None:
    try:  # the module alone: the package's dependencies are not in the build environment
        spec = importlib.util.spec_from_file_location("_ngbet_revision", ROOT / "ngbet" / "revision.py")
        mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        rev = mod.from_checkout(ROOT)
    except Exception:  # pragma: no cover - a build never fails for want of a revision
        rev = None
    target = ROOT / "ngbet" / "_revision.py"
    if rev is None and target.exists():
        return  # an sdist built from a checkout already carries its revision
    try:
        target.write_text(f'"""Written at build time by _build/backend.py."""\n\nREVISION = {rev or "unknown"!r}\n')
    except OSError:  # pragma: no cover - read-only source tree
        pass


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):  # type: ignore[no-untyped-def]
    """Setuptools' wheel, with the revision recorded first."""
    _record_revision()
    return _orig.build_wheel(wheel_directory, config_settings, metadata_directory)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):  # type: ignore[no-untyped-def]
    """Setuptools' editable wheel, with the revision recorded first."""
    _record_revision()
    return _orig.build_editable(wheel_directory, config_settings, metadata_directory)


def build_sdist(sdist_directory, config_settings=None):  # type: ignore[no-untyped-def]
    """Setuptools' sdist, with the revision recorded first (so that it carries it)."""
    _record_revision()
    return _orig.build_sdist(sdist_directory, config_settings)
