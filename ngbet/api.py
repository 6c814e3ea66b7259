"""The Python API: run a scene and get its results as numpy arrays.

    >>> import ngbet
    >>> r = ngbet.simulate(ngbet.default_scene().with_changes(**{"loading.u0_mm": 20}))  # doctest: +SKIP
    >>> r.u0_mm, r.force_N, r.profiles[20.0], r.fields()                                # doctest: +SKIP

:func:`simulate` runs a scene exactly as ``ngbet run`` does (the same run folder, the same
``summary.json``) and reads the folder back into a :class:`Result`. With ``out=None`` the run
goes into a temporary folder: the tables (``results.csv``, ``profile.csv``, ``summary.json``) are
read fully into memory, and the folder itself, which holds the final fields (``fields.vtu``), is
kept as long as the :class:`Result` or any copy of it lives (``copy.copy`` and ``copy.deepcopy``
share it; a pickled :class:`Result`, as a worker process returns it, carries the folder's files and
unpickles into a temporary folder of its own), and deleted with the last. Pass ``out`` to keep the
files; a temporary folder of a live :class:`Result` is never run into again.
"""

from __future__ import annotations

import copy
import json
import logging
import os
import shutil
import tempfile
import weakref
from pathlib import Path
from typing import Any, cast

import numpy as np

from .errors import ConvergenceError
from .scene.document import Scene

log = logging.getLogger(__name__)

__all__ = ["Result", "simulate", "load_result"]


class _Folder:
    """A temporary run folder owned by the :class:`Result` objects that hold this (removed with the last)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._finalizer = weakref.finalize(self, shutil.rmtree, str(path), True)
        _OWNED[_real(path)] = self


#: the temporary folders of live Results, by their real path: never run into again
_OWNED: weakref.WeakValueDictionary[str, _Folder] = weakref.WeakValueDictionary()


def _real(path: str | Path) -> str:
    return os.path.realpath(path)


def simulate(scene: Scene | str | Path, out: str | Path | None = None, progress: bool = False) -> Result:
    """Run ``scene`` and return its :class:`Result`.

    Parameters
    ----------
    scene : Scene, or the path of a scene TOML file
        The scene, e.g. ``ngbet.default_scene().with_changes(**{"material.alpha1": 200.0})`` or
        ``"my.toml"`` (read with :meth:`Scene.from_toml`).
    out : str or Path, optional
        Run folder (created; the layout of ``ngbet run``, see docs/outputs.md). ``None``: a
        temporary folder that lives as long as the returned :class:`Result` (and its copies); the
        force plot file is then not drawn (``outputs.plot`` is switched off; draw it with
        :meth:`Result.plot`). The temporary folder of another live :class:`Result` is refused
        (:class:`~ngbet.output.OutputError`): that Result reads its fields from it.
    progress : bool
        Show a progress bar over the clamp displacement.

    Returns
    -------
    Result

    Raises
    ------
    ngbet.errors.ConvergenceError
        When the load cannot be carried to the end. The exception's ``result`` attribute is the
        :class:`Result` of the converged steps (with ``status == "failed"``).
    ngbet.SceneError
        A bad scene (or scene file).
    ngbet.output.OutputError
        An output folder that cannot be used (as ``ngbet run`` refuses it).
    """
    from .run import run
    from .run_folder import OutputError

    if isinstance(scene, (str, os.PathLike)):
        scene = Scene.from_toml(scene)
    if not isinstance(scene, Scene):
        raise TypeError(f"simulate() takes a Scene or the path of a scene file, not {type(scene).__name__}")
    if _RAN_IN[0] not in (None, os.getpid()):  # forked from a process that ran one: Netgen's mesher hangs here
        return _in_a_fresh_process(scene, out, progress)
    if out is not None and _real(out) in _OWNED:
        raise OutputError(
            out,
            "the temporary folder of a live Result (its fields() are read from it); choose another out= (or out=None)",
        )
    tmp = None
    if out is None:
        tmp = Path(tempfile.mkdtemp(prefix="ngbet-"))
        out = tmp
        if scene.outputs.plot:
            scene = scene.with_changes(**{"outputs.plot": False})
    out = Path(out)
    _RAN_IN[0] = os.getpid()
    try:
        run(scene, out, progress=progress)
    except ConvergenceError as err:
        err.result = load_result(out, _owned=tmp)  # type: ignore[attr-defined]
        raise
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    return load_result(out, _owned=tmp)


#: the process that ran a scene through :func:`simulate` (None: none yet)
_RAN_IN: list[int | None] = [None]


def _in_a_fresh_process(scene: Scene, out: str | Path | None, progress: bool) -> Result:
    """:func:`simulate` in a spawned process, for a process forked after its parent ran a scene.

    Netgen's mesher does not survive a fork once it has run (a forked worker of
    ``ProcessPoolExecutor`` waited forever for its threads); a spawned process starts clean. The
    Result comes back pickled, with its folder's files (:meth:`Result.__getstate__`).
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    if mp.current_process().daemon:  # multiprocessing.Pool's workers may not start processes
        raise RuntimeError(
            "ngbet.simulate() cannot run in a daemonic worker forked from a process that already "
            "ran a scene (Netgen's mesher does not survive the fork, and the worker may not start a "
            "fresh process): give the pool a 'spawn' or 'forkserver' context, e.g. "
            "multiprocessing.get_context('forkserver').Pool()"
        )
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(simulate, scene, out, progress).result()


def load_result(out: str | Path, _owned: Path | None = None) -> Result:
    """Read a run folder (written by ``ngbet run`` or :func:`simulate`) into a :class:`Result`."""
    out = Path(out)
    summary = json.loads((out / "summary.json").read_text())
    columns = _read_columns(out / "results.csv")
    profiles = _read_profiles(out / "profile.csv")
    res = Result(out, Scene.from_dict(summary["scene"]), summary, columns, profiles)
    if _owned is not None:
        res._folder = _Folder(_owned)
    return res


class Result:
    """The outcome of one run, in memory.

    Attributes
    ----------
    out : Path
        The run folder (a temporary one with ``simulate(scene)``; it lives as long as this object).
    scene : Scene
        The complete scene that was run (with an accuracy target, as asked: the discretization its
        ladder chose is ``summary["accuracy"]["chosen"]``).
    summary : dict
        ``summary.json``: status, dofs, timings, versions, warnings (docs/outputs.md).
    columns : dict[str, numpy.ndarray]
        Every column of ``results.csv``, one entry per converged load step; also reachable as
        attributes (``r.gamma_centre_deg``). Every array's name ends in its unit, as the column's
        does (``u0_mm``, ``force_N``, ``double_force_Nm``, ``energy_J``, ``force_error_N``).
    profiles : dict[float, tuple[numpy.ndarray, numpy.ndarray]]
        Mid-axis profile per converged step: ``{u0_mm: (X_mm, uy_mm)}``.
    """

    def __init__(
        self,
        out: Path,
        scene: Scene,
        summary: dict[str, Any],
        columns: dict[str, np.ndarray],
        profiles: dict[float, tuple[np.ndarray, np.ndarray]],
    ) -> None:
        self.out = out
        self.scene = scene
        self.summary = summary
        self.columns = columns
        self.profiles = profiles
        self._folder: _Folder | None = None  # the temporary folder this Result (with its copies) owns

    # copies ---------------------------------------------------------------------------------
    def __copy__(self) -> Result:
        new = Result.__new__(Result)
        new.__dict__.update(self.__dict__)  # the same folder, owned by both
        return new

    def __deepcopy__(self, memo: dict[int, Any]) -> Result:
        new = Result.__new__(Result)
        memo[id(self)] = new
        for k, v in self.__dict__.items():  # the arrays copied, the folder shared (owned by both)
            new.__dict__[k] = v if k == "_folder" else copy.deepcopy(v, memo)
        return new

    def __getstate__(self) -> dict[str, Any]:
        """The pickled state: an owned temporary folder travels as its files (another process may unpickle it)."""
        state = dict(self.__dict__)
        folder = state.pop("_folder", None)
        if folder is not None:  # (a folder a cleaner of /tmp removed: the tables travel, fields() says it is gone)
            paths = list(folder.path.iterdir()) if folder.path.is_dir() else []
            state["_folder_files"] = {p.name: p.read_bytes() for p in paths if p.is_file()}
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        files = state.pop("_folder_files", None)
        self.__dict__.update(state)
        self._folder = None
        if files is not None:  # a temporary folder of its own, with the files of the pickled one
            path = Path(tempfile.mkdtemp(prefix="ngbet-"))
            self._folder = _Folder(path)
            for name, data in files.items():
                (path / name).write_bytes(data)
            self.out = path

    # per-step arrays ------------------------------------------------------------------------
    def __getattr__(self, name: str) -> np.ndarray:
        columns = self.__dict__.get("columns", {})
        if name in columns:
            return cast(np.ndarray, columns[name])
        raise AttributeError(f"Result has no attribute or results.csv column {name!r}; columns: {', '.join(columns)}")

    @property
    def status(self) -> str:
        """The run's status: ``"ok"``, or ``"failed"`` when the solver could not reach the final load.

        A folder read by :func:`load_result` may also say ``"interrupted"`` (Ctrl-C, SIGTERM) or
        ``"crashed"`` (the run's process died).
        """
        return str(self.summary.get("status"))

    @property
    def u0_mm(self) -> np.ndarray:
        """Clamp displacement of each converged step [mm]."""
        return self.columns["u0_mm"]

    @property
    def force_N(self) -> np.ndarray:
        """Reaction force on the moving clamp [N] (the whole specimen thickness)."""
        return self.columns["force_N"]

    @property
    def double_force_Nm(self) -> np.ndarray | None:
        """Reaction double force on the moving clamp [N m] (column ``double_force_Nm``).

        None when the run has none (the discrete model, or a scene without bending).
        """
        return self.columns.get("double_force_Nm")

    @property
    def energy_J(self) -> np.ndarray | None:
        """Total stored energy [J] (column ``energy_J``); None when not computed."""
        return self.columns.get("energy_J")

    @property
    def force_error_N(self) -> np.ndarray | None:
        """Estimated discretization error of the force [N], when the run estimates it; else None."""
        return self.columns.get("force_error_N")

    # files ----------------------------------------------------------------------------------
    def fields(self, step: int | None = None) -> Any:
        """The fields on the mesh as a ``pyvista.UnstructuredGrid`` (pyvista reads the VTU file).

        ``step=None``: the final fields (``fields.vtu``); ``step=k``: ``fields_00k.vtu``, written
        when ``outputs.vtk_every_step`` is on. Coordinates and displacements are in mm; warp by
        ``displacement`` to see the deformed specimen (docs/outputs.md).
        """
        path = self.out / ("fields.vtu" if step is None else f"fields_{step:03d}.vtu")
        if not self.out.is_dir():
            raise FileNotFoundError(
                f"{self.out}: the run folder no longer exists (removed after this Result "
                "was read); its tables are in memory, its fields were in the folder"
            )
        if not path.exists():
            raise FileNotFoundError(
                f"{path} does not exist: the continuum model writes it when outputs.vtk is true"
                + ("" if step is None else " and outputs.vtk_every_step is true")
            )
        try:
            import pyvista as pv
        except ImportError as exc:
            raise ImportError(
                "Result.fields() reads the VTU file with pyvista, which is not installed: pip install pyvista"
            ) from exc
        return pv.read(str(path))

    def to_csv(self, path: str | Path) -> Path:
        """Copy the per-step table (the run's results.csv, every column as written) to ``path``."""
        import shutil

        src = self.out / "results.csv"
        if Path(path).exists() and os.path.samefile(src, path):  # the table itself: nothing to copy
            return Path(path)
        return Path(shutil.copyfile(src, path))

    def plot(self, ax: Any = None, label: str | None = None, **kwargs: Any) -> Any:
        """Draw force against clamp displacement on ``ax`` (a new figure when None); returns ax.

        Straight lines from (0, 0) through the converged steps, which are marked: the curve between
        them is not computed.
        """
        from .figures.curves import force_curve

        if ax is None:
            try:
                import matplotlib.pyplot as plt
            except ImportError as exc:
                raise ImportError(
                    "Result.plot() draws with matplotlib, which is not installed: pip install matplotlib"
                ) from exc

            _, ax = plt.subplots(figsize=(5.5, 4))
        force_curve(ax, self.u0_mm, self.force_N, label=label, **kwargs)
        ax.set_xlabel("clamp displacement $u_0$ [mm]")
        ax.set_ylabel("force [N]")
        return ax

    def __repr__(self) -> str:
        n = len(self.u0_mm)
        last = f", u0 = {self.u0_mm[-1]:g} mm, force = {self.force_N[-1]:.4g} N" if n else ""
        return f"<ngbet.Result {self.scene.model} {self.status}: {n} steps{last}; {self.out}>"


def _read_columns(path: Path) -> dict[str, np.ndarray]:
    """results.csv as arrays, one per column (:func:`ngbet.output.read_rows`; an empty cell is nan)."""
    from .tables import read_rows

    rows = read_rows(path) if path.exists() else []
    out: dict[str, np.ndarray] = {}
    for n in rows[0] if rows else []:
        values = [np.nan if r[n] == "" else r[n] for r in rows]
        out[n] = np.array(values, dtype=float if all(isinstance(v, float) for v in values) else object)
    out.setdefault("u0_mm", np.zeros(0))
    out.setdefault("force_N", np.full(len(rows), np.nan))
    return out


def _read_profiles(path: Path) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    if not path.exists():
        return {}
    from .tables import read_profiles

    return {u0: (np.asarray(X), np.asarray(uy)) for u0, (X, uy) in read_profiles(path).items()}
