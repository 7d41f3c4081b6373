"""Readable numpy reference of the formation field S4 (kernel:
core/control/formation.py): a test oracle compared with the compiled
kernels in test/ (issue 12: not in the package).
"""

from __future__ import annotations

import numpy as np

from ament_formation.core.params import ControlGains


def _phi_terms(e: np.ndarray, alpha, v_cap):
    """Components of e, q = alpha^2 / v_cap^2 and s = sqrt(1 + q |e|^2) of S4's Phi."""
    e = np.asarray(e, dtype=float)
    ex = e[..., 0]
    ey = e[..., 1]
    q = alpha * alpha / (v_cap * v_cap)
    return ex, ey, q, np.sqrt(1.0 + q * (ex * ex + ey * ey))


def phi(e: np.ndarray, alpha, v_cap) -> np.ndarray:
    """S4: Phi(e) = alpha e / sqrt(1 + alpha^2 |e|^2 / v_cap^2), |Phi| < v_cap.
    (N, 2) -> (N, 2).
    """
    ex, ey, _q, s = _phi_terms(e, alpha, v_cap)
    g = alpha / s
    return np.stack((g * ex, g * ey), axis=-1)


def dphi(e: np.ndarray, alpha, v_cap) -> np.ndarray:
    """S4: DPhi(e) = (alpha/s) I - (alpha^3/(v_cap^2 s^3)) e e^T. (N, 2) -> (N, 2, 2)."""
    ex, ey, q, s = _phi_terms(e, alpha, v_cap)
    g = alpha / s
    k = alpha * q / (s * s * s)
    return np.stack(
        (
            np.stack((g - k * ex * ex, -k * ex * ey), -1),
            np.stack((-k * ex * ey, g - k * ey * ey), -1),
        ),
        axis=-2,
    )


def tracking_field(e, ref_vel, ref_acc, p_dot, alpha, v_cap):
    """Generic S4 field: V_d = ref_vel - Phi(e), V_d_dot = ref_acc - DPhi(e) (p_dot - ref_vel).

    All inputs (N, 2) (alpha, v_cap scalars or (N,)). Returns (v_d (N, 2), v_d_dot (N, 2)).
    """
    e = np.asarray(e, dtype=float)
    ex = e[..., 0]
    ey = e[..., 1]
    q = alpha * alpha / (v_cap * v_cap)
    s = np.sqrt(1.0 + q * (ex * ex + ey * ey))
    g = alpha / s
    k = alpha * q / (s * s * s)
    rx = p_dot[..., 0] - ref_vel[..., 0]
    ry = p_dot[..., 1] - ref_vel[..., 1]
    proj = k * (ex * rx + ey * ry)
    v_d = np.stack((ref_vel[..., 0] - g * ex, ref_vel[..., 1] - g * ey), axis=-1)
    v_d_dot = np.stack(
        (ref_acc[..., 0] - (g * rx - proj * ex), ref_acc[..., 1] - (g * ry - proj * ey)), axis=-1
    )
    return v_d, v_d_dot


def leader_field(p, p_dot, r, r_dot, r_ddot, gains: ControlGains):
    """S4 leader: e = p - r, V_d = r_dot - Phi(e), V_d_dot = r_ddot - DPhi(e)(p_dot - r_dot)."""
    e = np.asarray(p, dtype=float) - r
    return tracking_field(
        e,
        np.asarray(r_dot, dtype=float),
        np.asarray(r_ddot, dtype=float),
        np.asarray(p_dot, dtype=float),
        gains.formation_gain_per_s,
        gains.formation_speed_cap_mps,
    )


def follower_field(p_i, p_dot_i, p_j, p_dot_j, a_j, delta, gains: ControlGains):
    """S4 follower of parent j: e = p_i - p_j - delta_ij, V_d = p_dot_j - Phi(e),
    V_d_dot = a_j - DPhi(e)(p_dot_i - p_dot_j), with a_j j's broadcast commanded acceleration.
    """
    e = np.asarray(p_i, dtype=float) - p_j - delta
    return tracking_field(
        e,
        np.asarray(p_dot_j, dtype=float),
        np.asarray(a_j, dtype=float),
        np.asarray(p_dot_i, dtype=float),
        gains.formation_gain_per_s,
        gains.formation_speed_cap_mps,
    )
