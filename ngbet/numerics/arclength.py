r"""Following the equilibrium path through an instability: pseudo-arclength continuation.

Displacement control fixes the clamp displacement u0 = λ and solves r(x; λ) = 0 for the free
state x. Where the tangent J = ∂r/∂x becomes singular it cannot go on: at a turning point in u0
(a snap-back, the path turns back in u0) no equilibrium exists just beyond, and near it Newton
fails however small the increment. Pseudo-arclength continuation (Keller; Riks) treats λ as an
unknown and adds the constraint that the step lies on the hyperplane normal to the unit tangent
τ of the path at the last converged point, at the distance Δs:

    r(x, λ) = 0,        ⟨τ, (x − x₀, λ − λ₀)⟩ = Δs,

with ⟨a, b⟩ = Σ (w a)(w b) + a_λ b_λ / L², w the problem's unit-free weights (u by 1/L). The
Newton step of this bordered system is solved with the one factorization of J (two solves per
iteration): dx_r = −J⁻¹ r and the load tangent T = ∂x/∂λ = −J⁻¹ J_λ, then
dλ = −(g + ⟨τ, dx_r⟩) / ⟨τ, (T, 1)⟩ and (dx, dλ) = (dx_r + dλ T, dλ); the predictor satisfies
the constraint, so g = 0 and it stays 0 along the iteration.

The tangent's orientation follows the previous one (⟨τ_new, τ_old⟩ > 0), so the path passes
turning points in u0. Along the way the kind of instability is told apart:

- ``snap-back``: the λ-component of the tangent changes sign (the path turns back in u0);
  displacement control cannot pass it;
- ``bifurcation``: the lowest eigenvalue of the (scaled) tangent changes sign while u0 keeps
  growing; it is located by linear interpolation of the eigenvalue to zero between the two points;
- ``force maximum``: dF/du0 changes sign with a stable tangent; displacement control passes it.

At a bifurcation the path stays on its branch (``branch = "stay"``), or switches to the
bifurcated one (``branch = "switch"``): from the located point x_c, λ_c (interpolated between the
two points) the next step is predicted along the critical mode φ_c (the eigenvector of the
vanishing eigenvalue, its largest weighted entry made positive, times ``branch_sign``), made
orthogonal to the path's tangent τ, and corrected on the hyperplane normal to that direction at
the current Δs:

    n = (φ_c, 0) − ⟨(φ_c, 0), τ⟩ τ,    r(x, λ) = 0,    ⟨n, (x − x_c, λ − λ_c)⟩ = Δs |n|.

The trivial branch lies in that hyperplane's direction to first order, so the corrector lands on
the bifurcated branch, at amplitude ≈ Δs along φ_c; the path goes on from there.

:func:`arclength_steps` is a generator of the engine's step records (each carrying the
instabilities found in its step), run by the engine's one step loop
(:func:`ngbet.numerics.engine.path_steps`) with arc length as its corrector and step length; the
runner iterates it and decides what to write.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import Attempt, ConvergenceError
from .engine import Outcome, PathControl, PathResult, StepRecord, path_steps
from .newton import Problem, newton
from .settings import NewtonSettings

log = logging.getLogger(__name__)

__all__ = ["ArcLengthSettings", "Instability", "arclength_steps"]


@dataclass(frozen=True, kw_only=True)
class ArcLengthSettings(PathControl):
    """Step control of the arc-length continuation (lengths as clamp displacements [m] at the start).

    The engine's (:class:`~ngbet.numerics.engine.PathControl`): ``stops`` are the loads the path lands on
    the first time it reaches them (output stops), besides the target; ``growth``, ``cut`` and
    ``grow_after`` act on the arc length; ``land_within`` is not read.
    """

    max_steps: int = 200
    #: the path is given up when it returns below this fraction of the load it started from
    floor: float = 0.9


@dataclass
class Instability:
    """Where and what kind the path's instability is (loads [mm], force [N/m of thickness as in r])."""

    kind: str
    u0_mm: float
    reaction: float
    lowest_eigenvalue: float = math.nan
    details: dict[str, Any] = field(default_factory=dict)
    mode: np.ndarray | None = field(default=None, repr=False)  # the lowest mode of the tangent there
    #: where it lies in the last step, as a fraction of it (a bifurcation: where the eigenvalue vanishes)
    at: float = field(default=1.0, repr=False)

    def as_dict(self, thickness: float) -> dict[str, Any]:
        """The summary's record (force in N)."""
        return {
            "kind": self.kind,
            "u0_mm": self.u0_mm,
            "force_N": self.reaction * thickness,
            "lowest_eigenvalue": self.lowest_eigenvalue,
            **self.details,
        }


class _Path:
    """The state of the continuation: the converged point, its unit tangent, and the bordered Newton."""

    def __init__(self, problem: Problem, weights: np.ndarray, L: float, settings: NewtonSettings) -> None:
        self.p, self.w, self.L, self.settings = problem, weights, L, settings
        self.x0 = problem.x.copy()
        self.lam0 = problem.state.lam
        self.tau_x = np.zeros_like(self.x0)
        self.tau_l = 1.0

    def inner(self, ax: np.ndarray, al: float, bx: np.ndarray, bl: float) -> float:
        return float((self.w * ax) @ (self.w * bx) + al * bl / self.L**2)

    def tangent(self, orient: bool) -> float:
        """Factorize at the converged point and set the unit tangent; returns the norm of (T, 1)."""
        self.p.factorize()
        T = self.p.load_tangent(1.0)
        n = math.sqrt(self.inner(T, 1.0, T, 1.0))
        tx, tl = T / n, 1.0 / n
        if orient and self.inner(tx, tl, self.tau_x, self.tau_l) < 0:
            tx, tl = -tx, -tl
        self.tau_x, self.tau_l = tx, tl
        return n

    def step(self, ds: float, land: float | None = None) -> tuple[bool, int, list[float], str, np.ndarray | None]:
        """Predict by ds along τ and correct on the hyperplane (or at the fixed load ``land``).

        ``land`` is the target when the step lands on it; the state is left where it ends.
        """
        self.predict(ds, land)
        return self.correct(land)

    def predict(self, ds: float, land: float | None) -> None:
        """The predictor: ds along τ (at the load ``land`` when the step lands on it)."""
        p = self.p
        p.x[:] = self.x0 + ds * self.tau_x
        p.state.set_load(self.lam0 + ds * self.tau_l if land is None else land)

    def correct(self, land: float | None) -> tuple[bool, int, list[float], str, np.ndarray | None]:
        """Correct the predicted state on the hyperplane (or at the fixed load ``land``).

        Returns converged, iterations, decrements, reason and the residual at a converged state.
        """
        p = self.p
        if land is not None:
            e = p.energy()
            rep = newton(p, self.settings, e if math.isfinite(e) else 0.0)
            return rep.converged, rep.iterations, rep.history, rep.reason, rep.residual
        tol = self.settings.rtol * abs(p.energy()) + self.settings.atol
        history: list[float] = []
        for it in range(1, self.settings.max_iterations + 1):
            r = p.residual()
            if not np.all(np.isfinite(r)):
                return False, it, history, "residual is not finite", None
            p.factorize()
            dx = p.solve(r)
            delta = abs(float(dx @ r))
            history.append(delta)
            if delta <= tol:
                return True, it, history, "converged", r
            if not math.isfinite(delta) or (it > 3 and delta > history[0]):
                return False, it, history, "diverged", None
            T = p.load_tangent(1.0)
            dlam = -self.inner(self.tau_x, 0.0, dx, 0.0) / self.inner(self.tau_x, self.tau_l, T, 1.0)
            lam = p.state.lam + dlam
            p.x[:] += dx + dlam * np.where(self.w > 0, T, 0.0)
            p.state.set_load(lam)
        return False, self.settings.max_iterations, history, "iteration limit", None

    def commit(self) -> None:
        self.x0 = self.p.x.copy()
        self.lam0 = self.p.state.lam

    def snapshot(self) -> tuple[np.ndarray, float, np.ndarray, float]:
        """The converged point and its tangent."""
        return self.x0.copy(), self.lam0, self.tau_x.copy(), self.tau_l

    def reset(self, snap: tuple[np.ndarray, float, np.ndarray, float]) -> None:
        """Back to a point of :meth:`snapshot` (the state too)."""
        self.x0, self.lam0, self.tau_x, self.tau_l = snap[0].copy(), snap[1], snap[2].copy(), snap[3]
        self.restore()

    def restore(self) -> None:
        self.p.x[:] = self.x0
        self.p.state.set_load(self.lam0)


def arclength_steps(
    problem: Problem,
    ctl: ArcLengthSettings,
    settings: NewtonSettings,
    *,
    weights: np.ndarray,
    length: float,
    psi: np.ndarray,
    lowest_eigenpair: Callable[[], tuple[float, np.ndarray]] | None = None,
    result: PathResult | None = None,
    branch: str = "stay",
    branch_sign: float = 1.0,
) -> Generator[StepRecord, None, PathResult]:
    """Follow the path from the converged state of ``problem`` until u0 = ``ctl.target``.

    A generator of the converged points' records, each with the instabilities passed or met in
    its step (``instabilities``); it returns the result (``u0`` the last load reached; the
    caller decides what an unreached target means). ``psi`` is the reaction's test vector
    (R = ψ·r); ``lowest_eigenpair()`` gives the lowest eigenvalue of the tangent at the current
    state and its mode (full length), used to tell a bifurcation and to keep the mode of each
    instability. Steps are appended to ``result`` (a new one if None). ``branch``: at a
    bifurcation "stay" on the branch followed or "switch" to the bifurcated one along
    ``branch_sign`` times its mode (module docstring; needs ``lowest_eigenpair``). The point past
    a bifurcation on the branch left is not recorded.

    Raises
    ------
    ValueError
        at once, for an unknown ``branch`` or a switch without ``lowest_eigenpair``.
    """
    if branch not in ("stay", "switch"):
        raise ValueError(f"branch must be 'stay' or 'switch', not {branch!r}")
    if branch == "switch" and lowest_eigenpair is None:
        raise ValueError("branch = 'switch' needs lowest_eigenpair (the critical mode)")
    start = functools.partial(
        _ArcLength, problem, ctl, settings, weights, length, psi, lowest_eigenpair, branch, branch_sign
    )
    return _arclength_steps(start, problem, result)


def _arclength_steps(
    start: Callable[[PathResult], _ArcLength], problem: Problem, result: PathResult | None
) -> Generator[StepRecord, None, PathResult]:
    """The generator of :func:`arclength_steps` (its arguments checked): the engine's loop, arc length's corrector.

    ``start(result)`` builds the corrector at the generator's first step (it solves for the
    tangent there, not when the generator is made). The path stops without an error where it
    cannot go on (the step cut below its minimum, the time budget spent): the caller decides what
    an unreached target means.
    """
    res = result if result is not None else PathResult(problem.state.lam)
    given = res.u0
    arc = start(res)
    res.u0 = arc.path.lam0  # the loads of the attempts are the path's
    try:
        yield from path_steps(arc, arc.ctl, res, length=arc)
    except ConvergenceError:
        pass
    if not res.steps:
        res.u0 = given
    return res


class _ArcLength:
    """Arc length as the engine's corrector and step length (:class:`~ngbet.numerics.engine.StepLength`).

    h is the arc length Δs; a trial that would pass the next stop above the largest load reached
    is shortened to land on it, and the shortened length is the nominal one from then on. The path
    is done at the target, below ``floor`` times its start or after ``max_steps`` trials.
    """

    def __init__(
        self,
        problem: Problem,
        ctl: ArcLengthSettings,
        settings: NewtonSettings,
        weights: np.ndarray,
        length: float,
        psi: np.ndarray,
        lowest_eigenpair: Callable[[], tuple[float, np.ndarray]] | None,
        branch: str,
        branch_sign: float,
        res: PathResult,
    ) -> None:
        self.p, self.ctl, self.psi, self.res = problem, ctl, psi, res
        self.branch, self.branch_sign = branch, branch_sign
        self.path = _Path(problem, weights, length, settings)
        n = self.path.tangent(orient=False)
        # the first step moves the state as a load step of first_step would (Δx ≈ T Δu0)
        self.ds = min(ctl.first_step, ctl.max_step) * n
        self.ds_max = max(ctl.max_step / ctl.first_step, 1.0) * self.ds
        self.ds_min = ctl.min_step * n
        self.track = _Tracker(psi, lowest_eigenpair)
        self.track.start(problem, self.path)
        self.reached = self.path.lam0  # the largest load reached: a stop is landed on once, on the way up
        self.trials = 0
        self.land: float | None = None
        self.r: np.ndarray | None = None

    # the step length
    def first_step(self) -> float:
        return self.ds

    def max_step(self) -> float:
        return self.ds_max

    def too_short(self, step: float) -> bool:
        return step < self.ds_min

    def finished(self, u0: float) -> bool:
        path, ctl = self.path, self.ctl
        return (
            self.trials >= ctl.max_steps
            or path.lam0 >= ctl.target - 1e-12 * ctl.target
            or path.lam0 < ctl.floor * self.track.lam_start
        )

    def trial(self, u0: float, step: float) -> tuple[float, float, float]:
        self.trials += 1
        land = _next_mark(self.ctl, self.reached)
        to_target = _distance_to(self.path, land, step)
        ds = min(step, to_target)
        self.land = land if ds == to_target < math.inf else None
        return ds, math.nan if self.land is None else self.land, ds

    # the corrector
    def predict(self, u0: float, h: float) -> None:
        self.path.predict(h, self.land)

    def correct(self, u0: float, h: float) -> Outcome:
        ok, its, hist, why, self.r = self.path.correct(self.land)
        return Outcome("converged" if ok else "failed", its, hist, why, u0=self.p.state.lam)

    def accept(self, u0: float, h: float, outcome: Outcome) -> StepRecord:
        path, problem = self.path, self.p
        before = path.snapshot() if self.branch == "switch" else None
        path.commit()
        path.tangent(orient=True)
        rec = _step_record(
            problem, self.psi, len(self.res.steps) + 1, outcome.iterations, outcome.history, self.r, "arc-length"
        )
        new = self.track.update(path, rec, self.r)
        if before is not None:
            switch = _Switch(problem, path, self.psi, self.ctl.cut, self.res, self.branch_sign)
            rec = switch.at_bifurcation(new, before, self.track, h, self.ds_min) or rec
        rec.instabilities = new
        self.reached = max(self.reached, rec.u0)
        return rec

    def reject(self, u0: float, outcome: Outcome) -> None:
        self.path.restore()

    def diagnose(self, attempts: Sequence[Attempt]) -> tuple[str, object | None]:
        return "", None  # the caller diagnoses an unreached target


def _step_record(
    problem: Problem, psi: np.ndarray, number: int, its: int, hist: list[float], r: np.ndarray | None, reason: str
) -> StepRecord:
    """The record of the converged point the problem is at (its tangent factorized)."""
    rec = StepRecord(number, problem.state.lam, its, residual=r, history=hist, reason=reason)
    rec.dforce_du0 = problem.load_derivative(psi, problem.load_tangent(1.0))
    return rec


class _Switch:
    """Branch switching at a bifurcation (module docstring): from the located point along the critical mode."""

    def __init__(
        self, problem: Problem, path: _Path, psi: np.ndarray, cut: float, res: PathResult, sign: float
    ) -> None:
        self.p, self.path, self.psi, self.cut, self.res = problem, path, psi, cut, res
        self.sign = 1.0 if sign >= 0 else -1.0

    def direction(self, mode: np.ndarray) -> tuple[np.ndarray, float]:
        """(φ_c, 0), oriented by its largest weighted entry and the sign, orthogonal to τ, unit."""
        path = self.path
        phi = np.where(path.w > 0, mode, 0.0)
        k = int(np.argmax(np.abs(path.w * phi)))
        phi = phi * (self.sign if phi[k] >= 0 else -self.sign)
        c = path.inner(phi, 0.0, path.tau_x, path.tau_l)
        nx, nl = phi - c * path.tau_x, -c * path.tau_l
        norm = math.sqrt(path.inner(nx, nl, nx, nl))
        return nx / norm, nl / norm

    def at_bifurcation(
        self,
        new: list[Instability],
        before: tuple[np.ndarray, float, np.ndarray, float],
        track: _Tracker,
        ds: float,
        ds_min: float,
    ) -> StepRecord | None:
        """Switch at the bifurcation among ``new`` (if any): the record of the first point on the new branch.

        ``before`` is the point before the step; the path stands at the point after it. Without a
        converged step on the bifurcated branch (down to ``ds_min``) the path stays where it is
        and None is returned.
        """
        bif = next((i for i in new if i.kind == "bifurcation" and i.mode is not None), None)
        if bif is None or bif.mode is None:
            return None
        path, after = self.path, self.path.snapshot()
        x_c = before[0] + bif.at * (after[0] - before[0])
        lam_c = before[1] + bif.at * (after[1] - before[1])
        path.tau_x, path.tau_l = self.direction(bif.mode)
        path.x0, path.lam0 = x_c, lam_c
        while ds >= ds_min:
            ok, its, hist, why, r = path.step(ds)
            lam_to = self.p.state.lam
            self.res.attempts.append(Attempt(lam_c, lam_to, ok, its, why, hist))
            if ok:
                path.commit()
                path.tangent(orient=True)
                rec = _step_record(
                    self.p, self.psi, len(self.res.steps) + 1, its, hist, r, "arc-length, bifurcated branch"
                )
                track.restart(path, rec, r)
                bif.details.update(branch="switched", mode_sign=self.sign)
                log.warning("switched to the bifurcated branch at u0 = %.4g mm", bif.u0_mm)
                return rec
            self.res.cuts += 1
            ds *= self.cut
        path.reset(after)
        bif.details["branch"] = "stayed: no equilibrium found on the bifurcated branch"
        log.warning("no equilibrium found on the bifurcated branch at u0 = %.4g mm; staying", bif.u0_mm)
        return None


def _next_mark(ctl: ArcLengthSettings, reached: float) -> float:
    """The load the next step lands on if it would pass it: the first stop above ``reached``, else the target."""
    tol = 1e-9 * ctl.target
    return min([s for s in ctl.stops if reached + tol < s < ctl.target] + [ctl.target])


def _distance_to(path: _Path, target: float, ds: float) -> float:
    """The arc length that lands the predictor on u0 = target when it would pass it (else ds)."""
    if path.tau_l > 0 and path.lam0 + ds * path.tau_l > target:
        return (target - path.lam0) / path.tau_l
    return math.inf


class _Tracker:
    """Watches the sign of τ_λ, of dF/du0 and of the lowest eigenvalue along the path.

    A snap-back and a force maximum are reported at the last point before the sign change (the
    largest u0, resp. force, of the two), with the lowest eigenvalue and mode there: at a fold
    it is the mode whose eigenvalue vanishes. A bifurcation is reported where the eigenvalue
    interpolated between the two points vanishes (:func:`_bifurcation`).
    """

    def __init__(self, psi: np.ndarray, eig: Callable[[], tuple[float, np.ndarray]] | None) -> None:
        self.psi, self.eig = psi, eig
        self.lam_start = 0.0
        self.tau_l = 1.0
        self.dR = math.nan
        self.prev = Instability("", 0.0, math.nan)  # the last point: load, reaction, eigenvalue, mode

    def start(self, problem: Problem, path: _Path) -> None:
        self.lam_start = path.lam0
        self.tau_l = path.tau_l
        self.prev = Instability("", path.lam0 * 1e3, float(self.psi @ problem.residual()))
        if self.eig is not None:  # it refactorizes at this same point: the tangent stands
            self.prev.lowest_eigenvalue, self.prev.mode = self.eig()

    def point(self, rec: StepRecord, r: np.ndarray | None) -> Instability:
        """The record of the converged point the path stands at (its eigenpair when watched)."""
        here = Instability("", rec.u0 * 1e3, float(self.psi @ r) if r is not None else math.nan)
        if self.eig is not None:  # it refactorizes at this same point: the tangent stands
            here.lowest_eigenvalue, here.mode = self.eig()
        return here

    def update(self, path: _Path, rec: StepRecord, r: np.ndarray | None) -> list[Instability]:
        here = self.point(rec, r)
        prev, out = self.prev, []
        if self.tau_l > 0 >= path.tau_l:
            out.append(dataclasses.replace(prev, kind="snap-back", details={"note": "the path turns back in u0"}))
        elif path.tau_l > 0 and rec.dforce_du0 < 0 <= self.dR:
            out.append(dataclasses.replace(prev, kind="force maximum"))
        elif prev.lowest_eigenvalue > 0 >= here.lowest_eigenvalue and path.tau_l > 0:
            out.append(_bifurcation(prev, here))
        for ins in out:
            log.warning("%s at u0 = %.4g mm", ins.kind, ins.u0_mm)
        self.tau_l, self.dR, self.prev = path.tau_l, rec.dforce_du0, here
        return out

    def restart(self, path: _Path, rec: StepRecord, r: np.ndarray | None) -> None:
        """Watch from the point the path stands at, compared with nothing before it (a new branch)."""
        self.tau_l, self.dR, self.prev = path.tau_l, rec.dforce_du0, self.point(rec, r)


def _bifurcation(prev: Instability, here: Instability) -> Instability:
    """The bifurcation between two points: where the linear interpolant of the lowest eigenvalue vanishes.

    Load and force are interpolated there; the mode is that of the point nearer to it.
    """
    mu_a, mu_b = prev.lowest_eigenvalue, here.lowest_eigenvalue
    t = mu_a / (mu_a - mu_b)
    near = prev if t < 0.5 else here
    return Instability(
        "bifurcation",
        prev.u0_mm + t * (here.u0_mm - prev.u0_mm),
        prev.reaction + t * (here.reaction - prev.reaction),
        near.lowest_eigenvalue,
        {"bracket_mm": [prev.u0_mm, here.u0_mm], "eigenvalues": [mu_a, mu_b], "branch": "stayed"},
        near.mode,
        t,
    )
