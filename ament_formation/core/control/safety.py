"""The last line of defence of the law (docs/law-changes.md, issue 13): whatever the automaton and
the encounter arbitration decided, the desired point velocity V_d handed to the sliding-mode law
(S3.2) is filtered so that a robot can always stop before contact.

* **Bounded feed-forward** (S14.5): a parent's velocity and acceleration, a yield target's velocity
  and the mode's V_d itself are clipped to what a robot can do (``speed_limit_mps``; the
  acceleration bound 2 tau_max / (m~ r) of S2.2, S3.6). A feed-forward loop can then never drive a
  robot beyond the speed limit.
* **Braking barrier**: every control period, against the nearest obstacle boundary (P, whose
  boundary velocity includes the obstacle's rotation, S14.2) and the nearest robot (contact circle
  R_i + R_k), the speed of approach of V_d relative to the boundary is limited to
  sqrt(2 a_brk (gap - gap_0)), the speed from which the robot can still brake to rest before the
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
def _nearest_obstacle(px, py, oc, ov, ophi, ophid, oaxes, reach):
    """(gap, nx, ny, bvx, bvy) of the nearest obstacle boundary P within ``reach`` [m] of p, or
    gap = inf. The gap is the first-order distance (k - 1)/|grad k| to P (k: the level of p in
    P's similar ellipses), the normal is grad k, the boundary velocity that of the material point
    under p (translation and rotation, S14.2).
    """
    best = math.inf
    bnx = bny = bvx = bvy = 0.0
    for j in range(oc.shape[0]):
        zx = px - oc[j, 0]
        zy = py - oc[j, 1]
        r1 = oaxes[j, 0]
        r2 = oaxes[j, 1]
        if abs(zx) > r1 + reach or abs(zy) > r1 + reach:
            continue
        c = math.cos(ophi[j])
        s = math.sin(ophi[j])
        u = (c * zx + s * zy) / r1
        w = (-s * zx + c * zy) / r2
        k = math.sqrt(u * u + w * w)
        if k < 1e-9:
            continue
        gu = u / (k * r1)  # grad k in body axes
        gw = w / (k * r2)
        gx = c * gu - s * gw
        gy = s * gu + c * gw
        gn = math.hypot(gx, gy)
        gap = (k - 1.0) / gn
        if gap < best:
            best = gap
            bnx = gx / gn
            bny = gy / gn
            bvx = ov[j, 0] - ophid[j] * zy
            bvy = ov[j, 1] + ophid[j] * zx
    return best, bnx, bny, bvx, bvy


@njit(cache=True)
def _nearest_robot(i, x, pd, rbody, reach):
    """(gap, nx, ny, bvx, bvy) of the nearest other robot's contact circle R_i + R_k within
    ``reach`` [m], or gap = inf; n points from that robot to robot i.
    """
    best = math.inf
    bnx = bny = bvx = bvy = 0.0
    for k in range(x.shape[0]):
        if k == i:
            continue
        dx = x[i, 0] - x[k, 0]
        dy = x[i, 1] - x[k, 1]
        lim = rbody[i] + rbody[k] + reach
        if abs(dx) > lim or abs(dy) > lim:
            continue
        dist = math.hypot(dx, dy)
        gap = dist - rbody[i] - rbody[k]
        if gap < best and dist > 1e-9:
            best = gap
            bnx = dx / dist
            bny = dy / dist
            bvx = pd[k, 0]
            bvy = pd[k, 1]
    return best, bnx, bny, bvx, bvy


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
    px = x[i, 0]
    py = x[i, 1]
    go, onx, ony, obx, oby = _nearest_obstacle(px, py, oc, ov, ophi, ophid, oaxes, reach)
    gr, rnx, rny, _bx, _by = _nearest_robot(i, x, pd, rbody, reach)
    for _ in range(
        2
    ):  # the second pass re-checks the robot constraint; obstacles have the last word
        if gr < reach:  # reciprocal: each robot takes half of the approach budget
            vdx, vdy, vddx, vddy, _a = _barrier(
                vdx, vdy, vddx, vddy, rnx, rny, 0.0, 0.0, gr - g0, 0.25 * a_brk
            )
        if go < reach:
            vdx, vdy, vddx, vddy, _a = _barrier(
                vdx, vdy, vddx, vddy, onx, ony, obx, oby, go - g0, a_brk
            )
    return vdx, vdy, vddx, vddy
