"""A robot's processes stop cleanly: a formation_controller (and a formation_team) driving a robot
of the twin, stopped by SIGTERM, prints no FATAL / ERROR / Traceback (no publishing after the
context is gone), and the board then brakes the robot to rest instead of letting it coast.
"""

from __future__ import annotations

from pathlib import Path
import re
import signal
import subprocess

import numpy as np
from processes import program as find_program
import pytest

from ament_formation.ros.executors import spin_until

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / 'test' / 'data'
BAD_LINE = re.compile(r'\[FATAL\]|\[ERROR\]|Traceback|context is invalid')


def _system(ros_context, executor, tmp_path, with_bridge: bool):
    from rclpy.parameter import Parameter

    from ament_formation.nodes.bridge import BridgeNode
    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams
    from ament_formation.nodes.tracker import TrackerNode, TrackerNodeParams
    from ament_formation.nodes.world import WorldNode, WorldParams

    scenario = DATA / 'paper_short.yaml'
    pty = tmp_path / 'pty'
    world = WorldNode(
        context=ros_context, params=WorldParams(scenario=str(scenario), pty_dir=str(pty))
    )
    nodes = [
        world,
        TrackerNode(
            context=ros_context, params=TrackerNodeParams(marker_ids=(0, 1), robot_ids=(0, 1))
        ),
        CoordinatorNode(
            context=ros_context,
            params=CoordinatorParams(
                scenario=str(scenario), wait_for_robots=False, start_delay_s=0.0
            ),
        ),
    ]
    if with_bridge:
        nodes.append(
            BridgeNode(
                context=ros_context,
                namespace='/robot_0',
                parameter_overrides=[Parameter('port', value=str(pty / 'robot_0'))],
            )
        )
    for n in nodes:
        executor.add_node(n)
    return scenario, pty, world, nodes


@pytest.mark.parametrize('program', ['formation_controller', 'formation_team'])
def test_sigterm_stops_cleanly_and_the_board_brakes(ros_context, executor, tmp_path, program):
    team = program == 'formation_team'
    scenario, pty, world, nodes = _system(ros_context, executor, tmp_path, with_bridge=not team)
    if team:  # the team hosts robot 0's controller and bridge in one process
        cmd = [
            find_program(program),
            '--ros-args',
            '-p',
            f'scenario:={scenario}',
            '-p',
            'robot_ids:=[0]',
            '-p',
            f'port_template:={pty}/robot_0',
        ]
    else:
        cmd = [
            find_program(program),
            '--ros-args',
            '-r',
            '__ns:=/robot_0',
            '-p',
            f'scenario:={scenario}',
            '-p',
            'robot_id:=0',
        ]
    from sensor_msgs.msg import JointState

    from ament_formation.ros.qos import QOS_CONTROL

    torques: list[tuple[float, ...]] = []
    nodes[1].create_subscription(
        JointState, '/robot_0/wheel_torque', lambda m: torques.append(tuple(m.effort)), QOS_CONTROL
    )
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    board = world.boards[0].board
    try:
        ok = spin_until(
            executor,
            lambda: np.max(np.abs(board.applied_torque_nm)) > 0.002 or proc.poll() is not None,
            150.0,
        )  # start-up (kernel cache, discovery) is slow on a loaded machine
        assert ok and proc.poll() is None, f'{program} did not drive the board'
        # until this test hears its torques too (discovery is slow on a busy host), then stop it
        # as a launcher does
        assert spin_until(executor, lambda: any(t != (0.0, 0.0) for t in torques), 60.0), (
            f'no wheel_torque heard from {program}'
        )
        n_before = len(torques)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
        # its last word went out while the context was still valid: zero torque, after the signal
        assert spin_until(
            executor, lambda: len(torques) > n_before and torques[-1] == (0.0, 0.0), 2.0
        ), f'no zero torque after SIGTERM (last {torques[-3:]})'
        # the board stops the robot: it brakes (STOP from the bridge, or its watchdog), then
        # releases
        assert spin_until(executor, lambda: board.brakes >= 1, 3.0), 'the board never braked'
        assert spin_until(
            executor, lambda: not board.braking and np.all(board.applied_torque_nm == 0.0), 3.0
        )
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
        for n in nodes:
            if n is world:
                world.close()
            n.destroy_node()
    bad = [line for line in out.splitlines() if BAD_LINE.search(line)]
    print(f'{program}: exit code {proc.returncode}, {len(out.splitlines())} output lines')
    assert proc.returncode == 0, out[-2000:]
    assert bad == [], '\n'.join(bad)
