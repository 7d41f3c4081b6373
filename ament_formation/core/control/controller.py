"""One robot's switched sliding-mode controller for the ROS controller node (issue 5).

:class:`RobotController` wraps exactly the compiled functions of the simulator -- the decision step
:func:`ament_formation.core.control.encounters.decide` (S8 automaton + S7 encounter rules) and the
law
:func:`ament_formation.core.control.law.robot_law` (S3/S4/S6/S7 fields and the sliding-mode
torque)
--
so a node and ``formation sim`` behave alike. It keeps only this robot's automaton state between
calls; every other robot appears through its broadcast state.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
import math
from typing import Mapping, Sequence

import numpy as np

from ament_formation.core.control.automaton import (
    AutomatonState,
    MODE_C,
    MODE_MUTUAL,
    MODE_NAMES,
    MODE_OBSTACLE,
    MODE_YIELD,
    SwitchingParams,
)
from ament_formation.core.control.encounters import decide, DecisionRobots, KIND_AGENT
from ament_formation.core.control.law import (
    gains_vector,
    goals_and_fields,
    LawRobots,
    robot_law,
    Tracking,
)
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import PlantCoeffs, point_velocities, ROW_D
from ament_formation.core.model.obstacles import (
    ObstacleField,
    ObstacleSnapshot,
    ObstacleSpec,
    ObstacleStates,
)
from ament_formation.core.model.paths import fast_reference
from ament_formation.core.params import AvoidanceParams, ControlGains, RobotParams

_MODE_BY_NAME = {name: k for k, name in enumerate(MODE_NAMES)}
_SENSE_BY_NAME = {'ccw': 1.0, 'cw': -1.0}
# A mutual pair is one-sided when the partner, heard for this long after the pair's entry, does
# not report it (it left with its own exit test, or never took it): docs/law-changes.md section 16
PAIR_CONFIRM_S = 1.0


@dataclass(frozen=True)
class NeighbourState:
    """What this robot knows about another robot (its broadcast, S4/S10).

    ``state_m`` (5,) [x_m, y_m, theta_rad, v_mps, omega_radps] (p = controlled point, world frame);
    ``accel_mps2`` (2,) its commanded point acceleration a_j (S4); ``body_radius_m``; ``team`` its
    team leader id (S14.3 teammate rule; None = own team unknown, treated as another team);
    ``mode`` its reported mode name (``coordination|obstacle|yield|mutual``) and ``target`` its
    reported target (obstacle name or ``robot_<id>``), used for the S7 acyclicity rule.
    ``goal_m`` (2,) / ``goal_dot_mps`` (2,): its S8.3 goal g_k and g_k_dot when known (leader:
    r(t), r_dot(t); follower: p of its original parent + delta), used for its side of the joint
    exit test of a mutual pair and for its V_c; None: unknown, taken as its position and velocity.
    ``slot_m`` (2,): its formation slot c_k relative to its team leader (the scenario's, S1), for
    the teammates' protected region (docs/law-changes.md §22); None: unknown (the full Q).
    ``direction``: its reported sense (``ccw``/``cw``) while in a mutual pair, else None: a pair
    both robots formed by their own decisions, without the coordinator, takes the sense of the
    robot with the lower id (one sense per pair, S7 and docs/law-changes.md §14, §23).
    """

    state_m: np.ndarray
    accel_mps2: np.ndarray = field(default_factory=lambda: np.zeros(2))
    body_radius_m: float = 0.10
    team: int | None = None
    mode: str = 'coordination'
    target: str | None = None
    com_offset_m: float = 0.05
    goal_m: np.ndarray | None = None
    goal_dot_mps: np.ndarray | None = None
    slot_m: np.ndarray | None = None
    direction: str | None = None

    def __post_init__(self) -> None:
        for name in ('goal_m', 'goal_dot_mps', 'slot_m'):
            val = getattr(self, name)
            if val is None:
                continue
            arr = np.asarray(val, dtype=float).reshape(-1)
            if arr.shape != (2,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f'must be 2 finite numbers (got {val!r})', name)
            object.__setattr__(self, name, arr)
        if self.goal_dot_mps is not None and self.goal_m is None:
            raise ConfigError('needs goal_m', 'goal_dot_mps')
        st = np.asarray(self.state_m, dtype=float).reshape(-1)
        if st.shape != (5,) or not np.all(np.isfinite(st)):
            raise ConfigError(f'must be 5 finite numbers (got {self.state_m!r})', 'state_m')
        acc = np.asarray(self.accel_mps2, dtype=float).reshape(-1)
        if acc.shape != (2,) or not np.all(np.isfinite(acc)):
            raise ConfigError(f'must be 2 finite numbers (got {self.accel_mps2!r})', 'accel_mps2')
        if self.mode not in _MODE_BY_NAME:
            raise ConfigError(f'must be one of {list(_MODE_BY_NAME)} (got {self.mode!r})', 'mode')
        if self.direction not in (None, 'ccw', 'cw'):
            raise ConfigError(f"must be 'ccw', 'cw' or None (got {self.direction!r})", 'direction')
        object.__setattr__(self, 'state_m', st)
        object.__setattr__(self, 'accel_mps2', acc)

    @classmethod
    def trusted(
        cls,
        state_m: np.ndarray,
        accel_mps2: np.ndarray,
        body_radius_m: float,
        team: int | None,
        mode: str,
        target: str | None,
        com_offset_m: float,
        goal_m: np.ndarray | None,
        goal_dot_mps: np.ndarray | None,
        slot_m: np.ndarray | None = None,
        direction: str | None = None,
    ) -> 'NeighbourState':
        """Build from values the caller has already checked (float arrays of the right shapes,
        finite; a known mode): the controller node checks every message on arrival, and builds
        one of these per robot per control period, so the checks are not repeated here.
        """
        obj = object.__new__(cls)
        for name, value in (
            ('state_m', state_m),
            ('accel_mps2', accel_mps2),
            ('body_radius_m', body_radius_m),
            ('team', team),
            ('mode', mode),
            ('target', target),
            ('com_offset_m', com_offset_m),
            ('goal_m', goal_m),
            ('goal_dot_mps', goal_dot_mps),
            ('slot_m', slot_m),
            ('direction', direction),
        ):
            object.__setattr__(obj, name, value)
        return obj


@dataclass(frozen=True)
class EncounterAssignment:
    """A coordinator's S7 decision for this robot: ``mode`` ``yield`` or ``mutual`` toward robot
    ``partner``; ``direction`` +1 CCW / -1 CW (mutual: the pair's common sense); ``t_entry_s`` the
    common entry time; ``drift_mps`` (2,) the shared w_c of a mutual pair (None: 1/2 (p_dot_i +
    p_dot_k) now).
    """

    mode: str
    partner: int
    direction: float = 1.0
    t_entry_s: float | None = None
    drift_mps: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.mode not in ('yield', 'mutual'):
            raise ConfigError(f"must be 'yield' or 'mutual' (got {self.mode!r})", 'mode')
        if self.direction not in (1.0, -1.0, 1, -1):
            raise ConfigError(f'must be +1 or -1 (got {self.direction!r})', 'direction')


@dataclass(frozen=True)
class ControlOutput:
    """Result of one :meth:`RobotController.step`.

    ``torque_nm`` (2,) [left, right] after S3.6 saturation; ``accel_cmd_mps2`` (2,) commanded point
    acceleration to broadcast (S4 a_j); ``sigma_mps`` (2,); ``saturated``; ``mode`` name,
    ``target``
    (obstacle name, ``robot_<id>`` or None) and ``direction`` (``ccw``/``cw``/None) for the mode
    topic; ``events`` the mode events of this step ({t_s, robot, event, mode, target, direction}).
    """

    torque_nm: np.ndarray
    accel_cmd_mps2: np.ndarray
    sigma_mps: np.ndarray
    saturated: bool
    mode: str
    target: str | None
    direction: str | None
    events: tuple[dict, ...] = ()

    def mode_dict(self) -> dict:
        """{mode, target, direction}: the JSON of the robot's mode topic (DESIGN §6)."""
        return {'mode': self.mode, 'target': self.target, 'direction': self.direction}


class _Scratch:
    """Work arrays of :meth:`RobotController.step` for ``n`` robots, made once: the packed robot
    rows (states ``x``, commanded accelerations ``acmd``, radii ``rbody``, teams ``team``, plant
    coefficients ``coeffs``: the own ones in every column, row 4 the CoM offsets of the step); the
    automaton state, as a new AutomatonState(n) has it, and the step's references, offsets, goals
    and parent rows, each a view into one of four blocks that :meth:`reset` refills (one copy or
    fill per block instead of one per array); the obstacles' states and the decision's event rows
    (written by the compiled code); the row layout of the last robot set (``ids`` sorted, ``row``
    {id: row}, ``me`` the own row); ``pd`` and ``obs``, the step's point velocities and obstacle
    arrays.
    """

    def __init__(self, n: int, own_coeffs: np.ndarray, obstacle_buffers: tuple):
        self.coeffs = np.repeat(own_coeffs[:, None], n, axis=1)
        fresh = AutomatonState(n)
        self._ints0 = np.stack([fresh.mode, fresh.tgt, fresh.last_kind, fresh.last_tgt])
        self._floats0 = np.concatenate(
            [fresh.sdir, fresh.t_entry, fresh.since, fresh.last_exit, fresh.wc.ravel(),
             fresh.wtgt.ravel(), fresh.sweep_s]
        )
        self._ints = self._ints0.copy()
        self._floats = self._floats0.copy()
        st = self.state = fresh  # its arrays replaced by views of the blocks (same types)
        st.mode, st.tgt, st.last_kind, st.last_tgt = self._ints
        f = self._floats
        st.sdir, st.t_entry, st.since, st.last_exit = (f[k * n:(k + 1) * n] for k in range(4))
        st.wc, st.wtgt = f[4 * n:6 * n].reshape(n, 2), f[6 * n:8 * n].reshape(n, 2)
        st.sweep_s = f[8 * n:9 * n]
        self._work = np.zeros(16 * n)  # ref (n, 6), then five (n, 2): offsets and goals
        w = self._work
        self.ref = w[:6 * n].reshape(n, 6)
        self.orig_offset, self.offset, self.goal, self.goal_dot, self.vc = (
            w[(6 + 2 * k) * n:(8 + 2 * k) * n].reshape(n, 2) for k in range(5)
        )
        self._rows = np.empty((2, n), dtype=np.int64)
        self.orig_parent, self.parent_row = self._rows
        self.obstacles = obstacle_buffers
        self.events = np.zeros((8 * n + 16, 6))
        self.x = np.zeros((n, 5))
        self.acmd = np.zeros((n, 2))
        self.rbody = np.zeros(n)
        self.team = np.zeros(n, dtype=np.int64)
        self.slot = np.full((n, 2), np.nan)
        self.ids: list[int] | None = None
        self.row: dict[int, int] = {}
        self.me = -1
        self.pd = np.zeros((n, 2))
        self.obs: tuple = ()

    def reset(self) -> None:
        """The automaton state of a new AutomatonState(n); zero references, offsets and goals;
        no parents (-1).
        """
        self._ints[...] = self._ints0
        self._floats[...] = self._floats0
        self._work.fill(0.0)
        self._rows.fill(-1)


class RobotController:
    """ONE robot's S8 automaton and sliding-mode law (same compiled functions as the simulator).

    Construction
    ------------
    ``RobotController(robot_id, params, control, avoidance, obstacles, *, leader_path=None,
    team=None, slot_m=None, switching=None, floor=None)``
      * ``params`` :class:`RobotParams`; ``control`` :class:`ControlGains` (K, epsilon, alpha,
      v_cap,
        lambda); ``avoidance`` :class:`AvoidanceParams`; ``obstacles`` the
        :class:`ObstacleSpec` the law avoids (a scenario's ``avoided_obstacles()``: obstacles
        too close to pass between come as one, docs/law-changes.md §18; their motion is
        evaluated at the step time unless ``step`` receives measured :class:`ObstacleStates`);
      * ``leader_path``: a path with ``reference(t_s) -> (r, r_dot, r_ddot)`` when this robot leads
        a team (then it tracks r(t), S4), else None;
      * ``team``: id of its team leader (S14.3); ``slot_m``: its formation slot c_i relative to
        the team leader (S1; teammates' protected region, docs/law-changes.md §22; None:
        unknown); ``switching``: :class:`SwitchingParams`
        (decision period, default 0.01 s = 100 Hz); ``floor``: the scenario's
        :class:`FloorSpec` (its edges are walls of the safety barrier) or None.

    Graph (from the coordinator's ``/formation/graph``, S9)
    -------------------------------------------------------
    ``set_graph(parent, offset_m, original_parent, original_offset_m)``: current parent id (None:
    root) with delta = c_self - c_parent, and the original parent pi0 with its delta (for the goal
    g_i of S8.3 item 1; None for a leader).

    Per control period
    ------------------
    ``step(t_s, own_state, *, parent=None, original_parent=None, neighbours=None, obstacles=None,
    assignment=None, release=None) -> ControlOutput``
      * ``own_state`` (5,) own estimate [x_m, y_m, theta_rad, v_mps, omega_radps];
      * ``parent``: :class:`NeighbourState` of the current parent (state + commanded accel, used
      for
        the S4 follower field with feed-forward); ``original_parent``: of pi0 (exit test; may be
        the
        same object);
      * ``neighbours``: {robot id: NeighbourState} of every other robot it hears (robot-robot
        threats, S7); the parents are added automatically;
      * ``obstacles``: optional measured :class:`ObstacleStates` (else the specs' motion model);
      * ``assignment``: optional :class:`EncounterAssignment` from the coordinator; it replaces the
        robot's own robot-robot decision (an obstacle avoidance in progress is kept: static
        obstacles beat robots, S7). Without it the controller arbitrates robot encounters itself
        with the same rules as the simulator, over the robots it hears.
      * ``release``: id of a robot whose coordinator assignment (yield to it / mutual with it) was
        withdrawn: the coordinator decided the exit (mutual pairs exit jointly, S8.3), so the
        robot leaves that encounter now (event ``exit``, cool-down S8.4) -- unless it is inside
        the partner's emergency circle (h_em < 0, S8.3 item 2): then it stays and the caller
        repeats the release at the next step. Ignored when the robot is not in that encounter.
      * ``coordinated``: the coordinator is heard (its assignments arrive): the robot then enters
        a robot encounter by its own decision only in an emergency (inside E, or contact within
        ``imminent_s``), and takes every other from ``assignment`` (docs/law-changes.md §23: two
        deciders that disagree for a few decisions switch the robot twice).
      The automaton decides every ``switching.decision_period_s``; the law runs at every call.
    ``mode`` / ``target`` / ``direction`` properties: the current mode (names as in ControlOutput).
    """

    def __init__(
        self,
        robot_id: int,
        params: RobotParams,
        control: ControlGains,
        avoidance: AvoidanceParams,
        obstacles: Sequence[ObstacleSpec] = (),
        *,
        leader_path=None,
        team: int | None = None,
        slot_m=None,
        switching: SwitchingParams | None = None,
        floor=None,
    ):
        self.robot_id = int(robot_id)
        self.params = params
        self.leader_path = fast_reference(leader_path)
        self.team = self.robot_id if team is None else int(team)
        self._slot = np.full(2, np.nan)
        if slot_m is not None:
            slot = np.asarray(slot_m, dtype=float).reshape(-1)
            if slot.shape != (2,) or not np.all(np.isfinite(slot)):
                raise ConfigError(f'must be 2 finite numbers (got {slot_m!r})', 'slot_m')
            self._slot = slot
        base = switching or SwitchingParams()
        self.switching = base.for_avoidance(avoidance).on_floor(floor)
        self._prm = self.switching.compiled()
        self._gains = gains_vector(control)
        k = PlantCoeffs.from_params([params])
        self._own_coeffs = np.array(
            [k.m_tilde[0], k.I_tilde[0], k.r[0], k.a[0], k.d[0], k.m_c[0], k.tau_max[0]]
        )
        self.obstacle_names = tuple(o.name for o in obstacles)
        self._obstacle_index: dict[str, int] = {}  # name -> first index (as tuple.index)
        for j, name in enumerate(self.obstacle_names):
            self._obstacle_index.setdefault(name, j)
        self._field = ObstacleField(obstacles)
        self._axes, self._static = self._field.axes, self._field.static
        self._state = AutomatonState(1)  # own automaton; target kept as obstacle index / robot id
        self._target_id = -1
        self._parent: int | None = None
        self._offset = np.zeros(2)
        self._orig_parent: int | None = None
        self._orig_offset = np.zeros(2)
        self._last_decision_s = -math.inf
        self._last_step_s: float | None = None
        self._confirmed_pair: tuple | None = None  # (partner id, entry time) it reported
        self._scratch: dict[int, _Scratch] = {}  # work arrays of step() per robot count

    # ------------------------------------------------------------------ graph
    def set_graph(
        self,
        parent: int | None,
        offset_m=(0.0, 0.0),
        original_parent: int | None = None,
        original_offset_m=(0.0, 0.0),
    ) -> None:
        """Current parent and pi0 with their offsets delta = c_self - c_parent [m] (S9)."""
        self._parent = None if parent is None else int(parent)
        self._offset = np.asarray(offset_m, dtype=float).reshape(2)
        self._orig_parent = None if original_parent is None else int(original_parent)
        self._orig_offset = np.asarray(original_offset_m, dtype=float).reshape(2)

    # ------------------------------------------------------------------ mode
    @property
    def mode(self) -> str:
        return MODE_NAMES[int(self._state.mode[0])]

    @property
    def target(self) -> str | None:
        return self._target_name(int(self._state.mode[0]), self._target_id)

    @property
    def direction(self) -> str | None:
        if self._state.mode[0] == MODE_C:
            return None
        return 'ccw' if self._state.sdir[0] > 0 else 'cw'

    def _target_name(self, mode: int, target: int) -> str | None:
        if mode == MODE_C:
            return None
        if mode == MODE_OBSTACLE:
            return self.obstacle_names[target]
        return f'robot_{target}'

    def warm_up(self) -> None:
        """Compile (or load from numba's disk cache) every kernel :meth:`step` uses, on a copy, so
        that the first real control period is not late. The controller's own state is untouched.
        """
        clone = copy.deepcopy(self)
        clone._last_decision_s = -math.inf
        clone._scratch = {}  # (views into blocks do not survive a deep copy as views)
        other = NeighbourState(np.zeros(5))
        clone.step(
            0.0,
            np.zeros(5),
            parent=None if clone._parent is None else other,
            original_parent=other,
        )

    # ------------------------------------------------------------------ step
    def step(
        self,
        t_s: float,
        own_state,
        *,
        parent: NeighbourState | None = None,
        original_parent: NeighbourState | None = None,
        neighbours: Mapping[int, NeighbourState] | None = None,
        obstacles: ObstacleStates | None = None,
        assignment: EncounterAssignment | None = None,
        release: int | None = None,
        coordinated: bool = False,
    ) -> ControlOutput:
        """One control period: (maybe) decide, then the law. See the class docstring."""
        own = self._checked_own_state(own_state)
        before = (self.mode, self.target, self.direction)
        others = self._others(parent, original_parent, neighbours)
        sc = self._layout(others)
        blind = self._pack(sc, own, others)
        t_s = float(t_s)
        events: list[dict] = []
        self._load_own_automaton(sc, t_s, events)
        if not coordinated:
            self._one_sense_with(t_s, sc, others, events)
        sc.pd = self._point_velocities(sc)
        sc.obs = self._obstacles_at(t_s, obstacles, sc)
        self._goals(t_s, sc, blind)
        if t_s - self._last_decision_s >= self.switching.decision_period_s - 1e-9:
            self._last_decision_s = t_s
            events.extend(self._decision_events(t_s, sc, coordinated))
        if release is not None:
            self._release(t_s, sc, release, events)
        if assignment is not None:
            self._assign(t_s, sc, assignment, events)
        self._law_links(sc)
        t1, t2, sx, sy, sat, acx, acy, wdx, wdy = self._robot_law(t_s, sc)
        st, me = sc.state, sc.me
        if st.mode[me] == MODE_MUTUAL and self._last_step_s is not None:
            st.wc[me] += (t_s - self._last_step_s) * np.array([wdx, wdy])
        self._last_step_s = t_s
        self._keep_own_automaton(sc)
        if events:  # one step's net switch (docs/law-changes.md §19; an assignment that
            events = self._net_events(events, before)  # replaces a mode exits it too)
        return ControlOutput(
            torque_nm=np.array([t1, t2]),
            accel_cmd_mps2=np.array([acx, acy]),
            sigma_mps=np.array([sx, sy]),
            saturated=bool(sat),
            mode=self.mode,
            target=self.target,
            direction=self.direction,
            events=tuple(events),
        )

    def _net_events(self, events: list[dict], before: tuple) -> list[dict]:
        """The mode events of one step as the robot's net switch: the exit of the mode it
        ran the step before and the entry of the mode it runs now, or nothing when they are
        the same. Modes entered and left within the step (the coordinator's assignment over
        the own decision, a one-sided pair left at once) never ran the law.
        """
        after = (self.mode, self.target, self.direction)
        if before == after:
            return []
        t_s = events[0]['t_s']
        out = []
        for state, kind in ((before, 'exit'), (after, 'enter')):
            if state[0] != MODE_NAMES[MODE_C]:
                mode, target, direction = state
                out.append(
                    {
                        't_s': t_s,
                        'robot': self.robot_id,
                        'event': kind,
                        'mode': mode,
                        'target': target,
                        'direction': direction,
                    }
                )
        return out

    def _checked_own_state(self, own_state) -> np.ndarray:
        """``own_state`` as a (5,) float array; ValueError unless 5 finite numbers."""
        own = np.asarray(own_state, dtype=float).reshape(-1)
        if own.shape != (5,) or not all(map(math.isfinite, own.tolist())):
            raise ValueError(f'own_state: must be 5 finite numbers (got {own_state!r})')
        return own

    def _others(
        self,
        parent: NeighbourState | None,
        original_parent: NeighbourState | None,
        neighbours: Mapping[int, NeighbourState] | None,
    ) -> dict[int, NeighbourState]:
        """{id: NeighbourState} of every other robot of this step: the neighbours and the
        parents (required when the graph names them; the current parent's state wins).
        """
        others: dict[int, NeighbourState] = dict(neighbours or {})
        if self._parent is not None:
            if parent is None:
                raise ValueError(
                    f'parent: state of robot {self._parent} is required (current parent)'
                )
            others[self._parent] = parent
        if self._orig_parent is not None:
            if original_parent is None:
                raise ValueError(
                    f'original_parent: state of robot {self._orig_parent} is required'
                )
            others.setdefault(self._orig_parent, original_parent)
        others.pop(self.robot_id, None)
        return others

    def _layout(self, others: Mapping[int, NeighbourState]) -> _Scratch:
        """The work arrays for this robot and ``others``, reset, with the rows in id order
        (``ids``, ``row`` {id: row}, ``me``); the own row's constants are written when the set
        of robots changes.
        """
        ids = sorted([*others, self.robot_id])
        n = len(ids)
        sc = self._scratch.get(n)
        if sc is None:
            sc = self._scratch[n] = _Scratch(n, self._own_coeffs, self._field.buffers())
        sc.reset()
        if sc.ids != ids:
            sc.ids = ids
            sc.row = {rid: q for q, rid in enumerate(ids)}
            me = sc.me = sc.row[self.robot_id]
            sc.acmd[me] = 0.0
            sc.rbody[me] = self.params.body_radius_m
            sc.team[me] = self.team
            sc.slot[me] = self._slot
            sc.coeffs[ROW_D, me] = self._own_coeffs[ROW_D]
        return sc

    def _pack(self, sc: _Scratch, own: np.ndarray, others: Mapping[int, NeighbourState]) -> list:
        """The robots as rows: state, commanded acceleration, radius, team, CoM offset, reported
        mode and target (S7 acyclicity) and, when known, goal (into ``ref``). Returns the rows
        whose goal is not known.
        """
        x, acmd, rbody, team, d = sc.x, sc.acmd, sc.rbody, sc.team, sc.coeffs[ROW_D]
        mode, tgt, ref, row = sc.state.mode, sc.state.tgt, sc.ref, sc.row
        me = sc.me
        x[me] = own
        blind = []
        for q, rid in enumerate(sc.ids):
            if q == me:
                continue
            nb = others[rid]
            x[q] = nb.state_m
            acmd[q] = nb.accel_mps2
            rbody[q] = nb.body_radius_m
            team[q] = nb.team if nb.team is not None else -1 - rid
            sc.slot[q] = nb.slot_m if nb.slot_m is not None else np.nan
            d[q] = nb.com_offset_m
            if nb.mode != 'coordination':
                mode[q], tgt[q] = self._reported_mode(nb.mode, nb.target, row)
            goal = nb.goal_m
            if goal is None:
                blind.append(q)
            else:
                ref[q, 0:2] = goal
                if nb.goal_dot_mps is not None:
                    ref[q, 2:4] = nb.goal_dot_mps
        return blind

    def _reported_mode(self, name: str, target: str | None, row: Mapping[int, int]) -> tuple:
        """(mode, target row or obstacle index) of another robot's reported mode; a robot busy
        with a robot we do not hear counts as busy with an obstacle (-1).
        """
        mode, tgt = _MODE_BY_NAME[name], -1
        if name in ('yield', 'mutual') and target and target.startswith('robot_'):
            tgt = row.get(int(target[len('robot_'):]), -1)
            if tgt < 0:
                mode = MODE_OBSTACLE
        elif name == 'obstacle':
            tgt = self._obstacle_index.get(target, -1)
        return mode, tgt

    def _load_own_automaton(self, sc: _Scratch, t_s: float, events: list) -> None:
        """Own automaton state into row ``me`` (robot targets: ids -> rows); others' entry times
        are not known here (-1e9); a mutual partner's row is made reciprocal, unless the pair is
        one-sided (:meth:`_leave_one_sided_pair`).
        """
        st, me, row, src = sc.state, sc.me, sc.row, self._state
        st.t_entry.fill(-1e9)
        st.mode[me] = src.mode[0]
        st.sdir[me] = src.sdir[0]
        st.t_entry[me] = src.t_entry[0]
        st.sweep_s[me] = src.sweep_s[0]
        st.since[me] = src.since[0]
        st.last_kind[me] = src.last_kind[0]
        st.last_exit[me] = src.last_exit[0]
        st.wc[me] = src.wc[0]
        st.wtgt[me] = src.wtgt[0]
        if int(src.mode[0]) in (MODE_YIELD, MODE_MUTUAL):
            st.tgt[me] = row.get(self._target_id, -1)
            if st.tgt[me] < 0:  # partner no longer heard: back to coordination
                st.mode[me] = MODE_C
        else:
            st.tgt[me] = self._target_id
        if src.last_kind[0] == KIND_AGENT:
            st.last_tgt[me] = row.get(int(src.last_tgt[0]), -1)
        else:
            st.last_tgt[me] = src.last_tgt[0]
        if st.mode[me] == MODE_MUTUAL:
            k = st.tgt[me]
            pair = (self._target_id, float(st.t_entry[me]))
            if st.mode[k] == MODE_MUTUAL and st.tgt[k] == me:
                self._confirmed_pair = pair
            elif self._confirmed_pair == pair or t_s - st.t_entry[me] >= PAIR_CONFIRM_S:
                self._leave_one_sided_pair(t_s, sc, k, self._confirmed_pair == pair, events)
                return
            # the partner's view must be reciprocal
            st.mode[k] = MODE_MUTUAL
            st.tgt[k] = me
            st.sdir[k] = st.sdir[me]  # one sense for the pair (docs/law-changes.md section 14)
            st.t_entry[k] = st.t_entry[me]

    def _one_sense_with(self, t_s: float, sc: _Scratch, others, events: list) -> None:
        """A mutual pair both robots report, each with its own sense (each formed it by its own
        decision on its own estimates; opposite senses push the two the same way): the robot with
        the higher id turns the other's way (docs/law-changes.md §23; with the coordinator its
        assignment carries the pair's sense).
        """
        st, me = sc.state, sc.me
        if st.mode[me] != MODE_MUTUAL or self._target_id > self.robot_id:
            return
        k = st.tgt[me]
        if not (st.mode[k] == MODE_MUTUAL and st.tgt[k] == me):
            return
        sense = _SENSE_BY_NAME.get(others[self._target_id].direction)
        if sense is not None and sense != st.sdir[me]:
            st.sdir[me] = sense
            st.sdir[k] = sense
            events.append(self._entered(t_s, MODE_MUTUAL, self._target_id, sense))

    def _entered(self, t_s: float, mode: int, partner: int, sense: float) -> dict:
        """The mode event of entering a robot encounter ``mode`` with robot ``partner``."""
        return {
            't_s': t_s,
            'robot': self.robot_id,
            'event': 'enter',
            'mode': MODE_NAMES[mode],
            'target': f'robot_{partner}',
            'direction': 'ccw' if sense > 0 else 'cw',
        }

    def _leave_one_sided_pair(
        self, t_s: float, sc: _Scratch, k: int, partner_left: bool, events: list
    ) -> None:
        """The partner k does not report the mutual pair (docs/law-changes.md section 16). When
        it had reported the pair and left it (its side of the joint exit test, S8.3, held), or
        when it yields to this robot, this robot leaves the encounter too (event ``exit``, S8.4
        cool-down). When it never took the pair, this robot stays in the encounter as a plain
        yielder to k, as the coordinator does with a pair one robot left (S8.3), and leaves it
        with the yielder's exit test.
        """
        st, me = sc.state, sc.me
        if partner_left or (st.mode[k] == MODE_YIELD and st.tgt[k] == me):
            self._leave_robot(t_s, sc, events)
            return
        direction = 'ccw' if st.sdir[me] > 0 else 'cw'
        common = {'t_s': t_s, 'robot': self.robot_id, 'target': f'robot_{sc.ids[k]}'}
        events.append({**common, 'event': 'exit', 'mode': 'mutual', 'direction': direction})
        st.mode[me] = MODE_YIELD
        st.t_entry[me] = t_s
        st.since[me] = -1.0
        events.append({**common, 'event': 'enter', 'mode': 'yield', 'direction': direction})

    def _point_velocities(self, sc: _Scratch) -> np.ndarray:
        """(N, 2) p_dot = S1(theta) x2 of every row."""
        return point_velocities(sc.x, np.ascontiguousarray(sc.coeffs[ROW_D]))

    def _obstacles_at(self, t_s: float, obstacles: ObstacleStates | None, sc: _Scratch) -> tuple:
        """(centres, velocities, accelerations, phi, phi_dot, phi_ddot, semi-axes) of the
        obstacles at ``t_s``: the measured ``obstacles`` (one row per obstacle the law avoids),
        else the specs' motion model.
        """
        if obstacles is not None:
            return tuple(
                np.ascontiguousarray(a, dtype=float)
                for a in (
                    obstacles.center_m,
                    obstacles.velocity_mps,
                    obstacles.accel_mps2,
                    obstacles.phi_rad,
                    obstacles.phi_dot_radps,
                    obstacles.phi_ddot_radps2,
                    obstacles.semi_axes_m,
                )
            )
        return (*self._field.fill(t_s, sc.obstacles), self._axes)  # the motion model (S6.1)

    def _goals(self, t_s: float, sc: _Scratch, blind: list) -> None:
        """References (own: r(t) when leading; others: their goal when known, else their
        position and point velocity), own pi0 link, then goals and V_c (S8.3).
        """
        me, ref = sc.me, sc.ref
        if self.leader_path is not None:
            r, rd, rdd = self.leader_path.reference(t_s)
            ref[me, 0:2] = r
            ref[me, 2:4] = rd
            ref[me, 4:6] = rdd
        if self._orig_parent is not None:
            sc.orig_parent[me] = sc.row[self._orig_parent]
            sc.orig_offset[me] = self._orig_offset
        if blind:
            ref[blind, 0:2] = sc.x[blind, 0:2]
            ref[blind, 2:4] = sc.pd[blind]
        self._goals_and_fields(sc)

    def _goals_and_fields(self, sc: _Scratch) -> None:
        """Goals g, g_dot and V_c of every row into the scratch (as goal_fields())."""
        goals_and_fields(
            sc.x,
            sc.pd,
            sc.ref,
            sc.orig_parent,
            sc.orig_offset,
            self._gains,
            sc.goal,
            sc.goal_dot,
            sc.vc,
            True,
        )

    def _decide(self, t_s: float, sc: _Scratch, coordinated: bool) -> int:
        """The compiled S7/S8 decision over every row (automaton state updated in place, events
        into ``sc.events``); returns the event count. ``coordinated``: the own row enters robot
        encounters in emergencies only (docs/law-changes.md §23).
        """
        oc, ov, oa, ophi, ophid, ophidd, oaxes = sc.obs
        return decide(
            t_s,
            DecisionRobots(
                np.ascontiguousarray(sc.x[:, :2]),
                sc.pd,
                sc.goal,
                sc.goal_dot,
                sc.vc,
                sc.team,
                sc.rbody,
                self._parent_rows(sc.parent_row, sc.row, sc.me),
                sc.slot,
            ),
            ObstacleSnapshot(oc, ov, oa, ophi, ophid, ophidd, oaxes, self._static),
            sc.state.arrays(),
            self._prm._replace(deferring_row=float(sc.me)) if coordinated else self._prm,
            sc.events,
        )

    def _parent_rows(self, parent_row: np.ndarray, row: Mapping[int, int], me: int) -> np.ndarray:
        """The formation parent rows known here for the S14.5 acyclicity check: our own current
        parent (the others' are not heard: -1).
        """
        if self._parent is not None and self._parent in row:
            parent_row[me] = row[self._parent]
        return parent_row

    def _decision_events(self, t_s: float, sc: _Scratch, coordinated: bool) -> list[dict]:
        """Decide; the own mode events of the decision ({t_s, robot, event, mode, target,
        direction}).
        """
        nev = self._decide(t_s, sc, coordinated)
        events = []
        for r_ in sc.events[:nev]:
            if int(r_[1]) == sc.me:
                md = int(r_[3])
                tg = int(r_[4])
                events.append(
                    {
                        't_s': float(r_[0]),
                        'robot': self.robot_id,
                        'event': 'enter' if r_[2] > 0.5 else 'exit',
                        'mode': MODE_NAMES[md],
                        'target': self._target_name(md, sc.ids[tg] if md != MODE_OBSTACLE else tg),
                        'direction': 'ccw' if r_[5] > 0 else 'cw',
                    }
                )
        return events

    def _release(self, t_s: float, sc: _Scratch, release: int, events: list) -> None:
        """The coordinator withdrew the encounter with robot ``release``: leave it now (event
        ``exit``, S8.4 cool-down), unless inside the partner's emergency circle (S8.3 item 2).
        """
        st, me, ids = sc.state, sc.me, sc.ids
        if not (st.mode[me] in (MODE_YIELD, MODE_MUTUAL) and ids[int(st.tgt[me])] == int(release)):
            return
        k = int(st.tgt[me])
        x, rbody = sc.x, sc.rbody
        # S8.3 item 2: never leave inside the partner's emergency circle E (rho_em R_aa, S7)
        r_em = self._prm.emergency_scale * (
            rbody[me] + rbody[k] + self._prm.agent_keepout_margin_m
        )
        h_em = ((x[me, 0] - x[k, 0]) ** 2 + (x[me, 1] - x[k, 1]) ** 2) / r_em**2 - 1.0
        if h_em < 0.0:
            return
        self._leave_robot(t_s, sc, events)

    def _leave_robot(self, t_s: float, sc: _Scratch, events: list) -> None:
        """Leave the current yield or mutual encounter for coordination: event ``exit`` and the
        S8.4 cool-down record (robot target).
        """
        st, me = sc.state, sc.me
        k = int(st.tgt[me])
        events.append(
            {
                't_s': t_s,
                'robot': self.robot_id,
                'event': 'exit',
                'mode': MODE_NAMES[int(st.mode[me])],
                'target': f'robot_{sc.ids[k]}',
                'direction': 'ccw' if st.sdir[me] > 0 else 'cw',
            }
        )
        st.last_kind[me] = KIND_AGENT
        st.last_tgt[me] = k
        st.last_exit[me] = t_s
        st.mode[me] = MODE_C
        st.tgt[me] = -1
        st.since[me] = -1.0

    def _assign(
        self, t_s: float, sc: _Scratch, assignment: EncounterAssignment, events: list
    ) -> None:
        """Apply the coordinator's assignment (not over an obstacle avoidance, S7; an encounter
        left at this very decision is not re-entered, S8.3): enter it, or take its w_c; a mutual
        pair the robot is in with another sense (each robot's own decision on its own estimates)
        turns the coordinator's way, the pair's one sense (docs/law-changes.md §23).
        """
        st, me = sc.state, sc.me
        left_now = {(e['mode'], e['target']) for e in events if e['event'] == 'exit'}
        if (
            st.mode[me] == MODE_OBSTACLE
            or (assignment.mode, f'robot_{assignment.partner}') in left_now
        ):
            return
        k = sc.row.get(int(assignment.partner))
        if k is None:
            raise ValueError(f'assignment: partner {assignment.partner} is not a known robot')
        new_mode = MODE_YIELD if assignment.mode == 'yield' else MODE_MUTUAL
        if (
            st.mode[me] != new_mode
            or st.tgt[me] != k
            or (new_mode == MODE_MUTUAL and st.sdir[me] != float(assignment.direction))
        ):  # a pair entered by the robot's own decision takes the pair's one sense (§14, §23)
            st.set_mode(
                me,
                new_mode,
                k,
                float(assignment.direction),
                t_s if assignment.t_entry_s is None else float(assignment.t_entry_s),
            )
            w = (
                0.5 * (sc.pd[me] + sc.pd[k])
                if assignment.drift_mps is None
                else np.asarray(assignment.drift_mps, dtype=float)
            )
            st.wc[me] = w
            st.wtgt[me] = w
            events.append(self._entered(t_s, new_mode, assignment.partner, st.sdir[me]))
        elif new_mode == MODE_MUTUAL and assignment.drift_mps is not None:
            # the pair's w_c is the coordinator's (it knows both goals): common to both robots,
            # so z_dot = F(z) holds exactly (S7); the own relaxation would use a guessed goal
            st.wc[me] = np.asarray(assignment.drift_mps, dtype=float)
            st.wtgt[me] = st.wc[me]

    def _law_links(self, sc: _Scratch) -> None:
        """The own parent row and offset for the law (S4): the current parent; a follower
        without one (graph not received yet) holds via its original goal in coordination.
        """
        me = sc.me
        if self._parent is not None:
            sc.parent_row[me] = sc.row[self._parent]
            sc.offset[me] = self._offset
        elif self.leader_path is None and sc.state.mode[me] == MODE_C:
            if self._orig_parent is not None:
                sc.parent_row[me] = sc.row[self._orig_parent]
                sc.offset[me] = self._orig_offset

    def _robot_law(self, t_s: float, sc: _Scratch) -> tuple:
        """The compiled law of row ``me`` (S3.2 with the mode's field): (tau_l, tau_r, sigma_x,
        sigma_y, saturated, a_cmd_x, a_cmd_y, w_c_dot_x, w_c_dot_y).
        """
        st = sc.state
        oc, ov, oa, ophi, ophid, ophidd, oaxes = sc.obs
        return robot_law(
            sc.me,
            t_s,
            LawRobots(sc.x, sc.pd, sc.acmd, sc.rbody, sc.coeffs),
            Tracking(sc.parent_row, sc.offset, sc.ref, sc.goal, sc.goal_dot),
            st.arrays(),
            ObstacleSnapshot(oc, ov, oa, ophi, ophid, ophidd, oaxes, self._static),
            self._gains,
            self._prm,
        )

    def _keep_own_automaton(self, sc: _Scratch) -> None:
        """Row ``me`` of the automaton state back into the own state (robot targets as ids)."""
        st, me, ids, src = sc.state, sc.me, sc.ids, self._state
        src.mode[0] = st.mode[me]
        src.sdir[0] = st.sdir[me]
        src.t_entry[0] = st.t_entry[me]
        src.sweep_s[0] = st.sweep_s[me]
        src.since[0] = st.since[me]
        src.last_kind[0] = st.last_kind[me]
        src.last_exit[0] = st.last_exit[me]
        src.wc[0] = st.wc[me]
        src.wtgt[0] = st.wtgt[me]
        new_mode = int(st.mode[me])
        self._target_id = (
            ids[int(st.tgt[me])] if new_mode in (MODE_YIELD, MODE_MUTUAL) else int(st.tgt[me])
        )
        src.tgt[0] = self._target_id
        lk = int(st.last_kind[me])
        lt = int(st.last_tgt[me])
        src.last_tgt[0] = ids[lt] if (lk == 2 and 0 <= lt < len(ids)) else lt
