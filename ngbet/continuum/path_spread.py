r"""The force's dependence on the path: its spread over the branches a run's path left at its relaxations.

Where displacement control relaxes to a stable state (a snap-through at a fold, or a relaxation
after Newton failed on a short increment: :func:`ngbet.numerics.relax.relax`), the path leaves
the branch it was on. Where that branch goes on existing, the model has two (or more) stable
equilibria at the same clamp displacement, and which one a run reports depends on its path
(the step sizes, the barrier, the kick's sign). The spread of the force over them is an
uncertainty of the answer that no refinement of the discretization removes.

Method: the state just before each relaxation (at its load λ_b, on the branch the path left) is
kept. At every load λ > λ_b where the error is estimated, that branch is continued from its last
state to λ on a copy of the problem (the run's own is not touched: its state and factorization
stay the path's, and its forces are the same bit for bit): tangent predictor and Newton
(:func:`ngbet.numerics.newton.newton`), the first increment twice the path's shortest step (the
branch stands next to its fold), doubled after each success up to :data:`BRANCH_MAX_STEP`,
halved on failure down to the shortest step. If it reaches λ and the condensed tangent is
positive definite there (``problem.lowest_mode()``), the branch is a stable equilibrium at λ and
contributes |F_branch − F_path|; if it cannot be continued (a fold: the usual end of the branch a
snap left), is unstable, or has rejoined the path's state, it no longer exists apart from the
path and contributes nothing from then on (its record says where and why it ended). The continued
state is kept for the next estimated load.

.. math::  s(\lambda) = \max_b |F_b(\lambda) - F_{path}(\lambda)|

The error bar of the run (:class:`ngbet.continuum.estimate.RunEstimates`) is η + s, η the
discretization estimate: the exact force of any equilibrium the path could have taken lies within
|F_h,path − F_h,b| + |F_h,b − F_b| ≤ s + η of the reported one (triangle inequality, the
discretization error of a neighbouring branch taken as that of the path's).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..numerics.newton import Problem, newton
from ..numerics.settings import NewtonSettings

__all__ = ["BRANCH_MAX_STEP", "SAME_FORCE", "SAME_STATE", "Branch", "PathSpread", "RunPathSpread"]

log = logging.getLogger(__name__)

#: a branch whose state at the load differs from the path's by less than this (the problem's
#: unit-free norm) is the path itself (a relaxation that came back to it): no second equilibrium
SAME_STATE = 1e-6
#: ... or whose force differs from the path's by less than this fraction of it: Newton's tolerance
#: (measured: a branch that rejoined the path on 0.1 mm corners at p = 6 stayed 3e-10 to 4.5e-7 N,
#: at most 5e-9 of the force, from it at 46–56 mm; the finest accuracy the ladder offers is 2.5e-5)
SAME_FORCE = 1e-7
#: the longest increment of a branch's continuation [m]: longer ones may jump onto another branch
#: (measured: from 43 to 56 mm on 0.1 mm corners at p = 6, increments doubling up to 16 mm ended on
#: an unstable equilibrium at 56 mm; increments of at most 2 mm followed the stable branch there)
BRANCH_MAX_STEP = 2e-3


@dataclass
class Branch:
    """A branch the path left at a relaxation, as continued so far."""

    left_mm: float  #: the load where the path left it [mm]
    snap: bool  #: the relaxation released energy (a snap-through), not only a hard increment
    lam: float  #: the load of ``x`` [m]
    x: np.ndarray  #: its last state
    ended: str = ""  #: why it no longer exists ("" while it does)
    h: float = 0.0  #: the next increment of its continuation [m] (0: not started)
    records: dict[str, dict[str, Any]] = field(default_factory=dict)  # load [mm] -> what it gave there


class PathSpread:
    """The spread of the force over the branches a path left, at the loads asked (:meth:`at`).

    Parameters
    ----------
    make_problem : callable
        Builds the copy of the problem on which the branches are continued (called once, at the
        first load asked after a relaxation); its ``x`` has the layout of the states given to
        :meth:`left`.
    force : callable
        ``force(problem, residual) -> F`` [N] of a converged state.
    settings : NewtonSettings
        Newton's settings (the run's).
    first_step, min_step, max_step : float
        Increments of the continuation [m]: the first, the shortest before the branch is declared
        ended, the longest.
    """

    def __init__(
        self,
        make_problem: Callable[[], Problem],
        force: Callable[[Any, np.ndarray], float],
        settings: NewtonSettings,
        first_step: float,
        min_step: float,
        max_step: float = math.inf,
    ) -> None:
        self._make = make_problem
        self.problem: Any = None
        self.force = force
        self.settings = settings
        self.first_step = first_step
        self.min_step = max(min_step, 1e-12)
        self.max_step = max_step
        self.branches: list[Branch] = []
        self.total_s = 0.0

    def left(self, lam: float, x: np.ndarray, snap: bool) -> None:
        """The path left the branch whose state at load ``lam`` [m] is ``x`` (copied)."""
        self.branches.append(Branch(lam * 1e3, snap, lam, np.array(x, copy=True)))

    def at(self, lam: float, force_N: float, x_path: np.ndarray | None = None) -> float:
        """The spread [N] of the force at ``lam`` [m] over the branches left before it (0 if none exists).

        ``x_path``: the path's state at ``lam``, to tell a branch that came back to it.
        """
        t0 = time.perf_counter()
        spread = 0.0
        for b in self.branches:
            if b.ended or b.lam > lam:
                continue
            if self.problem is None:
                self.problem = self._make()
            rec = self._continue(b, lam, force_N, x_path)
            if rec.get("stable"):
                rec["spread_N"] = abs(rec["force_N"] - force_N)
                spread = max(spread, rec["spread_N"])
            b.records[f"{lam * 1e3:g}"] = rec
        self.total_s += time.perf_counter() - t0
        return spread

    def _continue(self, b: Branch, lam: float, force_N: float, x_path: np.ndarray | None) -> dict[str, Any]:
        """Carry branch ``b`` to ``lam``: its force there if it is a stable equilibrium, or why it ended.

        A branch back on the path's state (within :data:`SAME_STATE`, or its force within
        :data:`SAME_FORCE` of the path's) has rejoined the path: it ends there (from the same
        state it would follow the path), without a stability test.
        """
        p = self.problem
        # a branch left at a relaxation stands next to its fold: the first increment is the shortest
        # but one, doubled after each success (a long one could jump over the fold onto another branch)
        h = b.h if b.h > 0 else min(2.0 * self.min_step, self.first_step, self.max_step)
        its = 0
        while b.lam < lam:
            h = min(h, lam - b.lam)
            p.x[:] = b.x
            p.state.set_load(b.lam)
            p.factorize()
            p.x[:] += p.load_tangent(h)
            p.state.set_load(b.lam + h)
            e_ref = p.energy()
            rep = newton(p, self.settings, e_ref if math.isfinite(e_ref) else 0.0)
            its += rep.iterations
            if rep.converged:
                b.lam += h
                b.x = p.x.copy()
                h = b.h = min(2.0 * h, self.first_step, self.max_step)
                continue
            h *= 0.5
            if h < self.min_step:
                b.ended = (
                    f"cannot be continued beyond {b.lam * 1e3:.6g} mm (Newton: {rep.reason}): the branch folds there"
                )
                log.info("path spread: the branch left at %.6g mm %s", b.left_mm, b.ended)
                return {"stable": False, "ended": b.ended, "newton_iterations": its}
        p.x[:] = b.x
        p.state.set_load(lam)
        F = float(self.force(p, p.residual()))
        dist = float(p.state.norm(p.x - x_path)) if x_path is not None else math.inf  # unit-free
        if dist <= SAME_STATE or abs(F - force_N) <= SAME_FORCE * abs(force_N):
            b.ended = f"rejoined the path at {lam * 1e3:.6g} mm"
            return {"stable": False, "ended": b.ended, "force_N": F, "distance_to_path": dist, "newton_iterations": its}
        mu, _ = p.lowest_mode()
        if not mu > 0:
            b.ended = f"unstable at {lam * 1e3:.6g} mm (lowest scaled eigenvalue {mu:.3g})"
            return {"stable": False, "ended": b.ended, "force_N": F, "distance_to_path": dist, "newton_iterations": its}
        return {
            "stable": True,
            "force_N": F,
            "lowest_eigenvalue": float(mu),
            "distance_to_path": dist,
            "newton_iterations": its,
        }

    def summary(self) -> list[dict[str, Any]]:
        """Each branch left: where, whether by a snap-through, and what it gave at each load asked."""
        return [{"left_at_mm": b.left_mm, "snap": b.snap, "ended": b.ended, "loads": b.records} for b in self.branches]


class RunPathSpread:
    """The path spread of a continuum run, folded into its error estimates (:class:`~.estimate.RunEstimates`).

    Costs nothing until the path relaxes (:meth:`left`); from then on, at each estimated load, the
    branches left are continued on a copy of the problem (built once) with a solver of its own,
    of the run's settings. ``solver``: the run's (:class:`~ngbet.continuum.solver.ContinuumSolver`).
    """

    def __init__(self, solver: Any) -> None:
        self.solver = solver
        self.spread: PathSpread | None = None
        self.last = math.nan  #: the spread at the last estimated load [N]

    @property
    def cost_s(self) -> float:
        """Wall time spent continuing the branches [s]."""
        return self.spread.total_s if self.spread is not None else 0.0

    def left(self, lam: float, x: np.ndarray, snap: bool) -> None:
        """The path relaxed after load ``lam`` [m], leaving the branch whose state there is ``x``."""
        if self.spread is None:
            settings = self.solver.settings
            path = settings.path
            self.spread = PathSpread(
                self._copy,
                self._force,
                settings.newton,
                path.first_step,
                path.min_step,
                min(path.max_step, BRANCH_MAX_STEP),
            )
        self.spread.left(lam, x, snap)

    def _copy(self) -> Any:
        from .problem import ContinuumProblem
        from .solver import ContinuumSolver

        run = self.solver.problem
        return ContinuumSolver(ContinuumProblem(run.scene, mesh=run.mesh), self.solver.settings)

    def _force(self, solver: Any, r: np.ndarray) -> float:
        from .observables import reaction_force

        return cast(float, float(reaction_force(solver.problem, r)) * solver.problem.scene.specimen.t)

    def fold(self, lam: float, e: Any) -> Any:
        """The estimate ``e`` at ``lam`` [m] with the spread added to its bar (``e`` itself before any relaxation).

        A bar the estimate cannot vouch for (nan) stays nan; the spread is recorded all the same.
        """
        if self.spread is None:
            return e
        sp = self.spread
        if sp.problem is None:
            sp.problem = self._copy()
        run, copy = self.solver.problem, sp.problem.problem
        if run.jamming.on and not copy.jamming.on:
            copy.jamming.switch_on()  # the copy's barrier as the run's
        s = self.last = sp.at(lam, e.force_N, self.solver.x)
        if s > 0:
            log.warning(
                "at u0 = %.6g mm the force depends on the path: a branch the path left at a relaxation is "
                "stable there with a force %.3g N away; the error bar includes it",
                lam * 1e3,
                s,
            )
        return dataclasses.replace(e, force_error_N=e.force_error_N + s, path_spread_N=s)

    def summary(self) -> dict[str, Any]:
        """Summary keys: the spread at the last estimated load and each branch's record ({} before any relaxation)."""
        if self.spread is None:
            return {}
        return {
            "force_path_spread_N": self.last if math.isfinite(self.last) else None,
            "path_spread": {"branches": self.spread.summary(), "cost_s": self.spread.total_s},
        }
