"""Whole-system benchmarks (issue 5): run with `bench/run.sh bench_system.py
[--quick] [--team K] ...`.

1. End-to-end latency from a camera frame's capture stamp to the torque frame that the emulated
   motor board receives on its serial line, p50 / p99, with every node in one process and with
   the nodes as separate processes (scripts/launch_sim.sh-like: world in this process so the
   board's receive log is visible, everything else in its own process).
   Attribution: for each pose message of robot 0 (stamp = capture time), the first wheel_torque
   the controller stamped at or after the pose's DDS receive time at the probe (the same host: the
   controller's own copy arrives at about the same moment); that command's arrival at the board
   is found in the board's command log by its (quantised) torque values.
2. Robot count: the largest N (line formation, no obstacles, N controllers + N bridges as
   processes, 100 Hz control, 30 fps camera) with < 1 % missed control deadlines (late ticks from
   the controllers' /diagnostics) and the world keeping real time.

Options: --dds shm|udp (shared-memory Fast DDS profile config/fastdds_localhost_shm.xml, the
default here, or the loopback-UDP-only profile of the tests), --executor events|single (what the
node processes spin on, ros/executors.make_executor). The probe shares the world's process but
takes a pose's arrival from the middleware's receive stamp, so a busy world no longer pairs a pose
with a later torque (the over-estimate of earlier versions of this benchmark, up to a control
period). Only poses captured from 1 s after the mission start count: the start-up (processes
discovering each other, kernels loading) is not the loop.

Baseline for the ratios: the wire time of one torque frame at 115200 baud and the 10 ms control
period.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.tools.run_cmd import loopback_env  # noqa: E402

SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
SETTLE_S = (
    1.0  # latency counts poses captured this long after the mission start (not the start-up)
)


class LatencyProbe:
    """Subscribes to robot_<rid>/pose and robot_<rid>/wheel_torque; pairs them with the board
    log.
    """

    def __init__(self, node, rid: int = 0):
        from sensor_msgs.msg import JointState

        from ament_formation.ros import messages as m
        from ament_formation.ros.qos import QOS_CONTROL

        self.poses: list[tuple[float, float]] = []  # (capture stamp, DDS receive time, wall)
        self.torques: list[tuple[float, np.ndarray]] = []  # (publish stamp, efforts)
        # the pose's arrival is its DDS receive time (the middleware's, wall clock), not the
        # moment this process's executor ran the callback: a controller that runs its period on
        # the pose (tick_on_pose) stamps its torque before a busy probe gets there, and the
        # next period's torque would be paired instead (10 ms too late)
        node.create_subscription(
            m.PoseStamped,
            f'/robot_{rid}/pose',
            lambda msg, info: self.poses.append(
                (m.stamp_to_s(msg.header.stamp), info['received_timestamp'] * 1e-9)
            ),
            QOS_CONTROL,
        )
        node.create_subscription(
            JointState,
            f'/robot_{rid}/wheel_torque',
            lambda msg: self.torques.append(
                (m.stamp_to_s(msg.header.stamp), np.array(msg.effort))
            ),
            QOS_CONTROL,
        )

    def latencies_s(self, board_log: list, after_s: float = -np.inf) -> np.ndarray:
        """Capture -> board receive [s] per pose captured after ``after_s`` (wall clock)."""
        if not board_log or not self.torques:
            return np.zeros(0)
        log_t = np.array([e[0] for e in board_log])
        log_v = np.array([[e[2], e[3]] for e in board_log])
        tq_t = np.array([t for t, _ in self.torques])
        out = []
        for capture_s, arrival_s in self.poses:
            if capture_s < after_s:
                continue
            j = np.searchsorted(tq_t, arrival_s)
            if j >= len(tq_t):
                continue
            want = np.round(self.torques[j][1] * 1e4)
            k0 = np.searchsorted(log_t, tq_t[j] - 0.001)
            for k in range(k0, min(k0 + 20, len(log_t))):
                if np.all(np.abs(log_v[k] - want) <= 1):
                    out.append(log_t[k] - capture_s)
                    break
        return np.array(out)


class _ProbeThread:
    """The probe's node on a SingleThreadedExecutor of its own, in a thread (the probe's pose
    callback takes the message info, which the EventsExecutor of the world cannot give).
    """

    def __init__(self, node, context):
        import threading

        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='probe', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set() and self.executor.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)


def _wait_for_start(executor, world, timeout_s: float) -> bool:
    """Spin until the world has its mission start (the coordinator's start_s); False on timeout."""
    t0 = time.monotonic()
    while world.start_s is None and time.monotonic() - t0 < timeout_s:
        executor.spin_once(timeout_sec=0.01)
    return world.start_s is not None


def _spin_for(executor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)


def _percentiles(lat: np.ndarray) -> str:
    if len(lat) == 0:
        return 'no samples'
    return (
        f'p50 {1e3 * np.percentile(lat, 50):6.1f} ms  p99 {1e3 * np.percentile(lat, 99):6.1f} ms  '
        f'(n = {len(lat)})'
    )


def latency_in_process(seconds: float) -> np.ndarray:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from ament_formation.nodes.system import build_system

    ctx = Context()
    rclpy.init(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    system = build_system(ctx, SCENARIO, ex, start_delay_s=0.5)
    log: list = []
    system.world.boards[0].board.command_log = log
    probe_node = rclpy.create_node('_bench_probe', context=ctx)
    probe = LatencyProbe(probe_node)
    spinner = _ProbeThread(probe_node, ctx)
    try:
        _wait_for_start(ex, system.world, 60.0)
        _spin_for(ex, seconds)
        return probe.latencies_s(log, after_s=system.world.start_s + SETTLE_S)
    finally:
        spinner.close()
        system.destroy(ex)
        probe_node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _start(cmd: list[str], log_dir: Path, name: str) -> subprocess.Popen:
    return subprocess.Popen(
        cmd, stdout=open(log_dir / f'{name}.log', 'w'), stderr=subprocess.STDOUT
    )


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


TICK_ON_POSE: list[str] = []  # -p tick_on_pose:=... for controllers and teams (--tick-on-pose)


def node_processes(
    scenario_path: Path,
    pty_dir: Path,
    log_dir: Path,
    team: int = 0,
    control_nice: int | None = None,
) -> list[subprocess.Popen]:
    """Bridge + controller per robot, tracker, coordinator as processes (not the world).
    ``team`` > 0: the robots' bridges and controllers composed ``team`` robots per formation_team
    process (nodes/team.py) instead of two processes per robot.
    """
    from ament_formation.core.scenario.loader import load_scenario

    sc = load_scenario(scenario_path)
    b = ROOT / '.venv' / 'bin'
    ctl = [] if control_nice is None else ['nice', '-n', str(control_nice)]  # the control path
    controller = [*ctl, str(b / 'formation_controller')]
    procs = []
    ids = [r.id for r in sc.robots]
    for k in range(0, len(ids), team) if team > 0 else ():
        group = ids[k: k + team]
        procs.append(
            _start(
                [
                    *ctl,
                    str(b / 'formation_team'),
                    '--ros-args',
                    '-r',
                    f'formation_team:__node:=formation_team_{k // team}',
                    '-p',
                    f'scenario:={scenario_path}',
                    '-p',
                    f'robot_ids:={group}',
                    '-p',
                    f'port_template:={pty_dir}/robot_{{id}}',
                    '-p',
                    'poll_rate_hz:=200.0',
                    *TICK_ON_POSE,
                ],
                log_dir,
                f'team_{k // team}',
            )
        )
    for r in sc.robots if team <= 0 else ():
        ns = ['--ros-args', '-r', f'__ns:=/robot_{r.id}']
        procs.append(
            _start(
                [
                    *ctl,
                    str(b / 'formation_bridge'),
                    *ns,
                    '-p',
                    f'port:={pty_dir}/robot_{r.id}',
                    '-p',
                    f'torque_limit_nm:={r.params.torque_limit_nm}',
                    '-p',
                    'poll_rate_hz:=200.0',
                ],
                log_dir,
                f'bridge_{r.id}',
            )
        )
        procs.append(
            _start(
                [*controller, *ns, '-p', f'scenario:={scenario_path}', '-p', f'robot_id:={r.id}',
                 *TICK_ON_POSE],
                log_dir,
                f'controller_{r.id}',
            )
        )
    procs.append(
        _start(
            [
                str(b / 'formation_tracker'),
                '--ros-args',
                '-p',
                f'robot_ids:={ids}',
                '-p',
                f'marker_ids:={[r.marker_id for r in sc.robots]}',
            ],
            log_dir,
            'tracker',
        )
    )
    procs.append(
        _start(
            [
                str(b / 'formation_coordinator'),
                '--ros-args',
                '-p',
                f'scenario:={scenario_path}',
                '-p',
                'start_delay_s:=0.5',
            ],
            log_dir,
            'coordinator',
        )
    )
    return procs


def latency_multi_process(
    seconds: float, tmp: Path, team: int = 0, control_nice: int | None = None
) -> np.ndarray:
    import rclpy
    from rclpy.context import Context

    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.ros.executors import make_executor

    ctx = Context()
    rclpy.init(context=ctx)
    ex = make_executor(context=ctx)
    pty_dir = tmp / 'pty_lat'
    world = WorldNode(
        context=ctx, params=WorldParams(scenario=str(SCENARIO), pty_dir=str(pty_dir))
    )
    log: list = []
    world.boards[0].board.command_log = log
    probe_node = rclpy.create_node('_bench_probe', context=ctx)
    probe = LatencyProbe(probe_node)
    ex.add_node(world)
    spinner = _ProbeThread(probe_node, ctx)
    procs = node_processes(SCENARIO, pty_dir, tmp, team, control_nice)
    try:
        _wait_for_start(ex, world, 60.0)
        _spin_for(ex, seconds)
        return probe.latencies_s(log, after_s=world.start_s + SETTLE_S)
    finally:
        spinner.close()
        _stop(procs)
        world.destroy_node()
        probe_node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def line_scenario(n: int, path: Path) -> Path:
    if n > 21:
        raise SystemExit(f"line_scenario: at most 21 robots fit in the camera's view (asked {n})")
    """A leader on a straight line and N - 1 followers in rows of five behind it (0.45 m apart),
    all inside the camera's floor area (config/camera.yaml: 3 x 2.4 m around (1.2, 0.6); up to 21
    robots); star graph; no obstacles."""
    robots = [
        {
            'id': 0,
            'leader': True,
            'slot_m': [0.0, 0.0],
            'initial_pose': [1.8, 0.6, 0.0],
            'marker_id': 0,
            'path': {'type': 'line', 'start_m': [1.8, 0.6], 'heading_rad': 0.0, 'speed_mps': 0.03},
        }
    ]
    for i in range(1, n):
        row, col = divmod(i - 1, 5)
        dx, dy = -0.5 - 0.45 * row, -0.9 + 0.45 * col
        robots.append(
            {
                'id': i,
                'slot_m': [dx, dy],
                'initial_pose': [1.8 + dx, 0.6 + dy, 0.0],
                'marker_id': i,
            }
        )
    edges = [[0, i] for i in range(1, n)]
    path.write_text(
        yaml.safe_dump(
            {'name': f'line_{n}', 'duration_s': 25.0, 'robots': robots, 'graph': {'edges': edges}},
            sort_keys=False,
        )
    )
    return path


def robot_count(
    n: int, seconds: float, tmp: Path, team: int = 0, control_nice: int | None = None
) -> dict:
    """Run N robots through the whole system; missed-deadline fraction and world overruns."""
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from rclpy.context import Context

    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.ros.executors import make_executor
    from ament_formation.ros.qos import QOS_DIAGNOSTICS

    scenario = line_scenario(n, tmp / f'line_{n}.yaml')
    ctx = Context()
    rclpy.init(context=ctx)
    ex = make_executor(context=ctx)
    pty_dir = tmp / f'pty_{n}'
    world = WorldNode(
        context=ctx, params=WorldParams(scenario=str(scenario), pty_dir=str(pty_dir))
    )
    diag: dict[str, dict] = {}
    probe = rclpy.create_node('_bench_diag', context=ctx)

    def on_diag(msg):
        for st in msg.status:  # the control-loop status (a controller publishes several)
            vals = {kv.key: kv.value for kv in st.values}
            if st.name.startswith('formation_controller') and 'late_ticks' in vals:
                diag[st.name] = vals

    probe.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_DIAGNOSTICS)
    ex.add_node(world)
    ex.add_node(probe)
    procs = node_processes(scenario, pty_dir, tmp, team, control_nice)
    try:
        started = _wait_for_start(ex, world, 90.0)
        _spin_for(ex, 1.5)
        before = {k: (int(v['ticks']), int(v['late_ticks'])) for k, v in diag.items()}
        over0 = world.overruns
        _spin_for(ex, seconds)
        after = {k: (int(v['ticks']), int(v['late_ticks'])) for k, v in diag.items()}
        ticks = sum(after[k][0] - before.get(k, (0, 0))[0] for k in after)
        late = sum(after[k][1] - before.get(k, (0, 0))[1] for k in after)
        return {
            'n': n,
            'started': started,
            'controllers_reporting': len(after),
            'ticks': ticks,
            'late': late,
            'missed_fraction': late / ticks if ticks else float('nan'),
            'world_overruns': world.overruns - over0,
            'expected_ticks': int(100 * seconds * n),
        }
    finally:
        _stop(procs)
        world.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='shorter windows, fewer robot counts')
    ap.add_argument('--counts', type=int, nargs='*', default=None, help='robot counts to try')
    ap.add_argument('--skip-latency', action='store_true', help='only the robot-count table')
    ap.add_argument(
        '--dds',
        choices=('udp', 'shm'),
        default='udp',
        help='Fast DDS profile: udp = config/fastdds_localhost.xml (loopback UDP only), '
        'shm = config/fastdds_localhost_shm.xml (shared memory + loopback UDP)',
    )
    ap.add_argument(
        '--executor',
        choices=('events', 'single'),
        default='events',
        help='executor of the node processes and of the world (ros/executors.py)',
    )
    ap.add_argument(
        '--team',
        type=int,
        default=0,
        metavar='K',
        help="compose K robots' bridges and controllers per formation_team process "
        '(0: a bridge and a controller process per robot)',
    )
    ap.add_argument(
        '--control-nice',
        type=int,
        default=None,
        metavar='N',
        help='start the bridge/controller/team processes under `nice -n N` (like '
        'scripts/launch_sim.sh --control-nice; negative needs root)',
    )
    ap.add_argument(
        '--tick-on-pose',
        choices=('true', 'false'),
        default=None,
        help="the controllers' tick_on_pose parameter in the process layouts (default: the "
        "node's default, true): false runs the control period on the timer alone",
    )
    args = ap.parse_args()
    if args.tick_on_pose is not None:
        TICK_ON_POSE[:] = ['-p', f'tick_on_pose:={args.tick_on_pose}']
    tmp = Path(tempfile.mkdtemp(prefix='ament_formation_bench_'))
    profile = 'fastdds_localhost_shm.xml' if args.dds == 'shm' else 'fastdds_localhost.xml'
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(ROOT / 'config' / profile)
    os.environ['AMENT_FORMATION_EXECUTOR'] = args.executor
    print(
        f'DDS profile {profile}; executor {args.executor}; '
        + (f'{args.team} robots per formation_team process' if args.team else 'a process per node')
        + ('' if args.control_nice is None else f'; control processes at nice {args.control_nice}')
        + ('' if args.tick_on_pose is None else f'; tick_on_pose {args.tick_on_pose}')
    )
    try:
        loopback_env(tmp / 'ros_log')
        window = 5.0 if args.quick else 12.0
        wire_ms = 1e3 * 10 * 10 / 115200  # one 10-byte torque frame at 115200 baud, 10 bits/byte
        print(f'baseline: torque frame wire time {wire_ms:.2f} ms; control period 10 ms')
        if args.skip_latency:
            lat1 = lat2 = np.zeros(0)
        else:
            lat1 = latency_in_process(window)
            print(f'latency capture -> board, one process:    {_percentiles(lat1)}')
            lat2 = latency_multi_process(window, tmp, args.team, args.control_nice)
            print(f'latency capture -> board, processes:      {_percentiles(lat2)}')
        if len(lat1) and len(lat2):
            print(
                '  ratio p50 processes / one process: '
                f'{np.percentile(lat2, 50) / np.percentile(lat1, 50):.2f}; '
                f'p50 / wire time: {1e3 * np.percentile(lat2, 50) / wire_ms:.1f}'
            )
        counts = args.counts or ([2, 4, 6] if args.quick else [2, 4, 6, 8, 10, 12])
        print(f'{"robots":>6} {"ticks":>7} {"late":>6} {"missed %":>9} {"world overruns":>15}')
        best = 0
        for n in counts:
            r = robot_count(n, window, tmp, args.team, args.control_nice)
            print(
                f'{n:6d} {r["ticks"]:7d} {r["late"]:6d} {100 * r["missed_fraction"]:9.2f} '
                f'{r["world_overruns"]:15d}'
                + (
                    ''
                    if r['started'] and r['controllers_reporting'] == n
                    else '  (did not start / not all up)'
                )
            )
            if (
                r['started']
                and r['controllers_reporting'] == n
                and r['missed_fraction'] < 0.01
                and r['ticks'] >= 0.9 * r['expected_ticks']
                and r['world_overruns'] <= 0.01 * 100 * window
            ):
                best = n if best == counts[counts.index(n) - 1] or n == counts[0] else best
            elif r['missed_fraction'] > 0.5 or not r['started']:
                break
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(
        'largest robot count held in real time (< 1 % missed deadlines, every count up to it): '
        f'{best}'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
