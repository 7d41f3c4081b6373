"""Numba scalar kernels of the closed-loop hot path (twins of the numpy API, same spec labels).

Each ``*_k`` function takes scalars (and small arrays where stated) of ONE robot and returns a
tuple, so a compiled per-step loop over robots (the simulator) can call them without allocating.
They mirror, operation for operation, the vectorised numpy functions:

| kernel | numpy twin | spec |
|---|---|---|
| state_derivative_k | dynamics.state_derivative | S2.2 |
| rk4_step_k, rk4_step_all | dynamics.rk4_step | S2.2 |
| point_velocity_k | dynamics.point_velocity | S2.2 |
| commanded_point_accel_k | dynamics.commanded_point_accel | S2.2 |
| disturbance_k, disturbance_phasor_*_k | disturbance.Disturbance.__call__ | S2.3 |
| smc_torque_k | smc.sliding_mode_torque_raw | S3.1, S3.2, S3.5, S3.6 |
| tracking_field_k | formation.tracking_field (leader/follower) | S4 |
| ellipse_h_k, ellipse_field_k | limit_cycle.ellipse_h, limit_cycle.field | S6.2-S6.4 |
| gain_schedule_k | limit_cycle.gain_schedule | S6.5 |
| parking_factor_k | limit_cycle.parking_factor | S6.5 |
| ray_hits_ellipse_k | limit_cycle.ray_hits_ellipse | S8.1 |
| segment_hits_ellipse_k | limit_cycle.segment_hits_ellipse | S8.3 |

Plant coefficients are passed as scalars in the order (mt, It, r, a, d, mc[, tau_max]) =
(m~ [kg], I~ [kg m^2], wheel radius [m], axle length [m], CoM offset d [m], platform mass [kg],
torque limit [N m]): the fields of :class:`ament_formation.core.model.dynamics.PlantCoeffs`.
All kernels are ``@njit(cache=True, fastmath=False)``.
"""

from __future__ import annotations

import math

from numba import njit

_JIT = {'cache': True, 'fastmath': False}
TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------------------------- S2.2


@njit(**_JIT)
def state_derivative_k(x, y, th, v, w, t1, t2, g1, g2, mt, It, r, a, d, mc):
    """Xdot of (16)-(20) for one robot -> (xdot, ydot, thdot, vdot, wdot)."""
    c = math.cos(th)
    s = math.sin(th)
    mcd = mc * d
    dx = v * c - d * w * s
    dy = v * s + d * w * c
    dv = mcd / mt * w * w + (t1 + t2) / (mt * r) + g1
    dw = -mcd / It * w * v + a / (2.0 * It * r) * (t2 - t1) + g2
    return dx, dy, w, dv, dw


@njit(**_JIT)
def rk4_step_k(x, y, th, v, w, t1, t2, g0a, g0b, gha, ghb, g1a, g1b, dt, mt, It, r, a, d, mc):
    """One RK4 step with ZOH torque; g0 at t, gh at t + dt/2, g1 at t + dt. -> new 5-tuple
    state.
    """
    h = 0.5 * dt
    k1 = state_derivative_k(x, y, th, v, w, t1, t2, g0a, g0b, mt, It, r, a, d, mc)
    k2 = state_derivative_k(
        x + h * k1[0],
        y + h * k1[1],
        th + h * k1[2],
        v + h * k1[3],
        w + h * k1[4],
        t1,
        t2,
        gha,
        ghb,
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
        gha,
        ghb,
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
        g1a,
        g1b,
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


@njit(**_JIT)
def rk4_step_all(state, torque, g0, gh, g1, dt, mt, It, r, a, d, mc, out):
    """rk4_step_k over all rows: state (N, 5), torque/g0/gh/g1 (N, 2), coefficient arrays (N,);
    writes the new state into ``out`` (N, 5) (may be ``state`` itself).
    """
    for i in range(state.shape[0]):
        nx = rk4_step_k(
            state[i, 0],
            state[i, 1],
            state[i, 2],
            state[i, 3],
            state[i, 4],
            torque[i, 0],
            torque[i, 1],
            g0[i, 0],
            g0[i, 1],
            gh[i, 0],
            gh[i, 1],
            g1[i, 0],
            g1[i, 1],
            dt,
            mt[i],
            It[i],
            r[i],
            a[i],
            d[i],
            mc[i],
        )
        for j in range(5):
            out[i, j] = nx[j]
    return out


@njit(**_JIT)
def point_velocity_k(th, v, w, d):
    """p_dot = S1(theta) x2, (16)-(17) -> (px_dot, py_dot)."""
    c = math.cos(th)
    s = math.sin(th)
    return v * c - d * w * s, v * s + d * w * c


@njit(**_JIT)
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


# ---------------------------------------------------------------------------------------- S2.3


@njit(**_JIT)
def disturbance_k(t, amp, freq, phase):
    """g(t) = sum_m A sin(2 pi f t + phi) for one robot; amp/freq/phase (2, M) -> (g1, g2)."""
    g1 = 0.0
    g2 = 0.0
    for m in range(amp.shape[1]):
        g1 += amp[0, m] * math.sin(2.0 * math.pi * freq[0, m] * t + phase[0, m])
        g2 += amp[1, m] * math.sin(2.0 * math.pi * freq[1, m] * t + phase[1, m])
    return g1, g2


@njit(**_JIT)
def disturbance_phasor_init_k(t, freq, phase, sin_out, cos_out):
    """Start the phasors of one robot at time t:
    sin_out/cos_out (2, M) = sin/cos(2 pi f t + phi).
    """
    for k in range(2):
        for m in range(freq.shape[1]):
            arg = 2.0 * math.pi * freq[k, m] * t + phase[k, m]
            sin_out[k, m] = math.sin(arg)
            cos_out[k, m] = math.cos(arg)


@njit(**_JIT)
def disturbance_phasor_advance_k(amp, sin_st, cos_st, cos_step, sin_step):
    """Rotate the phasors of one robot by one step (angles 2 pi f h, from
    :meth:`Disturbance.step_rotation`) in place and return g (g1, g2) at the new time.

    No transcendental call per step: a closed loop with fixed dt evaluates g at t + dt/2 and t + dt
    by two half-step rotations (reusing g(t) of the previous step). Rounding drift is ~1e-16 per
    step relative to the bound; re-initialise with :func:`disturbance_phasor_init_k` now and then.
    """
    g1 = 0.0
    g2 = 0.0
    for m in range(amp.shape[1]):
        s0 = sin_st[0, m]
        c0 = cos_st[0, m]
        sn = s0 * cos_step[0, m] + c0 * sin_step[0, m]
        cn = c0 * cos_step[0, m] - s0 * sin_step[0, m]
        sin_st[0, m] = sn
        cos_st[0, m] = cn
        g1 += amp[0, m] * sn
        s0 = sin_st[1, m]
        c0 = cos_st[1, m]
        sn = s0 * cos_step[1, m] + c0 * sin_step[1, m]
        cn = c0 * cos_step[1, m] - s0 * sin_step[1, m]
        sin_st[1, m] = sn
        cos_st[1, m] = cn
        g2 += amp[1, m] * sn
    return g1, g2


# ---------------------------------------------------------------------------------------- S3


@njit(**_JIT)
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


@njit(**_JIT)
def smc_torque_k(th, v, w, vdx, vdy, vddx, vddy, mt, It, r, a, d, mc, tau_max, k1, k2, eps):
    """S3.1, S3.2 with sat(sigma/eps) (S3.5, eps = 0: sign) and uniform scaling (S3.6).

    (k1, k2) switching gains per component [m/s^2]. Returns
    (tau_left, tau_right, sigma_x, sigma_y, saturated, accel_cmd_x, accel_cmd_y).
    """
    c = math.cos(th)
    s = math.sin(th)
    pdx = v * c - d * w * s
    pdy = v * s + d * w * c
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


# ---------------------------------------------------------------------------------------- S4


@njit(**_JIT)
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


# ---------------------------------------------------------------------------------------- S6


@njit(**_JIT)
def ellipse_h_k(zx, zy, phi, r1, r2):
    """S6.2: h = u^2/R1^2 + w^2/R2^2 - 1."""
    c = math.cos(phi)
    s = math.sin(phi)
    u = c * zx + s * zy
    w = -s * zx + c * zy
    return u * u / (r1 * r1) + w * w / (r2 * r2) - 1.0


@njit(**_JIT)
def ellipse_field_k(zx, zy, zdx, zdy, phi, phi_dot, phi_ddot, r1, r2, psi_dot, psi_ddot, c, c_dot):
    """S6.3 field and S6.4 closed-form derivative (c1 = c2 = c) -> (fx, fy, fdx, fdy, h, h_dot)."""
    cphi = math.cos(phi)
    sphi = math.sin(phi)
    a2 = r1 * r1
    b2 = r2 * r2
    dab = a2 - b2
    h1 = dab * sphi * cphi
    h2 = a2 * cphi * cphi + b2 * sphi * sphi
    h3 = a2 * sphi * sphi + b2 * cphi * cphi
    inv_ab = 1.0 / (r1 * r2)
    u = cphi * zx + sphi * zy
    w = -sphi * zx + cphi * zy
    h = u * u / a2 + w * w / b2 - 1.0
    ud = cphi * zdx + sphi * zdy + phi_dot * w
    wd = -sphi * zdx + cphi * zdy - phi_dot * u
    hd = 2.0 * u * ud / a2 + 2.0 * w * wd / b2
    mx = h1 * zx - h2 * zy
    my = h3 * zx - h1 * zy
    fx = -zy * phi_dot + psi_dot * inv_ab * mx - c * zx * h
    fy = zx * phi_dot + psi_dot * inv_ab * my - c * zy * h
    cos2 = cphi * cphi - sphi * sphi
    sin2 = 2.0 * sphi * cphi
    h1p = dab * cos2
    h2p = -dab * sin2
    h3p = dab * sin2
    mdx = phi_dot * (h1p * zx - h2p * zy) + h1 * zdx - h2 * zdy
    mdy = phi_dot * (h3p * zx - h1p * zy) + h3 * zdx - h1 * zdy
    fdx = (
        -zdy * phi_dot
        - zy * phi_ddot
        + (psi_ddot * mx + psi_dot * mdx) * inv_ab
        - (c_dot * zx * h + c * zdx * h + c * zx * hd)
    )
    fdy = (
        zdx * phi_dot
        + zx * phi_ddot
        + (psi_ddot * my + psi_dot * mdy) * inv_ab
        - (c_dot * zy * h + c * zdy * h + c * zy * hd)
    )
    return fx, fy, fdx, fdy, h, hd


@njit(**_JIT)
def gain_schedule_k(t_since_entry_s, psi_dot_max, c_max, direction, mu, mu_dot, beta0, tau_g_s):
    """S6.5 beta(t) schedule -> (psi_dot, psi_ddot, c, c_dot)."""
    t = t_since_entry_s if t_since_entry_s > 0.0 else 0.0
    decay = (1.0 - beta0) * math.exp(-t / tau_g_s)
    beta = 1.0 - decay
    beta_dot = decay / tau_g_s
    scale = direction * psi_dot_max
    return (
        scale * mu * beta,
        scale * (mu * beta_dot + mu_dot * beta),
        c_max * beta,
        c_max * beta_dot,
    )


@njit(**_JIT)
def _anomaly_and_rate(zx, zy, zdx, zdy, cphi, sphi, phi_dot, r1, r2):
    u = cphi * zx + sphi * zy
    w = -sphi * zx + cphi * zy
    ud = cphi * zdx + sphi * zdy + phi_dot * w
    wd = -sphi * zdx + cphi * zdy - phi_dot * u
    uu = u / r1
    ww = w / r2
    den = uu * uu + ww * ww
    rate = 0.0
    if den > 0.0:
        rate = (uu * (wd / r2) - ww * (ud / r1)) / den
    return math.atan2(ww, uu), rate


@njit(**_JIT)
def parking_factor_k(
    zx, zy, zdx, zdy, gx, gy, gdx, gdy, phi, phi_dot, r1, r2, direction, psi_slow
):
    """S6.5 parking factor: agent z, goal g (both relative to the centre) -> (mu, mu_dot)."""
    cphi = math.cos(phi)
    sphi = math.sin(phi)
    psi_a, rate_a = _anomaly_and_rate(zx, zy, zdx, zdy, cphi, sphi, phi_dot, r1, r2)
    psi_g, rate_g = _anomaly_and_rate(gx, gy, gdx, gdy, cphi, sphi, phi_dot, r1, r2)
    dd = ((direction * (psi_g - psi_a) + 0.5 * math.pi) % TWO_PI) - 0.5 * math.pi
    q = dd / psi_slow
    if q >= 1.0:
        return 1.0, 0.0
    if q <= -1.0:
        return -1.0, 0.0
    return q, direction * (rate_g - rate_a) / psi_slow


@njit(**_JIT)
def ray_hits_ellipse_k(zx, zy, zdx, zdy, phi, r1, r2):
    """Does the ray {z + lam z_dot, lam >= 0} meet the closed ellipse? -> (hit, lam_first).

    lam_first = 0 when z is already inside, +inf when there is no hit.
    """
    c = math.cos(phi)
    s = math.sin(phi)
    u = c * zx + s * zy
    w = -s * zx + c * zy
    du = c * zdx + s * zdy
    dw = -s * zdx + c * zdy
    ia = 1.0 / (r1 * r1)
    ib = 1.0 / (r2 * r2)
    c0 = u * u * ia + w * w * ib - 1.0
    if c0 <= 0.0:
        return True, 0.0
    qa = du * du * ia + dw * dw * ib
    qb = u * du * ia + w * dw * ib
    if qa <= 0.0 or qb >= 0.0:
        return False, math.inf
    disc = qb * qb - qa * c0
    if disc < 0.0:
        return False, math.inf
    # first root, cancellation-free: lam1 = c0 / (-qb + sqrt(disc))
    return True, c0 / (-qb + math.sqrt(disc))


@njit(**_JIT)
def segment_hits_ellipse_k(p0x, p0y, p1x, p1y, cx, cy, phi, r1, r2):
    """Does the segment [p0, p1] meet the closed ellipse centred at (cx, cy)?"""
    c = math.cos(phi)
    s = math.sin(phi)
    zx = p0x - cx
    zy = p0y - cy
    dx = p1x - p0x
    dy = p1y - p0y
    u = c * zx + s * zy
    w = -s * zx + c * zy
    du = c * dx + s * dy
    dw = -s * dx + c * dy
    ia = 1.0 / (r1 * r1)
    ib = 1.0 / (r2 * r2)
    c0 = u * u * ia + w * w * ib - 1.0
    qa = du * du * ia + dw * dw * ib
    qb = u * du * ia + w * dw * ib
    lam = 0.0
    if qa > 0.0:
        lam = -qb / qa
        if lam < 0.0:
            lam = 0.0
        elif lam > 1.0:
            lam = 1.0
    return qa * lam * lam + 2.0 * qb * lam + c0 <= 0.0
