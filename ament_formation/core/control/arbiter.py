"""The coordinator's robot-robot encounter arbitration over all robots together (spec S7, S14.1).

:class:`EncounterArbiter` runs exactly the simulator's decision step
:func:`ament_formation.core.control.encounters.decide` on every robot whose broadcast state it
knows, and
turns the robot-robot modes it decides (yield / mutual) into one
:class:`~ament_formation.core.control.controller.EncounterAssignment` per robot, which
:class:`~ament_formation.core.control.controller.RobotController` accepts as an override.

Obstacle modes stay the robots' own decisions (safety must not wait for the network, DESIGN §6):
before every decision the arbiter copies each robot's reported obstacle mode into its automaton
state, so static obstacles beat robots (S7) and a robot avoiding an obstacle is stand-on. The
arbiter keeps its own yield/mutual state between calls (dwell, joint exits, cool-downs, S8.3-S8.4).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ament_formation.core.control.automaton import (
    AutomatonArrays,
    AutomatonState,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    SwitchingParams,
)
from ament_formation.core.control.controller import EncounterAssignment
from ament_formation.core.control.encounters import decide, DecisionRobots, KIND_OBSTACLE
from ament_formation.core.control.law import gains_vector, goal_fields
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.model.dynamics import PlantCoeffs, point_velocities
from ament_formation.core.model.obstacles import ObstacleField, ObstacleSnapshot


# a robot's mode report shows an encounter the arbiter ended up to this long ago (the release's
# way to the robot, the robot's next period, its report's way back) [s]
REPORT_LAG_S = 0.2


def _robot_id(target: str) -> int:
    """The id of a ``robot_<id>`` target, else -1."""
    head, _, tail = target.partition('_')
    return int(tail) if head == 'robot' and tail.isdigit() else -1


class EncounterArbiter:
    """S7 arbitration of a scenario's robots (see the module docstring).

    ``EncounterArbiter(scenario, switching=None)``; ``decide(t_s, states, modes)`` with ``t_s``
    scenario time [s], ``states`` {robot id: (5,) [x_m, y_m, theta_rad, v_mps, omega_radps]}
    (robots without a state are left out of the decision), ``modes`` {robot id: the JSON dict of
    its
    ``mode`` topic: mode, target, direction}. Returns {robot id: EncounterAssignment} for every
    robot the arbiter has in yield or mutual mode (``t_entry_s`` in scenario time, ``drift_mps``
    the pair's current w_c).
    """

    def __init__(self, scenario, switching: SwitchingParams | None = None):
        robots = sorted(scenario.robots, key=lambda r: r.id)
        self.ids = tuple(int(r.id) for r in robots)
        self.index = {rid: q for q, rid in enumerate(self.ids)}
        n = len(robots)
        base = switching or SwitchingParams()
        self.switching = base.for_avoidance(scenario.avoidance).on_floor(scenario.floor)
        self._prm = self.switching.compiled()
        self._gains = gains_vector(scenario.control)
        self._d = PlantCoeffs.from_params([r.params for r in robots]).d
        self._rbody = np.array([r.params.body_radius_m for r in robots], dtype=float)
        graph = self._graph = FormationGraph.from_scenario(scenario)
        self._orig = {rid: graph.original_parent.get(rid) for rid in self.ids}
        self._orig_off = {
            rid: (graph.offset(rid, p) if p is not None else np.zeros(2))
            for rid, p in self._orig.items()
        }
        self._team = {rid: scenario.team_leader(rid) for rid in self.ids}
        self._slot = np.array([scenario.slot(rid) for rid in self.ids], dtype=float).reshape(n, 2)
        self._paths = {r.id: (r.path if r.leader else None) for r in robots}
        obstacles = scenario.avoided_obstacles()  # §18
        self.obstacle_names = tuple(o.name for o in obstacles)
        self._field = ObstacleField(obstacles)
        self._axes, self._static = self._field.axes, self._field.static
        self._obs = self._field.buffers()  # written by every decision
        self._rewired: dict[tuple, dict] = {}  # S9 parents by avoiding set (the graph is fixed)
        self.state = AutomatonState(n)  # all robots, rows in robot-id order
        self.events: list[dict] = []  # robot-robot events decided here (ids, scenario time)
        self._drift_t: float | None = None

    # ------------------------------------------------------------------ reported obstacle modes
    def _sync_reported(self, t_s: float, modes: Mapping[int, dict]) -> None:
        st = self.state
        for rid, md in modes.items():
            q = self.index.get(int(rid))
            if q is None or not isinstance(md, dict):
                continue
            name = md.get('mode')
            if name == 'obstacle' and md.get('target') in self.obstacle_names:
                j = self.obstacle_names.index(md['target'])
                if st.mode[q] != MODE_OBSTACLE or st.tgt[q] != j:
                    self._drop_partner(q)
                    st.set_mode(
                        q, MODE_OBSTACLE, j, -1.0 if md.get('direction') == 'cw' else 1.0, t_s
                    )
            elif st.mode[q] == MODE_OBSTACLE:  # the robot left its obstacle
                st.last_kind[q] = KIND_OBSTACLE
                st.last_tgt[q] = st.tgt[q]
                st.last_exit[q] = t_s
                st.mode[q] = MODE_C
                st.tgt[q] = -1
                st.since[q] = -1.0

    def _adopt_reported(
        self, t_s: float, modes: Mapping[int, dict], pd: Mapping[int, np.ndarray]
    ) -> None:
        """A robot encounter a robot reports with another robot than the arbiter has it with,
        later than :data:`REPORT_LAG_S` after the arbiter's last change for it, is the robot's own
        (an emergency it decided itself, docs/law-changes.md §23 and §24): it replaces the
        arbiter's, so that the arbiter decides on what the robots do, and a yield loop such a
        robot closes with an assigned yield is broken here for both robots at once (S14.5), not
        by each robot against the other's late report. A reported pair becomes the arbiter's
        pair when the partner is free or yields to the robot (as S7 forms one), else the robot
        yields to it. Yield or pair with the same robot stays the arbiter's decision (a robot
        turns its pair into a yield on its partner's expected move, and its yield into a pair
        on its partner's late report). ``pd``: {robot id: p_dot (2,)} of the robots with a known
        state.
        """
        st = self.state
        for rid, md in modes.items():
            q = self.index.get(int(rid))
            if q is None or not isinstance(md, dict) or rid not in pd:
                continue
            name, target = md.get('mode'), md.get('target')
            if name not in ('yield', 'mutual') or not isinstance(target, str):
                continue
            k = self.index.get(_robot_id(target), -1)
            if k < 0 or k == q or self.ids[k] not in pd or st.mode[q] == MODE_OBSTACLE:
                continue
            if st.mode[q] in (MODE_YIELD, MODE_MUTUAL) and st.tgt[q] == k:
                continue  # yield or pair with that robot: the arbiter's to decide
            changed = st.last_exit[q] if st.mode[q] == MODE_C else st.t_entry[q]
            if t_s - changed < REPORT_LAG_S:
                continue  # the robot has not had the arbiter's last change yet
            sense = -1.0 if md.get('direction') == 'cw' else 1.0
            pair = name == 'mutual' and (
                st.mode[k] == MODE_C or (st.mode[k] == MODE_YIELD and st.tgt[k] == q)
            )
            self._drop_partner(q)
            st.set_mode(q, MODE_MUTUAL if pair else MODE_YIELD, k, sense, t_s)
            if pair:
                st.set_mode(k, MODE_MUTUAL, q, sense, t_s)
                w = 0.5 * (np.asarray(pd[rid]) + np.asarray(pd[self.ids[k]]))
                for a in (q, k):
                    st.wc[a] = w
                    st.wtgt[a] = w

    def _drop_partner(self, q: int) -> None:
        """Q leaves a mutual pair: its partner becomes a plain yielder (S8.3)."""
        st = self.state
        if st.mode[q] == MODE_MUTUAL:
            k = st.tgt[q]
            if st.mode[k] == MODE_MUTUAL and st.tgt[k] == q:
                st.mode[k] = MODE_YIELD
                st.since[k] = -1.0

    # ------------------------------------------------------------------ decision
    def decide(
        self, t_s: float, states: Mapping[int, np.ndarray], modes: Mapping[int, dict]
    ) -> dict[int, EncounterAssignment]:
        """One S7/S8 decision over every robot with a known state; see the class docstring."""
        t_s = float(t_s)
        self._sync_reported(t_s, modes)
        known = [rid for rid in self.ids if rid in states and np.isfinite(states[rid]).all()]
        n = len(known)
        if n == 0:
            return {}
        rows = np.array([self.index[r] for r in known], dtype=np.int64)
        row = {rid: q for q, rid in enumerate(known)}
        x = np.ascontiguousarray(
            np.stack([np.asarray(states[r], dtype=float).reshape(5) for r in known])
        )
        pd = point_velocities(x, np.ascontiguousarray(self._d[rows]))
        self._adopt_reported(t_s, modes, {rid: pd[q] for q, rid in enumerate(known)})
        goal, goal_dot, vc = self._goals(t_s, known, row, x, pd)
        team = np.array(
            [row.get(self._team[r], -1 - self.index[r]) for r in known], dtype=np.int64
        )
        sub = self._sub_state(t_s, known, rows)
        ev = np.zeros((8 * n + 16, 6))
        nev = self._decide(
            t_s,
            x,
            pd,
            goal,
            goal_dot,
            vc,
            team,
            self._rbody[rows],
            self._obstacles_at(t_s),
            sub,
            self._parent_rows(sub, known, row),
            np.ascontiguousarray(self._slot[rows]),
            ev,
        )
        self._record_events(ev, nev, known)
        self._write_back(sub, known, rows, modes)
        return self.assignments()

    def _goals(
        self, t_s: float, known: list[int], row: Mapping[int, int], x: np.ndarray, pd: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(goal, goal_dot, V_c) of the known robots (S8.3): a leader's r(t), a follower's
        original parent + delta when that parent is known, else the robot's own position.
        """
        n = len(known)
        ref = np.zeros((n, 6))
        orig_parent = np.full(n, -1, dtype=np.int64)
        orig_offset = np.zeros((n, 2))
        for q, rid in enumerate(known):
            path = self._paths[rid]
            p0 = self._orig[rid]
            if path is not None:
                r, rd, rdd = path.reference(t_s)
                ref[q] = np.concatenate([np.asarray(r), np.asarray(rd), np.asarray(rdd)])
            elif p0 is not None and p0 in row:
                orig_parent[q] = row[p0]
                orig_offset[q] = self._orig_off[rid]
            else:  # goal unknown: its own position
                ref[q, 0:2] = x[q, 0:2]
                ref[q, 2:4] = pd[q]
        return goal_fields(x, pd, ref, orig_parent, orig_offset, self._gains)

    def _obstacles_at(self, t_s: float) -> tuple:
        """(centres, velocities, accelerations, phi, phi_dot, phi_ddot) of the obstacles at
        ``t_s`` (S6.1 motion model).
        """
        return self._field.fill(t_s, self._obs)

    def _sub_state(self, t_s: float, known: list[int], rows: np.ndarray) -> AutomatonState:
        """The automaton state of the known robots (robot targets as rows of the sub-problem; a
        silent partner sends the robot back to coordination), w_c relaxed toward w_tgt since the
        last decision (S14.1, as the law does).
        """
        full = self.state
        n = len(known)
        sub = AutomatonState(n)
        for name in AutomatonArrays._fields:
            getattr(sub, name)[:] = getattr(full, name)[rows]
        idx_row = {self.index[r]: q for q, r in enumerate(known)}
        for q in np.flatnonzero((sub.mode == MODE_YIELD) | (sub.mode == MODE_MUTUAL)):
            sub.tgt[q] = idx_row.get(int(sub.tgt[q]), -1)
            if sub.tgt[q] < 0:  # partner silent: back to coordination
                sub.mode[q] = MODE_C
        for q in np.flatnonzero(sub.last_kind == 2):
            sub.last_tgt[q] = idx_row.get(int(sub.last_tgt[q]), -1)
        if self._drift_t is not None:  # w_c relaxes toward w_tgt (S14.1), as the law does
            tau = self.switching.mutual_drift_tau_s
            a = min(1.0, max(0.0, t_s - self._drift_t) / tau) if tau > 0 else 1.0
            sub.wc += a * (sub.wtgt - sub.wc) * (sub.mode == MODE_MUTUAL)[:, None]
        self._drift_t = t_s
        return sub

    def _decide(
        self, t_s, x, pd, goal, goal_dot, vc, team, rbody, obstacles, sub, parent_rows, slot, ev
    ) -> int:
        """The compiled S7/S8 decision over the known robots (``sub`` updated in place, events
        into ``ev``); returns the event count.
        """
        oc, ov, oa, ophi, ophid, ophidd = obstacles
        p = np.ascontiguousarray(x[:, :2])
        return decide(
            t_s,
            DecisionRobots(p, pd, goal, goal_dot, vc, team, rbody, parent_rows, slot),
            ObstacleSnapshot(oc, ov, oa, ophi, ophid, ophidd, self._axes, self._static),
            sub.arrays(),
            self._prm,
            ev,
        )

    def _record_events(self, ev: np.ndarray, nev: int, known: list[int]) -> None:
        """The decision's robot-robot events into :attr:`events` (ids, scenario time)."""
        for r_ in ev[: min(nev, ev.shape[0])]:
            md = int(r_[3])
            if md in (MODE_YIELD, MODE_MUTUAL):
                self.events.append(
                    {
                        't_s': float(r_[0]),
                        'robot': known[int(r_[1])],
                        'event': 'enter' if r_[2] > 0.5 else 'exit',
                        'mode': 'yield' if md == MODE_YIELD else 'mutual',
                        'target': f'robot_{known[int(r_[4])]}',
                    }
                )

    def _write_back(
        self, sub: AutomatonState, known: list[int], rows: np.ndarray, modes: Mapping[int, dict]
    ) -> None:
        """The sub-state into the full state (robot targets as full-state rows); obstacle modes
        stay the robots' own: an obstacle entry decided here is not kept.
        """
        full = self.state
        n = len(known)
        reported_obstacle = np.array(
            [(modes.get(rid) or {}).get('mode') == 'obstacle' for rid in known], dtype=bool
        )
        keep = ~(
            (sub.mode == MODE_OBSTACLE) & ~reported_obstacle & (full.mode[rows] != MODE_OBSTACLE)
        )  # the arbiter does not decide obstacle entries
        i, q = rows[keep], np.flatnonzero(keep)
        for name in ('mode', 'sdir', 't_entry', 'since', 'last_kind', 'last_exit', 'wc', 'wtgt',
                     'sweep_s'):
            getattr(full, name)[i] = getattr(sub, name)[q]
        tgt, lt = sub.tgt[q], sub.last_tgt[q]
        robot = (sub.mode[q] == MODE_YIELD) | (sub.mode[q] == MODE_MUTUAL)
        full.tgt[i] = np.where(robot, rows[np.clip(tgt, -n, n - 1)], tgt)
        known_lt = (sub.last_kind[q] == 2) & (lt >= 0) & (lt < n)
        full.last_tgt[i] = np.where(known_lt, rows[np.clip(lt, 0, n - 1)], lt)

    def _parent_rows(self, sub: AutomatonState, known: list[int], row: dict) -> np.ndarray:
        """Current formation parent row of each known robot (S9 rewiring with the robots in an
        avoidance mode as roots), for the S14.5 acyclicity check of every following link.
        """
        avoiding = tuple(rid for q, rid in enumerate(known) if sub.mode[q] != MODE_C)
        parents = self._rewired.get(avoiding)
        if parents is None:
            if len(self._rewired) >= 1024:
                self._rewired.clear()
            parents = self._rewired[avoiding] = self._graph.rewire(avoiding)
        out = np.full(len(known), -1, dtype=np.int64)
        for q, rid in enumerate(known):
            par = parents.get(rid)
            if par is not None and par in row:
                out[q] = row[par]
        return out

    def assignments(self) -> dict[int, EncounterAssignment]:
        """{robot id: EncounterAssignment} of the robots currently in yield or mutual mode."""
        st = self.state
        out = {}
        for i, rid in enumerate(self.ids):
            if st.mode[i] in (MODE_YIELD, MODE_MUTUAL):
                out[rid] = EncounterAssignment(
                    'yield' if st.mode[i] == MODE_YIELD else 'mutual',
                    self.ids[int(st.tgt[i])],
                    direction=float(st.sdir[i]),  # a mutual pair's common sense
                    t_entry_s=float(st.t_entry[i]),
                    drift_mps=(float(st.wc[i, 0]), float(st.wc[i, 1]))
                    if st.mode[i] == MODE_MUTUAL
                    else None,
                )
        return out


DRIFT_RESEND_MPS = 0.005  # a pair's w_c moved this much since it was sent: send it again [m/s]


def _decisions(assignments: Mapping[int, EncounterAssignment]) -> dict:
    return {k: (a.mode, a.partner, a.direction, a.t_entry_s) for k, a in assignments.items()}


def _drift_moved(new: EncounterAssignment, sent: EncounterAssignment | None) -> bool:
    if new.drift_mps is None or sent is None or sent.drift_mps is None:
        return False
    dx, dy = (a - b for a, b in zip(new.drift_mps, sent.drift_mps))
    return dx * dx + dy * dy > DRIFT_RESEND_MPS**2


class AssignmentSender:
    """When the coordinator sends its assignments (nodes/coordinator.py and the sensed simulator
    alike): ``update(new)`` with every decision's assignments returns ``'revision'`` for a new
    decision (a mode, partner, sense or entry time changed), ``'drift'`` when a mutual pair's
    w_c moved more than :data:`DRIFT_RESEND_MPS` since it was sent (the robots take the pair's
    w_c from the assignment, docs/law-changes.md §23: one frozen at the pair's entry drove pairs
    into walls), else None; :attr:`current` is the newest, :meth:`republish` marks it sent.
    """

    def __init__(self):
        self.current: dict[int, EncounterAssignment] = {}
        self._sent: dict[int, EncounterAssignment] = {}

    def update(self, new: Mapping[int, EncounterAssignment]) -> str | None:
        self.current = dict(new)
        if _decisions(self.current) != _decisions(self._sent):
            what = 'revision'
        elif any(_drift_moved(a, self._sent.get(k)) for k, a in self.current.items()):
            what = 'drift'
        else:
            return None
        self._sent = self.current
        return what

    def republish(self) -> dict[int, EncounterAssignment]:
        """The newest assignments, as sent again now."""
        self._sent = self.current
        return self.current
