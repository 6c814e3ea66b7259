"""The discrete model's Newton solver on small energies with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ngbet import cholmod
from ngbet.discrete.linsolve import FreeBlockSolver, LinearSolverError, resolve_backend
from ngbet.discrete.newton import StepControl, StepFailed, newton
from ngbet.discrete.solver import load_steps
from ngbet.numerics.engine import PathControl, PathResult, Steps


class DoubleWell:
    """E(x, y) = x^4/4 - x^2/2 + y^2/2: minima at (+-1, 0), a saddle at the origin."""

    n_dofs = 2
    fixed = np.zeros(2, bool)
    load = np.zeros(2)
    ramp = np.zeros(2)

    def evaluate(self, u, hessian=True):
        x, y = u
        E = x**4 / 4 - x**2 / 2 + y**2 / 2
        g = np.array([x**3 - x, y])
        K = sp.csr_matrix(np.array([[3 * x**2 - 1, 0.0], [0.0, 1.0]])) if hessian else None
        return E, g, K


class Convex:
    """E(u) = sum(cosh(u_i - a_i)) + 1/2 sum (u_i - u_{i+1})^2: one minimum, Newton converges quadratically."""

    def __init__(self, n: int = 6) -> None:
        self.n_dofs = n
        self.fixed = np.zeros(n, bool)
        self.load = np.zeros(n)
        self.ramp = np.zeros(n)
        self.a = np.linspace(0.5, 2.0, n)
        D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, 1], shape=(n - 1, n))
        self.L = (D.T @ D).tocsr()

    def evaluate(self, u, hessian=True):
        E = float(np.sum(np.cosh(u - self.a)) + 0.5 * u @ (self.L @ u))
        g = np.sinh(u - self.a) + self.L @ u
        K = (sp.diags(np.cosh(u - self.a)) + self.L).tocsr() if hessian else None
        return E, g, K


class Pulled:
    """A nonlinear spring chain pulled by a clamp: E = k/2 (c - x)^2 + m/2 x^2 + b/4 x^4, x free,
    c prescribed (= u0). One smooth branch x(u0): no snap, F = dE/du0 = k (c - x)."""

    n_dofs = 2
    fixed = np.array([False, True])
    load = np.array([0.0, 1.0])
    ramp = np.array([0.5, 1.0])
    k, m, b = 1.0, 0.5, 0.3

    def evaluate(self, u, hessian=True):
        x, c = u
        E = 0.5 * self.k * (c - x) ** 2 + 0.5 * self.m * x**2 + 0.25 * self.b * x**4
        g = np.array([-self.k * (c - x) + self.m * x + self.b * x**3, self.k * (c - x)])
        K = (
            sp.csr_matrix(np.array([[self.k + self.m + 3 * self.b * x**2, -self.k], [-self.k, self.k]]))
            if hessian
            else None
        )
        return E, g, K


def ctl(**kw) -> StepControl:
    return StepControl(path=PathControl(target=1.0, first_step=1.0, max_step=1.0, min_step=1e-3), **kw)


def solver(problem):
    return FreeBlockSolver(problem.evaluate(np.zeros(problem.n_dofs))[2], ~problem.fixed)


def test_relaxation_leaves_a_saddle_in_few_factorizations():
    # From x = 1e-3 next to the saddle the tangent 3x^2 - 1 < 0 gives no descent, and the shift
    # that makes it descend (mu = 10 of the ladder 1e-6, 1e-5, ..., mu |K_xx|; mu = 1 makes it
    # singular, which the ladder steps over: K + mu = 9) grows x only by the factor 1 + 1/9 per
    # Newton iteration: ~65 iterations to reach |x| = 1. Extended along the shifted direction while
    # the energy falls (energy evaluations only) and starting the next shift at a tenth of the
    # last, the relaxation reaches the minimum x = 1 in 6 iterations (16 factorizations, 9 of them
    # the first ladder).
    p = DoubleWell()
    lin = solver(p)
    u, its, hist, shifted = newton(
        p, np.array([1e-3, 0.0]), lin, ctl(), max_iterations=48, line_search=True, fail_fast=False
    )
    assert abs(u[0] - 1.0) < 1e-8 and abs(u[1]) < 1e-8, f"relaxed to {u}"
    assert its <= 12 and lin.n_factor <= 30, f"{its} iterations, {lin.n_factor} factorizations"


def test_no_shift_allowed_stops_at_the_first_indefinite_tangent():
    # a step that will be cut anyway (longer than the snap bracket) gives up at once
    p = DoubleWell()
    lin = solver(p)
    with pytest.raises(StepFailed) as exc:
        newton(p, np.array([1e-3, 0.0]), lin, ctl(), allow_shift=False)
    assert exc.value.indefinite and lin.n_factor == 1, (
        f"indefinite {exc.value.indefinite}, {lin.n_factor} factorizations"
    )


def test_solve_many_equals_column_solves():
    # one pass over the factor for several right-hand sides (the stability check's block) gives
    # the columns' own solutions, and they solve the system
    p = Convex(40)
    K = p.evaluate(np.linspace(-1, 1, p.n_dofs))[2]
    lin = solver(p)
    lin.factor(K)
    B = np.random.default_rng(0).standard_normal((p.n_dofs, 3))
    X = lin.solve_many(B)
    cols = np.column_stack([lin.solve(B[:, j]) for j in range(3)])
    assert np.abs(X - cols).max() <= 1e-12 * np.abs(cols).max(), f"{np.abs(X - cols).max():.2e}"
    assert np.abs(K @ X - B).max() <= 1e-10 * np.abs(B).max(), f"residual {np.abs(K @ X - B).max():.2e}"


def test_cholmod_hands_an_indefinite_tangent_to_the_ldlt():
    # CHOLMOD's LL^T stops at a non-positive pivot; such a tangent is factorized by NGSolve's
    # LDL^T, and the next positive definite one by the LL^T again. Each solve is checked against
    # a dense solve.
    p = Convex(40)
    K = p.evaluate(np.linspace(-1, 1, p.n_dofs))[2]
    lin = FreeBlockSolver(K, np.ones(p.n_dofs, bool), "cholmod")
    b = np.random.default_rng(1).standard_normal(p.n_dofs)
    shifted = (K - 2.2 * sp.identity(p.n_dofs, format="csr")).tocsr()  # cosh >= 1: K - 2.2 I is indefinite
    shifted = sp.csr_matrix((shifted[K != 0].A1, K.indices, K.indptr), shape=K.shape)  # K's pattern and order
    assert np.linalg.eigvalsh(shifted.toarray()).min() < 0 < np.linalg.eigvalsh(K.toarray()).min()
    for A, ldlt in ((K, 0), (shifted, 1), (K, 1)):
        lin.factor(A)
        x = lin.solve(b)
        ref = np.linalg.solve(A.toarray(), b)
        assert np.abs(x - ref).max() <= 1e-10 * np.abs(ref).max(), f"{np.abs(x - ref).max():.2e}"
        assert lin.n_factor_ldlt == ldlt


def test_linear_solver_auto_is_cholmod_where_cvxopt_is_installed(monkeypatch):
    assert resolve_backend("auto") == "cholmod"  # the test extra installs cvxopt
    monkeypatch.setattr(cholmod, "available", lambda: False)
    assert resolve_backend("auto") == "sparsecholesky"
    with pytest.raises(LinearSolverError, match=r"needs cvxopt.*ngbet\[cholmod\]"):
        resolve_backend("cholmod")
    with pytest.raises(LinearSolverError, match="'lu' unknown"):
        resolve_backend("lu")


def test_energy_balance_by_the_hermite_rule_on_a_smooth_branch():
    # on a continuous branch the clamp's work equals the energy change; the trapezoidal rule misses
    # it by ~h^3 F''/12, the Hermite rule with dF/du0 at both ends by O(h^5) (here <= 3e-5 of a
    # step's work, the trapezoid's ~200x more): what is left as "released" energy is the measure that
    # tells a snap-through (a jump releases percents of the step's work) from a long smooth step
    p = Pulled()
    rows = []
    steps = Steps(
        load_steps(
            p, StepControl(path=PathControl(target=2.0, first_step=0.25, max_step=0.25, min_step=1e-3), stability=False)
        )
    )
    for info in steps:
        rows.append((info.u0, float(p.load @ info.residual), info.energy, info.released))
    assert steps.result is not None
    res = steps.result.path_info
    assert not res["snap_events"] and res["failed_steps"] == 0, (
        f"snaps {res['snap_events']}, failed {res['failed_steps']}"
    )
    prev = (0.0, 0.0, 0.0)
    for u0, F, E, released in rows:
        h = u0 - prev[0]
        work = 0.5 * h * (F + prev[1])
        trap = work - (E - prev[2])
        assert abs(released) <= 1e-4 * work and abs(released) <= 1e-2 * abs(trap), (
            f"u0 {u0}: Hermite {released:.2e}, trapezoid {trap:.2e}, work {work:.3e}"
        )
        prev = (u0, F, E)


def test_krylov_step_with_the_tangents_own_factorization_is_the_newton_step():
    # preconditioned by K itself, conjugate gradients solve K du = -r in one iteration: the step
    # and its decrement r . K^-1 r are Newton's to round-off
    from ngbet.discrete.newton import _krylov_step

    p = Convex(40)
    u = np.linspace(-1, 1, p.n_dofs)
    _, g, K = p.evaluate(u)
    lin = solver(p)
    lin.factor(K)
    du, dec = _krylov_step(lin, K, g, ctl())
    exact = -np.linalg.solve(K.toarray(), g)
    assert np.abs(du - exact).max() <= 1e-12 * np.abs(exact).max(), f"{np.abs(du - exact).max():.2e}"
    assert dec == pytest.approx(-g @ exact, rel=1e-12)


def test_krylov_step_refuses_an_indefinite_tangent():
    # next to the double well's saddle K_xx = 3x^2 - 1 < 0: the first CG direction (from the
    # preconditioner, the positive tangent at the minimum) meets negative curvature, and the
    # caller must factorize and shift instead
    from ngbet.discrete.newton import _krylov_step

    p = DoubleWell()
    lin = solver(p)
    lin.factor(p.evaluate(np.array([1.0, 0.0]))[2])
    _, g, K = p.evaluate(np.array([1e-3, 0.0]))
    assert _krylov_step(lin, K, g, ctl()) is None


def test_inexact_newton_reaches_the_same_minimum_with_fewer_factorizations():
    # Newton from 0 needs 5 iterations (decrements 61, 11, 0.36, 7e-5, 8e-14 at energies 83 ... 40).
    # Inexact: the first two iterations are far (decrement above the energy) and factorize; from
    # then on each solves its own tangent by CG preconditioned with the last factorization, and
    # one full iteration at the end factorizes the converged tangent: 3 factorizations against 5;
    # both stop at the same tolerance, so the minima agree to it
    p = Convex(40)
    u0 = np.zeros(p.n_dofs)
    full, inexact = solver(p), solver(p)
    u_n, its_n, _, _ = newton(p, u0, full, ctl())
    c = ctl(krylov_min_free=0)
    u_i, its_i, hist, _ = newton(p, u0, inexact, c, inexact=True)
    assert its_n >= 4 and full.n_factor == its_n, f"Newton: {its_n} iterations, {full.n_factor} factorizations"
    assert inexact.n_factor == 3 and its_i <= its_n + 1, f"{its_i} iterations, {inexact.n_factor} factorizations"
    assert hist[-1][2] <= c.rtol * abs(hist[-1][0]) + c.atol
    assert np.abs(u_i - u_n).max() <= 1e-6, f"{np.abs(u_i - u_n).max():.2e}"
    assert np.abs(p.evaluate(u_i)[1]).max() <= 1e-6, f"residual {np.abs(p.evaluate(u_i)[1]).max():.2e}"


def test_lowest_eigenvalues_match_a_dense_solve_with_a_near_degenerate_pair():
    # K v = lambda diag(K) v for a chain Laplacian (Convex) plus a softened, nearly degenerate
    # pair of modes: the block Lanczos (whole block at the first expansion, the pair nearest 0
    # after it) returns the two lowest eigenvalues of the dense generalized problem, the
    # lowest to ~tol^2 = 1e-6 relative, from a cold start and from a perturbed warm start
    import scipy.linalg as sla

    from ngbet.discrete.eigen import lowest_eigenvalues

    p = Convex(60)
    K = p.evaluate(np.linspace(-1, 1, p.n_dofs))[2].toarray()
    w, V = np.linalg.eigh(K)
    w[0], w[1] = 1e-4, 1.02e-4  # a soft, nearly degenerate pair (modes 2 and 3 of the BET network cross)
    K = sp.csr_matrix((V * w) @ V.T)
    K.data[np.abs(K.data) < 1e-14 * np.abs(K.data).max()] = 0.0
    lin = FreeBlockSolver(K, np.ones(p.n_dofs, bool))
    lin.factor(K)
    d = np.abs(K.diagonal())
    ref = sla.eigh(K.toarray(), np.diag(d), eigvals_only=True)[:2]
    lam, modes = lowest_eigenvalues(lin, 2)
    assert lam[0] == pytest.approx(ref[0], rel=1e-5), (lam, ref)
    X0 = modes + 1e-2 * np.random.default_rng(3).standard_normal(modes.shape) * np.abs(modes).max()
    lam2, _ = lowest_eigenvalues(lin, 2, X0)
    assert lam2[0] == pytest.approx(ref[0], rel=1e-5), (lam2, ref)


def test_the_network_path_is_a_generator_that_hands_out_each_state_and_keeps_none():
    """The runner's loop: each record carries the converged state while it is the current step
    (x solves k (c - x) = m x + b x³ at c = u0, the pulled chain's equilibrium), dropped when the
    path moves on; breaking out after k records leaves k steps counted in the statistics, and the
    path carried to the end returns the statistics of all its steps."""
    p = Pulled()
    ctl = StepControl(path=PathControl(target=1.0, first_step=0.25, max_step=0.25, min_step=1e-3), stability=False)
    res = PathResult(0.0)
    seen = []
    for rec in load_steps(p, ctl, res):
        assert rec.state is not None and rec.state[1] == pytest.approx(rec.u0, abs=1e-15)
        x, c = rec.state
        assert p.k * (c - x) == pytest.approx(p.m * x + p.b * x**3, abs=1e-10)
        seen.append(rec)
        if len(seen) == 2:
            break
    assert seen[0].state is None and seen[1].state is not None  # the first dropped when the second came
    assert res.path_info["steps"] == 2 and [s.u0 for s in res.steps] == [0.25, 0.5]
    steps = Steps(load_steps(Pulled(), ctl))
    states = [rec.state.copy() for rec in steps]
    assert steps.result is not None and len(states) == 4 == steps.result.path_info["steps"]
    x, c = states[-1]
    assert c == 1.0 and p.k * (c - x) == pytest.approx(p.m * x + p.b * x**3, abs=1e-10)
    assert steps.result.path_info["newton_iterations"] == sum(r.iterations for r in steps.result.steps)
