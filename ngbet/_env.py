"""Environment variables set for the span of a block, then restored."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping

__all__ = ["environ"]


@contextlib.contextmanager
def environ(changes: Mapping[str, str]) -> Iterator[None]:
    """Set the variables ``changes`` in ``os.environ`` inside the block; restore (or remove) them after."""
    before = {k: os.environ.get(k) for k in changes}
    os.environ.update(changes)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
