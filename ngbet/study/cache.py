"""The case cache: one verified folder per case, stored atomically, and the locks of live studies.

    cache/<key>/                  a finished case: ngbet.run.run's folder + case.json (checksums)
    cache/.study-<token>.lock     held (fcntl.flock) by a running study for as long as it runs
    cache/.run-<key>-<token>/     a case being computed by the study <token>
    cache/.tmp-<key>-<token>-*/   a case being stored (milliseconds)

A ``.run-*`` or ``.tmp-*`` folder belongs to the study whose token it carries; it is debris, and
removed by the next study, only when that study's lock is not held: the lock is an advisory lock
the kernel releases when the process ends, however it ends, so a live study (also a stopped or
slow one) never loses its folders to another, and a killed one's are removed at once.

Trust: case.json records the sha256 of every file of the case; each cached case is verified on
every read (checksums; the folder's own key, recomputed from the scene.toml inside it, so that
two case folders swapped or renamed are caught; summary.json's status against case.json's; its step
count and last load against results.csv) and a damaged one is recomputed with a warning naming
the file.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import math
import os
import shutil
import uuid
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..run_folder import RUN_LOCK
from ..scene.document import Scene, SceneWarning
from ..scene.validate import SceneError
from ..tables import read_rows
from .keys import key_of_scene_dict

__all__ = [
    "CacheError",
    "cached",
    "clean_debris",
    "held",
    "reached",
    "run_dir",
    "sha256",
    "store",
    "study_lock",
    "verify_case",
]

log = logging.getLogger(__name__)


class CacheError(ValueError):
    """A cached case that cannot be trusted; the message names the file and what is wrong."""


# ------------------------------------------------------------------------------- live studies
@contextlib.contextmanager
def study_lock(cache: Path) -> Iterator[str]:
    """Hold the lock of a running study in ``cache``; yields its token (in its folders' names).

    The lock file is created under a name no cleaner removes, locked, then renamed into place, so
    that it is never seen unlocked. An unwritable cache is an OSError naming it, before anything runs.
    """
    token = uuid.uuid4().hex[:12]
    fresh = cache / f".lock-new-{token}"
    lock = cache / f".study-{token}.lock"
    try:
        fd = os.open(fresh, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
    except OSError as exc:  # named as the folder the user gave
        raise OSError(
            exc.errno, f"{exc.strerror} (a study writes its cases into its cache folder)", str(cache)
        ) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.rename(fresh, lock)
        yield token
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        with contextlib.suppress(OSError):
            fresh.unlink()
        os.close(fd)


def run_dir(cache: Path, key: str, token: str) -> Path:
    """The folder a case of the study ``token`` is computed in."""
    return cache / f".run-{key}-{token}"


def _owner(name: str) -> str | None:
    """The study token of a ``.run-<key>-<token>`` or ``.tmp-<key>-<token>-<random>`` folder."""
    parts = name.split("-")
    return parts[2] if len(parts) >= 3 and parts[2] else None


def held(lock: Path) -> bool:
    """Whether a live process holds the advisory lock on ``lock`` (False when it does not exist)."""
    try:
        fd = os.open(lock, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing releases the probe's own lock
    return False


def clean_debris(cache: Path) -> int:
    """Remove the folders of studies that no longer run; returns how many.

    A ``.run-*``/``.tmp-*`` folder is kept while its study's lock is held (or, for a ``.run-*``,
    while the run in it holds its run lock); the lock files of ended studies go too.
    """
    n = 0
    for d in sorted([*cache.glob(".run-*"), *cache.glob(".tmp-*")]):
        token = _owner(d.name)
        if not d.is_dir() or (token and held(cache / f".study-{token}.lock")) or held(d / RUN_LOCK):
            continue
        shutil.rmtree(d, ignore_errors=True)
        n += 1
    for lock in cache.glob(".study-*.lock"):
        if not held(lock):
            with contextlib.suppress(OSError):
                lock.unlink()
    return n


# ------------------------------------------------------------------------------- storing
def store(
    cache: Path,
    key: str,
    rec: dict[str, Any],
    token: str,
    workdir: Path | None = None,
    files: dict[str, bytes] | None = None,
) -> Path:
    """Move a finished case into ``cache/<key>`` atomically (a rename); returns that folder.

    The case is ``workdir`` (moved) or ``files`` (written, as a dask worker returned them). Its
    case.json gets the key and the sha256 of every file (what :func:`verify_case` checks). A case
    already there (a failed one retried, or the same scene finished by another study) is replaced.
    """
    tmp = cache / f".tmp-{key}-{token}-{uuid.uuid4().hex[:8]}"
    final = cache / key
    try:
        if workdir is not None and workdir.exists():
            workdir.rename(tmp)
        else:
            tmp.mkdir(parents=True)
        for name, data in (files or {}).items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)
        (tmp / RUN_LOCK).unlink(missing_ok=True)
        rec = {
            **rec,
            "key": key,
            "files_sha256": {
                p.relative_to(tmp).as_posix(): sha256(p)
                for p in sorted(tmp.rglob("*"))
                if p.is_file() and p.name != "case.json"
            },
        }
        (tmp / "case.json").write_text(json.dumps(rec, indent=2, default=str))
        if final.exists():
            old = cache / f".tmp-{key}-{token}-old{uuid.uuid4().hex[:6]}"
            with contextlib.suppress(FileNotFoundError):  # another study may have just replaced it
                final.rename(old)
            shutil.rmtree(old, ignore_errors=True)
        try:
            tmp.rename(final)
        except OSError:
            if not final.is_dir():
                raise
            # the same scene stored meanwhile by another study sharing the cache: the same result
            # (same scene, same code); keep that one, whole, and drop ours
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:  # an interrupt or a full disk: no half-stored case is left behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def sha256(path: Path) -> str:
    """The sha256 of a file's bytes."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# ------------------------------------------------------------------------------- reading
def verify_case(case_dir: Path) -> dict[str, Any]:
    """The record of a cached case after checking it; :class:`CacheError` naming the file otherwise.

    Checked: case.json is complete JSON with a status and the sha256 of each file; every file is
    there with that checksum; the folder's name is the key of the scene.toml inside it (a folder
    renamed or swapped with another is caught); summary.json agrees with case.json (status) and
    with results.csv (number of steps, last load).
    """
    case_json = case_dir / "case.json"
    rec = _json_file(case_json)
    sums = rec.get("files_sha256")
    if rec.get("status") not in ("ok", "failed") or not isinstance(sums, dict) or not sums:
        raise CacheError(f"{case_json}: no status or no checksums (incomplete, or written by an older ngbet)")
    for name, digest in sums.items():
        f = case_dir / name
        if not f.is_file():
            raise CacheError(f"{f}: missing")
        if sha256(f) != digest:
            raise CacheError(f"{f}: checksum mismatch (changed or truncated since it was cached)")
    _check_key(case_dir, rec)
    summary = _json_file(case_dir / "summary.json")
    if summary.get("status") != rec["status"]:
        raise CacheError(
            f"{case_dir / 'summary.json'}: status {summary.get('status')!r} but case.json says {rec['status']!r}"
        )
    steps = read_rows(case_dir / "results.csv") if (case_dir / "results.csv").exists() else []
    if len(steps) != summary.get("steps") or (
        steps
        and not math.isclose(
            float(steps[-1].get("u0_mm", math.nan)), float(summary.get("u0_reached_mm", math.nan)), abs_tol=1e-9
        )
    ):
        raise CacheError(f"{case_dir / 'results.csv'}: {len(steps)} steps do not match summary.json")
    return rec


def _check_key(case_dir: Path, rec: dict[str, Any]) -> None:
    """The folder's name is its own key: recorded in case.json and recomputed from its scene.toml."""
    if rec.get("key") not in (None, case_dir.name):
        raise CacheError(
            f"{case_dir / 'case.json'}: stored under the key {rec['key']}, found in {case_dir.name} "
            "(folders renamed or swapped)"
        )
    try:
        with warnings.catch_warnings():  # a scene's unused keys were warned about when it ran
            warnings.simplefilter("ignore", SceneWarning)
            key = key_of_scene_dict(Scene.from_toml(case_dir / "scene.toml").to_dict())
    except (SceneError, OSError, ValueError) as exc:
        raise CacheError(f"{case_dir / 'scene.toml'}: unreadable ({exc})") from None
    if key != case_dir.name:
        raise CacheError(
            f"{case_dir / 'scene.toml'}: the scene's key is {key}, not the folder's "
            f"{case_dir.name} (folders renamed or swapped, or another code version)"
        )


def _json_file(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise CacheError(f"{path}: missing") from None
    except (OSError, ValueError) as exc:
        raise CacheError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise CacheError(f"{path}: not a JSON object")
    return data


def cached(case_dir: Path) -> dict[str, Any] | None:
    """The verified record of a cached case, or None (absent, or damaged: then a warning names the file)."""
    if not case_dir.exists():
        return None
    try:
        return verify_case(case_dir)
    except CacheError as exc:
        log.warning("cached case not trusted, it is recomputed: %s", exc)
        return None


def reached(workdir: Path) -> float:
    """Last converged u0 [mm] of a running case (read from its results.csv)."""
    try:
        rows = read_rows(workdir / "results.csv")
        return float(rows[-1]["u0_mm"]) if rows else 0.0
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0
