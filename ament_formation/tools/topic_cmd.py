"""`formation topics | nodes | echo TOPIC | hz TOPIC`: the ros2 CLI's everyday commands for boards
without it. Types are resolved at runtime from the graph; subscriptions use a QoS compatible with
the topic's publishers (ros/introspection.py).

    formation topics [-t] [--wait S]          list topics (with types)
    formation nodes [--wait S]                list nodes (namespace/name)
    formation echo TOPIC [--once] [--count N] [--timeout S] [--full-arrays]
    formation hz TOPIC [--window N] [--count REPORTS] [--timeout S]
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
import os
import sys
import time
from typing import Callable, TextIO

import yaml

from ament_formation.core.errors import ConfigError


# --------------------------------------------------------------------------- rate statistics
@dataclass(frozen=True)
class RateStats:
    """Receive-rate statistics over a window of inter-arrival periods."""

    rate_hz: float
    min_s: float
    max_s: float
    std_s: float
    window: int


class RateMeter:
    """Inter-arrival statistics over the last ``window`` messages (like ``ros2 topic hz``)."""

    def __init__(self, window: int = 100):
        if window < 2:
            raise ConfigError(f'must be >= 2 (got {window})', '--window')
        self._times_ns: deque[int] = deque(maxlen=window)
        self.count = 0

    def add(self, t_ns: int) -> None:
        """Record one arrival at ``t_ns`` [ns, monotonic]."""
        self._times_ns.append(int(t_ns))
        self.count += 1

    def stats(self) -> RateStats | None:
        """Statistics of the current window, or None with fewer than two arrivals."""
        if len(self._times_ns) < 2:
            return None
        t = list(self._times_ns)
        periods = [(b - a) * 1e-9 for a, b in zip(t, t[1:])]
        mean = sum(periods) / len(periods)
        var = sum((p - mean) ** 2 for p in periods) / len(periods)
        return RateStats(
            1.0 / mean if mean > 0 else math.inf,
            min(periods),
            max(periods),
            math.sqrt(var),
            len(periods),
        )


def format_stats(s: RateStats) -> str:
    return (
        f'average rate: {s.rate_hz:.3f}\n\tmin: {s.min_s:.3f}s max: {s.max_s:.3f}s '
        f'std dev: {s.std_s:.5f}s window: {s.window + 1}'
    )


# --------------------------------------------------------------------------- graph helpers
def _spin_for(executor, until: Callable[[], bool], timeout_s: float) -> bool:
    from ament_formation.ros.executors import spin_until

    return spin_until(executor, until, timeout_s)


def wait_for_type(node, executor, topic: str, timeout_s: float) -> str | None:
    """The type name of ``topic`` once a publisher is visible (None after ``timeout_s``)."""
    from ament_formation.ros.introspection import topic_types

    found: dict[str, str] = {}

    def ready() -> bool:
        t = topic_types(node).get(topic)
        if t and node.count_publishers(topic) > 0:
            found['t'] = t
            return True
        return False

    _spin_for(executor, ready, timeout_s)
    return found.get('t')


def list_nodes(node) -> list[str]:
    """Fully qualified names of the visible, non-hidden nodes (sorted)."""
    out = set()
    for name, ns in node.get_node_names_and_namespaces():
        if name.startswith('_'):
            continue
        out.add(ns.rstrip('/') + '/' + name)
    return sorted(out)


def echo(
    node,
    executor,
    topic: str,
    type_name: str,
    count: int | None,
    out: TextIO,
    timeout_s: float | None = None,
    max_array: int | None = 16,
) -> int:
    """Print messages of ``topic`` as YAML documents until ``count`` were printed (None: forever)
    or ``timeout_s`` [s, wall] passed without completing. Returns the number printed.
    """
    from ament_formation.ros.introspection import compatible_qos, message_class, message_to_dict

    cls = message_class(type_name)
    printed = [0]

    def on_msg(msg) -> None:
        if count is not None and printed[0] >= count:
            return
        out.write(
            yaml.safe_dump(
                message_to_dict(msg, max_array),
                sort_keys=False,
                default_flow_style=None,
                width=120,
            )
        )
        out.write('---\n')
        out.flush()
        printed[0] += 1

    sub = node.create_subscription(cls, topic, on_msg, compatible_qos(node, topic))
    try:
        done = (lambda: printed[0] >= count) if count is not None else (lambda: False)
        _spin_for(executor, done, math.inf if timeout_s is None else timeout_s)
    finally:
        node.destroy_subscription(sub)
    return printed[0]


def hz(
    node,
    executor,
    topic: str,
    type_name: str,
    window: int,
    reports: int | None,
    out: TextIO,
    report_every_s: float = 1.0,
    timeout_s: float | None = None,
) -> RateStats | None:
    """Measure the receive rate of ``topic`` (raw subscription, no deserialisation); print a
    report every ``report_every_s`` [s]; stop after ``reports`` reports or ``timeout_s``.
    """
    from ament_formation.ros.introspection import compatible_qos, message_class

    meter = RateMeter(window)
    sub = node.create_subscription(
        message_class(type_name),
        topic,
        lambda _raw: meter.add(time.monotonic_ns()),
        compatible_qos(node, topic),
        raw=True,
    )
    made = [0]
    last: list[RateStats | None] = [None]
    deadline = math.inf if timeout_s is None else time.monotonic() + timeout_s
    try:
        next_report = time.monotonic() + report_every_s
        while time.monotonic() < deadline and (reports is None or made[0] < reports):
            executor.spin_once(timeout_sec=min(0.05, max(0.0, next_report - time.monotonic())))
            if time.monotonic() >= next_report:
                next_report += report_every_s
                s = meter.stats()
                if s is None:
                    continue
                out.write(format_stats(s) + '\n')
                out.flush()
                last[0] = s
                made[0] += 1
    finally:
        node.destroy_subscription(sub)
    return last[0]


# --------------------------------------------------------------------------- CLI plumbing
class _Session:
    """A private context, a hidden node and an executor for one command."""

    def __enter__(self):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(f'_formation_cli_{os.getpid()}', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        return self

    def __exit__(self, *exc):
        import rclpy

        self.executor.shutdown(timeout_sec=0.5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        return False


def _discover(session, wait_s: float) -> None:
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        session.executor.spin_once(timeout_sec=0.05)


def _cmd_topics(args) -> int:
    with _Session() as s:
        _discover(s, args.wait)
        from ament_formation.ros.introspection import topic_types

        for name, type_name in sorted(topic_types(s.node).items()):
            print(f'{name} [{type_name}]' if args.show_types else name)
    return 0


def _cmd_nodes(args) -> int:
    with _Session() as s:
        _discover(s, args.wait)
        for name in list_nodes(s.node):
            print(name)
    return 0


def _resolve(s, topic: str, timeout_s: float) -> str:
    type_name = wait_for_type(s.node, s.executor, topic, timeout_s)
    if type_name is None:
        raise ConfigError(f'no publisher seen within {timeout_s:g} s', f'topic {topic}')
    return type_name


def _cmd_echo(args) -> int:
    count = 1 if args.once else args.count
    with _Session() as s:
        type_name = _resolve(s, args.topic, args.timeout)
        n = echo(
            s.node,
            s.executor,
            args.topic,
            type_name,
            count,
            sys.stdout,
            timeout_s=None if count is None else args.timeout,
            max_array=None if args.full_arrays else 16,
        )
    if count is not None and n < count:
        print(
            f'formation echo: {args.topic}: got {n} of {count} messages in {args.timeout:g} s',
            file=sys.stderr,
        )
        return 1
    return 0


def _cmd_hz(args) -> int:
    with _Session() as s:
        type_name = _resolve(s, args.topic, args.timeout)
        hz(s.node, s.executor, args.topic, type_name, args.window, args.count, sys.stdout)
    return 0


def _topic_name(text: str) -> str:
    return text if text.startswith('/') else '/' + text


def register(subparsers) -> None:
    p = subparsers.add_parser('topics', help='list topics (like ros2 topic list)')
    p.add_argument('-t', '--show-types', action='store_true', help="also print each topic's type")
    p.add_argument('--wait', type=float, default=1.5, help='discovery time [s] (default 1.5)')
    p.set_defaults(func=_cmd_topics)

    p = subparsers.add_parser('nodes', help='list nodes (like ros2 node list)')
    p.add_argument('--wait', type=float, default=1.5, help='discovery time [s] (default 1.5)')
    p.set_defaults(func=_cmd_nodes)

    p = subparsers.add_parser('echo', help='print messages of a topic (any type)')
    p.add_argument('topic', type=_topic_name)
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--count', type=int, default=None, help='print N messages and exit')
    p.add_argument(
        '--timeout',
        type=float,
        default=10.0,
        help='wait at most this long [s] for the publisher / the messages (default 10)',
    )
    p.add_argument('--full-arrays', action='store_true', help='print arrays longer than 16 values')
    p.set_defaults(func=_cmd_echo)

    p = subparsers.add_parser('hz', help='receive rate of a topic (any type)')
    p.add_argument('topic', type=_topic_name)
    p.add_argument('--window', type=int, default=100, help='messages in the statistics window')
    p.add_argument(
        '--count', type=int, default=None, help='stop after N reports (default: Ctrl-C)'
    )
    p.add_argument('--timeout', type=float, default=10.0, help='wait for a publisher [s]')
    p.set_defaults(func=_cmd_hz)
