r"""One parameter set fitted to several measured curves (specimen sizes) of one fabric, and its predictions.

Each curve runs on its own specimen (the keys of its data file's header applied to the scene)
with load steps landing on its fitted displacements (:mod:`ngbet.measured.curves`); the force and
its derivatives with respect to the parameters come from the same run
(:func:`ngbet.runner.sensitivity.force_path`). Each curve's mesh is made once and reused by
every model run of the fit.

Least squares on the residuals e_i = (F_model(u_i) − F_i)/s_i, s_i the point's standard deviation
(:meth:`MeasuredCurve.sd`: half the printed error bar where the file has error bars, floored by
the reading error and 1 % of the force), in θ = ln p within the bounds of the scene's
``[calibration]`` table (:func:`scipy.optimize.least_squares`, trust region reflective). Where
the curves hold two or more specimens of a test that the model cannot fit within their noise,
s_i also holds the model error between specimens that the search's end shows, σ_m F_i, and the
search runs again under it (:func:`~ngbet.calibration.bands.weigh_model_error`; again on the
checked rungs before their search): each specimen counts by what the model can do for it, not by
the width of its error bars. The
covariance of θ is s²(JᵀJ)⁻¹ with s² = Σe²/(m − n): error bars that do not cover the misfit are
scaled up by it (never down: s² >= 1). A measured mid-axis profile and centre shear angles of the
first curve's specimen (:mod:`ngbet.measured.observations`) add their residuals over their
standard deviations.

Every model run is within a stated discretization error: the fit chooses each curve's mesh and
order from :data:`~ngbet.calibration.fit_params.FIT_LADDER` (graded towards the clamp
corners), coarse to fine, by the estimated force error at the fitted points
(:mod:`ngbet.continuum.estimate`); fit.json records the largest estimate per curve. A single
curve (one specimen size) fitted with the scene's own parameters holds the bending stiffnesses,
which one size cannot determine (:func:`held_parameters`).

Predictions of other specimens with their band: :mod:`ngbet.calibration.bands`.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..measured.curves import RANGE, MeasuredCurve
from ..measured.observations import Profile, ShearAngles
from ..scene.document import Scene
from ..scene.validate import SceneError
from .bands import weigh_model_error
from .fit_params import (
    COARSE_LEVEL,
    FINE_TOL,
    FIRST_CHECKED,
    FIT_LADDER,
    SIZE_PARAMS,
    STALL_RUNS,
    STEP_SE,
    TARGET_ERROR,
    CurveFit,
    JointFit,
    bounds,
    curve_scene,
    expand_params,
    gauss_newton_direction,
    portable_scene,
    rises_at_zero,
    smoothness_rows,
    value_of,
    with_values,
)
from .record import FitState
from .runs import CurveModel, Run, RunsSpent, default_workers, first_levels, probe_points, relative_error
from .statistics import fit_statistics

__all__ = [
    "ELONGATION_KEY",
    "Progress",
    "fit_curves",
    "held_parameters",
    "terminal_progress",
]

log = logging.getLogger(__name__)

#: searches again under the model error between specimens that a search's end shows, at most
REWEIGHTS = 2


Progress = Callable[[int, list[float], float], None]


def terminal_progress(stream: Any = None) -> Progress:
    """A progress line on the terminal: model runs, each curve's RMS, elapsed time."""
    stream = stream or sys.stderr
    tty = hasattr(stream, "isatty") and stream.isatty()
    t0 = time.perf_counter()

    def show(runs: int, rms: list[float], best: float) -> None:
        text = (
            f"ngbet fit: model run {runs}, RMS "
            + ", ".join(f"{100 * r:.1f} %" for r in rms)
            + f" (best cost {best:.4g}), {time.perf_counter() - t0:.0f} s"
        )
        stream.write(("\r" + text + "\x1b[K") if tty else text + "\n")
        stream.flush()

    return show


def held_parameters(
    curves: Sequence[MeasuredCurve], scene: Scene, params: Sequence[str], profile: Profile | None
) -> dict[str, str]:
    """The scene's parameters the curves cannot determine, with why: {key: reason}.

    Without a mid-axis profile, the bending stiffnesses (:data:`SIZE_PARAMS`) where every curve is
    of one specimen (they set the size effect, which one size does not show) or every curve is a
    picture frame (the fabric shears homogeneously there, whatever the frame's size).
    """
    sizes = {
        (
            c.specimen.get("specimen.width_mm", scene.specimen.width_mm),
            c.specimen.get("specimen.length_mm", scene.specimen.length_mm),
        )
        if c.test != "picture_frame"
        else "frame"
        for c in curves
    }
    if profile is not None or (len(sizes) > 1 and sizes != {"frame"}):
        return {}
    why = (
        "picture-frame tests alone: the fabric shears homogeneously in the frame, which leaves the bending "
        "stiffnesses without a part in its force"
        if sizes == {"frame"}
        else "one specimen size: the bending stiffnesses set the size effect, which one size does not show "
        "(measured: they end at their bounds with se(ln p) of 1e3 and more)"
    )
    how = (
        "; held at the scene's value. Bias-extension curves of two specimen sizes (e.g. 100 x 200 mm beside "
        "100 x 300 mm) or a measured mid-axis profile (--profile) determine them"
    )
    return {p: why + how for p in params if p in SIZE_PARAMS}


def fit_curves(  # noqa: C901
    curves: Sequence[MeasuredCurve],
    scene: Scene,
    params: Sequence[str] | None = None,
    max_runs: int = 40,
    progress: Progress | None = None,
    fractions: Sequence[tuple[float, float]] | None = None,
    *,
    target_error: float = TARGET_ERROR,
    profile: Profile | None = None,
    profile_sd_mm: float = 1.0,
    angles: ShearAngles | None = None,
    angle_sd_deg: float = 1.0,
    resample: bool = True,
    coarse: bool = True,
    choose_discretization: bool = True,
    workers: int | None = None,
    state: FitState | None = None,
) -> JointFit:
    """Fit ``params`` (default: the scene's ``calibration.params``) to all ``curves`` at once.

    ``fractions``: the part of each curve's displacement range fitted (default 10–90 %).
    ``resample``: the curve sampled at :data:`ngbet.measured.curves.POINTS_PER_CURVE` equally
    spaced displacements (False: its own points in the range).

    Discretization: every curve runs on a rung of :data:`FIT_LADDER` chosen by the fit. Each
    curve's first rung meeting the target at the start values is probed, the search starts one
    rung below it (``coarse``, not below :data:`COARSE_LEVEL`), and where it ends the rungs are
    probed again from the start's up. On these checked rungs the discretization error of the force
    is estimated (:class:`ngbet.continuum.estimate.ForceErrorEstimator`) before each search at
    :data:`~ngbet.calibration.runs.PROBE_POINTS` of the fitted points, and after it, where the
    fit ends, at every one; a curve whose largest estimate is above ``target_error`` of its force
    (or cannot be vouched for) moves one rung up and the search continues from where it stood,
    until every curve meets the target or the runs are spent. The search on the checked rungs
    is by Gauss-Newton steps (one model run each, halved until the cost falls); it runs only where
    the step would move the parameters by :data:`STEP_SE` standard errors or more, and ends where
    a step lowered the cost by less than STEP_SE² s² or :data:`STALL_RUNS` shortened steps did not
    lower it.
    The result records each curve's rung and largest estimate (``accuracy_met`` says whether the
    target was met).

    ``max_runs``: the model runs at most (a model run: every curve run once at one parameter set;
    a run the cache serves is not one). The last is kept for the check where the fit ends (the
    estimate at every fitted point): the probes, the searches and the climb share the others, and
    a fit whose runs are spent ends where it stands, not converged.

    ``choose_discretization=False``: every run on the scene's own discretization, its estimate
    recorded all the same.

    ``profile`` (mid-axis u_y) and ``angles`` (centre shear angle) are observations of the first
    curve's specimen, fitted with its force with the standard deviations ``profile_sd_mm`` and
    ``angle_sd_deg``.

    With ``params`` None and every curve of one specimen size (and no profile), the bending
    stiffnesses are held at the scene's values (:func:`held_parameters`; the result's ``held``).

    ``workers``: processes running the curves at the same time, one curve each (default: one per
    curve up to the cores, none inside a daemonic process); 1 runs every curve in this process.
    The results are those of one process to round-off. A script that starts a fit of several
    curves guards its top level (``if __name__ == "__main__":``): the workers are spawned and
    import it.

    ``state``: kept up to date as the fit goes (:class:`~ngbet.calibration.record.FitState`: its
    model runs, the lowest cost so far and its values), for a caller that must say what a fit
    ended by Ctrl-C or an error had done.
    """
    from scipy.optimize import OptimizeResult, least_squares, lsq_linear

    t0 = time.perf_counter()
    if scene.model != "continuum":
        raise SceneError(f"model = {scene.model!r}: ngbet fit calibrates the continuum model")
    if not curves:
        raise SceneError("no measured curve to fit")
    own = not params
    params = list(params) if params else list(scene.calibration.params)
    if not params:
        raise SceneError("no parameters to fit: give --params, or name them in the scene's [calibration] params")
    if not isinstance(max_runs, int) or max_runs < 1:
        raise SceneError(f"--max-runs = {max_runs!r}: must be an integer >= 1")
    if not (0 < target_error < 1):
        raise SceneError(
            f"--accuracy = {target_error!r}: the largest discretization error of the force relative "
            "to it, between 0 and 1 (e.g. 0.01)"
        )
    if not (profile_sd_mm > 0 and angle_sd_deg > 0):
        raise SceneError(f"--profile-sd = {profile_sd_mm}, --angle-sd = {angle_sd_deg}: both must be > 0")
    held = held_parameters(curves, scene, params, profile) if own else {}
    if own and ELONGATION_KEY not in params and scene.effects.elongation:
        held[ELONGATION_KEY] = (
            "not among the scene's [calibration] params: held at the scene's value (the fabric "
            "scenes: glass yarns after decrimping). Measured shear angles (--angles) would "
            "determine it; name it in --params to fit it"
        )
    fitted_params = [p for p in params if p not in held]
    names = expand_params(scene, fitted_params)
    start = np.array([value_of(scene, n) for n in names])
    bad = [n for n, v in zip(names, start, strict=True) if not v > 0]
    if bad:
        what = "parameters" if len(bad) > 1 else "parameter"
        raise SceneError(f"{what} {', '.join(bad)}: the fit works on ln p and needs positive start values")
    lo, hi = bounds(scene, fitted_params, names, start)
    start = np.clip(start, lo * (1 + 1e-9), hi * (1 - 1e-9))
    state = state if state is not None else FitState()
    state.names, state.start, state.t0 = list(names), start.tolist(), t0
    cfs = []
    for k, c in enumerate(curves):
        frac = fractions[k] if fractions is not None else RANGE
        if resample:
            u, F = c.sample(fraction=frac)
        else:
            a, b = c.window(frac)
            inside = (c.u_mm >= a) & (c.u_mm <= b) & (c.u_mm > 0)
            u, F = c.u_mm[inside], c.force_N[inside]
        sc = curve_scene(scene, c, u)
        prof = ang = None
        if k == 0 and profile is not None:
            prof = profile.inside(sc.specimen.length_mm)
            if len(prof.X_mm) == 0:
                raise SceneError(f"profile {profile.source}: no point strictly between the clamps (0 < X < L)")
        if k == 0 and angles is not None:
            ang = angles
            reach = max(float(np.max(ang.u_mm)), float(u.max()))
            sc = sc.with_changes(**{"loading.u0_mm": reach})
        cfs.append(CurveFit(c, sc, u, F, c.sd(u, F), prof, ang, FIRST_CHECKED if choose_discretization else None))
    prior = smoothness_rows(names, scene.calibration.table_smoothness_sd)
    state.labels = [cf.label for cf in cfs]
    model = CurveModel(cfs, names, workers if workers is not None else default_workers(len(cfs)))
    budget = model.limit = max_runs - 1  # the last run: the check where the fit ends
    try:
        here: list[Any] = [math.inf, None]  # the lowest cost of the current search and its θ
        quiet = [False]

        def blocks(res: list[Run], own: bool = False) -> np.ndarray:
            """The data's residuals over the weights' standard deviations (``own``: the points' own)."""
            e = []
            for r, c in zip(res, cfs, strict=True):
                e.append((r.F - c.measured_N) / (c.sd_N if own else c.weight_sd_N))
                if c.profile is not None:
                    e.append((r.P - c.profile.measured()) / profile_sd_mm)
                if c.angles is not None:
                    e.append((r.A - c.angles.angle_deg) / angle_sd_deg)
            return np.concatenate(e)

        def resid(theta: np.ndarray) -> np.ndarray:
            res = model(theta)
            e = blocks(res)
            e = np.concatenate([np.where(np.isfinite(e), e, 1e3), prior @ theta])
            cost = float(e @ e)
            rms = [
                float(np.sqrt(np.mean(((r.F - c.measured_N) / c.measured_N) ** 2)))
                for r, c in zip(res, cfs, strict=True)
            ]
            state.seen(model.runs, theta, cost, rms)
            if cost < here[0]:
                here[:] = [cost, np.array(theta)]
            if progress is not None and not quiet[0]:
                progress(model.runs, rms, state.cost)
            return e

        def jac(theta: np.ndarray) -> np.ndarray:
            rows = []
            for r, c in zip(model(theta), cfs, strict=True):
                rows.append(r.G / c.weight_sd_N[:, None])
                if c.profile is not None:
                    rows.append(r.GP / profile_sd_mm)
                if c.angles is not None:
                    rows.append(r.GA / angle_sd_deg)
            return np.vstack([*rows, prior])

        def search(theta: np.ndarray, runs: int, tol: float) -> Any:
            """The least-squares search from θ (at most ``runs`` model runs, tolerance ``tol``).

            Where the model's runs are spent (:class:`~ngbet.calibration.runs.RunsSpent`) it ends at
            the lowest cost it evaluated.
            """
            here[:] = [math.inf, theta]
            try:
                return search_from(theta, runs, tol)
            except RunsSpent:
                return OptimizeResult(x=here[1], success=False, status=0, message="the model runs were spent")

        def search_from(theta: np.ndarray, runs: int, tol: float) -> Any:
            return least_squares(
                resid,
                theta,
                jac=jac,
                bounds=(np.log(lo), np.log(hi)),
                method="trf",
                x_scale=1.0,
                max_nfev=max(runs, 1),
                xtol=tol,
                ftol=tol,
                gtol=1e-8,
            )

        def weighted_search(theta: np.ndarray, runs: int, tol: float) -> Any:
            """:func:`search`, then again under the model error between specimens that its end shows.

            At most :data:`REWEIGHTS` times, while the model error moves
            (:func:`~ngbet.calibration.bands.weigh_model_error`), and not where the runs are spent.
            """
            sol = search(theta, runs, tol)
            for _ in range(REWEIGHTS):
                try:
                    forces = [r.F for r in model(sol.x)]  # (run already, unless the runs were spent before any)
                except RunsSpent:
                    break
                if not weigh_model_error(cfs, forces, len(names)):
                    break
                sol = search(sol.x, runs, tol)
            return sol

        def gauss_newton_step(theta: np.ndarray) -> float:
            """The Gauss-Newton step from θ within the bounds, in standard errors (the Mahalanobis norm).

            The cost it would remove, over the covariance's s²: a step that moves the parameters by
            a small fraction of their uncertainty is not worth a search (its runs are the costly ones).
            """
            return step_from(theta, resid(theta), jac(theta))

        def step_from(theta: np.ndarray, e: np.ndarray, J: np.ndarray) -> float:
            """:func:`gauss_newton_step` from the residuals ``e`` and Jacobian ``J`` at θ."""
            if not np.all(np.isfinite(J)):
                return math.inf
            m, n = J.shape
            d = lsq_linear(J, -e, bounds=(np.log(lo) - theta, np.log(hi) - theta)).x
            drop = float(e @ e) - float(np.sum((J @ d + e) ** 2))
            return math.sqrt(max(drop, 0.0) / max(float(e @ e) / max(m - n, 1), 1.0))

        def gauss_newton(theta: np.ndarray, runs: int) -> Any:
            """Gauss-Newton steps from θ on the checked rungs while they lower the cost by what matters.

            Each step is :func:`~ngbet.calibration.fit_params.gauss_newton_direction`, halved
            until the cost falls. Each model run gives the residuals and
            the Jacobian at once, so a step costs one run. The steps end where the step would move
            the parameters by less than :data:`STEP_SE` standard errors, or where it lowered the
            cost by less than STEP_SE² s², there; :data:`STALL_RUNS` runs without a fall (the step
            halved each time) end them where they stand.
            """
            lo_t, hi_t = np.log(lo), np.log(hi)
            e = resid(theta)
            for _ in range(max(runs, 1)):
                J = jac(theta)
                step = step_from(theta, e, J)
                cost = float(e @ e)
                s2 = max(cost / max(len(e) - len(theta), 1), 1.0)
                log.info("Gauss-Newton on the checked rungs: cost %.6g, step %.3g standard errors", cost, step)
                if step <= STEP_SE:
                    return OptimizeResult(
                        x=theta,
                        success=True,
                        status=1,
                        message=f"the Gauss-Newton step within the bounds moves the parameters by {step:.2g} "
                        f"standard errors (< {STEP_SE}) on the checked rungs",
                    )
                d, t = gauss_newton_direction(J, e, theta, lo_t, hi_t)
                for _half in range(STALL_RUNS):
                    if model.runs >= budget:
                        return OptimizeResult(
                            x=theta,
                            success=False,
                            status=0,
                            message="the model runs were spent in the Gauss-Newton steps",
                        )
                    trial = np.clip(theta + t * d, lo_t, hi_t)
                    e_new = resid(trial)
                    if float(e_new @ e_new) < cost:
                        theta, e = trial, e_new
                        break
                    t /= 2
                else:
                    return OptimizeResult(
                        x=theta,
                        success=True,
                        status=2,
                        message=f"{STALL_RUNS} shortened Gauss-Newton steps did not lower the cost on the checked "
                        f"rungs (the step {step:.2g} standard errors)",
                    )
                if cost - float(e @ e) < STEP_SE**2 * s2:
                    return OptimizeResult(
                        x=theta,
                        success=True,
                        status=2,
                        message=f"a Gauss-Newton step lowered the cost by less than {STEP_SE}² s² on the checked "
                        f"rungs (parameters moving by less than {STEP_SE} standard errors)",
                    )
            return OptimizeResult(
                x=theta, success=False, status=0, message="the model runs were spent in the Gauss-Newton steps"
            )

        th0 = np.log(start)
        th = th0
        stages: list[dict[str, Any]] = []

        def stage(r0: int, ts: float, marks: list[int], **record: Any) -> None:
            """Record a stage: its model runs, wall time, and each curve's run wall and CPU time in it."""
            record["model_runs"] = model.runs - r0
            record["wall_s"] = time.perf_counter() - ts
            record["curve_run_s"] = [sum(x[2] for x in t[m:]) for t, m in zip(model.timings, marks, strict=True)]
            record["curve_cpu_s"] = [sum(x[3] for x in t[m:]) for t, m in zip(model.timings, marks, strict=True)]
            stages.append(record)

        def mark() -> tuple[int, float, list[int]]:
            return model.runs, time.perf_counter(), [len(t) for t in model.timings]

        sol = None
        checked_levels = [cf.level for cf in cfs]
        if choose_discretization:
            m0 = mark()
            checked_levels = first_levels(model, cfs, th0, target_error)
            stage(*m0, rungs=checked_levels, checked=True, probe=True)
        probe_levels = list(checked_levels)
        if coarse and choose_discretization and max_runs > 2:
            # the search gets near the optimum one rung below the first that met the target at the start
            coarse_levels = [max(COARSE_LEVEL, (lv or 0) - 1) for lv in checked_levels]
            for cf, lv in zip(cfs, coarse_levels, strict=True):
                cf.level = lv
            m0 = mark()
            model.limit = min(budget, model.runs + max_runs // 2)
            sol = weighted_search(th, max_runs // 2, 1e-3)
            model.limit = budget
            th = sol.x
            stage(*m0, rungs=coarse_levels, checked=False)
            # the parameters have moved: the rungs are chosen again where the coarse search ended, from
            # the start's up (fitted parameters may need finer rungs than the start values: a search
            # on a rung the target then rejects would be spent)
            m0 = mark()
            checked_levels = first_levels(model, cfs, th, target_error, probe_levels)
            stage(*m0, rungs=checked_levels, checked=True, probe=True)
        for cf, level in zip(cfs, checked_levels, strict=True):
            cf.level = level
        # on the checked rungs: the estimate where the search stands (a probe before a search, every
        # fitted point after it and where the fit ends); a rung that misses the target is left at once
        # (one rung up), a search runs only where its step would move a parameter
        searched = not choose_discretization  # the scene's own discretization: no probe, search first
        if searched:
            m0 = mark()
            sol = weighted_search(th, budget - model.runs, FINE_TOL)
            th = sol.x
        else:
            m0 = mark()
        while True:
            full = searched or model.runs >= budget  # the last run left: the check where the fit ends
            model.limit = max_runs if full else budget
            checked = model(th, check=True, probe=not full)
            model.limit = budget
            rel = [
                relative_error(r, None if full else probe_points(len(cf.u_mm)))
                for cf, r in zip(cfs, checked, strict=True)
            ]
            for cf, r in zip(cfs, checked, strict=True):
                cf.force_error_N = r.err
                cf.model_N = r.F
            step = gauss_newton_step(th)
            stage(
                *m0,
                rungs=[cf.level for cf in cfs],
                checked=True,
                probe=not full,
                force_error_rel_max=[x if math.isfinite(x) else None for x in rel],
                step_se=step,
            )
            m0 = mark()
            if model.runs >= max_runs and full:
                break
            moved = False  # a rung changed: the curves are checked again there (a search first where none ran)
            for cf, x in zip(cfs, rel, strict=True):
                if x <= target_error or cf.level is None or cf.climb.ended or cf.level >= len(FIT_LADDER) - 1:
                    continue
                if model.runs >= max_runs:
                    break
                if cf.climb.record(cf.level, x):
                    log.warning("%s: %s, where the accuracy target is not met", cf.label, cf.climb.why(cf.level, x))
                    moved = moved or cf.climb.choice() != cf.level
                    cf.level = cf.climb.choice()
                    continue
                log.info("%s: estimated discretization error %.3g above %.3g: one rung up", cf.label, x, target_error)
                cf.level += 1
                moved = True
            if moved:
                searched = False
                continue
            if full:
                break
            if weigh_model_error(cfs, [r.F for r in checked], len(names)):  # as the checked rungs show it
                step = gauss_newton_step(th)
            if step <= STEP_SE or model.runs >= budget:
                # the probe's θ is where the fit ends: its estimate at every fitted point next
                sol = OptimizeResult(
                    x=th,
                    success=step <= STEP_SE,
                    status=1 if step <= STEP_SE else 0,
                    message=f"the Gauss-Newton step within the bounds moves the parameters by {step:.2g} "
                    f"standard errors (< {STEP_SE}) on the checked rungs"
                    if step <= STEP_SE
                    else "the model runs were spent before a search on the checked rungs",
                )
            else:
                sol = gauss_newton(th, budget - model.runs)
                th = sol.x
            searched = True
        if sol is None:  # --max-runs spent by the probe
            sol = OptimizeResult(x=th, success=False, status=0, message="the model runs were spent before a search")
        quiet[0] = True
        e, J = resid(th), jac(th)
        st = fit_statistics(e, J, names, len(prior), blocks(checked, own=True))
        for cf, r in zip(cfs, checked, strict=True):
            cf.model_N, cf.dlogp, cf.force_error_N, cf.angle_deg = r.F, r.G, r.err, r.angle
            cf.profile_mm, cf.angles_model_deg = r.P, r.A
        levels = [cf.level for cf in cfs]
        for k, cf in enumerate(cfs):  # the start values: the probe's run, which met the target there
            made = model.at(k, th0, probe_levels[k])  # (another rung's where none; never a run beyond max_runs)
            cf.start_N = made.F if made is not None else np.full(len(cf.u_mm), np.nan)
        values = np.exp(th)
        at_bound = [
            nm for nm, t, a, b in zip(names, th, np.log(lo), np.log(hi), strict=True) if t - a < 1e-3 or b - t < 1e-3
        ]
        chosen = [lv for lv in levels if lv is not None]
        # on the first curve's test and specimen (or frame): the fitted scene runs what was fitted
        on = FIT_LADDER[max(chosen)].apply(cfs[0].scene) if chosen else cfs[0].scene
        fitted = portable_scene(with_values(on, names, values))
        zero = rises_at_zero(names, values, st["cov_data"], fitted.material.shear_stress_steps_Pa, st["undetermined"])
        ok = bool(sol.success and sol.status > 0)
        if not ok:
            # the caller says it (the command with its option, a study in its table): no advice from here
            log.info(
                "the least-squares search stopped without converging after %d model runs (%s)", model.runs, sol.message
            )
        return JointFit(
            fitted_params,
            names,
            values,
            np.exp(th0),
            lo,
            hi,
            st["cov"],
            cfs,
            fitted,
            st["noise_scale"],
            model.runs,
            time.perf_counter() - t0,
            ok,
            str(sol.message),
            at_bound,
            held,
            {p: why for p, why in st["undetermined"].items() if p not in zero},
            st["correlated"],
            [d for d in st["flat"] if not set(d) <= set(zero)],
            st["residual_scale"],
            target_error,
            stages,
            profile_sd_mm,
            angle_sd_deg,
            scene.calibration.table_smoothness_sd,
            zero,
        )

    finally:
        state.runs = model.runs  # the probes' runs too (the residuals count the others)
        model.close()


#: the yarn elongation modulus: held at the scene's value when the scene's [calibration] does not name it
ELONGATION_KEY = "material.K_el"
