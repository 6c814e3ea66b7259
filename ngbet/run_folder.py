"""A run folder on disk: ngbet's mark and lock, what a run may remove or replace, atomic writes.

:class:`ngbet.output.RunWriter` takes a folder through :func:`acquire_run_folder` and
:func:`clear_previous_run` and writes every file with :func:`write_json_atomic` and :func:`file_op`;
nothing else writes into a run folder.
"""

from __future__ import annotations

import contextlib
import fcntl
import fnmatch
import functools
import json
import logging
import math
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from .errors import NgbetError

__all__ = [
    "FIGURE_SUFFIXES",
    "RUN_FILE_PATTERNS",
    "RUN_LOCK",
    "RUN_MARKER",
    "TMP_PREFIX",
    "OutputError",
    "acquire_run_folder",
    "clear_previous_run",
    "file_op",
    "jsonable",
    "link_or_copy",
    "remove_path",
    "write_json_atomic",
]

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
RUN_FILE_PATTERNS = (
    "scene.toml",
    "summary.json",
    "results.csv",
    "profile.csv",
    "fields*.vtu",
    "force.png",
    "force.pdf",
    "shear_force.png",
    "shear_force.pdf",
    "profile.png",
    "profile.pdf",
    "shear_map.png",
    "shear_map.pdf",
    "map_*.npz",
    "state_*.npz",
    "yarns_*.png",
    "instability_mode.vtu",
    "instability_mode.png",
)
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
        file_op(tmp, lambda p: p.write_text(json_text(data)))
        file_op(path, lambda p: os.replace(tmp, p))
    finally:
        tmp.unlink(missing_ok=True)


def file_op(path: Path, action: Callable[[Path], Any]) -> Any:
    """Run a file operation; an OSError becomes an OutputError naming the path."""
    try:
        return action(path)
    except FileNotFoundError as exc:
        raise OutputError(path, _why_not_found(path, exc)) from exc
    except OSError as exc:
        raise OutputError(path, exc.strerror or str(exc)) from exc


def _why_not_found(path: Path, exc: OSError) -> str:
    """A missing file's error; a relative path's when the current folder itself is gone says that."""
    if not path.is_absolute():
        try:
            os.getcwd()
        except FileNotFoundError:
            return (
                "the current folder no longer exists (deleted or moved), and this path is relative to it: "
                "change to a folder that exists, or give an absolute path"
            )
    return exc.strerror or str(exc)


def acquire_run_folder(out: Path) -> tuple[IO[str], list[str]]:
    """Create ``out`` if needed, refuse it if it cannot be a run folder, and lock it.

    Returns the locked marker and the files the previous runs into the folder registered.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(out, "a file is in the place of the output folder")
    file_op(out, lambda p: p.mkdir(parents=True, exist_ok=True))
    names = {p.name for p in file_op(out, lambda p: list(p.iterdir()))}
    if names and RUN_MARKER not in names:
        raise OutputError(
            out,
            f"not empty and not an ngbet run folder (it holds {', '.join(sorted(names)[:5])}"
            f"{', ...' if len(names) > 5 else ''}; ngbet marks its run folders with "
            f"{RUN_MARKER}); choose another --out",
        )
    fh = _in_folder(out, out / RUN_MARKER, lambda p: p.open("a+"))
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        who = _marker_record(fh.read()).get("pid")
        fh.close()
        raise OutputError(
            out,
            f"busy: another ngbet run{f' (pid {who})' if who else ''} is writing into "
            "it; wait for it or choose another --out",
        ) from None
    except OSError as exc:
        fh.close()
        raise OutputError(out / RUN_MARKER, exc.strerror or str(exc)) from exc
    try:
        same = os.fstat(fh.fileno()).st_ino == os.stat(out / RUN_MARKER).st_ino
    except OSError:
        same = False
    if not same:  # removed or replaced between opening and locking: another process is at work here
        fh.close()
        raise OutputError(
            out, f"its {RUN_MARKER} was removed or replaced while this run took the folder; choose another --out"
        )
    try:
        _probe_longest(out)
    except OutputError:
        fh.close()
        raise
    fh.seek(0)
    previous = _marker_record(fh.read()).get("files")
    if not isinstance(previous, list):  # a new folder: its marker is empty
        previous = []
    return fh, [n for n in previous if isinstance(n, str) and n and "/" not in n and not n.startswith(".")]


#: the deepest path a run writes below its folder: a temporary folder with a file in it (the figures)
_LONGEST = (TMP_PREFIX + "probe.xxxxxxxxxxxx", "x" * 40)


def _probe_longest(out: Path) -> None:
    """Write and remove a file at the longest path a run writes in ``out``.

    A folder whose path leaves no room for the run's names (the OS limits a path to PATH_MAX) is
    refused now, before the solve, rather than when its last files are written.
    """
    d = out / f"{_LONGEST[0]}{os.getpid()}"
    try:
        d.mkdir(exist_ok=True)
        (d / _LONGEST[1]).write_bytes(b"")
    except OSError as exc:
        raise OutputError(
            out,
            f"cannot hold the files of a run ({exc.strerror or exc} for a file "
            f"{len(str(d / _LONGEST[1])) - len(str(out))} characters deeper); choose a shorter "
            "--out",
        ) from None
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _in_folder(out: Path, path: Path, action: Callable[[Path], Any]) -> Any:
    """:func:`file_op` on ``path`` in the folder ``out`` as the folder is taken: its error names the folder."""
    try:
        return file_op(path, action)
    except OutputError as exc:
        why = str(exc).removeprefix(f"{path}: ")
        raise OutputError(
            out, f"cannot be written ({why}: {path.name}); make it writable or choose another --out"
        ) from None


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
    clash = [
        p.name
        for p in present
        if p.name not in listed
        and not p.name.startswith(TMP_PREFIX)
        and any(fnmatch.fnmatchcase(p.name, pat) for pat in RUN_FILE_PATTERNS)
    ]
    if clash:
        raise OutputError(
            out,
            f"holds {', '.join(clash)}, which no ngbet run registered there (they are not "
            "ngbet's; this run would replace them): move them or choose another --out",
        )
    doomed = [
        p
        for p in [*present, *(d for d in out.iterdir() if d.is_dir() and d.name.startswith(TMP_PREFIX))]
        if p.name in listed or p.name.startswith(TMP_PREFIX)
    ]
    gone = _remove_all_or_none(out, doomed)
    other = sorted(p.name for p in out.iterdir() if p.name != RUN_MARKER)
    if other:
        log.warning("%s: keeping %s (not written by ngbet)", out, ", ".join(other))
    return gone


def _remove_all_or_none(out: Path, doomed: list[Path]) -> list[Path]:
    """Remove ``doomed`` (files and folders in ``out``), all of them or none.

    Each is first moved into a temporary folder; when one cannot be moved (an immutable file, a
    folder turned read-only) the moved ones are put back and :class:`OutputError` names it: the
    previous run's files and its summary.json stay as they were, true.
    """
    if not doomed:
        return []
    trash = out / f"{TMP_PREFIX}previous.{os.getpid()}"
    file_op(trash, lambda p: p.mkdir(exist_ok=True))
    moved: list[Path] = []
    try:
        for p in doomed:
            os.rename(p, trash / p.name)
            moved.append(p)
    except OSError as exc:
        for m in reversed(moved):
            with contextlib.suppress(OSError):
                os.rename(trash / m.name, m)
        with contextlib.suppress(OSError):
            trash.rmdir()
        bad = doomed[len(moved)]
        raise OutputError(
            bad,
            f"cannot be removed ({exc.strerror or exc}), so the previous run's files cannot be "
            "replaced; nothing was removed: make it writable or choose another --out",
        ) from None
    shutil.rmtree(trash, ignore_errors=True)
    return doomed


#: how a complete file of each kind ends (the last bytes a writer puts there), looked for in its tail
_ENDINGS = {".vtu": b"</VTKFile>", ".png": b"IEND\xaeB`\x82", ".pdf": b"%%EOF", ".npz": b"PK\x05\x06"}


def check_complete(path: Path, final: Path) -> None:
    """Refuse a file that its writer left incomplete (:class:`OutputError` naming ``final``).

    Writers in compiled code (NGSolve's VTU output) stop silently when the disk is full or a file
    size limit (``ulimit -f``) is reached; the file's own ending (:data:`_ENDINGS`) tells a
    complete file from a cut one, so that no cut file is renamed into place or listed.
    """
    end = _ENDINGS.get(path.suffix)
    if end is None or not path.exists():
        return
    try:
        with path.open("rb") as fh:
            size = fh.seek(0, os.SEEK_END)
            fh.seek(max(0, size - 65536))
            tail = fh.read()
    except OSError as exc:
        raise OutputError(final, exc.strerror or str(exc)) from exc
    if end not in tail:
        raise OutputError(
            final,
            f"written incomplete ({size} bytes, without its ending): the disk is full or "
            "a file size limit (ulimit -f) was reached",
        )


def strict(o: Any) -> Any:
    """``o`` with every non-finite float (NaN, ±inf) replaced by None: JSON that every language reads."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: strict(v) for k, v in o.items()}
    if isinstance(o, (list, tuple, set)):
        return [strict(v) for v in o]
    if hasattr(o, "tolist") and not isinstance(o, (str, bytes)):
        return strict(o.tolist())
    return o


def json_text(data: Any) -> str:
    """Strict JSON of ``data`` (no bare NaN or Infinity: null), indented; numpy values as lists and numbers."""
    return json.dumps(strict(data), indent=2, default=jsonable, allow_nan=False)


def jsonable(o: Any) -> Any:
    """A JSON-writable stand-in for ``o`` (``json.dumps(default=...)``): arrays, sets, tuples as lists, else text."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, (set, tuple)):
        return list(o)
    return str(o)


#: the mark of a folder a study, a sweep or a fit writes (``ngbet run``'s is :data:`RUN_MARKER`); held
#: (``fcntl.flock``) while the command writes, it records the command and the files it wrote (JSON)
FOLDER_MARKER = ".ngbet-folder.json"
#: names a study or fit may write: one of these in its folder that the command did not write is the
#: user's, and the folder is refused before anything is written
FOLDER_FILE_PATTERNS = ("*.csv", "*.json", "*.md", "*.png", "*.pdf", "*.svg", "*.toml", "*.vtu", "*.npz")


class OwnedFolder:
    """The output folder of a study, a sweep or a fit, owned as ``ngbet run`` owns its run folder.

    The constructor refuses (:class:`OutputError`, before anything is written or removed): a file in
    the folder's place; an ``ngbet run`` folder; a non-empty folder without :data:`FOLDER_MARKER`;
    the folder of another command (``kind``, ``name``: "study"/"alpha1", "study"/"sweep",
    "fit"/"fit"); a folder busy with another command; an unwritable folder; a file with a name the
    command may write (:data:`FOLDER_FILE_PATTERNS`) that the command did not write there before.
    :meth:`remove` removes files the command wrote before (and only those); :meth:`finish`
    registers what this command wrote (every file created or replaced meanwhile) and removes what
    the earlier command wrote and this one did not (an earlier study's figures); :meth:`release`
    unlocks. The folder's other files (the user's notes) are never touched.
    """

    def __init__(self, out: str | Path, kind: str, name: str) -> None:
        self.out, self.kind, self.name = Path(out), kind, name
        out = self.out
        if out.exists() and not out.is_dir():
            raise OutputError(out, "a file is in the place of the output folder")
        file_op(out, lambda p: p.mkdir(parents=True, exist_ok=True))
        names = {p.name for p in file_op(out, lambda p: list(p.iterdir()))}
        if RUN_MARKER in names:
            raise OutputError(
                out,
                f"an ngbet run folder (it holds {RUN_MARKER}); a {kind} writes a folder of its "
                "own: choose another --out",
            )
        if names and FOLDER_MARKER not in names:
            raise OutputError(
                out,
                f"not empty and not written by an ngbet {kind} (it holds "
                f"{', '.join(sorted(names)[:5])}{', ...' if len(names) > 5 else ''}; ngbet marks "
                f"the folders it writes with {FOLDER_MARKER}); choose another --out",
            )
        self._fh: IO[str] | None = _in_folder(out, out / FOLDER_MARKER, lambda p: p.open("a+"))
        self._before: dict[str, tuple[int, int, int]] = {}
        self.previous: list[str] = []
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.close()
            self._fh = None
            raise OutputError(
                out, "busy: another ngbet command is writing into it; wait for it or choose another --out"
            ) from None
        try:
            self._fh.seek(0)
            rec = _marker_record(self._fh.read())
            if rec and (rec.get("kind"), rec.get("name")) != (kind, name):
                raise OutputError(
                    out,
                    f"the folder of the {rec.get('kind')} {rec.get('name')!r}, not of the {kind} "
                    f"{name!r}: choose another --out",
                )
            files = rec.get("files")
            self.previous = [n for n in files if isinstance(n, str) and "/" not in n] if isinstance(files, list) else []
            clash = sorted(
                n
                for n in names - {*self.previous, FOLDER_MARKER}
                if (out / n).is_file() and any(fnmatch.fnmatchcase(n, pat) for pat in FOLDER_FILE_PATTERNS)
            )
            if clash:
                raise OutputError(
                    out,
                    f"holds {', '.join(clash)}, which no ngbet {kind} wrote there (this {kind} "
                    "could replace them): move them or choose another --out",
                )
            probe = out / f"{TMP_PREFIX}probe.{os.getpid()}"
            _in_folder(out, probe, lambda p: p.write_bytes(b""))
            probe.unlink()
            self._before = self._stat_files()
            self._save(self.previous)
        except BaseException:
            self._fh.close()
            self._fh = None
            raise

    def _stat_files(self) -> dict[str, tuple[int, int, int]]:
        out: dict[str, tuple[int, int, int]] = {}
        for p in self.out.iterdir():
            if p.name != FOLDER_MARKER and not p.name.startswith(TMP_PREFIX) and p.is_file():
                st = p.stat()
                out[p.name] = (st.st_ino, st.st_mtime_ns, st.st_size)
        return out

    def _save(self, files: list[str]) -> None:
        fh = self._fh
        if fh is None:
            return
        text = json.dumps(
            {"ngbet": "folder", "kind": self.kind, "name": self.name, "pid": os.getpid(), "files": sorted(set(files))}
        )
        file_op(self.out / FOLDER_MARKER, lambda p: (fh.seek(0), fh.truncate(), fh.write(text), fh.flush()))

    def write(self, name: str, produce: Callable[[Path], Any]) -> Path:
        """Write the file ``name`` complete: ``produce(tmp)`` writes a temporary file, renamed when complete.

        A file its writer left incomplete (:func:`check_complete`) is never renamed into place; the
        temporary file is removed whatever happens.
        """
        final = self.out / name
        tmp = self.out / (TMP_PREFIX + name)
        try:
            file_op(tmp, produce)
            check_complete(tmp, final)
            file_op(final, lambda p: os.replace(tmp, p))
        finally:
            tmp.unlink(missing_ok=True)
        return final

    def remove(self, *names: str) -> None:
        """Remove files of ``names`` that a command of this folder wrote (a user's file is never removed)."""
        for n in names:
            if n in self.previous:
                file_op(self.out / n, lambda p: p.unlink(missing_ok=True))

    def set_aside(self, names: Sequence[str], prefix: str) -> list[str]:
        """Rename each of ``names`` that the earlier command wrote to ``prefix`` + its name; returns the new names.

        The renamed files stay the earlier command's (the marker lists them at once, also for a
        process that ends without :meth:`release`): :meth:`finish` removes them as it removes every
        earlier file this command does not write again; after an error they stay. A file of the
        new name that the earlier command wrote is replaced; one it did not write is refused
        (:class:`OutputError`), nothing renamed after it.
        """
        done = []
        for n in names:
            old, new = self.out / n, self.out / (prefix + n)
            if n not in self.previous or not old.is_file():
                continue
            if new.exists() and new.name not in self.previous:
                raise OutputError(new, f"not written by an ngbet {self.kind}: move it, or choose another --out")
            file_op(new, functools.partial(os.replace, old))
            self.previous = sorted({*(x for x in self.previous if x != n), new.name})
            st = new.stat()
            self._before.pop(n, None)
            self._before[new.name] = (st.st_ino, st.st_mtime_ns, st.st_size)
            done.append(new.name)
        self.register()
        return done

    def register(self) -> None:
        """List in the marker every file the earlier command left and this one wrote so far (nothing removed).

        The marker then names this command's files even where its process ends without
        :meth:`release` (killed): the next command takes them as ngbet's.
        """
        self._save(sorted({*self.previous, *self.written()}))

    def written(self) -> list[str]:
        """The files created or replaced in the folder since it was taken."""
        before = self._before
        return sorted(n for n, st in self._stat_files().items() if before.get(n) != st)

    def finish(self, stale: bool = True) -> list[str]:
        """Register what this command wrote; with ``stale``, remove the earlier files it did not write again.

        ``stale=False`` (a redraw: figures and report from the tables) keeps every earlier file.
        Returns the files removed.
        """
        now = self.written()
        gone = [n for n in self.previous if n not in now and (self.out / n).is_file()] if stale else []
        for n in gone:
            file_op(self.out / n, lambda p: p.unlink(missing_ok=True))
        self.previous = sorted({*now, *(n for n in self.previous if n not in gone)}) if not stale else now
        self._save(self.previous)
        self._before = self._stat_files()
        return gone

    def release(self) -> None:
        """Unlock the folder, registering what was written meanwhile (the marker stays: it marks the folder).

        After an error nothing is removed: the earlier command's files stay, with this one's.
        """
        if self._fh is not None:
            try:
                self.register()
            except (OSError, NgbetError) as exc:
                log.error("%s: could not record the files written: %s", self.out, exc)
            finally:
                self._fh.close()
                self._fh = None

    def __enter__(self) -> OwnedFolder:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        """On success :meth:`finish`; on an error only what was written is registered; then unlock."""
        try:
            if exc_type is None:
                self.finish()
        finally:
            self.release()
