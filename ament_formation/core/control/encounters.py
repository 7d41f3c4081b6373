"""Robot-robot encounters (spec S7) and the decision step that runs the S8 automaton of every
robot.

:func:`decide` is the one decision function used by the simulator (all robots at once, at the
decision rate) and by :class:`ament_formation.core.control.controller.RobotController` (the same
call on
the robots it knows about). It

1. evaluates the S8.1 entry test of every robot against every obstacle (emergencies first, then
   the earliest contact);
2. finds robot pairs inside the robot protected circle with a uniform grid (spatial culling, cell =
   the largest protected radius), and evaluates the same entry test on each pair (S7: P is the
   circle of radius R_aa = R_body,i + R_body,k + margin, the neighbour's velocity is x~dot);
3. runs the obstacle transitions of the automaton (entry, S8.2 re-targeting, S8.3 exit);
4. arbitrates robot-robot encounters over *all* robots together (S7 rules, S14.1):
   * static obstacles beat robots; a robot avoiding an obstacle is stand-on, a free robot yields to
   it;
   * two free robots that threaten each other form a **mutual pair** (one common sense s: the S6.6
     sense of each round the other when they agree, else +1; mu = 1, shared w_c);
   * the directed reacts-to graph (i -> k when i uses k's velocity) stays acyclic except for mutual
     pairs: if k already reacts to i, directly or through a chain, i does not react, unless it is
     in
     an emergency, in which case the pair is converted to a mutual pair (k drops its target, a
     third
     robot that was mutual with i or k becomes a plain yielder);
   * two stand-on robots: the higher ID yields, and only in an emergency;
   * every robot picks its most urgent admissible threat among all robots (so a robot yielding to a
     busy robot re-targets to that robot's partner when the partner becomes more urgent, S14.1);
5. runs the S8.3 exits of yielding robots and the joint exit of mutual pairs;
6. refreshes the drift target of each mutual pair: w_c relaxes (time constant
``mutual_drift_tau_s``)
   from the frozen 1/2 (p_dot_i + p_dot_k)(t_s) toward the mean of the two coordination fields, so
   the drift does not outlive its reason (S14.1); the relative motion z_dot = F(z) is unaffected.

S14.3: a pair of teammates whose relative speed is below ``teammate_rel_speed_mps`` is not a
threat (only an emergency counts), whatever their modes: a teammate busy with an obstacle or
another robot but moving with us is no reason to leave the slot; a pair released from an
encounter with each other stays exempt up to ``teammate_release_speed_mps`` (hysteresis against
the jitter of an estimated relative speed; docs/law-changes.md §11). A robot threat needs a
contact with I within ``agent_horizon_s``.

Mode events are written to ``ev`` rows [t_s, robot_index, event (1 enter, 0 exit), mode, target,
direction]; the call returns the new event count.
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.control.automaton import (
    exit_conditions,
    exit_timer,
    in_cooldown,
    INF,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    relative_velocity,
    threat_test,
    threat_test_q,
)
from ament_formation.core.control.limit_cycle import anomaly, choose_direction
from ament_formation.core.model.ellipse import h_value
from ament_formation.core.model.obstacles import ObstacleSnapshot

KIND_OBSTACLE = 1  # cool-down bookkeeping: last target was an obstacle
KIND_AGENT = 2  # ... or a robot
MAX_THREATS = 8  # robot threats kept per robot and decision
RETARGET_MARGIN = 0.1  # S8.2 between robots: the new h_L must be lower by this (hysteresis)
STUCK_S = 5.0  # liveness: a robot held still this long on its limit cycle reverses its sense
STILL_MPS = 0.005  # ... "still": |p_dot| below this


@njit(cache=True)
def keepout_radius(rbody, i, k, prm):
    """R_aa of the pair (S7): R_body,i + R_body,k + margin (= 2 R_body + 0.05 m by default)."""
    return rbody[i] + rbody[k] + prm.agent_keepout_margin_m


@njit(cache=True)
def candidate_pairs(p, cell_m):
    """Robot pairs (i < k) closer than ``cell_m``, found with a uniform grid.
    p (N, 2) -> (P, 2) int.
    """
    n = p.shape[0]
    out = np.empty((max(16, 8 * n), 2), dtype=np.int64)
    cnt = 0
    if n < 2:
        return out[:0]
    if n <= 32:
        for i in range(n):
            for k in range(i + 1, n):
                dx = p[i, 0] - p[k, 0]
                dy = p[i, 1] - p[k, 1]
                if dx * dx + dy * dy < cell_m * cell_m:
                    if cnt >= out.shape[0]:
                        out = np.concatenate((out, np.empty_like(out)))
                    out[cnt, 0] = i
                    out[cnt, 1] = k
                    cnt += 1
        return out[:cnt]
    x0 = p[:, 0].min()
    y0 = p[:, 1].min()
    ix = np.empty(n, dtype=np.int64)
    iy = np.empty(n, dtype=np.int64)
    for i in range(n):
        ix[i] = int(math.floor((p[i, 0] - x0) / cell_m))
        iy[i] = int(math.floor((p[i, 1] - y0) / cell_m))
    nx = ix.max() + 1
    ny = iy.max() + 1
    if nx * ny > 16 * n + 4096:  # sparse, huge arena: fall back to one cell column per x
        ny = 1
        for i in range(n):
            iy[i] = 0
    # counting sort of the robots by cell (dense grid of nx * ny cells)
    cell = ix * ny + iy
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        members[fill[cell[i]]] = i
        fill[cell[i]] += 1
    c2 = cell_m * cell_m
    for i in range(n):
        for dx in range(-1, 2):
            cx = ix[i] + dx
            if cx < 0 or cx >= nx:
                continue
            for dy in range(-1, 2):
                cy = iy[i] + dy
                if cy < 0 or cy >= ny:
                    continue
                c = cx * ny + cy
                for q in range(start[c], start[c + 1]):
                    k = members[q]
                    if k <= i:
                        continue
                    ddx = p[i, 0] - p[k, 0]
                    ddy = p[i, 1] - p[k, 1]
                    if ddx * ddx + ddy * ddy < c2:
                        if cnt >= out.shape[0]:
                            out = np.concatenate((out, np.empty_like(out)))
                        out[cnt, 0] = i
                        out[cnt, 1] = k
                        cnt += 1
    return out[:cnt]


@njit(cache=True)
def reacts_to(k, i, mode, tgt, parent):
    """True when robot k reacts to robot i directly or through a chain of following links: yields
    (S7) and formation tracking links to the current parent (S4; ``parent`` row or -1), whose
    velocity and acceleration are feed-forward too (S14.5).
    """
    cur = k
    for _ in range(mode.shape[0] + 1):
        if mode[cur] == MODE_C:
            nxt = parent[cur]
            if nxt < 0:
                return False
        elif mode[cur] == MODE_YIELD or mode[cur] == MODE_MUTUAL:
            nxt = tgt[cur]
        else:
            return False
        if nxt == i:
            return True
        if mode[cur] == MODE_MUTUAL:
            return False  # the partner only reacts back to cur
        cur = nxt
    return False


DecisionRobots = namedtuple(
    'DecisionRobots', ['p', 'pd', 'goal', 'goal_dot', 'vc', 'team', 'rbody', 'parent', 'slot']
)
DecisionRobots.__doc__ = """Every robot as :func:`decide` reads it (rows in robot-ID order):
``p``, ``pd`` (N, 2) controlled-point positions [m] (C-contiguous) and velocities [m/s];
``goal``, ``goal_dot`` (N, 2) formation goal g_i [m] and g_i_dot [m/s] (leader r(t); follower p of
its *original* parent + delta, S8.3 item 1); ``vc`` (N, 2) coordination field V_c [m/s] (exit
test); ``team`` (N,) int team-leader row (S14.3); ``rbody`` (N,) body radius [m]; ``parent`` (N,)
current formation parent row (-1: root or unknown), for the acyclicity of every following link
(S14.5); ``slot`` (N, 2) formation slot c_i relative to the team leader [m] (S1; NaN: unknown),
for a teammate's protected region (§22).
"""

ObstacleThreats = namedtuple(
    'ObstacleThreats', ['j', 'em', 'lam', 'h_em', 'h_l', 'cur_em', 'cur_h_l']
)
ObstacleThreats.__doc__ = """Stage 1 of :func:`decide`, per robot (N,): the best obstacle entry
candidate ``j`` (-1: none), its emergency flag ``em``, ray time ``lam`` [s] and levels ``h_em``,
``h_l``; ``cur_em``, ``cur_h_l``: emergency flag and h_L of the obstacle the robot avoids now.
"""

RobotThreats = namedtuple('RobotThreats', ['k', 'em', 'lam', 'h_em', 'count'])
RobotThreats.__doc__ = """Stage 2 of :func:`decide`: the robot threats of each robot, (N,
MAX_THREATS) rows ``k`` (robot row), ``em``, ``lam`` [s], ``h_em``; ``count`` (N,) used slots.
"""


@njit(cache=True)
def _event(ev, nev, t, i, enter, mode, target, s):
    if nev < ev.shape[0]:
        ev[nev, 0] = t
        ev[nev, 1] = i
        ev[nev, 2] = 1.0 if enter else 0.0
        ev[nev, 3] = mode
        ev[nev, 4] = target
        ev[nev, 5] = s
    return nev + 1


@njit(cache=True)
def _leave(i, t, auto, ev, nev):
    """Leave the current avoidance target (event 'exit'); the cool-down starts now."""
    mode, tgt = auto.mode, auto.tgt
    nev = _event(ev, nev, t, i, False, mode[i], tgt[i], auto.sdir[i])
    auto.last_kind[i] = KIND_OBSTACLE if mode[i] == MODE_OBSTACLE else KIND_AGENT
    auto.last_tgt[i] = tgt[i]
    auto.last_exit[i] = t
    mode[i] = MODE_C
    tgt[i] = -1
    auto.since[i] = -1.0
    return nev


@njit(cache=True)
def _enter(i, t, kind, target, s, auto, ev, nev):
    auto.mode[i] = kind
    auto.tgt[i] = target
    auto.sdir[i] = s
    auto.t_entry[i] = t
    auto.since[i] = -1.0
    auto.sweep_s[i] = 0.0
    return _event(ev, nev, t, i, True, kind, target, s)


@njit(cache=True)
def _demote_partner(a, t, auto, ev, nev):
    """The mutual partner m of robot a becomes a plain yielder to a (events exit, enter)."""
    m = auto.tgt[a]
    nev = _event(ev, nev, t, m, False, MODE_MUTUAL, a, auto.sdir[m])
    auto.mode[m] = MODE_YIELD
    auto.since[m] = -1.0
    return _event(ev, nev, t, m, True, MODE_YIELD, a, auto.sdir[m])


@njit(cache=True)
def _release(i, t, auto, ev, nev):
    """Drop i's current target; a mutual partner becomes a plain yielder to i (S8.3)."""
    mode, tgt = auto.mode, auto.tgt
    if mode[i] == MODE_C:
        return nev
    if mode[i] == MODE_MUTUAL:
        k = tgt[i]
        if mode[k] == MODE_MUTUAL and tgt[k] == i:
            nev = _demote_partner(i, t, auto, ev, nev)
    return _leave(i, t, auto, ev, nev)


@njit(cache=True)
def _arc_leaves_floor(cx, cy, phi, big_r1, big_r2, psi0, dpsi, clear, prm):
    """Whether the limit cycle's arc from anomaly ``psi0`` over ``dpsi`` (signed) passes closer
    than ``clear`` to an edge of the declared floor (16 samples per turn, ends included).
    """
    c = math.cos(phi)
    s = math.sin(phi)
    m = max(2, int(abs(dpsi) / (2.0 * math.pi) * 16.0) + 2)
    for q in range(m + 1):
        psi = psi0 + dpsi * q / m
        u = big_r1 * math.cos(psi)
        w = big_r2 * math.sin(psi)
        x = cx + c * u - s * w
        y = cy + s * u + c * w
        if (
            x - clear < prm.floor_x_min_m
            or x + clear > prm.floor_x_max_m
            or y - clear < prm.floor_y_min_m
            or y + clear > prm.floor_y_max_m
        ):
            return True
    return False


@njit(cache=True)
def _floor_side(i, j, sense, robots, obstacles, prm):
    """The rotation sense that keeps to the floor: ``sense``, unless its limit-cycle arc from robot
    i to its goal passes closer than R_i + ``safety_gap_m`` to a floor edge while the other
    side's arc does not (docs/law-changes.md section 9).
    """
    big_r1 = prm.limit_cycle_scale * obstacles.axes[j, 0]
    big_r2 = prm.limit_cycle_scale * obstacles.axes[j, 1]
    cx, cy, phi = obstacles.c[j, 0], obstacles.c[j, 1], obstacles.phi[j]
    p, goal = robots.p, robots.goal
    psi_a = anomaly(p[i, 0] - cx, p[i, 1] - cy, phi, big_r1, big_r2)
    psi_g = anomaly(goal[i, 0] - cx, goal[i, 1] - cy, phi, big_r1, big_r2)
    ccw = (psi_g - psi_a) % (2.0 * math.pi)
    arc = ccw if sense > 0.0 else ccw - 2.0 * math.pi
    other = arc - 2.0 * math.pi if sense > 0.0 else arc + 2.0 * math.pi
    clear = robots.rbody[i] + prm.safety_gap_m
    if _arc_leaves_floor(cx, cy, phi, big_r1, big_r2, psi_a, arc, clear, prm):
        if not _arc_leaves_floor(cx, cy, phi, big_r1, big_r2, psi_a, other, clear, prm):
            return -sense
    return sense


@njit(cache=True)
def _still_for(i, t, robots, auto):
    """Robot i has been in its mode (or current sense, or sweep round static obstacles, §26) for
    ``STUCK_S`` and is still now.
    """
    speed = math.hypot(robots.pd[i, 0], robots.pd[i, 1])
    return t - auto.t_entry[i] + auto.sweep_s[i] >= STUCK_S and speed <= STILL_MPS


@njit(cache=True)
def _held_still(i, j, t, robots, obstacles, auto, prm):
    """Liveness (docs/law-changes.md section 8): robot i has been on obstacle j's limit cycle (or
    in its current sense) for ``STUCK_S``, is still now, and is not parked (its goal's anomaly is
    more than the parking anomaly away, so its field asks for full tangential speed).
    """
    if not _still_for(i, t, robots, auto):
        return False
    r1 = prm.limit_cycle_scale * obstacles.axes[j, 0]
    r2 = prm.limit_cycle_scale * obstacles.axes[j, 1]
    cx, cy, phi = obstacles.c[j, 0], obstacles.c[j, 1], obstacles.phi[j]
    psi_a = anomaly(robots.p[i, 0] - cx, robots.p[i, 1] - cy, phi, r1, r2)
    psi_g = anomaly(robots.goal[i, 0] - cx, robots.goal[i, 1] - cy, phi, r1, r2)
    dd = (psi_g - psi_a + math.pi) % (2.0 * math.pi) - math.pi
    return abs(dd) > prm.parking_anomaly_rad


@njit(cache=True)
def _held_by_robot(i, k, t, robots, auto, prm):
    """Liveness (docs/law-changes.md §21): robot i has been yielding to robot k (or in its
    current sense) for ``STUCK_S``, is still now, and is not parked (its goal, seen from k, is more
    than the parking anomaly away from it).
    """
    if not _still_for(i, t, robots, auto):
        return False
    p, goal = robots.p, robots.goal
    psi_a = math.atan2(p[i, 1] - p[k, 1], p[i, 0] - p[k, 0])
    psi_g = math.atan2(goal[i, 1] - p[k, 1], goal[i, 0] - p[k, 0])
    dd = (psi_g - psi_a + math.pi) % (2.0 * math.pi) - math.pi
    return abs(dd) > prm.parking_anomaly_rad


@njit(cache=True)
def _obstacle_dir(i, j, robots, obstacles, auto, prm):
    """S6.6 rotation sense of robot i entering obstacle j; one sense per obstacle for everyone on
    it (S14.6): a robot already circling j gives its sense.
    """
    mode, tgt = auto.mode, auto.tgt
    for q in range(mode.shape[0]):
        if q != i and mode[q] == MODE_OBSTACLE and tgt[q] == j:
            return auto.sdir[q]
    p, pd, goal, goal_dot = robots.p, robots.pd, robots.goal, robots.goal_dot
    oc, ov, oaxes = obstacles.c, obstacles.v, obstacles.axes
    zx = p[i, 0] - oc[j, 0]
    zy = p[i, 1] - oc[j, 1]
    rvx, rvy = relative_velocity(
        zx, zy, pd[i, 0], pd[i, 1], ov[j, 0], ov[j, 1], obstacles.phi_dot[j]
    )
    sense = choose_direction(
        zx,
        zy,
        rvx,
        rvy,
        goal[i, 0] - oc[j, 0],
        goal[i, 1] - oc[j, 1],
        goal_dot[i, 0] - ov[j, 0],
        goal_dot[i, 1] - ov[j, 1],
        obstacles.phi[j],
        prm.limit_cycle_scale * oaxes[j, 0],
        prm.limit_cycle_scale * oaxes[j, 1],
        2.0 * prm.protected_scale * oaxes[j, 0],
        True,
    )
    return _floor_side(i, j, sense, robots, obstacles, prm)


@njit(cache=True)
def _agent_dir(i, k, robots, prm):
    p, pd, goal, goal_dot = robots.p, robots.pd, robots.goal, robots.goal_dot
    r = keepout_radius(robots.rbody, i, k, prm)
    return choose_direction(
        p[i, 0] - p[k, 0],
        p[i, 1] - p[k, 1],
        pd[i, 0] - pd[k, 0],
        pd[i, 1] - pd[k, 1],
        goal[i, 0] - p[k, 0],
        goal[i, 1] - p[k, 1],
        goal_dot[i, 0] - pd[k, 0],
        goal_dot[i, 1] - pd[k, 1],
        0.0,
        prm.limit_cycle_scale * r,
        prm.limit_cycle_scale * r,
        2.0 * prm.protected_scale * r,
        False,
    )


@njit(cache=True)
def _agent_urgency(i, k, p, pd, rbody, prm):
    """(emergency, h_L) of robot k as seen from robot i."""
    r = keepout_radius(rbody, i, k, prm)
    zx = p[i, 0] - p[k, 0]
    zy = p[i, 1] - p[k, 1]
    trig, em, lam, h_em, h_l = threat_test(
        zx, zy, pd[i, 0] - pd[k, 0], pd[i, 1] - pd[k, 1], 0.0, r, r, prm
    )
    return em, h_l


@njit(cache=True)
def _reason_dwell(t, t_entry, h_stay, prm):
    """S14.2: a switch between an obstacle and a robot reason waits 2 T_min after the last switch,
    unless the robot is inside the obstacle's emergency ellipse (``h_stay`` = its h_em < 0); the
    safety barrier of the law covers the wait.
    """
    return t - t_entry < 2.0 * prm.min_avoid_s and h_stay >= 0.0


@njit(cache=True)
def _better(em, key_em, lam, best_set, best_em, best_key_em, best_lam):
    """S8.1 ranking: emergencies first (smallest h_em), then the earliest contact (smallest
    lambda).
    """
    if not best_set:
        return True
    if em and not best_em:
        return True
    if em and best_em:
        return key_em < best_key_em
    if not em and not best_em:
        return lam < best_lam
    return False


@njit(cache=True)
def _form_mutual(i, k, t, robots, auto, ev, nev, prm):
    """Convert/enter the mutual pair (i, k): same t_s, w_c = 1/2 (p_dot_i + p_dot_k)(t_s) (S7),
    and one sense s for both: the S6.6 sense of each round the other when the two agree, else +1
    (docs/law-changes.md section 14).
    """
    pd = robots.pd
    s = _agent_dir(i, k, robots, prm)
    if _agent_dir(k, i, robots, prm) != s:
        s = 1.0
    mode, tgt = auto.mode, auto.tgt
    for a in (i, k):
        if mode[a] == MODE_MUTUAL:
            m = tgt[a]
            if m != i and m != k and mode[m] == MODE_MUTUAL and tgt[m] == a:
                nev = _demote_partner(a, t, auto, ev, nev)
        if mode[a] != MODE_C:
            nev = _leave(a, t, auto, ev, nev)
    wx = 0.5 * (pd[i, 0] + pd[k, 0])
    wy = 0.5 * (pd[i, 1] + pd[k, 1])
    nev = _enter(i, t, MODE_MUTUAL, k, s, auto, ev, nev)
    nev = _enter(k, t, MODE_MUTUAL, i, s, auto, ev, nev)
    wc = auto.wc
    wc[i, 0] = wx
    wc[i, 1] = wy
    wc[k, 0] = wx
    wc[k, 1] = wy
    return nev


@njit(cache=True)
def _exit_against(i, k, vkx, vky, robots, r, prm):
    """S8.3 items 1-3 of robot i against the circle of radius r round robot k moving at vk."""
    p, goal, vc = robots.p, robots.goal, robots.vc
    return exit_conditions(
        p[i, 0],
        p[i, 1],
        goal[i, 0],
        goal[i, 1],
        vc[i, 0],
        vc[i, 1],
        p[k, 0],
        p[k, 1],
        vkx,
        vky,
        0.0,
        0.0,
        r,
        r,
        prm,
    )


@njit(cache=True)
def _pair_exit_conditions(i, k, robots, mutual, prm):
    """S8.3 items 1-3 of robot i avoiding robot k: a yielder against k's velocity; a mutual pair
    for both robots, each against the other's coordination field (both leave).
    """
    r = keepout_radius(robots.rbody, i, k, prm)
    if not mutual:
        pd = robots.pd
        return _exit_against(i, k, pd[k, 0], pd[k, 1], robots, r, prm)
    vc = robots.vc
    return _exit_against(i, k, vc[k, 0], vc[k, 1], robots, r, prm) and _exit_against(
        k, i, vc[i, 0], vc[i, 1], robots, r, prm
    )


@njit(cache=True)
def _break_cycles(t, robots, auto, ev, prm):
    """S14.5: a yield whose target reacts back to the yielder through a chain of following links
    (a re-parenting can close one after the yield was decided) becomes a mutual pair, whose
    reciprocal field has no velocity feed-forward loop. Returns the event count.
    """
    nev = 0
    mode, tgt = auto.mode, auto.tgt
    for i in range(mode.shape[0]):
        if mode[i] == MODE_YIELD and reacts_to(tgt[i], i, mode, tgt, robots.parent):
            nev = _form_mutual(i, tgt[i], t, robots, auto, ev, nev, prm)
    return nev


@njit(cache=True, inline='always')
def _obstacle_threats(t, robots, obstacles, auto, prm):
    """Stage 1 of :func:`decide` (S8.1, S14.2): every robot's best obstacle entry candidate and
    the state of the obstacle it avoids now -> :data:`ObstacleThreats`.
    """
    p, pd = robots.p, robots.pd
    oc, ov, ophi, ophid, oaxes = (
        obstacles.c,
        obstacles.v,
        obstacles.phi,
        obstacles.phi_dot,
        obstacles.axes,
    )
    mode, tgt = auto.mode, auto.tgt
    last_kind, last_tgt, last_exit = auto.last_kind, auto.last_tgt, auto.last_exit
    n = p.shape[0]
    m = oc.shape[0]
    out = ObstacleThreats(
        np.full(n, -1, dtype=np.int64),
        np.zeros(n, dtype=np.bool_),
        np.full(n, INF),
        np.full(n, INF),
        np.full(n, INF),
        np.zeros(n, dtype=np.bool_),
        np.full(n, INF),
    )
    ob_j, ob_em, ob_lam, ob_hem, ob_hl, cur_em, cur_hl = out
    reach2 = np.empty(m)  # culling: outside the circle of radius kappa r1 nothing triggers
    for j in range(m):
        reach2[j] = (prm.protected_scale * max(oaxes[j, 0], oaxes[j, 1])) ** 2
    for i in range(n):
        for j in range(m):
            zx = p[i, 0] - oc[j, 0]
            zy = p[i, 1] - oc[j, 1]
            if zx * zx + zy * zy >= reach2[j] and not (mode[i] == MODE_OBSTACLE and tgt[i] == j):
                continue
            rvx, rvy = relative_velocity(zx, zy, pd[i, 0], pd[i, 1], ov[j, 0], ov[j, 1], ophid[j])
            trig, em, lam, h_em, h_l = threat_test(
                zx, zy, rvx, rvy, ophi[j], oaxes[j, 0], oaxes[j, 1], prm
            )
            if mode[i] == MODE_OBSTACLE and tgt[i] == j:
                cur_em[i] = em
                cur_hl[i] = h_l
                continue
            if not em:
                if not trig or in_cooldown(
                    KIND_OBSTACLE, j, t, last_kind[i], last_tgt[i], last_exit[i], prm
                ):
                    continue
            if _better(em, h_em, lam, ob_j[i] >= 0, ob_em[i], ob_hem[i], ob_lam[i]):
                ob_j[i] = j
                ob_em[i] = em
                ob_lam[i] = lam
                ob_hem[i] = h_em
                ob_hl[i] = h_l
    return out


@njit(cache=True)
def _keep_threat(th, a, b, em, lam, h_em):
    """Record robot b as a threat of robot a in ``th`` (:data:`RobotThreats`); when a's slots are
    full, b replaces the least urgent one if it is more urgent (S8.1 ranking).
    """
    c = th.count[a]
    if c < MAX_THREATS:
        slot = c
        th.count[a] = c + 1
    else:  # replace the least urgent
        th_em, th_hem, th_lam = th.em, th.h_em, th.lam
        slot = 0
        for s in range(1, MAX_THREATS):
            if _better(
                th_em[a, slot],
                th_hem[a, slot],
                th_lam[a, slot],
                True,
                th_em[a, s],
                th_hem[a, s],
                th_lam[a, s],
            ):
                slot = s
        if not _better(em, h_em, lam, True, th_em[a, slot], th_hem[a, slot], th_lam[a, slot]):
            return
    th.k[a, slot] = b
    th.em[a, slot] = em
    th.lam[a, slot] = lam
    th.h_em[a, slot] = h_em


@njit(cache=True)
def _teammate_threshold(i, k, auto, prm):
    """S14.3 with hysteresis (docs/law-changes.md §11): the relative speed below which teammates i
    and k are no (non-emergency) threat: ``teammate_release_speed_mps`` when either one's last
    robot encounter was with the other (the pair was released: it stays exempt until it really
    moves apart or together, not at every jitter of the estimated speed), else
    ``teammate_rel_speed_mps``.
    """
    lk, lt = auto.last_kind, auto.last_tgt
    if (lk[i] == KIND_AGENT and lt[i] == k) or (lk[k] == KIND_AGENT and lt[k] == i):
        return prm.teammate_release_speed_mps
    return prm.teammate_rel_speed_mps


@njit(cache=True)
def _teammate_q_scale(i, k, r, robots, prm):
    """§22: the protected scale of robot k's region as robot i sees it. Teammates whose slots
    lie closer than Q's radius would stand inside each other's Q at their goals: their Q shrinks
    to the slot distance less the keep-out margin, never inside the heading region I.
    """
    kappa = prm.protected_scale
    if robots.team[i] != robots.team[k]:
        return kappa
    sx = robots.slot[i, 0] - robots.slot[k, 0]
    sy = robots.slot[i, 1] - robots.slot[k, 1]
    s = math.hypot(sx, sy)
    if not s < INF:  # NaN: a slot not known here
        return kappa
    return min(kappa, max(prm.heading_scale, (s - prm.agent_keepout_margin_m) / r))


@njit(cache=True, inline='always')
def _robot_threats(robots, auto, prm):
    """Stage 2 of :func:`decide` (S7, S14.3): the robot threats of every robot on the pairs
    culled by :func:`candidate_pairs` -> :data:`RobotThreats`.
    """
    p, pd, team, rbody = robots.p, robots.pd, robots.team, robots.rbody
    n = p.shape[0]
    th = RobotThreats(
        np.full((n, MAX_THREATS), -1, dtype=np.int64),
        np.zeros((n, MAX_THREATS), dtype=np.bool_),
        np.full((n, MAX_THREATS), INF),
        np.full((n, MAX_THREATS), INF),
        np.zeros(n, dtype=np.int64),
    )
    if n < 2:
        return th
    cell = prm.protected_scale * (2.0 * rbody.max() + prm.agent_keepout_margin_m)
    pairs = candidate_pairs(p, cell)
    for q in range(pairs.shape[0]):
        i = pairs[q, 0]
        k = pairs[q, 1]
        r = keepout_radius(rbody, i, k, prm)
        zx = p[i, 0] - p[k, 0]
        zy = p[i, 1] - p[k, 1]
        rvx = pd[i, 0] - pd[k, 0]
        rvy = pd[i, 1] - pd[k, 1]
        q_scale = _teammate_q_scale(i, k, r, robots, prm)
        trig, em, lam, h_em, h_l = threat_test_q(zx, zy, rvx, rvy, 0.0, r, r, q_scale, prm)
        if trig and lam > prm.agent_horizon_s:
            trig = False
        if (
            trig
            and not em
            and team[i] == team[k]
            and math.hypot(rvx, rvy) < _teammate_threshold(i, k, auto, prm)
        ):
            trig = False  # S14.3: teammates moving together, whatever their modes (§11)
        if not (trig or em):
            continue
        _keep_threat(th, i, k, em, lam, h_em)
        _keep_threat(th, k, i, em, lam, h_em)
    return th


@njit(cache=True)
def _obstacle_transitions(t, robots, obstacles, auto, obt, th, prm, ev, nev):
    """Stage 3 of :func:`decide`: S8.1 entry, S8.2 re-targeting and S8.3 exit of obstacles
    (``obt``, ``th``: stages 1 and 2). A row busy with no known obstacle (tgt -1: a neighbour
    busy with a robot not heard) has none. Returns the event count.
    """
    mode, tgt, sdir, since, t_entry = auto.mode, auto.tgt, auto.sdir, auto.since, auto.t_entry
    p, goal, vc = robots.p, robots.goal, robots.vc
    oc, ov, ophi, ophid, oaxes = (
        obstacles.c,
        obstacles.v,
        obstacles.phi,
        obstacles.phi_dot,
        obstacles.axes,
    )
    for i in range(mode.shape[0]):
        if mode[i] == MODE_OBSTACLE and tgt[i] >= 0:
            j = tgt[i]
            s = -sdir[i]
            if _held_still(i, j, t, robots, obstacles, auto, prm) and (
                _floor_side(i, j, s, robots, obstacles, prm) == s
            ):  # liveness: the other way, unless the floor closes it (§27)
                nev = _leave(i, t, auto, ev, nev)
                nev = _enter(i, t, MODE_OBSTACLE, j, s, auto, ev, nev)
                continue
            jn = obt.j[i]
            if jn >= 0 and not obt.cur_em[i] and (obt.em[i] or obt.h_l[i] < obt.cur_h_l[i]):
                sweep = obstacles.static[j] and obstacles.static[jn]
                swept = auto.sweep_s[i] + t - t_entry[i]
                if sweep:
                    s = sdir[i]  # S6.6 rule 5: keep the sweep direction
                else:
                    s = _obstacle_dir(i, jn, robots, obstacles, auto, prm)
                nev = _leave(i, t, auto, ev, nev)
                nev = _enter(i, t, MODE_OBSTACLE, jn, s, auto, ev, nev)
                if sweep:  # one sweep round static obstacles: its time, for liveness (§26)
                    auto.sweep_s[i] = swept
                continue
            cond = exit_conditions(
                p[i, 0],
                p[i, 1],
                goal[i, 0],
                goal[i, 1],
                vc[i, 0],
                vc[i, 1],
                oc[j, 0],
                oc[j, 1],
                ov[j, 0],
                ov[j, 1],
                ophi[j],
                ophid[j],
                oaxes[j, 0],
                oaxes[j, 1],
                prm,
            )
            ok, since[i] = exit_timer(cond, t, since[i], t_entry[i], prm)
            # S14.7: no exit into a robot emergency, unless held still there (liveness, section 13)
            if ok and (not th.em[i, :th.count[i]].any() or _still_for(i, t, robots, auto)):
                nev = _leave(i, t, auto, ev, nev)
        elif obt.j[i] >= 0:
            if mode[i] != MODE_C:
                # static obstacles beat robots (S7), unless the robot is in emergency and the
                # obstacle is not (S14.2: never swap one emergency for a lesser threat)
                em_k, hl_k = _agent_urgency(i, tgt[i], p, robots.pd, robots.rbody, prm)
                if (em_k and not obt.em[i]) or _reason_dwell(t, t_entry[i], obt.h_em[i], prm):
                    continue  # S14.2: no flipping between two emergency reasons
                nev = _release(i, t, auto, ev, nev)
            jn = obt.j[i]
            s = _obstacle_dir(i, jn, robots, obstacles, auto, prm)
            nev = _enter(i, t, MODE_OBSTACLE, jn, s, auto, ev, nev)
    return nev


@njit(cache=True)
def _stand_on_yield(i, t, robots, auto, th, prm, ev, nev):
    """Stage 4 for robot i avoiding an obstacle (stand-on): two stand-on robots, the higher ID
    yields, in an emergency only; not on the same obstacle (one sense, the safety barrier spaces
    them: S14.6), nor again to the robot it left for this obstacle (that pair would flip between
    the two reasons every dwell; the barrier spaces them). Returns the event count.
    """
    mode, tgt = auto.mode, auto.tgt
    kb = -1
    hb = INF
    for q in range(th.count[i]):
        k = th.k[i, q]
        same = tgt[k] == tgt[i]
        left_k = auto.last_kind[i] == KIND_AGENT and auto.last_tgt[i] == k
        if (
            th.em[i, q]
            and mode[k] == MODE_OBSTACLE
            and k < i
            and not same
            and not left_k
            and th.h_em[i, q] < hb
        ):
            kb = k
            hb = th.h_em[i, q]
    if kb >= 0 and not reacts_to(kb, i, mode, tgt, robots.parent):
        s = _agent_dir(i, kb, robots, prm)
        nev = _leave(i, t, auto, ev, nev)
        nev = _enter(i, t, MODE_YIELD, kb, s, auto, ev, nev)
    return nev


@njit(cache=True)
def _most_urgent(i, t, auto, th, parent, prm):
    """Stage 4: robot i's most urgent admissible robot threat -> (row or -1, emergency)
    (S8.4 cool-down, S14.2, S7 acyclicity: a robot that reacts to i is responsible; only
    emergencies with the ``prm.deferring_row``, whose encounters the coordinator decides).
    """
    mode, tgt = auto.mode, auto.tgt
    best = -1
    b_em = False
    b_hem = INF
    b_lam = INF
    for q in range(th.count[i]):
        k = th.k[i, q]
        em = th.em[i, q]
        if (mode[i] == MODE_YIELD or mode[i] == MODE_MUTUAL) and tgt[i] == k:
            continue
        if (not em or th.h_em[i, q] >= 0.0) and in_cooldown(
            KIND_AGENT, k, t, auto.last_kind[i], auto.last_tgt[i], auto.last_exit[i], prm
        ):
            continue  # S8.4; an imminent contact (not inside E) waits too (S14.2)
        if not em and reacts_to(k, i, mode, tgt, parent):
            continue  # k is responsible (S7 acyclicity)
        if not em and (i == prm.deferring_row or k == prm.deferring_row):
            continue  # that robot's encounters come from the coordinator (law-changes §23)
        if _better(em, th.h_em[i, q], th.lam[i, q], best >= 0, b_em, b_hem, b_lam):
            best = k
            b_em = em
            b_hem = th.h_em[i, q]
            b_lam = th.lam[i, q]
    return best, b_em


@njit(cache=True)
def _engage(i, k, b_em, t, robots, auto, prm, ev, nev):
    """Stage 4: robot i takes robot k as its target: re-targets only past T_dwell and when k is
    an emergency or clearly closer (S8.2, S14.2); a mutual pair when k reacts to i or both are
    free (S7), else i yields to k. Returns the event count.
    """
    mode, tgt, t_entry = auto.mode, auto.tgt, auto.t_entry
    p, pd, rbody = robots.p, robots.pd, robots.rbody
    if mode[i] != MODE_C:
        if t - t_entry[i] < prm.dwell_s:
            return nev  # S14.2: no re-target within T_dwell of a switch
        em_cur, hl_cur = _agent_urgency(i, tgt[i], p, pd, rbody, prm)
        if em_cur or (mode[i] == MODE_MUTUAL and not b_em):
            return nev  # a mutual pair is left only for an emergency (S14.2)
        big_r = prm.limit_cycle_scale * keepout_radius(rbody, i, k, prm)
        hl_new = h_value(p[i, 0] - p[k, 0], p[i, 1] - p[k, 1], 0.0, big_r, big_r)
        if not (b_em or hl_new < hl_cur - RETARGET_MARGIN):
            return nev
    if reacts_to(k, i, mode, tgt, robots.parent):
        # emergency against a robot that already reacts to i: convert to a mutual pair
        if t - t_entry[k] < prm.dwell_s:
            return nev
        return _form_mutual(i, k, t, robots, auto, ev, nev, prm)
    if mode[k] == MODE_C and (mode[i] == MODE_C or mode[i] == MODE_YIELD):
        # two free robots: reciprocal avoidance (S7 mutual)
        nev = _release(i, t, auto, ev, nev)
        return _form_mutual(i, k, t, robots, auto, ev, nev, prm)
    # k is busy (stand-on, yielding or in a pair): i yields to k
    s = _agent_dir(i, k, robots, prm)
    nev = _release(i, t, auto, ev, nev)
    return _enter(i, t, MODE_YIELD, k, s, auto, ev, nev)


@njit(cache=True)
def _arbitrate_robots(t, robots, auto, obt, th, prm, ev, nev):
    """Stage 4 of :func:`decide`: robot-robot arbitration over all robots (S7, S14.1). Returns
    the event count.
    """
    mode = auto.mode
    for i in range(mode.shape[0]):
        if th.count[i] == 0:
            continue
        if mode[i] == MODE_OBSTACLE:
            if obt.cur_em[i] or _reason_dwell(t, auto.t_entry[i], 0.0, prm):
                continue  # in an emergency of its own, or in dwell (S14.2)
            nev = _stand_on_yield(i, t, robots, auto, th, prm, ev, nev)
            continue
        k, b_em = _most_urgent(i, t, auto, th, robots.parent, prm)
        if k >= 0:
            nev = _engage(i, k, b_em, t, robots, auto, prm, ev, nev)
    return nev


@njit(cache=True)
def _pair_exits(t, robots, auto, prm, ev, nev):
    """Stage 5 of :func:`decide`: S8.3 exits of yielding robots and the joint exit of mutual
    pairs; a yielder held still on its limit cycle for ``STUCK_S`` turns the other way round its
    robot (liveness, docs/law-changes.md §21, as §8 on an obstacle). Returns the event count.
    """
    mode, tgt, since = auto.mode, auto.tgt, auto.since
    for i in range(mode.shape[0]):
        if mode[i] == MODE_YIELD and _held_by_robot(i, tgt[i], t, robots, auto, prm):
            k, s = tgt[i], -auto.sdir[i]
            nev = _leave(i, t, auto, ev, nev)
            nev = _enter(i, t, MODE_YIELD, k, s, auto, ev, nev)
            continue
        if mode[i] == MODE_YIELD or (mode[i] == MODE_MUTUAL and tgt[i] > i):
            k = tgt[i]
            mutual = mode[i] == MODE_MUTUAL
            cond = _pair_exit_conditions(i, k, robots, mutual, prm)
            ok, since[i] = exit_timer(cond, t, since[i], auto.t_entry[i], prm)
            if mutual:
                since[k] = since[i]
            if ok:  # pairs exit jointly
                nev = _leave(i, t, auto, ev, nev)
                if mutual:
                    nev = _leave(k, t, auto, ev, nev)
    return nev


@njit(cache=True)
def _drift_targets(robots, auto, prm):
    """Stage 6 of :func:`decide`: the drift target of each mutual pair, the mean of the two
    coordination fields capped at ``mutual_drift_cap_mps`` (S14.1); near a floor edge, the pair's
    centre is also driven away from it until the circle the two turn on (diameter R_aa, plus a body
    radius and the safety gap) fits on the floor, and never toward it (docs/law-changes.md §20).
    """
    cap = prm.mutual_drift_cap_mps
    p, vc, rb = robots.p, robots.vc, robots.rbody
    mode, tgt, wtgt = auto.mode, auto.tgt, auto.wtgt
    for i in range(mode.shape[0]):
        if mode[i] == MODE_MUTUAL:
            k = tgt[i]
            wx = 0.5 * (vc[i, 0] + vc[k, 0])
            wy = 0.5 * (vc[i, 1] + vc[k, 1])
            nrm = math.hypot(wx, wy)
            if nrm > cap:
                wx *= cap / nrm
                wy *= cap / nrm
            room = 0.5 * keepout_radius(rb, i, k, prm) + max(rb[i], rb[k]) + prm.safety_gap_m
            mx = 0.5 * (p[i, 0] + p[k, 0])
            my = 0.5 * (p[i, 1] + p[k, 1])
            wx = _off_edges(wx, mx - room - prm.floor_x_min_m, prm.floor_x_max_m - room - mx, cap)
            wy = _off_edges(wy, my - room - prm.floor_y_min_m, prm.floor_y_max_m - room - my, cap)
            wtgt[i, 0] = wx
            wtgt[i, 1] = wy


@njit(cache=True, inline='always')
def _off_edges(w, lo, hi, cap):
    """A drift component ``w`` with the room ``lo`` toward the lower edge and ``hi`` toward the
    upper one (< 0: the pair's circle crosses that edge): away from a crossed edge at
    ``cap`` x deficit / 0.05 m (at most ``cap``), never toward it.
    """
    if lo < 0.0 and hi >= 0.0:
        return max(w, 0.0, min(cap, -lo * cap / 0.05))
    if hi < 0.0 and lo >= 0.0:
        return min(w, 0.0, -min(cap, -hi * cap / 0.05))
    return w


@njit(cache=True)
def _any_mode(mode, a, b):
    """True when some robot is in mode ``a`` or ``b``."""
    for q in range(mode.shape[0]):
        if mode[q] == a or mode[q] == b:
            return True
    return False


# implements: S7, S8
@njit(cache=True)
def decide(t, robots, obstacles, auto, prm, ev):
    """One decision of every robot's automaton (S8) with robot encounters arbitrated jointly (S7).

    Parameters
    ----------
    t : float, time [s].
    robots : :data:`DecisionRobots`.
    obstacles : :data:`~ament_formation.core.model.obstacles.ObstacleSnapshot` at t (the
        accelerations are not read).
    auto : :data:`~ament_formation.core.control.automaton.AutomatonArrays`, updated in place
        (``since`` < 0: exit conditions not holding; ``last_*``: cool-down bookkeeping; ``wc``,
        ``wtgt``: mutual-pair drift w_c and its relaxation target).
    prm : :data:`~ament_formation.core.control.automaton.Switching` (named floats).
    ev : (E, 6) event buffer (filled from row 0). Returns the event count (may exceed E: the caller
        must then enlarge the buffer; rows beyond E are dropped).
    """
    mode = auto.mode  # (each stage runs only when it has work: fewer arrays to reference-count)
    nev = 0
    if _any_mode(mode, MODE_YIELD, MODE_YIELD):
        nev = _break_cycles(t, robots, auto, ev, prm)
    obt = _obstacle_threats(t, robots, obstacles, auto, prm)  # 1. S8.1, S14.2
    th = _robot_threats(robots, auto, prm)  # 2. S7, S14.3
    if _any_mode(mode, MODE_OBSTACLE, MODE_OBSTACLE) or (obt.j >= 0).any():  # 3. S8.1-S8.3
        nev = _obstacle_transitions(t, robots, obstacles, auto, obt, th, prm, ev, nev)
    if (th.count > 0).any():  # 4. S7, S14.1
        nev = _arbitrate_robots(t, robots, auto, obt, th, prm, ev, nev)
    if _any_mode(mode, MODE_YIELD, MODE_MUTUAL):  # 5. S8.3
        nev = _pair_exits(t, robots, auto, prm, ev, nev)
    if _any_mode(mode, MODE_MUTUAL, MODE_MUTUAL):  # 6. S14.1
        _drift_targets(robots, auto, prm)
    return nev


def decide_once(
    t_s: float,
    state,
    p,
    pd,
    goal,
    goal_dot,
    vc,
    team,
    rbody,
    obstacles,
    prm,
    ev_capacity: int | None = None,
    parent=None,
    slot=None,
) -> list[tuple]:
    """Python convenience around :func:`decide` (tests, controller): returns the events as tuples
    (t_s, robot_row, 'enter'|'exit', mode, target, direction).

    ``state`` : :class:`~ament_formation.core.control.automaton.AutomatonState`; ``obstacles`` :
    tuple (centres (M, 2), velocities (M, 2), phi (M,), phi_dot (M,), semi-axes (M, 2), static
    (M,) bool); ``parent`` : (N,) current formation parent rows (default: none); other arrays as
    in :class:`DecisionRobots`.
    """
    n = state.n
    ev = np.zeros((ev_capacity or 8 * n + 16, 6))
    oc, ov, ophi, ophid, oaxes, ostatic = obstacles

    def f(a):
        return np.ascontiguousarray(a, dtype=float)

    m = f(oc).reshape(-1, 2).shape[0]
    robots = DecisionRobots(
        f(p),
        f(pd),
        f(goal),
        f(goal_dot),
        f(vc),
        np.ascontiguousarray(team, dtype=np.int64),
        f(rbody),
        np.full(n, -1, dtype=np.int64)
        if parent is None
        else np.ascontiguousarray(parent, dtype=np.int64),
        np.full((n, 2), np.nan) if slot is None else f(slot).reshape(n, 2),
    )
    snapshot = ObstacleSnapshot(
        f(oc).reshape(-1, 2),
        f(ov).reshape(-1, 2),
        np.zeros((m, 2)),
        f(ophi).reshape(-1),
        f(ophid).reshape(-1),
        np.zeros(m),
        f(oaxes).reshape(-1, 2),
        np.ascontiguousarray(ostatic, dtype=np.bool_).reshape(-1),
    )
    nev = decide(float(t_s), robots, snapshot, state.arrays(), prm, ev)
    return [
        (
            float(r[0]),
            int(r[1]),
            'enter' if r[2] > 0.5 else 'exit',
            int(r[3]),
            int(r[4]),
            float(r[5]),
        )
        for r in ev[: min(nev, ev.shape[0])]
    ]
