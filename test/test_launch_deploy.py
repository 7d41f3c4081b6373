"""Deployment split: scripts/launch_base.sh (camera PC: tracker + coordinator) and one
scripts/launch_robot.sh per robot (bridge + controller on the robot's board) run the mission
against the simulated twin hosted in this test process; TERM stops every process they started.
Also their one-line errors (exit code 2) for bad input.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import subprocess
import time

import numpy as np
from processes import alive, program
import pytest

from ament_formation.ros.executors import spin_until

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / 'scripts'
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
ROBOT_1_TORQUE_LIMIT_NM = 0.12  # != the 0.15 N m of every other robot and of the bridge's default
SHM_PATTERN = re.compile(r'^(fastrtps_|sem\.fastrtps_)')
EXIT_ON_TERM = 143  # scripts/launch_common.sh: a launcher stopped by SIGTERM exits 128 + 15


def _pids(run_dir: Path) -> list[int]:
    path = run_dir / 'pids'
    if not path.exists():
        return []
    return [int(line.split()[0]) for line in path.read_text().splitlines() if line.strip()]


def _shm_names() -> set[str]:
    return {n for n in os.listdir('/dev/shm') if SHM_PATTERN.match(n)}


def _shm_mapped_by(pid: int) -> set[str]:
    """Names of the Fast DDS /dev/shm segments and semaphores process ``pid`` has mapped."""
    try:
        maps = Path(f'/proc/{pid}/maps').read_text()
    except OSError:
        return set()
    names = set()
    for line in maps.splitlines():
        parts = line.split(maxsplit=5)
        path = parts[5] if len(parts) == 6 else ''
        if path.startswith('/dev/shm/'):
            name = path[len('/dev/shm/'):].removesuffix(' (deleted)')
            if SHM_PATTERN.match(name):
                names.add(name)
    return names


def _stop(proc: subprocess.Popen, run_dir: Path) -> None:
    """Last resort for the finally: blocks: TERM the launcher, then KILL what is left, by PID."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for pid in _pids(run_dir):
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def _scenario(tmp_path: Path) -> Path:
    """paper_short.yaml with robot 1's own torque limit (proves the bridge reads it per id)."""
    text = SCENARIO.read_text()
    assert '  - id: 1\n' in text
    text = text.replace(
        '  - id: 1\n', f'  - id: 1\n    torque_limit_nm: {ROBOT_1_TORQUE_LIMIT_NM}\n'
    )
    path = tmp_path / 'paper_short_t1.yaml'
    path.write_text(text)
    return path


def _get_parameter(node, executor, fqn: str, name: str, timeout_s: float = 20.0):
    from rcl_interfaces.srv import GetParameters

    client = node.create_client(GetParameters, f'{fqn}/get_parameters')
    try:
        assert spin_until(executor, client.service_is_ready, timeout_s), (
            f'{fqn}/get_parameters not ready'
        )
        future = client.call_async(GetParameters.Request(names=[name]))
        assert spin_until(executor, future.done, timeout_s), f'{fqn}: no answer for {name}'
        return future.result().values[0].double_value
    finally:
        node.destroy_client(client)


def test_deployment_split(ros_context, executor, tmp_path):
    import rclpy

    from ament_formation.nodes.world import WorldNode, WorldParams
    from ament_formation.tools.topic_cmd import list_nodes

    scenario = _scenario(tmp_path)
    pty_dir = tmp_path / 'pty'
    shm_before = _shm_names()
    world = WorldNode(
        context=ros_context, params=WorldParams(scenario=str(scenario), pty_dir=str(pty_dir))
    )
    executor.add_node(world)
    probe = rclpy.create_node('_deploy_probe', context=ros_context)
    executor.add_node(probe)
    ids = list(world.ids)
    assert ids == [0, 1]
    expected = {'/formation_world', '/formation_tracker', '/formation_coordinator'} | {
        f'/robot_{i}/formation_{kind}' for i in ids for kind in ('bridge', 'controller')
    }

    launchers: list[tuple[subprocess.Popen, Path]] = []

    def launch(args: list[str], run_dir: Path) -> None:
        proc = subprocess.Popen(
            [*args, '--scenario', str(scenario), '--run-dir', str(run_dir), '--loopback'],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        launchers.append((proc, run_dir))

    def any_launcher_exited() -> bool:
        return any(proc.poll() is not None for proc, _ in launchers)

    launched_shm: set[str] = set()
    try:
        launch([str(SCRIPTS / 'launch_base.sh')], tmp_path / 'base')
        for i in ids:  # robot 0: the default robot process; robot 1: bridge and controller split
            launch(
                [
                    str(SCRIPTS / 'launch_robot.sh'),
                    '--id',
                    str(i),
                    '--port',
                    str(pty_dir / f'robot_{i}'),
                    *(['--split'] if i == 1 else []),
                ],
                tmp_path / f'robot_{i}',
            )
        n_procs = {tmp_path / 'base': 2, tmp_path / 'robot_0': 1, tmp_path / 'robot_1': 2}

        ok = spin_until(
            executor, lambda: expected <= set(list_nodes(probe)) or any_launcher_exited(), 60.0
        )
        assert ok and not any_launcher_exited(), f'nodes seen: {list_nodes(probe)}'
        assert spin_until(
            executor, lambda: world.start_s is not None or any_launcher_exited(), 60.0
        )
        assert world.start_s is not None, 'the mission did not start'
        accepted0 = [b.board.accepted_commands for b in world.boards]

        start_xy = None

        def leader_moved() -> bool:
            nonlocal start_xy
            if not world.twin.started:
                return False
            xy = np.array(world.twin.state[0, :2])
            if start_xy is None:
                start_xy = xy
            return float(np.hypot(*(xy - start_xy))) > 0.02

        assert spin_until(executor, leader_moved, 30.0), (
            "robot 0's truth did not move 2 cm after the start"
        )
        assert spin_until(
            executor,
            lambda: all(
                b.board.accepted_commands > a + 20 for b, a in zip(world.boards, accepted0)
            ),
            20.0,
        ), (
            f'torque frames per board: {[b.board.accepted_commands for b in world.boards]} '
            f'(from {accepted0})'
        )
        # each bridge got its robot's torque limit from the scenario
        limits = {
            i: _get_parameter(probe, executor, f'/robot_{i}/formation_bridge', 'torque_limit_nm')
            for i in ids
        }
        assert limits == {0: 0.15, 1: ROBOT_1_TORQUE_LIMIT_NM}
        assert world.boards[1].board.limit_e4nm == round(ROBOT_1_TORQUE_LIMIT_NM * 1e4)

        for proc, run_dir in launchers:
            assert len(_pids(run_dir)) == n_procs[run_dir], (run_dir / 'pids').read_text()
            for pid in _pids(run_dir):
                launched_shm |= _shm_mapped_by(pid)
        for proc, _ in launchers:
            proc.send_signal(signal.SIGTERM)
        outputs = []
        for proc, run_dir in launchers:
            out, _ = proc.communicate(timeout=20)
            outputs.append(out)
            assert proc.returncode == EXIT_ON_TERM, out
            deadline = time.monotonic() + 10.0
            while [p for p in _pids(run_dir) if alive(p)] and time.monotonic() < deadline:
                time.sleep(0.05)  # polling the PIDs' exit, not waiting for a result
            assert [p for p in _pids(run_dir) if alive(p)] == [], out
            assert f'stopped {n_procs[run_dir]} processes' in out
    finally:
        for proc, run_dir in launchers:
            _stop(proc, run_dir)
        executor.remove_node(world)
        world.destroy_node()
    # Fast DDS segments the launched processes used, minus those this process still maps (its own
    # ports, which the launched processes wrote into): none may be left in /dev/shm
    left = (launched_shm - _shm_mapped_by(os.getpid()) - shm_before) & _shm_names()
    assert left == set(), f'left in /dev/shm by the launched processes: {sorted(left)}'
    assert not any(pty_dir.glob('robot_*')), 'pty links left behind'


@pytest.mark.parametrize(
    'args, option',
    [
        (['launch_robot.sh', '--id', '0', '--scenario', str(SCENARIO)], '--port'),
        (
            ['launch_robot.sh', '--id', '7', '--port', '/dev/null', '--scenario', str(SCENARIO),
             '--loopback'],
            '--id',
        ),
        (
            ['launch_robot.sh', '--id', 'x', '--port', '/dev/null', '--scenario', str(SCENARIO)],
            '--id',
        ),
        (
            [
                'launch_robot.sh',
                '--id',
                '0',
                '--port',
                '/nonexistent/ttyACM9',
                '--scenario',
                str(SCENARIO),
            ],
            '--port',
        ),
        (['launch_base.sh', '--scenario', '/nonexistent/scenario.yaml'], '--scenario'),
        (['launch_base.sh'], '--scenario'),
        (['launch_base.sh', '--scenario', str(SCENARIO), '--domain', '102'], '--domain'),
        (['launch_base.sh', '--scenario', str(SCENARIO), '--domain', 'lab'], '--domain'),
        (
            ['launch_robot.sh', '--id', '0', '--port', '/dev/null', '--scenario', str(SCENARIO),
             '--domain', '-1'],
            '--domain',
        ),
        (['launch_sim.sh', str(SCENARIO), '--team', '0'], '--team'),
        (['launch_sim.sh', str(SCENARIO), '--team', 'two'], '--team'),
        (['launch_sim.sh', str(SCENARIO), '--control-nice', '20'], '--control-nice'),
        (['launch_sim.sh', str(SCENARIO), '--control-nice', '-5x'], '--control-nice'),
    ],
)
def test_launcher_bad_input(args, option, tmp_path):
    proc = subprocess.run(
        [str(SCRIPTS / args[0]), *args[1:]],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=tmp_path,
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and option in lines[0] and args[0] in lines[0], proc.stderr
    if option == '--id' and args[2] == '7':
        assert 'robot 7 is not in' in lines[0]
    if option == '--port' and '--port' in args:
        assert (
            "no such device '/nonexistent/ttyACM9'" in lines[0] and '--wait-for-port' in lines[0]
        )
    assert proc.stdout == ''  # nothing was started


@pytest.mark.parametrize('option, value', [('--team', '0'), ('--control-nice', '-21')])
def test_formation_run_rejects_bad_launch_options(tmp_path, option, value):
    proc = subprocess.run(
        [
            program('formation'),
            'run',
            str(SCENARIO),
            '--out',
            str(tmp_path / 'out'),
            option,
            value,
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and option in lines[0], proc.stderr
    assert not (tmp_path / 'out').exists()  # nothing was started


@pytest.mark.parametrize('split', [False, True], ids=['robot_process', 'split'])
def test_launch_robot_wait_for_port_starts_and_connects_when_the_board_appears(
    ros_context, executor, tmp_path, split
):
    """--wait-for-port: a missing port is no error; the bridge connects once the board's port
    appears (here an emulated board on a pty created after the start), and TERM stops it all.
    """
    import rclpy

    from ament_formation.core.serial import serial_protocol as sp
    from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard
    from ament_formation.hw.pty_board import PtyBoard
    from ament_formation.tools.topic_cmd import list_nodes

    port = tmp_path / 'ttyACM_later'
    run_dir = tmp_path / 'robot_0'
    proc = subprocess.Popen(
        [
            str(SCRIPTS / 'launch_robot.sh'),
            '--id',
            '0',
            '--port',
            str(port),
            '--scenario',
            str(SCENARIO),
            '--run-dir',
            str(run_dir),
            '--wait-for-port',
            '--loopback',
            *(['--split'] if split else []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    probe = rclpy.create_node('_wait_probe', context=ros_context)
    executor.add_node(probe)
    runner = PtyBoard(MotorBoard(BoardConfig(), now_s=time.monotonic()), link_path=port)
    try:
        assert spin_until(
            executor,
            lambda: '/robot_0/formation_bridge' in list_nodes(probe) or proc.poll() is not None,
            60.0,
        )
        assert proc.poll() is None, proc.communicate(timeout=20)[0]
        runner.open()
        runner.start(step_period_s=0.002)
        # the bridge opened the port and the handshake went through (the board answered a HELLO)
        assert spin_until(
            executor,
            lambda: not runner.board.flags & sp.FLAG_RESET or proc.poll() is not None,
            30.0,
        ), f'board flags {runner.board.flags:#x}'
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
        assert proc.returncode == EXIT_ON_TERM, out
        assert [p for p in _pids(run_dir) if alive(p)] == [], out
    finally:
        _stop(proc, run_dir)
        executor.remove_node(probe)
        probe.destroy_node()
        runner.close()
