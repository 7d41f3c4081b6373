"""MCAP recording: every topic (also late ones) is written rosbag2-style and reads back equal; the
folder is a rosbag2 bag (metadata.yaml, QoS and type hashes) that independent readers open.
"""

from __future__ import annotations

from mcap.reader import make_reader
import numpy as np
import yaml

from ament_formation.ros import messages as m
from ament_formation.ros import recorder as rec
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_IMAGE


def test_record_and_read_back(ros_context, executor, tmp_path):
    import rclpy
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    talker = rclpy.create_node('talker', namespace='/robot_2', context=ros_context)
    odom_pub = talker.create_publisher(m.Odometry, 'state', QOS_CONTROL)
    graph_pub = talker.create_publisher(String, '/formation/graph', QOS_GRAPH)
    graph_pub.publish(m.graph_msg(m.GraphMessage(1, {2: None})))  # latched before recording starts
    recorder_node = rclpy.create_node('_recorder', context=ros_context)
    executor.add_node(talker)
    executor.add_node(recorder_node)
    assert spin_until(
        executor, lambda: recorder_node.count_publishers('/robot_2/state') == 1, 10.0
    )

    writer = rec.McapWriter(tmp_path / 'run.mcap')
    recorder = rec.TopicRecorder(
        recorder_node, writer, exclude=('/rosout', '/parameter_events'), scan_period_s=0.1
    )
    assert spin_until(executor, lambda: recorder.counts.get('/formation/graph', 0) == 1, 10.0)

    assert spin_until(executor, lambda: odom_pub.get_subscription_count() == 1, 10.0)
    rng = np.random.default_rng(4)
    sent = rng.uniform(-1, 1, size=(10, 5))
    sent[:, 2] = rng.uniform(-3.0, 3.0, size=10)
    for k, row in enumerate(sent):
        odom_pub.publish(m.odometry(row, m.stamp_from_s(0.1 * k), 'robot_2'))
    # a topic that appears after recording started is picked up by the rescan
    img_pub = talker.create_publisher(Image, '/camera/image_raw', QOS_IMAGE)
    pixels = (np.arange(48) * 5).astype(np.uint8).reshape(6, 8)

    def img_seen():
        if '/camera/image_raw' in recorder.topics and recorder.counts['/camera/image_raw'] == 0:
            img_pub.publish(m.image_mono8(pixels, m.stamp_from_s(9.0)))
        return (
            recorder.counts.get('/camera/image_raw', 0) >= 1
            and recorder.counts['/robot_2/state'] == 10
        )

    ok = spin_until(executor, img_seen, 15.0)
    assert ok, (recorder.topics, recorder.counts)
    graph_pub.publish(m.graph_msg(m.GraphMessage(2, {2: None})))
    assert spin_until(executor, lambda: recorder.counts['/formation/graph'] == 2, 10.0)
    recorder.close()

    path = tmp_path / 'run.mcap'
    types = rec.topic_types(path)
    assert types['/robot_2/state'] == 'nav_msgs/msg/Odometry'
    assert types['/camera/image_raw'] == 'sensor_msgs/msg/Image'
    assert '/rosout' not in types
    t_s, states = rec.odometry_arrays(path, '/robot_2/state')
    np.testing.assert_allclose(t_s, 0.1 * np.arange(10), atol=1e-9)
    np.testing.assert_allclose(states, sent, atol=1e-12)
    graphs = [
        m.graph_from_msg(msg).revision for _, msg in rec.read_topic(path, '/formation/graph')
    ]
    assert graphs == [1, 2]
    images = rec.read_topic(path, '/camera/image_raw')
    n_images = len(images)
    assert n_images == recorder.counts['/camera/image_raw'] >= 1
    np.testing.assert_array_equal(m.array_from_image(images[0][1]), pixels)

    # the file follows the rosbag2 MCAP conventions
    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert schemas['nav_msgs/msg/Odometry'].encoding == 'ros2msg'
        assert b'MSG: geometry_msgs/Quaternion' in schemas['nav_msgs/msg/Odometry'].data
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
        assert summary.statistics.message_count == 10 + 2 + n_images
        times = [msg.log_time for _, _, msg in reader.iter_messages()]
        assert times == sorted(times)
        # channel metadata as rosbag2 writes it: the publishers' QoS (YAML) and the RIHS01 hash
        channels = {c.topic: c for c in summary.channels.values()}
        graph_qos = yaml.safe_load(channels['/formation/graph'].metadata['offered_qos_profiles'])
        assert [q['durability'] for q in graph_qos] == ['transient_local']
        assert graph_qos[0]['reliability'] == 'reliable'
        image_qos = yaml.safe_load(channels['/camera/image_raw'].metadata['offered_qos_profiles'])
        assert image_qos[0]['reliability'] == 'best_effort'
        for c in channels.values():
            assert c.metadata['topic_type_hash'].startswith('RIHS01_')

    check_bag_folder(tmp_path, sent, n_images)


def check_bag_folder(folder, sent, n_images):
    """Rosbags (an independent rosbag2 implementation) opens the folder as a bag: topics with
    their QoS (a replay re-offers transient local for /formation/graph), counts, type hashes equal
    to its own, and messages it deserializes itself.
    """
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores

    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(folder) as bag:
        conns = {c.topic: c for c in bag.connections}
        assert set(conns) == {'/robot_2/state', '/formation/graph', '/camera/image_raw'}
        assert conns['/robot_2/state'].msgtype == 'nav_msgs/msg/Odometry'
        assert conns['/robot_2/state'].msgcount == 10
        assert conns['/formation/graph'].msgcount == 2
        assert conns['/camera/image_raw'].msgcount == n_images
        assert bag.message_count == 12 + n_images
        graph_qos = conns['/formation/graph'].ext.offered_qos_profiles
        assert [q.durability for q in graph_qos] == [QosDurability.TRANSIENT_LOCAL]
        assert graph_qos[0].reliability == QosReliability.RELIABLE
        assert (
            conns['/camera/image_raw'].ext.offered_qos_profiles[0].reliability
            == QosReliability.BEST_EFFORT
        )
        for c in conns.values():
            assert c.digest == typestore.hash_rihs01(c.msgtype), c.topic
        rows = [
            typestore.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in bag.messages(connections=[conns['/robot_2/state']])
        ]
    got = np.array(
        [
            [
                r.pose.pose.position.x,
                r.pose.pose.position.y,
                r.twist.twist.linear.x,
                r.twist.twist.angular.z,
            ]
            for r in rows
        ]
    )
    np.testing.assert_allclose(got, sent[:, [0, 1, 3, 4]], atol=1e-12)


def test_writer_without_graph(tmp_path):
    w = rec.McapWriter(tmp_path / 'x.mcap', compression='none')
    for k in range(3):
        w.write_message('/robot_0/accel', m.accel_stamped([k, -k], m.stamp_from_s(k)), k * 1000)
    w.close()
    w.close()  # idempotent
    got = rec.read_topic(tmp_path / 'x.mcap', '/robot_0/accel')
    assert [t for t, _ in got] == [0, 1000, 2000]
    assert [m.accel_from_msg(msg)[0].tolist() for _, msg in got] == [[0, 0], [1, -1], [2, -2]]
    # without a graph there is no publisher QoS, but the type hash comes from the type description
    meta = yaml.safe_load((tmp_path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['x.mcap'] and meta['message_count'] == 3
    assert meta['duration']['nanoseconds'] == 2000
    (topic,) = meta['topics_with_message_count']
    assert topic['message_count'] == 3
    assert topic['topic_metadata']['type_description_hash'].startswith('RIHS01_')


def test_metadata_yaml_matches_rosbag2_layout(tmp_path):
    """Keys and types of rosbag2 (Jazzy, version 9) metadata, checked against rosbags' writer."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_typestore, Stores

    typestore = get_typestore(Stores.ROS2_JAZZY)
    ref_dir = tmp_path / 'ref'
    with Writer(ref_dir, version=9) as w:
        conn = w.add_connection(
            '/robot_0/accel', 'geometry_msgs/msg/AccelStamped', typestore=typestore
        )
        w.write(conn, 5, b'\x00\x01\x00\x00' + bytes(60))
    ref = yaml.safe_load((ref_dir / 'metadata.yaml').read_text())['rosbag2_bagfile_information']

    ours_dir = tmp_path / 'ours'
    ours_dir.mkdir()
    w = rec.McapWriter(ours_dir / 'run.mcap')
    w.write_message('/robot_0/accel', m.accel_stamped([1, 2], m.stamp_from_s(1)), 5)
    w.close()
    ours = yaml.safe_load((ours_dir / 'metadata.yaml').read_text())['rosbag2_bagfile_information']

    def shape(d):
        if isinstance(d, dict):
            return {k: shape(v) for k, v in d.items()}
        if isinstance(d, list):
            return [shape(d[0])] if d else []
        return type(d).__name__

    ref_topic = ref['topics_with_message_count'][0]
    our_topic = ours['topics_with_message_count'][0]
    assert set(ours) >= set(ref) - {'custom_data'}
    assert set(our_topic['topic_metadata']) == set(ref_topic['topic_metadata'])
    assert shape(our_topic['topic_metadata']['type_description_hash']) == 'str'
    assert (
        our_topic['topic_metadata']['type_description_hash']
        == ref_topic['topic_metadata']['type_description_hash']
    )
    for key in ('duration', 'starting_time', 'message_count', 'relative_file_paths', 'files'):
        assert shape(ours[key]) == shape(ref[key]), key


def test_spin_for_takes_every_queued_message_in_one_go(ros_context, executor, tmp_path):
    """The recorder of `formation run` (node in no executor, TopicRecorder.spin_for): a burst
    far larger than an executor would serve in one wait is recorded whole and in order, log time
    is the receive time (between the send and the take), publish time the sender's, and taps get
    each message deserialized.
    """
    import time

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    n = 500  # more than an executor's KEEP_LAST 100 recording queue held before
    talker = rclpy.create_node('talker', namespace='/robot_3', context=ros_context)
    # the writer keeps all n: what is tested is the recorder's side
    pub = talker.create_publisher(
        m.Odometry, 'state', QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE)
    )
    executor.add_node(talker)
    rec_node = rclpy.create_node('_recorder_batch', context=ros_context)  # in no executor
    writer = rec.McapWriter(tmp_path / 'run.mcap')
    recorder = rec.TopicRecorder(rec_node, writer, include=('/robot_3/.*',), scan_timer=False)
    tapped = []
    recorder.tap('/robot_3/state', lambda msg: tapped.append(m.stamp_to_s(msg.header.stamp)))
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and pub.get_subscription_count() == 0:
        recorder.spin_for(0.05)
    assert pub.get_subscription_count() == 1
    sent_ns = time.time_ns()
    for k in range(n):
        pub.publish(m.odometry(np.zeros(5), m.stamp_from_s(0.01 * k), 'robot_3'))
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and recorder.counts['/robot_3/state'] < n:
        recorder.spin_for(0.05)
    taken_ns = time.time_ns()
    recorder.close()
    assert recorder.counts['/robot_3/state'] == n
    np.testing.assert_allclose(tapped, 0.01 * np.arange(n), atol=1e-9)
    with open(tmp_path / 'run.mcap', 'rb') as f:
        msgs = [msg for _, _, msg in make_reader(f).iter_messages()]
    assert len(msgs) == n
    assert all(sent_ns <= x.log_time <= taken_ns for x in msgs)
    assert all(sent_ns <= x.publish_time <= x.log_time for x in msgs)
    rows = rec.read_topic(tmp_path / 'run.mcap', '/robot_3/state')
    stamps = [m.stamp_to_s(msg.header.stamp) for _, msg in rows]
    np.testing.assert_allclose(stamps, 0.01 * np.arange(n), atol=1e-9)
