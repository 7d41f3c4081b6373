"""The simulated hardware twin's physics: the plant of every robot of a scenario, its wheels as the
motor boards' encoders see them, the disturbance and the obstacles, stepped with 1 ms RK4 (S2.2).

Time is the scenario time t [s] (0 at the mission start). Before the start (``started`` False)
the plant integrates without disturbance, so robots at rest with zero torque stay where they are
while the processes of a run come up; the disturbance and the obstacle motion begin at t = 0.

Conventions: N robots in scenario order; state (N, 5) rows [x_m, y_m, theta_rad, v_mps,
omega_radps] of the controlled point p; wheel arrays (N, 2) [left, right]; torques [N m].
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from ament_formation.core.model.disturbance import Disturbance
from ament_formation.core.model.dynamics import (
    PlantCoeffs,
    point_velocities,
    rk4_step_k,
    RobotPlant,
)
from ament_formation.core.model.obstacles import ObstacleField, ObstacleStates


@njit(cache=True, error_model='numpy')
def _advance_k(state, wheel, tau, g, dt, mt, It, r, a, d, mc):
    """n_steps RK4 steps (ZOH torque) of every robot; g (2 n_steps + 1, N, 2) is the disturbance
    at t, t + dt/2, t + dt, ...; wheel angles integrated with the trapezoidal rule (S2.2).
    """
    n_steps = (g.shape[0] - 1) // 2
    for i in range(state.shape[0]):
        half = 0.5 * a[i]
        plant = RobotPlant(mt[i], It[i], r[i], a[i], d[i], mc[i])
        for s in range(n_steps):
            wl0 = (state[i, 3] - half * state[i, 4]) / r[i]
            wr0 = (state[i, 3] + half * state[i, 4]) / r[i]
            nx = rk4_step_k(
                (state[i, 0], state[i, 1], state[i, 2], state[i, 3], state[i, 4]),
                (tau[i, 0], tau[i, 1]),
                (g[2 * s, i, 0], g[2 * s, i, 1]),
                (g[2 * s + 1, i, 0], g[2 * s + 1, i, 1]),
                (g[2 * s + 2, i, 0], g[2 * s + 2, i, 1]),
                dt,
                plant,
            )
            for q in range(5):
                state[i, q] = nx[q]
            wl1 = (state[i, 3] - half * state[i, 4]) / r[i]
            wr1 = (state[i, 3] + half * state[i, 4]) / r[i]
            wheel[i, 0] += 0.5 * dt * (wl0 + wl1)
            wheel[i, 1] += 0.5 * dt * (wr0 + wr1)


def wheel_rates(state: np.ndarray, r_m: np.ndarray, a_m: np.ndarray) -> np.ndarray:
    """(N, 2) wheel rates [rad/s] of (N, 5) states: (v -+ (a/2) omega) / r (S2.2)."""
    v, w = state[:, 3], state[:, 4]
    half = 0.5 * a_m
    return np.stack([(v - half * w) / r_m, (v + half * w) / r_m], axis=1)


class PlantTwin:
    """All robots of ``scenario`` as physical bodies.

    Parameters
    ----------
    scenario : ament_formation.core.scenario.loader.Scenario
    dt_s : physics step [s] (1 ms by default, like the reference simulation of S12)
    """

    def __init__(self, scenario, dt_s: float = 0.001):
        if not (math.isfinite(dt_s) and 0 < dt_s <= 0.01):
            raise ValueError(f'dt_s: must be in (0, 0.01] s (got {dt_s!r})')
        self.scenario = scenario
        self.dt_s = float(dt_s)
        self.ids = tuple(r.id for r in scenario.robots)
        self.k = PlantCoeffs.from_params([r.params for r in scenario.robots])
        self.state = np.array([[*r.initial_pose, 0.0, 0.0] for r in scenario.robots], dtype=float)
        self.wheel_angle_rad = np.zeros((len(self.ids), 2))
        self.torque_nm = np.zeros((len(self.ids), 2))
        dist = scenario.disturbance
        self.disturbance = (
            Disturbance.from_bounds(len(self.ids), dist.accel_bound, dist.seed)
            if dist is not None and any(b > 0 for b in dist.accel_bound)
            else Disturbance.zero(len(self.ids))
        )
        self.obstacles = ObstacleField(scenario.obstacles)
        self.t_s = 0.0  # scenario time of the state
        self.started = False
        self._steps = 0
        k = self.k  # compile (or load) the kernel now, not in the first tick
        _advance_k(
            self.state.copy(),
            self.wheel_angle_rad.copy(),
            self.torque_nm,
            np.zeros((1, len(self.ids), 2)),
            self.dt_s,
            k.m_tilde,
            k.I_tilde,
            k.r,
            k.a,
            k.d,
            k.m_c,
        )

    def start(self) -> None:
        """Begin the mission: scenario time runs from 0 (disturbance and obstacles active)."""
        self.started = True
        self.t_s = 0.0

    def _g(self, t_s: float) -> np.ndarray:
        return self.disturbance(t_s)

    def advance(self, duration_s: float, torque_nm: np.ndarray) -> None:
        """Integrate ``duration_s`` [s] (rounded to whole steps) with ``torque_nm`` (N, 2) held.

        Torques are clamped to each robot's limit here too (the motors cannot do more).
        """
        n_steps = max(0, int(round(duration_s / self.dt_s)))
        tau = np.clip(
            np.asarray(torque_nm, dtype=float).reshape(-1, 2),
            -self.k.tau_max[:, None],
            self.k.tau_max[:, None],
        )
        tau = np.where(np.isfinite(tau), tau, 0.0)
        self.torque_nm = tau
        if n_steps == 0:
            return
        n = len(self.ids)
        if self.started:  # g at every half step, one vectorised evaluation
            t = self.t_s + 0.5 * self.dt_s * np.arange(2 * n_steps + 1)
            g = self.disturbance.at_times(t)
        else:
            g = np.zeros((2 * n_steps + 1, n, 2))
        k = self.k
        _advance_k(
            self.state,
            self.wheel_angle_rad,
            np.ascontiguousarray(tau),
            np.ascontiguousarray(g),
            self.dt_s,
            k.m_tilde,
            k.I_tilde,
            k.r,
            k.a,
            k.d,
            k.m_c,
        )
        if self.started:
            self.t_s += n_steps * self.dt_s
        self._steps += n_steps

    @property
    def wheel_rate_radps(self) -> np.ndarray:
        """(N, 2) current wheel rates [rad/s]."""
        return wheel_rates(self.state, self.k.r, self.k.a)

    def obstacle_states(self) -> ObstacleStates:
        """Obstacles at the current scenario time (frozen at t = 0 before the start)."""
        return self.obstacles.at(self.t_s if self.started else 0.0)

    def pose_rates(self) -> np.ndarray:
        """(N, 3) [xdot_mps, ydot_mps, thetadot_radps] of p (kinematics (16)-(18))."""
        pd = point_velocities(np.ascontiguousarray(self.state), np.ascontiguousarray(self.k.d))
        return np.concatenate([pd, self.state[:, 4:5]], axis=1)
