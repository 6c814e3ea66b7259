"""The process that watches ``ngbet run`` (ngbet.watch): the run's process is a fork of the watcher.

Each case runs the watcher in an interpreter of its own (the fork copies the process: never this
one's pytest) with a stand-in for the run, and checks the exit status that the command gives and
what the watcher records. The whole command under signals and crashes: tests/test_faults.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

WATCHER = """
import json, os, signal, sys
from pathlib import Path
from ngbet.watch import SUPERVISED, watch

case, folder = sys.argv[1], Path(sys.argv[2])

def run(argv):
    (folder.parent / "child.json").write_text(json.dumps(
        {"pid": os.getpid(), "sid": os.getsid(0), "watcher": os.getppid(), "supervised": os.environ.get(SUPERVISED)}
    ))
    if case == "returns":
        return 7
    if case == "exit-int":
        raise SystemExit(2)
    if case == "exit-text":
        raise SystemExit("a message from argparse")
    if case == "raises":
        raise RuntimeError("not caught by main")
    if case == "killed":
        os.kill(os.getpid(), signal.SIGKILL)

code = watch(["run", "--out", str(folder)], run, lambda: folder)
print(json.dumps({"pid": os.getpid(), "supervised": os.environ.get(SUPERVISED)}))  # the watcher alone prints
sys.exit(code)
"""


def run_folder(tmp_path):
    """A run folder whose summary.json says "running", as a run's process leaves it while it runs."""
    from ngbet.run_folder import RUN_MARKER

    out = tmp_path / "run"
    out.mkdir()
    (out / RUN_MARKER).touch()
    (out / "summary.json").write_text(json.dumps({"status": "running"}))
    return out


def watched(case: str, folder) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "NGBET_SUPERVISED"}
    return subprocess.run(
        [sys.executable, "-c", WATCHER, case, str(folder)], capture_output=True, text=True, env=env, timeout=60
    )


@pytest.mark.parametrize(
    "case, code, says",
    [
        ("returns", 7, ""),  # the run's own exit status
        ("exit-int", 2, ""),  # argparse refusing a command line
        ("exit-text", 1, "a message from argparse"),  # SystemExit with a text: 1 and the text, as Python
        ("raises", 70, "RuntimeError: not caught by main"),  # the last resort: an internal error, traceback
    ],
)
def test_the_watched_process_ends_as_the_interpreter_would(tmp_path, case, code, says):
    """The forked run never returns into the watcher's code: its status is its own, a SystemExit's code,
    or 70 for an exception that escaped; it runs in a session of its own, a child of the watcher,
    with the supervised mark in its environment (and not in the watcher's)."""
    p = watched(case, tmp_path / "run")
    assert p.returncode == code, p.stderr
    assert says in p.stderr
    child = json.loads((tmp_path / "child.json").read_text())
    assert child["sid"] == child["pid"] and child["supervised"] == "1"
    (watcher,) = [json.loads(line) for line in p.stdout.splitlines()]  # one line: the child never came back here
    assert child["watcher"] == watcher["pid"] != child["pid"] and watcher["supervised"] is None
    assert p.stderr.count("a message from argparse") <= 1  # said once, by the child


def test_a_run_process_killed_without_a_word_is_recorded_by_the_watcher(tmp_path):
    """A child that dies by a signal: the watcher records "crashed" in the folder's summary.json (the run had
    marked it running) and says so in one line, exit 70."""
    out = run_folder(tmp_path)
    p = watched("killed", out)
    assert p.returncode == 70, p.stderr
    assert "died by SIGKILL" in p.stderr and p.stderr.count("\n") == 1 and "could not" not in p.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "crashed" and "SIGKILL" in s["error"]


def test_a_stop_signal_is_passed_on_to_the_run(tmp_path):
    """SIGTERM to the watcher reaches the run (in its own session, so only through the watcher); a run that
    ends by it without recording its end is recorded as interrupted, exit 130."""
    out = run_folder(tmp_path)
    script = WATCHER.replace(
        'if case == "killed":', 'if case == "waits":\n        signal.pause()\n    if case == "killed":'
    )
    env = {k: v for k, v in os.environ.items() if k != "NGBET_SUPERVISED"}
    p = subprocess.Popen(
        [sys.executable, "-c", script, "waits", str(out)],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL),
    )
    try:
        for _ in range(600):
            if (tmp_path / "child.json").exists():
                break
            time.sleep(0.05)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert "interrupted by SIGTERM" in err and "could not" not in err
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"
