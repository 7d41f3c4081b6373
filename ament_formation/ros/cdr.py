"""The fields a controller reads of the messages it hears at high rate, straight from their
serialized form (a ``raw=True`` subscription): the parent's state and accel at 100 Hz, camera
poses at 30 fps per robot.

rclpy turns every received message into Python objects first (an Odometry is 12 nested message
objects and two 36-element covariance arrays, each field set through a checking property): that
costs several times what the callback then does with the handful of numbers it needs. Here the
numbers are unpacked at their offsets in the CDR stream (encapsulation CDR_LE, what rmw_fastrtps
sends: little-endian, 8-byte values aligned to 8 from the start of the body), giving the same
values as the message functions of ros/messages.py (``state_from_odometry``, ``accel_from_msg``,
``pose_from_msg``) give for the deserialized message. Any other encapsulation, or a stream that
does not have the expected length, is deserialized by rclpy and read by those functions.

Each reader also takes a message object (what a test or an in-process caller hands over). The
``finite_*`` readers give None for the array unless every value is finite, tested on the numbers
before any array is made (a callback at 100 Hz: numpy's machinery costs more than the test).
"""

from __future__ import annotations

from math import isfinite
import struct

from geometry_msgs.msg import AccelStamped, PoseStamped
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.serialization import deserialize_message

from ament_formation.ros import messages as m

_CDR_LE = b'\x00\x01'  # encapsulation identifier of plain little-endian CDR (XCDR1)
_STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: int32 sec, uint32 nanosec
_U32 = struct.Struct('<I')
_POSE = struct.Struct('<7d')  # geometry_msgs/Pose: position xyz, orientation xyzw
_D = struct.Struct('<d')
_ODOM_AFTER_POSE = 7 * 8 + 36 * 8  # pose, its covariance
_ODOM_TWIST_BYTES = 6 * 8 + 36 * 8  # twist (linear, angular), its covariance
_ANGULAR_Z = 5 * 8  # offset of twist.angular.z in the twist


def _after_string(data: bytes, pos: int) -> int:
    """Position just past the CDR string at ``pos`` (uint32 length with its NUL, bytes);
    -1 when it runs past the end.
    """
    if pos + 4 > len(data):
        return -1
    end = pos + 4 + _U32.unpack_from(data, pos)[0]
    return end if end <= len(data) else -1


def _header_end(data: bytes, strings: int) -> int:
    """Offset of the first 8-byte value after a std_msgs/Header (stamp, frame_id) and
    ``strings`` - 1 more strings, aligned to 8 relative to the body (which starts at 4); -1 when
    the stream is not plain little-endian CDR or is too short.
    """
    if len(data) < 16 or data[:2] != _CDR_LE:
        return -1
    pos = 12  # body: stamp (8 bytes), then the first string
    for k in range(strings):
        if k:
            pos = 4 + ((pos - 4 + 3) & ~3)
        pos = _after_string(data, pos)
        if pos < 0:
            return -1
    return 4 + ((pos - 4 + 7) & ~7)


def _stamp_s(data: bytes) -> float:
    sec, nanosec = _STAMP.unpack_from(data, 4)
    return sec + nanosec * 1e-9  # as messages.stamp_to_s


def _finite_or_none(values: tuple, stamp_s: float) -> tuple[np.ndarray | None, float]:
    return (np.array(values) if all(map(isfinite, values)) else None), stamp_s


def _checked(result: tuple[np.ndarray, float]) -> tuple[np.ndarray | None, float]:
    array, stamp_s = result
    return (array if np.all(np.isfinite(array)) else None), stamp_s


def _odometry_values(data: bytes) -> tuple[tuple, float] | None:
    pos = _header_end(data, 2)  # header.frame_id, child_frame_id
    if pos < 0 or pos + _ODOM_AFTER_POSE + _ODOM_TWIST_BYTES > len(data):
        return None
    x, y, _z, qx, qy, qz, qw = _POSE.unpack_from(data, pos)
    twist = pos + _ODOM_AFTER_POSE
    values = (
        x,
        y,
        m.quaternion_to_yaw(qx, qy, qz, qw),
        _D.unpack_from(data, twist)[0],
        _D.unpack_from(data, twist + _ANGULAR_Z)[0],
    )
    return values, _stamp_s(data)


def state_from_odometry(data) -> tuple[np.ndarray, float]:
    """``messages.state_from_odometry`` of a serialized nav_msgs/Odometry (or a message)."""
    read = _odometry_values(data) if isinstance(data, bytes) else None
    if read is None:
        return m.state_from_odometry(
            deserialize_message(data, Odometry) if isinstance(data, bytes) else data
        )
    return np.array(read[0]), read[1]


def finite_state_from_odometry(data) -> tuple[np.ndarray | None, float]:
    """:func:`state_from_odometry`, the state None unless its five values are finite."""
    read = _odometry_values(data) if isinstance(data, bytes) else None
    if read is None:
        return _checked(state_from_odometry(data))
    return _finite_or_none(*read)


_XY = struct.Struct('<2d')


def _accel_values(data: bytes) -> tuple[tuple, float] | None:
    pos = _header_end(data, 1)
    if pos < 0 or pos + 6 * 8 > len(data):
        return None
    return _XY.unpack_from(data, pos), _stamp_s(data)


def accel_from_msg(data) -> tuple[np.ndarray, float]:
    """``messages.accel_from_msg`` of a serialized geometry_msgs/AccelStamped (or a message)."""
    read = _accel_values(data) if isinstance(data, bytes) else None
    if read is None:
        return m.accel_from_msg(
            deserialize_message(data, AccelStamped) if isinstance(data, bytes) else data
        )
    return np.array(read[0]), read[1]


def finite_accel_from_msg(data) -> tuple[np.ndarray | None, float]:
    """:func:`accel_from_msg`, the acceleration None unless both values are finite."""
    read = _accel_values(data) if isinstance(data, bytes) else None
    if read is None:
        return _checked(accel_from_msg(data))
    return _finite_or_none(*read)


def pose_from_msg(data) -> tuple[np.ndarray, float]:
    """``messages.pose_from_msg`` of a serialized geometry_msgs/PoseStamped (or a message)."""
    if not isinstance(data, bytes):
        return m.pose_from_msg(data)
    pos = _header_end(data, 1)
    if pos < 0 or pos + 7 * 8 > len(data):
        return m.pose_from_msg(deserialize_message(data, PoseStamped))
    x, y, _z, qx, qy, qz, qw = _POSE.unpack_from(data, pos)
    return np.array([x, y, m.quaternion_to_yaw(qx, qy, qz, qw)]), _stamp_s(data)
