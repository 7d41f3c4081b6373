"""Coordination mode (spec S4, reconstructed): the saturated tracking field of a leader (e = p - r)
and of a follower (e = p_i - p_j - delta, with the parent's commanded acceleration as
feed-forward). One robot, scalars in, tuple out (numba kernel).
"""

from __future__ import annotations

import math

from numba import njit


# implements: S4
@njit(cache=True, error_model='numpy', forceinline=True)
def tracking_field_k(ex, ey, rvx, rvy, rax, ray, pdx, pdy, alpha, v_cap):
    """S4 field V_d = ref_vel - Phi(e), V_d_dot = ref_acc - DPhi(e)(p_dot - ref_vel).

    Leader: e = p - r, ref = (r_dot, r_ddot). Follower: e = p_i - p_j - delta, ref = (p_dot_j,
    a_j).
    Returns (vdx, vdy, vddx, vddy).
    """
    q = alpha * alpha / (v_cap * v_cap)
    s = math.sqrt(1.0 + q * (ex * ex + ey * ey))
    g = alpha / s
    k = alpha * q / (s * s * s)
    rx = pdx - rvx
    ry = pdy - rvy
    proj = k * (ex * rx + ey * ry)
    return (rvx - g * ex, rvy - g * ey, rax - (g * rx - proj * ex), ray - (g * ry - proj * ey))
