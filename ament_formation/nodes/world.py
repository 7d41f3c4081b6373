"""formation_world: the simulated hardware twin (docs/design.md §1, §6).

The plant of every robot (1 kHz RK4, core/sim/twin.py) with the scenario's disturbance and moving
obstacles; one emulated motor board per robot on its own pty (hw/pty_board.py: the bridge opens
``<pty_dir>/robot_<id>``); the synthetic overhead camera (core/vision/synthetic_camera.py)
rendering the
robots' markers; ground truth for evaluation. The mission starts when ``/formation/graph`` carries
a
``start_s`` (the coordinator starts it once every controller is up); until then the robots stand.

Topics (QoS from ros/qos.py)
  pub  /camera/image_raw          sensor_msgs/Image mono8, stamp = capture time     QOS_IMAGE
  pub  /camera/camera_info        sensor_msgs/CameraInfo (camera_config), with each image, same
                                  stamp                                            QOS_IMAGE
  pub  /world/truth/robot_<id>    nav_msgs/Odometry, every tick (while subscribed) QOS_CONTROL
  pub  /clock                     rosgraph_msgs/Clock (only when speed_factor != 1)  QOS_CLOCK
  sub  /formation/graph           std_msgs/String JSON graph/v1 (start_s); invalid ones counted
                                                                                   QOS_GRAPH
  pub  /diagnostics               "formation_world: simulation" (ticks, overruns: WARN for 5 s
                                  after one), "formation_world: inputs" (rejected graph payloads:
                                  WARN for 10 s after one), "formation_world: plant loop"
                                  (stalls), "formation_world: board robot_<id>" (watchdog trips,
                                  STOPs, brakes: cause, start and release in world time)

Parameters
  scenario         str    scenario YAML (required)
  camera_config    str    camera.yaml (config/ name or path)                  default camera.yaml
  pty_dir          str    folder for the robot_<id> pty links (default: a new temp folder)
  speed_factor     float  sim seconds per wall second; != 1 publishes /clock  default 1.0
  tick_s           float  plant/board/truth period [s sim]                     default 0.01
  physics_dt_s     float  RK4 step [s]                                         default 0.001
  camera_enabled   bool   render and publish frames                            default true
  camera_noise     float  sensor noise [grey levels]                           default 2.0
  exit_at_end      bool   shut down when the mission ends (the coordinator's mission_end_s, S17.3)
                          plus hold_s, or at the run's time cap             default true
  hold_s           float  run on this long after the mission ends [s]      default 0
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import shutil
import sys
import tempfile
import time

import numpy as np
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String

from ament_formation.core.config_files import config_file
from ament_formation.core.control.progress import max_time_s
from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard
from ament_formation.core.serial.serial_protocol import (
    STOP_HOST_SHUTDOWN,
    STOP_INPUT_STALE,
    STOP_UNSPECIFIED,
)
from ament_formation.core.sim.twin import PlantTwin
from ament_formation.core.vision.camera_model import load_camera_yaml
from ament_formation.core.vision.synthetic_camera import Obstacles, RenderOptions, SyntheticCamera
from ament_formation.hw.pty_board import PtyBoard, PtyBoardGroup
from ament_formation.ros import diagnostics as diag
from ament_formation.ros import messages as msgs
from ament_formation.ros.executors import run_node
from ament_formation.ros.image import camera_info
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CLOCK, QOS_CONTROL, QOS_GRAPH, QOS_IMAGE

SIM_CLOCK_START_S = 1.0  # /clock starts here (ROS time 0 means "no time yet")
STOP_REASONS = {
    STOP_UNSPECIFIED: 'unspecified',
    STOP_INPUT_STALE: 'input_stale',  # the bridge's input (the controller's torques) went stale
    STOP_HOST_SHUTDOWN: 'host_shutdown',  # the bridge shutting down
}


@dataclass(frozen=True)
class WorldParams:
    scenario: str = param('', 'scenario YAML path (required)')
    camera_config: str = param('camera.yaml', 'camera calibration: a config/ file name or a path')
    pty_dir: str = param('', "folder for the robot_<id> pty links ('': a new temp folder)")
    speed_factor: float = param(
        1.0, 'sim seconds per wall second; != 1 publishes /clock', range=(0.05, 50.0)
    )
    tick_s: float = param(0.01, 'plant/board/truth period [s sim]', range=(0.001, 0.05))
    physics_dt_s: float = param(0.001, 'RK4 step [s], <= tick_s', range=(0.0, 0.05))
    camera_enabled: bool = param(True, 'render and publish camera frames')
    camera_noise: float = param(2.0, 'sensor noise std [grey levels]')
    exit_at_end: bool = param(
        True, "shut down when the mission ends (the coordinator's mission_end_s) plus hold_s, or "
        "at the run's time cap (three times duration_s, at least 30 s more)")
    hold_s: float = param(0.0, 'run on this long after the mission ends [s]', range=(0.0, 3600.0))

    def __post_init__(self) -> None:
        if not self.scenario:
            raise ConfigError('is required (path of a scenario YAML)', 'scenario')
        if not (math.isfinite(self.speed_factor) and 0.05 <= self.speed_factor <= 50.0):
            raise ConfigError(f'must be in [0.05, 50] (got {self.speed_factor!r})', 'speed_factor')
        if not (0.001 <= self.tick_s <= 0.05):
            raise ConfigError(f'must be in [0.001, 0.05] s (got {self.tick_s!r})', 'tick_s')
        if not (0 < self.physics_dt_s <= self.tick_s):
            raise ConfigError(
                f'must be in (0, tick_s] s (got {self.physics_dt_s!r})', 'physics_dt_s'
            )
        if not (math.isfinite(self.hold_s) and 0.0 <= self.hold_s <= 3600.0):
            raise ConfigError(f'must be in [0, 3600] s (got {self.hold_s!r})', 'hold_s')


def _camera_path(name: str) -> Path:
    p = Path(name)
    return p if p.is_file() else config_file(name)


class WorldNode(Node):
    """See the module docstring."""

    def __init__(self, *, context=None, params: WorldParams | None = None, **node_kw):
        super().__init__('formation_world', context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, WorldParams)
        self.scenario = load_scenario(self.prm.scenario)
        self.twin = PlantTwin(self.scenario, dt_s=self.prm.physics_dt_s)
        self.ids = self.twin.ids
        self.sim_clock = self.prm.speed_factor != 1.0
        self._mono0 = time.monotonic()
        self.plant_time_s = self.now_s()  # ROS time [s] of the twin's state
        self.start_s: float | None = None
        self.done = False
        self.overruns = 0
        self.ticks = 0
        self.rejections = diag.Rejections(('graph', 'encounters'), time.monotonic)
        self._overruns_seen = (0, -math.inf)  # (count, when it last grew [s])
        self.diag = diag.Diagnostics(self)
        self.diag.add('simulation', self._simulation_status, hardware_id='simulation')
        self.diag.add('inputs', self.rejections.status)
        self.tick_watch = self.diag.watch(
            'plant loop', self.prm.tick_s / self.prm.speed_factor, hardware_id='simulation'
        )

        # boards on ptys
        self._own_pty_dir = not self.prm.pty_dir
        self.pty_dir = Path(self.prm.pty_dir or tempfile.mkdtemp(prefix='ament_formation_pty_'))
        self.pty_dir.mkdir(parents=True, exist_ok=True)
        self.boards: list[PtyBoard] = []
        for spec in self.scenario.robots:
            cfg = BoardConfig(hard_torque_limit_nm=spec.params.torque_limit_nm)
            board = PtyBoard(
                MotorBoard(cfg, now_s=self.plant_time_s),
                link_path=self.pty_dir / f'robot_{spec.id}',
                clock=self.now_s,
            )
            board.open()
            self.boards.append(board)
        self.board_runner = PtyBoardGroup(self.boards, step_period_s=0.005)  # one thread for all
        self.board_runner.start()
        for rid, b in zip(self.ids, self.boards):
            self.diag.add(f'board robot_{rid}', self._board_status(b.board), f'robot_{rid}')

        # camera
        self.camera = None
        if self.prm.camera_enabled:
            setup = load_camera_yaml(_camera_path(self.prm.camera_config))
            self._camera_info = camera_info(setup.camera)
            self.camera = SyntheticCamera(
                setup.camera,
                options=RenderOptions(noise_std=self.prm.camera_noise),
                floor=setup.floor,
            )
            self.frame_period_s = 1.0 / self.scenario.camera.fps
            self.next_frame_s = self.plant_time_s
            self.frames = 0
        self.marker_ids = np.array([r.marker_id for r in self.scenario.robots])

        self.pub_image = self.create_publisher(Image, '/camera/image_raw', QOS_IMAGE)
        self.pub_camera_info = self.create_publisher(CameraInfo, '/camera/camera_info', QOS_IMAGE)
        self._truth_msgs: list = [None] * len(self.ids)  # refilled every tick
        self.pub_truth = [
            self.create_publisher(msgs.Odometry, f'/world/truth/robot_{i}', QOS_CONTROL)
            for i in self.ids
        ]
        self.pub_clock = (
            self.create_publisher(Clock, '/clock', QOS_CLOCK) if self.sim_clock else None
        )
        self.create_subscription(String, '/formation/graph', self._on_graph, QOS_GRAPH)
        self.create_subscription(String, '/formation/encounters', self._on_encounters, QOS_GRAPH)
        self.mission_end_s: float | None = None
        self._publish_clock()
        self.timer = self.create_timer(self.prm.tick_s / self.prm.speed_factor, self._tick)
        self.get_logger().info(
            f'world: {len(self.ids)} robots, ptys in {self.pty_dir}, '
            f'speed x{self.prm.speed_factor:g}'
        )

    # ------------------------------------------------------------------ time
    def now_s(self) -> float:
        """World time [s]: ROS time of the run (system clock, or the /clock we publish)."""
        if self.sim_clock:
            return SIM_CLOCK_START_S + self.prm.speed_factor * (time.monotonic() - self._mono0)
        return time.time()

    def scenario_time_s(self) -> float | None:
        return None if self.start_s is None else self.plant_time_s - self.start_s

    def _publish_clock(self) -> None:
        if self.pub_clock is not None:
            self.pub_clock.publish(Clock(clock=msgs.stamp_from_s(self.plant_time_s)))

    # ------------------------------------------------------------------ callbacks
    def _on_graph(self, msg: String) -> None:
        try:
            graph = msgs.graph_from_msg(msg)
        except ValueError as err:
            self.rejections.counts['graph'] += 1
            self.diag.changed()
            self.get_logger().warn(f'/formation/graph: {err}', throttle_duration_sec=5.0)
            return
        if graph.start_s is not None and self.start_s is None:
            self.start_s = graph.start_s
            self.get_logger().info(f'mission start at {graph.start_s:.3f} s')

    def _on_encounters(self, msg: String) -> None:
        try:
            m = msgs.encounters_from_msg(msg)
        except ValueError:
            self.rejections.counts['encounters'] += 1
            self.diag.changed()
            return
        if m.mission_end_s is not None and self.mission_end_s is None:
            self.mission_end_s = m.mission_end_s
            self.get_logger().info(f'mission ended at t = {m.mission_end_s:.2f} s')

    def _tick(self) -> None:
        """Advance the plant to the world clock in tick_s steps (at most 5 per call)."""
        self.tick_watch.tick()
        target = self.now_s()
        n = 0
        while self.plant_time_s + self.prm.tick_s <= target + 1e-9 and n < 5 and not self.done:
            self._step_once()
            n += 1
        if target - self.plant_time_s > 5 * self.prm.tick_s:
            self.overruns += 1
            self.plant_time_s = target - self.prm.tick_s  # drop what we cannot catch up
        if n:
            self._publish_clock()

    def _simulation_status(self) -> tuple[int, str, dict]:
        now = time.monotonic()
        if self.overruns != self._overruns_seen[0]:
            self._overruns_seen = (self.overruns, now)
        t = self.scenario_time_s()
        values = {
            'ticks': self.ticks,
            'overruns': self.overruns,
            'plant_time_s': self.plant_time_s,
            'scenario_time_s': 'not started' if t is None else t,
            'speed_factor': self.prm.speed_factor,
        }
        if self.overruns and now - self._overruns_seen[1] <= 5.0:
            return diag.WARN, 'behind real time: plant steps dropped', values
        return diag.OK, 'waiting for the mission start' if t is None else 'running', values

    @staticmethod
    def _board_status(board: MotorBoard):
        """The emulated board's stops: its watchdog trips, STOPs received, brakes (when the last
        one started and was released, world time [s], and what started it: watchdog | stop).
        """

        def status() -> tuple[int, str, dict]:
            values = {
                'watchdog_trips': board.watchdog_trips,
                'stops_received': board.stops_received,
                'last_stop_reason': STOP_REASONS.get(board.last_stop_reason, 'none'),
                'brakes': board.brakes,
                'braking': board.braking,
                'brake_cause': board.brake_cause or 'none',
                'brake_started_s': board.brake_started_s or 'none',
                'brake_released_s': board.brake_released_s or 'none',
                'last_command_s': board.last_command_s or 'none',
            }
            return diag.OK, 'braking' if board.braking else 'ok', values

        return status

    def _step_once(self) -> None:
        tick = self.prm.tick_s
        if (
            self.start_s is not None
            and not self.twin.started
            and self.plant_time_s + 0.5 * self.prm.physics_dt_s >= self.start_s
        ):
            self.twin.start()
        torque = np.array([b.board.applied_torque_nm for b in self.boards])
        self.twin.advance(tick, torque)
        self.plant_time_s += tick
        self.ticks += 1
        angles, rates = self.twin.wheel_angle_rad, self.twin.wheel_rate_radps
        for k, b in enumerate(self.boards):
            with b.lock:
                b.board.set_wheel_state(angles[k], rates[k])
        stamp = msgs.stamp_from_s(self.plant_time_s)
        for k, rid in enumerate(self.ids):  # ground truth, while anyone listens (evaluation only)
            if self.pub_truth[k].get_subscription_count():
                self._truth_msgs[k] = msgs.odometry(
                    self.twin.state[k], stamp, f'robot_{rid}', out=self._truth_msgs[k]
                )
                self.pub_truth[k].publish(self._truth_msgs[k])
        if self.camera is not None and self.plant_time_s >= self.next_frame_s:
            self._render(stamp)
            self.next_frame_s += self.frame_period_s
            if self.next_frame_s < self.plant_time_s:
                self.next_frame_s = self.plant_time_s + self.frame_period_s
        t = self.scenario_time_s()
        end = max_time_s(self.scenario.duration_s)
        if self.mission_end_s is not None:
            end = min(end, self.mission_end_s + self.prm.hold_s)
        if self.prm.exit_at_end and t is not None and t >= end:
            self.done = True
            self.get_logger().info(f'scenario {self.scenario.name} finished at t = {t:.2f} s')

    def _render(self, stamp) -> None:
        obs = self.twin.obstacle_states()
        frame = self.camera.render(
            self.twin.state[:, :3],
            self.marker_ids,
            Obstacles(obs.center_m, obs.semi_axes_m, obs.phi_rad),
            pose_rates=self.twin.pose_rates(),
            frame_index=self.frames,
        )
        self.frames += 1
        self.pub_image.publish(msgs.image_mono8(frame, stamp))
        self._camera_info.header.stamp = stamp
        self.pub_camera_info.publish(self._camera_info)

    # ------------------------------------------------------------------ shutdown
    def close(self) -> None:
        """Stop the boards, remove the ptys (and the pty folder if we made it)."""
        self.board_runner.stop()
        for b in self.boards:
            b.close()
        self.boards = []
        if self._own_pty_dir:
            shutil.rmtree(self.pty_dir, ignore_errors=True)

    def destroy_node(self):
        self.close()
        return super().destroy_node()


# how long the world, when it ends, waits for its last ground truth to be acknowledged by every
# subscriber (the recorder of `formation run` is judged by it; on a loaded machine it lags behind)
TRUTH_ACK_S = 3.0


def main(args: list[str] | None = None) -> int:
    return run_node('formation_world', WorldNode, args, ack_s=TRUTH_ACK_S)


if __name__ == '__main__':
    sys.exit(main())
