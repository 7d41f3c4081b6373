"""Spinning helpers shared by tests, benchmarks and the `formation` tool: wait for a condition
with a timeout instead of sleeping a fixed time."""
from __future__ import annotations

import time
from typing import Callable

from rclpy.executors import Executor


def spin_until(
    executor: Executor,
    predicate: Callable[[], bool],
    timeout_s: float,
    step_s: float = 0.01,
) -> bool:
    """Spin ``executor`` until ``predicate()`` is true or ``timeout_s`` [s, wall] elapses.

    Returns the final value of the predicate (True when the condition was met in time).
    """
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        remaining = deadline - time.monotonic()
        if remaining <= 0.0:
            return bool(predicate())
        executor.spin_once(timeout_sec=min(step_s, remaining))
