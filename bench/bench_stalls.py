"""Stalls of the whole simulated system: the longest control and recording gap of each of N
whole-system runs (`formation run`), quiet and beside CPU-bound processes (issue 34).

Run with `bench/run.sh bench_stalls.py [--runs 20] [--hogs 2] [--scenario S] [--out DIR]
[-- FORMATION RUN OPTIONS]`, e.g. `-- --realtime-priority 0` for normal scheduling.

Quiet and loaded runs alternate (quiet, loaded, quiet, ...), so that whatever else the machine
does at the time weighs on both alike. Before each loaded run the bench starts --hogs processes
`python3 -c 'while 1: pass'`, each in a session of its own (as if started from other terminals:
the kernel gives every session one share of the CPU, so this is the harder case for the run), and
kills them by PID after it. For each run, from its metrics.json (docs/executors.md "The stall
found"):

  control     the longest pause of any robot's wheel torque commands, by the controller's stamps
              (stage_gaps_s.control_stamp) and as the recorder received them (control_gap_s)
  truth       of the twin's ground truth (its plant time: the world stopped)
  wheels      of the wheel states (the bridge, or the twin's emulated board)
  poses       of the tracker's camera poses (the world's camera or the tracker)
  recording   no truth, torque or wheel state message received by the recorder at all
  longest     the largest of these: a run passes when it is at most --threshold-s (0.2 s)

A run that did not produce metrics.json (killed at --run-timeout-s) counts as a failure.
Everything goes to OUT/stalls.json and OUT/<quiet|loaded>_<k>/; the table is printed at the end.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
FORMATION = str(ROOT / '.venv' / 'bin' / 'formation')
THRESHOLD_S = 0.2


def start_hogs(n: int) -> list[subprocess.Popen]:
    """``n`` CPU-bound processes, each in its own session."""
    return [
        subprocess.Popen(
            [sys.executable, '-c', 'while 1: pass'],
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(n)
    ]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for h in hogs:
        if h.poll() is None:
            os.kill(h.pid, signal.SIGKILL)
        h.wait()


def gaps_of(metrics: dict) -> dict:
    """The gaps [s] of one run (see the module docstring); None where the run has none."""
    stages = metrics.get('stage_gaps_s') or {}

    def worst(d):
        vals = [v for v in (d or {}).values() if v is not None]
        return max(vals) if vals else None

    out = {
        'control_stamp': worst(stages.get('control_stamp')),
        'control_received': worst(metrics.get('torque_max_gap_s')),
        'truth': metrics.get('truth_max_gap_s'),
        'wheels': worst(stages.get('wheel_state')),
        'poses': worst(stages.get('pose')),
        'recording': stages.get('recording'),
    }
    known = [v for v in out.values() if v is not None]
    out['longest'] = max(known) if len(known) == len(out) else None
    return out


def one_run(label: str, k: int, args, run_args: list[str]) -> dict:
    run_dir = Path(args.out) / f'{label}_{k:02d}'
    load0 = os.getloadavg()[0]
    hogs = start_hogs(args.hogs) if label == 'loaded' else []
    wall0 = time.monotonic()
    try:
        proc = subprocess.run(
            [FORMATION, 'run', str(args.scenario), '--out', str(run_dir), '--quiet', '--no-figure']
            + run_args,
            capture_output=True,
            text=True,
            timeout=args.run_timeout_s,
        )
        status, stderr = proc.returncode, proc.stderr.strip()
    except subprocess.TimeoutExpired:
        status, stderr = None, f'killed after {args.run_timeout_s:g} s'
    finally:
        stop_hogs(hogs)
    row = {
        'label': label,
        'k': k,
        'load_before': round(load0, 1),
        'wall_s': round(time.monotonic() - wall0, 1),
        'status': status,
        'stderr': stderr[-400:],
    }
    try:
        metrics = json.loads((run_dir / 'metrics.json').read_text())
    except (OSError, ValueError):
        row.update(ok=False, failure='no metrics.json', gaps={}, scheduling=None)
        return row
    row.update(
        ok=bool(metrics.get('ok')),
        failure=metrics.get('failure'),
        scheduling=metrics.get('scheduling'),
        gaps=gaps_of(metrics),
    )
    return row


def _fmt(v) -> str:
    return '–' if v is None else f'{v:.3f}'


def table(rows: list[dict], threshold_s: float) -> str:
    lines = [
        '| run | load | exit | control (stamp / received) | truth | wheels | poses | recording '
        '| longest | scheduling |',
        '|---|---|---|---|---|---|---|---|---|---|',
    ]
    for r in rows:
        g = r['gaps']
        longest = g.get('longest')
        mark = '' if longest is not None and longest <= threshold_s else ' **'
        lines.append(
            f"| {r['label']} {r['k']} | {r['load_before']} | {r['status']} | "
            f"{_fmt(g.get('control_stamp'))} / {_fmt(g.get('control_received'))} | "
            f"{_fmt(g.get('truth'))} | {_fmt(g.get('wheels'))} | {_fmt(g.get('poses'))} | "
            f"{_fmt(g.get('recording'))} | {_fmt(longest)}{mark} | {r['scheduling']} |"
        )
    for label in ('quiet', 'loaded'):
        sel = [r for r in rows if r['label'] == label]
        if not sel:
            continue
        over = [
            r
            for r in sel
            if r['gaps'].get('longest') is None or r['gaps']['longest'] > threshold_s
        ]
        longest = [r['gaps']['longest'] for r in sel if r['gaps'].get('longest') is not None]
        lines.append(
            f'\n{label}: {len(sel)} runs, {len(over)} with a gap over {threshold_s:g} s '
            f'(or no figures); longest gap of all {_fmt(max(longest) if longest else None)} s; '
            f'{sum(r["ok"] for r in sel)} passed every check of formation run'
        )
    return '\n'.join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--runs', type=int, default=20, help='runs per condition (default 20)')
    p.add_argument('--hogs', type=int, default=2, help='CPU-bound processes beside a loaded run')
    p.add_argument('--scenario', type=Path, default=ROOT / 'config' / 'scenarios' / 'paper.yaml')
    p.add_argument('--out', type=Path, default=Path('out') / 'bench_stalls')
    p.add_argument('--conditions', default='quiet,loaded', help='quiet,loaded (default both)')
    p.add_argument('--threshold-s', type=float, default=THRESHOLD_S)
    p.add_argument('--run-timeout-s', type=float, default=400.0)
    p.add_argument('run_args', nargs='*', help='options passed on to `formation run` (after --)')
    args = p.parse_args()
    labels = [c for c in args.conditions.split(',') if c]
    if not set(labels) <= {'quiet', 'loaded'} or args.runs < 1 or args.hogs < 0:
        print(
            'bench_stalls: --conditions is quiet and/or loaded, --runs >= 1, --hogs >= 0',
            file=sys.stderr,
        )
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    for k in range(args.runs):
        for label in labels:
            row = one_run(label, k, args, args.run_args)
            rows.append(row)
            g = row['gaps']
            print(
                f"{label} {k}: exit {row['status']}, longest gap {_fmt(g.get('longest'))} s "
                f"(control {_fmt(g.get('control_stamp'))}, truth {_fmt(g.get('truth'))}, "
                f"recording {_fmt(g.get('recording'))}), load {row['load_before']}, "
                f"{row['failure'] or 'ok'}",
                flush=True,
            )
            (args.out / 'stalls.json').write_text(json.dumps(rows, indent=1))
    print(table(rows, args.threshold_s))
    return 0


if __name__ == '__main__':
    sys.exit(main())
