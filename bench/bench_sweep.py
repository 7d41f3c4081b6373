"""Campaign throughput of `formation sweep` per engine, in one run on the same cases:
`bench/run.sh bench_sweep.py [--count 300] [--seed 1] [--engines ENGINE,..]`, engines
inprocess,dask,dask-scheduler,ray (the default).

inprocess       every case in this process, one after the other (the baseline: ratio 1)
dask            what `formation sweep` does by default: an embedded LocalCluster of --workers
                processes on 127.0.0.1, started and stopped inside the timing
dask-scheduler  the real programs: `dask scheduler` + `dask worker --nworkers 2` on 127.0.0.1
                (started before the timing), `formation sweep --scheduler` timed as a process
ray             ray.init(num_cpus=--workers) on 127.0.0.1 and ray.remote(run_case); only when
                ray is importable (it is not pinned: `pip install --target DIR ray` and
                PYTHONPATH=DIR to measure it)

Every engine must give the same rows as the baseline (wall time aside); the bench exits 1 when
one does not. Reported: runs/min, ratio to the baseline, start-up time, peak RSS of this process.
The machine's load average is printed: run it also beside two CPU-bound processes.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.core.scenario.families import FAMILIES  # noqa: E402
from ament_formation.core.sim.campaign import run_case  # noqa: E402

BIN = Path(sys.executable).parent
KEY = ('index', 'status', 'classes', 'min_clearance_m', 'min_robot_distance_m', 'peak_speed_mps')


def _key(rows):
    return sorted(tuple(r[k] for k in KEY) for r in rows)


def _typed(row: dict) -> dict:
    """A runs.csv row with KEY's numbers as numbers (as run_case returns them)."""
    out = dict(row)
    for k in KEY:
        v = row[k]
        if k == 'index':
            out[k] = int(v)
        elif k not in ('status', 'classes'):
            out[k] = None if v == '' else float(v)
    return out


def inprocess(cases, workers):
    return [run_case(c) for c in cases], 0.0


def dask_embedded(cases, workers):
    import logging

    from dask.distributed import Client, LocalCluster

    t0 = time.monotonic()
    scratch = tempfile.mkdtemp(prefix='af_bench_dask_')
    with LocalCluster(n_workers=workers, threads_per_worker=1, host='127.0.0.1',
                      dashboard_address='127.0.0.1:0', local_directory=scratch,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        start = time.monotonic() - t0
        rows = client.gather(client.map(run_case, cases, pure=False))
    shutil.rmtree(scratch, ignore_errors=True)
    return rows, start


def dask_scheduler(cases, workers, args):
    tmp = Path(tempfile.mkdtemp(prefix='af_bench_dask_sched_'))
    sched = tmp / 'scheduler.json'
    procs = []
    try:
        procs.append(subprocess.Popen(
            [str(BIN / 'dask'), 'scheduler', '--host', '127.0.0.1', '--port', '0',
             '--no-dashboard', '--scheduler-file', str(sched)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        while not sched.exists():
            time.sleep(0.1)
        procs.append(subprocess.Popen(
            [str(BIN / 'dask'), 'worker', '--scheduler-file', str(sched), '--nworkers',
             str(workers), '--nthreads', '1', '--host', '127.0.0.1', '--no-dashboard',
             '--local-directory', str(tmp)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        out = tmp / 'out'
        t0 = time.monotonic()
        subprocess.run(
            [str(BIN / 'formation'), 'sweep', '--out', str(out), '--count', str(args.count),
             '--seed', str(args.seed), '--scheduler-file', str(sched), '--no-plot', '--quiet'],
            check=False, timeout=3600)
        wall = time.monotonic() - t0
        import csv

        with open(out / 'runs.csv') as f:
            rows = [_typed(r) for r in csv.DictReader(f)]
        return rows, wall
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(timeout=30)
        shutil.rmtree(tmp, ignore_errors=True)


def ray_local(cases, workers):
    import ray

    t0 = time.monotonic()
    ray.init(num_cpus=workers, include_dashboard=False, _node_ip_address='127.0.0.1',
             log_to_driver=False, configure_logging=False)
    try:
        remote = ray.remote(run_case)
        ray.get(remote.remote(cases[0]))  # workers up (this case is counted again below)
        start = time.monotonic() - t0
        rows = ray.get([remote.remote(c) for c in cases])
    finally:
        ray.shutdown()
    return rows, start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--count', type=int, default=300)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--engines', default='inprocess,dask,dask-scheduler,ray')
    args = ap.parse_args()
    cases = [{'seed': args.seed, 'index': i, 'family': FAMILIES[i % len(FAMILIES)]}
             for i in range(args.count)]
    run_case(cases[0])  # compiled kernels loaded in this process before any timing
    print(f'{args.count} cases (seed {args.seed}), {args.workers} workers, '
          f'load average {os.getloadavg()[0]:.2f}')
    results, base, bad = {}, None, 0
    for engine in args.engines.split(','):
        if engine == 'ray':
            try:
                import ray  # noqa: F401
            except ImportError:
                print('ray: not importable here (not pinned); skipped')
                continue
        t0 = time.monotonic()
        if engine == 'dask-scheduler':
            rows, wall = dask_scheduler(cases, args.workers, args)
            start = float('nan')
        else:
            fn = {'inprocess': inprocess, 'dask': dask_embedded, 'ray': ray_local}[engine]
            rows, start = fn(cases, args.workers)
            wall = time.monotonic() - t0
        per_min = 60.0 * len(rows) / wall
        base = base or per_min
        same = base is None or 'inprocess' not in results or _key(rows) == results['inprocess']
        bad += not same
        results[engine] = _key(rows)
        print(f'{engine:>15}: {per_min:7.0f} runs/min  x{per_min / base:4.2f}  start-up '
              f'{start:5.1f} s  rows {"identical" if same else "DIFFER"}  '
              f'peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB')
    print(json.dumps({'load_average_end': os.getloadavg()[0]}))
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
