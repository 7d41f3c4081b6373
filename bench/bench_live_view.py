"""Live-view benchmark:
`bench/run.sh bench_live_view.py [--scenario S.yaml] [--repeat N] [--json FILE]`.

Runs the simulated system (scripts/launch_sim.sh, every node a process) three ways:

  base     without the live view
  idle     with ``--live`` and no Foxglove client (the live view serves, nobody subscribes)
  client   with ``--live`` and an independent Foxglove client (test/js/live_client.mjs, Foxglove's
           @foxglove/ws-protocol under Node) subscribed to every channel for the whole run

and reports, for each: the CPU time of every process of the run together (the launcher's waited
children, getrusage), the live view process's own CPU time over its life ([s] and % of one core;
/proc/<pid>/stat sampled every 0.2 s), and with the client the messages/s, kB/s and message count
per channel as the client received them. The client's own CPU (Node) is reported apart: it stands
for the Foxglove app, which runs elsewhere.

Timings depend on the machine's load (the load average before and after each run is printed):
compare the rows of one invocation, not numbers across machines.
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
import threading
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'
CLIENT = ROOT / 'test' / 'js' / 'live_client.mjs'
TICKS = os.sysconf('SC_CLK_TCK')


def _cpu_s(pid: int) -> float | None:
    """Utime + stime [s] of a live process (None when gone)."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICKS


class ProcessSampler(threading.Thread):
    """Follows the live view process of a run folder: its last CPU sample and how long it lived."""

    def __init__(self, run_dir: Path, name: str = 'live_view'):
        super().__init__(daemon=True)
        self.run_dir, self.name = run_dir, name
        self.pid = None
        self.cpu_s = 0.0
        self.first_wall = self.last_wall = None
        self.url = None
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            if self.pid is None:
                pids = self.run_dir / 'pids'
                if pids.exists():
                    for line in pids.read_text().splitlines():
                        parts = line.split()
                        if len(parts) == 2 and parts[1] == self.name:
                            self.pid = int(parts[0])
            if self.pid is not None:
                cpu = _cpu_s(self.pid)
                if cpu is not None:
                    self.cpu_s = cpu
                    now = time.monotonic()
                    self.first_wall = self.first_wall or now
                    self.last_wall = now
                log = self.run_dir / f'{self.name}.log'
                if self.url is None and log.exists():
                    self.url = next(
                        (w for w in log.read_text().split() if w.startswith('ws://')), None
                    )
            self.stop.wait(0.2)


def _loadavg() -> str:
    return ' '.join(Path('/proc/loadavg').read_text().split()[:3])


def run_once(mode: str, scenario: Path, work: Path, max_wall_s: float) -> dict:
    """One run of the system in ``mode`` (base | idle | client), stopped after ``max_wall_s``."""
    run_dir = work / f'{mode}_{time.monotonic_ns()}'
    cmd = [
        str(ROOT / 'scripts' / 'launch_sim.sh'),
        str(scenario),
        '--run-dir',
        str(run_dir),
        '--duration',
        str(int(max_wall_s)),
    ]
    if mode != 'base':
        cmd += ['--live', '0']
    load_before = _loadavg()
    wall0 = time.monotonic()
    launch = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True
    )
    sampler = ProcessSampler(run_dir)
    sampler.start()
    client = None
    client_out = work / f'{mode}_client.jsonl'
    try:
        if mode == 'client':
            deadline = time.monotonic() + 300
            while sampler.url is None and launch.poll() is None and time.monotonic() < deadline:
                time.sleep(0.1)
            if sampler.url is None:
                raise RuntimeError(f'the live view did not start; see {run_dir}/live_view.log')
            with open(client_out, 'w') as out:
                client = subprocess.Popen(
                    ['node', str(CLIENT), '--url', sampler.url, '--timeout-s', '600', '--quiet'],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
        _pid, status, usage = os.wait4(launch.pid, 0)  # the launcher waited for every process
        launch.returncode = os.waitstatus_to_exitcode(status)
        client_usage = None
        if client is not None:
            try:
                _cpid, _cstatus, client_usage = os.wait4(client.pid, 0)
            finally:
                client.returncode = 0
    finally:
        sampler.stop.set()
        sampler.join()
        for proc in (launch, client):
            if proc is not None and proc.returncode is None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=30)
    world_log = run_dir / 'world.log'
    completed = world_log.exists() and 'finished at t' in world_log.read_text()
    row = {
        'mode': mode,
        'launch_status': launch.returncode,
        'completed': completed,
        'wall_s': time.monotonic() - wall0,
        'system_cpu_s': usage.ru_utime + usage.ru_stime,
        'load_before': load_before,
        'load_after': _loadavg(),
        'run_dir': str(run_dir),
    }
    if sampler.pid is not None and sampler.first_wall is not None:
        life = max(1e-6, sampler.last_wall - sampler.first_wall)
        row.update(
            live_view_cpu_s=sampler.cpu_s,
            live_view_life_s=life,
            live_view_core_pct=100.0 * sampler.cpu_s / life,
        )
    if client_usage is not None:
        row['client_cpu_s'] = client_usage.ru_utime + client_usage.ru_stime
        summary = next(
            (
                json.loads(line)
                for line in client_out.read_text().splitlines()
                if line.startswith('{"event":"summary"')
            ),
            None,
        )
        if summary is not None:
            span = max(1e-6, summary['elapsedS'])
            row['channels'] = {
                topic: {
                    'messages': n,
                    'rate_hz': summary['ratesHz'][topic],
                    'kB_per_s': summary['bytes'][topic] / 1000.0 / span,
                }
                for topic, n in sorted(summary['counts'].items())
            }
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', type=Path, default=SCENARIO)
    ap.add_argument('--repeat', type=int, default=1, help='runs of each mode (interleaved)')
    ap.add_argument('--modes', default='base,idle,client')
    ap.add_argument('--json', type=Path, default=None, help='also write the rows here')
    ap.add_argument(
        '--max-wall-s',
        type=float,
        default=600.0,
        help='stop a run that has not finished after this many wall seconds (start-up included)',
    )
    ap.add_argument(
        '--no-warmup',
        action='store_true',
        help='skip the first, unmeasured run (it loads or compiles the numba kernels)',
    )
    args = ap.parse_args(argv)
    if not CLIENT.parent.joinpath('node_modules').is_dir():
        subprocess.run(
            ['npm', 'ci', '--no-audit', '--no-fund', '--loglevel=error'],
            cwd=CLIENT.parent,
            check=True,
        )
    modes = [m.strip() for m in args.modes.split(',') if m.strip()]
    rows = []
    with tempfile.TemporaryDirectory(prefix='bench_live_view_') as tmp:
        if not args.no_warmup:
            row = run_once('base', args.scenario.resolve(), Path(tmp), args.max_wall_s)
            print(
                f'warm-up (not counted): {"done" if row["completed"] else "UNFINISHED"}, '
                f'wall {row["wall_s"]:.1f} s',
                flush=True,
            )
        for k in range(args.repeat):
            for mode in modes:
                row = run_once(mode, args.scenario.resolve(), Path(tmp), args.max_wall_s)
                row['repeat'] = k
                rows.append(row)
                print(
                    f'{mode:7s} {"done" if row["completed"] else "UNFINISHED"}  '
                    f'wall {row["wall_s"]:6.1f} s  '
                    f'system CPU {row["system_cpu_s"]:7.1f} s'
                    + (
                        f'  live view CPU {row["live_view_cpu_s"]:5.2f} s '
                        f'over {row["live_view_life_s"]:5.1f} s'
                        f' = {row["live_view_core_pct"]:5.1f} % of a core'
                        if 'live_view_cpu_s' in row
                        else ''
                    )
                    + (f'  (client {row["client_cpu_s"]:.2f} s)' if 'client_cpu_s' in row else '')
                    + f'  load {row["load_before"]} -> {row["load_after"]}',
                    flush=True,
                )
                for topic, c in row.get('channels', {}).items():
                    print(
                        f'          {topic:30s} {c["messages"]:5d} msgs  '
                        f'{c["rate_hz"]:6.2f} msg/s  '
                        f'{c["kB_per_s"]:7.1f} kB/s',
                        flush=True,
                    )
    for mode in modes:
        got = [r for r in rows if r['mode'] == mode and r['completed']]
        if got:
            cpu = sorted(r['system_cpu_s'] for r in got)[len(got) // 2]
            live = [r['live_view_core_pct'] for r in got if 'live_view_core_pct' in r]
            print(
                f'median {mode:7s}: system CPU {cpu:7.1f} s'
                + (f', live view {sorted(live)[len(live) // 2]:5.1f} % of a core' if live else '')
            )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
