"""ROS-free closed-loop simulator: every robot's switched sliding-mode law, its own switching
(obstacles) and the coordinator's decisions (robot encounters, right of way, the references'
progress), S9 rewiring, and the plant (S2) integrated with RK4 at ``dt_s`` (ZOH torques) under
the bounded smooth disturbance g(t). Ideal sensing: every decision reads the true state at once
(the robot agent and the coordinator of core/sim/sensed.py read what the system would have).

Structure (compiled, numba ``cache=True``):

* :func:`_run_segment` -- the 1 kHz loop over all robots: the law (core/control/law.py) in
  topological order of the current forest (a follower reads its parent's commanded acceleration
  of the same sample), RK4 per robot; every ``decision_period_s`` :func:`_decide`: each robot's
  own table (core/control/switching.py), the coordinator's (core/control/arbitration.py), the
  teams' errors and their references' progress (core/control/progress.py), and the neighbour
  lists of the barrier (a grid: near-linear in N). It returns to Python on a mode event (S9
  rewiring), when the mission ends (every reference at its end, S17.3) and when the record is
  full.
* Reaching phases (S3.4, S8.5): after every switch, re-parenting and at t = 0 the loop records
  sigma0 = ||sigma(t_s)||_inf and the time until ||sigma||_inf <= epsilon.
"""

from __future__ import annotations

from collections import namedtuple
import math
import time
from typing import Callable

from numba import njit
import numpy as np

from ament_formation.core.borrowed import borrowed, keep_alive
from ament_formation.core.control.arbitration import candidate_pairs, coordinate, new_teams
from ament_formation.core.control.law import goal_k, mode_row, robot_law_k, RobotTracking
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.progress import (
    at,
    leader_reference,
    max_time_s,
    new_progress,
    tabulate,
)
from ament_formation.core.control.switching import (
    MODE_C,
    MODE_MUTUAL,
    MODE_NAMES,
    MODE_OBSTACLE,
    new_modes,
    robot_transitions_among,
    Robots,
    threat_radius,
)
from ament_formation.core.model.disturbance import (
    Disturbance,
    disturbance_k,
    disturbance_phasor_advance_k,
    disturbance_phasor_init_k,
)
from ament_formation.core.model.dynamics import (
    PlantCoeffs,
    point_velocity_k,
    rk4_step_k,
    robot_plant_k,
    ROW_D,
)
from ament_formation.core.model.obstacles import (
    obstacle_arrays,
    obstacle_pairs,
    obstacle_states,
    ObstacleField,
    ObstacleSnapshot,
)
from ament_formation.core.sim.trajectory import SimResult

# why _run_segment returned
CHUNK_END, EVENTS, MISSION_END, RECORD_FULL = range(4)

Clock = namedtuple('Clock', ['dt', 'dec_every', 'rec_every'])
RobotArrays = namedtuple(
    'RobotArrays', ['x', 'acmd', 'torque', 'sat_flag', 'pd', 'goal', 'goal_dot', 'vc', 'ref',
                    'e_team', 'known']
)
GraphArrays = namedtuple(
    'GraphArrays', ['parent', 'offset', 'order', 'orig_parent', 'orig_offset', 'team', 'slot',
                    'leaders']
)
PlantArrays = namedtuple('PlantArrays', ['rbody', 'coeffs', 'd_amp', 'd_freq', 'd_phase',
                                         'd_hc', 'd_hs'])
ObstacleArrays = namedtuple('ObstacleArrays', ['c0', 'v', 'amp', 'w', 'phi0', 'phid', 'axes',
                                               'static'])
ReachArrays = namedtuple('ReachArrays', ['pending', 'active', 't0', 'sigma0', 'records', 'count'])
RecordArrays = namedtuple(
    'RecordArrays', ['state', 'torque', 'goal', 'avoiding', 'saturated', 'ob_center', 'ob_phi',
                     'progress']
)
Neighbours = namedtuple('Neighbours', ['start', 'idx', 'ob_start', 'ob_idx'])
Neighbours.__doc__ = """Robot rows and obstacle rows each robot's barrier checks (CSR: the robot
rows of robot i are ``idx[start[i]:start[i + 1]]``, its obstacle rows
``ob_idx[ob_start[i]:ob_start[i + 1]]``), rebuilt every decision."""
Mission = namedtuple('Mission', ['refs', 'progress', 't_dec', 'end_s'])
Mission.__doc__ = """The leaders' references (:data:`References`), their progress
(:data:`Progress`), ``t_dec`` (1,) [s] the time of the last decision, ``end_s`` (1,) [s] when
the mission ended (NaN before)."""

NEIGHBOUR_SLACK_M = 0.05  # the neighbour lists reach this beyond the barrier's range


@njit(cache=True, error_model='numpy')
def _csr(n, pairs):
    """CSR lists of rows 0..n-1 from (P, 2) pairs (row, member)."""
    start = np.zeros(n + 1, dtype=np.int64)
    for q in range(pairs.shape[0]):
        start[pairs[q, 0] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    idx = np.empty(pairs.shape[0], dtype=np.int64)
    for q in range(pairs.shape[0]):
        a = pairs[q, 0]
        idx[fill[a]] = pairs[q, 1]
        fill[a] += 1
    return start, idx


@njit(cache=True, error_model='numpy')
def neighbour_lists(p, known, rbody, prm, oc, obstacles, horizon_s):
    """:data:`Neighbours` of every robot: the known robots whose keep-out circle is within the
    barrier's range, plus ``NEIGHBOUR_SLACK_M`` for the motion until the next decision; the
    obstacles (centres ``oc`` now, motion ``obstacles``) whose square of half-side r1 + range
    (the barrier's own first test, core/control/safety.py) may hold the robot before
    ``horizon_s`` [s] (their fastest motion over it and ``NEIGHBOUR_SLACK_M`` added).
    """
    reach = 2.0 * rbody.max() + prm.agent_keepout_margin_m + prm.safety_range_m + \
        NEIGHBOUR_SLACK_M
    pairs = candidate_pairs(p, known, reach)
    both = np.empty((2 * pairs.shape[0], 2), dtype=np.int64)
    for q in range(pairs.shape[0]):
        both[2 * q, 0], both[2 * q, 1] = pairs[q, 0], pairs[q, 1]
        both[2 * q + 1, 0], both[2 * q + 1, 1] = pairs[q, 1], pairs[q, 0]
    start, idx = _csr(p.shape[0], both)
    m = oc.shape[0]
    radius = np.empty(m)
    for j in range(m):
        speed = math.hypot(obstacles.v[j, 0], obstacles.v[j, 1]) + math.hypot(
            obstacles.amp[j, 0], obstacles.amp[j, 1]) * abs(obstacles.w[j])
        radius[j] = obstacles.axes[j, 0] + prm.safety_range_m + NEIGHBOUR_SLACK_M + \
            (speed + prm.speed_limit_mps) * horizon_s
    ob_start, ob_idx = _csr(p.shape[0], obstacle_pairs(p, oc, radius))
    for i in range(p.shape[0]):  # in row order, as the barrier's projections go
        ob_idx[ob_start[i]:ob_start[i + 1]] = np.sort(ob_idx[ob_start[i]:ob_start[i + 1]])
    return Neighbours(start, idx, ob_start, ob_idx)


@njit(cache=True, error_model='numpy')
def _barrier_rows_needed(nb):
    """Rows the barrier of any robot may fill with :data:`Neighbours` ``nb``: its robots, the
    four floor edges, its obstacles, then the escape's edges and obstacles (core/control/safety.py
    :func:`safe_field`).
    """
    most = 0
    for i in range(nb.start.shape[0] - 1):
        obs = nb.ob_start[i + 1] - nb.ob_start[i]
        most = max(most, nb.start[i + 1] - nb.start[i] + 8 + 2 * obs)
    return most


@njit(cache=True, error_model='numpy')
def _barrier_rows(nb):
    """Scratch rows of the barrier shared by every robot of a step (one allocation, not one per
    robot and step), with room to spare.
    """
    return np.empty((2 * _barrier_rows_needed(nb) + 16, 5))


@njit(cache=True, error_model='numpy', inline='always')  # per step: no call with its many arrays
def _references(t, robots, graph, mission):
    """The leaders' references r, r_dot, r_ddot at t (within the progress interval begun at the
    last decision) into ``robots.ref``.
    """
    pr, refs = mission.progress, mission.refs
    tau = t - mission.t_dec[0]
    for i in graph.leaders:
        s, sd, sdd = at(pr, i, tau, refs.s_end)
        leader_reference(refs, i, s, sd, sdd, robots.ref[i])


@njit(cache=True, error_model='numpy')
def _threat_rows(p, ob, m, prm):
    """CSR lists (start, rows) of the obstacle rows each robot's guard ``obstacle_threat`` tests
    (core/control/switching.py :func:`robot_transitions_among`): the obstacles whose square of
    :func:`threat_radius` holds the robot (a grid, near-linear in N + M), and the one it is on,
    ascending and once each.
    """
    n, m_ob = p.shape[0], ob.c.shape[0]
    if n * m_ob <= 256:  # a few: every robot tests every obstacle (no grid to build)
        return np.arange(n + 1) * m_ob, np.arange(n * m_ob) % max(m_ob, 1)
    pairs = obstacle_pairs(p, ob.c, threat_radius(ob, prm))
    on = 0
    for i in range(n):
        on += m.mode[i] == MODE_OBSTACLE
    both = np.empty((pairs.shape[0] + on, 2), dtype=np.int64)
    both[:pairs.shape[0]] = pairs
    q = pairs.shape[0]
    for i in range(n):
        if m.mode[i] == MODE_OBSTACLE:
            both[q, 0], both[q, 1] = i, m.tgt[i]
            q += 1
    start, idx = _csr(n, both)
    out = np.zeros(n + 1, dtype=np.int64)
    cnt = 0
    for i in range(n):  # insertion sort of each short list, then each row once, compacted
        for a in range(start[i] + 1, start[i + 1]):
            v = idx[a]
            b = a - 1
            while b >= start[i] and idx[b] > v:
                idx[b + 1] = idx[b]
                b -= 1
            idx[b + 1] = v
        for a in range(start[i], start[i + 1]):
            if a == start[i] or idx[a] != idx[a - 1]:
                idx[cnt] = idx[a]
                cnt += 1
        out[i + 1] = cnt
    return out, idx[:cnt]


@njit(cache=True, error_model='numpy', inline='always')  # per step: no call with its many arrays
def _goals(every, robots, graph, m, prm):
    """The formation goals g, g_dot and the fields V_c (core/control/law.py :func:`goal_k`) of
    every robot when ``every`` (a decision reads them all, the record the goals), else of the
    robots off coordination only (the law reads a goal in an avoidance mode alone, S6.5).
    """
    x, pd = robots.x, robots.pd
    for i in range(x.shape[0]):
        if every or m.mode[i] != MODE_C:
            gx, gy, gdx, gdy, vcx, vcy = goal_k(i, x, pd, robots.ref, graph.orig_parent,
                                                graph.orig_offset, prm)
            robots.goal[i, 0], robots.goal[i, 1] = gx, gy
            robots.goal_dot[i, 0], robots.goal_dot[i, 1] = gdx, gdy
            robots.vc[i, 0], robots.vc[i, 1] = vcx, vcy


@njit(cache=True, error_model='numpy')
def _decide(t, robots, graph, plant, ob, m, teams, mission, prm, ev):
    """One decision: each robot's table (S8.7), then the coordinator's (S8.8) with the teams'
    progress (S17). Returns the event count.
    """
    dec = Robots(robots.x[:, :2].copy(), robots.pd, robots.goal, robots.goal_dot, robots.vc,
                 graph.team, plant.rbody, graph.parent, graph.slot, robots.known,
                 graph.orig_parent)
    nev = 0
    start, rows = _threat_rows(dec.p, ob, m, prm)
    for i in range(robots.x.shape[0]):
        # no obstacle to test: a robot off obstacles has nothing to do (its table's rows all
        # start from an obstacle, R1-R4), and a call per robot costs its many arguments
        if start[i + 1] > start[i]:
            nev = robot_transitions_among(i, t, dec, ob, m, prm, ev, nev,
                                          rows[start[i]:start[i + 1]])
    nev, done = coordinate(t, t - mission.t_dec[0], dec, ob, m, teams, mission.progress,
                           mission.refs, graph.leaders, robots.e_team, prm, ev, nev)
    mission.t_dec[0] = t
    if done and not mission.end_s[0] == mission.end_s[0]:  # NaN: not ended yet
        mission.end_s[0] = t
    return nev


@njit(cache=True, error_model='numpy', forceinline=True)
def _reach_record(reach, i, t, done):
    """Append the reaching phase of robot i that ends at t (S3.4) while there is room."""
    r = reach.count[0]
    if r < reach.records.shape[0]:
        reach.records[r, 0] = i
        reach.records[r, 1] = reach.t0[i]
        reach.records[r, 2] = reach.sigma0[i]
        reach.records[r, 3] = t - reach.t0[i]
        reach.records[r, 4] = done
        reach.count[0] = r + 1


@njit(cache=True, error_model='numpy', inline='always')  # per step: no call with its many arrays
def _reaching(reach, i, t, sx, sy, eps):
    """S3.4: sigma0 at a pending switch, the end of the phase when ||sigma||_inf <= eps."""
    sig = max(abs(sx), abs(sy))
    if reach.pending[i]:
        if reach.active[i]:
            _reach_record(reach, i, t, 0.0)  # interrupted by the next switch
        reach.pending[i] = False
        reach.active[i] = True
        reach.t0[i] = t
        reach.sigma0[i] = sig
    if reach.active[i] and sig <= eps:
        _reach_record(reach, i, t, 1.0)
        reach.active[i] = False


@njit(cache=True, error_model='numpy')
def _record(rk, robots, mode, ob, rec, mission):
    """Sample ``rk`` of the record: states, torques, goals, flags, obstacle poses, the progress
    of every leader's reference (S17; 0 for followers).
    """
    x = robots.x
    for i in range(x.shape[0]):
        rec.progress[rk, i] = mission.progress.s[i] if mission.refs.row[i] >= 0 else 0.0
    for i in range(x.shape[0]):
        for q in range(5):
            rec.state[rk, i, q] = x[i, q]
        rec.torque[rk, i, 0] = robots.torque[i, 0]
        rec.torque[rk, i, 1] = robots.torque[i, 1]
        rec.goal[rk, i, 0] = robots.goal[i, 0]
        rec.goal[rk, i, 1] = robots.goal[i, 1]
        rec.avoiding[rk, i] = mode[i] != MODE_C
        rec.saturated[rk, i] = robots.sat_flag[i]
    for j in range(ob.c.shape[0]):
        rec.ob_center[rk, j, 0] = ob.c[j, 0]
        rec.ob_center[rk, j, 1] = ob.c[j, 1]
        rec.ob_phi[rk, j] = ob.phi[j]


@njit(cache=True, error_model='numpy', inline='always')  # per step: no call with its many arrays
def _plant_step(robots, plant, d_sin, d_cos, g_prev, dt):
    """RK4 with ZOH torques and g at t, t + dt/2, t + dt (S2.2) for every robot."""
    x = robots.x
    for i in range(x.shape[0]):
        gha, ghb = disturbance_phasor_advance_k(plant.d_amp[i], d_sin[i], d_cos[i], plant.d_hc[i],
                                                plant.d_hs[i])
        g1a, g1b = disturbance_phasor_advance_k(plant.d_amp[i], d_sin[i], d_cos[i], plant.d_hc[i],
                                                plant.d_hs[i])
        nx = rk4_step_k((x[i, 0], x[i, 1], x[i, 2], x[i, 3], x[i, 4]),
                        (robots.torque[i, 0], robots.torque[i, 1]), (g_prev[i, 0], g_prev[i, 1]),
                        (gha, ghb), (g1a, g1b), dt, robot_plant_k(plant.coeffs, i))
        g_prev[i, 0] = g1a
        g_prev[i, 1] = g1b
        for q in range(5):
            x[i, q] = nx[q]


@njit(cache=True, error_model='numpy')
def _run_segment(span, skip_decide, clock, robots, graph, plant, obstacles, m, teams, mission,
                 prm, ev, reach, rec):
    """Steps k0 .. k_end-1 of the closed loop, ``span`` = (k0, k_end, first record row).

    Returns (next step, next record row, events, why it returned: CHUNK_END, EVENTS,
    MISSION_END or RECORD_FULL).
    """
    dt, dec_every, rec_every = clock
    k0, k_end, rk0 = span
    # the loop reads every array without reference counting (core/borrowed.py): the
    # arguments' owners are the caller's, those allocated here are kept alive to the end
    robots, graph, plant, obstacles, m, teams, mission, ev, reach, rec = borrowed(
        (robots, graph, plant, obstacles, m, teams, mission, ev, reach, rec))
    x, pd = robots.x, robots.pd
    n = x.shape[0]
    own = (np.empty_like(plant.d_amp), np.empty_like(plant.d_amp), np.empty((n, 2)))
    d_sin, d_cos, g_prev = borrowed(own)
    for i in range(n):  # the disturbance phasors restart at every segment: no drift
        disturbance_phasor_init_k(k0 * dt, plant.d_freq[i], plant.d_phase[i], d_sin[i], d_cos[i])
        g_prev[i, 0], g_prev[i, 1] = disturbance_k(k0 * dt, plant.d_amp[i], plant.d_freq[i],
                                                   plant.d_phase[i])
    ob_own = ObstacleSnapshot(np.empty((obstacles.axes.shape[0], 2)),
                              np.empty((obstacles.axes.shape[0], 2)),
                              np.empty((obstacles.axes.shape[0], 2)),
                              np.empty(obstacles.axes.shape[0]), np.empty(obstacles.axes.shape[0]),
                              np.empty(obstacles.axes.shape[0]), obstacles.axes, obstacles.static)
    ob = borrowed(ob_own)
    horizon = dec_every * dt
    obstacle_states(k0 * dt, obstacles.c0, obstacles.v, obstacles.amp, obstacles.w,
                    obstacles.phi0, obstacles.phid, ob.c, ob.v, ob.a, ob.phi, ob.phi_dot,
                    ob.phi_ddot)
    nb_own = neighbour_lists(x[:, :2].copy(), robots.known, plant.rbody, prm, ob.c, obstacles,
                             horizon)
    nb = borrowed(nb_own)
    cons_own = _barrier_rows(nb)
    cons = borrowed(cons_own)
    rk = rk0
    ended = mission.end_s[0] == mission.end_s[0]
    for kk in range(k0, k_end):
        if kk % rec_every == 0 and rk >= rec.state.shape[0]:
            return kk, rk, 0, RECORD_FULL
        t = kk * dt
        obstacle_states(t, obstacles.c0, obstacles.v, obstacles.amp, obstacles.w,
                        obstacles.phi0, obstacles.phid, ob.c, ob.v, ob.a, ob.phi, ob.phi_dot,
                        ob.phi_ddot)
        for i in range(n):
            pd[i, 0], pd[i, 1] = point_velocity_k(x[i, 2], x[i, 3], x[i, 4],
                                                  plant.coeffs[ROW_D, i])
        _references(t, robots, graph, mission)
        _goals(kk % dec_every == 0 or kk % rec_every == 0, robots, graph, m, prm)
        if kk % dec_every == 0 and not (skip_decide and kk == k0):
            nev = _decide(t, robots, graph, plant, ob, m, teams, mission, prm, ev)
            nb_own = neighbour_lists(x[:, :2].copy(), robots.known, plant.rbody, prm, ob.c,
                                     obstacles, horizon)
            nb = borrowed(nb_own)
            if cons.shape[0] < _barrier_rows_needed(nb):
                cons_own = _barrier_rows(nb)
                cons = borrowed(cons_own)
            if nev > 0:
                return kk, rk, nev, EVENTS
            if not ended and mission.end_s[0] == mission.end_s[0]:
                return kk, rk, 0, MISSION_END
        for q in range(n):  # parents before children (S4 feed-forward of this sample's a_j)
            i = graph.order[q]
            par = graph.parent[i]
            track = RobotTracking(par, (graph.offset[i, 0], graph.offset[i, 1]),
                                  (robots.ref[i, 0], robots.ref[i, 1], robots.ref[i, 2],
                                   robots.ref[i, 3], robots.ref[i, 4], robots.ref[i, 5]),
                                  (robots.goal[i, 0], robots.goal[i, 1]),
                                  (robots.goal_dot[i, 0], robots.goal_dot[i, 1]))
            t1, t2, sx, sy, sat, acx, acy, wdx, wdy = robot_law_k(
                i, t, x, pd, robots.acmd, plant.rbody, plant.coeffs, ob,
                nb.idx[nb.start[i]:nb.start[i + 1]], nb.ob_idx[nb.ob_start[i]:nb.ob_start[i + 1]],
                track, mode_row(m, i), prm, cons)
            robots.torque[i, 0] = t1
            robots.torque[i, 1] = t2
            robots.sat_flag[i] = sat
            robots.acmd[i, 0] = acx
            robots.acmd[i, 1] = acy
            if m.mode[i] == MODE_MUTUAL:
                m.wc[i, 0] += dt * wdx
                m.wc[i, 1] += dt * wdy
            _reaching(reach, i, t, sx, sy, prm.boundary_layer_mps)
        if kk % rec_every == 0:
            _record(rk, robots, m.mode, ob, rec, mission)
            rk += 1
        _plant_step(robots, plant, d_sin, d_cos, g_prev, dt)
    keep_alive((own, ob_own, nb_own, cons_own))
    return k_end, rk, 0, CHUNK_END


# ------------------------------------------------------------------------------ Python driver


class _Setup:
    """Arrays of one scenario for the compiled loop (rows in robot-id order)."""

    def __init__(self, scenario, dt_s: float, law: LawParams):
        from ament_formation.core.control.rewiring import FormationGraph

        robots = sorted(scenario.robots, key=lambda r: r.id)
        self.ids = tuple(int(r.id) for r in robots)
        self.index = {rid: i for i, rid in enumerate(self.ids)}
        n = self.n = len(robots)
        k = PlantCoeffs.from_params([r.params for r in robots])
        coeffs = np.ascontiguousarray(np.stack([k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c,
                                                k.tau_max]))
        rbody = np.array([r.params.body_radius_m for r in robots], dtype=float)
        self.law = law
        self.prm = law.compiled()
        dist = Disturbance.from_bounds(n, np.asarray(scenario.disturbance.accel_bound, float),
                                       scenario.disturbance.seed)
        self.plant = PlantArrays(rbody, coeffs, dist.amplitude, dist.freq_hz, dist.phase_rad,
                                 *dist.step_rotation(0.5 * dt_s))
        self.obstacle_names = tuple(o.name for o in scenario.obstacles)
        law_obstacles = scenario.avoided_obstacles()  # S13.3 (the record keeps the scenario's)
        self.merged = law_obstacles != scenario.obstacles
        self.law_names = tuple(o.name for o in law_obstacles)
        self.obstacles = ObstacleArrays(*obstacle_arrays(law_obstacles))
        self.graph = FormationGraph.from_scenario(scenario)
        slots = np.array([r.slot_m for r in robots], dtype=float).reshape(n, 2)
        orig_parent = np.full(n, -1, dtype=np.int64)
        orig_offset = np.zeros((n, 2))
        for i, rid in enumerate(self.ids):
            par = self.graph.original_parent.get(rid)
            if par is not None:
                orig_parent[i] = self.index[par]
                orig_offset[i] = slots[i] - slots[orig_parent[i]]
        self.team = np.array([self.index[scenario.team_leader(rid)] for rid in self.ids],
                             dtype=np.int64)
        self.slots, self.orig_parent, self.orig_offset = slots, orig_parent, orig_offset
        self.leaders = np.array([i for i, r in enumerate(robots) if r.leader], dtype=np.int64)
        self.paths = [r.path if r.leader else None for r in robots]
        self.state0 = np.zeros((n, 5))
        for i, r in enumerate(robots):
            self.state0[i, :3] = r.initial_pose

    def graph_arrays(self, parent, offset, order) -> GraphArrays:
        return GraphArrays(parent, offset, order, self.orig_parent, self.orig_offset, self.team,
                           self.slots, self.leaders)

    def parents_from(self, parents: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(parent rows, offsets, topological order) of a parents dict {child: parent | None}."""
        n = self.n
        parent = np.full(n, -1, dtype=np.int64)
        for child, par in parents.items():
            if par is not None:
                parent[self.index[child]] = self.index[par]
        offset = np.zeros((n, 2))
        has = parent >= 0
        offset[has] = self.slots[has] - self.slots[parent[has]]
        children = [[] for _ in range(n)]
        for i in np.flatnonzero(has):
            children[parent[i]].append(i)
        order = [i for i in range(n) if parent[i] < 0]
        q = 0
        while q < len(order):
            order.extend(children[order[q]])
            q += 1
        if len(order) != n:  # a cycle cannot come out of S9; keep every robot anyway
            order += sorted(set(range(n)) - set(order))
        return parent, offset, np.array(order, dtype=np.int64)


def _buffers(setup: _Setup, n_rec: int):
    n, m = setup.n, len(setup.law_names)
    z2 = lambda: np.zeros((n, 2))  # noqa: E731 - a fresh (n, 2) array each call
    robots = RobotArrays(setup.state0.copy(), z2(), z2(), np.zeros(n, dtype=np.bool_), z2(),
                         z2(), z2(), z2(), np.zeros((n, 6)), np.zeros(n),
                         np.ones(n, dtype=np.bool_))
    reach = ReachArrays(np.ones(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_), np.zeros(n),
                        np.zeros(n), np.zeros((max(64, 16 * n), 5)), np.zeros(1, dtype=np.int64))
    return robots, reach, _record_arrays(n, m, n_rec)


def _record_arrays(n: int, m: int, n_rec: int) -> RecordArrays:
    return RecordArrays(np.zeros((n_rec, n, 5)), np.zeros((n_rec, n, 2)), np.zeros((n_rec, n, 2)),
                        np.zeros((n_rec, n), dtype=np.bool_), np.zeros((n_rec, n), dtype=np.bool_),
                        np.zeros((n_rec, m, 2)), np.zeros((n_rec, m)), np.zeros((n_rec, n)))


def _grown(rec: RecordArrays, rows: int) -> RecordArrays:
    """``rec`` with room for ``rows`` samples (its samples kept)."""
    return RecordArrays(*(np.concatenate([a, np.zeros((rows - a.shape[0], *a.shape[1:]),
                                                      dtype=a.dtype)]) for a in rec))


def simulate(
    scenario,
    *,
    dt_s: float = 0.001,
    record_every_s: float = 0.01,
    progress: Callable[[float, float], None] | None = None,
    law: LawParams | None = None,
    hold_s: float = 0.0,
) -> SimResult:
    """Run the closed loop of ``scenario`` until its mission ends (every leader's reference at
    its end, S17.3) and ``hold_s`` [s] longer (the references at rest, the hold in full), or
    until :func:`max_time_s` when the mission does not end; return the record (``mission_end_s``
    None when the mission did not end).

    ``dt_s``: integration and control period [s] (RK4, ZOH torques; the S3.2 law runs every
    step); ``record_every_s``: the record's period [s]; ``progress``: callable(t_s, duration_s)
    called about every 5 s of simulated time; ``law``: the law's parameters (default: the
    scenario's, :meth:`LawParams.for_scenario`).
    """
    wall0 = time.perf_counter()
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise ValueError(f'dt_s: must be a finite number > 0 (got {dt_s!r})')
    if not (hold_s >= 0 and math.isfinite(hold_s)):
        raise ValueError(f'hold_s: must be a finite number >= 0 (got {hold_s!r})')
    law = law or LawParams.for_scenario(scenario)
    setup = _Setup(scenario, dt_s, law)
    n = setup.n
    rec_every = max(1, int(round(record_every_s / dt_s)))
    dec_every = max(1, int(round(law.decision_period_s / dt_s)))
    k_cap = int(round(max_time_s(scenario.duration_s) / dt_s))
    robots, reach, rec = _buffers(setup, int((scenario.duration_s + 10.0) / dt_s) // rec_every)
    m = new_modes(n)
    teams = new_teams(n)
    mission = Mission(tabulate(setup.paths, scenario.duration_s), new_progress(n), np.zeros(1),
                      np.full(1, np.nan))
    ev = np.zeros((16 * n + 16, 6))
    clock = Clock(dt_s, dec_every, rec_every)
    avoiding: frozenset[int] = frozenset()
    parents = setup.graph.rewire(set())
    parent, offset, order = setup.parents_from(parents)
    mode_events: list[dict] = []
    graph_events: list[dict] = [{'t_s': 0.0, 'parents': _parents_json(parents)}]
    reaching: list[dict] = []
    k, rk, skip, k_end = 0, 0, False, k_cap
    next_progress = 5.0
    while k < k_end:
        k, rk, nev, why = _run_segment(
            (k, min(k_end, k + int(round(5.0 / dt_s))), rk), skip, clock, robots,
            setup.graph_arrays(parent, offset, order), setup.plant, setup.obstacles, m, teams,
            mission, setup.prm, ev, reach, rec)
        if reach.count[0] > reach.records.shape[0] // 2:
            _drain_reaching(setup, reach, reaching)
        skip = why in (EVENTS, MISSION_END)
        if why == RECORD_FULL:
            rec = _grown(rec, int(rec.state.shape[0] * 1.5) + 16)
        elif why == MISSION_END:
            k_end = k + int(round(hold_s / dt_s))  # the hold in full (S17.3)
        elif why == EVENTS:
            if nev > ev.shape[0]:
                raise RuntimeError('mode event buffer overflow')
            for i in _mode_events(setup, ev[:nev], mode_events):
                reach.pending[i] = True
            now_avoiding = frozenset(setup.ids[i] for i in range(n) if m.mode[i] != MODE_C)
            if now_avoiding != avoiding:
                avoiding = now_avoiding
                new_parents = setup.graph.rewire(set(avoiding))
                new_parent, offset, order = setup.parents_from(new_parents)
                reach.pending[new_parent != parent] = True
                parent = new_parent
                if new_parents != parents:
                    parents = new_parents
                    graph_events.append({'t_s': round(k * dt_s, 9),
                                         'parents': _parents_json(parents)})
            if mission.end_s[0] == mission.end_s[0] and k_end == k_cap:
                k_end = k + int(round(hold_s / dt_s))  # the hold in full (S17.3)
        if progress is not None and k * dt_s >= next_progress:
            progress(k * dt_s, scenario.duration_s)
            next_progress += 5.0
    _drain_reaching(setup, reach, reaching)
    if progress is not None:
        progress(k * dt_s, scenario.duration_s)
    rec = RecordArrays(*(a[:rk] for a in rec))
    t_rec = np.arange(rk) * rec_every * dt_s
    if setup.merged:
        rec = _record_scenario_obstacles(scenario, t_rec, rec)
    end = float(mission.end_s[0])
    return SimResult(
        scenario_name=scenario.name, robot_ids=setup.ids, obstacle_names=setup.obstacle_names,
        t_s=t_rec, state=rec.state, torque_nm=rec.torque, goal_m=rec.goal, avoiding=rec.avoiding,
        saturated=rec.saturated, obstacle_center_m=rec.ob_center, obstacle_phi_rad=rec.ob_phi,
        mode_events=mode_events, graph_events=graph_events, reaching=reaching, dt_s=dt_s,
        wall_time_s=time.perf_counter() - wall0,
        mission_end_s=None if math.isnan(end) else round(end, 9),
        nominal_duration_s=float(scenario.duration_s), progress_s=rec.progress,
    )


def _drain_reaching(setup: _Setup, reach: ReachArrays, reaching: list[dict]) -> None:
    """Move the reaching-phase records the loop wrote (S3.4) to ``reaching`` as dicts."""
    lam = setup.law.gains.reaching_rate_mps2
    for r in range(int(reach.count[0])):
        i, t0, s0, tr, done = reach.records[r]
        reaching.append({'robot': setup.ids[int(i)], 't_s': float(t0),
                         'sigma0_inf_mps': float(s0), 't_reach_s': float(tr),
                         'bound_s': float(s0) / lam, 'completed': bool(done)})
    reach.count[0] = 0


def _record_scenario_obstacles(scenario, t_rec: np.ndarray, rec: RecordArrays) -> RecordArrays:
    """``rec`` with the scenario's obstacles at the record times (the loop recorded the ones the
    law avoids, some merged: S13.3).
    """
    field = ObstacleField(scenario.obstacles)
    states = [field.at(float(t)) for t in t_rec]
    if not states:
        return rec
    return rec._replace(ob_center=np.stack([st.center_m for st in states]),
                        ob_phi=np.stack([st.phi_rad for st in states]))


def target_name(names, ids, mode: int, target: int) -> str:
    """A mode event's target: an obstacle's name or ``robot_<id>``."""
    return names[target] if mode == MODE_OBSTACLE else f'robot_{ids[target]}'


def _mode_events(setup: _Setup, rows: np.ndarray, mode_events: list[dict]) -> set[int]:
    """Append the event rows (t, robot row, enter, mode, target, sense) to ``mode_events`` as
    dicts; the set of robot rows that switched.
    """
    changed = set()
    for t_ev, i, enter, md, target, s in rows:
        i = int(i)
        changed.add(i)
        mode_events.append({
            't_s': round(float(t_ev), 9), 'robot': setup.ids[i],
            'event': 'enter' if enter > 0.5 else 'exit', 'mode': MODE_NAMES[int(md)],
            'target': target_name(setup.law_names, setup.ids, int(md), int(target)),
            'direction': 'ccw' if s > 0 else 'cw',
        })
    return changed


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}
