"""formation_controller: one robot's sliding-mode formation controller (namespace robot_<id>).

Every control period (100 Hz): the pose estimate (core/control/estimator.py, spec S10: wheel
odometry
between camera frames, each latency-compensated camera pose corrects it) feeds the robot's
switching automaton and sliding-mode law (core/control/controller.py RobotController: the same
compiled
functions as the simulator); the torque goes to the bridge. The node hears every robot of the
scenario (``state``, ``accel``, ``mode``): the current parent is the one of ``/formation/graph``
(S4 field with feed-forward), the original parent gives the S8.3 exit goal, and every robot is a
possible robot-robot threat (S7). The coordinator's assignment for this robot on
``/formation/encounters`` overrides the robot's own robot-robot decision; it is applied once per
decision (same mode, partner, t_entry_s). The robot leaves it with its own S8.3 exit test, or when
the coordinator withdraws it (the coordinator's joint exit decision, S8.3: mutual pairs exit
together; RobotController ``release``, never inside the partner's emergency circle). Every other
robot's S8.3 goal is derived from the scenario (leader: r(t); follower: its original parent's
point + slot offset), so the robot's own exit test sees the partner's goal too.
While the coordinator is heard (``coordinator_timeout_s``) the robot enters a robot encounter by
its own decision only in an emergency (docs/law-changes.md §23); without the coordinator it
arbitrates robot encounters itself with the same rules.
Safety (DESIGN §7): no pose for ``pose_timeout_s`` -> at rest by then (+ one control period): the
controlled stop begins when the camera age exceeds ``pose_timeout_s`` minus the time to rest from
the current speed under the stop law plus ``stop_margin_s`` (StopLead, docs/safety.md §7); no
wheel data for ``wheel_timeout_s`` -> zero torque (nothing to brake with); a parent silent for
``parent_timeout_s`` is extrapolated with its commanded acceleration, after ``parent_hold_s`` the
robot holds (brakes); NaN/inf inputs are rejected and counted; torques are clamped to the limit.
Before the mission start (``start_s`` of the graph) the robot stands still (zero torque).

Topics (namespace robot_<id>; QoS from ros/qos.py)
  sub  pose                     geometry_msgs/PoseStamped (camera, stamp = capture time)
  QOS_CONTROL
  sub  wheel_state              sensor_msgs/JointState (wheel angles rad, rates rad/s)
  QOS_CONTROL
                                (in a team: samples straight from the hosted bridge instead)
  sub  /formation/graph         std_msgs/String JSON (parents, offsets_m, start_s)
  QOS_GRAPH
  sub  /formation/encounters    std_msgs/String JSON {revision, assignments: {id: {mode,
                                partner, direction, t_entry_s, drift_mps}}} (S7)
                                QOS_GRAPH
  sub  /robot_<k>/state         nav_msgs/Odometry, every other robot k of the scenario
  QOS_CONTROL
  sub  /robot_<k>/accel         geometry_msgs/AccelStamped, every other robot k
  QOS_CONTROL
  sub  /robot_<k>/mode          std_msgs/String JSON, every other robot k (S7 acyclicity)
  QOS_CONTROL
  pub  wheel_torque             sensor_msgs/JointState effort [left, right] N m
  QOS_CONTROL
                                (in a team: handed to the hosted bridge, published while
                                subscribed)
  pub  state                    nav_msgs/Odometry (fused pose; twist v, omega)
  QOS_CONTROL
                                (while anyone subscribes)
  pub  accel                    geometry_msgs/AccelStamped (commanded point accel, S4)
  QOS_CONTROL
                                (while anyone subscribes)
  pub  mode                     std_msgs/String JSON {mode, target, direction, avoiding}
  QOS_CONTROL
                                (on change and every second)
  pub  /diagnostics             diagnostic_msgs/DiagnosticArray (docs/diagnostics.md), every
                                second and at once on a change: "formation_controller: robot_<id>
                                control" (safety state: running/waiting OK, hold_parent WARN,
                                stopped_* ERROR; ticks, late ticks, estimator counters),
                                "... robot_<id> control loop" (stalls of the control period, WARN),
                                "... robot_<id> inputs" (rejected inputs and payloads, WARN for 10
                                s
                                after one)
                                QOS_DIAGNOSTICS

Parameters
  scenario          str    scenario YAML (required)
  robot_id          int    this robot's id (required, >= 0)
  control_rate_hz   float  control loop rate [Hz]                                   default 100
  pose_timeout_s    float  no camera pose this long -> controlled stop [s]          default 0.5
  wheel_timeout_s   float  no wheel_state this long -> controlled stop [s]          default 0.1
  parent_timeout_s  float  parent (or other robot) state older than this is extrapolated [s]
  default 0.1
  parent_hold_s     float  parent state older than this -> hold; other robots older than
                           this are ignored [s]                                      default 1.0
  stop_time_s       float  time constant of the controlled stop [s]                 default 0.3
  stop_speed_max_mps float fastest |v| from which a camera loss ends at rest by pose_timeout_s
                           [m/s]                                                     default 0.15
  stop_turn_rate_max_radps float  fastest |omega| likewise [rad/s]                  default 2.5
  stop_decel_mps2   float  switching gain of the camera-loss stop on v [m/s^2]      default 0.8
  stop_margin_s     float  added to the time to rest in the camera-loss stop lead [s] default 0.03
  camera_gain       float  S10 complementary gain per camera frame, (0, 1]          default 0.5
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

from ament_formation.core.control.assignment import (
    AssignedLaw,
    original_parent_link,
    original_parent_state,
)
from ament_formation.core.control.controller import NeighbourState, RobotController
from ament_formation.core.control.estimator import EstimatorParams, PoseEstimator
from ament_formation.core.control.neighbours import extrapolate_neighbour, neighbour_goal
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.control.stop import stop_torque, StopLead
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import PlantCoeffs
from ament_formation.core.model.paths import fast_reference
from ament_formation.core.params import param
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.ros import cdr
from ament_formation.ros import diagnostics as diag
from ament_formation.ros import messages as msgs
from ament_formation.ros.executors import run_node
from ament_formation.ros.listeners import Listeners
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH
from ament_formation.ros.tick_inputs import served_by_executor, take_waiting, TakenAtTick

HEAR_HYSTERESIS_M = 0.3  # a robot stays heard until this much beyond the hearing range


@dataclass(frozen=True)
class ControllerParams:
    scenario: str = param('', 'scenario YAML path (required)')
    robot_id: int = param(-1, "this robot's id in the scenario (required, >= 0)")
    control_rate_hz: float = param(100.0, 'control loop rate [Hz]', range=(1.0, 2000.0))
    pose_timeout_s: float = param(
        0.5, 'no camera pose this long -> controlled stop [s]', range=(0.01, 10.0)
    )
    wheel_timeout_s: float = param(
        0.1, 'no wheel_state this long -> controlled stop [s]', range=(0.005, 10.0)
    )
    parent_timeout_s: float = param(
        0.1, 'older parent/other robot state is extrapolated [s]', range=(0.0, 10.0)
    )
    parent_hold_s: float = param(
        1.0,
        'older parent state -> hold; other robots ignored [s], >= parent_timeout_s',
        range=(0.0, 60.0),
    )
    stop_time_s: float = param(0.3, 'time constant of the controlled stop [s]', range=(0.01, 10.0))
    stop_speed_max_mps: float = param(
        0.15,
        'fastest |v| from which a camera loss ends at rest by pose_timeout_s (with '
        'stop_turn_rate_max_radps: the stop lead there must fit in pose_timeout_s) [m/s]',
        range=(0.001, 10.0),
    )
    stop_turn_rate_max_radps: float = param(
        2.5,
        'fastest |omega| from which a camera loss ends at rest by pose_timeout_s [rad/s]',
        range=(0.001, 100.0),
    )
    stop_decel_mps2: float = param(
        0.8,
        "switching gain of the camera-loss stop on v [m/s^2] (at least the formation law's "
        'K_p, at most what the torque limit allows within the stop speed bounds; boundary layer '
        '5 decel / control_rate_hz): a harder brake, a shorter stop lead',
        range=(0.0, 10.0),
    )
    stop_margin_s: float = param(
        0.03,
        'added to the time to rest of the camera-loss stop lead (command path to the wheels) [s]',
        range=(0.0, 1.0),
    )
    camera_gain: float = param(0.5, 'S10 complementary gain per camera frame, (0, 1]')
    hear_all: bool = param(
        False,
        "subscribe every robot's state and accel at full rate (off: only "
        'the parents and the robots within hearing range, S7)',
    )
    hear_margin_m: float = param(
        0.6,
        "hearing range beyond a robot's S7 region Q: full-rate state "
        'from a robot whose camera pose is closer than kappa R_aa + this [m]',
        range=(0.0, 100.0),
    )
    coordinator_timeout_s: float = param(
        2.5,
        'encounter assignments heard within this -> the robot enters robot encounters by itself '
        "in emergencies only (docs/law-changes.md section 23); above the coordinator's "
        'republish_s [s]',
        range=(0.0, 60.0),
    )
    realtime_priority: int = param(
        0,
        'SCHED_FIFO priority of the control loop (1..98; 0: normal '
        'scheduling; needs root or CAP_SYS_NICE)',
        range=(0, 98),
    )

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        if not (isinstance(self.robot_id, int) and self.robot_id >= 0):
            raise ConfigError(f'is required: an integer >= 0 (got {self.robot_id!r})', 'robot_id')
        for name, lo, hi in (
            ('control_rate_hz', 1.0, 2000.0),
            ('pose_timeout_s', 0.01, 10.0),
            ('wheel_timeout_s', 0.005, 10.0),
            ('parent_timeout_s', 0.0, 10.0),
            ('parent_hold_s', 0.0, 60.0),
            ('stop_time_s', 0.01, 10.0),
            ('stop_speed_max_mps', 0.001, 10.0),
            ('stop_turn_rate_max_radps', 0.001, 100.0),
            ('stop_decel_mps2', 0.0, 10.0),
            ('stop_margin_s', 0.0, 1.0),
            ('coordinator_timeout_s', 0.0, 60.0),
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ConfigError(f'must be in [{lo:g}, {hi:g}] (got {v!r})', name)
        if self.parent_hold_s < self.parent_timeout_s:
            raise ConfigError('must be >= parent_timeout_s', 'parent_hold_s')
        if not (
            isinstance(self.hear_margin_m, (int, float))
            and math.isfinite(self.hear_margin_m)
            and 0.0 <= self.hear_margin_m <= 100.0
        ):
            raise ConfigError(
                f'must be in [0, 100] m (got {self.hear_margin_m!r})', 'hear_margin_m'
            )
        if not (isinstance(self.realtime_priority, int) and 0 <= self.realtime_priority <= 98):
            raise ConfigError(
                f'must be an integer in [0, 98] (got {self.realtime_priority!r})',
                'realtime_priority',
            )


def _robot_tables(sc, fgraph: FormationGraph) -> tuple[dict, dict]:
    """(goal_source, robot_info) of every robot of scenario ``sc``, by id: its S8.3 goal source
    (leader: (path, None, None, 0.0); follower: (None, original parent, delta, parent's d),
    S8.3 item 1) and what the S7 tests need of it (body radius, team, d, slot c_k: §22).
    """
    goal_source, robot_info = {}, {}
    for r in sc.robots:
        p0 = fgraph.original_parent.get(r.id)
        goal_source[r.id] = (
            (fast_reference(r.path), None, None, 0.0)
            if p0 is None
            else (
                None,
                p0,
                tuple(float(v) for v in fgraph.offset(r.id, p0)),
                sc.robot(p0).params.com_offset_m,
            )
        )
        robot_info[r.id] = (
            r.params.body_radius_m,
            sc.team_leader(r.id),
            r.params.com_offset_m,
            sc.slot(r.id),
        )
    return goal_source, robot_info


def set_realtime(priority: int, logger=None) -> bool:
    """Put the calling thread under SCHED_FIFO ``priority`` (1..98), the scheduling a robot
    computer gives its control loop: it runs before every normal process as soon as it is ready
    (the kernel's real-time throttling, 95 % by default, still leaves the rest of the machine some
    time). False, with a warning, when not permitted (needs root or CAP_SYS_NICE).
    """
    import os

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
    except (OSError, AttributeError) as err:
        if logger is not None:
            logger.warn(
                f'realtime_priority {priority}: cannot use SCHED_FIFO ({err}); normal scheduling'
            )
        return False
    if logger is not None:
        logger.info(f'control loop under SCHED_FIFO priority {priority}')
    return True


def threat_mode(mode: dict) -> tuple[str, str | None]:
    """(mode, target) of another robot as its S7 acyclicity test reads it: an avoidance mode with
    its target, anything else (coordination, hold, stopped, ...) as coordination.
    """
    name, target = mode.get('mode'), mode.get('target')
    if name in ('obstacle', 'yield', 'mutual') and isinstance(target, str):
        return name, target
    return 'coordination', None


def pair_sense(mode: dict) -> str | None:
    """The sense (``ccw``/``cw``) of a robot in a mutual pair, else None (its ``mode`` dict)."""
    if mode.get('mode') == 'mutual' and mode.get('direction') in ('ccw', 'cw'):
        return mode['direction']
    return None


class _Neighbour:
    """Latest state/accel/mode of a robot: heard on its topics, or (PeerTable) written by its
    controller in the same process as it publishes them.
    """

    def __init__(self, rid: int):
        self.rid = rid
        self.state: np.ndarray | None = None
        self.accel = np.zeros(2)
        self.stamp_s = -math.inf
        self.mode = 'coordination'
        self.target: str | None = None
        self.direction: str | None = None  # its sense while in a mutual pair (§23)
        self.subs: list = []  # full-rate state + accel subscriptions (while heard)
        self.low_subs: list = []  # mode and (range gate) camera pose subscriptions
        self.in_range = False  # its camera pose is within hearing range (hysteresis)


class PeerTable:
    """Controllers composed in one process (nodes/team.py): each one writes what it publishes
    (state with its stamp, accel, mode) into its own record here, and reads the other robots'
    records instead of subscribing to their topics (the in-process delivery an rclcpp component
    container gives; no N^2 DDS subscriptions). ``records`` are made up front for ``ids``.
    """

    def __init__(self, ids):
        self.ids = frozenset(int(i) for i in ids)
        self.records: dict[int, _Neighbour] = {i: _Neighbour(i) for i in self.ids}
        self.goals: dict = {}  # S8.3 goals of this period, shared (ControllerNode._goal_of)


class ControllerNode(Node):
    """See the module docstring."""

    def __init__(
        self,
        *,
        context=None,
        params: ControllerParams | None = None,
        tick_timer: bool = True,
        peers: PeerTable | None = None,
        bridge=None,
        lock=None,
        tick_inputs: bool = False,
        **node_kw,
    ):
        """``tick_timer=False``: no control timer of its own; the owner calls :meth:`control_tick`
        every period (nodes/team.py). ``peers``: the controllers composed in the same process.
        ``bridge``: this robot's BridgeNode in the same process (a team): wheel samples come from
        it directly and torques go to it directly (:meth:`BridgeNode.command`) instead of through
        wheel_state / wheel_torque, which are then published only while someone subscribes.
        ``lock``: held by the callbacks that change what a control period reads (camera pose,
        graph, encounters) when the owner runs the control periods in a thread of their own
        (nodes/team.py ControlLoop, which holds it for each period); default: no lock.
        ``tick_inputs``: the full-rate state and accel of the robots heard are taken by that
        control loop at each period (:meth:`take_inputs`, ros/tick_inputs.py), not by the
        executor.
        """
        self._tick_inputs = tick_inputs
        super().__init__('formation_controller', context=context, **node_kw)
        self.lock = lock if lock is not None else contextlib.nullcontext()
        self._own_xy: tuple[float, float] | None = None  # own position of the last period [m]
        spec = self._init_robot(params)
        self._init_law(spec)
        self._init_state(peers)
        self._init_publishers()
        self._init_subscriptions(bridge, peers)
        self._init_diagnostics()
        self.timer = (
            self.create_timer(1.0 / self.prm.control_rate_hz, self._control)
            if tick_timer
            else None
        )
        self.law.warm_up()  # compile (or load) the law's kernels now, not in the first tick
        if tick_timer and self.prm.realtime_priority:  # the executor thread runs the control timer
            set_realtime(self.prm.realtime_priority, self.get_logger())

    def _init_robot(self, params: ControllerParams | None):
        """Parameters, scenario, this robot's plant coefficients, camera-loss stop and pose
        estimator; ConfigError when ``robot_id`` is not a robot of the scenario. Returns the
        robot's spec.
        """
        self.prm = params if params is not None else declare_dataclass(self, ControllerParams)
        self.scenario = load_scenario(self.prm.scenario)
        if self.prm.robot_id not in self.scenario.robot_ids:
            raise ConfigError(
                f'{self.prm.robot_id} is not a robot of {self.scenario.name} '
                f'(ids {list(self.scenario.robot_ids)})',
                'robot_id',
            )
        self.rid = self.prm.robot_id
        spec = self.scenario.robot(self.rid)
        self.k = PlantCoeffs.from_params([spec.params])
        self.tau_max = spec.params.torque_limit_nm
        # camera loss: the stop begins early enough to be at rest by pose_timeout_s (StopLead)
        self.stop_lead = self._make_stop_lead(spec.params)
        self._pose_stop = False  # the camera-loss stop is in force ...
        self._pose_stop_camera_s = None  # ... since this newest camera stamp (latched)
        self.over_stop_speed = 0  # ticks faster than stop_speed_max_mps/stop_turn_rate_max_radps
        self.estimator = PoseEstimator(
            EstimatorParams.from_robot(spec.params, camera_gain=self.prm.camera_gain)
        )
        return spec

    def _init_law(self, spec) -> None:
        """The robot's law (RobotController) on its original formation graph, the goal and
        robot tables, the hearing ranges.
        """
        sc = self.scenario
        self.law = RobotController(
            self.rid,
            spec.params,
            sc.control,
            sc.avoidance,
            sc.avoided_obstacles(),
            leader_path=spec.path if spec.leader else None,
            team=sc.team_leader(self.rid),
            slot_m=sc.slot(self.rid),
            floor=sc.floor,
        )
        fgraph = FormationGraph.from_scenario(sc)
        self.goal_source, self.robot_info = _robot_tables(sc, fgraph)
        av = sc.avoidance  # S7: Q of robot k seen by this robot is kappa R_aa about p_k
        self._hear_range_m = {
            r.id: av.protected_scale
            * (spec.params.body_radius_m + r.params.body_radius_m + av.agent_keepout_margin_m)
            + self.prm.hear_margin_m
            for r in sc.robots
        }
        self._goals: dict = {}  # robot id -> (g, g_dot) of this period ("t": its time)
        self.start_s: float | None = None
        self.graph: msgs.GraphMessage | None = None
        self.parent: _Neighbour | None = None
        self.orig_parent_id, self.orig_offset = original_parent_link(fgraph, self.rid)
        self.law.set_graph(
            self.orig_parent_id, self.orig_offset, self.orig_parent_id, self.orig_offset
        )
        self.orig: _Neighbour | None = None

    def _init_state(self, peers: PeerTable | None) -> None:
        """Assignment, mode, safety state, counters and clock of the control periods."""
        self.encounter_revision = -1
        self.encounters_at = -math.inf  # when /formation/encounters was last heard [s, ROS time]
        self.assigned = AssignedLaw(self.law)  # the coordinator's assignment applied (S7, S8.3)
        self.events: list[dict] = []  # mode events of the law (scenario time)
        self.last_wheel_s = -math.inf
        self.rejections = diag.Rejections(
            ('pose', 'wheel', 'parent', 'graph', 'encounters'), lambda: self.now_s()
        )
        self.rejected = self.rejections.counts  # kind -> count, reported as 'robot_<id> inputs'
        self.safety = 'waiting'  # waiting | running | stopped_pose | stopped_wheels | hold_parent
        self.mode = {'mode': 'hold', 'target': None, 'direction': None, 'avoiding': False}
        self._mode_sent = None
        self._last_mode_pub = -math.inf
        self.ticks = 0
        self.late_ticks = 0
        self._last_tick_wall = None
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self._now_ns = diag.clock_ns(self)  # the node's clock [ns] (read directly unless sim time)
        self.last_torque = np.zeros(2)
        self.peers = peers
        self.record = None if peers is None else peers.records[self.rid]  # what others read of us
        self._msg_state = self._msg_torque = self._msg_accel = None  # refilled every period

    def _init_publishers(self) -> None:
        """wheel_torque, state, accel and mode, with their matched-subscription listeners."""
        self.pub_torque = self.create_publisher(JointState, 'wheel_torque', QOS_CONTROL)
        self.pub_state = self.create_publisher(msgs.Odometry, 'state', QOS_CONTROL)
        self.pub_accel = self.create_publisher(AccelStamped, 'accel', QOS_CONTROL)
        self.pub_mode = self.create_publisher(String, 'mode', QOS_CONTROL)
        # matched subscriptions, asked of rmw at most every 0.1 s (ros/listeners.py)
        self._state_heard, self._torque_heard, self._accel_heard = (
            Listeners(self.pub_state),
            Listeners(self.pub_torque),
            Listeners(self.pub_accel),
        )

    def _init_subscriptions(self, bridge, peers: PeerTable | None) -> None:
        """Camera pose, wheels (topic or the bridge in the process), graph, encounters and the
        other robots (subscribed, or the records of the peers in the process).
        """
        # raw: the high-rate inputs are read from their serialized form (ros/cdr.py)
        self.create_subscription(PoseStamped, 'pose', self._on_pose, QOS_CONTROL, raw=True)
        self.bridge = bridge
        if bridge is None:
            self.create_subscription(JointState, 'wheel_state', self._on_wheels, QOS_CONTROL)
        else:
            bridge.telemetry_sinks.append(self.wheel_sample)
        self.create_subscription(String, '/formation/graph', self._on_graph, QOS_GRAPH)
        self.create_subscription(String, '/formation/encounters', self._on_encounters, QOS_GRAPH)
        sc = self.scenario
        self.neighbours = {
            k: (
                peers.records[k]
                if peers is not None and k in peers.ids
                else self._subscribe_neighbour(k)
            )
            for k in sc.robot_ids
            if k != self.rid
        }
        if self.orig_parent_id is not None:
            self.orig = self.neighbours[self.orig_parent_id]
        self._update_hearing()

    def _init_diagnostics(self) -> None:
        """Diagnostics of the control, the control loop's period and the inputs."""
        self.diag = diag.Diagnostics(self)
        robot = f'robot_{self.rid}'
        self.diag.add(f'{robot} control', self._control_status, hardware_id=robot)
        self.control_watch = self.diag.watch(
            f'{robot} control loop', 1.0 / self.prm.control_rate_hz, hardware_id=robot
        )
        self.diag.add(f'{robot} inputs', self.rejections.status, hardware_id=robot)

    def _make_stop_lead(self, robot) -> StopLead:
        """The camera-loss stop's :class:`StopLead` for this robot's ``robot`` parameters and the
        node's stop parameters; ConfigError when its worst case does not fit in
        ``pose_timeout_s``, a warning when it leaves less than two camera frame intervals.
        """
        lead = StopLead(
            robot,
            self.prm.stop_time_s,
            self.scenario.control,
            self.scenario.disturbance.accel_bound,
            margin_s=self.prm.stop_margin_s,
            speed_max_mps=self.prm.stop_speed_max_mps,
            turn_rate_max_radps=self.prm.stop_turn_rate_max_radps,
            decel_mps2=self.prm.stop_decel_mps2,
            period_s=1.0 / self.prm.control_rate_hz,
        )
        lead.check(self.prm.pose_timeout_s)
        frame_s = 1.0 / self.scenario.camera.fps
        if self.prm.pose_timeout_s - lead.max_s < 2.0 * frame_s:
            self.get_logger().warn(
                f'at the speed bounds the camera-loss stop begins at a camera age of '
                f'{self.prm.pose_timeout_s - lead.max_s:.3f} s (pose_timeout_s - '
                f'{lead.max_s:.3f} s), less than two frame intervals: a late frame '
                'will stop a robot driving that fast'
            )
        return lead

    @property
    def subscriptions(self):
        """What an executor serves: every subscription but those :meth:`take_inputs` takes."""
        return served_by_executor(super().subscriptions)

    def take_inputs(self) -> None:
        """Run the callbacks of the messages that arrived since the last call on the
        subscriptions taken at each period (``tick_inputs``; holding ``lock``).
        """
        take_waiting(list(super().subscriptions))

    # ------------------------------------------------------------------ time
    def now_s(self) -> float:
        return self._now_ns() * 1e-9

    # ------------------------------------------------------------------ inputs
    def _on_pose(self, msg: PoseStamped | bytes) -> None:
        pose, stamp_s = cdr.pose_from_msg(msg)
        with self.lock:
            outcome = self.estimator.camera_update(stamp_s, pose)
        if outcome.startswith('rejected'):
            self.rejected['pose'] += 1

    def _on_wheels(self, msg: JointState) -> None:
        try:
            q, qd, stamp_s = msgs.wheel_state_from_msg(msg)
        except ValueError:
            self.rejected['wheel'] += 1
            return
        self.wheel_sample(q, qd, stamp_s)

    def wheel_sample(self, q, qd, stamp_s: float) -> None:
        """One encoder sample: wheel angles q (2,) [rad], rates qd (2,) [rad/s] at ``stamp_s``."""
        if self.estimator.wheel_update(stamp_s, q, qd):
            self.last_wheel_s = self.now_s()
        else:
            self.rejected['wheel'] += 1

    def _on_graph(self, msg: String) -> None:
        with self.lock:
            self._apply_graph(msg)
        self._update_hearing()

    def _apply_graph(self, msg: String) -> None:
        try:
            graph = msgs.graph_from_msg(msg)
        except ValueError:
            self.rejected['graph'] += 1
            self.diag.changed()
            return
        if self.graph is not None and graph.revision < self.graph.revision:
            return
        self.graph = graph
        if graph.start_s is not None:
            self.start_s = graph.start_s
        parent = graph.parents.get(self.rid)
        if parent is not None and parent not in self.neighbours:
            self.rejected['graph'] += 1
            return
        self.parent = None if parent is None else self.neighbours[parent]
        offset = graph.offsets_m.get(self.rid, (0.0, 0.0))
        self.law.set_graph(parent, offset, self.orig_parent_id, self.orig_offset)

    def _on_encounters(self, msg: String) -> None:
        try:
            revision, assignments = msgs.encounters_from_msg(msg)
        except ValueError:
            self.rejected['encounters'] += 1
            self.diag.changed()
            return
        if revision < self.encounter_revision:
            return
        with self.lock:
            self.encounter_revision = revision
            self.encounters_at = self.now_s()
            self.assigned.assignment = assignments.get(self.rid)
        self._update_hearing()

    def _subscribe_neighbour(self, rid: int) -> _Neighbour:
        nb = _Neighbour(rid)

        def on_state(msg, nb=nb):
            state, stamp_s = cdr.finite_state_from_odometry(msg)
            if state is None:  # not finite
                self.rejected['parent'] += 1
                return
            nb.state, nb.stamp_s = state, stamp_s

        def on_accel(msg, nb=nb):
            accel, _ = cdr.finite_accel_from_msg(msg)
            if accel is None:  # not finite
                self.rejected['parent'] += 1
                return
            nb.accel = accel

        def on_mode(msg, nb=nb):
            try:
                mode = msgs.mode_from_msg(msg)
            except ValueError:
                self.rejected['parent'] += 1
                return
            nb.mode, nb.target = threat_mode(mode)
            nb.direction = pair_sense(mode)

        def on_camera(msg, nb=nb):
            pose, _ = cdr.pose_from_msg(msg)
            own = self._own_xy
            if own is None or not (math.isfinite(pose[0]) and math.isfinite(pose[1])):
                return
            dist = math.hypot(pose[0] - own[0], pose[1] - own[1])
            reach = self._hear_range_m[nb.rid]
            in_range = dist < reach or (nb.in_range and dist < reach + HEAR_HYSTERESIS_M)
            if in_range != nb.in_range:
                nb.in_range = in_range
                self._update_hearing(nb)

        nb.callbacks = (
            (TakenAtTick(on_state), TakenAtTick(on_accel))
            if self._tick_inputs
            else (on_state, on_accel)
        )
        nb.low_subs = [
            self.create_subscription(String, f'/robot_{rid}/mode', on_mode, QOS_CONTROL)
        ]
        if not self.prm.hear_all:  # range gate from the camera poses (30 fps) of robot rid
            nb.low_subs.append(
                self.create_subscription(
                    PoseStamped, f'/robot_{rid}/pose', on_camera, QOS_CONTROL, raw=True
                )
            )
        return nb

    def _needed(self, nb: _Neighbour) -> bool:
        """Full-rate state/accel of ``nb`` is needed: every robot with ``hear_all``; else the
        current and original parents (S4 field, S8.3 exit goal), the partner of the coordinator's
        assignment, and the robots whose camera pose is within hearing range (possible S7 threats).
        """
        if self.prm.hear_all or nb is self.parent or nb.rid == self.orig_parent_id or nb.in_range:
            return True
        a = self.assigned.assignment
        return a is not None and a.partner == nb.rid

    def _update_hearing(self, only: _Neighbour | None = None) -> None:
        """Subscribe / unsubscribe the full-rate state and accel of the robots in other processes
        as :meth:`_needed` says (executor thread only: graph, encounters and camera callbacks).
        """
        for nb in self.neighbours.values() if only is None else (only,):
            if not hasattr(nb, 'callbacks'):  # a peer in the same process: read directly
                continue
            need = self._needed(nb)
            if need and not nb.subs:
                on_state, on_accel = nb.callbacks
                nb.subs = [
                    self.create_subscription(
                        msgs.Odometry, f'/robot_{nb.rid}/state', on_state, QOS_CONTROL, raw=True
                    ),
                    self.create_subscription(
                        AccelStamped, f'/robot_{nb.rid}/accel', on_accel, QOS_CONTROL, raw=True
                    ),
                ]
            elif not need and nb.subs:
                with self.lock:  # no message taken at a period (tick_inputs) after this
                    for sub in nb.subs:
                        self.destroy_subscription(sub)
                    nb.subs = []
                    nb.state, nb.stamp_s = None, -math.inf  # not heard any more: not used

    def _neighbour_now(self, nb: _Neighbour | None, now_s: float) -> np.ndarray | None:
        """The neighbour's state extrapolated to now with its commanded acceleration
        (S10, S13 #13); None when unknown or older than parent_hold_s.
        """
        if nb is None or nb.state is None:
            return None
        return extrapolate_neighbour(
            nb.state,
            nb.accel,
            now_s - nb.stamp_s,
            float(self.k.d[0]),
            self.prm.parent_timeout_s,
            self.prm.parent_hold_s,
        )

    def _goal_of(self, rid: int, t_s: float, known: dict) -> tuple:
        """(g, g_dot) of robot ``rid`` at scenario time ``t_s`` (S8.3 item 1), each (2,) [m],
        [m/s]: a leader's r(t), r_dot(t); a follower's original parent point + delta and that
        point's velocity; (None, None) when its original parent is not heard.
        """
        cache = self._goals if self.peers is None else self.peers.goals  # a team ticks at one time
        if cache.get('t') != t_s:
            cache.clear()
            cache['t'] = t_s
        hit = cache.get(rid)
        if hit is not None:
            return hit
        path, p0, offset, d = self.goal_source[rid]
        hit = neighbour_goal(t_s, path, known.get(p0), offset, d)
        if hit[0] is None:
            return hit
        cache[rid] = hit
        return hit

    # ------------------------------------------------------------------ control loop
    def control_tick(self, now_s: float | None = None) -> None:
        """One control period (the node's own timer, or its owner's when ``tick_timer=False``;
        a team passes one ``now_s`` [s, ROS time] to every robot it hosts).
        """
        self._control(now_s)

    def _control(self, now_s: float | None = None) -> None:
        now = self.now_s() if now_s is None else now_s
        self.control_watch.tick(int(now * 1e9))
        wall = time.monotonic()
        if (
            self._last_tick_wall is not None
            and self.start_s is not None
            and not self._sim_time
            and wall - self._last_tick_wall > 1.5 / self.prm.control_rate_hz
        ):
            self.late_ticks += 1  # a missed control deadline (wall clock runs only)
        self._last_tick_wall = wall
        self.ticks += 1
        est = self.estimator
        if not est.initialized:
            self._safety('waiting')
            self._send(np.zeros(2), None, now)
            return
        state = est.state_at(now)
        self._own_xy = (float(state[0]), float(state[1]))
        stamp = msgs.stamp_from_s(now)
        self._msg_state = msgs.odometry(state, stamp, f'robot_{self.rid}', out=self._msg_state)
        if self._state_heard():  # (volatile: unheard, it reaches nobody)
            self.pub_state.publish(self._msg_state)
        if self.record is not None:
            self.record.state, self.record.stamp_s = state, now
        if now - self.last_wheel_s > self.prm.wheel_timeout_s:
            self._safety('stopped_wheels')
            self._send(np.zeros(2), None, now)  # no encoder data: nothing to brake with
            return
        if self._camera_lost(state, now):
            self._safety('stopped_pose')
            self._brake(state, now, camera_loss=True)
            return
        if self.start_s is None or now < self.start_s:
            self._safety('waiting')
            self._send(np.zeros(2), None, now)
            return
        t = now - self.start_s
        parent_state = self._neighbour_now(self.parent, now)
        if self.parent is not None and parent_state is None:
            self._safety('hold_parent')
            self._brake(state, now, camera_loss=False)
            return
        self._safety('running')
        heard: dict[int, NeighbourState] = {}
        known = {self.rid: state}
        for k, nb in self.neighbours.items():
            xk = parent_state if nb is self.parent else self._neighbour_now(nb, now)
            if xk is not None:
                known[k] = xk
        for k, xk in known.items():  # every input was checked on arrival (finite, known mode)
            if k == self.rid:
                continue
            nb = self.neighbours[k]
            radius, team, d, slot = self.robot_info[k]
            goal, goal_dot = self._goal_of(k, t, known)
            heard[k] = NeighbourState.trusted(
                xk,
                nb.accel,
                radius,
                team,
                nb.mode,
                nb.target,
                d,
                goal,
                goal_dot,
                slot,
                nb.direction,
            )
        parent = None if self.parent is None else self.parent.rid
        orig_state = original_parent_state(heard, self.orig_parent_id, self.orig_offset, state)
        out = self.assigned.step(t, state, parent, orig_state, heard, self.coordinated(now))
        self.events.extend(out.events)
        self.mode = {
            'mode': out.mode,
            'target': out.target,
            'direction': out.direction,
            'avoiding': out.mode != 'coordination',
        }
        self._send(
            np.asarray(out.torque_nm, dtype=float),
            np.asarray(out.accel_cmd_mps2, dtype=float),
            now,
        )

    def _brake(self, state: np.ndarray, now: float, camera_loss: bool) -> None:
        """Send the controlled stop's torque (DESIGN §7, :func:`stop_torque`), with the boundary
        layers of the control period: the camera-loss stop (``camera_loss``) brakes v with the
        gain its :class:`StopLead` was computed for (stop_decel_mps2); hold_parent keeps the
        formation law's gains.
        """
        lead = self.stop_lead  # the stop law its lead was computed for
        torque = stop_torque(
            state[None],
            self.k,
            self.prm.stop_time_s,
            self.scenario.control,
            lead.decel_mps2 if camera_loss else 0.0,
            lead.period_s,
        )[0]
        self._send(torque, None, now)

    def _camera_lost(self, state: np.ndarray, now: float) -> bool:
        """Camera loss (DESIGN §7): True once the camera age exceeds ``pose_timeout_s`` minus the
        stop lead at the current speed (:class:`StopLead`: the time to rest under the stop law +
        ``stop_margin_s``), so the robot is at rest by ``pose_timeout_s`` (+ one control period).
        Latched until a newer camera pose is accepted: the lead shrinks as the robot slows, and
        a stop once begun must not give way to driving on the same stale pose.
        """
        est = self.estimator
        if self._pose_stop:
            if est.last_camera_s == self._pose_stop_camera_s:
                return True
            self._pose_stop = False  # a new pose: decide afresh
        v, omega = float(state[3]), float(state[4])
        if self.stop_lead.over_bound(v, omega):
            self.over_stop_speed += 1
            self.get_logger().warn(
                f'driving faster than the stop bounds ({self.stop_lead.speed_max_mps:g} m/s, '
                f'{self.stop_lead.turn_rate_max_radps:g} rad/s): v {v:.3f} m/s, omega '
                f'{omega:.2f} rad/s; a camera loss may end at rest after pose_timeout_s',
                throttle_duration_sec=10.0,
            )
        if est.camera_age_s(now) > self.prm.pose_timeout_s - self.stop_lead.lead_s(v, omega):
            self._pose_stop, self._pose_stop_camera_s = True, est.last_camera_s
            return True
        return False

    def coordinated(self, now_s: float | None = None) -> bool:
        """The coordinator is heard: its assignments arrived within ``coordinator_timeout_s``
        (then the robot's own robot encounters are emergencies only, docs/law-changes.md §23).
        """
        now = self.now_s() if now_s is None else now_s
        return now - self.encounters_at <= self.prm.coordinator_timeout_s

    def _control_status(self) -> tuple[int, str, dict]:
        values = {
            'ticks': self.ticks,
            'late_ticks': self.late_ticks,
            'over_stop_speed': self.over_stop_speed,
            'safety': self.safety,
            'mode': self.mode['mode'],
            'coordinator_heard': self.coordinated(),
            **{f'rejected_{k}': v for k, v in self.rejected.items()},
            **self.estimator.counters.as_dict(),
        }
        level = (
            diag.OK
            if self.safety in ('running', 'waiting')
            else diag.WARN
            if self.safety == 'hold_parent'
            else diag.ERROR
        )
        return level, self.safety, values

    def _safety(self, status: str) -> None:
        if status != self.safety:
            if status.startswith(('stopped', 'hold')):
                self.get_logger().warn(f'safety: {self.safety} -> {status}')
            else:
                self.get_logger().info(f'safety: {self.safety} -> {status}')
            self.safety = status
            if status != 'running':
                self.mode = {
                    'mode': 'hold' if status in ('waiting', 'hold_parent') else 'stopped',
                    'target': None,
                    'direction': None,
                    'avoiding': False,
                }
            self.diag.changed()  # a safety change is published when it happens

    def _send(self, torque: np.ndarray, accel: np.ndarray | None, now: float) -> None:
        lim = self.tau_max  # non-finite -> 0, then DESIGN §7: clamp here too (two scalars)
        left, right = float(torque[0]), float(torque[1])
        left = min(max(left if math.isfinite(left) else 0.0, -lim), lim)
        right = min(max(right if math.isfinite(right) else 0.0, -lim), lim)
        torque = self.last_torque = np.array([left, right])
        stamp = None
        if self.bridge is None or self._torque_heard():
            stamp = msgs.stamp_from_s(now)
            self._msg_torque = msgs.wheel_torque(torque, stamp, out=self._msg_torque)
            self.pub_torque.publish(self._msg_torque)
        if self.bridge is not None:
            self.bridge.command((left, right))
        accel = np.zeros(2) if accel is None else accel
        if self.record is not None:
            self.record.accel = accel
            self.record.mode, self.record.target = threat_mode(self.mode)
            self.record.direction = pair_sense(self.mode)
        if self._accel_heard():  # (in a team, often nobody outside)
            stamp = msgs.stamp_from_s(now) if stamp is None else stamp
            self._msg_accel = msgs.accel_stamped(accel, stamp, out=self._msg_accel)
            self.pub_accel.publish(self._msg_accel)
        key = tuple(sorted(self.mode.items()))
        if key != self._mode_sent or now - self._last_mode_pub >= 1.0:
            self.pub_mode.publish(msgs.mode_msg(**self.mode))
            self._mode_sent, self._last_mode_pub = key, now


def _send_zero_torque(node: 'ControllerNode') -> None:
    """Last word of the process: zero torque on ``wheel_torque`` and to a hosted bridge, each
    tried on its own (a bridge whose port is already closed must not swallow the message).
    """
    try:
        node.pub_torque.publish(msgs.wheel_torque(np.zeros(2), msgs.stamp_from_s(node.now_s())))
    finally:
        if node.bridge is not None:
            node.bridge.command((0.0, 0.0))


def main(args: list[str] | None = None) -> int:
    return run_node('formation_controller', ControllerNode, args, on_exit=_send_zero_torque)


if __name__ == '__main__':
    sys.exit(main())
