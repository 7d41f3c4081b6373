"""The coordinator's robot-robot encounters over all robots together: the one authority for them
(docs/control-law.md S7.1), as a transition table with named guards (S8.8).

Robots on an obstacle (their own decision, core/control/switching.py) are stand-on: others yield
to them. Every other robot is in C, A(k, yield) or A(k, mutual), and only this module changes
that. Rows of the table, in the order :func:`arbitrate` tries them each decision:

====  ======  =============================================  =================================
row   from    guard                                          to
====  ======  =============================================  =================================
C1    A(k,m)  the partner is on an obstacle                  A(k, yield) (it is stand-on)
C2    A(k,y)  ``closes_loop``: k reacts to the robot         A(k, mutual) (S7.4, S14.5)
C3    A(k,y)  ``stalled``, not ``parked``                    A(k, yield), the other sense
C4    A(k,m)  ``stalled``                                    the lower-ranked robot yields, the
                                                             other to C (S7.5 ranks)
C5    C       ``stalled``, not ``at_goal``, ``blocked_by``   A(k, yield); a blocker that yields
                                                             to the robot stops parking (C9)
C6    C, A(.) ``robot_threat(k)``, admissible, most urgent   A(k, mutual) or A(k, yield)
                                                             (``pairing``, S7.3, S7.5)
C7    A(k,y)  ``cleared(k)`` held T_dwell, T_min             C
C8    A(k,m)  both sides ``cleared`` held T_dwell, T_min     C, C
C9    C, A(y) at rest beside a robot ``stalled`` on its      A(k, yield) without parking
              obstacle (``make_way``)                        (S8.9)
====  ======  =============================================  =================================

``robot_threat`` = S7.2 (the S8.1 test on the keep-out circle, with the teammate rules of S14.3);
admissible = not cooling down (S8.4), not toward a robot that reacts to this one (S7.4), not
toward a robot of a team that gives way to this one's (S7.5), emergencies always;
``pairing`` = two free robots of one team, or in an emergency, form a mutual pair; otherwise the
robot yields. Right of way between teams (S7.5): a team that meets another keeps a rank from
then until their robots are ``right_of_way_release_m`` apart; the team already further into the
meeting point (or at rest at its goals) ranks first, and the other's robots yield to its robots,
to a moving team's without parking (they go round, out of the way, until S8.3 lets them back).
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.control.floor import drift_off_edges
from ament_formation.core.control.limit_cycle import choose_direction
from ament_formation.core.control.progress import (
    finish_wait_s,
    path_heading,
    rate_targets,
    step,
    team_errors,
)
from ament_formation.core.control.switching import (
    anchor_at,
    begin_episode,
    cleared,
    cooling,
    dwell_exit,
    enter,
    event,
    INF,
    KIND_OBSTACLE,
    KIND_ROBOT,
    leave,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    progress,
    ranks_before,
    reanchor,
    release,
    stalled,
    threat_test,
)
from ament_formation.core.model.ellipse import h_value

MAX_THREATS = 8  # robot threats kept per robot and decision (the most urgent)

Teams = namedtuple('Teams', ['rank', 'done', 'way_rate', 'heading', 'anchor', 't_anchor'])
Teams.__doc__ = """Right of way between teams (S7.5), rows indexed by robot row (a team is its
leader's row): ``rank`` (N,) float, the team's rank key while it meets another team (lower goes
first; INF: meeting nobody); ``done`` (N,) bool, the team's reference has reached its end (S17);
``way_rate`` (N,) output, the cap in [0, 1] the right of way puts on the team's reference rate
(S17): 0 while some robot of it yields to a moving robot of a team that ranks before it, and the
headway (:func:`headway`) while such a robot moves in its way ahead; ``heading`` (N, 2) input,
the unit direction of the team's path at its progress (NaN: none); ``anchor`` (N, 2),
``t_anchor`` (N,): the coordinator's own progress monitor of the robots on obstacles (row C9,
S8.9).
"""


def new_teams(n: int) -> Teams:
    """:data:`Teams` of n robot rows, nobody meeting anybody."""
    return Teams(np.full(n, INF), np.zeros(n, dtype=np.bool_), np.ones(n),
                 np.full((n, 2), np.nan), np.full((n, 2), np.nan), np.zeros(n))


@njit(cache=True, error_model='numpy', forceinline=True)
def keepout_radius(rbody, i, k, prm):
    """R_aa of a robot pair (S7): R_body,i + R_body,k + margin (0.25 m by default)."""
    return rbody[i] + rbody[k] + prm.agent_keepout_margin_m


@njit(cache=True, error_model='numpy')
def candidate_pairs(p, known, cell_m):
    """Pairs (i < k) of known robots closer than ``cell_m`` [m], by a uniform grid (near-linear in
    N): p (N, 2) -> (P, 2) int.
    """
    n = p.shape[0]
    out = np.empty((max(16, 8 * n), 2), dtype=np.int64)
    cnt = 0
    if n < 2:
        return out[:0]
    x0, y0 = INF, INF
    for i in range(n):
        if known[i]:
            x0 = min(x0, p[i, 0])
            y0 = min(y0, p[i, 1])
    ix = np.zeros(n, dtype=np.int64)
    iy = np.zeros(n, dtype=np.int64)
    for i in range(n):
        if known[i]:
            ix[i] = int((p[i, 0] - x0) / cell_m)
            iy[i] = int((p[i, 1] - y0) / cell_m)
    nx = ix.max() + 1
    ny = iy.max() + 1
    if nx * ny > 16 * n + 4096:  # sparse, huge arena: one column of cells per x
        ny = 1
        iy[:] = 0
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        if known[i]:
            start[ix[i] * ny + iy[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        if known[i]:
            c = ix[i] * ny + iy[i]
            members[fill[c]] = i
            fill[c] += 1
    for i in range(n):
        if not known[i]:
            continue
        for cx in range(max(0, ix[i] - 1), min(nx, ix[i] + 2)):
            for cy in range(max(0, iy[i] - 1), min(ny, iy[i] + 2)):
                c = cx * ny + cy
                for q in range(start[c], start[c + 1]):
                    k = members[q]
                    if k <= i:
                        continue
                    dx, dy = p[i, 0] - p[k, 0], p[i, 1] - p[k, 1]
                    if dx * dx + dy * dy < cell_m * cell_m:
                        if cnt >= out.shape[0]:
                            out = np.concatenate((out, np.empty_like(out)))
                        out[cnt, 0] = i
                        out[cnt, 1] = k
                        cnt += 1
    return out[:cnt]


@njit(cache=True, error_model='numpy', forceinline=True)
def reacts_to(k, i, m, parent):
    """S7.4: robot k reacts to robot i, directly or through a chain of following links: yields,
    pairs and the formation link of a robot in C to its current parent (S14.5).
    """
    cur = k
    for _ in range(m.mode.shape[0] + 1):
        md = m.mode[cur]
        if md == MODE_C:
            nxt = parent[cur]
            if nxt < 0:
                return False
        elif md == MODE_YIELD or md == MODE_MUTUAL:
            nxt = m.tgt[cur]
        else:
            return False
        if nxt == i:
            return True
        if md == MODE_MUTUAL:
            return False  # the partner only reacts back to cur
        cur = nxt
    return False


@njit(cache=True, error_model='numpy', forceinline=True)
def _rank_first(a, b, robots, teams):
    """S7.5: robot a's team goes before robot b's (False for one team, or no meeting)."""
    ta, tb = robots.team[a], robots.team[b]
    return ta != tb and teams.rank[ta] < teams.rank[tb]


@njit(cache=True, error_model='numpy', forceinline=True)
def _teammate_q_scale(i, k, r, robots, prm):
    """S14.3: robot k's protected region Q as teammate i sees it: kappa R_aa shrunk to the slot
    distance less the keep-out margin (a team at its slots stands outside each other's Q),
    never inside the heading region I.
    """
    if robots.team[i] != robots.team[k]:
        return prm.protected_scale
    s = math.hypot(robots.slot[i, 0] - robots.slot[k, 0], robots.slot[i, 1] - robots.slot[k, 1])
    if not s < INF:  # a slot not known
        return prm.protected_scale
    return min(prm.protected_scale, max(prm.heading_scale, (s - prm.agent_keepout_margin_m) / r))


@njit(cache=True, error_model='numpy', forceinline=True)
def _moving_together(i, k, rvx, rvy, m, prm):
    """S14.3, S7.2: two robots moving together or resting together (relative speed below
    ``teammate_speed_mps``, or below ``teammate_release_speed_mps`` when their last encounter was
    with each other) are no threat but in an emergency.
    """
    lim = prm.teammate_speed_mps
    if (m.last_kind[i] == KIND_ROBOT and m.last_tgt[i] == k) or (
        m.last_kind[k] == KIND_ROBOT and m.last_tgt[k] == i
    ):
        lim = prm.teammate_release_speed_mps
    return math.hypot(rvx, rvy) < lim


RobotThreats = namedtuple('RobotThreats', ['k', 'em', 'lam', 'h_em', 'count'])


@njit(cache=True, error_model='numpy', forceinline=True)
def _keep(th, a, b, em, lam, h_em):
    """Record robot b as a threat of a; when a's slots are full b replaces the least urgent one
    if it ranks before it (S8.1).
    """
    c = th.count[a]
    if c < MAX_THREATS:
        slot = c
        th.count[a] = c + 1
    else:
        slot = 0
        for s in range(1, MAX_THREATS):
            if ranks_before(th.em[a, slot], th.h_em[a, slot], th.lam[a, slot], 0,
                            th.em[a, s], th.h_em[a, s], th.lam[a, s]):
                slot = s
        if not ranks_before(em, h_em, lam, 0, th.em[a, slot], th.h_em[a, slot], th.lam[a, slot]):
            return
    th.k[a, slot] = b
    th.em[a, slot] = em
    th.lam[a, slot] = lam
    th.h_em[a, slot] = h_em


# implements: S7.2
@njit(cache=True, error_model='numpy')
def robot_threats(robots, m, pairs, prm):
    """Guard ``robot_threat`` over the candidate pairs: the S8.1 test on the keep-out circle
    R_aa, the teammates' Q and exemption (S14.3), and a horizon: a contact with I more than
    ``robot_horizon_s`` away is no threat -> :data:`RobotThreats`.
    """
    p, pd, rbody = robots.p, robots.pd, robots.rbody
    n = p.shape[0]
    th = RobotThreats(np.full((n, MAX_THREATS), -1, dtype=np.int64),
                      np.zeros((n, MAX_THREATS), dtype=np.bool_),
                      np.full((n, MAX_THREATS), INF), np.full((n, MAX_THREATS), INF),
                      np.zeros(n, dtype=np.int64))
    for q in range(pairs.shape[0]):
        i, k = pairs[q, 0], pairs[q, 1]
        r = keepout_radius(rbody, i, k, prm)
        zx, zy = p[i, 0] - p[k, 0], p[i, 1] - p[k, 1]
        if zx * zx + zy * zy >= (prm.protected_scale * r) ** 2:
            continue  # outside Q (the pairs reach further, for S7.5)
        rvx, rvy = pd[i, 0] - pd[k, 0], pd[i, 1] - pd[k, 1]
        trig, em, lam, h_em, h_l = threat_test(zx, zy, rvx, rvy, 0.0, r, r,
                                               _teammate_q_scale(i, k, r, robots, prm), prm)
        if trig and (lam > prm.robot_horizon_s or _moving_together(i, k, rvx, rvy, m, prm)
                     or robots.origin[i] == k or robots.origin[k] == i):
            trig = False  # a follower and its own parent: the barrier, not an encounter (S7.2)
        if trig or em:
            _keep(th, i, k, em, lam, h_em)
            _keep(th, k, i, em, lam, h_em)
    return th


@njit(cache=True, error_model='numpy', forceinline=True)
def _agent_sense(i, k, robots, prm):
    """S6.6 rules 1-3 and 7: the sense of robot i round robot k (ties +1)."""
    p, pd, goal, gd = robots.p, robots.pd, robots.goal, robots.goal_dot
    big = prm.limit_cycle_scale * keepout_radius(robots.rbody, i, k, prm)
    return choose_direction(p[i, 0] - p[k, 0], p[i, 1] - p[k, 1], pd[i, 0] - pd[k, 0],
                            pd[i, 1] - pd[k, 1], goal[i, 0] - p[k, 0], goal[i, 1] - p[k, 1],
                            gd[i, 0] - pd[k, 0], gd[i, 1] - pd[k, 1], 0.0, big, big,
                            2.0 * prm.protected_scale * big / prm.limit_cycle_scale, False)


@njit(cache=True, error_model='numpy', forceinline=True)
def _urgency(i, k, robots, prm):
    """(emergency, h_L) of robot k as robot i sees it."""
    p, pd = robots.p, robots.pd
    r = keepout_radius(robots.rbody, i, k, prm)
    _t, em, _l, _h, h_l = threat_test(p[i, 0] - p[k, 0], p[i, 1] - p[k, 1], pd[i, 0] - pd[k, 0],
                                      pd[i, 1] - pd[k, 1], 0.0, r, r, prm.protected_scale, prm)
    return em, h_l


@njit(cache=True, error_model='numpy', forceinline=True)
def form_pair(i, k, t, robots, m, prm, ev, nev):
    """S7.3: robots i and k enter a mutual pair at one t_s with w_c = (p_dot_i + p_dot_k)/2 and
    one sense: the S6.6 sense of each round the other when they agree, else +1 (S14.1).
    """
    s = _agent_sense(i, k, robots, prm)
    if _agent_sense(k, i, robots, prm) != s:
        s = 1.0
    for a in (i, k):
        if m.mode[a] == MODE_MUTUAL and m.tgt[a] != i and m.tgt[a] != k:
            nev = release(a, t, m, ev, nev)
        elif m.mode[a] != MODE_C:
            nev = leave(a, t, m, ev, nev)
    pd = robots.pd
    for a, b in ((i, k), (k, i)):
        if m.mode[a] == MODE_C:
            begin_episode(a, t, robots.p, m, prm)
        nev = enter(a, t, MODE_MUTUAL, b, s, m, ev, nev)
        m.wc[a, 0] = 0.5 * (pd[i, 0] + pd[k, 0])
        m.wc[a, 1] = 0.5 * (pd[i, 1] + pd[k, 1])
        m.wtgt[a, 0] = m.wc[a, 0]
        m.wtgt[a, 1] = m.wc[a, 1]
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _yield_to(i, k, t, robots, m, prm, ev, nev):
    """Robot i yields to robot k (S7.3), sense by S6.6; the progress monitor starts again unless
    this re-targets a yield (S8.9: a robot still among several robots stays stalled).
    """
    s = _agent_sense(i, k, robots, prm)
    if m.mode[i] != MODE_C:
        nev = release(i, t, m, ev, nev)
    else:
        begin_episode(i, t, robots.p, m, prm)
    return enter(i, t, MODE_YIELD, k, s, m, ev, nev)


@njit(cache=True, error_model='numpy', forceinline=True)
def _most_urgent(i, t, robots, m, th, teams, prm):
    """Guard ``robot_threat`` and admissible (module docstring) -> (row or -1, emergency)."""
    best, b_em, b_hem, b_lam = -1, False, INF, INF
    for q in range(th.count[i]):
        k, em = th.k[i, q], th.em[i, q]
        if (m.mode[i] == MODE_YIELD or m.mode[i] == MODE_MUTUAL) and m.tgt[i] == k:
            continue
        if (not em or th.h_em[i, q] >= 0.0) and cooling(KIND_ROBOT, k, t, i, m, prm):
            continue  # S8.4; an imminent contact outside E waits too (S14.2)
        if not em and (reacts_to(k, i, m, robots.parent) or _rank_first(i, k, robots, teams)):
            continue  # k is responsible (S7.4), or k's team gives way to i's (S7.5)
        if not em and m.last_kind[i] == KIND_OBSTACLE and m.mode[i] == MODE_C and (
                t - m.last_exit[i] < prm.reason_dwell_s):
            continue  # no flipping from an obstacle to a robot reason (S8.4)
        if ranks_before(em, th.h_em[i, q], th.lam[i, q], best, b_em, b_hem, b_lam):
            best, b_em, b_hem, b_lam = k, em, th.h_em[i, q], th.lam[i, q]
    return best, b_em


@njit(cache=True, error_model='numpy', forceinline=True)
def _engage(i, k, em, t, robots, m, teams, prm, ev, nev):
    """Row C6: robot i takes robot k. From an encounter only past T_dwell, for an emergency or a
    robot clearly closer (S8.2); a pair is left for an emergency only (S14.2). Pairing: k reacts
    to i -> mutual (S7.4); both free and of one team, or an emergency -> mutual; else yield.
    """
    md = m.mode[i]
    if md != MODE_C:
        if t - m.t_entry[i] < prm.dwell_s:
            return nev
        em_cur, hl_cur = _urgency(i, m.tgt[i], robots, prm)
        if em_cur or (md == MODE_MUTUAL and not em):
            return nev
        big = prm.limit_cycle_scale * keepout_radius(robots.rbody, i, k, prm)
        hl_new = h_value(robots.p[i, 0] - robots.p[k, 0], robots.p[i, 1] - robots.p[k, 1], 0.0,
                         big, big)
        if not (em or hl_new < hl_cur - prm.retarget_margin):
            return nev
    if reacts_to(k, i, m, robots.parent):
        if t - m.t_entry[k] < prm.dwell_s:
            return nev
        return form_pair(i, k, t, robots, m, prm, ev, nev)
    free = m.mode[k] == MODE_C and (md == MODE_C or md == MODE_YIELD)
    if free and (robots.team[i] == robots.team[k] or em):
        return form_pair(i, k, t, robots, m, prm, ev, nev)
    nev = _yield_to(i, k, t, robots, m, prm, ev, nev)
    if _rank_first(k, i, robots, teams) and not teams.done[robots.team[k]]:
        m.park_at[i] = INF  # giving way to a moving team: out of its way, not waiting in it
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _sync_pairs_and_loops(t, robots, m, prm, ev, nev):
    """Rows C1 and C2: a pair whose partner went onto an obstacle becomes a yield to it; a yield
    whose target reacts back to the yielder (a chain closed by a re-parenting) becomes a pair.
    """
    for i in range(m.mode.shape[0]):
        if not robots.known[i]:
            continue
        k = m.tgt[i]
        if m.mode[i] == MODE_MUTUAL and m.mode[k] == MODE_OBSTACLE:  # C1
            nev = event(ev, nev, t, i, False, MODE_MUTUAL, k, m.sdir[i])
            m.mode[i] = MODE_YIELD
            m.since[i] = -1.0
            nev = event(ev, nev, t, i, True, MODE_YIELD, k, m.sdir[i])
        elif m.mode[i] == MODE_YIELD and reacts_to(k, i, m, robots.parent):  # C2
            nev = form_pair(i, k, t, robots, m, prm, ev, nev)
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _blocker(i, robots, m, prm):
    """Guard ``blocked_by``: the nearest known robot within the barrier's range of robot i's
    keep-out circle, on its way to its goal (-1: none).
    """
    p, goal = robots.p, robots.goal
    gx, gy = goal[i, 0] - p[i, 0], goal[i, 1] - p[i, 1]
    best, b_d = -1, INF
    for k in range(p.shape[0]):
        if k == i or not robots.known[k]:
            continue
        dx, dy = p[k, 0] - p[i, 0], p[k, 1] - p[i, 1]
        d = math.hypot(dx, dy)
        if d < keepout_radius(robots.rbody, i, k, prm) + prm.safety_range_m and (
            dx * gx + dy * gy > 0.0
        ) and d < b_d:
            best, b_d = k, d
    return best


@njit(cache=True, error_model='numpy', forceinline=True)
def _round_parked(i, k, robots, prm):
    """S8.9: robot i yielding round k waits where its goal, seen from k, is (it is parked)."""
    p, goal = robots.p, robots.goal
    dd = math.atan2(goal[i, 1] - p[k, 1], goal[i, 0] - p[k, 0]) - math.atan2(
        p[i, 1] - p[k, 1], p[i, 0] - p[k, 0])
    return abs((dd + math.pi) % (2.0 * math.pi) - math.pi) <= prm.parking_anomaly_rad


@njit(cache=True, error_model='numpy', forceinline=True)
def _make_way(i, t, robots, m, prm, ev, nev):
    """Row C9: the robots at rest beside robot i (stalled on its obstacle, S8.9) make way: one
    in C or yielding yields to i without parking (it circles i until S8.3 lets it go back); one
    parked on an obstacle of its own stops parking for ``make_way_s`` (it goes round).
    Returns the event count.
    """
    p, pd = robots.p, robots.pd
    for k in range(p.shape[0]):
        if k == i or not robots.known[k] or m.mode[k] == MODE_MUTUAL:
            continue
        d = math.hypot(p[k, 0] - p[i, 0], p[k, 1] - p[i, 1])
        if d > keepout_radius(robots.rbody, i, k, prm) + prm.safety_range_m or math.hypot(
                pd[k, 0], pd[k, 1]) > prm.teammate_speed_mps:
            continue
        if m.mode[k] == MODE_OBSTACLE:
            m.park_at[k] = max(m.park_at[k], t + prm.make_way_s)
        elif not (m.mode[k] == MODE_YIELD and m.tgt[k] == i and m.park_at[k] == INF):
            nev = _yield_to(k, i, t, robots, m, prm, ev, nev)
            m.park_at[k] = INF
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _stalls(t, robots, m, teams, prm, ev, nev):
    """Rows C3-C5 and C9: the progress monitor (S8.9) of every robot the coordinator owns, and
    its own watch of the robots on obstacles.
    """
    p = robots.p
    for i in range(m.mode.shape[0]):
        md = m.mode[i]
        if not robots.known[i]:
            continue
        if md == MODE_OBSTACLE:  # C9
            if stalled(i, t, p, teams.anchor, teams.t_anchor, prm):
                nev = _make_way(i, t, robots, m, prm, ev, nev)
                anchor_at(i, t, p, teams.anchor, teams.t_anchor)
            continue
        teams.anchor[i, 0] = np.nan  # the watch starts again on the next obstacle
        k = m.tgt[i]
        if md == MODE_MUTUAL:  # a pair is stalled when either robot is (its lower row acts)
            if k < i or not (progress(i, t, p, m, prm) | progress(k, t, p, m, prm)):
                continue
        elif not progress(i, t, p, m, prm):
            continue
        if md == MODE_YIELD and not (t >= m.park_at[i] and _round_parked(i, k, robots, prm)):
            s, park_at = -m.sdir[i], m.park_at[i]  # C3
            nev = leave(i, t, m, ev, nev)
            nev = enter(i, t, MODE_YIELD, k, s, m, ev, nev)
            m.park_at[i] = park_at
            reanchor(i, t, p, m)
        elif md == MODE_MUTUAL and k > i:  # C4: the robot of the later team (or id) yields
            a, b = (k, i) if not _rank_first(k, i, robots, teams) else (i, k)
            nev = leave(b, t, m, ev, nev)
            nev = leave(a, t, m, ev, nev)
            nev = _yield_to(a, b, t, robots, m, prm, ev, nev)
            reanchor(a, t, p, m)
            reanchor(b, t, p, m)
        elif md == MODE_C:  # C5
            e = math.hypot(p[i, 0] - robots.goal[i, 0], p[i, 1] - robots.goal[i, 1])
            b = _blocker(i, robots, m, prm) if e > prm.at_goal_m else -1
            if b >= 0 and m.mode[b] == MODE_YIELD and m.tgt[b] == i:
                m.park_at[b] = INF  # it yields to i but waits at its goal, in i's way: make way
            elif b >= 0 and not reacts_to(b, i, m, robots.parent):
                nev = _yield_to(i, b, t, robots, m, prm, ev, nev)
            reanchor(i, t, p, m)
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _exit_against(i, k, vkx, vky, robots, r, prm):
    """S8.3 items 1-3 of robot i against the circle of radius r round robot k moving at vk."""
    p, g, vc = robots.p, robots.goal, robots.vc
    return cleared(p[i, 0], p[i, 1], g[i, 0], g[i, 1], vc[i, 0], vc[i, 1], p[k, 0], p[k, 1],
                   vkx, vky, 0.0, 0.0, r, r, prm)


@njit(cache=True, error_model='numpy', forceinline=True)
def _exits(t, robots, m, prm, ev, nev):
    """Rows C7 and C8: a yielder leaves when S8.3 holds against k's velocity; a pair leaves
    jointly when it holds for both, each against the other's coordination field.
    """
    for i in range(m.mode.shape[0]):
        md = m.mode[i]
        if not robots.known[i] or not (md == MODE_YIELD or (md == MODE_MUTUAL and m.tgt[i] > i)):
            continue
        k = m.tgt[i]
        r = keepout_radius(robots.rbody, i, k, prm)
        if md == MODE_YIELD:
            holds = _exit_against(i, k, robots.pd[k, 0], robots.pd[k, 1], robots, r, prm)
        else:
            vc = robots.vc
            holds = _exit_against(i, k, vc[k, 0], vc[k, 1], robots, r, prm) and _exit_against(
                k, i, vc[i, 0], vc[i, 1], robots, r, prm)
        ok = dwell_exit(holds, t, i, m, prm)
        if md == MODE_MUTUAL:
            m.since[k] = m.since[i]
        if ok:
            nev = leave(i, t, m, ev, nev)
            if md == MODE_MUTUAL:
                nev = leave(k, t, m, ev, nev)
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _drift_targets(robots, m, prm):
    """S7.3/S14.1: each pair's drift target, the mean of the two coordination fields capped at
    ``mutual_drift_cap_mps``, kept off the floor's edges (S16.3).
    """
    cap, p, vc, rb = prm.mutual_drift_cap_mps, robots.p, robots.vc, robots.rbody
    for i in range(m.mode.shape[0]):
        if m.mode[i] != MODE_MUTUAL:
            continue
        k = m.tgt[i]
        wx, wy = 0.5 * (vc[i, 0] + vc[k, 0]), 0.5 * (vc[i, 1] + vc[k, 1])
        nrm = math.hypot(wx, wy)
        if nrm > cap:
            wx, wy = wx * cap / nrm, wy * cap / nrm
        room = 0.5 * keepout_radius(rb, i, k, prm) + max(rb[i], rb[k]) + prm.safety_gap_m
        m.wtgt[i, 0], m.wtgt[i, 1] = drift_off_edges(wx, wy, 0.5 * (p[i, 0] + p[k, 0]),
                                                     0.5 * (p[i, 1] + p[k, 1]), room, cap, prm)


@njit(cache=True, error_model='numpy', forceinline=True)
def _meeting_point_distance(ld, c, robots):
    """How far the meeting point c lies ahead of team leader row ``ld`` along its goal's motion
    [m] (0 for a goal at rest: it is there).
    """
    gx, gy = robots.goal_dot[ld, 0], robots.goal_dot[ld, 1]
    v = math.hypot(gx, gy)
    if v < 1e-6:
        return 0.0
    return ((c[0] - robots.p[ld, 0]) * gx + (c[1] - robots.p[ld, 1]) * gy) / v


@njit(cache=True, error_model='numpy', forceinline=True)
def headway(i, k, robots, teams, prm):
    """S7.5: the rate cap in [0, 1] that robot k, of a moving team that goes first, puts on robot
    i's team: 1 unless k moves (faster than ``teammate_speed_mps``, not against the way: within
    120 degrees of it) and lies ahead of i in its team's way (along ``Teams.heading``, within Q's
    radius of the line), falling from 1 at ``headway_go_m`` to 0 at ``headway_stop_m``: the team
    follows or waits at a distance instead of closing up, yielding and closing up again.
    """
    p, pd = robots.p, robots.pd
    ux, uy = teams.heading[robots.team[i], 0], teams.heading[robots.team[i], 1]
    vk = math.hypot(pd[k, 0], pd[k, 1])
    if not (ux == ux) or vk <= prm.teammate_speed_mps or pd[k, 0] * ux + pd[k, 1] * uy < -0.5 * vk:
        return 1.0  # at rest (go round it) or coming at i (waiting would stand in its way)
    dx, dy = p[k, 0] - p[i, 0], p[k, 1] - p[i, 1]
    if dx * ux + dy * uy <= 0.0 or abs(dx * uy - dy * ux) > prm.protected_scale * (
            keepout_radius(robots.rbody, i, k, prm)):
        return 1.0
    d = math.hypot(dx, dy)
    return min(1.0, max(0.0, (d - prm.headway_stop_m) / (prm.headway_go_m - prm.headway_stop_m)))


@njit(cache=True, error_model='numpy', forceinline=True)
def _way_rates(robots, m, pairs, teams, prm):
    """S7.5, S17.1: ``Teams.way_rate``, the cap the right of way puts on each team's rate: 0
    while one of its robots yields to a moving robot of a team that ranks first (it waits while
    that team goes by), else the least :func:`headway` over the close pairs with such robots in
    coordination (a robot circling an obstacle or a robot may take it nowhere for long).
    """
    wr, team = teams.way_rate, robots.team
    wr[:] = 1.0
    for q in range(pairs.shape[0]):
        for i, k in ((pairs[q, 0], pairs[q, 1]), (pairs[q, 1], pairs[q, 0])):
            if m.mode[k] == MODE_C and _rank_first(k, i, robots, teams) and not teams.done[
                    team[k]]:
                wr[team[i]] = min(wr[team[i]], headway(i, k, robots, teams, prm))
    for i in range(m.mode.shape[0]):
        k = m.tgt[i]
        if m.mode[i] == MODE_YIELD and _rank_first(k, i, robots, teams) and not teams.done[
                team[k]]:
            wr[team[i]] = 0.0


# implements: S7.5
@njit(cache=True, error_model='numpy')
def right_of_way(t, robots, pairs, teams, prm):
    """S7.5: teams meeting another team get a rank key (lower goes first): a team at rest at the
    end of its reference first, then by the time the meeting began, then the team further into
    the meeting point; a team whose robots are all ``right_of_way_release_m`` from every other
    team's loses its key. The keys order all meeting teams at once, so no three teams wait on
    each other in a circle; an exact tie (a symmetric meeting) goes to the lower team row.
    """
    n = robots.p.shape[0]
    near = np.zeros(n, dtype=np.bool_)
    fresh = np.full(n, INF)
    p, team = robots.p, robots.team
    for q in range(pairs.shape[0]):
        i, k = pairs[q, 0], pairs[q, 1]
        ti, tk = team[i], team[k]
        if ti == tk:
            continue
        d = math.hypot(p[i, 0] - p[k, 0], p[i, 1] - p[k, 1])
        if d >= prm.right_of_way_release_m:
            continue
        near[ti] = near[tk] = True
        c = (0.5 * (p[i, 0] + p[k, 0]), 0.5 * (p[i, 1] + p[k, 1]))
        for tm in (ti, tk):
            ahead = _meeting_point_distance(tm, c, robots)
            fresh[tm] = min(fresh[tm], t + 1e-4 * math.tanh(ahead))
    for tm in range(n):
        if not near[tm]:
            teams.rank[tm] = INF
        elif teams.done[tm]:
            teams.rank[tm] = -1.0  # at rest at its goals: the others go round it
        elif teams.rank[tm] == INF:
            teams.rank[tm] = _untied(tm, fresh[tm], teams.rank)


@njit(cache=True, error_model='numpy', forceinline=True)
def _untied(tm, key, rank):
    """S7.5: ``key`` moved up by the least step that makes it differ from every other team's
    key (a symmetric meeting gives equal keys; equal keys would order nobody).
    """
    tied = True
    while tied:
        tied = False
        for q in range(rank.shape[0]):
            if q != tm and rank[q] == key:
                key += max(abs(key), 1.0) * 1e-12
                tied = True
    return key


# implements: S7, S7.1
@njit(cache=True, error_model='numpy')
def arbitrate(t, robots, m, teams, prm, ev, nev):
    """One decision of the coordinator's table (module docstring) over every known robot:
    ``robots`` :data:`~ament_formation.core.control.switching.Robots`, ``m`` their
    :data:`~ament_formation.core.control.switching.Modes` (obstacle modes as the robots decided
    them), ``teams`` :data:`Teams` (updated). Returns the event count.
    """
    cell = prm.protected_scale * (2.0 * robots.rbody.max() + prm.agent_keepout_margin_m)
    pairs = candidate_pairs(robots.p, robots.known, max(cell, prm.right_of_way_release_m))
    right_of_way(t, robots, pairs, teams, prm)
    nev = _sync_pairs_and_loops(t, robots, m, prm, ev, nev)
    nev = _stalls(t, robots, m, teams, prm, ev, nev)
    th = robot_threats(robots, m, pairs, prm)
    for i in range(m.mode.shape[0]):
        if th.count[i] == 0 or m.mode[i] == MODE_OBSTACLE or not robots.known[i]:
            continue
        k, em = _most_urgent(i, t, robots, m, th, teams, prm)
        if k >= 0:
            nev = _engage(i, k, em, t, robots, m, teams, prm, ev, nev)
    nev = _exits(t, robots, m, prm, ev, nev)
    _drift_targets(robots, m, prm)
    _way_rates(robots, m, pairs, teams, prm)
    return nev


# implements: S17.3
@njit(cache=True, error_model='numpy')
def coordinate(t, dt, robots, ob, m, teams, progress, refs, leaders, e_team, prm, ev, nev):
    """The coordinator's decision (ideal simulator and coordinator alike): the table
    (:func:`arbitrate`), then every team's error, its reference's rate target and progress over
    ``dt`` [s] since the last decision (S17). Returns (event count, the mission has ended: every
    reference at its end, and every team re-formed or the finish wait used up).
    """
    for i in leaders:
        path_heading(refs, i, progress.s[i], teams.heading[i])
    nev = arbitrate(t, robots, m, teams, prm, ev, nev)
    team_errors(robots.p, robots.goal, robots.team, robots.known, ob, prm, e_team)
    rate_targets(t, e_team, teams.way_rate, progress, leaders, refs.s_end, prm, progress.target)
    done = True
    worst = 0.0
    for i in leaders:
        step(progress, i, dt, progress.target[i], refs.s_end, prm)
        teams.done[i] = progress.s[i] >= refs.s_end
        done = done and teams.done[i]
        worst = max(worst, abs(e_team[i]))
    # S17.3: at their ends the references still wait for the teams to re-form (a goal that
    # leaves an obstacle's Q in the last moments counts again), up to the finish wait's room
    waited = t - refs.s_end >= finish_wait_s(refs.s_end, prm)
    return nev, done and (worst <= prm.reform_stop_m or waited)
