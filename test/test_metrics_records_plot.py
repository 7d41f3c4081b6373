"""Metrics (docs/design.md §4) on synthetic runs with known answers; run directories round
trip; the figure is redrawn by `formation plot DIR`.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from ament_formation.core.model.ellipse import signed_distance_to_ellipse
from ament_formation.core.model.obstacles import ObstacleField
from ament_formation.core.scenario.loader import parse_scenario
from ament_formation.core.sim.metrics import (
    compute_metrics,
    count_entries,
    intervals,
    min_signed_distance,
)
from ament_formation.core.sim.records import read_run, write_run
from ament_formation.core.sim.trajectory import SimResult
from ament_formation.tools.cli import main as formation

DESIGN_KEYS = {
    'scenario',
    'sim_time_s',
    'wall_time_s',
    'prohibited_entries',
    'min_clearance_m',
    'min_inter_robot_distance_m',
    'robots',
    'mode_events',
    'graph_events',
    'mission_end_s',
    'mission_ratio',
}
ROBOT_KEYS = {
    'min_clearance_m',
    'avoidance_time_s',
    'avoidance_entries',
    'longest_avoidance_s',
    'avoiding_at_end',
    'formation_rms_settled_m',
    'final_error_m',
    'peak_torque_nm',
    'saturated_fraction',
}


def scenario(obstacles=None, robots=None, edges=None, duration_s=40.0):
    robots = robots or [
        {
            'id': 0,
            'leader': True,
            'initial_pose': [0.0, 0.25, 0.0],
            'path': {'type': 'line', 'start_m': [0.0, 0.25], 'heading_rad': 0.0, 'speed_mps': 0.1},
        },
        {'id': 1, 'slot_m': [0.0, -1.25], 'initial_pose': [0.0, -1.0, 0.0]},
    ]
    obstacles = (
        obstacles
        if obstacles is not None
        else [
            {'name': 'O1', 'center_m': [1.0, 0.0], 'semi_axes_m': [0.4, 0.15]},
            {
                'name': 'O2',
                'center_m': [3.0, -1.0],
                'semi_axes_m': [0.4, 0.15],
                'orientation_rad': math.pi / 2,
            },
        ]
    )
    return parse_scenario(
        {
            'name': 'synthetic',
            'duration_s': duration_s,
            'robots': robots,
            'graph': {'edges': edges if edges is not None else [[0, 1]]},
            'obstacles': obstacles,
        }
    )


def make_result(scen, t, xy, *, goal=None, avoiding=None, torque=None, saturated=None, **extra):
    """Build a SimResult from positions xy (T, N, 2); heading along the motion; obstacles from the
    scenario.
    """
    n_t, n = xy.shape[:2]
    state = np.zeros((n_t, n, 5))
    state[:, :, :2] = xy
    vel = np.gradient(xy, t, axis=0)
    state[:, :, 2] = np.arctan2(vel[..., 1], vel[..., 0])
    state[:, :, 3] = np.linalg.norm(vel, axis=-1)
    fld = ObstacleField(scen.obstacles)
    states = [fld.at(float(x)) for x in t]
    m = len(scen.obstacles)
    return SimResult(
        scenario_name=scen.name,
        robot_ids=scen.robot_ids,
        obstacle_names=tuple(o.name for o in scen.obstacles),
        t_s=t,
        state=state,
        torque_nm=torque if torque is not None else np.zeros((n_t, n, 2)),
        goal_m=goal if goal is not None else xy.copy(),
        avoiding=avoiding if avoiding is not None else np.zeros((n_t, n), bool),
        saturated=saturated if saturated is not None else np.zeros((n_t, n), bool),
        obstacle_center_m=np.stack([s.center_m for s in states]).reshape(n_t, m, 2),
        obstacle_phi_rad=np.stack([s.phi_rad for s in states]).reshape(n_t, m),
        **extra,
    )


def straight_run(scen, t):
    """R0 along y = 0.25 at 0.1 m/s (passes O1 at clearance 0.10 m); R1 along y = -1 straight
    through the centre of O2 (vertical 0.4 x 0.15: deepest point 0.15 m inside).
    """
    x = 0.1 * t
    xy = np.stack(
        [np.stack([x, np.full_like(x, 0.25)], -1), np.stack([x, np.full_like(x, -1.0)], -1)], 1
    )
    return xy


# ---------------------------------------------------------------------------------------------
# Metrics with known answers
# ---------------------------------------------------------------------------------------------


def test_straight_pass_clearance_and_one_entry():
    scen = scenario()
    t = np.round(np.arange(0.0, 40.0 + 1e-9, 0.01), 10)
    m = compute_metrics(make_result(scen, t, straight_run(scen, t), wall_time_s=0.5), scen)
    assert DESIGN_KEYS <= set(m) and all(ROBOT_KEYS <= set(r) for r in m['robots'].values())
    r0, r1 = m['robots']['0'], m['robots']['1']
    assert r0['min_clearance_m']['O1'] == pytest.approx(
        0.10, abs=1e-9
    )  # passes above the minor vertex
    assert r1['min_clearance_m']['O2'] == pytest.approx(-0.15, abs=1e-9)  # through the centre
    assert m['prohibited_entries'] == 1  # R1 in O2, counted once
    assert m['prohibited_entry_events'] == [
        {'t_s': pytest.approx(28.5, abs=0.011), 'robot': 1, 'target': 'O2'}
    ]
    assert m['min_clearance_m'] == pytest.approx(-0.15, abs=1e-9)
    assert m['min_inter_robot_distance_m'] == pytest.approx(1.25, abs=1e-12)
    assert m['sim_time_s'] == pytest.approx(40.0) and m['wall_time_s'] == 0.5
    json.dumps(m)  # plain JSON types


def test_mission_end_and_the_completed_check():
    """metrics.json carries the mission's end (every leader's reference at its end, S17.3) and
    its ratio to the free traversal (duration_s); ``completed`` is that the mission ended.
    """
    from ament_formation.core.sim.metrics import check_run

    scen = scenario()  # duration_s 40
    t = np.round(np.arange(0.0, 52.5 + 1e-9, 0.01), 10)
    m = compute_metrics(make_result(scen, t, straight_run(scen, t), mission_end_s=52.0), scen)
    assert m['mission_end_s'] == 52.0 and m['mission_ratio'] == pytest.approx(1.3)
    done = {c['name']: c for c in check_run(m, scen)['checks']}['completed']
    assert (done['ok'], done['value'], done['limit'], done['op']) == (True, 52.0, 40.0, '>=')
    # a run cut before its mission ended (the simulator's cap, a process that died)
    m = compute_metrics(make_result(scen, t, straight_run(scen, t)), scen)
    assert m['mission_end_s'] is None and m['mission_ratio'] is None
    checked = check_run(m, scen, measured=False)
    done = {c['name']: c for c in checked['checks']}['completed']
    assert done['ok'] is False and done['value'] is None and 'did not end' in done['detail']
    assert checked['ok'] is False and 'completed' in checked['failure']


def test_reached_goals_fails_a_run_whose_robot_stood_still_but_not_a_parked_goal():
    """``reached_goals``: when the mission ended, every robot within 0.5 m of its goal; a robot
    that stood still (a stop, a starved controller) fails the run even though the mission ended
    (its finish wait used up); a goal inside an avoided obstacle's Q is excepted (parked).
    """
    from ament_formation.core.sim.metrics import check_run, FAR_FROM_GOAL_M

    scen = scenario()
    t = np.round(np.arange(0.0, 52.5 + 1e-9, 0.01), 10)
    m = compute_metrics(make_result(scen, t, straight_run(scen, t), mission_end_s=52.0), scen)
    reached = {c['name']: c for c in check_run(m, scen)['checks']}['reached_goals']
    assert reached['ok'] and reached['value'] <= FAR_FROM_GOAL_M == reached['limit']
    worst = max(m['robots'], key=lambda k: m['robots'][k]['final_error_m'])
    m['robots'][worst]['final_error_m'] = 0.9  # stood still 0.9 m short
    checked = check_run(m, scen)
    reached = {c['name']: c for c in checked['checks']}['reached_goals']
    assert not reached['ok'] and reached['value'] == 0.9 and f'R{worst} ends 0.90 m' in (
        reached['detail'])
    assert not checked['ok'] and 'reached_goals 0.9 > 0.5' in checked['failure']
    m['robots'][worst]['goal_in_q_at_end'] = True  # its goal inside an obstacle's Q: parked
    assert 'reached_goals' not in (check_run(m, scen)['failure'] or '')


def test_each_entry_into_p_is_counted_once_and_robot_pairs_count():
    scen = scenario(
        obstacles=[{'name': 'W', 'center_m': [2.0, 0.0], 'semi_axes_m': [0.3, 0.3]}],
        robots=[
            {
                'id': 0,
                'leader': True,
                'initial_pose': [0.0, 0.0, 0.0],
                'path': {'type': 'line', 'start_m': [0, 0], 'heading_rad': 0, 'speed_mps': 0.1},
            },
            {'id': 1, 'slot_m': [0.0, 1.0], 'initial_pose': [0.0, 1.0, 0.0]},
        ],
    )
    t = np.arange(0.0, 30.0 + 1e-9, 0.01)
    # R0 dips into W three times (x = 2 + 0.4 cos(2 pi t / 20) on y = 0: |x - 2| < 0.3 around t =
    # 5,
    # 15, 25 s); R1 closes in on R0 to 0.2 m once
    x0 = 2.0 + 0.4 * np.cos(2 * np.pi * t / 20.0)
    y1 = np.where((t > 10) & (t < 12), 0.2, 1.0)
    xy = np.stack([np.stack([x0, 0 * t], -1), np.stack([x0, y1], -1)], 1)
    m = compute_metrics(make_result(scen, t, xy), scen)
    inside_runs = count_entries(np.abs(x0 - 2.0) < 0.3)
    assert inside_runs == 3
    pair = [e for e in m['prohibited_entry_events'] if e['target'] == 'robot_1']
    assert len(pair) == 1 and pair[0]['t_s'] == pytest.approx(10.01, abs=0.011)
    assert m['prohibited_entries'] == 3 + 1
    assert m['min_inter_robot_distance_m'] == pytest.approx(0.2, abs=1e-12)
    assert m['robots']['0']['min_clearance_m']['W'] == pytest.approx(-0.3, abs=1e-6)


def test_avoidance_time_entries_rms_peaks_and_saturation():
    scen = scenario()
    t = np.round(np.arange(0.0, 40.0 + 1e-9, 0.01), 10)
    xy = straight_run(scen, t)
    n_t = len(t)
    avoiding = np.zeros((n_t, 2), bool)
    avoiding[(t >= 2.0) & (t < 5.0), 0] = True  # 3.0 s
    avoiding[(t >= 6.0) & (t < 6.5), 0] = True  # + 0.5 s, second entry; last exit 6.5 s
    avoiding[(t >= 10.0) & (t < 12.0), 1] = True  # R1: 2.0 s; team's last exit 12.0 s
    goal = xy.copy()
    err = np.where(t < 22.0, 0.05, 0.003)  # settled window starts at 12 + 10 = 22 s
    goal[:, 0, 1] += err
    goal[:, 1, 0] += np.where(t < 22.0, 0.02, 0.004)
    torque = np.zeros((n_t, 2, 2))
    torque[:, 0, 0] = 0.05 * np.sin(t)
    torque[:, 0, 1] = -0.12 * (t == 7.0)
    saturated = np.zeros((n_t, 2), bool)
    saturated[: n_t // 4, 1] = True
    res = make_result(
        scen,
        t,
        xy,
        goal=goal,
        avoiding=avoiding,
        torque=torque,
        saturated=saturated,
        mode_events=[
            {'t_s': 2.0, 'robot': 0, 'event': 'enter', 'target': 'O1', 'direction': 'cw'}
        ],
        graph_events=[{'t_s': 0.0, 'parents': {'0': None, '1': 0}}],
    )
    m = compute_metrics(res, scen)
    r0, r1 = m['robots']['0'], m['robots']['1']
    assert r0['avoidance_time_s'] == pytest.approx(3.5, abs=1e-9) and r0['avoidance_entries'] == 2
    assert r1['avoidance_time_s'] == pytest.approx(2.0, abs=1e-9) and r1['avoidance_entries'] == 1
    assert r0['longest_avoidance_s'] == pytest.approx(3.0, abs=1e-9)
    assert r1['longest_avoidance_s'] == pytest.approx(2.0, abs=1e-9)
    assert r0['avoiding_at_end'] is False and r1['avoiding_at_end'] is False
    assert r0['settled_from_s'] == pytest.approx(22.0) and r1['settled_from_s'] == pytest.approx(
        22.0
    )
    assert r0['formation_rms_settled_m'] == pytest.approx(0.003, rel=1e-9)
    assert r1['formation_rms_settled_m'] == pytest.approx(0.004, rel=1e-9)
    assert r0['final_error_m'] == pytest.approx(0.003, rel=1e-9)
    # own-exit variant for R0: from 16.5 s, mixes 5.5 s of 0.05 with 18 s of 0.003
    w = t >= 16.5 - 1e-9
    assert r0['formation_rms_after_own_exit_m'] == pytest.approx(
        float(np.sqrt(np.mean(err[w] ** 2))), rel=1e-9
    )
    assert r0['peak_torque_nm'] == pytest.approx([0.05, 0.12], abs=1e-4)
    assert r1['peak_torque_nm'] == [0.0, 0.0]
    assert (
        r1['saturated_fraction'] == pytest.approx(0.25, abs=1e-3)
        and r0['saturated_fraction'] == 0.0
    )
    assert m['mode_events'] == res.mode_events and m['graph_events'][0]['parents'] == {
        '0': None,
        '1': 0,
    }


def test_interval_helpers():
    t = np.arange(10) * 0.5
    flag = np.array([1, 1, 0, 0, 1, 0, 0, 1, 1, 1], bool)
    assert intervals(flag, t) == [(0.0, 1.0), (2.0, 2.5), (3.5, 4.5)]
    assert count_entries(flag) == 3 and count_entries(np.zeros(4, bool)) == 0


def test_pruned_min_distance_equals_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n_t = 400
        pts = np.cumsum(rng.normal(0, 0.02, (n_t, 2)), axis=0) + rng.uniform(-1, 1, 2)
        centers = np.cumsum(rng.normal(0, 0.005, (n_t, 2)), axis=0)
        phi = np.cumsum(rng.normal(0, 0.01, n_t))
        r1, r2 = rng.uniform(0.2, 0.6), rng.uniform(0.05, 0.2)
        got, inside = min_signed_distance(pts, centers, phi, r1, r2)
        brute = signed_distance_to_ellipse(pts, centers, phi, r1, r2)
        assert got == pytest.approx(brute.min(), abs=1e-12)
        np.testing.assert_array_equal(inside, brute < 0)


# ---------------------------------------------------------------------------------------------
# Run directory and the figure
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory):
    scen = scenario()
    t = np.round(np.arange(0.0, 40.0 + 1e-9, 0.02), 10)
    xy = straight_run(scen, t)
    avoiding = np.zeros((len(t), 2), bool)
    avoiding[(t >= 5.0) & (t < 15.0), 0] = True
    torque = np.stack([0.03 * np.sin(t), 0.02 * np.cos(t)], -1)[:, None, :].repeat(2, axis=1)
    res = make_result(
        scen,
        t,
        xy,
        avoiding=avoiding,
        torque=torque,
        wall_time_s=0.25,
        reaching=[
            {'robot': 0, 't_s': 5.0, 'sigma0_inf_mps': 0.05, 't_reach_s': 0.1, 'bound_s': 0.33}
        ],
    )
    out = tmp_path_factory.mktemp('run')
    write_run(out, res, scen, compute_metrics(res, scen))
    return out, res, scen


def test_run_directory_round_trip(run_dir):
    out, res, scen = run_dir
    assert {p.name for p in out.iterdir()} >= {
        'metrics.json',
        'trajectories.csv',
        'obstacles.csv',
        'events.json',
        'run.json',
        'scenario.yaml',
    }
    back, scen_back, metrics = read_run(out)
    assert dataclasses.replace(scen_back, source=None) == scen
    assert scen_back.source == str(out / 'scenario.yaml')
    assert back.robot_ids == res.robot_ids and back.obstacle_names == res.obstacle_names
    np.testing.assert_allclose(back.t_s, res.t_s, rtol=1e-9)
    np.testing.assert_allclose(back.state, res.state, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back.torque_nm, res.torque_nm, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back.obstacle_center_m, res.obstacle_center_m, atol=1e-12)
    np.testing.assert_array_equal(back.avoiding, res.avoiding)
    assert back.reaching == res.reaching and back.wall_time_s == 0.25
    assert metrics['robots']['0']['avoidance_time_s'] == pytest.approx(10.0)
    assert metrics == json.loads((out / 'metrics.json').read_text())
    # metrics recomputed from the files equal the ones written
    again = compute_metrics(back, scen_back)
    assert again['robots']['1']['min_clearance_m']['O2'] == pytest.approx(
        metrics['robots']['1']['min_clearance_m']['O2'], abs=1e-9
    )


def test_formation_plot_redraws_the_figure(run_dir, capsys):
    import matplotlib.image as mpimg

    out, _res, _scen = run_dir
    fig = out / 'figure.png'
    assert not fig.exists()
    assert formation(['plot', str(out)]) == 0
    assert fig.exists() and fig.stat().st_size > 40_000
    img = mpimg.imread(fig)[..., :3]
    h, w = img.shape[:2]
    assert w > 1000 and h > 700
    non_white = np.mean(np.any(img < 0.9, axis=-1))
    assert 0.02 < non_white < 0.6
    # robot colours tab:blue and tab:orange are drawn (paths, thick avoidance segment, torques)
    blue = np.all(np.abs(img - np.array([31, 119, 180]) / 255) < 0.06, axis=-1).sum()
    orange = np.all(np.abs(img - np.array([255, 127, 14]) / 255) < 0.06, axis=-1).sum()
    assert blue > 500 and orange > 200
    # the avoidance of R0 (t 5..15 s) is drawn thick: more blue than orange even though both
    # robots' trajectories are equally long
    assert blue > orange
    assert 'figure.png' in capsys.readouterr().out


def test_read_run_rejects_a_damaged_directory(run_dir, tmp_path):
    from ament_formation.core.errors import ConfigError

    out, _res, _scen = run_dir
    broken = tmp_path / 'broken'
    broken.mkdir()
    for name in ('run.json', 'scenario.yaml', 'obstacles.csv', 'events.json'):
        (broken / name).write_text((out / name).read_text())
    with pytest.raises(ConfigError, match='trajectories.csv: missing'):
        read_run(broken)
    (broken / 'trajectories.csv').write_text('t_s,r0_x_m\n0,1\n')
    with pytest.raises(ConfigError, match='r0_y_m: missing column'):
        read_run(broken)


def test_formation_sim_writes_a_complete_run_directory(tmp_path, capsys):
    """`formation sim` end to end on the paper scenario cut to a 3 s mission (the simulator's
    behaviour over the whole run is tested with the simulator).
    """
    from pathlib import Path

    import yaml

    data = yaml.safe_load(
        (Path(__file__).resolve().parents[1] / 'config/scenarios/paper.yaml').read_text()
    )
    data['duration_s'] = 3.0
    data.pop('expect', None)  # paper.yaml's expectations need the whole run (a settled window)
    scen_file = tmp_path / 'short.yaml'
    scen_file.write_text(yaml.safe_dump(data))
    out = tmp_path / 'run'
    assert formation(['sim', str(scen_file), '--out', str(out), '--record-every-s', '0.05']) == 0
    summary = capsys.readouterr().out
    assert 'scenario paper' in summary and 'R1:' in summary
    m = json.loads((out / 'metrics.json').read_text())
    assert DESIGN_KEYS <= set(m) and set(m['robots']) == {'0', '1'}
    # the run lasts until the mission ends (the references at their ends), not less than 3 s
    assert 3.0 <= m['mission_end_s'] < 6.0 and m['mission_ratio'] == m['mission_end_s'] / 3.0
    assert m['sim_time_s'] == pytest.approx(m['mission_end_s'], abs=0.051)
    assert m['ok'] and {c['name']: c['ok'] for c in m['checks']}['completed'] is True
    assert m['prohibited_entries'] == 0 and m['min_clearance_m'] > 0.5
    assert (out / 'figure.png').stat().st_size > 20_000
    back, _scen, _m = read_run(out)
    assert back.state.shape[1:] == (2, 5) and len(back.t_s) >= 60
    # the follower starts 0.2 m off its slot and closes the gap
    err = back.formation_error_m[:, 1]
    assert err[0] == pytest.approx(0.2, abs=1e-9) and err[-1] < 0.2
    assert '(metrics.json, figure.png, trajectories.csv' in summary
    # --no-figure: no figure, and the summary does not claim one
    assert formation(['sim', str(scen_file), '--out', str(tmp_path / 'nofig'), '--no-figure']) == 0
    summary = capsys.readouterr().out
    assert not (tmp_path / 'nofig' / 'figure.png').exists()
    assert 'figure.png' not in summary and '(metrics.json, trajectories.csv' in summary


def test_progress_is_silent_for_short_runs_and_reports_long_ones():
    import io

    from ament_formation.tools.sim_cmd import _Progress

    class Clock:
        now = 0.0

        def __call__(self):
            return self.now

    clock, stream = Clock(), io.StringIO()
    progress = _Progress(stream, delay_s=1.0, clock=clock)
    clock.now = 0.5
    progress(10.0, 55.0)
    assert stream.getvalue() == ''  # within the first second: silent
    for k in range(1, 30):
        clock.now = 0.5 + k * 0.5
        progress(55.0 * k / 30, 55.0)
    lines = stream.getvalue().splitlines()
    assert 2 <= len(lines) <= 4  # not a tty: a line every 5 s of wall time
    assert lines[0].startswith('sim: t =') and '/ 55.0 s' in lines[0] and '%' in lines[0]
