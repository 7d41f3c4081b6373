"""The last line of defence of the law (docs/law-changes.md, issue 13): whatever the automaton and
the encounter arbitration decided, the desired point velocity V_d handed to the sliding-mode law
(S3.2) is filtered so that a robot can always stop before contact.

* **Bounded feed-forward** (S14.5): a parent's velocity and acceleration, a yield target's velocity
  and the mode's V_d itself are clipped to what a robot can do (``speed_limit_mps``; the
  acceleration bound 2 tau_max / (m~ r) of S2.2, S3.6). A feed-forward loop can then never drive a
  robot beyond the speed limit.
* **Braking barrier**: every control period, against every obstacle boundary (P, whose boundary
  velocity includes the obstacle's rotation, S14.2) and every robot (contact circle R_i + R_k)
  within ``safety_range_m``, the speed of approach of V_d relative to the boundary is limited to
  sqrt(2 a_brk (gap - gap_0)) (robot pairs: half of it each, reciprocally), the speed from which the robot can still brake to rest before the
  gap closes (a_brk: a fraction of the switching gain K, the deceleration the S3 loop realises
  without a feed-forward). Only the approaching normal component is removed: the tangential part
  is kept (heading-preserving), so two robots slide past each other instead of deadlocking, and a
  robot moving away from a threat is never held back (liveness).

Both run inside :func:`ament_formation.core.control.law.robot_law`, so the simulator and the
robot's controller run them alike. Scalar numba kernels.
"""

from __future__ import annotations

import math

from numba import njit

from ament_formation.core.control.automaton import (
    P_SAFE_ACCEL,
    P_SAFE_GAP,
    P_SAFE_RANGE,
    P_VMAX,
)


@njit(cache=True)
def clip_norm(vx, vy, cap):
    """(vx, vy) scaled down to length ``cap`` when longer."""
    nrm = math.hypot(vx, vy)
    if nrm > cap and nrm > 0.0:
        return vx * cap / nrm, vy * cap / nrm
    return vx, vy


@njit(cache=True)
def accel_limit(coeffs, i):
    """Largest point acceleration the torque limit allows, 2 tau_max / (m~ r) [m/s^2] (S2.2)."""
    return 2.0 * coeffs[6, i] / (coeffs[0, i] * coeffs[2, i])


@njit(cache=True)
def _barrier(vdx, vdy, vddx, vddy, nx, ny, bvx, bvy, gap, a_brk):
    """Limit the approach of V_d toward a boundary (outward normal n, boundary velocity bv) to
    sqrt(2 a_brk gap); returns (vdx, vdy, vddx, vddy, active).
    """
    ux = vdx - bvx
    uy = vdy - bvy
    approach = -(ux * nx + uy * ny)
    allowed = math.sqrt(2.0 * a_brk * gap) if gap > 0.0 else 0.0
    if approach <= allowed:
        return vdx, vdy, vddx, vddy, False
    cut = approach - allowed
    dn = vddx * nx + vddy * ny
    if dn < 0.0:  # no feed-forward toward the boundary while braking
        vddx -= dn * nx
        vddy -= dn * ny
    return vdx + cut * nx, vdy + cut * ny, vddx, vddy, True


@njit(cache=True)
def _obstacle_gap(px, py, oc, ov, ophi, ophid, oaxes, j):
    """(gap, nx, ny, bvx, bvy) of obstacle j's boundary P seen from p: the first-order distance
    (k - 1)/|grad k| (k: the level of p in P's similar ellipses), the normal grad k/|grad k| and
    the velocity of the material point under p (translation and rotation, S14.2).
    """
    zx = px - oc[j, 0]
    zy = py - oc[j, 1]
    r1 = oaxes[j, 0]
    r2 = oaxes[j, 1]
    c = math.cos(ophi[j])
    s = math.sin(ophi[j])
    u = (c * zx + s * zy) / r1
    w = (-s * zx + c * zy) / r2
    k = max(math.sqrt(u * u + w * w), 1e-9)
    gu = u / (k * r1)  # grad k in body axes
    gw = w / (k * r2)
    gx = c * gu - s * gw
    gy = s * gu + c * gw
    gn = max(math.hypot(gx, gy), 1e-12)
    return (k - 1.0) / gn, gx / gn, gy / gn, ov[j, 0] - ophid[j] * zy, ov[j, 1] + ophid[j] * zx


@njit(cache=True)
def _robot_barriers(i, x, vdx, vdy, vddx, vddy, rbody, g0, a_brk, reach):
    """The barrier against every other robot whose contact circle R_i + R_k is within ``reach``
    (reciprocal: each robot of a pair takes half of the approach speed budget).
    """
    for k in range(x.shape[0]):
        dx = x[i, 0] - x[k, 0]
        dy = x[i, 1] - x[k, 1]
        lim = rbody[i] + rbody[k] + reach
        if k == i or abs(dx) > lim or abs(dy) > lim:
            continue
        dist = math.hypot(dx, dy)
        gap = dist - rbody[i] - rbody[k]
        if gap < reach and dist > 1e-9:
            vdx, vdy, vddx, vddy, _a = _barrier(
                vdx, vdy, vddx, vddy, dx / dist, dy / dist, 0.0, 0.0, gap - g0, 0.25 * a_brk
            )
    return vdx, vdy, vddx, vddy


@njit(cache=True)
def _obstacle_barriers(px, py, vdx, vdy, vddx, vddy, oc, ov, ophi, ophid, oaxes, g0, a_brk, reach):
    """The barrier against every obstacle boundary P within ``reach`` (boundary velocity included)."""
    for j in range(oc.shape[0]):
        r1 = oaxes[j, 0]
        if abs(px - oc[j, 0]) > r1 + reach or abs(py - oc[j, 1]) > r1 + reach:
            continue
        gap, nx, ny, bvx, bvy = _obstacle_gap(px, py, oc, ov, ophi, ophid, oaxes, j)
        if gap < reach:
            vdx, vdy, vddx, vddy, _a = _barrier(
                vdx, vdy, vddx, vddy, nx, ny, bvx, bvy, gap - g0, a_brk
            )
    return vdx, vdy, vddx, vddy


# implements: S3 (safety filter of V_d)
@njit(cache=True)
def safe_field(i, x, pd, vdx, vdy, vddx, vddy, oc, ov, ophi, ophid, oaxes, rbody, gain_k, prm):
    """V_d, V_d_dot of robot i after the speed limit and the braking barrier (module docstring).

    Returns (vdx, vdy, vddx, vddy).
    """
    vdx, vdy = clip_norm(vdx, vdy, prm[P_VMAX])
    a_brk = prm[P_SAFE_ACCEL] * gain_k  # the S3 loop's deceleration without feed-forward
    reach = prm[P_SAFE_RANGE]
    g0 = prm[P_SAFE_GAP]
    for _ in range(2):  # the second pass re-checks the robots; obstacles have the last word
        vdx, vdy, vddx, vddy = _robot_barriers(i, x, vdx, vdy, vddx, vddy, rbody, g0, a_brk, reach)
        vdx, vdy, vddx, vddy = _obstacle_barriers(
            x[i, 0], x[i, 1], vdx, vdy, vddx, vddy, oc, ov, ophi, ophid, oaxes, g0, a_brk, reach
        )
    return vdx, vdy, vddx, vddy
