"""Spinning helpers shared by tests, benchmarks and the `formation` tool: wait for a condition
with a timeout instead of sleeping a fixed time.
"""

from __future__ import annotations

import gc
import sys
import time
from typing import Callable

from rclpy.executors import Executor, ExternalShutdownException
from rclpy.task import Future


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


# The executor each process spins, chosen by measurement (docs/executors.md,
# bench/bench_executors.py):
# rclpy's C++ EventsExecutor costs about half the CPU time per callback of the Python
# SingleThreadedExecutor, which matters on the control path (a robot's board runs the bridge and
# the controller at 100-200 Hz); where the executor's cost is small next to the work of the
# callbacks (physics and rendering, image processing, the graph) or where a stalled callback
# spoils the whole run (the world is the clock of a simulated run; the recorder of `formation run`
# is how a run is judged), the SingleThreadedExecutor: plain rcl wait sets, with a timeout on
# every wait. Keys are the process names given to run_node (and the node name of the recorder).
EXECUTOR_BY_PROCESS: dict[str, str] = {
    # ~430 callbacks/s per robot (control tick, wheels, pose, parent)
    'formation_controller': 'events',
    'formation_bridge': 'events',  # 200 Hz serial poll + 100 Hz torque
    'formation_team': 'events',  # several robots' controllers and bridges in one process
    'formation_world': 'single',  # plant + camera: the sim's clock; work >> executor cost
    'formation_tracker': 'single',  # 30 Hz frames: image processing >> executor cost
    'formation_coordinator': 'single',  # graph and arbiter; slow paths, safety-relevant decisions
    'formation_live_view': 'single',
    '_formation_run_recorder': 'single',  # formation run's judge: its stall would hide a failure
}
EXECUTOR_ENV = 'AMENT_FORMATION_EXECUTOR'  # "single" or "events" overrides the table (experiments)

# Processes whose every publish goes through a thread of its own that calls rcl without the GIL
# (ros/nonblocking.py): a send the network blocks (a robot's link down: 2-3 s in sendto) stalls
# neither the control loop nor the executor, of this process or of a peer still sending to the
# lost robot (docs/multi-machine.md). The robot processes and the camera PC's nodes that send
# to robots; not the world (a simulated plant, its images stay on the camera PC).
PUBLISH_THREAD_PROCESSES = frozenset(
    {
        'formation_team',
        'formation_controller',
        'formation_bridge',
        'formation_tracker',
        'formation_coordinator',
    }
)
PUBLISH_THREAD_ENV = 'AMENT_FORMATION_PUBLISH_THREAD'  # "0": rclpy's own publish (experiments)


def executor_kind(process: str | None = None, node=None) -> str:
    """Kind "single" or "events" for ``process`` (a key of EXECUTOR_BY_PROCESS; default: the node's
    name): SingleThreadedExecutor on simulated time (the EventsExecutor's timers do not follow
    /clock in Jazzy), else the environment override, else the table, else "events".
    """
    import os

    if (
        node is not None
        and node.has_parameter('use_sim_time')
        and bool(node.get_parameter('use_sim_time').value)
    ):
        return 'single'
    forced = os.environ.get(EXECUTOR_ENV, '').strip().lower()
    if forced in ('single', 'events'):
        return forced
    if process is None and node is not None:
        process = node.get_name()
    return EXECUTOR_BY_PROCESS.get(process or '', 'events')


def make_executor(node=None, context=None, process: str | None = None) -> Executor:
    """The executor for ``process`` (or ``node``'s name), see :func:`executor_kind`."""
    from rclpy.executors import SingleThreadedExecutor

    if executor_kind(process, node) == 'single':
        return SingleThreadedExecutor(context=context)
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # older rclpy
        return SingleThreadedExecutor(context=context)
    return EventsExecutor(context=context)


def spin_node(node, process: str | None = None) -> None:
    """Spin ``node`` (and the nodes it hosts, ``node.composed_nodes``, nodes/team.py) until its
    context shuts down (SIGINT/SIGTERM) or it sets ``node.done``, on :func:`make_executor`'s
    choice for ``process``.
    """
    executor = make_executor(node, context=node.context, process=process)
    nodes = [node, *getattr(node, 'composed_nodes', ())]
    for n in nodes:
        executor.add_node(n)
    try:
        # EventsExecutor.spin() does not return on SIGTERM in Jazzy: spin in slices of 0.1 s
        # instead; the EventsExecutor's slice is spin_until_future_complete on a future that
        # never completes (it runs every callback due in the slice without returning to Python
        # between them; spin_once returns after each), the Python executors' spin_once (their
        # spin_until_future_complete adds a callback to the future per call)
        if isinstance(executor, Executor):
            while node.context.ok() and not getattr(node, 'done', False):
                executor.spin_once(timeout_sec=0.1)
        else:
            never = Future()
            while node.context.ok() and not getattr(node, 'done', False):
                executor.spin_until_future_complete(never, timeout_sec=0.1)
    except ExternalShutdownException:  # SIGINT/SIGTERM shut the context down: a clean exit
        pass
    finally:
        for n in nodes:
            executor.remove_node(n)
        executor.shutdown()


def _stack_dump_on_sigusr1() -> None:
    """`kill -USR1 <pid>` writes every thread's Python stack to stderr (the process's log): how a
    stalled process is diagnosed without stopping it.
    """
    import faulthandler
    import signal

    try:
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (AttributeError, ValueError, OSError):  # no SIGUSR1 on this platform
        pass


def _stop_on_signals(get_node: Callable) -> None:
    """SIGINT/SIGTERM end the spin loop (``node.done``) instead of shutting the context down under
    running callbacks (which then fail to publish: "[FATAL] ... publisher's context is invalid"),
    so that ``on_exit`` and ``destroy_node`` still publish and the context is shut down last. A
    second signal interrupts at once.
    """
    import signal

    def handler(signum, frame):
        node = get_node()
        if node is None or getattr(node, 'done', False):
            raise KeyboardInterrupt
        node.done = True

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def run_node(
    name: str,
    make_node: Callable,
    args: list[str] | None = None,
    on_exit: Callable | None = None,
    ack_s: float | None = None,
) -> int:
    """The ``main()`` of every node process: init rclpy, build the node, spin it
    (:func:`spin_node`) and shut down cleanly. Bad configuration (ConfigError) prints one line
    naming it and returns 2; SIGINT/SIGTERM return 0. ``on_exit(node)`` runs last, best effort
    (e.g. a zero-torque command). Before the node is destroyed, its reliable messages get up to
    ``ack_s`` to be acknowledged (default: :data:`LAST_WORD_ACK_S` with ``on_exit``, else no wait).
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from ament_formation.core.errors import ConfigError
    from ament_formation.ros.params import init_rclpy_checked

    try:  # a bad params file or ROS argument: one line, not rcl's log and a traceback
        init_rclpy_checked(
            args if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO
        )
    except ConfigError as err:
        print(f'{name}: {err}', file=sys.stderr)
        return 2
    node = None
    sender = None
    _stop_on_signals(lambda: node)
    _stack_dump_on_sigusr1()
    try:
        node = make_node()
        sender = _publish_thread(name, node)
        # everything built so far (modules, compiled kernels, the nodes) lives as long as the
        # process: keep it out of the cyclic collector, whose full passes over it would otherwise
        # pause the control loop for milliseconds
        gc.collect()
        gc.freeze()
        spin_node(node, process=name)
        return 0
    except ConfigError as err:
        print(f'{name}: {err}', file=sys.stderr)
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
            if sender is not None:  # what on_exit published (a last zero torque) goes out first
                sender.stop(flush_timeout_s=1.0)
                node.get_logger().info(
                    f'publish thread: {sender.sent} sent, {sender.dropped} dropped (queue full), '
                    f'{sender.errors} failed, longest rcl publish {sender.longest_call_s:.3f} s'
                )
            if ack_s is None and on_exit is not None:
                ack_s = LAST_WORD_ACK_S
            if ack_s:
                _wait_acked(node, ack_s)
            node.destroy_node()
        rclpy.try_shutdown()


LAST_WORD_ACK_S = 0.5  # how long a process waits for its last word to be acknowledged


def _wait_acked(node, timeout_s: float) -> None:
    """Wait, up to ``timeout_s`` in all, until the reliable publishers of ``node`` and of the
    nodes it hosts have their messages acknowledged by every matched subscriber (so the last word
    of :func:`run_node`'s ``on_exit``, a zero torque, is not lost when the node is destroyed right
    after it). Best effort: a context already shut down ends the wait.
    """
    from rclpy.duration import Duration
    from rclpy.qos import ReliabilityPolicy

    end = time.monotonic() + timeout_s
    for n in (node, *getattr(node, 'composed_nodes', ())):
        for pub in list(n.publishers):
            left = end - time.monotonic()
            if left <= 0.0:
                return
            if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
                continue
            try:
                pub.wait_for_all_acked(Duration(seconds=left))
            except Exception:  # noqa: BLE001 - context or publisher already gone
                return


def _publish_thread(name: str, node):
    """For the processes of PUBLISH_THREAD_PROCESSES: every publisher of ``node`` and of the
    nodes it hosts published through a :class:`~ament_formation.ros.nonblocking.PublishThread`
    (None otherwise, or with AMENT_FORMATION_PUBLISH_THREAD=0).
    """
    import os

    if name not in PUBLISH_THREAD_PROCESSES or os.environ.get(PUBLISH_THREAD_ENV, '1') == '0':
        return None
    from ament_formation.ros.nonblocking import PublishThread

    sender = PublishThread(node.get_logger())
    nodes = [node, *getattr(node, 'composed_nodes', ())]
    if not sender.adopt(p for n in nodes for p in n.publishers):
        return None
    return sender


def set_realtime(priority: int, logger=None) -> bool:
    """Put the calling thread under SCHED_FIFO ``priority``; False (with a warning) when not
    permitted (needs root or CAP_SYS_NICE).
    """
    import os

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
    except (OSError, AttributeError) as err:
        if logger is not None:
            logger.warn(f'realtime_priority {priority}: cannot use SCHED_FIFO ({err})')
        return False
    return True
