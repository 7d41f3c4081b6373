"""The last line of defence of the law (docs/control-law.md S15): whatever the switching and the
coordinator decided, the desired point velocity V_d handed to the sliding-mode law (S3.2) is
filtered so that a robot can always stop before an obstacle's P, another robot's keep-out circle
or the floor's edge.

* **Bounded feed-forward** (S14.5): a parent's velocity and acceleration, a yield target's velocity
  and the mode's V_d itself are clipped to what a robot can do (``speed_limit_mps``; the
  acceleration bound 2 tau_max / (m~ r) of S2.2, S3.6). A feed-forward loop can then never drive a
  robot beyond the speed limit.
* **Braking barrier**: every control period, against every obstacle boundary (P, whose boundary
  velocity includes the obstacle's rotation, S14.2) and every robot (contact circle R_i + R_k)
  (keep-out circle R_aa = R_i + R_k + margin, S15.3) within ``safety_range_m``, the speed of
  approach of V_d relative to the boundary is limited to
  the speed from which the robot still stops before ``safety_gap_m`` after a reaction time
  ``safety_lag_s`` at the deceleration a_brk (a fraction of the switching gain K: what the S3
  loop realises without a feed-forward); a robot pair shares that budget (half each). Only the
  approaching normal component is removed, the tangential part is kept (heading-preserving), so
  two robots slide past each other instead of deadlocking, and a robot moving away from a threat
  is never held back (liveness). The constraints are met by alternating projections; a robot
  still squeezed between a robot and an obstacle stops (relative to the obstacles). The edges of a
  declared floor (S16.1) are walls of the same barrier; a robot squeezed
  between a wall and obstacles takes the exact solution of their constraints instead (it slides
  along the wall out of the way, :func:`_escape`), and stops only when there is none.

Both run inside :func:`ament_formation.core.control.law.robot_law_k`, so the simulator and the
robot agent run them alike. The robots checked are the rows of a neighbour list (the robots a
robot hears, or a grid's candidates in the simulator): the cost grows with the neighbours, not
with the team. Scalar numba kernels.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from ament_formation.core.control.floor import floor_edges, near_floor
from ament_formation.core.model.dynamics import ROW_M_TILDE, ROW_R, ROW_TAU_MAX

PASSES = 4  # alternating projections of the barrier (then a stop if a robot's is still violated)


@njit(cache=True, error_model='numpy', forceinline=True)
def clip_norm(vx, vy, cap):
    """(vx, vy) scaled down to length ``cap`` when longer."""
    nrm = math.hypot(vx, vy)
    if nrm > cap and nrm > 0.0:
        return vx * cap / nrm, vy * cap / nrm
    return vx, vy


@njit(cache=True, error_model='numpy', inline='always')
def clip_field(vx, vy, vdx, vdy, cap):
    """A field V (vx, vy) and its derivative V_dot (vdx, vdy) scaled down to speed ``cap`` when
    faster -> (vx, vy, vdx, vdy): the clipped field is cap V/|V|, its derivative
    cap/|V| (V_dot - (u.V_dot) u) with u = V/|V|, so that the feed-forward never pushes the robot
    along V beyond the cap (S15.1). Unchanged, bit for bit, when |V| <= cap.
    """
    nrm = math.hypot(vx, vy)
    if nrm <= cap or nrm == 0.0:
        return vx, vy, vdx, vdy
    ux, uy = vx / nrm, vy / nrm
    along = ux * vdx + uy * vdy
    scale = cap / nrm
    return ux * cap, uy * cap, (vdx - along * ux) * scale, (vdy - along * uy) * scale


@njit(cache=True, error_model='numpy', inline='always')
def accel_limit(coeffs, i):
    """Largest point acceleration the torque limit allows, 2 tau_max / (m~ r) [m/s^2] (S2.2)."""
    return 2.0 * coeffs[ROW_TAU_MAX, i] / (coeffs[ROW_M_TILDE, i] * coeffs[ROW_R, i])


@njit(cache=True, error_model='numpy', forceinline=True)
def allowed_speed(gap, a_brk, lag):
    """Approach speed [m/s] from which a robot stops within ``gap`` [m] after a reaction time
    ``lag`` [s] at the deceleration ``a_brk`` [m/s^2]: sqrt(2 a gap + (a lag)^2) - a lag. A closed
    gap (inside the margin: a disturbance drifted the robot in, below the boundary layer of S3.5)
    asks for a retreat at gap / (3 lag).
    """
    if gap <= 0.0:
        return gap / (3.0 * lag)
    al = a_brk * lag
    return math.sqrt(2.0 * a_brk * gap + al * al) - al


@njit(cache=True, error_model='numpy', forceinline=True)
def _barrier(vdx, vdy, vddx, vddy, pdx, pdy, nx, ny, bvx, bvy, allowed, lag, brake):
    """Limit the approach of V_d toward a boundary (outward normal n, boundary velocity bv) to
    ``allowed`` (:func:`allowed_speed` of its gap). With ``brake``, when the robot's own velocity
    p_dot exceeds it (the S3 loop lags V_d), V_d_dot gets the braking acceleration that removes the
    excess within lag / 3 (beyond the switching gain K). Returns (vdx, vdy, vddx, vddy).
    """
    approach = -((vdx - bvx) * nx + (vdy - bvy) * ny)
    excess = -((pdx - bvx) * nx + (pdy - bvy) * ny) - allowed if brake else 0.0
    if approach <= allowed and excess <= 0.0:
        return vdx, vdy, vddx, vddy
    dn = vddx * nx + vddy * ny
    if dn < 0.0:  # no feed-forward toward the boundary while braking
        vddx -= dn * nx
        vddy -= dn * ny
    if excess > 0.0:
        vddx += 3.0 * excess / lag * nx
        vddy += 3.0 * excess / lag * ny
    if approach > allowed:
        vdx += (approach - allowed) * nx
        vdy += (approach - allowed) * ny
    return vdx, vdy, vddx, vddy


@njit(cache=True, error_model='numpy', inline='always')
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


@njit(cache=True, error_model='numpy', inline='always')
def _obstacle_near(px, py, oc, ov, ophi, ophid, oaxes, j, prm):
    """Obstacle j's boundary P as the barrier sees it from p: (near, gap, nx, ny, bvx, bvy), near
    when P is within ``safety_range_m``, gap the distance to P less the margin, scaled to the
    boundary speed (S14.2: the boundary may move a lag further), n and bv as in
    :func:`_obstacle_gap`.
    """
    reach, lag = prm.safety_range_m, prm.safety_lag_s
    r1 = oaxes[j, 0]
    if abs(px - oc[j, 0]) > r1 + reach or abs(py - oc[j, 1]) > r1 + reach:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    gap, nx, ny, bvx, bvy = _obstacle_gap(px, py, oc, ov, ophi, ophid, oaxes, j)
    margin = prm.safety_gap_m + lag * (math.hypot(ov[j, 0], ov[j, 1]) + abs(ophid[j]) * r1)
    return gap < reach, gap - margin, nx, ny, bvx, bvy


# The boundaries within reach of a robot, as rows (nx, ny, bvx, bvy, allowed): outward normal n,
# boundary velocity bv, the approach speed allowed from the boundary's gap. They depend on the
# state only, not on V_d, so they are computed once per sample and every projection reuses them.


@njit(cache=True, error_model='numpy', inline='always')
def _row(cons, n, nx, ny, bvx, bvy, allowed):
    cons[n, 0], cons[n, 1], cons[n, 2], cons[n, 3], cons[n, 4] = nx, ny, bvx, bvy, allowed
    return n + 1


@njit(cache=True, error_model='numpy', inline='always')
def _robot_rows(i, x, pd, nbrs, rbody, a_brk, prm, cons):
    """Rows of every robot k of ``nbrs`` whose keep-out circle R_aa (S15.3) is within
    ``safety_range_m`` (reciprocal: each robot of a pair takes half of the approach speed budget,
    and makes way for the other's approach beyond its half, e.g. when an obstacle pushes that
    robot) from row 0. Returns the row count.
    """
    g0, reach, lag = prm.safety_gap_m, prm.safety_range_m, prm.safety_lag_s
    n = 0
    for q in range(nbrs.shape[0]):
        k = nbrs[q]
        dx = x[i, 0] - x[k, 0]
        dy = x[i, 1] - x[k, 1]
        keep = rbody[i] + rbody[k] + prm.agent_keepout_margin_m
        lim = keep + reach
        if k == i or abs(dx) > lim or abs(dy) > lim:
            continue
        dist = math.hypot(dx, dy)
        gap = dist - keep
        if gap < reach and dist > 1e-9:
            nx = dx / dist
            ny = dy / dist
            allowed = allowed_speed(gap - g0, 0.25 * a_brk, lag)
            # k coming at i faster than its own share (pushed, or lagging): i makes way
            push = max(0.0, pd[k, 0] * nx + pd[k, 1] * ny - max(0.0, allowed))
            n = _row(cons, n, nx, ny, push * nx, push * ny, allowed)
    return n


@njit(cache=True, error_model='numpy', inline='always')
def _wall_rows(px, py, rb, a_brk, prm, cons, n):
    """Rows of each edge of a declared floor within ``safety_range_m`` of the body (radius ``rb``
    about p): walls that do not move (inward normal). Returns the row count.
    """
    for gap, nx, ny in floor_edges(px, py, rb, prm):
        if gap < prm.safety_range_m:
            n = _row(cons, n, nx, ny, 0.0, 0.0,
                     allowed_speed(gap - prm.safety_gap_m, a_brk, prm.safety_lag_s))
    return n


@njit(cache=True, error_model='numpy', inline='always')
def _obstacle_rows(px, py, orows, ob, a_brk, prm, cons, n):
    """Rows of every obstacle boundary P of rows ``orows`` within ``safety_range_m`` (boundary
    velocity included). Returns the row count.
    """
    for j in orows:
        near, gap, nx, ny, bvx, bvy = _obstacle_near(px, py, ob.c, ob.v, ob.phi, ob.phi_dot,
                                                     ob.axes, j, prm)
        if near:
            n = _row(cons, n, nx, ny, bvx, bvy, allowed_speed(gap, a_brk, prm.safety_lag_s))
    return n


@njit(cache=True, error_model='numpy', inline='always')
def _project(cons, lo, hi, vdx, vdy, vddx, vddy, pdx, pdy, lag, brake):
    """:func:`_barrier` of rows ``lo`` .. ``hi`` - 1 in turn. Returns (vdx, vdy, vddx, vddy)."""
    for q in range(lo, hi):
        vdx, vdy, vddx, vddy = _barrier(vdx, vdy, vddx, vddy, pdx, pdy, cons[q, 0], cons[q, 1],
                                        cons[q, 2], cons[q, 3], cons[q, 4], lag, brake)
    return vdx, vdy, vddx, vddy


@njit(cache=True, error_model='numpy', forceinline=True)
def _feasible(cons, n, vx, vy):
    """Whether (vx, vy) meets every constraint n . v >= b of ``cons[:n]`` (rows nx, ny, b)."""
    for q in range(n):
        if cons[q, 0] * vx + cons[q, 1] * vy < cons[q, 2] - 1e-12:
            return False
    return True


@njit(cache=True, error_model='numpy', forceinline=True)
def _escape(vx0, vy0, p, rb, orows, oc, ov, ophi, ophid, oaxes, a_brk, prm, cons):
    """A robot squeezed between a floor edge and an obstacle (docs/law-changes.md §12): the
    velocity closest to (vx0, vy0) that meets every wall's and every obstacle's barrier within
    reach exactly (the alternating projections approach it slowly when the wall and the obstacle
    face each other at an acute angle, leaving a stop that a moving obstacle then pushes through
    the wall). Half-planes n . v >= b in 2-D: the closest point is v0, its projection on one line
    or the vertex of two. Returns (found, vx, vy); not found when they leave nothing within the
    speed limit. ``cons``: scratch rows (at least 4 + len(orows), 3 columns used).
    """
    g0, reach, lag = prm.safety_gap_m, prm.safety_range_m, prm.safety_lag_s
    px, py = p[0], p[1]
    # rows (nx, ny, b)
    n = 0
    for gap, nx, ny in floor_edges(px, py, rb, prm):
        if gap < reach:
            cons[n, 0], cons[n, 1], cons[n, 2] = nx, ny, -allowed_speed(gap - g0, a_brk, lag)
            n += 1
    for j in orows:
        near, gap, nx, ny, bvx, bvy = _obstacle_near(px, py, oc, ov, ophi, ophid, oaxes, j, prm)
        if near:
            cons[n, 0], cons[n, 1] = nx, ny
            cons[n, 2] = bvx * nx + bvy * ny - allowed_speed(gap, a_brk, lag)
            n += 1
    best, bx, by = math.inf, 0.0, 0.0
    if math.hypot(vx0, vy0) <= prm.speed_limit_mps and _feasible(cons, n, vx0, vy0):  # V_d
        best, bx, by = 0.0, vx0, vy0
    for a in range(n):
        for b in range(a, n):
            if a == b:  # V_d projected on line a
                t = cons[a, 2] - (cons[a, 0] * vx0 + cons[a, 1] * vy0)
                cx, cy = vx0 + t * cons[a, 0], vy0 + t * cons[a, 1]
            else:  # the vertex of lines a and b
                det = cons[a, 0] * cons[b, 1] - cons[a, 1] * cons[b, 0]
                if abs(det) < 1e-9:
                    continue
                cx = (cons[a, 2] * cons[b, 1] - cons[a, 1] * cons[b, 2]) / det
                cy = (cons[a, 0] * cons[b, 2] - cons[a, 2] * cons[b, 0]) / det
            d = (cx - vx0) ** 2 + (cy - vy0) ** 2
            if (
                d < best
                and math.hypot(cx, cy) <= prm.speed_limit_mps
                and _feasible(cons, n, cx, cy)
            ):
                best, bx, by = d, cx, cy
    return best < math.inf, bx, by


@njit(cache=True, error_model='numpy', inline='always')
def _same(a, b):
    """Whether a and b are the same float, the sign of a zero included (NaN: never)."""
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


# implements: S15
@njit(cache=True, error_model='numpy', inline='always')
def safe_field(i, x, pd, nbrs, orows, vdx, vdy, vddx, vddy, ob, rbody, prm, cons=None):
    """V_d, V_d_dot of robot i after the speed limit and the braking barrier (module docstring)
    against the obstacles of rows ``orows`` of ``ob`` (ObstacleSnapshot), the robots of ``nbrs``
    (rows of x, pd) and the floor. ``cons``: scratch rows (at least len(nbrs) + 8 +
    2 len(orows), 5: the barrier's rows, then :func:`_escape`'s) to use instead of a new array (a
    caller running many robots a step allocates them once; no allocation in the loop, so no
    exception path that keeps numba's reference counts). Returns (vdx, vdy, vddx, vddy).
    """
    vdx, vdy, vddx, vddy = clip_field(vdx, vdy, vddx, vddy, prm.speed_limit_mps)
    vx0, vy0 = vdx, vdy
    a_brk = prm.brake_gain_fraction * prm.switching_gain_mps2  # the S3 loop without feed-forward
    lag = prm.safety_lag_s
    px, py, pdx, pdy = x[i, 0], x[i, 1], pd[i, 0], pd[i, 1]
    rb = rbody[i]
    walls = near_floor(px, py, rb, prm)
    if cons is None:
        cons = np.empty((nbrs.shape[0] + 8 + 2 * orows.shape[0], 5))
    nr = _robot_rows(i, x, pd, nbrs, rbody, a_brk, prm, cons)  # rows: robots, walls, obstacles
    nw = _wall_rows(px, py, rb, a_brk, prm, cons, nr) if walls else nr
    no = _obstacle_rows(px, py, orows, ob, a_brk, prm, cons, nw) if orows.shape[0] else nw
    if no == 0:  # nothing within reach: the speed limit only
        return vdx, vdy, vddx, vddy
    for _ in range(PASSES):  # alternating projections onto the robots', walls' and obstacles'
        ux, uy, uxx, uyy = _project(cons, 0, no, vdx, vdy, vddx, vddy, pdx, pdy, lag, False)
        same = _same(ux, vdx) and _same(uy, vdy) and _same(uxx, vddx) and _same(uyy, vddy)
        vdx, vdy, vddx, vddy = ux, uy, uxx, uyy
        if same:  # a pass that changed nothing: every later pass would leave it as it is
            break
    qx, qy, _a, _b = _project(cons, 0, nr, vdx, vdy, vddx, vddy, pdx, pdy, lag, False)
    squeezed = abs(qx - vdx) + abs(qy - vdy)
    if walls:
        fx, fy, _c, _d = _project(cons, nr, nw, vdx, vdy, vddx, vddy, pdx, pdy, lag, False)
        squeezed += abs(fx - vdx) + abs(fy - vdy)
    if squeezed > 1e-9:  # between a robot or wall and an obstacle
        found = False
        if walls:  # along the wall, out of the obstacle's way (S16.1)
            found, ex, ey = _escape(vx0, vy0, (px, py, pdx, pdy), rb, orows, ob.c, ob.v, ob.phi,
                                    ob.phi_dot, ob.axes, a_brk, prm, cons[no:])
            if found:  # robots in the way: no escape
                qx, qy, _a, _b = _project(cons, 0, nr, ex, ey, 0.0, 0.0, pdx, pdy, lag, False)
                found = abs(qx - ex) + abs(qy - ey) <= 1e-9
        if found:
            vdx, vdy, vddx, vddy = ex, ey, 0.0, 0.0
        else:  # stop (obstacles may move it)
            vdx, vdy, vddx, vddy = 0.0, 0.0, 0.0, 0.0
    # the braking acceleration where the robot's own velocity is beyond the limits
    return _project(cons, 0, no, vdx, vdy, vddx, vddy, pdx, pdy, lag, True)
