"""The one translation of a scene into numerics: Newton, linear algebra, load path, arc length, network steps.

A scene says what to simulate and how finely (``scene.solver``, ``scene.loading``,
``scene.discrete``); the numerics (:mod:`ngbet.numerics`) read no scene. Every setting they are
given is made here from the scene, and nowhere else: the continuum's
(:class:`~ngbet.numerics.settings.SolverSettings`: linear algebra, Newton, load path), the arc
length's step control, and the network's (:class:`~ngbet.discrete.newton.StepControl`). Loads
go from millimetres to metres here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..continuum.problem import ContinuumProblem
from ..continuum.solver import ContinuumSolver
from ..numerics.arclength import ArcLengthSettings
from ..numerics.engine import PathControl
from ..numerics.settings import LinearSettings, NewtonSettings, PathSettings, SolverSettings
from ..scene.document import Scene

if TYPE_CHECKING:
    from ..discrete.newton import StepControl

__all__ = [
    "arclength_settings",
    "continuum_solver",
    "linear_settings",
    "newton_settings",
    "path_settings",
    "solver_settings",
    "step_control",
]


def newton_settings(scene: Scene) -> NewtonSettings:
    """The Newton numerics of ``scene.solver``."""
    s = scene.solver
    return NewtonSettings(rtol=s.rtol, atol=s.atol_energy, max_iterations=s.max_iterations, predictor=s.predictor)


def linear_settings(scene: Scene) -> LinearSettings:
    """The linear algebra of ``scene.solver``."""
    s = scene.solver
    return LinearSettings(linear_solver=s.linear_solver, condense=s.condense, compile=s.compile)


def path_settings(scene: Scene) -> PathSettings:
    """The load path of ``scene``: its loads in metres, its step control and how it is followed.

    ``stops`` are the loads the path lands on: the stops and the output grid (``chord_at``).
    """
    L, s = scene.loading, scene.solver
    grid = tuple(x * 1e-3 for x in L.path_stops_mm if x not in L.stops_mm)
    return PathSettings(
        target=L.u0_mm * 1e-3,
        first_step=L.first_step_mm * 1e-3,
        max_step=L.max_step_mm * 1e-3,
        min_step=L.min_step_mm * 1e-3,
        growth=s.growth,
        cut=s.cut,
        grow_after=s.grow_after,
        stops=tuple(x * 1e-3 for x in L.path_stops_mm),
        chord_at=grid,
        length=scene.specimen.L,
        path_following=s.path_following,
    )


def solver_settings(scene: Scene) -> SolverSettings:
    """The continuum's numerics of ``scene``: linear algebra, Newton and load path."""
    return SolverSettings(linear=linear_settings(scene), newton=newton_settings(scene), path=path_settings(scene))


def continuum_solver(problem: ContinuumProblem) -> ContinuumSolver:
    """The solver of ``problem`` with the numerics its scene asks for (:func:`solver_settings`)."""
    return ContinuumSolver(problem, solver_settings(problem.scene))


def arclength_settings(scene: Scene) -> ArcLengthSettings:
    """The arc length's step control of ``scene``: the load path's, landing on the stops (not the output grid)."""
    path = path_settings(scene)
    return ArcLengthSettings(
        target=path.target,
        first_step=path.first_step,
        max_step=path.max_step,
        min_step=path.min_step,
        growth=path.growth,
        cut=path.cut,
        grow_after=path.grow_after,
        stops=tuple(s * 1e-3 for s in scene.loading.stops_mm),
    )


def step_control(scene: Scene) -> StepControl:
    """The network's numerics of a scene in SI units.

    The steps are the smaller of [loading] and [discrete]; the path lands on the stops and the
    output grid.
    """
    from ..discrete.newton import StepControl  # the network's solver (scipy.sparse): imported by network runs alone

    ld, so, d = scene.loading, scene.solver, scene.discrete
    max_step = min(ld.max_step_mm, d.max_step_mm)
    path = PathControl(
        target=ld.u0_mm * 1e-3,
        first_step=min(ld.first_step_mm, d.first_step_mm) * 1e-3,
        max_step=max_step * 1e-3,
        min_step=ld.min_step_mm * 1e-3,
        growth=so.growth,
        cut=so.cut,
        grow_after=so.grow_after,
        stops=tuple(s * 1e-3 for s in ld.path_stops_mm),
    )
    return StepControl(
        path=path,
        rtol=so.rtol,
        atol=so.atol_energy,
        max_iterations=so.max_iterations,
        predictor=so.predictor,
        backend=so.linear_solver,
        snap_bracket=min(max(4 * ld.min_step_mm, 1.0), max_step) * 1e-3,
    )
