"""Scenario loading and strict validation (docs/design.md §5): every kind of bad input is
rejected with its own one-line message naming the file, the field and the problem; the CLI exits
with code 2.
"""

from __future__ import annotations

import math
from pathlib import Path
import subprocess
import sys

import pytest
import yaml

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import ellipses_overlap
from ament_formation.core.model.paths import LinePath, SinusoidPath
from ament_formation.core.scenario.loader import (
    dump_scenario,
    load_scenario,
    parse_scenario,
)

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / 'config' / 'scenarios' / 'paper.yaml'
V_FORMATION = ROOT / 'config' / 'scenarios' / 'v_formation.yaml'


def base() -> dict:
    return yaml.safe_load(PAPER.read_text())


def reject(tmp_path, data_or_text, field_part: str, problem_part: str) -> str:
    """Write the scenario, load it, and check the one-line message names file, field, problem."""
    path = tmp_path / 'bad.yaml'
    text = (
        data_or_text
        if isinstance(data_or_text, str)
        else yaml.safe_dump(data_or_text, sort_keys=False)
    )
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    msg = str(info.value)
    assert '\n' not in msg
    assert msg.startswith(f'{path}: '), msg
    assert field_part in msg, msg
    assert problem_part in msg, msg
    return msg


# ---------------------------------------------------------------------------------------------
# The shipped scenarios
# ---------------------------------------------------------------------------------------------


def test_paper_scenario_is_spec_s12_scenario_1():
    s = load_scenario(PAPER)
    assert s.name == 'paper' and s.duration_s == 55.0
    assert s.robot_ids == (0, 1) and s.leaders == (0,) and s.edges == ((0, 1),)
    lead, fol = s.robot(0), s.robot(1)
    assert isinstance(lead.path, SinusoidPath)
    assert lead.path.amplitude_m == 0.2 and lead.path.speed_mps == 0.05
    assert lead.path.wavenumber_radpm == pytest.approx(math.pi, abs=1e-12)
    assert tuple(fol.slot_m) == (0.0, 1.2) and tuple(fol.initial_pose) == (0.0, 1.0, 0.0)
    o1, o2 = s.obstacles
    assert (o1.name, o1.center_m, o1.semi_axes_m) == ('O1', (1.0, -0.2), (0.40, 0.15))
    assert (o2.name, o2.center_m, o2.semi_axes_m) == ('O2', (1.5, 1.2), (0.40, 0.15))
    assert o1.orientation_rad == pytest.approx(2 * math.pi / 3, abs=1e-12)
    assert o2.orientation_rad == pytest.approx(math.pi / 3, abs=1e-12)
    assert s.avoidance.limit_cycle_scale == 1.1 and s.avoidance.protected_scale == 1.8
    assert s.disturbance.accel_bound == (0.05, 0.5)


def test_v_formation_scenario_is_spec_s12_scenario_2():
    s = load_scenario(V_FORMATION)
    slots = {r.id: tuple(r.slot_m) for r in s.robots}
    assert slots == {
        0: (0.0, 0.0),
        1: (-0.4, 0.4),
        2: (-0.4, -0.4),
        3: (-0.8, 0.8),
        4: (-0.8, -0.8),
        5: (0.0, 0.0),
    }
    assert s.leaders == (0, 5)
    assert s.team_leader(3) == 0 and s.team_leader(5) == 5
    assert set(s.edges) == {(0, 1), (0, 2), (1, 3), (2, 4), (1, 2), (2, 1), (4, 3), (3, 4)}
    by_name = {o.name: o for o in s.obstacles}
    assert by_name['A'].semi_axes_m == (0.30, 0.20) and not (
        by_name['A'].moves or by_name['A'].rotates
    )
    assert by_name['B'].semi_axes_m == (0.35, 0.14) and by_name['B'].angular_velocity_radps == 0.05
    assert by_name['C'].velocity_mps == (0.0, -0.008) and by_name['C'].oscillation_amplitude_m == (
        0.05,
        0.0,
    )
    assert by_name['D'].semi_axes_m == (0.32, 0.12)
    r5 = s.robot(5)
    assert isinstance(r5.path, LinePath) and r5.path.start_m[1] == 0.4
    assert r5.path.heading_rad == pytest.approx(math.pi) and r5.path.speed_mps == 0.05
    # the nominal head-on meeting of R1 (slot y = 0.4) and R5 happens at t in 40..50 s
    lead = s.robot(0).path
    t_meet = [
        t / 10
        for t in range(0, 1000)
        if abs((lead.reference(t / 10)[0][0] - 0.4) - r5.path.reference(t / 10)[0][0]) < 0.005
    ]
    assert t_meet and 40.0 <= t_meet[0] <= 50.0


@pytest.mark.parametrize('path', [PAPER, V_FORMATION])
def test_scenario_round_trips_through_dump(path):
    s = load_scenario(path)
    again = parse_scenario(yaml.safe_load(dump_scenario(s)), source=str(path))
    assert again == s


def test_swapped_semi_axes_are_normalised_to_the_same_ellipse():
    data = base()
    data['obstacles'][0]['semi_axes_m'] = [0.15, 0.40]
    data['obstacles'][0]['orientation_rad'] = 2.0943951023931953 - math.pi / 2
    s = parse_scenario(data)
    assert s.obstacles[0].semi_axes_m == (0.40, 0.15)
    assert s.obstacles[0].orientation_rad == pytest.approx(2.0943951023931953)


def test_robot_override_of_a_default_parameter():
    data = base()
    data['robots'][1]['torque_limit_nm'] = 0.2
    s = parse_scenario(data)
    assert s.robot(1).params.torque_limit_nm == 0.2 and s.robot(0).params.torque_limit_nm == 0.15


# ---------------------------------------------------------------------------------------------
# Bad input: one kind per case, each with its own message
# ---------------------------------------------------------------------------------------------


def _mut(fn):
    data = base()
    fn(data)
    return data


BAD_CASES = {
    'unknown top-level key': (lambda d: d.update(durration_s=3), 'durration_s', 'unknown key'),
    'unknown robot key': (
        lambda d: d['robots'][0].update(colour='red'),
        'robots[0].colour',
        'unknown key',
    ),
    'unknown robot-default key': (
        lambda d: d['robot'].update(mass=1.0),
        'robot.mass',
        'unknown key',
    ),
    'unknown path key': (
        lambda d: d['robots'][0]['path'].update(phase_rad=1.0),
        'robots[0].path.phase_rad',
        'unknown key',
    ),
    'unknown obstacle key': (
        lambda d: d['obstacles'][1].update(colour=1),
        'obstacles[1].colour',
        'unknown key',
    ),
    'unknown avoidance key': (
        lambda d: d['avoidance'].update(kappa=2.0),
        'avoidance.kappa',
        'unknown key',
    ),
    'unknown graph key': (lambda d: d['graph'].update(nodes=[0, 1]), 'graph.nodes', 'unknown key'),
    'unknown camera key': (
        lambda d: d['camera'].update(exposure=1),
        'camera.exposure',
        'unknown key',
    ),
    'missing duration': (lambda d: d.pop('duration_s'), 'duration_s', 'missing required key'),
    'missing initial pose': (
        lambda d: d['robots'][1].pop('initial_pose'),
        'robots[1].initial_pose',
        'missing required key',
    ),
    'missing follower slot': (
        lambda d: d['robots'][1].pop('slot_m'),
        'robots[1].slot_m',
        'missing required key',
    ),
    'missing obstacle semi-axes': (
        lambda d: d['obstacles'][0].pop('semi_axes_m'),
        'obstacles[0].semi_axes_m',
        'missing required key',
    ),
    'string for a number': (
        lambda d: d['robots'][1]['initial_pose'].__setitem__(0, 'zero'),
        'robots[1].initial_pose[0]',
        'must be a number',
    ),
    'boolean for a number': (
        lambda d: d.update(duration_s=True),
        'duration_s',
        'must be a number',
    ),
    'pose of wrong length': (
        lambda d: d['robots'][1].update(initial_pose=[0, 1]),
        'robots[1].initial_pose',
        'list of 3 numbers',
    ),
    'robots not a list': (lambda d: d.update(robots={'id': 0}), 'robots', 'non-empty list'),
    'leader flag not a bool': (
        lambda d: d['robots'][0].update(leader='yes'),
        'robots[0].leader',
        'true or false',
    ),
    'zero semi-axis': (
        lambda d: d['obstacles'][0].update(semi_axes_m=[0.4, 0.0]),
        'obstacles[0].semi_axes_m[1]',
        '> 0',
    ),
    'negative semi-axis': (
        lambda d: d['obstacles'][1].update(semi_axes_m=[-0.4, 0.15]),
        'obstacles[1].semi_axes_m[0]',
        '> 0',
    ),
    'NaN': (
        lambda d: d['obstacles'][0].update(orientation_rad=float('nan')),
        'obstacles[0].orientation_rad',
        'finite',
    ),
    'infinity': (
        lambda d: d['robots'][1].update(slot_m=[0.0, float('inf')]),
        'robots[1].slot_m[1]',
        'finite',
    ),
    'negative duration': (lambda d: d.update(duration_s=-5.0), 'duration_s', '> 0'),
    'non-positive robot mass': (
        lambda d: d['robot'].update(platform_mass_kg=0.0),
        'robot.platform_mass_kg',
        '> 0',
    ),
    'bad avoidance scales': (
        lambda d: d['avoidance'].update(limit_cycle_scale=2.0),
        'avoidance.heading_scale',
        'limit_cycle_scale < heading_scale',
    ),
    'bad control gains': (
        lambda d: d.update(control={'switching_gain_mps2': 0.1}),
        'control.switching_gain_mps2',
        '>= reaching_rate_mps2',
    ),
    'duplicate robot id': (
        lambda d: d['robots'][1].update(id=0),
        'robots[1].id',
        'duplicate robot id 0',
    ),
    'duplicate marker id': (
        lambda d: d['robots'][1].update(marker_id=0),
        'robots[1].marker_id',
        'duplicate marker id 0',
    ),
    'duplicate obstacle name': (
        lambda d: d['obstacles'][1].update(name='O1'),
        'obstacles[1].name',
        'duplicate obstacle name',
    ),
    'bad obstacle name': (
        lambda d: d['obstacles'][1].update(name='O 2,x'),
        'obstacles[1].name',
        'letters, digits',
    ),
    'unknown robot in edge': (
        lambda d: d['graph'].update(edges=[[0, 1], [0, 7]]),
        'graph.edges[1]',
        'child 7 is not a robot id',
    ),
    'self-loop': (
        lambda d: d['graph'].update(edges=[[0, 1], [1, 1]]),
        'graph.edges[1]',
        'self-loop',
    ),
    'repeated edge': (
        lambda d: d['graph'].update(edges=[[0, 1], [0, 1]]),
        'graph.edges[1]',
        'listed twice',
    ),
    'edge not a pair': (
        lambda d: d['graph'].update(edges=[[0, 1, 2]]),
        'graph.edges[0]',
        '[parent, child] pair',
    ),
    'unreachable follower': (
        lambda d: d['graph'].update(edges=[[1, 0]]),
        'graph.edges',
        'robot 1 cannot be reached from its team leader 0',
    ),
    'team without leader': (
        lambda d: d['robots'].append({'id': 2, 'slot_m': [0, 2.4], 'initial_pose': [0, 3.0, 0]}),
        'robots[2]',
        'has no leader',
    ),
    'team with two leaders': (
        lambda d: d['robots'][1].update(leader=True, slot_m=[0, 0], path=d['robots'][0]['path']),
        'robots[1].leader',
        'a team has exactly one leader',
    ),
    'leader without path': (
        lambda d: d['robots'][0].pop('path'),
        'robots[0].path',
        'a leader needs a path',
    ),
    'follower with path': (
        lambda d: d['robots'][1].update(
            path={'type': 'line', 'start_m': [0, 1], 'heading_rad': 0, 'speed_mps': 0.05}
        ),
        'robots[1].path',
        'only a leader',
    ),
    'leader slot not zero': (
        lambda d: d['robots'][0].update(slot_m=[0.1, 0.0]),
        'robots[0].slot_m',
        'must be [0, 0]',
    ),
    'bad path type': (
        lambda d: d['robots'][0]['path'].update(type='spiral'),
        'robots[0].path.type',
        "unknown path type 'spiral'",
    ),
    'path missing key': (
        lambda d: d['robots'][0]['path'].pop('speed_mps'),
        'robots[0].path.speed_mps',
        'missing required key',
    ),
    'non-positive path speed': (
        lambda d: d['robots'][0]['path'].update(speed_mps=0.0),
        'robots[0].path.speed_mps',
        '> 0',
    ),
    'waypoints too tight to turn': (
        lambda d: d['robots'][0].update(
            path={
                'type': 'waypoints',
                'points_m': [[0, 0], [0.05, 0], [0.05, 0.05]],
                'speed_mps': 0.05,
            }
        ),
        'robots[0].path.points_m',
        'needs',
    ),
    'robot starts inside P': (
        lambda d: d['robots'][1].update(initial_pose=[1.5, 1.2, 0.0]),
        'robots[1].initial_pose',
        "starts inside the prohibited region P of obstacle 'O2'",
    ),
    "robots start in each other's keep-out": (
        lambda d: d['robots'][1].update(initial_pose=[0.1, 0.1, 0.0]),
        'robots[1].initial_pose',
        'inside the robot prohibited circle',
    ),
    'overlapping static limit cycles': (
        lambda d: d['obstacles'][1].update(center_m=[1.1, -0.1]),
        'obstacles[1]',
        "limit cycles (L = 1.1 P) of obstacles 'O1' and 'O2' overlap",
    ),
    'overlapping moving limit cycles': (
        lambda d: d['obstacles'][1].update(center_m=[3.0, -0.2], velocity_mps=[-0.05, 0.0]),
        'obstacles[1]',
        'overlap at t = ',
    ),
    'oscillation without period': (
        lambda d: d['obstacles'][1].update(oscillation={'amplitude_m': [0.1, 0]}),
        'obstacles[1].oscillation.period_s',
        'missing required key',
    ),
    'disturbance seed not an integer': (
        lambda d: d['disturbance'].update(seed=1.5),
        'disturbance.seed',
        'must be an integer',
    ),
    'negative disturbance bound': (
        lambda d: d['disturbance'].update(accel_bound=[-0.1, 0.5]),
        'disturbance.accel_bound[0]',
        '>= 0',
    ),
    'camera size zero': (lambda d: d['camera'].update(width_px=0), 'camera.width_px', '> 0'),
    'unknown expect key': (
        lambda d: d['expect'].update(settled_rms_m=0.01),
        'expect.settled_rms_m',
        'unknown key',
    ),
    'expect not a mapping': (lambda d: d.update(expect=[0.01]), 'expect', 'must be a mapping'),
    'expect of an unknown robot': (
        lambda d: d['expect'].update(settled_rms_max_m={'0': 0.01, '7': 0.02}),
        'expect.settled_rms_max_m',
        "'7' is not a robot id",
    ),
    'expect limit not positive': (
        lambda d: d['expect'].update(final_error_max_m={1: 0.0}),
        'expect.final_error_max_m.1',
        '> 0',
    ),
    'expect limit not a number': (
        lambda d: d['expect'].update(settled_rms_max_m='small'),
        'expect.settled_rms_max_m',
        'must be a number',
    ),
    'expect range reversed': (
        lambda d: d['expect'].update(avoidance_entries={0: [2, 1]}),
        'expect.avoidance_entries.0',
        'min must be <= max',
    ),
    'expect count negative': (
        lambda d: d['expect'].update(avoidance_entries={0: -1}),
        'expect.avoidance_entries.0',
        '>= 0',
    ),
    'expect count not an integer': (
        lambda d: d['expect'].update(avoidance_entries=1.5),
        'expect.avoidance_entries',
        'must be an integer',
    ),
    'expect empty per-robot mapping': (
        lambda d: d['expect'].update(settled_rms_max_m={}),
        'expect.settled_rms_max_m',
        'must not be empty',
    ),
    'expect clearance not finite': (
        lambda d: d['expect'].update(min_clearance_m=float('nan')),
        'expect.min_clearance_m',
        'finite',
    ),
}


@pytest.mark.parametrize('case', sorted(BAD_CASES))
def test_bad_input_rejected_with_a_clear_message(tmp_path, case):
    fn, field_part, problem_part = BAD_CASES[case]
    reject(tmp_path, _mut(fn), field_part, problem_part)


def test_every_bad_case_has_its_own_message(tmp_path):
    messages = set()
    for case in BAD_CASES.values():
        fn, field_part, problem_part = case
        path = tmp_path / 'bad.yaml'
        path.write_text(yaml.safe_dump(_mut(fn)))
        with pytest.raises(ConfigError) as info:
            load_scenario(path)
        messages.add(str(info.value))
    assert len(messages) == len(BAD_CASES) >= 15


def test_malformed_yaml(tmp_path):
    msg = reject(tmp_path, 'name: x\nrobots: [\n  - id: 0\n', '', 'malformed YAML at line')
    assert 'line' in msg


def test_duplicate_yaml_key(tmp_path):
    text = PAPER.read_text().replace('duration_s: 55.0', 'duration_s: 55.0\nduration_s: 60.0')
    reject(tmp_path, text, '', "duplicate key 'duration_s'")


def test_empty_file(tmp_path):
    reject(tmp_path, '', '', 'the file is empty')


def test_top_level_not_a_mapping(tmp_path):
    reject(tmp_path, '- 1\n- 2\n', '', 'must be a mapping')


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match='no such file'):
        load_scenario(tmp_path / 'nope.yaml')


def test_ellipse_overlap_against_known_geometry():
    # two unit circles 1.9 apart overlap, 2.1 apart do not; a thin ellipse crossing a circle
    # overlaps
    c = [[0.0, 0.0]]
    assert ellipses_overlap(c, [0.0], [[1.0, 1.0]], [[1.9, 0.0]], [0.0], [[1.0, 1.0]])[0]
    assert not ellipses_overlap(c, [0.0], [[1.0, 1.0]], [[2.1, 0.0]], [0.0], [[1.0, 1.0]])[0]
    assert ellipses_overlap(c, [0.0], [[3.0, 0.05]], [[0.0, 0.5]], [0.0], [[0.6, 0.6]])[0]
    # nested (one inside the other, no boundary crossing) counts as overlap
    assert ellipses_overlap(c, [0.0], [[3.0, 2.0]], [[0.2, 0.1]], [0.3], [[0.4, 0.1]])[0]
    # a rotated ellipse: reaches x = 1 only when turned along x
    assert ellipses_overlap(c, [0.0], [[1.0, 0.1]], [[1.5, 0.0]], [0.0], [[0.55, 0.55]])[0]
    assert not ellipses_overlap(
        c, [math.pi / 2], [[1.0, 0.1]], [[1.5, 0.0]], [0.0], [[0.55, 0.55]]
    )[0]


# ---------------------------------------------------------------------------------------------
# The command line: exit code 2, one line, no traceback
# ---------------------------------------------------------------------------------------------


def _formation(*args, cwd):
    return subprocess.run(
        [sys.executable, '-m', 'ament_formation.tools.cli', *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.parametrize('case', ['negative duration', 'self-loop', 'robot starts inside P'])
def test_cli_invalid_scenario_exit_2_single_line(tmp_path, case):
    fn, field_part, problem_part = BAD_CASES[case]
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(_mut(fn)))
    proc = _formation('sim', str(path), '--out', str(tmp_path / 'out'), cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert str(path) in lines[0] and field_part in lines[0] and problem_part in lines[0]
    assert 'Traceback' not in proc.stderr and proc.stdout == ''
    assert not (tmp_path / 'out').exists()


def test_cli_malformed_yaml_and_bad_option(tmp_path):
    path = tmp_path / 'broken.yaml'
    path.write_text('name: [unclosed\n')
    proc = _formation('sim', str(path), '--out', str(tmp_path / 'o'), cwd=tmp_path)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert 'malformed YAML' in proc.stderr
    proc = _formation(
        'sim', str(PAPER), '--out', str(tmp_path / 'o'), '--dt-s', '-0.001', cwd=tmp_path
    )
    assert (
        proc.returncode == 2
        and '--dt-s' in proc.stderr
        and len(proc.stderr.strip().splitlines()) == 1
    )
    proc = _formation('plot', str(tmp_path / 'no_run'), cwd=tmp_path)
    assert proc.returncode == 2 and 'no such run directory' in proc.stderr


# ---------------------------------------------------------------------------------------------
# The expect block and the checks made with it (core/sim/metrics.check_run)
# ---------------------------------------------------------------------------------------------


def test_expect_block_forms():
    data = base()
    data['expect'] = {
        'settled_rms_max_m': 0.02,
        'final_error_max_m': {'1': 0.05},
        'avoidance_entries': {0: 1, '1': [0, 2]},
        'min_clearance_m': -0.01,
        'min_inter_robot_distance_m': 0.3,
    }
    e = parse_scenario(data).expect
    assert e.settled_rms_max_m == ((0, 0.02), (1, 0.02))  # one value: every robot
    assert e.final_error_max_m == ((1, 0.05),)  # string ids as in JSON
    assert e.avoidance_entries == ((0, (1, 1)), (1, (0, 2)))  # a count or a [min, max] range
    assert e.min_clearance_m == -0.01 and e.min_inter_robot_distance_m == 0.3
    data.pop('expect')
    assert parse_scenario(data).expect.empty


def test_every_shipped_scenario_declares_what_a_run_must_achieve():
    for path in [PAPER, V_FORMATION, *sorted((ROOT / 'test' / 'data').glob('*.yaml'))]:
        assert not load_scenario(path).expect.empty, path


def _metrics(rms=(0.001, 0.004), entries=(1, 1), mission_end_s=57.3, pair_m=1.0, entries_p=0):
    # a run is complete when its mission ended (every reference at its end, S17.3): its
    # mission_end_s, no earlier than duration_s (55 s); None when it did not end (cut short)
    return {
        'sim_time_s': 9.8 if mission_end_s is None else mission_end_s,
        'mission_end_s': mission_end_s,
        'prohibited_entries': entries_p,
        'min_clearance_m': 0.03,
        'min_inter_robot_distance_m': pair_m,
        'robot_pair_min_distance_m': {'0-1': pair_m},
        'robots': {
            str(k): {'formation_rms_settled_m': r, 'final_error_m': 0.001, 'avoidance_entries': n}
            for k, (r, n) in enumerate(zip(rms, entries))
        },
    }


def test_check_run_passes_a_good_run_and_names_every_failed_check():
    from ament_formation.core.sim.metrics import check_run

    paper = load_scenario(PAPER)  # expect: RMS R0 <= 5 mm, R1 <= 15 mm, ...
    good = check_run(_metrics(), paper)
    assert good['ok'] is True and good['failure'] is None
    assert [c['name'] for c in good['checks']][:3] == [
        'completed',
        'prohibited_entries',
        'contact',
    ]

    bad = check_run(
        _metrics(rms=(0.0424, None), entries=(3, 1), mission_end_s=None, pair_m=0.15,
                 entries_p=1),
        paper,
    )
    failed = {c['name']: c for c in bad['checks'] if not c['ok']}
    assert set(failed) == {
        'completed',
        'prohibited_entries',
        'contact',
        'settled_rms_m[R0]',
        'settled_rms_m[R1]',
        'avoidance_entries[R0]',
    }
    assert failed['contact']['limit'] == pytest.approx(0.2)  # 2 x body radius
    assert failed['settled_rms_m[R1]']['value'] is None  # no settled window is a failure
    assert failed['completed']['value'] is None and good['checks'][0]['value'] == 57.3
    line = bad['failure']
    assert (
        '\n' not in line
        and 'completed: the mission did not end' in line
        and 'settled_rms_m[R0] 0.0424 > 0.005' in line
    )
    assert 'avoidance_entries[R0] 3 not in [1, 2]' in line and 'no settled window' in line
    # extra checks of the caller come first and count
    extra = check_run(
        _metrics(),
        paper,
        extra=[
            {
                'name': 'processes',
                'ok': False,
                'value': 'world:1',
                'limit': 'world:0',
                'op': '==',
                'detail': 'world crashed',
            }
        ],
    )
    assert extra['ok'] is False and extra['failure'].startswith(
        'processes world:1 != world:0 (world crashed)'
    )


def test_formation_sim_exits_1_naming_a_failed_expectation(tmp_path, capsys):
    """`formation sim` (in process: the simulator's kernels may be compiled already) judges the run
    with the same checks as `formation run`: a failed expectation is exit status 1, one line.
    """
    import json

    from ament_formation.tools.cli import main as formation

    data = yaml.safe_load((ROOT / 'test' / 'data' / 'paper_short.yaml').read_text())
    data['expect']['final_error_max_m'] = {0: 0.001}
    path = tmp_path / 'strict.yaml'
    path.write_text(yaml.safe_dump(data))
    assert formation(['sim', str(path), '--out', str(tmp_path / 'o'), '--no-figure']) == 1
    captured = capsys.readouterr()
    lines = [
        ln for ln in captured.err.strip().splitlines() if not ln.startswith('sim: t =')
    ]  # progress
    assert len(lines) == 1, captured.err
    assert (
        lines[0].startswith('formation sim: FAILED: final_error_m[R0]') and '> 0.001' in lines[0]
    )
    assert 'checks: FAILED' in captured.out
    metrics = json.loads((tmp_path / 'o' / 'metrics.json').read_text())
    assert metrics['ok'] is False and metrics['failure'] in lines[0]
    # the scenario as shipped passes
    assert (
        formation(
            [
                'sim',
                str(ROOT / 'test' / 'data' / 'paper_short.yaml'),
                '--out',
                str(tmp_path / 'p'),
                '--no-figure',
                '--quiet',
            ]
        )
        == 0
    )
    assert json.loads((tmp_path / 'p' / 'metrics.json').read_text())['ok'] is True
