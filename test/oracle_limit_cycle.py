"""Readable numpy reference of the limit-cycle field, gain design and
direction choice S6 (kernels: core/control/limit_cycle.py) and the ray/segment tests
(core/model/ellipse.py): a test oracle compared with the compiled
kernels in test/ (issue 12: not in the package).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import AvoidanceParams

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class FieldOutput:
    """S6.3/S6.4 for N agents: ``f`` (N, 2) [m/s], ``f_dot`` (N, 2) [m/s^2], ``h`` (N,),
    ``h_dot`` (N,) [1/s].
    """

    f: np.ndarray
    f_dot: np.ndarray
    h: np.ndarray
    h_dot: np.ndarray


# ----------------------------------------------------------------------------------------------
# S6.2 ellipse function
# ----------------------------------------------------------------------------------------------


def ellipse_coeffs(phi, r1, r2):
    """(h~1, h~2, h~3) of (27)-(29): h~1 = (R1^2-R2^2) sin cos, h~2 = R1^2 cos^2 + R2^2 sin^2,
    h~3 = R1^2 sin^2 + R2^2 cos^2. Each broadcast over the inputs.
    """
    c = np.cos(phi)
    s = np.sin(phi)
    a2 = np.multiply(r1, r1)
    b2 = np.multiply(r2, r2)
    return (a2 - b2) * s * c, a2 * c * c + b2 * s * s, a2 * s * s + b2 * c * c


def body_coords(z: np.ndarray, phi):
    """(u, w): z in the ellipse frame, u = cos z_x + sin z_y, w = -sin z_x + cos z_y (S6.2)."""
    c = np.cos(phi)
    s = np.sin(phi)
    return c * z[..., 0] + s * z[..., 1], -s * z[..., 0] + c * z[..., 1]


def ellipse_h(z: np.ndarray, phi, r1, r2) -> np.ndarray:
    """S6.2: h = u^2/R1^2 + w^2/R2^2 - 1 for z (N, 2) relative to the centre. Returns (N,)."""
    u, w = body_coords(z, phi)
    return u * u / np.multiply(r1, r1) + w * w / np.multiply(r2, r2) - 1.0


def ellipse_h_dot(z: np.ndarray, z_dot: np.ndarray, phi, phi_dot, r1, r2) -> np.ndarray:
    """S6.4: h_dot = 2 u u_dot/R1^2 + 2 w w_dot/R2^2 along the relative motion z_dot (N, 2)."""
    c = np.cos(phi)
    s = np.sin(phi)
    u = c * z[..., 0] + s * z[..., 1]
    w = -s * z[..., 0] + c * z[..., 1]
    ud = c * z_dot[..., 0] + s * z_dot[..., 1] + phi_dot * w
    wd = -s * z_dot[..., 0] + c * z_dot[..., 1] - phi_dot * u
    return 2.0 * u * ud / np.multiply(r1, r1) + 2.0 * w * wd / np.multiply(r2, r2)


# ----------------------------------------------------------------------------------------------
# S6.3 / S6.4 field and its closed-form derivative
# ----------------------------------------------------------------------------------------------


def field(z, z_dot, phi, phi_dot, phi_ddot, r1, r2, psi_dot, psi_ddot, c, c_dot) -> FieldOutput:
    """Limit-cycle field F (S6.3) and its total derivative F_dot (S6.4), c1 = c2 = c (S11.10).

    Parameters
    ----------
    z, z_dot : (N, 2) relative position p - x~ [m] and measured relative velocity [m/s].
    phi, phi_dot, phi_ddot : (N,) obstacle orientation [rad] and its rates.
    r1, r2 : (N,) semi-axes R1 >= R2 of the limit-cycle ellipse [m].
    psi_dot, psi_ddot : (N,) signed tangential rate s psi_dot [rad/s] and its derivative.
    c, c_dot : (N,) radial gain [1/s] and its derivative.
    """
    z = np.asarray(z, dtype=float)
    z_dot = np.asarray(z_dot, dtype=float)
    zx = z[..., 0]
    zy = z[..., 1]
    zdx = z_dot[..., 0]
    zdy = z_dot[..., 1]
    cphi = np.cos(phi)
    sphi = np.sin(phi)
    a2 = np.multiply(r1, r1)
    b2 = np.multiply(r2, r2)
    dab = a2 - b2
    h1 = dab * sphi * cphi  # (27)-(29)
    h2 = a2 * cphi * cphi + b2 * sphi * sphi
    h3 = a2 * sphi * sphi + b2 * cphi * cphi
    inv_ab = 1.0 / np.multiply(r1, r2)
    u = cphi * zx + sphi * zy  # S6.2
    w = -sphi * zx + cphi * zy
    h = u * u / a2 + w * w / b2 - 1.0
    ud = cphi * zdx + sphi * zdy + phi_dot * w  # S6.4
    wd = -sphi * zdx + cphi * zdy - phi_dot * u
    hd = 2.0 * u * ud / a2 + 2.0 * w * wd / b2
    mx = h1 * zx - h2 * zy
    my = h3 * zx - h1 * zy
    fx = -zy * phi_dot + psi_dot * inv_ab * mx - c * zx * h  # S6.3
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
    return FieldOutput(np.stack((fx, fy), axis=-1), np.stack((fdx, fdy), axis=-1), h, hd)


# ----------------------------------------------------------------------------------------------
# S6.5 gains
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EllipseGains:
    """Designed limit-cycle gains of one ellipse (S6.5): psi_dot_max [rad/s], c_max [1/s]."""

    psi_dot_max_radps: float
    c_max_per_s: float

    def __post_init__(self) -> None:
        for name in ('psi_dot_max_radps', 'c_max_per_s'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f'must be finite and > 0 (got {value!r})', name)

    @classmethod
    def design(
        cls, r1_m: float, r2_m: float, avoidance: AvoidanceParams, v_tan_mps: float | None = None
    ) -> 'EllipseGains':
        psi, c = design_gains(r1_m, r2_m, avoidance, v_tan_mps)
        return cls(float(psi), float(c))


def design_gains(r1, r2, avoidance: AvoidanceParams, v_tan=None):
    """S6.5 design rules for the prohibited ellipse P with semi-axes (r1, r2) [m].

    psi_dot_max = v_tan / sqrt(R1 R2) with (R1, R2) = rho_L (r1, r2);
    c_max = v_rad / (kappa sqrt(r1 r2) h_Q), h_Q = (kappa/rho_L)^2 - 1.
    ``v_tan`` defaults to ``avoidance.tangential_speed_mps``. Returns (psi_dot_max, c_max).
    """
    if v_tan is None:
        v_tan = avoidance.tangential_speed_mps
    rho = avoidance.limit_cycle_scale
    kappa = avoidance.protected_scale
    g = np.sqrt(np.multiply(r1, r2))
    psi_dot_max = v_tan / (rho * g)
    h_q = (kappa / rho) ** 2 - 1.0
    c_max = avoidance.radial_speed_mps / (kappa * g * h_q)
    return psi_dot_max, c_max


def gain_schedule(
    t_since_entry_s,
    psi_dot_max,
    c_max,
    direction=1.0,
    mu=1.0,
    mu_dot=0.0,
    beta0: float = 0.3,
    tau_g_s: float = 1.5,
):
    """S6.5 schedule from the entry instant: returns (psi_dot, psi_ddot, c, c_dot), broadcast.

    beta = 1 - (1 - beta0) exp(-t/tau_g), beta_dot = (1 - beta0) exp(-t/tau_g)/tau_g;
    psi_dot = s psi_dot_max mu beta, psi_ddot = s psi_dot_max (mu beta_dot + mu_dot beta),
    c = c_max beta, c_dot = c_max beta_dot.
    """
    t = np.maximum(np.asarray(t_since_entry_s, dtype=float), 0.0)
    decay = (1.0 - beta0) * np.exp(-t / tau_g_s)
    beta = 1.0 - decay
    beta_dot = decay / tau_g_s
    scale = direction * psi_dot_max
    psi_dot = scale * mu * beta
    psi_ddot = scale * (mu * beta_dot + mu_dot * beta)
    return psi_dot, psi_ddot, c_max * beta, c_max * beta_dot


# ----------------------------------------------------------------------------------------------
# S6.5 parking factor
# ----------------------------------------------------------------------------------------------


def _anomaly_and_rate(z, z_dot, cphi, sphi, phi_dot, r1, r2):
    """Eccentric anomaly psi = atan2(w/R2, u/R1) and its rate (U W_dot - W U_dot)/(U^2 + W^2)."""
    zx = z[..., 0]
    zy = z[..., 1]
    u = cphi * zx + sphi * zy
    w = -sphi * zx + cphi * zy
    ud = cphi * z_dot[..., 0] + sphi * z_dot[..., 1] + phi_dot * w
    wd = -sphi * z_dot[..., 0] + cphi * z_dot[..., 1] - phi_dot * u
    uu = u / r1
    ww = w / r2
    den = uu * uu + ww * ww
    num = uu * (wd / r2) - ww * (ud / r1)
    rate = np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), 0.0)
    return np.arctan2(ww, uu), rate


def eccentric_anomaly(z, phi, r1, r2):
    """Psi = atan2(w/R2, u/R1) of z (N, 2) relative to the centre (S6.5). Returns (N,) [rad]."""
    u, w = body_coords(np.asarray(z, dtype=float), phi)
    return np.arctan2(w / r2, u / r1)


def parking_factor(z, z_dot, goal, goal_dot, phi, phi_dot, r1, r2, direction, psi_slow):
    """S6.5 parking factor mu = sat(D/psi_slow) and mu_dot.

    ``z``, ``z_dot`` agent and ``goal``, ``goal_dot`` goal position/velocity RELATIVE to the
    obstacle
    centre (g - x~, g_dot - x~_dot), (N, 2). D = ((s(psi_g - psi_a) + pi/2) mod 2 pi) - pi/2;
    mu_dot = s(psi_g_dot - psi_a_dot)/psi_slow inside the linear zone, 0 outside.
    Returns (mu (N,), mu_dot (N,)).
    """
    z = np.asarray(z, dtype=float)
    goal = np.asarray(goal, dtype=float)
    cphi = np.cos(phi)
    sphi = np.sin(phi)
    psi_a, rate_a = _anomaly_and_rate(
        z, np.asarray(z_dot, dtype=float), cphi, sphi, phi_dot, r1, r2
    )
    psi_g, rate_g = _anomaly_and_rate(
        goal, np.asarray(goal_dot, dtype=float), cphi, sphi, phi_dot, r1, r2
    )
    dd = np.mod(direction * (psi_g - psi_a) + 0.5 * math.pi, TWO_PI) - 0.5 * math.pi
    q = dd / psi_slow
    linear = (q < 1.0) & (q > -1.0)
    mu = np.clip(q, -1.0, 1.0)
    mu_dot = np.where(linear, direction * (rate_g - rate_a) / psi_slow, 0.0)
    return mu, mu_dot


# ----------------------------------------------------------------------------------------------
# S6.6 rotation direction
# ----------------------------------------------------------------------------------------------

_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


def ellipse_arc_length(psi_from, delta, r1, r2):
    """Arc length of the ellipse (R1 cos psi, R2 sin psi) over psi in [psi_from, psi_from + delta]
    (delta >= 0), 48-point Gauss-Legendre on each of 4 sub-intervals. Broadcast, returns [m].
    """
    psi_from = np.asarray(psi_from, dtype=float)[..., None]
    delta = np.asarray(delta, dtype=float)[..., None]
    r1 = np.asarray(r1, dtype=float)[..., None]
    r2 = np.asarray(r2, dtype=float)[..., None]
    total = 0.0
    n_sub = 4
    for j in range(n_sub):
        lo = psi_from + delta * (j / n_sub)
        half = 0.5 * delta / n_sub
        psi = lo + half * (_GL_X + 1.0)
        speed = np.sqrt((r1 * np.sin(psi)) ** 2 + (r2 * np.cos(psi)) ** 2)
        total = total + half[..., 0] * np.sum(_GL_W * speed, axis=-1)
    return total


def ellipse_perimeter(r1, r2):
    """Perimeter of the ellipse with semi-axes (r1, r2) [m]
    (quadrature, relative error < 1e-12).
    """
    return ellipse_arc_length(0.0 * np.asarray(r1, dtype=float), TWO_PI, r1, r2)


def choose_direction(
    z, z_dot, goal, goal_dot, obstacle_vel, phi, r1, r2, lookahead_m, velocity_tie_break=True
):
    """S6.6 rules 1-4 (obstacle) or rules 1-3 and 7 (yielding agent: ``velocity_tie_break=False``).

    Parameters
    ----------
    z, z_dot : (N, 2) agent position relative to the centre [m] and relative velocity
        p_dot - x~_dot [m/s] (rule 4 tie-break).
    goal : (N, 2) goal g_i relative to the centre (g - x~) [m]; goal_dot (N, 2) g_dot (world)
    [m/s].
    obstacle_vel : (N, 2) x~_dot of the centre [m/s].
    phi, r1, r2 : orientation and semi-axes of the limit-cycle ellipse L_j [rad, m].
    lookahead_m : rule 1 look-ahead length 2 kappa r1j (r1j of P_j) [m].

    Rules 5 (keep s between adjacent static obstacles) and 6 (mutual: s = +1) are the caller's.
    Returns s (N,) float in {+1 (CCW), -1 (CW)}.
    """
    z = np.asarray(z, dtype=float)
    z_dot = np.asarray(z_dot, dtype=float)
    goal = np.asarray(goal, dtype=float)
    rel = np.asarray(goal_dot, dtype=float) - np.asarray(obstacle_vel, dtype=float)
    speed = np.hypot(rel[..., 0], rel[..., 1])
    scale = np.where(speed > 0.0, lookahead_m / np.where(speed > 0.0, speed, 1.0), 0.0)
    g_la = goal + scale[..., None] * rel  # rule 1
    psi_a = eccentric_anomaly(z, phi, r1, r2)
    psi_g = eccentric_anomaly(g_la, phi, r1, r2)
    d_plus = np.mod(psi_g - psi_a, TWO_PI)  # rule 2
    l_plus = ellipse_arc_length(psi_a, d_plus, r1, r2)
    perimeter = ellipse_perimeter(r1, r2)
    l_minus = perimeter - l_plus
    margin = 0.1 * perimeter  # rule 3
    s = np.where(l_plus < l_minus - margin, 1.0, np.where(l_minus < l_plus - margin, -1.0, 0.0))
    if velocity_tie_break:  # rule 4
        h1, h2, h3 = ellipse_coeffs(phi, r1, r2)
        mx = h1 * z[..., 0] - h2 * z[..., 1]
        my = h3 * z[..., 0] - h1 * z[..., 1]
        tie = np.sign(mx * z_dot[..., 0] + my * z_dot[..., 1])
        tie = np.where(tie == 0.0, 1.0, tie)
    else:  # rule 7
        tie = 1.0
    return np.where(s == 0.0, tie, s)


# ----------------------------------------------------------------------------------------------
# S8 helpers: ray / segment tests
# ----------------------------------------------------------------------------------------------


def _quadratic(z, dz, phi, r1, r2):
    c = np.cos(phi)
    s = np.sin(phi)
    u = c * z[..., 0] + s * z[..., 1]
    w = -s * z[..., 0] + c * z[..., 1]
    du = c * dz[..., 0] + s * dz[..., 1]
    dw = -s * dz[..., 0] + c * dz[..., 1]
    ia = 1.0 / np.multiply(r1, r1)
    ib = 1.0 / np.multiply(r2, r2)
    c0 = u * u * ia + w * w * ib - 1.0
    qa = du * du * ia + dw * dw * ib
    qb = u * du * ia + w * dw * ib
    return qa, qb, c0


def ray_hits_ellipse(z, z_dot, phi, r1, r2):
    """Does the ray {z + lam z_dot, lam >= 0} meet the closed ellipse (h <= 0)? (S8.1 heading
    test).

    ``z`` (N, 2) relative to the centre, ``z_dot`` (N, 2) direction (relative velocity).
    Returns (hit (N,) bool, lam (N,) first contact parameter [s if z_dot is a velocity];
    0 when already inside, +inf when missed).
    """
    z = np.asarray(z, dtype=float)
    qa, qb, c0 = _quadratic(z, np.asarray(z_dot, dtype=float), phi, r1, r2)
    inside = c0 <= 0.0
    disc = qb * qb - qa * c0
    ahead = (qa > 0.0) & (qb < 0.0) & (disc >= 0.0)
    root = np.sqrt(np.maximum(disc, 0.0))
    den = np.where(ahead, -qb + root, 1.0)
    lam = np.where(inside, 0.0, np.where(ahead, c0 / den, np.inf))
    return inside | ahead, lam


def segment_hits_ellipse(p0, p1, center, phi, r1, r2):
    """Does the segment [p0, p1] (N, 2) meet the closed ellipse at ``center``? (S8.3 cleared test).

    Minimises h along the segment in closed form. Returns (N,) bool.
    """
    p0 = np.asarray(p0, dtype=float)
    z = p0 - center
    qa, qb, c0 = _quadratic(z, np.asarray(p1, dtype=float) - p0, phi, r1, r2)
    lam = np.where(qa > 0.0, np.clip(-qb / np.where(qa > 0.0, qa, 1.0), 0.0, 1.0), 0.0)
    return qa * lam * lam + 2.0 * qb * lam + c0 <= 0.0


# ----------------------------------------------------------------------------------------------
# Exact signed distance (metrics)
# ----------------------------------------------------------------------------------------------
