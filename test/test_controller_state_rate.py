"""A controller sends its commanded acceleration (and, once its estimate is initialised, its
state) every ``round(control_rate_hz / state_rate_hz)``-th control period (docs/control-law.md
S10.2): the bytes on a robot's link scale with ``state_rate_hz``.

A real subscription in a private context counts what the node sent against its own tick count.
"""

from __future__ import annotations

from pathlib import Path

import pytest

SCENARIO = Path(__file__).resolve().parent / 'data' / 'paper_short.yaml'


def _spin_until(executor, condition, timeout_s: float, what: str) -> None:
    from ament_formation.ros.executors import spin_until

    assert spin_until(executor, condition, timeout_s), f'timed out waiting for {what}'


@pytest.mark.parametrize('state_hz, every', [(100.0, 1), (25.0, 4)])
def test_the_state_goes_out_every_state_every_th_period(ros_context, executor, state_hz, every):
    from geometry_msgs.msg import AccelStamped
    from rclpy.node import Node

    from ament_formation.nodes.controller import ControllerNode, ControllerParams
    from ament_formation.ros.qos import QOS_CONTROL

    node = ControllerNode(
        context=ros_context, namespace='/robot_0',
        params=ControllerParams(scenario=str(SCENARIO), robot_id=0, state_rate_hz=state_hz))
    probe = Node('state_probe', context=ros_context)
    got: list[int] = []
    try:
        probe.create_subscription(AccelStamped, '/robot_0/accel',
                                  lambda _m: got.append(node.ticks), QOS_CONTROL)
        executor.add_node(node)
        executor.add_node(probe)
        _spin_until(executor, lambda: node.pub_accel.get_subscription_count() > 0, 20.0,
                    'the subscription')
        _spin_until(executor, lambda: len(got) >= 3, 20.0, 'the first accelerations')
        first, n0 = node.ticks, len(got)
        _spin_until(executor, lambda: node.ticks >= first + 40 * every, 60.0, 'the ticks')
        last = node.ticks
        _spin_until(executor, lambda: len(got) > n0 and got[-1] >= last, 10.0, 'the last one')
        sent = sum(1 for t in got if first < t <= last)
        # one in each run of `every` consecutive ticks (none lost on a private context)
        assert (last - first) // every - 1 <= sent <= (last - first) // every + 1, (sent, every)
    finally:
        executor.remove_node(probe)
        executor.remove_node(node)
        probe.destroy_node()
        node.destroy_node()
