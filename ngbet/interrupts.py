"""Stop signals as interruptions: Ctrl-C, SIGTERM, SIGHUP and SIGUSR1/2 end a command as "interrupted".

:func:`interrupts` is the context of every command (:func:`ngbet.cli.main`): the signal raises
KeyboardInterrupt in the main thread, and a watchdog thread records the interruption in the active
run folders itself (and in the records :func:`recorded_if_stuck` names, a fit's fit.json) when the
main thread is held inside one NGSolve call for longer than :data:`GRACE_S`, then exits with
status 130.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

from .commands import EXIT_INTERRUPTED
from .messages import say

__all__ = ["GRACE_S", "STOP_SIGNALS", "interrupts", "recorded_if_stuck", "signal_name", "stop_signals"]

GRACE_S = 2.0  # how long the main thread may take to act on Ctrl-C before the watchdog does
#: the signals that end a command as an interruption (summary.json "interrupted", exit 130): Ctrl-C,
#: SIGTERM, the terminal closed (SIGHUP) and the user signals, whose default would kill the run silently
STOP_SIGNALS = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1", "SIGUSR2") if hasattr(signal, n)
)


#: what the watchdog calls besides the run folders' record (:func:`recorded_if_stuck`)
_RECORDERS: list[Callable[[str], str | None]] = []


@contextlib.contextmanager
def recorded_if_stuck(record: Callable[[str], str | None]) -> Iterator[None]:
    """While inside: a stop the main thread cannot act on is recorded by ``record(reason)`` too.

    ``record`` runs in the watchdog's thread while the main thread is held in one NGSolve call
    (so no Python of the main thread runs meanwhile); it writes its record (a fit's fit.json of
    status "interrupted") and returns what it kept, in words, for the command's last line, or
    None. Its errors are its own: logged, and the exit stays 130.
    """
    _RECORDERS.append(record)
    try:
        yield
    finally:
        _RECORDERS.remove(record)


def stop_signals() -> list[int]:
    """:data:`STOP_SIGNALS` but those this process ignores (``nohup`` ignores SIGHUP: the run goes on)."""
    return [sig for sig in STOP_SIGNALS if signal.getsignal(sig) is not signal.SIG_IGN]


def signal_name(signum: int) -> str:
    """The name of a signal (``SIGTERM``), or ``signal N`` for a number Python does not name."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


@contextlib.contextmanager
def interrupts() -> Iterator[None]:
    """Ctrl-C, SIGTERM, SIGHUP and SIGUSR1/2 raise KeyboardInterrupt in the main thread (recorded as "interrupted").

    The run folder's summary names the signal.

    The main thread can be inside one NGSolve call for a long time (assembly or
    factorization at high order: tens of seconds) and only acts when it returns; a watchdog thread
    woken by the signal (``signal.set_wakeup_fd``) then records the interruption in the active run
    folders itself and exits with 130 after GRACE_S.
    """
    from .numerics.engine import STOP_REQUESTED, request_stop, stop_deferred

    acted = threading.Event()

    def handler(signum: int, frame: Any) -> None:
        acted.set()
        request_stop(signal_name(signum))  # in case the exception is lost (engine.STOP_REQUESTED): the next step raises
        if stop_deferred():  # inside an uninterrupted block: raised as it ends (engine.uninterrupted)
            return
        raise KeyboardInterrupt(signal_name(signum))

    try:
        previous = {sig: signal.signal(sig, handler) for sig in stop_signals()}
    except ValueError:  # not the main thread: leave the signals alone
        yield
        return
    r, w = socket.socketpair()
    w.setblocking(False)
    old_fd = signal.set_wakeup_fd(w.fileno(), warn_on_full_buffer=False)
    watchdog = threading.Thread(target=_watch, args=(r, acted), daemon=True, name="ngbet-interrupt-watchdog")
    watchdog.start()
    STOP_REQUESTED.clear()
    try:
        yield
    finally:
        STOP_REQUESTED.clear()
        signal.set_wakeup_fd(old_fd)
        for sig, h in previous.items():
            signal.signal(sig, h)
        w.close()  # ends the watchdog
        watchdog.join(timeout=1)
        r.close()


def _watch(r: socket.socket, acted: threading.Event) -> None:
    while True:
        try:
            data = r.recv(64)
        except OSError:
            return
        if not data:
            return
        got = [s for s in data if s in STOP_SIGNALS]
        if not got:  # another library's signal
            continue
        if not acted.wait(GRACE_S):
            from .output import interrupt_active_runs

            reason = f"interrupted ({signal_name(got[0])}) inside a computation; stopped after {GRACE_S:g} s"
            folders = interrupt_active_runs(reason)
            kept = [f"converged steps and summary.json (status interrupted) are in {', '.join(map(str, folders))}"]
            kept = kept if folders else []
            for record in list(_RECORDERS):
                try:
                    said = record(reason)
                except Exception as exc:  # the exit is the stop's: the record's failure is said
                    said = f"could not record the interruption: {type(exc).__name__}: {exc}"
                kept += [said] if said else []
            say(f"interrupted; {'; '.join(kept) or 'no run folder was open'}")
            sys.stderr.flush()
            os._exit(EXIT_INTERRUPTED)
        acted.clear()
