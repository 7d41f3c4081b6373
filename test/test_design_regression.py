"""Issue 13, "a design with no contact and no runaway": random scenarios that failed before the
design changes of docs/law-changes.md (test/scenarios_regression/*.yaml, each with its old failure
in its header) must run without a hard failure, and the law's safety filter
(core/control/safety.py) must behave as documented.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from ament_formation.core.control.automaton import SwitchingParams
from ament_formation.core.control.safety import safe_field
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate

FILES = sorted((Path(__file__).resolve().parent / 'scenarios_regression').glob('*.yaml'))
CONTACT_M = 0.20  # two robot bodies touch (R_body = 0.1 m)
PEAK_SPEED_MPS = 0.3  # the sweep's runaway speed (the law's speed limit is 0.25 m/s)
MAX_EVENTS = 50  # mode events of one robot: more is chattering
PRM = SwitchingParams().compiled()


@pytest.mark.parametrize('path', FILES, ids=[p.stem for p in FILES])
def test_formerly_failing_random_scenario_has_no_hard_failure(path):
    scenario = load_scenario(path)
    result = simulate(scenario)
    m = compute_metrics(result, scenario)
    clearance = m['min_clearance_m']  # None without obstacles
    assert clearance is None or clearance > 0.0, 'a robot entered an obstacle region P'
    assert m['min_inter_robot_distance_m'] >= CONTACT_M, 'robot bodies touched'
    vel = np.diff(result.state[:, :, :2], axis=0) / np.diff(result.t_s)[:, None, None]
    assert np.linalg.norm(vel, axis=2).max() <= PEAK_SPEED_MPS, 'runaway'
    events = Counter(e['robot'] for e in m['mode_events'])
    assert max(events.values(), default=0) <= MAX_EVENTS, f'chattering: {events}'
    if scenario.floor is not None:
        assert m['floor_excursion_m'] <= 0.0, 'a robot body crossed the floor edge'


@pytest.mark.parametrize(
    'name',
    ['stuck1653', 'stuck346', 'chatter1660', 'stuck190', 'stuck1801'],
    ids=['wall', 'parked_robot', 'two_obstacles', 'parked_pair', 'parked_and_yielding'],
)
def test_a_robot_held_still_on_its_limit_cycle_finds_its_way_to_a_free_goal(name):
    # liveness (docs/law-changes.md §8-§10, §13): these robots were held still to the run's end
    scenario = load_scenario(FILES[0].parent / f'{name}.yaml')
    m = compute_metrics(simulate(scenario), scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'


@pytest.mark.parametrize('name', ['wallpair217', 'gridlock1507', 'gridlock1837', 'crowd1251'])
def test_stuck_robots_reach_their_goals_once_the_paths_stop(name):
    # docs/law-changes.md §20 (a mutual pair against a wall drifts off it), §21 (a yielder held
    # still turns the other way) and §22 (teammates' slots inside each other's Q): the paths stop
    # at the first run's end and 30 s follow; before, a robot was still more than 0.5 m from its
    # goal at the end (`stuck`)
    scenario = load_scenario(FILES[0].parent / f'{name}.yaml')
    m = compute_metrics(simulate(scenario), scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'


def test_a_robot_held_still_waits_on_the_open_side_of_an_obstacle_by_the_floor():
    # docs/law-changes.md §27: R3 turned (§8) into a pass the floor closes and stayed there,
    # 0.88 m from its goal, however long the paths were held
    from ament_formation.core.sim.campaign import held_scenario

    scenario = held_scenario(load_scenario(FILES[0].parent / 'floorpass1258.yaml'), 30.0)
    result = simulate(scenario)
    m = compute_metrics(result, scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'
    turns = [e for e in result.mode_events if e['robot'] == 3 and e['mode'] == 'obstacle']
    assert len(turns) <= 4, f'R3 turned on its obstacle: {turns}'


def test_a_mutual_pair_turning_toward_both_goals_lets_two_teams_cross_on_time():
    # docs/law-changes.md §14: before, R1 ended 0.77 m from its goal (every pair turned ccw)
    scenario = load_scenario(FILES[0].parent / 'pairsense65.yaml')
    result = simulate(scenario)
    m = compute_metrics(result, scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'
    first = next(e for e in result.mode_events if e['robot'] == 1 and e['mode'] == 'mutual')
    assert (first['target'], first['direction']) == ('robot_3', 'cw')


# camera-sensed chattering of teammates (docs/law-changes.md §11): file -> campaign sensing seed
CAMERA_CHATTER = {
    'camchatter699': 1000702,
    'camchatter1098': 1001101,
    'camchatter1470': 1001473,
    'camchatter1575': 1001578,
    'camchatter1619': 1001622,
}


def _camera_run_neither_chatters_nor_touches(name: str, seed: int) -> None:
    from ament_formation.core.sim.sensed import SensingParams, simulate_sensed

    scenario = load_scenario(FILES[0].parent / f'{name}.yaml')
    sensing = SensingParams.preset('camera', seed=seed)
    result = simulate_sensed(scenario, sensing, dt_s=0.001, record_every_s=0.01)
    m = compute_metrics(result, scenario)
    events = Counter(e['robot'] for e in m['mode_events'])
    assert max(events.values(), default=0) <= MAX_EVENTS, f'chattering: {events}'
    clearance = m['min_clearance_m']  # None without obstacles
    assert clearance is None or clearance > 0.0, 'a robot entered an obstacle region P'
    assert m['min_inter_robot_distance_m'] >= CONTACT_M, 'robot bodies touched'


@pytest.mark.parametrize('name', sorted(CAMERA_CHATTER))
def test_camera_sensed_teammates_do_not_chatter(name):
    # four wedges and a two-team crossing: a robot with 51-63 mode events before §11
    _camera_run_neither_chatters_nor_touches(name, CAMERA_CHATTER[name])


# a robot's own decision against the coordinator's (docs/law-changes.md §23): file -> sensing seed
CAMERA_COORDINATED = {'camchatter542': 1000545, 'camchatter1637': 1001640}
# the coordinator's yield turned into a pair by the robot's own S14.5 check on its partner's late
# report, again and again (docs/law-changes.md §24): file -> sensing seed
CAMERA_ASSIGNED_YIELD = {'camchatter323': 1000326, 'camchatter463': 1000466}


@pytest.mark.parametrize('name', sorted(CAMERA_COORDINATED))
def test_a_robot_that_hears_the_coordinator_does_not_chatter(name):
    # two-team crossings: R1 with 59 and 63 mode events before §23, the coordinator's mutual pair
    # replacing a yield of the robot's own decision 10-20 ms after it, encounter after encounter
    _camera_run_neither_chatters_nor_touches(name, CAMERA_COORDINATED[name])


@pytest.mark.parametrize('name', sorted(CAMERA_ASSIGNED_YIELD))
def test_a_yield_loop_a_robots_own_yield_closes_is_broken_for_both_robots(name):
    # a two-team and a four-robot crossing: the assigned yield turned into a mutual pair by the
    # robot's own loop check, assigned again, ...: R1 64 and R0 54 mode events before §24
    _camera_run_neither_chatters_nor_touches(name, CAMERA_ASSIGNED_YIELD[name])


# camera-sensed one-sided mutual pairs (docs/law-changes.md §16): file -> campaign sensing seed
CAMERA_ONE_SIDED = {'onesided16': 1000019, 'onesided49': 1000052}


@pytest.mark.parametrize('name', sorted(CAMERA_ONE_SIDED))
def test_a_robot_whose_partner_left_the_pair_leaves_it_too(name):
    # crossings of 3-4 robots: a robot ended 1.43-1.54 m from its goal before §16
    _camera_run_reaches_every_goal(name, CAMERA_ONE_SIDED[name])


def _camera_run_reaches_every_goal(name: str, seed: int) -> None:
    from ament_formation.core.sim.sensed import SensingParams, simulate_sensed

    scenario = load_scenario(FILES[0].parent / f'{name}.yaml')
    sensing = SensingParams.preset('camera', seed=seed)
    m = compute_metrics(simulate_sensed(scenario, sensing), scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'
    assert m['min_inter_robot_distance_m'] >= CONTACT_M, 'robot bodies touched'


# a mutual pair's drift as the coordinator sends it (docs/law-changes.md §23): file -> sensing seed
CAMERA_PAIR_DRIFT = {'camstuck511': 1000514, 'camstuck904': 1000907}


@pytest.mark.parametrize('name', sorted(CAMERA_PAIR_DRIFT))
def test_a_pair_at_the_floor_edge_gets_the_coordinators_current_drift(name):
    # crossings of 4 robots: a pair slid along the floor's edge with the w_c of its entry, and a
    # robot ended 2.61 / 1.49 m from its goal before §23
    _camera_run_reaches_every_goal(name, CAMERA_PAIR_DRIFT[name])


# held 30 s after the paths end, camera (docs/law-changes.md §25, §26): file -> sensing seed
CAMERA_HELD = {'camstuck119': 1000122, 'camstuck1660': 1001663}


@pytest.mark.parametrize('name', sorted(CAMERA_HELD))
def test_robots_stuck_with_camera_sensing_reach_their_goals_once_the_paths_stop(name):
    # camstuck119: a leader and its follower in a pair, each turning its own way, slid into a
    # floor corner (R2 0.90 m from its goal, §25); camstuck1660: two robots in the gap between two
    # static obstacles re-targeted between them every second and were never turned (R1 1.18 m,
    # R2 99 mode events, §26)
    from ament_formation.core.sim.campaign import held_scenario
    from ament_formation.core.sim.sensed import SensingParams, simulate_sensed

    scenario = held_scenario(load_scenario(FILES[0].parent / f'{name}.yaml'), 30.0)
    sensing = SensingParams.preset('camera', seed=CAMERA_HELD[name])
    m = compute_metrics(simulate_sensed(scenario, sensing), scenario)
    far = {rid: r['final_error_m'] for rid, r in m['robots'].items() if r['final_error_m'] > 0.5}
    assert not far, f'robots ending more than 0.5 m from their goals: {far}'
    assert m['min_inter_robot_distance_m'] >= CONTACT_M, 'robot bodies touched'
    events = Counter(e['robot'] for e in m['mode_events'])
    assert max(events.values(), default=0) <= MAX_EVENTS, f'chattering: {events}'


# the coordinator's yield and a robot's own yield in a loop: file -> (sensing seed, hold [s])
CAMERA_YIELD_LOOP = {'camrunaway197': (1000200, 10.0), 'camrunaway1229': (1001232, 30.0)}


@pytest.mark.parametrize('name', sorted(CAMERA_YIELD_LOOP))
def test_a_yield_loop_of_the_coordinator_and_a_robot_is_broken_with_camera_sensing(name):
    # docs/law-changes.md "Not changed (yet)": the coordinator's yield and a robot's own
    # emergency yield formed a loop; without the robots' own S14.5 check (camrunaway197: R2 ran
    # to 0.315 m/s 8.4 s after the paths ended), or with it in emergencies only (the change
    # tried on 2026-12-04, camrunaway1229: R4 0.32 m/s in the held run), a robot ran away
    from ament_formation.core.sim.campaign import held_scenario
    from ament_formation.core.sim.sensed import SensingParams, simulate_sensed

    seed, hold_s = CAMERA_YIELD_LOOP[name]
    scenario = held_scenario(load_scenario(FILES[0].parent / f'{name}.yaml'), hold_s)
    sensing = SensingParams.preset('camera', seed=seed)
    result = simulate_sensed(scenario, sensing, dt_s=0.001, record_every_s=0.01)
    vel = np.diff(result.state[:, :, :2], axis=0) / np.diff(result.t_s)[:, None, None]
    assert np.linalg.norm(vel, axis=2).max() <= PEAK_SPEED_MPS, 'runaway'
    m = compute_metrics(result, scenario)
    assert m['min_inter_robot_distance_m'] >= CONTACT_M, 'robot bodies touched'


def _field(x, vd, obstacles=None):
    n = x.shape[0]
    pd = np.zeros((n, 2))  # heading 0, omega 0: p_dot = (v, 0)
    pd[:, 0] = x[:, 3]
    oc, ov, ophi, ophid, oaxes = obstacles or (
        np.zeros((0, 2)),
        np.zeros((0, 2)),
        np.zeros(0),
        np.zeros(0),
        np.zeros((0, 2)),
    )
    return safe_field(
        0, x, pd, vd[0], vd[1], 0.0, 0.0, oc, ov, ophi, ophid, oaxes, np.full(n, 0.1), 0.27, PRM
    )


def test_safety_filter_leaves_a_free_robot_alone_and_caps_its_speed():
    x = np.array([[0.0, 0.0, 0.0, 0.05, 0.0], [2.0, 0.0, 0.0, 0.0, 0.0]])
    assert _field(x, (0.05, 0.01)) == (0.05, 0.01, 0.0, 0.0)  # untouched, bit for bit
    vx, vy, _, _ = _field(x, (3.0, 4.0))
    assert np.hypot(vx, vy) == pytest.approx(SwitchingParams().speed_limit_mps)
    assert vx / vy == pytest.approx(0.75)


def test_safety_filter_stops_the_approach_but_keeps_the_tangential_motion():
    # robot 1 is 1 mm beyond the contact circle ahead, inside the 1 cm margin: no approach left
    # (a slow retreat), sliding past allowed
    x = np.array([[0.0, 0.0, 0.0, 0.1, 0.0], [0.201, 0.0, 0.0, 0.0, 0.0]])
    vx, vy, _, _ = _field(x, (0.1, 0.05))
    assert -0.02 < vx < 0.0 and vy == pytest.approx(0.05)
    # moving away is never held back (liveness)
    assert _field(x, (-0.1, 0.0))[:2] == (-0.1, 0.0)


def test_safety_filter_sees_a_rotating_obstacle_sweeping_toward_the_robot():
    # a bar (P 0.3 x 0.05 m) turning CCW at 0.5 rad/s; the robot 5 cm beyond its tip's path
    obstacles = (
        np.zeros((1, 2)),
        np.zeros((1, 2)),
        np.array([0.0]),
        np.array([0.5]),
        np.array([[0.3, 0.05]]),
    )
    x = np.array([[0.0, 0.15, 0.0, 0.0, 0.0]])  # above the bar's middle, at rest
    vx, vy, _, _ = _field(x, (0.0, 0.0), obstacles)
    assert (vx, vy) == (0.0, 0.0)  # the material point under the robot moves along -x only
    x = np.array([[0.25, 0.15, 0.0, 0.0, 0.0]])  # above the tip, which moves +y at 0.125 m/s
    vx, vy, _, _ = _field(x, (0.0, 0.0), obstacles)
    assert vy > 0.02  # the robot is told to get out of the way


def _wall_field(px, vd, floor=(0.0, 3.0, 0.0, 2.5)):
    """Robot 0 at (px, 1.0) moving with V_d on a floor with walls (safety filter only)."""
    x = np.array([[px, 1.0, 0.0, vd[0], 0.0]])
    pd = np.array([[vd[0], vd[1]]])
    prm = SwitchingParams(floor_m=floor).compiled()
    none = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    return safe_field(0, x, pd, vd[0], vd[1], 0.0, 0.0, *none, np.full(1, 0.1), 0.27, prm)


def test_safety_filter_treats_the_floor_edges_as_walls():
    # 2 cm from the x_max wall (body radius 0.1 m: p at 3.0 - 0.12): the approach is cut to the
    # braking speed, the motion along the wall is kept
    vx, vy, _, _ = _wall_field(2.88, (0.05, 0.03))
    assert vx < 0.03 and vy == pytest.approx(0.03)
    # inside the gap (p past the wall's safety margin): a retreat is commanded
    assert _wall_field(2.895, (0.05, 0.0))[0] < 0.0
    # moving away from the wall, far from it, or with no declared floor: untouched
    assert _wall_field(2.88, (-0.05, 0.03))[:2] == (-0.05, 0.03)
    assert _wall_field(1.5, (0.05, 0.03))[:2] == (0.05, 0.03)
    assert _wall_field(2.88, (0.05, 0.03), floor=None)[:2] == (0.05, 0.03)
    # the x_min and y_min walls alike
    x = np.array([[0.12, 0.12, 0.0, -0.05, 0.0]])
    prm = SwitchingParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()
    none = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    vx, vy, _, _ = safe_field(
        0, x, np.array([[-0.05, -0.05]]), -0.05, -0.05, 0.0, 0.0, *none, np.full(1, 0.1), 0.27, prm
    )
    assert vx > -0.03 and vy > -0.03


def test_safety_filter_escapes_along_the_wall_from_an_obstacle_driving_at_it():
    """§12: a robot 12 mm from the y_min wall with an obstacle coming down at it from above and to
    the left (the normals of the wall and of P 137° apart): it slides along the wall out of the
    obstacle's way, never into the wall or the obstacle, instead of stopping (which let the
    obstacle's barrier push it past the edge: regressions floor496/1669/1747).
    """
    prm = SwitchingParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()
    x = np.array([[2.355, 0.112, 4.8, 0.0, 0.0]])
    pd = np.zeros((1, 2))
    oc, ov = np.array([[2.192, 0.262]]), np.array([[0.0, -0.0186]])
    phi, phid, axes = np.array([2.614]), np.zeros(1), np.array([[0.226, 0.187]])
    vx, vy, _, _ = safe_field(
        0, x, pd, 0.0, -0.02, 0.0, 0.0, oc, ov, phi, phid, axes, np.full(1, 0.1), 0.27, prm
    )
    assert vx > 0.01  # along the wall, away from the obstacle (it lies to the left)
    from ament_formation.core.control.safety import _obstacle_gap, allowed_speed

    a_brk = prm.brake_gain_fraction * 0.27
    # toward the wall no faster than it still stops before the margin (body 12 mm from the edge)
    assert vy >= -allowed_speed(0.112 - 0.1 - prm.safety_gap_m, a_brk, prm.safety_lag_s) - 1e-9
    # P's barrier: the approach toward the boundary no faster than the boundary comes

    gap, nx, ny, bvx, bvy = _obstacle_gap(2.355, 0.112, oc, ov, phi, phid, axes, 0)
    assert (vx - bvx) * nx + (vy - bvy) * ny >= -1e-6
    # a robot in the way along the wall: no escape, a stop as before
    x2 = np.vstack([x, [[2.58, 0.112, 0.0, 0.0, 0.0]]])
    vx2, vy2, _, _ = safe_field(
        0, x2, np.zeros((2, 2)), 0.0, -0.02, 0.0, 0.0, oc, ov, phi, phid, axes,
        np.full(2, 0.1), 0.27, prm,
    )
    assert vx2 < vx
