"""Spinning helpers shared by tests, benchmarks and the `formation` tool: wait for a condition
with a timeout instead of sleeping a fixed time."""
from __future__ import annotations

import gc
import sys
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
    """Spin ``node`` (and the nodes it hosts, ``node.composed_nodes``, nodes/team.py) until its
    context shuts down (SIGINT/SIGTERM) or it sets ``node.done``, on :func:`make_executor`."""
    executor = make_executor(node, context=node.context)
    nodes = [node, *getattr(node, "composed_nodes", ())]
    for n in nodes:
        executor.add_node(n)
    try:
        # EventsExecutor.spin() does not return on SIGTERM in Jazzy: loop on spin_once instead
        while node.context.ok() and not getattr(node, "done", False):
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:  # SIGINT/SIGTERM shut the context down: a clean exit
        pass
    finally:
        for n in nodes:
            executor.remove_node(n)
        executor.shutdown()


def run_node(name: str, make_node: Callable, args: list[str] | None = None,
             on_exit: Callable | None = None) -> int:
    """The ``main()`` of every node process: init rclpy, build the node, spin it (:func:`spin_node`)
    and shut down cleanly. Bad configuration (ConfigError) prints one line naming it and returns 2;
    SIGINT/SIGTERM return 0. ``on_exit(node)`` runs last, best effort (e.g. a zero-torque command).
    """
    import rclpy

    from ament_formation.core.errors import ConfigError

    rclpy.init(args=args if args is not None else sys.argv)
    node = None
    try:
        node = make_node()
        # everything built so far (modules, compiled kernels, the nodes) lives as long as the
        # process: keep it out of the cyclic collector, whose full passes over it would otherwise
        # pause the control loop for milliseconds
        gc.collect()
        gc.freeze()
        spin_node(node)
        return 0
    except ConfigError as err:
        print(f"{name}: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0
    except Exception:  # noqa: BLE001 - SIGTERM/SIGINT shut the context down under spin
        if not rclpy.ok():
            return 0
        raise
    finally:
        if node is not None:
            if on_exit is not None:
                try:
                    on_exit(node)
                except Exception:  # noqa: BLE001 - context already shut down
                    pass
            node.destroy_node()
        rclpy.try_shutdown()
