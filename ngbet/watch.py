"""The process that watches ``ngbet run``: the run in a forked child, its end recorded whatever it is.

A run that dies without a word (a crash in compiled code, the kernel's OOM killer) cannot record
its end itself; the watching process records it in the run folder's summary.json ("crashed", with
the signal) and says so in one line (exit 70). Ctrl-C, SIGTERM, SIGHUP (the terminal closed) and
SIGUSR1/2 are passed on to the run, which records "interrupted" as always; the run dies with its
watcher. The run's process is a fork of the watcher (its interpreter and imports are the
watcher's, not started again) in a session of its own; the stop signals are held from the fork
until the watcher passes them on, so that none is lost in between.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from .commands import EXIT_INTERNAL, EXIT_INTERRUPTED
from .errors import NgbetError
from .interrupts import STOP_SIGNALS, signal_name, stop_signals
from .messages import say

__all__ = ["SUPERVISED", "end_run_process", "watch"]

#: set in the environment of the run's process (the watched child)
SUPERVISED = "NGBET_SUPERVISED"


def watch(argv: list[str], main: Callable[[list[str]], int], folder: Callable[[], Path]) -> int:
    """``main(argv)`` (``ngbet run``) in a forked child, waited for: its exit status.

    ``folder``: the run folder of ``argv`` (called only after the child died by a signal without
    recording its end, which is then recorded there: :func:`_died`).
    """
    stops = stop_signals()
    for stream in (sys.stdout, sys.stderr):  # nothing buffered twice
        with contextlib.suppress(Exception):
            stream.flush()
    held = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    watcher = os.getpid()
    child = os.fork()
    if child == 0:
        _run_watched(lambda: main(argv), watcher, held)  # never returns

    def forward(signum: int, frame: Any) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(child, signum)

    for sig in stops:
        signal.signal(sig, forward)
    signal.pthread_sigmask(signal.SIG_SETMASK, held)
    code = os.waitstatus_to_exitcode(os.waitpid(child, 0)[1])
    return code if code >= 0 else _died(folder, -code)


def _run_watched(run: Callable[[], int], watcher: int, mask: Any) -> NoReturn:
    """The forked run's process: its own session, SIGKILL when the watcher dies, ``run()``, then out.

    ``watcher``: the watching process's id; ``mask``: the signal mask to restore once the process
    is in its own session (a Ctrl-C then reaches the watcher alone, which passes it on). Ends by
    :func:`end_run_process` whatever happens: it never returns into the watcher's code. A
    ``SystemExit`` (``--help``, a command line argparse refuses) gives its code, as the
    interpreter would.
    """
    code = EXIT_INTERNAL
    try:
        os.setsid()
        with contextlib.suppress(Exception):
            import ctypes

            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux; elsewhere nothing)
        if os.getppid() != watcher:  # the watcher died before that: no one would record the end
            end_run_process(EXIT_INTERRUPTED)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        os.environ[SUPERVISED] = "1"
        code = run()
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            code = exc.code or 0
        else:
            say(str(exc.code))
            code = 1
    except BaseException:  # main() catches what a command raises; this is the last resort
        import traceback

        traceback.print_exc()
    finally:
        end_run_process(code)


def end_run_process(code: int) -> NoReturn:
    """End the watched run's process with ``code``: the atexit functions, the streams flushed, then ``os._exit``.

    Everything of the run is written and closed by now (its files, the plot process, the
    report); what is left is the interpreter's teardown of the modules and of NGSolve's objects,
    which nothing needs (its time: bench/README.md).
    """
    import atexit
    import ctypes

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)  # C streams (compiled libraries' output), as exit() would
    os._exit(code)


def _died(folder: Callable[[], Path], signum: int) -> int:
    """The run's process ended by signal ``signum`` without recording its end: record it, say it."""
    from .output import RunWriter
    from .tables import read_rows

    name = signal_name(signum)
    interrupted = signum in STOP_SIGNALS
    status = "interrupted" if interrupted else "crashed"
    msg = (
        f"the run was interrupted by {name}"
        if interrupted
        else f"the run's process died by {name} (a crash in compiled code, or killed from outside)"
    )
    with contextlib.suppress(SystemExit):  # an unreadable command line was the child's to report
        out = folder()
        try:
            if json.loads((out / "summary.json").read_text()).get("status") == "running":
                rows = read_rows(out / "results.csv") if (out / "results.csv").exists() else []
                u0 = float(rows[-1]["u0_mm"]) if rows else 0.0
                RunWriter.amend(
                    out,
                    {"status": status, "error": msg, "steps": len(rows), "u0_reached_mm": u0, "last_converged_mm": u0},
                )
                msg += f" after u0 = {u0:g} mm; converged steps and summary.json (status {status}) are in {out}/"
        except (OSError, ValueError, NgbetError) as exc:
            msg += f"; its folder {out} could not record it ({exc})"
    say(msg)
    return EXIT_INTERRUPTED if interrupted else EXIT_INTERNAL
