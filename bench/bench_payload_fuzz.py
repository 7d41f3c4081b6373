"""Bad JSON payloads into the running system:
`bench/run.sh bench_payload_fuzz.py [--count N] [--pace-s S] [--scenario S.yaml] [--json FILE]`.

Starts the simulated system as processes (scripts/launch_sim.sh with the live view: the world, a
bridge and a controller per robot, the tracker, the coordinator, formation_live_view), waits until
every receiver reports its "inputs" status on /diagnostics, then publishes COUNT fuzzed payloads
(test/test_payloads.py:bad_payloads: truncated JSON, wrong types, missing members, other schema
versions, NaN tokens, random bytes, non-objects, unknown members) on each of

  /formation/graph        (received by the world, every controller and the live view)
  /formation/encounters   (every controller)
  /robot_<first>/mode     (the coordinator; beside that robot's own controller's good ones)

one of each every PACE seconds (the receivers keep the newest sample only, QoS depth 1: a payload
overwritten before its receiver took it is not delivered, so the pace must leave them time). It
then reads every receiver's counts from /diagnostics and reports, per receiver and topic, the
payloads counted against those sent, whether every process of the run is still alive, and any
traceback in their logs. Exit status 1 when a process died, a log has a traceback or the run
stopped early. A count below COUNT is reported, not failed: on a loaded machine a receiver busy
for longer than PACE has the next payload overwrite the one it had not taken yet (depth 1), so
it never received it; test/test_payloads.py checks the one-for-one counting through the callbacks.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

SCENARIO = ROOT / 'config' / 'scenarios' / 'v_formation.yaml'  # 100 s: time for 1,000 rounds


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _pids(run_dir: Path) -> dict[int, str]:
    try:
        lines = (run_dir / 'pids').read_text().splitlines()
    except OSError:
        return {}
    return {int(p): n for p, n in (line.split() for line in lines if line.strip())}


def fuzz(scenario: Path, count: int, pace_s: float, run_dir: Path) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile
    from std_msgs.msg import String
    from test_payloads import bad_payloads

    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.ros import payloads as pl
    from ament_formation.ros.executors import spin_until
    from ament_formation.ros.qos import QOS_CONTROL, QOS_DIAGNOSTICS, QOS_GRAPH

    ids = load_scenario(str(scenario)).robot_ids
    inputs = {f'formation_controller: robot_{i} inputs' for i in ids} | {
        'formation_world: inputs',
        'formation_live_view: inputs',
        'formation_coordinator: inputs',
    }
    launch = subprocess.Popen(
        [
            str(ROOT / 'scripts' / 'launch_sim.sh'),
            str(scenario),
            '--run-dir',
            str(run_dir),
            '--live',
            '0',
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    node = rclpy.create_node('payload_fuzzer', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    latest: dict[str, dict] = {}

    def on_diag(arr):
        for st in arr.status:
            if st.name in inputs:
                latest[st.name] = {kv.key: kv.value for kv in st.values}

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_DIAGNOSTICS)
    keep_all = QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        reliability=QOS_GRAPH.reliability,
        durability=QOS_GRAPH.durability,
    )
    pubs = {
        'graph': node.create_publisher(String, '/formation/graph', keep_all),
        'encounters': node.create_publisher(String, '/formation/encounters', keep_all),
        'mode': node.create_publisher(String, f'/robot_{ids[0]}/mode', QOS_CONTROL),
    }
    # receivers of each topic: world + controllers + live view; controllers; the coordinator
    want = {'graph': len(ids) + 2, 'encounters': len(ids), 'mode': 1}
    row: dict = {'count': count, 'pace_s': pace_s, 'robots': len(ids)}
    try:
        ready = spin_until(
            ex,
            lambda: (
                inputs <= set(latest)
                and all(pubs[k].get_subscription_count() >= n for k, n in want.items())
            ),
            300.0,
        )
        if not ready:
            raise RuntimeError(
                f'the system did not come up: heard {sorted(latest)}; see {run_dir}'
            )
        before = {name: dict(values) for name, values in latest.items()}
        texts = {
            'graph': bad_payloads(pl.GRAPH_V1, count, 101),
            'encounters': bad_payloads(pl.ENCOUNTERS_V2, count, 102),
            'mode': bad_payloads(pl.MODE_V1, count, 103),
        }
        t0 = time.monotonic()
        for k in range(count):
            for topic, pub in pubs.items():
                pub.publish(String(data=texts[topic][k]))
            spin_until(ex, lambda: False, pace_s)  # pace (see the module docstring)
        row['send_s'] = time.monotonic() - t0

        def gained(name: str, key: str) -> int:
            return int(latest[name][key]) - int(before[name][key])

        expected = [
            (f'formation_controller: robot_{i} inputs', k)
            for i in ids
            for k in ('rejected_graph', 'rejected_encounters')
        ]
        expected += [
            ('formation_world: inputs', 'rejected_graph'),
            ('formation_live_view: inputs', 'rejected_graph'),
            ('formation_coordinator: inputs', 'rejected_mode'),
        ]
        spin_until(ex, lambda: all(gained(n, k) >= count for n, k in expected), 30.0)
        row['counted'] = {f'{n} {k}': gained(n, k) for n, k in expected}
        pids = _pids(run_dir)
        row['processes'] = len(pids)
        row['dead'] = sorted(name for pid, name in pids.items() if not _alive(pid))
        row['launcher_running'] = launch.poll() is None
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        if launch.poll() is None:
            launch.send_signal(signal.SIGINT)
            try:
                launch.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(launch.pid, signal.SIGKILL)
                launch.wait()
    row['tracebacks'] = sorted(
        log.name for log in run_dir.glob('*.log') if 'Traceback' in log.read_text(errors='replace')
    )
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', type=Path, default=SCENARIO)
    ap.add_argument('--count', type=int, default=1000, help='payloads per topic')
    ap.add_argument('--pace-s', type=float, default=0.04, help='seconds between rounds')
    ap.add_argument('--json', type=Path, default=None, help='also write the row here')
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='bench_payload_fuzz_') as tmp:
        row = fuzz(args.scenario.resolve(), args.count, args.pace_s, Path(tmp) / 'run')
    for key, n in row['counted'].items():
        print(f'{key:<58} {n:>6} of {args.count}')
    short = {k: n for k, n in row['counted'].items() if n < args.count}
    more = {k: n for k, n in row['counted'].items() if n > args.count}
    print(
        f'{row["processes"]} processes, dead: {row["dead"] or "none"}, launcher running to the '
        f'end: {row["launcher_running"]}, tracebacks: {row["tracebacks"] or "none"}, '
        f'sent in {row["send_s"]:.1f} s'
    )
    if args.json:
        args.json.write_text(json.dumps(row, indent=1))
    bad = row['dead'] or row['tracebacks'] or more or not row['launcher_running']
    if bad:
        print('FAILED')
    elif short:
        print(
            f'OK: no process lost; {len(short)} receiver counts below {args.count} (payloads '
            'overwritten in a depth-1 queue before the receiver took them: try a longer --pace-s)'
        )
    else:
        print('OK: every payload counted by every receiver, no process lost')
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
