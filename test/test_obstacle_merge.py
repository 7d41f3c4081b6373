"""Obstacles too close to pass between are avoided as one (spec S13 #3, docs/law-changes.md §18):
the enclosing ellipse, which obstacles merge and which do not, the validator's check of the
merged limit cycle, and the law (simulator, robot agent, coordinator) avoiding the merged one
while metrics and records keep the scenario's obstacles.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ament_formation.core.control.agent import RobotAgent
from ament_formation.core.control.coordinator import Coordinator
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import (
    boundary_points,
    enclosing_ellipse,
    points_inside,
)
from ament_formation.core.model.obstacles import avoided_as_one, MERGE_REACH, ObstacleSpec
from ament_formation.core.params import AvoidanceParams
from ament_formation.core.scenario.loader import parse_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate

AV = AvoidanceParams()
RHO_IN, RHO_L = AV.heading_scale, AV.limit_cycle_scale


def _merge(*specs, starts=()):
    return avoided_as_one(specs, RHO_IN, RHO_L, starts)


def _inside(spec, pts, scale=1.0):
    axes = scale * np.asarray(spec.semi_axes_m)[None]
    c = np.asarray(spec.center_m)[None]
    return points_inside(pts[None], c, np.array([spec.orientation_rad]), axes)[0]


@pytest.mark.parametrize('seed', range(5))
def test_the_enclosing_ellipse_of_an_ellipse_is_that_ellipse(seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-2, 2, 2)
    phi = rng.uniform(-1.5, 1.5)
    r2 = rng.uniform(0.05, 0.5)
    r1 = r2 * rng.uniform(1.2, 3.0)
    centre, got_phi, (g1, g2) = enclosing_ellipse(boundary_points(c, phi, (r1, r2))[0])
    assert centre == pytest.approx(c, abs=1e-5)
    assert (g1, g2) == pytest.approx((r1, r2), rel=1e-4)
    assert math.sin(got_phi - phi) == pytest.approx(0.0, abs=1e-4)  # the same axis, either way


def test_the_enclosing_ellipse_holds_every_point_and_is_tight():
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(300, 2)) * (0.4, 0.1) + (1.0, 2.0)
    centre, phi, axes = enclosing_ellipse(pts)
    inside = points_inside(pts[None], centre[None], np.array([phi]), np.asarray(axes)[None])[0]
    assert inside.all()
    shrunk = 0.99 * np.asarray(axes)[None]
    assert not points_inside(pts[None], centre[None], np.array([phi]), shrunk)[0].all()


def test_two_obstacles_whose_heading_ellipses_overlap_are_avoided_as_one():
    # L = 1.1 P apart (the validator accepts them), I = 1.15 P overlapping: 1 cm between the L's
    a = ObstacleSpec('A', (1.0, 1.0), (0.2, 0.1))
    b = ObstacleSpec('B', (1.45, 1.0), (0.2, 0.1))
    far = ObstacleSpec('C', (3.0, 1.0), (0.2, 0.1))
    law, members = _merge(a, far, b)
    assert [o.name for o in law] == ['A+B', 'C'] and members == ((0, 2), (1,))
    merged = law[0]
    assert law[1] is far and merged.angular_velocity_radps == 0.0 and not merged.moves
    for o in (a, b):  # the merged P holds both P's (their boundaries, densely)
        pts = boundary_points(o.center_m, o.orientation_rad, o.semi_axes_m, 2048)[0]
        assert _inside(merged, pts).all()
    # and stays near them (within MERGE_REACH P)
    outline = boundary_points(merged.center_m, merged.orientation_rad, merged.semi_axes_m)[0]
    assert (_inside(a, outline, MERGE_REACH) | _inside(b, outline, MERGE_REACH)).all()
    # a robot starting inside the merged limit cycle (between the two, 12 cm off their axis)
    # would be pushed out through one of them: no merge
    assert _merge(a, b, starts=[(1.225, 1.12)])[0] == (a, b)
    assert _merge(a, b, starts=[(1.225, 1.4)])[0] == (merged,)


def test_obstacles_with_a_lane_between_them_stay_apart():
    a = ObstacleSpec('A', (1.0, 1.0), (0.2, 0.1))
    b = ObstacleSpec('B', (1.47, 1.0), (0.2, 0.1))  # I's 1 cm apart
    law, members = _merge(a, b)
    assert law == (a, b) and members == ((0,), (1,))


def test_a_merge_that_would_claim_free_floor_is_not_made():
    # a T: the ellipse around a long bar and a small disc at its middle reaches far from both
    # (beyond MERGE_REACH P); a robot may drive there
    bar = ObstacleSpec('bar', (1.0, 1.0), (0.6, 0.05))
    disc = ObstacleSpec('disc', (1.0, 1.115), (0.05, 0.05))
    law, _ = _merge(bar, disc)
    assert law == (bar, disc)


def test_a_moving_obstacle_never_merges_a_rotating_one_merges_as_its_disc():
    a = ObstacleSpec('A', (1.0, 1.0), (0.2, 0.1))
    moving = ObstacleSpec('M', (1.45, 1.0), (0.2, 0.1), velocity_mps=(0.01, 0.0))
    assert _merge(a, moving)[0] == (a, moving)
    rot = ObstacleSpec('R', (1.43, 1.0), (0.2, 0.19), angular_velocity_radps=0.3)
    law, _ = _merge(a, rot)
    assert [o.name for o in law] == ['A+R'] and law[0].angular_velocity_radps == 0.0
    disc = boundary_points(rot.center_m, 0.0, (0.2, 0.2), 2048)[0]  # swept by the rotation
    assert _inside(law[0], disc).all()


def _scenario(obstacles, duration_s=40.0, start=(0.3, 1.0), heading=0.0):
    return parse_scenario(
        {
            'name': 'merge',
            'duration_s': duration_s,
            'robots': [
                {
                    'id': 0,
                    'leader': True,
                    'initial_pose': [start[0], start[1], heading],
                    'path': {
                        'type': 'line',
                        'start_m': list(start),
                        'heading_rad': heading,
                        'speed_mps': 0.05,
                    },
                }
            ],
            'obstacles': obstacles,
        }
    )


PAIR = [
    {'name': 'A', 'center_m': [1.2, 1.05], 'semi_axes_m': [0.2, 0.1]},
    {'name': 'B', 'center_m': [1.65, 1.05], 'semi_axes_m': [0.2, 0.1]},
]


def test_the_validator_checks_the_merged_limit_cycle_against_moving_obstacles():
    mover = {'name': 'M', 'center_m': [1.425, 1.45], 'semi_axes_m': [0.1, 0.1]}
    mover['velocity_mps'] = [0.001, 0.0]
    _scenario(PAIR + [mover])  # clear of the merged L: accepted
    mover['center_m'] = [1.425, 1.27]  # clear of A's and B's L's, not of the merged one's
    with pytest.raises(ConfigError) as err:
        _scenario(PAIR + [mover])
    assert "'A+B' and 'M' overlap" in str(err.value) and 'obstacles[2]' in str(err.value)


def test_a_robot_aimed_between_two_close_obstacles_goes_round_both():
    # 1 cm between the two limit cycles; the path runs up through the gap. Before section 18
    # the robot passed from A's limit cycle to B's and back 14 times (28 mode events) before
    # the liveness rule let it out; now it goes round the ellipse enclosing both, once
    scenario = _scenario(PAIR, start=(1.425, 0.3), heading=math.pi / 2)
    result = simulate(scenario)
    assert result.obstacle_names == ('A', 'B')  # the record: the scenario's obstacles
    assert result.obstacle_center_m[-1].tolist() == [[1.2, 1.05], [1.65, 1.05]]
    events = [(e['event'], e['target']) for e in result.mode_events]
    assert events == [('enter', 'A+B'), ('exit', 'A+B')]
    m = compute_metrics(result, scenario)
    assert m['prohibited_entries'] == 0 and m['min_clearance_m'] > 0.0
    (robot,) = m['robots'].values()
    assert robot['final_error_m'] < 0.01  # back on its path


def test_the_robot_agent_and_the_coordinator_know_the_merged_obstacle():
    scenario = _scenario(PAIR)
    assert [o.name for o in scenario.avoided_obstacles()] == ['A+B']
    agent = RobotAgent(scenario, 0)
    assert agent.obstacle_names == ('A+B',)
    assert agent.encode_mode({'mode': 'obstacle', 'target': 'A+B', 'direction': 'cw'})[:2] == (
        1, 0)
    coordinator = Coordinator(scenario)
    assert coordinator.obstacle_names == ('A+B',)
    np.testing.assert_allclose(coordinator.field.axes[0], scenario.avoided_obstacles()[0]
                               .semi_axes_m)
