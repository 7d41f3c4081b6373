"""Elliptical limit-cycle field (spec S6, paper (15), (21)-(30), corrected per S11).

* S6.3 field F = H - C~ z h and S6.4 its closed-form total derivative along the measured relative
  motion, moving and rotating obstacles included (:func:`ellipse_field_k`);
* S6.5 gain design psi_dot_max, c_max (:func:`design_gains`), the beta(t) schedule
  (:func:`gain_schedule_k`) and the parking factor mu (:func:`parking_factor_k`);
* S6.6 rotation-direction rules 1-4 and 7 (:func:`choose_direction`; rules 5-6 are the caller's).

Scalar numba kernels for ONE robot; z, z_dot relative to the obstacle centre [m, m/s]. The ellipse
function h and the ray/segment tests are :mod:`ament_formation.core.model.ellipse`.
"""

from __future__ import annotations

import math

from numba import njit

from ament_formation.core.model.ellipse import ellipse_coords

TWO_PI = 2.0 * math.pi


# implements: S6
@njit(cache=True, error_model='numpy', forceinline=True)
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


@njit(cache=True, error_model='numpy', forceinline=True)
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


@njit(cache=True, error_model='numpy', forceinline=True)
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


@njit(cache=True, error_model='numpy', forceinline=True)
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


@njit(cache=True, error_model='numpy', forceinline=True)
def anomaly(zx, zy, phi, r1, r2):
    """Eccentric anomaly psi = atan2(w/R2, u/R1) of z on the ellipse (S6.5)."""
    u, w = ellipse_coords(zx, zy, phi, r1, r2)
    return math.atan2(w, u)


@njit(cache=True, error_model='numpy', forceinline=True)
def arc_length(psi0, dpsi, r1, r2):
    """Length of the ellipse arc from anomaly psi0 over dpsi >= 0 (midpoint rule, 64 nodes)."""
    n = 64
    h = dpsi / n
    total = 0.0
    for k in range(n):
        p = psi0 + (k + 0.5) * h
        sp = math.sin(p)
        cp = math.cos(p)
        total += math.sqrt(r1 * r1 * sp * sp + r2 * r2 * cp * cp)
    return total * h


# implements: S6.6
@njit(cache=True, error_model='numpy', forceinline=True)
def choose_direction(
    zx, zy, zdx, zdy, gx, gy, gdx, gdy, phi, big_r1, big_r2, look_ahead_m, velocity_tiebreak
):
    """Rotation sense s (+1 CCW, -1 CW) at entry, S6.6 rules 1-4 and 7.

    z, z_dot: robot relative to the target centre; g, g_dot: goal relative to the centre and its
    velocity relative to the centre's velocity; (big_r1, big_r2) = L. ``look_ahead_m`` = 2 kappa r1
    (rule 1). Ties (rule 3 margin 10 % of the perimeter) go to sign((M z).z_dot) when
    ``velocity_tiebreak`` (rule 4, obstacles) and to +1 otherwise (rule 7, yielding to a robot).
    """
    n = math.hypot(gdx, gdy)
    if n > 1e-9:
        gx += look_ahead_m * gdx / n
        gy += look_ahead_m * gdy / n
    psi_a = anomaly(zx, zy, phi, big_r1, big_r2)
    psi_g = anomaly(gx, gy, phi, big_r1, big_r2)
    dpsi = (psi_g - psi_a) % (2.0 * math.pi)
    l_plus = arc_length(psi_a, dpsi, big_r1, big_r2)
    perim = arc_length(0.0, 2.0 * math.pi, big_r1, big_r2)
    l_minus = perim - l_plus
    if l_plus < l_minus - 0.1 * perim:
        return 1.0
    if l_minus < l_plus - 0.1 * perim:
        return -1.0
    if not velocity_tiebreak:
        return 1.0
    c = math.cos(phi)
    s = math.sin(phi)
    a2 = big_r1 * big_r1
    b2 = big_r2 * big_r2
    h1 = (a2 - b2) * s * c
    h2 = a2 * c * c + b2 * s * s
    h3 = a2 * s * s + b2 * c * c
    mx = h1 * zx - h2 * zy
    my = h3 * zx - h1 * zy
    return 1.0 if mx * zdx + my * zdy >= 0.0 else -1.0


# implements: S6.5
@njit(cache=True, error_model='numpy', forceinline=True)
def design_gains(r1, r2, v_tan, prm):
    """S6.5 design: psi_dot_max = v_tan / sqrt(R1 R2), c_max = v_rad / (kappa sqrt(r1 r2) h_Q)."""
    rho_l = prm.limit_cycle_scale
    kappa = prm.protected_scale
    big = rho_l * math.sqrt(r1 * r2)
    h_q = (kappa / rho_l) ** 2 - 1.0
    return v_tan / big, prm.radial_speed_mps / (kappa * math.sqrt(r1 * r2) * h_q)
