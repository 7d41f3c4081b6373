"""The record of one closed-loop run: what the simulator (or the ROS recorder) produces and what
metrics, plots and files consume. Shapes use T samples, N robots, M obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SimResult:
    """A recorded run. All arrays share the sample axis ``t_s``; world frame, SI units.

    Attributes
    ----------
    t_s : (T,) sample times [s]
    state : (T, N, 5) rows [x_m, y_m, theta_rad, v_mps, omega_radps]; (x, y) is the controlled
    point p
    torque_nm : (T, N, 2) applied wheel torques [left, right] after saturation (ZOH value)
    goal_m : (T, N, 2) formation goal g_i (leader: r(t); follower: p of its original parent +
    delta)
    avoiding : (T, N) bool, robot in any avoidance mode
    saturated : (T, N) bool, torque was scaled down by S3.6 at this sample
    obstacle_center_m : (T, M, 2) and obstacle_phi_rad : (T, M): obstacle poses at each sample
    mode_events : [{t_s, robot, event: enter|exit, target, direction: cw|ccw}]
    graph_events : [{t_s, parents: {"<child>": parent-or-null}}]
    reaching : [{robot, t_s, sigma0_inf_mps, t_reach_s, bound_s}] one per reaching phase (S3.4)
    mission_end_s : when every leader's reference reached its end (S17.3); None: it did not
    nominal_duration_s : the scenario's duration_s, the mission's free traversal [s]
    progress_s : (T, N) progress s of each leader's reference [s of path time] (S17; 0 for
    followers), or None
    """

    scenario_name: str
    robot_ids: tuple[int, ...]
    obstacle_names: tuple[str, ...]
    t_s: np.ndarray
    state: np.ndarray
    torque_nm: np.ndarray
    goal_m: np.ndarray
    avoiding: np.ndarray
    saturated: np.ndarray
    obstacle_center_m: np.ndarray
    obstacle_phi_rad: np.ndarray
    mode_events: list[dict] = field(default_factory=list)
    graph_events: list[dict] = field(default_factory=list)
    reaching: list[dict] = field(default_factory=list)
    dt_s: float = 0.001
    wall_time_s: float = 0.0
    mission_end_s: float | None = None
    nominal_duration_s: float | None = None
    progress_s: np.ndarray | None = None

    @property
    def formation_error_m(self) -> np.ndarray:
        """(T, N) |p_i - g_i| [m]."""
        return np.linalg.norm(self.state[:, :, :2] - self.goal_m, axis=2)
