"""The controller node's algorithms, in the core (issue 12): the controlled stop
(core/control/stop.py) and what a robot makes of the robots it hears (core/control/neighbours.py:
S10 extrapolation, S8.3 goal of a neighbour).
"""

from __future__ import annotations

import numpy as np
import pytest

from ament_formation.core.control.law import gains_vector, goal_fields
from ament_formation.core.control.neighbours import extrapolate_neighbour, neighbour_goal
from ament_formation.core.control.stop import stop_torque
from ament_formation.core.model.dynamics import (
    PlantCoeffs,
    point_velocities,
    rk4_step_k,
    RobotPlant,
)
from ament_formation.core.model.paths import LinePath
from ament_formation.core.params import ControlGains, RobotParams

K = PlantCoeffs.from_params([RobotParams()])
GAINS = ControlGains()


def test_stop_torque_is_zero_at_rest_and_brakes_motion():
    rest = np.array([[0.3, -0.2, 1.0, 0.0, 0.0]])
    np.testing.assert_allclose(stop_torque(rest, K, 0.5, GAINS), 0.0, atol=1e-15)
    moving = np.array([[0.0, 0.0, 0.0, 0.2, 0.0]])
    tau = stop_torque(moving, K, 0.5, GAINS)[0]
    assert tau[0] < 0 and tau[1] < 0 and tau[0] == pytest.approx(tau[1])
    fast = np.array([[0.0, 0.0, 0.0, 5.0, 3.0]])
    assert np.max(np.abs(stop_torque(fast, K, 0.5, GAINS))) == pytest.approx(K.tau_max[0])


def test_stop_brings_the_wheels_to_rest():
    x = np.array([0.0, 0.0, 0.3, 0.15, 0.8])
    dt = 0.001
    for _ in range(3000):  # 3 s, six stop times
        t1, t2 = stop_torque(x[None], K, 0.5, GAINS)[0]
        k = [K.m_tilde[0], K.I_tilde[0], K.r[0], K.a[0], K.d[0], K.m_c[0]]
        x = np.array(
            rk4_step_k(tuple(x), (t1, t2), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), dt, RobotPlant(*k))
        )
    assert abs(x[3]) < 1e-4 and abs(x[4]) < 1e-3


def test_extrapolation_fresh_held_and_lost():
    state = np.array([1.0, 2.0, 0.0, 0.1, 0.0])
    acc = np.array([0.02, -0.04])
    assert extrapolate_neighbour(state, acc, 0.05, 0.05, 0.1, 1.0) is state
    assert extrapolate_neighbour(state, acc, 1.5, 0.05, 0.1, 1.0) is None
    x = extrapolate_neighbour(state, acc, 0.5, 0.05, 0.1, 1.0)
    np.testing.assert_allclose(x[:2], [1.0 + 0.1 * 0.5 + 0.01 * 0.25, 2.0 - 0.02 * 0.25])
    np.testing.assert_array_equal(x[2:], state[2:])
    assert state[0] == 1.0  # the heard state is not modified


def test_neighbour_goal_is_the_law_s_goal():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(2, 5))
    d = np.array([0.05, 0.07])
    offset = np.array([0.0, 1.2])
    g, gd = neighbour_goal(4.0, None, x[0], offset, d[0])
    pd = point_velocities(x, d)
    goal, goal_dot, _ = goal_fields(
        x,
        pd,
        np.zeros((2, 6)),
        np.array([-1, 0]),
        np.array([[0.0, 0.0], offset]),
        gains_vector(GAINS),
    )
    np.testing.assert_array_equal(g, goal[1])
    np.testing.assert_array_equal(gd, goal_dot[1])
    assert neighbour_goal(4.0, None, None, offset, 0.05) == (None, None)
    path = LinePath(start_m=(0.0, 0.0), heading_rad=0.0, speed_mps=0.05)
    g, gd = neighbour_goal(4.0, path, None, offset, 0.05)
    np.testing.assert_allclose(g, [0.2, 0.0])
    np.testing.assert_allclose(gd, [0.05, 0.0])
