"""ONE robot's law at one sample (S3 with the mode's field: S4, S6, S7) and the S8.3 formation
goal: the functions the simulator, the robot's controller and the coordinator's arbiter all call.

* :func:`robot_law` -- the mode's desired velocity field V_d, V_d_dot (S4 leader/follower with the
  parent's commanded acceleration as feed-forward; S6.3/S6.4 limit cycle for obstacles, moving and
  rotating; S7 yield and mutual fields) and the sliding-mode torque (S3.1, S3.2, S3.5, S3.6).
* :func:`goals_and_fields` -- the formation goal g_i, g_i_dot and the coordination field V_c
  (S8.3); :func:`goal_fields` returns new arrays for one snapshot.
* :func:`gains_vector` -- the packed gains of :class:`ControlGains` for the compiled code
  (``G_*`` indices).
"""

from __future__ import annotations

from numba import njit
import numpy as np

from ament_formation.core.control.automaton import (
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    P_BETA0,
    P_DRIFT_TAU,
    P_L,
    P_PSI_SLOW,
    P_TAU_G,
    P_VMAX,
    P_VTAN,
    P_VTAN_AGENT,
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

# gains vector layout for the compiled code
G_K, G_EPS, G_ALPHA, G_VCAP, G_LAMBDA = range(5)


def gains_vector(control) -> np.ndarray:
    """(5,) [K, epsilon, alpha, v_cap, lambda] of a :class:`ControlGains` (``G_*`` indices)."""
    return np.array(
        [
            control.switching_gain_mps2,
            control.boundary_layer_mps,
            control.formation_gain_per_s,
            control.formation_speed_cap_mps,
            control.reaching_rate_mps2,
        ],
        dtype=float,
    )


@njit(cache=True)
def _target_k(i, md, k, x, pd, acmd, oc, ov, oa, ophi, ophid, ophidd, oaxes, rbody, prm):
    """The avoidance target of robot i: (c, c_dot, c_ddot, phi, phi_dot, phi_ddot, r1, r2, v_tan)
    of obstacle k (MODE_OBSTACLE, S6) or of robot k (yield/mutual: the circle R_aa, S7).
    """
    if md == MODE_OBSTACLE:
        return (
            oc[k, 0],
            oc[k, 1],
            ov[k, 0],
            ov[k, 1],
            oa[k, 0],
            oa[k, 1],
            ophi[k],
            ophid[k],
            ophidd[k],
            oaxes[k, 0],
            oaxes[k, 1],
            prm[P_VTAN],
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
        prm[P_VTAN_AGENT],
    )


@njit(cache=True)
def robot_law(
    i,
    t,
    x,
    pd,
    acmd,
    parent,
    offset,
    ref,
    goal,
    goal_dot,
    mode,
    tgt,
    sdir,
    t_entry,
    wc,
    wtgt,
    oc,
    ov,
    oa,
    ophi,
    ophid,
    ophidd,
    oaxes,
    rbody,
    coeffs,
    gains,
    prm,
):
    """Torque of robot i at time t in its current mode (S3.2 with the mode's V_d, V_d_dot).

    Parameters
    ----------
    i : robot row. t : time [s].
    x : (N, 5) states; pd : (N, 2) point velocities; acmd : (N, 2) commanded point accelerations
        of the other robots (a parent's must be current: feed-forward of S4).
    parent : (N,) current parent row (-1: root); offset : (N, 2) delta to the current parent.
    ref : (N, 6) leader reference rows [r, r_dot, r_ddot] (used when parent < 0 and mode C).
    goal, goal_dot : (N, 2) formation goal and its velocity (S6.5 parking factor).
    mode, tgt, sdir, t_entry : (N,) automaton state; wc, wtgt : (N, 2) mutual drift.
    oc, ov, oa : (M, 2), ophi, ophid, ophidd : (M,), oaxes : (M, 2): obstacles at t (P semi-axes).
    rbody : (N,) body radii; coeffs : (7, N) [m~, I~, r, a, d, m_c, tau_max]; gains : packed
        [K, eps, alpha, v_cap, lambda]; prm : packed SwitchingParams.

    Returns
    -------
    (tau_left, tau_right, sigma_x, sigma_y, saturated, a_cmd_x, a_cmd_y, w_c_dot_x, w_c_dot_y)
    """
    th = x[i, 2]
    v = x[i, 3]
    w = x[i, 4]
    pdx = pd[i, 0]
    pdy = pd[i, 1]
    wdx = 0.0
    wdy = 0.0
    md = mode[i]
    vmax = prm[P_VMAX]
    amax = accel_limit(coeffs, i)
    if md == MODE_C:
        j = parent[i]
        if j < 0:  # leader: e = p - r (S4)
            ex, ey, rvx, rvy, rax, ray = (
                x[i, 0] - ref[i, 0],
                x[i, 1] - ref[i, 1],
                ref[i, 2],
                ref[i, 3],
                ref[i, 4],
                ref[i, 5],
            )
        else:  # follower: e = p_i - p_j - delta, feed-forward p_dot_j, a_j (S4), bounded (S14.5)
            ex, ey = x[i, 0] - x[j, 0] - offset[i, 0], x[i, 1] - x[j, 1] - offset[i, 1]
            rvx, rvy = clip_norm(pd[j, 0], pd[j, 1], vmax)
            rax, ray = clip_norm(acmd[j, 0], acmd[j, 1], amax)
        vdx, vdy, vddx, vddy = tracking_field_k(
            ex, ey, rvx, rvy, rax, ray, pdx, pdy, gains[G_ALPHA], gains[G_VCAP]
        )
    else:
        k = tgt[i]
        cx, cy, cvx, cvy, cax, cay, phi, phd, phdd, r1, r2, vtan = _target_k(
            i, md, k, x, pd, acmd, oc, ov, oa, ophi, ophid, ophidd, oaxes, rbody, prm
        )
        if md != MODE_OBSTACLE:  # a robot target's feed-forward is bounded (S14.5)
            cvx, cvy = clip_norm(cvx, cvy, vmax)
            cax, cay = clip_norm(cax, cay, amax)
        big1 = prm[P_L] * r1
        big2 = prm[P_L] * r2
        psi_max, c_max = design_gains(r1, r2, vtan, prm)  # S6.5
        zx = x[i, 0] - cx
        zy = x[i, 1] - cy
        zdx = pdx - cvx
        zdy = pdy - cvy
        s = sdir[i]
        if md == MODE_MUTUAL:
            mu = 1.0
            mud = 0.0
        else:
            mu, mud = parking_factor_k(
                zx,
                zy,
                zdx,
                zdy,
                goal[i, 0] - cx,
                goal[i, 1] - cy,
                goal_dot[i, 0] - cvx,
                goal_dot[i, 1] - cvy,
                phi,
                phd,
                big1,
                big2,
                s,
                prm[P_PSI_SLOW],
            )
        psd, psdd, cc, ccd = gain_schedule_k(
            t - t_entry[i], psi_max, c_max, s, mu, mud, prm[P_BETA0], prm[P_TAU_G]
        )
        fx, fy, fdx, fdy, h, hd = ellipse_field_k(
            zx, zy, zdx, zdy, phi, phd, phdd, big1, big2, psd, psdd, cc, ccd
        )
        if md == MODE_MUTUAL:  # S7 reciprocal field: V_d = w_c + F/2
            tau = prm[P_DRIFT_TAU]
            wdx = (wtgt[i, 0] - wc[i, 0]) / tau
            wdy = (wtgt[i, 1] - wc[i, 1]) / tau
            vdx, vdy = wc[i, 0] + 0.5 * fx, wc[i, 1] + 0.5 * fy
            vddx, vddy = wdx + 0.5 * fdx, wdy + 0.5 * fdy
        else:  # S6.3/S6.4 (obstacle) and S7 yield: V_d = x~dot + F
            vdx, vdy, vddx, vddy = cvx + fx, cvy + fy, cax + fdx, cay + fdy
    vdx, vdy, vddx, vddy = safe_field(  # speed limit and braking barrier (core/control/safety.py)
        i, x, pd, vdx, vdy, vddx, vddy, oc, ov, ophi, ophid, oaxes, rbody, gains[G_K], prm
    )
    t1, t2, sx, sy, sat, acx, acy = smc_torque_k(
        th,
        v,
        w,
        vdx,
        vdy,
        vddx,
        vddy,
        coeffs[0, i],
        coeffs[1, i],
        coeffs[2, i],
        coeffs[3, i],
        coeffs[4, i],
        coeffs[5, i],
        coeffs[6, i],
        gains[G_K],
        gains[G_K],
        gains[G_EPS],
    )
    return t1, t2, sx, sy, sat, acx, acy, wdx, wdy


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
            gains[G_ALPHA],
            gains[G_VCAP],
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
