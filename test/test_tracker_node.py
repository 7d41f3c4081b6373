"""formation_tracker in-process: rendered frames of moving robots in, PoseStamped out with the
right ids, stamps (= image capture stamps) and poses; diagnostics, debug image, covariance;
a video file opened by the node itself, under both executors a process may spin; the
``source`` forms; the capture thread's loss/reopen/backoff; image conversions without
cv_bridge; the world's camera_info.
(The console script with real sources: test_tracker_source.py.).
"""

from __future__ import annotations

from pathlib import Path

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
import numpy as np
import pytest
from rclpy.node import Node
from sensor_msgs.msg import Image

from ament_formation.core.errors import ConfigError
from ament_formation.core.vision.camera_model import CameraSetup
from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera
from ament_formation.nodes.tracker import TrackerNode, TrackerNodeParams
from ament_formation.ros.executors import spin_until
from ament_formation.ros.image import image_to_mono8, image_to_numpy, numpy_to_image
from ament_formation.ros.messages import pose_from_msg, stamp_from_s, stamp_to_ns
from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS, QOS_IMAGE

SETUP = CameraSetup()
MARKERS, ROBOTS = (3, 7), (0, 1)


def _truth(t_s: float) -> np.ndarray:
    """(2, 3) poses of two robots driving arcs at 0.2 m/s."""
    return np.array(
        [
            [0.3 + 0.2 * t_s, 0.1, 0.0],
            [1.5 + 0.2 * np.cos(0.5 * t_s + 1.0) * t_s, 1.2 - 0.1 * t_s, 0.5 * t_s + 1.0],
        ]
    )


class _Probe(Node):

    def __init__(self, context):
        super().__init__('tracker_probe', context=context)
        self.poses: dict[int, list[PoseStamped]] = {r: [] for r in ROBOTS}
        self.covs: list[PoseWithCovarianceStamped] = []
        self.diags: list[DiagnosticArray] = []
        self.debug: list[Image] = []
        for r in ROBOTS:
            self.create_subscription(
                PoseStamped, f'robot_{r}/pose', lambda m, r=r: self.poses[r].append(m), QOS_CONTROL
            )
        self.create_subscription(
            PoseWithCovarianceStamped, 'robot_1/pose_cov', self.covs.append, QOS_CONTROL
        )
        self.create_subscription(
            DiagnosticArray, '/diagnostics', self.diags.append, QOS_DIAGNOSTICS
        )
        self.create_subscription(
            Image, '/formation_tracker/debug_image', self.debug.append, QOS_IMAGE
        )
        self.pub = self.create_publisher(Image, '/camera/image_raw', QOS_IMAGE)


def test_rendered_frames_become_pose_messages(ros_context, executor):
    params = TrackerNodeParams(
        marker_ids=MARKERS, robot_ids=ROBOTS, publish_debug_image=True, diagnostics_period_s=0.25
    )
    tracker = TrackerNode(context=ros_context, params=params)
    probe = _Probe(ros_context)
    executor.add_node(tracker)
    executor.add_node(probe)
    try:
        assert spin_until(
            executor,
            lambda: (
                probe.pub.get_subscription_count() >= 1
                and all(p.get_subscription_count() >= 1 for p in tracker.pub_pose.values())
            ),
            10.0,
        )
        sc = SyntheticCamera(SETUP.camera, options=RenderOptions(noise_std=2.0), floor=SETUP.floor)
        sent = []
        for k in range(20):
            t_s = 100.0 + k / 30.0  # capture times (e.g. sim time) – not the wall clock
            stamp = stamp_from_s(t_s)
            probe.pub.publish(
                numpy_to_image(sc.render(_truth(k / 30.0), MARKERS, frame_index=k), 'mono8', stamp)
            )
            sent.append((stamp_to_ns(stamp), _truth(k / 30.0)))
            spin_until(
                executor,
                lambda: all(
                    any(stamp_to_ns(m.header.stamp) == sent[-1][0] for m in probe.poses[r])
                    for r in ROBOTS
                ),
                3.0,
            )
        truth_of = dict(sent)
        for i, r in enumerate(ROBOTS):
            msgs = probe.poses[r]
            assert len(msgs) >= 18  # best-effort images: allow a drop
            for m in msgs:
                assert m.header.frame_id == 'world'
                ns = stamp_to_ns(m.header.stamp)
                assert ns in truth_of  # stamp = the image's capture stamp
                pose, _ = pose_from_msg(m)
                truth = truth_of[ns][i]
                assert np.hypot(*(pose[:2] - truth[:2])) < 5e-3
                assert abs((pose[2] - truth[2] + np.pi) % (2 * np.pi) - np.pi) < np.radians(1.0)
        assert probe.covs and all(
            0 < c.pose.covariance[0] < 1e-4 and 0 < c.pose.covariance[35] < 1e-3
            for c in probe.covs
        )
        assert spin_until(executor, lambda: bool(probe.debug), 3.0)
        dbg = image_to_numpy(probe.debug[-1])
        assert probe.debug[-1].encoding == 'bgr8' and dbg.shape == (480, 640, 3)
        assert (dbg[:, :, 2].astype(int) - dbg[:, :, 0]).max() > 100  # red pose arrows drawn

        def diag_with_frames():
            for arr in probe.diags:
                values = {kv.key: kv.value for kv in arr.status[0].values}
                if int(values['frames_total']) >= 18 and float(values['frame_rate_hz']) > 0:
                    return values
            return None

        assert spin_until(executor, lambda: diag_with_frames() is not None, 3.0)
        values = diag_with_frames()
        assert float(values['detection_rate']) > 0.9
        assert float(values['latency_mean_ms']) > 0
    finally:
        executor.remove_node(tracker)
        executor.remove_node(probe)
        tracker.destroy_node()
        probe.destroy_node()


@pytest.mark.parametrize('executor_kind', ['single', 'events'])
def test_the_node_opens_a_video_source_itself(ros_context, executor_kind, tmp_path):
    """Both executors a node process may spin (ros/executors.py make_executor) take the frames the
    capture thread grabs (no guard condition: the EventsExecutor has none).
    """
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    video = tmp_path / 'overhead.avi'
    writer = cv2.VideoWriter(
        str(video), cv2.VideoWriter_fourcc(*'MJPG'), 30.0, (640, 480), isColor=False
    )
    assert writer.isOpened()
    sc = SyntheticCamera(SETUP.camera, options=RenderOptions(noise_std=2.0), floor=SETUP.floor)
    for k in range(15):
        writer.write(sc.render(_truth(k / 30.0), MARKERS, frame_index=k))
    writer.release()
    params = TrackerNodeParams(
        source=str(video),
        source_loop=True,
        marker_ids=MARKERS,
        robot_ids=ROBOTS,
        publish_covariance=False,
    )
    executor = (EventsExecutor if executor_kind == 'events' else SingleThreadedExecutor)(
        context=ros_context
    )
    probe = _Probe(ros_context)
    tracker = TrackerNode(context=ros_context, params=params)
    executor.add_node(tracker)
    executor.add_node(probe)
    try:
        t0 = tracker.get_clock().now()
        assert spin_until(executor, lambda: all(len(probe.poses[r]) >= 3 for r in ROBOTS), 20.0)
        for i, r in enumerate(ROBOTS):
            pose, _ = pose_from_msg(probe.poses[r][-1])
            assert stamp_to_ns(probe.poses[r][-1].header.stamp) >= t0.nanoseconds  # grab time
            # somewhere on the robot's recorded path (JPEG compression: a few mm)
            path = np.array([_truth(k / 30.0)[i, :2] for k in range(15)])
            assert np.linalg.norm(path - pose[:2], axis=1).min() < 0.01
    finally:
        executor.remove_node(tracker)
        executor.remove_node(probe)
        tracker.destroy_node()
        probe.destroy_node()
        executor.shutdown()
    assert not tracker.grabber.is_alive()


def test_source_parameter_forms():
    """``source``: device index (int or digits), device path, stream URL, file; bad types
    refused.
    """
    from ament_formation.hw.video_source import DEVICE, FILE, parse_source, STREAM

    assert parse_source('') is None and parse_source(None) is None
    assert (parse_source(0).kind, parse_source(0).target, parse_source(0).device_path) == (
        DEVICE,
        0,
        '/dev/video0',
    )
    assert (parse_source('2').kind, parse_source('2').target) == (DEVICE, 2)
    assert (
        parse_source('/dev/v4l/by-id/usb-cam-video-index0').device_path
        == '/dev/v4l/by-id/usb-cam-video-index0'
    )
    assert parse_source('rtsp://10.0.0.5:554/live').kind == STREAM
    assert parse_source('http://127.0.0.1:8080/stream.mjpg').kind == STREAM
    assert parse_source('runs/overhead.avi').kind == FILE
    for bad in (1.5, True, [0], -1):
        with pytest.raises(ConfigError, match='source'):
            TrackerNodeParams(source=bad)
    assert TrackerNodeParams(source=0).source_spec.kind == DEVICE
    with pytest.raises(ConfigError, match='source_wait_s'):
        TrackerNodeParams(source_wait_s=-1.0)


def test_capture_loss_and_reopen_with_backoff():
    """The grabber of a live source: lost when grab fails, reopened with growing waits, frames
    resume; a file that ends is 'ended'.
    """
    import threading
    import time

    from ament_formation.hw.video_source import FrameGrabber, SourceSpec

    class FakeCapture:

        def __init__(self, frames):
            self.frames = frames

        def grab(self):
            if self.frames <= 0:
                return False
            self.frames -= 1
            time.sleep(0.002)
            return True

        def retrieve(self):
            return True, np.zeros((4, 6, 3), np.uint8)

        def get(self, prop):
            return 0.0

        def release(self):
            pass

    attempts, lock = [], threading.Lock()
    plan = iter([5, None, None, None, 5])  # open, lost, two failed reopens, back

    def opener(spec):
        with lock:
            attempts.append(time.monotonic())
        n = next(plan, None)
        return None if n is None else FakeCapture(n)

    g = FrameGrabber(
        SourceSpec('stream', 'http://x', 'http://x'),
        now=time.monotonic,
        backoff_s=(0.02, 0.08),
        opener=opener,
    )
    assert g.try_open() and g.state == 'open'
    g.start()
    deadline = time.monotonic() + 10.0
    while g.reopens < 1 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert g.reopens == 1
    gaps = np.diff(attempts)  # lost at once after the 5 frames, then waits of 0.02, 0.04, 0.08 s
    assert len(attempts) == 5 and gaps[0] < 1.0
    assert gaps[1] >= 0.0195 and gaps[2] >= 0.0395 and gaps[3] >= 0.0795
    while g.frames < 10 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert g.frames == 10 and g.take()[0].shape == (4, 6)  # grey
    g.stop()
    assert not g.is_alive()

    f = FrameGrabber(
        SourceSpec('file', 'x.avi', 'x.avi'),
        now=time.monotonic,
        opener=lambda spec: FakeCapture(3),
    )
    assert f.try_open()
    f.start()
    f.join(timeout=5.0)
    assert f.state == 'ended' and f.frames == 3


def test_bad_parameters_are_refused():
    with pytest.raises(ConfigError, match='robot_ids'):
        TrackerNodeParams(marker_ids=(1, 2), robot_ids=(0,))
    with pytest.raises(ConfigError, match='marker_ids'):
        TrackerNodeParams(marker_ids=(1, 1), robot_ids=(0, 1))
    with pytest.raises(ConfigError, match='size_m'):
        TrackerNodeParams(marker_size_m=-0.1)


def test_image_conversions_round_trip_without_cv_bridge():
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (5, 7), dtype=np.uint8)
    msg = numpy_to_image(grey, 'mono8')
    assert msg.step == 7 and np.array_equal(image_to_mono8(msg), grey)
    bgr = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert np.array_equal(
        image_to_mono8(numpy_to_image(bgr, 'bgr8')), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )
    rgb = np.ascontiguousarray(bgr[:, :, ::-1])
    assert np.array_equal(
        image_to_mono8(numpy_to_image(rgb, 'rgb8')), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )
    deep = rng.integers(0, 65536, (5, 7), dtype=np.uint16)
    m16 = numpy_to_image(deep, 'mono16')
    assert np.array_equal(image_to_numpy(m16), deep)
    assert np.array_equal(image_to_mono8(m16), (deep >> 8).astype(np.uint8))
    # big-endian 16 bit with padded rows
    padded = Image(height=5, width=7, encoding='mono16', is_bigendian=1, step=16)
    raw = np.zeros((5, 16), np.uint8)
    raw[:, :14] = deep.astype('>u2').view(np.uint8).reshape(5, 14)
    padded.data = raw.tobytes()
    assert np.array_equal(image_to_numpy(padded), deep)
    with pytest.raises(ValueError, match='encoding'):
        image_to_numpy(Image(height=1, width=1, encoding='yuv422', step=2, data=b'\0\0'))
    with pytest.raises(ValueError, match='data'):
        image_to_numpy(Image(height=4, width=4, encoding='mono8', step=4, data=b'\0' * 8))


def test_world_publishes_camera_info_with_each_image(ros_context, executor, tmp_path):
    """The simulated camera (formation_world) sends /camera/camera_info from config/camera.yaml
    with every /camera/image_raw, stamped like the image.
    """
    from sensor_msgs.msg import CameraInfo

    from ament_formation.nodes.world import WorldNode, WorldParams

    scenario = Path(__file__).resolve().parent / 'data' / 'paper_short.yaml'
    world = WorldNode(
        context=ros_context,
        params=WorldParams(
            scenario=str(scenario), pty_dir=str(tmp_path / 'pty'), exit_at_end=False
        ),
    )
    probe = Node('camera_info_probe', context=ros_context)
    images, infos = [], []
    probe.create_subscription(Image, '/camera/image_raw', images.append, QOS_IMAGE)
    probe.create_subscription(CameraInfo, '/camera/camera_info', infos.append, QOS_IMAGE)
    executor.add_node(world)
    executor.add_node(probe)
    try:
        assert spin_until(executor, lambda: len(images) >= 5 and len(infos) >= 5, 20.0)
        image_stamps = {stamp_to_ns(m.header.stamp) for m in images}
        assert len({stamp_to_ns(i.header.stamp) for i in infos} & image_stamps) >= 4
        info = infos[-1]
        cam = SETUP.camera
        assert (
            (info.width, info.height)
            == (cam.width_px, cam.height_px)
            == (images[-1].width, images[-1].height)
        )
        assert info.header.frame_id == images[-1].header.frame_id
        assert np.allclose(np.reshape(info.k, (3, 3)), cam.k) and np.allclose(
            info.d, cam.distortion
        )
        assert (
            np.allclose(np.reshape(info.p, (3, 4))[:, :3], cam.k)
            and info.distortion_model == 'plumb_bob'
        )
    finally:
        executor.remove_node(world)
        executor.remove_node(probe)
        world.destroy_node()
        probe.destroy_node()
