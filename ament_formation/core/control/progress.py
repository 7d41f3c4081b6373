"""Formations that re-form: the leader's reference waits for its team (docs/control-law.md S17).

A leader tracks r(s) of its path at a progress s [s of path time] instead of r(t):
r_dot = r'(s) s_dot and r_ddot = r''(s) s_dot^2 + r'(s) s_ddot. The progress rate follows a
target with a first-order lag (``progress_tau_s``), so s_ddot stays bounded (S17.2):

* the team's error E = max over its robots of |p_i - g_i| (goals inside an obstacle's Q left
  out: such a robot is parked, S6.5) slows the target from 1 at ``reform_start_m`` to 0 at
  ``reform_stop_m`` (S17.1): a team that fell apart waits for its robots instead of leaving them
  behind;
* a team that gives way to another (S7.5) waits: target 0 while one of its robots yields to a
  moving robot of a team that ranks before it, and below 1 while such a robot moves across its
  way close ahead of one of its robots (the headway, ``Teams.way_rate``);
* a team whose leader's goal lies inside an obstacle's Q moves on (target 1): waiting would
  keep the leader parked, and its followers' goals with it;
* the reference ends at s = s_end (the scenario's ``duration_s``): there it rests.

The mission ends when every leader's reference has reached its end (S17.3); a reference within
``finish_s`` of its end waits while any team is not re-formed, so that the mission ends with every
team in formation (a team already at its end may have been pushed out of formation since). The
wait along the path is bounded by :func:`max_wait_s`; the finish wait outlasts that budget, bounded
by :func:`finish_wait_s` so that the mission still ends within the run's cap (:func:`max_time_s`).
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.model.ellipse import h_value
from ament_formation.core.model.obstacles import obstacle_pairs
from ament_formation.core.model.paths import tabulated_reference_k

REFERENCE_STEP_S = 0.01  # grid of the tabulated references in progress s [s]

References = namedtuple('References', ['table', 'row', 'step_s', 's_end'])
References.__doc__ = """The leaders' paths tabulated in progress s: ``table`` (L, G, 6) rows
[x, y, x', y', x'', y''] (derivatives in s) every ``step_s`` from s = 0 to ``s_end``; ``row``
(N,) the table of each robot row (-1: not a leader); ``step_s`` [s]; ``s_end`` [s].
"""

Progress = namedtuple('Progress', ['s', 'sd', 'sdd', 'target'])
Progress.__doc__ = """The progress of every team's reference, rows by robot row (a team is its
leader's row): ``s`` (N,) [s], ``sd`` (N,) rate [1], ``sdd`` (N,) [1/s], ``target`` (N,) the
rate it follows [1].
"""


MIN_WAIT_S = 20.0  # the least a reference may wait in all (S17.2) [s]


@njit(cache=True, error_model='numpy', forceinline=True)
def max_wait_s(s_end, prm):
    """S17.2: how long in all a team's reference may wait (lag behind its nominal timing) [s]."""
    return max(MIN_WAIT_S, prm.max_wait_fraction * s_end)


def max_time_s(duration_s: float) -> float:
    """S17.3: how long a mission may take before a run gives up on it: three times its free
    traversal, at least 30 s more [s].
    """
    return duration_s + max(30.0, 2.0 * duration_s)


@njit(cache=True, error_model='numpy', forceinline=True)
def finish_wait_s(s_end, prm):
    """S17.3: how long in all (t - s) a reference may lag when it waits at its finish for the
    teams to re-form: what :func:`max_time_s` leaves, less the time to finish after the wait
    (twice ``finish_s`` + ``progress_tau_s``), so that the mission still ends within the run [s].
    """
    return max(30.0, 2.0 * s_end) - 2.0 * (prm.finish_s + prm.progress_tau_s)


def tabulate(paths, s_end: float, step_s: float = REFERENCE_STEP_S) -> References:
    """:data:`References` of ``paths`` (one per robot row, None for a follower) over
    [0, ``s_end``].
    """
    grid = np.arange(int(math.ceil(s_end / step_s)) + 2) * step_s
    rows = np.full(len(paths), -1, dtype=np.int64)
    tabs = []
    for i, path in enumerate(paths):
        if path is None:
            continue
        r, rd, rdd = (np.asarray(v, dtype=float).reshape(-1, 2) for v in path.reference(grid))
        rows[i] = len(tabs)
        tabs.append(np.concatenate([r, rd, rdd], axis=1))
    table = np.stack(tabs) if tabs else np.zeros((0, grid.size, 6))
    return References(np.ascontiguousarray(table), rows, float(step_s), float(s_end))


def new_progress(n: int) -> Progress:
    """:data:`Progress` of n rows at the start: s = 0, at the nominal rate."""
    return Progress(np.zeros(n), np.ones(n), np.zeros(n), np.ones(n))


# implements: S17
@njit(cache=True, error_model='numpy', forceinline=True)
def leader_reference(refs, i, s, sd, sdd, out):
    """r, r_dot, r_ddot of leader row i at progress (s, s_dot, s_ddot) -> ``out`` (6,)."""
    h = refs.step_s
    table = refs.table[refs.row[i]]
    s = min(max(s, 0.0), refs.s_end)
    u = s / h
    j = min(int(u), table.shape[0] - 2)
    tabulated_reference_k(table, j, u - j, h, out)
    rpx, rpy = out[2], out[3]
    out[2] = rpx * sd
    out[3] = rpy * sd
    out[4] = out[4] * sd * sd + rpx * sdd
    out[5] = out[5] * sd * sd + rpy * sdd


@njit(cache=True, error_model='numpy', forceinline=True)
def goal_free(gx, gy, ob, prm):
    """The goal lies outside every obstacle's protected region Q (else the robot is parked on a
    limit cycle by design and does not count in its team's error, S17.1).
    """
    kap = prm.protected_scale
    for j in range(ob.c.shape[0]):
        dx, dy = gx - ob.c[j, 0], gy - ob.c[j, 1]
        big = 1.01 * kap * max(ob.axes[j, 0], ob.axes[j, 1])
        if abs(dx) > big or abs(dy) > big:  # beyond Q's bounding square: outside Q
            continue
        if h_value(dx, dy, ob.phi[j], kap * ob.axes[j, 0], kap * ob.axes[j, 1]) < 0.0:
            return False
    return True


@njit(cache=True, error_model='numpy', forceinline=True)
def _goal_free_among(gx, gy, ob, prm, rows):
    """:func:`goal_free` over the obstacle rows ``rows`` only (those whose Q's bounding square
    holds the goal: the others pass its first test).
    """
    kap = prm.protected_scale
    for j in rows:
        if h_value(gx - ob.c[j, 0], gy - ob.c[j, 1], ob.phi[j], kap * ob.axes[j, 0],
                   kap * ob.axes[j, 1]) < 0.0:
            return False
    return True


@njit(cache=True, error_model='numpy')
def _free_goals(goal, ob, prm):
    """(N,) bool: :func:`goal_free` of every row's goal; for many robots and obstacles by a grid
    of the obstacles' bounding squares of Q (the same squares, so the same answers).
    """
    n, m = goal.shape[0], ob.c.shape[0]
    free = np.ones(n, dtype=np.bool_)
    if n * m <= 256:
        for i in range(n):
            free[i] = goal_free(goal[i, 0], goal[i, 1], ob, prm)
        return free
    big = np.empty(m)
    for j in range(m):
        big[j] = 1.01 * prm.protected_scale * max(ob.axes[j, 0], ob.axes[j, 1])
    pairs = obstacle_pairs(goal, ob.c, big)  # |g - c| <= big in x and y: goal_free's test
    q = 0
    while q < pairs.shape[0]:
        i = pairs[q, 0]
        r = q
        while r < pairs.shape[0] and pairs[r, 0] == i:
            r += 1
        free[i] = _goal_free_among(goal[i, 0], goal[i, 1], ob, prm, pairs[q:r, 1])
        q = r
    return free


@njit(cache=True, error_model='numpy', forceinline=True)
def team_errors(p, goal, team, known, ob, prm, out):
    """S17.1: E of every team -> ``out`` (N,) at the leader rows: the largest |p_i - g_i| of its
    known robots with a free goal; -E when the leader's own goal is not free (the reference must
    carry it out of the obstacle's Q, the followers' goals hang on the parked leader).
    """
    out[:] = 0.0
    free = _free_goals(goal, ob, prm)
    for i in range(p.shape[0]):
        if not known[i] or not free[i]:
            continue
        e = math.hypot(p[i, 0] - goal[i, 0], p[i, 1] - goal[i, 1])
        if e > out[team[i]]:
            out[team[i]] = e
    for i in range(p.shape[0]):
        if team[i] == i and not free[i]:
            out[i] = -out[i]


@njit(cache=True, error_model='numpy', forceinline=True)
def rate_target(e_team, way_rate, prm):
    """S17.1, S17.2: the progress rate a team's reference follows, in [0, 1]: its error's,
    capped by ``way_rate``, the right of way's (S7.5).
    """
    span = prm.reform_stop_m - prm.reform_start_m
    return min(way_rate, 1.0, max(0.0, (prm.reform_stop_m - e_team) / span))


# implements: S17.1
@njit(cache=True, error_model='numpy', forceinline=True)
def rate_targets(t, e_team, way_rate, pr, leaders, s_end, prm, out):
    """S17.1-S17.3: the rate target of every leader row at time ``t`` [s since the mission's
    start] -> ``out``: :func:`rate_target` of its team (``way_rate`` (N,) the right of way's cap,
    S7.5), and 0 within ``finish_s`` of its end while
    some team is not re-formed (E above ``reform_stop_m``): the mission ends with every team in
    formation. A reference that has waited :func:`max_wait_s` in all (t - s) moves on at 1, but
    for the finish wait, which lasts up to :func:`finish_wait_s` in all.
    """
    worst = 0.0
    for i in leaders:
        worst = max(worst, abs(e_team[i]))
    budget = max_wait_s(s_end, prm)
    finish_room = finish_wait_s(s_end, prm)
    for i in leaders:
        # a parked leader (E < 0) moves on: its goal must come out of the obstacle's Q
        out[i] = min(way_rate[i], 1.0) if e_team[i] < 0.0 else rate_target(
            e_team[i], way_rate[i], prm)
        late = t - pr.s[i]
        if late >= budget:
            out[i] = 1.0
        if worst > prm.reform_stop_m and pr.s[i] >= s_end - prm.finish_s and late < finish_room:
            out[i] = 0.0  # the finish wait outlasts the budget, within the run's cap (S17.3)


@njit(cache=True, error_model='numpy', forceinline=True)
def path_heading(refs, i, s, out):
    """The unit direction r'(s)/|r'(s)| of leader row i's path at progress s -> ``out`` (2,) (NaN
    where the path does not move): the way its team goes, also while its reference waits.
    """
    table = refs.table[refs.row[i]]
    j = min(max(int(round(s / refs.step_s)), 0), table.shape[0] - 1)
    vx, vy = table[j, 2], table[j, 3]
    v = math.hypot(vx, vy)
    out[0], out[1] = (vx / v, vy / v) if v > 1e-9 else (np.nan, np.nan)


@njit(cache=True, error_model='numpy', forceinline=True)
def at(pr, i, tau, s_end):
    """(s, s_dot, s_ddot) of row i ``tau`` [s] into its current interval (s_ddot constant over
    it); at s_end the reference rests.
    """
    sdd = pr.sdd[i]
    s = pr.s[i] + pr.sd[i] * tau + 0.5 * sdd * tau * tau
    if s >= s_end:
        return s_end, 0.0, 0.0
    return s, max(0.0, pr.sd[i] + sdd * tau), sdd


@njit(cache=True, error_model='numpy', forceinline=True)
def step(pr, i, dt, target, s_end, prm):
    """Row i to the end of its interval of ``dt`` [s], then toward ``target`` for the next one:
    s_ddot = (target - s_dot) / ``progress_tau_s`` (S17.2).
    """
    s, sd, _ = at(pr, i, dt, s_end)
    pr.s[i] = s
    pr.sd[i] = sd
    pr.target[i] = target
    pr.sdd[i] = 0.0 if s >= s_end else (target - sd) / prm.progress_tau_s
