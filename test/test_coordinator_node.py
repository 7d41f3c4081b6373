"""formation_coordinator in-process: mission start, S9 rewiring on /formation/graph, markers that
replace and delete as a viewer sees them, diagnostics.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.marker_view import MarkerViewer
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_MARKERS

DATA = Path(__file__).resolve().parent / 'data'


def test_redundant_edge_rewiring_seen_on_graph(ros_context, executor):
    import rclpy
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams

    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(
            scenario=str(DATA / 'redundant_chain.yaml'), start_delay_s=0.5, markers_rate_hz=20.0
        ),
    )
    fake = rclpy.create_node('fake_controllers', context=ros_context)
    state_pubs = {
        i: fake.create_publisher(m.Odometry, f'/robot_{i}/state', QOS_CONTROL) for i in range(4)
    }
    mode_pubs = {
        i: fake.create_publisher(String, f'/robot_{i}/mode', QOS_CONTROL) for i in range(4)
    }
    graphs: list[m.GraphMessage] = []
    markers: list = []
    fake.create_subscription(
        String, '/formation/graph', lambda msg: graphs.append(m.graph_from_msg(msg)), QOS_GRAPH
    )
    fake.create_subscription(MarkerArray, '/formation/markers', markers.append, QOS_MARKERS)
    executor.add_node(coord)
    executor.add_node(fake)

    assert spin_until(
        executor,
        lambda: (
            graphs
            and all(p.get_subscription_count() for p in state_pubs.values())
            and all(p.get_subscription_count() for p in mode_pubs.values())
        ),
        10.0,
    )
    first = graphs[-1]
    assert first.start_s is None
    assert first.parents == {0: None, 1: 0, 2: 1, 3: 0}
    assert first.offsets_m[2] == pytest.approx((-0.5, -0.5))  # c_2 - c_1

    # not every controller is up: no start yet
    for i in (0, 1, 2):
        state_pubs[i].publish(m.odometry([0, 0, 0, 0, 0], m.stamp_from_s(1.0), f'robot_{i}'))
    assert spin_until(executor, lambda: len(coord.states) == 3, 5.0)
    assert coord.start_s is None
    state_pubs[3].publish(m.odometry([0, 0, 0, 0, 0], m.stamp_from_s(1.0), 'robot_3'))
    assert spin_until(executor, lambda: graphs[-1].start_s is not None, 5.0)
    started = graphs[-1]
    assert (
        0.3 < started.start_s - started.stamp_s <= 0.5
    )  # start_delay_s after the last robot came up

    def latest_with(pred):
        return spin_until(executor, lambda: bool(graphs) and pred(graphs[-1]), 5.0)

    # robot 1 (the middle of the chain 0 -> 1 -> 2) starts avoiding: 2 is re-parented to 3 (S9)
    mode_pubs[1].publish(m.mode_msg('obstacle', 'O1', 'ccw', avoiding=True))
    assert latest_with(lambda g: g.avoiding == (1,))
    avoid = graphs[-1]
    assert avoid.revision == started.revision + 1
    assert avoid.parents == {0: None, 1: None, 2: 3, 3: 0}
    assert avoid.offsets_m[2] == pytest.approx((-0.5, 0.5))  # c_2 - c_3
    assert avoid.start_s == started.start_s

    # a mode message that does not change the avoiding set does not make a new revision
    mode_pubs[0].publish(m.mode_msg('coordination', avoiding=False))
    spin_until(executor, lambda: coord.modes.get(0) is not None, 5.0)
    assert coord.revision == avoid.revision

    # robot 1 exits: the original tree is restored (S9 step 6)
    mode_pubs[1].publish(m.mode_msg('coordination', avoiding=False))
    assert latest_with(lambda g: g.avoiding == ())
    restored = graphs[-1]
    assert restored.revision == avoid.revision + 1
    assert restored.parents == first.parents

    # markers drawn after the restoration: P/L/Q ellipse of the obstacle, four robots (disc +
    # arrow; they published a state within ROBOT_SILENT_S), one arrow per edge of the original tree
    # (an array already in flight at the restoration may still show the pruned tree)
    def edges(arr):
        return sorted(
            mk.id for mk in arr.markers if mk.ns == 'graph_edges' and mk.action == mk.ADD
        )

    for i in range(4):
        state_pubs[i].publish(m.odometry([0.1 * i, 0, 0, 0, 0], m.stamp_from_s(2.0), f'robot_{i}'))
    n_before = len(markers)
    assert spin_until(
        executor,
        lambda: any(
            sum(mk.action == mk.ADD for mk in a.markers) == 3 + 8 + 3 and edges(a) == [1, 2, 3]
            for a in markers[n_before:]
        ),
        5.0,
    )
    fake.destroy_node()
    coord.destroy_node()


def test_bad_parameters_name_the_field():
    from ament_formation.core.errors import ConfigError
    from ament_formation.nodes.coordinator import CoordinatorParams

    with pytest.raises(ConfigError, match='scenario'):
        CoordinatorParams()
    with pytest.raises(ConfigError, match='start_delay_s'):
        CoordinatorParams(scenario='x.yaml', start_delay_s=-1.0)


def expected_markers(robots, edge_children, obstacles=1):
    keys = {(f'ellipse_{s}', j) for s in 'PLQ' for j in range(obstacles)}
    keys |= {('robots', i) for i in robots} | {('headings', i) for i in robots}
    return keys | {('graph_edges', c) for c in edge_children}


def test_markers_replace_and_delete_over_a_run(ros_context, executor):
    """A run in three layouts (all robots; robot 1 avoiding, the graph re-parents 2 under 3;
    robot 3 silent): the viewer always shows exactly the live objects, never more.
    """
    import time

    import rclpy
    from visualization_msgs.msg import MarkerArray

    from ament_formation.nodes.coordinator import (
        CoordinatorNode,
        CoordinatorParams,
        ROBOT_SILENT_S,
    )

    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(
            scenario=str(DATA / 'redundant_chain.yaml'),
            start_delay_s=0.0,
            markers_rate_hz=20.0,
            encounter_rate_hz=1.0,
        ),
    )
    fake = rclpy.create_node('fake_controllers', context=ros_context)
    from std_msgs.msg import String

    state_pubs = {
        i: fake.create_publisher(m.Odometry, f'/robot_{i}/state', QOS_CONTROL) for i in range(4)
    }
    mode_pub = fake.create_publisher(String, '/robot_1/mode', QOS_CONTROL)
    alive = {0, 1, 2, 3}
    fake.create_timer(
        0.05,
        lambda: [
            state_pubs[i].publish(
                m.odometry([0.3 * i, 0.1, 0, 0, 0], m.stamp_from_s(1.0), f'robot_{i}')
            )
            for i in sorted(alive)
        ],
    )
    viewer = MarkerViewer()
    arrays = []

    def on_markers(arr):
        now = time.monotonic()
        viewer.apply(arr, now)
        arrays.append(arr)
        # never more than the objects of the scenario on screen (3 ellipses, 4 robots x 2, 3 edges)
        assert len(viewer.shown(now)) <= 3 + 8 + 3

    fake.create_subscription(MarkerArray, '/formation/markers', on_markers, QOS_MARKERS)
    executor.add_node(coord)
    executor.add_node(fake)

    def shows(keys):
        return spin_until(executor, lambda: viewer.shown(time.monotonic()) == keys, 10.0)

    assert shows(expected_markers(range(4), [1, 2, 3])), viewer.shown(time.monotonic())
    # robot 1 avoids: edge 0 -> 1 goes, 2 is re-parented to 3 (same marker id 2, new end points)
    assert spin_until(executor, lambda: mode_pub.get_subscription_count() > 0, 5.0)
    mode_pub.publish(m.mode_msg('obstacle', 'O1', 'ccw', avoiding=True))
    assert shows(expected_markers(range(4), [2, 3]))
    # robot 3 falls silent: its disc, heading and both edges touching it disappear
    alive.discard(3)
    t_silent = time.monotonic()
    assert shows(expected_markers([0, 1, 2], []))
    assert time.monotonic() - t_silent >= ROBOT_SILENT_S * 0.9

    n = len(arrays)
    # DELETEALLs came first in their arrays, at least one per layout (a viewer on a depth-1
    # subscription may miss one: the lifetimes then remove what it still shows)
    for arr in arrays:
        assert all(mk.action != mk.DELETEALL for mk in arr.markers[1:])
    assert viewer.actions['deleteall'] >= 2, viewer.actions
    # a DELETEALL exactly when the set of objects changes (checked on the arrays as built)
    now = coord.now_s()

    def has_deleteall(arr):
        return arr.markers[0].action == arr.markers[0].DELETEALL

    coord.marker_array(now)
    assert not has_deleteall(coord.marker_array(now))
    coord._heard_mono[0] = -1e9  # robot 0 falls silent too
    arr = coord.marker_array(now)
    assert has_deleteall(arr) and ('robots', 0) not in {(mk.ns, mk.id) for mk in arr.markers}
    assert not has_deleteall(coord.marker_array(now))
    assert viewer.max_adds_per_array <= 3 + 8 + 3
    assert viewer.actions['add'] <= n * (3 + 8 + 3)
    print(f'{n} arrays: {viewer.actions}')
    # robot and edge markers expire when not re-sent; ellipses stay until replaced
    last = arrays[-1]
    lifetimes = {mk.ns: mk.lifetime.sec + mk.lifetime.nanosec * 1e-9 for mk in last.markers}
    assert lifetimes['robots'] >= 1.0 and lifetimes['ellipse_P'] == 0.0
    fake.destroy_node()
    coord.destroy_node()


def test_diagnostics_of_the_coordinator(ros_context, executor):
    """Names '<node>: <component>', a bad mode payload counted (WARN), a stalled timer reported."""
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from std_msgs.msg import String

    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams
    from ament_formation.ros import diagnostics as diag
    from ament_formation.ros.qos import QOS_DIAGNOSTICS

    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(
            scenario=str(DATA / 'redundant_chain.yaml'), start_delay_s=0.0, wait_for_robots=False
        ),
    )
    probe = rclpy.create_node('probe', context=ros_context)
    statuses: dict[str, list] = {}

    def on_diag(arr):
        for st in arr.status:
            statuses.setdefault(st.name, []).append(st)

    probe.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_DIAGNOSTICS)
    mode_pub = probe.create_publisher(String, '/robot_2/mode', QOS_CONTROL)
    executor.add_node(coord)
    executor.add_node(probe)
    names = {
        'formation_coordinator: graph',
        'formation_coordinator: robots',
        'formation_coordinator: inputs',
        'formation_coordinator: arbitration loop',
        'formation_coordinator: markers loop',
    }
    assert spin_until(executor, lambda: names <= set(statuses), 60.0), set(statuses)

    assert spin_until(executor, lambda: mode_pub.get_subscription_count() > 0, 5.0)
    mode_pub.publish(String(data='{"mode": "obstacle"}'))  # no schema: rejected, counted
    assert spin_until(
        executor,
        lambda: any(
            diag.level_int(s.level) == diag.WARN
            and {kv.key: kv.value for kv in s.values}['rejected_mode'] == '1'
            for s in statuses['formation_coordinator: inputs']
        ),
        5.0,
    )
    assert coord.rejected['mode'] == 1

    # the executor is blocked for 0.3 s (15 arbitration periods): the stall is published at once
    # (the first arbitrations may load compiled kernels: wait until the loop runs steadily)
    watch = coord.arbitration_watch
    ticks0 = watch.ticks
    assert spin_until(executor, lambda: watch.ticks > ticks0 + 20, 120.0)
    stalls0 = watch.stalls
    n_before = len(statuses['formation_coordinator: arbitration loop'])
    blocker = probe.create_timer(0.05, lambda: (time.sleep(0.3), blocker.cancel()))

    def stall_seen():
        for s in statuses['formation_coordinator: arbitration loop'][n_before:]:
            values = {kv.key: kv.value for kv in s.values}
            if diag.level_int(s.level) == diag.WARN and int(values['stalls']) > stalls0:
                return float(values['last_stall_gap_s'])
        return None

    assert spin_until(executor, lambda: stall_seen() is not None, 5.0)
    assert stall_seen() >= 0.25
    probe.destroy_node()
    coord.destroy_node()


def _two_robots(tmp_path, duration_s: float):
    """Leader 0 on a line at 0.05 m/s, follower 1 1 m to its left; no obstacle."""
    import yaml

    path = tmp_path / 'two.yaml'
    path.write_text(yaml.safe_dump({
        'name': 'two',
        'duration_s': duration_s,
        'robots': [
            {'id': 0, 'leader': True, 'slot_m': [0.0, 0.0], 'initial_pose': [0.0, 0.0, 0.0],
             'path': {'type': 'line', 'start_m': [0.0, 0.0], 'heading_rad': 0.0,
                      'speed_mps': 0.05}},
            {'id': 1, 'slot_m': [0.0, 1.0], 'initial_pose': [0.0, 1.0, 0.0]},
        ],
        'graph': {'edges': [[0, 1]]},
    }, sort_keys=False))
    return path


def test_encounters_v2_carry_the_teams_rates_and_the_missions_end(
    ros_context, executor, tmp_path
):
    """/formation/encounters (v2): sent before the start (the robots hear the coordinator), then
    the leader's progress rate (S17.1): 0 while its follower is 1 m from its goal (the team waits
    for it, E above reform_stop_m), 1 once it is back; the mission's end (every reference at its
    end, S17.3) once, no earlier than duration_s of progress.
    """
    import rclpy
    from std_msgs.msg import String

    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams

    duration_s = 2.0
    coord = CoordinatorNode(
        context=ros_context,
        params=CoordinatorParams(scenario=str(_two_robots(tmp_path, duration_s)),
                                 start_delay_s=0.2, wait_for_robots=False, markers_rate_hz=0.0,
                                 republish_s=0.3),
    )
    fake = rclpy.create_node('fake_controllers', context=ros_context)
    got: list[m.EncountersMessage] = []
    fake.create_subscription(
        String, '/formation/encounters', lambda msg: got.append(m.encounters_from_msg(msg)),
        QOS_GRAPH)
    state_pubs = {i: fake.create_publisher(m.Odometry, f'/robot_{i}/state', QOS_CONTROL)
                  for i in (0, 1)}
    where = {0: (0.0, 0.0), 1: (0.0, 2.0)}  # robot 1 1 m beyond its slot
    fake.create_timer(0.02, lambda: [
        state_pubs[i].publish(m.odometry([*where[i], 0.0, 0.0, 0.0], m.stamp_from_s(1.0),
                                         f'robot_{i}')) for i in (0, 1)])
    executor.add_node(coord)
    executor.add_node(fake)
    try:
        # transient local: the message sent before the start reaches a late subscriber
        assert spin_until(executor, lambda: bool(got), 10.0)
        assert got[0].assignments == {} and got[0].mission_end_s is None
        start_s = coord.start_s
        # the team waits for robot 1: target 0, the reference slows down and stays short of its
        # end
        assert spin_until(executor, lambda: got[-1].rates.get(0) == 0.0, 20.0), got[-1]
        assert got[-1].stamp_s >= start_s and got[-1].mission_end_s is None
        # its rate follows the target with progress_tau_s (1 s): it comes to rest about 1 s of
        # path time on, short of the end
        pr = coord.core.progress
        assert spin_until(executor, lambda: pr.sd[0] < 0.02, 20.0), pr
        assert 0.5 < pr.s[0] < 1.1 and got[-1].mission_end_s is None
        # robot 1 back at its goal: the rate goes back to 1, the mission ends
        where[1] = (0.0, 1.0)
        assert spin_until(executor, lambda: got[-1].rates.get(0) == 1.0, 20.0), got[-1]
        assert spin_until(executor, lambda: got[-1].mission_end_s is not None, 30.0), got[-1]
        end = got[-1]
        # the waiting made the mission last longer than its free traversal
        assert duration_s < end.mission_end_s <= end.stamp_s - start_s + 1e-6
        assert coord.core.progress.s[0] == duration_s  # the reference rests at its end
        n = len(got)
        assert spin_until(executor, lambda: len(got) > n, 5.0)  # re-sent: the end stays said
        assert got[-1].mission_end_s == end.mission_end_s
        assert [g.revision for g in got] == sorted(g.revision for g in got)
    finally:
        fake.destroy_node()
        coord.destroy_node()
