"""Whole-system tests: every node in one executor with real ptys and rendered frames, and the
safety behaviour of the controller (docs/design.md §7).
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess

import numpy as np
from processes import program
import pytest

from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_GRAPH

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / 'test' / 'data'


def _commanded_torque(ctrl) -> np.ndarray:
    """The torque [N m] (left, right) a controller node sent in its last period."""
    return ctrl.batch.out.torque[ctrl.r].copy()


def _own_mode(ctrl) -> str:
    """The switching mode a controller's agent holds for its own robot (S8.7), running or not."""
    from ament_formation.core.control.switching import MODE_NAMES

    b = ctrl.batch
    return MODE_NAMES[int(b.state.modes.mode[ctrl.r, b.row[ctrl.rid]])]


def test_shortened_paper_run_all_nodes_in_one_process(ros_context, executor, tmp_path):
    """Leader goes round O1 with positive clearance, the follower keeps formation, the graph
    revision changes when the leader starts and stops avoiding, torques stay within limits.
    """
    import rclpy
    from std_msgs.msg import String

    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.nodes.system import build_system

    scenario_path = DATA / 'paper_short.yaml'
    sc = load_scenario(scenario_path)
    # one executor serves every callback of every node: run the clock at half speed (/clock,
    # use_sim_time) so that 100 Hz control, 30 fps camera and the bridges fit on this machine
    system = build_system(
        ros_context,
        scenario_path,
        executor,
        pty_dir=tmp_path / 'pty',
        start_delay_s=0.5,
        speed_factor=0.5,
        bridge_poll_rate_hz=200.0,
    )
    probe = rclpy.create_node('_probe', context=ros_context)
    graphs: list[m.GraphMessage] = []
    probe.create_subscription(
        String, '/formation/graph', lambda msg: graphs.append(m.graph_from_msg(msg)), QOS_GRAPH
    )
    executor.add_node(probe)
    samples = []  # (world time, states (2, 5), commanded torques (2, 2)) after every callback

    def finished():
        w = system.world
        samples.append(
            (
                w.plant_time_s,
                w.twin.state.copy(),
                # what each controller's agent commanded in its last period
                np.array([_commanded_torque(system.controllers[i]) for i in (0, 1)]),
            )
        )
        return w.done

    try:
        assert spin_until(executor, finished, 90.0), 'the world did not finish the scenario'
    finally:
        system.destroy(executor)
    start_s = system.world.start_s
    assert start_s is not None
    t = np.array([s[0] for s in samples]) - start_s
    x = np.stack([s[1] for s in samples])
    tau = np.stack([s[2] for s in samples])
    run = t >= 0.0
    t, x, tau = t[run], x[run], tau[run]

    # leader round O1: positive clearance, back on its path at the end
    o1 = next(o for o in sc.obstacles if o.name == 'O1')
    from ament_formation.core.model.ellipse import signed_distance_to_ellipse

    dist = signed_distance_to_ellipse(
        x[:, 0, :2], np.asarray(o1.center_m), o1.orientation_rad, *o1.semi_axes_m
    )
    assert dist.min() > 0.0
    assert t[-1] >= sc.duration_s - 0.05
    r_end = sc.robot(0).path.reference(t[-1])[0]
    assert np.hypot(*(x[-1, 0, :2] - r_end)) < 0.05
    # follower keeps its slot (delta = (0, 1.2)): the initial 0.2 m error shrinks to < 2 cm
    err = np.hypot(*(x[:, 1, :2] - x[:, 0, :2] - np.array([0.0, 1.2])).T)
    assert err[0] > 0.15 and err[t > 12.0].max() < 0.03 and err[-1] < 0.02
    # graph: one revision when the leader starts avoiding, one when it stops
    avoiding_revs = [g.revision for g in graphs if g.avoiding == (0,)]
    assert avoiding_revs, [(g.revision, g.avoiding) for g in graphs]
    later = [g for g in graphs if g.revision > max(avoiding_revs) and g.avoiding == ()]
    assert later, 'no revision after the leader stopped avoiding'
    assert all(g.parents == {0: None, 1: 0} for g in graphs)
    # torques within the limit, and the controllers did drive
    for k, rid in enumerate((0, 1)):
        assert np.all(np.abs(tau[:, k]) <= sc.robot(rid).params.torque_limit_nm + 1e-12)
        assert np.max(np.abs(tau[:, k])) > 0.005


def test_controller_stops_when_poses_stop(ros_context, executor, tmp_path):
    """Cut the camera: within pose_timeout_s the controller switches to a controlled stop and the
    robot comes to rest; the safety state and the mode say so.
    """
    from ament_formation.core.control.stop import REST_SPEED_MPS
    from ament_formation.nodes.system import build_system

    system = build_system(
        ros_context,
        DATA / 'paper_short.yaml',
        executor,
        pty_dir=tmp_path / 'pty',
        start_delay_s=0.3,
        speed_factor=0.5,
        bridge_poll_rate_hz=200.0,
    )
    ctrl = system.controllers[0]
    try:
        assert spin_until(
            executor, lambda: ctrl.safety == 'running' and system.world.twin.t_s > 1.5, 30.0
        )
        assert abs(system.world.twin.state[0, 3]) > 0.02  # moving
        system.world.camera = None  # the camera goes dark
        t_cut = system.world.now_s()
        assert spin_until(executor, lambda: ctrl.safety == 'stopped_pose', 5.0)
        assert system.world.now_s() - t_cut < 0.5 + 0.1  # pose_timeout_s + a control period or so
        assert ctrl.mode['mode'] == 'stopped'
        # at rest (both wheels' rim speeds below REST_SPEED_MPS, docs/safety.md) and still at
        # rest 0.5 s later on the plant's clock: a stop that chatters around zero passes the
        # first test at its zero crossings, never the second
        half_axle = 0.5 * system.world.scenario.robot(0).params.axle_length_m
        rest = {'since': None, 'worst': 0.0}

        def at_rest_for(duration_s: float) -> bool:
            v, w = system.world.twin.state[0, 3], system.world.twin.state[0, 4]
            rim = abs(v) + half_axle * abs(w)
            t = system.world.twin.t_s
            if rim >= REST_SPEED_MPS:
                rest['since'], rest['worst'] = None, max(rest['worst'], rim)
                return False
            rest['since'] = t if rest['since'] is None else rest['since']
            return t - rest['since'] >= duration_s

        assert spin_until(executor, lambda: at_rest_for(0.5), 10.0), rest
    finally:
        system.destroy(executor)


def test_killing_the_controller_process_zeroes_the_board(ros_context, executor, tmp_path):
    """A controller process drives robot 0 through the in-process bridge and board; SIGKILL it:
    within 250 ms the board stops applying its torque (a zero command or STOP from the bridge's
    input timeout, or its own watchdog; STOP brakes the wheels to rest, docs/safety.md), measured
    in the board's own clock (the world's, which steps the boards), not when this test sees it.
    """
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
    bridge = BridgeNode(
        context=ros_context,
        namespace='/robot_0',
        parameter_overrides=[Parameter('port', value=str(pty / 'robot_0'))],
    )
    tracker = TrackerNode(
        context=ros_context, params=TrackerNodeParams(marker_ids=(0, 1), robot_ids=(0, 1))
    )
    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(scenario=str(scenario), wait_for_robots=False, start_delay_s=0.0),
    )
    for n in (world, bridge, tracker, coord):
        executor.add_node(n)
    # generous input timeouts: the subject is the kill, not a controlled stop when this test's one
    # executor (world, camera, tracker, bridge) runs late on a busy machine
    proc = subprocess.Popen(
        [
            program('formation_controller'),
            '--ros-args',
            '-r',
            '__ns:=/robot_0',
            '-p',
            f'scenario:={scenario}',
            '-p',
            'robot_id:=0',
            '-p',
            'wheel_timeout_s:=2.0',
            '-p',
            'pose_timeout_s:=5.0',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    board = world.boards[0].board
    board.command_log = log = []  # (board time, seq, left, right) of every torque command
    try:
        # the controller drives: the board applies a nonzero command from it (not a brake torque)
        ok = spin_until(
            executor,
            lambda: (
                bool(log)
                and log[-1][2:] != (0, 0)
                and not getattr(board, 'braking', False)
                or proc.poll() is not None
            ),
            120.0,
        )
        assert ok and proc.poll() is None, (
            f'the controller did not drive the board: {len(log)} commands, '
            f'last {log[-3:]}; controller: {_output(proc)}'
        )

        def stopped_at_s():
            """Board time when it stopped applying the controller's torque (None: not yet)."""
            times = [
                t for t, _, left, right in list(log) if t >= t_kill and (left, right) == (0, 0)
            ]
            times += [
                t
                for t in (getattr(board, 'brake_started_s', None), board.watchdog_tripped_at_s)
                if t is not None and t >= t_kill
            ]
            return min(times, default=None)

        t_kill = world.now_s()  # the boards' clock
        proc.send_signal(signal.SIGKILL)
        assert spin_until(executor, lambda: stopped_at_s() is not None, 2.0), (
            'the board never stopped'
        )
        print(
            f'board stopped {1e3 * (stopped_at_s() - t_kill):.0f} ms (board time) after the kill'
        )
        assert stopped_at_s() - t_kill <= 0.25
        assert np.all(board.applied_torque_nm == 0.0) or getattr(board, 'braking', False)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)
        for n in (coord, tracker, bridge, world):
            executor.remove_node(n)
            n.destroy_node()


def _output(proc) -> str:
    """What a process wrote so far (stdout, non-blocking), its last 2000 characters."""
    import os
    import select

    chunks = []
    while proc.stdout is not None and select.select([proc.stdout], [], [], 0)[0]:
        data = os.read(proc.stdout.fileno(), 65536)
        if not data:
            break
        chunks.append(data.decode(errors='replace'))
    return ''.join(chunks)[-2000:]


@pytest.mark.parametrize('team', [False, True], ids=['node_per_robot', 'formation_team'])
def test_head_on_encounter_through_the_nodes(ros_context, executor, tmp_path, team):
    """Two one-robot teams drive toward each other on a line (test/data/head_on.yaml): the
    coordinator assigns the mutual pair on /formation/encounters (S7), both controllers resolve it,
    BOTH leave it again (back to coordination; the coordinator's release forces the joint exit,
    S8.3), and the ground truth keeps them apart (> R_aa = 0.25 m between the controlled points).
    ``team``: both robots' bridges and controllers in one formation_team node, the controllers
    reading each other's state and mode in process (nodes/team.py) instead of over DDS.
    """
    import rclpy
    from std_msgs.msg import String

    from ament_formation.nodes.system import build_system

    system = build_system(
        ros_context,
        DATA / 'head_on.yaml',
        executor,
        pty_dir=tmp_path / 'pty',
        start_delay_s=0.5,
        speed_factor=0.5,
        bridge_poll_rate_hz=200.0,
        team=team,
    )
    # a team: one agent batch hosts both robots, which hear each other in process; a node per
    # robot: each agent hosts its own robot only and hears the other through DDS
    hosted = [c.batch.hosted for c in system.controllers.values()]
    assert hosted == ([(0, 1), (0, 1)] if team else [(0,), (1,)]), hosted
    assert all(c.batch is system.controllers[0].batch for c in system.controllers.values()) == team
    probe = rclpy.create_node('_probe_enc', context=ros_context)
    encounters = []
    probe.create_subscription(
        String,
        '/formation/encounters',
        lambda msg: encounters.append(m.encounters_from_msg(msg)),
        QOS_GRAPH,
    )
    executor.add_node(probe)
    samples = []
    heard = []  # whether each controller hears the coordinator (docs/law-changes.md §23)
    dds = set()  # (robot, other robot) whose state a controller subscribed to over DDS

    def finished():
        w = system.world
        samples.append((w.plant_time_s, w.twin.state[:, :2].copy()))
        heard.append([c.coordinated() for c in system.controllers.values()])
        for rid, c in system.controllers.items():
            topics = {s.topic_name for s in c.subscriptions}
            dds.update((rid, k) for k in (0, 1) if f'/robot_{k}/state' in topics)
        return w.done

    try:
        assert spin_until(executor, finished, 60.0), 'the world did not finish the scenario'
    finally:
        executor.remove_node(probe)
        probe.destroy_node()
        system.destroy(executor)
    start_s = system.world.start_s
    t = np.array([s[0] for s in samples]) - start_s
    x = np.stack([s[1] for s in samples])[t >= 0.0]
    dist = np.hypot(*(x[:, 0] - x[:, 1]).T)
    print(f'head-on: min distance {dist.min():.3f} m, end distance {dist[-1]:.3f} m')
    assert dist.min() > 0.25
    assert x[-1, 0, 0] > x[-1, 1, 0] + 0.2  # they passed: robot 0 ended up east of robot 1
    assert heard[-1] == [True, True], heard[-1]
    # in a team the robots never subscribe to each other's state; apart, each hears its partner
    assert dds == (set() if team else {(0, 1), (1, 0)}), dds
    pairs = [
        e.assignments
        for e in encounters
        if any(a['mode'] in ('yield', 'mutual') for a in e.assignments.values())
    ]
    assert pairs, 'the coordinator never assigned an encounter'
    a0, a1 = pairs[0][0], pairs[0][1]
    assert (a0['mode'], a0['partner'], a1['mode'], a1['partner']) == ('mutual', 1, 'mutual', 0)
    assert a0['t_entry_s'] == a1['t_entry_s']
    assert encounters[-1].assignments == {}  # released after the joint exit
    ev = {
        rid: [(e['event'], e['mode'], e['target']) for e in c.events]
        for rid, c in system.controllers.items()
    }
    assert ev[0][:1] == [('enter', 'mutual', 'robot_1')] and ev[1][:1] == [
        ('enter', 'mutual', 'robot_0')
    ], ev
    # BOTH robots leave the pair (own S8.3 test or the coordinator's joint release) and end in
    # coordination, after the coordinator assigned it
    exits = {
        rid: [e['t_s'] for e in c.events if (e['event'], e['mode']) == ('exit', 'mutual')]
        for rid, c in system.controllers.items()
    }
    print(f'head-on: mutual exits robot 0 at {exits[0]}, robot 1 at {exits[1]} s')
    assert ev[0] == [('enter', 'mutual', 'robot_1'), ('exit', 'mutual', 'robot_1')], ev
    assert ev[1] == [('enter', 'mutual', 'robot_0'), ('exit', 'mutual', 'robot_0')], ev
    for rid, c in system.controllers.items():
        assert _own_mode(c) == 'coordination', (rid, _own_mode(c), ev[rid])
        assert c.mode['mode'] in ('coordination', 'hold'), (rid, c.mode)
        assert exits[rid] and exits[rid][0] > pairs[0][rid]['t_entry_s'] + 1.0  # T_min (S8.3)
    assert abs(exits[0][0] - exits[1][0]) < 1.0, exits  # jointly (S8.3), up to the network
