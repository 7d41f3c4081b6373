"""Differential-drive robot dynamics with the CoM ahead of the axle (spec S2.1, S2.2).

Implements S2.2: the kinematics (16)-(18), the dynamics (19)-(20) in control-affine form
x2dot = f2(x2) + B2 u + g, the output map S1(theta) (23) with its inverse and S1dot x2, the point
acceleration p_ddot = S1 (f2 + B2 u + g) + S1dot x2, and a vectorised RK4 step with zero-order-hold
torques. Numba scalar twins of the hot path live in :mod:`ament_formation.core.control.kernels`.

Conventions: N robots; ``state`` (N, 5) rows [x_m, y_m, theta_rad, v_mps, omega_radps] where (x, y)
is the controlled point p (CoM, distance d ahead of the axle midpoint); ``torque`` (N, 2) rows
[left, right] N m; ``disturbance`` (N, 2) rows [g1_mps2, g2_radps2]; world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import RobotParams

DisturbanceFn = Callable[[float], np.ndarray]


@dataclass(frozen=True)
class PlantCoeffs:
    """Per-robot plant coefficients, each an (N,) float array (S2.2, S2.3).

    Attributes: ``m_tilde`` [kg], ``I_tilde`` [kg m^2], ``r`` wheel radius [m], ``a`` axle length
    [m], ``d`` CoM offset [m], ``m_c`` platform mass [kg], ``tau_max`` per-wheel torque limit [N
    m].
    """

    m_tilde: np.ndarray
    I_tilde: np.ndarray
    r: np.ndarray
    a: np.ndarray
    d: np.ndarray
    m_c: np.ndarray
    tau_max: np.ndarray

    def __post_init__(self) -> None:
        n = None
        for name in ('m_tilde', 'I_tilde', 'r', 'a', 'd', 'm_c', 'tau_max'):
            value = np.ascontiguousarray(np.asarray(getattr(self, name), dtype=float))
            if value.ndim != 1:
                raise ConfigError(f'must be a 1-D array (got shape {value.shape})', name)
            if n is None:
                n = value.shape[0]
            elif value.shape[0] != n:
                raise ConfigError(
                    f'must have {n} entries like m_tilde (got {value.shape[0]})', name
                )
            if not (np.all(np.isfinite(value)) and np.all(value > 0)):
                raise ConfigError('must be finite and > 0', name)
            object.__setattr__(self, name, value)

    @property
    def n(self) -> int:
        """Number of robots N."""
        return int(self.m_tilde.shape[0])

    @classmethod
    def from_params(cls, params: Sequence[RobotParams]) -> 'PlantCoeffs':
        """Coefficients of robots ``params`` (length N), m~ and I~ derived as in S2.2."""
        params = list(params)
        return cls(
            m_tilde=np.array([p.mass_tilde_kg for p in params], dtype=float),
            I_tilde=np.array([p.inertia_tilde_kgm2 for p in params], dtype=float),
            r=np.array([p.wheel_radius_m for p in params], dtype=float),
            a=np.array([p.axle_length_m for p in params], dtype=float),
            d=np.array([p.com_offset_m for p in params], dtype=float),
            m_c=np.array([p.platform_mass_kg for p in params], dtype=float),
            tau_max=np.array([p.torque_limit_nm for p in params], dtype=float),
        )

    def take(self, index) -> 'PlantCoeffs':
        """The coefficients of the robots selected by ``index`` (int array, slice or mask)."""
        return PlantCoeffs(
            *(
                np.atleast_1d(getattr(self, f)[index])
                for f in ('m_tilde', 'I_tilde', 'r', 'a', 'd', 'm_c', 'tau_max')
            )
        )


def f2(state: np.ndarray, k: PlantCoeffs) -> np.ndarray:
    """Drift f2 at x2: [(m_c d/m~) w^2, -(m_c d/I~) w v] (S2.2). Returns (N, 2)."""
    v = state[:, 3]
    w = state[:, 4]
    mcd = k.m_c * k.d
    return np.stack((mcd / k.m_tilde * w * w, -mcd / k.I_tilde * w * v), axis=1)


def b2(k: PlantCoeffs) -> np.ndarray:
    """Input matrix B2 = [[1/(m~ r), 1/(m~ r)], [-a/(2 I~ r), a/(2 I~ r)]] (S2.2).
    Returns (N, 2, 2).
    """
    lin = 1.0 / (k.m_tilde * k.r)
    ang = k.a / (2.0 * k.I_tilde * k.r)
    out = np.empty((k.n, 2, 2))
    out[:, 0, 0] = lin
    out[:, 0, 1] = lin
    out[:, 1, 0] = -ang
    out[:, 1, 1] = ang
    return out


def b2_inv(k: PlantCoeffs) -> np.ndarray:
    """B2^-1 = (r/2) [[m~, -2 I~/a], [m~, 2 I~/a]] (S2.2). Returns (N, 2, 2)."""
    half_r = 0.5 * k.r
    out = np.empty((k.n, 2, 2))
    out[:, 0, 0] = half_r * k.m_tilde
    out[:, 0, 1] = -half_r * 2.0 * k.I_tilde / k.a
    out[:, 1, 0] = half_r * k.m_tilde
    out[:, 1, 1] = half_r * 2.0 * k.I_tilde / k.a
    return out


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
