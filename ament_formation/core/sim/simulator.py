"""ROS-free closed-loop simulator: every robot's switched sliding-mode law, the S8 automaton with
the S7 encounter arbitration, S9 rewiring, and the plant (S2) integrated with RK4 at ``dt_s`` (ZOH
torques) under the bounded smooth disturbance g(t).

Structure (fast path, numba ``cache=True``):

* :func:`~ament_formation.core.control.law.robot_law` -- ONE robot's law at one sample: the
  mode's field (S4 leader/follower with the parent's commanded acceleration as feed-forward;
  S6.3/S6.4 limit cycle for obstacles, moving and rotating; S7 yield and mutual fields) and the
  sliding-mode torque (S3.1, S3.2, S3.5, S3.6). The per-robot
  :class:`~ament_formation.core.control.controller.RobotController` calls it; the loop here calls
  its kernel :func:`~ament_formation.core.control.law.robot_law_k` with the robot's rows (the same
  law, fewer arrays handed over per call).
* :func:`_run_segment` -- the 1 kHz loop over all robots (law in topological order of the current
  forest, so followers get the parent's commanded acceleration of the same sample; RK4 per robot),
  with :func:`ament_formation.core.control.encounters.decide` every ``decision_period_s``. It
  returns to
  Python only when a mode event happened (for S9 rewiring with
  :class:`ament_formation.core.control.rewiring.FormationGraph` and event records) or at a chunk
  end (the
  leaders' references are tabulated per chunk).
* Reaching phases (S3.4, S8.5): after every switch, re-parenting and at t = 0 the loop records
  sigma0 = ||sigma(t_s)||_inf and the time until ||sigma||_inf <= epsilon; the S3.4 bound is
  ||sigma0||_inf / lambda.
"""

from __future__ import annotations

from collections import namedtuple
import math
import time
from typing import Callable

from numba import njit
import numpy as np

from ament_formation.core.control.automaton import (
    AutomatonArrays,
    MODE_C,
    MODE_MUTUAL,
    MODE_NAMES,
    MODE_OBSTACLE,
    robot_mode_k,
    SwitchingParams,
)
from ament_formation.core.control.encounters import decide, DecisionRobots
from ament_formation.core.control.law import (
    gains_vector,
    goals_and_fields,
    robot_law_k,
    Tracking,
    tracking_row_k,
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
    obstacle_states,
    ObstacleField,
    ObstacleSnapshot,
)
from ament_formation.core.model.paths import quintic_hermite_k
from ament_formation.core.sim.trajectory import SimResult

REF_SUB = 10  # leader references are tabulated every REF_SUB steps and interpolated

# What _run_segment takes, grouped and named (numba compiles named tuples of arrays as records).
Clock = namedtuple('Clock', ['dt', 'dec_every', 'rec_every'])
Reference = namedtuple('Reference', ['k0', 'sub', 'table', 'leader_rows'])
RobotArrays = namedtuple(
    'RobotArrays', ['x', 'acmd', 'torque', 'sat_flag', 'pd', 'goal', 'goal_dot', 'vc', 'ref']
)
GraphArrays = namedtuple(
    'GraphArrays', ['parent', 'offset', 'order', 'orig_parent', 'orig_offset', 'team', 'slot']
)
PlantArrays = namedtuple(
    'PlantArrays', ['rbody', 'coeffs', 'gains', 'd_amp', 'd_freq', 'd_phase', 'd_hc', 'd_hs']
)
ObstacleArrays = namedtuple(
    'ObstacleArrays', ['c0', 'v', 'amp', 'w', 'phi0', 'phid', 'axes', 'static']
)
ReachArrays = namedtuple('ReachArrays', ['pending', 'active', 't0', 'sigma0', 'records', 'count'])
RecordArrays = namedtuple(
    'RecordArrays', ['state', 'torque', 'goal', 'avoiding', 'saturated', 'ob_center', 'ob_phi']
)


@njit(cache=True)
def reference_at(step, sub, dt, tab, ref, rows):
    """Quintic Hermite interpolation (:func:`quintic_hermite_k`) of the tabulated leader references
    for step ``step`` of the chunk -> ``ref`` (N, 6) rows ``rows`` (the leaders; other rows are
    left untouched).
    """
    g = step // sub
    h = sub * dt
    s = (step - g * sub) / sub
    for i in rows:
        for q in range(2):
            r, rd, rdd = quintic_hermite_k(
                s,
                h,
                tab[i, g, q],
                tab[i, g, 2 + q],
                tab[i, g, 4 + q],
                tab[i, g + 1, q],
                tab[i, g + 1, 2 + q],
                tab[i, g + 1, 4 + q],
            )
            ref[i, q] = r
            ref[i, 2 + q] = rd
            ref[i, 4 + q] = rdd


# ------------------------------------------------------------------------------ the 1 kHz loop


@njit(cache=True)
def _disturbance_start(t0, d_amp, d_freq, d_phase):
    """The disturbance phasors (sin, cos) of every robot and g (N, 2) at ``t0`` [s]: restarted at
    every segment, so no drift accumulates.
    """
    d_sin = np.empty_like(d_amp)
    d_cos = np.empty_like(d_amp)
    g_prev = np.empty((d_amp.shape[0], 2))
    for i in range(d_amp.shape[0]):
        disturbance_phasor_init_k(t0, d_freq[i], d_phase[i], d_sin[i], d_cos[i])
        g_prev[i, 0], g_prev[i, 1] = disturbance_k(t0, d_amp[i], d_freq[i], d_phase[i])
    return d_sin, d_cos, g_prev


@njit(cache=True)
def _obstacle_buffers(axes, static):
    """An :data:`ObstacleSnapshot` to fill with :func:`obstacle_states` (semi-axes and static
    flags are fixed).
    """
    m = axes.shape[0]
    return ObstacleSnapshot(
        np.empty((m, 2)),
        np.empty((m, 2)),
        np.empty((m, 2)),
        np.empty(m),
        np.empty(m),
        np.empty(m),
        axes,
        static,
    )


@njit(cache=True)
def _reach_record(reach, i, t, done):
    """Append the reaching phase of robot i that ends at t [s] (S3.4) to ``reach``
    (:class:`ReachArrays`; rows [robot, t0_s, sigma0_inf_mps, duration_s, completed]) while there
    is room.
    """
    r = reach.count[0]
    if r < reach.records.shape[0]:
        rows = reach.records
        rows[r, 0] = i
        rows[r, 1] = reach.t0[i]
        rows[r, 2] = reach.sigma0[i]
        rows[r, 3] = t - reach.t0[i]
        rows[r, 4] = done
        reach.count[0] = r + 1


@njit(cache=True)
def _record(rk, x, torque, goal, mode, sat_flag, obstacles, rec):
    """Sample ``rk`` of the record ``rec`` (:class:`RecordArrays`; nothing past its end): every
    robot's state, torque, goal, avoiding and saturated flags, every obstacle's centre and
    orientation.
    """
    if rk >= rec.state.shape[0]:
        return
    for i in range(x.shape[0]):
        for q in range(5):
            rec.state[rk, i, q] = x[i, q]
        rec.torque[rk, i, 0] = torque[i, 0]
        rec.torque[rk, i, 1] = torque[i, 1]
        rec.goal[rk, i, 0] = goal[i, 0]
        rec.goal[rk, i, 1] = goal[i, 1]
        rec.avoiding[rk, i] = mode[i] != MODE_C
        rec.saturated[rk, i] = sat_flag[i]
    oc, ophi = obstacles.c, obstacles.phi
    for j in range(oc.shape[0]):
        rec.ob_center[rk, j, 0] = oc[j, 0]
        rec.ob_center[rk, j, 1] = oc[j, 1]
        rec.ob_phi[rk, j] = ophi[j]


@njit(cache=True)
def _run_segment(
    k0,
    k_end,
    skip_decide,
    clock,
    reference,
    robots,
    graph,
    plant,
    obstacles,
    automaton,
    prm,
    ev,
    reach,
    rec,
):
    """Steps k0 .. k_end-1 of the closed loop. Returns (next step, number of new events).

    The arrays come grouped in named tuples (:class:`Clock`, :class:`Reference`,
    :class:`RobotArrays`, :class:`GraphArrays`, :class:`PlantArrays`, :class:`ObstacleArrays`,
    :meth:`AutomatonState.arrays` order, :class:`ReachArrays`, :class:`RecordArrays`); the
    loop's arrays are updated in place.
    """
    dt, dec_every, rec_every = clock
    ref_k0, ref_sub, ref_tab, leader_rows = reference
    x, acmd, torque, sat_flag, pd, goal, goal_dot, vc, ref = robots
    parent, offset, order, orig_parent, orig_offset, team, slot = graph
    rbody, coeffs, gains, d_amp, d_freq, d_phase, d_hc, d_hs = plant
    ob_c0, ob_v, ob_amp, ob_w, ob_phi0, ob_phid, oaxes, ostatic = obstacles
    mode, wc = automaton.mode, automaton.wc
    reach_pending, reach_active, reach_t0, reach_sig0, _, _ = reach
    n = x.shape[0]
    eps = gains.boundary_layer_mps
    d_sin, d_cos, g_prev = _disturbance_start(k0 * dt, d_amp, d_freq, d_phase)
    pos = np.empty((n, 2))  # contiguous positions for decide (one compiled specialisation)
    obs_now = _obstacle_buffers(oaxes, ostatic)
    oc, ov, oa, ophi, ophid, ophidd, _, _ = obs_now
    tracking = Tracking(parent, offset, ref, goal, goal_dot)
    decision_robots = DecisionRobots(pos, pd, goal, goal_dot, vc, team, rbody, parent, slot)
    for kk in range(k0, k_end):
        t = kk * dt
        obstacle_states(
            t, ob_c0, ob_v, ob_amp, ob_w, ob_phi0, ob_phid, oc, ov, oa, ophi, ophid, ophidd
        )
        reference_at(kk - ref_k0, ref_sub, dt, ref_tab, ref, leader_rows)
        for i in range(n):
            pvx, pvy = point_velocity_k(x[i, 2], x[i, 3], x[i, 4], coeffs[ROW_D, i])
            pd[i, 0] = pvx
            pd[i, 1] = pvy
        decision = kk % dec_every == 0 and not (skip_decide and kk == k0)
        goals_and_fields(x, pd, ref, orig_parent, orig_offset, gains, goal, goal_dot, vc, decision)
        if decision:
            for i in range(n):
                pos[i, 0] = x[i, 0]
                pos[i, 1] = x[i, 1]
            nev = decide(t, decision_robots, obs_now, automaton, prm, ev)
            if nev > 0:
                return kk, nev
        # ---- law, parents before children (S4 feed-forward of the current a_j)
        for q in range(n):
            i = order[q]
            track, state = tracking_row_k(tracking, i), robot_mode_k(automaton, i)
            t1, t2, sx, sy, sat, acx, acy, wdx, wdy = robot_law_k(
                i, t, x, pd, acmd, rbody, coeffs, obs_now, track, state, gains, prm
            )
            torque[i, 0] = t1
            torque[i, 1] = t2
            sat_flag[i] = sat
            acmd[i, 0] = acx
            acmd[i, 1] = acy
            if mode[i] == MODE_MUTUAL:
                wc[i, 0] += dt * wdx
                wc[i, 1] += dt * wdy
            # ---- reaching phases (S3.4, S8.5)
            sig = max(abs(sx), abs(sy))
            if reach_pending[i]:
                if reach_active[i]:
                    _reach_record(reach, i, t, 0.0)  # interrupted by the next switch
                reach_pending[i] = False
                reach_active[i] = True
                reach_t0[i] = t
                reach_sig0[i] = sig
            if reach_active[i] and sig <= eps:
                _reach_record(reach, i, t, 1.0)
                reach_active[i] = False
        if kk % rec_every == 0:
            _record(kk // rec_every, x, torque, goal, mode, sat_flag, obs_now, rec)
        # ---- plant: RK4 with ZOH torque and g at t, t + dt/2, t + dt (S2.2)
        for i in range(n):
            # g at t (kept from the previous step), t + dt/2 and t + dt by phasor rotation
            g0a = g_prev[i, 0]
            g0b = g_prev[i, 1]
            gha, ghb = disturbance_phasor_advance_k(d_amp[i], d_sin[i], d_cos[i], d_hc[i], d_hs[i])
            g1a, g1b = disturbance_phasor_advance_k(d_amp[i], d_sin[i], d_cos[i], d_hc[i], d_hs[i])
            g_prev[i, 0] = g1a
            g_prev[i, 1] = g1b
            nx = rk4_step_k(
                (x[i, 0], x[i, 1], x[i, 2], x[i, 3], x[i, 4]),
                (torque[i, 0], torque[i, 1]),
                (g0a, g0b),
                (gha, ghb),
                (g1a, g1b),
                dt,
                robot_plant_k(coeffs, i),
            )
            for q in range(5):
                x[i, q] = nx[q]
    return k_end, 0


# ------------------------------------------------------------------------------ Python driver


class _Setup:
    """Arrays of one scenario for the compiled loop (rows in robot-ID order)."""

    def __init__(self, scenario, dt_s: float, switching: SwitchingParams):
        from ament_formation.core.control.rewiring import FormationGraph

        robots = sorted(scenario.robots, key=lambda r: r.id)
        self.ids = tuple(int(r.id) for r in robots)
        self.index = {rid: i for i, rid in enumerate(self.ids)}
        n = len(robots)
        self.n = n
        self.robots = robots
        k = PlantCoeffs.from_params([r.params for r in robots])
        self.coeffs = np.ascontiguousarray(
            np.stack([k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c, k.tau_max])
        )
        self.rbody = np.array([r.params.body_radius_m for r in robots], dtype=float)
        self.gains = gains_vector(scenario.control)
        self.prm = switching.for_avoidance(scenario.avoidance).on_floor(scenario.floor).compiled()
        bound = np.asarray(scenario.disturbance.accel_bound, dtype=float)
        dist = Disturbance.from_bounds(n, bound, scenario.disturbance.seed)
        self.d_amp, self.d_freq, self.d_phase = dist.amplitude, dist.freq_hz, dist.phase_rad
        self.d_hc, self.d_hs = dist.step_rotation(0.5 * dt_s)  # half-step phasor rotation
        self.obstacle_names = tuple(o.name for o in scenario.obstacles)
        law_obstacles = scenario.avoided_obstacles()  # §18 (the record keeps the scenario's)
        self.merged = law_obstacles != scenario.obstacles
        self.law_names = tuple(o.name for o in law_obstacles)
        (
            self.ob_c0,
            self.ob_v,
            self.ob_amp,
            self.ob_w,
            self.ob_phi0,
            self.ob_phid,
            self.oaxes,
            self.ostatic,
        ) = obstacle_arrays(law_obstacles)
        slots = {r.id: np.asarray(r.slot_m, dtype=float) for r in robots}
        self.slots = np.array([slots[rid] for rid in self.ids], dtype=float).reshape(n, 2)
        self.graph = FormationGraph.from_scenario(scenario)
        self.orig_parent = np.full(n, -1, dtype=np.int64)
        for rid in self.ids:
            par = self.graph.original_parent.get(rid)
            if par is not None:
                self.orig_parent[self.index[rid]] = self.index[par]
        self.orig_offset = np.zeros((n, 2))
        for i in range(n):
            if self.orig_parent[i] >= 0:
                self.orig_offset[i] = self.slots[i] - self.slots[self.orig_parent[i]]
        team_of = {rid: scenario.team_leader(rid) for rid in self.ids}
        self.team = np.array([self.index[team_of[rid]] for rid in self.ids], dtype=np.int64)
        self.paths = [r.path if r.leader else None for r in robots]
        self.leader_rows = np.array([i for i, r in enumerate(robots) if r.leader], dtype=np.int64)
        self.state = np.zeros((n, 5))
        for i, r in enumerate(robots):
            self.state[i, :3] = r.initial_pose

    def graph_arrays(self, parent, offset, order) -> GraphArrays:
        """The formation graph now (current ``parent``, ``offset``, ``order``) with the fixed
        original links, teams and slots.
        """
        return GraphArrays(
            parent, offset, order, self.orig_parent, self.orig_offset, self.team, self.slots
        )

    def plant_arrays(self) -> PlantArrays:
        """Bodies, plant coefficients, gains and disturbance terms (fixed for the run)."""
        return PlantArrays(
            self.rbody,
            self.coeffs,
            self.gains,
            self.d_amp,
            self.d_freq,
            self.d_phase,
            self.d_hc,
            self.d_hs,
        )

    def obstacle_arrays(self) -> ObstacleArrays:
        """The obstacles' motion parameters, semi-axes and static flags."""
        return ObstacleArrays(
            self.ob_c0,
            self.ob_v,
            self.ob_amp,
            self.ob_w,
            self.ob_phi0,
            self.ob_phid,
            self.oaxes,
            self.ostatic,
        )

    def parents_from(self, parents: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(parent rows, offsets, topological order) of a parents dict
        {child_id: parent_id | None}.
        """
        n = self.n
        parent = np.full(n, -1, dtype=np.int64)
        for child, par in parents.items():
            if par is not None:
                parent[self.index[child]] = self.index[par]
        offset = np.zeros((n, 2))
        for i in range(n):
            if parent[i] >= 0:
                offset[i] = self.slots[i] - self.slots[parent[i]]
        children = [[] for _ in range(n)]
        for i in range(n):
            if parent[i] >= 0:
                children[parent[i]].append(i)
        order = [i for i in range(n) if parent[i] < 0]
        q = 0
        while q < len(order):
            order.extend(children[order[q]])
            q += 1
        if len(order) != n:  # a cycle cannot come out of S9; keep every robot anyway
            order += [i for i in range(n) if i not in set(order)]
        return parent, offset, np.array(order, dtype=np.int64)

    def reference_table(self, k0: int, k1: int, dt_s: float) -> np.ndarray:
        """(N, G, 6) leader references [r, r_dot, r_ddot] on the grid t = (k0 + REF_SUB g) dt_s
        covering steps k0 .. k1-1 (zeros for followers); :func:`reference_at` interpolates.
        """
        n_grid = (k1 - k0 - 1) // REF_SUB + 2
        tab = np.zeros((self.n, n_grid, 6))
        t = (k0 + REF_SUB * np.arange(n_grid)) * dt_s
        for i, path in enumerate(self.paths):
            if path is not None:
                r, rd, rdd = path.reference(t)
                tab[i, :, 0:2] = r
                tab[i, :, 2:4] = rd
                tab[i, :, 4:6] = rdd
        return tab


def _loop_arrays(setup: _Setup, n_rec: int):
    """The closed loop's arrays as a run starts: (RobotArrays, the automaton arrays in
    AutomatonState order, ReachArrays, RecordArrays of ``n_rec`` samples).
    """
    n, m = setup.n, len(setup.law_names)
    z2 = lambda: np.zeros((n, 2))  # noqa: E731 - a fresh (n, 2) array each call
    robots = RobotArrays(
        setup.state.copy(),
        z2(),
        z2(),
        np.zeros(n, dtype=np.bool_),
        z2(),
        z2(),
        z2(),
        z2(),
        np.zeros((n, 6)),
    )
    automaton = AutomatonArrays(
        np.zeros(n, dtype=np.int64),  # mode
        np.full(n, -1, dtype=np.int64),  # tgt
        np.ones(n),  # sdir
        np.zeros(n),  # t_entry
        np.full(n, -1.0),  # since
        np.zeros(n, dtype=np.int64),  # last_kind
        np.full(n, -1, dtype=np.int64),  # last_tgt
        np.full(n, -1e9),  # last_exit
        z2(),  # wc
        z2(),  # wtgt
        np.zeros(n),  # sweep_s
    )
    reach = ReachArrays(
        np.ones(n, dtype=np.bool_),
        np.zeros(n, dtype=np.bool_),
        np.zeros(n),
        np.zeros(n),
        np.zeros((max(64, 16 * n), 5)),
        np.zeros(1, dtype=np.int64),
    )
    rec = RecordArrays(
        np.zeros((n_rec, n, 5)),
        np.zeros((n_rec, n, 2)),
        np.zeros((n_rec, n, 2)),
        np.zeros((n_rec, n), dtype=np.bool_),
        np.zeros((n_rec, n), dtype=np.bool_),
        np.zeros((n_rec, m, 2)),
        np.zeros((n_rec, m)),
    )
    return robots, automaton, reach, rec


def _target_name(setup: _Setup, mode: int, target: int) -> str:
    if mode == MODE_OBSTACLE:
        return setup.law_names[target]
    return f'robot_{setup.ids[target]}'


def simulate(
    scenario,
    *,
    dt_s: float = 0.001,
    record_every_s: float = 0.01,
    progress: Callable[[float, float], None] | None = None,
    switching: SwitchingParams | None = None,
    chunk_s: float = 5.0,
) -> SimResult:
    """Run the closed loop of ``scenario`` for its ``duration_s`` and return the record.

    Parameters
    ----------
    scenario : :class:`ament_formation.core.scenario.loader.Scenario`.
    dt_s : integration and control period [s] (RK4, ZOH torques; the S3.2 law runs every step).
    record_every_s : sampling period of the record [s] (rounded to a multiple of ``dt_s``).
    progress : callable(t_s, duration_s) called after each chunk, or None.
    switching : automaton/encounter parameters (decision period etc.); defaults from the
        scenario's ``avoidance`` block and :class:`SwitchingParams` defaults.
    chunk_s : the leaders' references are tabulated per chunk of this length [s].
    """
    wall0 = time.perf_counter()
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise ValueError(f'dt_s: must be a finite number > 0 (got {dt_s!r})')
    switching = switching or SwitchingParams(avoidance=scenario.avoidance)
    setup = _Setup(scenario, dt_s, switching)
    n = setup.n
    n_steps = int(round(scenario.duration_s / dt_s))
    rec_every = max(1, int(round(record_every_s / dt_s)))
    dec_every = max(1, int(round(switching.decision_period_s / dt_s)))
    n_rec = (n_steps - 1) // rec_every + 1
    chunk = max(1, int(round(chunk_s / dt_s)))

    ev = np.zeros((8 * n + 16, 6))
    clock = Clock(dt_s, dec_every, rec_every)
    robots, automaton, reach, rec = _loop_arrays(setup, n_rec)
    plant, obstacles = setup.plant_arrays(), setup.obstacle_arrays()
    mode = automaton.mode
    reach_pending, reach_rec, nreach = reach.pending, reach.records, reach.count
    avoiding: frozenset[int] = frozenset()
    parents = setup.graph.rewire(set())
    parent, offset, order = setup.parents_from(parents)
    mode_events: list[dict] = []
    graph_events: list[dict] = [{'t_s': 0.0, 'parents': _parents_json(parents)}]
    reaching: list[dict] = []
    k = 0
    skip = False
    while k < n_steps:
        k_chunk_end = min(n_steps, (k // chunk + 1) * chunk)
        ref_k0 = k
        ref_tab = setup.reference_table(k, k_chunk_end, dt_s)
        while k < k_chunk_end:
            k, nev = _run_segment(
                k,
                k_chunk_end,
                skip,
                clock,
                Reference(ref_k0, REF_SUB, ref_tab, setup.leader_rows),
                robots,
                setup.graph_arrays(parent, offset, order),
                plant,
                obstacles,
                automaton,
                setup.prm,
                ev,
                reach,
                rec,
            )
            if nreach[0] > reach_rec.shape[0] // 2:
                _drain_reaching(setup, reach, reaching)
            skip = False
            if nev == 0:
                continue
            if nev > ev.shape[0]:
                raise RuntimeError('mode event buffer overflow')  # cannot happen: <= 8 per robot
            skip = True
            changed = _mode_events(setup, ev[:nev], mode_events)
            for i in changed:
                reach_pending[i] = True
            now_avoiding = frozenset(setup.ids[i] for i in range(n) if mode[i] != MODE_C)
            if now_avoiding != avoiding:
                avoiding = now_avoiding
                new_parents = setup.graph.rewire(set(avoiding))
                new_parent, offset, order = setup.parents_from(new_parents)
                for i in np.nonzero(new_parent != parent)[0]:
                    reach_pending[i] = True
                parent = new_parent
                if new_parents != parents:
                    parents = new_parents
                    graph_events.append(
                        {'t_s': round(k * dt_s, 9), 'parents': _parents_json(parents)}
                    )
        if progress is not None:
            progress(k * dt_s, scenario.duration_s)
    _drain_reaching(setup, reach, reaching)
    t_rec = np.arange(n_rec) * rec_every * dt_s
    if setup.merged:
        rec = _record_scenario_obstacles(scenario, t_rec, rec)
    return SimResult(
        scenario_name=scenario.name,
        robot_ids=setup.ids,
        obstacle_names=setup.obstacle_names,
        t_s=t_rec,
        state=rec.state,
        torque_nm=rec.torque,
        goal_m=rec.goal,
        avoiding=rec.avoiding,
        saturated=rec.saturated,
        obstacle_center_m=rec.ob_center,
        obstacle_phi_rad=rec.ob_phi,
        mode_events=mode_events,
        graph_events=graph_events,
        reaching=reaching,
        dt_s=dt_s,
        wall_time_s=time.perf_counter() - wall0,
    )


def _drain_reaching(setup: _Setup, reach: ReachArrays, reaching: list[dict]) -> None:
    """Move the reaching-phase records the loop wrote (S3.4) to ``reaching`` as dicts."""
    lam = setup.gains.reaching_rate_mps2
    for r in range(int(reach.count[0])):
        i, t0, s0, tr, done = reach.records[r]
        reaching.append(
            {
                'robot': setup.ids[int(i)],
                't_s': float(t0),
                'sigma0_inf_mps': float(s0),
                't_reach_s': float(tr),
                'bound_s': float(s0) / lam,
                'completed': bool(done),
            }
        )
    reach.count[0] = 0


def _record_scenario_obstacles(scenario, t_rec: np.ndarray, rec: RecordArrays) -> RecordArrays:
    """``rec`` with the scenario's obstacles at the record times ``t_rec`` (the loop recorded
    the ones the law avoids, where some are merged: docs/law-changes.md §18).
    """
    field = ObstacleField(scenario.obstacles)
    states = [field.at(float(t)) for t in t_rec]
    return rec._replace(
        ob_center=np.stack([st.center_m for st in states]),
        ob_phi=np.stack([st.phi_rad for st in states]),
    )


def _mode_events(setup: _Setup, rows: np.ndarray, mode_events: list[dict]) -> set[int]:
    """Append the event rows the loop wrote (t, robot row, enter, mode, target, direction) to
    ``mode_events`` as dicts; the set of robot rows that switched.
    """
    changed = set()
    for row in rows:
        t_ev, i, enter, md, target, s = row
        i = int(i)
        changed.add(i)
        mode_events.append(
            {
                't_s': round(float(t_ev), 9),
                'robot': setup.ids[i],
                'event': 'enter' if enter > 0.5 else 'exit',
                'mode': MODE_NAMES[int(md)],
                'target': _target_name(setup, int(md), int(target)),
                'direction': 'ccw' if s > 0 else 'cw',
            }
        )
    return changed


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}
