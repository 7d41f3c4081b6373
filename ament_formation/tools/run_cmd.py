"""`formation run SCENARIO.yaml --out DIR`: the whole ROS 2 system on the simulated hardware twin.

Starts every process with scripts/launch_sim.sh (world, one bridge and one controller per robot,
or with ``--team K`` one formation_team process per K robots, tracker, coordinator; logs in
DIR/processes/), records every topic to DIR/run.mcap from this
process (camera images only with --record-images), waits until the world has finished the
scenario, then computes DIR/metrics.json from the recorded ground truth (core/metrics.py, the same
code as `formation sim`), writes the trajectories (CSV) and DIR/figure.png, and prints a summary.
DDS stays on loopback (the environment of scripts/ros_env.sh is applied when not already set).
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from ament_formation.core.errors import ConfigError

_ROOT = Path(__file__).resolve().parents[2]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="run a scenario through the whole ROS 2 system (simulated hardware twin)",
        description="Run SCENARIO.yaml through every node of the system on the simulated twin and write "
                    "DIR/run.mcap, DIR/metrics.json, DIR/figure.png and the trajectories.")
    p.add_argument("scenario", metavar="SCENARIO.yaml")
    p.add_argument("--out", required=True, metavar="DIR", help="run directory (created)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="sim seconds per wall second (!= 1 uses /clock and use_sim_time; default 1)")
    p.add_argument("--team", type=int, default=None, metavar="K",
                   help="compose K robots' bridge and controller nodes per process (formation_team; "
                        "ceil(N/K) processes instead of 2 per robot: for many robots on one machine). "
                        "Default: one bridge and one controller process per robot")
    p.add_argument("--control-nice", type=int, default=None, metavar="N",
                   help="run the bridge/controller (or team) processes under `nice -n N` (-20..19; "
                        "negative puts the control loops before the world, tracker and coordinator; "
                        "needs root or CAP_SYS_NICE)")
    p.add_argument("--record-images", action="store_true", help="also record /camera/image_raw")
    p.add_argument("--live", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="watch the run live in Foxglove: formation_live_view on ws://127.0.0.1:PORT "
                        "(default 8765; 0 = any free port, see DIR/processes/live_view.log; docs/live_view.md)")
    p.add_argument("--live-host", default=None, metavar="HOST",
                   help="bind the live view to HOST instead of 127.0.0.1 (e.g. the lab address; implies --live)")
    p.add_argument("--no-figure", action="store_true", help="skip figure.png")
    p.add_argument("--quiet", action="store_true", help="no progress and no summary")
    p.add_argument("--startup-timeout", type=float, default=90.0, metavar="S",
                   help="give up when the mission has not started after S wall seconds (default 90)")
    p.set_defaults(func=run_system)


def loopback_env(log_dir: Path) -> None:
    """The environment of scripts/ros_env.sh, for callers that did not source it."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(_ROOT / "config" / "fastdds_localhost.xml"))
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ.setdefault("ROS_DOMAIN_ID", str((os.getpid() + time.time_ns() // 1000) % 200 + 1))
    os.environ.setdefault("ROS_LOG_DIR", str(log_dir))


class _Progress:
    def __init__(self, stream, duration_s: float):
        self.stream, self.duration_s = stream, duration_s
        self.tty = stream.isatty()
        self.next = 0.0

    def __call__(self, text: str) -> None:
        now = time.monotonic()
        if now < self.next:
            return
        self.next = now + (0.5 if self.tty else 5.0)
        self.stream.write(("\r" if self.tty else "") + text + ("" if self.tty else "\n"))
        self.stream.flush()

    def finish(self) -> None:
        if self.tty:
            self.stream.write("\n")


def run_system(args: argparse.Namespace) -> int:
    from ament_formation.core.scenario import load_scenario

    if not (math.isfinite(args.speed) and 0.05 <= args.speed <= 50.0):
        raise ConfigError(f"must be in [0.05, 50] (got {args.speed})", "--speed")
    if args.team is not None and args.team < 1:
        raise ConfigError(f"must be a positive integer (robots per process; got {args.team})", "--team")
    if args.control_nice is not None and not -20 <= args.control_nice <= 19:
        raise ConfigError(f"must be in [-20, 19] (got {args.control_nice})", "--control-nice")
    if args.live is not None and not 0 <= args.live <= 65535:
        raise ConfigError(f"must be a TCP port in [0, 65535] (got {args.live})", "--live")
    out = Path(args.out).resolve()
    if out.exists() and not out.is_dir():
        raise ConfigError("exists and is not a directory", "--out", str(out))
    scenario = load_scenario(args.scenario)
    out.mkdir(parents=True, exist_ok=True)
    loopback_env(out / "ros_log")
    from ament_formation.ros import shm

    shm_before = shm.snapshot()     # what this run leaves in /dev/shm is removed at its end

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    from ament_formation.ros import messages as msgs
    from ament_formation.ros.executors import make_executor
    from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH
    from ament_formation.ros.recorder import McapWriter, TopicRecorder

    mcap_path = out / "run.mcap"
    if mcap_path.exists():
        mcap_path.unlink()
    ctx = Context()
    rclpy.init(context=ctx)
    use_sim_time = args.speed != 1.0
    node = rclpy.create_node("_formation_run_recorder", context=ctx,
                             parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)])
    executor = make_executor(node, context=ctx)   # EventsExecutor unless on sim time (cheap wait sets)
    executor.add_node(node)
    exclude = ["/rosout", "/parameter_events"] + ([] if args.record_images else ["/camera/image_raw"])
    recorder = TopicRecorder(node, McapWriter(mcap_path), exclude=exclude, scan_period_s=0.25)
    start = {"s": None}
    latest = {"s": None}

    def on_graph(msg):
        try:
            g = msgs.graph_from_msg(msg)
        except ValueError:
            return
        if g.start_s is not None:
            start["s"] = g.start_s

    node.create_subscription(String, "/formation/graph", on_graph, QOS_GRAPH)
    leader = scenario.robots[0].id
    node.create_subscription(msgs.Odometry, f"/world/truth/robot_{leader}",
                             lambda m: latest.__setitem__("s", msgs.stamp_to_s(m.header.stamp)), QOS_CONTROL)

    wall0 = time.monotonic()
    proc_dir = out / "processes"
    launch = subprocess.Popen(
        [str(_ROOT / "scripts" / "launch_sim.sh"), str(Path(args.scenario).resolve()),
         "--run-dir", str(proc_dir), "--speed", repr(float(args.speed))]
        + ([] if args.team is None else ["--team", str(args.team)])
        + ([] if args.control_nice is None else ["--control-nice", str(args.control_nice)])
        + ([] if args.live is None and args.live_host is None
           else ["--live", str(8765 if args.live is None else args.live)])
        + ([] if args.live_host is None else ["--live-host", args.live_host]),
        stdout=open(out / "launch.log", "w"), stderr=subprocess.STDOUT, start_new_session=True)
    progress = None if args.quiet else _Progress(sys.stderr, scenario.duration_s)
    status = 0
    live_log = proc_dir / "live_view.log" if (args.live, args.live_host) != (None, None) else None
    try:
        while launch.poll() is None:
            executor.spin_once(timeout_sec=0.05)
            if live_log is not None and not args.quiet and live_log.exists():   # say where to look, once
                url = next((w for w in live_log.read_text().split() if w.startswith("ws://")), None)
                if url is not None:
                    print(f"run: live view on {url} (Foxglove: open a Foxglove WebSocket connection)",
                          file=sys.stderr)
                    live_log = None
            if progress is not None:
                if start["s"] is None or latest["s"] is None:
                    progress(f"run: starting the system ({time.monotonic() - wall0:4.1f} s)")
                else:
                    t = max(0.0, latest["s"] - start["s"])
                    progress(f"run: t = {t:6.1f} / {scenario.duration_s:.1f} s, "
                             f"{recorder.writer.message_count} messages recorded")
            if start["s"] is None and time.monotonic() - wall0 > args.startup_timeout:
                print(f"formation run: the mission did not start within {args.startup_timeout:g} s; "
                      f"see {proc_dir}/*.log", file=sys.stderr)
                status = 1
                break
        launch_rc = launch.poll()
    except KeyboardInterrupt:
        status = 130
        launch_rc = None
    finally:
        if launch.poll() is None:
            launch.send_signal(signal.SIGTERM)   # launch_sim.sh stops every process it started
            try:
                launch.wait(timeout=15)
            except subprocess.TimeoutExpired:
                launch.kill()
                launch.wait()
        if progress is not None:
            progress.finish()
        recorder.close()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        shm.cleanup(shm_before, ignore_pid=os.getpid())   # this process is done with DDS
    wall_s = time.monotonic() - wall0
    if status:
        return status
    if launch_rc not in (0, None):
        print(f"formation run: a process of the system failed (launch status {launch_rc}); "
              f"see {out}/launch.log and {proc_dir}/*.log", file=sys.stderr)
    return _evaluate(mcap_path, scenario, out, wall_s, args, launch_rc)


def _evaluate(mcap_path: Path, scenario, out: Path, wall_s: float, args, launch_rc) -> int:
    from ament_formation.core.metrics import compute_metrics
    from ament_formation.core.records import write_run
    from ament_formation.ros.run_record import load_run

    try:
        result = load_run(mcap_path, scenario)
    except ValueError as err:
        print(f"formation run: {err}", file=sys.stderr)
        return 1
    result.wall_time_s = wall_s
    metrics = compute_metrics(result, scenario)
    metrics["wall_time_s"] = wall_s
    metrics["source"] = "formation run (ROS 2 system, ground truth of the simulated twin)"
    write_run(out, result, scenario, metrics)
    if not args.no_figure:
        from ament_formation.core.plot import render_figure

        render_figure(result, scenario, out / "figure.png")
    if not args.quiet:
        from ament_formation.tools.sim_cmd import _summary

        print(_summary(metrics, out, figure=not args.no_figure, first=("run.mcap",)))
    return 0 if launch_rc in (0, None) else 1
