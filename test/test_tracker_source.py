"""formation_tracker capturing frames itself (``source``), run as the console script with a params
file, the way a lab runs it: a rendered video file and an MJPEG stream served on loopback become
poses close to the rendered truth, stamped at capture, with camera_info next to the frames; a
missing source is one line and exit status 1 (also ``-p source:=0`` and ``launch_base.sh --camera
0`` on a machine without /dev/video0); a stream cut mid-run is a diagnostics ERROR, and tracking
resumes when it comes back; SIGINT and SIGTERM end it cleanly.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
import numpy as np
from processes import program
import pytest
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
import yaml

from ament_formation.core.vision.camera_model import CameraSetup
from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera
from ament_formation.hw.mjpeg_stream import free_port, MjpegServer
from ament_formation.ros.executors import spin_until
from ament_formation.ros.messages import pose_from_msg, stamp_to_ns
from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS, QOS_IMAGE

ROOT = Path(__file__).resolve().parents[1]
MARKERS, ROBOTS = (3, 7), (60, 61)  # robot ids no simulation uses: a run that happens to share
# our DDS domain on a busy machine does not feed our topics
N_FRAMES = 90
CLOCK_STEP_M = 0.01  # robot 0 moves 1 cm per frame along x: its pose tells the frame index
START_TIMEOUT_S = 180.0  # first pose: process start-up on a loaded 2-core machine


def truth(k: np.ndarray | int) -> np.ndarray:
    """(K, 2, 3) poses at frame indices ``k``: robot 0 on a line (the frame clock), robot 1 on an
    arc of radius 0.4 m, turning 0.02 rad per frame.
    """
    k = np.atleast_1d(np.asarray(k, dtype=float))
    phi = 0.02 * k
    r0 = np.column_stack([0.2 + CLOCK_STEP_M * k, np.zeros_like(k), np.zeros_like(k)])
    r1 = np.column_stack([1.5 + 0.4 * np.cos(phi), 0.8 + 0.4 * np.sin(phi), phi + np.pi / 2])
    return np.stack([r0, r1], axis=1)


def render_frames(n: int = N_FRAMES) -> list[np.ndarray]:
    setup = CameraSetup()
    sc = SyntheticCamera(setup.camera, options=RenderOptions(noise_std=2.0), floor=setup.floor)
    return [sc.render(truth(k)[0], MARKERS, frame_index=k) for k in range(n)]


def write_video(path: Path, frames: list[np.ndarray], fps_hz: float = 30.0) -> Path:
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter_fourcc(*'MJPG'), fps_hz, (640, 480), isColor=False
    )
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def params_file(tmp_path: Path, **params) -> Path:
    base = {'marker_ids': list(MARKERS), 'robot_ids': list(ROBOTS), 'diagnostics_period_s': 0.5}
    base.update(params)
    path = tmp_path / 'tracker.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': base}}))
    return path


def start_tracker(tmp_path: Path, *ros_args: str, **params) -> subprocess.Popen:
    args = [
        program('formation_tracker'),
        '--ros-args',
        '--params-file',
        str(params_file(tmp_path, **params)),
        *ros_args,
    ]
    err = open(tmp_path / f'tracker_{time.monotonic_ns()}.err', 'w+')
    proc = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=err, text=True, env=os.environ.copy()
    )
    proc.err_file = err
    return proc


def stderr_of(proc: subprocess.Popen) -> str:
    """What the tracker wrote on stderr so far."""
    proc.err_file.flush()
    return Path(proc.err_file.name).read_text()


def finish(
    proc: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 20.0
) -> tuple[int, str]:
    """Signal the tracker (if still running), wait for it; (exit status, stderr)."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail(f'formation_tracker did not end within {timeout_s} s of signal {sig}')
    return proc.returncode, stderr_of(proc)


class Probe(Node):
    """Everything the tracker publishes, with receive times; diagnostics of the tracker whose
    hardware_id is ``source`` (set it before starting the tracker).
    """

    def __init__(
        self, context, robots: tuple[int, ...] = ROBOTS, name: str = 'tracker_source_probe'
    ):
        super().__init__(name, context=context)
        self.source = ''
        self.robots = robots
        self.poses: dict[int, list[tuple[PoseStamped, int]]] = {r: [] for r in robots}
        self.diags: list[DiagnosticStatus] = []
        self.infos: list[CameraInfo] = []
        self.images: list[Image] = []
        clock = self.get_clock()
        for r in robots:
            self.create_subscription(
                PoseStamped,
                f'/robot_{r}/pose',
                lambda m, r=r: self.poses[r].append((m, clock.now().nanoseconds)),
                QOS_CONTROL,
            )
        self.create_subscription(
            DiagnosticArray,
            '/diagnostics',
            lambda m: self.diags.extend(
                s
                for s in m.status
                if s.name.startswith('formation_tracker')
                and s.name.endswith('camera tracking')
                and s.hardware_id == self.source
            ),
            QOS_DIAGNOSTICS,
        )
        self.create_subscription(CameraInfo, '/camera/camera_info', self.infos.append, QOS_IMAGE)
        self.create_subscription(Image, '/camera/image_raw', self.images.append, QOS_IMAGE)


@pytest.fixture
def probe(ros_context, executor):
    node = Probe(ros_context)
    executor.add_node(node)
    yield node
    executor.remove_node(node)
    node.destroy_node()


def pose_errors(probe: Probe, since_ns: int = 0) -> dict:
    """Match each frame's poses to the rendered truth through robot 0 (the frame clock).

    Returns frame indices, stamps, and position [m] / heading [rad] errors of both robots.
    """
    by_stamp: dict[int, dict[int, np.ndarray]] = {}  # stamp -> {robot index: pose}
    for i, r in enumerate(probe.robots):
        for m, _ in probe.poses[r]:
            ns = stamp_to_ns(m.header.stamp)
            if ns >= since_ns:
                by_stamp.setdefault(ns, {})[i] = pose_from_msg(m)[0]
    frames, pos_err, head_err = [], [], []
    for ns in sorted(by_stamp):
        poses = by_stamp[ns]
        if 0 not in poses:
            continue
        k = int(round((poses[0][0] - 0.2) / CLOCK_STEP_M))
        t = truth(k)[0]
        frames.append((ns, k))
        for r, p in poses.items():
            pos_err.append(np.hypot(*(p[:2] - t[r, :2])))
            head_err.append(abs((p[2] - t[r, 2] + np.pi) % (2 * np.pi) - np.pi))
    return {'frames': frames, 'pos': np.array(pos_err), 'head': np.array(head_err)}


def levels_seen(probe: Probe) -> list[tuple[int, str]]:
    return [(s.level, s.message) for s in probe.diags]


def assert_tracked_like_truth(probe: Probe, since_ns: int, min_frames: int) -> dict:
    res = pose_errors(probe, since_ns)
    assert len(res['frames']) >= min_frames, f'only {len(res["frames"])} frames tracked'
    # JPEG (quality 90 in the stream, MJPG in the file) on top of sensor noise: well under 1 mm
    # typically; a few mm on frames where the constant-velocity prediction is far off (track
    # start, the ping-pong reversal, frames skipped on a busy machine). A frame matched to the
    # wrong truth would be off by a frame's motion (8-10 mm) on every pose.
    pos, head = res['pos'], res['head']
    assert np.median(pos) < 1e-3 and np.percentile(pos, 95) < 5e-3 and pos.max() < 10e-3, pos
    assert np.median(head) < np.radians(0.5) and np.percentile(head, 95) < np.radians(1.5), (
        np.degrees(head)
    )
    return res


def test_video_file_becomes_poses_with_capture_stamps(tmp_path, probe, executor):
    rendered = write_video(tmp_path / 'rendered.avi', render_frames())
    video = tmp_path / 'overhead.avi'
    t_start_ns = probe.get_clock().now().nanoseconds
    probe.source = str(video)
    # the file appears once this probe hears the tracker (source_wait_s: the tracker waits for
    # its source): a file plays from its opening, and discovery took up to 3 s on a busy machine,
    # longer than these 90 frames
    proc = start_tracker(tmp_path, source=str(video), source_wait_s=START_TIMEOUT_S)
    try:
        pose_subs = [s for s in probe.subscriptions if s.topic_name.endswith('/pose')]
        assert spin_until(
            executor,
            lambda: proc.poll() is not None or all(s.get_publisher_count() for s in pose_subs),
            START_TIMEOUT_S,
        ), 'the tracker was not discovered'
        assert proc.poll() is None, stderr_of(proc)
        rendered.rename(video)
        assert spin_until(
            executor,
            lambda: (
                proc.poll() is not None
                or any(s.message == 'video file ended' for s in probe.diags)
            ),
            START_TIMEOUT_S + N_FRAMES / 30.0,
        ), 'the file did not play to its end'
        assert proc.poll() is None, stderr_of(proc)
        res = assert_tracked_like_truth(probe, 0, min_frames=N_FRAMES // 3)
        # a frame's poses carry the time it was grabbed: after the test started, before receipt
        for r in probe.robots:
            for m, received_ns in probe.poses[r]:
                assert t_start_ns < stamp_to_ns(m.header.stamp) <= received_ns
        # the file plays at its own 30 fps (frames skipped rather than played late on a busy
        # machine): stamp differences follow the frame index
        ks = np.array([k for _, k in res['frames']])
        ns = np.array([n for n, _ in res['frames']])
        rate_hz = (ks[-1] - ks[0]) / ((ns[-1] - ns[0]) * 1e-9)
        assert 24.0 < rate_hz < 36.0, rate_hz
        # camera_info next to the frames: the calibration, with frame stamps
        assert probe.infos, 'no camera_info'
        info = probe.infos[-1]
        assert (info.width, info.height, info.distortion_model) == (640, 480, 'plumb_bob')
        assert info.k[0] == pytest.approx(540.0) and info.d[0] == pytest.approx(-0.18)
        pose_stamps = {stamp_to_ns(m.header.stamp) for m, _ in probe.poses[ROBOTS[0]]}
        assert pose_stamps & {stamp_to_ns(i.header.stamp) for i in probe.infos}
        # the captured frames themselves, while someone subscribes
        assert probe.images and probe.images[-1].encoding == 'mono8'
        assert stamp_to_ns(probe.images[-1].header.stamp) in {
            stamp_to_ns(i.header.stamp) for i in probe.infos
        }
        assert levels_seen(probe)[-1][0] == DiagnosticStatus.ERROR  # the file ended
    finally:
        status, err = finish(proc, signal.SIGINT)
    assert status == 0 and 'Traceback' not in err, err


def test_stream_on_loopback_and_camera_loss(tmp_path, probe, executor):
    server = MjpegServer()
    url = server.start()
    server.play(render_frames(), fps_hz=30.0)
    probe.source = url
    proc = start_tracker(tmp_path, source=url, source_timeout_s=0.5)
    try:
        # 1. decoded stream frames -> poses like the truth
        assert spin_until(
            executor,
            lambda: proc.poll() is not None or len(pose_errors(probe)['frames']) >= 60,
            START_TIMEOUT_S,
        ), 'no poses from the stream'
        assert proc.poll() is None, stderr_of(proc)
        assert_tracked_like_truth(probe, 0, min_frames=60)
        assert spin_until(  # the first diagnostics may come after the first 60 frames' poses
            executor,
            lambda: any(lv == DiagnosticStatus.OK for lv, _ in levels_seen(probe)),
            10.0,
        ), levels_seen(probe)
        # 2. the stream is cut: diagnostics ERROR, no poses of frames after the cut
        n_diag = len(probe.diags)
        server.stop()
        cut_ns = probe.get_clock().now().nanoseconds
        assert spin_until(
            executor,
            lambda: any(
                s.level == DiagnosticStatus.ERROR and 'camera lost' in s.message
                for s in probe.diags[n_diag:]
            ),
            20.0,
        ), levels_seen(probe)[n_diag:]
        lost_ns = probe.get_clock().now().nanoseconds
        assert all(
            stamp_to_ns(m.header.stamp) <= cut_ns
            for m, rx in probe.poses[ROBOTS[0]]
            if rx > lost_ns
        )
        # 3. the stream is back on the same port: tracking resumes, diagnostics OK again
        back_ns = probe.get_clock().now().nanoseconds
        server.start()
        assert spin_until(
            executor, lambda: len(pose_errors(probe, back_ns)['frames']) >= 40, 60.0
        ), f'tracking did not resume: {levels_seen(probe)[-5:]}\n{stderr_of(proc)}'
        # judged from the tenth frame on: the tracks start again after the cut, and a track's
        # first frames carry its start-up error (under load: 2.4 deg of heading on two of them)
        settled_ns = pose_errors(probe, back_ns)['frames'][10][0]
        assert_tracked_like_truth(probe, settled_ns, min_frames=30)
        n_diag = len(probe.diags)
        assert spin_until(
            executor,
            lambda: any(s.level == DiagnosticStatus.OK for s in probe.diags[n_diag:]),
            10.0,
        )
        values = {kv.key: kv.value for kv in probe.diags[-1].values}
        assert int(values['reopens']) >= 1 and values['source_state'] == 'open'
    finally:
        server.close()
        status, err = finish(proc, signal.SIGTERM)
    assert status == 0 and 'Traceback' not in err, err


@pytest.mark.parametrize(
    'source, line',
    [
        (
            '/nonexistent/overhead.avi',
            "formation_tracker: source '/nonexistent/overhead.avi': no such file",
        ),
        (
            'http://127.0.0.1:9/stream.mjpg',
            "formation_tracker: source 'http://127.0.0.1:9/stream.mjpg': cannot open the stream",
        ),
    ],
)
def test_missing_source_is_one_line_and_status_1(tmp_path, source, line):
    proc = start_tracker(tmp_path, source=source)
    proc.wait(timeout=180)
    err = stderr_of(proc)
    assert proc.returncode == 1
    assert len(err.strip().splitlines()) == 1 and err.startswith(line), err


def test_waiting_for_a_camera_that_appears_late(tmp_path, probe, executor):
    """source_wait_s: the node runs with diagnostics ERROR while it retries; the stream starts ->
    poses; a camera that never appears ends the process with the one line and status 1.
    """
    server = MjpegServer(port=free_port())
    probe.source = server.url
    proc = start_tracker(tmp_path, source=server.url, source_wait_s=300.0)
    try:
        assert spin_until(
            executor,
            lambda: proc.poll() is not None or 'retrying for 300 s' in stderr_of(proc),
            START_TIMEOUT_S,
        ), stderr_of(proc)
        assert spin_until(
            executor,
            lambda: (
                proc.poll() is not None
                or any(
                    s.level == DiagnosticStatus.ERROR
                    and s.message.startswith('waiting for the camera')
                    for s in probe.diags
                )
            ),
            30.0,
        ), f'{levels_seen(probe)}\n{stderr_of(proc)}'
        assert proc.poll() is None
        server.start()
        server.play(render_frames(), fps_hz=30.0)
        assert spin_until(executor, lambda: len(pose_errors(probe)['frames']) >= 30, 60.0), (
            'no poses'
        )
        assert_tracked_like_truth(probe, 0, min_frames=30)
    finally:
        server.close()
        status, err = finish(proc, signal.SIGINT)
    assert status == 0 and 'Traceback' not in err, err
    late = start_tracker(tmp_path, source='/nonexistent/overhead.avi', source_wait_s=1.0)
    late.wait(timeout=180)
    err = stderr_of(late)
    assert late.returncode == 1
    assert err.strip().splitlines()[-1] == (
        "formation_tracker: source '/nonexistent/overhead.avi': no such file (waited 1 s)"
    ), err


@pytest.mark.skipif(os.path.exists('/dev/video0'), reason='this machine has a /dev/video0')
def test_device_index_from_the_command_line(tmp_path):
    proc = start_tracker(tmp_path, '-p', 'source:=0')  # an INTEGER parameter
    proc.wait(timeout=180)
    err = stderr_of(proc)
    assert proc.returncode == 1
    assert err.strip() == "formation_tracker: source '0': no such video device /dev/video0", err


def _launch_base(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, Path]:
    run_dir = tmp_path / 'run'
    proc = subprocess.Popen(
        [str(ROOT / 'scripts' / 'launch_base.sh'), *args, '--run-dir', str(run_dir), '--loopback'],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    return proc, run_dir


def _run_pids(run_dir: Path) -> list[int]:
    path = run_dir / 'pids'
    return (
        [int(line.split()[0]) for line in path.read_text().splitlines()] if path.exists() else []
    )


@pytest.mark.skipif(os.path.exists('/dev/video0'), reason='this machine has a /dev/video0')
def test_launch_base_with_camera_0(tmp_path):
    # the shipped params file sets source: "" -- the launcher's --camera must win over it
    proc, run_dir = _launch_base(
        tmp_path,
        '--scenario',
        str(ROOT / 'config' / 'scenarios' / 'paper.yaml'),
        '--params',
        str(ROOT / 'config' / 'params' / 'formation_tracker.yaml'),
        '--camera',
        '0',
    )
    try:
        out, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    assert proc.returncode == 1, out
    assert 'tracker exited with status 1' in out
    log = (run_dir / 'tracker.log').read_text()
    assert "formation_tracker: source '0': no such video device /dev/video0" in log
    assert 'InvalidParameterType' not in log and 'Traceback' not in log


def test_launch_base_with_camera_file(tmp_path, ros_context, executor):
    """The camera PC's launcher with --camera FILE: the scenario's robots tracked from the file."""
    from processes import alive

    text = (ROOT / 'test' / 'data' / 'paper_short.yaml').read_text()
    scenario = tmp_path / 'markers_3_7.yaml'
    scenario.write_text(
        text.replace('marker_id: 0', f'marker_id: {MARKERS[0]}').replace(
            'marker_id: 1', f'marker_id: {MARKERS[1]}'
        )
    )
    video = write_video(tmp_path / 'overhead.avi', render_frames())
    params = tmp_path / 'base.yaml'
    params.write_text(
        yaml.safe_dump(
            {
                '/**/formation_tracker': {
                    'ros__parameters': {
                        'source_loop': True,
                        'marker_ids': [0, 1],
                        'robot_ids': [5, 6],
                    }
                }
            }
        )
    )  # ids: the scenario wins
    probe = Probe(ros_context, robots=(0, 1), name='launch_base_probe')  # the scenario's robots
    executor.add_node(probe)
    proc, run_dir = _launch_base(
        tmp_path, '--scenario', str(scenario), '--camera', str(video), '--params', str(params)
    )
    try:
        assert spin_until(
            executor,
            lambda: proc.poll() is not None or len(pose_errors(probe)['frames']) >= 30,
            START_TIMEOUT_S,
        ), 'no poses through launch_base.sh --camera FILE'
        assert proc.poll() is None, proc.communicate()[0]
        assert_tracked_like_truth(probe, 0, min_frames=30)
    finally:
        pids = _run_pids(run_dir)
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        executor.remove_node(probe)
        probe.destroy_node()
    assert proc.returncode == 143, out
    assert pids and not any(alive(pid) for pid in pids)
    assert 'Traceback' not in (run_dir / 'tracker.log').read_text()
