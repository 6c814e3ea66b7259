r"""Energy terms of the constrained micromorphic continuum (Madeo et al. 2016; docs/model.md, *Energy*).

Pure functions from NGSolve CoefficientFunctions to CoefficientFunctions. Per unit reference
volume [Pa], with F = I + ∇u, C = FᵀF and the yarn directions m1 (thick), m2 (thin):

.. math::

    i_4 = m_1\cdot C m_1,\quad i_6 = m_2\cdot C m_2,\quad i_8 = m_1\cdot C m_2 \\
    W_{sh} = \tfrac12 K_{sh} i_8^2\ \text{(or a stiffening law, below)},\qquad
    W_{el} = \tfrac12 K_{el}\,[(\sqrt{i_4}-1)^2 + (\sqrt{i_6}-1)^2] \\
    W_{b} = \tfrac12 \alpha_1 (\nabla\varphi\cdot m_1)^2 + \tfrac12 \alpha_2 (\nabla\varphi\cdot m_2)^2

the jamming barrier on the sine s of the angle between the deformed yarns (the yarns cannot cross)

.. math::

    W_{jam} = K_{jam}\, s_{jam}^2 \,(1 - t)^3/t,\quad t = s/s_{jam} < 1 \quad (0 \text{ for } t \ge 1),

and the constraint φ = i8 by a multiplier Λ (Λ(φ − i8)), a penalty ½K(φ − i8)², or the mixed
penalty Λ(φ − i8) − Λ²/(2K) whose Λ is eliminated element by element.

The paper prints W_b = ½⟨α, ∇φ⟩², which drops the squares; docs/model.md (*Energy*) explains why the form above is used.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import ngsolve as ngs
import numpy as np
from ngsolve import CoefficientFunction as CF

from ..scene.physical import SHEAR_LAW_KEYS

__all__ = [
    "JAMMING_CUTOFF",
    "LOCKING_CUTOFF",
    "Invariants",
    "bending_energy",
    "elongation_energy",
    "invariants",
    "jamming_energy",
    "lagrange_constraint",
    "locking_shear_energy",
    "mixed_penalty_constraint",
    "penalty_constraint",
    "polynomial_shear_energy",
    "shear_angle",
    "shear_energy",
    "shear_law_energy",
    "table_greville",
    "table_shear_energy",
    "table_stress_spline",
    "yarn_angle_sine",
]


class Invariants(NamedTuple):
    """F = I + ∇u and the yarn invariants i4, i6 (squared stretches) and i8 (angle variation, from rest)."""

    F: CF
    i4: CF
    i6: CF
    i8: CF


def invariants(grad_u: CF, m1: CF, m2: CF) -> Invariants:
    """F = I + ∇u and the yarn invariants i4, i6 (squared stretches) and i8 (angle variation).

    i8 = m1·C·m2 − m1·m2 is measured from the rest state, so that it is 0 at rest for any yarn
    angle (docs/model.md, *Energy*); for the orthogonal yarns of the paper (±45°) m1·m2 = 0 and nothing changes.
    """
    F = ngs.Id(2) + grad_u
    Fm1 = F * m1
    Fm2 = F * m2
    i8 = ngs.InnerProduct(Fm1, Fm2) - ngs.InnerProduct(m1, m2)
    return Invariants(F, ngs.InnerProduct(Fm1, Fm1), ngs.InnerProduct(Fm2, Fm2), i8)


def shear_energy(i8: CF, K_sh: float) -> CF:
    """W_sh = ½ K_sh i8²."""
    return 0.5 * K_sh * i8 * i8


def polynomial_shear_energy(i8: CF, K_sh: float, K_sh4: float, K_sh6: float) -> CF:
    r"""W_sh = ½ K_sh i8² + ¼ K_sh4 i8⁴ + ⅙ K_sh6 i8⁶ [Pa]: a stiffening shear law.

    The shear stress ∂W/∂i8 = K_sh i8 + K_sh4 i8³ + K_sh6 i8⁵ is the odd polynomial that fabric
    shear data are usually fitted with (the normalised shear force of the Cao et al. 2008
    benchmark as a polynomial in the shear angle; hyperelastic fabric models writing the shear
    energy as a polynomial in the shear invariant). With K_sh4 = K_sh6 = 0 it is the quadratic law.
    """
    s = i8 * i8
    return s * (0.5 * K_sh + s * (0.25 * K_sh4 + s * (K_sh6 / 6.0)))


#: x = (i8 / sin γ_lock)² beyond which the locking law continues by its second-order Taylor
#: polynomial in x, so that Newton iterates past the locking angle see a finite, convex energy
LOCKING_CUTOFF = 0.95


def locking_shear_energy(i8: CF, K_sh: float, K_lock: float, gamma_lock_deg: float) -> CF:
    r"""W_sh = ½ K_sh i8² − ½ K_lock s² [ln(1 − x) + x], x = i8²/s², s = sin γ_lock [Pa].

    A limiting-angle law in the manner of Gent's limited-extensibility energy: the shear stress
    ∂W/∂i8 = K_sh i8 + K_lock i8 x/(1 − x) starts as the quadratic law's (slope K_sh: the extra
    term is O(i8³)) and grows without bound as the yarns close to the locking angle γ_lock
    (i8 = sin γ for inextensible yarns at ±45°). Beyond x = :data:`LOCKING_CUTOFF` the logarithm is
    replaced by its second-order Taylor polynomial (C² join), so that the energy stays finite.
    """
    s2 = (
        math.sin(math.radians(gamma_lock_deg)) ** 2
        if isinstance(gamma_lock_deg, (int, float))
        else ngs.sin(gamma_lock_deg * (math.pi / 180.0)) ** 2
    )
    x = i8 * i8 / s2
    xc = LOCKING_CUTOFF
    dx = x - xc
    taylor = math.log(1.0 - xc) - dx / (1.0 - xc) - dx * dx / (2.0 * (1.0 - xc) ** 2)
    log1mx = ngs.IfPos(dx, taylor, ngs.log(1.0 - ngs.IfPos(dx, xc, x)))
    return 0.5 * K_sh * i8 * i8 - 0.5 * K_lock * s2 * (log1mx + x)


def table_stress_spline(steps: Sequence[float] | np.ndarray, x_max: float) -> Any:
    r"""The shear stress τ(x) of the tabulated law, x = |i8|, as a :class:`scipy.interpolate.BSpline`.

    A B-spline of degree 3 (2 with two rises) on uniform clamped knots over [0, x_max] whose
    control values are c_0 = 0 and c_j = Σ_{i<=j} steps_i: rises >= 0 make the control values
    monotone, and a B-spline with monotone control values is monotone (its derivative is a
    B-spline with the differences as control values), so the energy is convex. A B-spline
    reproduces straight lines from their values at the Greville abscissae
    (:func:`table_greville`): the rises K (ξ_j − ξ_{j−1}) give τ = K x, the quadratic law, exactly.
    """
    from scipy.interpolate import BSpline

    c = np.concatenate([[0.0], np.cumsum(np.asarray(steps, dtype=float))])
    k = min(3, len(c) - 1)
    inner = np.linspace(0.0, x_max, len(c) - k + 1)
    t = np.concatenate([[0.0] * k, inner, [x_max] * k])
    return BSpline(t, c, k, extrapolate=False)


def table_greville(n_steps: int, x_max: float) -> np.ndarray:
    """The Greville abscissae of the tabulated law's control values (n_steps + 1 of them, from 0)."""
    t = table_stress_spline(np.ones(n_steps), x_max).t
    k = min(3, n_steps)
    return np.array([t[j + 1 : j + k + 1].mean() for j in range(n_steps + 1)])


def _truncated_powers(x: CF, breaks: np.ndarray, coeffs: np.ndarray, tail: tuple[float, float, float]) -> CF:
    """Σ_k coeffs[k, i] (x − breaks[i])^(K−k) on [breaks[i], breaks[i+1]], as P_0(x) + Σ_i Q_i((x − b_i)₊).

    Beyond the last break: tail = (W, τ, k) there, continued as W + τ s + ½ k s², s = x − x_end.
    P_0 is the first piece, Q_i the difference of the pieces meeting at the break b_i (the tail's at the last), a
    polynomial in x − b_i whose terms below the order of the jump vanish (dropped below 1e-12 of
    its largest). One ``IfPos`` per break, on x − b_i alone, and one polynomial each: ``IfPos``
    computes both of its branches, so a nested choice among the pieces would evaluate every piece.
    """
    from numpy.polynomial import Polynomial as Poly

    K = coeffs.shape[0] - 1
    pieces = [
        sum((float(coeffs[K - m, i]) * Poly([-float(b), 1.0]) ** m for m in range(K + 1)), Poly([0.0]))
        for i, b in enumerate(breaks[:-1])
    ]
    x_end = float(breaks[-1])
    pieces.append(
        Poly([tail[0] - tail[1] * x_end + 0.5 * tail[2] * x_end**2, tail[1] - tail[2] * x_end, 0.5 * tail[2]])
    )

    def horner(q: np.ndarray, t: CF) -> CF:
        out: CF = float(q[-1])
        for a in q[-2::-1]:
            out = out * t + float(a)
        return out

    expr = horner(pieces[0].coef, x)
    for b, prev, nxt in zip(breaks[1:], pieces[:-1], pieces[1:], strict=True):
        q = np.trim_zeros(((nxt - prev)(Poly([float(b), 1.0]))).coef, "b")
        if not q.size:
            continue
        low = int(np.argmax(np.abs(q) > 1e-12 * np.max(np.abs(q))))
        s = ngs.IfPos(x - float(b), x - float(b), 0.0)
        expr = expr + horner(q[low:], s) * s**low if low else expr + horner(q, s)
    return expr


def table_shear_energy(i8: CF, steps: Sequence[float] | np.ndarray, x_max: float) -> CF:
    r"""W_sh(i8) = ∫₀^|i8| τ(x) dx [Pa] with τ the monotone spline of :func:`table_stress_spline`.

    A piecewise polynomial in i8 (degree 4 with cubic τ), even in i8, built from ``IfPos``: W is
    C², so the Newton tangent W'' = τ' is continuous; beyond x_max the stress continues linearly
    with its end slope (W quadratic there, still convex). The energy is linear in the rises, so
    dW/d(rise j) is this function with the unit rise e_j.
    """
    from scipy.interpolate import PPoly

    spl = table_stress_spline(steps, x_max)
    spl_e = type(spl)(spl.t, spl.c, spl.k, extrapolate=True)
    W = PPoly.from_spline(spl_e.antiderivative())
    keep = np.r_[np.diff(W.x) > 0, True]  # drop the empty intervals of the clamped knots
    x, c = W.x[keep], W.c[:, keep[:-1]]
    tail = (float(W(x_max)), float(spl_e(x_max)), float(spl_e.derivative()(x_max)))
    return _truncated_powers(ngs.IfPos(i8, i8, -i8), x, c, tail)  # at |i8|: IfPos computes both of its branches


def shear_law_energy(i8: CF, law: str, coefficients: dict[str, Any]) -> CF:
    """The shear energy of ``law`` (a key of :data:`~ngbet.scene.physical.SHEAR_LAW_KEYS`), its coefficients given.

    The coefficients are floats, or NGSolve Parameters to differentiate with respect to.
    """
    c = [coefficients[k] for k in SHEAR_LAW_KEYS[law]]
    if law == "polynomial":
        return polynomial_shear_energy(i8, *c)
    if law == "locking":
        return locking_shear_energy(i8, *c)
    if law == "table":
        return table_shear_energy(i8, *c)
    return shear_energy(i8, *c)


def elongation_energy(i4: CF, i6: CF, K_el: float) -> CF:
    """W_el = ½ K_el [(√i4 − 1)² + (√i6 − 1)²]: equivalent elongation (decrimping, slip)."""
    return 0.5 * K_el * ((ngs.sqrt(i4) - 1) ** 2 + (ngs.sqrt(i6) - 1) ** 2)


#: t = s/s_jam below which the jamming barrier continues by its second-order Taylor polynomial in t
#: (C² join), so that the energy stays finite and convex in t for crossed yarns (t <= 0) too
JAMMING_CUTOFF = 0.05


def yarn_angle_sine(F: CF, m1: CF, m2: CF, orientation: float = 1.0) -> CF:
    r"""The sine s = (Fm1 × Fm2)/(|Fm1| |Fm2|) of the angle between the deformed yarns, signed.

    Fm1 × Fm2 = det F (m1 × m2), so s = det F sin θ0 / √(i4 i6) (θ0 the rest angle): it falls to 0 as
    the yarns close on each other (θ → 0 or 180°, as lines the acute angle → 0) and changes sign
    where they cross, i.e. where the material turns inside out (det F < 0). ``orientation`` is the
    sign of m1 × m2, so that s > 0 at rest.
    """
    a, b = F * m1, F * m2
    cross = a[0] * b[1] - a[1] * b[0]
    return orientation * cross / ngs.sqrt(ngs.InnerProduct(a, a) * ngs.InnerProduct(b, b))


def jamming_energy(s: CF, K_jam: float, s_jam: float) -> CF:
    r"""W_jam = K_jam s_jam² (1 − t)³/t for t = s/s_jam < 1, 0 beyond [Pa]: the yarns cannot cross.

    A barrier on the sine s of the angle between the deformed yarns (:func:`yarn_angle_sine`). It
    vanishes with its first and second derivatives at the threshold t = 1 (Newton's tangent is
    continuous there: the term is invisible to any state whose yarns stay more open than s_jam),
    is convex in t below it and grows like K_jam s_jam²/t as the yarns close (t → 0), so that
    no state of finite energy has crossed yarns. Below t = :data:`JAMMING_CUTOFF` it continues by
    its second-order Taylor polynomial in t (still decreasing and convex), so that a Newton
    iterate with crossed yarns sees a large, finite energy rather than a negative one.
    """
    tc = JAMMING_CUTOFF
    h_c = (1.0 - tc) ** 3 / tc
    dh_c = -3.0 * (1.0 - tc) ** 2 / tc - (1.0 - tc) ** 3 / tc**2
    d2h_c = 6.0 * (1.0 - tc) / tc + 6.0 * (1.0 - tc) ** 2 / tc**2 + 2.0 * (1.0 - tc) ** 3 / tc**3
    t = s / s_jam
    dt = t - tc
    # the branches are evaluated everywhere: keep t away from 0 where the rational branch is not taken
    t_safe = ngs.IfPos(dt, t, tc)
    h = ngs.IfPos(dt, (1.0 - t_safe) ** 3 / t_safe, h_c + dt * (dh_c + 0.5 * d2h_c * dt))
    return ngs.IfPos(t - 1.0, 0.0, (K_jam * s_jam * s_jam) * h)


def bending_energy(grad_phi: CF, m1: CF, m2: CF, alpha1: float, alpha2: float) -> CF:
    """W_b = ½ α1 φ,1² + ½ α2 φ,2² with φ,i = ∇φ·m_i (corrected form, docs/model.md, *Energy*)."""
    p1 = ngs.InnerProduct(grad_phi, m1)
    p2 = ngs.InnerProduct(grad_phi, m2)
    return 0.5 * alpha1 * p1 * p1 + 0.5 * alpha2 * p2 * p2


def lagrange_constraint(phi: CF, i8: CF, lam: CF) -> CF:
    """Λ (φ − i8): the Lagrangian's constraint term (saddle point in Λ)."""
    return lam * (phi - i8)


def penalty_constraint(phi: CF, i8: CF, K: float) -> CF:
    """½ K (φ − i8)²: the paper's penalty (appendix A), imposed pointwise."""
    return 0.5 * K * (phi - i8) ** 2


def mixed_penalty_constraint(phi: CF, i8: CF, lam: CF, K: float) -> CF:
    """The stabilized constraint term Λ (φ − i8) − Λ²/(2K).

    Stationary in Λ at Λ = K Π(φ − i8), i.e. the penalty ½K‖Π(φ − i8)‖² with Π the L2 projection
    onto Λ's space. K → ∞ gives the Lagrange multiplier method.
    """
    return lam * (phi - i8) - lam * lam / (2.0 * K)


def shear_angle(i4: CF, i6: CF, i8: CF, cos0: float = 0.0) -> CF:
    """The shear angle γ [rad]: the angle between the deformed yarn directions is θ0 + γ.

    θ0 = acos(m1·m2) is the rest angle (docs/model.md, *Ideal kinematics*: 90° + γ at ±45°, where
    sin γ = −i8 / √(i4 i6)).

    ``cos0`` = m1·m2; i8 is measured from rest (:func:`invariants`), so cos θ = (i8 + cos0)/√(i4 i6).
    """
    if cos0 == 0.0:
        return ngs.asin(-i8 / ngs.sqrt(i4 * i6))
    c = (i8 + cos0) / ngs.sqrt(i4 * i6)
    # acos loses accuracy only near 0° and 180°, far from the angles between yarns; c is clipped
    # to [−1, 1] against round-off
    return ngs.acos(ngs.IfPos(c - 1, 1, ngs.IfPos(-1 - c, -1, c))) - math.acos(cos0)
