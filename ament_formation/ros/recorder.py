"""Record every topic to a rosbag2 bag (one MCAP file + metadata.yaml), and read a recording back
into arrays (docs/recordings.md).

File layout (what rosbag2's mcap storage plugin writes, so ``ros2 bag info/play``, rosbags and
Foxglove open it): profile ``ros2``; one schema per message type, named ``pkg/msg/Type``, encoding
``ros2msg``, data = the .msg text with every dependency appended (ros/introspection.py); one
channel per topic, message encoding ``cdr``, channel metadata ``offered_qos_profiles`` (the QoS of
the topic's publishers when it was discovered, rosbag2's version-9 YAML string: a replay offers the
same reliability and durability, e.g. transient local for /formation/graph) and
``topic_type_hash`` (RIHS01 type description hash); the message data are the serialized CDR bytes
as received (raw subscriptions, no re-encoding); log_time = receive time [ns]: the time the
recorder's DDS reader received the message (as rosbag2 in Jazzy records it) when messages are
taken with :meth:`TopicRecorder.spin_for`, else (an executor's callbacks, or ``use_sim_time``) the
recorder node's clock when the callback runs; publish_time = the sender's source timestamp when
known, else log_time. Chunks are zstd-compressed. On close,
``metadata.yaml`` (rosbag2 version 9, storage ``mcap``, per-topic QoS and counts) is written beside
the file, so the folder is a rosbag2 bag.

    writer = McapWriter(path)                     # plain file writer (no ROS graph needed)
    rec = TopicRecorder(node, writer)             # subscribes to all topics, also later ones
    ...                                           # an executor spins node (a callback a message)
    rec.spin_for(0.05)                            # or: node in no executor, every queued message
    ...; rec.close()                              # finalises the file, writes metadata.yaml
    for topic, t_ns, msg in read_messages(path):  # deserialised messages in log-time order
"""

from __future__ import annotations

from contextlib import ExitStack
import json
from pathlib import Path
import re
import threading
import time
from typing import Callable, Iterable, Iterator

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
import numpy as np

from ament_formation.ros.introspection import compatible_qos, message_class, message_definition

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
BAG_METADATA_VERSION = 9  # rosbag2 in Jazzy
ROS_DISTRO = 'jazzy'
# Messages a recording subscription keeps queued (KEEP_LAST depth): 10 s of a 100 Hz topic, so a
# recorder that other work keeps off the CPU for seconds loses nothing; image topics keep fewer
# (a 640x480 frame is 300 kB).
RECORD_DEPTH = 1000
RECORD_DEPTH_IMAGES = 30
_IMAGE_TYPES = frozenset({'sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'})
_INFINITE_NS = 9_223_372_036_854_775_807


# --------------------------------------------------------------------------- rosbag2 metadata
def _duration(d) -> dict:
    ns = getattr(d, 'nanoseconds', None)
    ns = _INFINITE_NS if ns is None or ns >= _INFINITE_NS or ns < 0 else int(ns)
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def qos_dict(qos) -> dict:
    """One rclpy QoSProfile as rosbag2 (metadata version 9) writes it: policies by lower-case name
    (keep_last, reliable, transient_local, automatic, unknown, ...), durations as {sec, nsec}.
    """
    return {
        'history': qos.history.name.lower(),
        'depth': int(qos.depth),
        'reliability': qos.reliability.name.lower(),
        'durability': qos.durability.name.lower(),
        'deadline': _duration(qos.deadline),
        'lifespan': _duration(qos.lifespan),
        'liveliness': qos.liveliness.name.lower(),
        'liveliness_lease_duration': _duration(qos.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': bool(qos.avoid_ros_namespace_conventions),
    }


def qos_yaml(profiles) -> str:
    """The ``offered_qos_profiles`` string of a channel: a YAML list of :func:`qos_dict`."""
    import yaml

    return (
        yaml.safe_dump([qos_dict(q) for q in profiles], sort_keys=False, default_flow_style=False)
        if profiles
        else ''
    )


def type_hash(type_name: str) -> str:
    """RIHS01 type description hash of ``pkg/msg/Type`` from the type description that rosidl
    installs (share/pkg/msg/Type.json); "" when not found.
    """
    from ament_formation.ros.introspection import _share_dir, full_type_name

    try:
        pkg, name = full_type_name(message_class(type_name)).split('/msg/')
        doc = json.loads((_share_dir(pkg) / 'msg' / f'{name}.json').read_text())
        want = f'{pkg}/msg/{name}'
        return next(h['hash_string'] for h in doc['type_hashes'] if h['type_name'] == want)
    except (ValueError, OSError, KeyError, StopIteration, TypeError):
        return ''


class McapWriter:
    """A thread-safe MCAP writer for serialized ROS 2 messages (ros2 profile)."""

    def __init__(self, path: str | Path, compression: str = 'zstd', bag_metadata: bool = True):
        """``bag_metadata``: on close, write rosbag2's metadata.yaml into the file's folder (the
        folder becomes a bag of this one file).
        """
        comp = {
            'zstd': CompressionType.ZSTD,
            'lz4': CompressionType.LZ4,
            'none': CompressionType.NONE,
        }.get(compression)
        if comp is None:
            raise ValueError(f'compression: expected zstd, lz4 or none (got {compression!r})')
        self.path = Path(path)
        self._file = open(self.path, 'wb')
        self._writer = Writer(self._file, compression=comp)
        self._writer.start(profile=PROFILE, library='ament_formation')
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._topics: dict[int, dict] = {}  # channel id -> rosbag2 topic_metadata
        self._lock = threading.Lock()
        self.message_count = 0
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self._closed = False
        self.bag_metadata = bag_metadata

    def channel(
        self, topic: str, type_name: str, offered_qos=(), type_hash_str: str | None = None
    ) -> int:
        """The channel id of ``topic`` (registered with its schema on first use).

        ``offered_qos``: the rclpy QoSProfiles of the topic's publishers (channel metadata
        ``offered_qos_profiles``); ``type_hash_str``: its RIHS01 hash (default: the installed
        type description's, :func:`type_hash`).
        """
        with self._lock:
            if topic in self._channels:
                return self._channels[topic]
            if type_name not in self._schemas:
                self._schemas[type_name] = self._writer.register_schema(
                    name=type_name,
                    encoding=SCHEMA_ENCODING,
                    data=message_definition(type_name).encode(),
                )
            qos_text = qos_yaml(list(offered_qos))
            digest = type_hash(type_name) if type_hash_str is None else type_hash_str
            cid = self._writer.register_channel(
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schemas[type_name],
                metadata={'offered_qos_profiles': qos_text, 'topic_type_hash': digest},
            )
            self._channels[topic] = cid
            self._sequence[cid] = 0
            self._topics[cid] = {
                'name': topic,
                'type': type_name,
                'serialization_format': MESSAGE_ENCODING,
                'offered_qos_profiles': [qos_dict(q) for q in offered_qos],
                'type_description_hash': digest,
            }
            return cid

    def write(
        self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None
    ) -> None:
        """Append one serialized message."""
        with self._lock:
            if self._closed:
                return
            seq = self._sequence[channel_id]
            self._sequence[channel_id] = seq + 1
            t = int(log_time_ns)
            self._writer.add_message(
                channel_id=channel_id,
                log_time=t,
                data=bytes(data),
                publish_time=int(t if publish_time_ns is None else publish_time_ns),
                sequence=seq,
            )
            self.message_count += 1
            if self._first_ns is None or t < self._first_ns:
                self._first_ns = t
            if self._last_ns is None or t > self._last_ns:
                self._last_ns = t

    def write_message(self, topic: str, msg, log_time_ns: int) -> None:
        """Serialize and append a message object (used by tools that write without a graph)."""
        from rclpy.serialization import serialize_message

        from ament_formation.ros.introspection import full_type_name

        cid = self.channel(topic, full_type_name(type(msg)))
        self.write(cid, log_time_ns, serialize_message(msg))

    def close(self) -> None:
        """Write the summary section, close the file and (``bag_metadata``) write metadata.yaml
        beside it (idempotent).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self._file.close()
            if self.bag_metadata:
                (self.path.parent / 'metadata.yaml').write_text(self.metadata_yaml())

    def metadata_yaml(self) -> str:
        """rosbag2's metadata.yaml (version 9, storage mcap) of what was written so far."""
        import yaml

        start = self._first_ns or 0
        duration = 0 if self._first_ns is None else self._last_ns - self._first_ns
        info = {
            'version': BAG_METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self.message_count,
            'topics_with_message_count': [
                {'topic_metadata': meta, 'message_count': self._sequence[cid]}
                for cid, meta in sorted(self._topics.items())
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.path.name],
            'files': [
                {
                    'path': self.path.name,
                    'starting_time': {'nanoseconds_since_epoch': start},
                    'duration': {'nanoseconds': duration},
                    'message_count': self.message_count,
                }
            ],
            'custom_data': {'recorded_by': 'ament_formation'},
            'ros_distro': ROS_DISTRO,
        }
        return yaml.safe_dump(
            {'rosbag2_bagfile_information': info}, sort_keys=False, default_flow_style=False
        )


class TopicRecorder:
    """Subscribes ``node`` to every visible topic (rescanning every ``scan_period_s``) and writes
    each received message unchanged to ``writer``.

    ``include``/``exclude``: regular expressions on the topic name (exclude wins). Subscriptions
    use a QoS compatible with the publishers seen when the topic is first discovered, with
    ``depth`` messages queued (:data:`RECORD_DEPTH`; image topics :data:`RECORD_DEPTH_IMAGES`).

    Two ways to run it. With ``node`` in an executor, every message is a callback and a timer
    rescans (``scan_timer``). Or, ``node`` in no executor and ``scan_timer=False``:
    :meth:`spin_for` waits on the node's subscriptions itself and takes *every* queued message of
    each ready subscription in one go, so its cost is per batch, not per message (an rclpy
    executor rebuilds its wait set in Python for every single callback: ~0.4 ms a message, about
    half a core for the ~1,500 messages/s of a whole system). :meth:`tap` hands a topic's
    messages, deserialized, to a function as well (``formation run`` watches the graph and the
    ground truth that way).
    """

    def __init__(
        self,
        node,
        writer: McapWriter,
        include: Iterable[str] = ('.*',),
        exclude: Iterable[str] = (),
        scan_period_s: float = 0.5,
        depth: int = RECORD_DEPTH,
        scan_timer: bool = True,
    ):
        self.node = node
        self.writer = writer
        self.depth = int(depth)
        self.scan_period_s = float(scan_period_s)
        self._include = [re.compile(p) for p in include]
        self._exclude = [re.compile(p) for p in exclude]
        self._subs: dict[str, object] = {}
        self._channel: dict[str, int] = {}
        self._taps: dict[str, list[Callable]] = {}
        self.counts: dict[str, int] = {}
        self._next_scan = 0.0
        self._wait_set = None  # (subscriptions it was built for, rclpy WaitSet)
        self._sim_time = bool(
            node.has_parameter('use_sim_time') and node.get_parameter('use_sim_time').value
        )
        self.scan()
        self._timer = node.create_timer(scan_period_s, self.scan) if scan_timer else None

    def _wanted(self, topic: str) -> bool:
        return any(p.fullmatch(topic) for p in self._include) and not any(
            p.fullmatch(topic) for p in self._exclude
        )

    def tap(self, topic: str, fn: Callable) -> None:
        """Also call ``fn(message)`` (deserialized) for every recorded message of ``topic``."""
        self._taps.setdefault(topic, []).append(fn)

    def scan(self) -> None:
        """Subscribe to topics that appeared since the last scan."""
        self._next_scan = time.monotonic() + self.scan_period_s
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._subs or not types or not self._wanted(topic):
                continue
            if self.node.count_publishers(topic) == 0:
                continue  # only subscribers so far: wait to learn the publishers' QoS
            type_name = types[0]
            try:
                cls = message_class(type_name)
            except ValueError:
                continue  # a type this machine cannot decode: skip it
            infos = [
                i
                for i in self.node.get_publishers_info_by_topic(topic)
                if i.topic_type == type_name
            ]
            hashes = {str(i.topic_type_hash) for i in infos} - {''}
            cid = self.writer.channel(
                topic,
                type_name,
                offered_qos=[i.qos_profile for i in infos],
                type_hash_str=hashes.pop() if len(hashes) == 1 else None,
            )
            self.counts[topic] = 0
            self._channel[topic] = cid
            depth = self.depth
            if type_name in _IMAGE_TYPES:
                depth = min(depth, RECORD_DEPTH_IMAGES)
            self._subs[topic] = self.node.create_subscription(
                cls,
                topic,
                self._callback(topic),
                compatible_qos(self.node, topic, depth=depth),
                raw=True,
            )

    def _record(self, topic: str, data: bytes, log_ns: int, publish_ns: int | None = None) -> None:
        self.writer.write(self._channel[topic], log_ns, data, publish_ns)
        self.counts[topic] += 1
        taps = self._taps.get(topic)
        if taps:
            from rclpy.serialization import deserialize_message

            msg = deserialize_message(data, self._subs[topic].msg_type)
            for fn in taps:
                fn(msg)

    def _callback(self, topic: str):
        clock = self.node.get_clock()

        def on_raw(data: bytes) -> None:
            self._record(topic, data, clock.now().nanoseconds)

        return on_raw

    def spin_for(self, duration_s: float, batch_s: float = 0.01) -> int:
        """Record for ``duration_s`` [s, wall]: wait on the node's subscriptions, take every
        queued message of each ready one, then let ``batch_s`` pass before the next wait (the
        messages of that time queue up and are taken together); rescan every
        ``scan_period_s``. Subscriptions of the node that are not the recording's (the
        ``/clock`` of its time source under ``use_sim_time``) get their callbacks. For a
        ``node`` that no executor spins. Returns the number of messages taken.
        """
        end = time.monotonic() + duration_s
        taken = 0
        while True:
            now = time.monotonic()
            if now >= self._next_scan:
                self.scan()
            left = end - now
            if left <= 0.0:
                return taken
            n = self._take_ready(min(left, max(self._next_scan - now, 0.0)))
            taken += n
            if n and batch_s > 0.0:
                time.sleep(min(batch_s, max(end - time.monotonic(), 0.0)))

    def _take_ready(self, timeout_s: float) -> int:
        """One wait (up to ``timeout_s``) on every subscription of the node; take all that is
        queued on the ready ones.
        """
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        subs = list(self.node.subscriptions)
        if not subs:
            time.sleep(timeout_s)
            return 0
        mine = {id(s): t for t, s in self._subs.items()}
        taken = 0
        with ExitStack() as stack:
            for sub in subs:
                stack.enter_context(sub.handle)
            stack.enter_context(self.node.context.handle)
            if self._wait_set is None or self._wait_set[0] != subs:
                ws = _rclpy.WaitSet(len(subs), 0, 0, 0, 0, 0, self.node.context.handle)
                self._wait_set = (subs, ws)
            ws = self._wait_set[1]
            ws.clear_entities()
            for sub in subs:
                ws.add_subscription(sub.handle)
            ws.wait(max(int(timeout_s * 1e9), 0))
            ready = set(ws.get_ready_entities('subscription'))
            for sub in subs:
                if sub.handle.pointer not in ready:
                    continue
                topic = mine.get(id(sub))
                taken += self._take_all(sub, topic)
        return taken

    def _take_all(self, sub, topic: str | None) -> int:
        """Take every queued message of ``sub``: recorded (``topic``) or its own callback."""
        clock = self.node.get_clock()
        n = 0
        while True:
            got = sub.handle.take_message(sub.msg_type, sub.raw)
            if got is None:
                return n
            n += 1
            msg, info = got
            if topic is None:
                sub.callback(msg)
                continue
            received = 0 if self._sim_time else int(info.get('received_timestamp') or 0)
            self._record(
                topic,
                msg,
                received or clock.now().nanoseconds,
                int(info.get('source_timestamp') or 0) or None,
            )

    @property
    def topics(self) -> list[str]:
        return sorted(self._subs)

    def close(self) -> None:
        """Stop recording (destroy the subscriptions) and finalise the file."""
        if self._timer is not None:
            self.node.destroy_timer(self._timer)
        self._wait_set = None
        for sub in self._subs.values():
            self.node.destroy_subscription(sub)
        self._subs.clear()
        self.writer.close()


# --------------------------------------------------------------------------- reading
def topic_types(path: str | Path) -> dict[str, str]:
    """{topic: pkg/msg/Type} of a recording."""
    with open(path, 'rb') as f:
        summary = make_reader(f).get_summary()
    if summary is None:
        raise ValueError(f'{path}: no MCAP summary (the recording was not closed)')
    return {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}


def read_messages(
    path: str | Path, topics: Iterable[str] | None = None
) -> Iterator[tuple[str, int, object]]:
    """Yield (topic, log_time_ns, message) in log-time order, deserialised with the
    installed types.
    """
    from rclpy.serialization import deserialize_message

    classes: dict[int, type] = {}
    with open(path, 'rb') as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(
            topics=list(topics) if topics is not None else None
        ):
            cls = classes.get(channel.id)
            if cls is None:
                if schema is None or channel.message_encoding != MESSAGE_ENCODING:
                    continue
                cls = classes[channel.id] = message_class(schema.name)
            yield channel.topic, message.log_time, deserialize_message(message.data, cls)


def read_topic(path: str | Path, topic: str) -> list[tuple[int, object]]:
    """[(log_time_ns, message)] of one topic."""
    return [(t, msg) for _, t, msg in read_messages(path, [topic])]


def odometry_arrays(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamp_s (T,), state (T, 5)) of an Odometry topic, in header-stamp order."""
    from ament_formation.ros.messages import state_from_odometry

    rows = [state_from_odometry(msg) for _, msg in read_topic(path, topic)]
    if not rows:
        return np.zeros(0), np.zeros((0, 5))
    rows.sort(key=lambda r: r[1])
    return np.array([r[1] for r in rows]), np.stack([r[0] for r in rows])
