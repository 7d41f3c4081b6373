"""Readable numpy reference of S2.2 (vectorised dynamics, S1(theta),
RK4; kernels in core/model/dynamics.py): a test oracle compared with the compiled
kernels in test/ (issue 12: not in the package).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ament_formation.core.model.dynamics import PlantCoeffs

DisturbanceFn = Callable[[float], np.ndarray]


def s1(theta: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Output map S1(theta) = [[cos, -d sin], [sin, d cos]] (23). Returns (N, 2, 2)."""
    c = np.cos(theta)
    s = np.sin(theta)
    d = np.broadcast_to(d, c.shape)
    return np.stack((np.stack((c, -d * s), -1), np.stack((s, d * c), -1)), axis=-2)


def s1_inv(theta: np.ndarray, d: np.ndarray) -> np.ndarray:
    """S1^-1 = [[cos, sin], [-sin/d, cos/d]] (S2.2; det S1 = d > 0). Returns (N, 2, 2)."""
    c = np.cos(theta)
    s = np.sin(theta)
    d = np.broadcast_to(d, c.shape)
    return np.stack((np.stack((c, s), -1), np.stack((-s / d, c / d), -1)), axis=-2)


def s1dot_x2(state: np.ndarray, d: np.ndarray) -> np.ndarray:
    """S1dot x2 = w [-v sin - d w cos, v cos - d w sin] (S2.2). Returns (N, 2) [m/s^2]."""
    th = state[:, 2]
    v = state[:, 3]
    w = state[:, 4]
    c = np.cos(th)
    s = np.sin(th)
    return np.stack((w * (-v * s - d * w * c), w * (v * c - d * w * s)), axis=1)


def point_velocity(state: np.ndarray, d: np.ndarray) -> np.ndarray:
    """p_dot = S1(theta) x2, eqs. (16)-(17). Returns (N, 2) [m/s]."""
    th = state[:, 2]
    v = state[:, 3]
    w = state[:, 4]
    c = np.cos(th)
    s = np.sin(th)
    return np.stack((v * c - d * w * s, v * s + d * w * c), axis=1)


def _x2dot(state: np.ndarray, torque: np.ndarray, k: PlantCoeffs) -> np.ndarray:
    """f2 + B2 u (disturbance-free), (19)-(20). Returns (N, 2)."""
    v = state[:, 3]
    w = state[:, 4]
    mcd = k.m_c * k.d
    t1 = torque[:, 0]
    t2 = torque[:, 1]
    vdot = mcd / k.m_tilde * w * w + (t1 + t2) / (k.m_tilde * k.r)
    wdot = -mcd / k.I_tilde * w * v + k.a / (2.0 * k.I_tilde * k.r) * (t2 - t1)
    return np.stack((vdot, wdot), axis=1)


def _s1_apply(theta: np.ndarray, d: np.ndarray, vec: np.ndarray) -> np.ndarray:
    c = np.cos(theta)
    s = np.sin(theta)
    return np.stack((c * vec[:, 0] - d * s * vec[:, 1], s * vec[:, 0] + d * c * vec[:, 1]), axis=1)


def commanded_point_accel(state: np.ndarray, torque: np.ndarray, k: PlantCoeffs) -> np.ndarray:
    """Disturbance-free point acceleration a = S1 (f2 + B2 u) + S1dot x2
    (S2.2; a_j of S4). (N, 2).
    """
    return _s1_apply(state[:, 2], k.d, _x2dot(state, torque, k)) + s1dot_x2(state, k.d)


def point_accel(
    state: np.ndarray, torque: np.ndarray, disturbance: np.ndarray | None, k: PlantCoeffs
) -> np.ndarray:
    """True point acceleration p_ddot = S1 (f2 + B2 u + g) + S1dot x2 (S2.2). Returns (N, 2)."""
    x2dot = _x2dot(state, torque, k)
    if disturbance is not None:
        x2dot = x2dot + disturbance
    return _s1_apply(state[:, 2], k.d, x2dot) + s1dot_x2(state, k.d)


def state_derivative(
    state: np.ndarray, torque: np.ndarray, disturbance: np.ndarray | None, k: PlantCoeffs
) -> np.ndarray:
    """Xdot of (16)-(20) for every robot. ``disturbance`` (N, 2) or None (= 0). Returns (N, 5)."""
    th = state[:, 2]
    v = state[:, 3]
    w = state[:, 4]
    c = np.cos(th)
    s = np.sin(th)
    d = k.d
    mcd = k.m_c * d
    t1 = torque[:, 0]
    t2 = torque[:, 1]
    out = np.empty(state.shape)
    out[:, 0] = v * c - d * w * s  # (16)
    out[:, 1] = v * s + d * w * c  # (17)
    out[:, 2] = w  # (18)
    out[:, 3] = mcd / k.m_tilde * w * w + (t1 + t2) / (k.m_tilde * k.r)  # (19)
    out[:, 4] = -mcd / k.I_tilde * w * v + k.a / (2.0 * k.I_tilde * k.r) * (t2 - t1)  # (20)
    if disturbance is not None:
        out[:, 3] += disturbance[:, 0]
        out[:, 4] += disturbance[:, 1]
    return out


def rk4_step(
    state: np.ndarray,
    torque: np.ndarray,
    disturbance_fn: DisturbanceFn | None,
    t_s: float,
    dt_s: float,
    k: PlantCoeffs,
) -> np.ndarray:
    """One classical RK4 step of length ``dt_s`` with the torque held constant (ZOH).

    ``disturbance_fn(t_s) -> (N, 2)`` is evaluated at t, t + dt/2 (once, shared by the two
    midpoint stages) and t + dt; None means no disturbance. Returns the new (N, 5) state.
    """
    if disturbance_fn is None:
        g0 = gh = g1 = None
    else:
        g0 = disturbance_fn(t_s)
        gh = disturbance_fn(t_s + 0.5 * dt_s)
        g1 = disturbance_fn(t_s + dt_s)
    k1 = state_derivative(state, torque, g0, k)
    k2 = state_derivative(state + (0.5 * dt_s) * k1, torque, gh, k)
    k3 = state_derivative(state + (0.5 * dt_s) * k2, torque, gh, k)
    k4 = state_derivative(state + dt_s * k3, torque, g1, k)
    return state + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
