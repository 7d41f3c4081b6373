"""Publishing that never blocks the caller on the network, not even through the GIL.

Why: rclpy's ``Publisher.publish`` calls ``rcl_publish`` while holding the Python GIL, and Fast
DDS (synchronous publication, the rmw_fastrtps default) sends on a blocking UDP socket in the
caller's thread. When a robot's link goes down (cable pulled, switch port down) the kernel cannot
resolve the peers' addresses any more, queues the datagrams (charged to the socket's send
buffer) and ``sendto`` then blocks until the address resolution fails, about 2-3 s. Measured in
network namespaces (docs/multi-machine.md): a publish took 2.3 s, and every other thread of the
process stood still with it because the GIL was held; with RMW_FASTRTPS_PUBLICATION_MODE=
ASYNCHRONOUS still 0.9 s (the publish waits for the writer's mutex, which Fast DDS's sending
thread holds while blocked). A robot's control thread that publishes its state, or merely waits
for the GIL while the executor thread publishes diagnostics, misses its periods for seconds.

What: :class:`PublishThread` takes over the ``publish`` of chosen publishers. ``publish(msg)``
serializes the message in the caller's thread (no network) and queues the bytes, keeping at most
the publisher's QoS depth per publisher (the oldest dropped first, like KEEP_LAST; counted in
``dropped``). A thread of its own hands them to ``rcl_publish_serialized_message`` through
ctypes, which releases the GIL for the call: if that call blocks, only this thread waits. The
order of one publisher's messages is kept. Where the rcl library cannot be found, nothing is
replaced (``available`` is False) and publishing stays as it was.

    sender = PublishThread(logger)
    sender.adopt(node.publishers)        # every publisher of the node (and of hosted nodes)
    ...
    sender.stop(flush_timeout_s=1.0)     # sends what is queued (bounded wait), then ends

ros/executors.py ``run_node`` does this for the robot processes (formation_team, and
formation_controller / formation_bridge of --split) and for the camera PC's tracker and
coordinator (PUBLISH_THREAD_PROCESSES; AMENT_FORMATION_PUBLISH_THREAD=0 turns it off for
experiments). Publishers created after the node was built are not adopted.

A lab's Fast DDS profile can also make the sockets themselves non-blocking (UDPv4 transport
``<non_blocking_send>true</non_blocking_send>``, as config/fastdds_udp.xml does); that covers Fast
DDS's own threads (heartbeats, discovery) too, but not a lab profile without it: this does.
"""

from __future__ import annotations

from collections import deque
import ctypes
import re
import threading
import time

_RCL_RE = re.compile(r'\s(/\S*/librcl\.so(?:\.[\d.]+)?)$')


class _Allocator(ctypes.Structure):  # rcutils_allocator_t
    _fields_ = [
        ('allocate', ctypes.c_void_p),
        ('deallocate', ctypes.c_void_p),
        ('reallocate', ctypes.c_void_p),
        ('zero_allocate', ctypes.c_void_p),
        ('state', ctypes.c_void_p),
    ]


class _Serialized(ctypes.Structure):  # rcl_serialized_message_t = rcutils_uint8_array_t
    _fields_ = [
        ('buffer', ctypes.c_void_p),
        ('buffer_length', ctypes.c_size_t),
        ('buffer_capacity', ctypes.c_size_t),
        ('allocator', _Allocator),
    ]


_publish_serialized = None


def _rcl_publish_serialized():
    """``rcl_publish_serialized_message`` of the librcl this process loaded for rclpy (ctypes:
    the GIL is released during the call); None when not found.
    """
    global _publish_serialized
    if _publish_serialized is None:
        import rclpy.impl.implementation_singleton  # noqa: F401 - loads librcl

        path = None
        try:
            with open('/proc/self/maps') as maps:
                for line in maps:
                    m = _RCL_RE.search(line.rstrip('\n'))
                    if m:
                        path = m.group(1)
                        break
            if path is None:
                return None
            fn = ctypes.CDLL(path).rcl_publish_serialized_message
        except (OSError, AttributeError):
            return None
        fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Serialized), ctypes.c_void_p]
        fn.restype = ctypes.c_int
        _publish_serialized = fn
    return _publish_serialized


class PublishThread:
    """See the module docstring."""

    def __init__(self, logger=None, name: str = 'publish'):
        self.logger = logger
        self._fn = _rcl_publish_serialized()
        self.available = self._fn is not None
        self._cv = threading.Condition()
        self._queue: deque = deque()  # (publisher, bytes) in publish order
        self._count: dict[int, int] = {}  # id(publisher) -> queued messages
        self._stop = False
        self.sent = 0
        self.dropped = 0
        self.errors = 0
        self.longest_call_s = 0.0  # the longest rcl_publish call (the network's blocking)
        self.adopted: list = []
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._started = False

    def adopt(self, publishers) -> int:
        """Route ``publish`` of each of ``publishers`` through this thread; the number adopted
        (0 when unavailable).
        """
        if not self.available:
            if self.logger is not None:
                self.logger.warn('librcl not found: publishing stays in the caller thread')
            return 0
        from rclpy.serialization import serialize_message

        n = 0
        for pub in publishers:
            if getattr(pub, '_af_nonblocking', False):
                continue
            depth = max(1, int(getattr(pub.qos_profile, 'depth', 10) or 10))

            def publish(msg, pub=pub, depth=depth, serialize=serialize_message):
                data = msg if isinstance(msg, bytes) else serialize(msg)
                self._put(pub, data, depth)

            pub.publish = publish
            pub._af_nonblocking = True
            self.adopted.append(pub)
            n += 1
        if n and not self._started:
            self._started = True
            self._thread.start()
        return n

    def _put(self, pub, data: bytes, depth: int) -> None:
        key = id(pub)
        with self._cv:
            if self._stop and not self._thread.is_alive():
                return
            if self._count.get(key, 0) >= depth:  # KEEP_LAST: the oldest of this publisher goes
                for i, (p, _d) in enumerate(self._queue):
                    if p is pub:
                        del self._queue[i]
                        break
                self._count[key] -= 1
                self.dropped += 1
            idle = not self._queue  # the thread waits only on an empty queue
            self._queue.append((pub, data))
            self._count[key] = self._count.get(key, 0) + 1
            if idle:
                self._cv.notify()

    def pending(self) -> int:
        with self._cv:
            return len(self._queue)

    def _run(self) -> None:
        msg = _Serialized()
        while True:
            with self._cv:  # everything queued, in one go (one wake-up per burst)
                while not self._queue and not self._stop:
                    self._cv.wait()
                if not self._queue:
                    return
                batch = list(self._queue)
                self._queue.clear()
                self._count.clear()
            for pub, data in batch:
                # the bytes object's own buffer (no copy); ``data`` lives through the call
                msg.buffer = ctypes.cast(ctypes.c_char_p(data), ctypes.c_void_p)
                msg.buffer_length = msg.buffer_capacity = len(data)
                t0 = time.monotonic()
                try:
                    with pub.handle:  # kept alive (not destroyed) during the call
                        ret = self._fn(pub.handle.pointer, ctypes.byref(msg), None)
                except Exception:  # noqa: BLE001 - destroyed publisher, shut-down context
                    ret = -1
                dt = time.monotonic() - t0
                if dt > self.longest_call_s:
                    self.longest_call_s = dt
                if ret == 0:
                    self.sent += 1
                else:
                    self.errors += 1

    def stop(self, flush_timeout_s: float = 1.0) -> bool:
        """Send what is queued (waiting at most ``flush_timeout_s``), then end the thread; True
        when it ended (False: still blocked in a call; it is a daemon thread).
        """
        with self._cv:
            self._stop = True
            self._cv.notify()
        if self._started and threading.current_thread() is not self._thread:
            self._thread.join(timeout=flush_timeout_s)
        with self._cv:
            self._queue.clear()  # whatever could not be sent in time
            self._count.clear()
        self.release()
        return not self._thread.is_alive()

    def release(self) -> None:
        """Give every adopted publisher its own ``publish`` back and drop the references to them
        (the replaced method referred to its publisher: a cycle that would keep the publishers,
        and with them the node and the DDS participant, until the process ends).
        """
        for pub in self.adopted:
            pub.__dict__.pop('publish', None)
            pub.__dict__.pop('_af_nonblocking', None)
        self.adopted = []
