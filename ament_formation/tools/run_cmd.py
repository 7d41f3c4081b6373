"""`formation run SCENARIO.yaml --out DIR`: the whole ROS 2 system on the simulated hardware twin.

Starts every process with scripts/launch_sim.sh (world, one bridge and one controller per robot,
or with ``--team K`` one formation_team process per K robots, tracker, coordinator; logs in
DIR/processes/), records every topic to DIR/run.mcap from this
process (camera images only with --record-images), waits until the world has finished the
scenario, then computes DIR/metrics.json from the recorded ground truth (core/sim/metrics.py, the
same code as `formation sim`), writes the trajectories (CSV) and DIR/figure.png, and prints a
summary.
DDS stays on loopback (the environment of scripts/ros_env.sh is applied when not already set).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from ament_formation.core.config_files import config_file, script_file
from ament_formation.core.errors import ConfigError

TRUTH_GAP_MAX_S = (
    1.0  # the longest pause [s, scenario time] of the recorded ground truth of a good run
)
# SCHED_RR priority of the simulated system and its recorder (--realtime-priority): above every
# normal process of the machine, below the usual IRQ threads (50) and a robot's own control loop
# (realtime_priority of the controllers, docs/executors.md "The stall found")
REALTIME_PRIORITY = 10


def check(*args, **kw) -> dict:
    """core/sim/metrics.check, imported when needed (the `formation` tool starts without numpy)."""
    from ament_formation.core.sim.metrics import check as make

    return make(*args, **kw)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'run',
        help='run a scenario through the whole ROS 2 system (simulated hardware twin)',
        description='Run SCENARIO.yaml through every node of the system on the simulated twin '
        'and write '
        'DIR/run.mcap, DIR/metrics.json, DIR/figure.png and the trajectories.',
    )
    p.add_argument('scenario', metavar='SCENARIO.yaml')
    p.add_argument('--out', required=True, metavar='DIR', help='run directory (created)')
    p.add_argument(
        '--speed',
        type=float,
        default=1.0,
        help='sim seconds per wall second (!= 1 uses /clock and use_sim_time; default 1)',
    )
    p.add_argument(
        '--team',
        type=int,
        default=None,
        metavar='K',
        help="compose K robots' bridge and controller nodes per process (formation_team; "
        'ceil(N/K) processes instead of 2 per robot: for many robots on one machine). '
        'Default: one bridge and one controller process per robot',
    )
    p.add_argument(
        '--control-nice',
        type=int,
        default=None,
        metavar='N',
        help='run the bridge/controller (or team) processes under `nice -n N` (-20..19; '
        'negative puts the control loops before the world, tracker and coordinator; '
        'needs root or CAP_SYS_NICE)',
    )
    p.add_argument('--record-images', action='store_true', help='also record /camera/image_raw')
    p.add_argument(
        '--camera',
        default=None,
        metavar='FILE',
        help='the simulated camera (a config/ name or a path; default camera.yaml); a camera '
        'that does not see every start and goal is replaced by one fitted to the scenario, '
        'written to DIR/processes/camera.yaml (docs/camera.md, "Coverage")',
    )
    p.add_argument(
        '--live',
        nargs='?',
        type=int,
        const=8765,
        default=None,
        metavar='PORT',
        help='watch the run live in Foxglove: formation_live_view on ws://127.0.0.1:PORT '
        '(default 8765; 0 = any free port, see DIR/processes/live_view.log; docs/live_view.md)',
    )
    p.add_argument(
        '--live-host',
        default=None,
        metavar='HOST',
        help=(
            'bind the live view to HOST instead of 127.0.0.1 '
            '(e.g. the lab address; implies --live)'
        ),
    )
    p.add_argument('--no-figure', action='store_true', help='skip figure.png')
    p.add_argument('--quiet', action='store_true', help='no progress and no summary')
    p.add_argument(
        '--realtime-priority',
        type=int,
        default=REALTIME_PRIORITY,
        metavar='P',
        help='run the whole simulated system and the recorder under SCHED_RR priority P '
        f'(1..98, default {REALTIME_PRIORITY}; 0 = normal scheduling), so that CPU-bound work '
        'elsewhere on the machine cannot pause the run; needs root, CAP_SYS_NICE or an '
        'RLIMIT_RTPRIO of P (otherwise one line says so and the run goes on at normal priority)',
    )
    p.add_argument(
        '--startup-timeout',
        type=float,
        default=90.0,
        metavar='S',
        help='give up when the mission has not started after S wall seconds (default 90)',
    )
    p.add_argument(
        '--stall-timeout',
        type=float,
        default=20.0,
        metavar='S',
        help="give up when the world's ground truth has not advanced for S wall seconds "
        'after the start (a frozen process; default 20)',
    )
    p.set_defaults(func=run_system)


_DOMAIN_LOCK = None  # the open lock file of the domain this process took (held until exit)


def _free_domain_id() -> str:
    """Take a domain id no other run on this machine holds (scripts/ros_env.sh's lock files)."""
    global _DOMAIN_LOCK
    import fcntl

    first = (os.getpid() + time.time_ns() // 1000) % 101  # ids 1..101: ROS's safe range on Linux
    lock_dir = Path(
        os.environ.get('AF_DOMAIN_LOCK_DIR')
        or Path(os.environ.get('TMPDIR') or '/tmp') / 'ament_formation_domains'
    )
    try:
        lock_dir.mkdir(parents=True, exist_ok=True)
        for i in range(101):
            d = (first + i) % 101 + 1
            f = open(lock_dir / f'{d}.lock', 'a')
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.close()
                continue
            _DOMAIN_LOCK = f
            return str(d)
    except OSError:
        pass
    return str(first + 1)


def loopback_env(log_dir: Path) -> None:
    """The environment of scripts/ros_env.sh, for callers that did not source it: discovery range
    LOCALHOST with the shared-memory profile (4 MB segments: large camera frames arrive;
    docs/executors.md "Large frames"), or loopback UDP only with AMENT_FORMATION_DDS=udp (the
    loopback UDP profile governs discovery; docs/executors.md "The stall found").
    """
    udp_profile = str(config_file('fastdds_localhost.xml'))
    env = os.environ
    if env.get('AMENT_FORMATION_DDS', 'shm') == 'udp':
        if (
            not env.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
            and env.get('FASTRTPS_DEFAULT_PROFILES_FILE', udp_profile) == udp_profile
        ):
            env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'  # loopback UDP only (see ros_env.sh)
        env.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', udp_profile)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(config_file('fastdds_localhost_shm.xml')))
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    if not os.environ.get('ROS_DOMAIN_ID'):
        os.environ['ROS_DOMAIN_ID'] = _free_domain_id()
    os.environ.setdefault('ROS_LOG_DIR', str(log_dir))


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
        self.stream.write(('\r' if self.tty else '') + text + ('' if self.tty else '\n'))
        self.stream.flush()

    def finish(self) -> None:
        if self.tty:
            self.stream.write('\n')


def _check_options(args: argparse.Namespace) -> None:
    """Raise ConfigError for an option of `formation run` out of its range."""
    if not (math.isfinite(args.speed) and 0.05 <= args.speed <= 50.0):
        raise ConfigError(f'must be in [0.05, 50] (got {args.speed})', '--speed')
    if args.team is not None and args.team < 1:
        raise ConfigError(
            f'must be a positive integer (robots per process; got {args.team})', '--team'
        )
    if args.control_nice is not None and not -20 <= args.control_nice <= 19:
        raise ConfigError(f'must be in [-20, 19] (got {args.control_nice})', '--control-nice')
    if not 0 <= args.realtime_priority <= 98:
        raise ConfigError(
            f'must be in [0, 98] (got {args.realtime_priority})', '--realtime-priority'
        )
    if args.live is not None and not 0 <= args.live <= 65535:
        raise ConfigError(f'must be a TCP port in [0, 65535] (got {args.live})', '--live')


def _recording_node(ctx, args: argparse.Namespace, scenario, mcap_path: Path):
    """The recorder's node: every topic to ``mcap_path``; the mission start and the leader's
    latest ground-truth stamp kept in the returned dicts.

    The node is in no executor: :meth:`TopicRecorder.spin_for` takes every queued message at once
    (ros/recorder.py), about a tenth of the CPU of an executor's callback per message, so the
    judge of a run is not what a busy machine starves first.

    Returns (node, recorder, start {'s'}, latest {'s'}).
    """
    import rclpy
    from rclpy.parameter import Parameter

    from ament_formation.ros import messages as msgs
    from ament_formation.ros.recorder import McapWriter, TopicRecorder

    use_sim_time = args.speed != 1.0
    node = rclpy.create_node(
        '_formation_run_recorder',
        context=ctx,
        parameter_overrides=[Parameter('use_sim_time', value=use_sim_time)],
    )
    exclude = ['/rosout', '/parameter_events'] + (
        [] if args.record_images else ['/camera/image_raw']
    )
    recorder = TopicRecorder(
        node, McapWriter(mcap_path), exclude=exclude, scan_period_s=0.25, scan_timer=False
    )
    start = {'s': None}
    latest = {'s': None}

    def on_graph(msg):
        try:
            g = msgs.graph_from_msg(msg)
        except ValueError:
            return
        if g.start_s is not None:
            start['s'] = g.start_s

    def on_decision(msg):
        try:
            m = msgs.encounters_from_msg(msg)
        except ValueError:
            return
        if m.mission_end_s is not None and start['s'] is not None:
            latest['mission_end_s'] = m.mission_end_s + start['s']

    recorder.tap('/formation/graph', on_graph)
    recorder.tap('/formation/encounters', on_decision)
    leader = scenario.robots[0].id
    recorder.tap(
        f'/world/truth/robot_{leader}',
        lambda m: latest.__setitem__('s', msgs.stamp_to_s(m.header.stamp)),
    )
    return node, recorder, start, latest


def _start_launch(args: argparse.Namespace, out: Path, proc_dir: Path) -> subprocess.Popen:
    """scripts/launch_sim.sh with the run's options, its output to out/launch.log."""
    return subprocess.Popen(
        [
            str(script_file('launch_sim.sh')),  # the checkout's, or share/ament_formation's
            str(Path(args.scenario).resolve()),
            '--run-dir',
            str(proc_dir),
            '--speed',
            repr(float(args.speed)),
        ]
        + ([] if args.team is None else ['--team', str(args.team)])
        + ([] if args.control_nice is None else ['--control-nice', str(args.control_nice)])
        + (
            []
            if args.live is None and args.live_host is None
            else ['--live', str(8765 if args.live is None else args.live)]
        )
        + ([] if args.live_host is None else ['--live-host', args.live_host])
        + ([] if args.camera is None else ['--camera', args.camera]),
        stdout=open(out / 'launch.log', 'w'),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )


def _timeout_check(now, wall0, start, latest, last_truth, args, proc_dir):
    """The failed ``started`` or ``stalled`` check when the mission did not start in time or the
    ground truth stopped coming, else None (``last_truth`` follows the latest sample).
    """
    if start['s'] is None and now - wall0 > args.startup_timeout:
        return check(
            'started',
            False,
            round(now - wall0, 2),
            args.startup_timeout,
            '<=',
            f'the mission did not start within {args.startup_timeout:g} s; see {proc_dir}/*.log',
        )
    if latest['s'] != last_truth['s']:
        last_truth.update(s=latest['s'], wall=now)
    elif start['s'] is not None and now - (last_truth['wall'] or now) > args.stall_timeout:
        t = None if latest['s'] is None else latest['s'] - start['s']
        where = 'before the first sample' if t is None else f'at t = {t:.2f} s'
        return check(
            'stalled',
            False,
            round(now - last_truth['wall'], 2),
            args.stall_timeout,
            '<=',
            f'no ground truth for {now - last_truth["wall"]:.0f} s {where} (a frozen '
            f'process or recorder); see {proc_dir}/*.log',
        )
    if start['s'] is not None and last_truth['wall'] is None:
        last_truth['wall'] = now  # the stall clock runs from the start
    return None


def _supervise(launch, recorder, args, scenario, proc_dir, wall0, start, latest, progress):
    """Spin the recorder until the launch ends; the failed check that stopped it early, if any.

    Shows progress (unless --quiet) and, once, where the live view is.
    """
    last_truth = {'s': None, 'wall': None}
    live_log = proc_dir / 'live_view.log' if (args.live, args.live_host) != (None, None) else None
    while launch.poll() is None:
        recorder.spin_for(0.05)
        if (
            live_log is not None and not args.quiet and live_log.exists()
        ):  # say where to look, once
            url = next((w for w in live_log.read_text().split() if w.startswith('ws://')), None)
            if url is not None:
                print(
                    f'run: live view on {url} (Foxglove: open a Foxglove WebSocket connection)',
                    file=sys.stderr,
                )
                live_log = None
        if progress is not None:
            if start['s'] is None or latest['s'] is None:
                progress(f'run: starting the system ({time.monotonic() - wall0:4.1f} s)')
            else:
                t = max(0.0, latest['s'] - start['s'])
                progress(
                    f'run: t = {t:6.1f} / {scenario.duration_s:.1f} s, '
                    f'{recorder.writer.message_count} messages recorded'
                )
        now = time.monotonic()
        stop_reason = _timeout_check(now, wall0, start, latest, last_truth, args, proc_dir)
        if stop_reason is not None:
            return stop_reason
    return None


def _drain(recorder, complete=None, quiet_s: float = 0.3, max_s: float = 5.0) -> None:
    """After the system stopped: record what is still queued until nothing came for ``quiet_s``
    (at most ``max_s``), so a recorder a little behind keeps the run's last seconds. While
    ``complete()`` is False (the ground truth has not reached the scenario's end yet), a quiet
    spell does not end it: a process starved of CPU can be silent for longer than ``quiet_s``
    with the world's last messages still to take.
    """
    t0 = last_change = time.monotonic()
    count = recorder.writer.message_count
    while time.monotonic() - t0 < max_s and (
        time.monotonic() - last_change < quiet_s or (complete is not None and not complete())
    ):
        recorder.spin_for(0.05)
        if recorder.writer.message_count != count:
            count, last_change = recorder.writer.message_count, time.monotonic()


def _stop_system(
    launch,
    progress,
    recorder,
    node,
    ctx,
    shm_before,
    previous,
    drain: bool = True,
    complete=None,
) -> None:
    """Stop the launch (and so every process it started), close the recording, shut ROS down,
    remove what the run left in /dev/shm, restore the signal handlers. ``complete()``: whether the
    recording has the scenario's end yet (:func:`_drain`).
    """
    import rclpy

    from ament_formation.ros import shm

    if launch.poll() is None:
        launch.send_signal(signal.SIGTERM)  # launch_sim.sh stops every process it started
        try:
            launch.wait(timeout=15)
        except subprocess.TimeoutExpired:
            launch.kill()
            launch.wait()
    if progress is not None:
        progress.finish()
    if drain:  # not after SIGINT/SIGTERM: the user asked to stop now
        try:
            _drain(recorder, complete)
        except (KeyboardInterrupt, RuntimeError):  # a signal while draining: stop now
            pass
    recorder.close()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    shm.cleanup(shm_before, ignore_pid=os.getpid())  # this process is done with DDS
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def _realtime(priority: int, quiet: bool) -> str:
    """Put this thread under SCHED_RR ``priority`` before anything else starts: the recorder's DDS
    threads and every process of the launch (world, bridges, controllers, tracker, coordinator)
    inherit it, so other work on the machine cannot take the CPU from the run. The scheduling
    in use, as metrics.json states it; refused (no privilege), one line on stderr and normal
    scheduling. Why (docs/executors.md "The stall found"): the run needs about 1.1 of this
    machine's 2 cores, and the kernel gives each session (autogroup) of the machine one share.
    """
    if priority == 0:
        return 'normal'
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))
    except (OSError, AttributeError) as err:  # EPERM without the privilege; not Linux
        why = getattr(err, 'strerror', None) or str(err)
        if not quiet:
            print(
                f'formation run: normal scheduling (SCHED_RR priority {priority}: {why}); '
                'CPU-bound work elsewhere on this machine can pause the run '
                '(--realtime-priority 0 runs at normal priority without this note)',
                file=sys.stderr,
            )
        return f'normal (SCHED_RR {priority} refused: {why})'
    return f'SCHED_RR {priority}'


def _normal_scheduling() -> None:
    """Back to normal scheduling (the evaluation and the figure need no priority)."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


def run_system(args: argparse.Namespace) -> int:
    from ament_formation.core.scenario.loader import load_scenario

    _check_options(args)
    out = Path(args.out).resolve()
    if out.exists() and not out.is_dir():
        raise ConfigError('exists and is not a directory', '--out', str(out))
    scenario = load_scenario(args.scenario)
    out.mkdir(parents=True, exist_ok=True)
    loopback_env(out / 'ros_log')
    args.scheduling = _realtime(args.realtime_priority, args.quiet)
    from ament_formation.ros import shm

    shm_before = shm.snapshot()  # what this run leaves in /dev/shm is removed at its end

    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    mcap_path = out / 'run.mcap'
    if mcap_path.exists():
        mcap_path.unlink()
    ctx = Context()
    # SIGINT and SIGTERM end the run through the same clean-up (the launch and every process it
    # started are stopped, the recording closed): rclpy's own handlers would end this process with
    # the launch still running
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    terminated = {'signal': None}

    def on_signal(signum, _frame):
        terminated['signal'] = signum
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    node, recorder, start, latest = _recording_node(ctx, args, scenario, mcap_path)

    wall0 = time.monotonic()
    proc_dir = out / 'processes'
    launch = _start_launch(args, out, proc_dir)
    progress = None if args.quiet else _Progress(sys.stderr, scenario.duration_s)
    status = 0
    stop_reason = None  # why this process stopped the system early (a failed check)
    try:
        stop_reason = _supervise(
            launch, recorder, args, scenario, proc_dir, wall0, start, latest, progress
        )
        launch_rc = launch.poll()
    except (KeyboardInterrupt, RuntimeError, TypeError) as err:
        status, launch_rc = _signal_status(err, terminated), None
    finally:
        _stop_system(
            launch,
            progress,
            recorder,
            node,
            ctx,
            shm_before,
            previous,
            drain=terminated['signal'] is None,
            complete=lambda: _truth_complete(start, latest, scenario),
        )
    wall_s = time.monotonic() - wall0
    _normal_scheduling()
    if status:
        return status
    extra = (
        [stop_reason]
        if stop_reason is not None
        else [_process_check(out / 'launch.log', launch_rc, proc_dir)]
    )
    return _evaluate(mcap_path, scenario, out, wall_s, args, extra)


def _truth_complete(start: dict, latest: dict, scenario) -> bool:
    """Whether the recorded ground truth has reached the mission's end (the coordinator's
    ``mission_end_s``, as the ``completed`` check counts it) or the run's time cap.
    """
    from ament_formation.core.control.progress import max_time_s

    if start['s'] is None or latest['s'] is None:
        return False
    end = latest.get('mission_end_s')  # [s, ROS time]
    if end is not None:
        return latest['s'] >= end - 0.05
    return latest['s'] - start['s'] >= max_time_s(scenario.duration_s) - 0.05


_EXIT_RE = re.compile(r'^(\S+) exited with status (-?\d+)$', re.M)


def _process_check(launch_log: Path, launch_rc, proc_dir: Path) -> dict:
    """The ``processes`` check: a run ends well when the world is the first process to exit, with
    status 0 (it finished the scenario); any other first exit (a crash, a kill, a process stopped
    by a signal) names the process, its status and its log.
    """
    try:
        found = _EXIT_RE.search(launch_log.read_text())
    except OSError:
        found = None
    if found is None:
        return check(
            'processes',
            False,
            f'launch status {launch_rc}',
            'world:0',
            '==',
            f'the launcher ended (status {launch_rc}) before any process exited; see {launch_log}',
        )
    name, rc = found.group(1), int(found.group(2))
    if name == 'world' and rc == 0:
        return check('processes', True, 'world:0', 'world:0', '==')
    how = f'was killed by signal {rc - 128}' if rc > 128 else f'exited with status {rc}'
    return check(
        'processes',
        False,
        f'{name}:{rc}',
        'world:0',
        '==',
        f'{name} {how} before the world finished; see {proc_dir / (name + ".log")}',
    )


def _signal_status(err: BaseException, terminated: dict) -> int:
    """Exit status of a run stopped by SIGINT/SIGTERM (128 + the signal). A signal's
    KeyboardInterrupt raised inside rclpy's C++ code comes out as pybind11's RuntimeError
    "Unable to convert call argument" (a message being taken) or TypeError "Unable to convert
    function return value" (a message being deserialized, seen with two CPU-bound processes
    beside the run): the same stop. Any other error is raised again.
    """
    if terminated['signal'] is None and not isinstance(err, KeyboardInterrupt):
        raise err
    return 128 + (terminated['signal'] or signal.SIGINT)


def _evaluate(mcap_path: Path, scenario, out: Path, wall_s: float, args, extra: list[dict]) -> int:
    """Metrics from the recording, the checks (core/sim/metrics.check_run: every run's, the
    scenario's ``expect:`` and ``extra``), metrics.json, figure, summary. Exit status 0 exactly
    when metrics.json says ``"ok": true``; otherwise one line on stderr names what failed.
    """
    from ament_formation.core.sim.metrics import check_run, compute_metrics
    from ament_formation.core.sim.records import write_metrics, write_run
    from ament_formation.ros.run_record import load_run

    stats: dict = {}
    try:
        result = load_run(mcap_path, scenario, stats=stats)
    except ValueError as err:  # nothing to evaluate: metrics.json still says why
        extra = [*extra, check('recorded', False, None, None, '==', str(err))]
        metrics = {
            'scenario': scenario.name,
            'sim_time_s': 0.0,
            'wall_time_s': wall_s,
            'source': 'formation run (ROS 2 system, ground truth of the simulated twin)',
            'scheduling': getattr(args, 'scheduling', None),
        }
        check_run(metrics, scenario, extra=extra, measured=False)
        write_metrics(out, metrics)
        print(f'formation run: FAILED: {metrics["failure"]}', file=sys.stderr)
        return 1
    result.wall_time_s = wall_s
    metrics = compute_metrics(result, scenario)
    metrics['wall_time_s'] = wall_s
    metrics['source'] = 'formation run (ROS 2 system, ground truth of the simulated twin)'
    metrics['scheduling'] = getattr(args, 'scheduling', None)
    metrics['truth_max_gap_s'] = stats.get('truth_max_gap_s')
    gap = stats.get('truth_max_gap_s')
    extra = [
        *extra,
        check(
            'truth_gap_s',
            gap is not None and gap <= TRUTH_GAP_MAX_S,
            gap,
            TRUTH_GAP_MAX_S,
            '<=',
            f'the recorded ground truth stops for {gap or 0:.2f} s at t = '
            f'{stats.get("truth_max_gap_at_s") or 0:.2f} s (a stalled world or recorder)',
        ),
    ]
    for rid, spans in (stats.get('safety_stops') or {}).items():  # stop-and-go (ros/run_record.py)
        robot = metrics['robots'][str(rid)]
        robot['safety_stops'] = len(spans)
        robot['safety_stop_time_s'] = float(sum(b - a for a, b in spans))
    torque_gaps = stats.get('torque_max_gap_s') or {}
    metrics['torque_max_gap_s'] = {str(k): v for k, v in torque_gaps.items()}
    # every stage's longest pause (ros/run_record.py): which one stopped first names a stall
    metrics['stage_gaps_s'] = stats.get('stage_gaps')
    if torque_gaps:
        rid, worst = max(torque_gaps.items(), key=lambda kv: kv[1])
        extra.append(
            check(
                'control_gap_s',
                worst <= TRUTH_GAP_MAX_S,
                worst,
                TRUTH_GAP_MAX_S,
                '<=',
                f"robot {rid}'s wheel torque commands stop for {worst:.2f} s (a stalled or dead "
                f'controller or recorder)',
            )
        )
    check_run(metrics, scenario, extra=extra)
    write_run(out, result, scenario, metrics)
    if not args.no_figure:
        from ament_formation.core.sim.plot import render_figure

        render_figure(result, scenario, out / 'figure.png')
    if not args.quiet:
        from ament_formation.tools.sim_cmd import _summary

        print(_summary(metrics, out, figure=not args.no_figure, first=('run.mcap',)))
    if not metrics['ok']:
        print(f'formation run: FAILED: {metrics["failure"]}', file=sys.stderr)
        return 1
    return 0
