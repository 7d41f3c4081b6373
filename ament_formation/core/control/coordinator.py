"""The coordinator without ROS (nodes/coordinator.py and the camera-sensing simulator drive it):
the graph (S9 rewiring when the set of avoiding robots changes), the robot-robot encounters of
every robot (the one authority for them, S7.1), the teams' right of way (S7.5) and the progress
rate of every team's reference (S17).

It reads what the robots send: their states (the estimate each broadcasts) and their mode
reports (a robot's own obstacle modes are taken as given). :meth:`Coordinator.decide` runs the
compiled decision (:func:`~ament_formation.core.control.arbitration.coordinate`, the one the
ideal simulator runs) and returns what to publish; :class:`Publisher` says when.
"""

from __future__ import annotations

import math

import numpy as np

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
from ament_formation.core.model.dynamics import PlantCoeffs, point_velocities
from ament_formation.core.model.obstacles import ObstacleField, ObstacleSnapshot

SILENT_S = 1.0  # a robot whose state is older takes no part in the decisions [s]


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
        self.d = PlantCoeffs.from_params([r.params for r in robots]).d
        obstacles = scenario.avoided_obstacles()
        self.obstacle_names = tuple(o.name for o in obstacles)
        self.field = ObstacleField(obstacles)
        self._obs = self.field.buffers()
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
        self._t_dec: float | None = None
        self.mission_end_s: float | None = None

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
            self.reported[int(rid)] = mode

    def reported_avoiding(self) -> dict | None:
        """The new S9 parents when the set of robots the reports show avoiding changed, else
        None (restoration is rewiring with fewer avoiders, S9 step 6).
        """
        avoiding = frozenset(r for r, m in self.reported.items() if m.get('avoiding'))
        if avoiding == self.avoiding:
            return None
        self.avoiding = avoiding
        self.parents = self.graph.rewire(sorted(avoiding))
        return self.parents

    # ------------------------------------------------------------------ decision
    def _sync_obstacles(self, t_s: float) -> None:
        """The robots' own obstacle modes into the decision's state (S7.1: theirs to decide)."""
        m = self.modes
        for rid, mode in self.reported.items():
            q = self.row[rid]
            on = mode.get('mode') == 'obstacle' and mode.get('target') in self.obstacle_names
            if on:
                j = self.obstacle_names.index(mode['target'])
                sdir = -1.0 if mode.get('direction') == 'cw' else 1.0
                if m.mode[q] != MODE_OBSTACLE or m.tgt[q] != j:
                    m.mode[q], m.tgt[q], m.sdir[q], m.t_entry[q] = MODE_OBSTACLE, j, sdir, t_s
                    m.since[q] = -1.0
                    m.anchor[q] = np.nan
            elif m.mode[q] == MODE_OBSTACLE:  # it left its obstacle
                m.last_kind[q], m.last_tgt[q], m.last_exit[q] = KIND_OBSTACLE, m.tgt[q], t_s
                m.mode[q], m.tgt[q], m.since[q] = MODE_C, -1, -1.0
                m.anchor[q] = np.nan

    def _parent_rows(self) -> np.ndarray:
        out = np.full(len(self.ids), -1, dtype=np.int64)
        for child, par in self.parents.items():
            if par is not None:
                out[self.row[child]] = self.row[par]
        return out

    def decide(self, t_s: float) -> tuple[dict, dict]:
        """One decision at scenario time ``t_s``: (assignments {robot id: {mode, partner,
        direction, t_entry_s, drift_mps}}, rates {leader id: progress rate target}).
        """
        t_s = float(t_s)
        dt = 0.0 if self._t_dec is None else max(0.0, t_s - self._t_dec)
        self._t_dec = t_s
        self._sync_obstacles(t_s)
        known = self.stamp >= t_s - SILENT_S
        x = np.ascontiguousarray(self.x)
        pd = point_velocities(x, self.d)
        for i in self.leaders:
            leader_reference(self.refs, i, self.progress.s[i], self.progress.sd[i],
                             self.progress.sdd[i], self.ref[i])
        n = len(self.ids)
        goal, goal_dot, vc = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2))
        goals_and_fields(x, pd, self.ref, self.orig_parent, self.orig_offset, self.prm, goal,
                         goal_dot, vc)
        robots = Robots(np.ascontiguousarray(x[:, :2]), pd, goal, goal_dot, vc, self.team,
                        self.rbody, self._parent_rows(), self.slot, known, self.orig_parent)
        oc, ov, oa, ophi, ophid, ophidd = self.field.fill(t_s, self._obs)
        ob = ObstacleSnapshot(oc, ov, oa, ophi, ophid, ophidd, self.field.axes, self.field.static)
        m = self.modes
        if dt > 0.0:  # a pair's drift w_c relaxes toward its target (S14.1), as on board
            a = min(1.0, dt / self.prm.mutual_drift_tau_s)
            pair = (m.mode == MODE_MUTUAL)[:, None]
            m.wc[...] = np.where(pair, m.wc + a * (m.wtgt - m.wc), m.wc)
        nev, done = coordinate(t_s, dt, robots, ob, m, self.teams, self.progress, self.refs,
                               self.leaders, self.e_team, self.prm, self.ev, 0)
        if done and self.mission_end_s is None:
            self.mission_end_s = t_s
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
