"""The clamp force along a load path and its derivatives, for the fits: a path run without a run folder.

:func:`force_path` carries a continuum scene's load through the loads asked for and records the
force there with its derivatives with respect to material parameters
(:class:`ngbet.continuum.sensitivity.Recorder`, whose module states the method and its
accuracy); :func:`finite_difference` is its check by central differences of whole paths.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..continuum.problem import ContinuumProblem
from ..continuum.sensitivity import ForcePath, Recorder, check_params, material_value, with_material
from ..continuum.solver import ContinuumSolver
from ..numerics.path import load_steps
from ..scene.document import Scene
from .settings import solver_settings
from .threads import ngsolve_threads

__all__ = ["finite_difference", "force_path"]


def force_path(
    scene: Scene,
    u_mm: Sequence[float] | np.ndarray,
    params: Sequence[str] = (),
    profile: dict[float, np.ndarray] | None = None,
    mesh: Any = None,
    angles: Sequence[float] = (),
    estimate: bool = False,
    estimate_at: Sequence[float] | None = None,
) -> ForcePath:
    """The force at each of ``u_mm`` and its derivatives dF/d ln p for the material keys ``params``.

    ``scene`` (continuum) runs with a load step landing on each of ``u_mm``; ``params`` are keys
    such as ``"material.K_sh"``.

    ``profile``: {u0 [mm]: X [mm]}: also the mid-axis u_y at those X at load u0 (and its
    derivatives, two more back-substitutions and residual evaluations per parameter). ``mesh``: a mesh of the scene's
    specimen made before (:func:`ngbet.continuum.mesh.make_mesh`), reused instead of meshing
    again. ``angles``: loads u0 [mm] at which the centre shear angle (and its derivatives) is wanted.
    ``estimate``: the discretization error of the force at each of ``u_mm``
    (:class:`ngbet.continuum.estimate.ForceErrorEstimator`); ``estimate_at``: only at these of
    ``u_mm`` (the others' errors nan: not estimated). Nothing is written to disk. Raises
    :class:`ngbet.errors.ConvergenceError` when the path cannot be followed to the last load.
    """
    names = check_params(scene, params)
    profile = {float(k): np.asarray(v, float) for k, v in (profile or {}).items()}
    u = np.asarray(sorted(set(float(v) for v in u_mm if v > 0) | set(profile) | {float(v) for v in angles}))
    scene = scene.with_changes(**{"loading.u0_mm": float(u[-1]), "loading.stops_mm": list(u[:-1])})
    # displacement control landing on each load asked for (no output grid)
    settings = solver_settings(scene)
    path = dataclasses.replace(
        settings.path, stops=tuple(s * 1e-3 for s in u), chord_at=(), path_following="displacement"
    )
    with ngsolve_threads(scene):
        solver = ContinuumSolver(ContinuumProblem(scene, mesh), settings)
        rec = Recorder(
            solver,
            names,
            profile,
            [float(v) for v in u_mm if v > 0],
            angles,
            estimate,
            None if estimate_at is None else [float(v) for v in estimate_at],
        )
        for step in load_steps(
            solver,
            path,
            settings.newton,
            hessian=solver if solver.can_relax else None,
            watch=solver.problem,
            locate=solver.problem,
        ):
            rec(step)
    keys = np.array(sorted(rec.rows))
    # the force (and its derivatives) at each requested load, in the caller's order, repeats
    # included; the unloaded state carries none; loads only asked for by the profile are left out
    want = np.asarray(u_mm, dtype=float)
    zero = (0.0, np.zeros(len(names)))
    at = [rec.rows[keys[int(np.argmin(np.abs(keys - v)))]] if v > 0 else zero for v in want]
    F = np.array([a[0] for a in at])
    D = np.array([a[1] if len(a[1]) == len(names) else np.full(len(names), np.nan) for a in at]) if names else None
    err = None
    if estimate:
        ekeys = np.array(sorted(rec.errors)) if rec.errors else np.zeros(1)
        asked = None if estimate_at is None else np.asarray(estimate_at, float)

        def error_at(v: float) -> float:
            if v <= 0:
                return 0.0
            if asked is not None and not np.any(np.abs(asked - v) < 1e-9):
                return math.nan  # not estimated there
            return rec.errors.get(float(ekeys[int(np.argmin(np.abs(ekeys - v)))]), math.nan)

        err = np.array([error_at(float(v)) for v in want])
    angles_deg = {float(a): rec.angles[float(a)] for a in angles if float(a) in rec.angles}
    return ForcePath(
        want,
        F,
        D,
        float(keys[-1]) if len(keys) else 0.0,
        rec.profiles,
        rec.profile_dlogp,
        err,
        angles_deg,
        rec.angle_dlogp,
    )


def finite_difference(
    scene: Scene, u_mm: Sequence[float] | np.ndarray, params: Sequence[str], rel_step: float = 1e-4
) -> np.ndarray:
    """The derivatives dF/d ln p by central differences of :func:`force_path` (2 runs per parameter).

    The check of the implicit derivative, and its cost to compare with.
    """
    cols = []
    for p in params:
        name = p.partition(".")[2]
        value = material_value(scene, name)
        up = force_path(with_material(scene, name, value * math.exp(rel_step)), u_mm).force_N
        dn = force_path(with_material(scene, name, value * math.exp(-rel_step)), u_mm).force_N
        cols.append((up - dn) / (2 * rel_step))
    return np.column_stack(cols)
