"""A second process that draws the run's figures, so that importing matplotlib overlaps the solve.

``ngbet run`` spends about 0.4 s importing matplotlib and about 0.1 s on the first drawing
(fonts, the text layout), all of it independent of the results. On a machine with an idle core
the command starts this process before it imports NGSolve: it imports matplotlib and draws
one small figure (fonts, Agg, the PNG writer) while the run solves, then waits on its stdin
for the run folder, draws the run's figures (``force``, ``shear_force``, ``profile``, ``shear_map``, in the scene's
``outputs.figure_formats``) with the same function as the run itself
(:func:`ngbet.figures.run.draw_force`, so the figures are the same; shared among itself and a forked
child per further idle core, :func:`ngbet.figures.run.draw_run`: a fork costs CPU time, one per
figure more than one per core, and on a busy machine the children gain nothing) and answers on
its stdout with the force figure's file.

Nothing depends on it: when it is not running, died, or answers with an error, the run draws
the figure itself (the log says why at INFO level). It is a fork of the run where it can be
(before NGSolve is imported; else a new interpreter), a child of the run in its own session
(a Ctrl-C at the terminal reaches the run alone, which decides) and exits when its stdin closes,
i.e. when the run ends by any means, SIGKILL included.

``NGBET_PLOT_PROCESS`` chooses: ``auto`` (default: only when the machine has the half core the
process needs to spare, i.e. the 1-minute load average is at most the number of usable cores
minus 0.5), ``always`` or ``never``. On a saturated machine the process gains nothing (measured
on 2 cores at a load of 3.5: 5.88 s against 5.93 s median wall time of the default run, six runs
each) and costs more CPU time in all (a second interpreter, its imports, the forked children),
which the other jobs pay; ``auto`` leaves it out there.

Protocol: one JSON line per request, ``{"run_dir": str, "extra": [[label, x, y], ...]}``; one JSON
line per answer, ``{"png": str | None}`` or ``{"error": str}``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import subprocess
import sys
from collections.abc import Iterable, Iterator, Sequence
from importlib.util import find_spec
from pathlib import Path
from typing import IO, Any

__all__ = [
    "CHOICES",
    "ENV",
    "SPARE_CORES",
    "PlotProcess",
    "PlotProcessError",
    "active",
    "plot_process",
    "serve",
    "wanted",
]

log = logging.getLogger(__name__)

ENV = "NGBET_PLOT_PROCESS"
CHOICES = ("auto", "always", "never")


class PlotProcessError(RuntimeError):
    """The plot process could not draw (it died, or its drawing failed); the caller draws instead."""


class PlotProcess:
    """The running plot process (see the module docstring).

    Forked from this process where it can be (POSIX, NGSolve not imported): the process then
    starts with this interpreter and its imports (ngbet, numpy) instead of a new interpreter
    importing them again. Otherwise, or where the fork fails, a new interpreter.
    """

    def __init__(self) -> None:
        self.proc: Any = None
        if _can_fork():
            with contextlib.suppress(OSError):
                self.proc = _Forked()
        if self.proc is None:
            root = str(Path(__file__).resolve().parent.parent)  # this ngbet, however it was found
            code = f"import sys; sys.path.insert(0, {root!r}); from ngbet.plot_process import serve; serve()"
            self.proc = subprocess.Popen(
                [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True
            )

    def plot(
        self, run_dir: str | Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = ()
    ) -> Path | None:
        """Draw the figures of ``run_dir`` in the process; returns force.png (None: nothing to draw).

        Raises
        ------
        PlotProcessError
            when the process is gone or its drawing failed.
        """
        self.request(run_dir, extra)
        return self.answer()

    def request(self, run_dir: str | Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = ()) -> None:
        """Ask for the figures of ``run_dir`` without waiting (:meth:`answer` waits).

        Raises
        ------
        PlotProcessError
            when the process is gone.
        """
        stdin = self.proc.stdin
        assert stdin is not None
        request = {"run_dir": str(Path(run_dir).resolve()), "extra": [[lab, list(x), list(y)] for lab, x, y in extra]}
        try:
            stdin.write((json.dumps(request) + "\n").encode())
            stdin.flush()
        except OSError as exc:
            raise PlotProcessError(f"the plot process is gone ({exc})") from exc

    def answer(self) -> Path | None:
        """Wait for the answer to the last :meth:`request`: force.png, or None when there was nothing to draw.

        Raises
        ------
        PlotProcessError
            when the process is gone or its drawing failed.
        """
        stdout = self.proc.stdout
        assert stdout is not None
        try:
            line = stdout.readline()
        except OSError as exc:
            raise PlotProcessError(f"the plot process is gone ({exc})") from exc
        if not line:
            raise PlotProcessError(f"the plot process ended (exit status {self.proc.poll()})")
        answer = json.loads(line)
        if "error" in answer:
            raise PlotProcessError(answer["error"])
        return Path(answer["png"]) if answer["png"] is not None else None

    def close(self) -> None:
        """End the process (it is idle or importing: nothing of the run is lost)."""
        if self.proc.stdin is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def _can_fork() -> bool:
    """Whether the plot process may be forked from this one: POSIX, and no NGSolve (its threads) here yet."""
    return hasattr(os, "fork") and "ngsolve" not in sys.modules


class _Forked:
    """The plot process as a fork of this one (what :class:`PlotProcess` uses of :class:`subprocess.Popen`).

    ``stdin``, ``stdout``, ``poll``, ``kill``, ``wait``, ``returncode`` as Popen's.
    The child is in a session of its own, has the request pipe as its stdin and the answer pipe
    as its stdout, no other file descriptor of this process but stderr (so that it holds no end of
    a pipe or socket of the run: its stdin closes when the run ends by any means), the stop
    signals at their defaults, and ends by ``os._exit`` (nothing of the run's runs in it).
    """

    def __init__(self) -> None:
        req_r, req_w = os.pipe()
        ans_r, ans_w = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # nothing buffered here is written twice
            with contextlib.suppress(Exception):
                stream.flush()
        try:
            pid = os.fork()
        except OSError:
            for fd in (req_r, req_w, ans_r, ans_w):
                os.close(fd)
            raise
        if pid == 0:  # the child
            code = 1
            try:
                _child_setup(req_r, ans_w)
                serve(open(0, "rb", closefd=False), open(1, "wb", closefd=False))
                code = 0
            finally:
                os._exit(code)
        os.close(req_r)
        os.close(ans_w)
        self.pid = pid
        self.returncode: int | None = None
        self.stdin: IO[bytes] | None = open(req_w, "wb")
        self.stdout: IO[bytes] | None = open(ans_r, "rb")

    def poll(self) -> int | None:
        """The exit code if the child has ended (negative: the signal), else None."""
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def kill(self) -> None:
        """SIGKILL the child (if it has not been waited for)."""
        if self.returncode is None:
            import signal

            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)

    def wait(self) -> int:
        """Wait for the child to end; its exit code."""
        if self.returncode is None:
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])
        return self.returncode


def _child_setup(req_r: int, ans_w: int) -> None:
    """In the forked child: its own session, the pipes as fds 0 and 1, no other fd but 2, default signals.

    Every signal the run handles in Python (its stop signals: :mod:`ngbet.interrupts`) is back
    at its default; :func:`serve` then ignores SIGINT.
    """
    import signal

    os.setsid()
    signal.set_wakeup_fd(-1)
    for sig in signal.valid_signals():
        with contextlib.suppress(OSError, ValueError):
            if callable(signal.getsignal(sig)):
                signal.signal(sig, signal.SIG_DFL)
    os.dup2(req_r, 0)
    os.dup2(ans_w, 1)
    os.closerange(3, os.sysconf("SC_OPEN_MAX") if hasattr(os, "sysconf") else 1024)


_ACTIVE: list[PlotProcess] = []


def active() -> PlotProcess | None:
    """The plot process of this run, if one is running."""
    return _ACTIVE[-1] if _ACTIVE else None


def wanted(plot: bool) -> bool:
    """Whether a run that draws (``plot``) should start the plot process (``NGBET_PLOT_PROCESS``)."""
    choice = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if choice not in CHOICES:
        log.warning("%s=%r is none of %s; using auto", ENV, choice, ", ".join(CHOICES))
        choice = "auto"
    if not plot or choice == "never" or not sys.executable or "ngsolve" in sys.modules:
        return False  # no figure, refused, or too late to overlap anything
    if find_spec("matplotlib") is None:
        return False
    if choice == "always":
        return True
    return _spare_cores() >= SPARE_CORES


def _spare_cores() -> float:
    """The usable cores minus the 1-minute load average."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores - os.getloadavg()[0]


#: the share of a core the plot process needs during a run (about 0.5 s of CPU time in a run of 1 s)
SPARE_CORES = 0.5


@contextlib.contextmanager
def plot_process(plot: bool) -> Iterator[PlotProcess | None]:
    """Run the plot process for the duration of the block, if :func:`wanted`; ends it afterwards."""
    if not wanted(plot):
        yield None
        return
    try:
        proc = PlotProcess()
    except OSError as exc:
        log.info("no plot process (%s): the run draws its figure itself", exc)
        yield None
        return
    _ACTIVE.append(proc)
    try:
        yield proc
    finally:
        _ACTIVE.remove(proc)
        proc.close()


def serve(stdin: IO[bytes] | None = None, stdout: IO[bytes] | None = None) -> None:
    """The plot process: import and warm up matplotlib, then answer requests until stdin closes."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run decides
    stdin = stdin or sys.stdin.buffer
    stdout = stdout or sys.stdout.buffer
    from .figures.run import draw_force, warm_up

    try:
        warm_up()
    except Exception as exc:  # the requests will say what fails
        log.debug("warm-up failed: %s", exc)
    for line in stdin:
        try:
            req = json.loads(line)
            png = draw_force(
                Path(req["run_dir"]),
                [(lab, x, y) for lab, x, y in req.get("extra", [])],
                workers=1 + max(0, int(_spare_cores())),
            )
            answer: dict[str, Any] = {"png": str(png) if png is not None else None}
        except Exception as exc:  # reported to the run, which draws the figure itself
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        stdout.write((json.dumps(answer) + "\n").encode())
        stdout.flush()
