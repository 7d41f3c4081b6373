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

import numpy as np

from ament_formation.core.disturbance import Disturbance
from ament_formation.core.dynamics import PlantCoeffs, rk4_step
from ament_formation.core.obstacles import ObstacleField, ObstacleStates


def wheel_rates(state: np.ndarray, r_m: np.ndarray, a_m: np.ndarray) -> np.ndarray:
    """(N, 2) wheel rates [rad/s] of (N, 5) states: (v -+ (a/2) omega) / r (S2.2)."""
    v, w = state[:, 3], state[:, 4]
    half = 0.5 * a_m
    return np.stack([(v - half * w) / r_m, (v + half * w) / r_m], axis=1)


class PlantTwin:
    """All robots of ``scenario`` as physical bodies.

    Parameters
    ----------
    scenario : ament_formation.core.scenario.Scenario
    dt_s : physics step [s] (1 ms by default, like the reference simulation of S12)
    """

    def __init__(self, scenario, dt_s: float = 0.001):
        if not (math.isfinite(dt_s) and 0 < dt_s <= 0.01):
            raise ValueError(f"dt_s: must be in (0, 0.01] s (got {dt_s!r})")
        self.scenario = scenario
        self.dt_s = float(dt_s)
        self.ids = tuple(r.id for r in scenario.robots)
        self.k = PlantCoeffs.from_params([r.params for r in scenario.robots])
        self.state = np.array([[*r.initial_pose, 0.0, 0.0] for r in scenario.robots], dtype=float)
        self.wheel_angle_rad = np.zeros((len(self.ids), 2))
        self.torque_nm = np.zeros((len(self.ids), 2))
        dist = scenario.disturbance
        self.disturbance = (Disturbance.from_bounds(len(self.ids), dist.accel_bound, dist.seed)
                            if dist is not None and any(b > 0 for b in dist.accel_bound)
                            else Disturbance.zero(len(self.ids)))
        self.obstacles = ObstacleField(scenario.obstacles)
        self.t_s = 0.0            # scenario time of the state
        self.started = False
        self._steps = 0

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
        tau = np.clip(np.asarray(torque_nm, dtype=float).reshape(-1, 2),
                      -self.k.tau_max[:, None], self.k.tau_max[:, None])
        tau = np.where(np.isfinite(tau), tau, 0.0)
        self.torque_nm = tau
        g_fn = self._g if self.started else None
        for _ in range(n_steps):
            rates0 = wheel_rates(self.state, self.k.r, self.k.a)
            self.state = rk4_step(self.state, tau, g_fn, self.t_s, self.dt_s, self.k)
            rates1 = wheel_rates(self.state, self.k.r, self.k.a)
            self.wheel_angle_rad += 0.5 * self.dt_s * (rates0 + rates1)
            if self.started:
                self.t_s += self.dt_s
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
        th, v, w = self.state[:, 2], self.state[:, 3], self.state[:, 4]
        d = self.k.d
        return np.stack([v * np.cos(th) - d * w * np.sin(th), v * np.sin(th) + d * w * np.cos(th), w],
                        axis=1)
