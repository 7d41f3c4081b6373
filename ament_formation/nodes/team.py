"""formation_team: several robots' bridge and controller nodes composed in one process.

What an rclcpp component container gives, for Python nodes: every hosted robot keeps its own
``formation_controller`` and ``formation_bridge`` node (namespace ``robot_<id>``, the same topics,
parameters, QoS and safety as when they run as separate processes), but they share one process
and one executor, and

* the hosted robots' agents are one :class:`~ament_formation.core.control.agent.AgentBatch`:
  one compiled call runs every hosted robot's control period (one wake-up of the process per
  period instead of one per robot), and one timer polls every hosted bridge;
* the hosted robots hear each other in process (``AgentBatch.share``) instead of through N^2 DDS
  subscriptions, and each controller hands its torques to its robot's bridge and takes the wheel
  samples from it directly. State,
  accel and mode are still published on DDS for the coordinator, the recorder, the tools and the
  robots in other processes; wheel_torque and wheel_state are published while anyone subscribes
  (a hosted bridge takes its commands only from its hosted controller).

On wall-clock time the control periods run in a thread of their own (:class:`ControlLoop`), not
on an executor timer: a period starts on time whatever the executor is doing (decoding messages,
diagnostics), reads the serial ports first, then runs every hosted controller; between periods
the thread sleeps in select() on the ports and reads telemetry the moment it arrives (no poll
timer). The full-rate state and accel of the robots the controllers hear (other processes) are
taken by the loop at the start of each period, what arrived since the previous one
(ros/tick_inputs.py: no executor wake per message). Callbacks that change what a period reads
(camera pose, graph, encounters, wheel samples, heard states) take the team's lock, a re-entrant
one: the loop itself runs some of them while it holds it. With ``realtime_priority`` P the loop
thread runs under SCHED_FIFO P and the executor thread under P - 1. On simulated time
(``use_sim_time``) executor timers run the periods. With ``tick_on_pose: true`` (default false), a
team of one robot (a robot's computer) runs a period as soon as that robot's camera pose arrives,
the next one a full period later: a pose does not wait up to a period for the schedule.

The robot process of a robot's computer (scripts/launch_robot.sh, default): a team of one robot,
``robot_ids:=[N]``, ``port_template:=/dev/ttyACM0`` (no ``{id}`` needed for one robot). For
simulated runs of many robots on one machine: ``scripts/launch_sim.sh --team K`` (K robots per
process).

Parameters (this node; ``--ros-args -p NAME:=VALUE`` given to the process also reaches every
hosted node, as in any ROS 2 process, e.g. ``control_rate_hz``, ``pose_timeout_s``,
``poll_rate_hz``, ``use_sim_time``)
  scenario        str    scenario YAML (required)
  robot_ids       int[]  robots hosted here                         default [] = every robot
  port_template   str    serial port of robot {id}, e.g. /dev/ttyACM{id} or PTY_DIR/robot_{id}
                         (one hosted robot: any path); empty: no bridges (controllers only)
                                                                     default ""
  realtime_priority int  SCHED_FIFO priority of the control loop thread (0: normal)  default 0
Torque limits of the bridges come from the scenario.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
import select
import sys
import threading
import time
from typing import Sequence

from rclpy.node import Node
from rclpy.parameter import Parameter

from ament_formation.core.control.agent import AgentBatch, AgentParams
from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.nodes.bridge import BridgeNode
from ament_formation.nodes.controller import _send_zero_torque as _controller_zero_torque
from ament_formation.nodes.controller import ControllerNode
from ament_formation.ros import diagnostics as diag
from ament_formation.ros.executors import run_node, set_realtime
from ament_formation.ros.params import declare_dataclass


@dataclass(frozen=True)
class TeamParams:
    scenario: str = param('', 'scenario YAML path (required)')
    robot_ids: tuple[int, ...] = param((), 'robots hosted here (empty: every robot)')
    port_template: str = param(
        '', "serial port of robot {id}, e.g. /dev/ttyACM{id} ('': no bridges, controllers only)"
    )
    realtime_priority: int = param(
        0,
        'SCHED_FIFO priority of the control loop thread (1..98; 0: normal scheduling)',
        range=(0, 98),
    )

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        ids = self.robot_ids
        if len(set(ids)) != len(ids) or any(not isinstance(i, int) or i < 0 for i in ids):
            raise ConfigError(f'must be distinct integers >= 0 (got {list(ids)})', 'robot_ids')
        if self.port_template and '{id}' not in self.port_template and len(ids) != 1:
            raise ConfigError(
                f'must contain {{id}} unless one robot is hosted (got {self.port_template!r})',
                'port_template',
            )
        if not (isinstance(self.realtime_priority, int) and 0 <= self.realtime_priority <= 98):
            raise ConfigError(
                f'must be an integer in [0, 98] (got {self.realtime_priority!r})',
                'realtime_priority',
            )


class TeamNode(Node):
    """See the module docstring. ``composed_nodes``: the hosted nodes (spun with this one)."""

    def __init__(
        self,
        *,
        context=None,
        params: TeamParams | None = None,
        hosted_parameters: Sequence[Parameter] = (),
        control_thread: bool = True,
        **node_kw,
    ):
        """``hosted_parameters``: parameter overrides for every hosted node
        (what ``-p NAME:=VALUE`` on the process command line does), e.g. ``poll_rate_hz`` or
        ``pose_timeout_s``.
        ``control_thread=False``: executor timers run the control periods even on wall-clock time
        (tests that call :meth:`_control` themselves).
        """
        super().__init__('formation_team', context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, TeamParams)
        scenario = load_scenario(self.prm.scenario)
        ids = list(self.prm.robot_ids) or list(scenario.robot_ids)
        unknown = [i for i in ids if i not in scenario.robot_ids]
        if unknown:
            raise ConfigError(
                f'{unknown} are not robots of {scenario.name} (ids {list(scenario.robot_ids)})',
                'robot_ids',
            )
        use_sim_time = bool(self.get_parameter('use_sim_time').value)
        self._now_ns = diag.clock_ns(self)  # the node's clock [ns] (read directly unless sim time)
        common = [*hosted_parameters, Parameter('use_sim_time', value=use_sim_time)]
        threaded = not use_sim_time and control_thread
        # re-entrant: the loop thread holds it for a whole period and, within it, runs callbacks
        # that take it too when the executor thread may run them (a hosted bridge's wheel
        # samples, the heard robots' state taken at the period); a plain Lock deadlocked there
        self.lock = threading.RLock() if threaded else None
        self.loop: ControlLoop | None = None
        self.poll_watch = None  # stalls of the bridges' poll timer (diagnostics "serial poll")
        # the hosted controllers' parameters reach this node too (-p NAME:=VALUE of the process)
        self.batch = AgentBatch(scenario, ids, declare_dataclass(self, AgentParams))
        self.controllers: dict[int, ControllerNode] = {}
        self.bridges: dict[int, BridgeNode] = {}
        try:
            for rid in ids:
                ns = f'/robot_{rid}'
                if self.prm.port_template:
                    self.bridges[rid] = BridgeNode(
                        context=context,
                        namespace=ns,
                        poll_timer=False,
                        torque_topic=False,
                        parameter_overrides=common
                        + [
                            Parameter(
                                'port', value=self.prm.port_template.replace('{id}', str(rid))
                            ),
                            Parameter(
                                'torque_limit_nm',
                                value=float(scenario.robot(rid).params.torque_limit_nm),
                            ),
                        ],
                    )
                self.controllers[rid] = ControllerNode(
                    context=context,
                    namespace=ns,
                    tick_timer=False,
                    batch=self.batch,
                    bridge=self.bridges.get(rid),
                    lock=self.lock,
                    tick_inputs=threaded,  # the heard robots' state/accel: taken at each period
                    parameter_overrides=common
                    + [
                        Parameter('scenario', value=str(self.prm.scenario)),
                        Parameter('robot_id', value=int(rid)),
                    ],
                )
        except BaseException:
            self.destroy_node()
            raise
        rates = {c.prm.control_rate_hz for c in self.controllers.values()}
        rate_hz = rates.pop()
        if threaded:
            self.loop = ControlLoop(self, rate_hz, self.prm.realtime_priority)
            # one robot hosted (a robot's computer): its camera pose runs the period at once
            # (tick_on_pose); with several, each robot's pose of a frame would run one period
            if len(self.controllers) == 1:
                (only,) = self.controllers.values()
                if only.prm.tick_on_pose:
                    only.on_own_pose = self.loop.pose_arrived
            if self.prm.realtime_priority > 1:  # the executor thread: callbacks before other work
                set_realtime(self.prm.realtime_priority - 1, None)
            self.loop.start()
        else:
            self.create_timer(1.0 / rate_hz, self._control)
            if self.bridges:
                poll_hz = next(iter(self.bridges.values())).params.poll_rate_hz
                self.diag = diag.Diagnostics(self)  # the hosted bridges' poll timer is ours
                self.poll_watch = self.diag.watch('serial poll', 1.0 / poll_hz)
                self.create_timer(1.0 / poll_hz, self._poll)
        self.get_logger().info(f'hosting robots {ids}' + (' with bridges' if self.bridges else ''))

    @property
    def composed_nodes(self) -> list[Node]:
        return [*self.bridges.values(), *self.controllers.values()]

    def _poll(self) -> None:
        if self.poll_watch is not None:
            self.poll_watch.tick()
        for bridge in self.bridges.values():
            bridge.poll()

    def _control(self) -> None:
        if self.loop is not None:  # what arrived since the last period (ros/tick_inputs.py)
            for controller in self.controllers.values():
                controller.take_inputs()
        now_s = self._now_ns() * 1e-9  # one time for the whole period
        for controller in self.controllers.values():
            controller._check_clocks()
        self.batch.tick(now_s)
        self.batch.share(now_s)
        for controller in self.controllers.values():
            controller.publish(now_s)

    def destroy_node(self):
        for controller in self.controllers.values():
            controller.on_own_pose = None
        if self.loop is not None:
            self.loop.stop()
        for node in [*self.controllers.values(), *self.bridges.values()]:
            node.destroy_node()
        self.controllers, self.bridges = {}, {}
        return super().destroy_node()


class ControlLoop:
    """The team's control periods in a thread of their own (a separate loop from the executor's;
    ros/executors.py is untouched): every ``1 / rate_hz`` [s, monotonic clock] it reads every
    hosted bridge's port, then runs :meth:`TeamNode._control`, holding ``team.lock``; in between
    it waits in select() on the bridges' ports and reads telemetry as it arrives. A period that
    starts late is run at once and the schedule moves on (the controllers count the late tick).
    ``priority`` > 0: the thread runs under SCHED_FIFO ``priority``.
    """

    MIN_READ_GAP_S = 0.002  # event-driven serial reads: at most 500 per second

    def __init__(self, team: 'TeamNode', rate_hz: float, priority: int = 0):
        self.team = team
        self.period_s = 1.0 / rate_hz
        self.priority = priority
        self._stop = threading.Event()
        self.errors = 0
        self.pose_periods = 0  # periods run at once for a fresh pose (pose_arrived)
        # pose_arrived() wakes the select() through this pipe
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._pose_due = False
        self.thread = threading.Thread(target=self._run, name='control_loop', daemon=True)

    def start(self) -> None:
        sys.setswitchinterval(0.0005)  # a waiting control thread gets the GIL within 0.5 ms
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        if self.thread.is_alive() and threading.current_thread() is not self.thread:
            self.thread.join(timeout=2.0)
        if not self.thread.is_alive() and self._wake_r >= 0:
            r, w = self._wake_r, self._wake_w
            self._wake_r = self._wake_w = -1  # a late pose_arrived() writes nowhere
            os.close(r)
            os.close(w)

    def pose_arrived(self) -> None:
        """The hosted robot's camera pose arrived (executor thread): run a period now, the next
        one a full period later (the pose-to-torque path without an idle wait).
        """
        self._pose_due = True
        self._wake()

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b'.')
        except (BlockingIOError, OSError):  # already woken (pipe full), or closed
            pass

    def _drain(self) -> None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except (BlockingIOError, OSError):
            pass

    def _fds(self) -> list[int]:
        fds = []
        for bridge in self.team.bridges.values():
            port = getattr(bridge, '_port', None)
            try:
                fds.append(port.fileno())
            except (AttributeError, OSError, ValueError, TypeError):
                pass  # closed (reopening with backoff) or no file descriptor
        return fds

    def _poll_all(self) -> None:
        for bridge in self.team.bridges.values():
            bridge.poll()

    def _run(self) -> None:
        if self.priority:
            set_realtime(self.priority, self.team.get_logger())
        lock, team, period = self.team.lock, self.team, self.period_s
        next_s = time.monotonic() + period
        read_ok_s = -math.inf  # the next read on readiness is due from then on
        while not self._stop.is_set():
            try:
                wait = next_s - time.monotonic()
                if wait > 0.0:
                    ready = select.select([*self._fds(), self._wake_r], [], [], wait)[0]
                    if self._wake_r in ready:
                        self._drain()
                        ready.remove(self._wake_r)
                        if self._pose_due:  # a fresh pose: this period now
                            self._pose_due = False
                            self.pose_periods += 1
                            next_s = time.monotonic()
                            continue
                    if ready:
                        # at most one read per MIN_READ_GAP_S: a port that stays readable without
                        # data (a hung-up pty) must not turn this (real-time) thread into a busy
                        # loop. Data that comes sooner waits for the gap's end (a plain sleep:
                        # cheaper than an Event's wait; stop() waits for it); a period with no
                        # data after its read wakes only at its end
                        now = time.monotonic()
                        if now < read_ok_s:
                            pause = min(read_ok_s, next_s) - now  # < 0 once the period is due
                            if pause > 0.0:
                                time.sleep(pause)
                            continue
                        with lock:
                            self._poll_all()  # telemetry as it arrives
                        read_ok_s = time.monotonic() + self.MIN_READ_GAP_S
                    continue
                with lock:
                    self._poll_all()
                    team._control()
                next_s += period
                now = time.monotonic()
                if next_s < now:  # overran a whole period: restart the schedule
                    next_s = now + period
            # keep the loop; the board's watchdog stops the robot
            except Exception as err:  # noqa: BLE001
                if self._stop.is_set() or not team.context.ok():
                    return
                self.errors += 1
                team.get_logger().error(
                    f'control loop: {type(err).__name__}: {err}', throttle_duration_sec=1.0
                )
                time.sleep(period)


def _send_zero_torque(team: TeamNode) -> None:
    """Last word of the process: zero torque from every hosted controller."""
    if team.loop is not None:
        team.loop.stop()
    errors = []
    for node in team.controllers.values():
        try:
            _controller_zero_torque(node)
        except Exception as err:  # noqa: BLE001 - every hosted robot gets its zero
            errors.append(err)
    if errors:
        raise errors[0]


def main(args: list[str] | None = None) -> int:
    return run_node('formation_team', TeamNode, args, on_exit=_send_zero_torque)


if __name__ == '__main__':
    sys.exit(main())
