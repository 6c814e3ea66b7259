"""Writing a run to disk, step by step, so that nothing converged is ever lost.

Layout of a run folder (both models)::

    scene.toml        the complete scene that produced everything beside it
    results.csv       one row per converged load step (written and flushed as each step converges)
    profile.csv       mid-axis (Y = W/2) vertical displacement, one block per step: step,u0_mm,X_mm,uy_mm
    summary.json      scene, versions, dofs, timings, status: "running" from the start, then "ok",
                      "failed" or "interrupted" with the last converged load (written atomically)
    .ngbet.lock       ngbet's mark of a run folder: held (fcntl.flock) while a run writes into the
                      folder; lists the files the runs registered
    fields_*.vtu      fields for ParaView
    force.png/.pdf    force-displacement plot

:class:`RunWriter` is the one writer of a run folder: the runners hand it every file (the numerics
write none), it writes each complete under a temporary name and renames it, and registers it.
:func:`read_rows` is the one reader of the tables. Plotting reads these files; nothing in the
physics imports this module.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import IO, Any, cast

from .errors import NgbetError
from .numerics.engine import uninterrupted
from .preflight import preflight
from .provenance import git_revision, machine, versions
from .run_folder import (
    FIGURE_SUFFIXES,
    RUN_MARKER,
    TMP_PREFIX,
    OutputError,
    acquire_run_folder,
    check_complete,
    clear_previous_run,
    file_op,
    json_text,
    link_or_copy,
    remove_path,
    write_json_atomic,
)
from .scene.document import Scene
from .tables import append_lines, append_rows, write_table

log = logging.getLogger(__name__)

__all__ = ["RunWriter", "interrupt_active_runs"]


class RunWriter:
    """The one writer of a run folder: every file of a run is written, and registered, through it.

    Lifecycle: the constructor refuses a folder that is a file, not writable, not an ngbet run
    folder (non-empty without the marker :data:`RUN_MARKER`), holding a file with an ngbet name
    that no run registered (:data:`RUN_FILE_PATTERNS`), or locked by another run (``fcntl.flock``
    on the marker); then removes the files the previous runs registered (nothing else) and writes
    ``scene.toml`` and summary.json with ``"status": "running"``. ``data``: the measured curve the
    figures draw (``--data``), named in every summary.json with its SHA-256 (``data``).

    Every file is written complete under a temporary name (:data:`TMP_PREFIX`) and renamed into
    place (:meth:`write`, :meth:`write_text`, :meth:`write_group`; the force plot drawn in a
    temporary folder, :meth:`plot`), and registered in the marker as it is written; summary.json
    lists them (``files``). The exceptions are the two tables that grow by a row per converged
    step: results.csv (header: the union of the columns of all rows, in the order they first
    appear; a column that first appears at a later step rewrites the file under a temporary name)
    and profile.csv are appended to and flushed. Files that appear in the
    folder by other means during a run are not ngbet's: never registered, never removed.

    :meth:`summary` records "ok" or "failed"; leaving the ``with`` block on Ctrl-C/SIGTERM (any signal
    the command line turns into KeyboardInterrupt, named in the error) records
    "interrupted", on any other exception "failed" with the error, both with the last converged
    load; then the lock is released.
    """

    def __init__(self, out: str | Path, scene: Scene, data: str | Path | None = None) -> None:
        self.out = Path(out)
        self.scene = scene
        self.rows: list[dict[str, Any]] = []
        self.status = "new"
        self.t_start = time.perf_counter()
        # what every summary.json of this run carries, from the first ("running") to the last
        self._base: dict[str, Any] = {"pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        if data is not None:  # the measured curve drawn on the figures (``--data``): which file, which bytes
            path = Path(data).resolve()
            self._base["data"] = {"file": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
        self._summary: dict[str, Any] = {}
        self._columns: list[str] = []
        self._files: list[str] = []  # registered by this run, in the order written
        self.warnings: list[str] = preflight(scene)  # refuses before the folder is touched
        self._lock: IO[str] | None = None
        self._lock, previous = acquire_run_folder(self.out)
        _ACTIVE.add(self)
        try:
            cleared = clear_previous_run(self.out, previous)
            if cleared:
                log.info("%s: removed %d files of a previous run", self.out, len(cleared))
            self._save_registry()
            self.write_text("scene.toml", scene.to_toml())
            self.summary({}, "running")
        except BaseException:
            self.release()
            raise

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        """Ctrl-C or SIGTERM leaves "interrupted", any other escape "failed"; then the folder is unlocked.

        Unless the run said so already; each with the last converged load.
        """
        try:
            if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
                # the solver's statistics until then, where it attached them (the network's)
                why = str(exc) if str(exc).startswith("SIG") else "SIGINT/SIGTERM"  # the CLI's handler names it
                self.summary(
                    dict(getattr(exc, "path_info", {})),
                    "interrupted",
                    f"interrupted ({why}) after u0 = {self.last_converged_mm:g} mm",
                )
            elif exc_type is not None and self.status == "running":
                self.summary({"error_type": exc_type.__name__}, "failed", f"{exc_type.__name__}: {exc}")
            elif self._summary and self._summary.get("files") != self.files():
                self._write_summary()
        except (OSError, NgbetError) as err:  # the folder itself failed: the original error says more
            log.error("could not record the end of the run in %s: %s", self.out, err)
        finally:
            if self._lock is not None:  # what a write cut short left behind
                with contextlib.suppress(OSError):
                    for t in self.out.glob(TMP_PREFIX + "*"):
                        remove_path(t)
            self.release()

    # registered files ------------------------------------------------------------------------
    def files(self) -> list[str]:
        """The files this run registered that are in the folder (sorted)."""
        return sorted(n for n in self._files if (self.out / n).is_file())

    def _register(self, name: str) -> None:
        if "/" in name or name.startswith(".") or not name:
            raise ValueError(f"not a file name of a run folder: {name!r}")
        if name not in self._files:
            self._files.append(name)
            self._save_registry()

    def _save_registry(self) -> None:
        """The marker's record: this run's pid and the files it registered (rewritten in place: the lock stays)."""
        fh = self._lock
        if fh is None:
            return
        text = json.dumps({"ngbet": "run folder", "pid": os.getpid(), "files": self._files})
        file_op(self.out / RUN_MARKER, lambda p: (fh.seek(0), fh.truncate(), fh.write(text), fh.flush()))

    def plot(self, start: Callable[[Path], Callable[[], Path | None]]) -> Callable[[], Path | None]:
        """Start drawing the run's figures from its finished files; the function returned finishes it.

        ``start(folder)`` (the runner's: :func:`ngbet.figures.run.start_plot`) starts drawing the figures
        of the run files in ``folder``, a temporary folder of links to the files this run registered,
        and returns a function that waits for the drawing. The function returned here waits, renames
        every PNG and PDF drawn into the run folder, registered, and returns the force figure's file
        (None when nothing was drawn). A drawing cut short leaves no figure.
        """
        tmp = self.out / (TMP_PREFIX + "plot")
        shutil.rmtree(tmp, ignore_errors=True)
        file_op(tmp, lambda d: d.mkdir())
        for name in self.files():
            if not name.endswith(FIGURE_SUFFIXES):
                file_op(tmp / name, functools.partial(link_or_copy, self.out / name))
        drawn = start(tmp)

        def finish() -> Path | None:
            try:
                png = drawn()
                done = {}
                for fig in sorted(tmp.iterdir()):
                    if fig.name.endswith(FIGURE_SUFFIXES) and fig.is_file():
                        final = self._target(fig.name)
                        self._register(fig.name)
                        file_op(final, functools.partial(os.replace, fig))
                        done[fig.name] = final
                if done and self.status not in ("new", "running"):
                    self._write_summary()
                return done.get(png.name) if png is not None else None
            finally:
                shutil.rmtree(tmp, ignore_errors=True)

        return finish

    def write(self, name: str, produce: Callable[[Path], Any]) -> Path | None:
        """Write the file ``name``: ``produce(tmp)`` writes it complete at ``tmp``, which is then renamed.

        ``tmp`` ends like ``name`` (writers that choose the format by the suffix see the right one).
        An existing file of that name that this run did not register is never replaced
        (:class:`OutputError`). Returns the final path, or None when ``produce`` wrote nothing
        (a figure without matplotlib).
        """
        final = self._target(name)
        tmp = self.out / (TMP_PREFIX + name)
        self._register(name)
        try:
            try:
                file_op(tmp, produce)
            except OutputError as exc:  # named as the file it becomes, not its temporary name
                if exc.path != tmp:
                    raise
                raise OutputError(final, str(exc)[len(str(tmp)) + 2 :]) from exc
            except Exception:  # a reader of a cut file (the VTU's rescaling) fails: the cut is the cause
                check_complete(tmp, final)
                raise
            if not tmp.exists():
                return None
            check_complete(tmp, final)
            file_op(final, lambda p: os.replace(tmp, p))
        finally:
            tmp.unlink(missing_ok=True)
        return final

    def write_text(self, name: str, text: str) -> None:
        """Write a text file (see :meth:`write`)."""
        self.write(name, lambda p: p.write_text(text))

    def write_json(self, name: str, data: Any) -> None:
        """Write a JSON file (see :meth:`write`)."""
        self.write_text(name, json_text(data))

    def write_group(self, stem: str, produce: Callable[[Path], Iterable[Path]]) -> list[Path]:
        """Write files that one writer makes together, ``stem`` + a suffix each (a VTU file and its picture).

        ``produce(tmp_stem)`` writes them as ``tmp_stem`` + suffix and returns their paths; each is
        renamed to ``stem`` + its suffix and registered. Returns the final paths.
        """
        tmp_stem = self.out / (TMP_PREFIX + stem)
        made: list[Path] = []
        try:
            made = [Path(p) for p in file_op(tmp_stem, lambda p: list(produce(p)))]
            done = []
            for m in made:
                if not m.name.startswith(tmp_stem.name):
                    raise ValueError(f"{m}: not a file of the group {tmp_stem}")
                name = stem + m.name[len(tmp_stem.name) :]
                final = self._target(name)
                check_complete(m, final)
                self._register(name)
                file_op(final, functools.partial(os.replace, m))
                done.append(final)
            return done
        finally:
            for m in made:
                m.unlink(missing_ok=True)

    def _target(self, name: str) -> Path:
        final = self.out / name
        if name not in self._files and final.exists():
            raise OutputError(final, "exists and was not written by this run; ngbet does not replace it")
        return final

    def release(self) -> None:
        """Unlock the folder (the marker stays: it marks the folder as ngbet's, and removing it would race)."""
        _ACTIVE.discard(self)
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    @property
    def last_converged_mm(self) -> float:
        """The last converged clamp displacement [mm] (0 before the first step)."""
        return float(self.rows[-1]["u0_mm"]) if self.rows else 0.0

    # the growing tables ----------------------------------------------------------------------
    def add_step(self, row: dict[str, Any], profile: Sequence[tuple[float, float]] | None = None) -> None:
        """Write one converged step (and its mid-axis profile) and flush it to disk.

        The header of results.csv is the union of the columns of all rows so far: a row with a new
        column rewrites the file (complete, under a temporary name) with it, earlier rows empty there.
        """
        new = [k for k in row if k not in self._columns]
        columns = [*self._columns, *new]
        # a stop signal waits until the row is on disk and counted: summary.json's steps = the file's rows
        with uninterrupted():
            if new:
                self.write("results.csv", lambda p: write_table(p, columns, [*self.rows, row]))
            else:
                file_op(self.out / "results.csv", lambda p: append_rows(p, columns, [row]))
            self._columns = columns
            self.rows.append(row)
        if profile is not None:
            block = [[row["step"], row["u0_mm"], f"{X_mm:.6g}", f"{uy_mm:.9g}"] for X_mm, uy_mm in profile]
            if "profile.csv" in self._files:
                file_op(self.out / "profile.csv", lambda p: append_lines(p, block))
            else:
                self.write("profile.csv", lambda p: append_lines(p, [["step", "u0_mm", "X_mm", "uy_mm"], *block]))

    # summary.json ----------------------------------------------------------------------------
    def summary(self, info: dict[str, Any], status: str, error: str | None = None) -> dict[str, Any]:
        """Write summary.json atomically (at the start, at the end, and on failure with the error).

        Returns the summary; the same dict is kept up to date with the files registered later.
        """
        s = {
            "status": status,
            "error": error,
            "scene": self.scene.to_dict(),
            "scene_digest": self.scene.digest(),
            "versions": versions(),
            "git_revision": git_revision(),
            "machine": machine(),
            "steps": len(self.rows),
            "u0_reached_mm": self.last_converged_mm,
            "last_converged_mm": self.last_converged_mm,
            "wall_s": time.perf_counter() - self.t_start,
            **self._base,
            **info,
        }
        s["steps"] = len(self.rows)  # the rows on disk, whatever a solver's statistics counted (an interrupt in a step)
        s["warnings"] = [*self.warnings, *info.get("warnings", [])]
        self._summary.clear()
        self._summary.update(s)
        self._write_summary()
        self.status = status
        return self._summary

    def _write_summary(self) -> None:
        self._register("summary.json")
        self._summary["files"] = sorted(n for n in self._files if n == "summary.json" or (self.out / n).is_file())
        self.write_json("summary.json", self._summary)

    @classmethod
    def amend(cls, out: str | Path, updates: dict[str, Any], scene: Scene | None = None) -> dict[str, Any]:
        """Add ``updates`` to the summary.json of a finished run in ``out`` (under its lock); returns it.

        ``files`` is taken from the folder's registry, the rest of the summary is kept. ``scene``:
        the scene the folder answers for, where it is not the one that was solved (an accuracy
        target's, whose ladder solved it on a discretization of its own choice): it replaces
        scene.toml (atomically) and the summary's ``scene`` and ``scene_digest``, so that running
        scene.toml again, or a study's cache, finds the scene that was asked for.
        """
        out = Path(out)
        fh, registry = acquire_run_folder(out)
        try:
            if scene is not None:
                tmp = out / (TMP_PREFIX + "scene.toml")
                try:
                    file_op(tmp, lambda p: p.write_text(scene.to_toml()))
                    file_op(out / "scene.toml", lambda p: os.replace(tmp, p))
                finally:
                    tmp.unlink(missing_ok=True)
                updates = {**updates, "scene": scene.to_dict(), "scene_digest": scene.digest()}
            s = json.loads(file_op(out / "summary.json", lambda p: p.read_text()))
            s.update(updates)
            s["files"] = sorted(n for n in registry if (out / n).is_file())
            write_json_atomic(out / "summary.json", s)
            return cast("dict[str, Any]", s)
        finally:
            fh.close()


_ACTIVE: set[RunWriter] = set()


def interrupt_active_runs(reason: str) -> list[Path]:
    """Record "interrupted" in every run folder still open in this process; returns the folders.

    For a watchdog thread when the main thread cannot act.
    """
    done = []
    for w in list(_ACTIVE):
        if w.status == "running":
            try:
                w.summary({}, "interrupted", f"{reason}; last converged u0 = {w.last_converged_mm:g} mm")
                done.append(w.out)
            except (OSError, NgbetError) as exc:
                log.error("could not record the interruption in %s: %s", w.out, exc)
    return done
