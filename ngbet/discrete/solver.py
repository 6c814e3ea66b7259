"""The network's corrector: shifted minimizing Newton with stability check and snap handling.

:class:`ShiftedNewton` runs on the engine's load stepping (:func:`ngbet.numerics.engine.path_steps`);
:func:`load_steps` puts the two together: a generator of the step records (each with its state),
which the runner (:mod:`ngbet.runner.discrete`) iterates and writes from. Newton at a fixed load is
:func:`ngbet.discrete.newton.newton`, the stability check :func:`ngbet.discrete.eigen.lowest_eigenvalues`;
both are described below.

The solver knows nothing of yarns. A problem provides ``n_dofs``, ``fixed`` (bool mask of
prescribed dofs), ``load`` (prescribed values per unit load parameter u0), ``ramp`` (a field for
the "clamp" predictor) and ``evaluate(u, hessian) -> (E, dE/du, d2E/du2)``, and may provide
``half_turn()`` (:class:`~ngbet.discrete.newton.Symmetric`, :mod:`.symmetry`): then the tangents
of states on the symmetric path are factorized as their two half-size blocks, and the predictions
are projected back onto that path.

Step from u0 to u0 + h:
  predictor  "tangent": u_f += -K_ff^{-1} K_fc h load_c  (K at the last converged state)
             "clamp":   u   += h ramp
  corrector  Newton on the free dofs, du = -K_ff^{-1} r; where du is not a descent direction
             (K_ff indefinite) the tangent is shifted by mu diag(K_ff) until it is (mu from a
             tenth of the last shift of the same Newton run, 1e-6 at first, raised tenfold).
             While relaxing past a snap-through: Armijo backtracking on the energy, and shifted
             steps extended while the energy keeps falling along them.
             Inexact (networks of at least ``krylov_min_free`` free dofs): once the decrement is
             below the energy, an iteration solves its own tangent by conjugate gradients
             preconditioned with the last factorization (to ``krylov_tol``; a factorization
             where CG meets negative curvature or needs more than ``krylov_max`` iterations),
             and a step converged that way ends with one full Newton iteration.
  converged  when the Newton decrement |r . du| (an energy, twice the predicted energy change)
             is below rtol |E| + atol: unit-free.
  step size  (the engine, with ``ctl.path``) grows by ``growth`` (up to max_step) after a step
             with at most ``grow_after`` iterations, is cut by ``cut`` after a failed step, and a
             step below ``min_step`` raises :class:`ngbet.errors.ConvergenceError` (every attempt's
             decrements, the last converged u0 in mm). A step
             longer than ``snap_bracket`` stops at its first indefinite tangent and is cut (it
             would be cut as a possible snap anyway, see below); a step no longer than that
             stops there too and is relaxed from its last iterate (see ``_relax``): a step that
             needs a shifted tangent is a snap event either way, and the damped Newton of the
             relaxation gets there with fewer factorizations than shifted Newton giving up
             after its contraction checks.
  snap       a step that releases energy (energy change below the work of the clamp, by the
             Hermite rule with F' = dF/du0 at both ends: exact to O(h^5) on a continuous branch)
             beyond ``snap_release_hermite`` of that work (``snap_release`` for the trapezoid when
             a tangent is missing) has jumped branches: it is cut to ``snap_bracket`` and, at that
             length, accepted and reported as a snap-through.
  stability  at each converged state the eigenvalues of K_ff v = lambda D v nearest to 0
             (D = diag K_ff, so lambda is unit-free) are computed by shift-invert Lanczos with the
             factorization already made for the next predictor. lambda_min < 0 means an unstable
             equilibrium: it is logged, perturbed along the unstable mode (both signs) and
             relaxed to the lower stable neighbour, and counted as a snap event. A step that
             only converges with shifted (indefinite) tangents is also a snap event: the state
             jumped to a non-adjacent branch.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Generator, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import scipy.sparse as sp

from ..errors import Attempt, ConvergenceError
from ..numerics import engine
from ..numerics.engine import Outcome, PathResult, StepRecord
from .eigen import check_stability
from .linsolve import FreeBlockSolver
from .newton import Problem, StepControl, StepFailed, Symmetric, Tally, TimedProblem, newton

log = logging.getLogger(__name__)

__all__ = ["ShiftedNewton", "load_steps"]


def load_steps(
    problem: Problem, ctl: StepControl, out: PathResult | None = None
) -> Generator[StepRecord, None, PathResult]:
    """Follow the load path u0 = 0 -> ``ctl.path.target`` with :class:`ShiftedNewton` on the engine.

    Yields the record of each converged step, its state in ``state`` (dropped when the path moves
    on: the result keeps no states); returns the :class:`~ngbet.numerics.engine.PathResult` (``out`` if
    given), whose ``path_info`` holds the iteration and time statistics and the snap events, as of
    the last step yielded while the path goes on. The caller holds the BLAS pools to one thread
    (:func:`ngbet.runner.threads.single_threaded_blas`, within every run): the solver's dense
    operations are vector-sized (dot products, the Lanczos block of a few columns), where a
    second BLAS thread saves nothing and, spinning between calls, keeps a second core busy.

    Raises
    ------
    ngbet.errors.ConvergenceError
        when a step fails at the minimum step size (the states before it have been yielded);
        its ``path_info`` holds the statistics gathered until then (snap events included).
    KeyboardInterrupt
        passed on with the same ``path_info`` attached (Ctrl-C, SIGTERM).
    """
    out = PathResult(0.0) if out is None else out
    corrector = ShiftedNewton(problem, ctl)
    try:
        for rec in engine.path_steps(corrector, ctl.path, out):
            out.path_info = corrector.statistics()
            yield rec
            rec.state = None
    except (ConvergenceError, KeyboardInterrupt) as exc:  # Ctrl-C / SIGTERM too: the statistics so far
        out.path_info = info = corrector.statistics()
        if isinstance(exc, ConvergenceError):
            exc.path_info.update(info)
        else:
            exc.path_info = info  # type: ignore[attr-defined]
        raise
    out.path_info = corrector.statistics()
    return out


@dataclass
class _Trial:
    """A corrected state awaiting acceptance (between ``correct`` and ``accept``)."""

    u: np.ndarray
    iterations: int
    history: list[tuple[float, float, float]]
    shifted: int
    relaxed: bool
    nout: dict[str, Any]
    mark: tuple[int, int, float]
    energy: float = math.nan
    gradient: np.ndarray | None = None
    tangent: np.ndarray | None = None  # du/du0 at the corrected state (None: none at hand)
    dforce_du0: float = math.nan
    released: float = 0.0
    work: float = 0.0
    jumped: bool = False


def _decrements(history: list[tuple[float, float, float]]) -> list[float]:
    return [h[2] for h in history]


class ShiftedNewton:
    """The network's corrector for :func:`ngbet.numerics.engine.path_steps` (see the module docstring).

    Two factorizations of the same pattern: ``lin`` holds the tangent at the converged state
    (predictor, stability check, restart after a failed or cut step: no refactorization),
    ``work`` the Newton iterations; they swap roles when a step is accepted.
    """

    def __init__(self, problem: Problem, ctl: StepControl) -> None:
        self.problem = self._timed = TimedProblem(problem)
        self.ctl = ctl
        self.u = np.zeros(problem.n_dofs)
        self.E, self.g, K = self.problem.evaluate(self.u, True)
        assert K is not None
        self.K: sp.csr_matrix = K
        free_mask = ~problem.fixed
        self.half_turn = problem.half_turn() if (ctl.half_turn and isinstance(problem, Symmetric)) else None
        self.lin = FreeBlockSolver(K, free_mask, ctl.backend, self.half_turn)
        self.work = self.lin.twin()
        self.free = self.lin.free
        self.tally = Tally((self.lin, self.work))
        mark = self.tally.start()
        self.lin.factor(K)
        self.tally.add("initial tangent", mark)
        self.modes: np.ndarray | None = None  # modes of the last stability check: start block of the next
        self.tangent: np.ndarray | None = None  # du/du0 at the converged state
        self.tangent_prev: tuple[np.ndarray, float] | None = None  # du/du0 one step back, and that step
        self.step = 0
        self.stats: dict[str, Any] = {
            "newton_iterations": 0,
            "failed_steps": 0,
            "snap_events": [],
            "unstable_states": 0,
            "shifted_iterations": 0,
            "t_stability_s": 0.0,
            "lambda_min": [],
            "factorizations": 0,
            "snap_bracketing": 0,
        }
        self._predicted = self.u
        self._trial: _Trial | None = None

    # ------------------------------------------------------------------------------ predict
    def _tangent_at(self, lin: FreeBlockSolver, K: sp.csr_matrix) -> np.ndarray:
        """du/du0 at the state whose tangent K is factorized in ``lin``.

        On the symmetric path (``lin`` holds the half-turn blocks) du/du0 - S du/du0 = c, so du/du0
        is c / 2 (a rigid translation, K c = 0) plus a symmetric field w that the symmetric block
        gives alone; solved whole, that translation would come out of the soft antisymmetric
        block only to about 1e-5 (cancellation in K c).
        """
        load, free = self.problem.load, self.free
        ht = self.half_turn
        if ht is None or not lin.in_blocks:
            t = load.copy()
            t[free] = -lin.solve((K @ load)[free])
            return t
        w = np.where(self.problem.fixed, load - 0.5 * ht.shift, 0.0)
        t = 0.5 * ht.shift + w
        t[free] += -lin.solve((K @ w)[free], symmetric_rhs=True)
        return cast(np.ndarray, t)

    def predict(self, u0: float, h: float) -> None:
        """Tangent predictor with the second-order (Hermite) term, or the clamp's ramp."""
        p, free = self.problem, self.free
        trial = self.u.copy()
        if self.ctl.predictor == "tangent":
            if self.tangent is None:  # at the start and after a jump
                mark = self.tally.start()
                self.tangent = self._tangent_at(self.lin, self.K)
                self.tally.add("predictor tangent", mark)
            trial += h * self.tangent
            if self.tangent_prev is not None:
                t_prev, h_prev = self.tangent_prev
                trial[free] += 0.5 * h * h * (self.tangent[free] - t_prev[free]) / h_prev
        else:
            trial += h * p.ramp
            trial[p.fixed] = self.u[p.fixed] + h * p.load[p.fixed]
        if self.half_turn is not None:
            # on the symmetric path, the prediction is put back on it (off it by round-off only), so
            # that Newton's tangents stay block diagonal and its steps symmetric
            sym = self.half_turn.project(trial, u0 + h)
            trial = trial if sym is None else sym
        self._predicted = trial

    # ------------------------------------------------------------------------------ correct
    def correct(self, u0: float, h: float) -> Outcome:
        """Newton from the prediction; relaxation past a limit point; snap classification."""
        ctl = self.ctl
        nout: dict[str, Any] = {}
        mark = self.tally.start()
        bracketing = h > ctl.snap_bracket * (1 + 1e-9)
        try:
            # a step that meets an indefinite tangent is a snap event whether or not Newton converges
            # (see ``_classify``): give up at once; a step longer than the snap bracket is cut, a
            # shorter one relaxed from the last iterate
            unew, its, hist, shifted = newton(
                self.problem, self._predicted, self.work, ctl, out=nout, allow_shift=False, inexact=True
            )
            trial = _Trial(unew, its, hist, shifted, False, nout, mark)
        except StepFailed as exc:
            if exc.indefinite and bracketing:
                self.tally.add("indefinite tangent (step cut to bracket a snap)", mark, nout)
                log.info(
                    "step u0 %.5g -> %.5g mm met an indefinite tangent: cutting to bracket a snap",
                    u0 * 1e3,
                    (u0 + h) * 1e3,
                )
                return self._bracket(h, len(exc.history), _decrements(exc.history), str(exc))
            self.tally.add("failed attempt", mark, nout)
            self.stats["failed_steps"] += 1
            log.info("step u0 %.5g -> %.5g mm failed (%s)", u0 * 1e3, (u0 + h) * 1e3, exc)
            relaxed = None
            if not bracketing or h * ctl.path.cut < ctl.path.min_step * (1 - 1e-9):
                relaxed = self._relax(exc, u0, h)
            if relaxed is None:
                return Outcome("failed", len(exc.history), _decrements(exc.history), str(exc))
            trial = relaxed
        return self._classify(trial, u0, h)

    def _bracket(self, h: float, iterations: int, history: list[float], reason: str) -> Outcome:
        """Retry at a shorter step, not below the snap bracket."""
        self.stats["snap_bracketing"] += 1
        step = max(h * self.ctl.path.cut, self.ctl.snap_bracket)
        return Outcome("retry", iterations, history, reason, retry_step=step)

    def _relax(self, exc: StepFailed, u0: float, h: float) -> _Trial | None:
        """After a short step failed: no equilibrium near the predictor, the branch ends (limit point).

        A damped Newton (shifted where indefinite) runs long enough to reach the branch the state
        snaps to, from where the failed attempt got if that is lower.
        """
        p, ctl = self.problem, self.ctl
        start = self._predicted
        if exc.u is not None:
            E_fail = p.evaluate(exc.u, False)[0]
            E_trial = exc.history[0][0] if exc.history else p.evaluate(start, False)[0]
            if np.isfinite(E_fail) and E_fail < E_trial:
                start = exc.u
        nout: dict[str, Any] = {}
        mark = self.tally.start()
        trial = None
        try:
            unew, its, hist, shifted = newton(
                p,
                start,
                self.work,
                ctl,
                max_iterations=4 * ctl.max_iterations,
                line_search=True,
                fail_fast=False,
                out=nout,
                inexact=True,
            )
            # the state left its branch
            trial = _Trial(unew, its + len(exc.history), hist, max(shifted, 1), True, nout, mark)
        except StepFailed as exc2:
            log.info("relaxation u0 %.5g -> %.5g mm failed (%s)", u0 * 1e3, (u0 + h) * 1e3, exc2)
        self.tally.add("relaxation", mark, nout)
        return trial

    def _classify(self, tr: _Trial, u0: float, h: float) -> Outcome:
        """Accept the converged state, or ask for a shorter step when it has snapped.

        Envelope theorem: on a continuous branch dE/du0 = F = load . g, so the work of the clamp
        equals the energy change; energy released beyond it is a snap-through. The work by the
        trapezoidal rule is exact to O(h^3 F''); with F' = dF/du0 = load . K du/du0 at both ends
        (the tangent at the start is the predictor's, the one at the end the next predictor's,
        from the factorization at hand) the Hermite rule adds h^2/12 (F'_0 - F'_1) and is exact
        to O(h^5): on smooth steps of up to 7.6 mm at 17k dofs it left <= 2e-5 of the step's work,
        snaps released >= 2 %; the trapezoid alone left up to 0.5 %, and a snap of 2-4 % of a
        long step's work hid below its 5 % threshold.
        """
        p, ctl, load = self.problem, self.ctl, self.problem.load
        tr.energy, tr.gradient, _ = p.evaluate(tr.u, False)
        tr.work = 0.5 * h * float(load @ self.g + load @ tr.gradient)
        if self.tangent is not None and not self.work.shifted:
            mark = self.tally.start()
            tr.tangent = self._tangent_at(self.work, tr.nout["K"])
            if tr.relaxed:  # the relaxation's row is closed; a converged step's row is closed later
                self.tally.add("tangent after a relaxation", mark)
            dF0 = float(load @ (self.K @ self.tangent))
            tr.dforce_du0 = float(load @ (tr.nout["K"] @ tr.tangent))
            tr.work += h * h / 12 * (dF0 - tr.dforce_du0)
        tr.released = tr.work - (tr.energy - self.E)
        threshold = ctl.snap_release_hermite if tr.tangent is not None else ctl.snap_release
        tr.jumped = tr.released > threshold * abs(tr.work) or tr.shifted > 0
        decs = _decrements(tr.history)
        if tr.jumped and h > ctl.snap_bracket * (1 + 1e-9):
            if not tr.relaxed:
                self.tally.add("snap bracketing (converged, rejected)", tr.mark, tr.nout)
            log.info(
                "step u0 %.5g -> %.5g mm released %.3g J of %.3g J work (indefinite iterations: %d): "
                "cutting to bracket the snap",
                u0 * 1e3,
                (u0 + h) * 1e3,
                tr.released,
                tr.work,
                tr.shifted,
            )
            return self._bracket(h, tr.iterations, decs, "snap-through: bracketing")
        self._trial = tr
        return Outcome("converged", tr.iterations, decs, "converged")

    # ------------------------------------------------------------------------------ accept / reject
    def reject(self, u0: float, outcome: Outcome) -> None:
        """Nothing to undo: the converged state and its factorization (``lin``) are untouched."""
        self._trial = None

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        """Commit the trial, record a snap-through, check the stability of the new state."""
        tr = self._trial
        assert tr is not None and tr.gradient is not None
        self._commit(tr, h)
        u0_new = u0 + h
        if tr.jumped:
            self._record_snap(tr, u0, u0_new)
        rec = StepRecord(
            self.step,
            u0_new,
            tr.iterations,
            residual=self.g,
            energy=self.E,
            snap=tr.jumped,
            released=tr.released,
            history=_decrements(tr.history),
            dforce_du0=tr.dforce_du0,
        )
        if self.ctl.stability:
            rec.lambda_min, escaped = self._check(u0_new)
            if escaped:
                rec.residual, rec.energy, rec.snap, rec.dforce_du0 = self.g, self.E, True, math.nan
        self.stats["lambda_min"].append(rec.lambda_min)
        rec.state = self.u
        return rec

    def _commit(self, tr: _Trial, h: float) -> None:
        """The trial becomes the converged state; ``lin`` gets its tangent (refactorized only after a shift).

        The tangent of the last Newton iteration is the converged one up to the last update
        (below the tolerance).
        """
        K_new = tr.nout["K"]
        if not tr.relaxed:
            self.tally.add("converged step", tr.mark, tr.nout)
        if self.work.shifted:
            mark = self.tally.start()
            K_new = self.problem.evaluate(tr.u, True)[2]
            self.work.factor(K_new)
            self.tally.add("converged tangent after a shifted last iteration", mark)
        self.lin, self.work = self.work, self.lin
        self.tangent_prev = (self.tangent, h) if (self.tangent is not None and not tr.jumped) else None
        self.tangent = tr.tangent  # du/du0 at the new state (None: the predictor solves for it)
        self.stats["newton_iterations"] += tr.iterations
        self.stats["shifted_iterations"] += tr.shifted
        assert tr.gradient is not None
        self.u, self.E, self.g, self.K = tr.u, tr.energy, tr.gradient, K_new
        self.step += 1
        self._trial = None

    def _record_snap(self, tr: _Trial, u0: float, u0_new: float) -> None:
        # one plain line: the force curve jumps here (its energy and iterations are in summary.json, snap_events)
        log.warning(
            "the network snaps through between u0 = %.4g and %.4g mm: the force jumps there", u0 * 1e3, u0_new * 1e3
        )
        self.stats["snap_events"].append(
            {
                "u0": u0_new,
                "u0_before": u0,
                "kind": "snap_through",
                "step": self.step,
                "released_J": tr.released,
                "work_J": tr.work,
                "indefinite_iterations": tr.shifted,
            }
        )

    def _check(self, u0: float) -> tuple[float, bool]:
        """Lowest eigenvalue at the converged state; an unstable state is left for a stable neighbour.

        Returns the lowest eigenvalue (after an escape: that of the new state) and whether the
        state changed.
        """
        ts = time.perf_counter()
        mark = self.tally.start(ts)
        lam, v, V = check_stability(self.lin, self.ctl, self.modes)
        self.modes = V
        self.tally.add("stability check", mark)
        escaped = lam < -1e-9 and v is not None
        if escaped:
            assert v is not None and self.lin.Kff is not None
            self.stats["unstable_states"] += 1
            mark = self.tally.start()
            self.u, self.E, self.g, self.K, lam2, self.modes = _escape(
                self.problem, self.u, self.E, v, self.work, self.ctl, np.abs(self.lin.diagonal())
            )
            self.tally.add("escape from an unstable state", mark)
            self.lin, self.work = self.work, self.lin  # _escape left the tangent of the final state in ``work``
            self.tangent_prev = self.tangent = None
            self.stats["snap_events"].append(
                {
                    "u0": u0,
                    "kind": "unstable_equilibrium",
                    "step": self.step,
                    "lambda_min": lam,
                    "lambda_min_after": lam2,
                }
            )
            log.warning(
                "step %d, u0 = %.5g mm: unstable equilibrium (lambda_min = %.3g); relaxed to lambda_min = %.3g",
                self.step,
                u0 * 1e3,
                lam,
                lam2,
            )
            lam = lam2
        self.stats["t_stability_s"] += time.perf_counter() - ts
        return lam, escaped

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        """The snap events met before the failure (the network fails where it keeps snapping)."""
        n = len(self.stats["snap_events"])
        return (f"{n} snap events before the failure" if n else ""), None

    def statistics(self) -> dict[str, Any]:
        """Iteration, factorization and time statistics of the path (for the summary)."""
        lin, work, t = self.lin, self.work, self._timed
        s = dict(self.stats)
        s.update(
            {
                "steps": self.step,
                "backend": lin.backend,
                "n_free": len(self.free),
                "factorizations": lin.n_factor + work.n_factor,
                "work_by_cause": self.tally.rows,
                "half_turn_blocks": lin.has_half_turn,
                "factorizations_antisymmetric": lin.n_factor_antisymmetric + work.n_factor_antisymmetric,
                "factorizations_ldlt": lin.n_factor_ldlt + work.n_factor_ldlt,
                "factorizations_off_symmetry": lin.n_factor_whole + work.n_factor_whole,
            }
        )
        s["timers"] = {
            "assembly_s": t.t_hessian,
            "assemblies": t.n_hessian,
            "gradient_only_s": t.t_gradient,
            "gradients_only": t.n_gradient,
            "factor_s": lin.t_factor + work.t_factor,
            "solve_s": lin.t_solve + work.t_solve,
            "solves": lin.n_solve + work.n_solve,
        }
        return s


def _escape(
    problem: Problem, u: np.ndarray, E: float, v: np.ndarray, lin: FreeBlockSolver, ctl: StepControl, diag: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray, sp.csr_matrix, float, np.ndarray | None]:
    """Leave an unstable equilibrium along its unstable mode v (both signs); keep the lower stable state.

    ``lin`` is a solver whose factorization may be overwritten; it holds the tangent at the
    returned state on return. ``diag``: |diag K_ff| at u (the metric of v).
    """
    free = lin.free
    # a kick whose quadratic energy is 1e-3 |E|: large enough to leave the saddle, small on the whole
    amp = np.sqrt(2e-3 * max(abs(E), 1e-30) / max(float(v @ (diag * v)), 1e-300))
    best = None
    for sgn in (1.0, -1.0):
        w = u.copy()
        w[free] += sgn * amp * v
        try:
            w, _, _, _ = newton(problem, w, lin, ctl, max_iterations=20 * ctl.max_iterations, line_search=True)
        except StepFailed:
            continue
        Ew = problem.evaluate(w, False)[0]
        if best is None or Ew < best[1]:
            best = (w, Ew)
    if best is not None and best[1] < E:
        u = best[0]
    E, g, K = problem.evaluate(u, True)
    lin.factor(K)
    lam2, _, V = check_stability(lin, ctl)
    return u, E, g, K, lam2, V
