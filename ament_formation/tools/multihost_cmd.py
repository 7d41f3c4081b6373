"""`formation multihost`: the whole system with the camera PC and every robot on a host of its
own, made of Linux network namespaces on this machine (docs/multi-machine.md).

    formation multihost --scenario S.yaml [--out DIR] [--link-down ROBOT:AT_S:DURATION_S ...]
                        [--fault ROBOT:AT_S:KIND ...] [--clock-shift ROBOT:SECONDS ...]
                        [--rate LIMIT] [--profile LAB.xml] [--robot-params P.yaml]
                        [--no-expect]
    formation multihost --robots N [--duration S]          # a generated N-robot formation

Hosts (tools/netns.py): ``af_cam_<run>`` runs the simulated twin's world (plant, emulated motor
boards on ptys, rendered camera), ``scripts/launch_base.sh --domain D`` (tracker, coordinator;
the lab network, the launchers' default) and the recorder (tools/multihost_record.py); each
``af_r<id>_<run>`` runs ``scripts/launch_robot.sh --domain D`` (the robot process: bridge +
controller) on its emulated board's pty (a pty is a file: a robot's namespace opens the one the
world made, as a robot's computer opens its USB serial port); a switch namespace bridges them.
DDS is UDP only (config/fastdds_udp.xml, or ``--profile``: kept by the launchers as a lab's own
profile), discovery range SUBNET, a domain id D in 1..101 of its own. Everything made is
removed at the end, also after a failure or Ctrl-C.

Prints and writes to DIR/multihost.json: discovery (robot launchers started -> each controller
heard by the camera PC -> mission start -> every controller running), bytes/s per robot link
during the mission (switch port counters: from / to the robot), each link-loss event (the robot's
controller stop, time and distance to rest from the ground truth, rejoin), each process fault
(``--fault``: its controller or bridge process killed or frozen; time and distance to rest from the
ground truth, the emulated board's brake and what started it), the clocks (each robot's shift,
``--clock-shift``, and the offsets its controller estimated for the camera PC, the coordinator and
the robots it heard, with their errors; a robot stopped by its clock, ``stopped_clock``, and why)
and the run's checks
(core/sim/metrics.check_run on the recorded ground truth, as `formation run`, plus the multi-host
checks). DIR/metrics.json, DIR/run.mcap and DIR/figure.png as `formation run`. Exit status 0
when every check passed, 1 when one failed, 2 for bad input or when namespaces are unavailable
(not root, no `ip netns`).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
import os
from pathlib import Path
import re
import select
import signal
import subprocess
import sys
import tempfile
import time

from ament_formation.core.config_files import config_dir, program_file, script_file
from ament_formation.core.errors import ConfigError

UDP_PROFILE = 'fastdds_udp.xml'  # config/ of the checkout or of share/ament_formation
REST_SPEED_MPS = 0.005  # at rest below this point speed (docs/safety.md)
CONTROL_GAP_MAX_S = 0.2  # a longer control-loop gap lets the board's watchdog brake on its own
TRUTH_GAP_MAX_S = 1.0
REJOIN_MAX_S = 5.0  # after the link is back, the robot runs again within this [s]
# --clock-shift: a shifted robot's controller estimates the camera PC's clock within this [s]
# (core/clock.py: short by the smallest latency seen, stamp to arrival)
CLOCK_ERROR_MAX_S = 0.05
# --fault KIND: (the robot process it hits, the signal); the robot runs launch_robot.sh --split
FAULT_KINDS = {
    'controller-kill': ('controller', signal.SIGKILL),
    'controller-stop': ('controller', signal.SIGSTOP),  # frozen, not dead: SIGCONT after a hold
    'bridge-kill': ('bridge', signal.SIGKILL),  # no STOP, port closed: the board's watchdog
}
FAULT_HOLD_S = 3.0  # controller-stop: SIGCONT this long after the SIGSTOP
# A robot whose commands stop is at rest within 0.8 s and 0.35 m of where it was, at the top
# speed (docs/safety.md §3-4: 0.2 s bridge input timeout or board watchdog, then the brake;
# analytic 0.67 s / 0.32 m, measured <= 0.8 s / 0.35 m).
FAULT_REST_MAX_S = 0.8
FAULT_REST_MAX_M = 0.35
# After a fault nothing holds the robot once its board released the brake: in the twin (no
# friction) the scenario's disturbance then moves it again, so a fault's rest is the first time
# the point speed stays below REST_SPEED_MPS for this long (the board's own rest test: 50 ms)
# and the drift after it is reported on its own.
FAULT_REST_HOLD_S = 0.1
_LOG_TIME = re.compile(r'^\[(\w+)\] \[(\d+\.\d+)\] \[([^\]]*)\]: (.*)$')


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'multihost',
        help='run the system with the camera PC and each robot on a host of its own '
        '(network namespaces; root)',
        description=__doc__.split('\n\n')[0],
    )
    p.add_argument('--scenario', metavar='S.yaml', default=None)
    p.add_argument(
        '--robots',
        type=int,
        default=None,
        metavar='N',
        help='without --scenario: a generated formation of N robots (1..9) on the camera floor; '
        "with it: must equal the scenario's robot count",
    )
    p.add_argument(
        '--duration',
        type=float,
        default=20.0,
        metavar='S',
        help='duration of a generated scenario [s] (default 20)',
    )
    p.add_argument('--out', default=None, metavar='DIR', help='run folder (default: a new one)')
    p.add_argument(
        '--link-down',
        action='append',
        default=[],
        metavar='ROBOT:AT_S:DURATION_S',
        help="take robot ROBOT's link down at scenario time AT_S for DURATION_S seconds "
        '(repeatable)',
    )
    p.add_argument(
        '--fault',
        action='append',
        default=[],
        metavar='ROBOT:AT_S:KIND',
        help="at scenario time AT_S, KIND = controller-kill (SIGKILL to robot ROBOT's controller "
        f'process), controller-stop (SIGSTOP, SIGCONT {FAULT_HOLD_S:g} s later) or bridge-kill '
        "(SIGKILL to its bridge process: the board's watchdog stops it); that robot runs "
        'launch_robot.sh --split (repeatable, one fault per robot)',
    )
    p.add_argument(
        '--clock-shift',
        action='append',
        default=[],
        metavar='ROBOT:SECONDS',
        help="run robot ROBOT's host with its wall clock SECONDS ahead (negative: behind) of the "
        'camera PC (libfaketime; scripts/install_clock_deps.sh); beyond the bound of the '
        'controllers (2 s) the robot stops, stopped_clock (repeatable, one per robot)',
    )
    p.add_argument(
        '--rate',
        default=None,
        metavar='LIMIT',
        help='limit every robot link to LIMIT each way (tc tbf rate, e.g. 2mbit, 500kbit)',
    )
    p.add_argument(
        '--profile',
        default=None,
        metavar='XML',
        help="a lab's own Fast DDS profile for every host (default config/fastdds_udp.xml)",
    )
    p.add_argument(
        '--no-expect',
        action='store_true',
        help="skip the scenario's expect: block (implied by --link-down and --fault: a robot "
        'that stood for seconds cannot meet the nominal errors); every-run checks still apply',
    )
    p.add_argument(
        '--robot-rt', type=int, default=None, metavar='P', help='launch_robot.sh --rt-priority P'
    )
    p.add_argument(
        '--robot-params',
        default=None,
        metavar='YAML',
        help="every robot's node parameters (launch_robot.sh --params; e.g. the controller's "
        'state_rate_hz, config/params/formation_controller.yaml)',
    )
    p.add_argument(
        '--record-all',
        action='store_true',
        help="also record the robots' full-rate topics (state, accel, wheels; adds link traffic)",
    )
    p.add_argument(
        '--dump-stacks',
        action='store_true',
        help="SIGUSR1 to a robot's process 1 s into each link loss (its Python stacks in its log)",
    )
    p.add_argument(
        '--control-gap-max',
        type=float,
        default=CONTROL_GAP_MAX_S,
        metavar='S',
        help="the longest gap between two of a robot's control periods (its diagnostics) a run "
        f'may show (default {CONTROL_GAP_MAX_S:g} s: the motor board watchdog)',
    )
    p.add_argument('--startup-timeout', type=float, default=120.0, metavar='S')
    p.add_argument('--stall-timeout', type=float, default=20.0, metavar='S')
    p.add_argument('--no-figure', action='store_true')
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=run_multihost)


# ------------------------------------------------------------------------------- scenario
GRID = [
    (1.2, 0.6),
    (0.6, 0.6),
    (1.2, 0.0),
    (1.2, 1.2),
    (0.6, 0.0),
    (0.6, 1.2),
    (0.0, 0.6),
    (0.0, 0.0),
    (0.0, 1.2),
]  # a 3 x 3 grid, 0.6 m apart, inside the camera's floor (config/camera.yaml), leader first


def formation_yaml(n: int, duration_s: float) -> str:
    """A formation of ``n`` robots (1..9) on a 0.6 m grid: robot 0 leads along +x at 0.05 m/s,
    every other robot follows the nearest robot of a lower id (a tree), 2 cm off its slot at the
    start; no obstacles. Each robot hears its grid neighbours (hearing range 1.05 m).
    """
    if not 1 <= n <= len(GRID):
        raise ConfigError(f'must be in [1, {len(GRID)}] (got {n})', '--robots')
    lx, ly = GRID[0]
    lines = [
        f'# generated by formation multihost --robots {n}',
        f'name: formation_{n}',
        f'duration_s: {duration_s}',
        'disturbance: {accel_bound: [0.05, 0.5], seed: 1}',
        'robots:',
    ]
    edges = []
    for k in range(n):
        x, y = GRID[k]
        lines.append(f'  - id: {k}')
        if k == 0:
            lines += [
                '    leader: true',
                f'    path: {{type: line, start_m: [{lx}, {ly}], heading_rad: 0.0, '
                'speed_mps: 0.05}',
            ]
        else:
            parent = min(range(k), key=lambda j: (math.dist(GRID[j], (x, y)), j))
            edges.append([parent, k])
        lines += [
            f'    slot_m: [{round(x - lx, 3)}, {round(y - ly, 3)}]',
            f'    initial_pose: [{round(x - (0.02 if k else 0.0), 3)}, {y}, 0.0]',
            f'    marker_id: {k}',
        ]
    lines += [f'graph: {{edges: {json.dumps(edges)}}}', 'obstacles: []', '']
    return '\n'.join(lines)


def parse_link_down(text: str, ids) -> tuple[int, float, float]:
    try:
        rid, at_s, dur_s = text.split(':')
        rid, at_s, dur_s = int(rid), float(at_s), float(dur_s)
    except ValueError:
        raise ConfigError(f'expected ROBOT:AT_S:DURATION_S (got {text!r})', '--link-down')
    if rid not in ids:
        raise ConfigError(f'robot {rid} is not in the scenario (ids {list(ids)})', '--link-down')
    if not (math.isfinite(at_s) and at_s >= 0 and math.isfinite(dur_s) and dur_s > 0):
        raise ConfigError(f'expected AT_S >= 0 and DURATION_S > 0 (got {text!r})', '--link-down')
    return rid, at_s, dur_s


def parse_fault(text: str, ids) -> tuple[int, float, str]:
    """``ROBOT:AT_S:KIND`` of ``--fault`` -> (robot, at_s, kind); ConfigError naming --fault."""
    try:
        rid, at_s, kind = text.split(':')
        rid, at_s = int(rid), float(at_s)
    except ValueError:
        raise ConfigError(f'expected ROBOT:AT_S:KIND (got {text!r})', '--fault')
    if rid not in ids:
        raise ConfigError(f'robot {rid} is not in the scenario (ids {list(ids)})', '--fault')
    if not (math.isfinite(at_s) and at_s >= 0):
        raise ConfigError(f'expected AT_S >= 0 (got {text!r})', '--fault')
    if kind not in FAULT_KINDS:
        raise ConfigError(f'KIND must be one of {", ".join(FAULT_KINDS)} (got {kind!r})',
                          '--fault')  # fmt: skip
    return rid, at_s, kind


def parse_faults(texts, ids) -> list[tuple[int, float, str]]:
    """Every ``--fault``; at most one per robot (a killed process cannot be hit again)."""
    faults = [parse_fault(t, ids) for t in texts]
    robots = [f[0] for f in faults]
    for rid in robots:
        if robots.count(rid) > 1:
            raise ConfigError(f'robot {rid} has more than one fault', '--fault')
    return faults


# ------------------------------------------------------------------------------- processes
class _Proc:

    def __init__(self, name: str, popen: subprocess.Popen, log: Path):
        self.name, self.popen, self.log = name, popen, log
        self.rc: int | None = None
        self.exited_wall: float | None = None

    def poll(self) -> int | None:
        if self.rc is None and self.popen.poll() is not None:
            self.rc, self.exited_wall = self.popen.returncode, time.time()
        return self.rc

    def stop(self, timeout_s: float = 15.0) -> None:
        """SIGTERM (a launcher stops every process it started), then SIGKILL to its own process
        group (it was started in a session of its own) if it is still there.
        """
        if self.popen.poll() is None:
            try:
                self.popen.send_signal(signal.SIGTERM)
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.popen.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.popen.wait()
        self.poll()


def _program(name: str) -> str:
    """A console script of this package: beside this interpreter (the venv), else the installed
    one (lib/ament_formation), else on PATH.
    """
    return program_file(name)


def _log_lines(path: Path, shift_s: float = 0.0):
    """(severity, wall time, logger, message) of every ROS console line of a log file; a host
    whose clock runs ``shift_s`` ahead (--clock-shift) has its times put back on the true clock.
    """
    try:
        text = path.read_text(errors='replace')
    except OSError:
        return
    for line in text.splitlines():
        m = _LOG_TIME.match(line.strip())
        if m:
            yield m.group(1), float(m.group(2)) - shift_s, m.group(3), m.group(4)


def _pid_of(run_dir: Path, name: str) -> int | None:
    try:
        for line in (run_dir / 'pids').read_text().splitlines():
            pid, n = line.split(maxsplit=1)
            if n == name:
                return int(pid)
    except (OSError, ValueError):
        pass
    return None


def _environ(pid: int) -> dict:
    try:
        raw = Path(f'/proc/{pid}/environ').read_bytes()
    except OSError:
        return {}
    return dict(kv.split('=', 1) for kv in raw.decode(errors='replace').split('\0') if '=' in kv)


# ------------------------------------------------------------------------------- the run
def run_multihost(args: argparse.Namespace) -> int:
    from ament_formation.core.config_files import read_user_text
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.tools import clock_shift, netns

    reason = netns.unavailable_reason()
    if reason is not None:
        print(f'formation multihost: {reason}', file=sys.stderr)
        return 2
    if args.rate is not None and not netns.valid_rate(args.rate):
        raise ConfigError(f'expected a tc rate such as 2mbit or 500kbit (got {args.rate!r})',
                          '--rate')  # fmt: skip
    if args.clock_shift and clock_shift.missing_reason() is not None:
        raise ConfigError(clock_shift.missing_reason(), '--clock-shift')
    profile = Path(args.profile).resolve() if args.profile else config_dir() / UDP_PROFILE
    if not profile.is_file():
        raise ConfigError('no such file', '--profile', str(profile))
    read_user_text(profile, 'Fast DDS profile')  # text, no control characters (tinyxml2 parses it)
    if args.robot_params is not None:
        args.robot_params = str(Path(args.robot_params).resolve())
        if not Path(args.robot_params).is_file():
            raise ConfigError('no such file', '--robot-params', args.robot_params)
        read_user_text(Path(args.robot_params), 'parameters file')
    out = Path(args.out or tempfile.mkdtemp(prefix='ament_formation_multihost_')).resolve()
    if out.exists() and not out.is_dir():
        raise ConfigError('exists and is not a directory', '--out', str(out))
    out.mkdir(parents=True, exist_ok=True)
    if args.scenario is None:
        if args.robots is None:
            raise ConfigError('give --scenario S.yaml or --robots N', '--scenario')
        if not (math.isfinite(args.duration) and args.duration > 0):
            raise ConfigError(f'must be > 0 (got {args.duration})', '--duration')
        scenario_path = out / f'formation_{args.robots}.yaml'  # (scenario.yaml: write_run's)
        scenario_path.write_text(formation_yaml(args.robots, args.duration))
    else:
        scenario_path = Path(args.scenario).resolve()
    scenario = load_scenario(str(scenario_path))
    ids = list(scenario.robot_ids)
    if args.robots is not None and args.robots != len(ids):
        raise ConfigError(f'{args.robots} robots asked, the scenario has {len(ids)}', '--robots')
    events = [parse_link_down(t, ids) for t in args.link_down]
    faults = parse_faults(args.fault, ids)
    shifts = clock_shift.parse_clock_shifts(args.clock_shift, ids)
    from ament_formation.tools.run_cmd import _free_domain_id

    # the robots' launchers take the lab network's domain ids only: ROS's safe range, 0..101
    domain = os.environ.get('AF_MULTIHOST_DOMAIN_ID') or _free_domain_id()
    net = netns.LabNetwork(ids, rate=args.rate)
    say = (lambda *a: None) if args.quiet else (lambda *a: print('multihost:', *a, flush=True))
    report: dict = {
        'scenario': scenario.name,
        'scenario_file': str(scenario_path),
        'robots': len(ids),
        'namespaces': {str(k): v for k, v in net.hosts.items()} | {'switch': net.switch},
        'ros_domain_id': int(domain),
        'profile': str(profile),
        'rate': args.rate,
        'clock_shift_s': {str(r): s for r, s in sorted(shifts.items())},
        'load_avg_start': os.getloadavg(),
    }
    procs: dict[str, _Proc] = {}
    stopping = {'signal': None}

    def on_signal(signum, frame):
        stopping['signal'] = signum
        raise KeyboardInterrupt

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    status = 1
    since = time.time()
    run = None
    try:
        net.build()
        say(f'namespaces {", ".join(net.made)} (domain {domain}, profile {profile.name})')
        run = _Run(args, out, scenario, scenario_path, ids, events, net, profile, domain, procs,
                   report, say, faults, shifts)  # fmt: skip
        run.execute()
        status = run.evaluate()
    except KeyboardInterrupt:
        status = 130 if stopping['signal'] != signal.SIGTERM else 143
    finally:
        for name in sorted(procs, key=lambda n: (n == 'world', n == 'recorder')):
            procs[name].stop()
        failed = net.destroy()
        if run is not None and shifts:
            report['clock_shm_removed'] = clock_shift.remove_shm(run.faketime_pids(), since)
        for s, h in old.items():
            signal.signal(s, h)
        left = net.leftovers()
        report['namespaces_left'] = left
        (out / 'multihost.json').write_text(json.dumps(_plain(report), indent=1) + '\n')
        if failed or left:
            print(f'formation multihost: namespaces not removed: {failed or left}',
                  file=sys.stderr)  # fmt: skip
            status = status or 1
    return status


class _Run:
    def __init__(self, args, out, scenario, scenario_path, ids, events, net, profile, domain,
                 procs, report, say, faults=(), shifts=None):  # fmt: skip
        self.args, self.out, self.scenario, self.scenario_path = args, out, scenario, scenario_path
        self.ids, self.events, self.net, self.profile = ids, events, net, profile
        self.domain, self.procs, self.report, self.say = domain, procs, report, say
        self.proc_dir = out / 'processes'
        self.proc_dir.mkdir(exist_ok=True)
        self.pty_dir = out / 'pty'
        self.mcap = out / 'run.mcap'
        self.rec_buf = b''
        self.rec_events: list[dict] = []
        self.start_s: float | None = None
        self.truth_t: float | None = None
        self.truth_wall: float | None = None
        self.first_state: dict[int, float] = {}
        self.modes: list[tuple[float, int, str]] = []  # (wall, robot, mode)
        self.samples: list[tuple[float, dict]] = []  # (wall, link counters)
        self.stop_reason: dict | None = None
        self.link_log: list[dict] = []
        self.faults = list(faults)
        self.split = {f[0] for f in faults}  # robots launched with --split
        self.fault_log: list[dict] = []
        self.shifts: dict[int, float] = dict(shifts or {})  # --clock-shift: robot -> seconds
        self.clock_hosts: dict[int, dict] = {}  # robot -> its faketime variables and probe
        self.wall0 = time.monotonic()

    # ---------------------------------------------------------------- processes
    def _env(self, host) -> dict:
        env = {
            k: v
            for k, v in os.environ.items()
            if k
            not in (
                'ROS_AUTOMATIC_DISCOVERY_RANGE',
                'ROS_STATIC_PEERS',
                'FASTRTPS_DEFAULT_PROFILES_FILE',
                'FASTDDS_DEFAULT_PROFILES_FILE',
                'AMENT_FORMATION_DDS',
                'ROS_LOCALHOST_ONLY',
                'AMENT_FORMATION_LOOPBACK_ONLY',  # inside the namespaces: the lab network
            )
        }
        env.update(
            ROS_DOMAIN_ID=str(self.domain),
            FASTRTPS_DEFAULT_PROFILES_FILE=str(self.profile),
            ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
            RMW_IMPLEMENTATION='rmw_fastrtps_cpp',
            ROS_LOG_DIR=str(self.out / 'ros_log' / str(host)),
            PYTHONUNBUFFERED='1',
        )
        return env

    def _start(self, name: str, host, argv: list[str], pipe: bool = False) -> _Proc:
        log = self.proc_dir / f'{name}.log'
        with open(log, 'w') as f:
            popen = subprocess.Popen(
                [*self.net.exec_prefix(host), *argv],
                stdout=subprocess.PIPE if pipe else f,
                stderr=f,
                env=self._env(host),
                cwd=str(self.out),
                start_new_session=True,
            )
        proc = _Proc(name, popen, log)
        self.procs[name] = proc
        return proc

    def _read_recorder(self, timeout_s: float) -> None:
        rec = self.procs['recorder'].popen
        ready, _, _ = select.select([rec.stdout], [], [], timeout_s)
        if not ready:
            return
        chunk = os.read(rec.stdout.fileno(), 65536)
        self.rec_buf += chunk
        *lines, self.rec_buf = self.rec_buf.split(b'\n')
        for line in lines:
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            self.rec_events.append(ev)
            kind = ev.get('ev')
            if kind == 'start' and self.start_s is None:
                self.start_s = float(ev['start_s'])
            elif kind == 't':
                if ev['t'] != self.truth_t:
                    self.truth_t, self.truth_wall = ev['t'], time.monotonic()
            elif kind == 'state':
                self.first_state.setdefault(int(ev['robot']), float(ev['wall']))
            elif kind == 'mode':
                self.modes.append((float(ev['wall']), int(ev['robot']), ev['mode']))

    def _wait(self, what: str, predicate, timeout_s: float, watch=()) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            for name in watch:
                if self.procs[name].poll() is not None:
                    raise _Abort(f'{name} exited with status {self.procs[name].rc} while '
                                 f'waiting for {what}; see {self.procs[name].log}')  # fmt: skip
            if time.monotonic() > deadline:
                raise _Abort(f'{what}: not within {timeout_s:g} s')
            if 'recorder' in self.procs:
                self._read_recorder(0.05)
            else:
                time.sleep(0.05)

    # ---------------------------------------------------------------- execute
    def execute(self) -> None:
        try:
            self._execute()
        except _Abort as err:
            self.stop_reason = {'name': 'multihost', 'detail': str(err)}
            self.say(f'FAILED: {err}')

    def _camera(self) -> Path:
        """The camera the world renders and the tracker reads: config/camera.yaml, or one fitted
        to a scenario it does not see (core/scenario/coverage.py, as launch_sim.sh does).
        """
        from ament_formation.core.scenario import coverage
        from ament_formation.core.vision.camera_model import load_camera_yaml, save_camera_yaml

        path = config_dir() / 'camera.yaml'
        setup = load_camera_yaml(path)
        if not coverage.needs_fitting(setup, self.scenario):
            return path
        fitted = coverage.fit_camera(setup, coverage.scenario_extent_m(self.scenario))
        out = save_camera_yaml(fitted, self.out / 'camera.yaml')
        self.say(f'the simulated camera is fitted to the scenario ({fitted.camera.width_px}x'
                 f'{fitted.camera.height_px} px): {out}')
        return out

    def _execute(self) -> None:
        a, sc = self.args, str(self.scenario_path)
        params = config_dir() / 'params'
        camera = self._camera()
        base_params = self.out / 'base_params.yaml'
        base_params.write_text('formation_tracker:\n  ros__parameters:\n'
                               f'    camera_config: {json.dumps(str(camera))}\n')
        self._start(
            'world',
            'camera',
            [_program('formation_world'), '--ros-args', '--params-file',
             str(params / 'formation_world.yaml'), '-p', f'scenario:={sc}',
             '-p', f'pty_dir:={self.pty_dir}', '-p', 'speed_factor:=1.0',
             '-p', f'camera_config:={camera}'],
        )  # fmt: skip
        self._start(
            'recorder',
            'camera',
            [sys.executable, '-m', 'ament_formation.tools.multihost_record', '--scenario', sc,
             '--out', str(self.mcap), *(['--all'] if a.record_all else [])],
            pipe=True,
        )  # fmt: skip
        self._start(
            'base',
            'camera',
            [str(script_file('launch_base.sh')), '--scenario', sc, '--run-dir',
             str(self.out / 'base'), '--domain', str(self.domain), '--params',
             str(base_params)],
        )  # fmt: skip
        self._wait(
            "the world's ptys",
            lambda: all((self.pty_dir / f'robot_{i}').exists() for i in self.ids),
            90.0,
            watch=('world', 'base', 'recorder'),
        )
        self._wait(
            'the recorder',
            lambda: any(e.get('ev') == 'ready' for e in self.rec_events),
            90.0,
            watch=('world', 'base', 'recorder'),
        )
        self._shift_clocks()
        launched = time.time()
        rt = [] if a.robot_rt is None else ['--rt-priority', str(a.robot_rt)]
        for rid in self.ids:
            shifted = self.clock_hosts.get(rid, {}).get('prefix', [])
            self._start(
                f'robot_{rid}',
                rid,
                [*shifted, str(script_file('launch_robot.sh')), '--id', str(rid), '--port',
                 str(self.pty_dir / f'robot_{rid}'), '--scenario', sc, '--run-dir',
                 str(self.out / f'robot_{rid}'), '--domain', str(self.domain), *rt,
                 *(['--params', a.robot_params] if a.robot_params else []),
                 *(['--split'] if rid in self.split else [])],
            )  # fmt: skip
        self.say(f'{len(self.ids)} robot hosts launched; waiting for the mission start')
        self.report['launched_wall'] = launched
        everyone = ('world', 'base', 'recorder', *(f'robot_{r}' for r in self.ids))
        self._wait('the mission start', lambda: self.start_s is not None,
                   a.startup_timeout, watch=everyone)  # fmt: skip
        self.say(f'mission start {self.start_s - launched:.2f} s after the robots were launched')
        self._profiles_in_use()
        self._mission(everyone)

    def _shift_clocks(self) -> None:
        """--clock-shift: the variables of each shifted robot host (tools/clock_shift.py) and its
        wall clock measured against ours by a probe run as its robot process will be.
        """
        if not self.shifts:
            return
        from ament_formation.tools import clock_shift

        fix = clock_shift.build_fix(self.out / 'clock')
        for rid, seconds in sorted(self.shifts.items()):
            variables = clock_shift.host_env(seconds, fix)
            prefix = clock_shift.env_prefix(variables)
            probe = clock_shift.measure_shift([*self.net.exec_prefix(rid), *prefix])
            self.clock_hosts[rid] = {'variables': variables, 'prefix': prefix, 'probe': probe}
            self.say(f'robot {rid}: wall clock {variables["FAKETIME"]} s (libfaketime), measured '
                     f'{_signed(probe["shift_s"])} (round trip {_s(probe["rtt_s"])})')  # fmt: skip
            if probe['shift_s'] is None or abs(probe['shift_s'] - seconds) > 0.01:
                raise _Abort(f'--clock-shift {rid}:{seconds:g}: the clock of its host reads '
                             f'{_signed(probe["shift_s"])} ahead ({probe.get("error", "")})')

    def faketime_pids(self) -> list[int]:
        """The processes that loaded libfaketime first on their host (see remove_shm)."""
        pids = [h['probe'].get('pid') for h in self.clock_hosts.values()]
        pids += [self.procs[f'robot_{r}'].popen.pid for r in self.clock_hosts
                 if f'robot_{r}' in self.procs]  # fmt: skip
        return [p for p in pids if p]

    def _profiles_in_use(self) -> None:
        """The Fast DDS profile each robot process really runs with (its /proc environment)."""
        used = {}
        for rid in self.ids:
            pid = _pid_of(self.out / f'robot_{rid}', self._process_name(rid))
            env = _environ(pid) if pid else {}
            used[str(rid)] = {
                'FASTRTPS_DEFAULT_PROFILES_FILE': env.get('FASTRTPS_DEFAULT_PROFILES_FILE'),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': env.get('ROS_AUTOMATIC_DISCOVERY_RANGE'),
                'ROS_DOMAIN_ID': env.get('ROS_DOMAIN_ID'),
                'FAKETIME': env.get('FAKETIME'),
                'LD_PRELOAD': env.get('LD_PRELOAD'),
            }
        self.report['robot_process_environment'] = used

    def _process_name(self, rid, part: str = 'controller') -> str:
        """The name of robot ``rid``'s process in its launcher's pids file (``part`` of a split
        robot: controller | bridge).
        """
        return f'{part}_{rid}' if rid in self.split else f'robot_{rid}'

    def _apply_faults(self, t: float, pending: list, frozen: list) -> None:
        """Hit the processes whose fault is due at scenario time ``t``; SIGCONT the frozen ones
        whose hold is over.
        """
        while pending and t >= pending[0][1]:
            rid, at_s, kind = pending.pop(0)
            part, sig = FAULT_KINDS[kind]
            name = self._process_name(rid, part)
            pid = _pid_of(self.out / f'robot_{rid}', name)
            if pid is None:
                raise _Abort(f'--fault {rid}:{at_s:g}:{kind}: no {name} in the pids file of '
                             f'robot {rid}')  # fmt: skip
            os.kill(pid, sig)
            ev = {'robot': rid, 'at_s': at_s, 'kind': kind, 'process': name, 'pid': pid,
                  'fault_wall': time.time()}  # fmt: skip
            ev['fault_t_s'] = ev['fault_wall'] - self.start_s
            self.fault_log.append(ev)
            if sig == signal.SIGSTOP:
                frozen.append(ev)
            self.say(f'robot {rid}: {kind} ({name}, pid {pid}) at t = {ev["fault_t_s"]:.2f} s')
        for ev in list(frozen):
            if time.time() >= ev['fault_wall'] + FAULT_HOLD_S:
                self._resume(ev)
                frozen.remove(ev)

    def _resume(self, ev: dict) -> None:
        try:
            os.kill(ev['pid'], signal.SIGCONT)
        except ProcessLookupError:
            pass
        ev['cont_wall'] = time.time()
        ev['cont_t_s'] = ev['cont_wall'] - self.start_s
        self.say(f'robot {ev["robot"]}: SIGCONT to {ev["process"]} at t = {ev["cont_t_s"]:.2f} s')

    def _launcher_gone_by_fault(self, name: str) -> bool:
        """A robot's launcher that exited because a fault killed one of its processes (it then
        stops the other: expected).
        """
        return any(
            f'robot_{ev["robot"]}' == name and FAULT_KINDS[ev['kind']][1] == signal.SIGKILL
            for ev in self.fault_log
        )

    def _mission(self, everyone) -> None:
        frozen: list[dict] = []
        try:
            self._mission_loop(everyone, frozen)
        finally:
            for ev in frozen:  # never leave a process stopped (its launcher could not stop it)
                self._resume(ev)
        for ev in self.fault_log:
            proc = self.procs.get(f'robot_{ev["robot"]}')
            if proc is not None and proc.poll() is not None:
                ev['launcher_exit_status'] = proc.rc
                ev['launcher_exit_after_s'] = round(proc.exited_wall - ev['fault_wall'], 3)

    def _mission_loop(self, everyone, frozen: list) -> None:
        a = self.args
        faults = sorted(self.faults, key=lambda f: f[1])
        pending = sorted(self.events, key=lambda e: e[1])
        down: list[dict] = []  # links currently down
        counters_at_start = None
        next_sample = 0.0
        while True:
            self._read_recorder(0.02)
            now = time.time()
            mono = time.monotonic()
            if counters_at_start is None and now >= self.start_s:
                counters_at_start = (now, self.net.counters())
                self.samples.append(counters_at_start)
                next_sample = mono + 0.5
            elif counters_at_start is not None and mono >= next_sample:
                self.samples.append((now, self.net.counters()))
                next_sample = mono + 0.5
            t = now - self.start_s  # scenario time (the world runs on the wall clock)
            self._apply_faults(t, faults, frozen)
            while pending and t >= pending[0][1]:
                rid, at_s, dur_s = pending.pop(0)
                self.net.set_link(rid, up=False)
                ev = {'robot': rid, 'at_s': at_s, 'duration_s': dur_s, 'down_wall': time.time()}
                ev['down_t_s'] = ev['down_wall'] - self.start_s
                self.link_log.append(ev)
                down.append(ev)
                self.say(f'robot {rid}: link down at t = {ev["down_t_s"]:.2f} s')
            for ev in list(down):
                wall = time.time()
                if a.dump_stacks and not ev.get('dumped') and wall >= ev['down_wall'] + 1.0:
                    ev['dumped'] = True
                    pid = _pid_of(self.out / f'robot_{ev["robot"]}', f'robot_{ev["robot"]}')
                    if pid:
                        os.kill(pid, signal.SIGUSR1)
                if wall >= ev['down_wall'] + ev['duration_s']:
                    self.net.set_link(ev['robot'], up=True)
                    ev['up_wall'] = time.time()
                    ev['up_t_s'] = ev['up_wall'] - self.start_s
                    down.remove(ev)
                    self.say(f'robot {ev["robot"]}: link up at t = {ev["up_t_s"]:.2f} s')
            world = self.procs['world'].poll()
            if world is not None:
                break
            dead = [
                n
                for n in everyone
                if n != 'world'
                and self.procs[n].poll() is not None
                and not self._launcher_gone_by_fault(n)
            ]
            if dead:
                raise _Abort(f'{dead[0]} exited with status {self.procs[dead[0]].rc} before the '
                             f'world finished; see {self.procs[dead[0]].log}')  # fmt: skip
            stalled_since = self.truth_wall or self.wall0
            if mono - stalled_since > a.stall_timeout and now > self.start_s:
                raise _Abort(f'no ground truth for {a.stall_timeout:g} s (a frozen process)')
        for ev in down:  # the run ended with a link still down
            self.net.set_link(ev['robot'], up=True)
            ev['up_wall'] = time.time()
            ev['up_t_s'] = ev['up_wall'] - self.start_s
        end = (time.time(), self.net.counters())
        self.samples.append(end)
        if counters_at_start is not None:
            self.report['traffic'] = _traffic(counters_at_start, end, self.ids)

    # ---------------------------------------------------------------- evaluate
    def evaluate(self) -> int:
        """Stop every process, then judge the recording; the exit status."""
        for name in [n for n in self.procs if n.startswith('robot_')] + ['base', 'recorder']:
            if name in self.procs:
                self.procs[name].stop()
        if 'recorder' in self.procs:
            self._read_recorder(0.0)
        wall_s = time.monotonic() - self.wall0
        self.report['discovery'] = self._discovery()
        self.report['link_events'] = self.link_log
        self.report['fault_events'] = self.fault_log
        self.report['load_avg_end'] = os.getloadavg()
        extra = []
        if self.stop_reason is not None:
            extra.append(_check(self.stop_reason['name'], False, None, None, '==',
                                self.stop_reason['detail']))  # fmt: skip
        else:
            extra.append(self._process_check())
        return self._judge(wall_s, extra)

    def _discovery(self) -> dict:
        launched = self.report.get('launched_wall')
        if launched is None:
            return {}
        up = {}
        for rid in self.ids:
            split = rid in self.split  # node up: the controller process's first log line
            for _sev, wall, _logger, message in _log_lines(
                self.out / f'robot_{rid}' / f'{self._process_name(rid)}.log',
                self.shifts.get(rid, 0.0),
            ):
                if split or message.startswith('hosting robots'):
                    up[rid] = wall
                    break
        running = {}
        if self.start_s is not None:
            for wall, rid, mode in self.modes:
                if mode not in ('hold', 'stopped') and wall >= self.start_s - 1e-3:
                    running.setdefault(rid, wall)
        per_robot = {
            str(rid): {
                'node_up_s': _rel(up.get(rid), launched),
                'heard_s': _rel(self.first_state.get(rid), launched),
                'discovery_s': _rel(self.first_state.get(rid), up.get(rid)),
                'running_s': _rel(running.get(rid), launched),
            }
            for rid in self.ids
        }
        delay = _coordinator_start_delay()
        return {
            'robots': per_robot,
            'all_heard_s': _max_or_none([r['heard_s'] for r in per_robot.values()]),
            'max_discovery_s': _max_or_none([r['discovery_s'] for r in per_robot.values()]),
            'mission_start_decided_s': None
            if self.start_s is None
            else self.start_s - delay - launched,
            'mission_start_s': None if self.start_s is None else self.start_s - launched,
            'all_running_s': _max_or_none([r['running_s'] for r in per_robot.values()]),
        }

    def _process_check(self) -> dict:
        world = self.procs.get('world')
        if world is None or world.rc is None:
            return _check('processes', False, None, 'world:0', '==', 'the world did not finish')
        if world.rc != 0:
            return _check('processes', False, f'world:{world.rc}', 'world:0', '==',
                          f'the world exited with status {world.rc}; see {world.log}')  # fmt: skip
        return _check('processes', True, 'world:0', 'world:0', '==')

    def _judge(self, wall_s: float, extra: list[dict]) -> int:
        from ament_formation.core.scenario.loader import ExpectSpec
        from ament_formation.core.sim.metrics import check_run, compute_metrics
        from ament_formation.core.sim.records import write_metrics, write_run
        from ament_formation.ros.run_record import load_run

        scenario = self.scenario
        if self.args.no_expect or self.events or self.faults:
            scenario = replace(scenario, expect=ExpectSpec())
            self.report['expect_checked'] = False
        else:
            self.report['expect_checked'] = not scenario.expect.empty
        stats: dict = {}
        try:
            result = load_run(self.mcap, scenario, stats=stats)
        except (ValueError, OSError) as err:
            extra.append(_check('recorded', False, None, None, '==', str(err)))
            metrics = {'scenario': scenario.name, 'sim_time_s': 0.0, 'wall_time_s': wall_s}
            check_run(metrics, scenario, extra=extra, measured=False)
            write_metrics(self.out, metrics)
            self.report['checks'] = metrics['checks']
            self.report['ok'] = False
            self._print(metrics)
            return 1
        result.wall_time_s = wall_s
        metrics = compute_metrics(result, scenario)
        metrics['wall_time_s'] = wall_s
        metrics['source'] = 'formation multihost (namespaced hosts, ground truth of the twin)'
        gap = stats.get('truth_max_gap_s')
        metrics['truth_max_gap_s'] = gap
        extra.append(
            _check('truth_gap_s', gap is not None and gap <= TRUTH_GAP_MAX_S, gap,
                   TRUTH_GAP_MAX_S, '<=', 'the recorded ground truth stops (a stalled world)')
        )  # fmt: skip
        for rid, spans in (stats.get('safety_stops') or {}).items():
            robot = metrics['robots'][str(rid)]
            robot['safety_stops'] = len(spans)
            robot['safety_stop_time_s'] = float(sum(b - a for a, b in spans))
        loops = control_loops(self.mcap, self.ids)
        self.report['control_loops'] = loops
        for rid in self.ids:
            if rid in self.split:
                continue  # its controller was killed or frozen on purpose (--fault)
            gap_s = (loops.get(str(rid)) or {}).get('max_gap_s')
            limit = self.args.control_gap_max
            extra.append(
                _check(f'control_gap_s[R{rid}]', gap_s is not None and gap_s <= limit,
                       gap_s, limit, '<=',
                       "the robot's control loop stalled (its diagnostics; none heard: None)")
            )  # fmt: skip
        traces = []
        for ev in self.link_log:
            trace = link_loss_trace(result, scenario, ev, self.out, self.modes,
                                    self.shifts.get(ev['robot'], 0.0))  # fmt: skip
            traces.append(trace)
            extra += trace.pop('checks')
        self.report['link_loss'] = traces
        boards = board_brakes(self.mcap, self.ids) if self.fault_log else {}
        faults = []
        for ev in self.fault_log:
            trace = fault_trace(result, scenario, ev, boards.get(ev['robot'], []), self.modes)
            faults.append(trace)
            extra += trace.pop('checks')
        self.report['faults'] = faults
        self.report['clock'], clock_checks = self._clocks()
        extra += clock_checks
        check_run(metrics, scenario, extra=extra)
        metrics['multihost'] = {
            k: self.report.get(k)
            for k in ('discovery', 'traffic', 'link_loss', 'faults', 'control_loops', 'clock')
        }
        write_run(self.out, result, scenario, metrics)
        if not self.args.no_figure:
            from ament_formation.core.sim.plot import render_figure

            render_figure(result, scenario, self.out / 'figure.png')
        self.report['checks'] = metrics['checks']
        self.report['ok'] = metrics['ok']
        self.report['settled_rms_m'] = {
            rid: r.get('formation_rms_settled_m') for rid, r in metrics['robots'].items()
        }
        self.report['final_error_m'] = {
            rid: r.get('final_error_m') for rid, r in metrics['robots'].items()
        }
        self.report['prohibited_entries'] = metrics.get('prohibited_entries')
        self.report['mission_end_s'] = metrics.get('mission_end_s')
        self._print(metrics)
        return 0 if metrics['ok'] else 1

    def _clocks(self) -> tuple[dict, list[dict]]:
        """Each robot's clock (its shift, the offsets its controller estimated, from its
        /diagnostics in the recording; its clock stop and why, from its log) and the checks: no
        robot stopped by its clock (``clock_stop[R<id>]``; the stop beyond the bound is the
        controlled stop a run with such a shift must end in, and a failed run all the same), and
        per shifted robot each camera PC source estimated within CLOCK_ERROR_MAX_S.
        """
        from ament_formation.core.clock import ClockParams
        from ament_formation.tools import clock_shift

        p = ClockParams()
        statuses = clock_shift.controller_status(self.mcap, self.ids)
        robots, checks = {}, []
        for rid in self.ids:
            log = self.out / f'robot_{rid}' / f'{self._process_name(rid)}.log'
            rec = clock_shift.robot_clock(rid, self.shifts, statuses.get(rid, []), self.start_s,
                                          log)  # fmt: skip
            host = self.clock_hosts.get(rid)
            if host is not None:
                rec['faketime'] = host['variables']['FAKETIME']
                rec['measured_shift_s'] = host['probe']['shift_s']
                rec['probe_rtt_s'] = host['probe']['rtt_s']
            rec['beyond_bound'] = abs(rec['shift_s']) > p.bound_s
            robots[str(rid)] = rec
            stop = rec['clock_stop']
            if stop is None:
                checks.append(_check(f'clock_stop[R{rid}]', True, 'none', 'none', '=='))
            else:
                checks.append(_check(
                    f'clock_stop[R{rid}]', False, None, 'none', '==',
                    f'stopped_clock at t = {stop["t_s"]} s: '
                    f'{stop["reason"] or "(no reason in its log)"}'))  # fmt: skip
            if rid not in self.shifts:
                continue
            for source in ('camera', 'coordinator'):
                est = rec['estimates'].get(source) or {}
                err = est.get('error_s')
                checks.append(_check(
                    f'clock_offset[R{rid}.{source}]', err is not None
                    and abs(err) <= CLOCK_ERROR_MAX_S, None if err is None else abs(err),
                    CLOCK_ERROR_MAX_S, '<=', f'no offset of {source} reported' if err is None
                    else f'|error|: estimated {est["estimated_offset_s"]:+.4f} s, true '
                    f'{est["true_offset_s"]:+.4f} s'))  # fmt: skip
        clock = {'bound_s': p.bound_s, 'deadband_s': p.deadband_s, 'window_s': p.window_s,
                 'error_max_s': CLOCK_ERROR_MAX_S, 'robots': robots}  # fmt: skip
        return clock, checks

    def _print(self, metrics: dict) -> None:
        if self.args.quiet:
            if not metrics.get('ok'):
                print(f'formation multihost: FAILED: {metrics.get("failure")}', file=sys.stderr)
            return
        print(summary(self.report))
        if metrics.get('robots'):
            from ament_formation.tools.sim_cmd import _summary

            print(_summary(metrics, self.out, figure=not self.args.no_figure,
                           first=('run.mcap', 'multihost.json')))  # fmt: skip
        if not metrics.get('ok'):
            print(f'formation multihost: FAILED: {metrics.get("failure")}', file=sys.stderr)


class _Abort(Exception):
    """The run cannot go on (a process died, a timeout): the reason."""


# ------------------------------------------------------------------------------- analysis
def _check(name, ok, value, limit, op, detail=None) -> dict:
    from ament_formation.core.sim.metrics import check

    return check(name, bool(ok), value, limit, op, detail)


def _rel(t, t0):
    return None if t is None or t0 is None else round(t - t0, 3)


def _max_or_none(values):
    values = [v for v in values if v is not None]
    return max(values) if values else None


def _coordinator_start_delay() -> float:
    """start_delay_s of config/params/formation_coordinator.yaml (what launch_base.sh passes)."""
    try:
        import yaml

        doc = yaml.safe_load((config_dir() / 'params' / 'formation_coordinator.yaml')
                             .read_text())  # fmt: skip
        return float(next(iter(doc.values()))['ros__parameters'].get('start_delay_s', 1.0))
    except (OSError, ValueError, KeyError, TypeError, StopIteration):
        return 1.0


def _traffic(first: tuple, last: tuple, ids) -> dict:
    """Bytes/s per link over the mission, from the switch port counters."""
    (t0, c0), (t1, c1) = first, last
    span = max(t1 - t0, 1e-9)
    links = {}
    for host in ['camera', *ids]:
        up = (c1[host][0] - c0[host][0]) / span
        dn = (c1[host][1] - c0[host][1]) / span
        links[str(host)] = {
            'from_host_Bps': round(up, 1),
            'to_host_Bps': round(dn, 1),
            'total_Bps': round(up + dn, 1),
        }
    robots = [links[str(r)]['total_Bps'] for r in ids]
    return {
        'window_s': round(span, 2),
        'links': links,
        'robot_link_mean_Bps': round(sum(robots) / len(robots), 1),
        'robot_link_max_Bps': max(robots),
    }


def control_loops(mcap: Path, ids) -> dict:
    """Per robot, from its controller's /diagnostics "robot_<id> control loop" and "control"
    statuses in the recording: the largest gap between two control periods, the stalls and the
    ticks and late ticks last reported.
    """
    from ament_formation.ros.recorder import read_messages

    out: dict = {str(r): {} for r in ids}
    try:
        for _topic, _t, msg in read_messages(mcap, ['/diagnostics']):
            for st in msg.status:
                m = re.match(r'.*: robot_(\d+) control( loop)?$', st.name)
                if not m or m.group(1) not in out:
                    continue
                values = {kv.key: kv.value for kv in st.values}
                rec = out[m.group(1)]
                if m.group(2):
                    gap = _num(values.get('max_gap_s'))
                    if gap is not None:
                        rec['max_gap_s'] = max(gap, rec.get('max_gap_s', 0.0))
                    rec['stalls'] = _num(values.get('stalls'))
                else:
                    rec['ticks'] = _num(values.get('ticks'))
                    rec['late_ticks'] = _num(values.get('late_ticks'))
    except (OSError, ValueError):
        pass
    return out


def _num(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def rest_trace(result, scenario, rid: int, t0: float, t1: float, hold_s=None) -> dict:
    """Robot ``rid`` from scenario time ``t0`` to ``t1`` in the ground truth: its point speed at
    ``t0``, the time [s] and path length [m] from ``t0`` until it is at rest for good (point speed
    below REST_SPEED_MPS from then until ``t1``; None when it never is), the largest speed after.
    ``hold_s``: at rest once the speed stays below REST_SPEED_MPS for ``hold_s`` instead; then also
    how far it drifted from that point until ``t1`` (the largest distance) and its largest speed.
    """
    import numpy as np

    k = list(result.robot_ids).index(rid)
    t = result.t_s
    x = result.state[:, k]
    d = scenario.robot(rid).params.com_offset_m
    speed = np.hypot(x[:, 3], d * x[:, 4])
    idx = np.flatnonzero((t >= t0) & (t <= t1))
    out: dict = {
        'speed_at_start_mps': None,
        'time_to_rest_s': None,
        'distance_to_rest_m': None,
        'max_speed_at_rest_mps': None,
    }
    if idx.size:
        i0 = idx[0]
        out['speed_at_start_mps'] = float(speed[i0])
        moving = np.flatnonzero(speed[idx] >= REST_SPEED_MPS)
        i_rest = idx[0] if not moving.size else (idx[moving[-1]] + 1)
        if hold_s is not None:
            i_rest = idx[-1] + 1
            slow = speed[idx] < REST_SPEED_MPS
            run_from = None
            for j, ok in enumerate(slow):
                if not ok:
                    run_from = None
                    continue
                run_from = j if run_from is None else run_from
                if t[idx[j]] - t[idx[run_from]] >= hold_s:
                    i_rest = idx[run_from]
                    break
        if i_rest <= idx[-1]:
            path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(x[:, :2], axis=0).T))])
            out['time_to_rest_s'] = float(t[i_rest] - t0)
            out['distance_to_rest_m'] = float(path[i_rest] - path[i0])
            i_end = idx[-1] + 1
            out['max_speed_at_rest_mps'] = float(np.max(speed[i_rest:i_end]))
            if hold_s is not None:
                drift = np.hypot(*(x[i_rest:i_end, :2] - x[i_rest, :2]).T)
                out['drift_after_rest_m'] = float(np.max(drift))
    return out


def board_brakes(mcap: Path, ids) -> dict:
    """Per robot, the brakes of its emulated board (the world's "board robot_<id>" /diagnostics
    in the recording): [{'cause', 'started_s', 'released_s'}] in world time [s], one per brake.
    """
    from ament_formation.ros.recorder import read_messages

    out: dict = {r: {} for r in ids}
    try:
        for _topic, _t, msg in read_messages(mcap, ['/diagnostics']):
            for st in msg.status:
                m = re.match(r'.*: board robot_(\d+)$', st.name)
                if not m or int(m.group(1)) not in out:
                    continue
                values = {kv.key: kv.value for kv in st.values}
                started = _num(values.get('brake_started_s'))
                if started is None:
                    continue
                rec = out[int(m.group(1))].setdefault(started, {'started_s': started})
                rec['cause'] = values.get('brake_cause')
                if rec['cause'] == 'stop':
                    rec.setdefault('stop_reason', values.get('last_stop_reason'))
                released = _num(values.get('brake_released_s'))
                if released is not None:
                    rec['released_s'] = released
    except (OSError, ValueError):
        pass
    return {r: sorted(v.values(), key=lambda b: b['started_s']) for r, v in out.items()}


def fault_trace(result, scenario, ev: dict, brakes: list, modes) -> dict:
    """What the robot whose controller or bridge process was hit (``--fault``) did, from the
    ground truth: times [s] from the fault, until the end of the run (a frozen controller: until
    its SIGCONT). Its board's first brake after the fault (the world's diagnostics: started by a
    STOP of the bridge or by the board's watchdog). Checks: at rest within FAULT_REST_MAX_S and
    FAULT_REST_MAX_M (docs/safety.md), and the board braked.
    """
    rid, kind = ev['robot'], ev['kind']
    t = result.t_s
    t0 = ev['fault_t_s']
    t1 = ev.get('cont_t_s', float(t[-1]))
    rest = rest_trace(result, scenario, rid, t0, t1, hold_s=FAULT_REST_HOLD_S)
    trace: dict = {
        'robot': rid,
        'kind': kind,
        'process': ev['process'],
        'fault_t_s': round(t0, 3),
        'until_t_s': round(t1, 3),
        'speed_at_fault_mps': rest['speed_at_start_mps'],
        'time_to_rest_s': rest['time_to_rest_s'],
        'distance_to_rest_m': rest['distance_to_rest_m'],
        'max_speed_after_rest_mps': rest['max_speed_at_rest_mps'],
        'drift_after_rest_m': rest.get('drift_after_rest_m'),
        'launcher_exit_after_s': ev.get('launcher_exit_after_s'),
        'launcher_exit_status': ev.get('launcher_exit_status'),
        'brake_cause': None,
        'stop_reason': None,  # a brake started by a STOP: input_stale | host_shutdown
        'brake_after_s': None,
        'brake_released_after_s': None,
    }
    w0 = ev['fault_wall']
    brake = next((b for b in brakes if b['started_s'] >= w0 - 0.005), None)
    if brake is not None:
        trace['brake_cause'] = brake.get('cause')
        trace['stop_reason'] = brake.get('stop_reason')
        trace['brake_after_s'] = _rel(brake['started_s'], w0)
        trace['brake_released_after_s'] = _rel(brake.get('released_s'), w0)
    if 'cont_wall' in ev:
        cont = ev['cont_wall']
        heard = [w for w, r, m in modes if r == rid and w >= cont and m not in ('hold', 'stopped')]
        trace['heard_running_after_cont_s'] = _rel(min(heard), cont) if heard else None
    name = f'fault[R{rid}@{ev["at_s"]:g}s {kind}]'
    rest_s, rest_m = trace['time_to_rest_s'], trace['distance_to_rest_m']
    trace['checks'] = [
        _check(f'{name}.at_rest_s', rest_s is not None and rest_s <= FAULT_REST_MAX_S, rest_s,
               FAULT_REST_MAX_S, '<=',
               f'not at rest (< {REST_SPEED_MPS} m/s) within {FAULT_REST_MAX_S} s of the fault'),
        _check(f'{name}.distance_to_rest_m', rest_m is not None and rest_m <= FAULT_REST_MAX_M,
               rest_m, FAULT_REST_MAX_M, '<=', 'rolled too far after the fault'),
        _check(f'{name}.board_brake', brake is not None, trace['brake_cause'], 'stop|watchdog',
               '==', "its board did not brake after the fault (the world's diagnostics)"),
    ]  # fmt: skip
    return trace


def link_loss_trace(result, scenario, ev: dict, out: Path, modes, shift_s: float = 0.0) -> dict:
    """What the robot that lost its link did, from the ground truth (SimResult on scenario time)
    and its controller's log, and what the others did meanwhile. Times [s] from the link going
    down. The robot must be at rest (point speed < REST_SPEED_MPS from then until the link came
    back), its controller must have entered a stopped state, and it must run again within
    REJOIN_MAX_S of the link coming back.
    """
    import numpy as np

    rid = ev['robot']
    ids = list(result.robot_ids)
    t = result.t_s
    t_down, t_up = ev['down_t_s'], ev.get('up_t_s', t[-1])
    win = (t >= t_down) & (t <= t_up)
    rest = rest_trace(result, scenario, rid, t_down, t_up)
    trace: dict = {
        'robot': rid,
        'down_t_s': round(t_down, 3),
        'up_t_s': round(t_up, 3),
        'speed_at_loss_mps': rest['speed_at_start_mps'],
        'time_to_rest_s': rest['time_to_rest_s'],
        'distance_to_rest_m': rest['distance_to_rest_m'],
        'max_speed_at_rest_mps': rest['max_speed_at_rest_mps'],
    }
    # the robot's own view: its controller's safety transitions (its log, wall clock)
    log = out / f'robot_{rid}' / f'robot_{rid}.log'
    down_w, up_w = ev['down_wall'], ev.get('up_wall', math.inf)
    stop_w = resume_w = None
    stop_state = None
    at_down = None  # the safety state in force when the link went down
    for _sev, wall, logger, message in _log_lines(log, shift_s):
        if 'formation_controller' not in logger or not message.startswith('safety:'):
            continue
        new = message.rsplit('->', 1)[-1].strip()
        if wall < down_w:
            at_down = new
            continue
        if stop_w is None and wall <= up_w and new.startswith(('stopped', 'hold')):
            stop_w, stop_state = wall, new
        elif resume_w is None and new == 'running' and wall >= up_w:
            resume_w = wall
    if at_down is not None and at_down.startswith(('stopped', 'hold')):
        stop_w, stop_state = down_w, at_down  # already stopped (e.g. late camera frames)
    trace['controller_state_at_loss'] = at_down
    trace['controller_stop'] = stop_state
    trace['controller_stop_after_s'] = _rel(stop_w, down_w)
    trace['controller_running_after_up_s'] = _rel(resume_w, up_w)
    heard = [w for w, r, m in modes if r == rid and w >= up_w and m not in ('hold', 'stopped')]
    trace['heard_running_after_up_s'] = _rel(min(heard), up_w) if heard else None
    # the others meanwhile: their modes (heard) and how far they went
    others = {}
    for j, other in enumerate(ids):
        if other == rid:
            continue
        seen = sorted({m for w, r, m in modes if r == other and down_w <= w <= up_w})
        xo = result.state[:, j]
        path = float(np.sum(np.hypot(*np.diff(xo[win][:, :2], axis=0).T))) if win.sum() > 1 else 0
        others[str(other)] = {'modes': seen, 'distance_m': round(path, 3)}
    trace['others'] = others
    name = f'link_loss[R{rid}@{ev["at_s"]:g}s]'
    trace['checks'] = [
        _check(f'{name}.controller_stop', stop_state is not None, stop_state, 'stopped|hold',
               '==', 'its controller did not stop while its link was down'),
        _check(f'{name}.at_rest_s', trace['time_to_rest_s'] is not None,
               trace['time_to_rest_s'], round(t_up - t_down, 3), '<=',
               f'not at rest (< {REST_SPEED_MPS} m/s) before its link came back'),
        _check(f'{name}.rejoined_s', trace['controller_running_after_up_s'] is not None
               and trace['controller_running_after_up_s'] <= REJOIN_MAX_S,
               trace['controller_running_after_up_s'], REJOIN_MAX_S, '<=',
               'its controller did not run again after the link came back'),
    ]  # fmt: skip
    return trace


def summary(report: dict) -> str:
    lines = []
    disc = report.get('discovery') or {}
    if disc:
        lines.append(
            f'discovery: every controller heard {_s(disc.get("all_heard_s"))} after the robot '
            f'hosts were launched (node up -> heard: at most {_s(disc.get("max_discovery_s"))}), '
            f'mission start decided {_s(disc.get("mission_start_decided_s"))}, every controller '
            f'running {_s(disc.get("all_running_s"))}'
        )
    tr = report.get('traffic')
    if tr:
        per = ', '.join(
            f'R{h} {v["total_Bps"] / 1e3:.1f} kB/s ({v["from_host_Bps"] / 1e3:.1f} out, '
            f'{v["to_host_Bps"] / 1e3:.1f} in)'
            for h, v in tr['links'].items()
            if h != 'camera'
        )
        lines.append(f'traffic per robot link over {tr["window_s"]:.1f} s: {per}')
    for ft in report.get('faults') or []:
        lines.append(
            f'fault R{ft["robot"]} {ft["kind"]} ({ft["process"]}) t = {ft["fault_t_s"]:.2f} s: '
            f'at rest after {_s(ft["time_to_rest_s"])} and {_m(ft["distance_to_rest_m"])} (from '
            f'{_m(ft["speed_at_fault_mps"])}/s); board brake ({ft["brake_cause"]}'
            + (f' {ft["stop_reason"]}' if ft['stop_reason'] else '')
            + f') after '
            f'{_s(ft["brake_after_s"])}, released after {_s(ft["brake_released_after_s"])}, '
            f'drift after rest {_m(ft["drift_after_rest_m"])}; '
            f'launcher exited after {_s(ft["launcher_exit_after_s"])}'
        )
    for lt in report.get('link_loss') or []:
        lines.append(
            f'link loss R{lt["robot"]} t = {lt["down_t_s"]:.2f}..{lt["up_t_s"]:.2f} s: controller '
            f'{lt["controller_stop"]} after {_s(lt["controller_stop_after_s"])}, at rest after '
            f'{_s(lt["time_to_rest_s"])} and {_m(lt["distance_to_rest_m"])} (from '
            f'{_m(lt["speed_at_loss_mps"])}/s), running again '
            f'{_s(lt["controller_running_after_up_s"])} after the link came back; others: '
            + ', '.join(
                f'R{r} {o["modes"]} {o["distance_m"]:.3f} m' for r, o in lt['others'].items()
            )
        )
    lines += clock_lines(report.get('clock') or {})
    loops = report.get('control_loops') or {}
    if loops:
        lines.append(
            'control loops: '
            + ', '.join(f'R{r} max gap {_s(v.get("max_gap_s"))}' for r, v in loops.items())
        )
    lines.append(f'load average {report.get("load_avg_start")} -> {report.get("load_avg_end")}')
    return '\n'.join(lines)


def clock_lines(clock: dict) -> list[str]:
    """One line per robot whose clock is shifted or that a clock stopped: its shift, the offsets
    its controller estimated (error from the truth), its clock stop and why.
    """
    lines = []
    for rid, rec in (clock.get('robots') or {}).items():
        if not rec.get('shift_s') and rec.get('clock_stop') is None:
            continue
        est = ', '.join(
            f'{src} {_signed(e["estimated_offset_s"])} (true {_signed(e["true_offset_s"])}, error '
            f'{_signed(e["error_s"])})'
            for src, e in rec['estimates'].items()
        )
        line = (f'clock R{rid}: shifted {_signed(rec["shift_s"])} (measured '
                f'{_signed(rec.get("measured_shift_s"))}); estimated offsets {est or "none"}')
        stop = rec.get('clock_stop')
        if stop is not None:
            line += f'; stopped_clock at t = {stop["t_s"]} s: {stop["reason"]}'
        lines.append(line)
    return lines


def _s(v) -> str:
    return 'n/a' if v is None else f'{v:.3f} s'


def _signed(v) -> str:
    return 'n/a' if v is None else f'{v:+.4f} s'


def _m(v) -> str:
    return 'n/a' if v is None else f'{v:.3f} m'


def _plain(value):
    from ament_formation.core.sim.metrics import json_ready

    return json_ready(value)
