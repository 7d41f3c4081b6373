"""One robot's law at one sample (docs/control-law.md S3 with the mode's field: S4, S6, S7) and the
formation goal (S8.3 item 1): the functions the simulator and the robot agent both call.

* :func:`robot_law_k` -- the mode's desired velocity field V_d, V_d_dot (S4 leader/follower with
  the parent's commanded acceleration as feed-forward; S6.3/S6.4 limit cycle round an obstacle,
  moving and rotating; S7.3 yield and mutual fields round a robot), the last line of defence
  (S15) and the sliding-mode torque (S3.1, S3.2, S3.5, S3.6).
* :func:`goal_k` / :func:`goals_and_fields` -- the formation goal g_i, g_i_dot and the
  coordination field V_c (S8.3).
"""

from __future__ import annotations

from collections import namedtuple

from numba import njit

from ament_formation.core.control.formation import tracking_field_k
from ament_formation.core.control.limit_cycle import (
    design_gains,
    ellipse_field_k,
    gain_schedule_k,
    parking_factor_k,
)
from ament_formation.core.control.safety import accel_limit, clip_norm, safe_field
from ament_formation.core.control.smc import smc_torque_k
from ament_formation.core.control.switching import MODE_C, MODE_MUTUAL, MODE_OBSTACLE
from ament_formation.core.model.dynamics import robot_plant_k, ROW_TAU_MAX

RobotTracking = namedtuple('RobotTracking', ['parent', 'offset', 'ref', 'goal', 'goal_dot'])
RobotTracking.__doc__ = """What robot i tracks, as scalars: ``parent`` its current parent row
(-1: root, then ``ref`` applies); ``offset`` (2-tuple) delta to the parent [m]; ``ref``
(6-tuple) [r, r_dot, r_ddot] of a leader's reference (S17); ``goal``, ``goal_dot`` (2-tuples)
its formation goal [m] and its velocity [m/s] (S6.5 parking factor).
"""

RobotMode = namedtuple(
    'RobotMode', ['mode', 'target', 'direction', 't_entry_s', 'drift', 'drift_target', 'park_at']
)
RobotMode.__doc__ = """Row i of :data:`~ament_formation.core.control.switching.Modes` as
scalars: ``mode`` (MODE_*), ``target`` (obstacle index or robot row), ``direction`` (+1 CCW,
-1 CW), ``t_entry_s`` [s], ``drift`` and ``drift_target`` (2-tuples [m/s]) a pair's w_c and its
target, ``park_at`` [s] when the S6.5 parking factor applies from.
"""


@njit(cache=True, error_model='numpy', inline='always')
def mode_row(m, i):
    """:data:`RobotMode` of row i of ``m`` (:data:`Modes`)."""
    return RobotMode(m.mode[i], m.tgt[i], m.sdir[i], m.t_entry[i], (m.wc[i, 0], m.wc[i, 1]),
                     (m.wtgt[i, 0], m.wtgt[i, 1]), m.park_at[i])


@njit(cache=True, error_model='numpy', inline='always')
def _target_k(i, md, k, x, pd, acmd, rbody, ob, prm):
    """The avoidance target of robot i: (c, c_dot, c_ddot, phi, phi_dot, phi_ddot, r1, r2, v_tan)
    of obstacle k (S6) or of robot k (S7: its keep-out circle R_aa).
    """
    if md == MODE_OBSTACLE:
        return (ob.c[k, 0], ob.c[k, 1], ob.v[k, 0], ob.v[k, 1], ob.a[k, 0], ob.a[k, 1],
                ob.phi[k], ob.phi_dot[k], ob.phi_ddot[k], ob.axes[k, 0], ob.axes[k, 1],
                prm.tangential_speed_mps)
    r = rbody[i] + rbody[k] + prm.agent_keepout_margin_m
    return (x[k, 0], x[k, 1], pd[k, 0], pd[k, 1], acmd[k, 0], acmd[k, 1], 0.0, 0.0, 0.0, r, r,
            prm.agent_tangential_speed_mps)


@njit(cache=True, error_model='numpy', inline='always')
def _formation_field(i, x, pd, acmd, track, prm, vmax, amax):
    """S4 field of robot i -> (vdx, vdy, vddx, vddy): a leader tracks r(s) (S17), a follower
    p_j + delta with its parent's velocity and commanded acceleration as feed-forward, bounded
    by ``vmax`` [m/s] and ``amax`` [m/s^2] (S15.1).
    """
    j = track.parent
    if j < 0:
        ref = track.ref
        ex, ey, rvx, rvy, rax, ray = (x[i, 0] - ref[0], x[i, 1] - ref[1], ref[2], ref[3],
                                      ref[4], ref[5])
    else:
        ox, oy = track.offset
        ex, ey = x[i, 0] - x[j, 0] - ox, x[i, 1] - x[j, 1] - oy
        rvx, rvy = clip_norm(pd[j, 0], pd[j, 1], vmax)
        rax, ray = clip_norm(acmd[j, 0], acmd[j, 1], amax)
    return tracking_field_k(ex, ey, rvx, rvy, rax, ray, pd[i, 0], pd[i, 1],
                            prm.formation_gain_per_s, prm.formation_speed_cap_mps)


@njit(cache=True, error_model='numpy', forceinline=True)
def _avoidance_field(t, p, target, track, state, prm, vmax, amax):
    """S6.3/S6.4 limit-cycle field of a robot at ``p`` (x, y, x_dot, y_dot of its point) round
    its ``target`` (:func:`_target_k`) -> (vdx, vdy, vddx, vddy, w_c_dot_x, w_c_dot_y); the w_c
    derivative is non-zero for a mutual pair only (V_d = w_c + F/2, S7.3).
    """
    md = state.mode
    cx, cy, cvx, cvy, cax, cay, phi, phd, phdd, r1, r2, vtan = target
    if md != MODE_OBSTACLE:  # a robot target's feed-forward is bounded (S15.1)
        cvx, cvy = clip_norm(cvx, cvy, vmax)
        cax, cay = clip_norm(cax, cay, amax)
    big1 = prm.limit_cycle_scale * r1
    big2 = prm.limit_cycle_scale * r2
    psi_max, c_max = design_gains(r1, r2, vtan, prm)  # S6.5
    zx, zy = p[0] - cx, p[1] - cy
    zdx, zdy = p[2] - cvx, p[3] - cvy
    s = state.direction
    mu, mud = 1.0, 0.0
    if md != MODE_MUTUAL and t >= state.park_at:
        goal, goal_dot = track.goal, track.goal_dot
        mu, mud = parking_factor_k(zx, zy, zdx, zdy, goal[0] - cx, goal[1] - cy,
                                   goal_dot[0] - cvx, goal_dot[1] - cvy, phi, phd, big1, big2, s,
                                   prm.parking_anomaly_rad)
    psd, psdd, cc, ccd = gain_schedule_k(t - state.t_entry_s, psi_max, c_max, s, mu, mud,
                                         prm.gain_start_fraction, prm.gain_time_constant_s)
    fx, fy, fdx, fdy, _h, _hd = ellipse_field_k(zx, zy, zdx, zdy, phi, phd, phdd, big1, big2, psd,
                                                psdd, cc, ccd)
    if md == MODE_MUTUAL:  # S7.3 reciprocal field
        (wcx, wcy), (wtx, wty) = state.drift, state.drift_target
        wdx = (wtx - wcx) / prm.mutual_drift_tau_s
        wdy = (wty - wcy) / prm.mutual_drift_tau_s
        return wcx + 0.5 * fx, wcy + 0.5 * fy, wdx + 0.5 * fdx, wdy + 0.5 * fdy, wdx, wdy
    return cvx + fx, cvy + fy, cax + fdx, cay + fdy, 0.0, 0.0  # S6.3/S6.4, S7.3 yield


# implements: S3.2
@njit(cache=True, error_model='numpy', inline='always')
def robot_law_k(i, t, x, pd, acmd, rbody, coeffs, ob, nbrs, orows, track, state, prm,
                cons=None):
    """Torque of robot i at time ``t`` [s] in its mode (S3.2 with the mode's V_d, V_d_dot).

    x (N, 5) states, pd (N, 2) point velocities, acmd (N, 2) commanded point accelerations (a
    parent's of this sample, S4), rbody (N,), coeffs (7, N) plant rows; ``ob`` the obstacles
    (ObstacleSnapshot) at t; ``nbrs`` rows of the robots the barrier checks, ``orows`` rows of
    the obstacles it checks (the rest are out of its reach); ``track``
    :data:`RobotTracking`, ``state`` :data:`RobotMode`; ``prm`` LawK; ``cons`` the barrier's
    scratch rows (core/control/safety.py :func:`safe_field`; None: its own). Returns (tau_left,
    tau_right, sigma_x, sigma_y, saturated, a_cmd_x, a_cmd_y, w_c_dot_x, w_c_dot_y).
    """
    vmax = prm.speed_limit_mps
    amax = accel_limit(coeffs, i)
    wdx = wdy = 0.0
    if state.mode == MODE_C:
        vdx, vdy, vddx, vddy = _formation_field(i, x, pd, acmd, track, prm, vmax, amax)
    else:
        target = _target_k(i, state.mode, state.target, x, pd, acmd, rbody, ob, prm)
        p = (x[i, 0], x[i, 1], pd[i, 0], pd[i, 1])
        vdx, vdy, vddx, vddy, wdx, wdy = _avoidance_field(t, p, target, track, state, prm, vmax,
                                                          amax)
    if cons is None:
        vdx, vdy, vddx, vddy = safe_field(i, x, pd, nbrs, orows, vdx, vdy, vddx, vddy, ob, rbody,
                                          prm)
    else:
        vdx, vdy, vddx, vddy = safe_field(i, x, pd, nbrs, orows, vdx, vdy, vddx, vddy, ob, rbody,
                                          prm, cons)
    k = prm.switching_gain_mps2
    t1, t2, sx, sy, sat, acx, acy = smc_torque_k(
        x[i, 2], x[i, 3], x[i, 4], vdx, vdy, vddx, vddy, robot_plant_k(coeffs, i),
        coeffs[ROW_TAU_MAX, i], k, k, prm.boundary_layer_mps,
    )
    return t1, t2, sx, sy, sat, acx, acy, wdx, wdy


# implements: S8.3/goal
@njit(cache=True, error_model='numpy', inline='always')
def goal_k(i, x, pd, ref, orig_parent, orig_offset, prm):
    """S8.3 item 1: the formation goal of robot i and the coordination field V_c = g_dot -
    Phi(p - g) -> (gx, gy, gdx, gdy, vcx, vcy). Leaders: g = r(s) (``ref`` row i); followers:
    the point of the original parent + delta.
    """
    j = orig_parent[i]
    if j < 0:
        gx, gy, gdx, gdy = ref[i, 0], ref[i, 1], ref[i, 2], ref[i, 3]
    else:
        gx, gy = x[j, 0] + orig_offset[i, 0], x[j, 1] + orig_offset[i, 1]
        gdx, gdy = pd[j, 0], pd[j, 1]
    vcx, vcy, _a, _b = tracking_field_k(x[i, 0] - gx, x[i, 1] - gy, gdx, gdy, 0.0, 0.0, pd[i, 0],
                                        pd[i, 1], prm.formation_gain_per_s,
                                        prm.formation_speed_cap_mps)
    return gx, gy, gdx, gdy, vcx, vcy


@njit(cache=True, error_model='numpy')
def goals_and_fields(x, pd, ref, orig_parent, orig_offset, prm, goal, goal_dot, vc):
    """:func:`goal_k` of every row -> ``goal``, ``goal_dot``, ``vc`` (N, 2)."""
    for i in range(x.shape[0]):
        gx, gy, gdx, gdy, vcx, vcy = goal_k(i, x, pd, ref, orig_parent, orig_offset, prm)
        goal[i, 0], goal[i, 1], goal_dot[i, 0], goal_dot[i, 1] = gx, gy, gdx, gdy
        vc[i, 0], vc[i, 1] = vcx, vcy
