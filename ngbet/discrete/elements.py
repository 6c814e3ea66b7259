"""Element energies of the yarn network, with exact gradients and Hessians (vectorized over elements).

Nodal dofs are (ux, uy, theta); x = X + u is the current position.

Co-rotational Euler-Bernoulli beam (nodes a, b; reference chord d0 = X_b - X_a, length L0):
    d = x_b - x_a,  l = |d|,  beta = atan2(d0 x d, d0 . d)          (rigid rotation of the chord, exact)
    theta_1 = wrap(theta_a - beta),  theta_2 = wrap(theta_b - beta)  (end rotations relative to the chord)
    psi = 1/2 EA (l - L0)^2 / L0  +  2 EI / L0 (theta_1^2 + theta_1 theta_2 + theta_2^2)
The local part is the linear Euler-Bernoulli (cubic Hermite) element; the large rotation is carried
exactly by beta, so that psi is invariant under rigid motions of any size. With q = (l, theta_1,
theta_2) and B = dq/dx_e, the gradient is B^T dpsi/dq and the Hessian
    B^T (d2psi/dq2) B + N d2l/dx2 - (M_1 + M_2) d2beta/dx2,
    d2l/dd2 = (I - e e^T) / l,   d2beta/dd2 = [[2 e_x e_y, e_y^2 - e_x^2], [e_y^2 - e_x^2, -2 e_x e_y]] / l^2,
with e = d / l, N = EA (l - L0) / L0, M_1 = 2EI/L0 (2 theta_1 + theta_2), M_2 = 2EI/L0 (theta_1 + 2 theta_2).

Truss (inter-yarn springs): psi = 1/2 K (l - L0)^2 / L0 on the translations of two nodes.
Slip spring: psi = 1/2 K_slip |u_a - u_b|^2 (nodes of the two yarns at one crossing).
Rotational crossing spring: psi = 1/2 K_phi (theta_b - theta_a)^2 (change of angle between the yarns).

Each function returns (psi_e, g_e, H_e) with shapes (n,), (n, k), (n, k, k) for the element dof
vectors of length k (6 for a beam, 4 for a truss and a slip spring, 2 for a rotational spring).
"""

from __future__ import annotations

import numpy as np

__all__ = ["beam", "beam_energy_parts", "beam_local", "rotational_spring", "slip_spring", "truss", "wrap_angle"]


def wrap_angle(t: np.ndarray) -> np.ndarray:
    """Map angles to (-pi, pi]: the beam's local rotations are small, the nodal ones need not be."""
    return t - 2 * np.pi * np.round(t / (2 * np.pi))


def _chord(xa: np.ndarray, xb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = xb - xa
    l = np.hypot(d[:, 0], d[:, 1])
    return d, l, d / l[:, None]


def _d2l_d2beta(e: np.ndarray, l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Second derivatives of l and beta with respect to the chord vector d, (n, 2, 2) each."""
    ex, ey = e[:, 0], e[:, 1]
    Hl = (np.eye(2)[None] - e[:, :, None] * e[:, None, :]) / l[:, None, None]
    Hb = np.empty_like(Hl)
    Hb[:, 0, 0] = 2 * ex * ey
    Hb[:, 1, 1] = -2 * ex * ey
    Hb[:, 0, 1] = Hb[:, 1, 0] = ey * ey - ex * ex
    return Hl, Hb / (l * l)[:, None, None]


def beam_local(x: np.ndarray, theta: np.ndarray, d0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local deformation of co-rotational beams: (l, theta_1, theta_2).

    Parameters
    ----------
    x : (n, 2, 2) current positions of nodes a, b
    theta : (n, 2) nodal rotations of a, b
    d0 : (n, 2) reference chords
    """
    d = x[:, 1] - x[:, 0]
    l = np.hypot(d[:, 0], d[:, 1])
    beta = np.arctan2(d0[:, 0] * d[:, 1] - d0[:, 1] * d[:, 0], d0[:, 0] * d[:, 0] + d0[:, 1] * d[:, 1])
    return l, wrap_angle(theta[:, 0] - beta), wrap_angle(theta[:, 1] - beta)


def beam_energy_parts(ue: np.ndarray, Xe: np.ndarray, EA: np.ndarray, EI: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axial and bending energies of co-rotational beams.

    psi_axial = 1/2 EA (l - L0)^2 / L0,  psi_bend = 2 EI/L0 (theta_1^2 + theta_1 theta_2 + theta_2^2).

    Parameters
    ----------
    ue : (n, 6) element dofs (ux_a, uy_a, theta_a, ux_b, uy_b, theta_b)
    Xe : (n, 2, 2) reference positions of nodes a, b
    EA, EI : (n,) axial [N] and bending [N m^2] stiffness
    """
    d0 = Xe[:, 1] - Xe[:, 0]
    L0 = np.hypot(d0[:, 0], d0[:, 1])
    x = Xe + ue[:, [[0, 1], [3, 4]]]
    l, t1, t2 = beam_local(x, ue[:, [2, 5]], d0)
    return 0.5 * EA * (l - L0) ** 2 / L0, 2 * EI / L0 * (t1 * t1 + t1 * t2 + t2 * t2)


def beam(
    ue: np.ndarray, Xe: np.ndarray, EA: np.ndarray, EI: np.ndarray, hessian: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Energy, gradient and Hessian of co-rotational Euler-Bernoulli beams (formulas: module docstring)."""
    n = ue.shape[0]
    d0 = Xe[:, 1] - Xe[:, 0]
    L0 = np.hypot(d0[:, 0], d0[:, 1])
    x = Xe + ue[:, [[0, 1], [3, 4]]]
    l, t1, t2 = beam_local(x, ue[:, [2, 5]], d0)
    e = (x[:, 1] - x[:, 0]) / l[:, None]
    kb = 2 * EI / L0
    psi = 0.5 * EA * (l - L0) ** 2 / L0 + kb * (t1 * t1 + t1 * t2 + t2 * t2)
    N = EA * (l - L0) / L0
    M1 = kb * (2 * t1 + t2)
    M2 = kb * (t1 + 2 * t2)
    g = e[:, ::-1] * np.array([-1.0, 1.0]) / l[:, None]  # dbeta/dd = (-e_y, e_x) / l
    B = np.zeros((n, 3, 6))
    B[:, 0, 0:2], B[:, 0, 3:5] = -e, e
    B[:, 1, 0:2], B[:, 1, 3:5], B[:, 1, 2] = g, -g, 1.0  # theta_1 = theta_a - beta
    B[:, 2, 0:2], B[:, 2, 3:5], B[:, 2, 5] = g, -g, 1.0
    grad = N[:, None] * B[:, 0] + M1[:, None] * B[:, 1] + M2[:, None] * B[:, 2]
    if not hessian:
        return psi, grad, None
    # B^T (Dq B) with Dq = [[EA/L0, 0, 0], [0, 2kb, kb], [0, kb, 2kb]]: one batched (6x3)(3x6) matmul
    # (the same values to round-off as the outer products written out, with fewer temporaries)
    b0, b1, b2 = B[:, 0], B[:, 1], B[:, 2]
    DB = np.stack([(EA / L0)[:, None] * b0, kb[:, None] * (2 * b1 + b2), kb[:, None] * (b1 + 2 * b2)], axis=1)
    H = np.matmul(B.transpose(0, 2, 1), DB)
    Hl, Hb = _d2l_d2beta(e, l)
    Hd = N[:, None, None] * Hl - (M1 + M2)[:, None, None] * Hb
    H[:, 0:2, 0:2] += Hd
    H[:, 3:5, 3:5] += Hd
    H[:, 0:2, 3:5] -= Hd
    H[:, 3:5, 0:2] -= Hd
    return psi, grad, H


def truss(
    ue: np.ndarray, Xe: np.ndarray, K: np.ndarray, hessian: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Geometrically exact truss psi = 1/2 K (l - L0)^2 / L0; dofs (ux_a, uy_a, ux_b, uy_b)."""
    d0 = Xe[:, 1] - Xe[:, 0]
    L0 = np.hypot(d0[:, 0], d0[:, 1])
    _, l, e = _chord(Xe[:, 0] + ue[:, 0:2], Xe[:, 1] + ue[:, 2:4])
    N = K * (l - L0) / L0
    psi = 0.5 * K * (l - L0) ** 2 / L0
    grad = np.concatenate([-N[:, None] * e, N[:, None] * e], axis=1)
    if not hessian:
        return psi, grad, None
    k = (K / L0)[:, None, None] * e[:, :, None] * e[:, None, :] + N[:, None, None] * _d2l_d2beta(e, l)[0]
    H = np.concatenate([np.concatenate([k, -k], axis=2), np.concatenate([-k, k], axis=2)], axis=1)
    return psi, grad, H


def slip_spring(ue: np.ndarray, K: float, hessian: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Psi = 1/2 K_slip |u_a - u_b|^2; dofs (ux_a, uy_a, ux_b, uy_b)."""
    s = ue[:, 0:2] - ue[:, 2:4]
    psi = 0.5 * K * np.sum(s * s, axis=1)
    grad = K * np.concatenate([s, -s], axis=1)
    if not hessian:
        return psi, grad, None
    k = K * np.array([[1.0, 0, -1, 0], [0, 1, 0, -1], [-1, 0, 1, 0], [0, -1, 0, 1]])
    return psi, grad, np.broadcast_to(k, (ue.shape[0], 4, 4))


def rotational_spring(
    ue: np.ndarray, K: float, hessian: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Psi = 1/2 K_phi (theta_b - theta_a)^2; dofs (theta_a, theta_b)."""
    dphi = ue[:, 1] - ue[:, 0]
    psi = 0.5 * K * dphi * dphi
    grad = K * np.column_stack([-dphi, dphi])
    if not hessian:
        return psi, grad, None
    return psi, grad, np.broadcast_to(K * np.array([[1.0, -1.0], [-1.0, 1.0]]), (ue.shape[0], 2, 2))
