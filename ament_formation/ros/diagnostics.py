"""/diagnostics for every node: one naming scheme, levels from the state, changes published at
once, and stall detection of periodic work (docs/diagnostics.md).

Naming: ``DiagnosticStatus.name`` = ``"<node name>: <component>"`` (the node's own name, first;
per-robot components start with ``robot_<id>``: ``formation_controller: robot_0 control``);
``hardware_id`` = the robot (``robot_<id>``) or the device (serial port, camera source), empty for
software-only components.

    diag = Diagnostics(node)                          # publisher + 1 s timer
    diag.add("robot_0 control", self._control_status, hardware_id="robot_0")
    watch = diag.watch("robot_0 control loop", period_s=0.01, hardware_id="robot_0")
    ...  in the periodic callback:  watch.tick(now_ns)
    ...  on a state change:          diag.changed()   # published now if a level/message changed

A status function returns ``(level, message, values)``; values become KeyValue pairs.
"""

from __future__ import annotations

import math
import re
import time
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy._rclpy_pybind11 import InvalidHandle, RCLError

# levels as ints (DiagnosticStatus.OK etc. are bytes in rclpy; level_int() reads either)
OK = 0
WARN = 1
ERROR = 2
STALE = 3
_LEVEL_NAMES = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}

StatusFn = Callable[[], 'tuple[int, str, dict]']


def _fmt(value) -> str:
    if isinstance(value, float):
        return f'{value:.3f}' if abs(value) >= 1e5 else f'{value:.6g}'  # times [s] keep their ms
    return str(value)


def _level_byte(level) -> bytes:
    return level if isinstance(level, bytes) else bytes([int(level)])


def level_int(level) -> int:
    """A DiagnosticStatus level (bytes in rclpy messages) as an int."""
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def status(
    name: str, hardware_id: str, level: int, message: str, values: dict
) -> DiagnosticStatus:
    """One DiagnosticStatus; ``values`` become KeyValue pairs (floats to 6 significant digits)."""
    msg = DiagnosticStatus()
    msg.level = _level_byte(level)
    msg.name = name
    msg.hardware_id = hardware_id
    msg.message = message
    msg.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
    return msg


def array(stamp, statuses: list[DiagnosticStatus]) -> DiagnosticArray:
    """A DiagnosticArray stamped ``stamp`` (builtin_interfaces/Time)."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg


def status_name(node_name: str, component: str) -> str:
    """``"<node name>: <component>"`` (the one naming scheme of the package)."""
    return f'{node_name}: {component}'


def robot_of_namespace(namespace: str) -> str | None:
    """``robot_<id>`` of a node namespace such as ``/robot_3`` (None for other namespaces)."""
    m = re.search(r'(?:^|/)(robot_\d+)(?:/|$)', namespace or '')
    return m.group(1) if m else None


def clock_ns(node) -> Callable[[], int]:
    """A function giving now on ``node``'s clock [ns]: the system clock read directly (0.1 us)
    unless the node runs on sim time (then Clock.now(), 7 us).
    """
    if bool(node.get_parameter('use_sim_time').value):
        clock = node.get_clock()
        return lambda: clock.now().nanoseconds
    return time.time_ns


# --------------------------------------------------------------------------- stall detection
class PeriodWatch:
    """Notices when periodic work stalls: a call of :meth:`tick` later than ``late_periods``
    periods (and at least ``min_late_s``) after the previous one, measured on the clock that drives
    the timer (``now_ns``: the node's clock, ROS or sim time [ns]). A stall is counted at the tick
    that ends it; :meth:`status` is WARN for ``warn_hold_s`` after the last stall, and also while
    the work has not run for that long (a stall still in progress).

    ``on_stall(watch)``: called at once when a stall is counted (e.g. publish diagnostics now).
    A clock that goes backward or starts (0 = no time yet, sim time) restarts the measurement.
    """

    def __init__(
        self,
        period_s: float,
        now_ns: Callable[[], int] | None = None,
        late_periods: float = 3.0,
        min_late_s: float = 0.02,
        warn_hold_s: float = 5.0,
        on_stall: Callable[['PeriodWatch'], None] | None = None,
    ):
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f'period_s: must be > 0 s (got {period_s!r})')
        if not (late_periods > 1.0):
            raise ValueError(f'late_periods: must be > 1 (got {late_periods!r})')
        self.period_s = float(period_s)
        self.late_periods = float(late_periods)
        self.threshold_ns = int(max(late_periods * period_s, min_late_s) * 1e9)
        self.warn_hold_ns = int(warn_hold_s * 1e9)
        self._now_ns = now_ns
        self.on_stall = on_stall
        self.ticks = 0
        self.stalls = 0
        self.last_gap_s = 0.0  # gap of the last stall [s]
        self.max_gap_s = 0.0  # largest gap between two ticks seen [s]
        self._last_ns: int | None = None
        self._last_stall_ns: int | None = None

    def tick(self, now_ns: int | None = None) -> bool:
        """Record one run of the periodic work; True when it ends a stall (counted)."""
        now = self._now_ns() if now_ns is None else int(now_ns)
        self.ticks += 1
        last, self._last_ns = self._last_ns, now
        if last is None or now <= 0 or last <= 0 or now < last:
            return False
        gap = now - last
        if gap * 1e-9 > self.max_gap_s:
            self.max_gap_s = gap * 1e-9
        if gap <= self.threshold_ns:
            return False
        self.stalls += 1
        self.last_gap_s = gap * 1e-9
        self._last_stall_ns = now
        if self.on_stall is not None:
            self.on_stall(self)
        return True

    def status(self, now_ns: int | None = None) -> tuple[int, str, dict]:
        """(level, message, values) of the watch at ``now_ns``."""
        now = self._now_ns() if now_ns is None else int(now_ns)
        values = {
            'period_s': self.period_s,
            'late_after_s': self.threshold_ns * 1e-9,
            'ticks': self.ticks,
            'stalls': self.stalls,
            'last_stall_gap_s': self.last_gap_s,
            'max_gap_s': self.max_gap_s,
        }
        if self._last_ns is None:
            return OK, 'not started', values
        running_gap = now - self._last_ns
        if self._last_ns > 0 and running_gap > max(self.threshold_ns, self.warn_hold_ns // 5):
            return (
                WARN,
                f'stalled: not run for {running_gap * 1e-9:.3g} s ({self.stalls} stalls)',
                values,
            )
        if self._last_stall_ns is not None and 0 <= now - self._last_stall_ns <= self.warn_hold_ns:
            return (
                WARN,
                f'stalled {self.last_gap_s:.3g} s '
                f'({self.last_gap_s / self.period_s:.0f} periods); '
                f'{self.stalls} stalls',
                values,
            )
        return (
            OK,
            'on time' if not self.stalls else f'on time ({self.stalls} stalls so far)',
            values,
        )


# --------------------------------------------------------------------------- publisher
class _Task:
    __slots__ = ('name', 'hardware_id', 'fn', 'sent')

    def __init__(self, name: str, hardware_id: str, fn: StatusFn):
        self.name, self.hardware_id, self.fn = name, hardware_id, fn
        self.sent: tuple[int, str] | None = None  # (level, message) last published


class Rejections:
    """Inputs a node rejected, counted by kind and reported as one status: WARN for ``hold_s``
    after the newest rejection (the message stays the same during a flood, so a flood is published
    once, not once per payload), then OK with the counts kept.

    ``counts`` is a plain dict (kind -> count) the node increments; :meth:`status` is the status
    function for :meth:`Diagnostics.add`; ``now_s`` is the node's clock [s].
    """

    def __init__(self, kinds, now_s: Callable[[], float], hold_s: float = 10.0):
        self.counts: dict[str, int] = dict.fromkeys(kinds, 0)
        self.now_s, self.hold_s = now_s, hold_s
        self._seen = (0, -math.inf)  # (total, when it last grew [s])

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def status(self) -> tuple[int, str, dict]:
        total, since = self.total, self._seen[1]
        now = self.now_s()
        if total != self._seen[0]:
            self._seen = (total, since := now)
        values = {f'rejected_{k}': v for k, v in self.counts.items()}
        if total and now - since <= self.hold_s:
            return WARN, f'inputs rejected in the last {self.hold_s:g} s', values
        return (
            OK,
            'inputs valid' if not total else f'no input rejected in the last {self.hold_s:g} s',
            values,
        )


class Diagnostics:
    """A node's /diagnostics: its status tasks, published together every ``period_s`` and at once
    (:meth:`changed`) when any task's level or message differs from what was last published.
    """

    def __init__(self, node, period_s: float = 1.0):
        from ament_formation.ros.qos import QOS_DIAGNOSTICS

        self.node = node
        self.node_name = node.get_name()
        self.tasks: list[_Task] = []
        self.published = 0
        self._clock = node.get_clock()
        self.now_ns = clock_ns(node)  # what drives the node's timers (polls read it often)
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', QOS_DIAGNOSTICS)
        self.timer = node.create_timer(period_s, self.publish)

    def add(self, component: str, fn: StatusFn, hardware_id: str = '') -> None:
        """A status ``"<node>: <component>"`` computed by ``fn() -> (level, message, values)``."""
        self.tasks.append(_Task(status_name(self.node_name, component), hardware_id, fn))

    def watch(self, component: str, period_s: float, hardware_id: str = '', **kw) -> PeriodWatch:
        """A :class:`PeriodWatch` on this node's clock reported as ``"<node>: <component>"``; a
        stall is published at once. ``kw``: PeriodWatch options (late_periods, warn_hold_s, ...).
        """
        w = PeriodWatch(period_s, self.now_ns, on_stall=lambda _w: self.changed(), **kw)
        self.add(component, w.status, hardware_id)
        return w

    def _evaluate(self) -> list[tuple[_Task, int, str, dict]]:
        out = []
        for t in self.tasks:
            level, message, values = t.fn()
            out.append((t, level_int(level), message, values))
        return out

    def publish(self, evaluated=None) -> None:
        """Publish every task's status now (nothing once the node's context is shut down: a
        change seen while a node shuts down, e.g. its port closing, is not an error).
        """
        if not self.node.context.ok():
            return
        rows = self._evaluate() if evaluated is None else evaluated
        if not rows:
            return
        statuses = []
        for t, level, message, values in rows:
            statuses.append(status(t.name, t.hardware_id, level, message, values))
            t.sent = (level, message)
        try:
            self.pub.publish(array(self._clock.now().to_msg(), statuses))
        except (RCLError, InvalidHandle):  # shut down between the check and the publish
            return
        self.published += 1

    def changed(self) -> bool:
        """Publish now if some task's level or message changed since it was last published."""
        if not self.node.context.ok():
            return False
        rows = self._evaluate()
        if any(t.sent != (level, message) for t, level, message, _ in rows):
            self.publish(rows)
            return True
        return False


def level_name(level) -> str:
    """Name of a level: "OK", "WARN", "ERROR" or "STALE"."""
    return _LEVEL_NAMES.get(level_int(level), str(level_int(level)))
