"""Writing a run to disk, step by step, so that nothing converged is ever lost.

Layout of a run folder (both models)::

    scene.toml        the complete scene that produced everything beside it
    results.csv       one row per converged load step (written and flushed as each step converges)
    profile.csv       mid-axis (Y = W/2) vertical displacement, one block per step: step,u0_mm,X_mm,uy_mm
    summary.json      scene, versions, dofs, timings, status: "running" from the start, then "ok",
                      "failed" or "interrupted" with the last converged load (written atomically)
    .ngbet.lock       held (fcntl.flock) while a run writes into the folder
    fields_*.vtu      fields for ParaView
    force.png/.pdf    force-displacement plot

Plotting reads these files; nothing in the physics imports this module.
"""

from __future__ import annotations

import csv
import fcntl
import fnmatch
import json
import logging
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import IO, Any

from .errors import NgbetError
from .scene import Scene

log = logging.getLogger(__name__)


#: module -> the distribution that installs it
DISTRIBUTIONS = {"ngbet": "ngbet", "ngsolve": "ngsolve", "netgen": "netgen-mesher", "numpy": "numpy", "scipy": "scipy"}


def versions() -> dict[str, str]:
    """Versions of the libraries a result depends on.

    The ``__version__`` of a module already imported (ngbet itself, NGSolve in a run), else the
    installed package's metadata (no import: a study's process need not import NGSolve to name its
    version); a module installed without metadata is imported; one not installed is left out.
    """
    import sys
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str] = {"python": platform.python_version()}
    for mod, dist in DISTRIBUTIONS.items():
        try:
            m = sys.modules.get(mod)
            out[mod] = str(getattr(m, "__version__", "unknown")) if m is not None else version(dist)
        except PackageNotFoundError:
            try:
                out[mod] = str(getattr(__import__(mod), "__version__", "unknown"))
            except Exception:  # pragma: no cover - optional modules
                pass
    return out


def git_revision(path: Path | None = None) -> str:
    """The git revision of ngbet (the checkout's, or the one recorded at install), or 'unknown'."""
    from .revision import revision

    return revision()


def machine() -> dict[str, Any]:
    """The machine a run ran on (node, architecture, CPUs, system), for summary.json."""
    import os

    return {"node": platform.node(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "system": platform.platform()}


RUN_LOCK = ".ngbet.lock"
# what an ngbet run writes into its folder; only these (and the files the previous summary.json
# lists) are removed when a folder is reused
RUN_FILE_PATTERNS = ("scene.toml", "summary.json", "summary.json.tmp", "results.csv", "profile.csv",
                     "fields*.vtu", "fields*.pvd", "force.png", "force.pdf", "state_*.npz", "yarns_*.png",
                     "yarns_*.pdf", "instability_mode.vtu", "instability_mode.png")
_RUN_MARKERS = (RUN_LOCK, "summary.json", "scene.toml")


class OutputError(NgbetError):
    """The output folder cannot be used.

    Not writable, a file in its place, busy with another run, or not an ngbet run folder. ``path`` names it.
    """

    def __init__(self, path: str | Path, why: str) -> None:
        super().__init__(f"{path}: {why}")
        self.path = Path(path)


class RunWriter:
    """The run folder of one run: locked, cleared of a previous run, its status kept in summary.json.

    Lifecycle: the constructor refuses a folder that is a file, not writable, not an ngbet run
    folder (non-empty without ``summary.json``/``scene.toml``/``.ngbet.lock``) or locked by another
    run (``fcntl.flock`` on ``.ngbet.lock``; the OS releases it when that process dies), then
    removes what a previous run wrote (``RUN_FILE_PATTERNS`` and the files its summary.json lists;
    nothing else) and writes ``scene.toml`` and summary.json with ``"status": "running"``. Each
    converged step is appended to results.csv and flushed. :meth:`summary` records "ok" or
    "failed"; leaving the ``with`` block on Ctrl-C/SIGTERM records "interrupted", on any other
    exception "failed" with the error, both with the last converged load; then the lock is released.
    """

    def __init__(self, out: str | Path, scene: Scene) -> None:
        self.out = Path(out)
        self.scene = scene
        self.rows: list[dict[str, Any]] = []
        self.status = "new"
        self.t_start = time.perf_counter()
        # what every summary.json of this run carries, from the first ("running") to the last
        self._base = {"pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        self.warnings: list[str] = preflight(scene)  # refuses before the folder is touched
        self._lock: IO[str] | None = _acquire_run_folder(self.out)
        _ACTIVE.add(self)
        try:
            cleared = _clear_previous_run(self.out)
            if cleared:
                log.info("%s: removed %d files of a previous run", self.out, len(cleared))
            self._kept = {p.name for p in self.out.iterdir()}
            _io(self.out / "scene.toml", lambda p: p.write_text(scene.to_toml()))
            self._rows_path = self.out / "results.csv"
            self._profile_path = self.out / "profile.csv"
            self._columns: list[str] | None = None
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
                self.summary(dict(getattr(exc, "path_info", {})), "interrupted",
                             f"interrupted (SIGINT/SIGTERM) after u0 = {self.last_converged_mm:g} mm")
            elif exc_type is not None and self.status == "running":
                self.summary({"error_type": exc_type.__name__}, "failed", f"{exc_type.__name__}: {exc}")
            elif exc_type is None and self.status != "running":
                self._record_files()
        except (OSError, NgbetError) as err:  # the folder itself failed: the original error says more
            log.error("could not record the end of the run in %s: %s", self.out, err)
        finally:
            self.release()

    def _record_files(self) -> None:
        """List in summary.json also the files written after it (plots, fields).

        So the next run into this folder knows them as ngbet's.
        """
        path = self.out / "summary.json"
        s = json.loads(path.read_text())
        files = self._files()
        if s.get("files") != files:
            s["files"] = files
            write_json_atomic(path, s)

    def _files(self) -> list[str]:
        return sorted(p.name for p in self.out.iterdir() if p.is_file() and p.name not in self._kept
                      and not p.name.startswith(".") and not p.name.endswith(".tmp"))

    def release(self) -> None:
        """Unlock the folder (the lock file stays: removing it would race with a waiting run)."""
        _ACTIVE.discard(self)
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    @property
    def last_converged_mm(self) -> float:
        """The last converged clamp displacement [mm] (0 before the first step)."""
        return float(self.rows[-1]["u0_mm"]) if self.rows else 0.0

    def add_step(self, row: dict[str, Any], profile: Sequence[tuple[float, float]] | None = None) -> None:
        """Write one converged step (and its mid-axis profile) and flush it to disk."""
        self.rows.append(row)
        new = self._columns is None
        if self._columns is None:
            self._columns = list(row)
        with self._rows_path.open("a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=self._columns, extrasaction="ignore", lineterminator="\n")
            if new:
                w.writeheader()
            w.writerow(row)
        if profile is not None:
            write_header = not self._profile_path.exists()
            with self._profile_path.open("a", newline="") as fh:
                w2 = csv.writer(fh, lineterminator="\n")
                if write_header:
                    w2.writerow(["step", "u0_mm", "X_mm", "uy_mm"])
                for X_mm, uy_mm in profile:
                    w2.writerow([row["step"], row["u0_mm"], f"{X_mm:.6g}", f"{uy_mm:.9g}"])

    def summary(self, info: dict[str, Any], status: str, error: str | None = None) -> dict[str, Any]:
        """Write summary.json atomically (at the start, at the end, and on failure with the error)."""
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
        s["warnings"] = [*self.warnings, *info.get("warnings", [])]
        s["files"] = self._files()
        write_json_atomic(self.out / "summary.json", s)
        self.status = status
        return s


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


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to a temporary file and rename it: a reader sees the old or the new file, never half."""
    tmp = path.with_name(path.name + ".tmp")
    _io(tmp, lambda p: p.write_text(json.dumps(data, indent=2, default=_jsonable)))
    os.replace(tmp, path)


def _io(path: Path, action: Callable[[Path], Any]) -> Any:
    """Run a file operation; an OSError becomes an OutputError naming the path."""
    try:
        return action(path)
    except OSError as exc:
        raise OutputError(path, exc.strerror or str(exc)) from exc


def _acquire_run_folder(out: Path) -> IO[str]:
    """Create ``out`` if needed, refuse it if it cannot be a run folder, and lock it."""
    if out.exists() and not out.is_dir():
        raise OutputError(out, "a file is in the place of the output folder")
    _io(out, lambda p: p.mkdir(parents=True, exist_ok=True))
    names = {p.name for p in out.iterdir()}
    if names and not names & set(_RUN_MARKERS):
        raise OutputError(out, f"not empty and not an ngbet run folder (it holds {', '.join(sorted(names)[:5])}"
                               f"{', ...' if len(names) > 5 else ''}); choose another --out")
    fh = _io(out / RUN_LOCK, lambda p: p.open("a+"))
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        who = fh.read().strip()
        fh.close()
        raise OutputError(out, f"busy: another ngbet run{f' (pid {who})' if who else ''} is writing into "
                               "it; wait for it or choose another --out") from None
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return fh


def _clear_previous_run(out: Path) -> list[Path]:
    """Remove the files a previous ngbet run wrote into ``out``; anything else stays (with a warning)."""
    listed: set[str] = set()
    try:
        prev = json.loads((out / "summary.json").read_text())
        listed = {n for n in prev.get("files", []) if isinstance(n, str) and "/" not in n and not n.startswith(".")}
    except (OSError, ValueError, AttributeError):
        pass
    gone = []
    for p in sorted(out.iterdir()):
        if p.is_file() and (p.name in listed or any(fnmatch.fnmatchcase(p.name, pat) for pat in RUN_FILE_PATTERNS)):
            _io(p, lambda q: q.unlink())
            gone.append(p)
    other = sorted(p.name for p in out.iterdir() if p.name != RUN_LOCK)
    if other:
        log.warning("%s: keeping %s (not written by ngbet)", out, ", ".join(other))
    return gone


def preflight(scene: Scene) -> list[str]:
    """Checks of a scene against this machine before anything is built.

    Warnings (loads past ideal yarn locking, a large problem) are logged and returned; a problem that cannot fit in the
    available memory is refused (:class:`SceneError` naming the keys).
    """
    from .scene import check_size, locking_warning

    found = [w for w in (locking_warning(scene), check_size(scene)) if w]
    for w in found:
        log.warning("%s", w)
    return found


def _jsonable(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, (set, tuple)):
        return list(o)
    return str(o)


def read_rows(path: str | Path) -> list[dict[str, float]]:
    """Read a results.csv back as a list of dicts of floats (non-numbers kept as strings)."""
    rows = []
    with Path(path).open() as fh:
        for r in csv.DictReader(fh):
            rows.append({k: _num(v) for k, v in r.items()})
    return rows


def _num(v: str) -> Any:
    try:
        return float(v)
    except (TypeError, ValueError):
        return v


def read_profiles(path: str | Path) -> dict[float, tuple[list[float], list[float]]]:
    """profile.csv -> {u0_mm: (X_mm, uy_mm)}."""
    out: dict[float, tuple[list[float], list[float]]] = {}
    with Path(path).open() as fh:
        for r in csv.DictReader(fh):
            X, uy = out.setdefault(float(r["u0_mm"]), ([], []))
            X.append(float(r["X_mm"]))
            uy.append(float(r["uy_mm"]))
    return out


def _error_bars(ax: Any, rows: list[dict[str, Any]]) -> None:
    """The estimated discretization error of the force (``force_error_N``) as error bars where estimated."""
    pts = [(r["u0_mm"], r["force_N"], r["force_error_N"]) for r in rows
           if isinstance(r.get("force_error_N"), float) and r["force_error_N"] == r["force_error_N"]]
    if pts:
        u, F, e = zip(*pts, strict=True)
        ax.errorbar(u, F, yerr=e, fmt="none", ecolor="k", elinewidth=1, capsize=4,
                    label="estimated discretization error")


def plot_force(run_dir: str | Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = ()) -> Path | None:
    """Force-displacement plot (and the double force when present) from results.csv: force.png, force.pdf.

    The converged steps are marked; between them the curve is the cubic Hermite interpolant of the
    force and dF/du0 when results.csv has ``dforce_du0_N_per_mm``, else straight lines (the legend
    says which). ``extra``: more curves (label, u0 [mm], force [N]), dashed. Drawn by the run's plot
    process when one runs (:mod:`ngbet.plot_process`), else here; the figure is the same. Returns
    None, with a note in the log, when matplotlib is not installed or results.csv has no force.
    """
    return start_plot(run_dir, extra)()


def start_plot(run_dir: str | Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = ()
               ) -> Callable[[], Path | None]:
    """Start :func:`plot_force` of a finished results.csv; the function returned finishes it.

    With a plot process the request goes out now and the process draws while the run writes its
    other files; the function returned waits for it (and draws here if it failed). Without one,
    the function returned draws.
    """
    from .plot_process import PlotProcessError, active

    proc = active()
    if proc is not None:
        try:
            proc.request(run_dir, extra)
        except PlotProcessError as exc:
            log.info("the plot process did not take %s (%s): drawing it here", run_dir, exc)
            proc = None

    def finish() -> Path | None:
        if proc is not None:
            try:
                return proc.answer()
            except PlotProcessError as exc:
                log.info("the plot process did not draw %s (%s): drawing it here", run_dir, exc)
        return draw_force(Path(run_dir), extra)

    return finish


def draw_force(run_dir: Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = (),
               fork_pdf: bool = False) -> Path | None:
    """Draw force.png and force.pdf of ``run_dir`` in this process (see :func:`plot_force`).

    ``fork_pdf``: a forked child writes the PDF while this process writes the PNG (for a process
    without threads, such as the plot process; if the child fails, the PDF is written here).
    """
    try:
        from matplotlib.figure import Figure
    except ImportError:
        log.warning("no force plot: matplotlib is not installed (pip install matplotlib)")
        return None
    rows = read_rows(run_dir / "results.csv")
    if not rows or "force_N" not in rows[0]:
        return None
    fig = _force_figure(Figure, rows, extra)
    png, pdf = run_dir / "force.png", run_dir / "force.pdf"
    child = os.fork() if fork_pdf else -1
    if child == 0:  # the child: the PDF, and out without running anything of the parent's
        code = 1
        try:
            fig.savefig(pdf)
            code = 0
        finally:
            os._exit(code)
    fig.savefig(png, dpi=PNG_DPI)
    if child < 0 or os.waitstatus_to_exitcode(os.waitpid(child, 0)[1]) != 0:
        fig.savefig(pdf)
    return png


PNG_DPI = 130


def warm_up() -> None:
    """Draw a throw-away force figure into memory: loads matplotlib's fonts, mathtext and PDF backend."""
    import io

    from matplotlib.figure import Figure

    rows = [{"u0_mm": u, "force_N": u * u, "dforce_du0_N_per_mm": 2 * u, "force_error_N": 0.1,
             "double_force_Nm": 0.1 * u} for u in (1.0, 2.0)]
    fig = _force_figure(Figure, rows, [("extra", [0.0, 2.0], [0.0, 4.0])])
    fig.savefig(io.BytesIO(), format="png", dpi=PNG_DPI)
    fig.savefig(io.BytesIO(), format="pdf")


def _force_figure(figure: Any, rows: list[dict[str, Any]],
                  extra: Iterable[tuple[str, Sequence[float], Sequence[float]]]) -> Any:
    """The force figure of the rows of a results.csv (``figure``: matplotlib's Figure class)."""
    from .plotting import force_curve

    u0 = [r["u0_mm"] for r in rows]
    has_T = "double_force_Nm" in rows[0]
    fig = figure(figsize=(10 if has_T else 5.5, 4))
    axes = fig.subplots(1, 2 if has_T else 1, squeeze=False)
    ax = axes[0, 0]
    dF = [r["dforce_du0_N_per_mm"] for r in rows] if "dforce_du0_N_per_mm" in rows[0] else None
    force_curve(ax, u0, [r["force_N"] for r in rows], dF, label="force")
    _error_bars(ax, rows)
    for label, x, y in extra:
        ax.plot(x, y, "--", label=label)
    ax.set_xlabel("clamp displacement $u_0$ [mm]")
    ax.set_ylabel("reaction force on the moving clamp [N]")
    ax.legend(fontsize=8, loc="upper left")
    if has_T:
        ax2 = axes[0, 1]
        ax2.plot([0.0] + u0, [0.0] + [r["double_force_Nm"] for r in rows], "s-", ms=4, color="C3",
                 label="converged steps, joined by lines")
        ax2.set_xlabel("clamp displacement $u_0$ [mm]")
        ax2.set_ylabel("reaction double force [N m]")
        ax2.grid(alpha=0.3)
        ax2.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return fig
