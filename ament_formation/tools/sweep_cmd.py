"""`formation sweep --out DIR`: a Monte Carlo campaign of closed-loop runs.

Cases are random scenarios of declared families (core/scenario/families.py), seeded
perturbations of a given scenario (``--perturb SCENARIO.yaml``), or every scenario file of a
folder as it is (``--scenarios DIR``: your own, or another generator's); each runs in the fast
simulator (``--sensing ideal``, or camera sensing) and is classified
(core/sim/campaign.py). Engines:

* embedded (default): a Dask ``LocalCluster`` of ``--workers`` processes on 127.0.0.1, started and
  stopped by the command (``--workers 0``: every run in this process, no Dask);
* a cluster: ``--scheduler tcp://HOST:PORT`` (or ``--scheduler-file FILE``) of a running Dask
  scheduler whose workers can import ament_formation (the same version).

Writes DIR/runs.csv (one row per run), DIR/summary.json (class counts per family, throughput),
DIR/distributions.png and DIR/failures/*.yaml (each failing scenario, replayable with
`formation sim`, its reason on the first line). Exit status 1 when a run has a hard failure class,
0 otherwise; 2 for bad options.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
from pathlib import Path
import shutil
import signal
import sys
import tempfile
import time

from ament_formation.core.config_files import read_user_text
from ament_formation.core.errors import ConfigError
from ament_formation.core.sim.campaign import HOLD_S
from ament_formation.tools.sensing_args import SENSING_CHOICES as SENSING


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'sweep',
        help='Monte Carlo campaign: random or perturbed scenarios in the fast simulator',
        description='Run COUNT seeded random scenarios (or perturbations of one) in the fast '
        'simulator, in parallel, and write a table of every run, class counts, distributions and '
        'each failing scenario as a replayable YAML.',
    )
    p.add_argument('--out', required=True, metavar='DIR', help='campaign directory (created)')
    p.add_argument('--count', type=int, default=100, metavar='N', help='runs (default 100)')
    p.add_argument('--seed', type=int, default=0, metavar='S', help='campaign seed (default 0)')
    p.add_argument(
        '--families',
        default='formation,crossing,two_teams',
        metavar='F,..',
        help='families, taken in turn (default formation,crossing,two_teams)',
    )
    p.add_argument(
        '--perturb', metavar='SCENARIO.yaml', help='perturb this scenario instead of generating'
    )
    p.add_argument('--scale', type=float, default=1.0, help='perturbation size (default 1)')
    p.add_argument(
        '--scenarios',
        metavar='DIR',
        help='run every scenario file DIR/*.yaml as it is (sorted by name; --count and --families '
        'do not apply): a campaign of your own scenarios or of another generator',
    )
    p.add_argument(
        '--replay',
        metavar='CAMPAIGN',
        help="run again the failing runs of an earlier campaign's directory (its failures/, its "
        'seed and sensing): after a change of the law, what is fixed and what is not',
    )
    p.add_argument('--sensing', choices=SENSING, default='ideal', help='default ideal')
    p.add_argument(
        '--hold',
        type=float,
        default=HOLD_S,
        metavar='S',
        help='run a far_from_goal run again S s longer with the paths held at their end, to tell '
        f'a robot catching up from a stuck one (default {HOLD_S:g}; 0: off)',
    )
    p.add_argument(
        '--workers',
        type=int,
        default=None,
        metavar='K',
        help='embedded worker processes (default: CPU count; 0: run in this process)',
    )
    p.add_argument('--scheduler', metavar='ADDRESS', help='Dask scheduler, e.g. tcp://HOST:8786')
    p.add_argument('--scheduler-file', metavar='FILE', help="Dask scheduler's address file")
    p.add_argument('--no-plot', action='store_true', help='skip distributions.png')
    p.add_argument('--quiet', action='store_true', help='no progress and no summary')
    p.set_defaults(func=run_sweep)


# ------------------------------------------------------------------------------------------------
# Cases and engines
# ------------------------------------------------------------------------------------------------


def _cases(args) -> list[dict]:
    from ament_formation.core.scenario import families
    from ament_formation.core.scenario.loader import load_scenario, scenario_to_mapping

    if not 0 < args.count <= 1_000_000:
        raise ConfigError(f'must be in [1, 1000000] (got {args.count})', '--count')
    if not (math.isfinite(args.scale) and 0.0 < args.scale <= 10.0):
        raise ConfigError(f'must be in (0, 10] (got {args.scale})', '--scale')
    if not (math.isfinite(args.hold) and 0.0 <= args.hold <= 600.0):
        raise ConfigError(f'must be in [0, 600] (got {args.hold})', '--hold')
    given = [flag for flag, value in (('--replay', args.replay), ('--perturb', args.perturb),
                                      ('--scenarios', args.scenarios)) if value]
    if len(given) > 1:
        raise ConfigError(f'give one of {", ".join(given)}, not several', given[0])
    if args.replay:
        return _replayed(args)
    if args.scenarios:
        return _given(args)
    common = {'seed': args.seed, 'sensing': args.sensing, 'hold_s': args.hold}
    if args.perturb:
        base = scenario_to_mapping(load_scenario(args.perturb))
        return [
            {**common, 'index': i, 'family': 'perturbed', 'base': base, 'scale': args.scale}
            for i in range(args.count)
        ]
    names = [f.strip() for f in args.families.split(',') if f.strip()]
    for name in names:
        if name not in families.FAMILIES:
            raise ConfigError(
                f'unknown family {name[:40]!r} (one of {", ".join(families.FAMILIES)})',
                '--families',
            )
    if not names:
        raise ConfigError('names no family', '--families')
    return [{**common, 'index': i, 'family': names[i % len(names)]} for i in range(args.count)]


def _replayed(args) -> list[dict]:
    """The cases of ``--replay CAMPAIGN``: each ``failures/NNNNN-NAME.yaml`` of that campaign as
    given, with the campaign's seed, sensing and the run's index and family (so a camera run sees
    the same camera noise); ``args.seed`` and ``args.sensing`` become the campaign's.
    """
    from ament_formation.core.scenario.loader import load_scenario, scenario_to_mapping

    src = Path(args.replay)
    if Path(args.out).resolve() == src.resolve():
        raise ConfigError('must not be the campaign replayed', '--out', str(args.out))
    if not (src / 'summary.json').is_file():
        raise ConfigError('not a campaign directory (no summary.json)', '--replay', str(src))
    text = read_user_text(src / 'summary.json', 'campaign summary')
    try:
        summary = json.loads(text)
        args.seed, args.sensing = int(summary['seed']), str(summary['sensing'])
    except (ValueError, KeyError, TypeError, RecursionError) as err:
        raise ConfigError(
            f'not a campaign directory ({type(err).__name__} reading summary.json)', '--replay'
        ) from None
    if args.sensing not in SENSING:
        raise ConfigError(f'unknown sensing {args.sensing[:40]!r} in summary.json', '--replay')
    families = {}
    if (src / 'runs.csv').is_file():
        rows = read_user_text(src / 'runs.csv', 'campaign table', 1_000_000_000)
        try:
            families = {
                row.get('index'): row.get('family')
                for row in csv.DictReader(io.StringIO(rows, newline=''))
            }
        except csv.Error as err:
            raise ConfigError(f'malformed CSV: {err}', None, str(src / 'runs.csv')) from None
    cases = []
    for path in sorted((src / 'failures').glob('[0-9][0-9][0-9][0-9][0-9]-*.yaml')):
        index = int(path.name[:5])
        mapping = scenario_to_mapping(load_scenario(path))
        cases.append(
            {
                'mapping': mapping,
                'seed': args.seed,
                'index': index,
                'family': families.get(str(index)) or 'given',
                'sensing': args.sensing,
                'hold_s': args.hold,
            }
        )
    if not cases:
        raise ConfigError('has no failures/NNNNN-NAME.yaml to replay', '--replay', str(src))
    return cases


def _given(args) -> list[dict]:
    """The cases of ``--scenarios DIR``: every ``DIR/*.yaml`` as it is, in name order (index: its
    place in that order, family ``given``), each validated first: a file the validator refuses
    stops the campaign before any run, in one line naming the file.
    """
    from ament_formation.core.scenario.loader import load_scenario, scenario_to_mapping

    src = Path(args.scenarios)
    if not src.is_dir():
        raise ConfigError('is not a directory', '--scenarios', str(src))
    paths = sorted(src.glob('*.yaml'))
    if not paths:
        raise ConfigError('has no *.yaml scenario file', '--scenarios', str(src))
    common = {'seed': args.seed, 'sensing': args.sensing, 'hold_s': args.hold, 'family': 'given'}
    return [{**common, 'index': i, 'mapping': scenario_to_mapping(load_scenario(path))}
            for i, path in enumerate(paths)]


class _Stop:
    """SIGINT/SIGTERM while a campaign runs: remembered, and the campaign stops after the run in
    hand (Dask's client swallows a KeyboardInterrupt raised while it waits for results), keeping
    what is done.
    """

    def __init__(self):
        self.signal = None
        self._previous = {}

    def __enter__(self) -> '_Stop':
        for signum in (signal.SIGINT, signal.SIGTERM):
            self._previous[signum] = signal.signal(signum, self._on_signal)
        return self

    def _on_signal(self, signum, _frame) -> None:
        self.signal = signum

    def __exit__(self, *exc) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


def _serial(cases, on_row, stop: _Stop):
    from ament_formation.core.sim.campaign import run_case

    for case in cases:
        on_row(run_case(case))
        if stop.signal is not None:
            break
    return {'engine': 'in-process', 'workers': 1}


def _dask(cases, on_row, args, stop: _Stop):
    import logging

    import dask
    from dask.distributed import as_completed, Client, LocalCluster

    from ament_formation.core.sim.campaign import run_case

    cluster, scratch = None, None
    if args.scheduler or args.scheduler_file:
        client = Client(args.scheduler, scheduler_file=args.scheduler_file, timeout='30s')
        engine = {'engine': 'dask', 'scheduler': client.scheduler.address}
    else:
        scratch = tempfile.mkdtemp(prefix='af_sweep_dask_')
        dask.config.set({'temporary-directory': scratch})  # its lock files too, removed at the end
        cluster = LocalCluster(
            n_workers=args.workers,
            threads_per_worker=1,
            processes=True,
            host='127.0.0.1',
            dashboard_address='127.0.0.1:0',  # its HTTP server: loopback, any free port
            local_directory=scratch,
            silence_logs=logging.ERROR,
        )
        client = Client(cluster)
        engine = {'engine': 'dask-embedded', 'scheduler': cluster.scheduler_address}
    try:
        client.wait_for_workers(1, timeout=120)
        futures = client.map(run_case, cases, pure=False)
        for future in as_completed(futures):
            on_row(future.result())
            future.release()
            if stop.signal is not None:
                client.cancel(futures)
                break
        engine['workers'] = len(client.scheduler_info(n_workers=-1)['workers'])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    return engine


class _Progress:
    """Runs done, failed and the rate, on stderr: a tty line rewritten; else (a log file) a line
    per 10 % of the runs, and at least one every ``every_s`` seconds (a camera campaign's 10 %
    can take six minutes).
    """

    def __init__(self, total: int, quiet: bool, every_s: float = 60.0):
        self.total, self.quiet, self.every_s = total, quiet, every_s
        self.done = self.failed = 0
        self.t0 = time.monotonic()
        self.tty = sys.stderr.isatty()
        self._next_line = 0
        self._next_s = self.t0

    def __call__(self, row: dict) -> None:
        self.done += 1
        self.failed += row['status'] == 'fail'
        if self.quiet:
            return
        now = time.monotonic()
        due = self.done >= self._next_line or now >= self._next_s or self.done == self.total
        if not self.tty and not due:
            return
        self._next_line = self.done + max(self.total // 10, 1)
        self._next_s = now + self.every_s
        rate = self.done / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / rate
        line = (
            f'sweep: {self.done}/{self.total} runs, {self.failed} failed, '
            f'{60.0 * rate:.0f} runs/min, eta {eta:.0f} s'
        )
        sys.stderr.write(('\r' + line) if self.tty else line + '\n')
        if self.tty and self.done == self.total:
            sys.stderr.write('\n')
        sys.stderr.flush()


# ------------------------------------------------------------------------------------------------
# Outputs
# ------------------------------------------------------------------------------------------------


def _write_failure(out: Path, row: dict) -> str | None:
    import yaml

    if row['mapping'] is None:
        return None
    name = f'{row["index"]:05d}-{row["name"]}.yaml'
    text = (
        f'# formation sweep ({row["sensing"]} sensing): {row["reason"]}\n'
        f'# replay: formation sim failures/{name} {row.get("replay") or ""}'.rstrip()
        + ' --out RUN_DIR\n'
        + yaml.safe_dump(row['mapping'], sort_keys=False, default_flow_style=None)
    )
    (out / 'failures').mkdir(exist_ok=True)
    (out / 'failures' / name).write_text(text)
    return name


def _write_table(out: Path, rows: list[dict]) -> None:
    from ament_formation.core.sim.campaign import COLUMNS

    with open(out / 'runs.csv', 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=list(COLUMNS), extrasaction='ignore')
        writer.writeheader()
        for row in sorted(rows, key=lambda r: r['index']):
            writer.writerow(row)


def _plot(out: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from ament_formation.core.sim.campaign import distribution

    panels = (
        ('min_clearance_m', 'min clearance to P [m]', 0.0),
        ('min_robot_distance_m', 'min robot distance [m]', 0.20),
        ('settled_rms_max_m', 'settled RMS, worst robot [m]', None),
        ('mode_events_max', 'mode events, worst robot', 50),
        ('peak_speed_mps', 'peak speed [m/s]', 0.3),
        ('wall_s', 'wall time per run [s]', None),
    )
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    for ax, (column, title, limit) in zip(axes.flat, panels):
        values = distribution(rows, column)
        if values.size:
            ax.hist(values, bins=40, color='tab:blue')
        if limit is not None:
            ax.axvline(limit, color='tab:red', linestyle='--', label='failure limit')
            ax.legend(loc='upper right', fontsize=8)
        ax.set_title(f'{title} (n = {values.size})', fontsize=10)
        ax.set_yscale('log')
    fig.suptitle(f'formation sweep: {len(rows)} runs')
    fig.tight_layout()
    fig.savefig(out / 'distributions.png', dpi=90)
    plt.close(fig)


def _table(counts: dict) -> str:
    from ament_formation.core.sim.campaign import CLASSES

    keys = [k for k in counts if k != 'all'] + ['all']
    head = f'{"class":<14}' + ''.join(f'{k:>12}' for k in keys)
    lines = [head, f'{"runs":<14}' + ''.join(f'{counts[k]["runs"]:>12}' for k in keys)]
    lines.append(f'{"any hard":<14}' + ''.join(f'{counts[k]["hard"]:>12}' for k in keys))
    for c in CLASSES:
        lines.append(f'{c:<14}' + ''.join(f'{counts[k][c]:>12}' for k in keys))
    return '\n'.join(lines)


def run_sweep(args: argparse.Namespace) -> int:
    from ament_formation.core.sim.campaign import class_counts, quantiles

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError('exists and is not a directory', '--out', str(out))
    if args.workers is not None and not 0 <= args.workers <= 1024:
        raise ConfigError(f'must be in [0, 1024] (got {args.workers})', '--workers')
    if args.scheduler and args.scheduler_file:
        raise ConfigError('give --scheduler or --scheduler-file, not both', '--scheduler')
    cases = _cases(args)
    out.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(out / 'failures', ignore_errors=True)
    rows: list[dict] = []
    progress = _Progress(len(cases), args.quiet)

    def on_row(row: dict) -> None:
        row['failure_file'] = _write_failure(out, row) if row['status'] == 'fail' else None
        row['mapping'] = None
        rows.append(row)
        progress(row)

    t0 = time.monotonic()
    with _Stop() as stop:
        if args.workers == 0 and not (args.scheduler or args.scheduler_file):
            engine = _serial(cases, on_row, stop)
        else:
            args.workers = args.workers or os.cpu_count() or 1
            engine = _dask(cases, on_row, args, stop)
    interrupted = stop.signal is not None
    engine['interrupted_by_signal'] = stop.signal
    wall = time.monotonic() - t0
    counts = class_counts(rows)
    summary = {
        **engine,
        'runs': len(rows),
        'requested': len(cases),
        'seed': args.seed,
        'sensing': args.sensing,
        'families': sorted({r['family'] for r in rows}),
        'wall_s': wall,
        'runs_per_min': 60.0 * len(rows) / wall if wall > 0 else None,
        'counts': counts,
        'distributions': quantiles(rows),
        'failures': sorted(r['failure_file'] for r in rows if r['failure_file']),
    }
    _write_table(out, rows)
    (out / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    if rows and not args.no_plot:
        _plot(out, rows)
    hard = counts.get('all', {}).get('hard', 0)
    if not args.quiet and rows:
        print(_table(counts))
        print(
            f'{len(rows)} runs in {wall:.1f} s ({summary["runs_per_min"]:.0f} runs/min, '
            f'{engine["engine"]}, {engine.get("workers", "?")} workers); {hard} with a hard '
            f'failure; wrote {out}/ (runs.csv, summary.json'
            + (', distributions.png' if not args.no_plot else '')
            + (', failures/' if hard else '')
            + ')'
        )
    if interrupted:
        print(
            f'formation sweep: stopped by signal {stop.signal} after {len(rows)} of {len(cases)} '
            'runs (their results are written)',
            file=sys.stderr,
        )
        return 128 + stop.signal
    if hard:
        print(
            f'formation sweep: FAILED: {hard} of {len(rows)} runs with a hard failure class',
            file=sys.stderr,
        )
        return 1
    return 0
