"""The settings of the saddle-point numerics: Newton's, the linear algebra's and the load path's.

A problem holds spaces, energy, boundary conditions and load; what the numerics do with it
(tolerances, damping, step control, the loads they must land on, how the path is followed) is
set here. The step control is the engine's (:class:`ngbet.numerics.engine.PathControl`), which
:class:`PathSettings` extends. The runner translates a scene into these
(:mod:`ngbet.runner.settings`, the one translation); nothing here reads a scene.
"""

from __future__ import annotations

from dataclasses import dataclass

from .engine import PathControl

__all__ = ["LinearSettings", "NewtonSettings", "PathSettings", "SolverSettings"]


@dataclass(frozen=True, kw_only=True)
class NewtonSettings:
    """Tolerances, damping and predictor of Newton (:func:`ngbet.numerics.newton.newton`; ``scene.solver``)."""

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


@dataclass(frozen=True, kw_only=True)
class LinearSettings:
    """The linear algebra of Newton on an NGSolve energy form (``scene.solver``).

    What :class:`ngbet.continuum.solver.ContinuumSolver` is built with. The choices are the
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


@dataclass(frozen=True, kw_only=True)
class PathSettings(PathControl):
    """How a saddle-point load path is carried (``scene.loading``, ``scene.solver``); loads in m.

    The engine's step control (:class:`~ngbet.numerics.engine.PathControl`: target, first, largest and
    shortest step, growth, cut, the loads landed on) with the defaults of :func:`ngbet.numerics.path.load_steps`
    (a stop within a fifth of a step beyond a trial load is landed on; at most 500 trials) and what
    only that path has.
    """

    land_within: float = 0.2
    #: bound on the trial increments, converged or not (a bound on the time)
    max_attempts: int | None = 500
    #: loads of the output grid: corrected by the chord with the factorization at hand
    #: (:mod:`ngbet.numerics.chord`) before Newton
    chord_at: tuple[float, ...] = ()
    #: the problem's length scale [m] (the chord's difference step)
    length: float = 1.0
    #: "displacement", "arclength" or "auto" (``solver.path_following``)
    path_following: str = "displacement"
    #: under displacement control, relax an increment that fails at the shortest length to a
    #: stable state (a snap-through)
    snap: bool = True


@dataclass(frozen=True, kw_only=True)
class SolverSettings:
    """The numerics of one problem: its linear algebra, Newton and load path.

    What a solver is built with, so that the problems derived from it (an enriched problem of the
    error estimate, a branch copy of the path spread) are solved as it is.
    """

    linear: LinearSettings = LinearSettings()
    newton: NewtonSettings = NewtonSettings()
    path: PathSettings
