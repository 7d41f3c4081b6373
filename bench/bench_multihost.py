"""Robots as separate hosts (issue 11): traffic per robot link, the paper scenario, link losses,
process faults.

    bench/run.sh bench_multihost.py [--traffic 2 4 8 [--state-rates 100 25]] [--paper]
        [--link-loss 3]
        [--link-variants default lab lab_nofix] [--faults 5 [--fault-kinds KIND ...]]
        [--duration 20] [--robot-rt P] [--quiet-load L [--quiet-wait S]] [--out DIR]
        [--json OUT.json]

Every run is `formation multihost` (tools/multihost_cmd.py; root, network namespaces): the camera
PC (world, tracker, coordinator, recorder) and each robot (launch_robot.sh --domain D) on a
host of its own, DDS over UDP only between them.

* ``--traffic N ...``: a generated formation of N robots (`--robots N`, 0.6 m grid, leader along
  +x, ``--duration`` s): bytes/s on each robot link over the mission (switch port counters, both
  directions), with the run's health (checks, world/control-loop gaps, safety stops) because a
  2-core machine may not hold N robots in real time.
* ``--paper``: config/scenarios/paper.yaml (55 s): settled RMS per robot, prohibited entries,
  final errors, the checks of the scenario's ``expect:``.
* ``--link-loss K``: K runs of test/data/paper_short.yaml with robot 1's link down at t = 4 s for
  3 s: its controller's stop, time and distance to rest (point speed < 5 mm/s, docs/safety.md),
  speed at the loss, rejoin, its control loop's longest gap. ``--link-variants``: default
  (config/fastdds_udp.xml: non-blocking sends), lab (test/data/fastdds_lab_udp.xml: Fast DDS's
  blocking sends, only the robot process's publish thread protects its control loop), lab_nofix
  (the same with AMENT_FORMATION_PUBLISH_THREAD=0: publishing as before the fix).
* ``--faults K``: K runs per fault kind of test/data/paper_short.yaml with robot 1 (launched
  with launch_robot.sh --split) hit at t = 4 s (`--fault 1:4:KIND`): controller-kill (SIGKILL to
  its controller process), controller-stop (SIGSTOP, SIGCONT 3 s later), bridge-kill (SIGKILL to
  its bridge process: the board's watchdog). Per run, from the ground truth: speed at the fault,
  time and distance from the fault to rest (point speed < 5 mm/s for 0.1 s, docs/safety.md), the
  drift after rest, the board's brake (STOP or watchdog, from the world's diagnostics) and when
  the launcher exited; then a table and the worst case per kind. The kinds alternate within a
  trial, so that a change of the machine's load hits them alike.

``--robot-rt P``: the robots' control loops under SCHED_FIFO P (launch_robot.sh --rt-priority), so
that on a loaded machine a control-loop gap is the network's, not the scheduler's.
``--quiet-load L``: each run starts once the 1-minute load average is below L (waiting at most
``--quiet-wait`` s). Prints one line per run with the load average; ``--json`` keeps everything.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
# link-loss variants: (Fast DDS profile, the robot process's publish thread on)
VARIANTS = {
    'default': (ROOT / 'config' / 'fastdds_udp.xml', True),
    'lab': (ROOT / 'test' / 'data' / 'fastdds_lab_udp.xml', True),
    'lab_nofix': (ROOT / 'test' / 'data' / 'fastdds_lab_udp.xml', False),  # as before the fix
}


QUIET = {'load': None, 'wait_s': 0.0, 'robot_rt': None}  # main() sets these


def wait_for_quiet() -> float:
    """Before a run: wait (at most QUIET['wait_s']) until the 1-minute load average is below
    QUIET['load'] (a machine shared with other work); the load average when the run starts.
    """
    if QUIET['load'] is None:
        return os.getloadavg()[0]
    deadline = time.monotonic() + QUIET['wait_s']
    while os.getloadavg()[0] >= QUIET['load'] and time.monotonic() < deadline:
        time.sleep(5.0)
    return os.getloadavg()[0]


def multihost(out: Path, *args: str, timeout_s: float = 900.0, env: dict | None = None) -> dict:
    """One `formation multihost` run; its multihost.json and metrics.json (+ exit status)."""
    wait_for_quiet()
    if QUIET['robot_rt'] is not None:
        args = (*args, '--robot-rt', str(QUIET['robot_rt']))
    t0 = time.monotonic()
    load0 = os.getloadavg()
    proc = subprocess.run(
        [sys.executable, '-m', 'ament_formation.tools.cli', 'multihost', '--out', str(out),
         '--no-figure', '--quiet', *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        cwd=str(ROOT),
        env={**os.environ, **(env or {})},
    )  # fmt: skip
    try:
        report = json.loads((out / 'multihost.json').read_text())
    except (OSError, ValueError):
        report = {}
    try:
        metrics = json.loads((out / 'metrics.json').read_text())
    except (OSError, ValueError):
        metrics = {}
    return {
        'status': proc.returncode,
        'stderr': proc.stderr.strip()[-2000:],
        'wall_s': round(time.monotonic() - t0, 1),
        'load_avg_before': load0,
        'load_avg_after': os.getloadavg(),
        'report': report,
        'metrics': metrics,
    }


def _health(run: dict) -> dict:
    rep, met = run['report'], run['metrics']
    robots = met.get('robots') or {}
    loops = rep.get('control_loops') or {}
    gaps = [v.get('max_gap_s') for v in loops.values() if v.get('max_gap_s') is not None]
    return {
        'ok': rep.get('ok'),
        'failure': met.get('failure'),
        'prohibited_entries': met.get('prohibited_entries'),
        'truth_max_gap_s': met.get('truth_max_gap_s'),
        'control_gap_max_s': max(gaps) if gaps else None,
        'safety_stop_time_s': {r: v.get('safety_stop_time_s') for r, v in robots.items()},
        'discovery': rep.get('discovery'),
    }


def _state_rate_params(out: Path, rate_hz: float) -> Path:
    """A robot parameters file sending the state at ``rate_hz``; 100 Hz as before issue 34's
    change: every period, used as heard up to 0.1 s (parent_timeout_s).
    """
    path = out / f'robot_params_{rate_hz:g}hz.yaml'
    fresh = 0.1 if rate_hz >= 100 else 0.0
    path.write_text('/**/formation_controller:\n  ros__parameters:\n'
                    f'    state_rate_hz: {float(rate_hz)}\n    parent_timeout_s: {fresh}\n')
    return path


def traffic_part(ns: list[int], duration_s: float, out: Path,
                 state_rates: list[float] | None = None) -> list[dict]:
    rows = []
    for n, rate in [(n, r) for n in ns for r in (state_rates or [None])]:
        extra = [] if rate is None else ['--robot-params', str(_state_rate_params(out, rate))]
        name = f'traffic_{n}' + ('' if rate is None else f'_{rate:g}hz')
        run = multihost(out / name, '--robots', str(n), '--duration', str(duration_s), *extra)
        tr = run['report'].get('traffic') or {}
        links = {h: v for h, v in (tr.get('links') or {}).items() if h != 'camera'}
        row = {
            'robots': n,
            'state_rate_hz': rate,
            'status': run['status'],
            'window_s': tr.get('window_s'),
            'per_link_total_Bps': {h: v['total_Bps'] for h, v in links.items()},
            'per_link_from_robot_Bps': {h: v['from_host_Bps'] for h, v in links.items()},
            'per_link_to_robot_Bps': {h: v['to_host_Bps'] for h, v in links.items()},
            'mean_Bps': tr.get('robot_link_mean_Bps'),
            'max_Bps': tr.get('robot_link_max_Bps'),
            'camera_link_Bps': (tr.get('links') or {}).get('camera', {}).get('total_Bps'),
            'load_avg': [run['load_avg_before'][0], run['load_avg_after'][0]],
            'wall_s': run['wall_s'],
            **_health(run),
        }
        rows.append(row)
        print(
            f'N={n}' + ('' if rate is None else f' state {rate:g} Hz')
            + f': robot link mean {_k(row["mean_Bps"])} max {_k(row["max_Bps"])} '
            f'(out/in per robot: '
            + ', '.join(
                f'R{h} {_k(row["per_link_from_robot_Bps"][h])}/'
                f'{_k(row["per_link_to_robot_Bps"][h])}'
                for h in row['per_link_total_Bps']
            )
            + f'), camera link {_k(row["camera_link_Bps"])}; ok={row["ok"]} '
            f'control gap max {row["control_gap_max_s"]} s, truth gap {row["truth_max_gap_s"]} s, '
            f'load {row["load_avg"][0]:.1f}->{row["load_avg"][1]:.1f}',
            flush=True,
        )
        if not row['ok']:
            print(f'   failure: {row["failure"]}', flush=True)
    return rows


def paper_part(out: Path) -> dict:
    run = multihost(out / 'paper', '--scenario', str(ROOT / 'config' / 'scenarios' / 'paper.yaml'))
    met = run['metrics']
    robots = met.get('robots') or {}
    row = {
        'status': run['status'],
        'settled_rms_m': {r: v.get('formation_rms_settled_m') for r, v in robots.items()},
        'final_error_m': {r: v.get('final_error_m') for r, v in robots.items()},
        'avoidance_entries': {r: v.get('avoidance_entries') for r, v in robots.items()},
        'min_clearance_m': met.get('min_clearance_m'),
        'load_avg': [run['load_avg_before'][0], run['load_avg_after'][0]],
        'wall_s': run['wall_s'],
        **_health(run),
    }
    print(
        f'paper: prohibited entries {row["prohibited_entries"]}, settled RMS '
        + ', '.join(f'R{r} {_mm(v)}' for r, v in row['settled_rms_m'].items())
        + ', final '
        + ', '.join(f'R{r} {_mm(v)}' for r, v in row['final_error_m'].items())
        + f', avoidance entries {row["avoidance_entries"]}, min clearance '
        f'{row["min_clearance_m"]}; ok={row["ok"]}; load {row["load_avg"][0]:.1f}',
        flush=True,
    )
    if not row['ok']:
        print(f'   failure: {row["failure"]}', flush=True)
    return row


def link_loss_part(trials: int, variants: list[str], out: Path) -> list[dict]:
    rows = []
    scenario = ROOT / 'test' / 'data' / 'paper_short.yaml'
    for k in range(trials):
        for profile in variants:
            xml, publish_thread = VARIANTS[profile]
            run = multihost(
                out / f'link_{profile}_{k}',
                '--scenario', str(scenario), '--link-down', '1:4:3', '--profile', str(xml),
                env={'AMENT_FORMATION_PUBLISH_THREAD': '1' if publish_thread else '0'},
            )  # fmt: skip
            traces = run['report'].get('link_loss') or [{}]
            tr = traces[0]
            loops = run['report'].get('control_loops') or {}
            row = {
                'profile': profile,
                'trial': k,
                'status': run['status'],
                'speed_at_loss_mps': tr.get('speed_at_loss_mps'),
                'state_at_loss': tr.get('controller_state_at_loss'),
                'controller_stop': tr.get('controller_stop'),
                'controller_stop_after_s': tr.get('controller_stop_after_s'),
                'time_to_rest_s': tr.get('time_to_rest_s'),
                'distance_to_rest_m': tr.get('distance_to_rest_m'),
                'max_speed_at_rest_mps': tr.get('max_speed_at_rest_mps'),
                'running_after_up_s': tr.get('controller_running_after_up_s'),
                'heard_running_after_up_s': tr.get('heard_running_after_up_s'),
                'r1_control_gap_s': (loops.get('1') or {}).get('max_gap_s'),
                'r0_control_gap_s': (loops.get('0') or {}).get('max_gap_s'),
                'r0_distance_m': (tr.get('others') or {}).get('0', {}).get('distance_m'),
                'r0_modes': (tr.get('others') or {}).get('0', {}).get('modes'),
                'publish_longest_s': _longest_publish(out / f'link_{profile}_{k}'),
                'load_avg': [run['load_avg_before'][0], run['load_avg_after'][0]],
                **_health(run),
            }
            rows.append(row)
            print(
                f'link loss [{profile} profile] trial {k}: R1 at {_f(row["speed_at_loss_mps"])} '
                f'm/s ({row["state_at_loss"]}), controller {row["controller_stop"]} after '
                f'{_f(row["controller_stop_after_s"])} s, at rest after '
                f'{_f(row["time_to_rest_s"])} s / {_f(row["distance_to_rest_m"])} m, running '
                f'{_f(row["running_after_up_s"])} s after the link came back; R1 control gap '
                f'{_f(row["r1_control_gap_s"])} s (longest rcl publish '
                f'{_f(row["publish_longest_s"])} s); R0 went {_f(row["r0_distance_m"])} m '
                f'{row["r0_modes"]}; ok={row["ok"]}, load {row["load_avg"][0]:.1f}',
                flush=True,
            )
            if not row['ok']:
                print(f'   failure: {row["failure"]}', flush=True)
    return rows


FAULT_KINDS = ['controller-kill', 'controller-stop', 'bridge-kill']


def fault_part(trials: int, kinds: list[str], out: Path) -> list[dict]:
    rows = []
    scenario = ROOT / 'test' / 'data' / 'paper_short.yaml'
    for k in range(trials):
        for kind in kinds:
            run_dir = out / f'fault_{kind}_{k}'
            # the subject is the faulted robot's stop: a loaded 2-core machine's few-hundred-ms
            # control-loop gaps of the other robot are not (test_multihost.py's limit)
            run = multihost(
                run_dir, '--scenario', str(scenario), '--fault', f'1:4:{kind}',
                '--control-gap-max', '1.0',
            )  # fmt: skip
            tr = (run['report'].get('faults') or [{}])[0]
            checks = [
                c for c in (run['report'].get('checks') or []) if c['name'].startswith('fault[')
            ]
            row = {
                'kind': kind,
                'trial': k,
                'status': run['status'],
                'speed_at_fault_mps': tr.get('speed_at_fault_mps'),
                'time_to_rest_s': tr.get('time_to_rest_s'),
                'distance_to_rest_m': tr.get('distance_to_rest_m'),
                'brake_cause': tr.get('brake_cause'),
                'stop_reason': tr.get('stop_reason'),
                'brake_after_s': tr.get('brake_after_s'),
                'brake_released_after_s': tr.get('brake_released_after_s'),
                'drift_after_rest_m': tr.get('drift_after_rest_m'),
                'max_speed_after_rest_mps': tr.get('max_speed_after_rest_mps'),
                'launcher_exit_after_s': tr.get('launcher_exit_after_s'),
                'heard_running_after_cont_s': tr.get('heard_running_after_cont_s'),
                'fault_checks_ok': bool(checks) and all(c['ok'] for c in checks),
                'load_avg': [run['load_avg_before'][0], run['load_avg_after'][0]],
                **_health(run),
            }
            rows.append(row)
            print(
                f'fault {kind} trial {k}: R1 at {_f(row["speed_at_fault_mps"])} m/s, board brake '
                f'({_cause(row)}) after {_f(row["brake_after_s"])} s, at rest after '
                f'{_f(row["time_to_rest_s"])} s / {_f(row["distance_to_rest_m"])} m, drift after '
                f'{_f(row["drift_after_rest_m"])} m; fault checks ok={row["fault_checks_ok"]}, '
                f'run ok={row["ok"]}, load {row["load_avg"][0]:.1f}',
                flush=True,
            )
            if not row['ok']:
                print(f'   failure: {row["failure"]}', flush=True)
                if run['stderr']:
                    print(f'   stderr: {run["stderr"][-300:]}', flush=True)
    print(fault_table(rows), flush=True)
    return rows


def fault_table(rows: list[dict]) -> str:
    """The markdown table of the fault runs and the worst case per kind."""
    lines = [
        '| kind | trial | speed at the fault | board brake (cause) | time to rest | distance to '
        'rest | drift after rest | load avg |',
        '|---|---|---|---|---|---|---|---|',
    ]
    for r in rows:
        lines.append(
            f'| {r["kind"]} | {r["trial"]} | {_f(r["speed_at_fault_mps"])} m/s | '
            f'{_f(r["brake_after_s"])} s ({_cause(r)}) | {_f(r["time_to_rest_s"])} s | '
            f'{_f(r["distance_to_rest_m"])} m | {_f(r["drift_after_rest_m"])} m | '
            f'{r["load_avg"][0]:.1f} |'
        )
    lines.append('')
    for kind in dict.fromkeys(r['kind'] for r in rows):
        mine = [r for r in rows if r['kind'] == kind]
        times = [r['time_to_rest_s'] for r in mine]
        dists = [r['distance_to_rest_m'] for r in mine]
        never = sum(v is None for v in times)
        worst_t = max((v for v in times if v is not None), default=None)
        worst_d = max((v for v in dists if v is not None), default=None)
        lines.append(
            f'worst case {kind} ({len(mine)} runs): at rest after {_f(worst_t)} s and '
            f'{_f(worst_d)} m'
            + (f'; NOT AT REST in {never} run(s)' if never else '')
            + f'; fault checks failed in {sum(not r["fault_checks_ok"] for r in mine)} run(s)'
        )
    return '\n'.join(lines)


def _cause(row: dict) -> str:
    """What started the board's brake: watchdog, or stop and the STOP's reason."""
    cause = str(row.get('brake_cause'))
    return f'{cause}: {row["stop_reason"]}' if row.get('stop_reason') else cause


def _longest_publish(run_dir: Path):
    """The robot process's own report of its longest rcl publish call (nodes/team.py)."""
    try:
        text = (run_dir / 'robot_1' / 'robot_1.log').read_text(errors='replace')
    except OSError:
        return None
    for line in text.splitlines():
        if 'publish thread:' in line and 'longest rcl publish' in line:
            try:
                return float(line.rsplit('longest rcl publish', 1)[1].split()[0])
            except (IndexError, ValueError):
                return None
    return None


def _k(v) -> str:
    return 'n/a' if v is None else f'{v / 1e3:.1f} kB/s'


def _mm(v) -> str:
    return 'n/a' if v is None else f'{v * 1e3:.1f} mm'


def _f(v) -> str:
    return 'n/a' if v is None else f'{v:.3f}'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--traffic', type=int, nargs='*', default=None, metavar='N')
    ap.add_argument('--paper', action='store_true')
    ap.add_argument('--link-loss', type=int, default=0, metavar='K')
    ap.add_argument(
        '--link-variants',
        nargs='+',
        choices=sorted(VARIANTS),
        default=['default', 'lab'],
        help='default: config/fastdds_udp.xml; lab: a lab profile with blocking sends; '
        'lab_nofix: the same without the robot process publish thread (as before the fix)',
    )
    ap.add_argument(
        '--state-rates',
        nargs='+',
        type=float,
        default=None,
        metavar='HZ',
        help="--traffic: each N once per rate the robots send their state at (the controller's "
        'state_rate_hz; 100: every period, as before issue 34); default: the params files',
    )
    ap.add_argument('--faults', type=int, default=0, metavar='K', help='K runs per fault kind')
    ap.add_argument('--fault-kinds', nargs='+', choices=FAULT_KINDS, default=FAULT_KINDS)
    ap.add_argument('--duration', type=float, default=20.0)
    ap.add_argument(
        '--quiet-load',
        type=float,
        default=None,
        metavar='L',
        help='before each run wait until the 1-minute load average is below L',
    )
    ap.add_argument('--quiet-wait', type=float, default=1800.0, metavar='S')
    ap.add_argument(
        '--robot-rt', type=int, default=None, metavar='P', help='robots at SCHED_FIFO priority P'
    )
    ap.add_argument('--out', type=Path, default=None)
    ap.add_argument('--json', type=Path, default=None)
    a = ap.parse_args()
    QUIET.update(load=a.quiet_load, wait_s=a.quiet_wait, robot_rt=a.robot_rt)
    out = a.out or Path(tempfile.mkdtemp(prefix='bench_multihost_'))
    out.mkdir(parents=True, exist_ok=True)
    report: dict = {
        'cpus': os.cpu_count(),
        'load_avg_start': os.getloadavg(),
        'out': str(out),
        'robot_rt': a.robot_rt,
        'quiet_load': a.quiet_load,
    }
    print(f'bench_multihost: runs in {out}; load average {os.getloadavg()}', flush=True)
    if a.traffic is not None:
        report['traffic'] = traffic_part(a.traffic or [2, 4, 8], a.duration, out, a.state_rates)
    if a.paper:
        report['paper'] = paper_part(out)
    if a.link_loss:
        report['link_loss'] = link_loss_part(a.link_loss, a.link_variants, out)
    if a.faults:
        report['faults'] = fault_part(a.faults, a.fault_kinds, out)
    report['load_avg_end'] = os.getloadavg()
    print(f'load average at the end {os.getloadavg()}', flush=True)
    if a.json:
        a.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
