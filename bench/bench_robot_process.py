"""What one robot's computer spends on its robot (issue "Robots as separate hosts"):
run with `bench/run.sh bench_robot_process.py [options]`.

1. Cost per robot at 100 Hz, two layouts in the same run: robot 1 of the paper scenario (a
   follower: it hears its parent at full rate) started by scripts/launch_robot.sh as on a robot's
   computer, against its emulated motor board on a pty (`formation board`, another process, not
   counted), with what the lab sends it published from this process (camera poses of every robot
   at 30 fps, the parent's state and accel at 100 Hz, /formation/graph with the mission start):
     split  launch_robot.sh --split: a formation_bridge and a formation_controller process;
     robot  launch_robot.sh: one robot process (formation_team hosting both nodes).
   For each, idle and (``--quota``) with the robot's processes in a cgroup of their own with a
   CPU quota (default 25 % of one core: cgroup v2 cpu.max "25000 100000", or cgroup v1
   cpu.cfs_quota_us and cpu.rt_runtime_us 25000 per 100000 us; removed afterwards).
   Measured over a fixed window once the controller runs the mission:
     CPU %    utime + stime of the robot's processes from /proc/<pid>/stat, per 100 % of one core
     RSS      VmRSS of the robot's processes from /proc/<pid>/status (summed)
     late     late control ticks / ticks from the controller's /diagnostics (a tick more than
              1.5 periods after the previous one)
2. (``--paper``) The paper scenario (config/scenarios/paper.yaml, 55 s) through `formation run`
   with one robot process per robot, idle, next to two CPU-bound processes (``hogs``) and with each
   robot process under the quota: prohibited entries, settled formation RMS and avoidance entries
   per robot, and the controlled stops (``stopped_pose``) and outlier-rejected camera poses the
   controllers logged.

3. (``--profile PY_SPY``) where the robot process's time goes: py-spy (a sampling profiler, not a
   dependency of the project: ``pip install py-spy`` anywhere and give its path) records every
   process of the robot at 200 Hz, without pausing it (``--nonblocking``), over the window; the
   table gives each function's share of the samples, inclusive (it or a callee on the stack) and
   self (on top), for the threads that ran; the raw stacks are kept in the run folder
   (``profile_<layout>.txt``, collapsed format for flame graphs).

Options: --window-s S (default 15), --layouts split robot, --no-idle, --quota [PCT], --paper
[idle hogs quota], --rt-priority P (control loops under SCHED_FIFO P: launch_sim.sh
--control-rt), --control-nice N. The machine's other load is printed (load average): figures
from a shared machine are only comparable within one run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.core.control.agent import AgentParams  # noqa: E402
from ament_formation.tools.run_cmd import loopback_env  # noqa: E402

SCENARIO = ROOT / 'config' / 'scenarios' / 'paper.yaml'
HZ = os.sysconf('SC_CLK_TCK')


# ------------------------------------------------------------------ /proc
def cpu_ticks(pid: int) -> int:
    """Utime + stime of ``pid`` (all its threads) [clock ticks]; 0 once it is gone."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return 0
    fields = text[text.rindex(')') + 2:].split()
    return int(fields[11]) + int(fields[12])


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def read_pids(path: Path) -> dict[str, int]:
    """NAME -> PID from a launcher's pids file ("PID NAME" per line)."""
    if not path.exists():
        return {}
    out = {}
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) == 2:
            out[parts[1]] = int(parts[0])
    return out


# ------------------------------------------------------------------ cgroups
class CpuQuota:
    """A child cgroup with a CPU quota of ``pct`` % of one core (v2 cpu.max, else v1 cpu
    controller: CFS quota and, when the kernel groups real-time tasks, the same real-time runtime,
    so SCHED_FIFO threads are held to it too). :meth:`add` moves a process (all its threads) in;
    :meth:`remove` moves what is left back to the parent and deletes the group.
    """

    PERIOD_US = 100_000

    def __init__(self, name: str, pct: float):
        quota = int(self.PERIOD_US * pct / 100.0)
        v2 = Path('/sys/fs/cgroup/cgroup.controllers')
        if v2.exists() and 'cpu' in v2.read_text().split():
            self.parent = Path('/sys/fs/cgroup')
            sub = self.parent / 'cgroup.subtree_control'
            if 'cpu' not in sub.read_text().split():
                sub.write_text('+cpu')
            self.path = self.parent / name
            self.path.mkdir(exist_ok=True)
            (self.path / 'cpu.max').write_text(f'{quota} {self.PERIOD_US}')
        elif Path('/sys/fs/cgroup/cpu/cpu.cfs_quota_us').exists():
            self.parent = Path('/sys/fs/cgroup/cpu')
            self.path = self.parent / name
            self.path.mkdir(exist_ok=True)
            (self.path / 'cpu.cfs_period_us').write_text(str(self.PERIOD_US))
            (self.path / 'cpu.cfs_quota_us').write_text(str(quota))
            if (self.path / 'cpu.rt_runtime_us').exists():
                (self.path / 'cpu.rt_period_us').write_text(str(self.PERIOD_US))
                (self.path / 'cpu.rt_runtime_us').write_text(str(quota))
        else:
            raise SystemExit('no cgroup cpu controller found under /sys/fs/cgroup')

    def add(self, pid: int) -> None:
        (self.path / 'cgroup.procs').write_text(str(pid))

    def throttled(self) -> tuple[int, float]:
        """(periods throttled, seconds throttled) so far."""
        stat = {}
        try:
            for line in (self.path / 'cpu.stat').read_text().splitlines():
                k, v = line.split()
                stat[k] = int(v)
        except OSError:
            return 0, 0.0
        if 'throttled_usec' in stat:
            return stat.get('nr_throttled', 0), stat['throttled_usec'] * 1e-6
        return stat.get('nr_throttled', 0), stat.get('throttled_time', 0) * 1e-9

    def remove(self) -> None:
        try:
            for pid in (self.path / 'cgroup.procs').read_text().split():
                try:
                    (self.parent / 'cgroup.procs').write_text(pid)
                except OSError:
                    pass
            self.path.rmdir()
        except OSError:
            pass


# ------------------------------------------------------------------ diagnostics probe
class DiagProbe:
    """Latest controller diagnostics values per robot (ticks, late_ticks, safety)."""

    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from ament_formation.ros.qos import QOS_DIAGNOSTICS

        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('_bench_robot_probe', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.values: dict[str, dict] = {}
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on, QOS_DIAGNOSTICS)

    def _on(self, msg) -> None:
        for st in msg.status:
            if not st.name.startswith('formation_controller'):
                continue
            vals = {kv.key: kv.value for kv in st.values}
            if 'late_ticks' in vals and 'safety' in vals:
                robot = (st.hardware_id or st.name.split()[-1]).strip()
                self.values[robot] = {**vals, '_message': st.message, '_t': time.monotonic()}

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.05)

    def spin_until(self, pred, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if pred():
                return True
            self.ex.spin_once(timeout_sec=0.05)
        return pred()

    COUNTERS = ('ticks', 'late_ticks', 'camera_accepted', 'rejected_outlier', 'rejected_stale')

    def ticks(self) -> dict[str, tuple[int, ...]]:
        """Per robot: the :data:`COUNTERS` (ticks, late ticks, camera poses accepted /
        rejected).
        """
        return {k: tuple(int(v.get(c, 0)) for c in self.COUNTERS) for k, v in self.values.items()}

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


# ------------------------------------------------------------------ part 1: one robot's computer
PARENT_STATE_HZ = [AgentParams().state_rate_hz]  # main() sets it (--parent-state-hz)


class RobotInputs:
    """What a robot's computer receives from the rest of the lab, published from this process:
    its camera pose at 30 fps (``robot_<rid>/pose``, capture stamp 20 ms old), its parent's state
    and commanded acceleration at ``--parent-state-hz`` (default: the controllers'
    state_rate_hz, 100 Hz), the parent's camera pose and mode,
    ``/formation/graph`` with the mission start and the coordinator's (empty) decisions every
    second; plus a probe of the controllers' diagnostics.
    """

    def __init__(self, probe: DiagProbe, scenario: Path, rid: int):
        from geometry_msgs.msg import AccelStamped, PoseStamped
        import rclpy
        from std_msgs.msg import String

        from ament_formation.core.control.rewiring import FormationGraph
        from ament_formation.core.scenario.loader import load_scenario
        from ament_formation.ros import messages as m
        from ament_formation.ros.qos import QOS_CONTROL, QOS_GRAPH

        self.m, self.rid, self.probe = m, rid, probe
        self.node = rclpy.create_node('_bench_robot_inputs', context=probe.ctx)
        probe.ex.add_node(self.node)
        sc = load_scenario(scenario)
        fg = FormationGraph.from_scenario(sc)
        self.parent = fg.original_parent.get(rid)
        self.pose = {r.id: [float(v) for v in r.initial_pose] for r in sc.robots}
        n = self.node
        self.pub_pose = {
            k: n.create_publisher(PoseStamped, f'/robot_{k}/pose', QOS_CONTROL) for k in self.pose
        }
        self.pub_state = n.create_publisher(m.Odometry, f'/robot_{self.parent}/state', QOS_CONTROL)
        self.pub_accel = n.create_publisher(
            AccelStamped, f'/robot_{self.parent}/accel', QOS_CONTROL
        )
        self.pub_mode = n.create_publisher(String, f'/robot_{self.parent}/mode', QOS_CONTROL)
        self.pub_graph = n.create_publisher(String, '/formation/graph', QOS_GRAPH)
        # the coordinator's decisions (none) every second, as formation_coordinator republishes
        # them: without them the controller stops (stopped_coordinator, coordinator_timeout_s)
        self.pub_encounters = n.create_publisher(String, '/formation/encounters', QOS_GRAPH)
        now = self.now_s()
        parents = {r.id: fg.original_parent.get(r.id) for r in sc.robots}
        offsets = {
            c: tuple(float(v) for v in fg.offset(c, p))
            for c, p in parents.items()
            if p is not None
        }
        self.pub_graph.publish(
            m.graph_msg(
                m.GraphMessage(
                    revision=1, parents=parents, offsets_m=offsets, stamp_s=now, start_s=now + 2.0
                )
            )
        )
        self.ticks = 0
        n.create_timer(0.01, self._tick)

    def now_s(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def close(self) -> None:
        self.probe.ex.remove_node(self.node)
        self.node.destroy_node()

    def _tick(self) -> None:
        from geometry_msgs.msg import PoseStamped

        m, now = self.m, self.now_s()
        self.ticks += 1
        px, py, pth = self.pose[self.parent]
        stamp = m.stamp_from_s(now)
        if (self.ticks - 1) % max(1, round(100.0 / PARENT_STATE_HZ[0])) == 0:
            self.pub_state.publish(m.odometry([px, py, pth, 0.0, 0.0], stamp,
                                              f'robot_{self.parent}'))
            self.pub_accel.publish(m.accel_stamped([0.0, 0.0], stamp))
        if self.ticks % 3 == 0:  # the camera: 30 fps (every robot's pose, as the tracker sends)
            for k, (x, y, th) in self.pose.items():
                msg = PoseStamped()
                msg.header.frame_id = 'world'
                msg.header.stamp = m.stamp_from_s(now - 0.02)
                msg.pose.position.x, msg.pose.position.y = x, y
                msg.pose.orientation.z, msg.pose.orientation.w = math.sin(th / 2), math.cos(th / 2)
                self.pub_pose[k].publish(msg)
        if self.ticks % 100 == 1:
            self.pub_encounters.publish(m.encounters_msg(m.EncountersMessage(
                revision=1, assignments={}, rates={}, stamp_s=now)))
        if self.ticks % 100 == 0:
            self.pub_mode.publish(
                m.mode_msg(mode='coordination', target=None, direction=None, avoiding=False)
            )


def measure_cost(
    layout: str,
    quota_pct: float | None,
    window_s: float,
    tmp: Path,
    probe: DiagProbe,
    extra: list[str],
    scenario: Path = SCENARIO,
    rid: int = 1,
    py_spy: str | None = None,
) -> dict:
    """Robot ``rid`` of ``scenario`` on its own: its emulated motor board on a pty (`formation
    board`, not counted), scripts/launch_robot.sh (``split``: --split), inputs from
    :class:`RobotInputs`; CPU and RSS of the launcher's processes, late ticks from diagnostics.
    """
    run_dir = tmp / f'cost_{layout}_{"quota" if quota_pct else "idle"}'
    run_dir.mkdir(parents=True, exist_ok=True)
    link = run_dir / f'robot_{rid}.tty'
    board = subprocess.Popen(
        [str(ROOT / '.venv' / 'bin' / 'formation'), 'board', '--pty', '--link', str(link)],
        stdout=open(run_dir / 'board.log', 'w'),
        stderr=subprocess.STDOUT,
    )
    groups: list[CpuQuota] = []
    launch = None
    probe.values.clear()
    inputs = None
    try:
        probe.spin_until(lambda: link.exists() or board.poll() is not None, 60.0)
        cmd = [
            str(ROOT / 'scripts' / 'launch_robot.sh'),
            '--id',
            str(rid),
            '--port',
            str(link),
            '--scenario',
            str(scenario),
            '--run-dir',
            str(run_dir / 'robot'),
            '--loopback',
            *(['--split'] if layout == 'split' else []),
            *extra,
        ]
        launch = subprocess.Popen(
            cmd,
            stdout=open(run_dir / 'launch.out', 'w'),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        names = {'split': 2, 'robot': 1}[layout]
        probe.spin_until(
            lambda: (
                len(read_pids(run_dir / 'robot' / 'pids')) == names or launch.poll() is not None
            ),
            60.0,
        )
        pids = list(read_pids(run_dir / 'robot' / 'pids').values())
        if quota_pct:
            g = CpuQuota(f'af_bench_{os.getpid()}_robot_{rid}', quota_pct)
            groups.append(g)
            for pid in pids:
                g.add(pid)
        started = time.monotonic()

        def fresh(message=None) -> bool:  # diagnostics of this launch's controller
            return any(
                v['_t'] > started and (message is None or v['_message'] == message)
                for v in probe.values.values()
            )

        # the controller is up (diagnostics) before the mission start is published
        probe.spin_until(lambda: fresh() or launch.poll() is not None, 300.0)
        inputs = RobotInputs(probe, scenario, rid)
        ok = (
            probe.spin_until(lambda: fresh('running') or launch.poll() is not None, 60.0)
            and launch.poll() is None
        )
        if not ok:
            return {
                'layout': layout,
                'error': 'the controller did not run: '
                + str(
                    [
                        (v['_message'], v.get('camera_accepted'), v.get('odometry'))
                        for v in probe.values.values()
                    ]
                ),
            }
        probe.spin_for(2.0)
        spies = [subprocess.Popen(
            [py_spy, 'record', '--pid', str(pid), '--duration', str(int(math.ceil(window_s))),
             '--rate', '200', '--nonblocking', '--threads', '--format', 'raw', '--output',
             str(run_dir / f'profile_{layout}_{pid}.txt')],
            stdout=subprocess.DEVNULL, stderr=open(run_dir / f'py_spy_{pid}.log', 'w'))
            for pid in (pids if py_spy else [])]
        t0, c0, d0, thr0 = (
            time.monotonic(),
            sum(cpu_ticks(p) for p in pids),
            probe.ticks(),
            [g.throttled() for g in groups],
        )
        probe.spin_for(window_s)
        t1, c1 = time.monotonic(), sum(cpu_ticks(p) for p in pids)
        probe.spin_for(1.2)  # the diagnostics of the window's end (published every second)
        d1 = probe.ticks()
        key = next(iter(d1), None)
        delta = [b - a for a, b in zip(d0.get(key, ()), d1.get(key, ()))] or [0] * len(
            probe.COUNTERS
        )
        states = {v['_message'] for v in probe.values.values()}
        for spy in spies:
            spy.wait(timeout=60)
        thr = [
            (b[0] - a[0], round(b[1] - a[1], 3))
            for a, b in zip(thr0, (g.throttled() for g in groups))
        ]
        return {
            'layout': layout,
            'quota_pct': quota_pct,
            'window_s': t1 - t0,
            'throttled': thr,
            'safety': states,
            'profiles': sorted(run_dir.glob(f'profile_{layout}_*.txt')) if py_spy else [],
            'robots': {
                rid: {
                    'cpu_pct': 100.0 * (c1 - c0) / HZ / (t1 - t0),
                    'rss_mb': sum(rss_mb(p) for p in pids),
                    'ticks': delta[0],
                    'late': delta[1],
                    'camera': delta[2:],
                    'processes': len(pids),
                }
            },
        }
    finally:
        if inputs is not None:
            inputs.close()
        if launch is not None and launch.poll() is None:
            launch.send_signal(signal.SIGTERM)
            try:
                launch.wait(timeout=30)
            except subprocess.TimeoutExpired:
                launch.kill()
                launch.wait()
        board.send_signal(signal.SIGTERM)
        try:
            board.wait(timeout=10)
        except subprocess.TimeoutExpired:
            board.kill()
            board.wait()
        for g in groups:
            g.remove()


# ------------------------------------------------------------------ part 2
def profile_table(paths: list[Path], top: int = 25) -> str:
    """Functions by their share of the samples of py-spy's collapsed stacks (``frame;frame;...
    count`` per line, the thread first): inclusive and self, over every thread.
    """
    incl: dict[str, int] = {}
    own: dict[str, int] = {}
    total = 0
    for path in paths:
        for line in path.read_text(errors='replace').splitlines():
            stack, _, count = line.rpartition(' ')
            if not count.isdigit():
                continue
            n = int(count)
            total += n
            frames = [re.sub(r' \(([^)]*/)?([^/)]+)\)$', r' (\2)', f)  # file name, no folder
                      for f in stack.split(';')[1:]]
            for f in set(frames):
                incl[f] = incl.get(f, 0) + n
            if frames:
                own[frames[-1]] = own.get(frames[-1], 0) + n
    if not total:
        return '(no samples)'
    rows = [f'{"incl %":>7} {"self %":>7}  function (file:line)  [{total} samples]']
    for f, n in sorted(incl.items(), key=lambda kv: -kv[1])[:top]:
        rows.append(f'{100.0 * n / total:7.1f} {100.0 * own.get(f, 0) / total:7.1f}  {f}')
    rows.append('top self:')
    for f, n in sorted(own.items(), key=lambda kv: -kv[1])[:top // 2]:
        rows.append(f'{100.0 * n / total:7.1f}  {f}')
    return '\n'.join(rows)


def hog() -> subprocess.Popen:
    """A CPU-bound process (a busy loop) beside the system."""
    return subprocess.Popen([sys.executable, '-c', 'while True: pass'])


def paper_run(condition: str, quota_pct: float, tmp: Path, extra: list[str]) -> dict:
    out = tmp / f'paper_{condition}'
    cmd = [
        str(ROOT / '.venv' / 'bin' / 'formation'),
        'run',
        str(SCENARIO),
        '--out',
        str(out),
        '--team',
        '1',
        '--no-figure',
        '--quiet',
        '--startup-timeout',
        '400',
        *extra,
    ]
    hogs = [hog(), hog()] if condition == 'hogs' else []
    groups: list[CpuQuota] = []
    t0 = time.monotonic()
    run = subprocess.Popen(
        cmd,
        stdout=open(tmp / f'paper_{condition}.out', 'w'),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        moved: set[int] = set()
        while run.poll() is None:
            if condition == 'quota':
                for name, pid in read_pids(out / 'processes' / 'pids').items():
                    if name.startswith('team_') and pid not in moved:
                        g = CpuQuota(f'af_bench_{os.getpid()}_{name}', quota_pct)
                        groups.append(g)
                        g.add(pid)
                        moved.add(pid)
            time.sleep(0.2)
        rc = run.returncode
    finally:
        for h in hogs:
            h.kill()
            h.wait()
        if run.poll() is None:
            run.send_signal(signal.SIGTERM)
            run.wait(timeout=60)
        for g in groups:
            g.remove()
    res = {'condition': condition, 'rc': rc, 'wall_s': time.monotonic() - t0}
    mpath = out / 'metrics.json'
    if mpath.exists():
        m = json.loads(mpath.read_text())
        if 'robots' not in m:
            res['failure'] = m.get('failure')
            return res
        res['prohibited_entries'] = m['prohibited_entries']
        res['robots'] = {
            rid: {
                'rms_mm': (
                    float('nan')
                    if r['formation_rms_settled_m'] is None
                    else 1e3 * r['formation_rms_settled_m']
                ),
                'final_mm': 1e3 * r['final_error_m'],
                'entries': r['avoidance_entries'],
            }
            for rid, r in m['robots'].items()
        }
        if m.get('failure'):
            res['failure'] = m['failure']
    logs = ''.join(p.read_text(errors='replace') for p in (out / 'processes').glob('team_*.log'))
    res['stopped_pose'] = logs.count('-> stopped_pose')
    res['hold_parent'] = logs.count('-> hold_parent')
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--window-s', type=float, default=15.0)
    ap.add_argument('--layouts', nargs='+', choices=('split', 'robot'), default=['split', 'robot'])
    ap.add_argument('--no-idle', action='store_true', help='skip the runs without a quota')
    ap.add_argument(
        '--quota',
        type=float,
        nargs='?',
        const=25.0,
        default=None,
        metavar='PCT',
        help=(
            "also run with every robot's processes under a CPU quota of PCT %% of a core "
            '(default 25)'
        ),
    )
    ap.add_argument(
        '--paper',
        nargs='*',
        choices=('idle', 'hogs', 'quota'),
        default=None,
        help='paper scenario through `formation run --team 1` under these conditions',
    )
    ap.add_argument(
        '--rt-priority',
        type=int,
        default=None,
        metavar='P',
        help='control loops under SCHED_FIFO priority P (launch_sim.sh --control-rt)',
    )
    ap.add_argument('--control-nice', type=int, default=None, metavar='N')
    ap.add_argument('--parent-state-hz', type=float, default=PARENT_STATE_HZ[0], metavar='HZ',
                    help="the rate the parent's state and accel are sent at (default: the "
                    "controller's state_rate_hz)")
    ap.add_argument('--keep', action='store_true', help='keep the run folders')
    ap.add_argument('--profile', default=None, metavar='PY_SPY',
                    help='py-spy executable: profile the robot processes over the window')
    args = ap.parse_args()
    if not 0.1 <= args.parent_state_hz <= 100.0:
        ap.error('--parent-state-hz: expected a rate in [0.1, 100] Hz')
    PARENT_STATE_HZ[0] = args.parent_state_hz
    tmp = Path(tempfile.mkdtemp(prefix='ament_formation_bench_robot_'))
    loopback_env(tmp / 'ros_log')
    extra = ([] if args.rt_priority is None else ['--control-rt', str(args.rt_priority)]) + (
        [] if args.control_nice is None else ['--control-nice', str(args.control_nice)]
    )
    robot_extra = (
        [] if args.rt_priority is None else ['--rt-priority', str(args.rt_priority)]
    ) + (
        [] if args.control_nice is None else ['--nice', str(args.control_nice)]
    )  # launch_robot.sh
    if args.rt_priority is not None:
        os.environ['AF_CONTROL_RT_PRIORITY'] = str(
            args.rt_priority
        )  # formation run -> launch_sim.sh
    print(
        f'load average before: {os.getloadavg()}; {os.cpu_count()} cores; '
        f'options: {" ".join(extra) or "none"}'
    )
    try:
        conditions = ([] if args.no_idle else [None]) + ([args.quota] if args.quota else [])
        if conditions:
            if True:
                print(
                    f'{"layout":7} {"quota":>6} {"robot":>5} {"CPU %":>7} {"RSS MB":>7} '
                    f'{"ticks":>6} {"late":>5} '
                    f'{"late %":>7}  camera poses accepted/outlier/stale'
                )
                for q in conditions:
                    for layout in args.layouts:
                        probe = DiagProbe()  # a fresh participant per run: nothing carried over
                        try:
                            r = measure_cost(layout, q, args.window_s, tmp, probe, robot_extra,
                                             py_spy=args.profile)
                        finally:
                            probe.close()
                        if 'error' in r:
                            print(f'{layout:7} {q or "-":>6} {r["error"]}')
                            continue
                        for i, row in r['robots'].items():
                            pct = (
                                100.0 * row['late'] / row['ticks']
                                if row['ticks']
                                else float('nan')
                            )
                            print(
                                f'{layout:7} {q or "-":>6} {i:5d} {row["cpu_pct"]:7.1f} '
                                f'{row["rss_mb"]:7.0f} '
                                f'{row["ticks"]:6d} {row["late"]:5d} {pct:7.2f}  '
                                f'{"/".join(map(str, row["camera"]))}'
                            )
                        if r.get('profiles'):
                            print(profile_table(r['profiles']))
                        if r['throttled']:
                            print(f'        cgroup throttling in the window: {r["throttled"]}')
                        print(
                            f'        (window {r["window_s"]:.1f} s, '
                            f'load average {os.getloadavg()[0]:.1f})'
                        )
        for cond in args.paper or ():
            r = paper_run(
                cond,
                args.quota or 25.0,
                tmp,  # formation run: priority from the environment
                [] if args.control_nice is None else ['--control-nice', str(args.control_nice)],
            )
            robots = r.get('robots', {})
            if 'robots' not in r:
                print(f'paper {cond:6}: FAILED: {r.get("failure")}')
                continue
            print(
                f'paper {cond:6}: prohibited entries {r.get("prohibited_entries")}, settled RMS '
                + ', '.join(
                    f'R{k} {v["rms_mm"]:.1f} mm (final {v["final_mm"]:.0f} mm)'
                    for k, v in robots.items()
                )
                + ', avoidance entries '
                + ', '.join(f'R{k} {v["entries"]}' for k, v in robots.items())
                + f'; stopped_pose {r["stopped_pose"]}, '
                f'hold_parent {r["hold_parent"]} (rc {r["rc"]}, '
                f'{r["wall_s"]:.0f} s wall, load {os.getloadavg()[0]:.1f})'
                + (f'\n        run checks failed: {r["failure"]}' if r.get('failure') else '')
            )
    finally:
        if args.keep:
            print(f'run folders kept in {tmp}')
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
