"""The coordinator without ROS (nodes/coordinator.py and the camera-sensing simulator drive it):
the graph (S9 rewiring when the set of avoiding robots changes), the robot-robot encounters of
every robot (the one authority for them, S7.1), the teams' right of way (S7.5) and the progress
rate of every team's reference (S17).

It reads what the robots send: their states (the estimate each broadcasts) and their mode
reports (a robot's own obstacle modes are taken as given). :meth:`Coordinator.decide` runs the
compiled decision (:func:`decide_k`: the robots' obstacle modes taken over, their goals, then
:func:`~ament_formation.core.control.arbitration.coordinate`, the one the ideal simulator runs)
and returns what to publish; :class:`Publisher` says when. The camera-sensing simulator calls
:func:`decide_k` on :attr:`Coordinator.k` from its compiled loop (core/sim/sensed_loop.py).
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.control.agent import (
    ASSIGN_MUTUAL,
    ASSIGN_NONE,
    ASSIGN_NONE_PARK,
    ASSIGN_YIELD,
)
from ament_formation.core.control.arbitration import coordinate, new_teams
from ament_formation.core.control.law import goals_and_fields
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.progress import leader_reference, new_progress, tabulate
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.control.switching import (
    KIND_OBSTACLE,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    new_modes,
    Robots,
)
from ament_formation.core.model.dynamics import PlantCoeffs, point_velocity_k
from ament_formation.core.model.obstacles import (
    obstacle_arrays,
    obstacle_states,
    ObstacleField,
    ObstacleSnapshot,
)

SILENT_S = 1.0  # a robot whose state is older takes no part in the decisions [s]

CoordK = namedtuple('CoordK', ['x', 'stamp', 'rep_has', 'rep_ob', 'rep_sdir', 'parent', 'd',
                               'rbody', 'team', 'slot', 'orig_parent', 'orig_offset', 'leaders',
                               'refs', 'progress', 'ref', 'obstacles', 'ob', 'modes', 'teams',
                               'e_team', 'ev', 't_dec', 'end_s', 'prm'])
CoordK.__doc__ = """The coordinator's arrays as :func:`decide_k` reads and updates them (rows in
robot-id order): what the robots sent (``x`` (N, 5) states, ``stamp`` (N,) [s]; their mode
reports: ``rep_has`` (N,) bool, ``rep_ob`` (N,) the obstacle index of a robot on an obstacle,
-1 otherwise, ``rep_sdir`` (N,) its sense); ``parent`` (N,) the current S9 parent rows; the
scenario's (``d``, ``rbody``, ``team``, ``slot``, ``orig_parent``, ``orig_offset``,
``leaders``, ``refs``, ``obstacles`` the avoided obstacles' motion (obstacle_arrays) and ``ob``
their snapshot's buffers (6)); the decision's state (``progress``, ``ref`` (N, 6), ``modes``,
``teams``, ``e_team``, ``ev`` events); ``t_dec`` (1,) the last decision [s] (NaN: none yet),
``end_s`` (1,) when the mission ended (NaN: not yet); ``prm`` LawK."""


@njit(cache=True, error_model='numpy')
def sync_obstacles_k(t, ck):
    """The robots' own obstacle modes (their reports) into the decision's state (S7.1: theirs
    to decide): a robot newly on an obstacle enters it, one that left it exits.
    """
    m = ck.modes
    for q in range(m.mode.shape[0]):
        if not ck.rep_has[q]:
            continue
        j = ck.rep_ob[q]
        if j >= 0:
            if m.mode[q] != MODE_OBSTACLE or m.tgt[q] != j:
                m.mode[q], m.tgt[q], m.sdir[q], m.t_entry[q] = MODE_OBSTACLE, j, ck.rep_sdir[q], t
                m.since[q] = -1.0
                m.anchor[q, 0] = m.anchor[q, 1] = np.nan
        elif m.mode[q] == MODE_OBSTACLE:  # it left its obstacle
            m.last_kind[q], m.last_tgt[q], m.last_exit[q] = KIND_OBSTACLE, m.tgt[q], t
            m.mode[q], m.tgt[q], m.since[q] = MODE_C, -1, -1.0
            m.anchor[q, 0] = m.anchor[q, 1] = np.nan


@njit(cache=True, error_model='numpy')
def decide_k(t, ck):
    """One decision of the coordinator at scenario time ``t`` on :data:`CoordK` ``ck``: the
    robots' obstacle modes, the goals of the states heard within :data:`SILENT_S` (each moved on
    by its age at its point velocity), the pairs'
    drift relaxation since the last decision, then :func:`coordinate`. Returns the event count
    (rows of ``ck.ev``).
    """
    d = t - ck.t_dec[0]
    dt = d if d > 0.0 else 0.0  # max(0, t - t_dec); 0 at the first decision (NaN)
    ck.t_dec[0] = t
    sync_obstacles_k(t, ck)
    n = ck.x.shape[0]
    x = ck.x.copy()
    known = np.empty(n, dtype=np.bool_)
    pd = np.empty((n, 2))
    for i in range(n):
        known[i] = ck.stamp[i] >= t - SILENT_S
        pd[i, 0], pd[i, 1] = point_velocity_k(x[i, 2], x[i, 3], x[i, 4], ck.d[i])
        age = t - ck.stamp[i]
        if known[i] and age > 0.0:  # states come at state_rate_hz: each moved on by its age
            x[i, 0] += pd[i, 0] * age
            x[i, 1] += pd[i, 1] * age
    pr = ck.progress
    for i in ck.leaders:
        leader_reference(ck.refs, i, pr.s[i], pr.sd[i], pr.sdd[i], ck.ref[i])
    goal, goal_dot, vc = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2))
    prm = ck.prm
    goals_and_fields(x, pd, ck.ref, ck.orig_parent, ck.orig_offset, prm, goal, goal_dot, vc)
    robots = Robots(x[:, :2].copy(), pd, goal, goal_dot, vc, ck.team, ck.rbody, ck.parent,
                    ck.slot, known, ck.orig_parent)
    o, b = ck.obstacles, ck.ob
    obstacle_states(t, o[0], o[1], o[2], o[3], o[4], o[5], b[0], b[1], b[2], b[3], b[4], b[5])
    ob = ObstacleSnapshot(b[0], b[1], b[2], b[3], b[4], b[5], o[6], o[7])
    m = ck.modes
    if dt > 0.0:  # a pair's drift w_c relaxes toward its target (S14.1), as on board
        a = dt / prm.mutual_drift_tau_s
        a = a if a < 1.0 else 1.0
        for q in range(n):
            if m.mode[q] == MODE_MUTUAL:
                for c in range(2):
                    m.wc[q, c] = m.wc[q, c] + a * (m.wtgt[q, c] - m.wc[q, c])
    nev, done = coordinate(t, dt, robots, ob, m, ck.teams, pr, ck.refs, ck.leaders, ck.e_team,
                           prm, ck.ev, 0)
    if done and not ck.end_s[0] == ck.end_s[0]:  # NaN: not ended yet
        ck.end_s[0] = t
    return nev


class Coordinator:
    """S7.1/S7.5/S9/S17 of a scenario's robots (module docstring).

    ``report(rid, mode)`` and ``state(rid, x, stamp_s)`` as messages arrive; ``decide(t_s)``
    at its rate (scenario time) -> (assignments {robot id: dict}, rates {leader id: float});
    :attr:`parents` the current S9 parents, changed by :meth:`reported_avoiding`.
    """

    def __init__(self, scenario, law: LawParams | None = None):
        robots = sorted(scenario.robots, key=lambda r: r.id)
        self.ids = tuple(int(r.id) for r in robots)
        self.row = {rid: q for q, rid in enumerate(self.ids)}
        n = len(robots)
        self.law = law or LawParams.for_scenario(scenario)
        self.prm = self.law.compiled()
        self.graph = FormationGraph.from_scenario(scenario)
        self._parent = np.full(n, -1, dtype=np.int64)
        self.parents = self.graph.rewire(())
        self.avoiding: frozenset[int] = frozenset()
        slot = np.array([r.slot_m for r in robots], dtype=float).reshape(n, 2)
        self.slot = slot
        self.orig_parent = np.full(n, -1, dtype=np.int64)
        self.orig_offset = np.zeros((n, 2))
        for q, rid in enumerate(self.ids):
            par = self.graph.original_parent.get(rid)
            if par is not None:
                self.orig_parent[q] = self.row[par]
                self.orig_offset[q] = slot[q] - slot[self.row[par]]
        self.team = np.array([self.row[scenario.team_leader(r)] for r in self.ids], np.int64)
        self.leaders = np.array([q for q, r in enumerate(robots) if r.leader], dtype=np.int64)
        self.rbody = np.array([r.params.body_radius_m for r in robots])
        self.d = np.ascontiguousarray(PlantCoeffs.from_params([r.params for r in robots]).d,
                                      dtype=float)
        obstacles = scenario.avoided_obstacles()
        self.obstacle_names = tuple(o.name for o in obstacles)
        self.field = ObstacleField(obstacles)
        self.refs = tabulate([r.path if r.leader else None for r in robots], scenario.duration_s)
        self.progress = new_progress(n)
        self.modes = new_modes(n)
        self.teams = new_teams(n)
        self.x = np.zeros((n, 5))
        self.stamp = np.full(n, -np.inf)
        self.reported: dict[int, dict] = {}
        self.e_team = np.zeros(n)
        self.ref = np.zeros((n, 6))
        self.ev = np.zeros((16 * n + 16, 6))
        self.events: list[dict] = []  # robot-robot events of the last decision (ids)
        self.k = CoordK(self.x, self.stamp, np.zeros(n, dtype=np.bool_),
                        np.full(n, -1, dtype=np.int64), np.ones(n), self._parent, self.d,
                        self.rbody, self.team, self.slot, self.orig_parent, self.orig_offset,
                        self.leaders, self.refs, self.progress, self.ref,
                        tuple(obstacle_arrays(obstacles)), self.field.buffers(), self.modes,
                        self.teams, self.e_team, self.ev, np.full(1, np.nan),
                        np.full(1, np.nan), self.prm)

    @property
    def parents(self) -> dict:
        """The current S9 parents {child id: parent id | None}."""
        return self._parents

    @parents.setter
    def parents(self, parents: dict) -> None:
        self._parents = parents
        self._parent[:] = -1
        for child, par in parents.items():
            if par is not None:
                self._parent[self.row[child]] = self.row[par]

    @property
    def mission_end_s(self) -> float | None:
        """When every leader's reference reached its end (scenario time [s]; None: not yet)."""
        end = float(self.k.end_s[0])
        return None if math.isnan(end) else end

    # ------------------------------------------------------------------ inputs
    def state(self, rid: int, x, stamp_s: float) -> None:
        """Take robot ``rid``'s broadcast x (5 values) stamped ``stamp_s`` (scenario time)."""
        q = self.row.get(int(rid))
        if q is not None:
            self.x[q] = x
            self.stamp[q] = stamp_s

    def report(self, rid: int, mode: dict) -> None:
        """Take robot ``rid``'s mode report, a dict {mode, target, direction, avoiding}."""
        if int(rid) in self.row and isinstance(mode, dict):
            q = self.row[int(rid)]
            self.reported[int(rid)] = mode
            on = mode.get('mode') == 'obstacle' and mode.get('target') in self.obstacle_names
            self.k.rep_has[q] = True
            self.k.rep_ob[q] = self.obstacle_names.index(mode['target']) if on else -1
            self.k.rep_sdir[q] = -1.0 if mode.get('direction') == 'cw' else 1.0

    def reported_avoiding(self) -> dict | None:
        """The new S9 parents when the set of robots the reports show avoiding changed, else
        None (restoration is rewiring with fewer avoiders, S9 step 6).
        """
        return self.set_avoiding(
            frozenset(r for r, m in self.reported.items() if m.get('avoiding')))

    def set_avoiding(self, avoiding: frozenset) -> dict | None:
        """The new S9 parents when ``avoiding`` (robot ids) is not the set of avoiding robots
        any more, else None.
        """
        if avoiding == self.avoiding:
            return None
        self.avoiding = avoiding
        self.parents = self.graph.rewire(sorted(avoiding))
        return self.parents

    # ------------------------------------------------------------------ decision
    def decide(self, t_s: float) -> tuple[dict, dict]:
        """One decision at scenario time ``t_s`` (:func:`decide_k`): (assignments {robot id:
        {mode, partner, direction, t_entry_s, drift_mps}}, rates {leader id: progress rate
        target}).
        """
        nev = decide_k(float(t_s), self.k)
        self.events = self._events(nev)
        return self.assignments(), self.rates()

    def _events(self, nev: int) -> list[dict]:
        out = []
        for row in self.ev[:min(nev, self.ev.shape[0])]:
            md = int(row[3])
            if md in (MODE_YIELD, MODE_MUTUAL):
                out.append({'t_s': float(row[0]), 'robot': self.ids[int(row[1])],
                            'event': 'enter' if row[2] > 0.5 else 'exit',
                            'mode': 'yield' if md == MODE_YIELD else 'mutual',
                            'target': f'robot_{self.ids[int(row[4])]}'})
        return out

    def assignments(self) -> dict:
        """{robot id: assignment dict} of the robots in a robot encounter now, and of the robots
        on an obstacle asked to make way ({mode: make_way, park_at_s}).
        """
        m, out = self.modes, {}
        for q, rid in enumerate(self.ids):
            if m.mode[q] == MODE_OBSTACLE and math.isfinite(m.park_at[q]) and m.park_at[q] > 0:
                out[rid] = {'mode': 'make_way', 'partner': rid, 'direction': 1.0, 't_entry_s': 0.0,
                            'drift_mps': None, 'park_at_s': float(m.park_at[q])}
            if m.mode[q] in (MODE_YIELD, MODE_MUTUAL):
                out[rid] = {
                    'mode': 'yield' if m.mode[q] == MODE_YIELD else 'mutual',
                    'partner': self.ids[int(m.tgt[q])],
                    'direction': float(m.sdir[q]),
                    't_entry_s': float(m.t_entry[q]),
                    'drift_mps': [float(m.wc[q, 0]), float(m.wc[q, 1])]
                    if m.mode[q] == MODE_MUTUAL else None,
                    'park_at_s': float(m.park_at[q]),
                }
        return out

    def rates(self) -> dict:
        """{leader id: the progress rate target of its reference (S17)}."""
        return {self.ids[i]: float(self.progress.target[i]) for i in self.leaders}


RATE_RESEND = 0.02  # a rate target that moved this much is sent again
DRIFT_RESEND_MPS = 0.005  # a pair's w_c that moved this much is sent again [m/s]


class Publisher:
    """When the coordinator publishes its decision (node and sensed simulator alike): on a new
    decision (a mode, partner, sense or entry time changed), when a pair's w_c or a rate target
    moved (:data:`DRIFT_RESEND_MPS`, :data:`RATE_RESEND`), and every ``republish_s``.
    """

    def __init__(self, republish_s: float = 1.0):
        self.republish_s = float(republish_s)
        self._sent: tuple[dict, dict] | None = None
        self._sent_t = -math.inf

    def due(self, t_s: float, assignments: dict, rates: dict) -> bool:
        """Whether to publish (assignments, rates) at ``t_s``; marks them sent when so."""
        if self._sent is None or t_s - self._sent_t >= self.republish_s - 1e-9 or self._moved(
                assignments, rates):
            self._sent, self._sent_t = (assignments, rates), t_s
            return True
        return False

    def _moved(self, assignments: dict, rates: dict) -> bool:
        sent_a, sent_r = self._sent

        def key(a):
            return {k: (v['mode'], v['partner'], v['direction'], v['t_entry_s'], v['park_at_s'])
                    for k, v in a.items()}

        if key(assignments) != key(sent_a):
            return True
        for k, v in assignments.items():
            w, w0 = v['drift_mps'], sent_a[k]['drift_mps']
            if w is not None and math.hypot(w[0] - w0[0], w[1] - w0[1]) > DRIFT_RESEND_MPS:
                return True
        return any(abs(rates[k] - sent_r.get(k, -1.0)) > RATE_RESEND for k in rates)


PubK = namedtuple('PubK', ['sent_t', 'kind', 'partner', 'val', 'rate', 'republish_s'])
PubK.__doc__ = """:class:`Publisher` on arrays, for the compiled loop of the camera-sensing
simulator (:func:`publish_due_k`): ``sent_t`` (1,) when it last published [s] (-inf: never);
what it published, by robot row, as :func:`~ament_formation.core.control.agent.assign_k` reads
it: ``kind`` (N,), ``partner`` (N,) rows, ``val`` (N, 5) [direction, t_entry_s, park_at_s,
drift (2)], ``rate`` (N,) the leaders' rate targets; ``republish_s``."""


def new_pub(n: int, republish_s: float) -> PubK:
    return PubK(np.full(1, -np.inf), np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int64),
                np.zeros((n, 5)), np.zeros(n), float(republish_s))


@njit(cache=True, error_model='numpy')
def _entry_k(m, q):
    """Robot row q's assignment as :meth:`Coordinator.assignments` has it: (kind, partner row,
    direction, t_entry_s, park_at_s, drift x, drift y).
    """
    md = m.mode[q]
    if md == MODE_OBSTACLE and math.isfinite(m.park_at[q]) and m.park_at[q] > 0:
        return ASSIGN_NONE_PARK, q, 1.0, 0.0, m.park_at[q], 0.0, 0.0
    if md == MODE_YIELD:
        return ASSIGN_YIELD, m.tgt[q], m.sdir[q], m.t_entry[q], m.park_at[q], 0.0, 0.0
    if md == MODE_MUTUAL:
        return (ASSIGN_MUTUAL, m.tgt[q], m.sdir[q], m.t_entry[q], m.park_at[q], m.wc[q, 0],
                m.wc[q, 1])
    return ASSIGN_NONE, -1, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True, error_model='numpy')
def _moved_k(ck, pub):
    """:meth:`Publisher._moved` of the coordinator's decision now against ``pub``'s."""
    m = ck.modes
    for q in range(m.mode.shape[0]):
        k, p, d, te, pk, wx, wy = _entry_k(m, q)
        if k != pub.kind[q]:
            return True
        if k != ASSIGN_NONE and not (p == pub.partner[q] and d == pub.val[q, 0]
                                     and te == pub.val[q, 1] and pk == pub.val[q, 2]):
            return True
    for q in range(m.mode.shape[0]):
        if pub.kind[q] == ASSIGN_MUTUAL and math.hypot(
                m.wc[q, 0] - pub.val[q, 3], m.wc[q, 1] - pub.val[q, 4]) > DRIFT_RESEND_MPS:
            return True
    for i in ck.leaders:
        if abs(ck.progress.target[i] - pub.rate[i]) > RATE_RESEND:
            return True
    return False


@njit(cache=True, error_model='numpy')
def publish_due_k(t, ck, pub):
    """:meth:`Publisher.due` of the coordinator's decision now (:data:`CoordK` ``ck``) at ``t``
    [s]: when due, ``pub`` takes it (what is published) and True comes back.
    """
    if not (t - pub.sent_t[0] >= pub.republish_s - 1e-9 or _moved_k(ck, pub)):
        return False
    m = ck.modes
    for q in range(m.mode.shape[0]):
        k, p, d, te, pk, wx, wy = _entry_k(m, q)
        pub.kind[q], pub.partner[q] = k, p
        v = pub.val[q]
        v[0], v[1], v[2], v[3], v[4] = d, te, pk, wx, wy
    for i in ck.leaders:
        pub.rate[i] = ck.progress.target[i]
    pub.sent_t[0] = t
    return True
