"""formation_tracker: overhead camera frames → each robot's pose (core/marker_tracking.py).

Contract

| topic | type | QoS | direction |
|---|---|---|---|
| /camera/image_raw (``image_topic``) | sensor_msgs/Image (mono8, bgr8, rgb8, mono16, …) | QOS_IMAGE | subscribed when ``source`` is empty |
| robot_<id>/pose | geometry_msgs/PoseStamped, frame ``world``, stamp = capture time | QOS_CONTROL | published per frame the robot's marker is seen |
| robot_<id>/pose_cov | geometry_msgs/PoseWithCovarianceStamped (same pose, σ² of x, y, yaw) | QOS_CONTROL | when ``publish_covariance`` |
| ~/debug_image | sensor_msgs/Image bgr8 (markers, poses drawn) | QOS_IMAGE | when ``publish_debug_image`` |
| /diagnostics | diagnostic_msgs/DiagnosticArray (frame rate, detection rate, latency) | QOS_DIAGNOSTICS | every ``diagnostics_period_s`` |

Parameters (TrackerNodeParams)
  source               str     "" = subscribe image_topic; a number = video device index; else a
                               path/URL for cv2.VideoCapture (read in a thread)        default ""
  source_loop          bool    replay a video file from the start when it ends         default false
  image_topic          str     topic of frames                                         default /camera/image_raw
  camera_config        str     camera.yaml (config/ name or path)                      default camera.yaml
  marker_ids           int[]   marker id per robot                                     default [0, 1]
  robot_ids            int[]   robot id for each entry of marker_ids                   default [0, 1]
  dictionary           str     ArUco dictionary                                        default DICT_4X4_50
  marker_size_m        float   marker side [m]                                         default 0.12
  marker_offset_m      float[] marker centre in the controlled point's body frame [m]  default [-0.05, 0.0]
  marker_height_m      float   marker plane above the floor [m]                        default 0.08
  max_speed_mps        float   faster apparent motion is rejected as a jump [m/s]      default 1.5
  use_roi              bool    region-of-interest search around predicted poses        default true
  publish_covariance   bool                                                            default true
  publish_debug_image  bool                                                            default false
  diagnostics_period_s float   [s]                                                     default 1.0

With ``source`` set, a thread grabs frames (stamped with the node clock at grab time) and hands
the newest to the executor through a guard condition: the executor never blocks on the camera.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.node import Node
from sensor_msgs.msg import Image

from ament_formation.core.camera_model import load_camera_yaml
from ament_formation.core.errors import ConfigError
from ament_formation.core.marker_tracking import MarkerTracker, TrackerConfig
from ament_formation.core.params import param
from ament_formation.core.paths_config import config_file
from ament_formation.core.robot_marker import MarkerLayout
from ament_formation.ros import diagnostics as diag
from ament_formation.ros.image import image_to_mono8, numpy_to_image
from ament_formation.ros.executors import run_node
from ament_formation.ros.messages import pose_stamped, stamp_to_s
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS, QOS_IMAGE


@dataclass(frozen=True)
class TrackerNodeParams:
    """Parameters of formation_tracker (see the module docstring)."""

    source: str = ""
    source_loop: bool = param(False, "replay a video file from the start when it ends")
    image_topic: str = param("/camera/image_raw", "topic of frames when source is empty")
    camera_config: str = param("camera.yaml", "camera calibration: a config/ file name or a path")
    marker_ids: tuple[int, ...] = param((0, 1), "ArUco marker id of each robot")
    robot_ids: tuple[int, ...] = param((0, 1), "robot id for each entry of marker_ids")
    dictionary: str = param("DICT_4X4_50", "ArUco dictionary")
    marker_size_m: float = param(0.12, "marker side [m]")
    marker_offset_m: tuple[float, ...] = param(
        (-0.05, 0.0), "marker centre in the controlled point's body frame [x, y] [m]")
    marker_height_m: float = param(0.08, "marker plane above the floor [m]")
    max_speed_mps: float = param(1.5, "faster apparent motion is rejected as a jump [m/s]")
    use_roi: bool = param(True, "search around the predicted poses first")
    publish_covariance: bool = param(True, "also publish robot_<id>/pose_cov")
    publish_debug_image: bool = param(False, "publish ~/debug_image (bgr8, markers drawn)")
    diagnostics_period_s: float = param(1.0, "/diagnostics period [s], > 0")

    def __post_init__(self) -> None:
        if len(self.marker_ids) != len(self.robot_ids):
            raise ConfigError(f"{len(self.robot_ids)} robot ids for {len(self.marker_ids)} marker ids",
                              "robot_ids")
        for name in ("marker_ids", "robot_ids"):
            v = getattr(self, name)
            if len(set(v)) != len(v) or any(not isinstance(i, int) or i < 0 for i in v):
                raise ConfigError(f"must be distinct integers >= 0 (got {list(v)})", name)
        if not self.source and not self.image_topic:
            raise ConfigError("is empty and no source is set", "image_topic")
        if not (math.isfinite(self.diagnostics_period_s) and self.diagnostics_period_s > 0):
            raise ConfigError(f"must be > 0 s (got {self.diagnostics_period_s})", "diagnostics_period_s")
        self.layout()
        TrackerConfig(max_speed_mps=self.max_speed_mps, use_roi=self.use_roi)

    def layout(self) -> MarkerLayout:
        return MarkerLayout(self.dictionary, self.marker_size_m, tuple(self.marker_offset_m),
                            self.marker_height_m)


def _camera_path(name: str) -> Path:
    p = Path(name)
    return p if p.is_file() else config_file(name)


class _Capture(threading.Thread):
    """Grabs frames from cv2.VideoCapture; keeps only the newest (frame, stamp)."""

    def __init__(self, source: str, clock, on_frame, loop: bool = False) -> None:
        super().__init__(daemon=True, name="formation_tracker_capture")
        self._source = int(source) if source.isdigit() else source
        self._clock = clock
        self._on_frame = on_frame
        self._loop = loop
        self._halt = threading.Event()
        self._lock = threading.Lock()
        self._latest = None
        self.errors = 0
        self.ended = False

    def take(self):
        with self._lock:
            item, self._latest = self._latest, None
        return item

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        backoff_s = 0.1
        while not self._halt.is_set():
            cap = cv2.VideoCapture(self._source)
            if not cap.isOpened():
                self.errors += 1
                self._halt.wait(backoff_s)
                backoff_s = min(2 * backoff_s, 2.0)
                continue
            backoff_s = 0.1
            is_file = isinstance(self._source, str) and "://" not in self._source
            fps = cap.get(cv2.CAP_PROP_FPS) if is_file else 0.0
            period_s = 1.0 / fps if fps and 0 < fps < 1000 else (1.0 / 30.0 if is_file else 0.0)
            next_s = time.monotonic()
            while not self._halt.is_set():
                if period_s:  # a file plays at its own frame rate, like a camera would
                    next_s += period_s
                    self._halt.wait(max(next_s - time.monotonic(), 0.0))
                if not cap.grab():
                    break
                stamp = self._clock.now().to_msg()
                ok, frame = cap.retrieve()
                if not ok:
                    self.errors += 1
                    continue
                if frame.ndim == 3:
                    frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                with self._lock:
                    self._latest = (np.ascontiguousarray(frame), stamp)
                self._on_frame()
            cap.release()
            if is_file and not self._loop:
                self.ended = True  # a video file ran out
                return


class TrackerNode(Node):
    """See the module docstring."""

    def __init__(self, *, context=None, params: TrackerNodeParams | None = None, **node_kw) -> None:
        super().__init__("formation_tracker", context=context, **node_kw)
        self.prm = params if params is not None else declare_dataclass(self, TrackerNodeParams)
        setup = load_camera_yaml(_camera_path(self.prm.camera_config))
        self.camera = setup.camera
        self.tracker = MarkerTracker(self.camera, self.prm.layout(),
                                     TrackerConfig(max_speed_mps=self.prm.max_speed_mps,
                                                   use_roi=self.prm.use_roi),
                                     expected_ids=tuple(self.prm.marker_ids))
        self.robot_of = dict(zip(self.prm.marker_ids, self.prm.robot_ids))
        self.pub_pose = {m: self.create_publisher(PoseStamped, f"robot_{r}/pose", QOS_CONTROL)
                         for m, r in self.robot_of.items()}
        self.pub_cov = ({m: self.create_publisher(PoseWithCovarianceStamped, f"robot_{r}/pose_cov",
                                                  QOS_CONTROL) for m, r in self.robot_of.items()}
                        if self.prm.publish_covariance else {})
        self.pub_debug = (self.create_publisher(Image, "~/debug_image", QOS_IMAGE)
                          if self.prm.publish_debug_image else None)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", QOS_DIAGNOSTICS)
        self._reset_stats()
        self.frames_total = 0
        self.capture = None
        if self.prm.source:
            self._guard = self.create_guard_condition(self._on_captured)
            self.capture = _Capture(self.prm.source, self.get_clock(), self._guard.trigger,
                                    loop=self.prm.source_loop)
            self.capture.start()
        else:
            self.create_subscription(Image, self.prm.image_topic, self._on_image, QOS_IMAGE)
        self.create_timer(self.prm.diagnostics_period_s, self._publish_diagnostics)

    # ------------------------------------------------------------------ frames
    def _on_image(self, msg: Image) -> None:
        try:
            frame = image_to_mono8(msg)
        except ValueError as err:
            self.bad_frames += 1
            self.get_logger().warn(f"{self.prm.image_topic}: {err}", throttle_duration_sec=5.0)
            return
        self.process(frame, msg.header.stamp)

    def _on_captured(self) -> None:
        item = self.capture.take() if self.capture is not None else None
        if item is not None:
            self.process(*item)

    def process(self, frame: np.ndarray, stamp) -> None:
        """One frame (mono8) captured at ``stamp`` → pose messages."""
        t0 = time.perf_counter()
        try:
            result = self.tracker.step(frame, stamp_to_s(stamp))
        except ValueError as err:
            self.bad_frames += 1
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
            self.pub_debug.publish(numpy_to_image(self._annotate(frame, acc), "bgr8", stamp))

    def _annotate(self, frame: np.ndarray, acc) -> np.ndarray:
        img = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        if len(acc):
            cv2.aruco.drawDetectedMarkers(img, [c.reshape(1, 4, 2).astype(np.float32) for c in acc.corners_px],
                                          acc.ids.reshape(-1, 1).astype(np.int32))
            tips = acc.poses[:, :2] + 0.15 * np.column_stack([np.cos(acc.poses[:, 2]), np.sin(acc.poses[:, 2])])
            h = self.prm.marker_height_m
            p0 = self.camera.floor_to_pixel(acc.poses[:, :2], h)
            p1 = self.camera.floor_to_pixel(tips, h)
            for a, b, mid in zip(p0, p1, acc.ids):
                cv2.arrowedLine(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (0, 0, 255), 2)
                r = self.robot_of.get(int(mid))
                if r is not None:
                    cv2.putText(img, f"robot {r}", (int(a[0]) + 8, int(a[1]) - 8),
                                cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 0), 1)
        return img

    # ------------------------------------------------------------------ diagnostics
    def _reset_stats(self) -> None:
        self.frames = 0
        self.full_frames = 0
        self.detected = 0
        self.rejected = 0
        self.bad_frames = 0
        self.latency_s: list[float] = []
        self._stats_t0 = time.monotonic()

    def _publish_diagnostics(self) -> None:
        elapsed = max(time.monotonic() - self._stats_t0, 1e-9)
        expected = self.frames * len(self.robot_of)
        lat = np.array(self.latency_s) if self.latency_s else np.zeros(1)
        values = {
            "frame_rate_hz": self.frames / elapsed,
            "detection_rate": self.detected / expected if expected else 0.0,
            "latency_mean_ms": float(lat.mean() * 1e3),
            "latency_max_ms": float(lat.max() * 1e3),
            "full_frame_fraction": self.full_frames / self.frames if self.frames else 0.0,
            "rejected_jumps": self.rejected,
            "bad_frames": self.bad_frames,
            "tracked_markers": len(self.tracker.tracked_ids),
            "frames_total": self.frames_total,
        }
        if self.capture is not None:
            values["capture_errors"] = self.capture.errors
        if self.frames == 0:
            level, text = diag.WARN, "no frames"
        elif expected and self.detected < 0.9 * expected:
            level, text = diag.WARN, "markers missing"
        else:
            level, text = diag.OK, "tracking"
        status = diag.status("formation_tracker: camera tracking", self.prm.source or self.prm.image_topic,
                             level, text, values)
        self.pub_diag.publish(diag.array(self.get_clock().now().to_msg(), [status]))
        self._reset_stats()

    def destroy_node(self) -> None:
        if self.capture is not None:
            self.capture.stop()
            self.capture.join(timeout=2.0)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node("formation_tracker", TrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
