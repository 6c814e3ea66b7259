"""``python -m ngbet``: the command line.

``ngbet run`` runs in a child ``python -m ngbet run`` that the command watches
(:func:`ngbet.cli.console`). That process ends by :func:`_end_run_process`.
"""

import os
import sys

from .cli import SUPERVISED, console

__all__: list[str] = []


def _end_run_process(code: int) -> None:
    """End the watched run's process with ``code``: the atexit functions, the streams flushed, then ``os._exit``.

    Everything of the run is written and closed by now (its files, the plot process, the
    report); what is left is the interpreter's teardown of the modules and of NGSolve's objects,
    which nothing needs (its time: bench/README.md).
    """
    import atexit
    import contextlib
    import ctypes

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)  # C streams (compiled libraries' output), as exit() would
    os._exit(code)


code = console()
if os.environ.get(SUPERVISED) and sys.argv[1:2] == ["run"]:
    _end_run_process(code)
sys.exit(code)
