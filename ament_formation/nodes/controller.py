"""formation_controller: one robot's on-board controller (namespace robot_<id>).

The node wires the robot agent (core/control/agent.py: estimator, stops, the robots it hears,
its switching and the law, docs/control-law.md S10.3) to its topics and times its control period;
every computation is the agent's. Remote stamps are put on this machine's clock with the offsets
estimated from them (core/clock.py); an offset beyond its bound stops the robot
(``stopped_clock``). A robot that hears no coordinator for ``coordinator_timeout_s`` stops
(``stopped_coordinator``): the coordinator owns its robot encounters (S7.1).

Topics (namespace robot_<id>; QoS from ros/qos.py)
  sub  pose                    geometry_msgs/PoseStamped (camera, stamp = capture)  QOS_CONTROL
  sub  wheel_state             sensor_msgs/JointState (wheel angles, rates)        QOS_CONTROL
                               (in a team: straight from the hosted bridge)
  sub  /formation/graph        std_msgs/String JSON graph/v1 (parents, start_s)    QOS_GRAPH
  sub  /formation/encounters   std_msgs/String JSON encounters/v2                  QOS_GRAPH
  sub  /robot_<k>/mode, pose   every other robot: its report; its camera pose (hearing range)
  sub  /robot_<k>/state, accel the robots it needs (S10.2: parents, partner, in range)
  pub  wheel_torque            JointState effort [l, r] N m (none without wheel data) QOS_CONTROL
  pub  state, accel            nav_msgs/Odometry, geometry_msgs/AccelStamped (while heard)
  pub  mode                    std_msgs/String JSON mode/v1 (on change and every second)
  pub  /diagnostics            "formation_controller: robot_<id> control" (status and why,
                               clock offsets), "... control loop" (stalls), "... inputs"

Parameters: those of :class:`~ament_formation.core.control.agent.AgentParams` (units in their
descriptions) and ``scenario``, ``robot_id``, ``realtime_priority``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
import math
import sys
import time

from geometry_msgs.msg import AccelStamped, PoseStamped
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ament_formation.core.clock import ClockOffsets
from ament_formation.core.control.agent import AgentBatch, AgentParams, STOPPED_CLOCK
from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.ros import cdr
from ament_formation.ros import diagnostics as diag
from ament_formation.ros import messages as msgs
from ament_formation.ros.executors import run_node, set_realtime
from ament_formation.ros.listeners import Listeners
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH
from ament_formation.ros.tick_inputs import served_by_executor, take_waiting, TakenAtTick

WHY = {
    'waiting': 'no camera pose, graph or mission start yet (is the camera PC up: tracker and '
    'coordinator, same ROS_DOMAIN_ID?)',
    'hold_parent': "the parent's state is lost: holding",
    'stopped_wheels': 'no wheel data: no command, the board brakes (is the bridge up?)',
    'stopped_pose': 'no camera pose for pose_timeout_s: controlled stop',
    'stopped_coordinator': 'no message from the coordinator for coordinator_timeout_s: '
    'controlled stop (is formation_coordinator running, is the network up?)',
    'stopped_clock': "a machine's clock is off by more than the bound: synchronise the clocks "
    '(docs/lab.md, Clocks)',
}


@dataclass(frozen=True)
class ControllerParams(AgentParams):
    scenario: str = param('', 'scenario YAML path (required)')
    robot_id: int = param(-1, "this robot's id in the scenario (required, >= 0)")
    realtime_priority: int = param(0, 'SCHED_FIFO priority of the control loop (1..98; 0: normal '
                                   'scheduling; needs root or CAP_SYS_NICE)', range=(0, 98))
    tick_on_pose: bool = param(
        False, "run the control period as soon as this robot's camera pose arrives, then every "
        '1/control_rate_hz from there (false: the timer alone, a pose waits up to a period; off '
        'by default: measured, it did not shorten the pose-to-torque p99, docs/executors.md)')

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        if not (isinstance(self.robot_id, int) and self.robot_id >= 0):
            raise ConfigError(f'is required: an integer >= 0 (got {self.robot_id!r})', 'robot_id')
        if not (isinstance(self.realtime_priority, int) and 0 <= self.realtime_priority <= 98):
            raise ConfigError(f'must be an integer in [0, 98] (got {self.realtime_priority!r})',
                              'realtime_priority')
        super().__post_init__()


class ControllerNode(Node):
    """See the module docstring. In a team (nodes/team.py) the agents of every hosted robot are
    one ``batch`` the team ticks; this node then only wires robot ``robot_id``'s topics.
    """

    def __init__(self, *, context=None, params: ControllerParams | None = None,
                 tick_timer: bool = True, batch: AgentBatch | None = None, bridge=None,
                 lock=None, tick_inputs: bool = False, **node_kw):
        self._tick_inputs = tick_inputs
        super().__init__('formation_controller', context=context, **node_kw)
        self.lock = lock if lock is not None else contextlib.nullcontext()
        self.prm = params if params is not None else declare_dataclass(self, ControllerParams)
        self.scenario = batch.scenario if batch is not None else load_scenario(self.prm.scenario)
        self.rid = self.prm.robot_id
        if self.rid not in self.scenario.robot_ids:
            raise ConfigError(f'{self.rid} is not a robot of {self.scenario.name} '
                              f'(ids {list(self.scenario.robot_ids)})', 'robot_id')
        self.batch = batch or AgentBatch(self.scenario, [self.rid], AgentParams.of(self.prm))
        self.r = self.batch.hosted.index(self.rid)
        self.clocks = ClockOffsets()
        self.graph: msgs.GraphMessage | None = None
        self.encounter_revision = -1
        self.events: list[dict] = []
        self.ticks = self.late_ticks = 0
        self._last_tick_wall: float | None = None
        self._mode_sent, self._last_mode_pub = None, -math.inf
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self._now_ns = diag.clock_ns(self)
        self.rejections = diag.Rejections(('pose', 'wheel', 'robots', 'graph', 'encounters'),
                                          self.now_s)
        self.rejected = self.rejections.counts
        self.pub_torque = self.create_publisher(JointState, 'wheel_torque', QOS_CONTROL)
        self.pub_state = self.create_publisher(msgs.Odometry, 'state', QOS_CONTROL)
        self.pub_accel = self.create_publisher(AccelStamped, 'accel', QOS_CONTROL)
        self.pub_mode = self.create_publisher(String, 'mode', QOS_CONTROL)
        self._heard = {'state': Listeners(self.pub_state), 'torque': Listeners(self.pub_torque),
                       'accel': Listeners(self.pub_accel)}
        self._msgs = {'state': None, 'torque': None, 'accel': None}
        self.create_subscription(PoseStamped, 'pose', self._on_pose, QOS_CONTROL, raw=True)
        self.bridge = bridge
        if bridge is None:
            self.create_subscription(JointState, 'wheel_state', self._on_wheels, QOS_CONTROL)
        else:
            bridge.telemetry_sinks.append(self.wheel_sample)
        self.create_subscription(String, '/formation/graph', self._on_graph, QOS_GRAPH)
        self.create_subscription(String, '/formation/encounters', self._on_encounters, QOS_GRAPH)
        self._full: dict[int, list] = {}  # robot id -> its state and accel subscriptions
        self._accel: dict[int, np.ndarray] = {}  # robot id -> its latest commanded accel
        hosted = set(self.batch.hosted)
        for k in self.scenario.robot_ids:
            if k in hosted:
                continue  # a robot of this process: heard in process (AgentBatch.share)
            self.create_subscription(String, f'/robot_{k}/mode',
                                     lambda msg, k=k: self._on_mode(k, msg), QOS_CONTROL)
            self.create_subscription(PoseStamped, f'/robot_{k}/pose',
                                     lambda msg, k=k: self._on_camera(k, msg), QOS_CONTROL,
                                     raw=True)
        self.diag = diag.Diagnostics(self)
        robot = f'robot_{self.rid}'
        self.diag.add(f'{robot} control', self._control_status, hardware_id=robot)
        self.control_watch = self.diag.watch(
            f'{robot} control loop', 1.0 / self.prm.control_rate_hz, hardware_id=robot)
        self.diag.add(f'{robot} inputs', self.rejections.status, hardware_id=robot)
        self._last_status = None
        self.hearing_check = self.create_timer(0.1, self.update_hearing)
        self.timer = (self.create_timer(1.0 / self.prm.control_rate_hz, self.control_tick)
                      if tick_timer else None)
        if tick_timer and self.prm.realtime_priority:
            set_realtime(self.prm.realtime_priority, self.get_logger())
        # a pose is used the moment it arrives (not when the inputs are taken at the tick: the tick
        # would run inside its own input pass); in a team of one robot, the team's loop runs it
        self._tick_on_pose = bool(self.timer and self.prm.tick_on_pose and not tick_inputs)
        self.on_own_pose = None  # set by nodes/team.py

    @property
    def subscriptions(self):
        """What an executor serves: every subscription but those taken at each period."""
        return served_by_executor(super().subscriptions)

    def take_inputs(self) -> None:
        """The messages taken at each period (``tick_inputs``): what arrived since the last."""
        take_waiting(list(super().subscriptions))

    def now_s(self) -> float:
        return self._now_ns() * 1e-9

    # ------------------------------------------------------------------ inputs
    def _on_pose(self, msg) -> None:
        pose, stamp_s = cdr.pose_from_msg(msg)
        now = self.now_s()
        self.clocks.observe('camera', stamp_s, now)
        if not np.all(np.isfinite(pose)):
            self.rejected['pose'] += 1
            return
        with self.lock:
            self.batch.camera(self.rid, self.clocks.local('camera', stamp_s), pose)
        if self._tick_on_pose:
            self.control_tick()
            self.timer.reset()  # the next period a full period from this one: no double tick
        elif self.on_own_pose is not None:
            self.on_own_pose()

    def _on_camera(self, k: int, msg) -> None:
        pose, _stamp = cdr.pose_from_msg(msg)
        with self.lock:
            self.batch.camera(k, 0.0, pose)  # another robot's pose: hearing range only

    def _on_wheels(self, msg: JointState) -> None:
        try:
            q, qd, stamp_s = msgs.wheel_state_from_msg(msg)
        except ValueError:
            self.rejected['wheel'] += 1
            return
        self.wheel_sample(q, qd, stamp_s)

    def wheel_sample(self, q, qd, stamp_s: float) -> None:
        """One encoder sample (angles [rad], rates [rad/s]) from this robot's own board."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and math.isfinite(stamp_s)):
            self.rejected['wheel'] += 1
            return
        with self.lock:
            self.batch.wheel(self.rid, stamp_s, q, qd)

    def _on_graph(self, msg: String) -> None:
        try:
            graph = msgs.graph_from_msg(msg)
        except ValueError:
            self.rejected['graph'] += 1
            self.diag.changed()
            return
        if self.graph is not None and graph.revision < self.graph.revision:
            return
        self.graph = graph
        self.clocks.observe_latched('graph', 'coordinator', graph.stamp_s, self.now_s())
        start = None if graph.start_s is None else self.clocks.local('coordinator', graph.start_s)
        with self.lock:
            self.batch.set_graph(graph.parents, start)

    def _on_encounters(self, msg: String) -> None:
        try:
            m = msgs.encounters_from_msg(msg)
        except ValueError:
            self.rejected['encounters'] += 1
            self.diag.changed()
            return
        if m.revision < self.encounter_revision:
            return
        self.encounter_revision = m.revision
        now = self.now_s()
        self.clocks.observe_latched('encounters', 'coordinator', m.stamp_s, now)
        with self.lock:
            self.batch.assign(now, m.assignments, m.rates)

    def _on_mode(self, k: int, msg: String) -> None:
        try:
            mode = msgs.mode_from_msg(msg)
        except ValueError:
            self.rejected['robots'] += 1
            return
        with self.lock:
            self.batch.hear_mode(k, mode)

    def _on_state(self, k: int, msg) -> None:
        state, stamp_s = cdr.finite_state_from_odometry(msg)
        if state is None:
            self.rejected['robots'] += 1
            return
        source = f'robot_{k}'
        self.clocks.observe(source, stamp_s, self.now_s())
        with self.lock:
            self.batch.hear(k, state, self._accel.get(k, np.zeros(2)),
                            self.clocks.local(source, stamp_s))

    def _on_accel(self, k: int, msg) -> None:
        accel, _ = cdr.finite_accel_from_msg(msg)
        if accel is None:
            self.rejected['robots'] += 1
            return
        self._accel[k] = accel

    def update_hearing(self) -> None:
        """Subscribe the state and accel of the robots the agent needs (S10.2), drop the
        others.
        """
        need = set(self.batch.needed(self.rid)) - set(self.batch.hosted)
        for k in need - set(self._full):
            wrap = TakenAtTick if self._tick_inputs else (lambda f: f)
            self._full[k] = [
                self.create_subscription(msgs.Odometry, f'/robot_{k}/state',
                                         wrap(lambda m, k=k: self._on_state(k, m)), QOS_CONTROL,
                                         raw=True),
                self.create_subscription(AccelStamped, f'/robot_{k}/accel',
                                         wrap(lambda m, k=k: self._on_accel(k, m)), QOS_CONTROL,
                                         raw=True)]
        for k in set(self._full) - need:
            with self.lock:
                for sub in self._full.pop(k):
                    self.destroy_subscription(sub)

    # ------------------------------------------------------------------ the period
    def control_tick(self, now_s: float | None = None) -> None:
        """One control period of this robot's own agent (not in a team: the team ticks)."""
        now = self.now_s() if now_s is None else now_s
        self._check_clocks()
        with self.lock:
            self.batch.tick(now)
        self.publish(now)

    def _check_clocks(self) -> None:
        bad = self.clocks.beyond_bound()
        halt = 0 if bad is None else STOPPED_CLOCK
        if halt and self.batch.state.halt[self.r] != halt:
            self.get_logger().error(
                f'the clock of {bad[0]} is {bad[1]:+.3f} s off ours, beyond the bound of '
                f'{self.clocks.p.bound_s:g} s: controlled stop; synchronise the clocks '
                '(docs/lab.md, Clocks)')
        self.batch.state.halt[self.r] = halt
        for src, off in self.clocks.newly_beyond_bound():
            self.get_logger().warning(
                f"{src}'s clock is {off:+.3f} s off ours and the base's: its stamps are "
                'compensated and it stops itself (docs/lab.md, Clocks)')

    def publish(self, now: float) -> None:
        """What this robot's agent made of the period: torque, state, accel, mode, events."""
        self.control_watch.tick(int(now * 1e9))
        wall = time.monotonic()
        if self._last_tick_wall is not None and not self._sim_time and (
                wall - self._last_tick_wall > 1.5 / self.prm.control_rate_hz):
            self.late_ticks += 1  # a missed control deadline
        self._last_tick_wall = wall
        self.ticks += 1
        b, r = self.batch, self.r
        torque = b.out.torque[r]
        stamp = msgs.stamp_from_s(now)
        # no wheel data: no command; the bridge's timeout brakes (docs/safety.md, No wheel data)
        commanding = b.status(r) != 'stopped_wheels'
        if commanding and (self.bridge is None or self._heard['torque']()):
            self._msgs['torque'] = msgs.wheel_torque(torque, stamp, out=self._msgs['torque'])
            self.pub_torque.publish(self._msgs['torque'])
        if commanding and self.bridge is not None:
            self.bridge.command((float(torque[0]), float(torque[1])))
        due = (self.ticks - 1) % self.prm.state_every == 0  # state_rate_hz
        if due and b.initialized(r) and self._heard['state']():
            self._msgs['state'] = msgs.odometry(b.out.state[r], stamp, f'robot_{self.rid}',
                                                out=self._msgs['state'])
            self.pub_state.publish(self._msgs['state'])
        if due and self._heard['accel']():
            self._msgs['accel'] = msgs.accel_stamped(b.out.accel[r], stamp,
                                                     out=self._msgs['accel'])
            self.pub_accel.publish(self._msgs['accel'])
        self.events.extend(e for e in b.events if e['robot'] == self.rid)
        mode = b.mode_dict(r)
        key = tuple(sorted(mode.items()))
        if key != self._mode_sent or now - self._last_mode_pub >= 1.0:
            self.pub_mode.publish(msgs.mode_msg(**mode))
            self._mode_sent, self._last_mode_pub = key, now
        status = b.status(r)
        if status != self._last_status:
            text = f'safety: {self._last_status} -> {status}' + (
                '' if status == 'running' else f' ({WHY[status]})')
            if status in ('running', 'waiting'):
                self.get_logger().info(text)
            else:
                self.get_logger().warn(text)
            self._last_status = status
            self.diag.changed()

    @property
    def safety(self) -> str:
        return self.batch.status(self.r)

    @property
    def mode(self) -> dict:
        return self.batch.mode_dict(self.r)

    def coordinated(self, now_s: float | None = None) -> bool:
        """The coordinator is heard: its last message arrived within ``coordinator_timeout_s``
        (then it decides this robot's robot encounters, S7.1; diagnostics ``coordinator_heard``).
        """
        now = self.now_s() if now_s is None else now_s
        return bool(now - self.batch.state.coord_s[self.r] <= self.prm.coordinator_timeout_s)

    def _control_status(self) -> tuple[int, str, dict]:
        b, r, now = self.batch, self.r, self.now_s()
        status = b.status(r)
        values = {'ticks': self.ticks, 'late_ticks': self.late_ticks, 'safety': status,
                  'mode': b.mode_dict(r)['mode'], 'coordinator_heard': self.coordinated(now),
                  'camera_age_s': round(b.camera_age_s(r, now), 3),
                  **{f'rejected_{k}': v for k, v in self.rejected.items()},
                  **b.counters(r), **self.clocks.report()}
        level = (diag.OK if status in ('running', 'waiting') else
                 diag.WARN if status == 'hold_parent' else diag.ERROR)
        return level, status if status == 'running' else f'{status}: {WHY[status]}', values


def _send_zero_torque(node: ControllerNode) -> None:
    """Last word of the process: zero torque on ``wheel_torque`` and to a hosted bridge."""
    try:
        node.pub_torque.publish(msgs.wheel_torque(np.zeros(2), msgs.stamp_from_s(node.now_s())))
    finally:
        if node.bridge is not None:
            node.bridge.command((0.0, 0.0))


def main(args: list[str] | None = None) -> int:
    return run_node('formation_controller', ControllerNode, args, on_exit=_send_zero_torque)


if __name__ == '__main__':
    sys.exit(main())
