"""Spinning helpers shared by tests, benchmarks and the `formation` tool: wait for a condition
with a timeout instead of sleeping a fixed time."""
from __future__ import annotations

import time
from typing import Callable

from rclpy.executors import Executor, ExternalShutdownException


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


def make_executor(node=None, context=None) -> Executor:
    """The executor a node process spins: rclpy's C++ EventsExecutor, unless the node runs on
    simulated time (``use_sim_time``: its timer manager does not follow /clock in Jazzy) or
    ``AMENT_FORMATION_EXECUTOR=single`` asks for the SingleThreadedExecutor.

    The EventsExecutor costs about a quarter of the CPU time per timer tick or message of the
    Python SingleThreadedExecutor (bench/bench_system.py), which is what lets many robots' nodes
    share two cores.
    """
    import os

    from rclpy.executors import SingleThreadedExecutor

    sim_time = False
    if node is not None and node.has_parameter("use_sim_time"):
        sim_time = bool(node.get_parameter("use_sim_time").value)
    if sim_time or os.environ.get("AMENT_FORMATION_EXECUTOR", "events") == "single":
        return SingleThreadedExecutor(context=context)
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # older rclpy
        return SingleThreadedExecutor(context=context)
    return EventsExecutor(context=context)


def spin_node(node) -> None:
    """Spin ``node`` until its context shuts down (SIGINT/SIGTERM), on :func:`make_executor`."""
    executor = make_executor(node, context=node.context)
    executor.add_node(node)
    try:
        while node.context.ok():   # EventsExecutor.spin() does not return on SIGTERM in Jazzy
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:  # SIGINT/SIGTERM shut the context down: a clean exit
        pass
    finally:
        executor.remove_node(node)
        executor.shutdown()
