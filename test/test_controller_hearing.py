"""What a controller hears (S10.2, issue "Robots as separate hosts"): full-rate state/accel of its
current and original parents, of its assignment's partner and of the robots within hearing range
only (range from the camera poses against its own estimate), so per-robot traffic grows linearly
with the team instead of every robot hearing every robot at 100 Hz. The agent decides what it
needs (AgentBatch.needed); the node subscribes and drops accordingly (update_hearing, 10 Hz).
"""

from __future__ import annotations

import math

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


def _pose(stamp_s: float, y: float):
    from geometry_msgs.msg import PoseStamped

    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = m.stamp_from_s(stamp_s)
    msg.pose.position.y = float(y)
    msg.pose.orientation.w = 1.0
    return msg


def _locate(ctl, executor, probe, y: float = 1.0) -> None:
    """Robot 1's own camera pose at (0, y), through its pose topic, and one control period: its
    estimate (what the hearing range is measured from) is there.
    """
    from geometry_msgs.msg import PoseStamped

    pub = probe.create_publisher(PoseStamped, '/robot_1/pose', QOS_CONTROL)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 10.0)
    st = ctl.batch.state
    assert spin_until(
        executor, lambda: (pub.publish(_pose(ctl.now_s(), y)), st.ncam[ctl.r] > 0)[1], 10.0
    )
    ctl.control_tick(ctl.now_s())
    assert ctl.batch.initialized(ctl.r)
    np.testing.assert_allclose(st.x[ctl.r, ctl.batch.row[1], :2], (0.0, y), atol=1e-9)


@pytest.mark.parametrize('kind', ['single', 'events'])
def test_controller_hears_parent_always_and_others_only_in_range(ros_context, tmp_path, kind):
    """Subscriptions made and dropped while spinning, under both executors the programs use."""
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        tick_timer=False,
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1),
    )
    probe = rclpy.create_node('_hearing_probe', context=ros_context)
    pose_pub = probe.create_publisher(PoseStamped, '/robot_2/pose', QOS_CONTROL)
    state_pub = probe.create_publisher(m.Odometry, '/robot_2/state', QOS_CONTROL)
    executor = (SingleThreadedExecutor if kind == 'single' else EventsExecutor)(
        context=ros_context
    )
    executor.add_node(ctl)
    executor.add_node(probe)
    b, st = ctl.batch, ctl.batch.state
    k2 = b.row[2]
    try:
        # pi0 (the original parent) at full rate from the first hearing check; robot 2 not
        assert spin_until(executor, lambda: 0 in ctl._full, 10.0)
        assert len(ctl._full[0]) == 2 and 2 not in ctl._full
        # S10.2: Q of robot 2 seen by robot 1 is kappa (R1 + R2 + margin) = 1.8 * 0.25 m; plus
        # the hearing margin
        reach = b.static.reach[b.row[1], k2]
        assert reach == pytest.approx(1.8 * 0.25 + ctl.prm.hear_margin_m, abs=1e-12)
        _locate(ctl, executor, probe)
        hyst = ctl.prm.hear_hysteresis_m

        def state():
            return m.odometry(
                np.array([0.0, 1.0 - reach + 0.1, 0.0, 0.05, 0.0]),
                m.stamp_from_s(ctl.now_s()),
                'robot_2',
            )

        # far: never heard at full rate, whatever it publishes (three hearing checks)
        spin_until(executor, lambda: (pose_pub.publish(_pose(0.0, -1.0)),
                                      state_pub.publish(state()), False)[2], 0.35)
        assert 2 not in ctl._full and st.stamp[ctl.r, k2] == -math.inf
        assert not st.in_range[ctl.r, k2]
        # its camera pose comes within range: state heard from then on
        assert spin_until(
            executor,
            lambda: (pose_pub.publish(_pose(0.0, 1.0 - reach + 0.1)), 2 in ctl._full)[1],
            10.0,
        )
        assert st.in_range[ctl.r, k2] and b.needed(1) == [0, 2]

        def heard():
            state_pub.publish(state())
            return st.stamp[ctl.r, k2] > -math.inf

        assert spin_until(executor, heard, 10.0), "robot 2's state was not heard once in range"
        np.testing.assert_allclose(st.heard_x[ctl.r, k2, :2], [0.0, 1.0 - reach + 0.1], atol=1e-9)
        # hysteresis: still heard just beyond the range (three hearing checks), dropped beyond
        # range + hysteresis
        spin_until(executor, lambda: (pose_pub.publish(_pose(0.0, 1.0 - reach - 0.5 * hyst)),
                                      False)[1], 0.35)
        assert 2 in ctl._full and st.in_range[ctl.r, k2]
        assert spin_until(
            executor,
            lambda: (pose_pub.publish(_pose(0.0, 1.0 - reach - 2 * hyst)), 2 not in ctl._full)[1],
            10.0,
        )
        assert not st.in_range[ctl.r, k2] and b.needed(1) == [0]
        # no longer heard: what it publishes now does not reach the agent
        stamp = st.stamp[ctl.r, k2]
        spin_until(executor, lambda: (state_pub.publish(state()), False)[1], 0.3)
        assert st.stamp[ctl.r, k2] == stamp
        assert len(ctl._full[0]) == 2  # the parent stays heard
    finally:
        for n in (ctl, probe):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


def test_the_current_parent_and_the_partner_are_heard_wherever_they_are(
    ros_context, executor, tmp_path
):
    """Robot 2 is 2 m from robot 1 (out of range): heard while the graph makes it robot 1's
    parent (S9) and while the coordinator pairs the two (S7.1), dropped when neither holds.
    """
    import rclpy

    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        tick_timer=False,
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1),
    )
    probe = rclpy.create_node('_hearing_probe', context=ros_context)
    executor.add_node(ctl)
    executor.add_node(probe)
    try:
        _locate(ctl, executor, probe)
        assert spin_until(executor, lambda: 0 in ctl._full, 10.0) and 2 not in ctl._full
        # S9: robot 1 re-parented under robot 2
        ctl._on_graph(m.graph_msg(m.GraphMessage(3, {0: None, 1: 2, 2: 0}, {1: (0.0, 2.0)})))
        assert ctl.batch.needed(1) == [0, 2]  # pi0 stays: the S8.3 exit goal
        assert spin_until(executor, lambda: 2 in ctl._full, 5.0)
        np.testing.assert_allclose(ctl.batch.state.offset[ctl.r], (0.0, 2.0))  # c_1 - c_2
        ctl._on_graph(m.graph_msg(m.GraphMessage(4, {0: None, 1: 0, 2: 0}, {1: (0.0, 1.0)})))
        assert spin_until(executor, lambda: 2 not in ctl._full, 5.0)
        # S7.1: the coordinator tells robot 1 to yield to robot 2
        yield_to_2 = {'mode': 'yield', 'partner': 2, 'direction': 1.0, 't_entry_s': 1.0,
                      'drift_mps': None, 'park_at_s': -math.inf}
        ctl._on_encounters(m.encounters_msg(m.EncountersMessage(1, {1: yield_to_2}, {0: 1.0},
                                                                ctl.now_s())))
        assert ctl.batch.needed(1) == [0, 2]
        assert spin_until(executor, lambda: 2 in ctl._full, 5.0)
        ctl._on_encounters(m.encounters_msg(m.EncountersMessage(2, {}, {0: 1.0}, ctl.now_s())))
        assert spin_until(executor, lambda: 2 not in ctl._full, 5.0)
        assert ctl.batch.needed(1) == [0]
    finally:
        probe.destroy_node()
        ctl.destroy_node()


def test_hear_all_subscribes_every_robot(ros_context, tmp_path):
    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    ctl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        tick_timer=False,
        params=ControllerParams(scenario=str(_scenario(tmp_path)), robot_id=1, hear_all=True),
    )
    try:
        assert ctl.batch.needed(1) == [0, 2]  # before any pose: every other robot
        ctl.update_hearing()
        assert sorted(ctl._full) == [0, 2] and all(len(s) == 2 for s in ctl._full.values())
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
    probe = rclpy.create_node('_tick_inputs_probe', context=ros_context)
    state_pub = probe.create_publisher(m.Odometry, '/robot_0/state', QOS_CONTROL)
    accel_pub = probe.create_publisher(AccelStamped, '/robot_0/accel', QOS_CONTROL)
    pose_pub = probe.create_publisher(PoseStamped, '/robot_2/pose', QOS_CONTROL)
    executor = (SingleThreadedExecutor if kind == 'single' else EventsExecutor)(
        context=ros_context
    )
    executor.add_node(ctl)
    executor.add_node(probe)
    b, st = ctl.batch, ctl.batch.state
    k0, k2 = b.row[0], b.row[2]
    try:
        assert spin_until(executor, lambda: 0 in ctl._full, 10.0)
        parent_subs = ctl._full[0]
        assert len(parent_subs) == 2  # in the graph as before, but not served by executors
        served = list(ctl.subscriptions)
        assert all(s not in served for s in parent_subs) and len(served) >= 4
        assert spin_until(executor, lambda: state_pub.get_subscription_count() > 0
                          and accel_pub.get_subscription_count() > 0, 10.0)
        t0 = ctl.now_s()

        def state(k):
            return m.odometry([0.1 * k, 0.0, 0.0, 0.05, 0.0], m.stamp_from_s(t0 - 0.3 + 0.1 * k),
                              'robot_0')

        for k in (1, 2, 3):
            accel_pub.publish(m.accel_stamped([0.01 * k, 0.0], m.stamp_from_s(t0 - 0.3 + 0.1 * k)))
            state_pub.publish(state(k))
        # the executor runs (whatever it has to do) but never takes these
        spin_until(executor, lambda: False, 1.0)
        assert st.stamp[ctl.r, k0] == -math.inf
        deadline = time.monotonic() + 10.0
        while not np.array_equal(st.heard_x[ctl.r, k0], [0.1 * 3, 0.0, 0.0, 0.05, 0.0]):
            assert time.monotonic() < deadline, 'the period never took the parent state'
            executor.spin_once(timeout_sec=0.02)
            ctl.take_inputs()
        # the newest state, and the newest commanded accel (paired with the next state)
        np.testing.assert_array_equal(ctl._accel[0], [0.01 * 3, 0.0])
        assert st.stamp[ctl.r, k0] > -math.inf
        # robot 2 comes within range (its camera pose: executor thread), then leaves it: its
        # state subscription is dropped under the lock, and no later period brings its state
        _locate(ctl, executor, probe)
        far = b.static.reach[b.row[1], k2] + 2.0
        assert spin_until(
            executor, lambda: (pose_pub.publish(_pose(0.0, 0.9)), 2 in ctl._full)[1], 10.0
        )
        assert all(s not in list(ctl.subscriptions) for s in ctl._full[2])
        assert spin_until(
            executor, lambda: (pose_pub.publish(_pose(0.0, 1.0 - far)), 2 not in ctl._full)[1],
            10.0,
        )
        ctl.take_inputs()
        assert st.stamp[ctl.r, k2] == -math.inf
    finally:
        executor.shutdown()
        probe.destroy_node()
        ctl.destroy_node()
