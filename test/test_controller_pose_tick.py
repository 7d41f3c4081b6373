"""A camera pose is used the moment it arrives (issue 34, ``tick_on_pose``): the controller runs
its control period in the pose's callback and then restarts its timer from there, so the
pose-to-torque path has no idle wait of up to a period and no second tick follows at once; with
``tick_on_pose: false`` only the timer ticks.

A real subscription in a private context. The timer's callback holds the node's own
``control_tick``; the test wraps the node's attribute, which only the pose's callback looks up:
what the wrapper sees are the ticks the poses ran.
"""

from __future__ import annotations

from pathlib import Path
import time

import pytest

SCENARIO = Path(__file__).resolve().parent / 'data' / 'paper_short.yaml'


def _spin_until(executor, condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')
        executor.spin_once(timeout_sec=0.01)


@pytest.mark.parametrize('on_pose', [True, False])
def test_a_pose_runs_the_control_period_at_once_and_restarts_the_timer(
        ros_context, executor, on_pose):
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node

    from ament_formation.nodes.controller import ControllerNode, ControllerParams
    from ament_formation.ros.qos import QOS_CONTROL

    node = ControllerNode(
        context=ros_context, namespace='/robot_1',
        params=ControllerParams(scenario=str(SCENARIO), robot_id=1, tick_on_pose=on_pose))
    camera = Node('camera_probe', context=ros_context)
    calls: list[str] = []
    tick, reset = node.control_tick, node.timer.reset
    node.control_tick = lambda now_s=None: (calls.append('tick'), tick(now_s))[1]
    node.timer.reset = lambda: (calls.append('reset'), reset())[1]
    try:
        pub = camera.create_publisher(PoseStamped, '/robot_1/pose', QOS_CONTROL)
        executor.add_node(node)
        executor.add_node(camera)
        _spin_until(executor, lambda: pub.get_subscription_count() > 0, 20.0, 'the subscription')
        _spin_until(executor, lambda: node.ticks >= 3, 10.0, 'timer ticks')
        assert calls == []  # the timer's ticks do not go through the attribute
        msg = PoseStamped()
        now_ns = node.get_clock().now().nanoseconds
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now_ns, 1_000_000_000)
        msg.pose.position.y = 1.0
        msg.pose.orientation.w = 1.0
        pub.publish(msg)
        _spin_until(executor, lambda: node.batch.state.est.i[node.r].any(), 10.0,
                    'the pose in the agent')
        ticks = node.ticks
        _spin_until(executor, lambda: node.ticks >= ticks + 3, 10.0, 'timer ticks after it')
        assert calls == (['tick', 'reset'] if on_pose else [])
    finally:
        executor.remove_node(camera)
        executor.remove_node(node)
        camera.destroy_node()
        node.destroy_node()
