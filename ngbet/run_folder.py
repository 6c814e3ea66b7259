"""A run folder on disk: ngbet's mark and lock, what a run may remove or replace, atomic writes.

:class:`ngbet.output.RunWriter` takes a folder through :func:`acquire_run_folder` and
:func:`clear_previous_run` and writes every file with :func:`write_json_atomic` and :func:`file_op`;
nothing else writes into a run folder.
"""

from __future__ import annotations

import fcntl
import fnmatch
import json
import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from .errors import NgbetError

__all__ = ["FIGURE_SUFFIXES", "RUN_FILE_PATTERNS", "RUN_LOCK", "RUN_MARKER", "TMP_PREFIX", "OutputError",
           "acquire_run_folder", "clear_previous_run", "file_op", "jsonable", "link_or_copy", "remove_path",
           "write_json_atomic"]

log = logging.getLogger(__name__)


#: ngbet's mark of a run folder, and its lock: a folder is a run folder only when it holds this file
#: (created by the run that first wrote into the folder, and never removed by ngbet). A run holds
#: ``fcntl.flock`` on it while it writes (released by the OS when the process ends, however it ends:
#: it cannot go stale); it also lists the files the runs registered (JSON), the only files a later
#: run into the folder removes.
RUN_MARKER = ".ngbet.lock"
RUN_LOCK = RUN_MARKER
#: the prefix of the temporary names every file is written under before it is renamed into place
TMP_PREFIX = ".ngbet-tmp."
#: names an ngbet run writes: one of these in a run folder that no run registered is refused before
#: anything is written (it is the user's; the run would replace it)
RUN_FILE_PATTERNS = ("scene.toml", "summary.json", "results.csv", "profile.csv", "fields*.vtu", "force.png",
                     "force.pdf", "shear_force.png", "shear_force.pdf", "profile.png", "profile.pdf",
                     "shear_map.png", "shear_map.pdf", "map_*.npz", "state_*.npz", "yarns_*.png",
                     "instability_mode.vtu", "instability_mode.png")
#: the run's figures: drawn from its files, never read by a figure
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


class OutputError(NgbetError):
    """The output folder cannot be used.

    Not writable, a file in its place, busy with another run, or not an ngbet run folder. ``path`` names it.
    """

    def __init__(self, path: str | Path, why: str) -> None:
        super().__init__(f"{path}: {why}")
        self.path = Path(path)


def link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` a hard link to ``src`` (a copy where the file system has none)."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to a temporary file and rename it: a reader sees the old or the new file, never half."""
    tmp = path.with_name(TMP_PREFIX + path.name)
    try:
        file_op(tmp, lambda p: p.write_text(json.dumps(data, indent=2, default=jsonable)))
        file_op(path, lambda p: os.replace(tmp, p))
    finally:
        tmp.unlink(missing_ok=True)


def file_op(path: Path, action: Callable[[Path], Any]) -> Any:
    """Run a file operation; an OSError becomes an OutputError naming the path."""
    try:
        return action(path)
    except OSError as exc:
        raise OutputError(path, exc.strerror or str(exc)) from exc


def acquire_run_folder(out: Path) -> tuple[IO[str], list[str]]:
    """Create ``out`` if needed, refuse it if it cannot be a run folder, and lock it.

    Returns the locked marker and the files the previous runs into the folder registered.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(out, "a file is in the place of the output folder")
    file_op(out, lambda p: p.mkdir(parents=True, exist_ok=True))
    names = {p.name for p in file_op(out, lambda p: list(p.iterdir()))}
    if names and RUN_MARKER not in names:
        raise OutputError(out, f"not empty and not an ngbet run folder (it holds {', '.join(sorted(names)[:5])}"
                               f"{', ...' if len(names) > 5 else ''}; ngbet marks its run folders with "
                               f"{RUN_MARKER}); choose another --out")
    fh = file_op(out / RUN_MARKER, lambda p: p.open("a+"))
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        who = _marker_record(fh.read()).get("pid")
        fh.close()
        raise OutputError(out, f"busy: another ngbet run{f' (pid {who})' if who else ''} is writing into "
                               "it; wait for it or choose another --out") from None
    except OSError as exc:
        fh.close()
        raise OutputError(out / RUN_MARKER, exc.strerror or str(exc)) from exc
    try:
        same = os.fstat(fh.fileno()).st_ino == os.stat(out / RUN_MARKER).st_ino
    except OSError:
        same = False
    if not same:  # removed or replaced between opening and locking: another process is at work here
        fh.close()
        raise OutputError(out, f"its {RUN_MARKER} was removed or replaced while this run took the folder; "
                               "choose another --out")
    fh.seek(0)
    previous = _marker_record(fh.read()).get("files")
    if not isinstance(previous, list):  # a new folder: its marker is empty
        previous = []
    return fh, [n for n in previous if isinstance(n, str) and n and "/" not in n and not n.startswith(".")]


def remove_path(p: Path) -> None:
    """Remove a file, or a temporary folder with what is in it."""
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p)
    else:
        p.unlink(missing_ok=True)


def _marker_record(text: str) -> dict[str, Any]:
    """The marker's record (``pid``, ``files``); empty for a new marker or one that is not a JSON object."""
    try:
        rec = json.loads(text)
    except ValueError:
        return {}
    return rec if isinstance(rec, dict) else {}


def clear_previous_run(out: Path, registered: list[str]) -> list[Path]:
    """Remove the files previous ngbet runs registered in ``out`` (and their temporary files).

    Anything else stays (with a warning). A file with the name of one an ngbet run writes
    (:data:`RUN_FILE_PATTERNS`) that no run registered is the user's: the folder is refused before
    anything is removed, since this run would replace it.
    """
    listed = set(registered)
    present = sorted(p for p in out.iterdir() if p.is_file() and p.name != RUN_MARKER)
    clash = [p.name for p in present if p.name not in listed and not p.name.startswith(TMP_PREFIX)
             and any(fnmatch.fnmatchcase(p.name, pat) for pat in RUN_FILE_PATTERNS)]
    if clash:
        raise OutputError(out, f"holds {', '.join(clash)}, which no ngbet run registered there (they are not "
                               "ngbet's; this run would replace them): move them or choose another --out")
    gone = []
    for p in [*present, *(d for d in out.iterdir() if d.is_dir() and d.name.startswith(TMP_PREFIX))]:
        if p.name in listed or p.name.startswith(TMP_PREFIX):
            file_op(p, remove_path)
            gone.append(p)
    other = sorted(p.name for p in out.iterdir() if p.name != RUN_MARKER)
    if other:
        log.warning("%s: keeping %s (not written by ngbet)", out, ", ".join(other))
    return gone


def jsonable(o: Any) -> Any:
    """A JSON-writable stand-in for ``o`` (``json.dumps(default=...)``): arrays, sets, tuples as lists, else text."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, (set, tuple)):
        return list(o)
    return str(o)
