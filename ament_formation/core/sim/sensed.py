"""The closed loop with what the robots really have (issue 13: sensing in the fast simulator).

Where :func:`ament_formation.core.sim.simulator.simulate` closes the loop on the TRUE state at
every 1 ms step, :func:`simulate_sensed` runs each robot as the ROS system does, with the same core
objects the nodes hold:

* camera: every robot's pose of p captured at the scenario's ``camera.fps`` (or ``fps``), with
  Gaussian noise (``noise_m`` per axis, ``noise_rad`` on the heading), lost with probability
  ``drop_prob`` per robot and frame, delivered ``latency_s`` after capture with its capture stamp
  (the tracker's PoseStamped, DESIGN §6);
* each robot's S10 estimator (:class:`~ament_formation.core.control.estimator.PoseEstimator`, as in
  nodes/controller.py): wheel encoder samples at every control period, camera poses on arrival;
* each robot's :class:`~ament_formation.core.control.controller.RobotController` at
  ``control_rate_hz`` on its estimate and on the other robots' broadcasts of the previous period
  (state, commanded acceleration, mode; extrapolated with
  :func:`~ament_formation.core.control.neighbours.extrapolate_neighbour`, goals with
  :func:`~ament_formation.core.control.neighbours.neighbour_goal`), torque held (ZOH) until the
  next period;
* the coordinator (nodes/coordinator.py): S9 rewiring with
  :class:`~ament_formation.core.control.rewiring.FormationGraph` whenever the set of avoiding
  robots changes, S7 arbitration with
  :class:`~ament_formation.core.control.arbiter.EncounterArbiter` at ``encounter_rate_hz``, its
  assignments delivered at the start, on change (a new decision, or a mutual pair's w_c moved,
  :class:`~ament_formation.core.control.arbiter.AssignmentSender`) and every ``republish_s``;
* the plant: :class:`~ament_formation.core.sim.twin.PlantTwin` (RK4 at ``dt_s``, wheel encoders,
  disturbance, obstacle motion).

Not modelled: the controller's safety stops (camera loss after ``pose_timeout_s``, wheel timeout,
parent hold: a run never starves them at drop rates below about 0.5), encoder quantisation and
DDS delays (a broadcast reaches the robots that hear it by their next period; a robot coming into
hearing range is heard at once).

The record is the TRUE state (the same :class:`~ament_formation.core.sim.trajectory.SimResult` as
``simulate``); :attr:`SensedResult.sensing` adds the sensing figures (frames, drops, estimator
counters, estimate error).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace
import math
import time
from typing import Callable

import numpy as np

from ament_formation.core.control.arbiter import AssignmentSender, EncounterArbiter
from ament_formation.core.control.assignment import (
    AssignedLaw,
    original_parent_link,
    original_parent_state,
)
from ament_formation.core.control.controller import NeighbourState, RobotController
from ament_formation.core.control.estimator import EstimatorParams, PoseEstimator
from ament_formation.core.control.neighbours import extrapolate_neighbour, neighbour_goal
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.errors import ConfigError, excerpt
from ament_formation.core.model.paths import fast_reference
from ament_formation.core.sim.trajectory import SimResult
from ament_formation.core.sim.twin import PlantTwin

# The tracker's measured accuracy (docs/camera.md "Marker size", 0.12 m markers): position p95
# 0.43 mm (radial: 2.448 sigma per axis), heading p95 0.30 deg (1.96 sigma), detection 100 %;
# capture -> pose p50 / p95 8.0 / 12.2 ms on a live MJPEG stream (docs/camera.md, "The real
# camera"): the p95.
MEASURED_NOISE_M = 0.43e-3 / 2.448  # 0.176 mm per axis
MEASURED_NOISE_RAD = math.radians(0.30) / 1.96  # 0.153 deg
MEASURED_LATENCY_S = 0.012
# issue 13's stress figures: 30 fps, 50 ms delay, 3 mm noise, 5 % drops; the heading noise keeps
# the measured ratio of heading to position noise (3 mm -> 2.6 deg)
STRESS_NOISE_M = 3.0e-3
STRESS_NOISE_RAD = STRESS_NOISE_M * MEASURED_NOISE_RAD / MEASURED_NOISE_M


@dataclass(frozen=True)
class SensingParams:
    """What the robots sense and how often they act (see the module docstring).

    ``fps`` camera frame rate [Hz] (None: the scenario's ``camera.fps``); ``latency_s`` capture to
    arrival at the controller [s]; ``noise_m`` standard deviation per axis of the camera position
    of p [m]; ``noise_rad`` of its heading [rad]; ``drop_prob`` probability that a robot's pose is
    missing from a frame, [0, 1); ``seed`` of the sensing noise and drops. The robot side, as in
    config/params: ``control_rate_hz`` (formation_controller, 100 Hz), ``camera_gain`` (its S10
    gain, 0.5), ``hear_all`` and ``hear_margin_m`` (its hearing range: parents, the assignment's
    partner and the robots whose camera pose is within kappa R_aa + 0.6 m, 0.3 m hysteresis),
    ``encounter_rate_hz`` and ``republish_s`` (formation_coordinator, 50 Hz, 1 s),
    ``coordinator_timeout_s`` (formation_controller, 2.5 s: assignments heard within it, the
    robot's own robot encounters are emergencies only, docs/law-changes.md §23).
    """

    fps: float | None = None
    latency_s: float = MEASURED_LATENCY_S
    noise_m: float = MEASURED_NOISE_M
    noise_rad: float = MEASURED_NOISE_RAD
    drop_prob: float = 0.0
    seed: int = 0
    control_rate_hz: float = 100.0
    camera_gain: float = 0.5
    encounter_rate_hz: float = 50.0
    republish_s: float = 1.0
    coordinator_timeout_s: float = 2.5
    hear_all: bool = False
    hear_margin_m: float = 0.6

    def __post_init__(self) -> None:
        def bad(name, value, what):
            raise ConfigError(f'must be {what} (got {excerpt(value)})', name)

        def number(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        if self.fps is not None and not (number(self.fps) and 0 < self.fps <= 1000):
            bad('fps', self.fps, 'a number in (0, 1000] Hz or None')
        for name, hi in (('latency_s', 10.0), ('noise_m', 1.0), ('noise_rad', math.pi)):
            v = getattr(self, name)
            if not (number(v) and 0 <= v <= hi):
                bad(name, v, f'a number in [0, {hi:g}]')
        if not (number(self.drop_prob) and 0 <= self.drop_prob < 1):
            bad('drop_prob', self.drop_prob, 'a number in [0, 1)')
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool) and self.seed >= 0):
            bad('seed', self.seed, 'an integer >= 0')
        for name, lo, hi in (
            ('control_rate_hz', 1.0, 1000.0),
            ('encounter_rate_hz', 0.0, 1000.0),
            ('republish_s', 1e-3, 60.0),
            ('coordinator_timeout_s', 0.0, 60.0),
        ):
            v = getattr(self, name)
            if not (number(v) and lo <= v <= hi):
                bad(name, v, f'a number in [{lo:g}, {hi:g}]')
        if not (number(self.camera_gain) and 0 < self.camera_gain <= 1):
            bad('camera_gain', self.camera_gain, 'a number in (0, 1]')
        if not isinstance(self.hear_all, bool):
            bad('hear_all', self.hear_all, 'true or false')
        if not (number(self.hear_margin_m) and 0 <= self.hear_margin_m <= 100):
            bad('hear_margin_m', self.hear_margin_m, 'a number in [0, 100] m')

    @classmethod
    def preset(cls, name: str, **overrides) -> 'SensingParams':
        """The figures called ``name`` in :data:`PRESETS` with ``overrides`` (fields; None values
        are ignored): ``camera`` the tracker's measured figures, ``camera-stress`` issue 13's
        30 fps, 50 ms, 3 mm, 5 % drops, ``camera-perfect`` no noise, latency or drops.
        """
        if name not in PRESETS:
            raise ConfigError(f'must be one of {sorted(PRESETS)} (got {excerpt(name)})', 'sensing')
        kept = {k: v for k, v in overrides.items() if v is not None}
        return replace(PRESETS[name], **kept)

    def frame_rate_hz(self, scenario) -> float:
        return float(self.fps if self.fps is not None else scenario.camera.fps)

    def as_dict(self, scenario=None) -> dict:
        out = dict(self.__dict__)
        if scenario is not None:
            out['fps'] = self.frame_rate_hz(scenario)
        return out


PRESETS = {
    'camera': SensingParams(),
    'camera-stress': SensingParams(
        fps=30.0,
        latency_s=0.050,
        noise_m=STRESS_NOISE_M,
        noise_rad=STRESS_NOISE_RAD,
        drop_prob=0.05,
    ),
    'camera-perfect': SensingParams(latency_s=0.0, noise_m=0.0, noise_rad=0.0, drop_prob=0.0),
}


@dataclass
class SensedResult(SimResult):
    """A :class:`SimResult` (TRUE state) plus ``sensing``: {params, prestart_frames (fused by
    every robot at rest before t = 0), frames (from t = 0), poses_sent, poses_dropped, estimator:
    summed counters (pre-start frames included), estimate_error_m: {rms, max} of |p_hat - p| at
    the control periods}.
    """

    sensing: dict = field(default_factory=dict)


def _threat_mode(mode: str, target: str | None) -> tuple[str, str | None]:
    """A robot's mode as the others read it (nodes/controller.py threat_mode)."""
    if mode in ('obstacle', 'yield', 'mutual') and isinstance(target, str):
        return mode, target
    return 'coordination', None


class _Camera:
    """Captures, noise, drops and delivery of the tracker's poses (seeded)."""

    def __init__(self, n: int, sensing: SensingParams, dt_s: float):
        self.n = n
        self.s = sensing
        self.rng = np.random.default_rng(sensing.seed)
        self.queue: deque = deque()  # (arrival_s, stamp_s, poses (N, 3), kept (N,))
        self.frames = 0
        self.sent = 0
        self.dropped = 0
        self.lat_s = sensing.latency_s

    def capture(self, stamp_s: float, true_pose: np.ndarray) -> None:
        """A frame at ``stamp_s`` of (N, 3) true poses [x_m, y_m, theta_rad] of p."""
        u = self.rng.random(self.n)  # always drawn: a drop rate does not change the noise
        e = self.rng.standard_normal((self.n, 3))
        pose = true_pose.copy()
        pose[:, :2] += self.s.noise_m * e[:, :2]
        pose[:, 2] = (pose[:, 2] + self.s.noise_rad * e[:, 2] + math.pi) % (2 * math.pi) - math.pi
        kept = u >= self.s.drop_prob
        self.frames += 1
        self.sent += int(kept.sum())
        self.dropped += self.n - int(kept.sum())
        self.queue.append((stamp_s + self.lat_s, stamp_s, pose, kept))

    def deliver(self, now_s: float, estimators: list) -> list:
        """Every frame arrived by ``now_s`` into the robots' estimators (capture stamps);
        returns those frames [(poses (N, 3), kept (N,))].
        """
        q = self.queue
        out = []
        while q and q[0][0] <= now_s + 1e-12:
            _arr, stamp, pose, kept = q.popleft()
            for i in np.flatnonzero(kept):
                estimators[i].camera_update(stamp, pose[i])
            out.append((pose, kept))
        return out


# the controller node's defaults (config/params/formation_controller.yaml)
PARENT_TIMEOUT_S = 0.1  # an older broadcast is extrapolated ...
PARENT_HOLD_S = 1.0  # ... up to this age
PRESTART_FRAMES = 10  # frames the estimators fuse before the mission starts (robots at rest)
HEAR_HYSTERESIS_M = 0.3  # nodes/controller.py: heard until this much beyond the hearing range


class _RobotNode:
    """What nodes/controller.py ControllerNode does around its core objects at one control period
    (estimator, RobotController, the coordinator's graph and assignment), without ROS.
    """

    def __init__(self, scenario, spec, fgraph: FormationGraph, sensing: SensingParams):
        self.rid = int(spec.id)
        self.est = PoseEstimator(
            EstimatorParams.from_robot(spec.params, camera_gain=sensing.camera_gain)
        )
        self.law = RobotController(
            self.rid,
            spec.params,
            scenario.control,
            scenario.avoidance,
            scenario.avoided_obstacles(),
            leader_path=spec.path if spec.leader else None,
            team=scenario.team_leader(self.rid),
            slot_m=scenario.slot(self.rid),
            floor=scenario.floor,
        )
        self.orig_parent_id, self.orig_offset = original_parent_link(fgraph, self.rid)
        self.law.set_graph(
            self.orig_parent_id, self.orig_offset, self.orig_parent_id, self.orig_offset
        )
        self.parent: int | None = None
        self.assigned = AssignedLaw(self.law)  # the coordinator's assignment applied (S7, S8.3)
        self.encounters_at = -math.inf  # when the coordinator's assignments last arrived [s]
        self.coordinator_timeout_s = sensing.coordinator_timeout_s

    def apply_graph(self, parent: int | None, offset_m) -> None:
        """A /formation/graph message (ControllerNode._apply_graph)."""
        self.parent = parent
        self.law.set_graph(parent, offset_m, self.orig_parent_id, self.orig_offset)

    def step(self, t_s: float, state: np.ndarray, heard: dict):
        """One control period on the own estimate ``state`` (5,) and the broadcasts ``heard``
        {id: NeighbourState} (ControllerNode._control from the parent lookup on).
        """
        orig_state = original_parent_state(heard, self.orig_parent_id, self.orig_offset, state)
        coordinated = t_s - self.encounters_at <= self.coordinator_timeout_s
        return self.assigned.step(t_s, state, self.parent, orig_state, heard, coordinated)


class _Coordinator:
    """nodes/coordinator.py without ROS: S9 rewiring on a change of the avoiding set, S7
    arbitration at its rate, assignments sent at the start, on change and every ``republish_s``.
    """

    def __init__(self, scenario, sensing: SensingParams):
        self.graph = FormationGraph.from_scenario(scenario)
        self.arbiter = EncounterArbiter(scenario)
        self.avoiding: set[int] = set()
        self.parents = self.graph.rewire(())
        self.sender = AssignmentSender()  # new decisions, a pair's w_c moved (§23)
        self.republish_s = sensing.republish_s
        self._next_republish = 0.0  # as the node: sent once at the start

    def on_modes(self, modes: dict) -> dict | None:
        """{id: mode dict}; the new parents when the avoiding set changed (a graph is sent)."""
        avoiding = {rid for rid, m in modes.items() if m['avoiding']}
        if avoiding == self.avoiding:
            return None
        self.avoiding = avoiding
        self.parents = self.graph.rewire(sorted(avoiding))  # S9 steps 1-6
        return self.parents

    def arbitrate(self, t_s: float, states: dict, modes: dict) -> dict | None:
        """S7 over all robots; the assignments when they are published (else None)."""
        sent = self.sender.update(self.arbiter.decide(t_s, states, modes))
        if t_s >= self._next_republish - 1e-9:
            self._next_republish += self.republish_s
            return self.sender.republish()
        return self.sender.current if sent is not None else None


class _Loop:
    """The state of one sensed run (see :func:`simulate_sensed`)."""

    def __init__(self, scenario, sensing: SensingParams, dt_s: float):
        self.sc = scenario
        self.dt = dt_s
        robots = sorted(scenario.robots, key=lambda r: r.id)
        self.ids = tuple(int(r.id) for r in robots)
        self.row = {rid: i for i, rid in enumerate(self.ids)}
        self.twin = PlantTwin(scenario, dt_s)
        twin_row = {int(rid): q for q, rid in enumerate(self.twin.ids)}
        self.rows = np.array([twin_row[rid] for rid in self.ids], dtype=np.int64)
        self.tau_max = [float(r.params.torque_limit_nm) for r in robots]
        fgraph = FormationGraph.from_scenario(scenario)
        self.nodes = [_RobotNode(scenario, r, fgraph, sensing) for r in robots]
        self.coord = _Coordinator(scenario, sensing)
        self.camera = _Camera(len(robots), sensing, dt_s)
        # per robot: (body radius, team, d, slot) and its S8.3 goal source (nodes/controller.py
        # tables)
        self.info = {
            r.id: (
                r.params.body_radius_m,
                scenario.team_leader(r.id),
                r.params.com_offset_m,
                scenario.slot(r.id),
            )
            for r in robots
        }
        self.goal_source = {}
        for r in robots:
            p0 = fgraph.original_parent.get(r.id)
            self.goal_source[r.id] = (
                (fast_reference(r.path), None, None)
                if p0 is None
                else (None, p0, tuple(float(v) for v in fgraph.offset(r.id, p0)))
            )
        self.torque = np.zeros((len(robots), 2))  # sorted-id rows, held between periods
        self.saturated = np.zeros(len(robots), dtype=bool)
        self.modes = {
            rid: {'mode': 'coordination', 'target': None, 'direction': None, 'avoiding': False}
            for rid in self.ids
        }
        # id -> (state, accel, stamp_s, threat mode, threat target, sense in a mutual pair)
        self.pub: dict = {}
        self.mode_events: list[dict] = []
        self.graph_events: list[dict] = [
            {'t_s': 0.0, 'parents': _parents_json(self.coord.parents)}
        ]
        self.err_sq = 0.0
        self.err_max = 0.0
        self.err_n = 0
        self._apply_parents(self.coord.parents)
        # hearing (ControllerNode._needed): range [m] of robot k seen by robot i, who is in range
        av = scenario.avoidance
        rb = np.array([r.params.body_radius_m for r in robots])
        self.hear_all = sensing.hear_all
        self.reach = (
            av.protected_scale * (rb[:, None] + rb[None, :] + av.agent_keepout_margin_m)
            + sensing.hear_margin_m
        )
        self.in_range = np.zeros((len(robots), len(robots)), dtype=bool)
        self.own_xy: np.ndarray | None = None  # own positions of the last period [m]

    def _apply_parents(self, parents: dict) -> None:
        offsets = self.coord.graph.offsets(parents)
        for node in self.nodes:
            node.apply_graph(parents.get(node.rid), offsets.get(node.rid, (0.0, 0.0)))

    def true_pose(self) -> np.ndarray:
        return self.twin.state[self.rows, :3]

    def prestart(self, fps: float) -> None:
        """The estimators fuse frames of the robots at rest before the mission starts (the
        coordinator starts it ``start_delay_s`` after every controller is up).
        """
        pose = self.true_pose()
        for j in range(PRESTART_FRAMES):
            stamp = (j - PRESTART_FRAMES) / fps
            for node in self.nodes:
                node.est.wheel_update(stamp, (0.0, 0.0), (0.0, 0.0))
            self.camera.capture(stamp, pose)
            self.camera.deliver(math.inf, [n.est for n in self.nodes])
        self.camera.frames = self.camera.sent = self.camera.dropped = 0  # mission frames only
        for node in self.nodes:
            self.pub[node.rid] = (node.est.state(), np.zeros(2), 0.0, 'coordination', None, None)

    def heard(self, t_s: float) -> dict:
        """{id: NeighbourState} of every robot's last broadcast, as a controller reads it."""
        known = {}
        for rid, (state, accel, stamp, *_mode) in self.pub.items():
            d = self.info[rid][2]
            known[rid] = extrapolate_neighbour(
                state, accel, t_s - stamp, d, PARENT_TIMEOUT_S, PARENT_HOLD_S
            )
        heard = {}
        for rid, (_s, accel, _st, mode, target, sense) in self.pub.items():
            path, p0, offset = self.goal_source[rid]
            d0 = 0.0 if p0 is None else self.info[p0][2]
            goal, goal_dot = neighbour_goal(t_s, path, known.get(p0), offset, d0)
            radius, team, d, slot = self.info[rid]
            heard[rid] = NeighbourState.trusted(
                known[rid], accel, radius, team, mode, target, d, goal, goal_dot, slot, sense
            )
        return heard

    def tick(self, t_s: float, arbitrate: bool) -> None:
        """One control period of every robot, then the coordinator."""
        tw = self.twin
        q = tw.wheel_angle_rad[self.rows].tolist()
        w = tw.wheel_rate_radps[self.rows].tolist()
        for i, node in enumerate(self.nodes):  # the encoder sample of this period, then ...
            node.est.wheel_update(t_s, tuple(q[i]), tuple(w[i]))
        frames = self.camera.deliver(t_s, [n.est for n in self.nodes])  # ... the frames by now
        self._update_hearing(frames)
        truth = tw.state[self.rows, :2].tolist()
        heard = self.heard(t_s)
        pub = {}
        own_xy = np.zeros((len(self.nodes), 2))
        for i, node in enumerate(self.nodes):
            state = node.est.state_at(t_s)
            own_xy[i] = state[:2]
            e = math.hypot(state[0] - truth[i][0], state[1] - truth[i][1])
            self.err_sq += e * e
            self.err_max = max(self.err_max, e)
            self.err_n += 1
            out = node.step(t_s, state, self._heard_by(i, heard))
            lim = self.tau_max[i]  # DESIGN §7: clamped in the controller (non-finite -> 0)
            left, right = out.torque_nm.tolist()
            left = min(max(left if math.isfinite(left) else 0.0, -lim), lim)
            right = min(max(right if math.isfinite(right) else 0.0, -lim), lim)
            self.torque[i] = (left, right)
            self.saturated[i] = out.saturated
            self.mode_events.extend(out.events)
            mode, target = _threat_mode(out.mode, out.target)
            sense = out.direction if mode == 'mutual' else None
            pub[node.rid] = (state, out.accel_cmd_mps2, t_s, mode, target, sense)
            self.modes[node.rid] = {
                'mode': out.mode,
                'target': out.target,
                'direction': out.direction,
                'avoiding': out.mode != 'coordination',
            }
        self.pub = pub
        self.own_xy = own_xy
        parents_before = self.coord.parents
        new_parents = self.coord.on_modes(self.modes)
        if new_parents is not None:
            self._apply_parents(new_parents)
            if new_parents != parents_before:
                self.graph_events.append(
                    {'t_s': round(t_s, 9), 'parents': _parents_json(new_parents)}
                )
        if arbitrate:
            states = {rid: p[0] for rid, p in pub.items()}
            published = self.coord.arbitrate(t_s, states, self.modes)
            if published is not None:
                for node in self.nodes:
                    node.assigned.assignment = published.get(node.rid)
                    node.encounters_at = t_s

    def _update_hearing(self, frames: list) -> None:
        """The range gate of every controller on the camera poses just delivered."""
        if self.hear_all or self.own_xy is None:
            return
        for pose, kept in frames:
            d = np.hypot(
                pose[None, :, 0] - self.own_xy[:, 0:1], pose[None, :, 1] - self.own_xy[:, 1:2]
            )
            near = (d < self.reach) | (self.in_range & (d < self.reach + HEAR_HYSTERESIS_M))
            self.in_range = np.where(kept[None, :], near, self.in_range)

    def _heard_by(self, i: int, heard: dict) -> dict:
        """The broadcasts robot row ``i`` hears: every robot with ``hear_all``, else its parents,
        its assignment's partner and the robots in range (ControllerNode._needed).
        """
        if self.hear_all:
            return heard
        node = self.nodes[i]
        partner = None if node.assigned.assignment is None else node.assigned.assignment.partner
        keep = {node.parent, node.orig_parent_id, partner}
        in_range = self.in_range[i]
        row = self.row
        return {
            rid: nb
            for rid, nb in heard.items()
            if rid in keep or (rid != node.rid and in_range[row[rid]])
        }

    def estimator_counters(self) -> dict:
        total: dict = {}
        for node in self.nodes:
            for k, v in node.est.counters.as_dict().items():
                total[k] = total.get(k, 0) + v
        return total


def _parents_json(parents: dict) -> dict:
    return {str(c): (None if p is None else int(p)) for c, p in sorted(parents.items())}


def _schedule(duration_s: float, dt_s: float, ctrl_every: int, rec_every: int, fps: float):
    """(n_steps, event steps (sorted), capture steps (set)) of a run."""
    n_steps = int(round(duration_s / dt_s))
    n_frames = int(math.ceil(duration_s * fps - 1e-9))
    cap = np.unique(np.round(np.arange(n_frames) / fps / dt_s).astype(np.int64))
    cap = cap[cap < n_steps]
    steps = np.unique(
        np.concatenate([np.arange(0, n_steps, ctrl_every), np.arange(0, n_steps, rec_every), cap])
    )
    return n_steps, steps.tolist(), set(cap.tolist())


def _true_goals(scenario, ids: tuple, t_s: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(T, N, 2) formation goals g_i of the TRUE states (leader: r(t); follower: p of its
    original parent + delta), as ``simulate`` records them.
    """
    graph = FormationGraph.from_scenario(scenario)
    row = {rid: i for i, rid in enumerate(ids)}
    goal = np.zeros((len(t_s), len(ids), 2))
    for i, rid in enumerate(ids):
        spec = scenario.robot(rid)
        p0 = graph.original_parent.get(rid)
        if p0 is None:
            goal[:, i] = np.asarray(spec.path.reference(t_s)[0], dtype=float).reshape(-1, 2)
        else:
            goal[:, i] = state[:, row[p0], :2] + graph.offset(rid, p0)
    return goal


def simulate_sensed(
    scenario,
    sensing: SensingParams,
    dt_s: float = 0.001,
    record_every_s: float = 0.01,
    progress: Callable[[float, float], None] | None = None,
) -> SensedResult:
    """Run ``scenario`` with camera sensing, the S10 estimators, the law at its control period
    and the coordinator (module docstring); return the TRUE record.

    Parameters
    ----------
    scenario : :class:`ament_formation.core.scenario.loader.Scenario`.
    sensing : :class:`SensingParams` (e.g. ``SensingParams.preset('camera')``).
    dt_s : plant integration step [s] (RK4, torque held between control periods); the control
        period 1 / ``sensing.control_rate_hz`` is rounded to a whole number of steps.
    record_every_s : sampling period of the record [s] (rounded to a multiple of ``dt_s``).
    progress : callable(t_s, duration_s) called about every 5 s of simulated time, or None.
    """
    wall0 = time.perf_counter()
    if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0 < dt_s <= 0.01):
        raise ValueError(f'dt_s: must be a finite number in (0, 0.01] s (got {dt_s!r})')
    fps = sensing.frame_rate_hz(scenario)
    ctrl_every = max(1, int(round(1.0 / (sensing.control_rate_hz * dt_s))))
    rec_every = max(1, int(round(record_every_s / dt_s)))
    arb_every = (
        0
        if sensing.encounter_rate_hz <= 0
        else max(1, int(round(1.0 / (sensing.encounter_rate_hz * dt_s))))
    )
    n_steps, steps, captures = _schedule(scenario.duration_s, dt_s, ctrl_every, rec_every, fps)
    loop = _Loop(scenario, sensing, dt_s)
    loop.prestart(fps)
    loop.twin.start()
    n, m = len(loop.ids), len(scenario.obstacles)
    n_rec = (n_steps - 1) // rec_every + 1
    rec_state = np.zeros((n_rec, n, 5))
    rec_torque = np.zeros((n_rec, n, 2))
    rec_avoid = np.zeros((n_rec, n), dtype=bool)
    rec_sat = np.zeros((n_rec, n), dtype=bool)
    rec_oc = np.zeros((n_rec, m, 2))
    rec_ophi = np.zeros((n_rec, m))
    tw, rows = loop.twin, loop.rows
    inv = np.argsort(rows)  # twin rows -> sorted-id rows
    cur = 0
    next_progress = 5.0
    for s in steps:
        if s > cur:
            tw.advance((s - cur) * dt_s, loop.torque[inv])
            cur = s
        t = s * dt_s
        if s in captures:
            loop.camera.capture(t, loop.true_pose())
        if s % ctrl_every == 0:
            loop.tick(t, arb_every > 0 and s % arb_every == 0)
        if s % rec_every == 0:
            r = s // rec_every
            rec_state[r] = tw.state[rows]
            rec_torque[r] = loop.torque
            rec_avoid[r] = [md['avoiding'] for md in loop.modes.values()]
            rec_sat[r] = loop.saturated
            if m:
                obs = tw.obstacle_states()
                rec_oc[r] = obs.center_m
                rec_ophi[r] = obs.phi_rad
        if progress is not None and t >= next_progress:
            progress(t, scenario.duration_s)
            next_progress += 5.0
    if n_steps > cur:
        tw.advance((n_steps - cur) * dt_s, loop.torque[inv])
    if progress is not None:
        progress(n_steps * dt_s, scenario.duration_s)
    t_rec = np.arange(n_rec) * rec_every * dt_s
    cam = loop.camera
    return SensedResult(
        scenario_name=scenario.name,
        robot_ids=loop.ids,
        obstacle_names=tuple(o.name for o in scenario.obstacles),
        t_s=t_rec,
        state=rec_state,
        torque_nm=rec_torque,
        goal_m=_true_goals(scenario, loop.ids, t_rec, rec_state),
        avoiding=rec_avoid,
        saturated=rec_sat,
        obstacle_center_m=rec_oc,
        obstacle_phi_rad=rec_ophi,
        mode_events=loop.mode_events,
        graph_events=loop.graph_events,
        reaching=[],
        dt_s=dt_s,
        wall_time_s=time.perf_counter() - wall0,
        sensing={
            'params': sensing.as_dict(scenario),
            'prestart_frames': PRESTART_FRAMES,
            'frames': cam.frames,
            'poses_sent': cam.sent,
            'poses_dropped': cam.dropped,
            'estimator': loop.estimator_counters(),
            'estimate_error_m': {
                'rms': math.sqrt(loop.err_sq / max(1, loop.err_n)),
                'max': loop.err_max,
            },
        },
    )
