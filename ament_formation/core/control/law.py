"""ONE robot's law at one sample (S3 with the mode's field: S4, S6, S7) and the S8.3 formation
goal: the functions the simulator, the robot's controller and the coordinator's arbiter all call.

* :func:`robot_law` -- the mode's desired velocity field V_d, V_d_dot (S4 leader/follower with the
  parent's commanded acceleration as feed-forward; S6.3/S6.4 limit cycle for obstacles, moving and
  rotating; S7 yield and mutual fields) and the sliding-mode torque (S3.1, S3.2, S3.5, S3.6).
* :func:`goals_and_fields` -- the formation goal g_i, g_i_dot and the coordination field V_c
  (S8.3); :func:`goal_fields` returns new arrays for one snapshot.
* :func:`gains_vector` -- the gains of :class:`ControlGains` for the compiled code
  (:data:`Gains`).
"""

from __future__ import annotations

from collections import namedtuple

from numba import njit
import numpy as np

from ament_formation.core.control.automaton import (
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    robot_mode_k,
)
from ament_formation.core.control.encounters import keepout_radius
from ament_formation.core.control.formation import tracking_field_k
from ament_formation.core.control.limit_cycle import (
    design_gains,
    ellipse_field_k,
    gain_schedule_k,
    parking_factor_k,
)
from ament_formation.core.control.safety import accel_limit, clip_norm, safe_field
from ament_formation.core.control.smc import smc_torque_k
from ament_formation.core.model.dynamics import robot_plant_k, ROW_TAU_MAX

Gains = namedtuple(
    'Gains',
    [
        'switching_gain_mps2',
        'boundary_layer_mps',
        'formation_gain_per_s',
        'formation_speed_cap_mps',
        'reaching_rate_mps2',
    ],
)
Gains.__doc__ = """The gains of :class:`~ament_formation.core.params.ControlGains` for the compiled
code: a named tuple of floats, fields named and in the units of ControlGains (K [m/s^2], epsilon
[m/s], alpha [1/s], v_cap [m/s], lambda [m/s^2]).
"""


def gains_vector(control) -> Gains:
    """:data:`Gains` of a :class:`ControlGains`."""
    return Gains(*(float(getattr(control, name)) for name in Gains._fields))


LawRobots = namedtuple('LawRobots', ['x', 'pd', 'acmd', 'rbody', 'coeffs'])
LawRobots.__doc__ = """Every robot as :func:`robot_law` reads it (rows in one robot order): ``x``
(N, 5) states [x_m, y_m, theta_rad, v_mps, omega_radps]; ``pd`` (N, 2) point velocities [m/s];
``acmd`` (N, 2) commanded point accelerations [m/s^2] (a parent's must be current: S4);
``rbody`` (N,) body radii [m]; ``coeffs`` (7, N) plant rows [m~, I~, r, a, d, m_c, tau_max].
"""

Tracking = namedtuple('Tracking', ['parent', 'offset', 'ref', 'goal', 'goal_dot'])
Tracking.__doc__ = """What each robot tracks: ``parent`` (N,) current parent row (-1: root);
``offset`` (N, 2) delta to the current parent [m]; ``ref`` (N, 6) leader reference rows
[r, r_dot, r_ddot] (used when parent < 0 and in coordination); ``goal``, ``goal_dot`` (N, 2) the
S8.3 formation goal [m] and its velocity [m/s] (S6.5 parking factor).
"""


RobotTracking = namedtuple(
    'RobotTracking',
    ['parent', 'offset', 'ref', 'goal', 'goal_dot'],
)
RobotTracking.__doc__ = """Row i of :data:`Tracking` as scalars (what the law of robot i reads of
it): ``parent`` row (int, -1: root); ``offset`` (2-tuple) [m]; ``ref`` (6-tuple) [r, r_dot,
r_ddot]; ``goal`` (2-tuple) [m]; ``goal_dot`` (2-tuple) [m/s].
"""


@njit(cache=True)
def tracking_row_k(tracking, i):
    """:data:`RobotTracking` of robot row i of ``tracking`` (:data:`Tracking`)."""
    offset, ref, goal, goal_dot = tracking.offset, tracking.ref, tracking.goal, tracking.goal_dot
    return RobotTracking(
        tracking.parent[i],
        (offset[i, 0], offset[i, 1]),
        (ref[i, 0], ref[i, 1], ref[i, 2], ref[i, 3], ref[i, 4], ref[i, 5]),
        (goal[i, 0], goal[i, 1]),
        (goal_dot[i, 0], goal_dot[i, 1]),
    )


@njit(cache=True)
def _target_k(i, md, k, x, pd, acmd, rbody, obstacles, prm):
    """The avoidance target of robot i: (c, c_dot, c_ddot, phi, phi_dot, phi_ddot, r1, r2, v_tan)
    of obstacle k (MODE_OBSTACLE, S6) or of robot k (yield/mutual: the circle R_aa, S7).
    """
    if md == MODE_OBSTACLE:
        ob = obstacles
        return (
            ob.c[k, 0],
            ob.c[k, 1],
            ob.v[k, 0],
            ob.v[k, 1],
            ob.a[k, 0],
            ob.a[k, 1],
            ob.phi[k],
            ob.phi_dot[k],
            ob.phi_ddot[k],
            ob.axes[k, 0],
            ob.axes[k, 1],
            prm.tangential_speed_mps,
        )
    r = keepout_radius(rbody, i, k, prm)
    return (
        x[k, 0],
        x[k, 1],
        pd[k, 0],
        pd[k, 1],
        acmd[k, 0],
        acmd[k, 1],
        0.0,
        0.0,
        0.0,
        r,
        r,
        prm.agent_tangential_speed_mps,
    )


@njit(cache=True)
def _formation_field(i, x, pd, acmd, track, gains, vmax, amax):
    """S4 coordination field of robot i (``track``: its :data:`RobotTracking`) -> (vdx, vdy,
    vddx, vddy): a leader tracks r(t), a follower p_j + delta with its parent's velocity and
    commanded acceleration as feed-forward, bounded by ``vmax`` [m/s] and ``amax`` [m/s^2]
    (S14.5).
    """
    j = track.parent
    if j < 0:  # leader: e = p - r (S4)
        ref = track.ref
        ex, ey, rvx, rvy, rax, ray = (
            x[i, 0] - ref[0],
            x[i, 1] - ref[1],
            ref[2],
            ref[3],
            ref[4],
            ref[5],
        )
    else:  # follower: e = p_i - p_j - delta, feed-forward p_dot_j, a_j (S4), bounded (S14.5)
        ox, oy = track.offset
        ex, ey = x[i, 0] - x[j, 0] - ox, x[i, 1] - x[j, 1] - oy
        rvx, rvy = clip_norm(pd[j, 0], pd[j, 1], vmax)
        rax, ray = clip_norm(acmd[j, 0], acmd[j, 1], amax)
    return tracking_field_k(
        ex,
        ey,
        rvx,
        rvy,
        rax,
        ray,
        pd[i, 0],
        pd[i, 1],
        gains.formation_gain_per_s,
        gains.formation_speed_cap_mps,
    )


@njit(cache=True)
def _avoidance_field(t, p, target, track, state, prm, vmax, amax):
    """S6.3/S6.4 limit-cycle field of a robot at ``p`` (x, y, x_dot, y_dot of its point) around
    its ``target`` (:func:`_target_k`: an obstacle, or a robot for S7 yield/mutual); ``track``
    and ``state`` are its :data:`RobotTracking` and
    :data:`~ament_formation.core.control.automaton.RobotMode`. Returns (vdx, vdy, vddx, vddy,
    w_c_dot_x, w_c_dot_y); the w_c derivative is non-zero for a mutual pair only
    (V_d = w_c + F/2).
    """
    md = state.mode
    cx, cy, cvx, cvy, cax, cay, phi, phd, phdd, r1, r2, vtan = target
    if md != MODE_OBSTACLE:  # a robot target's feed-forward is bounded (S14.5)
        cvx, cvy = clip_norm(cvx, cvy, vmax)
        cax, cay = clip_norm(cax, cay, amax)
    big1 = prm.limit_cycle_scale * r1
    big2 = prm.limit_cycle_scale * r2
    psi_max, c_max = design_gains(r1, r2, vtan, prm)  # S6.5
    zx = p[0] - cx
    zy = p[1] - cy
    zdx = p[2] - cvx
    zdy = p[3] - cvy
    s = state.direction
    if md == MODE_MUTUAL:
        mu = 1.0
        mud = 0.0
    else:
        goal, goal_dot = track.goal, track.goal_dot
        mu, mud = parking_factor_k(
            zx,
            zy,
            zdx,
            zdy,
            goal[0] - cx,
            goal[1] - cy,
            goal_dot[0] - cvx,
            goal_dot[1] - cvy,
            phi,
            phd,
            big1,
            big2,
            s,
            prm.parking_anomaly_rad,
        )
    psd, psdd, cc, ccd = gain_schedule_k(
        t - state.t_entry_s,
        psi_max,
        c_max,
        s,
        mu,
        mud,
        prm.gain_start_fraction,
        prm.gain_time_constant_s,
    )
    fx, fy, fdx, fdy, h, hd = ellipse_field_k(
        zx, zy, zdx, zdy, phi, phd, phdd, big1, big2, psd, psdd, cc, ccd
    )
    if md == MODE_MUTUAL:  # S7 reciprocal field: V_d = w_c + F/2
        (wcx, wcy), (wtx, wty) = state.drift, state.drift_target
        tau = prm.mutual_drift_tau_s
        wdx = (wtx - wcx) / tau
        wdy = (wty - wcy) / tau
        vdx, vdy = wcx + 0.5 * fx, wcy + 0.5 * fy
        vddx, vddy = wdx + 0.5 * fdx, wdy + 0.5 * fdy
        return vdx, vdy, vddx, vddy, wdx, wdy
    # S6.3/S6.4 (obstacle) and S7 yield: V_d = x~dot + F
    return cvx + fx, cvy + fy, cax + fdx, cay + fdy, 0.0, 0.0


@njit(cache=True)
def robot_law_k(i, t, x, pd, acmd, rbody, coeffs, obstacles, track, state, gains, prm):
    """:func:`robot_law` with the arrays of :data:`LawRobots` and robot i's rows of the tracking
    and automaton state as scalars (``track`` :data:`RobotTracking`, ``state``
    :data:`~ament_formation.core.control.automaton.RobotMode`).
    """
    vmax = prm.speed_limit_mps
    amax = accel_limit(coeffs, i)
    md = state.mode
    if md == MODE_C:
        vdx, vdy, vddx, vddy = _formation_field(i, x, pd, acmd, track, gains, vmax, amax)
        wdx = 0.0
        wdy = 0.0
    else:
        target = _target_k(i, md, state.target, x, pd, acmd, rbody, obstacles, prm)
        p = (x[i, 0], x[i, 1], pd[i, 0], pd[i, 1])
        vdx, vdy, vddx, vddy, wdx, wdy = _avoidance_field(
            t, p, target, track, state, prm, vmax, amax
        )
    k = gains.switching_gain_mps2
    ob = obstacles
    vdx, vdy, vddx, vddy = safe_field(  # speed limit and braking barrier (core/control/safety.py)
        i, x, pd, vdx, vdy, vddx, vddy, ob.c, ob.v, ob.phi, ob.phi_dot, ob.axes, rbody, k, prm
    )
    plant = robot_plant_k(coeffs, i)
    t1, t2, sx, sy, sat, acx, acy = smc_torque_k(
        x[i, 2],
        x[i, 3],
        x[i, 4],
        vdx,
        vdy,
        vddx,
        vddy,
        plant,
        coeffs[ROW_TAU_MAX, i],
        k,
        k,
        gains.boundary_layer_mps,
    )
    return t1, t2, sx, sy, sat, acx, acy, wdx, wdy


@njit(cache=True)
def robot_law(i, t, robots, tracking, auto, obstacles, gains, prm):
    """Torque of robot i at time t in its current mode (S3.2 with the mode's V_d, V_d_dot).

    Parameters
    ----------
    i : robot row. t : time [s].
    robots : :data:`LawRobots`; tracking : :data:`Tracking`.
    auto : :data:`~ament_formation.core.control.automaton.AutomatonArrays` (mode, target,
        direction, entry time, mutual drift w_c and its target of row i are read).
    obstacles : :data:`~ament_formation.core.model.obstacles.ObstacleSnapshot` at t.
    gains : :data:`Gains`; prm : :data:`~ament_formation.core.control.automaton.Switching`.

    Returns
    -------
    (tau_left, tau_right, sigma_x, sigma_y, saturated, a_cmd_x, a_cmd_y, w_c_dot_x, w_c_dot_y)
    """
    x, pd, acmd, rbody, coeffs = robots
    track = tracking_row_k(tracking, i)
    state = robot_mode_k(auto, i)
    return robot_law_k(i, t, x, pd, acmd, rbody, coeffs, obstacles, track, state, gains, prm)


@njit(cache=True)
def follower_goal_k(px, py, pdx, pdy, ox, oy):
    """S8.3 item 1 for a follower: g = p of its original parent + delta, g_dot = that point's
    velocity -> (gx, gy, gdx, gdy).
    """
    return px + ox, py + oy, pdx, pdy


# implements: S8.3
@njit(cache=True)
def goals_and_fields(
    x, pd, ref, orig_parent, orig_offset, gains, goal, goal_dot, vc, with_fields=True
):
    """Formation goal g_i, its velocity and the coordination field V_c = g_dot - Phi(p - g) (S8.3).

    Leaders: g = r(t). Followers: g = p of the original parent + delta (S8.3 item 1). V_c only
    when ``with_fields`` (the automaton needs it at decisions only).
    """
    n = x.shape[0]
    for i in range(n):
        j = orig_parent[i]
        if j < 0:
            goal[i, 0] = ref[i, 0]
            goal[i, 1] = ref[i, 1]
            goal_dot[i, 0] = ref[i, 2]
            goal_dot[i, 1] = ref[i, 3]
        else:
            goal[i, 0], goal[i, 1], goal_dot[i, 0], goal_dot[i, 1] = follower_goal_k(
                x[j, 0], x[j, 1], pd[j, 0], pd[j, 1], orig_offset[i, 0], orig_offset[i, 1]
            )
        if not with_fields:
            continue
        vdx, vdy, _, _ = tracking_field_k(
            x[i, 0] - goal[i, 0],
            x[i, 1] - goal[i, 1],
            goal_dot[i, 0],
            goal_dot[i, 1],
            0.0,
            0.0,
            pd[i, 0],
            pd[i, 1],
            gains.formation_gain_per_s,
            gains.formation_speed_cap_mps,
        )
        vc[i, 0] = vdx
        vc[i, 1] = vdy


def goal_fields(
    x, pd, ref, orig_parent, orig_offset, gains
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`goals_and_fields` into new arrays: (goal, goal_dot, V_c), each (N, 2). For callers
    that evaluate one snapshot (core/control/controller.py, core/control/arbiter.py); the simulator
    reuses buffers.
    """
    n = x.shape[0]
    goal, goal_dot, vc = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2))
    goals_and_fields(x, pd, ref, orig_parent, orig_offset, gains, goal, goal_dot, vc, True)
    return goal, goal_dot, vc
