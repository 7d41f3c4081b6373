"""The campaign's failure classes of a scenario through the ROS nodes (`formation run`: every node
as a process on the simulated twin, evaluated from the recorded ground truth) next to the fast
simulator's (`formation sweep`'s run of the same scenario, core/sim/campaign.py), for
config/scenarios/v_formation.yaml and generated two-team scenarios (issue 32).

    bench/run.sh bench_nodes_vs_sim.py [--two-teams SEED:INDEX ...] [--out DIR] [--team K]

For each scenario: the fast simulator's row (classes, reason, mission time over free traversal,
settled RMS, minimum robot distance and clearance, final error) and the same figures from the
run's recording (ros/run_record.py reads run.mcap into the simulator's SimResult, so the same
metrics and the same classification apply), plus `formation run`'s exit status and failed check.
The classes of a run through the nodes are judged without the campaign's held second run (a
`far_from_goal` there is not retried as `stuck`). Exit status 0 when every scenario has the same
hard classes both ways, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile

import yaml

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TWO_TEAMS = ('1:2', '2:5')


def _scenarios(two_teams: list[str], folder: Path) -> list[Path]:
    from ament_formation.core.scenario import families

    paths = [ROOT / 'config' / 'scenarios' / 'v_formation.yaml']
    for spec in two_teams:
        seed, index = (int(v) for v in spec.split(':'))
        mapping, _draws = families.generate('two_teams', seed, index)
        path = folder / f'two_teams-s{seed}-{index}.yaml'
        path.write_text(yaml.safe_dump(mapping, sort_keys=False))
        paths.append(path)
    return paths


def _figures(metrics: dict, result, scenario) -> dict:
    from ament_formation.core.sim import campaign

    classes, reason = campaign.classify(metrics, result, scenario)
    robots = metrics['robots'].values()
    end = result.mission_end_s
    return {
        'classes': ' '.join(classes) or '-',
        'reason': reason,
        'mission_ratio': None if end is None else end / scenario.duration_s,
        'settled_rms_max_m': max((r['formation_rms_settled_m'] for r in robots
                                  if r['formation_rms_settled_m'] is not None), default=None),
        'final_error_max_m': max((r['final_error_m'] for r in robots
                                  if r['final_error_m'] is not None), default=None),
        'min_robot_distance_m': metrics['min_inter_robot_distance_m'],
        'min_clearance_m': metrics['min_clearance_m'],
        'entries': metrics.get('prohibited_entries'),
    }


def _fast(path: Path) -> dict:
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.core.sim.metrics import compute_metrics
    from ament_formation.core.sim.simulator import simulate

    scenario = load_scenario(path)
    result = simulate(scenario, record_every_s=0.01)
    return _figures(compute_metrics(result, scenario), result, scenario)


def _formation() -> str:
    """The console script: on PATH (a sourced workspace, an activated venv), else beside this
    interpreter (bench/run.sh runs .venv's python).
    """
    import shutil

    found = shutil.which('formation')
    if found:
        return found
    beside = Path(sys.executable).parent / 'formation'
    if beside.exists():
        return str(beside)
    raise SystemExit('bench_nodes_vs_sim: no `formation` program on PATH')


def _nodes(path: Path, out: Path, team: int | None = None) -> dict:
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.core.sim.metrics import compute_metrics
    from ament_formation.ros.run_record import load_run

    # 14 processes for 6 robots start in about a minute on 2 cores: the start is given 300 s
    res = subprocess.run([_formation(), 'run', str(path), '--out', str(out), '--quiet',
                          '--no-figure', '--startup-timeout', '300',
                          *([] if team is None else ['--team', str(team)])],
                         capture_output=True, text=True, timeout=1800)
    row = {'exit': res.returncode, 'failed_check': res.stderr.strip().splitlines()[-1:] or ['-']}
    scenario = load_scenario(path)
    try:
        result = load_run(out / 'run.mcap', scenario)
    except (OSError, ValueError) as err:
        return {**row, 'classes': 'no recording', 'reason': str(err)}
    return {**row, **_figures(compute_metrics(result, scenario), result, scenario)}


def _fmt(v) -> str:
    if v is None:
        return '-'
    if isinstance(v, float):
        return f'{v:.3f}'
    return str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--two-teams', nargs='*', default=list(DEFAULT_TWO_TEAMS),
                    metavar='SEED:INDEX', help='generated two_teams scenarios (default 1:2 2:5)')
    ap.add_argument('--out', type=Path, help='keep the runs here (default: a temporary folder)')
    ap.add_argument('--team', type=int, default=None, metavar='K',
                    help='formation run --team K (K robots per process; default: a process '
                    'per node, 2 per robot)')
    args = ap.parse_args(argv)
    for spec in args.two_teams:
        parts = spec.split(':')
        if len(parts) != 2 or not all(p.isdigit() for p in parts):
            ap.error(f'--two-teams: expected SEED:INDEX, got {spec!r}')
    with tempfile.TemporaryDirectory(prefix='nodes_vs_sim_') as tmp:
        base = args.out or Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        rows, same = [], True
        for path in _scenarios(args.two_teams, base):
            fast = _fast(path)
            nodes = _nodes(path, base / f'run-{path.stem}', args.team)
            hard = lambda c: {x for x in c.split() if x not in ('-', 'keepout', 'parked')}  # noqa
            agree = hard(fast['classes']) == hard(nodes.get('classes', ''))
            same &= agree
            rows.append({'scenario': path.stem, 'fast': fast, 'nodes': nodes, 'agree': agree})
        keys = ('classes', 'mission_ratio', 'settled_rms_max_m', 'final_error_max_m',
                'min_robot_distance_m', 'min_clearance_m', 'entries')
        print('| scenario | where | ' + ' | '.join(keys) + ' | exit |')
        print('|---' * (len(keys) + 3) + '|')
        for r in rows:
            for where in ('fast', 'nodes'):
                d = r[where]
                print(f'| {r["scenario"]} | {where} | '
                      + ' | '.join(_fmt(d.get(k)) for k in keys)
                      + f' | {d.get("exit", "-")} |')
        for r in rows:
            for where in ('fast', 'nodes'):
                if r[where].get('reason'):
                    print(f'{r["scenario"]} {where}: {r[where]["reason"]}')
            if r['nodes'].get('exit'):
                print(f'{r["scenario"]} formation run: {r["nodes"]["failed_check"][0]}')
        if args.out:
            (args.out / 'nodes_vs_sim.json').write_text(json.dumps(rows, indent=2, default=str))
        print('the same hard classes both ways' if same else 'DIFFERENT hard classes: see above')
    return 0 if same else 1


if __name__ == '__main__':
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    sys.exit(main())
