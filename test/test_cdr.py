"""ros/cdr.py: the fields read from a serialized message are those of the deserialized message."""

from geometry_msgs.msg import AccelStamped, PoseStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.serialization import serialize_message

from ament_formation.ros import cdr
from ament_formation.ros import messages as m

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
NAMES = st.text(alphabet='abcdefghijklmnopqrstuvwxyz_/0123456789', max_size=40)
STAMPS = st.tuples(st.integers(-(2**31), 2**31 - 1), st.integers(0, 2**32 - 1))


def same(a, b) -> bool:
    """Equal arrays and stamps, bit for bit (NaN included)."""
    (xa, sa), (xb, sb) = a, b
    return xa.tobytes() == xb.tobytes() and np.float64(sa).tobytes() == np.float64(sb).tobytes()


def finite_or_none(checked, expected) -> bool:
    """``checked`` (a finite_* reader's result) is ``expected`` when all its values are finite,
    else (None, the same stamp).
    """
    if np.all(np.isfinite(expected[0])):
        return checked[0] is not None and same(checked, expected)
    return checked[0] is None and same((np.zeros(1), checked[1]), (np.zeros(1), expected[1]))


def _stamp(msg, stamp) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp


@settings(max_examples=300, deadline=None)
@given(STAMPS, NAMES, NAMES, st.lists(FLOATS, min_size=13, max_size=13), FLOATS)
def test_odometry(stamp, frame, child, values, cov):
    msg = Odometry()
    _stamp(msg, stamp)
    msg.header.frame_id, msg.child_frame_id = frame, child
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = values[:7]
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = values[7:]
    msg.pose.covariance[7] = msg.twist.covariance[35] = cov
    data = serialize_message(msg)
    expected = m.state_from_odometry(msg)
    assert same(cdr.state_from_odometry(data), expected)
    assert same(cdr.state_from_odometry(msg), expected)
    for arg in (data, msg):
        checked = cdr.finite_state_from_odometry(arg)
        assert finite_or_none(checked, expected)


@settings(max_examples=300, deadline=None)
@given(STAMPS, NAMES, st.lists(FLOATS, min_size=7, max_size=7))
def test_pose_stamped(stamp, frame, values):
    msg = PoseStamped()
    _stamp(msg, stamp)
    msg.header.frame_id = frame
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = values
    data = serialize_message(msg)
    assert same(cdr.pose_from_msg(data), m.pose_from_msg(msg))
    assert same(cdr.pose_from_msg(msg), m.pose_from_msg(msg))


@settings(max_examples=300, deadline=None)
@given(STAMPS, NAMES, st.lists(FLOATS, min_size=6, max_size=6))
def test_accel_stamped(stamp, frame, values):
    msg = AccelStamped()
    _stamp(msg, stamp)
    msg.header.frame_id = frame
    a = msg.accel
    a.linear.x, a.linear.y, a.linear.z, a.angular.x, a.angular.y, a.angular.z = values
    data = serialize_message(msg)
    expected = m.accel_from_msg(msg)
    assert same(cdr.accel_from_msg(data), expected)
    assert same(cdr.accel_from_msg(msg), expected)
    for arg in (data, msg):
        assert finite_or_none(cdr.finite_accel_from_msg(arg), expected)


def test_other_encapsulations_and_short_streams_go_through_rclpy():
    msg = m.odometry([1.0, 2.0, 0.5, 0.1, -0.2], m.stamp_from_s(12.25), 'robot_3')
    data = serialize_message(msg)
    assert cdr._header_end(data, 2) > 0
    # a big-endian stream (encapsulation CDR_BE) is not read here: rclpy deserializes it
    big = b'\x00\x00' + data[2:]
    assert cdr._header_end(big, 2) == -1
    # a stream cut short is not read past its end
    assert cdr._header_end(data[:14], 2) == -1
    bad_length = data[:12] + (10**6).to_bytes(4, 'little') + data[16:]
    assert cdr._header_end(bad_length, 2) == -1
    pose = serialize_message(m.pose_stamped([1.0, 2.0, 0.5], m.stamp_from_s(3.0)))
    assert same(cdr.pose_from_msg(pose), (np.array([1.0, 2.0, 0.5]), 3.0))
