"""Soak: many whole-system runs (`formation run`) with CPU-bound processes beside them.

Run with `bench/run.sh soak_run.py [--runs 20] [--hogs 2] [--quiet-runs 2] [--scenario S] [--out
DIR]`.

For each run it records the exit status, metrics.json's verdict (``ok``, ``failure``, ``checks``)
and figures, then reports:
  * frozen runs: a run whose world, recorder or controller stopped for seconds (the ``stalled``
    check failed, or the recorded ground truth or a robot's torque commands pause for more than
    --frozen-gap-s, 3 s) or that did not end on its own (killed at --run-timeout); must be 0.
    Shorter pauses (over the runs' own 1 s limit, the ``truth_gap_s``/``control_gap_s`` checks)
    are counted apart as hiccups: a starved machine, not a stopped process;
  * agreement: the exit status is 0 exactly when metrics.json says ``"ok": true``, and the one
    line `formation run` printed names metrics.json's ``failure``; must hold for every run;
  * the formation error under load next to the quiet runs (no hogs) and `formation sim` (the
    same scenario without ROS, deterministic): metrics.json's ``formation_rms_settled_m`` and,
    because a short scenario can end before its settled window (last avoidance exit + 10 s),
    the RMS of |p - g| from t = 10 s to the end per robot (``rms_from_10s_m``, from
    trajectories.csv) and the final error.
The --hogs processes (`while 1: pass`) are started here before the loaded runs and killed by PID
after them. Everything goes to OUT/soak.json and OUT/run_<k>/; the machine's load average is
recorded with each run (other work on the machine counts too).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FORMATION = str(ROOT / '.venv' / 'bin' / 'formation')
FROZEN_GAP_S = 3.0


def rms_from(run_dir: Path, t0_s: float = 10.0) -> dict:
    """{robot id: RMS [m] of |p - g| for t >= t0_s} from run_dir/trajectories.csv."""
    path = run_dir / 'trajectories.csv'
    if not path.exists():
        return {}
    with path.open() as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    if not len(data):
        return {}
    col = {name: k for k, name in enumerate(header)}
    t = data[:, col['t_s']]
    out = {}
    for name in header:
        if name.endswith('_goal_x_m'):
            rid = name[1: -len('_goal_x_m')]
            err = np.hypot(
                data[:, col[f'r{rid}_x_m']] - data[:, col[f'r{rid}_goal_x_m']],
                data[:, col[f'r{rid}_y_m']] - data[:, col[f'r{rid}_goal_y_m']],
            )
            window = t >= t0_s - 1e-9
            out[rid] = float(np.sqrt(np.mean(err[window] ** 2))) if np.any(window) else None
    return out


def one_run(k: int, scenario: Path, out: Path, label: str, args) -> dict:
    run_dir = out / f'run_{k:02d}'
    wall0 = time.monotonic()
    load0 = os.getloadavg()[0]
    try:
        proc = subprocess.run(
            [
                FORMATION,
                'run',
                str(scenario),
                '--out',
                str(run_dir),
                '--quiet',
                '--no-figure',
                '--startup-timeout',
                str(args.startup_timeout),
            ],
            capture_output=True,
            text=True,
            timeout=args.run_timeout,
        )
        rc, stderr, timed_out = proc.returncode, proc.stderr, False
    except subprocess.TimeoutExpired as err:  # subprocess.run killed it: counts as frozen
        rc, stderr, timed_out = (
            None,
            (err.stderr or b'').decode(errors='replace')
            if isinstance(err.stderr, bytes)
            else (err.stderr or ''),
            True,
        )
    wall = time.monotonic() - wall0
    row = {
        'run': k,
        'label': label,
        'rc': rc,
        'timed_out': timed_out,
        'wall_s': wall,
        'load_before': load0,
        'load_after': os.getloadavg()[0],
        'stderr_last': stderr.strip().splitlines()[-1] if stderr.strip() else '',
    }
    metrics_path = run_dir / 'metrics.json'
    if metrics_path.exists():
        m = json.loads(metrics_path.read_text())
        row.update(
            ok=m.get('ok'),
            failure=m.get('failure'),
            sim_time_s=m.get('sim_time_s'),
            truth_max_gap_s=m.get('truth_max_gap_s'),
            torque_max_gap_s=m.get('torque_max_gap_s'),
            failed_checks=[c['name'] for c in m.get('checks', []) if not c['ok']],
            settled_rms_m={
                rid: r.get('formation_rms_settled_m') for rid, r in m.get('robots', {}).items()
            },
            final_error_m={rid: r.get('final_error_m') for rid, r in m.get('robots', {}).items()},
            avoidance_entries={
                rid: r.get('avoidance_entries') for rid, r in m.get('robots', {}).items()
            },
            rms_from_10s_m=rms_from(run_dir),
        )
    else:
        row.update(ok=None, failure=None, failed_checks=[])
    classify(row, FROZEN_GAP_S)
    # agreement of the exit status and the one-line reason with metrics.json
    agree = row['ok'] is not None and (rc == 0) == bool(row['ok'])
    if agree and not row['ok']:
        agree = bool(row['failure']) and row['failure'] in row['stderr_last']
    row['agrees'] = bool(agree)
    print(
        f'{label} run {k:2d}: rc {rc}, ok {row["ok"]}, '
        f'sim {row.get("sim_time_s") or 0:5.1f} s in {wall:5.1f} s '
        f'wall, load {load0:4.1f}, frozen {row["frozen"]}, agrees {row["agrees"]}, rms>=10s '
        + ', '.join(
            f'R{r} {1e3 * v:.1f} mm'
            for r, v in (row.get('rms_from_10s_m') or {}).items()
            if v is not None
        )
        + ('' if row['ok'] else f' | {row["failure"] or row["stderr_last"]}'),
        flush=True,
    )
    return row


def classify(row: dict, frozen_gap_s: float) -> None:
    """Set row["frozen"] (see the module doc) and row["longest_pause_s"]."""
    gaps = [row.get('truth_max_gap_s') or 0.0, *((row.get('torque_max_gap_s') or {}).values())]
    row['longest_pause_s'] = max(gaps)
    row['frozen'] = bool(
        row['timed_out']
        or 'stalled' in row['failed_checks']
        or row['longest_pause_s'] > frozen_gap_s
    )


def figures(rows: list[dict], key: str) -> dict:
    """{robot id: [values]} of a per-robot figure over the rows."""
    out: dict[str, list] = {}
    for r in rows:
        for rid, v in (r.get(key) or {}).items():
            if v is not None:
                out.setdefault(rid, []).append(v)
    return out


def spread(values: list[float]) -> str:
    if not values:
        return 'n/a'
    v = 1e3 * np.asarray(values)
    return (
        f'median {np.median(v):.1f} mm, p90 {np.percentile(v, 90):.1f} mm, max {v.max():.1f} mm '
        f'(n = {len(v)})'
    )


def sim_reference(scenario: Path, out: Path) -> dict:
    ref = out / 'sim'
    subprocess.run(
        [FORMATION, 'sim', str(scenario), '--out', str(ref), '--quiet', '--no-figure'],
        capture_output=True,
        text=True,
        timeout=600,
    )
    m = json.loads((ref / 'metrics.json').read_text()) if (ref / 'metrics.json').exists() else {}
    return {
        'ok': m.get('ok'),
        'rms_from_10s_m': rms_from(ref),
        'settled_rms_m': {
            rid: r.get('formation_rms_settled_m') for rid, r in m.get('robots', {}).items()
        },
        'final_error_m': {rid: r.get('final_error_m') for rid, r in m.get('robots', {}).items()},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=20, help='loaded runs (default 20)')
    ap.add_argument(
        '--quiet-runs', type=int, default=2, help='runs without hogs first (default 2)'
    )
    ap.add_argument(
        '--hogs', type=int, default=2, help='CPU-bound processes beside the loaded runs'
    )
    ap.add_argument('--scenario', default=str(ROOT / 'test' / 'data' / 'paper_short.yaml'))
    ap.add_argument('--out', default=str(ROOT / 'out' / 'soak'))
    ap.add_argument(
        '--startup-timeout', type=float, default=300.0, help='formation run --startup-timeout'
    )
    ap.add_argument(
        '--run-timeout', type=float, default=900.0, help='kill a run after this many s (frozen)'
    )
    ap.add_argument(
        '--frozen-gap-s',
        type=float,
        default=FROZEN_GAP_S,
        help='a pause of the ground truth or torques longer than this is a frozen run [s]',
    )
    ap.add_argument(
        '--summarize', action='store_true', help='only print the summary of OUT/soak.json'
    )
    args = ap.parse_args()
    out = Path(args.out).resolve()
    if args.summarize:
        return summarize(json.loads((out / 'soak.json').read_text()), out, args)
    out.mkdir(parents=True, exist_ok=True)
    scenario = Path(args.scenario).resolve()
    report = {
        'scenario': str(scenario),
        'hogs': args.hogs,
        'started': time.strftime('%Y-%m-%d %H:%M:%S'),
        'sim': sim_reference(scenario, out),
        'rows': [],
    }
    rows = report['rows']
    for k in range(args.quiet_runs):
        rows.append(one_run(k, scenario, out, 'quiet ', args))
    # SIGTERM ends the soak through the finally below (the hogs are killed), as Ctrl-C does
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    hogs = [subprocess.Popen([sys.executable, '-c', 'while 1: pass']) for _ in range(args.hogs)]
    report['hog_pids'] = [h.pid for h in hogs]
    try:
        for k in range(args.quiet_runs, args.quiet_runs + args.runs):
            rows.append(one_run(k, scenario, out, 'loaded', args))
            (out / 'soak.json').write_text(json.dumps(report, indent=1))
    finally:
        for h in hogs:  # the hogs this script started, by PID
            h.kill()
            h.wait()
    return summarize(report, out, args)


def summarize(report: dict, out: Path, args) -> int:
    rows = report['rows']
    for r in rows:
        classify(r, args.frozen_gap_s)
    loaded = [r for r in rows if r['label'] == 'loaded']
    quiet = [r for r in rows if r['label'] != 'loaded']
    summary = {
        'loaded_runs': len(loaded),
        'frozen': sum(r['frozen'] for r in loaded),
        'ok': sum(bool(r['ok']) for r in loaded),
        'exit_status_agrees_with_metrics': sum(r['agrees'] for r in rows),
        'runs': len(rows),
        'hiccups': sum(not r['frozen'] and r['longest_pause_s'] > 1.0 for r in loaded),
        'not_started': sum('started' in r['failed_checks'] for r in loaded),
        'longest_pause_s': [round(r['longest_pause_s'], 2) for r in loaded],
        'failures': [r['failure'] or r['stderr_last'] for r in loaded if not r['ok']],
    }
    report['summary'] = summary
    (out / 'soak.json').write_text(json.dumps(report, indent=1))
    loads = [r['load_before'] for r in rows]
    print(
        f'\nsoak of {Path(report["scenario"]).name}: '
        f'{len(loaded)} runs with {report["hogs"]} hogs, '
        f'{len(quiet)} quiet runs '
        f'(load average before a run: {min(loads):.1f} to {max(loads):.1f})'
    )
    print(
        f'  frozen runs (a pause > {args.frozen_gap_s:g} s, a stall, a hang): '
        f'{summary["frozen"]} / {len(loaded)}; '
        f'hiccups (a pause of 1 to {args.frozen_gap_s:g} s): {summary["hiccups"]}; '
        'passed their checks: '
        f'{summary["ok"]} / {len(loaded)}; exit status agrees with metrics.json: '
        f'{summary["exit_status_agrees_with_metrics"]} / {len(rows)}; did not start within '
        f'--startup-timeout: {summary["not_started"]}'
    )
    print(f'  longest pause per loaded run [s]: {summary["longest_pause_s"]}')
    sim = report['sim']
    for key, what in (
        ('rms_from_10s_m', 'formation RMS from t = 10 s'),
        ('settled_rms_m', 'settled formation RMS'),
        ('final_error_m', 'final error'),
    ):
        print(f'  {what}:')
        ref = sim.get(key) or {}
        q, ld = figures(quiet, key), figures(loaded, key)
        for rid in sorted(set(ref) | set(q) | set(ld)):
            r = ref.get(rid)
            print(
                f'    R{rid}: sim {"n/a" if r is None else f"{1e3 * r:.1f} mm"}; '
                f'quiet {spread(q.get(rid, []))}; '
                f'loaded {spread(ld.get(rid, []))}'
            )
    for f in summary['failures']:
        print(f'  failed: {f}')
    return (
        0
        if summary['frozen'] == 0 and summary['exit_status_agrees_with_metrics'] == len(rows)
        else 1
    )


if __name__ == '__main__':
    sys.exit(main())
