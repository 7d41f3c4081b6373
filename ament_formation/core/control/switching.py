"""A robot's switching between its modes, as a transition table with named guards
(docs/control-law.md S8.7), and the progress monitor (S8.9).

Modes (one int per robot): ``MODE_C`` coordination (S4), ``MODE_OBSTACLE`` A(j) on obstacle j's
limit cycle (S6), ``MODE_YIELD`` A(k, yield) and ``MODE_MUTUAL`` A(k, mutual) round robot k (S7).
Two authorities own them (S7.1): each robot decides its own obstacle modes (this module:
:func:`robot_transitions`, safety must not wait for the network), the coordinator decides every
robot-robot encounter (core/control/arbitration.py). A robot applies the coordinator's
assignment (:func:`apply_assignment`) unless it is on an obstacle (static obstacles beat robots).

The robot's table (S8.7), rows tried in this order each decision period:

====  ==========  ========================================  ===================================
row   from        guard                                     to
====  ==========  ========================================  ===================================
R1    A(j)        not ``parked``, the other way keeps to    A(j), the other sense
                  the floor, and ``stalled`` or (T_min
                  after the entry, no other robot on j
                  its way) the floor closes the way ahead
R2    A(j)        ``more_urgent(j')``                       A(j') (sense kept between two
                                                            static obstacles, S6.6 rule 5)
R3    A(j)        ``cleared(j)`` held T_dwell, T_min in A   C (cool-down starts)
R4    C, robot    ``obstacle_threat(j)`` (from a robot      A(j), sense by ``choose_sense``
      encounter   encounter: an emergency, or the reason
                  dwell has passed)
====  ==========  ========================================  ===================================

Guards: ``obstacle_threat`` = S8.1 entry test (inside Q, heading into I, not cooling down) or an
emergency (inside E, or P reached within ``imminent_s``); ``more_urgent`` = S8.2;
``cleared`` = S8.3 items 1-3; ``stalled`` and ``parked`` = S8.9.
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.control.floor import cycle_inside, floor_side, has_floor
from ament_formation.core.control.limit_cycle import anomaly, choose_direction
from ament_formation.core.model.ellipse import ellipse_coords, h_value, ray_time, segment_hits

MODE_C = 0
MODE_OBSTACLE = 1
MODE_YIELD = 2
MODE_MUTUAL = 3
MODE_NAMES = ('coordination', 'obstacle', 'yield', 'mutual')
KIND_OBSTACLE = 1  # cool-down record: the last target was an obstacle ...
KIND_ROBOT = 2  # ... or a robot
INF = math.inf

Modes = namedtuple(
    'Modes',
    ['mode', 'tgt', 'sdir', 't_entry', 'since', 'last_kind', 'last_tgt', 'last_exit', 'wc',
     'wtgt', 'anchor', 't_anchor', 'park_at'],
)
Modes.__doc__ = """The switching state of N robots (rows), updated in place by the compiled code:
``mode`` (N,) int MODE_*; ``tgt`` (N,) int obstacle index or robot row (-1 in C); ``sdir`` (N,)
+1 CCW / -1 CW; ``t_entry`` (N,) [s]; ``since`` (N,) [s] start of the S8.3 dwell window (< 0: not
holding); ``last_kind``, ``last_tgt``, ``last_exit`` [s] the S8.4 cool-down record;
``wc``, ``wtgt`` (N, 2) [m/s] a mutual pair's drift w_c and its target (S7.3); ``anchor`` (N, 2)
[m] and ``t_anchor`` (N,) [s] the progress monitor's last anchor (S8.9); ``park_at`` (N,) [s]:
the S6.5 parking factor applies from then on (later while making way for a stalled robot,
S8.9).
"""


def new_modes(n: int) -> Modes:
    """:data:`Modes` of n robots in coordination."""
    return Modes(
        np.zeros(n, dtype=np.int64),
        np.full(n, -1, dtype=np.int64),
        np.ones(n),
        np.zeros(n),
        np.full(n, -1.0),
        np.zeros(n, dtype=np.int64),
        np.full(n, -1, dtype=np.int64),
        np.full(n, -1e9),
        np.zeros((n, 2)),
        np.zeros((n, 2)),
        np.full((n, 2), np.nan),
        np.zeros(n),
        np.full(n, -np.inf),
    )


Robots = namedtuple(
    'Robots',
    ['p', 'pd', 'goal', 'goal_dot', 'vc', 'team', 'rbody', 'parent', 'slot', 'known', 'origin'],
)
Robots.__doc__ = """Every robot as the decisions read it (rows in robot-id order): ``p``, ``pd``
(N, 2) controlled points [m] and their velocities [m/s]; ``goal``, ``goal_dot`` (N, 2) the
formation goal g [m] and its velocity [m/s] (S8.3 item 1); ``vc`` (N, 2) the coordination field
V_c [m/s]; ``team`` (N,) team-leader row; ``rbody`` (N,) body radii [m]; ``parent`` (N,) current
formation parent row (-1: root or unknown); ``slot`` (N, 2) formation slot c [m] (NaN: unknown);
``known`` (N,) bool: the row's data is current (a robot heard, S10.2); ``origin`` (N,) the original
parent row (S9 pi0; -1 for a leader).
"""


# --------------------------------------------------------------------------- events


@njit(cache=True, error_model='numpy', forceinline=True)
def event(ev, nev, t, i, enter, mode, target, s):
    """Write a mode event row [t_s, robot row, 1 enter / 0 exit, mode, target, sense]."""
    if nev < ev.shape[0]:
        ev[nev, 0] = t
        ev[nev, 1] = i
        ev[nev, 2] = 1.0 if enter else 0.0
        ev[nev, 3] = mode
        ev[nev, 4] = target
        ev[nev, 5] = s
    return nev + 1


@njit(cache=True, error_model='numpy', forceinline=True)
def leave(i, t, m, ev, nev):
    """Robot i leaves its mode for C (event exit); the S8.4 cool-down starts now."""
    nev = event(ev, nev, t, i, False, m.mode[i], m.tgt[i], m.sdir[i])
    m.last_kind[i] = KIND_OBSTACLE if m.mode[i] == MODE_OBSTACLE else KIND_ROBOT
    m.last_tgt[i] = m.tgt[i]
    m.last_exit[i] = t
    m.mode[i] = MODE_C
    m.tgt[i] = -1
    m.since[i] = -1.0
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def enter(i, t, mode, target, s, m, ev, nev):
    """Robot i enters ``mode`` toward ``target`` with sense ``s`` (event enter)."""
    m.mode[i] = mode
    m.tgt[i] = target
    m.sdir[i] = s
    m.t_entry[i] = t
    m.since[i] = -1.0
    m.park_at[i] = -INF
    return event(ev, nev, t, i, True, mode, target, s)


@njit(cache=True, error_model='numpy', forceinline=True)
def release(i, t, m, ev, nev):
    """Robot i leaves a robot encounter; a mutual partner becomes a plain yielder to i (S8.3)."""
    if m.mode[i] == MODE_MUTUAL:
        k = m.tgt[i]
        if m.mode[k] == MODE_MUTUAL and m.tgt[k] == i:
            nev = event(ev, nev, t, k, False, MODE_MUTUAL, i, m.sdir[k])
            m.mode[k] = MODE_YIELD
            m.since[k] = -1.0
            nev = event(ev, nev, t, k, True, MODE_YIELD, i, m.sdir[k])
    return leave(i, t, m, ev, nev)


# --------------------------------------------------------------------------- geometry guards


@njit(cache=True, error_model='numpy', forceinline=True)
def relative_velocity(zx, zy, vx, vy, cvx, cvy, phi_dot):
    """S14.2: the robot's velocity relative to the target's material point under it,
    p_dot - (c_dot + phi_dot J z).
    """
    return vx - cvx + phi_dot * zy, vy - cvy - phi_dot * zx


@njit(cache=True, error_model='numpy', forceinline=True)
def _h_dot(zx, zy, rvx, rvy, phi, r1, r2):
    """dh/dt up to a positive factor: grad h . z_dot_rel (S6.4, S6.3(b))."""
    u, w = ellipse_coords(zx, zy, phi, r1, r2)
    du, dw = ellipse_coords(rvx, rvy, phi, r1, r2)
    return 2.0 * (u * du + w * dw)


# implements: S8.1
@njit(cache=True, error_model='numpy', forceinline=True)
def threat_test(zx, zy, rvx, rvy, phi, r1, r2, q_scale, prm):
    """S8.1 entry test of one target P = (r1, r2) seen from z, relative velocity rv, protected
    region Q = ``q_scale`` P -> (triggered, emergency, lam_in [s], h_em, h_l).

    ``triggered``: inside Q, the ray along rv meets I and dh/dt < 0 (cool-down is the caller's);
    ``emergency``: inside E, or inside Q approaching with the ray reaching P within
    ``imminent_s`` (S14.2).
    """
    hdot = _h_dot(zx, zy, rvx, rvy, phi, r1, r2)
    h_em = h_value(zx, zy, phi, prm.emergency_scale * r1, prm.emergency_scale * r2)
    h_q = h_value(zx, zy, phi, q_scale * r1, q_scale * r2)
    h_l = h_value(zx, zy, phi, prm.limit_cycle_scale * r1, prm.limit_cycle_scale * r2)
    lam_in = INF
    triggered = False
    emergency = h_em < 0.0
    if h_q < 0.0 and hdot < 0.0:
        lam_in = ray_time(zx, zy, rvx, rvy, phi, prm.heading_scale * r1, prm.heading_scale * r2)
        triggered = lam_in < INF
        if not emergency:
            emergency = ray_time(zx, zy, rvx, rvy, phi, r1, r2) < prm.imminent_s
    return triggered, emergency, lam_in, h_em, h_l


# implements: S8.3
@njit(cache=True, error_model='numpy', forceinline=True)
def cleared(px, py, gx, gy, vcx, vcy, cx, cy, cvx, cvy, phi, phi_dot, r1, r2, prm):
    """S8.3 items 1-3 against one target P (centre c, velocity c_dot, orientation phi): the
    segment [p, g] misses C = rho_clr P; outside E; the coordination field V_c the robot would
    switch to does not pass the heading test against I (relative to the material point).
    """
    zx = px - cx
    zy = py - cy
    if segment_hits(px, py, gx, gy, cx, cy, phi, prm.clearance_scale * r1,
                    prm.clearance_scale * r2):
        return False
    if h_value(zx, zy, phi, prm.emergency_scale * r1, prm.emergency_scale * r2) < 0.0:
        return False
    rvx, rvy = relative_velocity(zx, zy, vcx, vcy, cvx, cvy, phi_dot)
    if _h_dot(zx, zy, rvx, rvy, phi, r1, r2) >= 0.0:
        return True
    return ray_time(zx, zy, rvx, rvy, phi, prm.heading_scale * r1, prm.heading_scale * r2) == INF


@njit(cache=True, error_model='numpy', forceinline=True)
def dwell_exit(holds, t, i, m, prm):
    """S8.3 item 4: items 1-3 have held for T_dwell and the robot has been T_min in its mode."""
    if not holds:
        m.since[i] = -1.0
        return False
    if m.since[i] < 0.0:
        m.since[i] = t
    return t - m.since[i] >= prm.dwell_s - 1e-9 and t - m.t_entry[i] >= prm.min_avoid_s - 1e-9


@njit(cache=True, error_model='numpy', forceinline=True)
def cooling(kind, target, t, i, m, prm):
    """S8.4: a heading-triggered re-entry to the target just left waits T_cool."""
    return m.last_kind[i] == kind and m.last_tgt[i] == target and (
        t - m.last_exit[i] < prm.cooldown_s
    )


@njit(cache=True, error_model='numpy', forceinline=True)
def ranks_before(em, h_em, lam, best, b_em, b_hem, b_lam):
    """S8.1 ranking: emergencies first (smallest h_em), then the earliest contact (smallest
    lambda); ``best`` < 0: nothing ranked yet.
    """
    if best < 0:
        return True
    if em != b_em:
        return em
    return h_em < b_hem if em else lam < b_lam


# --------------------------------------------------------------------------- progress monitor


# implements: S8.9
@njit(cache=True, error_model='numpy', forceinline=True)
def stalled(i, t, p, anchor, t_anchor, prm):
    """S8.9 progress monitor of robot i at p (its ``anchor`` (N, 2) and ``t_anchor`` (N,)):
    re-anchors when the robot has moved more than ``stall_distance_m`` from its anchor; True
    when it has not for ``stall_time_s``. Whoever owns the robot's mode acts (R1, the
    coordinator's C3-C5, C9) and re-anchors (:func:`anchor_at`).
    """
    ax, ay = anchor[i, 0], anchor[i, 1]
    if not (math.hypot(p[i, 0] - ax, p[i, 1] - ay) <= prm.stall_distance_m):  # NaN: first call
        anchor_at(i, t, p, anchor, t_anchor)
        return False
    return t - t_anchor[i] >= prm.stall_time_s


@njit(cache=True, error_model='numpy', forceinline=True)
def anchor_at(i, t, p, anchor, t_anchor):
    """The progress monitor of robot i starts again at p."""
    anchor[i, 0] = p[i, 0]
    anchor[i, 1] = p[i, 1]
    t_anchor[i] = t


@njit(cache=True, error_model='numpy', forceinline=True)
def progress(i, t, p, m, prm):
    """:func:`stalled` on the monitor of ``m`` (:data:`Modes`)."""
    return stalled(i, t, p, m.anchor, m.t_anchor, prm)


@njit(cache=True, error_model='numpy', forceinline=True)
def reanchor(i, t, p, m):
    """The monitor of ``m`` starts again at robot i's p (after it acted)."""
    anchor_at(i, t, p, m.anchor, m.t_anchor)


@njit(cache=True, error_model='numpy', forceinline=True)
def begin_episode(i, t, p, m, prm):
    """Robot i leaves C for an avoidance: its monitor starts again, unless it left an avoidance
    less than ``stall_time_s`` ago (one episode: a robot that flips between reasons without
    moving stays stalled, S8.9).
    """
    if t - m.last_exit[i] >= prm.stall_time_s:
        reanchor(i, t, p, m)


@njit(cache=True, error_model='numpy', forceinline=True)
def parked(px, py, gx, gy, cx, cy, phi, r1, r2, prm):
    """S8.9/S6.5: the goal's anomaly on the limit cycle is within the parking anomaly of the
    robot's: the field asks it to wait there (it is not stalled, it is parked).
    """
    big1 = prm.limit_cycle_scale * r1
    big2 = prm.limit_cycle_scale * r2
    dd = anomaly(gx - cx, gy - cy, phi, big1, big2) - anomaly(px - cx, py - cy, phi, big1, big2)
    return abs((dd + math.pi) % (2.0 * math.pi) - math.pi) <= prm.parking_anomaly_rad


# --------------------------------------------------------------------------- the robot's table


@njit(cache=True, error_model='numpy', forceinline=True)
def obstacle_candidate(i, t, robots, ob, m, prm, rows):
    """Guard ``obstacle_threat`` of robot i over the obstacle rows ``rows`` (ascending; at least
    those of :func:`robot_transitions_among`) (S8.1, S14.2) -> (best candidate j or -1, its
    emergency flag, its h_L, emergency and h_L of the obstacle the robot is on now).
    """
    p, pd = robots.p, robots.pd
    best, b_em, b_hem, b_lam, b_hl = -1, False, INF, INF, INF
    cur_em, cur_hl = False, INF
    for j in rows:
        zx = p[i, 0] - ob.c[j, 0]
        zy = p[i, 1] - ob.c[j, 1]
        on_j = m.mode[i] == MODE_OBSTACLE and m.tgt[i] == j
        reach = prm.protected_scale * ob.axes[j, 0]
        if zx * zx + zy * zy >= reach * reach and not on_j:
            continue
        rvx, rvy = relative_velocity(zx, zy, pd[i, 0], pd[i, 1], ob.v[j, 0], ob.v[j, 1],
                                     ob.phi_dot[j])
        trig, em, lam, h_em, h_l = threat_test(zx, zy, rvx, rvy, ob.phi[j], ob.axes[j, 0],
                                               ob.axes[j, 1], prm.protected_scale, prm)
        if on_j:
            cur_em, cur_hl = em, h_l
            continue
        if not em and (not trig or cooling(KIND_OBSTACLE, j, t, i, m, prm)):
            continue
        if ranks_before(em, h_em, lam, best, b_em, b_hem, b_lam):
            best, b_em, b_hem, b_lam, b_hl = j, em, h_em, lam, h_l
    return best, b_em, b_hl, cur_em, cur_hl


@njit(cache=True, error_model='numpy', forceinline=True)
def sense_on(i, j, robots, m):
    """The sense of a known robot other than i on obstacle j (S14.6: one sense per obstacle), 0
    when there is none.
    """
    for q in range(m.mode.shape[0]):
        if q != i and robots.known[q] and m.mode[q] == MODE_OBSTACLE and m.tgt[q] == j:
            return m.sdir[q]
    return 0.0


@njit(cache=True, error_model='numpy', forceinline=True)
def choose_sense(i, j, robots, ob, m, prm):
    """The sense of robot i entering obstacle j: the sense of a robot already on j (one sense per
    obstacle, S14.6), else S6.6 rules 1-4; then S16.2 (the floor).
    """
    shared = sense_on(i, j, robots, m)
    if shared != 0.0:
        return shared
    p, pd, goal, gd = robots.p, robots.pd, robots.goal, robots.goal_dot
    zx, zy = p[i, 0] - ob.c[j, 0], p[i, 1] - ob.c[j, 1]
    rvx, rvy = relative_velocity(zx, zy, pd[i, 0], pd[i, 1], ob.v[j, 0], ob.v[j, 1],
                                 ob.phi_dot[j])
    big1, big2 = prm.limit_cycle_scale * ob.axes[j, 0], prm.limit_cycle_scale * ob.axes[j, 1]
    s = choose_direction(zx, zy, rvx, rvy, goal[i, 0] - ob.c[j, 0], goal[i, 1] - ob.c[j, 1],
                         gd[i, 0] - ob.v[j, 0], gd[i, 1] - ob.v[j, 1], ob.phi[j], big1, big2,
                         2.0 * prm.protected_scale * ob.axes[j, 0], True)
    s, _ = floor_side(s, p[i, 0], p[i, 1], goal[i, 0], goal[i, 1], ob.c[j, 0], ob.c[j, 1],
                      ob.phi[j], big1, big2, robots.rbody[i] + prm.safety_gap_m, prm)
    return s


@njit(cache=True, error_model='numpy', forceinline=True)
def _reverse_on_obstacle(i, j, t, robots, ob, m, prm, ev, nev):
    """Row R1: a robot on obstacle j's limit cycle, not parked, turns the other way when it is
    stalled, or when the floor closes its way ahead while the other way is open and no other
    robot goes round j its way (S16.2: an obstacle moving toward an edge narrows the arc ahead
    after the entry chose it; S14.6), in either case unless the floor closes the other way
    (S8.9, S16.2). Returns (acted, nev).
    """
    p, goal = robots.p, robots.goal
    stuck = progress(i, t, p, m, prm)
    big1, big2 = prm.limit_cycle_scale * ob.axes[j, 0], prm.limit_cycle_scale * ob.axes[j, 1]
    clear = robots.rbody[i] + prm.safety_gap_m
    if not stuck and (not has_floor(prm) or cycle_inside(ob.c[j, 0], ob.c[j, 1], ob.phi[j],
                                                         big1, big2, clear, prm)):
        # the answer below without its arcs: no floor, or none near the whole cycle (floor_side
        # would keep the sense, so not closed ahead), and not stalled
        return False, nev
    if parked(p[i, 0], p[i, 1], goal[i, 0], goal[i, 1], ob.c[j, 0], ob.c[j, 1], ob.phi[j],
              ob.axes[j, 0], ob.axes[j, 1], prm):
        return False, nev
    s = m.sdir[i]  # here stalled, or near an edge of a declared floor
    kept, other_open = floor_side(s, p[i, 0], p[i, 1], goal[i, 0], goal[i, 1], ob.c[j, 0],
                                  ob.c[j, 1], ob.phi[j], big1, big2, clear, prm)
    closed_ahead = (kept != s and t - m.t_entry[i] >= prm.min_avoid_s - 1e-9
                    and sense_on(i, j, robots, m) != s)  # not against one sense per obstacle
    if not (stuck or closed_ahead) or not other_open:
        return False, nev  # progressing on an open way, or the floor closes the other way
    reanchor(i, t, p, m)
    nev = leave(i, t, m, ev, nev)
    return True, enter(i, t, MODE_OBSTACLE, j, -s, m, ev, nev)


@njit(cache=True, error_model='numpy')
def threat_radius(ob, prm):
    """(M,) [m] per obstacle: the half-side of a square about its centre beyond which
    :func:`obstacle_candidate` skips it (Q's reach ``protected_scale`` r1, widened by 1e-9
    relative so that no rounding of the squared test falls outside).
    """
    return prm.protected_scale * ob.axes[:, 0] * (1.0 + 1e-9) + 1e-12


# implements: S8, S8.7
@njit(cache=True, error_model='numpy')
def robot_transitions(i, t, robots, ob, m, prm, ev, nev):
    """One decision of robot i's own table (module docstring, rows R1-R4) on ``robots``
    (:data:`Robots`), obstacles ``ob`` (ObstacleSnapshot) and the switching state ``m``
    (:data:`Modes`, row i updated in place; a mutual partner demoted, S8.3). Returns the event
    count.
    """
    return robot_transitions_among(i, t, robots, ob, m, prm, ev, nev,
                                   np.arange(ob.c.shape[0]))


@njit(cache=True, error_model='numpy', forceinline=True)
def robot_transitions_among(i, t, robots, ob, m, prm, ev, nev, orows):
    """:func:`robot_transitions` with the obstacle rows ``orows`` (ascending) the guard
    ``obstacle_threat`` tests: every obstacle whose square of :func:`threat_radius` holds the
    robot, and the one it is on (the others cannot pass the guard; the simulator finds them by a
    grid once per decision instead of testing all M for each robot).
    """
    jn, em_n, hl_n, cur_em, cur_hl = obstacle_candidate(i, t, robots, ob, m, prm, orows)
    md = m.mode[i]
    if md == MODE_OBSTACLE:
        j = m.tgt[i]
        acted, nev = _reverse_on_obstacle(i, j, t, robots, ob, m, prm, ev, nev)  # R1
        if acted:
            return nev
        # R2: more_urgent; back to the obstacle just left only reason_dwell_s after the switch,
        # emergencies included (between two near obstacles they alternate, S8.4)
        back = m.last_kind[i] == KIND_OBSTACLE and m.last_tgt[i] == jn and (
            t - m.t_entry[i] < prm.reason_dwell_s)
        if jn >= 0 and not cur_em and (em_n or hl_n < cur_hl) and not back:
            sweep = ob.static[j] and ob.static[jn]
            s = m.sdir[i] if sweep else choose_sense(i, jn, robots, ob, m, prm)
            nev = leave(i, t, m, ev, nev)
            return enter(i, t, MODE_OBSTACLE, jn, s, m, ev, nev)
        p, g, vc = robots.p, robots.goal, robots.vc
        holds = cleared(p[i, 0], p[i, 1], g[i, 0], g[i, 1], vc[i, 0], vc[i, 1], ob.c[j, 0],
                        ob.c[j, 1], ob.v[j, 0], ob.v[j, 1], ob.phi[j], ob.phi_dot[j],
                        ob.axes[j, 0], ob.axes[j, 1], prm)
        if dwell_exit(holds, t, i, m, prm):  # R3
            nev = leave(i, t, m, ev, nev)
        return nev
    if jn < 0:
        return nev
    if md != MODE_C:  # R4 from a robot encounter: static obstacles beat robots (S7), not at once
        h_em = h_value(robots.p[i, 0] - ob.c[jn, 0], robots.p[i, 1] - ob.c[jn, 1], ob.phi[jn],
                       prm.emergency_scale * ob.axes[jn, 0], prm.emergency_scale * ob.axes[jn, 1])
        if h_em >= 0.0 and t - m.t_entry[i] < prm.reason_dwell_s:
            return nev
        nev = release(i, t, m, ev, nev)
    else:
        begin_episode(i, t, robots.p, m, prm)
    s = choose_sense(i, jn, robots, ob, m, prm)
    return enter(i, t, MODE_OBSTACLE, jn, s, m, ev, nev)


# --------------------------------------------------------------------------- assignments


@njit(cache=True, error_model='numpy')
def apply_assignment(i, t, a_mode, a_row, a_sense, a_t_entry, a_wx, a_wy, a_park_at, m, ev,
                     nev):
    """The coordinator's robot encounter for robot i (S7.1): ``a_mode`` MODE_YIELD/MODE_MUTUAL
    toward row ``a_row`` (MODE_C / -1: none) with its sense, entry time, a pair's drift w_c and
    when its parking factor applies (``a_park_at`` [s]). On an obstacle the robot keeps its own
    mode (static obstacles beat robots; its report tells the coordinator) and takes only a
    request to make way (``a_park_at``: no parking until then, S8.9). A different or withdrawn
    assignment ends the encounter in force.
    """
    md = m.mode[i]
    if md == MODE_OBSTACLE:
        m.park_at[i] = max(m.park_at[i], a_park_at)
        return nev
    if a_mode == MODE_C or a_row < 0:
        if md != MODE_C:
            nev = leave(i, t, m, ev, nev)
        return nev
    same = md == a_mode and m.tgt[i] == a_row and m.sdir[i] == a_sense
    if not same:
        if md != MODE_C:
            nev = leave(i, t, m, ev, nev)
        nev = enter(i, t, a_mode, a_row, a_sense, m, ev, nev)
    m.t_entry[i] = a_t_entry
    m.park_at[i] = a_park_at
    m.wc[i, 0] = a_wx
    m.wc[i, 1] = a_wy
    m.wtgt[i, 0] = a_wx
    m.wtgt[i, 1] = a_wy
    return nev
