"""What a controller hears (issue "Robots as separate hosts"): full-rate state/accel of its parents
and of the robots within hearing range only (range from the camera poses, S7), so per-robot traffic
grows linearly with the team instead of every robot hearing every robot at 100 Hz.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL


def _scenario(tmp_path):
    """Leader 0, followers 1 and 2 of it, 2 m apart (far outside each other's S7 region Q)."""
    robots = [
        {
            'id': 0,
            'leader': True,
            'slot_m': [0.0, 0.0],
            'initial_pose': [0.0, 0.0, 0.0],
            'path': {'type': 'line', 'start_m': [0.0, 0.0], 'heading_rad': 0.0, 'speed_mps': 0.05},
        },
        {'id': 1, 'slot_m': [0.0, 1.0], 'initial_pose': [0.0, 1.0, 0.0]},
        {'id': 2, 'slot_m': [0.0, -1.0], 'initial_pose': [0.0, -1.0, 0.0]},
    ]
    path = tmp_path / 'three.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'name': 'three',
                'duration_s': 10.0,
                'robots': robots,
                'graph': {'edges': [[0, 1], [0, 2]]},
            },
            sort_keys=False,
        )
    )
    return path


@pytest.mark.parametrize('kind', ['single', 'events'])
def test_controller_hears_parent_always_and_others_only_in_range(ros_context, tmp_path, kind):
    """Subscriptions made and dropped while spinning, under both executors the programs use."""
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    from ament_formation.nodes.controller import (
        ControllerNode,
        ControllerParams,
        HEAR_HYSTERESIS_M,
    )

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1),
    )
    pub_node = rclpy.create_node('_hearing_probe', context=ros_context)
    pose_pub = pub_node.create_publisher(PoseStamped, '/robot_2/pose', QOS_CONTROL)
    state_pub = pub_node.create_publisher(m.Odometry, '/robot_2/state', QOS_CONTROL)
    executor = (SingleThreadedExecutor if kind == 'single' else EventsExecutor)(
        context=ros_context
    )
    executor.add_node(ctl)
    executor.add_node(pub_node)
    try:
        parent, other = ctl.neighbours[0], ctl.neighbours[2]
        assert len(parent.subs) == 2 and other.subs == []  # pi0 at full rate, robot 2 not
        reach = ctl._hear_range_m[2]
        # S7: Q of robot 2 seen by robot 1 is kappa (R1 + R2 + margin) = 1.8 * 0.25 m; plus the
        # margin
        assert reach == np.float64(1.8 * 0.25 + ctl.prm.hear_margin_m)
        ctl._own_xy = (0.0, 1.0)

        def pose(y):
            msg = PoseStamped()
            msg.header.frame_id = 'world'
            msg.header.stamp = m.stamp_from_s(ctl.now_s())
            msg.pose.position.y = float(y)
            msg.pose.orientation.w = 1.0
            return msg

        def state():
            return m.odometry(
                np.array([0.0, 1.0 - reach + 0.1, 0.0, 0.05, 0.0]),
                m.stamp_from_s(ctl.now_s()),
                'robot_2',
            )

        # far: never heard at full rate, whatever it publishes
        for _ in range(5):
            pose_pub.publish(pose(-1.0))
            state_pub.publish(state())
            executor.spin_once(timeout_sec=0.02)
        assert other.subs == [] and other.state is None
        # its camera pose comes within range: state heard from then on
        assert spin_until(
            executor,
            lambda: (pose_pub.publish(pose(1.0 - reach + 0.1)), bool(other.subs))[1],
            10.0,
        )

        def heard():
            state_pub.publish(state())
            return other.state is not None

        assert spin_until(executor, heard, 10.0), "robot 2's state was not heard once in range"
        np.testing.assert_allclose(other.state[:2], [0.0, 1.0 - reach + 0.1], atol=1e-9)
        # hysteresis: still heard just beyond the range, dropped beyond range + hysteresis
        for _ in range(3):
            pose_pub.publish(pose(1.0 - reach - 0.5 * HEAR_HYSTERESIS_M))
            executor.spin_once(timeout_sec=0.02)
        assert other.subs
        assert spin_until(
            executor,
            lambda: (pose_pub.publish(pose(1.0 - reach - 2 * HEAR_HYSTERESIS_M)), not other.subs)[
                1
            ],
            10.0,
        )
        assert other.state is None  # no longer used
        assert len(parent.subs) == 2  # the parent stays heard
    finally:
        for n in (ctl, pub_node):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


def test_hear_all_subscribes_every_robot(ros_context, tmp_path):
    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1, hear_all=True),
    )
    try:
        assert all(len(nb.subs) == 2 for nb in ctl.neighbours.values())
    finally:
        ctl.destroy_node()


@pytest.mark.parametrize('kind', ['single', 'events'])
def test_tick_inputs_are_taken_at_the_period_not_by_the_executor(ros_context, tmp_path, kind):
    """``tick_inputs`` (a team's control loop): the heard robots' state and accel wait for
    take_inputs() (called at each period), which runs them oldest first; executors never take
    them; a robot no longer heard gets no state from a message taken after it was dropped.
    """
    import threading
    import time

    from geometry_msgs.msg import AccelStamped, PoseStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1),
        tick_timer=False,
        lock=threading.Lock(),
        tick_inputs=True,
    )
    pub_node = rclpy.create_node('_tick_inputs_probe', context=ros_context)
    state_pub = pub_node.create_publisher(m.Odometry, '/robot_0/state', QOS_CONTROL)
    accel_pub = pub_node.create_publisher(AccelStamped, '/robot_0/accel', QOS_CONTROL)
    pose_pub = pub_node.create_publisher(PoseStamped, '/robot_2/pose', QOS_CONTROL)
    executor = (SingleThreadedExecutor if kind == 'single' else EventsExecutor)(
        context=ros_context
    )
    executor.add_node(ctl)
    executor.add_node(pub_node)
    try:
        parent, other = ctl.neighbours[0], ctl.neighbours[2]
        assert len(parent.subs) == 2  # in the graph as before, but not served by executors
        served = list(ctl.subscriptions)
        assert all(s not in served for s in parent.subs) and len(served) >= 4
        t0 = ctl.now_s()

        def state(k):
            return m.odometry([0.1 * k, 0.0, 0.0, 0.05, 0.0], m.stamp_from_s(t0 + k), 'robot_0')

        for k in (1, 2, 3):
            state_pub.publish(state(k))
            accel_pub.publish(m.accel_stamped([0.01 * k, 0.0], m.stamp_from_s(t0 + k)))
        # the executor runs (whatever it has to do) but never takes these
        spin_until(executor, lambda: False, 1.0)
        assert parent.state is None
        deadline = time.monotonic() + 10.0
        while parent.stamp_s != m.stamp_to_s(m.stamp_from_s(t0 + 3)):
            assert time.monotonic() < deadline, 'the period never took the parent state'
            executor.spin_once(timeout_sec=0.02)
            ctl.take_inputs()
        np.testing.assert_array_equal(parent.state, [0.1 * 3, 0.0, 0.0, 0.05, 0.0])  # the newest
        np.testing.assert_array_equal(parent.accel, [0.01 * 3, 0.0])
        # robot 2 comes within range (its camera pose: executor thread), then leaves it: its state
        # subscription is dropped under the lock, and no later period brings its state back
        ctl._own_xy = (0.0, 1.0)
        far = ctl._hear_range_m[2] + 2.0

        def pose(y):
            msg = PoseStamped()
            msg.header.frame_id = 'world'
            msg.header.stamp = m.stamp_from_s(ctl.now_s())
            msg.pose.position.y = float(y)
            msg.pose.orientation.w = 1.0
            return msg

        assert spin_until(
            executor, lambda: (pose_pub.publish(pose(0.9)), bool(other.subs))[1], 10.0
        )
        assert all(s not in list(ctl.subscriptions) for s in other.subs)
        assert spin_until(
            executor, lambda: (pose_pub.publish(pose(1.0 - far)), not other.subs)[1], 10.0
        )
        ctl.take_inputs()
        assert other.state is None
    finally:
        executor.shutdown()
        pub_node.destroy_node()
        ctl.destroy_node()
