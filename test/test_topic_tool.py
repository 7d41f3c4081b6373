"""`formation topics/nodes/echo/hz` and the runtime introspection they rely on."""

from __future__ import annotations

import io
import os
from pathlib import Path
import subprocess

from processes import program
import pytest
import yaml

from ament_formation.ros import introspection as intro
from ament_formation.ros import messages as m
from ament_formation.ros.executors import spin_until
from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH, QOS_IMAGE
from ament_formation.tools import topic_cmd

ROOT = Path(__file__).resolve().parents[1]


def test_rate_meter_statistics():
    meter = topic_cmd.RateMeter(window=5)
    assert meter.stats() is None
    for k in range(10):
        meter.add(k * 20_000_000 + (1_000_000 if k == 9 else 0))  # 50 Hz, last one 1 ms late
    s = meter.stats()
    assert s.window == 4
    assert s.max_s == pytest.approx(0.021)
    assert s.min_s == pytest.approx(0.020)
    assert s.rate_hz == pytest.approx(1.0 / (0.081 / 4))
    with pytest.raises(ValueError, match='--window'):
        topic_cmd.RateMeter(window=1)


def test_message_class_and_definition():
    from nav_msgs.msg import Odometry

    assert intro.message_class('nav_msgs/msg/Odometry') is Odometry
    assert intro.full_type_name(Odometry) == 'nav_msgs/msg/Odometry'
    with pytest.raises(ValueError, match='type'):
        intro.message_class('nav_msgs/msg/NoSuchThing')
    text = intro.message_definition('nav_msgs/msg/Odometry')
    sections = [line[5:] for line in text.splitlines() if line.startswith('MSG: ')]
    assert sections == [
        'std_msgs/Header',
        'builtin_interfaces/Time',
        'geometry_msgs/PoseWithCovariance',
        'geometry_msgs/Pose',
        'geometry_msgs/Point',
        'geometry_msgs/Quaternion',
        'geometry_msgs/TwistWithCovariance',
        'geometry_msgs/Twist',
        'geometry_msgs/Vector3',
    ]
    assert text.count('=' * 80 + '\n') == len(sections)


def _publisher_node(ctx, name='talker'):
    import rclpy

    return rclpy.create_node(name, namespace='/robot_4', context=ctx)


def test_echo_hz_nodes_in_process(ros_context, executor):
    import rclpy
    from std_msgs.msg import String

    talker = _publisher_node(ros_context)
    pub = talker.create_publisher(m.Odometry, 'state', QOS_CONTROL)
    latched = talker.create_publisher(String, '/formation/graph', QOS_GRAPH)
    k = [0]

    def tick():
        k[0] += 1
        pub.publish(
            m.odometry([0.1 * k[0], 2.0, 0.5, 0.05, 0.0], m.stamp_from_s(0.02 * k[0]), 'robot_4')
        )

    talker.create_timer(0.02, tick)
    latched.publish(m.graph_msg(m.GraphMessage(3, {0: None, 4: 0})))
    tool = rclpy.create_node('_tool', context=ros_context)
    executor.add_node(talker)
    executor.add_node(tool)

    type_name = topic_cmd.wait_for_type(tool, executor, '/robot_4/state', 10.0)
    assert type_name == 'nav_msgs/msg/Odometry'
    assert spin_until(executor, lambda: '/robot_4/talker' in topic_cmd.list_nodes(tool), 10.0)
    assert '/_tool' not in topic_cmd.list_nodes(tool)

    out = io.StringIO()
    assert topic_cmd.echo(tool, executor, '/robot_4/state', type_name, 3, out, timeout_s=10.0) == 3
    docs = [d for d in yaml.safe_load_all(out.getvalue()) if d]
    assert len(docs) == 3
    assert docs[0]['child_frame_id'] == 'robot_4'
    assert docs[0]['pose']['pose']['position']['y'] == 2.0
    assert docs[0]['pose']['covariance'] == '<36 values>'
    xs = [d['pose']['pose']['position']['x'] for d in docs]
    assert all(b > a for a, b in zip(xs, xs[1:]))

    # a transient-local topic published before the subscription is still echoed (latched QoS)
    assert intro.compatible_qos(tool, '/formation/graph').durability == QOS_GRAPH.durability
    out = io.StringIO()
    assert (
        topic_cmd.echo(
            tool, executor, '/formation/graph', 'std_msgs/msg/String', 1, out, timeout_s=10.0
        )
        == 1
    )
    assert (
        m.graph_from_msg(
            String(data=yaml.safe_load(out.getvalue().split('---')[0])['data'])
        ).revision
        == 3
    )

    stats = topic_cmd.hz(
        tool,
        executor,
        '/robot_4/state',
        type_name,
        window=20,
        reports=2,
        out=io.StringIO(),
        report_every_s=0.5,
        timeout_s=20.0,
    )
    assert stats is not None and 25.0 < stats.rate_hz < 75.0  # 50 Hz timer


def test_best_effort_publisher_gets_best_effort_reader(ros_context, executor):
    import rclpy
    from rclpy.qos import ReliabilityPolicy
    from sensor_msgs.msg import Image

    talker = _publisher_node(ros_context, 'cam')
    talker.create_publisher(Image, '/camera/image_raw', QOS_IMAGE)
    tool = rclpy.create_node('_tool2', context=ros_context)
    executor.add_node(tool)
    assert spin_until(executor, lambda: tool.count_publishers('/camera/image_raw') == 1, 10.0)
    assert (
        intro.compatible_qos(tool, '/camera/image_raw').reliability
        == ReliabilityPolicy.BEST_EFFORT
    )


def test_cli_echo_once_and_topics_across_processes(ros_context, executor):
    import rclpy
    from std_msgs.msg import String

    talker = rclpy.create_node('cli_talker', context=ros_context)
    pub = talker.create_publisher(String, '/robot_0/mode', QOS_CONTROL)
    talker.create_timer(0.05, lambda: pub.publish(m.mode_msg('coordination')))
    executor.add_node(talker)
    cli = [program('formation')]
    env = dict(os.environ)
    echo = subprocess.Popen(
        cli + ['echo', 'robot_0/mode', '--once', '--timeout', '20'],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    topics = subprocess.Popen(
        cli + ['topics', '-t', '--wait', '5.0'],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert spin_until(
            executor, lambda: echo.poll() is not None and topics.poll() is not None, 40.0
        )
    finally:
        for p in (echo, topics):
            if p.poll() is None:
                p.kill()
    out, err = echo.communicate()
    assert echo.returncode == 0, err
    assert (
        m.mode_from_msg(String(data=yaml.safe_load(out.split('---')[0])['data']))['mode']
        == 'coordination'
    )
    tout, terr = topics.communicate()
    assert topics.returncode == 0, terr
    assert '/robot_0/mode [std_msgs/msg/String]' in tout.splitlines()


def test_cli_echo_unknown_topic_is_a_one_line_error():
    proc = subprocess.run(
        [program('formation'), 'echo', '/nobody/here', '--timeout', '0.5'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        'formation echo: topic /nobody/here: no publisher seen within 0.5 s'
    ]
