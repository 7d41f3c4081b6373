"""`formation sim SCENARIO.yaml --out DIR` and `formation plot DIR`.

sim   runs the ROS-free vectorised closed loop (core/sim/simulator.py) on a scenario and writes the
run
      directory (core/sim/records.py): metrics.json, figure.png, trajectories.csv, obstacles.csv,
      events.json, run.json, scenario.yaml. A summary goes to stdout; progress of runs longer than
      about a second goes to stderr. The run is checked like `formation run`
      (core/sim/metrics.check_run:
      no prohibited entry, no contact, the scenario's ``expect:`` block); exit status 1 and one
      line
      on stderr naming the failed checks when it fails (metrics.json ``ok``/``checks`` say the
      same).
plot  redraws DIR/figure.png (or --output) from a run directory.

Bad input (scenario, options, run directory) raises ConfigError: the dispatcher prints one line
naming file, field and problem and exits with code 2.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import math
from pathlib import Path
import sys
import time

from ament_formation.core.errors import ConfigError
from ament_formation.tools.sensing_args import add_sensing_arguments, sensing_from_args


def register(subparsers) -> None:
    sim = subparsers.add_parser(
        'sim',
        help='run a scenario in the ROS-free closed-loop simulator',
        description='Run SCENARIO.yaml in the vectorised closed-loop simulator and write '
        'DIR/metrics.json, '
        'DIR/figure.png and the trajectories (CSV).',
    )
    sim.add_argument(
        'scenario', metavar='SCENARIO.yaml', help='scenario file (see README: scenario format)'
    )
    sim.add_argument(
        '--out', required=True, metavar='DIR', help='run directory to write (created)'
    )
    sim.add_argument(
        '--dt-s',
        type=float,
        default=0.001,
        metavar='S',
        help='integration and control period [s] (default 0.001)',
    )
    sim.add_argument(
        '--record-every-s',
        type=float,
        default=0.01,
        metavar='S',
        help='recording interval of the trajectories [s] (default 0.01)',
    )
    sim.add_argument(
        '--hold',
        type=float,
        default=0.0,
        metavar='S',
        help="run S s past the mission's end (every leader's reference at its end, at rest "
        'there; how formation sweep tells a stuck robot from a late one; default 0)',
    )
    sim.add_argument('--no-figure', action='store_true', help='skip figure.png')
    sim.add_argument('--quiet', action='store_true', help='no progress and no summary')
    add_sensing_arguments(sim)
    sim.set_defaults(func=run_sim)

    plot = subparsers.add_parser(
        'plot',
        help='redraw the figure of a finished run',
        description='Draw the Fig. 4-like figure of a run directory written by '
        '`formation sim` or `formation run`.',
    )
    plot.add_argument('run_dir', metavar='DIR', help='run directory')
    plot.add_argument('--output', metavar='PNG', help='figure file (default DIR/figure.png)')
    plot.set_defaults(func=run_plot)


def _positive(value: float, option: str) -> float:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f'must be a finite number > 0 (got {value})', option)
    return value


class _Progress:
    """Progress callback(t_s, duration_s) writing to ``stream`` at most every ``period_s``
    of wall time.

    Nothing is shown before ``delay_s`` of wall time, so short runs stay silent. A tty gets one
    line rewritten in place; a log file gets a line per update.
    """

    def __init__(self, stream, delay_s: float = 1.0, period_s: float = 0.5, clock=time.monotonic):
        self._stream = stream
        self._clock = clock
        self._start = clock()
        self._delay_s = delay_s
        self._period_s = period_s if stream.isatty() else 5.0
        self._next = self._start + delay_s
        self._tty = stream.isatty()
        self.shown = False

    def __call__(self, t_s: float, duration_s: float) -> None:
        now = self._clock()
        if now < self._next:
            return
        self._next = now + self._period_s
        frac = min(max(t_s / duration_s, 0.0), 1.0) if duration_s > 0 else 1.0
        elapsed = now - self._start
        eta = elapsed * (1.0 - frac) / frac if frac > 0 else float('nan')
        line = f'sim: t = {t_s:7.2f} / {duration_s:.1f} s ({100 * frac:5.1f} %), eta {eta:5.1f} s'
        if self._tty:
            self._stream.write('\r' + line)
        else:
            self._stream.write(line + '\n')
        self._stream.flush()
        self.shown = True

    def finish(self) -> None:
        if self.shown and self._tty:
            self._stream.write('\n')
            self._stream.flush()


def _summary(metrics: dict, out: Path, figure: bool = True, first: tuple[str, ...] = ()) -> str:
    """The run's summary lines; the last names what was written (``first`` + metrics.json,
    figure.png unless ``figure`` is false, trajectories.csv).
    """

    def fmt(value, unit='m', scale=1.0, digits=3):
        return 'n/a' if value is None else f'{value * scale:.{digits}f} {unit}'

    lines = [
        f'scenario {metrics["scenario"]}: {metrics["sim_time_s"]:.1f} s simulated in '
        f'{metrics["wall_time_s"]:.2f} s wall',
        *(
            []
            if 'ok' not in metrics
            else [
                f'  checks: {"OK" if metrics["ok"] else "FAILED"} '
                f'({sum(c["ok"] for c in metrics["checks"])}/'
                f'{len(metrics["checks"])} passed)'
                + ('' if metrics['ok'] else f': {metrics["failure"]}')
            ]
        ),
        f'  prohibited entries {metrics["prohibited_entries"]}, min clearance '
        f'{fmt(metrics["min_clearance_m"])}, min robot distance '
        f'{fmt(metrics["min_inter_robot_distance_m"])}',
    ]
    for rid, r in metrics['robots'].items():
        lines.append(
            f'  R{rid}: avoid {r["avoidance_entries"]}x {r["avoidance_time_s"]:.1f} s, '
            f'settled RMS {fmt(r["formation_rms_settled_m"], "mm", 1e3, 1)}, '
            f'final {fmt(r["final_error_m"], "mm", 1e3, 1)}, '
            f'peak torque {max(r["peak_torque_nm"]):.3f} N m, '
            f'saturated {100 * r["saturated_fraction"]:.1f} %'
            + (
                f', safety stops {r["safety_stops"]} ({r["safety_stop_time_s"]:.1f} s)'
                if 'safety_stops' in r
                else ''
            )
        )
    wrote = [
        *first,
        'metrics.json',
        *(['figure.png'] if figure else []),
        'trajectories.csv',
        '...',
    ]
    lines.append(f'  wrote {out}/ ({", ".join(wrote)})')
    return '\n'.join(lines)


def run_sim(args: argparse.Namespace) -> int:
    from ament_formation.core.scenario.loader import check_sim_budget, load_scenario
    from ament_formation.core.sim.metrics import check_run, compute_metrics
    from ament_formation.core.sim.records import write_run

    dt_s = _positive(args.dt_s, '--dt-s')
    record_s = _positive(args.record_every_s, '--record-every-s')
    if record_s < dt_s:
        raise ConfigError(f'must be >= --dt-s ({dt_s}) (got {record_s})', '--record-every-s')
    sensing = sensing_from_args(args)  # None: ideal sensing
    if sensing is not None and dt_s > 0.01:
        raise ConfigError(f'must be <= 0.01 with camera sensing (got {dt_s})', '--dt-s')
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError('exists and is not a directory', '--out', str(out))
    if not (math.isfinite(args.hold) and 0.0 <= args.hold <= 600.0):
        raise ConfigError(f'must be in [0, 600] (got {args.hold})', '--hold')
    scenario = load_scenario(args.scenario)
    # a run lasts at least its free traversal (duration_s) and the hold after the mission's end
    check_sim_budget(replace(scenario, duration_s=scenario.duration_s + args.hold), dt_s,
                     record_s, sensed=sensing is not None)

    from ament_formation.core.sim.simulator import simulate

    progress = None if args.quiet else _Progress(sys.stderr)
    try:
        if sensing is None:
            result = simulate(scenario, dt_s=dt_s, record_every_s=record_s, progress=progress,
                              hold_s=args.hold)
        else:
            from ament_formation.core.sim.sensed import simulate_sensed

            result = simulate_sensed(scenario, sensing, dt_s, record_s, progress=progress,
                                     hold_s=args.hold)
    finally:
        if progress is not None:
            progress.finish()
    metrics = check_run(compute_metrics(result, scenario), scenario)
    if sensing is not None:  # (an ideal run's metrics.json is as before)
        metrics['sensing'] = {'model': args.sensing, **result.sensing}
    write_run(out, result, scenario, metrics)
    if not args.no_figure:
        from ament_formation.core.sim.plot import render_figure

        render_figure(result, scenario, out / 'figure.png')
    if not args.quiet:
        print(_summary(metrics, out, figure=not args.no_figure))
    if not metrics['ok']:
        print(f'formation sim: FAILED: {metrics["failure"]}', file=sys.stderr)
        return 1
    return 0


def run_plot(args: argparse.Namespace) -> int:
    from ament_formation.core.sim.plot import render_figure
    from ament_formation.core.sim.records import read_run

    result, scenario, _metrics = read_run(args.run_dir)
    target = Path(args.output) if args.output else Path(args.run_dir) / 'figure.png'
    render_figure(result, scenario, target)
    print(f'wrote {target}')
    return 0
