"""The fast simulator with camera sensing (core/sim/sensed.py, issue 13): camera poses with
latency, noise and drops, every robot's agent (one AgentBatch) at the controller's period, the
coordinator; runs until the mission ends; the record; and the `formation sim --sensing` option.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from ament_formation.core.config_files import config_file
from ament_formation.core.errors import ConfigError
from ament_formation.core.scenario.loader import load_scenario, parse_scenario
from ament_formation.core.sim.campaign import classify
from ament_formation.core.sim.metrics import check_run, compute_metrics
from ament_formation.core.sim.sensed import (
    MEASURED_NOISE_M,
    MEASURED_NOISE_RAD,
    SensedResult,
    SensingParams,
    simulate_sensed,
)
from ament_formation.core.sim.simulator import simulate
from ament_formation.core.sim.trajectory import SimResult
from ament_formation.tools.cli import main as formation

DATA = Path(__file__).resolve().parent / 'data'


@pytest.fixture(scope='module')
def short():
    return load_scenario(DATA / 'paper_short.yaml')


@pytest.fixture(scope='module')
def ideal(short):
    return simulate(short)


@pytest.fixture(scope='module')
def camera(short):
    return simulate_sensed(short, SensingParams.preset('camera'))


def _metrics(result, scenario):
    return check_run(compute_metrics(result, scenario), scenario)


def test_presets_carry_the_measured_and_the_stress_figures():
    cam = SensingParams.preset('camera')
    assert cam.fps is None and cam.drop_prob == 0.0  # the scenario's rate; 100 % detection
    assert 2.448 * cam.noise_m == pytest.approx(0.43e-3)  # radial p95 0.43 mm
    assert 1.96 * cam.noise_rad == pytest.approx(np.radians(0.30))  # heading p95 0.30 deg
    assert cam.noise_m == MEASURED_NOISE_M and cam.noise_rad == MEASURED_NOISE_RAD
    assert 0.008 <= cam.latency_s <= 0.023  # capture -> pose p50 .. p95 (docs/camera.md)
    stress = SensingParams.preset('camera-stress')
    assert (stress.fps, stress.latency_s, stress.noise_m, stress.drop_prob) == (
        30.0,
        0.050,
        0.003,
        0.05,
    )
    assert SensingParams.preset('camera', seed=7, latency_s=None).seed == 7
    # the robot side is the shipped nodes' configuration
    ctrl = yaml.safe_load(config_file('params/formation_controller.yaml').read_text())
    coord = yaml.safe_load(config_file('params/formation_coordinator.yaml').read_text())
    ctrl = ctrl['/**/formation_controller']['ros__parameters']
    coord = next(iter(coord.values()))['ros__parameters']
    assert cam.control_rate_hz == ctrl['control_rate_hz']
    assert cam.camera_gain == ctrl['camera_gain']
    assert cam.encounter_rate_hz == coord['encounter_rate_hz']
    assert cam.republish_s == coord['republish_s']


@pytest.mark.parametrize(
    'field, value',
    [
        ('fps', 0.0),
        ('latency_s', -0.01),
        ('noise_m', float('nan')),
        ('drop_prob', 1.0),
        ('seed', -1),
        ('control_rate_hz', 0.5),
    ],
)
def test_bad_sensing_values_name_the_field(field, value):
    with pytest.raises(ConfigError, match=field):
        SensingParams(**{field: value})
    with pytest.raises(ConfigError, match='sensing'):
        SensingParams.preset('sonar')


def test_camera_run_is_a_simresult_and_stays_accurate(short, camera):
    assert isinstance(camera, SimResult) and isinstance(camera, SensedResult)
    m = _metrics(camera, short)
    assert m['ok'], m['failure']
    assert m['prohibited_entries'] == 0
    assert m['min_clearance_m'] > 0.05  # ideal 0.062 m
    assert m['robots']['0']['final_error_m'] < 0.012  # ideal 8.3 mm (after its detour)
    assert m['robots']['1']['final_error_m'] < 0.003  # ideal 1.4 mm
    assert [(e['robot'], e['event'], e['target']) for e in camera.mode_events] == [
        (0, 'enter', 'O1'),
        (0, 'exit', 'O1'),
    ]
    s = camera.sensing
    assert s['poses_dropped'] == 0 and s['poses_sent'] == 2 * s['frames']
    # 30 fps for the whole run, which lasts until the mission ends (S17.3), after duration_s
    assert s['frames'] == pytest.approx(30 * camera.t_s[-1], abs=1)
    assert s['estimator']['camera_accepted'] == s['poses_sent'] + 2 * 10  # + the pre-start frames
    assert s['estimate_error_m']['rms'] < 0.5e-3  # the estimator fuses 0.18 mm noise


def test_the_record_is_the_true_run_until_the_mission_ends(short, camera):
    """The record of a sensed run: every 10 ms from t = 0 to the end of the mission (every
    reference at its end, S17.3, which is no earlier than duration_s); the goals are the
    formation's on the true states, at the coordinator's progress; avoiding follows the mode
    events.
    """
    rec = camera
    n = rec.t_s.size
    assert rec.state.shape == (n, 2, 5) and rec.torque_nm.shape == (n, 2, 2)
    np.testing.assert_allclose(np.diff(rec.t_s), 0.01, atol=1e-9)
    assert short.duration_s <= rec.mission_end_s <= short.duration_s + 5.0
    assert rec.nominal_duration_s == short.duration_s
    assert rec.mission_end_s <= rec.t_s[-1] < rec.mission_end_s + 0.02
    assert np.abs(rec.torque_nm).max() <= short.robot(0).params.torque_limit_nm
    # the leader's progress: from 0, never backwards, to the end of its path; a follower has none
    s = rec.progress_s[:, 0]
    assert s[0] == 0.0 and np.all(np.diff(s) >= 0.0)
    assert s[-1] == pytest.approx(short.duration_s, abs=1e-9)
    assert np.all(rec.progress_s[:, 1] == 0.0)
    # goals: r(s) for the leader, its true p + delta for the follower
    path = short.robot(0).path
    for k in range(0, n, 97):
        r, _, _ = path.reference(float(s[k]))
        np.testing.assert_allclose(rec.goal_m[k, 0], r, atol=1e-6)
    np.testing.assert_allclose(rec.goal_m[:, 1], rec.state[:, 0, :2] + [0.0, 1.2], atol=1e-12)
    # the leader slowed down for its detour: progress fell behind the clock (about 0.1 s, as in
    # the ideal run) and no further after it, so the mission ended that much after duration_s
    lag = 12.0 - s[np.searchsorted(rec.t_s, 12.0)]
    assert 0.05 < lag < 0.2
    assert rec.mission_end_s - short.duration_s == pytest.approx(lag, abs=0.03)
    # avoiding: from each enter to its exit
    (enter, exit_), = [(a['t_s'], b['t_s']) for a, b in
                       zip(rec.mode_events[::2], rec.mode_events[1::2])]
    inside = (rec.t_s >= enter + 0.011) & (rec.t_s < exit_ - 0.011)
    outside = (rec.t_s < enter - 0.011) | (rec.t_s >= exit_ + 0.011)
    assert rec.avoiding[inside, 0].all() and not rec.avoiding[outside, 0].any()
    assert not rec.avoiding[:, 1].any()
    assert rec.graph_events[0] == {'t_s': 0.0, 'parents': {'0': None, '1': 0}}
    np.testing.assert_allclose(rec.obstacle_center_m[:, 0], [[0.55, -0.2]] * n)


def test_a_hold_runs_on_past_the_mission_end_on_the_same_run(short, camera):
    held = simulate_sensed(short, SensingParams.preset('camera'), hold_s=2.0)
    assert held.mission_end_s == camera.mission_end_s
    assert held.t_s[-1] == pytest.approx(camera.t_s[-1] + 2.0, abs=0.011)
    n = camera.t_s.size
    np.testing.assert_array_equal(held.state[:n], camera.state)
    np.testing.assert_array_equal(held.torque_nm[:n], camera.torque_nm)
    # at rest at its end, the leader's reference holds still, and so does the team
    assert np.all(held.progress_s[n:, 0] == short.duration_s)
    err = np.hypot(*(held.state[-1, :, :2] - held.goal_m[-1]).T)
    assert err.max() < 0.012


@pytest.mark.parametrize('name', ['paper', 'v_formation'])
def test_camera_sensing_gives_the_ideal_runs_classes_on_the_shipped_scenarios(name):
    """The shipped scenarios, ideal and with the measured camera: both pass their checks, and
    the campaign's failure classes (core/sim/campaign.py) agree: none.
    """
    sc = load_scenario(config_file(f'scenarios/{name}.yaml'))
    ideal = simulate(sc)
    cam = simulate_sensed(sc, SensingParams.preset('camera', seed=5))
    found = {}
    for label, res in (('ideal', ideal), ('camera', cam)):
        m = compute_metrics(res, sc)
        found[label] = classify(m, res, sc)[0]
        checked = check_run(m, sc)
        assert checked['ok'], (label, checked['failure'])
        assert res.mission_end_s is not None and res.mission_end_s >= sc.duration_s
    assert found['camera'] == found['ideal'] == []

    # the same detours: each robot enters the same obstacles
    def entered(res):
        return sorted({(e['robot'], e['target']) for e in res.mode_events
                       if e['event'] == 'enter' and e['mode'] == 'obstacle'})

    assert entered(cam) == entered(ideal)
    assert cam.mission_end_s == pytest.approx(ideal.mission_end_s, abs=2.0)


def test_perfect_sensing_is_close_to_the_ideal_run(short, ideal):
    perfect = simulate_sensed(short, SensingParams.preset('camera-perfect'))
    # both run until the mission ends (S17.3): the coordinator sees it at its next decision
    # (every 20 ms here, every 10 ms in the ideal run); the records agree on the common span
    assert perfect.mission_end_s == pytest.approx(ideal.mission_end_s, abs=0.02 + 1e-9)
    n = min(perfect.t_s.size, ideal.t_s.size)
    assert n >= 100 * short.duration_s and abs(perfect.t_s.size - ideal.t_s.size) <= 3
    np.testing.assert_allclose(perfect.t_s[:n], ideal.t_s[:n])
    # the law at 100 Hz on the broadcasts of the last period vs at 1 kHz on the true state (at
    # most 2.7 mm, just after the leader leaves O1 20 ms later than in the ideal run)
    assert np.abs(perfect.state[:n, :, :2] - ideal.state[:n, :, :2]).max() < 3e-3
    assert perfect.sensing['estimate_error_m']['max'] < 1e-4
    ev_i = [(e['robot'], e['event'], e['target']) for e in ideal.mode_events]
    ev_p = [(e['robot'], e['event'], e['target']) for e in perfect.mode_events]
    assert ev_p == ev_i
    for a, b in zip(perfect.mode_events, ideal.mode_events):
        assert abs(a['t_s'] - b['t_s']) <= 0.05
    assert perfect.graph_events == ideal.graph_events


def test_a_seed_reproduces_the_run_and_another_seed_does_not(short, camera):
    again = simulate_sensed(short, SensingParams.preset('camera'))
    np.testing.assert_array_equal(again.state, camera.state)
    np.testing.assert_array_equal(again.torque_nm, camera.torque_nm)
    assert again.mode_events == camera.mode_events
    other = simulate_sensed(short, SensingParams.preset('camera', seed=1))
    assert not np.array_equal(other.state, camera.state)


def test_dropouts_happen_and_the_estimator_bridges_them(short):
    res = simulate_sensed(
        short, SensingParams.preset('camera-stress', drop_prob=0.3, seed=3, fps=20.0)
    )
    s = res.sensing
    total = 2 * s['frames']
    assert s['frames'] == pytest.approx(20 * res.t_s[-1], abs=1)  # until the mission's end
    assert s['poses_sent'] + s['poses_dropped'] == total
    assert 0.22 * total < s['poses_dropped'] < 0.38 * total  # binomial, > 5 sigma wide
    est = s['estimator']
    # every pose sent is fused (but the last frame, still in flight at the end; plus those of the
    # pre-start frames that were not dropped)
    assert est['rejected_outlier'] == 0
    assert s['poses_sent'] - 2 <= est['camera_accepted'] <= s['poses_sent'] + 2 * 10
    m = _metrics(res, short)
    assert m['prohibited_entries'] == 0
    assert m['robots']['1']['final_error_m'] < 0.015


@pytest.mark.parametrize('hear_all', [False, True])
def test_robot_encounter_goes_through_the_coordinator(hear_all):
    # (hear_all False: the robots hear each other only once their camera poses come in range)
    sc = load_scenario(DATA / 'head_on.yaml')
    res = simulate_sensed(sc, SensingParams.preset('camera-stress', hear_all=hear_all))
    m = _metrics(res, sc)
    assert m['ok'], m['failure']
    assert m['min_inter_robot_distance_m'] > 0.3  # ideal 0.347 m
    kinds = {(e['robot'], e['event'], e['mode']) for e in res.mode_events}
    assert kinds == {(r, ev, 'mutual') for r in (0, 1) for ev in ('enter', 'exit')}


@pytest.mark.parametrize('lanes, sense', [((0.70, 0.50), 'cw'), ((0.50, 0.70), 'ccw')])
def test_a_sensed_pair_turns_the_way_both_goals_agree_on(lanes, sense):
    # docs/law-changes.md section 14, through the coordinator's arbiter and both controllers:
    # robot 0 drives east in the northern lane, robot 1 west in the southern one, so both goals
    # lie clockwise round the other robot (mirrored: counter-clockwise). The two robots are two
    # teams: the coordinator has the later-ranked one yield (S7.5, no mutual pair outside an
    # emergency), and whichever yields turns the way its goal (and so both goals) asks
    mapping = yaml.safe_load((DATA / 'head_on.yaml').read_text())
    for robot, y in zip(mapping['robots'], lanes):
        robot['path']['start_m'][1] = robot['initial_pose'][1] = y
    sc = parse_scenario(mapping, 'two_lanes')
    res = simulate_sensed(sc, SensingParams.preset('camera', seed=3))
    enters = [
        (e['robot'], e['mode'], e['direction']) for e in res.mode_events if e['event'] == 'enter'
    ]
    assert len(enters) == 1 and enters[0][1:] == ('yield', sense), enters
    assert enters[0][0] in (0, 1)
    assert compute_metrics(res, sc)['min_inter_robot_distance_m'] > 0.3


def test_cli_sensing_option_writes_metrics_and_exit_status_follows_the_checks(tmp_path, capsys):
    out = tmp_path / 'run'
    args = ['sim', str(DATA / 'paper_short.yaml'), '--out', str(out), '--no-figure', '--quiet']
    rc = formation([*args, '--sensing', 'camera', '--sensing-seed', '4'])
    metrics = json.loads((out / 'metrics.json').read_text())
    assert rc == (0 if metrics['ok'] else 1) == 0
    assert metrics['sensing']['model'] == 'camera'
    assert metrics['sensing']['params']['seed'] == 4
    assert metrics['sensing']['params']['fps'] == 30.0
    # a scenario whose expectation the sensed run cannot meet: exit 1, one line naming it
    sc = yaml.safe_load((DATA / 'paper_short.yaml').read_text())
    sc['expect']['final_error_max_m'] = {0: 0.0001, 1: 0.015}
    strict = tmp_path / 'strict.yaml'
    strict.write_text(yaml.safe_dump(sc))
    capsys.readouterr()
    rc = formation(
        [
            'sim',
            str(strict),
            '--out',
            str(tmp_path / 'r2'),
            '--no-figure',
            '--quiet',
            '--sensing',
            'camera-stress',
            '--camera-latency-s',
            '0.03',
        ]
    )
    metrics = json.loads((tmp_path / 'r2' / 'metrics.json').read_text())
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and not metrics['ok']
    assert metrics['sensing']['params']['latency_s'] == 0.03
    assert len(err) == 1 and 'final_error_m[R0]' in err[0]


@pytest.mark.parametrize(
    'extra, option',
    [
        (['--sensing', 'sonar'], '--sensing'),
        (['--camera-drop', '0.1'], '--camera-drop'),  # an override needs a camera model
        (['--sensing', 'camera', '--camera-drop', '1.5'], '--camera-drop'),
        (['--sensing', 'camera', '--camera-noise-m', 'x'], '--camera-noise-m'),
        (['--sensing', 'camera', '--sensing-seed', '2.5'], '--sensing-seed'),
        (['--sensing', 'camera', '--camera-fps', '-30'], '--camera-fps'),
        (['--sensing', 'camera', '--dt-s', '0.02', '--record-every-s', '0.02'], '--dt-s'),
    ],
)
def test_bad_sensing_options_exit_2_with_one_line(tmp_path, capsys, extra, option):
    rc = formation(['sim', str(DATA / 'paper_short.yaml'), '--out', str(tmp_path / 'r'), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith(f'formation sim: {option}:'), err
    assert not (tmp_path / 'r').exists()


# --------------------------------------------------------------------------- the compiled loop


def _python_loop(scenario, sensing, hold_s=0.0):
    """The sensed run through the Python interfaces, period by period (the loop of
    simulate_sensed before issue 34 compiled it): the twin, the camera's queue, the agents'
    AgentBatch.tick, the coordinator's state/report/reported_avoiding/decide, the Publisher and
    AgentBatch.assign. Returns (state, torque, mode events, graph events, frames, error sum).
    """
    from ament_formation.core.control.agent import broadcast_k, frame_k, RUNNING, wheels_k
    from ament_formation.core.control.coordinator import Publisher
    from ament_formation.core.control.progress import max_time_s
    from ament_formation.core.sim.sensed import _Loop, _parents_json

    dt = 0.001
    fps = sensing.frame_rate_hz(scenario)
    loop = _Loop(scenario, sensing, dt)
    loop.prestart(fps)
    loop.twin.start()
    tw, ag, coord, cam = loop.twin, loop.agents, loop.coord, loop.camera
    st, sc, prm, rows = ag.state, ag.static, loop.params, loop.rows
    publisher, reports = Publisher(sensing.republish_s), [None] * len(loop.ids)
    states, torques, err_sq = [], [], 0.0
    k_cap = int(round(max_time_s(scenario.duration_s) / dt))
    k, k_end, next_frame, cap_every = 0, k_cap, 0, 1.0 / (fps * dt)
    while k < k_end:
        t = k * dt
        if k >= next_frame * cap_every - 1e-9:
            cam.capture(t, loop.true_pose())
            next_frame += 1
        if k % 10 == 0:  # 100 Hz
            wheels_k(t, tw.wheel_angle_rad[rows], tw.wheel_rate_radps[rows], st, sc)
            for pose, kept, stamp in cam.deliver(t):
                frame_k(stamp, pose, kept, st, sc, prm.hear_all, prm.hear_hysteresis_m)
            due = round(loop.b_t / 0.01) % prm.state_every == 0  # states at state_rate_hz
            broadcast_k(loop.b_t, loop.bx, loop.ba, loop.bmode, loop.sent, st, sc, prm.hear_all,
                        due)
            ag.tick(t)
            e = np.hypot(*(ag.out.state[:, :2] - tw.state[rows, :2]).T)
            err_sq += float(e @ e)
            loop.mode_events.extend(ag.events)
            loop.bx[:], loop.ba[:], loop.bmode[:] = ag.out.state, ag.out.accel, ag.out.mode
            loop.b_t = t
            loop.bmode[st.status != RUNNING] = (0.0, -1.0, 1.0)
            for r, rid in enumerate(loop.ids):
                if round(t / 0.01) % prm.state_every == 0:
                    coord.state(rid, ag.out.state[r], t)
                key = (int(st.status[r]), *ag.out.mode[r].tolist())
                if key != reports[r]:
                    reports[r] = key
                    coord.report(rid, ag.mode_dict(r))
            parents = coord.reported_avoiding()
            if parents is not None:
                ag.set_graph(parents, 0.0)
                graph = _parents_json(parents)
                if graph != loop.graph_events[-1]['parents']:
                    loop.graph_events.append({'t_s': round(t, 9), 'parents': graph})
            if k % 20 == 0:  # 50 Hz
                assignments, rates = coord.decide(t)
                if publisher.due(t, assignments, rates):
                    ag.assign(t, assignments, rates)
            if coord.mission_end_s is not None and k_end == k_cap:
                k_end = k + int(round(hold_s / dt)) + 1
        if k % 10 == 0:
            states.append(tw.state[rows].copy())
            torques.append(ag.out.torque.copy())
        nxt = min(k_end, (k // 10 + 1) * 10, int(np.ceil(next_frame * cap_every - 1e-9)))
        tw.advance((nxt - k) * dt, ag.out.torque[np.argsort(rows)])
        k = nxt
    return (np.array(states), np.array(torques), loop.mode_events, loop.graph_events,
            cam.frames, err_sq)


@pytest.mark.parametrize('name, preset, state_hz', [('head_on', 'camera-stress', 100.0),
                                                    ('redundant_chain', 'camera', 100.0),
                                                    ('head_on', 'camera', 25.0)])
def test_the_compiled_loop_is_the_python_interfaces_bit_for_bit(name, preset, state_hz):
    """simulate_sensed runs the mission in one compiled loop (issue 34); fed the same camera
    draws, it is the agents', the coordinator's, the publisher's and the twin's Python
    interfaces period by period, bit for bit: a head-on mutual pair (its drift resent as it
    moves; hearing by range), and a chain whose follower turns onto an obstacle (the graph
    rewired) and stays parked there; the pair again with states sent every 4th period.
    """
    sc = load_scenario(DATA / f'{name}.yaml')
    sensing = SensingParams.preset(preset, seed=7, state_rate_hz=state_hz)
    res = simulate_sensed(sc, sensing, hold_s=1.0)
    state, torque, events, graphs, frames, err_sq = _python_loop(sc, sensing, hold_s=1.0)
    assert res.state.shape == state.shape
    assert res.state.tobytes() == state.tobytes() and res.torque_nm.tobytes() == torque.tobytes()
    assert res.mode_events == events and len(events) >= (1 if name == 'redundant_chain' else 4)
    assert res.graph_events == graphs and len(graphs) >= (2 if name == 'redundant_chain' else 1)
    assert res.sensing['frames'] == frames
    # a period per record sample
    n = len(sc.robots)
    assert res.sensing['estimate_error_m']['rms'] == np.sqrt(err_sq / (n * len(state)))
