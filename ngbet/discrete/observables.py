"""Observables of a yarn-network state u (SI in, the units in the names out).

- slip at a crossing: s = |u_a - u_b|, the relative displacement of the two yarns' nodes that
  coincided at rest;
- shear angle at a crossing: gamma = r_2 - r_1, the change of the angle between the family-2
  and the family-1 yarn, each yarn's rotation r_k taken as the mean rotation of its two chords
  adjacent to the crossing (the springs K_phi act on the nodal rotations theta instead, which
  equal r_k only when the bending stiffness dominates K_phi). With m1 = (cos a, sin a), m2 = (-cos a, sin a)
  the angle between the direction vectors opens from pi - 2a to pi - 2a + gamma, as in docs/model.md,
  *Ideal kinematics* (gamma > 0 in the BET);
- zone means of gamma over the crossings of zones A, B, C;
- mid-axis profile: u_y where the yarns cross Y = W/2 in the reference configuration (linear
  interpolation along the element), interpolated along X for each family and averaged over the two
  families, with u_y = 0 at both clamps.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import cast

import numpy as np

from .network import Network

__all__ = [
    "centre_mean",
    "chain_neighbours",
    "crossing_gamma",
    "crossing_slip",
    "crossing_spring_angle",
    "midline_points",
    "midline_profile",
    "node_gamma",
    "save_state",
    "segment_gamma_deg",
    "yarn_polylines",
    "yarn_rotation",
    "zone_means",
]

log = logging.getLogger(__name__)


def crossing_slip(net: Network, u: np.ndarray) -> np.ndarray:
    """|u_a - u_b| [m] at each crossing."""
    a, b = net.crossings[:, 0], net.crossings[:, 1]
    return cast(np.ndarray, np.hypot(u[3 * a] - u[3 * b], u[3 * a + 1] - u[3 * b + 1]))


def chain_neighbours(net: Network) -> tuple[np.ndarray, np.ndarray]:
    """Previous and next node of every node along its yarn (-1 at the yarn ends)."""
    prev = -np.ones(net.n_nodes, int)
    nxt = -np.ones(net.n_nodes, int)
    for c in net.yarn_nodes:
        prev[c[1:]] = c[:-1]
        nxt[c[:-1]] = c[1:]
    return prev, nxt


def yarn_rotation(net: Network, u: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Rotation of the yarn at interior nodes [rad]: mean rigid rotation of the two adjacent chords.

    beta_e = atan2(d0 x d, d0 . d) for the chord d (reference d0) of each adjacent element.
    """
    prev, nxt = chain_neighbours(net)
    x = net.X + u.reshape(-1, 3)[:, :2]
    rot = np.zeros(len(nodes))
    for a, b in ((prev[nodes], nodes), (nodes, nxt[nodes])):
        d0, d = net.X[b] - net.X[a], x[b] - x[a]
        rot += 0.5 * np.arctan2(d0[:, 0] * d[:, 1] - d0[:, 1] * d[:, 0], np.sum(d0 * d, axis=1))
    return rot


def crossing_gamma(net: Network, u: np.ndarray) -> np.ndarray:
    """Gamma = r_2 - r_1 [rad] at each crossing, r_k the rotation of yarn k there (:func:`yarn_rotation`).

    The chords, not the nodal rotations, measure the yarn directions: with a bending stiffness
    small against K_phi the nodal rotations follow the crossing spring, not the yarn.
    """
    return cast(np.ndarray, (yarn_rotation(net, u, net.crossings[:, 1]) - yarn_rotation(net, u, net.crossings[:, 0])))


def crossing_spring_angle(net: Network, u: np.ndarray) -> np.ndarray:
    """theta_2 - theta_1 [rad]: the angle change seen by the rotational springs K_phi (nodal rotations)."""
    return cast(np.ndarray, u[3 * net.crossings[:, 1] + 2] - u[3 * net.crossings[:, 0] + 2])


def zone_means(net: Network, values: np.ndarray) -> dict[str, float]:
    """Mean of a per-crossing value over the zones A, B, C (nan for an empty zone)."""
    out = {}
    for i, z in enumerate("ABC"):
        sel = net.crossing_zone == i
        out[z] = float(values[sel].mean()) if np.any(sel) else math.nan
    return out


def centre_mean(net: Network, values: np.ndarray) -> float:
    """Mean of a per-crossing value over the crossings nearest the specimen centre (L/2, W/2)."""
    Xc = net.X[net.crossings[:, 0]]
    r = np.hypot(Xc[:, 0] - 0.5 * net.L, Xc[:, 1] - 0.5 * net.W)
    if not len(r):
        return math.nan
    return float(values[r <= r.min() * (1 + 1e-9) + 1e-12].mean())


def midline_points(net: Network, u: np.ndarray, family: int) -> tuple[np.ndarray, np.ndarray]:
    """(X, u_y) [m] where the beams of one family cross Y = W/2 in the reference configuration."""
    b = net.beams[net.beam_family == family]
    Ya, Yb = net.X[b[:, 0], 1], net.X[b[:, 1], 1]
    y = 0.5 * net.W
    hit = ((Ya - y) * (Yb - y) <= 0) & (Ya != Yb)
    b = b[hit]
    s = (y - net.X[b[:, 0], 1]) / (net.X[b[:, 1], 1] - net.X[b[:, 0], 1])
    X = net.X[b[:, 0], 0] + s * (net.X[b[:, 1], 0] - net.X[b[:, 0], 0])
    uy = u[3 * b[:, 0] + 1] + s * (u[3 * b[:, 1] + 1] - u[3 * b[:, 0] + 1])
    X, keep = np.unique(X, return_index=True)  # a yarn node exactly on the line is hit twice
    return X, uy[keep]


def midline_profile(net: Network, u: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """u_y on Y = W/2 at n_points equally spaced X in [0, L], averaged over the two families [m]."""
    Xg = np.linspace(0.0, net.L, n_points)
    curves = []
    for fam in (1, 2):
        X, uy = midline_points(net, u, fam)
        if len(X):
            curves.append(np.interp(Xg, np.concatenate([[0.0], X, [net.L]]), np.concatenate([[0.0], uy, [0.0]])))
    return Xg, np.mean(curves, axis=0) if curves else np.zeros_like(Xg)


def yarn_polylines(net: Network, u: np.ndarray) -> list[np.ndarray]:
    """Deformed polyline (n, 2) [m] of each yarn."""
    x = net.X + u.reshape(-1, 3)[:, :2]
    return [x[c] for c in net.yarn_nodes]


def node_gamma(net: Network, u: np.ndarray) -> np.ndarray:
    """Gamma interpolated along each yarn from its crossings to all its nodes [rad] (for plots)."""
    g = np.full(net.n_nodes, np.nan)
    gc = crossing_gamma(net, u)
    g[net.crossings[:, 0]] = gc
    g[net.crossings[:, 1]] = gc
    for chain in net.yarn_nodes:
        known = np.isfinite(g[chain])
        if known.any():
            idx = np.arange(len(chain))
            g[chain] = np.interp(idx, idx[known], g[chain][known])
    return cast(np.ndarray, np.nan_to_num(g))


def save_state(path: str | Path, net: Network, u: np.ndarray, u0: float) -> None:
    """Write a state as npz: reference nodes, displacements, yarn chains, crossings with slip and angle.

    Also what its picture needs (:func:`ngbet.figures.maps.yarn_state_figure`, drawn from the file
    alone): the beams (node pairs) with their family and shear angle, and the clamped nodes.
    """
    chains = list(net.yarn_nodes)
    ptr = np.concatenate([[0], np.cumsum([len(c) for c in chains])])
    gamma = crossing_gamma(net, u)
    np.savez_compressed(
        path,
        u0_mm=u0 * 1e3,
        X_mm=net.X * 1e3,
        u_mm=u.reshape(-1, 3)[:, :2] * 1e3,
        theta_rad=u.reshape(-1, 3)[:, 2],
        yarn_nodes=np.concatenate(chains),
        yarn_ptr=ptr,
        yarn_family=net.yarn_family,
        crossing_nodes=net.crossings,
        crossing_zone=net.crossing_zone,
        crossing_X_mm=net.X[net.crossings[:, 0]] * 1e3,
        crossing_slip_mm=crossing_slip(net, u) * 1e3,
        crossing_gamma_deg=np.degrees(gamma),
        crossing_spring_angle_deg=np.degrees(crossing_spring_angle(net, u)),
        crossing_angle_deg=180.0 - 2 * math.degrees(net.angle) + np.degrees(gamma),
        beams=net.beams,
        beam_family=net.beam_family,
        segment_gamma_deg=segment_gamma_deg(net, u),
        clamped_nodes=np.flatnonzero(net.node_end > 0),
    )


def segment_gamma_deg(net: Network, u: np.ndarray) -> np.ndarray:
    """The shear angle γ [°] of each beam segment: the mean of its two nodes'."""
    ang = np.degrees(node_gamma(net, u))
    return cast(np.ndarray, 0.5 * (ang[net.beams[:, 0]] + ang[net.beams[:, 1]]))
