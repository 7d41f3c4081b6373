"""Readable numpy reference of the sliding-mode law S3 (kernel:
core/control/smc.py): a test oracle compared with the compiled
kernels in test/ (issue 12: not in the package).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from oracle_dynamics import commanded_point_accel

from ament_formation.core.model.dynamics import PlantCoeffs
from ament_formation.core.params import ControlGains


@dataclass(frozen=True)
class SmcOutput:
    """Result of :func:`sliding_mode_torque` for N robots.

    ``torque_nm`` (N, 2) [left, right] after S3.6; ``sigma_mps`` (N, 2) S3.1; ``saturated`` (N,)
    True where S3.6 scaled the torque; ``accel_cmd_mps2`` (N, 2) the commanded (disturbance-free)
    point acceleration S1 (f2 + B2 u) + S1dot x2 of the torque actually applied.
    """

    torque_nm: np.ndarray
    sigma_mps: np.ndarray
    saturated: np.ndarray
    accel_cmd_mps2: np.ndarray


def sat(x: np.ndarray) -> np.ndarray:
    """Componentwise saturation min(1, max(-1, x)) (S1 notation: sat of x)."""
    return np.clip(x, -1.0, 1.0)


def switching_term(sigma: np.ndarray, gain_mps2, eps_mps: float) -> np.ndarray:
    """K sat(sigma/eps) (S3.5); ``eps_mps`` = 0 gives the pure K sign(sigma) of paper (8)."""
    if eps_mps > 0.0:
        return gain_mps2 * sat(sigma / eps_mps)
    return gain_mps2 * np.sign(sigma)


def saturate_torque(torque: np.ndarray, tau_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S3.6: tau <- tau * min(1, tau_max / max_k |tau_k|).

    Returns (torque (N, 2), saturated (N,)).
    """
    peak = np.max(np.abs(torque), axis=1)
    saturated = peak > tau_max
    scale = np.where(saturated, tau_max / np.where(saturated, peak, 1.0), 1.0)
    return torque * scale[:, None], saturated


def sliding_mode_torque_raw(
    state: np.ndarray,
    v_d: np.ndarray,
    v_d_dot: np.ndarray,
    k: PlantCoeffs,
    gain_mps2,
    eps_mps: float,
) -> SmcOutput:
    """S3.1, S3.2, S3.5, S3.6 with an explicit switching gain K (scalar or (2,) or (N, 2)) and eps.

    u = B2^-1 { S1^-1 [ V_d_dot - S1dot x2 - K sat(sigma/eps) ] - f2 }, all in closed form.
    """
    th = state[:, 2]
    v = state[:, 3]
    w = state[:, 4]
    c = np.cos(th)
    s = np.sin(th)
    d = k.d
    # S3.1: sigma = S1 x2 - V_d
    pdx = v * c - d * w * s
    pdy = v * s + d * w * c
    sigx = pdx - v_d[:, 0]
    sigy = pdy - v_d[:, 1]
    sigma = np.stack((sigx, sigy), axis=1)
    sw = switching_term(sigma, gain_mps2, eps_mps)
    # S2.2: S1dot x2
    s1dx = w * (-v * s - d * w * c)
    s1dy = w * (v * c - d * w * s)
    # desired point acceleration and x2dot = S1^-1 (...)
    ax = v_d_dot[:, 0] - s1dx - sw[:, 0]
    ay = v_d_dot[:, 1] - s1dy - sw[:, 1]
    vdot = c * ax + s * ay
    wdot = (-s * ax + c * ay) / d
    mcd = k.m_c * d
    qv = vdot - mcd / k.m_tilde * w * w
    qw = wdot + mcd / k.I_tilde * w * v
    # B2^-1 = (r/2) [[m~, -2 I~/a], [m~, 2 I~/a]]
    half_r = 0.5 * k.r
    lin = half_r * k.m_tilde * qv
    ang = half_r * 2.0 * k.I_tilde / k.a * qw
    torque = np.stack((lin - ang, lin + ang), axis=1)
    torque, saturated = saturate_torque(torque, k.tau_max)
    accel = commanded_point_accel(state, torque, k)
    return SmcOutput(torque, sigma, saturated, accel)


def sliding_mode_torque(
    state: np.ndarray, v_d: np.ndarray, v_d_dot: np.ndarray, k: PlantCoeffs, gains: ControlGains
) -> SmcOutput:
    """Sliding-mode wheel torques for the field (V_d, V_d_dot), each (N, 2)
    (S3.1, S3.2, S3.5, S3.6).

    ``state`` (N, 5); the gain is ``gains.switching_gain_mps2`` (K) and the layer
    ``gains.boundary_layer_mps`` (eps).
    """
    return sliding_mode_torque_raw(
        state, v_d, v_d_dot, k, gains.switching_gain_mps2, gains.boundary_layer_mps
    )


def switching_gain_for(
    reaching_rate_mps2: float,
    g1_bar_mps2: float,
    g2_bar_radps2: float,
    d_m: float,
    delta_a_bound_mps2: float = 0.0,
) -> float:
    """S3.3: K = lambda + sqrt(g1_bar^2 + d^2 g2_bar^2) + sup|Delta a| [m/s^2]."""
    return (
        reaching_rate_mps2 + float(np.hypot(g1_bar_mps2, d_m * g2_bar_radps2)) + delta_a_bound_mps2
    )


def reaching_time_bound(
    sigma0: np.ndarray, reaching_rate_mps2, eps_mps: float = 0.0
) -> np.ndarray:
    """S3.4: T_reach <= max_k (|sigma_k(t_s)| - eps)^+ / lambda_k [s].

    ``sigma0`` (N, 2) -> (N,).
    """
    excess = np.maximum(np.abs(sigma0) - eps_mps, 0.0)
    return np.max(excess / reaching_rate_mps2, axis=-1)
