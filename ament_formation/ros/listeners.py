"""Whether anyone listens to a publisher, asked of rmw at most every ``max_age_s``.

A publisher that only matters to observers (a team's wheel_torque and wheel_state, the state and
accel of a robot nobody outside the process hears) publishes while someone subscribes. Asking rmw
for the matched subscriptions costs microseconds per call, several times per control period; the
answer only changes when discovery matches or unmatches a subscription, which itself takes tens to
hundreds of milliseconds, so the count is kept for ``max_age_s`` (0.1 s) and read again after.
A subscriber that just matched gets the messages from the next refresh on: no later, for it,
than discovery already makes them.
"""

from __future__ import annotations

import time


class Listeners:
    """``listeners()``: the publisher's matched subscription count, at most ``max_age_s`` old."""

    __slots__ = ('publisher', 'max_age_s', '_clock', '_count', '_next_s')

    def __init__(self, publisher, max_age_s: float = 0.1, clock=time.monotonic):
        self.publisher = publisher
        self.max_age_s = float(max_age_s)
        self._clock = clock
        self._count = 0
        self._next_s = -float('inf')

    def __call__(self) -> int:
        now = self._clock()
        if now >= self._next_s:
            self._count = self.publisher.get_subscription_count()
            self._next_s = now + self.max_age_s
        return self._count
