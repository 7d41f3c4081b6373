"""Message conversions round-trip the core's arrays (ros/messages.py)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from std_msgs.msg import String

from ament_formation.ros import messages as m

finite = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False)
angle = st.floats(min_value=-math.pi + 1e-6, max_value=math.pi, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    x=finite,
    y=finite,
    th=angle,
    v=finite,
    w=finite,
    t=st.floats(min_value=0.0, max_value=1e6, allow_nan=False),
)
def test_odometry_round_trip(x, y, th, v, w, t):
    msg = m.odometry([x, y, th, v, w], m.stamp_from_s(t), 'robot_3')
    state, stamp_s = m.state_from_odometry(msg)
    np.testing.assert_allclose(state, [x, y, th, v, w], atol=1e-9)
    assert abs(stamp_s - t) <= 1e-9 * max(1.0, t) + 1e-9
    assert msg.child_frame_id == 'robot_3' and msg.header.frame_id == 'world'


@settings(max_examples=40, deadline=None)
@given(x=finite, y=finite, th=angle)
def test_pose_round_trip(x, y, th):
    pose, _ = m.pose_from_msg(m.pose_stamped([x, y, th], m.stamp_from_s(1.5)))
    np.testing.assert_allclose(pose, [x, y, th], atol=1e-9)


def test_stamp_helpers_and_bad_time():
    st_ = m.stamp_from_s(12.345678901)
    assert (st_.sec, st_.nanosec) == (12, 345678901)
    assert m.stamp_to_ns(m.stamp_from_ns(5_000_000_123)) == 5_000_000_123
    with pytest.raises(ValueError, match='t_s'):
        m.stamp_from_s(float('nan'))
    with pytest.raises(ValueError, match='t_s'):
        m.stamp_from_s(-1.0)


def test_accel_and_wheels_round_trip():
    a, t = m.accel_from_msg(m.accel_stamped([0.25, -0.5], m.stamp_from_s(2.0)))
    np.testing.assert_allclose(a, [0.25, -0.5])
    assert t == 2.0
    tau, _ = m.torque_from_msg(m.wheel_torque([0.1, -0.05], m.stamp_from_s(0.0)))
    np.testing.assert_allclose(tau, [0.1, -0.05])
    q, qd, _ = m.wheel_state_from_msg(m.wheel_state([1.0, 2.0], [3.0, -4.0], m.stamp_from_s(0.0)))
    np.testing.assert_allclose(q, [1.0, 2.0])
    np.testing.assert_allclose(qd, [3.0, -4.0])
    bad = m.wheel_torque([0.0, 0.0], m.stamp_from_s(0.0))
    bad.effort = [0.1]
    with pytest.raises(ValueError, match='effort'):
        m.torque_from_msg(bad)


def test_mode_and_graph_json():
    d = m.mode_from_msg(m.mode_msg('obstacle', 'O1', 'ccw', since_s=3.0))
    assert d == {'mode': 'obstacle', 'target': 'O1', 'direction': 'ccw', 'since_s': 3.0}
    g = m.GraphMessage(7, {0: None, 1: 0, 2: 0}, {1: (0.0, 1.2), 2: (-0.5, 0.0)}, (1,), 4.5, 2.0)
    back = m.graph_from_msg(m.graph_msg(g))
    assert back == g
    with pytest.raises(ValueError, match='graph'):
        m.graph_from_msg(String(data='{"parents": {}}'))
    with pytest.raises(ValueError, match='mode'):
        m.mode_from_msg(String(data='not json'))


def test_image_round_trip_and_errors():
    px = (np.arange(12 * 7) % 256).astype(np.uint8).reshape(7, 12)
    msg = m.image_mono8(px, m.stamp_from_s(0.5))
    assert (msg.width, msg.height, msg.step) == (12, 7, 12)
    np.testing.assert_array_equal(m.array_from_image(msg), px)
    with pytest.raises(ValueError, match='pixels'):
        m.image_mono8(px.astype(np.float32), m.stamp_from_s(0.0))


def test_markers_geometry():
    stamp = m.stamp_from_s(1.0)
    robots = m.robot_markers(
        [0, 1],
        np.array([[0, 0, 0, 0, 0], [1, 2, math.pi / 2, 0, 0]]),
        0.1,
        stamp,
        avoiding=[False, True],
    )
    assert len(robots) == 4
    arrow = robots[3]
    assert arrow.points[1].y - arrow.points[0].y == pytest.approx(0.15)
    ells = m.ellipse_markers(
        ['O1'],
        np.array([[1.0, -0.2]]),
        np.array([2.0944]),
        np.array([[0.4, 0.15]]),
        {'P': 1.0, 'L': 1.1, 'Q': 1.8},
        stamp,
    )
    assert [e.ns for e in ells] == ['ellipse_P', 'ellipse_L', 'ellipse_Q']
    # every point of the L polyline satisfies the ellipse equation at scale 1.1
    pts = np.array([[p.x, p.y] for p in ells[1].points]) - [1.0, -0.2]
    c, s = math.cos(2.0944), math.sin(2.0944)
    local = pts @ np.array([[c, -s], [s, c]])
    np.testing.assert_allclose(
        (local[:, 0] / 0.44) ** 2 + (local[:, 1] / 0.165) ** 2, 1.0, atol=1e-9
    )
    edges = m.edge_markers({0: None, 1: 0, 2: 7}, {0: (0, 0), 1: (0, 1.2), 2: (1, 1)}, stamp)
    assert len(edges[0].points) == 2  # 2's parent 7 has no position: skipped
    arr = m.marker_array(robots, ells, edges)
    assert len(arr.markers) == 8
