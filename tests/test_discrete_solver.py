"""The discrete model's Newton solver on small energies with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ngbet.discrete.linsolve import FreeBlockSolver
from ngbet.discrete.solver import StepControl, _StepFailed, newton, single_threaded_blas


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


def ctl(**kw) -> StepControl:
    return StepControl(u0_final=1.0, first_step=1.0, max_step=1.0, min_step=1e-3, **kw)


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
    u, its, hist, shifted = newton(p, np.array([1e-3, 0.0]), lin, ctl(), max_iterations=48, line_search=True,
                                   fail_fast=False)
    assert abs(u[0] - 1.0) < 1e-8 and abs(u[1]) < 1e-8, f"relaxed to {u}"
    assert its <= 12 and lin.n_factor <= 30, f"{its} iterations, {lin.n_factor} factorizations"


def test_no_shift_allowed_stops_at_the_first_indefinite_tangent():
    # a step that will be cut anyway (longer than the snap bracket) gives up at once
    p = DoubleWell()
    lin = solver(p)
    with pytest.raises(_StepFailed) as exc:
        newton(p, np.array([1e-3, 0.0]), lin, ctl(), allow_shift=False)
    assert exc.value.indefinite and lin.n_factor == 1, f"indefinite {exc.value.indefinite}, {lin.n_factor} factorizations"


def test_simplified_exit_saves_a_factorization_same_minimum():
    # the simplified correction with the last factorization replaces the linearization that would
    # only confirm convergence: one factorization less, the same minimizer to the Newton tolerance
    # (decrements here 9.5, 1.7, 0.05, 1.1e-5, 2.4e-13 against a tolerance of 6e-10: the exit is
    # tried from 1.1e-5 on, within 1e6 tolerances)
    p = Convex()
    res = {}
    for exit_ in (0.0, 1e6):
        lin = solver(p)
        u, its, hist, _ = newton(p, np.zeros(p.n_dofs), lin, ctl(simplified_exit=exit_))
        res[exit_] = (u, lin.n_factor, hist)
    (u0, n0, _), (u1, n1, h1) = res[0.0], res[1e6]
    assert n1 == n0 - 1, f"factorizations {n0} (plain) vs {n1} (simplified exit)"
    assert np.abs(u1 - u0).max() < 1e-7, f"minimizers differ by {np.abs(u1 - u0).max():.2e}"
    # and the accepted state passes the decrement test: its last recorded decrement is below tolerance
    assert abs(h1[-1][2]) <= 1e-10 * abs(h1[-1][0]) + 1e-14, f"last decrement {h1[-1][2]:.3g}"


def test_blas_pools_single_threaded_during_the_solve():
    # the solver's dense operations are vector-sized; a second BLAS thread only spins (CPU = 2x wall)
    from threadpoolctl import threadpool_info

    with single_threaded_blas():
        blas = [i for i in threadpool_info() if i["user_api"] == "blas"]
        assert blas and all(i["num_threads"] == 1 for i in blas), f"{[(i['filepath'], i['num_threads']) for i in blas]}"


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
