"""Wheel JointState conversions used by the bridge (builders live in ros/messages.py).

A wheel_torque message names its joints optionally: with the names ``left_wheel``/``right_wheel``
in either order the efforts are matched by name, otherwise they are read positionally
[left, right]. Anything but exactly two efforts is rejected.
"""

from __future__ import annotations

from sensor_msgs.msg import JointState

from ament_formation.ros.messages import WHEEL_NAMES


def torques_from_joint_state(msg: JointState) -> tuple[float, float] | None:
    """(left, right) efforts [N·m] of a wheel_torque message, or None if it has not exactly two.

    Values are returned as sent (NaN/inf included): the link logic rejects and counts those.
    """
    effort = list(msg.effort)
    if len(effort) != 2:
        return None
    names = list(msg.name)
    if names == [WHEEL_NAMES[1], WHEEL_NAMES[0]]:
        return float(effort[1]), float(effort[0])
    return float(effort[0]), float(effort[1])
