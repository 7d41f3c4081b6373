"""ros/nonblocking.py: publishing through a thread of its own (the robot processes, the tracker and
the coordinator, ros/executors.py run_node). Messages arrive as with rclpy's publish, in order;
a publisher's queue keeps its QoS depth (the oldest dropped); a blocked rcl call does not block
the caller; stop() sends what is queued and gives the publishers their own publish back.
"""

from __future__ import annotations

import threading
import time

from std_msgs.msg import String

from ament_formation.ros.executors import spin_until
from ament_formation.ros.nonblocking import PublishThread
from ament_formation.ros.qos import QOS_CONTROL


def _pair(ros_context, executor, name):
    import rclpy

    node = rclpy.create_node(name, context=ros_context)
    got: list[str] = []
    node.create_subscription(String, f'/{name}', lambda m: got.append(m.data), QOS_CONTROL)
    pub = node.create_publisher(String, f'/{name}', QOS_CONTROL)
    executor.add_node(node)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 30.0)
    return node, pub, got


def test_messages_arrive_in_order_and_stop_gives_publish_back(ros_context, executor):
    node, pub, got = _pair(ros_context, executor, 'nonblocking_order')
    sender = PublishThread(node.get_logger())
    assert sender.available, 'librcl not found in /proc/self/maps'
    assert sender.adopt([pub]) == 1 and sender.adopt([pub]) == 0  # once only
    try:
        for i in range(5):
            pub.publish(String(data=str(i)))
            assert spin_until(executor, lambda i=i: len(got) > i, 10.0)
        assert got == ['0', '1', '2', '3', '4']
        # the thread counts a message after rcl returns; the subscriber may see it first
        assert spin_until(executor, lambda: sender.sent == 5, 10.0), sender.sent
        assert sender.errors == 0
    finally:
        assert sender.stop(flush_timeout_s=2.0)
    assert 'publish' not in pub.__dict__ and sender.adopted == []
    pub.publish(String(data='direct'))  # rclpy's own publish again
    assert spin_until(executor, lambda: got[-1:] == ['direct'], 10.0)
    executor.remove_node(node)
    node.destroy_node()


def test_a_blocked_send_does_not_block_the_caller(ros_context, executor):
    node, pub, got = _pair(ros_context, executor, 'nonblocking_blocked')
    sender = PublishThread(node.get_logger())
    assert sender.adopt([pub]) == 1
    real = sender._fn
    gate = threading.Event()

    def blocked(*args):  # stands for a sendto the network holds
        gate.wait(10.0)
        return real(*args)

    sender._fn = blocked
    try:
        t0 = time.monotonic()
        for i in range(3 * QOS_CONTROL.depth):
            pub.publish(String(data=str(i)))
        assert time.monotonic() - t0 < 0.5  # never waited for the held send
        # at most the QoS depth waits (plus the one in the held call); the oldest went first
        assert sender.pending() <= QOS_CONTROL.depth and sender.dropped >= QOS_CONTROL.depth
        gate.set()
        last = str(3 * QOS_CONTROL.depth - 1)
        assert spin_until(executor, lambda: got[-1:] == [last], 10.0)
        assert got == sorted(got, key=int)  # in order
    finally:
        gate.set()
        sender.stop(flush_timeout_s=2.0)
    executor.remove_node(node)
    node.destroy_node()
