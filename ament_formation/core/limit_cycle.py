"""Elliptical limit-cycle obstacle field (spec S6, paper (15), (21)-(30), corrected per S11).

Implements:
* S6.2 ellipse function h = z^T A z - 1 and the coefficients h~1, h~2, h~3 of (27)-(29);
* S6.3 the field F = H - C~ z h (rigid co-rotation, tangential term at eccentric-anomaly rate psi_dot,
  radial attraction c h), for which h_dot = -2 c h (h + 1) on the surface when c1 = c2;
* S6.4 the closed-form total derivative F_dot along the measured relative motion, including moving
  (x~dot) and rotating (phi_dot, phi_ddot) obstacles and time-varying psi_dot, c;
* S6.5 gain design (psi_dot_max, c_max), the beta(t) schedule and the parking factor mu;
* S6.6 rotation-direction rules 1-4 and 7 (rules 5-6 are the caller's: keep s, mutual s = +1);
* ray/segment tests used by S8 (heading and cleared tests) and the exact Euclidean signed distance
  of points to an ellipse (for metrics).

Shapes: z, z_dot (N, 2) relative to the obstacle centre [m, m/s]; angles, semi-axes and gains (N,)
or scalars (broadcast). Semi-axes passed to :func:`field` and :func:`ellipse_h` are those of the
ellipse that is used (L_j = rho_L P_j for the limit cycle). Numba twins live in
:mod:`ament_formation.core.kernels`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.params import AvoidanceParams

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class FieldOutput:
    """S6.3/S6.4 for N agents: ``f`` (N, 2) [m/s], ``f_dot`` (N, 2) [m/s^2], ``h`` (N,), ``h_dot`` (N,) [1/s]."""

    f: np.ndarray
    f_dot: np.ndarray
    h: np.ndarray
    h_dot: np.ndarray


# ----------------------------------------------------------------------------------------------
# S6.2 ellipse function
# ----------------------------------------------------------------------------------------------

def ellipse_coeffs(phi, r1, r2):
    """(h~1, h~2, h~3) of (27)-(29): h~1 = (R1^2-R2^2) sin cos, h~2 = R1^2 cos^2 + R2^2 sin^2,
    h~3 = R1^2 sin^2 + R2^2 cos^2. Each broadcast over the inputs."""
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
    h1 = dab * sphi * cphi                      # (27)-(29)
    h2 = a2 * cphi * cphi + b2 * sphi * sphi
    h3 = a2 * sphi * sphi + b2 * cphi * cphi
    inv_ab = 1.0 / np.multiply(r1, r2)
    u = cphi * zx + sphi * zy                   # S6.2
    w = -sphi * zx + cphi * zy
    h = u * u / a2 + w * w / b2 - 1.0
    ud = cphi * zdx + sphi * zdy + phi_dot * w  # S6.4
    wd = -sphi * zdx + cphi * zdy - phi_dot * u
    hd = 2.0 * u * ud / a2 + 2.0 * w * wd / b2
    mx = h1 * zx - h2 * zy
    my = h3 * zx - h1 * zy
    fx = -zy * phi_dot + psi_dot * inv_ab * mx - c * zx * h     # S6.3
    fy = zx * phi_dot + psi_dot * inv_ab * my - c * zy * h
    cos2 = cphi * cphi - sphi * sphi
    sin2 = 2.0 * sphi * cphi
    h1p = dab * cos2
    h2p = -dab * sin2
    h3p = dab * sin2
    mdx = phi_dot * (h1p * zx - h2p * zy) + h1 * zdx - h2 * zdy
    mdy = phi_dot * (h3p * zx - h1p * zy) + h3 * zdx - h1 * zdy
    fdx = (-zdy * phi_dot - zy * phi_ddot + (psi_ddot * mx + psi_dot * mdx) * inv_ab
           - (c_dot * zx * h + c * zdx * h + c * zx * hd))
    fdy = (zdx * phi_dot + zx * phi_ddot + (psi_ddot * my + psi_dot * mdy) * inv_ab
           - (c_dot * zy * h + c * zdy * h + c * zy * hd))
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
        for name in ("psi_dot_max_radps", "c_max_per_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"must be finite and > 0 (got {value!r})", name)

    @classmethod
    def design(cls, r1_m: float, r2_m: float, avoidance: AvoidanceParams,
               v_tan_mps: float | None = None) -> "EllipseGains":
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


def gain_schedule(t_since_entry_s, psi_dot_max, c_max, direction=1.0, mu=1.0, mu_dot=0.0,
                  beta0: float = 0.3, tau_g_s: float = 1.5):
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
