"""The generic sliding-mode law used in every mode (spec S3): sigma = p_dot - V_d (S3.1), the
torque of S3.2 with the boundary layer sat(sigma/eps) (S3.5; eps = 0: sign) and the uniform torque
scaling at the limit (S3.6). One robot, scalars in, tuple out (numba kernel).
"""

from __future__ import annotations

import math

from numba import njit

from ament_formation.core.model.dynamics import commanded_point_accel_k, point_velocity_k


@njit(cache=True, error_model='numpy', forceinline=True)
def _switch(sig, gain, eps):
    if eps > 0.0:
        q = sig / eps
        if q > 1.0:
            q = 1.0
        elif q < -1.0:
            q = -1.0
        return gain * q
    if sig > 0.0:
        return gain
    if sig < 0.0:
        return -gain
    return 0.0


# implements: S3, S5
@njit(cache=True, error_model='numpy', forceinline=True)
def smc_torque_k(th, v, w, vdx, vdy, vddx, vddy, plant, tau_max, k1, k2, eps):
    """S3.1, S3.2 with sat(sigma/eps) (S3.5, eps = 0: sign) and uniform scaling (S3.6).

    State (th [rad], v [m/s], w [rad/s]); V_d (vdx, vdy) [m/s] and V_d_dot (vddx, vddy) [m/s^2];
    ``plant`` the robot's :data:`~ament_formation.core.model.dynamics.RobotPlant`, ``tau_max``
    its torque limit [N m]; (k1, k2) switching gains per component [m/s^2]; eps the boundary
    layer [m/s]. Returns
    (tau_left, tau_right, sigma_x, sigma_y, saturated, accel_cmd_x, accel_cmd_y).
    """
    mt, It, r, a, d, mc = plant
    c = math.cos(th)
    s = math.sin(th)
    pdx, pdy = point_velocity_k(th, v, w, d)
    sx = pdx - vdx
    sy = pdy - vdy
    swx = _switch(sx, k1, eps)
    swy = _switch(sy, k2, eps)
    s1dx = w * (-v * s - d * w * c)
    s1dy = w * (v * c - d * w * s)
    ax = vddx - s1dx - swx
    ay = vddy - s1dy - swy
    vdot = c * ax + s * ay
    wdot = (-s * ax + c * ay) / d
    mcd = mc * d
    qv = vdot - mcd / mt * w * w
    qw = wdot + mcd / It * w * v
    half_r = 0.5 * r
    lin = half_r * mt * qv
    ang = half_r * 2.0 * It / a * qw
    t1 = lin - ang
    t2 = lin + ang
    peak = max(abs(t1), abs(t2))
    saturated = peak > tau_max
    if saturated:
        scale = tau_max / peak
        t1 = t1 * scale
        t2 = t2 * scale
    acx, acy = commanded_point_accel_k(th, v, w, t1, t2, mt, It, r, a, d, mc)
    return t1, t2, sx, sy, saturated, acx, acy
