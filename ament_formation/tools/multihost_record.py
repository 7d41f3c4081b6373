"""The recorder of `formation multihost`, started by it inside the camera PC's network namespace.

    python -m ament_formation.tools.multihost_record --scenario S.yaml --out RUN/run.mcap [--all]

Records the run to a rosbag2 MCAP file (ros/recorder.py, as `formation run` does) and reports
what the orchestrator waits for as JSON lines on stdout (wall times are ``time.time()``):

  {"ev": "ready"}                                   the node is up
  {"ev": "state", "robot": i, "wall": w}            first state heard from robot i's controller
  {"ev": "start", "start_s": s, "wall": w}          first graph with the mission start
  {"ev": "mode", "robot": i, "mode": m, "wall": w}  robot i's controller mode changed
  {"ev": "t", "t": t}                               scenario time of the newest ground truth
                                                    (every 0.25 s)
  {"ev": "closed", "messages": n}                   the file is finalised (after SIGTERM)

Not recorded unless ``--all``: the camera images and the robots' full-rate topics no other node
of the camera PC needs (``state``, ``accel``, ``wheel_state``, ``wheel_torque``): a recorder
subscribing to them would make every robot send them over its link, and the link traffic is what
a multi-host run measures. The run is judged on the world's ground truth, the robots' ``mode``
and ``/diagnostics`` (their control-loop stalls), which are recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time

ROBOT_FULL_RATE = r'/robot_\d+/(state|accel|wheel_state|wheel_torque)'


def emit(**event) -> None:
    sys.stdout.write(json.dumps(event) + '\n')
    sys.stdout.flush()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenario', required=True)
    ap.add_argument('--out', required=True, help='MCAP file to write')
    ap.add_argument('--all', action='store_true', help='record every topic but the images')
    a = ap.parse_args(argv)

    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.ros import messages as msgs
    from ament_formation.ros.executors import make_executor
    from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH
    from ament_formation.ros.recorder import McapWriter, TopicRecorder

    scenario = load_scenario(a.scenario)
    stop = {'now': False}

    def on_signal(signum, frame):
        stop['now'] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('_formation_run_recorder', context=ctx)
    executor = make_executor(node, context=ctx)
    executor.add_node(node)
    exclude = ['/rosout', '/parameter_events', '/camera/image_raw']
    if not a.all:
        exclude.append(ROBOT_FULL_RATE)
    recorder = TopicRecorder(node, McapWriter(a.out), exclude=exclude, scan_period_s=0.25)
    seen = {'start': None, 't': None, 'modes': {}, 'state': set()}

    def on_graph(msg):
        try:
            g = msgs.graph_from_msg(msg)
        except ValueError:
            return
        if g.start_s is not None and seen['start'] is None:
            seen['start'] = g.start_s
            emit(ev='start', start_s=g.start_s, wall=time.time())

    node.create_subscription(String, '/formation/graph', on_graph, QOS_GRAPH)

    def on_truth(m):
        seen['t'] = msgs.stamp_to_s(m.header.stamp)

    node.create_subscription(
        msgs.Odometry, f'/world/truth/robot_{scenario.robots[0].id}', on_truth, QOS_CONTROL
    )
    # the first state of each robot: a state subscription only until it is heard (then the robot
    # sends its state to the coordinator alone)
    state_subs = {}
    for r in scenario.robots:

        def on_mode(msg, rid=r.id):
            try:
                mode = msgs.mode_from_msg(msg).get('mode')
            except ValueError:
                return
            if seen['modes'].get(rid) != mode:
                seen['modes'][rid] = mode
                emit(ev='mode', robot=rid, mode=mode, wall=time.time())

        def on_state(msg, rid=r.id):
            if rid not in seen['state']:
                seen['state'].add(rid)
                emit(ev='state', robot=rid, wall=time.time())

        node.create_subscription(String, f'/robot_{r.id}/mode', on_mode, QOS_CONTROL)
        state_subs[r.id] = node.create_subscription(
            msgs.Odometry, f'/robot_{r.id}/state', on_state, QOS_CONTROL
        )
    emit(ev='ready', pid=os.getpid())
    next_t = 0.0
    try:
        while not stop['now'] and ctx.ok():
            executor.spin_once(timeout_sec=0.05)
            for rid in [rid for rid in state_subs if rid in seen['state']]:
                node.destroy_subscription(state_subs.pop(rid))
            now = time.monotonic()
            if now >= next_t and seen['start'] is not None and seen['t'] is not None:
                emit(ev='t', t=seen['t'] - seen['start'])
                next_t = now + 0.25
    finally:
        recorder.close()
        emit(ev='closed', messages=recorder.writer.message_count)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return 0


if __name__ == '__main__':
    sys.exit(main())
