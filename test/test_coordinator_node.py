"""formation_coordinator in-process: mission start, S9 rewiring on /formation/graph, markers."""
from __future__ import annotations

from pathlib import Path

import pytest

from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_MARKERS

DATA = Path(__file__).resolve().parent / "data"


def test_redundant_edge_rewiring_seen_on_graph(ros_context, executor):
    import rclpy
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    from ament_formation.nodes.coordinator import CoordinatorNode, CoordinatorParams

    coord = CoordinatorNode(context=ros_context, params=CoordinatorParams(
        scenario=str(DATA / "redundant_chain.yaml"), start_delay_s=0.5, markers_rate_hz=20.0))
    fake = rclpy.create_node("fake_controllers", context=ros_context)
    state_pubs = {i: fake.create_publisher(m.Odometry, f"/robot_{i}/state", QOS_CONTROL) for i in range(4)}
    mode_pubs = {i: fake.create_publisher(String, f"/robot_{i}/mode", QOS_CONTROL) for i in range(4)}
    graphs: list[m.GraphMessage] = []
    markers: list = []
    fake.create_subscription(String, "/formation/graph", lambda msg: graphs.append(m.graph_from_msg(msg)),
                             QOS_GRAPH)
    fake.create_subscription(MarkerArray, "/formation/markers", markers.append, QOS_MARKERS)
    executor.add_node(coord)
    executor.add_node(fake)

    assert spin_until(executor, lambda: graphs and all(p.get_subscription_count() for p in state_pubs.values())
                      and all(p.get_subscription_count() for p in mode_pubs.values()), 10.0)
    first = graphs[-1]
    assert first.start_s is None
    assert first.parents == {0: None, 1: 0, 2: 1, 3: 0}
    assert first.offsets_m[2] == pytest.approx((-0.5, -0.5))   # c_2 - c_1

    # not every controller is up: no start yet
    for i in (0, 1, 2):
        state_pubs[i].publish(m.odometry([0, 0, 0, 0, 0], m.stamp_from_s(1.0), f"robot_{i}"))
    assert spin_until(executor, lambda: len(coord.states) == 3, 5.0)
    assert coord.start_s is None
    state_pubs[3].publish(m.odometry([0, 0, 0, 0, 0], m.stamp_from_s(1.0), "robot_3"))
    assert spin_until(executor, lambda: graphs[-1].start_s is not None, 5.0)
    started = graphs[-1]
    assert 0.3 < started.start_s - started.stamp_s <= 0.5  # start_delay_s after the last robot came up

    def latest_with(pred):
        return spin_until(executor, lambda: bool(graphs) and pred(graphs[-1]), 5.0)

    # robot 1 (the middle of the chain 0 -> 1 -> 2) starts avoiding: 2 is re-parented to 3 (S9)
    mode_pubs[1].publish(m.mode_msg("obstacle", "O1", "ccw", avoiding=True))
    assert latest_with(lambda g: g.avoiding == (1,))
    avoid = graphs[-1]
    assert avoid.revision == started.revision + 1
    assert avoid.parents == {0: None, 1: None, 2: 3, 3: 0}
    assert avoid.offsets_m[2] == pytest.approx((-0.5, 0.5))    # c_2 - c_3
    assert avoid.start_s == started.start_s

    # a mode message that does not change the avoiding set does not make a new revision
    mode_pubs[0].publish(m.mode_msg("coordination", avoiding=False))
    spin_until(executor, lambda: coord.modes.get(0) is not None, 5.0)
    assert coord.revision == avoid.revision

    # robot 1 exits: the original tree is restored (S9 step 6)
    mode_pubs[1].publish(m.mode_msg("coordination", avoiding=False))
    assert latest_with(lambda g: g.avoiding == ())
    restored = graphs[-1]
    assert restored.revision == avoid.revision + 1
    assert restored.parents == first.parents

    # markers drawn after the restoration: P/L/Q ellipse of the obstacle, four robots (disc +
    # arrow), one edge list with the 3 edges of the original tree
    # (an array already in flight at the restoration may still show the pruned tree)
    def edge_points(arr):
        return [len(mk.points) for mk in arr.markers if mk.ns == "graph_edges"]

    n_before = len(markers)
    assert spin_until(executor, lambda: any(len(a.markers) == 3 + 8 + 1 and edge_points(a) == [2 * 3]
                                            for a in markers[n_before:]), 5.0)
    fake.destroy_node()
    coord.destroy_node()


def test_bad_parameters_name_the_field():
    from ament_formation.core.errors import ConfigError
    from ament_formation.nodes.coordinator import CoordinatorParams

    with pytest.raises(ConfigError, match="scenario"):
        CoordinatorParams()
    with pytest.raises(ConfigError, match="start_delay_s"):
        CoordinatorParams(scenario="x.yaml", start_delay_s=-1.0)
