"""`formation sweep` (issue "Safe on scenarios nobody picked"): the random families keep their
feasibility rules, runs are classified by what happened, the command writes every output and says
failure when a run failed, failing scenarios replay, and a Dask scheduler with two worker processes
on loopback gives the same rows as a run in one process.
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import time

import numpy as np
from processes import program
import pytest

from ament_formation.core.model.obstacles import ObstacleField
from ament_formation.core.params import AvoidanceParams, RobotParams
from ament_formation.core.scenario import families
from ament_formation.core.scenario.loader import load_scenario, parse_scenario
from ament_formation.core.sim import campaign
from ament_formation.tools import cli

RULES = families.Rules()
SEEDS = range(25)


def _goals(scenario) -> np.ndarray:
    """(T, N, 2) formation goals every 0.5 s: each team leader's reference + the robot's slot."""
    t = np.arange(0.0, scenario.duration_s + 1e-9, 0.5)
    refs = {r.id: np.asarray(r.path.reference(t)[0]) for r in scenario.robots if r.leader}
    return np.stack(
        [refs[scenario.team_leader(r.id)] + np.asarray(r.slot_m) for r in scenario.robots], axis=1
    )


@pytest.mark.parametrize('family', families.FAMILIES)
def test_generated_scenarios_are_valid_feasible_and_reproducible(family):
    keep = RobotParams().body_radius_m + RULES.edge_margin_m
    kappa = AvoidanceParams().protected_scale
    for seed in SEEDS:
        mapping, draws = families.generate(family, seed, 7)
        assert 1 <= draws <= families.MAX_DRAWS
        assert families.generate(family, seed, 7)[0] == mapping  # same seed, same scenario
        scenario = parse_scenario(mapping)
        assert scenario.floor.x_m == RULES.floor_x_m and scenario.floor.y_m == RULES.floor_y_m
        goals = _goals(scenario)
        assert goals[..., 0].min() >= RULES.floor_x_m[0] + keep - 1e-9
        assert goals[..., 0].max() <= RULES.floor_x_m[1] - keep + 1e-9
        assert goals[..., 1].min() >= RULES.floor_y_m[0] + keep - 1e-9
        assert goals[..., 1].max() <= RULES.floor_y_m[1] - keep + 1e-9
        for r in scenario.robots:  # every robot starts near its goal
            k = scenario.robot_ids.index(r.id)
            assert math.dist(r.initial_pose[:2], goals[0, k]) <= RULES.start_error_m * 1.5
        if family != 'crossing':
            slots = np.asarray(
                [
                    r.slot_m
                    for r in scenario.robots
                    if scenario.team_leader(r.id) == scenario.team_leader(scenario.robots[0].id)
                ]
            )
            gaps = np.linalg.norm(slots[:, None] - slots[None], axis=2) + 9 * np.eye(len(slots))
            assert gaps.min() >= RULES.spacing_m[0] * 0.99
        # robots of different teams come to rest as far apart as slots (0.35 m)
        assert families.resting_gap_m(scenario) >= RULES.spacing_m[0]
        field = ObstacleField(scenario.obstacles).at(0.0) if scenario.obstacles else None
        for j, o in enumerate(scenario.obstacles):
            osc = (
                2 * math.pi * math.hypot(*o.oscillation_amplitude_m) / o.oscillation_period_s
                if o.oscillation_period_s > 0
                else 0.0
            )
            boundary = (
                math.hypot(*o.velocity_mps)
                + osc
                + abs(o.angular_velocity_radps) * max(o.semi_axes_m)
            )
            assert boundary <= RULES.obstacle_speed_max_mps + 1e-9, (o, boundary)
            c, phi = field.center_m[j], field.phi_rad[j]
            for r in scenario.robots:  # every start outside Q
                z = np.asarray(r.initial_pose[:2]) - c
                u = math.cos(phi) * z[0] + math.sin(phi) * z[1]
                w = -math.sin(phi) * z[0] + math.cos(phi) * z[1]
                r1, r2 = kappa * np.asarray(o.semi_axes_m)
                assert (u / r1) ** 2 + (w / r2) ** 2 > 1.0
    other = families.generate(family, 0, 8)[0]
    assert other != families.generate(family, 0, 7)[0]


def test_families_cover_what_they_declare():
    """Across 90 draws: 2-8 robots, every shape and path kind, obstacles that move and rotate."""
    seen = {'robots': set(), 'names': set(), 'moving': 0, 'rotating': 0, 'static': 0}
    for i in range(90):
        mapping, _ = families.generate(families.FAMILIES[i % 3], 11, i)
        seen['robots'].add(len(mapping['robots']))
        seen['names'].add('-'.join(mapping['name'].split('-')[3:]))
        for o in mapping['obstacles']:
            kind = (
                'rotating'
                if o.get('angular_velocity_radps')
                else 'moving'
                if o.get('velocity_mps')
                else 'static'
            )
            seen[kind] += 1
    assert {2, 3, 4, 8} <= seen['robots']
    for shape in families.SHAPES:
        assert any(n.startswith(shape) for n in seen['names']), (shape, seen['names'])
    for kind in ('line', 'sinusoid', 'waypoints'):
        assert any(n.endswith(kind) for n in seen['names'])
    assert min(seen['moving'], seen['rotating'], seen['static']) > 0


def test_formation_slots_shapes():
    slots = families.formation_slots('v', 5, 0.4, 0.0)
    assert np.allclose(slots, [[0, 0], [-0.4, 0.4], [-0.4, -0.4], [-0.8, 0.8], [-0.8, -0.8]])
    assert np.allclose(
        families.formation_slots('column', 3, 0.5, math.pi / 2),
        [[0, 0], [0, -0.5], [0, -1.0]],
        atol=1e-12,
    )
    wedge = families.formation_slots('wedge', 6, 0.4, 0.0)
    assert np.allclose(wedge[1:3], [[-0.4, -0.2], [-0.4, 0.2]]) and np.allclose(wedge[3:, 0], -0.8)
    with pytest.raises(ValueError):
        families.formation_slots('blob', 3, 0.4, 0.0)
    with pytest.raises(ValueError, match='unknown family'):
        families.generate('blob', 0, 0)


class _Result:
    """What :func:`campaign.classify` reads of a run besides its metrics."""

    def __init__(self, goals, centers=np.zeros((1, 0, 2)), phis=np.zeros((1, 0))):
        self.robot_ids = (0, 1)
        self.obstacle_names = tuple(f'O{j}' for j in range(centers.shape[1]))
        self.goal_m = np.asarray(goals, dtype=float)[None]
        self.obstacle_center_m, self.obstacle_phi_rad = centers, phis


def _scenario(obstacles=()):
    robots = [
        {
            'id': 0,
            'leader': True,
            'initial_pose': [0, 0, 0],
            'path': {'type': 'line', 'start_m': [0, 0], 'heading_rad': 0, 'speed_mps': 0.05},
        },
        {'id': 1, 'slot_m': [0, 0.5], 'initial_pose': [0, 0.5, 0]},
    ]
    return parse_scenario(
        {
            'name': 't',
            'duration_s': 1.0,
            'robots': robots,
            'graph': {'edges': [[0, 1]]},
            'obstacles': list(obstacles),
        }
    )


def _metrics(clear=0.1, pair=0.5, speed=0.05, final=(0.0, 0.0), events=0, floor=None):
    return {
        'min_clearance_m': clear,
        'robot_pair_min_distance_m': {'0-1': pair},
        'peak_speed_mps': {'0': speed, '1': 0.01},
        'robots': {'0': {'final_error_m': final[0]}, '1': {'final_error_m': final[1]}},
        'mode_events': [{'robot': 1}] * events,
        **({} if floor is None else {'floor_excursion_m': floor}),
    }


@pytest.mark.parametrize(
    'kw, classes',
    [
        ({}, []),
        ({'clear': -0.001}, ['inside_p']),
        ({'pair': 0.199}, ['contact']),
        ({'pair': 0.24}, ['keepout']),
        ({'pair': 0.26}, []),
        ({'speed': 0.31}, ['runaway']),
        ({'final': (0.0, 0.51)}, ['far_from_goal']),
        ({'events': 50}, []),
        ({'events': 51}, ['chattering']),
        ({'floor': 0.001}, ['off_floor']),
        ({'floor': -0.01}, []),
    ],
)
def test_classify_names_each_failure_class_at_its_limit(kw, classes):
    found, reason = campaign.classify(_metrics(**kw), _Result([[0, 0], [5, 5]]), _scenario())
    assert found == classes
    assert bool(reason) == bool(classes) and '\n' not in reason


def test_far_from_goal_says_whether_the_robot_ends_in_avoidance_and_for_how_long():
    metrics = _metrics(final=(0.0, 0.7))
    metrics['robots']['1'].update(avoiding_at_end=True, longest_avoidance_s=42.0)
    found, reason = campaign.classify(metrics, _Result([[0, 0], [5, 5]]), _scenario())
    assert found == ['far_from_goal']
    assert reason == (
        'far_from_goal: R1 ends 0.70 m from its goal (in avoidance; longest avoidance 42.0 s)'
    )


def test_a_goal_inside_an_obstacles_q_is_parked_not_a_failure():
    obstacle = {'name': 'A', 'center_m': [5.0, 5.0], 'semi_axes_m': [0.2, 0.1]}
    result = _Result([[0, 0], [5.1, 5.0]], np.array([[[5.0, 5.0]]]), np.zeros((1, 1)))
    found, _ = campaign.classify(_metrics(final=(0, 0.6)), result, _scenario([obstacle]))
    assert found == ['parked']
    result.goal_m[0, 1] = [5.5, 5.0]  # outside Q = 1.8 P (0.36 m along x)
    assert campaign.classify(_metrics(final=(0, 0.6)), result, _scenario([obstacle]))[0] == [
        'far_from_goal'
    ]


LATE_M = 5.0  # S17: a reference waits for its team (S17.2, S17.3): a robot 2.2 m late catches
# up before the mission ends; one 5 m late does not (1.34 m from its goal)


def _late_start() -> dict:
    """head_on.yaml with robot 1 starting 5 m behind its goal: 1.34 m from it when the mission
    ends (its reference waited for it as long as S17.2 and S17.3 let it).
    """
    import yaml

    mapping = yaml.safe_load(
        (Path(__file__).resolve().parent / 'data' / 'head_on.yaml').read_text()
    )
    mapping['robots'][1]['initial_pose'][0] += LATE_M
    # head_on.yaml's avoidance entries are the two robots meeting in time; this late robot meets
    # a robot that has the right of way (S7.5) and alone gives way: only the distance is kept
    del mapping['expect']['avoidance_entries']
    return mapping


def test_a_robot_that_catches_up_once_the_paths_stop_is_far_but_not_stuck():
    row = campaign.run_case({'mapping': _late_start(), 'hold_s': 30.0})
    assert row['classes'] == 'far_from_goal' and row['status'] == 'fail'
    assert 0.0 < row['hold_catch_up_s'] < 30.0


def test_a_robot_still_far_when_the_hold_ends_is_stuck():
    row = campaign.run_case({'mapping': _late_start(), 'hold_s': 0.5})
    assert row['classes'] == 'far_from_goal stuck' and row['hold_catch_up_s'] is None
    assert 'stuck: R1 still 1.2' in row['reason']
    assert 'm from its goal 0.5 s after the mission ended' in row['reason']  # docs/sweep.md


def test_a_stuck_run_replays_with_formation_sim_hold(tmp_path):
    import yaml

    row = campaign.run_case({'mapping': _late_start(), 'hold_s': 0.5})
    assert row['replay'] == '--hold 0.5'
    scen = tmp_path / 'late.yaml'
    scen.write_text(yaml.safe_dump(row['mapping']))
    out = tmp_path / 'run'
    rc = cli.main(['sim', str(scen), '--hold', '0.5', '--out', str(out), '--quiet', '--no-figure'])
    metrics = json.loads((out / 'metrics.json').read_text())
    # docs/sweep.md: --hold runs 0.5 s past the mission's end, the references at rest there
    assert metrics['mission_end_s'] is not None
    assert metrics['sim_time_s'] == pytest.approx(metrics['mission_end_s'] + 0.5, abs=0.02)
    assert metrics['robots']['1']['final_error_m'] > 1.0  # still far: stuck
    # a robot that never arrived fails the run (check reached_goals), not only the campaign row
    assert rc == 1 and metrics['failure'].startswith('reached_goals ')
    assert 'R1 ends' in metrics['failure']
    assert cli.main(['sim', str(scen), '--hold', 'nan', '--out', str(out), '--quiet']) == 2


def test_no_hold_no_stuck_class():
    row = campaign.run_case({'mapping': _late_start(), 'hold_s': 0.0})
    assert row['classes'] == 'far_from_goal' and row['hold_catch_up_s'] is None


def test_the_hold_keeps_the_run_and_rests_the_references_past_the_missions_end():
    # docs/sweep.md (replacing campaign.held_scenario, S17.3): the held run is the same run up
    # to the mission's end, then goes on hold_s with every reference at rest at its end
    from ament_formation.core.sim.simulator import simulate

    scenario = parse_scenario(_late_start())
    plain = simulate(scenario, record_every_s=0.01)
    held = simulate(scenario, record_every_s=0.01, hold_s=3.0)
    end = plain.mission_end_s
    assert end is not None and held.mission_end_s == pytest.approx(end)
    assert held.t_s[-1] == pytest.approx(end + 3.0, abs=0.02)
    k = len(plain.t_s)
    np.testing.assert_array_equal(held.state[:k], plain.state)
    after = np.asarray(held.t_s) >= end
    np.testing.assert_allclose(held.goal_m[after], held.goal_m[after][:1].repeat(after.sum(), 0))


def _rows(path: Path) -> list[dict]:
    with open(path / 'runs.csv') as f:
        return [{k: v for k, v in row.items() if k != 'wall_s'} for row in csv.DictReader(f)]


@pytest.fixture(scope='module')
def serial_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp('sweep_serial')
    rc = cli.main(
        ['sweep', '--out', str(out), '--count', '9', '--seed', '5', '--workers', '0', '--quiet']
    )
    return rc, out


def test_sweep_writes_every_output_and_its_status_agrees_with_the_runs(serial_sweep):
    rc, out = serial_sweep
    rows = _rows(out)
    summary = json.loads((out / 'summary.json').read_text())
    assert len(rows) == 9 and summary['runs'] == 9 and summary['engine'] == 'in-process'
    assert [r['family'] for r in rows] == list(families.FAMILIES) * 3
    hard = [r for r in rows if r['status'] == 'fail']
    assert summary['counts']['all']['hard'] == len(hard)
    assert rc == (1 if hard else 0)
    assert (out / 'distributions.png').stat().st_size > 10_000
    spread = summary['distributions']['min_robot_distance_m']
    assert spread['n'] == 9 and spread['min'] <= spread['p50'] <= spread['max']
    assert spread['min'] == pytest.approx(min(float(r['min_robot_distance_m']) for r in rows))
    files = sorted((out / 'failures').glob('*.yaml')) if hard else []
    assert len(files) == len(hard) == len(summary['failures'])
    for r in rows:
        assert r['status'] in ('ok', 'fail') and r['classes'] != 'error', r['reason']


@pytest.fixture(scope='module')
def failing_sweep(tmp_path_factory):
    """Two perturbations of a scenario that always fails: robot 1 starts 5 m behind its
    leader path's start and cannot catch up before the mission ends (far_from_goal).
    """
    import yaml

    out = tmp_path_factory.mktemp('sweep_failing')
    mapping = yaml.safe_load(
        (Path(__file__).resolve().parent / 'data' / 'head_on.yaml').read_text()
    )
    mapping['robots'][1]['initial_pose'][0] += LATE_M
    base = out / 'late_start.yaml'
    base.write_text(yaml.safe_dump(mapping))
    args = ['--out', str(out / 'runs'), '--perturb', str(base), '--count', '2', '--workers', '0']
    rc = cli.main(['sweep', *args, '--quiet', '--no-plot'])
    return rc, out / 'runs'


def test_a_failing_scenario_replays_with_formation_sim(failing_sweep, tmp_path):
    rc, out = failing_sweep
    files = sorted((out / 'failures').glob('*.yaml'))
    assert rc == 1 and len(files) == 2
    text = files[0].read_text()
    first = text.splitlines()[0]
    assert first.startswith('# formation sweep (ideal sensing): ') and len(first) < 400
    row = next(r for r in _rows(out) if f'{int(r["index"]):05d}-' in files[0].name)
    cli.main(['sim', str(files[0]), '--out', str(tmp_path / 'replay'), '--quiet', '--no-figure'])
    metrics = json.loads((tmp_path / 'replay' / 'metrics.json').read_text())
    assert metrics['min_clearance_m'] is None and row['min_clearance_m'] == ''  # no obstacle
    assert metrics['min_inter_robot_distance_m'] == pytest.approx(
        float(row['min_robot_distance_m']), rel=1e-12
    )
    final = max(r['final_error_m'] for r in metrics['robots'].values())
    assert final == pytest.approx(float(row['final_error_max_m']), rel=1e-12) and final > 0.5


def test_replay_runs_a_campaigns_failures_again_with_the_same_results(failing_sweep, tmp_path):
    rc, out = failing_sweep
    before = {r['index']: r for r in _rows(out) if r['status'] == 'fail'}
    again = tmp_path / 'again'
    args = ['sweep', '--out', str(again), '--replay', str(out), '--workers', '0']
    assert cli.main([*args, '--quiet', '--no-plot']) == 1
    rows = {r['index']: r for r in _rows(again)}
    assert sorted(rows) == sorted(before) and len(rows) == 2
    for index, row in rows.items():
        old = before[index]
        assert row['family'] == old['family'] == 'perturbed' and row['name'] == old['name']
        for key in ('classes', 'reason', 'min_robot_distance_m', 'final_error_max_m'):
            assert row[key] == old[key], key
    summary = json.loads((again / 'summary.json').read_text())
    assert summary['seed'] == 0 and summary['sensing'] == 'ideal' and summary['runs'] == 2


def test_replay_refuses_what_is_not_a_campaign(failing_sweep, tmp_path, capsys):
    _rc, out = failing_sweep
    for argv, field in (
        (['--replay', str(tmp_path)], '--replay'),  # no summary.json
        (['--replay', str(out), '--perturb', str(out / 'x.yaml')], '--replay'),
    ):
        rc = cli.main(['sweep', '--out', str(tmp_path / 'o'), '--quiet', *argv])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and field in err and '\n' not in err
    assert cli.main(['sweep', '--out', str(out), '--replay', str(out), '--quiet']) == 2
    assert (out / 'failures').is_dir()  # the campaign replayed is left as it was


def test_perturbed_campaign_of_a_shipped_scenario(tmp_path):
    scen = Path(__file__).resolve().parents[1] / 'config' / 'scenarios' / 'paper.yaml'
    rc = cli.main(
        [
            'sweep',
            '--out',
            str(tmp_path),
            '--perturb',
            str(scen),
            '--count',
            '2',
            '--workers',
            '0',
            '--quiet',
            '--no-plot',
        ]
    )
    rows = _rows(tmp_path)
    assert [r['family'] for r in rows] == ['perturbed', 'perturbed']
    assert rows[0]['name'] != rows[1]['name'] and rows[0]['name'].startswith('paper-p0-')
    assert rc == (1 if any(r['status'] == 'fail' for r in rows) else 0)


def test_a_folder_of_scenario_files_runs_each_as_it_is(tmp_path):
    """--scenarios DIR: every DIR/*.yaml once, in name order, as given (another generator's
    files, a user's own): rows of family "given" named after the scenarios, the same row as the
    campaign's run of that mapping, and a failing one written to failures/ like any other.
    """
    import shutil

    data = Path(__file__).resolve().parent / 'data'
    folder = tmp_path / 'mine'
    folder.mkdir()
    shutil.copy(data / 'paper_short.yaml', folder / 'b-paper_short.yaml')
    shutil.copy(data / 'head_on.yaml', folder / 'a-head_on.yaml')
    (folder / 'notes.txt').write_text('not a scenario')  # only *.yaml is read
    out = tmp_path / 'out'
    rc = cli.main(['sweep', '--out', str(out), '--scenarios', str(folder), '--workers', '0',
                   '--quiet', '--no-plot'])
    rows = _rows(out)
    names = [load_scenario(f).name for f in sorted(folder.glob('*.yaml'))]
    assert [r['name'] for r in rows] == names and [r['index'] for r in rows] == ['0', '1']
    assert {r['family'] for r in rows} == {'given'}
    assert rc == (1 if any(r['status'] == 'fail' for r in rows) else 0)
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['runs'] == summary['requested'] == 2 and summary['families'] == ['given']


@pytest.mark.parametrize(
    'make, field',
    [
        (lambda d: d / 'missing', '--scenarios'),  # no such folder
        (lambda d: d, '--scenarios'),  # a folder without *.yaml
        (lambda d: (d / 'bad.yaml').write_text('name: x\nrobots: 3\n') and d, 'bad.yaml'),
    ],
)
def test_scenarios_folder_refusals_are_one_line(make, field, tmp_path, capsys):
    folder = tmp_path / 'in'
    folder.mkdir()
    rc = cli.main(['sweep', '--out', str(tmp_path / 'o'), '--quiet', '--scenarios',
                   str(make(folder))])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and field in err and '\n' not in err and len(err) < 300
    rc = cli.main(['sweep', '--out', str(tmp_path / 'o'), '--quiet', '--scenarios', str(folder),
                   '--perturb', str(folder / 'x.yaml')])
    assert rc == 2 and 'not several' in capsys.readouterr().err


@pytest.mark.parametrize(
    'argv, field',
    [
        (['--count', '0'], '--count'),
        (['--families', 'formation,blob'], '--families'),
        (['--scale', 'nan'], '--scale'),
        (['--hold', '-1'], '--hold'),
        (['--hold', 'inf'], '--hold'),
        (['--workers', '-1'], '--workers'),
        (['--perturb', '/nonexistent.yaml'], 'nonexistent'),
    ],
)
def test_bad_options_are_refused_in_one_line(argv, field, tmp_path, capsys):
    rc = cli.main(['sweep', '--out', str(tmp_path / 'o'), '--quiet', *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and field in err and '\n' not in err and len(err) < 300


def _wait(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')


def test_dask_scheduler_with_two_worker_processes_on_loopback_gives_the_same_rows(
    serial_sweep, tmp_path
):
    """The real programs: `dask scheduler` and `dask worker --nworkers 2` on 127.0.0.1, then the
    `formation sweep` console script pointed at them; the rows equal the in-process campaign's.
    """
    _rc, serial_out = serial_sweep
    sched_file = tmp_path / 'scheduler.json'
    env = {**os.environ, 'DASK_TEMPORARY_DIRECTORY': str(tmp_path / 'dask')}
    logs = [open(tmp_path / name, 'w') for name in ('scheduler.log', 'worker.log')]
    procs = [
        subprocess.Popen(
            [
                program('dask'),
                'scheduler',
                '--host',
                '127.0.0.1',
                '--port',
                '0',
                '--no-dashboard',
                '--scheduler-file',
                str(sched_file),
            ],
            stdout=logs[0],
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        ),
    ]
    try:
        _wait(sched_file.exists, 60, 'the scheduler file')
        procs.append(
            subprocess.Popen(
                [
                    program('dask'),
                    'worker',
                    '--scheduler-file',
                    str(sched_file),
                    '--nworkers',
                    '2',
                    '--nthreads',
                    '1',
                    '--host',
                    '127.0.0.1',
                    '--no-dashboard',
                    '--local-directory',
                    str(tmp_path / 'dask'),
                ],
                stdout=logs[1],
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,
            )
        )
        address = json.loads(sched_file.read_text())['address']
        assert address.startswith('tcp://127.0.0.1:')
        from dask.distributed import Client

        with Client(address, timeout='60s') as client:
            client.wait_for_workers(2, timeout=120)
        out = tmp_path / 'out'
        run = subprocess.run(
            [
                program('formation'),
                'sweep',
                '--out',
                str(out),
                '--count',
                '9',
                '--seed',
                '5',
                '--scheduler',
                address,
                '--no-plot',
            ],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
        )
        summary = json.loads((out / 'summary.json').read_text())
        assert summary['engine'] == 'dask' and summary['workers'] == 2, (run.stderr, summary)
        assert _rows(out) == _rows(serial_out)
        hard = summary['counts']['all']['hard']
        assert run.returncode == (1 if hard else 0), run.stderr
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        for f in logs:
            f.close()


def test_a_campaign_run_with_camera_sensing_is_classified_and_seeded_per_run():
    rows = [
        campaign.run_case({'family': 'crossing', 'seed': 2, 'index': i, 'sensing': 'camera'})
        for i in (0, 0, 3)
    ]
    for row in rows:
        assert row['sensing'] == 'camera' and row['classes'] != 'error', row['reason']
        assert row['min_robot_distance_m'] is not None
    assert rows[0]['min_robot_distance_m'] == rows[1]['min_robot_distance_m']  # reproducible
    ideal = campaign.run_case({'family': 'crossing', 'seed': 2, 'index': 0})
    assert ideal['name'] == rows[0]['name']
    assert ideal['min_robot_distance_m'] != rows[0]['min_robot_distance_m']  # it did sense


def test_sigint_stops_a_dask_campaign_and_keeps_what_is_done(tmp_path):
    """Ctrl-C on the console script: the campaign stops after the runs in hand (Dask's client
    swallowed the KeyboardInterrupt: it kept running), writes the rows done and exits 130.
    """
    out = tmp_path / 'out'
    proc = subprocess.Popen(
        [program('formation'), 'sweep', '--out', str(out), '--count', '400', '--seed', '5',
         '--workers', '2', '--no-plot'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = ''
        for _ in range(50):  # the first progress line (a run is done), after any warnings
            first = proc.stderr.readline()
            if first.startswith('sweep: ') or not first:
                break
        assert first.startswith('sweep: 1/400'), first
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    summary = json.loads((out / 'summary.json').read_text())
    assert proc.returncode == 130, err
    assert 'stopped by signal 2' in err
    assert 1 <= summary['runs'] < 400 and summary['interrupted_by_signal'] == 2
    assert len(_rows(out)) == summary['runs']


def test_progress_in_a_log_file_is_a_line_per_tenth_and_at_least_one_a_minute(monkeypatch, capsys):
    """Not on a tty: a line per 10 % of the runs, and one whenever a minute passed without one
    (a camera campaign's 10 % of 2,000 runs takes about six minutes), and the last run's line.
    """
    from ament_formation.tools import sweep_cmd

    clock = [1000.0]
    monkeypatch.setattr(sweep_cmd.time, 'monotonic', lambda: clock[0])
    progress = sweep_cmd._Progress(total=100, quiet=False)
    assert not progress.tty  # pytest captures stderr
    for k in range(1, 101):
        clock[0] += 1.0 if k <= 50 else 7.0  # 7 s a run from the 51st on
        progress({'status': 'fail' if k % 25 == 0 else 'ok'})
    lines = capsys.readouterr().err.splitlines()
    done = [int(line.split()[1].split('/')[0]) for line in lines]
    # 1, 11, ..., 51 by the tenth; then a minute is 9 runs of 7 s (before the next tenth): 60,
    # 69, ...; and the 100th
    assert done[:6] == [1, 11, 21, 31, 41, 51], done
    assert done[6:] == [60, 69, 78, 87, 96, 100], done
    assert lines[-1].startswith('sweep: 100/100 runs, 4 failed,')
