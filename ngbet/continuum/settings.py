"""The one translation of a scene into the continuum's numerics: Newton's settings and the path's.

The problem (:class:`ngbet.continuum.problem.ContinuumProblem`) holds spaces, energy, boundary
conditions and load; what the solver does with it (tolerances, damping, step control, the loads
it must land on, how the path is followed) is set here, from ``scene.solver`` and
``scene.loading``, and nowhere else. The step control is the engine's
(:class:`ngbet.engine.PathControl`), which :class:`PathSettings` extends with what only the
continuum has.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..engine import PathControl

if TYPE_CHECKING:
    from ..scene.document import Scene

__all__ = ["LinearSettings", "NewtonSettings", "PathSettings", "linear_settings", "newton_settings", "path_settings"]


@dataclass(frozen=True, kw_only=True)
class NewtonSettings:
    """Tolerances, damping and predictor of the continuum's Newton (from ``scene.solver``)."""

    rtol: float = 1e-10
    atol: float = 1e-14
    max_iterations: int = 12
    min_damping: float = 1.0 / 64
    predictor: str = "tangent"
    #: contraction θ = ‖dx̄‖/‖dx‖ below which a small simplified correction ends Newton without a
    #: new linearization (0 disables the shortcut)
    simplified_theta: float = 0.5
    #: an iteration after a full step that contracted by at most this keeps the factorization (a
    #: chord step, its decrement tested against (1 − θ) times the tolerance); 0: a new
    #: linearization at every iteration
    reuse_contraction: float = 0.0


def newton_settings(scene: Scene) -> NewtonSettings:
    """The Newton numerics of ``scene.solver`` (the one translation of the scene into them)."""
    s = scene.solver
    return NewtonSettings(rtol=s.rtol, atol=s.atol_energy, max_iterations=s.max_iterations, predictor=s.predictor)


@dataclass(frozen=True, kw_only=True)
class LinearSettings:
    """The linear algebra of the continuum's Newton (from ``scene.solver``).

    What :class:`ngbet.continuum.numerics.ContinuumSolver` is built with. The choices are the
    user's; "auto" is resolved by each solver for its own problem (the inverse by definiteness and
    size, the compilation by size), so that one set of settings serves the run, its enriched
    estimates and its branch copies alike.
    """

    #: the sparse inverse: "auto", "sparsecholesky", "umfpack", "cholmod", ... (``solver.linear_solver``)
    linear_solver: str = "auto"
    #: eliminate element-local dofs (Λ) before factorizing (``solver.condense``)
    condense: bool = True
    #: the energy integrand "interpret"ed, "native" C++ or "auto" by size (``solver.compile``)
    compile: str = "auto"


def linear_settings(scene: Scene) -> LinearSettings:
    """The linear algebra of ``scene.solver`` (the one translation of the scene into it)."""
    s = scene.solver
    return LinearSettings(linear_solver=s.linear_solver, condense=s.condense, compile=s.compile)


@dataclass(frozen=True, kw_only=True)
class PathSettings(PathControl):
    """How a continuum load path is carried (from ``scene.loading`` and ``scene.solver``); loads in m.

    The engine's step control (:class:`~ngbet.engine.PathControl`: target, first, largest and
    shortest step, growth, cut, the loads landed on) with the continuum's defaults (a stop within
    a fifth of a step beyond a trial load is landed on; at most 500 trials) and what only the
    continuum has.
    """

    land_within: float = 0.2
    #: bound on the trial increments, converged or not (a bound on the time)
    max_attempts: int | None = 500
    #: loads of the output grid: corrected by the chord with the factorization at hand
    #: (:mod:`ngbet.continuum.chord`) before Newton
    chord_at: tuple[float, ...] = ()
    #: the problem's length scale [m] (the chord's difference step)
    length: float = 1.0
    #: "displacement", "arclength" or "auto" (``solver.path_following``)
    path_following: str = "displacement"
    #: under displacement control, relax an increment that fails at the shortest length to a
    #: stable state (a snap-through)
    snap: bool = True


def path_settings(scene: Scene) -> PathSettings:
    """The load path of ``scene``: its loads in metres, its step control and how it is followed.

    ``stops`` are the loads the path lands on: the stops and the output grid (``chord_at``).
    """
    L, s = scene.loading, scene.solver
    grid = tuple(x * 1e-3 for x in L.path_stops_mm if x not in L.stops_mm)
    return PathSettings(target=L.u0_mm * 1e-3, first_step=L.first_step_mm * 1e-3, max_step=L.max_step_mm * 1e-3,
                        min_step=L.min_step_mm * 1e-3, growth=s.growth, cut=s.cut, grow_after=s.grow_after,
                        stops=tuple(x * 1e-3 for x in L.path_stops_mm), chord_at=grid, length=scene.specimen.L,
                        path_following=s.path_following)
