"""What a robot's controller makes of the other robots it hears (S10, S8.3): a neighbour's state
extrapolated to now with its broadcast commanded acceleration, and a neighbour's formation goal
g_k, g_k_dot (for its side of a mutual pair's joint exit test and its V_c).

Called once per heard robot per control period from Python, so the scalar kernels are called
through ``.py_func`` (the same source, run by the interpreter): no dispatch, and nothing compiles
while the robot drives.
"""

from __future__ import annotations

import numpy as np

from ament_formation.core.control.law import follower_goal_k
from ament_formation.core.model.dynamics import point_velocity_k

_point_velocity = point_velocity_k.py_func
_follower_goal = follower_goal_k.py_func


# implements: S10/neighbours
def extrapolate_neighbour(
    state: np.ndarray,
    accel_mps2: np.ndarray,
    age_s: float,
    com_offset_m: float,
    fresh_s: float,
    hold_s: float,
) -> np.ndarray | None:
    """The neighbour's state (5,) [x_m, y_m, theta_rad, v_mps, omega_radps] heard ``age_s`` ago,
    at now (S10, S13 #13): as heard while ``age_s <= fresh_s``; its point moved on by
    p_dot age + a_cmd age^2 / 2 up to ``hold_s``; None when older (unknown: the caller holds).
    """
    if age_s > hold_s:
        return None
    if age_s <= fresh_s:
        return state
    x = state.copy()
    pdot = np.array(_point_velocity(x[2], x[3], x[4], com_offset_m))
    x[:2] = x[:2] + pdot * age_s + 0.5 * accel_mps2 * age_s * age_s
    return x


def neighbour_goal(t_s: float, path, parent_state, offset_m, com_offset_m: float) -> tuple:
    """(g, g_dot) of a robot at scenario time ``t_s`` (S8.3 item 1), each (2,) [m], [m/s]: a
    leader's (``path`` not None) r(t), r_dot(t); a follower's original parent point + delta
    ``offset_m`` and that point's velocity, from the parent's ``parent_state`` (5,) (its
    ``com_offset_m``); (None, None) when the parent's state is unknown.
    """
    if path is not None:
        r, rd, _ = path.reference(t_s)
        return np.asarray(r, dtype=float), np.asarray(rd, dtype=float)
    if parent_state is None:
        return None, None
    x, y, th, v, w = (float(q) for q in parent_state)
    pdx, pdy = _point_velocity(th, v, w, com_offset_m)
    gx, gy, gdx, gdy = _follower_goal(x, y, pdx, pdy, float(offset_m[0]), float(offset_m[1]))
    return np.array([gx, gy]), np.array([gdx, gdy])
