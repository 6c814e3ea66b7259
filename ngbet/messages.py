"""What ngbet's commands say on the terminal: one ``ngbet: ...`` line per message, on stderr.

Log records of level WARNING and above and Python warnings (a :class:`ngbet.scene.document.SceneWarning`
among them) are each written as one line, without the logger's name or the warning's source line;
a line said once is not repeated within a command. ``-v`` (verbose) keeps the level, the
logger's name, INFO records and Python's own warning format. The command line installs this for the
span of a command (:func:`messages`), a study's worker processes for their lifetime (:func:`install`).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import warnings
from collections.abc import Iterator
from typing import Any

__all__ = ["OneLine", "install", "messages", "one_line", "say", "show_warning"]


def say(msg: str) -> None:
    """Write ``msg`` as one ``ngbet: ...`` line on stderr (whitespace runs become one space)."""
    with contextlib.suppress(OSError, ValueError):
        print(one_line(msg), file=sys.stderr)


def one_line(msg: str) -> str:
    """``msg`` as the one line ``ngbet: ...``."""
    return f"ngbet: {' '.join(str(msg).split())}"


_SHOWN: set[str] = set()  # the lines said so far (in this command): each is said once


class _Once(logging.Filter):
    """Lets a record through only the first time its line is said (in this command)."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = one_line(record.getMessage())
        if text in _SHOWN:
            return False
        _SHOWN.add(text)
        return True


class OneLine(logging.Formatter):
    """A log record as one ``ngbet: ...`` line (``verbose``: level and logger too, every line kept)."""

    def __init__(self, verbose: bool = False) -> None:
        super().__init__("%(levelname)s %(name)s: %(message)s" if verbose else None)
        self.verbose = verbose

    def format(self, record: logging.LogRecord) -> str:
        """The record in one line (verbose: Python's format, with a traceback if the record has one)."""
        return super().format(record) if self.verbose else one_line(record.getMessage())


def show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    """A warning as one ``ngbet: ...`` line on stderr, without Python's source line; each once."""
    from .scene.document import SceneNote, SceneWarning

    kind = (
        "note: "
        if issubclass(category, SceneNote)
        else ""
        if issubclass(category, SceneWarning)
        else f"{category.__name__}: "
    )
    text = one_line(f"{kind}{message}")
    if text not in _SHOWN:
        _SHOWN.add(text)
        with contextlib.suppress(OSError, ValueError):
            print(text, file=file or sys.stderr)


def install(verbose: bool = False) -> logging.Handler:
    """Log records and warnings as ``ngbet:`` lines from now on in this process; the handler added."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(OneLine(verbose))
    # records of other libraries' loggers that set their own level (dask's INFO) stop here too
    handler.setLevel(logging.INFO if verbose else logging.WARNING)
    if not verbose:
        handler.addFilter(_Once())
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.INFO if verbose else logging.WARNING)
    _SHOWN.clear()
    if not verbose:  # -v keeps Python's warnings with their source
        warnings.showwarning = show_warning
    return handler


@contextlib.contextmanager
def messages(verbose: bool = False) -> Iterator[None]:
    """:func:`install` for the span of the block; the logging and warning setup is restored after it."""
    root = logging.getLogger()
    level, showwarning = root.level, warnings.showwarning
    handler = install(verbose)
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
        warnings.showwarning = showwarning
