"""Verification of the co-rotational Euler-Bernoulli beam against elastica solutions.

A single yarn is a chain of beam elements; the tests load it by dead forces through a tiny
problem class and solve with the discrete model's own Newton method.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from scipy.special import ellipe, ellipk

from ngbet.discrete import elements as el
from ngbet.discrete.linsolve import FreeBlockSolver
from ngbet.discrete.model import Pattern
from ngbet.discrete.newton import StepControl, newton
from ngbet.numerics.engine import PathControl


class Chain:
    """A straight beam along e1 (length L, n elements), clamped at s = 0, with a dead tip force."""

    def __init__(self, L: float, n: int, EA: float, EI: float) -> None:
        self.X = np.column_stack([np.linspace(0, L, n + 1), np.zeros(n + 1)])
        self.nodes = np.column_stack([np.arange(n), np.arange(1, n + 1)])
        self.dofs = (3 * self.nodes[..., None] + np.arange(3)).reshape(n, 6)
        self.EA, self.EI = np.full(n, EA), np.full(n, EI)
        self.n_dofs = 3 * (n + 1)
        self.fixed = np.zeros(self.n_dofs, bool)
        self.fixed[:3] = True
        self.load = np.zeros(self.n_dofs)
        self.ramp = np.zeros(self.n_dofs)
        self.force = np.zeros(2)  # dead force on the tip [N]
        self.pattern = Pattern([self.dofs], self.n_dofs)

    def evaluate(self, u, hessian=True):
        psi, ge, He = el.beam(u[self.dofs], self.X[self.nodes], self.EA, self.EI, hessian)
        g = np.bincount(self.dofs.ravel(), weights=ge.ravel(), minlength=self.n_dofs)
        g[-3:-1] -= self.force
        E = float(psi.sum()) - float(self.force @ u[-3:-1])
        return E, g, (self.pattern.matrix([He]) if hessian else None)


def solve_chain(chain: Chain, forces: list[np.ndarray], u: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Newton under a sequence of tip forces (a force-controlled load path); returns u, max iterations."""
    ctl = StepControl(
        path=PathControl(target=1.0, first_step=1.0, max_step=1.0, min_step=1.0), rtol=1e-13, max_iterations=40
    )
    u = np.zeros(chain.n_dofs) if u is None else u
    lin = FreeBlockSolver(chain.evaluate(u)[2], ~chain.fixed)
    worst = 0
    for f in forces:
        chain.force = np.asarray(f, float)
        u, its, _, _ = newton(chain, u, lin, ctl, fail_fast=False)
        worst = max(worst, its)
    return u, worst


def elastica_cantilever(L: float, EI: float, P: float) -> tuple[float, float]:
    """Tip displacement (ux, uy) of an inextensible cantilever under a transverse dead tip load P.

    EI theta'' = -P cos(theta), theta(0) = 0, theta'(L) = 0, solved by shooting on theta'(0)
    (bracketed in (0, P L / EI]: the root moment is P times the tip abscissa, at most P L).
    """

    def rhs(s, y):
        th, k, x, yy = y
        return [k, -P / EI * math.cos(th), math.cos(th), math.sin(th)]

    def end(k0):
        return solve_ivp(rhs, (0, L), [0, k0, 0, 0], rtol=1e-12, atol=1e-14).y[:, -1]

    k0 = brentq(lambda k: end(k)[1], 1e-9, P * L / EI, xtol=1e-15)
    th, _, x, y = end(k0)
    return x - L, y


def test_cantilever_elastica_and_h2_convergence():
    # P L^2 / EI = 3: a large deflection (tip rotation about 60 deg) where linear theory is 50 % off
    L, EI, P = 1.0, 1.0, 3.0
    EA = 1e9  # inextensible in practice: the axial strain P / EA ~ 3e-9 is far below the errors measured
    ux_ex, uy_ex = elastica_cantilever(L, EI, P)
    ns = [4, 8, 16, 32]
    errs = []
    for n in ns:
        ch = Chain(L, n, EA, EI)
        u, _ = solve_chain(ch, [np.array([0.0, P * t]) for t in np.linspace(0.2, 1.0, 5)])
        errs.append(math.hypot(u[-3] - ux_ex, u[-2] - uy_ex))
    rate = np.polyfit(np.log(ns), -np.log(errs), 1)[0]
    # exact elastica anchors the finest mesh: 32 elements are accurate to 1e-4 of the tip deflection
    assert errs[-1] < 1e-4 * math.hypot(ux_ex, uy_ex), f"tip error {errs[-1]:.3g} with 32 elements, errors {errs}"
    # cubic Hermite beams with a co-rotational chord converge as O(h^2) in the tip displacement
    assert 1.8 < rate < 2.3, f"observed convergence rate {rate:.3f} (errors {errs})"


def test_postbuckled_column_clamped_free():
    """Clamped-free column under an axial load P = 1.5 P_cr in the post-buckled elastica.

    Exact (inextensible): L sqrt(P / EI) = K(k), tip lateral deflection 2 k / sqrt(P / EI),
    tip axial position (2 E(k) - K(k)) / sqrt(P / EI), with k = sin(alpha / 2), alpha the tip angle.
    """
    L, EI = 1.0, 1.0
    Pcr = math.pi**2 * EI / (4 * L**2)
    P = 1.5 * Pcr
    lam = math.sqrt(P / EI)
    m = brentq(lambda m: ellipk(m) - L * lam, 1e-12, 1 - 1e-12)  # m = k^2
    k = math.sqrt(m)
    delta_ex = 2 * k / lam
    xtip_ex = (2 * ellipe(m) - ellipk(m)) / lam
    ch = Chain(L, 32, 1e9, EI)
    # an imperfection (a small lateral force) selects the branch, then is removed: the perfect
    # column's post-buckled state is stable, so Newton stays on it
    path = [np.array([-P * t, 0.02 * P]) for t in np.linspace(0.25, 1.0, 8)] + [np.array([-P, 0.0])]
    u, _ = solve_chain(ch, path)
    delta, xtip = abs(u[-2]), L + u[-3]
    # 32 elements: O(h^2) discretization error ~ 1e-3 relative
    assert abs(delta - delta_ex) < 2e-3 * delta_ex, f"lateral tip deflection {delta:.6f} vs elastica {delta_ex:.6f}"
    assert abs(xtip - xtip_ex) < 2e-3 * L, f"tip abscissa {xtip:.6f} vs elastica {xtip_ex:.6f}"


def test_newton_converges_quadratically_on_beam():
    # a 1/5 load increment of the large-deflection cantilever from the solved previous state: a
    # quadratically convergent Newton needs few iterations (the line search rarely acts)
    ch = Chain(1.0, 16, 1e9, 1.0)
    _, worst = solve_chain(ch, [np.array([0.0, 3.0 * t]) for t in np.linspace(0.2, 1.0, 5)])
    assert worst <= 8, f"Newton needed {worst} iterations for a load increment"


@pytest.mark.parametrize("theta", [0.3, 2.5])
def test_beam_rigid_rotation_has_zero_energy(theta):
    # exact co-rotation: a rigid rotation by any angle (here also beyond 90 deg) costs no energy
    X = np.array([[[0.1, 0.2], [0.4, 0.6]]])
    c, s = math.cos(theta), math.sin(theta)
    R = np.array([[c, -s], [s, c]])
    x = X[0] @ R.T + np.array([0.3, -0.7])
    ue = np.array([[*(x[0] - X[0, 0]), theta, *(x[1] - X[0, 1]), theta]])
    psi, g, _ = el.beam(ue, X, np.array([5e4]), np.array([0.4]))
    assert abs(psi[0]) < 1e-20 and np.abs(g).max() < 1e-8, f"rigid motion: psi {psi[0]:.3g}, |g| {np.abs(g).max():.3g}"
