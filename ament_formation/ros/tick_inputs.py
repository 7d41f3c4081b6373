"""Subscriptions whose messages a control loop takes once per period, instead of an executor
taking each message as it arrives.

Why: each message an executor takes wakes its thread, and on a robot's computer a thread's wake
costs more than the callback it runs (caches and branch predictors are cold again after every
sleep): for the 100 Hz state and accel of the robots a controller hears, the wakes were about
half of the executor thread's time. A team's control loop (nodes/team.py ControlLoop) is awake
at every period anyway and only reads these inputs then, so it takes what has arrived since the
previous period, oldest first, just before the period: the same messages, in the same order,
seen by the same period's control.

    sub = node.create_subscription(Odometry, topic, TakenAtTick(on_state), qos, raw=True)
    ...  the node's ``subscriptions`` property: served_by_executor(super().subscriptions)
    ...  at each period, in the control loop: take_waiting(node's subscriptions)

A subscription so marked stays an ordinary subscription of the node (same topic, type and QoS in
the ROS graph; node.destroy_subscription and node.destroy_node destroy it); only executors do not
see it, because they ask the node for its ``subscriptions``. Its queue is the subscription's QoS
history (KEEP_LAST depth): a control loop that stalls longer than that loses the oldest messages,
as an executor that stalls does.
"""

from __future__ import annotations

from rclpy._rclpy_pybind11 import InvalidHandle


class TakenAtTick:
    """A subscription callback run by :func:`take_waiting` (the control loop), not by executors."""

    __slots__ = ('callback',)

    def __init__(self, callback):
        self.callback = callback

    def __call__(self, msg) -> None:
        self.callback(msg)


def served_by_executor(subscriptions) -> list:
    """``subscriptions`` without those whose callback is a :class:`TakenAtTick`."""
    return [s for s in subscriptions if not isinstance(s.callback, TakenAtTick)]


def take_waiting(subscriptions) -> int:
    """Run the :class:`TakenAtTick` callback of every message waiting on these subscriptions
    (the others are skipped), oldest first; the number of messages. A subscription destroyed
    meanwhile is skipped.
    """
    n = 0
    for sub in subscriptions:
        callback = sub.callback
        if not isinstance(callback, TakenAtTick):
            continue
        try:
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
                    if taken is None:
                        break
                    callback(taken[0])
                    n += 1
        except InvalidHandle:
            pass
    return n
