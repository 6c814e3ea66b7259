"""What ngbet's commands share.

The exit statuses, the one-line message of an error that ends a command, and the scene of a
command line (a scene file with ``--set`` overrides).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

from .scene.document import Scene, SceneNote, SceneWarning
from .scene.validate import SceneError

__all__ = [
    "EXIT_INPUT",
    "EXIT_INTERNAL",
    "EXIT_INTERRUPTED",
    "EXIT_IO",
    "EXIT_OK",
    "EXIT_SOLVER",
    "exit_code",
    "load_scene",
    "parse_value",
]

EXIT_OK, EXIT_SOLVER, EXIT_INPUT, EXIT_IO, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 70, 130


def parse_value(text: str) -> object:
    """The value of ``--set key=VALUE``: a Python literal (number, list, quoted string), true/false, else the text."""
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def load_scene(path: str | None, overrides: list[str], tests: Sequence[str] = ()) -> Scene:
    """The scene file (or the default scene) with ``section.key=value`` (or ``model=``, ``test=``) overrides applied.

    The file's tables and the overrides are read into one scene: its missing keys take the
    defaults, and a default that contradicts a key the file or an override sets gives way to it,
    with a note on stderr (``ngbet: note: ...``), as are the scene's warnings. ``tests``: the tests
    the scene will run besides its own (a fit of curves of both tests): the keys one of them reads
    are not reported as without effect.
    """
    from .scene.document import TOP_LEVEL, apply_changes, read_toml

    changes = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or ("." not in key and key.strip() not in TOP_LEVEL):
            raise SceneError(
                f"--set expects section.key=value, model=continuum|discrete or "
                f"test=bias_extension|picture_frame, got {item!r}"
            )
        changes[key.strip()] = parse_value(value.strip())
    data = read_toml(path) if path else {}
    if not isinstance(data, dict):
        raise SceneError(f"scene file {path}: not a table of sections")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneNote)
        warnings.simplefilter("always", SceneWarning)
        scene = Scene.from_dict(apply_changes(data, changes))
    every = (scene.test, *tests)
    for w in caught:  # shown as one `ngbet:` line each, once (ngbet.messages)
        message = w.message
        if tests and str(message) == str(scene.unused_warning()):
            if not scene.unused_keys(every):
                continue
            message = scene.unused_warning(every)
        warnings.warn_explicit(message, w.category, w.filename, w.lineno)
    return scene


def exit_code(exc: BaseException, where: Path | None = None, load: str = "u0") -> tuple[int, str]:
    """The exit status and the one-line message of an error that ends a command.

    ``where``: the output folder, named when the OS error names no file (e.g. a full disk on write);
    ``load``: the name of the run's load (:func:`ngbet.scene.physical.load_symbol`).
    """
    from .errors import ConvergenceError, FitWorkerError
    from .run_folder import OutputError
    from .study.cluster import SchedulerError

    if isinstance(exc, SceneError):
        return EXIT_INPUT, f"bad scene: {exc}"
    if isinstance(exc, FitWorkerError):  # killed or out of memory, not necessarily a bug
        return EXIT_SOLVER, str(exc)
    if isinstance(exc, ConvergenceError):
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        advice = getattr(exc.detail, "advice", lambda: "")()  # the diagnosis's cause and remedy
        reason = exc.attempts[-1].reason if exc.attempts else ""
        if not advice and "relaxation:" in reason:  # why no stable state was found at the load
            advice = reason.split("relaxation:", 1)[1].strip().removesuffix(")")
        return EXIT_SOLVER, (
            f"the solver stopped after {load} = {exc.last_converged_mm:g} mm: {first}"
            + (f"; {advice}" if advice else "")
        )
    if isinstance(exc, OutputError):
        return EXIT_IO, f"cannot use the output folder {exc}"
    if isinstance(exc, SchedulerError):
        return EXIT_IO, str(exc)
    if isinstance(exc, OSError):
        path = exc.filename if exc.filename is not None else where
        return EXIT_IO, f"I/O error on {path if path is not None else 'an unnamed file'}: {exc.strerror or exc}"
    if isinstance(exc, MemoryError):  # the size check before the run should have refused it
        return EXIT_INTERNAL, (
            "out of memory"
            + (f" (converged steps and summary.json are in {where}/)" if where else "")
            + ": the estimate of the problem's size missed it; "
            "please report it"
        )
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return EXIT_INTERNAL, (
        f"internal error ({type(exc).__name__}{': ' + first if first else ''}); this is a bug in "
        "ngbet: please report it (-v shows the traceback)"
    )


def tolerant_streams() -> None:
    """Make stdout and stderr never fail on a character their encoding lacks (``LC_ALL=C``, ASCII pipes).

    Such a character (±, γ, ½) is written as its backslash escape: a run is never failed by its report.
    """
    if sys.stderr is None:  # closed by the shell (2>&-): the messages go nowhere, the exit status still says it
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - for the life of the process
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, OSError):
            stream.reconfigure(errors="backslashreplace")  # type: ignore[union-attr]


def positionals_first(parser: argparse.ArgumentParser, words: list[str]) -> list[str]:
    """``words`` after the command with its positional words first (``study alpha1 --quick my.toml``).

    argparse takes a command's positionals in one go, before its options; a scene file written
    after an option was refused. Options that take a value keep it.
    """
    if not words or words[0] not in ("study", "sweep"):
        return words
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[words[0]]
    valued = {o for a in sub._actions if a.option_strings and a.nargs != 0 for o in a.option_strings}
    pos: list[str] = []
    opts: list[str] = []
    rest = words[1:]
    i = 0
    while i < len(rest):
        w = rest[i]
        if w == "--":
            pos += rest[i + 1 :]
            break
        if w.startswith("-") and len(w) > 1 and not _number(w):
            opts.append(w)
            if w in valued and i + 1 < len(rest):
                opts.append(rest[i + 1])
                i += 1
        else:
            pos.append(w)
        i += 1
    return [words[0], *pos, *opts]


def _number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True
