"""formation_tracker: overhead camera frames → each robot's pose (core/vision/marker_tracking.py).

Contract

Topics (type; QoS; direction):

- /camera/image_raw (``image_topic``): sensor_msgs/Image (mono8, bgr8, rgb8, mono16, …);
  QOS_IMAGE; subscribed when ``source`` is empty; with ``source``, published (mono8, capture
  stamp) while anyone subscribes and ``publish_image``
- /camera/camera_info (next to ``image_topic``): sensor_msgs/CameraInfo (camera_config), same
  stamp as the frame; QOS_IMAGE; published per captured frame when ``source`` is set; subscribed
  instead (the camera driver's calibration) when ``intrinsics_source`` is ``camera_info``
- robot_<id>/pose: geometry_msgs/PoseStamped, frame ``world``, stamp = capture time; QOS_CONTROL;
  published per frame the robot's marker is seen
- robot_<id>/pose_cov: geometry_msgs/PoseWithCovarianceStamped (same pose, σ² of x, y, yaw);
  QOS_CONTROL; when ``publish_covariance``
- ~/debug_image: sensor_msgs/Image bgr8 (markers, poses drawn); QOS_IMAGE; when
  ``publish_debug_image``
- /diagnostics: diagnostic_msgs/DiagnosticArray (source state, frame rate, detection rate,
  latency); QOS_DIAGNOSTICS; every ``diagnostics_period_s`` and at once when the camera is lost or
  back

Parameters (TrackerNodeParams; name, type, default: meaning)
  source               str|int ""        "" = subscribe image_topic; else capture frames in the
                                         node from a device index (0 or "0"), a device path
                                         (/dev/video0, /dev/v4l/by-id/...), a video file or a
                                         stream URL (http://, rtsp://) (hw/video_source.py)
  source_loop          bool    false     replay a video file from the start when it ends
  source_wait_s        float   0         at start, keep trying to open the source this long [s]
                                         (0: one attempt; .inf: wait forever)
  source_timeout_s     float   1.0       a stream silent this long is lost and reopened [s]
  capture_poll_s       float   0.01      period of the timer that takes the newest frame [s]
  publish_image        bool    true      with source: publish the captured frames on image_topic
  image_topic          str     /camera/image_raw   topic of frames
  camera_config        str     camera.yaml         camera calibration (config/ name or path):
                                                   the mounting, and the intrinsics unless
                                                   intrinsics_source says otherwise
  intrinsics_source    str     camera_config       camera_config | calibration_file (a ROS
                                                   camera_calibration YAML) | camera_info (the
                                                   topic beside image_topic; without source)
  calibration_file     str     ""        the ROS camera_calibration YAML (calibration_file)
  marker_ids           int[]   [0, 1]    marker id per robot
  robot_ids            int[]   [0, 1]    robot id for each entry of marker_ids
  dictionary           str     DICT_4X4_50         ArUco dictionary
  marker_size_m        float   0.12      marker side [m]
  marker_offset_m      float[] [-0.05, 0.0]        marker centre in the controlled point's body
                                                   frame [m]
  marker_height_m      float   0.08      marker plane above the floor [m]
  max_speed_mps        float   1.5       faster apparent motion is rejected as a jump [m/s]
  use_roi              bool    true      region-of-interest search around predicted poses
  publish_covariance   bool    true      publish robot_<id>/pose_cov
  publish_debug_image  bool    false     publish ~/debug_image
  diagnostics_period_s float   1.0       [s]

With ``source`` set, a thread grabs frames (stamped with the node clock at grab time) and keeps the
newest; a timer of the node (``capture_poll_s``) takes it and runs the tracker, so the executor
never blocks on the camera and any executor works (no guard condition: rclpy's EventsExecutor has
none). Failure policy (docs/camera.md): a source that cannot be opened at start prints one line
on stderr and the process exits with status 1 (after ``source_wait_s`` of retries, if set); a
camera lost at run time is reported (log, diagnostics ERROR) and reopened with backoff for as long
as the node runs, while the controllers, which get no pose, stop after their ``pose_timeout_s``;
when frames come back, tracking resumes. A video file that ends (without ``source_loop``) is
reported as an ERROR and the node keeps running.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import sys
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from ament_formation.core.config_files import config_file
from ament_formation.core.errors import ConfigError
from ament_formation.core.params import param
from ament_formation.core.vision import aruco_compat
from ament_formation.core.vision.camera_model import load_camera_yaml
from ament_formation.core.vision.marker_tracking import MarkerTracker, TrackerConfig
from ament_formation.core.vision.robot_marker import MarkerLayout
from ament_formation.core.vision.ros_calibration import (
    apply_intrinsics,
    Intrinsics,
    intrinsics_from_fields,
    load_ros_calibration,
)
from ament_formation.hw.video_source import FrameGrabber, open_problem, parse_source, SourceSpec
from ament_formation.ros import diagnostics as diag
from ament_formation.ros.executors import run_node
from ament_formation.ros.image import camera_info, image_to_mono8, numpy_to_image
from ament_formation.ros.messages import pose_stamped, stamp_to_ns, stamp_to_s
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS, QOS_IMAGE


@dataclass(frozen=True)
class TrackerNodeParams:
    """Parameters of formation_tracker (see the module docstring)."""

    source: str | int = param(
        '',
        "'': subscribe image_topic; else a device index (0), a device path "
        '(/dev/video0), a video file or a stream URL to capture',
        dynamic_typing=True,
    )
    source_loop: bool = param(False, 'replay a video file from the start when it ends')
    source_wait_s: float = param(
        0.0,
        'at start, keep trying to open the source this long [s] (0: one attempt; .inf: forever)',
    )
    source_timeout_s: float = param(
        1.0, 'a stream silent this long is lost and reopened [s]', range=(0.05, 60.0)
    )
    capture_poll_s: float = param(
        0.01, 'period of taking the newest captured frame [s]', range=(0.001, 1.0)
    )
    publish_image: bool = param(
        True, 'with source: publish captured frames on image_topic while anyone subscribes'
    )
    image_topic: str = param('/camera/image_raw', 'topic of frames when source is empty')
    camera_config: str = param('camera.yaml', 'camera calibration: a config/ file name or a path')
    intrinsics_source: str = param(
        'camera_config',
        'intrinsics from: camera_config, calibration_file (a ROS camera_calibration YAML) or '
        'camera_info (the topic beside image_topic, without source)',
    )
    calibration_file: str = param(
        '', 'ROS camera_calibration YAML (with intrinsics_source calibration_file)'
    )
    marker_ids: tuple[int, ...] = param((0, 1), 'ArUco marker id of each robot')
    robot_ids: tuple[int, ...] = param((0, 1), 'robot id for each entry of marker_ids')
    dictionary: str = param('DICT_4X4_50', 'ArUco dictionary')
    marker_size_m: float = param(0.12, 'marker side [m]')
    marker_offset_m: tuple[float, ...] = param(
        (-0.05, 0.0), "marker centre in the controlled point's body frame [x, y] [m]"
    )
    marker_height_m: float = param(0.08, 'marker plane above the floor [m]')
    max_speed_mps: float = param(1.5, 'faster apparent motion is rejected as a jump [m/s]')
    use_roi: bool = param(True, 'search around the predicted poses first')
    publish_covariance: bool = param(True, 'also publish robot_<id>/pose_cov')
    publish_debug_image: bool = param(False, 'publish ~/debug_image (bgr8, markers drawn)')
    diagnostics_period_s: float = param(1.0, '/diagnostics period [s], > 0')

    def __post_init__(self) -> None:
        if len(self.marker_ids) != len(self.robot_ids):
            raise ConfigError(
                f'{len(self.robot_ids)} robot ids for {len(self.marker_ids)} marker ids',
                'robot_ids',
            )
        for name in ('marker_ids', 'robot_ids'):
            v = getattr(self, name)
            if len(set(v)) != len(v) or any(not isinstance(i, int) or i < 0 for i in v):
                raise ConfigError(f'must be distinct integers >= 0 (got {list(v)})', name)
        parse_source(self.source)  # ConfigError naming source for a float, a list, -1, …
        if self.intrinsics_source not in INTRINSICS_SOURCES:
            raise ConfigError(
                f'must be one of {", ".join(INTRINSICS_SOURCES)} (got {self.intrinsics_source!r})',
                'intrinsics_source',
            )
        if (self.intrinsics_source == 'calibration_file') != bool(self.calibration_file):
            raise ConfigError(
                'is needed with intrinsics_source calibration_file, and only with it',
                'calibration_file',
            )
        if self.intrinsics_source == 'camera_info' and self.source_spec is not None:
            raise ConfigError(
                'camera_info comes from a camera driver publishing image_topic: not with source',
                'intrinsics_source',
            )
        if self.source_spec is None and not self.image_topic:
            raise ConfigError('is empty and no source is set', 'image_topic')
        if math.isnan(self.source_wait_s) or self.source_wait_s < 0:
            raise ConfigError(f'must be >= 0 s (got {self.source_wait_s})', 'source_wait_s')
        for name, lo, hi in (('source_timeout_s', 0.05, 60.0), ('capture_poll_s', 0.001, 1.0)):
            v = getattr(self, name)
            if not (math.isfinite(v) and lo <= v <= hi):
                raise ConfigError(f'must be in [{lo:g}, {hi:g}] s (got {v})', name)
        if not (math.isfinite(self.diagnostics_period_s) and self.diagnostics_period_s > 0):
            raise ConfigError(
                f'must be > 0 s (got {self.diagnostics_period_s})', 'diagnostics_period_s'
            )
        self.layout()
        TrackerConfig(max_speed_mps=self.max_speed_mps, use_roi=self.use_roi)

    @property
    def source_spec(self) -> SourceSpec | None:
        """The parsed ``source`` (None: frames come on ``image_topic``)."""
        return parse_source(self.source)

    def layout(self) -> MarkerLayout:
        return MarkerLayout(
            self.dictionary, self.marker_size_m, tuple(self.marker_offset_m), self.marker_height_m
        )


INTRINSICS_SOURCES = ('camera_config', 'calibration_file', 'camera_info')


def _camera_path(name: str) -> Path:
    p = Path(name)
    return p if p.is_file() else config_file(name)


class SourceUnavailable(RuntimeError):
    """The video source cannot be opened at start (the process prints one line, exits 1)."""


class TrackerNode(Node):
    """See the module docstring."""

    def __init__(
        self, *, context=None, params: TrackerNodeParams | None = None, **node_kw
    ) -> None:
        super().__init__('formation_tracker', context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, TrackerNodeParams)
        aruco_compat.require_aruco()  # an OpenCV without cv2.aruco: one line, exit code 2
        setup = load_camera_yaml(_camera_path(self.prm.camera_config))
        self._base_camera = setup.camera  # the mounting (and intrinsics of camera_config)
        self.intrinsics: Intrinsics | None = None
        self.info_errors = 0
        self.last_info_error = ''
        self.frames_waiting_info = 0
        self.tracker: MarkerTracker | None = None
        self.camera = setup.camera
        if self.prm.intrinsics_source == 'calibration_file':
            path = Path(self.prm.calibration_file)
            self.intrinsics = load_ros_calibration(path)
            self._build_tracker(apply_intrinsics(self._base_camera, self.intrinsics, str(path)))
        elif self.prm.intrinsics_source == 'camera_config':
            self._build_tracker(self._base_camera)
        self.robot_of = dict(zip(self.prm.marker_ids, self.prm.robot_ids))
        self.pub_pose = {
            m: self.create_publisher(PoseStamped, f'robot_{r}/pose', QOS_CONTROL)
            for m, r in self.robot_of.items()
        }
        self.pub_cov = (
            {
                m: self.create_publisher(
                    PoseWithCovarianceStamped, f'robot_{r}/pose_cov', QOS_CONTROL
                )
                for m, r in self.robot_of.items()
            }
            if self.prm.publish_covariance
            else {}
        )
        self.pub_debug = (
            self.create_publisher(Image, '~/debug_image', QOS_IMAGE)
            if self.prm.publish_debug_image
            else None
        )
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_DIAGNOSTICS)
        self._reset_stats()
        self.frames_total = 0
        self.failure: str | None = None  # set (with done) when the source never opened in time
        self.done = False
        self.grabber: FrameGrabber | None = None
        spec = self.prm.source_spec
        if spec is not None:
            self._start_capture(spec)
        else:
            self.create_subscription(Image, self.prm.image_topic, self._on_image, QOS_IMAGE)
        self.info_topic = self.prm.image_topic.rsplit('/', 1)[0] + '/camera_info'
        if self.prm.intrinsics_source == 'camera_info':
            self.create_subscription(CameraInfo, self.info_topic, self._on_camera_info, QOS_IMAGE)
        self.create_timer(self.prm.diagnostics_period_s, self._publish_diagnostics)

    def _build_tracker(self, camera) -> None:
        """(Re)build the marker tracker for ``camera`` (tracks start over)."""
        self.camera = camera
        self.tracker = MarkerTracker(
            camera,
            self.prm.layout(),
            TrackerConfig(max_speed_mps=self.prm.max_speed_mps, use_roi=self.prm.use_roi),
            expected_ids=tuple(self.prm.marker_ids),
        )

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """The camera driver's calibration: new intrinsics rebuild the tracker; a message that
        is no usable calibration is counted and reported, the last good one is kept.
        """
        try:
            if not any(msg.k):
                raise ConfigError(
                    'K is zero: the camera driver publishes no calibration (calibrate it with '
                    'camera_calibration, or set intrinsics_source: camera_config)',
                    'camera_matrix',
                    self.info_topic,
                )
            intr = intrinsics_from_fields(
                msg.width, msg.height, msg.distortion_model, list(msg.d), list(msg.k),
                list(msg.r), list(msg.p), source=self.info_topic,
            )
            if self.intrinsics is not None and intr.close_to(self.intrinsics):
                return
            camera = apply_intrinsics(self._base_camera, intr, self.info_topic)
        except ConfigError as err:
            self.info_errors += 1
            self.last_info_error = str(err)
            self.get_logger().error(str(err), throttle_duration_sec=5.0)
            return
        self.intrinsics = intr
        self._build_tracker(camera)
        self.get_logger().info(
            f'intrinsics from {self.info_topic}: {intr.width_px}x{intr.height_px} px, fx '
            f'{intr.fx_px:.2f} fy {intr.fy_px:.2f} cx {intr.cx_px:.2f} cy {intr.cy_px:.2f}'
        )

    def _start_capture(self, spec: SourceSpec) -> None:
        """Open ``spec`` (one attempt now; more in the grabber thread within ``source_wait_s``),
        start grabbing and the timer that takes the newest frame.
        """
        clock = self.get_clock()
        self.grabber = FrameGrabber(
            spec,
            lambda: clock.now().to_msg(),
            loop=self.prm.source_loop,
            size_px=self.camera.size_px,
            fps_hz=self.camera.fps_hz,
            read_timeout_s=self.prm.source_timeout_s,
        )
        self._wait_deadline_s = None
        if not self.grabber.try_open():
            if self.prm.source_wait_s <= 0.0:
                raise SourceUnavailable(f'source {spec.text!r}: {open_problem(spec)}')
            self._wait_deadline_s = time.monotonic() + self.prm.source_wait_s
            self.get_logger().warn(
                f'source {spec.text!r}: {open_problem(spec)}; retrying for '
                f'{self.prm.source_wait_s:g} s'
            )
        else:
            self._log_opened()
        self._source_state = self.grabber.state
        info_topic = self.prm.image_topic.rsplit('/', 1)[0] + '/camera_info'
        self.pub_info = self.create_publisher(CameraInfo, info_topic, QOS_IMAGE)
        self._info = camera_info(self.camera, frame_id='camera')
        self.pub_image = (
            self.create_publisher(Image, self.prm.image_topic, QOS_IMAGE)
            if self.prm.publish_image
            else None
        )
        self.grabber.start()
        self.capture_watch = diag.PeriodWatch(
            self.prm.capture_poll_s, diag.clock_ns(self)
        )  # stalls
        self.create_timer(self.prm.capture_poll_s, self._take_captured)

    def _log_opened(self) -> None:
        g = self.grabber
        fps = f' at {g.fps_hz:g} fps' if g.fps_hz else ''
        self.get_logger().info(f'capturing {g.spec.kind} {g.spec.text!r}{fps}')

        # ------------------------------------------------------------------ frames

    def _on_image(self, msg: Image) -> None:
        try:
            frame = image_to_mono8(msg)
        except ValueError as err:
            self.bad_frames += 1
            self.get_logger().warn(f'{self.prm.image_topic}: {err}', throttle_duration_sec=5.0)
            return
        self.process(frame, msg.header.stamp)

    def _take_captured(self) -> None:
        """Timer (``capture_poll_s``): the newest captured frame, if any, → camera_info, image,
        poses; source state changes → log and diagnostics at once.
        """
        self.capture_watch.tick()
        g = self.grabber
        if g.state != self._source_state:
            self._on_source_state(self._source_state, g.state)
            self._source_state = g.state
        if (
            g.state == 'closed'
            and self._wait_deadline_s is not None
            and time.monotonic() > self._wait_deadline_s
        ):
            self.failure = (
                f'source {g.spec.text!r}: {open_problem(g.spec)} '
                f'(waited {self.prm.source_wait_s:g} s)'
            )
            self.done = True
            return
        item = g.take()
        if item is None:
            if g.state == 'open' and time.monotonic() - g.last_frame_s > self.prm.source_timeout_s:
                self.get_logger().warn(
                    f'source {g.spec.text!r} open but silent for more than '
                    f'{self.prm.source_timeout_s:g} s',
                    throttle_duration_sec=5.0,
                )
            return
        frame, stamp = item
        self.capture_delay_s.append(
            max(self.get_clock().now().nanoseconds - stamp_to_ns(stamp), 0) * 1e-9
        )
        self._info.header.stamp = stamp
        self.pub_info.publish(self._info)
        if self.pub_image is not None and self.pub_image.get_subscription_count():
            self.pub_image.publish(numpy_to_image(frame, 'mono8', stamp))
        self.process(frame, stamp)

    def _on_source_state(self, old: str, new: str) -> None:
        g, log = self.grabber, self.get_logger()
        if new == 'lost':
            log.error(
                f'camera lost ({g.spec.text!r}): reopening with backoff; without poses the '
                f'robots stop after their pose_timeout_s'
            )
        elif new == 'open' and old == 'lost':
            lost_s = time.monotonic() - g.lost_since_s if g.lost_since_s else 0.0
            log.info(f'camera back ({g.spec.text!r}) after {lost_s:.1f} s')
        elif new == 'open':
            self._log_opened()
        elif new == 'ended':
            log.warn(f'video file {g.spec.text!r} ended (source_loop false): no more poses')
        self._publish_diagnostics()

    def process(self, frame: np.ndarray, stamp) -> None:
        """One frame (mono8) captured at ``stamp`` → pose messages."""
        if self.tracker is None:  # intrinsics_source camera_info: none received yet
            self.frames_waiting_info += 1
            return
        t0 = time.perf_counter()
        try:
            result = self.tracker.step(frame, stamp_to_s(stamp))
        except ValueError as err:
            self.bad_frames += 1
            self.last_bad_frame = str(err)
            self.get_logger().warn(str(err), throttle_duration_sec=5.0)
            return
        acc = result.accepted
        for mid, pose, sxy, sth in zip(acc.ids, acc.poses, acc.sigma_xy_m, acc.sigma_theta_rad):
            pub = self.pub_pose.get(int(mid))
            if pub is None:
                continue
            msg = pose_stamped(pose, stamp)
            pub.publish(msg)
            if self.pub_cov:
                cov = PoseWithCovarianceStamped()
                cov.header = msg.header
                cov.pose.pose = msg.pose
                c = [0.0] * 36
                c[0] = c[7] = float(sxy) ** 2
                c[14] = c[21] = c[28] = 1e6  # z, roll, pitch: not measured
                c[35] = float(sth) ** 2
                cov.pose.covariance = c
                self.pub_cov[int(mid)].publish(cov)
        self.latency_s.append(time.perf_counter() - t0)
        self.frames += 1
        self.frames_total += 1
        self.full_frames += int(result.full_frame)
        self.detected += sum(int(m) in self.robot_of for m in acc.ids)
        self.rejected += len(result.rejected_ids)
        if self.pub_debug is not None:
            self.pub_debug.publish(numpy_to_image(self._annotate(frame, acc), 'bgr8', stamp))

    def _annotate(self, frame: np.ndarray, acc) -> np.ndarray:
        img = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        if len(acc):
            aruco_compat.draw_detected_markers(
                img,
                [c.reshape(1, 4, 2).astype(np.float32) for c in acc.corners_px],
                acc.ids.reshape(-1, 1).astype(np.int32),
            )
            tips = acc.poses[:, :2] + 0.15 * np.column_stack(
                [np.cos(acc.poses[:, 2]), np.sin(acc.poses[:, 2])]
            )
            h = self.prm.marker_height_m
            p0 = self.camera.floor_to_pixel(acc.poses[:, :2], h)
            p1 = self.camera.floor_to_pixel(tips, h)
            for a, b, mid in zip(p0, p1, acc.ids):
                cv2.arrowedLine(
                    img, tuple(int(v) for v in a), tuple(int(v) for v in b), (0, 0, 255), 2
                )
                r = self.robot_of.get(int(mid))
                if r is not None:
                    cv2.putText(
                        img,
                        f'robot {r}',
                        (int(a[0]) + 8, int(a[1]) - 8),
                        cv2.FONT_HERSHEY_SIMPLEX,
                        0.4,
                        (0, 255, 0),
                        1,
                    )
        return img

    # ------------------------------------------------------------------ diagnostics
    def _reset_stats(self) -> None:
        self.frames = 0
        self.full_frames = 0
        self.detected = 0
        self.rejected = 0
        self.bad_frames = 0
        self.last_bad_frame = ''
        self.latency_s: list[float] = []
        self.capture_delay_s: list[float] = []
        self._stats_t0 = time.monotonic()

    def _source_status(self) -> tuple[int, str] | None:
        """(ERROR, text) while the own source gives no frames, else None."""
        g = self.grabber
        if g is None:
            return None
        now = time.monotonic()
        if g.state == 'closed':
            return (
                diag.ERROR,
                f'waiting for the camera: {open_problem(g.spec)} (attempt {g.open_attempts})',
            )
        if g.state == 'lost':
            lost_s = now - g.lost_since_s if g.lost_since_s else 0.0
            return (
                diag.ERROR,
                f'camera lost {lost_s:.1f} s ago, reopening (attempt {g.open_attempts})',
            )
        if g.state == 'ended':
            return diag.ERROR, 'video file ended'
        silent_s = now - g.last_frame_s
        if silent_s > max(self.prm.source_timeout_s, 2.0 / max(self.camera.fps_hz, 1e-3)):
            return diag.ERROR, f'no frames for {silent_s:.1f} s'
        return None

    def _publish_diagnostics(self) -> None:
        elapsed = max(time.monotonic() - self._stats_t0, 1e-9)
        expected = self.frames * len(self.robot_of)
        lat = np.array(self.latency_s) if self.latency_s else np.zeros(1)
        values = {
            'frame_rate_hz': self.frames / elapsed,
            'detection_rate': self.detected / expected if expected else 0.0,
            'latency_mean_ms': float(lat.mean() * 1e3),
            'latency_max_ms': float(lat.max() * 1e3),
            'full_frame_fraction': self.full_frames / self.frames if self.frames else 0.0,
            'rejected_jumps': self.rejected,
            'bad_frames': self.bad_frames,
            'tracked_markers': len(self.tracker.tracked_ids) if self.tracker else 0,
            'frames_total': self.frames_total,
            'intrinsics_source': self.prm.intrinsics_source,
        }
        if self.prm.intrinsics_source == 'camera_info':
            values.update(
                {'camera_info_errors': self.info_errors,
                 'frames_waiting_camera_info': self.frames_waiting_info}
            )
        g = self.grabber
        if g is not None:
            delay = np.array(self.capture_delay_s) if self.capture_delay_s else np.zeros(1)
            values.update(
                {
                    'source_state': g.state,
                    'capture_delay_mean_ms': float(
                        delay.mean() * 1e3
                    ),  # grab -> tracker (poll timer)
                    'capture_errors': g.errors,
                    'reopens': g.reopens,
                }
            )
        source = self._source_status()
        if source is not None:
            level, text = source
        elif self.tracker is None:
            level = diag.ERROR
            text = f'waiting for camera_info on {self.info_topic} (intrinsics_source camera_info)'
            if self.last_info_error:
                text = f'no usable camera_info: {self.last_info_error}'
        elif self.frames == 0 and self.bad_frames:
            level, text = diag.ERROR, f'unusable frames: {self.last_bad_frame}'
        elif self.frames == 0:
            level, text = diag.WARN, 'no frames'
        elif expected and self.detected < 0.9 * expected:
            level, text = diag.WARN, 'markers missing'
        else:
            level, text = diag.OK, 'tracking'
        hardware_id = (
            g.spec.text if g is not None else 'camera'
        )  # the device (docs/diagnostics.md)
        statuses = [
            diag.status(
                diag.status_name(self.get_name(), 'camera tracking'),
                hardware_id,
                level,
                text,
                values,
            )
        ]
        if getattr(self, 'capture_watch', None) is not None:
            statuses.append(
                diag.status(
                    diag.status_name(self.get_name(), 'capture poll'),
                    hardware_id,
                    *self.capture_watch.status(),
                )
            )
        self.pub_diag.publish(diag.array(self.get_clock().now().to_msg(), statuses))
        self._reset_stats()

    def destroy_node(self) -> None:
        if self.grabber is not None:
            self.grabber.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Console script ``formation_tracker``. Exit status: 0 (SIGINT/SIGTERM), 1 (the source could
    not be opened: one line on stderr), 2 (bad configuration: one line).
    """
    made: list[TrackerNode] = []

    def make() -> TrackerNode:
        made.append(TrackerNode())
        return made[-1]

    try:
        status = run_node('formation_tracker', make, args)
    except SourceUnavailable as err:
        print(f'formation_tracker: {err}', file=sys.stderr)
        return 1
    if made and made[-1].failure:
        print(f'formation_tracker: {made[-1].failure}', file=sys.stderr)
        return 1
    return status


if __name__ == '__main__':
    sys.exit(main())
