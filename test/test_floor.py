"""The floor in one place (core/control/floor.py, docs/control-law.md S16): its edges as walls of
the braking barrier (S16.1), the rotation sense that keeps a limit-cycle arc on the floor
(S16.2) and a mutual pair's drift kept off the edges (S16.3).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ament_formation.core.control.floor import drift_off_edges, floor_edges, floor_side, near_floor
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.safety import allowed_speed, safe_field
from ament_formation.core.model.obstacles import ObstacleSnapshot

FLOOR = (0.0, 3.0, 0.0, 2.5)
WALLED = LawParams(floor_m=FLOOR).compiled()
OPEN = LawParams().compiled()
RB = 0.1
CLEAR = RB + OPEN.safety_gap_m  # what a body needs from an edge on its arc (S16.2)


# ------------------------------------------------------------------ S16.1 edges


def test_edges_are_the_gaps_of_the_body_to_each_wall_with_inward_normals():
    edges = floor_edges(0.5, 2.0, RB, WALLED)
    assert [e[0] for e in edges] == pytest.approx([0.4, 2.4, 1.9, 0.4])
    assert [e[1:] for e in edges] == [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
    assert all(e[0] == math.inf for e in floor_edges(0.5, 2.0, RB, OPEN))
    # near: within safety_range_m (0.3 m) of an edge, body included
    assert near_floor(0.39, 1.0, RB, WALLED) and not near_floor(0.41, 1.0, RB, WALLED)
    assert near_floor(1.5, 2.5 - 0.39, RB, WALLED) and not near_floor(1.5, 1.0, RB, WALLED)
    assert not near_floor(0.0, 0.0, RB, OPEN)


def _no_obstacles():
    z = np.zeros((0, 2))
    return ObstacleSnapshot(z, z, z, np.zeros(0), np.zeros(0), np.zeros(0), z,
                            np.zeros(0, dtype=np.bool_))


def _field(p, pd, vd, prm):
    x = np.array([[p[0], p[1], 0.0, 0.0, 0.0]])
    return safe_field(0, x, np.array([pd], float), np.zeros(0, dtype=np.int64),
                      np.zeros(0, dtype=np.int64), vd[0], vd[1], 0.0, 0.0, _no_obstacles(),
                      np.array([RB]), prm)


def test_an_edge_is_a_wall_the_approach_speed_toward_it_is_limited_the_slide_along_it_kept():
    p, vd = (0.25, 1.0), (-0.2, 0.1)  # 0.15 m from the wall x = 0, heading into it
    vdx, vdy, _ax, _ay = _field(p, vd, vd, WALLED)
    gap = p[0] - RB - WALLED.safety_gap_m
    a_brk = WALLED.brake_gain_fraction * WALLED.switching_gain_mps2
    allowed = allowed_speed(gap, a_brk, WALLED.safety_lag_s)
    assert 0.0 < allowed < 0.2
    assert -vdx == pytest.approx(allowed, rel=1e-9)  # approach limited to the stopping speed
    assert vdy == pytest.approx(0.1)  # tangential part kept: it slides along the wall
    # no floor declared, or moving away from the wall: untouched
    assert _field(p, vd, vd, OPEN)[:2] == pytest.approx(vd)
    assert _field(p, (0.2, 0.1), (0.2, 0.1), WALLED)[:2] == pytest.approx((0.2, 0.1))


@pytest.mark.parametrize('corner', [(0.0, 0.0), (3.0, 2.5)])
def test_a_point_following_the_barriers_field_stops_before_the_walls(corner):
    # a point that follows V_d (the S3 loop's ideal) driven at a corner at the speed limit
    # stops the gap outside both walls and never crosses them
    cx, cy = corner
    p = np.array([1.5, 1.25])
    aim = np.array([cx, cy]) - p
    v = aim / np.linalg.norm(aim) * WALLED.speed_limit_mps
    dt, closest = 0.002, math.inf
    for _ in range(int(30.0 / dt)):
        vdx, vdy, _a, _b = _field(p, v, v * 10.0, WALLED)  # V_d asks for more than the limit
        v = np.array([vdx, vdy])
        assert np.hypot(*v) <= WALLED.speed_limit_mps + 1e-12
        p = p + dt * v
        closest = min(closest, p[0] - RB, 3.0 - p[0] - RB, p[1] - RB, 2.5 - p[1] - RB)
    assert closest >= 0.0  # the body never touches an edge ...
    assert closest == pytest.approx(WALLED.safety_gap_m, abs=2e-3)  # ... it ends the gap away
    assert np.hypot(*v) < 1e-3  # at rest in the corner


# ------------------------------------------------------------------ S16.2 the sense


# a limit cycle of an obstacle near the bottom edge: P (0.3, 0.15) at (1.5, 0.25), L = 1.1 P
# reaches y = 0.085 at its bottom, closer to the edge y = 0 than a body and the gap (0.11 m)
C, AXES = (1.5, 0.25), (0.33, 0.165)
TOP, GOAL = (1.5, 0.415), (2.2, 0.3)  # the robot on top; its goal ahead to the right


def _side(sense, prm, p=TOP, goal=GOAL):
    return floor_side(sense, *p, *goal, *C, 0.0, *AXES, CLEAR, prm)


def test_the_sense_whose_arc_leaves_the_floor_is_not_chosen_when_the_other_keeps_to_it():
    # clockwise (-1) goes over the top to the goal; counter-clockwise passes under the bottom
    assert _side(1.0, WALLED) == (-1.0, True)  # flipped: the other way is open
    assert _side(-1.0, WALLED) == (-1.0, False)  # kept; the other way is closed
    # without a floor, or with the edge far enough below, every sense is kept
    for prm in (OPEN, LawParams(floor_m=(0.0, 3.0, -1.0, 2.5)).compiled()):
        assert _side(1.0, prm) == (1.0, True) and _side(-1.0, prm) == (-1.0, True)
    # the edge at y = -0.03: the bottom of L is 0.115 m above it, just more than 0.11 m
    barely = LawParams(floor_m=(0.0, 3.0, -0.03, 2.5)).compiled()
    assert _side(1.0, barely) == (1.0, True)
    tight = LawParams(floor_m=(0.0, 3.0, -0.02, 2.5)).compiled()
    assert _side(1.0, tight) == (-1.0, True)


def test_when_both_arcs_leave_the_floor_the_sense_is_kept():
    # the edge at y = 0.2 cuts under the goal side too: both ways leave, no reason to turn
    both = LawParams(floor_m=(0.0, 3.0, 0.2, 2.5)).compiled()
    assert _side(1.0, both)[0] == 1.0 and _side(-1.0, both)[0] == -1.0


def test_the_arc_checked_is_the_one_from_the_robot_to_its_goal():
    # the goal to the right (anomaly 0); from the left side (180 deg) counter-clockwise passes
    # the closed bottom, clockwise the open top ...
    left = (C[0] - AXES[0], C[1])
    goal = (C[0] + 0.7, C[1])
    assert _side(1.0, WALLED, p=left, goal=goal) == (-1.0, True)
    # ... from -30 deg (on the bottom right, 0.17 m above the edge) counter-clockwise is the
    # short way up to the goal and stays on the floor; clockwise would pass the bottom
    low = (C[0] + AXES[0] * math.cos(-0.52), C[1] + AXES[1] * math.sin(-0.52))
    assert low[1] - CLEAR > 0.0
    assert _side(1.0, WALLED, p=low, goal=goal) == (1.0, False)
    assert _side(-1.0, WALLED, p=low, goal=goal) == (1.0, True)


# ------------------------------------------------------------------ S16.3 a pair's drift


def _drift(w, m, room=0.235, prm=WALLED):
    return drift_off_edges(w[0], w[1], m[0], m[1], room, WALLED.mutual_drift_cap_mps, prm)


def test_a_pairs_drift_toward_a_crossed_edge_is_dropped_and_one_away_added():
    cap, push = WALLED.mutual_drift_cap_mps, WALLED.floor_push_m
    # the pair's circle (room 0.235 m round the centre at x = 0.2) crosses x = 0 by 0.035 m
    wx, wy = _drift((-0.02, 0.03), (0.2, 1.0))
    assert wx == pytest.approx(min(cap, 0.035 * cap / push))  # away from it, cap x deficit/push
    assert wy == pytest.approx(0.03)  # the other component is left alone
    # deeper in: the push saturates at the cap; a drift already away and faster is kept
    assert _drift((-0.02, 0.0), (0.1, 1.0))[0] == pytest.approx(cap)
    assert _drift((0.045, 0.0), (0.2, 1.0))[0] == pytest.approx(max(0.045, 0.035 * cap / push))
    # the upper edges alike
    assert _drift((0.0, 0.04), (1.5, 2.5 - 0.2))[1] == pytest.approx(-0.035 * cap / push)
    assert _drift((0.04, 0.0), (3.0 - 0.2, 1.0))[0] == pytest.approx(-0.035 * cap / push)


def test_a_pairs_drift_is_unchanged_inside_the_floor_without_a_floor_or_squeezed_both_ways():
    assert _drift((-0.03, 0.02), (1.5, 1.25)) == pytest.approx((-0.03, 0.02))
    assert _drift((-0.03, 0.02), (0.1, 1.25), prm=OPEN) == pytest.approx((-0.03, 0.02))
    # a floor narrower than the pair's circle: both edges crossed, no side to push to
    narrow = LawParams(floor_m=(0.0, 0.4, 0.0, 2.5)).compiled()
    assert _drift((-0.03, 0.02), (0.2, 1.25), prm=narrow) == pytest.approx((-0.03, 0.02))
