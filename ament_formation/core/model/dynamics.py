"""Differential-drive robot dynamics with the CoM ahead of the axle (spec S2.1, S2.2).

Implements S2.2 as numba scalar kernels for ONE robot (the closed loop, the controller and the
twin call them): the state derivative (16)-(20) (:func:`state_derivative_k`), the RK4 step with
zero-order-hold torques (:func:`rk4_step_k`), the point velocity p_dot = S1(theta) x2
(:func:`point_velocity_k`, the one place it is written) and the commanded point acceleration
S1 (f2 + B2 u) + S1dot x2 (:func:`commanded_point_accel_k`); plus the plant coefficients and the
control-affine terms f2(x2), B2 and B2^-1 for vectorised callers (the controlled stop).
Plant coefficients go to the kernels as scalars in the order (mt, It, r, a, d, mc[, tau_max]) =
(m~ [kg], I~ [kg m^2], wheel radius [m], axle length [m], CoM offset d [m], platform mass [kg],
torque limit [N m]): the fields of :class:`PlantCoeffs`.

Conventions: N robots; ``state`` (N, 5) rows [x_m, y_m, theta_rad, v_mps, omega_radps] where (x, y)
is the controlled point p (CoM, distance d ahead of the axle midpoint); ``torque`` (N, 2) rows
[left, right] N m; ``disturbance`` (N, 2) rows [g1_mps2, g2_radps2]; world frame.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
import math
from typing import Callable, Sequence

from numba import njit
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


# ------------------------------------------------------------------------------- S2.2 kernels


# implements: S2
@njit(cache=True, error_model='numpy', forceinline=True)
def state_derivative_k(x, y, th, v, w, t1, t2, g1, g2, mt, It, r, a, d, mc):
    """Xdot of (16)-(20) for one robot -> (xdot, ydot, thdot, vdot, wdot)."""
    mcd = mc * d
    dx, dy = point_velocity_k(th, v, w, d)
    dv = mcd / mt * w * w + (t1 + t2) / (mt * r) + g1
    dw = -mcd / It * w * v + a / (2.0 * It * r) * (t2 - t1) + g2
    return dx, dy, w, dv, dw


# rows of the (7, N) plant coefficient array [m~, I~, r, a, d, m_c, tau_max] (PlantCoeffs stacked)
ROW_M_TILDE, ROW_I_TILDE, ROW_R, ROW_A, ROW_D, ROW_M_C, ROW_TAU_MAX = range(7)

RobotPlant = namedtuple('RobotPlant', ['m_tilde', 'I_tilde', 'r', 'a', 'd', 'm_c'])
RobotPlant.__doc__ = """One robot's plant coefficients as :func:`rk4_step_k` takes them (floats,
the fields of :class:`PlantCoeffs` for one robot without the torque limit)."""


@njit(cache=True, error_model='numpy', inline='always')
def robot_plant_k(coeffs, i):
    """:data:`RobotPlant` of robot column ``i`` of the (7, N) coefficient rows
    [m~, I~, r, a, d, m_c, tau_max] (the torque limit, row 6, is not part of it).
    """
    return RobotPlant(
        coeffs[ROW_M_TILDE, i],
        coeffs[ROW_I_TILDE, i],
        coeffs[ROW_R, i],
        coeffs[ROW_A, i],
        coeffs[ROW_D, i],
        coeffs[ROW_M_C, i],
    )


@njit(cache=True, error_model='numpy', forceinline=True)
def rk4_step_k(s, tau, g0, gh, g1, dt, p):
    """One RK4 step of one robot with ZOH torque: state ``s`` (x, y, theta, v, omega), torque
    ``tau`` (left, right), the disturbance g (g1, g2) at t (``g0``), t + dt/2 (``gh``) and t + dt
    (``g1``), coefficients ``p`` (:data:`RobotPlant`) -> the new state (5-tuple).
    """
    h = 0.5 * dt
    mt, It, r, a, d, mc = p.m_tilde, p.I_tilde, p.r, p.a, p.d, p.m_c
    x, y, th, v, w = s[0], s[1], s[2], s[3], s[4]
    t1, t2 = tau[0], tau[1]
    k1 = state_derivative_k(x, y, th, v, w, t1, t2, g0[0], g0[1], mt, It, r, a, d, mc)
    k2 = state_derivative_k(
        x + h * k1[0],
        y + h * k1[1],
        th + h * k1[2],
        v + h * k1[3],
        w + h * k1[4],
        t1,
        t2,
        gh[0],
        gh[1],
        mt,
        It,
        r,
        a,
        d,
        mc,
    )
    k3 = state_derivative_k(
        x + h * k2[0],
        y + h * k2[1],
        th + h * k2[2],
        v + h * k2[3],
        w + h * k2[4],
        t1,
        t2,
        gh[0],
        gh[1],
        mt,
        It,
        r,
        a,
        d,
        mc,
    )
    k4 = state_derivative_k(
        x + dt * k3[0],
        y + dt * k3[1],
        th + dt * k3[2],
        v + dt * k3[3],
        w + dt * k3[4],
        t1,
        t2,
        g1[0],
        g1[1],
        mt,
        It,
        r,
        a,
        d,
        mc,
    )
    s6 = dt / 6.0
    return (
        x + s6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
        y + s6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
        th + s6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
        v + s6 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]),
        w + s6 * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]),
    )


@njit(cache=True, error_model='numpy')
def rk4_step_all(state, torque, g0, gh, g1, dt, mt, It, r, a, d, mc, out):
    """rk4_step_k over all rows: state (N, 5), torque/g0/gh/g1 (N, 2), coefficient arrays (N,);
    writes the new state into ``out`` (N, 5) (may be ``state`` itself).
    """
    for i in range(state.shape[0]):
        nx = rk4_step_k(
            (state[i, 0], state[i, 1], state[i, 2], state[i, 3], state[i, 4]),
            (torque[i, 0], torque[i, 1]),
            (g0[i, 0], g0[i, 1]),
            (gh[i, 0], gh[i, 1]),
            (g1[i, 0], g1[i, 1]),
            dt,
            RobotPlant(mt[i], It[i], r[i], a[i], d[i], mc[i]),
        )
        for j in range(5):
            out[i, j] = nx[j]
    return out


@njit(cache=True, error_model='numpy', forceinline=True)
def point_velocity_k(th, v, w, d):
    """p_dot = S1(theta) x2, (16)-(17) -> (px_dot, py_dot)."""
    c = math.cos(th)
    s = math.sin(th)
    return v * c - d * w * s, v * s + d * w * c


@njit(cache=True, error_model='numpy')
def commanded_point_accel_k(th, v, w, t1, t2, mt, It, r, a, d, mc):
    """A = S1 (f2 + B2 u) + S1dot x2 (disturbance-free) -> (ax, ay)."""
    c = math.cos(th)
    s = math.sin(th)
    mcd = mc * d
    vdot = mcd / mt * w * w + (t1 + t2) / (mt * r)
    wdot = -mcd / It * w * v + a / (2.0 * It * r) * (t2 - t1)
    ax = c * vdot - d * s * wdot + w * (-v * s - d * w * c)
    ay = s * vdot + d * c * wdot + w * (v * c - d * w * s)
    return ax, ay


@njit(cache=True, error_model='numpy')
def point_velocities(state, d):
    """p_dot of every row: state (N, 5), d (N,) CoM offsets [m] -> (N, 2) [m/s]
    (:func:`point_velocity_k` row by row).
    """
    out = np.empty((state.shape[0], 2))
    for i in range(state.shape[0]):
        out[i, 0], out[i, 1] = point_velocity_k(state[i, 2], state[i, 3], state[i, 4], d[i])
    return out
