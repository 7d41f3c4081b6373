"""The programs users start: every node's console script (``formation_*``, found on PATH or in the
install prefix by processes.program) as a subprocess with its installed params file
(config/params/<node>.yaml), watched from this test's own rclpy context (a private Context per
ROS domain).

Three sets of processes start together at module set-up, each on its own ROS domain:

* ``mission``: formation_world, formation_tracker, formation_coordinator and a formation_team
  hosting both robots of test/data/paper_short.yaml on the world's emulated boards: the mission
  runs through the real programs (images -> poses -> graph -> torques -> the world's plant).
* ``boards``: formation_bridge + formation_controller for robot 0 and formation_team for robot 1
  on emulated motor boards this test owns (ament_formation/hw/pty_board.py), plus
  formation_coordinator; this test publishes the camera poses. The boards show what arrives on
  the serial line: torque frames while running, a stop frame when the program is signalled.
* ``camera``: formation_world + formation_tracker, and a bridge + controller for robot 0 (board
  owned by this test, no coordinator: the robot holds) - the other signal for each program.

Each program gets SIGINT in one set and SIGTERM in another, and must exit 0 without a traceback;
where it drives a board, the board receives a stop (zero torque or STOP) after the signal.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import signal
import subprocess
import time

import numpy as np
from processes import program, take_free_domain, warm_numba_kernels
import pytest

from ament_formation.core.config_files import config_file

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
START_TIMEOUT_S = 90.0  # process start-up on a loaded 2-core machine (imports, numba cache load)
LIMIT_E4NM = 1500  # 0.15 N m on the wire (1e-4 N m units)


# ------------------------------------------------------------------------------------- helpers
class Program:
    """One console script as a subprocess (own process group), output to a log file."""

    def __init__(
        self,
        name: str,
        exe: str,
        args: list[str],
        domain: int,
        log_dir: Path,
        params: tuple[str, ...] | None = None,
    ):
        self.name = name
        self.log = log_dir / f'{name}.log'
        files = [str(config_file(f'params/{p}.yaml')) for p in (params or (exe,))]
        cmd = [
            program(exe),
            '--ros-args',
            *[a for f in files for a in ('--params-file', f)],
            *args,
        ]
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        with open(self.log, 'w') as out:
            self.proc = subprocess.Popen(
                cmd, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        return self.log.read_text(errors='replace')

    def signal(self, sig: int) -> None:
        assert self.alive(), (
            f'{self.name} exited early ({self.proc.returncode}):\n{self.output()[-3000:]}'
        )
        self.proc.send_signal(sig)

    def wait_clean_exit(self, timeout_s: float = 20.0) -> None:
        """Exit status 0 and no traceback (the process was signalled before)."""
        try:
            rc = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(
                f'{self.name} did not exit within {timeout_s} s:\n{self.output()[-3000:]}'
            )
        out = self.output()
        assert rc == 0 and 'Traceback' not in out, f'{self.name} exited {rc}:\n{out[-3000:]}'

    def kill(self) -> None:
        if self.alive():
            self.proc.kill()
        self.proc.wait()


class Observer:
    """A private rclpy Context on ``domain`` with one node and one executor."""

    def __init__(self, domain: int, name: str):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def keep(self, msg_type, topic: str, qos, store: list | None = None) -> list:
        """Subscribe ``topic``; keep pairs of (receive time [s, monotonic], message)."""
        store = [] if store is None else store
        self.node.create_subscription(
            msg_type, topic, lambda m: store.append((time.monotonic(), m)), qos
        )
        return store

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Board:
    """An emulated motor board (wheel model on) on a pty at ``link``, stepped in its own thread;
    ``log`` gets (board time [s], seq, left, right) of every torque command.
    """

    def __init__(self, link: Path):
        from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard
        from ament_formation.hw.pty_board import PtyBoard

        self.log: list = []
        self.board = MotorBoard(
            BoardConfig(), now_s=time.monotonic(), standalone=True, command_log=self.log
        )
        self.runner = PtyBoard(self.board, link_path=link)
        self.runner.open()
        self.runner.start(step_period_s=0.002)

    def now_s(self) -> float:
        return self.runner.clock()

    def stops(self) -> int:
        return getattr(self.board, 'stops_received', 0)

    def stopped_since(self, t_s: float, stops_before: int) -> bool:
        """A stop reached the board after its time ``t_s``: a zero torque command or a STOP
        frame.
        """
        with self.runner.lock:
            zero = any(t >= t_s and (left, right) == (0, 0) for t, _, left, right in self.log)
            return zero or self.stops() > stops_before

    def driven(self) -> bool:
        """Torque frames arrived, some nonzero, none beyond the limit."""
        with self.runner.lock:
            wire = np.array([(left, right) for _, _, left, right in self.log]).reshape(-1, 2)
        return len(wire) > 20 and np.abs(wire).max() > 0 and np.abs(wire).max() <= LIMIT_E4NM

    def close(self) -> None:
        self.runner.close()


def spin_until(observers, predicate, timeout_s: float, programs=()) -> bool:
    """Spin every observer until ``predicate()`` or the timeout [s]; stop early (False) when one of
    ``programs`` exits.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if any(not p.alive() for p in programs):
            return bool(predicate())
        for obs in observers:
            obs.executor.spin_once(timeout_sec=0.005)
    return bool(predicate())


def _dead(programs) -> str:
    return '; '.join(
        f'{p.name} exited {p.proc.returncode}: {p.output()[-1500:]}'
        for p in programs
        if not p.alive()
    )


# ------------------------------------------------------------------------------------- fixture
@pytest.fixture(scope='module')
def sets(tmp_path_factory):
    """Start the three sets of programs (module docstring) and the observers; stop what is left."""
    from ament_formation.ros.qos import QOS_CONTROL

    # numba's kernels compiled once, before the programs start, if the core changed since
    # scripts/setup.sh did it (a fresh process: the sources as they are now), for the copy of the
    # package the programs import (under colcon test: the installed one)
    warm_numba_kernels(timeout_s=600.0, check=True)
    tmp = tmp_path_factory.mktemp('programs')
    # a domain per set, each held by this run (scripts/ros_env.sh's locks): another run on the
    # machine in one of them would see, and answer, our nodes and topics
    base = int(os.environ['ROS_DOMAIN_ID'])
    held = []
    for _ in range(2):
        taken = take_free_domain(avoid=(base, *(d for d, _ in held)))
        assert taken is not None, 'no free ROS domain id on this machine'
        held.append(taken)
    dom = {'mission': base, 'boards': held[0][0], 'camera': held[1][0]}
    scen = f'scenario:={SCENARIO}'
    programs: dict[str, Program] = {}
    boards: dict[str, Board] = {}
    observers: dict[str, Observer] = {}

    def start(key, exe, args, domain, params=None):
        programs[key] = Program(key, exe, args, dom[domain], tmp, params)

    try:
        # boards first: the bridges must find their ports at start
        (tmp / 'pty').mkdir()
        for key in ('b0', 'b1', 'c0'):
            boards[key] = Board(tmp / 'pty' / key)
        team_params = ('formation_team', 'formation_controller', 'formation_bridge')
        # mission: the world makes the ptys the team opens: the team waits for them
        start(
            'm_world',
            'formation_world',
            ['-p', scen, '-p', f'pty_dir:={tmp / "mission_pty"}', '-p', 'exit_at_end:=false'],
            'mission',
        )
        start('m_tracker', 'formation_tracker', [], 'mission')
        start('m_coordinator', 'formation_coordinator', ['-p', scen], 'mission')
        start(
            'm_team',
            'formation_team',
            [
                '-p',
                scen,
                '-p',
                f'port_template:={tmp / "mission_pty"}/robot_{{id}}',
                '-p',
                'wait_for_port:=true',
            ],
            'mission',
            team_params,
        )
        # boards: robot 0 as bridge + controller processes, robot 1 in a team process
        ns0 = ['-r', '__ns:=/robot_0']
        start(
            'b_bridge',
            'formation_bridge',
            [*ns0, '-p', f'port:={boards["b0"].runner.port}'],
            'boards',
        )
        start(
            'b_controller',
            'formation_controller',
            [*ns0, '-p', scen, '-p', 'robot_id:=0'],
            'boards',
        )
        start(
            'b_team',
            'formation_team',
            [
                '-p',
                scen,
                '-p',
                'robot_ids:=[1]',
                '-p',
                f'port_template:={boards["b1"].runner.port}',
            ],
            'boards',
            team_params,
        )
        start('b_coordinator', 'formation_coordinator', ['-p', scen], 'boards')
        # camera: world + tracker, and robot 0's bridge + controller without a coordinator
        start(
            'c_world',
            'formation_world',
            ['-p', scen, '-p', f'pty_dir:={tmp / "camera_pty"}', '-p', 'exit_at_end:=false'],
            'camera',
        )
        start('c_tracker', 'formation_tracker', [], 'camera')
        start(
            'c_bridge',
            'formation_bridge',
            [*ns0, '-p', f'port:={boards["c0"].runner.port}'],
            'camera',
        )
        start(
            'c_controller',
            'formation_controller',
            [*ns0, '-p', scen, '-p', 'robot_id:=0'],
            'camera',
        )

        for key in dom:
            observers[key] = Observer(dom[key], f'_programs_{key}')
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Image, JointState
        from std_msgs.msg import String

        from ament_formation.ros.qos import QOS_GRAPH, QOS_IMAGE

        seen: dict[str, list] = {}
        m, b, c = observers['mission'], observers['boards'], observers['camera']
        seen['m_image'] = m.keep(Image, '/camera/image_raw', QOS_IMAGE)
        for rid in (0, 1):
            seen[f'm_pose_{rid}'] = m.keep(PoseStamped, f'/robot_{rid}/pose', QOS_CONTROL)
            seen[f'm_truth_{rid}'] = m.keep(Odometry, f'/world/truth/robot_{rid}', QOS_CONTROL)
            seen[f'm_state_{rid}'] = m.keep(Odometry, f'/robot_{rid}/state', QOS_CONTROL)
            seen[f'b_state_{rid}'] = b.keep(Odometry, f'/robot_{rid}/state', QOS_CONTROL)
        seen['m_graph'] = m.keep(String, '/formation/graph', QOS_GRAPH)
        seen['b_graph'] = b.keep(String, '/formation/graph', QOS_GRAPH)
        seen['b_wheel_state_0'] = b.keep(JointState, '/robot_0/wheel_state', QOS_CONTROL)
        seen['b_torque_0'] = b.keep(JointState, '/robot_0/wheel_torque', QOS_CONTROL)
        seen['c_pose_0'] = c.keep(PoseStamped, '/robot_0/pose', QOS_CONTROL)
        seen['c_torque_0'] = c.keep(JointState, '/robot_0/wheel_torque', QOS_CONTROL)

        # the camera of the "boards" set: this test, 30 Hz poses at the robots' initial poses
        from ament_formation.core.scenario.loader import load_scenario

        sc = load_scenario(SCENARIO)
        pose_pubs = {
            r.id: b.node.create_publisher(PoseStamped, f'/robot_{r.id}/pose', QOS_CONTROL)
            for r in sc.robots
        }

        def camera():
            stamp = b.node.get_clock().now().to_msg()
            for r in sc.robots:
                x, y, th = r.initial_pose
                msg = PoseStamped()
                msg.header.stamp, msg.header.frame_id = stamp, 'world'
                msg.pose.position.x, msg.pose.position.y = float(x), float(y)
                msg.pose.orientation.z, msg.pose.orientation.w = math.sin(th / 2), math.cos(th / 2)
                pose_pubs[r.id].publish(msg)

        b.node.create_timer(1.0 / 30.0, camera)
        yield {'programs': programs, 'boards': boards, 'obs': observers, 'seen': seen, 'tmp': tmp}
    finally:
        for p in programs.values():
            p.kill()
        for obs in observers.values():
            obs.close()
        for board in boards.values():
            board.close()
        for _, fd in held:
            os.close(fd)


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def _poses_in_truth_span(seen, rid: int) -> list:
    """The poses of robot ``rid`` whose capture time lies within the ground truth heard so far."""
    truth = [_stamp_s(t.header.stamp) for _, t in seen[f'm_truth_{rid}']]
    if not truth:
        return []
    poses = [p for _, p in seen[f'm_pose_{rid}']]
    return [p for p in poses if truth[0] <= _stamp_s(p.header.stamp) <= truth[-1]]


def _graph_started(store) -> bool:
    from ament_formation.ros import messages as msgs

    return any(msgs.graph_from_msg(msg).start_s is not None for _, msg in store)


# ------------------------------------------------------------------------------------- tests
def test_mission_through_the_programs(sets):
    """World -> images; tracker -> poses close to the truth; coordinator -> a started graph;
    team -> both robots' states, and the leader's truth moves (torques reached the world's boards).
    """
    progs, seen, obs = sets['programs'], sets['seen'], [sets['obs']['mission']]
    mission = [progs[k] for k in ('m_world', 'm_tracker', 'm_coordinator', 'm_team')]
    ok = spin_until(
        obs,
        lambda: _graph_started(seen['m_graph'])
        and all(seen[f'm_state_{i}'] and _poses_in_truth_span(seen, i) for i in (0, 1)),
        START_TIMEOUT_S,
        mission,
    )
    assert ok, (
        f'graph {len(seen["m_graph"])}, '
        f'states {[len(seen[f"m_state_{i}"]) for i in (0, 1)]}, '
        f'poses in the truth span {[len(_poses_in_truth_span(seen, i)) for i in (0, 1)]}; '
        f'{_dead(mission)}'
    )
    # images: mono8 frames of the camera in config/camera.yaml, not blank
    _, img = seen['m_image'][-1]
    assert (img.encoding, img.width, img.height) == ('mono8', 640, 480) and len(
        img.data
    ) == img.step * img.height
    pixels = np.frombuffer(bytes(img.data), np.uint8)
    assert pixels.std() > 5.0
    # poses: frame world, within 1 cm of the ground truth at the capture time (truth interpolated)
    for rid in (0, 1):
        truth = [
            (_stamp_s(t.header.stamp), t.pose.pose.position) for _, t in seen[f'm_truth_{rid}']
        ]
        poses = _poses_in_truth_span(seen, rid)
        assert poses, f"robot {rid}: no pose inside the truth's time span"
        # the newest pose whose capture time the truth brackets within 0.1 s (this test's own
        # subscriber can miss truth samples while the machine is busy: seen once, a 2.6 s gap)
        times = [tt for tt, _ in truth]
        bracketed = []
        for pose in poses:
            t = _stamp_s(pose.header.stamp)
            k = next(i for i in range(1, len(truth)) if truth[i][0] >= t)
            if truth[k][0] - truth[k - 1][0] < 0.1:
                bracketed.append((pose, t, k))
        gap = max(np.diff(times), default=0.0)
        assert bracketed, f'robot {rid}: no pose between truth samples < 0.1 s apart (gap {gap} s)'
        pose, t, k = bracketed[-1]
        assert pose.header.frame_id == 'world'
        (t0, a), (t1, b) = truth[k - 1], truth[k]
        w = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
        err = math.hypot(
            pose.pose.position.x - (a.x + w * (b.x - a.x)),
            pose.pose.position.y - (a.y + w * (b.y - a.y)),
        )
        assert err < 0.01, f'robot {rid}: pose {err * 1e3:.1f} mm from the truth'
        assert len(bracketed) >= len(poses) // 2, (len(bracketed), len(poses), gap)
    # the team drives: robot 0's truth moves 2 cm after the mission start
    x0 = seen['m_truth_0'][-1][1].pose.pose.position

    def moved():
        p = seen['m_truth_0'][-1][1].pose.pose.position
        return math.hypot(p.x - x0.x, p.y - x0.y) > 0.02

    assert spin_until(obs, moved, 30.0, mission), f'robot 0 did not move; {_dead(mission)}'
    for rid in (0, 1):
        _, st = seen[f'm_state_{rid}'][-1]
        assert st.header.frame_id == 'world' and all(
            math.isfinite(v)
            for v in (st.pose.pose.position.x, st.pose.pose.position.y, st.twist.twist.linear.x)
        )


def test_bridge_controller_and_team_drive_boards_on_ptys(sets):
    """Torque frames (nonzero, within the 0.15 N m limit) reach the boards from the bridge process
    (robot 0, commanded by the controller process) and from the team process (robot 1); the
    bridge publishes the board's wheel_state, the controllers their state.
    """
    progs, seen, boards, obs = (
        sets['programs'],
        sets['seen'],
        sets['boards'],
        [sets['obs']['boards']],
    )
    procs = [progs[k] for k in ('b_bridge', 'b_controller', 'b_team', 'b_coordinator')]
    ok = spin_until(
        obs,
        lambda: (
            _graph_started(seen['b_graph']) and boards['b0'].driven() and boards['b1'].driven()
        ),
        START_TIMEOUT_S,
        procs,
    )
    assert ok, (
        f'graph started {_graph_started(seen["b_graph"])}, frames {len(boards["b0"].log)}, '
        f'{len(boards["b1"].log)}; {_dead(procs)}'
    )
    _, ws = seen['b_wheel_state_0'][-1]
    assert (
        list(ws.name) == ['left_wheel', 'right_wheel']
        and len(ws.position) == len(ws.velocity) == 2
    )
    assert all(math.isfinite(v) for v in [*ws.position, *ws.velocity])
    assert all(seen[f'b_state_{rid}'] for rid in (0, 1))


def test_sigint_and_sigterm_end_every_program_cleanly(sets):
    """Each program gets SIGINT in one set and SIGTERM in another: exit 0, no traceback; the
    bridge and the team send a stop to their board, the controller a zero torque.
    """
    progs, seen, boards, obs = (
        sets['programs'],
        sets['seen'],
        sets['boards'],
        list(sets['obs'].values()),
    )
    # the camera set is running: poses from the tracker, the controller talks to its bridge
    camera = [progs[k] for k in ('c_world', 'c_tracker', 'c_bridge', 'c_controller')]
    assert spin_until(
        obs,
        lambda: (
            seen['c_pose_0']
            and len(boards['c0'].log) > 0
            and sets['obs']['camera'].node.count_publishers('/robot_0/wheel_torque') > 0
        ),
        START_TIMEOUT_S,
        camera,
    ), _dead(camera)
    assert spin_until(
        obs, lambda: boards['b0'].driven() and boards['b1'].driven(), START_TIMEOUT_S
    ), 'the boards set is not driving'

    def stop_check(prog: Program, sig: int, board: Board) -> None:
        t_sig, stops = board.now_s(), board.stops()
        prog.signal(sig)
        assert spin_until(obs, lambda: board.stopped_since(t_sig, stops), 10.0), (
            f'{prog.name}: no stop reached the board after {signal.Signals(sig).name}'
        )
        prog.wait_clean_exit()

    def zero_torque_check(prog: Program, sig: int, store: list) -> None:
        t_sig = time.monotonic()
        prog.signal(sig)
        prog.wait_clean_exit()
        assert spin_until(
            obs,
            lambda: any(t >= t_sig and list(msg.effort) == [0.0, 0.0] for t, msg in store),
            5.0,
        ), f'{prog.name}: no zero wheel_torque after {signal.Signals(sig).name}'

    # bridges and the team while their controllers still command torque: the stop is theirs
    stop_check(progs['b_bridge'], signal.SIGINT, boards['b0'])
    stop_check(progs['c_bridge'], signal.SIGTERM, boards['c0'])
    stop_check(progs['b_team'], signal.SIGTERM, boards['b1'])
    zero_torque_check(progs['b_controller'], signal.SIGTERM, seen['b_torque_0'])
    zero_torque_check(progs['c_controller'], signal.SIGINT, seen['c_torque_0'])
    # the mission's team: SIGINT (its board is the world's: the stop is not visible from here)
    for key, sig in (
        ('m_team', signal.SIGINT),
        ('m_world', signal.SIGTERM),
        ('c_world', signal.SIGINT),
        ('m_tracker', signal.SIGTERM),
        ('c_tracker', signal.SIGINT),
        ('m_coordinator', signal.SIGINT),
        ('b_coordinator', signal.SIGTERM),
    ):
        progs[key].signal(sig)
    for key in (
        'm_team',
        'm_world',
        'c_world',
        'm_tracker',
        'c_tracker',
        'm_coordinator',
        'b_coordinator',
    ):
        progs[key].wait_clean_exit()


def test_a_port_that_cannot_be_opened_is_one_line_and_exit_2(tmp_path):
    """formation_bridge and formation_team with a port that does not exist: one line on stderr
    naming the port, exit code 2, nothing else (no traceback, no retry loop).
    """
    port = tmp_path / 'ttyACM9'
    env = dict(os.environ, ROS_DOMAIN_ID=str((int(os.environ['ROS_DOMAIN_ID']) + 101) % 200 + 1))
    runs = {
        'formation_bridge': [
            program('formation_bridge'),
            '--ros-args',
            '--params-file',
            str(config_file('params/formation_bridge.yaml')),
            '-r',
            '__ns:=/robot_0',
            '-p',
            f'port:={port}',
        ],
        'formation_team': [
            program('formation_team'),
            '--ros-args',
            '--params-file',
            str(config_file('params/formation_team.yaml')),
            '-p',
            f'scenario:={SCENARIO}',
            '-p',
            'robot_ids:=[0]',
            '-p',
            f'port_template:={port}',
        ],
    }
    procs = {
        k: subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )
        for k, cmd in runs.items()
    }
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=START_TIMEOUT_S)
        lines = err.strip().splitlines()
        assert proc.returncode == 2, (name, proc.returncode, err)
        assert len(lines) == 1 and lines[0].startswith(
            f'{name}: /robot_0/formation_bridge: port: cannot open {port}'
        ), err
        assert 'No such file or directory' in lines[0] and 'Traceback' not in out + err
