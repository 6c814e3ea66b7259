"""Writing a run to disk, step by step, so that nothing converged is ever lost.

Layout of a run folder (both models)::

    scene.toml        the complete scene that produced everything beside it
    results.csv       one row per converged load step (written and flushed as each step converges)
    profile.csv       mid-axis (Y = W/2) vertical displacement, one block per step: step,u0_mm,X_mm,uy_mm
    summary.json      scene, versions, dofs, timings, status (rewritten at the end, also on failure)
    fields_*.vtu      fields for ParaView
    force.png/.pdf    force-displacement plot

Plotting reads these files; nothing in the physics imports this module.
"""

from __future__ import annotations

import csv
import json
import logging
import platform
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

from .scene import Scene

log = logging.getLogger(__name__)


def versions() -> dict[str, str]:
    """Versions of the libraries a result depends on."""
    out: dict[str, str] = {"python": platform.python_version()}
    for mod in ("ngbet", "ngsolve", "netgen", "numpy", "scipy"):
        try:
            m = __import__(mod)
            out[mod] = str(getattr(m, "__version__", "unknown"))
        except Exception:  # pragma: no cover - optional modules
            pass
    return out


def git_revision(path: Path | None = None) -> str:
    """The git revision of ngbet (the checkout's, or the one recorded at install), or 'unknown'."""
    from .revision import revision

    return revision()


def machine() -> dict[str, Any]:
    import os

    return {"node": platform.node(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "system": platform.platform()}


class RunWriter:
    """Appends converged steps to the run folder as they come."""

    def __init__(self, out: str | Path, scene: Scene) -> None:
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.scene = scene
        (self.out / "scene.toml").write_text(scene.to_toml())
        self._rows_path = self.out / "results.csv"
        self._profile_path = self.out / "profile.csv"
        for p in (self._rows_path, self._profile_path):
            if p.exists():
                p.unlink()
        self._columns: list[str] | None = None
        self.rows: list[dict[str, Any]] = []
        self.t_start = time.perf_counter()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        """An interrupt (Ctrl-C) leaves a summary that says so, with the last converged load."""
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            self.summary({}, "interrupted", "interrupted by the user")

    def add_step(self, row: dict[str, Any], profile: Sequence[tuple[float, float]] | None = None) -> None:
        """Write one converged step (and its mid-axis profile) and flush it to disk."""
        self.rows.append(row)
        new = self._columns is None
        if new:
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
        """Write summary.json (called at the end, and on failure with the error)."""
        s = {
            "status": status,
            "error": error,
            "scene": self.scene.to_dict(),
            "scene_digest": self.scene.digest(),
            "versions": versions(),
            "git_revision": git_revision(),
            "machine": machine(),
            "steps": len(self.rows),
            "u0_reached_mm": self.rows[-1]["u0_mm"] if self.rows else 0.0,
            "wall_s": time.perf_counter() - self.t_start,
            **info,
        }
        (self.out / "summary.json").write_text(json.dumps(s, indent=2, default=_jsonable))
        return s


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


def plot_force(run_dir: str | Path, extra: Iterable[tuple[str, Sequence[float], Sequence[float]]] = ()) -> Path | None:
    """Force-displacement plot (and the double force when present) from results.csv: force.png, force.pdf.

    The converged steps are marked; between them the curve is the cubic Hermite interpolant of the
    force and dF/du0 when results.csv has ``dforce_du0_N_per_mm``, else straight lines (the legend
    says which). Returns None, with a note in the log, when matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("no force plot: matplotlib is not installed (pip install 'ngbet[viz]')")
        return None
    from .plotting import force_curve

    run_dir = Path(run_dir)
    rows = read_rows(run_dir / "results.csv")
    if not rows or "force_N" not in rows[0]:
        return None
    u0 = [r["u0_mm"] for r in rows]
    has_T = "double_force_Nm" in rows[0]
    fig, axes = plt.subplots(1, 2 if has_T else 1, figsize=(10 if has_T else 5.5, 4), squeeze=False)
    ax = axes[0, 0]
    dF = [r["dforce_du0_N_per_mm"] for r in rows] if "dforce_du0_N_per_mm" in rows[0] else None
    force_curve(ax, u0, [r["force_N"] for r in rows], dF, label="force")
    for label, x, y in extra:
        ax.plot(x, y, "--", label=label)
    ax.set_xlabel("clamp displacement $u_0$ [mm]")
    ax.set_ylabel("reaction force on the moving clamp [N]")
    ax.legend(fontsize=8)
    if has_T:
        ax2 = axes[0, 1]
        ax2.plot([0.0] + u0, [0.0] + [r["double_force_Nm"] for r in rows], "s-", ms=4, color="C3",
                 label="converged steps, joined by lines")
        ax2.set_xlabel("clamp displacement $u_0$ [mm]")
        ax2.set_ylabel("reaction double force [N m]")
        ax2.grid(alpha=0.3)
        ax2.legend(fontsize=8)
    fig.tight_layout()
    png = run_dir / "force.png"
    fig.savefig(png, dpi=130)
    fig.savefig(run_dir / "force.pdf")
    plt.close(fig)
    return png
