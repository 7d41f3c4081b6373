"""Executor benchmark (docs/executors.md): what each rclpy executor costs per callback, how late it
runs callbacks, and whether it keeps running them when the machine is overloaded.

Run with `bench/run.sh bench_executors.py [--seconds S] [--hogs N] [--executors events,single]`.

One publisher process sends what the world sends a node (nav_msgs/Odometry at 100 Hz, stamped at
publication; a 640x480 mono8 Image at 30 Hz). Beside it, one subscriber process per executor kind,
all at the same time so they share the same load: each spins one node with a 100 Hz wall timer
(a control tick) and both subscriptions on ros/executors.make_executor's choice for that kind, and
reports per second:
  * CPU time [ms] of the process per callback (timer ticks + messages): the cost of the executor;
  * timer lateness (call time - due time) p50/p99 [ms] and message latency (arrival - stamp)
    p50/p99 [ms];
  * the longest silence [s] of the timer and of each subscription: a frozen executor shows as a
    silence of many seconds while the publisher keeps publishing.
``--hogs N`` starts N CPU-bound processes (`while 1: pass`) for the duration and kills them by PID.
Several ``--repeat`` rounds count how often each executor froze (a silence > --freeze-s).
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.tools.run_cmd import loopback_env  # noqa: E402

PY = str(ROOT / '.venv' / 'bin' / 'python')


def publisher(seconds: float) -> int:
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Image

    from ament_formation.ros.qos import QOS_CONTROL, QOS_IMAGE

    rclpy.init()
    node = rclpy.create_node('bench_pub')
    pub_odom = node.create_publisher(Odometry, '/bench/odom', QOS_CONTROL)
    pub_img = node.create_publisher(Image, '/bench/image', QOS_IMAGE)
    img = Image(height=480, width=640, encoding='mono8', step=640, data=bytes(640 * 480))
    odom = Odometry()
    k = {'n': 0}

    def tick():
        now = node.get_clock().now().to_msg()
        odom.header.stamp = now
        pub_odom.publish(odom)
        k['n'] += 1
        if k['n'] % 3 == 0:
            img.header.stamp = now
            pub_img.publish(img)

    node.create_timer(0.01, tick)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def subscriber(kind: str, seconds: float, out: str, window: tuple[float, float]) -> int:
    os.environ['AMENT_FORMATION_EXECUTOR'] = kind
    from nav_msgs.msg import Odometry
    import rclpy
    from sensor_msgs.msg import Image

    from ament_formation.ros.executors import make_executor
    from ament_formation.ros.qos import QOS_CONTROL, QOS_IMAGE

    rclpy.init()
    node = rclpy.create_node(f'bench_sub_{kind}')
    period_s = 0.01
    ticks: list[float] = []
    odom_t: list[tuple[float, float]] = []
    img_t: list[tuple[float, float]] = []

    def stamp(msg) -> float:
        return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    node.create_timer(period_s, lambda: ticks.append(time.time()))
    node.create_subscription(
        Odometry, '/bench/odom', lambda m: odom_t.append((time.time(), stamp(m))), QOS_CONTROL
    )
    node.create_subscription(
        Image, '/bench/image', lambda m: img_t.append((time.time(), stamp(m))), QOS_IMAGE
    )
    ex = make_executor(node)
    ex.add_node(node)
    cpu0 = time.process_time()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.1)
    cpu = time.process_time() - cpu0

    def silence(times: list[float]) -> float:
        """Longest gap [s] in the publishing window (from the first sample, or the window start
        plus 3 s for discovery, to the publisher's end).
        """
        a, b = window
        inside = [t for t in times if a <= t <= b]
        first = min(inside[0], a + 3.0) if inside else a + 3.0
        edges = [first, *[t for t in inside if t >= first], b]
        return float(np.max(np.diff(edges))) if len(edges) > 1 else b - a

    tk = np.array(ticks)
    late_ms = []
    if len(tk) > 1:  # lateness against the best-fitting grid of the nominal period
        due = tk[0] + period_s * np.round((tk - tk[0]) / period_s)
        late_ms = (tk - due) * 1e3
    lat = [1e3 * (a - s) for a, s in odom_t]
    res = {
        'executor': type(ex).__name__,
        'kind': kind,
        'seconds': seconds,
        'timer_ticks': len(ticks),
        'odom_msgs': len(odom_t),
        'image_msgs': len(img_t),
        'cpu_ms_per_callback': 1e3 * cpu / max(1, len(ticks) + len(odom_t) + len(img_t)),
        'cpu_fraction': cpu / seconds,
        'timer_late_ms_p50': float(np.percentile(late_ms, 50)) if len(late_ms) else None,
        'timer_late_ms_p99': float(np.percentile(late_ms, 99)) if len(late_ms) else None,
        'odom_latency_ms_p50': float(np.percentile(lat, 50)) if lat else None,
        'odom_latency_ms_p99': float(np.percentile(lat, 99)) if lat else None,
        'silence_s': {
            'timer': silence(ticks),
            'odom': silence([a for a, _ in odom_t]),
            'image': silence([a for a, _ in img_t]),
        },
    }
    Path(out).write_text(json.dumps(res))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def one_round(kinds: list[str], seconds: float, hogs: int, tmp: Path) -> list[dict]:
    hog_procs = [subprocess.Popen([sys.executable, '-c', 'while 1: pass']) for _ in range(hogs)]
    procs = []
    try:
        outs = {k: tmp / f'{k}.json' for k in kinds}
        start = time.time() + 3.0  # the subscribers start first
        window = f'{start},{start + seconds - 0.5}'
        subs = [
            subprocess.Popen(
                [
                    PY,
                    __file__,
                    '--role',
                    'sub',
                    '--kind',
                    k,
                    '--seconds',
                    str(seconds + 5),
                    '--out',
                    str(outs[k]),
                    '--window',
                    window,
                ]
            )
            for k in kinds
        ]
        procs += subs
        time.sleep(max(0.0, start - time.time()))
        pub = subprocess.Popen([PY, __file__, '--role', 'pub', '--seconds', str(seconds)])
        procs.append(pub)
        for p in procs:
            p.wait(timeout=seconds + 120)
        return [json.loads(outs[k].read_text()) for k in kinds if outs[k].exists()]
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(timeout=10)
        for h in hog_procs:  # the hogs this round started, by PID
            h.kill()
            h.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        '--role', choices=('main', 'pub', 'sub'), default='main', help=argparse.SUPPRESS
    )
    ap.add_argument('--kind', default='events', help=argparse.SUPPRESS)
    ap.add_argument('--out', default='', help=argparse.SUPPRESS)
    ap.add_argument('--window', default='0,0', help=argparse.SUPPRESS)
    ap.add_argument('--seconds', type=float, default=30.0, help='publishing time per round [s]')
    ap.add_argument('--hogs', type=int, default=0, help='CPU-bound processes beside the round')
    ap.add_argument('--repeat', type=int, default=1, help='rounds')
    ap.add_argument(
        '--executors', default='events,single', help='kinds to compare (events, single)'
    )
    ap.add_argument(
        '--freeze-s', type=float, default=2.0, help='a silence longer than this is a freeze [s]'
    )
    args = ap.parse_args()
    if args.role == 'pub':
        return publisher(args.seconds)
    if args.role == 'sub':
        a, b = (float(v) for v in args.window.split(','))
        return subscriber(args.kind, args.seconds, args.out, (a, b))
    loopback_env(Path(tempfile.mkdtemp(prefix='bench_exec_log_')))
    kinds = [k.strip() for k in args.executors.split(',') if k.strip()]
    rows: dict[str, list[dict]] = {k: [] for k in kinds}
    with tempfile.TemporaryDirectory(prefix='bench_exec_') as tmp:
        for r in range(args.repeat):
            for res in one_round(kinds, args.seconds, args.hogs, Path(tmp)):
                rows[res['kind']].append(res)
                s = res['silence_s']
                print(
                    f'round {r + 1} {res["executor"]:24s} '
                    f'cpu {res["cpu_ms_per_callback"]:.3f} ms/callback '
                    f'({100 * res["cpu_fraction"]:.1f} % of a core), timer late p50/p99 '
                    f'{res["timer_late_ms_p50"]:.2f}/{res["timer_late_ms_p99"]:.2f} ms, '
                    f'odom latency p50/p99 '
                    f'{res["odom_latency_ms_p50"]:.2f}/{res["odom_latency_ms_p99"]:.2f} ms, '
                    f'longest silence '
                    f'timer {s["timer"]:.2f} s odom {s["odom"]:.2f} s image {s["image"]:.2f} s',
                    flush=True,
                )
    print(
        f'\nsummary ({args.repeat} rounds of {args.seconds:g} s, {args.hogs} hogs, load '
        f'{os.getloadavg()[0]:.1f} at the end):'
    )
    for k, rs in rows.items():
        if not rs:
            continue
        frozen = sum(max(r['silence_s'].values()) > args.freeze_s for r in rs)
        cpu = np.median([r['cpu_ms_per_callback'] for r in rs])
        p99 = np.median([r['timer_late_ms_p99'] for r in rs])
        lat = np.median([r['odom_latency_ms_p99'] for r in rs])
        print(
            f'  {rs[0]["executor"]:24s} frozen {frozen}/{len(rs)}, '
            f'median cpu {cpu:.3f} ms/callback, '
            f'median timer late p99 {p99:.2f} ms, median odom latency p99 {lat:.2f} ms, '
            f'worst silence {max(max(r["silence_s"].values()) for r in rs):.2f} s'
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
