"""MCAP recording: every topic (also late ones) is written rosbag2-style and reads back equal."""
from __future__ import annotations

import numpy as np
from mcap.reader import make_reader

from ament_formation.ros import messages as m
from ament_formation.ros import recorder as rec
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_IMAGE


def test_record_and_read_back(ros_context, executor, tmp_path):
    import rclpy
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    talker = rclpy.create_node("talker", namespace="/robot_2", context=ros_context)
    odom_pub = talker.create_publisher(m.Odometry, "state", QOS_CONTROL)
    graph_pub = talker.create_publisher(String, "/formation/graph", QOS_GRAPH)
    graph_pub.publish(m.graph_msg(m.GraphMessage(1, {2: None})))  # latched before recording starts
    recorder_node = rclpy.create_node("_recorder", context=ros_context)
    executor.add_node(talker)
    executor.add_node(recorder_node)
    assert spin_until(executor, lambda: recorder_node.count_publishers("/robot_2/state") == 1, 10.0)

    writer = rec.McapWriter(tmp_path / "run.mcap")
    recorder = rec.TopicRecorder(recorder_node, writer, exclude=("/rosout", "/parameter_events"),
                                 scan_period_s=0.1)
    assert spin_until(executor, lambda: recorder.counts.get("/formation/graph", 0) == 1, 10.0)

    assert spin_until(executor, lambda: odom_pub.get_subscription_count() == 1, 10.0)
    rng = np.random.default_rng(4)
    sent = rng.uniform(-1, 1, size=(10, 5))
    sent[:, 2] = rng.uniform(-3.0, 3.0, size=10)
    for k, row in enumerate(sent):
        odom_pub.publish(m.odometry(row, m.stamp_from_s(0.1 * k), "robot_2"))
    # a topic that appears after recording started is picked up by the rescan
    img_pub = talker.create_publisher(Image, "/camera/image_raw", QOS_IMAGE)
    pixels = (np.arange(48) * 5).astype(np.uint8).reshape(6, 8)

    def img_seen():
        if "/camera/image_raw" in recorder.topics and recorder.counts["/camera/image_raw"] == 0:
            img_pub.publish(m.image_mono8(pixels, m.stamp_from_s(9.0)))
        return recorder.counts.get("/camera/image_raw", 0) >= 1 and recorder.counts["/robot_2/state"] == 10

    ok = spin_until(executor, img_seen, 15.0)
    assert ok, (recorder.topics, recorder.counts)
    graph_pub.publish(m.graph_msg(m.GraphMessage(2, {2: None})))
    assert spin_until(executor, lambda: recorder.counts["/formation/graph"] == 2, 10.0)
    recorder.close()

    path = tmp_path / "run.mcap"
    types = rec.topic_types(path)
    assert types["/robot_2/state"] == "nav_msgs/msg/Odometry"
    assert types["/camera/image_raw"] == "sensor_msgs/msg/Image"
    assert "/rosout" not in types
    t_s, states = rec.odometry_arrays(path, "/robot_2/state")
    np.testing.assert_allclose(t_s, 0.1 * np.arange(10), atol=1e-9)
    np.testing.assert_allclose(states, sent, atol=1e-12)
    graphs = [m.graph_from_msg(msg).revision for _, msg in rec.read_topic(path, "/formation/graph")]
    assert graphs == [1, 2]
    images = rec.read_topic(path, "/camera/image_raw")
    n_images = len(images)
    assert n_images == recorder.counts["/camera/image_raw"] >= 1
    np.testing.assert_array_equal(m.array_from_image(images[0][1]), pixels)

    # the file follows the rosbag2 MCAP conventions
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert schemas["nav_msgs/msg/Odometry"].encoding == "ros2msg"
        assert b"MSG: geometry_msgs/Quaternion" in schemas["nav_msgs/msg/Odometry"].data
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert summary.statistics.message_count == 10 + 2 + n_images
        times = [msg.log_time for _, _, msg in reader.iter_messages()]
        assert times == sorted(times)


def test_writer_without_graph(tmp_path):
    w = rec.McapWriter(tmp_path / "x.mcap", compression="none")
    for k in range(3):
        w.write_message("/robot_0/accel", m.accel_stamped([k, -k], m.stamp_from_s(k)), k * 1000)
    w.close()
    w.close()  # idempotent
    got = rec.read_topic(tmp_path / "x.mcap", "/robot_0/accel")
    assert [t for t, _ in got] == [0, 1000, 2000]
    assert [m.accel_from_msg(msg)[0].tolist() for _, msg in got] == [[0, 0], [1, -1], [2, -2]]
