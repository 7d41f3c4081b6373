"""formation_tracker capturing its own frames (``source``), through the console script:
run with `bench/run.sh bench_tracker_source.py [--frames 300] [--robots 4] [--seconds 10]
[--sources ''] [--trials 5]`.

1. Video file: rendered frames (core/vision/synthetic_camera.py, sensor noise σ = 2 grey levels)
   of K robots moving on Lissajous curves plus one "clock" robot on a circle whose position gives
   the
   frame index, written as MJPG .avi and played by the tracker at its 30 fps.
2. Loopback stream: the same frames served as MJPEG over HTTP on 127.0.0.1 (hw/mjpeg_stream.py,
   JPEG quality 90) at 30 fps, opened by the tracker through OpenCV's FFmpeg backend.
   For both: frames/s tracked, detection rate (poses of the K robots per frame in which the clock
   robot was seen), position / heading error p95 against the rendered truth (clock robot
   excluded), capture stamp → pose received p50/p95 (includes the ``capture_poll_s`` hand-over,
   the tracking and DDS), and the tracker process's CPU (% of one core).
3. Camera loss in the whole system (unless --no-system): formation_world (in this process) renders
   the scenario; this process serves its frames as an MJPEG stream; the tracker, the coordinator,
   and a bridge and controller per robot run as processes with the tracker reading the stream.
   Some seconds into the mission the stream is cut. Reported: from the last pose each controller
   got (its capture stamp) to the controller's controlled stop (mode "stopped" received) and to
   every robot at rest in the twin, against pose_timeout_s + one control period; then the stream
   comes back and the time until the robots drive again. At rest as in docs/safety.md: both
   wheels' rim speeds |v -+ (a/2) ω| below 5 mm/s (REST_SPEED_MPS), times on the twin's plant
   clock (the ROS time of the capture stamps). ``--trials N`` repeats the whole system run.

The machine is shared: say what else ran when quoting numbers.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.tools.run_cmd import loopback_env  # noqa: E402

BIN = ROOT / '.venv' / 'bin'
FPS_HZ = 30.0
CLOCK_MARKER = 40  # the clock robot: marker id = robot id
CLOCK_CENTER_M, CLOCK_RADIUS_M = (0.3, 0.6), 0.45
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'


# ---------------------------------------------------------------------- rendered truth
def truth(k: np.ndarray, n_frames: int, n_robots: int) -> np.ndarray:
    """(len(k), 1 + n_robots, 3) poses at frame indices k: the clock robot (one lap of its circle
    per n_frames), then robots on Lissajous curves in cells of the right part of the floor.
    """
    k = np.asarray(k, dtype=float)
    phi = 2 * np.pi * k / n_frames
    out = np.zeros((len(k), 1 + n_robots, 3))
    out[:, 0] = np.column_stack(
        [
            CLOCK_CENTER_M[0] + CLOCK_RADIUS_M * np.cos(phi),
            CLOCK_CENTER_M[1] + CLOCK_RADIUS_M * np.sin(phi),
            phi + np.pi / 2,
        ]
    )
    t = k / FPS_HZ
    for i in range(n_robots):
        row, col = divmod(i, 2)
        cx, cy = 1.3 + 0.75 * col, 1.45 - 0.6 * row
        w1, w2, p = 0.9 + 0.13 * i, 1.3 + 0.07 * i, 0.7 * i
        x, y = cx + 0.17 * np.sin(w1 * t + p), cy + 0.12 * np.sin(w2 * t)
        dx, dy = 0.17 * w1 * np.cos(w1 * t + p), 0.12 * w2 * np.cos(w2 * t)
        out[:, 1 + i] = np.column_stack([x, y, np.arctan2(dy, dx)])
    return out


def frame_index(clock_xy: np.ndarray, n_frames: int) -> int:
    phi = np.arctan2(clock_xy[1] - CLOCK_CENTER_M[1], clock_xy[0] - CLOCK_CENTER_M[0])
    return int(round(phi / (2 * np.pi / n_frames))) % n_frames


def render(n_frames: int, n_robots: int) -> list[np.ndarray]:
    from ament_formation.core.vision.camera_model import CameraSetup
    from ament_formation.core.vision.synthetic_camera import RenderOptions, SyntheticCamera

    setup = CameraSetup()
    sc = SyntheticCamera(setup.camera, options=RenderOptions(noise_std=2.0), floor=setup.floor)
    poses = truth(np.arange(n_frames), n_frames, n_robots)
    ids = [CLOCK_MARKER, *range(n_robots)]
    return [sc.render(poses[k], ids, frame_index=k) for k in range(n_frames)]


# ---------------------------------------------------------------------- processes
def cpu_s(pid: int) -> float:
    """User + system CPU time [s] of process ``pid`` so far."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def start(cmd: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=open(log, 'w'), stderr=subprocess.STDOUT)


def stop(procs: list[subprocess.Popen]) -> None:
    """SIGTERM our processes (by PID), SIGKILL what is left after 10 s."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def tracker_cmd(tmp: Path, name: str, params: dict) -> list[str]:
    path = tmp / f'{name}.yaml'
    params = {
        k: list(v) if isinstance(v, list) else v for k, v in params.items()
    }  # no YAML aliases
    path.write_text(yaml.safe_dump({'/**/formation_tracker': {'ros__parameters': params}}))
    return [str(BIN / 'formation_tracker'), '--ros-args', '--params-file', str(path)]


# ---------------------------------------------------------------------- 1 + 2: accuracy, rate
class PoseProbe:

    def __init__(self, node, robot_ids: list[int]):
        from geometry_msgs.msg import PoseStamped

        from ament_formation.ros.messages import pose_from_msg, stamp_to_ns
        from ament_formation.ros.qos import QOS_CONTROL

        self.poses: dict[int, list[tuple[int, int, np.ndarray]]] = {r: [] for r in robot_ids}
        clock = node.get_clock()

        def on_pose(msg, r):
            self.poses[r].append(
                (stamp_to_ns(msg.header.stamp), clock.now().nanoseconds, pose_from_msg(msg)[0])
            )

        for r in robot_ids:
            node.create_subscription(
                PoseStamped, f'/robot_{r}/pose', lambda m, r=r: on_pose(m, r), QOS_CONTROL
            )

    def count(self) -> int:
        return len(self.poses[CLOCK_MARKER])


def evaluate(probe: PoseProbe, n_frames: int, n_robots: int, t0_ns: int, t1_ns: int) -> dict:
    """Metrics of the poses whose capture stamps lie in [t0_ns, t1_ns)."""
    clock = {ns: p for ns, _, p in probe.poses[CLOCK_MARKER] if t0_ns <= ns < t1_ns}
    stamps = {ns for r in probe.poses for ns, _, _ in probe.poses[r] if t0_ns <= ns < t1_ns}
    pos, head, delay, seen = [], [], [], 0
    for r in range(n_robots):
        for ns, rx, p in probe.poses[r]:
            if ns not in clock:
                continue
            k = frame_index(clock[ns][:2], n_frames)
            t = truth(np.array([k]), n_frames, n_robots)[0, 1 + r]
            pos.append(np.hypot(*(p[:2] - t[:2])))
            head.append(abs((p[2] - t[2] + np.pi) % (2 * np.pi) - np.pi))
            delay.append((rx - ns) * 1e-9)
            seen += 1
    span_s = (max(stamps) - min(stamps)) * 1e-9 if len(stamps) > 1 else float('nan')
    pos, head, delay = np.array(pos), np.array(head), np.array(delay)
    return {
        'frames': len(stamps),
        'fps': (len(stamps) - 1) / span_s if len(stamps) > 1 else 0.0,
        'detection': seen / (len(clock) * n_robots) if clock else 0.0,
        'pos_p95_mm': float(np.percentile(pos, 95) * 1e3) if len(pos) else float('nan'),
        'pos_max_mm': float(pos.max() * 1e3) if len(pos) else float('nan'),
        'head_p95_deg': float(np.degrees(np.percentile(head, 95))) if len(head) else float('nan'),
        'delay_p50_ms': float(np.percentile(delay, 50) * 1e3) if len(delay) else float('nan'),
        'delay_p95_ms': float(np.percentile(delay, 95) * 1e3) if len(delay) else float('nan'),
    }


def run_source(
    ctx, kind: str, frames: list[np.ndarray], n_robots: int, seconds: float, tmp: Path
) -> dict:
    """Track ``frames`` from a video file or a loopback MJPEG stream; the metrics of evaluate()."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from ament_formation.hw.mjpeg_stream import MjpegServer

    n_frames = len(frames)
    server = None
    if kind == 'file':
        source = str(tmp / 'overhead.avi')
        writer = cv2.VideoWriter(
            source, cv2.VideoWriter_fourcc(*'MJPG'), FPS_HZ, (640, 480), isColor=False
        )
        for f in frames:
            writer.write(f)
        writer.release()
    else:
        server = MjpegServer(quality=90)
        source = server.start()
        server.play(frames, FPS_HZ)
    robot_ids = [CLOCK_MARKER, *range(n_robots)]
    ex = SingleThreadedExecutor(context=ctx)
    node = rclpy.create_node(f'_bench_tracker_probe_{kind}', context=ctx)
    probe = PoseProbe(node, robot_ids)
    ex.add_node(node)
    proc = start(
        tracker_cmd(
            tmp,
            kind,
            {
                'source': source,
                'source_loop': kind == 'file',
                'marker_ids': robot_ids,
                'robot_ids': robot_ids,
                'publish_covariance': False,
            },
        ),
        tmp / f'tracker_{kind}.log',
    )
    try:
        deadline = time.monotonic() + 120.0
        while probe.count() < 10 and time.monotonic() < deadline and proc.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        if probe.count() < 10:
            log = (tmp / f'tracker_{kind}.log').read_text().strip().splitlines()[-5:]
            raise SystemExit(f"{kind}: no poses; the tracker's log ends:\n" + '\n'.join(log))
        t0_ns, c0 = node.get_clock().now().nanoseconds, cpu_s(proc.pid)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        t1_ns, c1 = node.get_clock().now().nanoseconds, cpu_s(proc.pid)
        res = evaluate(probe, n_frames, n_robots, t0_ns, t1_ns)
        res['cpu_pct'] = 100.0 * (c1 - c0) / seconds
        return res
    finally:
        stop([proc])
        if server is not None:
            server.close()
        ex.remove_node(node)
        node.destroy_node()
        ex.shutdown()


# ---------------------------------------------------------------------- 3: camera loss in the
# system
def camera_loss(ctx, tmp: Path, run_s: float) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from std_msgs.msg import String

    from ament_formation.core.control.stop import REST_SPEED_MPS
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.hw.mjpeg_stream import MjpegServer
    from ament_formation.nodes.controller import ControllerParams
    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.ros.executors import make_executor
    from ament_formation.ros.image import image_to_mono8
    from ament_formation.ros.messages import stamp_to_ns
    from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS

    sc = load_scenario(SCENARIO)
    ids = [r.id for r in sc.robots]
    ctl = ControllerParams.__dataclass_fields__
    pose_timeout_s = ctl['pose_timeout_s'].default
    period_s = 1.0 / ctl['control_rate_hz'].default
    ex = make_executor(context=ctx)
    pty = tmp / 'pty'
    world = WorldNode(
        context=ctx,
        params=WorldParams(scenario=str(SCENARIO), pty_dir=str(pty), exit_at_end=False),
    )
    server = MjpegServer(quality=90)
    url = server.start()
    node = rclpy.create_node('_bench_loss_probe', context=ctx)
    publish_image = world.pub_image.publish

    def camera_out(msg) -> None:  # every rendered frame also goes out on the MJPEG stream
        server.publish(image_to_mono8(msg))
        publish_image(msg)

    world.pub_image.publish = camera_out
    last_pose_ns = dict.fromkeys(ids, 0)
    stopped_at: dict[int, float] = {}
    modes: dict[int, str] = {}

    cut_ns = [None]  # set when the stream is cut
    late_poses = []  # (robot, capture stamp [s]) of poses captured after the cut

    def on_pose(msg, r):
        ns = stamp_to_ns(msg.header.stamp)
        if cut_ns[0] is not None and ns > cut_ns[0]:
            late_poses.append((r, (ns - cut_ns[0]) * 1e-9))  # a buffered frame, or another system
        last_pose_ns[r] = ns

    resumed_at: dict[int, float] = {}

    def on_mode(msg, r):
        before, modes[r] = modes.get(r), json.loads(msg.data).get('mode', '')
        if modes[r] == 'stopped' and r not in stopped_at:
            stopped_at[r] = time.time()
        if before == 'stopped' and modes[r] != 'stopped' and r not in resumed_at:
            resumed_at[r] = time.time()

    loop_stalls: dict[int, tuple[int, float]] = {}  # robot -> (stalls, last stall gap [s])

    def on_diagnostics(arr) -> None:  # the controllers' control-loop stalls (ros/diagnostics.py)
        for st in arr.status:
            for r in ids:
                if st.name == f'formation_controller: robot_{r} control loop':
                    kv = {x.key: x.value for x in st.values}
                    loop_stalls[r] = (
                        int(kv.get('stalls', 0)),
                        float(kv.get('last_stall_gap_s', 0)),
                    )

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, QOS_DIAGNOSTICS)
    for r in ids:
        node.create_subscription(
            PoseStamped, f'/robot_{r}/pose', lambda m, r=r: on_pose(m, r), QOS_CONTROL
        )
        node.create_subscription(
            String, f'/robot_{r}/mode', lambda m, r=r: on_mode(m, r), QOS_CONTROL
        )
    ex.add_node(world)
    ex.add_node(node)
    procs = []
    for r in sc.robots:
        ns = ['--ros-args', '-r', f'__ns:=/robot_{r.id}']
        procs.append(
            start(
                [
                    str(BIN / 'formation_bridge'),
                    *ns,
                    '-p',
                    f'port:={pty}/robot_{r.id}',
                    '-p',
                    f'torque_limit_nm:={r.params.torque_limit_nm}',
                ],
                tmp / f'bridge_{r.id}.log',
            )
        )
        procs.append(
            start(
                [
                    str(BIN / 'formation_controller'),
                    *ns,
                    '-p',
                    f'scenario:={SCENARIO}',
                    '-p',
                    f'robot_id:={r.id}',
                ],
                tmp / f'controller_{r.id}.log',
            )
        )
    procs.append(
        start(
            tracker_cmd(
                tmp,
                'system',
                {'source': url, 'robot_ids': ids, 'marker_ids': [r.marker_id for r in sc.robots]},
            ),
            tmp / 'tracker_system.log',
        )
    )
    procs.append(
        start(
            [
                str(BIN / 'formation_coordinator'),
                '--ros-args',
                '-p',
                f'scenario:={SCENARIO}',
                '-p',
                'start_delay_s:=0.5',
            ],
            tmp / 'coordinator.log',
        )
    )

    def spin_for(seconds: float, until=None) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.005)
            if until is not None and until():
                return True
        return False

    half_axle = np.array([0.5 * r.params.axle_length_m for r in sc.robots])

    def speeds() -> tuple[float, float]:
        st = world.twin.state
        return float(np.abs(st[:, 3]).max()), float(np.abs(st[:, 4]).max())

    def rim_speed() -> float:
        """The fastest wheel's rim speed over every robot [m/s] (|v| + (a/2)|ω|)."""
        st = world.twin.state
        return float(np.max(np.abs(st[:, 3]) + half_axle * np.abs(st[:, 4])))

    try:
        if not spin_for(120.0, lambda: world.start_s is not None):
            raise SystemExit(
                'camera loss: the mission did not start (see the logs in ' + str(tmp) + ')'
            )
        spin_for(run_s)

        def tracked() -> bool:  # every controller drives on fresh camera poses
            now_ns = node.get_clock().now().nanoseconds
            return all(
                modes.get(r) not in (None, 'hold', 'stopped') and now_ns - last_pose_ns[r] < 0.2e9
                for r in ids
            )

        steady_since = None
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.005)
            if not tracked():
                steady_since = None
            elif steady_since is None:
                steady_since = time.monotonic()
            elif time.monotonic() - steady_since > 2.0:
                break
        else:
            tails = '\n'.join(
                f'--- {log.name}\n' + '\n'.join(log.read_text().splitlines()[-6:])
                for log in sorted(tmp.glob('*.log'))
            )
            raise SystemExit(
                f'camera loss: robots not driving on camera poses (modes {modes}, last pose '
                f'{[(time.time_ns() - last_pose_ns[r]) * 1e-9 for r in ids]} s ago)\n{tails}'
            )
        v_before, w_before = speeds()
        rim_before = rim_speed()
        stopped_at.clear()
        server.stop()
        cut_s = time.time()
        cut_ns[0] = time.time_ns()
        stalls_at_cut = {r: loop_stalls.get(r, (0, 0.0))[0] for r in ids}
        at_rest_s = None  # plant time of the first state at rest after the last one moving
        plant_s = world.plant_time_s
        end = time.monotonic() + 10.0
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.002)
            if world.plant_time_s == plant_s:
                continue
            plant_s = world.plant_time_s
            if rim_speed() < REST_SPEED_MPS:
                if at_rest_s is None:
                    at_rest_s = plant_s
            else:
                at_rest_s = None
            if at_rest_s is not None and len(stopped_at) == len(ids) and plant_s - at_rest_s > 1.0:
                break
        # what the controllers last got before the stream comes back (it brings new poses)
        last_pose = {r: last_pose_ns[r] * 1e-9 for r in ids}
        after_cut = list(late_poses)
        stalls = {  # control-loop stalls (> 3 periods) counted from the cut to rest
            r: (
                loop_stalls.get(r, (0, 0.0))[0] - stalls_at_cut[r],
                loop_stalls.get(r, (0, 0.0))[1],
            )
            for r in ids
        }
        cut_ns[0] = None
        stopped = dict(stopped_at)
        last_pose_s = max(last_pose.values())
        if os.environ.get('BENCH_DEBUG'):
            print(
                'modes after the cut:',
                modes,
                'stopped_at:',
                stopped_at,
                'last pose ages:',
                [time.time() - last_pose_ns[r] * 1e-9 for r in ids],
            )
            for log in sorted(tmp.glob('*.log')):
                print(f'--- {log.name}\n' + '\n'.join(log.read_text().splitlines()[-8:]))
        # the stream back: poses again, controllers leave the stop, robots drive
        back_s = time.time()
        resumed_at.clear()
        server.start()
        moving = spin_for(30.0, lambda: len(resumed_at) == len(ids) and speeds()[0] > 0.01)
        return {
            'pose_timeout_s': pose_timeout_s,
            'control_period_s': period_s,
            'speed_before_mps': v_before,
            'omega_before_radps': w_before,
            'rim_speed_before_mps': rim_before,
            'cut_after_last_pose_s': cut_s - last_pose_s,
            'stop_after_last_pose_s': {r: stopped[r] - last_pose[r] for r in stopped},
            'rest_after_last_pose_s': None if at_rest_s is None else at_rest_s - last_pose_s,
            'poses_after_cut': after_cut,
            'control_stalls': stalls,
            'driving_again_after_s': (time.time() - back_s)
            if moving and len(stopped) == len(ids)
            else None,
        }
    finally:
        stop(procs)
        server.close()
        ex.remove_node(world)
        ex.remove_node(node)
        world.destroy_node()
        node.destroy_node()
        ex.shutdown()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument(
        '--frames', type=int, default=300, help='rendered frames (one lap of the clock robot)'
    )
    ap.add_argument('--robots', type=int, default=4, help='robots besides the clock robot (<= 6)')
    ap.add_argument('--seconds', type=float, default=10.0, help='measured window per source [s]')
    ap.add_argument('--sources', default='file,stream', help='which of file,stream to measure')
    ap.add_argument('--no-system', action='store_true', help='skip the camera-loss system run')
    ap.add_argument(
        '--system-run-s', type=float, default=5.0, help='mission time before the cut [s]'
    )
    ap.add_argument(
        '--trials', type=int, default=1, help='camera-loss system runs (a fresh system each)'
    )
    args = ap.parse_args()
    if not 1 <= args.robots <= 6:
        ap.error('--robots: 1..6')
    with tempfile.TemporaryDirectory(prefix='bench_tracker_source_') as tmp_name:
        tmp = Path(tmp_name)
        loopback_env(tmp / 'ros_log')
        import rclpy
        from rclpy.context import Context

        ctx = Context()
        rclpy.init(context=ctx)
        print(f'load average before: {os.getloadavg()[0]:.1f} (2 cores shared)')
        frames = render(args.frames, args.robots)
        print(
            f'{args.frames} frames, {args.robots} robots + the clock robot, '
            f'{args.seconds:g} s per source'
        )
        print(
            '| source | frames/s | detection | position p95 (max) | heading p95 '
            '| capture→pose p50 / p95 | tracker CPU |'
        )
        print('|---|---|---|---|---|---|---|')
        for kind in [k for k in args.sources.split(',') if k]:
            r = run_source(ctx, kind, frames, args.robots, args.seconds, tmp)
            print(
                f'| {kind} | {r["fps"]:.1f} | {100 * r["detection"]:.2f} % | '
                f'{r["pos_p95_mm"]:.2f} '
                f'({r["pos_max_mm"]:.2f}) mm | {r["head_p95_deg"]:.2f}° | '
                f'{r["delay_p50_ms"]:.1f} / '
                f'{r["delay_p95_ms"]:.1f} ms | {r["cpu_pct"]:.0f} % |',
                flush=True,
            )
        rests = []
        for trial in range(0 if args.no_system else args.trials):
            trial_tmp = tmp / f'trial_{trial}'
            trial_tmp.mkdir()
            r = camera_loss(ctx, trial_tmp, args.system_run_s)
            bound = r['pose_timeout_s'] + r['control_period_s']
            print(
                f'\ncamera loss, trial {trial} ({SCENARIO.name}, stream cut '
                f'{args.system_run_s:g} s into the mission; robots at up to '
                f'{r["speed_before_mps"]:.3f} m/s, {r["omega_before_radps"]:.2f} rad/s, wheel rim '
                f'{r["rim_speed_before_mps"]:.3f} m/s; load average {os.getloadavg()[0]:.1f}):'
            )
            print(f"  cut {r['cut_after_last_pose_s']:.3f} s after the last pose's capture")
            late = r['poses_after_cut']
            if late:  # a frame the tracker still had, or (seconds later) another system's poses
                print(
                    f'  {len(late)} pose(s) stamped after the cut, the latest '
                    f'{max(t for _, t in late):.3f} s after it (counted as the last pose)'
                )
            for rid, s in sorted(r['stop_after_last_pose_s'].items()):
                print(
                    f'  robot {rid}: controlled stop (mode received) {s:.3f} s after its last pose'
                )
            for rid, (n, gap) in sorted(r['control_stalls'].items()):
                if n:  # the stop is applied by the control loop: a stalled loop delays it
                    print(
                        f'  robot {rid}: control loop stalled {n}x since the cut (last {gap:.3f}s)'
                    )
            rest = r['rest_after_last_pose_s']
            rests.append(rest)
            print(
                "  all robots at rest (both wheels' rim speeds < 5 mm/s): "
                f'{"not within 10 s" if rest is None else f"{rest:.3f} s after the last pose"} '
                f'(pose_timeout_s + one control period = {bound:.3f} s)'
            )
            again = r['driving_again_after_s']
            print(
                f'  stream back: robots driving again after '
                f'{"(not within 30 s)" if again is None else f"{again:.2f} s"}',
                flush=True,
            )
        if rests:
            worst = None if None in rests else max(rests)
            print(
                f'\nall robots at rest after the last pose, {len(rests)} trial(s): '
                + ', '.join('-' if x is None else f'{x:.3f}' for x in rests)
                + ' s; worst '
                + ('not at rest' if worst is None else f'{worst:.3f} s')
                + f' (pose_timeout_s + one control period = {bound:.3f} s: '
                + ('FAILED' if worst is None or worst > bound else 'met')
                + ')'
            )
        print(f'load average after: {os.getloadavg()[0]:.1f}')
        rclpy.try_shutdown(context=ctx)
    return 0


if __name__ == '__main__':
    sys.exit(main())
