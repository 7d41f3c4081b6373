"""Other machines' clocks, estimated from what they send (docs/lab.md "Clocks").

A message stamped by another machine (a camera pose, a robot's state, the coordinator's graph and
decisions) arrives after some latency: ``received - stamp = latency - offset``, where ``offset``
is how far the sender's clock is ahead of ours. The smallest such difference over a window is
``min latency - offset``: :class:`ClockOffsets` keeps that minimum per source over
``window_s`` and takes ``-minimum`` as the offset (a few ms short of the truth by the smallest
latency, which errs on the side of ages read slightly too young). Offsets within
``deadband_s`` are taken as 0: one machine, or clocks already synchronised (chrony, NTP), are not
touched. A remote stamp on our clock is ``stamp - offset``.

Which clock is wrong: a robot times everything against the base machines' clocks, the camera
PC's (capture stamps) and the coordinator's (mission start, decisions): :data:`BASE_SOURCES`.
When one of those is beyond ``bound_s`` from ours, our clock (or the base's) is wrong and the
robot stops (:meth:`ClockOffsets.beyond_bound`). Another robot's clock beyond the bound is that
robot's fault, not ours: its own base offsets show it and it stops itself, while we keep
compensating its stamps with the estimate (:meth:`ClockOffsets.peers_beyond_bound` names it).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

from ament_formation.core.errors import ConfigError

BASE_SOURCES = ('camera', 'coordinator')


@dataclass(frozen=True)
class ClockParams:
    """``window_s``: the minimum is taken over this long [s]; ``deadband_s``: smaller offsets are
    0 [s]; ``bound_s``: a larger offset is not compensated: the robot stops and says why [s].
    """

    window_s: float = 10.0
    deadband_s: float = 0.02
    bound_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ('window_s', 'deadband_s', 'bound_s'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f'must be a finite number >= 0 [s] (got {v!r})', name)
        if self.bound_s <= self.deadband_s:
            raise ConfigError(f'must be > deadband_s ({self.deadband_s:g} s) (got '
                              f'{self.bound_s!r})', 'bound_s')


class _Source:
    __slots__ = ('samples', 'offset', 'count')

    def __init__(self):
        self.samples: deque = deque()  # (received, difference), differences increasing
        self.offset = 0.0
        self.count = 0


class ClockOffsets:
    """Per-source clock offsets (module docstring)."""

    def __init__(self, params: ClockParams | None = None):
        self.p = params or ClockParams()
        self.sources: dict[str, _Source] = {}
        self._latched: set[str] = set()  # transient-local topics heard once
        self._named: set[str] = set()  # peers beyond the bound already reported

    def observe(self, source: str, stamp_s: float, received_s: float) -> None:
        """A message of ``source`` stamped ``stamp_s`` (its clock) received at ``received_s``
        (ours).
        """
        if not (math.isfinite(stamp_s) and math.isfinite(received_s)):
            return
        src = self.sources.get(source)
        if src is None:
            src = self.sources[source] = _Source()
        diff = received_s - stamp_s
        q = src.samples
        while q and q[-1][1] >= diff:  # a monotonic deque: q[0] is the window's minimum
            q.pop()
        q.append((received_s, diff))
        while q[0][0] < received_s - self.p.window_s:
            q.popleft()
        src.count += 1
        offset = -q[0][1]
        src.offset = 0.0 if abs(offset) <= self.p.deadband_s else offset

    def observe_latched(self, topic: str, source: str, stamp_s: float,
                        received_s: float) -> None:
        """:meth:`observe` for a transient-local ``topic``, except its first message: that may
        be the history kept for late joiners, stamped long before it was sent to us, and its
        age would read as clock offset.
        """
        if topic in self._latched:
            self.observe(source, stamp_s, received_s)
        self._latched.add(topic)

    def offset_s(self, source: str) -> float:
        """How far ``source``'s clock runs ahead of ours [s] (0 when unknown or in the
        deadband).
        """
        src = self.sources.get(source)
        return 0.0 if src is None else src.offset

    def local(self, source: str, stamp_s: float) -> float:
        """A stamp of ``source`` on our clock [s]."""
        return stamp_s - self.offset_s(source)

    def beyond_bound(self) -> tuple[str, float] | None:
        """(source, offset) of the base source (:data:`BASE_SOURCES`) farthest beyond
        ``bound_s``, else None: our clock disagrees with the base's, and the robot stops.
        """
        base = [(name, self.sources[name].offset) for name in BASE_SOURCES
                if name in self.sources]
        worst = max(base, key=lambda kv: abs(kv[1]), default=None)
        if worst is None or abs(worst[1]) <= self.p.bound_s:
            return None
        return worst

    def peers_beyond_bound(self) -> list[tuple[str, float]]:
        """(source, offset) of every other source (another robot) beyond ``bound_s``: its clock
        is wrong when the base's agree with ours; its stamps stay compensated.
        """
        return [(name, src.offset) for name, src in sorted(self.sources.items())
                if name not in BASE_SOURCES and abs(src.offset) > self.p.bound_s]

    def newly_beyond_bound(self) -> list[tuple[str, float]]:
        """:meth:`peers_beyond_bound` not returned by an earlier call (to say once)."""
        new = [(n, off) for n, off in self.peers_beyond_bound() if n not in self._named]
        self._named.update(n for n, _ in new)
        return new

    def report(self) -> dict:
        """{``clock_offset_<source>_s``: offset} for diagnostics."""
        return {f'clock_offset_{name}_s': round(src.offset, 4)
                for name, src in sorted(self.sources.items())}
