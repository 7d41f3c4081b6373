"""Multi-process smoke test: scripts/launch_sim.sh starts every node of a simulated run, they find
each other, topics flow, the mission starts and robots move; TERM stops every process it started.
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess

import numpy as np
from processes import alive

from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
EXPECTED_NODES = {
    '/formation_world',
    '/formation_tracker',
    '/formation_coordinator',
    '/robot_0/formation_bridge',
    '/robot_0/formation_controller',
    '/robot_1/formation_bridge',
    '/robot_1/formation_controller',
}


def test_launch_sim_smoke(ros_context, executor, tmp_path):
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from ament_formation.tools.topic_cmd import list_nodes

    run_dir = tmp_path / 'run'
    proc = subprocess.Popen(
        [str(ROOT / 'scripts' / 'launch_sim.sh'), str(SCENARIO), '--run-dir', str(run_dir)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    probe = rclpy.create_node('_smoke_probe', context=ros_context)
    executor.add_node(probe)
    seen = {'torque': 0, 'pose': 0, 'state': 0, 'truth': []}
    graphs: list[m.GraphMessage] = []
    probe.create_subscription(
        JointState,
        '/robot_1/wheel_torque',
        lambda _m: seen.__setitem__('torque', seen['torque'] + 1),
        QOS_CONTROL,
    )
    probe.create_subscription(
        m.PoseStamped,
        '/robot_0/pose',
        lambda _m: seen.__setitem__('pose', seen['pose'] + 1),
        QOS_CONTROL,
    )
    probe.create_subscription(
        m.Odometry,
        '/robot_0/state',
        lambda _m: seen.__setitem__('state', seen['state'] + 1),
        QOS_CONTROL,
    )
    probe.create_subscription(
        m.Odometry,
        '/world/truth/robot_0',
        lambda msg: seen['truth'].append(m.state_from_odometry(msg)[0][:2]),
        QOS_CONTROL,
    )
    probe.create_subscription(
        String, '/formation/graph', lambda msg: graphs.append(m.graph_from_msg(msg)), QOS_GRAPH
    )
    try:
        ok = spin_until(
            executor,
            lambda: EXPECTED_NODES <= set(list_nodes(probe)) or proc.poll() is not None,
            60.0,
        )
        assert ok and proc.poll() is None, f'nodes seen: {list_nodes(probe)}'
        assert spin_until(executor, lambda: graphs and graphs[-1].start_s is not None, 60.0)
        n0 = dict(seen, truth=len(seen['truth']))
        start_pos = None

        def moving():
            nonlocal start_pos
            if seen['truth'] and start_pos is None:
                start_pos = seen['truth'][-1]
            return start_pos is not None and np.hypot(*(seen['truth'][-1] - start_pos)) > 0.05

        assert spin_until(executor, moving, 30.0), 'the leader did not move 5 cm after the start'
        assert seen['torque'] > n0['torque'] + 5 and seen['pose'] > n0['pose'] + 5
        assert seen['state'] > n0['state'] + 5  # (the probe shares 2 cores with 7 processes)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    pids = [
        int(line.split()[0])
        for line in (run_dir / 'pids').read_text().splitlines()
        if line.strip()
    ]
    assert len(pids) == 1 + 2 * 2 + 2
    assert [p for p in pids if alive(p)] == [], out
    assert 'stopped 7 processes' in out
    assert not any((run_dir / 'pty').glob('robot_*')), 'pty links left behind'


def test_launch_sim_team_smoke(ros_context, executor, tmp_path):
    """--team 2: one formation_team process hosts both robots' bridge and controller nodes;
    --control-nice 5 starts it under nice 5 (the other processes keep theirs).
    """
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from ament_formation.tools.topic_cmd import list_nodes

    run_dir = tmp_path / 'run'
    proc = subprocess.Popen(
        [
            str(ROOT / 'scripts' / 'launch_sim.sh'),
            str(SCENARIO),
            '--run-dir',
            str(run_dir),
            '--team',
            '2',
            '--control-nice',
            '5',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    probe = rclpy.create_node('_team_probe', context=ros_context)
    executor.add_node(probe)
    torques = {0: 0, 1: 0}
    for rid in torques:
        probe.create_subscription(
            JointState,
            f'/robot_{rid}/wheel_torque',
            lambda _m, rid=rid: torques.__setitem__(rid, torques[rid] + 1),
            QOS_CONTROL,
        )
    graphs: list[m.GraphMessage] = []
    probe.create_subscription(
        String, '/formation/graph', lambda msg: graphs.append(m.graph_from_msg(msg)), QOS_GRAPH
    )
    expected = EXPECTED_NODES | {'/formation_team_0'}  # one team process, named by its index
    try:
        ok = spin_until(
            executor, lambda: expected <= set(list_nodes(probe)) or proc.poll() is not None, 60.0
        )
        assert ok and proc.poll() is None, f'nodes seen: {list_nodes(probe)}'
        # the coordinator starts the mission once both composed controllers publish their state
        assert spin_until(executor, lambda: graphs and graphs[-1].start_s is not None, 60.0)
        n0 = dict(torques)
        assert spin_until(executor, lambda: all(torques[r] > n0[r] + 10 for r in torques), 30.0), (
            torques
        )
        launched = dict(
            line.split()[::-1]
            for line in (run_dir / 'pids').read_text().splitlines()
            if line.strip()
        )
        nice = {
            name: int(Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[16])
            for name, pid in launched.items()
        }
        assert nice['team_0'] == nice['world'] + 5, nice
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    names = [
        line.split()[1] for line in (run_dir / 'pids').read_text().splitlines() if line.strip()
    ]
    assert names == ['world', 'team_0', 'tracker', 'coordinator'], out
    pids = [
        int(line.split()[0])
        for line in (run_dir / 'pids').read_text().splitlines()
        if line.strip()
    ]
    assert [p for p in pids if alive(p)] == [], out
    assert 'stopped 4 processes' in out
    assert proc.returncode == 143, out  # stopped by TERM (scripts/launch_common.sh)
    assert not any((run_dir / 'pty').glob('robot_*')), 'pty links left behind'
