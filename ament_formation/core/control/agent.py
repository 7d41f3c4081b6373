"""The robot agent: everything one robot runs on board, behind one call per control period
(docs/control-law.md S10.3).

An :class:`AgentBatch` hosts one robot (the controller node) or several (a team process, the
camera-sensing simulator) and owns, per robot: the S10.1 pose estimator, the camera-loss and
hold stops (docs/design.md §7), the table of the robots it hears
(states extrapolated with their commanded accelerations, S10.2, and the hearing range), the
formation graph and the coordinator's encounter assignment (S7.1), the progress of its
reference when it leads a team (S17), its own switching (S8.7) and the law (S3, S15) with the
torque clamp. The caller feeds what arrived (:meth:`AgentBatch.wheel`, :meth:`camera`,
:meth:`hear`, :meth:`hear_mode`, :meth:`set_graph`, :meth:`assign`) and calls
:meth:`AgentBatch.tick` once per control period: one compiled call for every hosted robot
(:func:`agent_tick_k`). It reads the results from :attr:`AgentBatch.out`.

Times are the robot's clock [s]; the caller converts a remote stamp to it (the node with its
clock-offset estimate). Scenario time is ``now - start_s`` (the coordinator's mission start).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, fields
import math

from numba import njit
import numpy as np

from ament_formation.core.borrowed import borrowed
from ament_formation.core.control.estimator import (
    camera_update_k,
    COUNTERS,
    EstimatorK,
    EstimatorParams,
    F_CAMERA_T,
    F_ODOM_T,
    I_INIT,
    new_estimates,
    state_at_k,
    wheel_update_k,
)
from ament_formation.core.control.law import goal_k, mode_row, robot_law_k, RobotTracking
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.progress import leader_reference, new_progress, step, tabulate
from ament_formation.core.control.stop import (delay_scale_k, lead_k, stop_torque_k, StopK,
                                               StopLead)
from ament_formation.core.control.switching import (
    apply_assignment,
    MODE_C,
    MODE_MUTUAL,
    MODE_NAMES,
    MODE_OBSTACLE,
    MODE_YIELD,
    Modes,
    new_modes,
    robot_transitions,
    Robots,
)
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import (
    PlantCoeffs,
    point_velocity_k,
    robot_plant_k,
    ROW_D,
    ROW_TAU_MAX,
)
from ament_formation.core.model.obstacles import obstacle_arrays, obstacle_states, ObstacleSnapshot
from ament_formation.core.params import param

STATUS = ('waiting', 'running', 'hold_parent', 'stopped_wheels', 'stopped_pose',
          'stopped_coordinator', 'stopped_clock')
(WAITING, RUNNING, HOLD_PARENT, STOPPED_WHEELS, STOPPED_POSE, STOPPED_COORDINATOR,
 STOPPED_CLOCK) = range(7)
WHEEL_QUEUE = 16  # wheel samples and camera poses kept between two periods (newest win)
CAMERA_QUEUE = 8


@dataclass(frozen=True)
class AgentParams:
    """The on-board parameters of a robot (node parameters of formation_controller)."""

    control_rate_hz: float = param(100.0, 'control loop rate [Hz]', range=(1.0, 2000.0))
    state_rate_hz: float = param(
        100.0, 'rate of the state and commanded acceleration this robot sends to the others '
        'and the coordinator, <= control_rate_hz: every round(control_rate_hz / state_rate_hz)-th '
        'period (lower: fewer bytes on the link, more hard runs, S10.2; docs/multi-machine.md, '
        'Bytes) [Hz]',
        range=(0.1, 2000.0))
    pose_timeout_s: float = param(
        0.5, 'no camera pose this long -> controlled stop [s]', range=(0.01, 10.0))
    wheel_timeout_s: float = param(
        0.1, "no wheel_state this long -> no torque command: the bridge's input timeout brakes "
        '[s]', range=(0.005, 10.0))
    parent_timeout_s: float = param(
        0.1, 'older states of other robots are extrapolated by their age [s] (0: every one; '
        'with a state_rate_hz below the control rate, S10.2)', range=(0.0, 10.0))
    parent_hold_s: float = param(
        1.0, 'older parent state -> hold; other robots ignored [s], >= parent_timeout_s',
        range=(0.0, 60.0))
    stop_time_s: float = param(0.3, 'time constant of the controlled stop [s]',
                               range=(0.01, 10.0))
    stop_speed_max_mps: float = param(
        0.15, 'fastest |v| from which a camera loss ends at rest by pose_timeout_s [m/s]',
        range=(0.001, 10.0))
    stop_turn_rate_max_radps: float = param(
        2.5, 'fastest |omega| from which a camera loss ends at rest by pose_timeout_s [rad/s]',
        range=(0.001, 100.0))
    stop_decel_mps2: float = param(
        0.8, 'switching gain of the camera-loss stop on v [m/s^2]', range=(0.0, 10.0))
    stop_margin_s: float = param(
        0.03, 'added to the time to rest of the camera-loss stop lead [s]', range=(0.0, 1.0))
    camera_gain: float = param(0.5, 'S10 complementary gain per camera frame, (0, 1]',
                               range=(0.001, 1.0))
    coordinator_timeout_s: float = param(
        2.5, 'no message from the coordinator this long -> controlled stop (it owns the robot '
        "encounters, S7.1) [s]; above the coordinator's republish_s", range=(0.05, 60.0))
    hear_all: bool = param(False, "hear every robot (off: the parents, the assignment's partner "
                           'and the robots within hearing range, S10.2)')
    hear_margin_m: float = param(
        0.6, "hearing range beyond a robot's protected region Q [m]", range=(0.0, 100.0))
    hear_hysteresis_m: float = param(
        0.3, 'a robot stays heard until this much beyond the hearing range [m]',
        range=(0.0, 10.0))

    def __post_init__(self) -> None:
        for f in fields(AgentParams):
            lo, hi = f.metadata.get('range') or (None, None)
            v = getattr(self, f.name)
            if f.type == 'bool' or isinstance(f.default, bool):
                if not isinstance(v, bool):
                    raise ConfigError(f'must be true or false (got {v!r})', f.name)
                continue
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    and lo <= v <= hi):
                raise ConfigError(f'must be in [{lo:g}, {hi:g}] (got {v!r})', f.name)
        if self.parent_hold_s < self.parent_timeout_s:
            raise ConfigError('must be >= parent_timeout_s', 'parent_hold_s')
        if self.state_rate_hz > self.control_rate_hz:
            raise ConfigError('must be <= control_rate_hz (a state is sent in a control period)',
                              'state_rate_hz')

    @property
    def state_every(self) -> int:
        """The state and commanded acceleration go out every this many control periods."""
        return max(1, round(self.control_rate_hz / self.state_rate_hz))

    @classmethod
    def of(cls, obj) -> 'AgentParams':
        """The agent's fields of ``obj`` (a node's parameter set that has them all)."""
        return cls(**{f.name: getattr(obj, f.name) for f in fields(cls)})


AgentK = namedtuple('AgentK', ['period_s', 'pose_timeout_s', 'wheel_timeout_s', 'fresh_s',
                               'hold_s', 'coordinator_timeout_s'])

Static = namedtuple('Static', ['rows', 'rbody', 'coeffs', 'team', 'slot', 'orig_parent',
                               'orig_offset', 'leader', 'refs', 'obstacles', 'est_k', 'stop_k',
                               'reach', 'prm', 'ak', 'ob_rows'])
Static.__doc__ = """What does not change during a run: ``rows`` (R,) the hosted robots' rows;
per robot row (N,): ``rbody``, ``coeffs`` (7, N), ``team``, ``slot`` (N, 2), ``orig_parent``,
``orig_offset`` (N, 2), ``leader`` bool; ``refs`` the leaders' references (S17); ``obstacles``
the avoided obstacles' motion (obstacle_arrays); per hosted robot: ``est_k`` (R, 10) estimator
constants, ``stop_k`` (R, 15) the stop's (StopK); ``reach`` (N, N) hearing range [m]; ``prm``
LawK; ``ak`` AgentK; ``ob_rows`` (M,) the obstacle rows the barrier checks (every one: a robot
sees a lab's few obstacles)."""

State = namedtuple('State', ['est', 'heard_x', 'heard_a', 'stamp', 'rep_mode', 'rep_tgt',
                             'rep_sdir', 'in_range', 'x', 'pd', 'acmd', 'known', 'goal',
                             'goal_dot', 'vc', 'ref', 'modes', 'parent', 'offset', 'start_s',
                             'assigned', 'assigned_w', 'coord_s', 'rate_target', 'progress',
                             't_ref', 'stop', 'status', 't_dec', 'ev', 'nev', 'camq', 'ncam',
                             'wheelq', 'nwheel', 'counters', 'halt'])
State.__doc__ = """The agents' state, hosted robot r first axis (R): the estimator; what each
hears of the N robots (``heard_x`` (R, N, 5), ``heard_a`` (R, N, 2), ``stamp`` (R, N) [s, own
clock], reported ``rep_mode``/``rep_tgt``/``rep_sdir``, ``in_range`` (R, N)); the period's view
(``x``, ``pd``, ``acmd``, ``known``, ``goal``, ``goal_dot``, ``vc``, ``ref``); the switching
state ``modes`` (Modes of (R, N) arrays); the graph (``parent`` (R, N): the current parent row
of the robot itself in its own row, -1 elsewhere; ``offset`` (R, 2), ``start_s`` (R,));
the assignment (``assigned`` (R, 5) [mode, row, sense, t_entry, park_at], ``assigned_w``
(R, 2)),
``coord_s`` when the coordinator was last heard, ``rate_target`` (R,) its progress rate for a
leader; ``progress`` (Progress of R rows) and ``t_ref`` (R,) when it last advanced; ``stop``
(R, 2) [latched, camera stamp];
``status`` (R,); ``t_dec`` (R,) the last decision [s]; events ``ev`` (R, E, 6), ``nev`` (R,);
queues ``camq`` (R, Q, 4), ``wheelq`` (R, Q, 5) and their counts; ``counters`` (R, 2) [late
decisions (unused), over the stop bounds]; ``halt`` (R,) a status the caller stops the robot
with (0: none; STOPPED_CLOCK: a remote clock beyond the bound, core/clock.py)."""

Out = namedtuple('Out', ['torque', 'accel', 'state', 'mode', 'sigma', 'saturated'])
Out.__doc__ = """The period's results per hosted robot: ``torque`` (R, 2) [N m] clamped;
``accel`` (R, 2) commanded point acceleration to broadcast [m/s^2] (0 when stopped); ``state``
(R, 5) the estimate [x_m, y_m, theta_rad, v_mps, omega_radps]; ``mode`` (R, 3) [mode, target,
sense]; ``sigma`` (R, 2) [m/s]; ``saturated`` (R,)."""


def _modes(n_hosted: int, n: int) -> Modes:
    """Modes whose arrays are (R, N)."""
    one = new_modes(n)
    return Modes(*(np.array(np.broadcast_to(a, (n_hosted, *a.shape))) for a in one))


@njit(cache=True, error_model='numpy')
def _modes_of(ms, r):
    return Modes(ms.mode[r], ms.tgt[r], ms.sdir[r], ms.t_entry[r], ms.since[r], ms.last_kind[r],
                 ms.last_tgt[r], ms.last_exit[r], ms.wc[r], ms.wtgt[r], ms.anchor[r],
                 ms.t_anchor[r], ms.park_at[r])


@njit(cache=True, error_model='numpy')
def _est_k(row):
    return EstimatorK(row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7], row[8],
                      row[9])


@njit(cache=True, error_model='numpy')
def _view(r, i, now, hold_s, fresh_s, heard, view, reported, plant_d):
    """S10.2: the robots robot r (row i) hears (``heard``: stamp, heard_x, heard_a, rep_mode,
    rep_tgt, rep_sdir), extrapolated to ``now`` with their commanded accelerations while younger
    than ``hold_s`` -> ``view`` (x, pd, acmd, known) and ``reported`` (mode, tgt, sdir), row r of
    the State's arrays.
    """
    stamp, heard_x, heard_a, rep_mode, rep_tgt, rep_sdir = heard
    x, pd, acmd, known = view
    mode, tgt, sdir = reported
    for k in range(x.shape[1]):
        if k == i:
            continue
        age = now - stamp[r, k]
        ok = age <= hold_s
        known[r, k] = ok
        if not ok:
            continue
        xk = x[r, k]
        hx = heard_x[r, k]
        for q in range(5):
            xk[q] = hx[q]
        acmd[r, k, 0] = heard_a[r, k, 0]
        acmd[r, k, 1] = heard_a[r, k, 1]
        pdx, pdy = point_velocity_k(xk[2], xk[3], xk[4], plant_d[k])
        if age > fresh_s:
            xk[0] += pdx * age + 0.5 * acmd[r, k, 0] * age * age
            xk[1] += pdy * age + 0.5 * acmd[r, k, 1] * age * age
        pd[r, k, 0], pd[r, k, 1] = pdx, pdy
        mode[r, k] = rep_mode[r, k]
        tgt[r, k] = rep_tgt[r, k]
        sdir[r, k] = rep_sdir[r, k]


@njit(cache=True, error_model='numpy')
def _brake(r, i, v, w, sk, coeffs, camera_loss, torque, age_s):
    """The controlled stop (camera loss: the stop lead's gains ``sk`` (15,); hold: the formation
    law's) -> torque[r], its rates scaled for (v, omega) ``age_s`` old (stop.delay_scale_k).
    """
    gv, ev_ = (sk[1], sk[2]) if camera_loss else (sk[13], sk[14])
    s = delay_scale_k(sk[0], gv, ev_, sk[5], sk[6], age_s)
    t1, t2 = stop_torque_k(v, w, robot_plant_k(coeffs, i), coeffs[ROW_TAU_MAX, i], sk[0] / s,
                           gv * s, ev_, sk[5] * s, sk[6])
    torque[r, 0], torque[r, 1] = t1, t2


@njit(cache=True, error_model='numpy')
def _camera_lost(r, now, v, w, cam_t, stop, sk, counters, pose_timeout_s):
    """docs/design.md §7 camera loss: the stop begins once the camera age (the newest pose
    ``cam_t``) exceeds pose_timeout_s minus the time to rest from (v, omega) (docs/safety.md §7);
    latched until a newer pose.
    """
    if stop[r, 0] > 0.5:
        if cam_t == stop[r, 1]:
            return True
        stop[r, 0] = 0.0
    if abs(v) > sk[11] or abs(w) > sk[12]:
        counters[r, 1] += 1
    lead = lead_k(v, w, StopK(sk[0], sk[1], sk[2], sk[3], sk[4], sk[5], sk[6], sk[7], sk[8],
                              sk[9], sk[10], sk[11], sk[12], sk[13], sk[14]))
    if now - cam_t > pose_timeout_s - lead:
        stop[r, 0] = 1.0
        stop[r, 1] = cam_t
        return True
    return False


@njit(cache=True, error_model='numpy')
def _inputs(r, est, ek_row, nwheel, wheelq, ncam, camq):
    """Row r's queued wheel samples, then its camera poses, into its estimator."""
    ek = _est_k(ek_row)
    for q in range(nwheel[r]):
        w = wheelq[r, q]
        wheel_update_k(est, r, w[0], w[1], w[2], w[3], w[4], ek)
    for q in range(ncam[r]):
        c = camq[r, q]
        camera_update_k(est, r, c[0], c[1], c[2], c[3], ek)
    nwheel[r] = 0
    ncam[r] = 0
    return ek


@njit(cache=True, error_model='numpy')
def _decide(r, i, t, view, fixed, ob, modes, prm, events, assignment):
    """Row r's own table (S8.7) every decision period, then the coordinator's assignment (on the
    State's and Static's arrays: ``view`` x, pd, goal, goal_dot, vc, known, parent; ``fixed``
    team, rbody, slot, orig_parent; ``events`` nev, ev; ``assignment`` assigned, assigned_w).
    """
    x, pd, goal, goal_dot, vc, known, parent = view
    team, rbody, slot, orig_parent = fixed
    nev, ev = events
    assigned, assigned_w = assignment
    m = _modes_of(modes, r)
    robots = Robots(x[r, :, :2].copy(), pd[r], goal[r], goal_dot[r], vc[r], team, rbody,
                    parent[r], slot, known[r], orig_parent)
    n_ev = nev[r]
    evr = ev[r]
    n_ev = robot_transitions(i, t, robots, ob, m, prm, evr, n_ev)
    a = assigned[r]
    am, arow = int(a[0]), int(a[1])
    if am != MODE_C and (arow < 0 or not known[r, arow]):
        am, arow = MODE_C, -1  # the partner is not heard: no encounter with it
    n_ev = apply_assignment(i, t, am, arow, a[2], a[3], assigned_w[r, 0], assigned_w[r, 1], a[4],
                            m, evr, n_ev)
    nev[r] = n_ev


# implements: S10.3
@njit(cache=True, error_model='numpy')
def agent_tick_k(now, st, sc, out):
    """One control period of every hosted robot at ``now`` [s, own clock] (module docstring).

    The State's and Static's arrays are taken out once and handed to the helpers as arrays (a
    compiled call taking the tuples themselves, some 70 arrays, costs about 1 us). They are read
    without reference counting (core/borrowed.py): all are the caller's.
    """
    st, sc, out = borrowed((st, sc, out))
    nob = sc.obstacles[6].shape[0]
    ob = ObstacleSnapshot(np.empty((nob, 2)), np.empty((nob, 2)), np.empty((nob, 2)),
                          np.empty(nob), np.empty(nob), np.empty(nob), sc.obstacles[6],
                          sc.obstacles[7])
    rows, coeffs, ak, prm, o = sc.rows, sc.coeffs, sc.ak, sc.prm, sc.obstacles
    plant_d = coeffs[ROW_D]
    est, x, pd, acmd, known, status = st.est, st.x, st.pd, st.acmd, st.known, st.status
    ms, ref, goal, goal_dot, vc = st.modes, st.ref, st.goal, st.goal_dot, st.vc
    torque = out.torque
    for r in range(rows.shape[0]):
        i = rows[r]
        ek = _inputs(r, est, sc.est_k[r], st.nwheel, st.wheelq, st.ncam, st.camq)
        torque[r, 0] = torque[r, 1] = 0.0
        out.accel[r, 0] = out.accel[r, 1] = 0.0
        out.saturated[r] = False
        if est.i[r, I_INIT] == 0:
            status[r] = WAITING
            continue
        state_at_k(est, r, now, ek, out.state[r])
        xi = x[r, i]
        for q in range(5):
            xi[q] = out.state[r, q]
        known[r, i] = True
        v, w = xi[3], xi[4]
        pd[r, i, 0], pd[r, i, 1] = point_velocity_k(xi[2], v, w, plant_d[i])
        if not now - est.f[r, F_ODOM_T] <= ak.wheel_timeout_s:
            status[r] = STOPPED_WHEELS  # nothing to brake with: zero torque
            continue
        sk = sc.stop_k[r]
        if _camera_lost(r, now, v, w, est.f[r, F_CAMERA_T], st.stop, sk, st.counters,
                        ak.pose_timeout_s):
            status[r] = STOPPED_POSE
            _brake(r, i, v, w, sk, coeffs, True, torque, now - est.f[r, F_ODOM_T])
            continue
        t = now - st.start_s[r]
        if not t >= 0.0:  # NaN: no graph yet
            status[r] = WAITING
            continue
        if not now - st.coord_s[r] <= ak.coordinator_timeout_s or st.halt[r] > 0:
            status[r] = st.halt[r] if st.halt[r] > 0 else STOPPED_COORDINATOR
            _brake(r, i, v, w, sk, coeffs, False, torque, now - est.f[r, F_ODOM_T])
            continue
        _view(r, i, now, ak.hold_s, ak.fresh_s,
              (st.stamp, st.heard_x, st.heard_a, st.rep_mode, st.rep_tgt, st.rep_sdir),
              (x, pd, acmd, known), (ms.mode, ms.tgt, ms.sdir), plant_d)
        par = st.parent[r, i]
        if par >= 0 and not known[r, par]:
            status[r] = HOLD_PARENT
            _brake(r, i, v, w, sk, coeffs, False, torque, now - est.f[r, F_ODOM_T])
            continue
        status[r] = RUNNING
        obstacle_states(t, o[0], o[1], o[2], o[3], o[4], o[5], ob.c, ob.v, ob.a, ob.phi,
                        ob.phi_dot, ob.phi_ddot)
        # the running robot's period: goals, reference, decisions, law, clamp
        if sc.leader[i]:
            pr = st.progress
            dt = t - st.t_ref[r] if st.t_ref[r] == st.t_ref[r] else 0.0
            step(pr, r, max(0.0, dt), st.rate_target[r], sc.refs.s_end, prm)
            st.t_ref[r] = t
            leader_reference(sc.refs, i, pr.s[r], pr.sd[r], pr.sdd[r], ref[r, i])
        xr, pdr = x[r], pd[r]
        j0 = sc.orig_parent[i]
        if j0 >= 0 and not known[r, j0]:  # pi0 silent: the goal on the robot (no exit pull)
            ref[r, i, 0], ref[r, i, 1] = xr[i, 0], xr[i, 1]
            ref[r, i, 2], ref[r, i, 3] = pdr[i, 0], pdr[i, 1]
            j0 = -1
        op = sc.orig_parent.copy()
        op[i] = j0
        gx, gy, gdx, gdy, vcx, vcy = goal_k(i, xr, pdr, ref[r], op, sc.orig_offset, prm)
        goal[r, i, 0], goal[r, i, 1] = gx, gy
        goal_dot[r, i, 0], goal_dot[r, i, 1] = gdx, gdy
        vc[r, i, 0], vc[r, i, 1] = vcx, vcy
        if t - st.t_dec[r] >= ak.period_s - 1e-9 or st.t_dec[r] < 0.0:
            _decide(r, i, t, (x, pd, goal, goal_dot, vc, known, st.parent),
                    (sc.team, sc.rbody, sc.slot, sc.orig_parent), ob, ms, prm, (st.nev, st.ev),
                    (st.assigned, st.assigned_w))
            st.t_dec[r] = t
        m = _modes_of(ms, r)
        nbrs = np.flatnonzero(known[r])
        par = st.parent[r, i]
        track = RobotTracking(par, (st.offset[r, 0], st.offset[r, 1]),
                              (ref[r, i, 0], ref[r, i, 1], ref[r, i, 2], ref[r, i, 3],
                               ref[r, i, 4], ref[r, i, 5]), (gx, gy), (gdx, gdy))
        t1, t2, sx, sy, sat, acx, acy, wdx, wdy = robot_law_k(
            i, t, xr, pdr, acmd[r], sc.rbody, coeffs, ob, nbrs, sc.ob_rows, track,
            mode_row(m, i), prm)
        if m.mode[i] == MODE_MUTUAL:
            m.wc[i, 0] += ak.period_s * wdx
            m.wc[i, 1] += ak.period_s * wdy
        lim = coeffs[ROW_TAU_MAX, i]  # docs/design.md §7: clamped here too; non-finite -> 0
        torque[r, 0] = min(max(t1 if math.isfinite(t1) else 0.0, -lim), lim)
        torque[r, 1] = min(max(t2 if math.isfinite(t2) else 0.0, -lim), lim)
        out.accel[r, 0], out.accel[r, 1] = acx, acy
        out.sigma[r, 0], out.sigma[r, 1] = sx, sy
        out.saturated[r] = sat
        acmd[r, i, 0], acmd[r, i, 1] = acx, acy
        out.mode[r, 0], out.mode[r, 1], out.mode[r, 2] = ms.mode[r, i], ms.tgt[r, i], \
            ms.sdir[r, i]


@njit(cache=True, error_model='numpy')
def _needs(r, i, k, hear_all, parent, orig_parent, assigned, in_range):
    """:func:`needed_k` of hosted row r (robot row i) on the arrays it reads."""
    if k == i:
        return False
    return (hear_all or k == parent[r, i] or k == orig_parent[i] or k == int(assigned[r, 1])
            or in_range[r, k])


@njit(cache=True, error_model='numpy')
def needed_k(r, k, st, sc, hear_all):
    """S10.2: robot r needs robot k's state at the control rate: its current and original
    parents, its assignment's partner, and the robots within hearing range (every robot with
    ``hear_all``).
    """
    return _needs(r, sc.rows[r], k, hear_all, st.parent, sc.orig_parent, st.assigned,
                  st.in_range)


@njit(cache=True, error_model='numpy')
def broadcast_k(stamp, x, a, modes, sent, st, sc, hear_all, states):
    """What the robots of ``sent`` (N,) bool broadcast at ``stamp`` [s] (states x (N, 5),
    commanded accelerations a (N, 2), reports modes (N, 3) [mode, target, sense]) reaches every
    hosted robot that needs it (:func:`needed_k`; reports reach every one). The states and
    accelerations only when ``states`` (a period of ``AgentParams.state_rate_hz``).
    """
    rows, orig_parent = sc.rows, sc.orig_parent
    parent, assigned, in_range = st.parent, st.assigned, st.in_range
    rep_mode, rep_tgt, rep_sdir = st.rep_mode, st.rep_tgt, st.rep_sdir
    heard_x, heard_a, heard_t = st.heard_x, st.heard_a, st.stamp
    for r in range(rows.shape[0]):
        i = rows[r]
        for k in range(x.shape[0]):
            if not sent[k]:
                continue
            rep_mode[r, k] = int(modes[k, 0])
            rep_tgt[r, k] = int(modes[k, 1])
            rep_sdir[r, k] = modes[k, 2]
            if states and _needs(r, i, k, hear_all, parent, orig_parent, assigned, in_range):
                for q in range(5):
                    heard_x[r, k, q] = x[k, q]
                heard_a[r, k, 0], heard_a[r, k, 1] = a[k, 0], a[k, 1]
                heard_t[r, k] = stamp


@njit(cache=True, error_model='numpy')
def _in_range(k, px, py, rows, init, x, reach, in_range, hysteresis):
    """:func:`range_k` on the arrays it reads (``init`` the estimators' I_INIT column)."""
    for r in range(rows.shape[0]):
        i = rows[r]
        if k == i or init[r] == 0:
            continue
        d = math.hypot(px - x[r, i, 0], py - x[r, i, 1])
        rch = reach[i, k]
        in_range[r, k] = d < rch or (in_range[r, k] and d < rch + hysteresis)


@njit(cache=True, error_model='numpy')
def range_k(k, px, py, st, sc, hysteresis):
    """A camera pose (px, py) of robot k: the hearing range of every hosted robot (its own
    estimate against the reach, with hysteresis) -> st.in_range[:, k].
    """
    _in_range(k, px, py, sc.rows, st.est.i[:, I_INIT], st.x, sc.reach, st.in_range, hysteresis)


@njit(cache=True, error_model='numpy')
def frame_k(stamp, poses, kept, st, sc, hear_all, hysteresis):
    """A camera frame (poses (N, 3) of every robot, ``kept`` (N,) bool) captured at ``stamp``:
    each hosted robot's own pose to its estimator's queue, every pose to the hearing ranges.
    """
    for r in range(sc.rows.shape[0]):
        i = sc.rows[r]
        if kept[i]:
            q = min(st.ncam[r], CAMERA_QUEUE - 1)
            st.camq[r, q, 0] = stamp
            for c in range(3):
                st.camq[r, q, 1 + c] = poses[i, c]
            st.ncam[r] = q + 1
    if not hear_all:
        rows, init, x, reach, in_range = sc.rows, st.est.i[:, I_INIT], st.x, sc.reach, st.in_range
        for k in range(poses.shape[0]):
            if kept[k]:
                _in_range(k, poses[k, 0], poses[k, 1], rows, init, x, reach, in_range,
                          hysteresis)


@njit(cache=True, error_model='numpy')
def wheels_k(t, angle, rate, st, sc):
    """Every hosted robot's wheel sample at ``t`` (angle, rate (N, 2) by robot row)."""
    for r in range(sc.rows.shape[0]):
        i = sc.rows[r]
        q = min(st.nwheel[r], WHEEL_QUEUE - 1)
        st.wheelq[r, q, 0] = t
        st.wheelq[r, q, 1], st.wheelq[r, q, 2] = angle[i, 0], angle[i, 1]
        st.wheelq[r, q, 3], st.wheelq[r, q, 4] = rate[i, 0], rate[i, 1]
        st.nwheel[r] = q + 1


ASSIGN_NONE, ASSIGN_NONE_PARK, ASSIGN_YIELD, ASSIGN_MUTUAL = range(4)  # assign_k's kinds


@njit(cache=True, error_model='numpy')
def assign_k(now, rows, kind, partner, val, has_rate, rate, coord_s, assigned, assigned_w,
             rate_target):
    """The coordinator's message at ``now`` for every hosted robot (rows ``rows``), by robot row
    i: ``kind`` (N,) ASSIGN_NONE (no assignment), ASSIGN_NONE_PARK (none, but ``park_at_s``:
    make way), ASSIGN_YIELD or ASSIGN_MUTUAL with ``partner`` (N,) row and ``val`` (N, 5)
    [direction, t_entry_s, park_at_s, drift w_c (2) [m/s]]; the progress rate target ``rate``
    (N,) where ``has_rate`` (clamped to [0, 1]) -> ``coord_s``, ``assigned``, ``assigned_w``,
    ``rate_target`` (State's, by hosted row).
    """
    for r in range(rows.shape[0]):
        i = rows[r]
        coord_s[r] = now
        k = kind[i]
        if k == ASSIGN_YIELD or k == ASSIGN_MUTUAL:
            assigned[r, 0] = MODE_YIELD if k == ASSIGN_YIELD else MODE_MUTUAL
            assigned[r, 1] = partner[i]
            assigned[r, 2], assigned[r, 3], assigned[r, 4] = val[i, 0], val[i, 1], val[i, 2]
            assigned_w[r, 0], assigned_w[r, 1] = val[i, 3], val[i, 4]
        else:
            assigned[r, 0], assigned[r, 1], assigned[r, 2], assigned[r, 3] = MODE_C, -1, 1.0, 0.0
            assigned[r, 4] = val[i, 2] if k == ASSIGN_NONE_PARK else -np.inf
        if has_rate[i]:
            v = rate[i]
            v = v if v > 0.0 else 0.0  # min(1, max(0, rate))
            rate_target[r] = v if v < 1.0 else 1.0


class AgentBatch:
    """The robot agents of ``robot_ids`` in ``scenario`` (module docstring).

    ``AgentBatch(scenario, robot_ids, params=AgentParams(), law=None)``. Rows: ``self.ids``
    (every robot of the scenario, sorted) and ``self.rows`` (the hosted ones).
    """

    def __init__(self, scenario, robot_ids, params: AgentParams | None = None,
                 law: LawParams | None = None):
        self.params = params or AgentParams()
        self.scenario = scenario
        robots = sorted(scenario.robots, key=lambda rb: rb.id)
        self.ids = tuple(int(rb.id) for rb in robots)
        self.row = {rid: q for q, rid in enumerate(self.ids)}
        hosted = [int(v) for v in robot_ids]
        unknown = [v for v in hosted if v not in self.row]
        if unknown:
            raise ConfigError(f'robot {unknown[0]} is not a robot of the scenario '
                              f'(ids {list(self.ids)})', 'robot_id')
        self.hosted = tuple(hosted)
        self.law = law or LawParams.for_scenario(scenario)
        self.obstacle_names = tuple(o.name for o in scenario.avoided_obstacles())
        self.static = self._static(scenario, robots, hosted)
        self.state = self._state(len(hosted), len(robots))
        self.out = Out(np.zeros((len(hosted), 2)), np.zeros((len(hosted), 2)),
                       np.zeros((len(hosted), 5)), np.zeros((len(hosted), 3)),
                       np.zeros((len(hosted), 2)), np.zeros(len(hosted), dtype=np.bool_))
        self.events: list[dict] = []  # the hosted robots' mode events of the last tick

    # ------------------------------------------------------------------ construction
    def _static(self, scenario, robots, hosted) -> Static:
        from ament_formation.core.control.rewiring import FormationGraph

        p = self.params
        n = len(robots)
        k = PlantCoeffs.from_params([rb.params for rb in robots])
        coeffs = np.ascontiguousarray(np.stack([k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c,
                                                k.tau_max]))
        rbody = np.array([rb.params.body_radius_m for rb in robots])
        graph = FormationGraph.from_scenario(scenario)
        slot = np.array([rb.slot_m for rb in robots], dtype=float).reshape(n, 2)
        orig_parent = np.full(n, -1, dtype=np.int64)
        orig_offset = np.zeros((n, 2))
        for q, rid in enumerate(self.ids):
            par = graph.original_parent.get(rid)
            if par is not None:
                orig_parent[q] = self.row[par]
                orig_offset[q] = slot[q] - slot[self.row[par]]
        self.graph = graph
        team = np.array([self.row[scenario.team_leader(rid)] for rid in self.ids], np.int64)
        leader = np.array([rb.leader for rb in robots], dtype=np.bool_)
        refs = tabulate([rb.path if rb.leader else None for rb in robots], scenario.duration_s)
        est_k, stop_k = [], []
        for rid in hosted:
            rb = robots[self.row[rid]]
            est_k.append(EstimatorParams.from_robot(rb.params, camera_gain=p.camera_gain)
                         .compiled())
            lead = StopLead(rb.params, p.stop_time_s, scenario.control,
                            scenario.disturbance.accel_bound, p.stop_margin_s,
                            p.stop_speed_max_mps, p.stop_turn_rate_max_radps, p.stop_decel_mps2,
                            1.0 / p.control_rate_hz)
            lead.check(p.pose_timeout_s)
            stop_k.append(lead.compiled(scenario.control))
        av = scenario.avoidance
        reach = av.protected_scale * (rbody[:, None] + rbody[None, :]
                                      + av.agent_keepout_margin_m) + p.hear_margin_m
        ak = AgentK(1.0 / p.control_rate_hz, p.pose_timeout_s, p.wheel_timeout_s,
                    p.parent_timeout_s, p.parent_hold_s, p.coordinator_timeout_s)
        obstacles = tuple(obstacle_arrays(scenario.avoided_obstacles()))
        return Static(np.array([self.row[r] for r in hosted], dtype=np.int64), rbody, coeffs,
                      team, slot, orig_parent, orig_offset, leader, refs, obstacles,
                      np.array(est_k, dtype=float).reshape(-1, 10),
                      np.array(stop_k, dtype=float).reshape(-1, 15), reach,
                      self.law.compiled(), ak,
                      np.arange(obstacles[0].shape[0], dtype=np.int64))

    @staticmethod
    def _state(nr: int, n: int) -> State:
        z = lambda *shape: np.zeros(shape)  # noqa: E731
        stamp = np.full((nr, n), -np.inf)
        assigned = np.zeros((nr, 5))
        assigned[:, 1] = -1
        return State(new_estimates(nr), z(nr, n, 5), z(nr, n, 2), stamp,
                     np.zeros((nr, n), np.int64), np.full((nr, n), -1, np.int64),
                     np.ones((nr, n)), np.zeros((nr, n), np.bool_), z(nr, n, 5), z(nr, n, 2),
                     z(nr, n, 2), np.zeros((nr, n), np.bool_), z(nr, n, 2), z(nr, n, 2),
                     z(nr, n, 2), z(nr, n, 6), _modes(nr, n), np.full((nr, n), -1, np.int64),
                     z(nr, 2), np.full(nr, np.nan), assigned, z(nr, 2), np.full(nr, -np.inf),
                     np.ones(nr), new_progress(nr), np.full(nr, np.nan), z(nr, 2),
                     np.zeros(nr, np.int64), np.full(nr, -1.0), z(nr, 32, 6),
                     np.zeros(nr, np.int64), z(nr, CAMERA_QUEUE, 4), np.zeros(nr, np.int64),
                     z(nr, WHEEL_QUEUE, 5), np.zeros(nr, np.int64),
                     np.zeros((nr, 2), np.int64), np.zeros(nr, np.int64))

    # ------------------------------------------------------------------ inputs
    def _r(self, rid: int) -> int:
        return self.hosted.index(int(rid))

    def wheel(self, rid: int, t_s: float, angle_rad, rate_radps) -> None:
        """A wheel encoder sample of hosted robot ``rid`` (angles [rad], rates [rad/s])."""
        r, st = self._r(rid), self.state
        q = min(int(st.nwheel[r]), WHEEL_QUEUE - 1)  # full: the newest replaces the last
        st.wheelq[r, q] = (t_s, angle_rad[0], angle_rad[1], rate_radps[0], rate_radps[1])
        st.nwheel[r] = q + 1

    def camera(self, rid: int, stamp_s: float, pose) -> None:
        """A camera pose [x_m, y_m, theta_rad] of p captured at ``stamp_s`` (own clock): of a
        hosted robot, for its estimator; of any other robot, for the hearing ranges.
        """
        rid = int(rid)
        if rid in self.hosted:
            r, st = self._r(rid), self.state
            q = min(int(st.ncam[r]), CAMERA_QUEUE - 1)
            st.camq[r, q] = (stamp_s, pose[0], pose[1], pose[2])
            st.ncam[r] = q + 1
        if not self.params.hear_all and math.isfinite(pose[0]) and math.isfinite(pose[1]):
            range_k(self.row[rid], float(pose[0]), float(pose[1]), self.state, self.static,
                    self.params.hear_hysteresis_m)

    def hear(self, rid: int, state, accel, stamp_s: float) -> None:
        """Robot ``rid``'s broadcast (state (5,), commanded acceleration (2,)) stamped
        ``stamp_s`` (own clock), for every hosted robot.
        """
        k, st = self.row[int(rid)], self.state
        st.heard_x[:, k] = state
        st.heard_a[:, k] = accel
        st.stamp[:, k] = stamp_s

    def hear_mode(self, rid: int, mode: dict) -> None:
        """Robot ``rid``'s mode report ({mode, target, direction}) for every hosted robot."""
        k, st = self.row[int(rid)], self.state
        md, tgt, sdir = self.encode_mode(mode)
        st.rep_mode[:, k], st.rep_tgt[:, k], st.rep_sdir[:, k] = md, tgt, sdir

    def encode_mode(self, mode: dict) -> tuple[int, int, float]:
        """(mode, target row or obstacle index, sense) of a mode report; anything not an
        avoidance mode with a known target is coordination.
        """
        name, target = mode.get('mode'), mode.get('target')
        sdir = -1.0 if mode.get('direction') == 'cw' else 1.0
        if name == 'obstacle' and target in self.obstacle_names:
            return MODE_OBSTACLE, self.obstacle_names.index(target), sdir
        if name in ('yield', 'mutual') and isinstance(target, str) and target.startswith(
                'robot_'):
            tail = target[6:]
            if tail.isdigit() and int(tail) in self.row:
                return MODE_NAMES.index(name), self.row[int(tail)], sdir
        return MODE_C, -1, 1.0

    def needed(self, rid: int) -> list[int]:
        """The robot ids hosted robot ``rid`` needs at the control rate (S10.2)."""
        r = self._r(rid)
        return [k for q, k in enumerate(self.ids)
                if needed_k(r, q, self.state, self.static, self.params.hear_all)]

    def set_graph(self, parents: dict, start_s: float | None) -> None:
        """The coordinator's graph (S9): {child id: parent id | None}, and the mission start
        [s, own clock] (None: not fixed yet).
        """
        st = self.state
        for r, rid in enumerate(self.hosted):
            i = self.row[rid]
            par = parents.get(rid, parents.get(str(rid)))
            st.parent[r, i] = -1 if par is None or int(par) not in self.row else self.row[
                int(par)]
            if st.parent[r, i] >= 0:
                st.offset[r] = self.static.slot[i] - self.static.slot[st.parent[r, i]]
            st.start_s[r] = np.nan if start_s is None else float(start_s)

    def assign(self, now_s: float, assignments: dict, rates: dict | None = None) -> None:
        """The coordinator's message at ``now_s``: {robot id: {mode, partner, direction,
        t_entry_s, drift_mps, park_at_s}} or {mode: make_way, park_at_s} (robots without one:
        none) and {team leader id: progress rate target} (S7.1, S8.9, S17); :func:`assign_k`.
        """
        n = len(self.ids)
        kind, partner = np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int64)
        val = np.zeros((n, 5))  # direction, t_entry_s, park_at_s, drift (2)
        has_rate, rate = np.zeros(n, dtype=np.bool_), np.zeros(n)
        for rid in self.hosted:
            i = self.row[rid]
            a = assignments.get(rid, assignments.get(str(rid)))
            if a is None:
                continue
            val[i, 2] = float(a.get('park_at_s', -np.inf))
            if a['mode'] == 'make_way' or int(a['partner']) not in self.row:
                kind[i] = ASSIGN_NONE_PARK
                continue
            kind[i] = ASSIGN_YIELD if a['mode'] == 'yield' else ASSIGN_MUTUAL
            partner[i] = self.row[int(a['partner'])]
            val[i, 0], val[i, 1] = float(a['direction']), float(a['t_entry_s'])
            w = a.get('drift_mps')
            val[i, 3:5] = (0.0, 0.0) if w is None else w
        if rates is not None:
            for rid in self.hosted:
                r = rates.get(rid, rates.get(str(rid)))
                if r is not None:
                    has_rate[self.row[rid]] = True
                    rate[self.row[rid]] = float(r)
        st = self.state
        assign_k(float(now_s), self.static.rows, kind, partner, val, has_rate, rate, st.coord_s,
                 st.assigned, st.assigned_w, st.rate_target)

    def share(self, now_s: float) -> None:
        """The hosted robots' broadcasts of this period reach each other in the process (a
        team: no DDS between the robots it hosts).
        """
        n = len(self.ids)
        x, a, modes = np.zeros((n, 5)), np.zeros((n, 2)), np.zeros((n, 3))
        sent = np.zeros(n, dtype=np.bool_)
        rows = self.static.rows
        running = self.state.status == RUNNING
        x[rows], a[rows] = self.out.state, self.out.accel
        modes[rows] = np.where(running[:, None], self.out.mode, (0.0, -1.0, 1.0))
        sent[rows] = [self.initialized(r) for r in range(len(rows))]
        broadcast_k(now_s, x, a, modes, sent, self.state, self.static, self.params.hear_all,
                    True)

    # ------------------------------------------------------------------ the period
    def tick(self, now_s: float) -> None:
        """One control period of every hosted robot; results in :attr:`out`, mode events of
        the hosted robots in :attr:`events`.
        """
        st = self.state
        st.nev[:] = 0
        agent_tick_k(float(now_s), st, self.static, self.out)
        self.events = []
        if st.nev.any():
            self._collect_events()

    def _collect_events(self) -> None:
        st = self.state
        for r, rid in enumerate(self.hosted):
            i = self.row[rid]
            for row in st.ev[r, :min(int(st.nev[r]), st.ev.shape[1])]:
                if int(row[1]) != i:
                    continue
                md, tgt = int(row[3]), int(row[4])
                self.events.append({
                    't_s': float(row[0]), 'robot': rid,
                    'event': 'enter' if row[2] > 0.5 else 'exit', 'mode': MODE_NAMES[md],
                    'target': self._target(md, tgt), 'direction': 'ccw' if row[5] > 0 else 'cw'})

    def _target(self, md: int, tgt: int) -> str | None:
        if md == MODE_OBSTACLE:
            return self.obstacle_names[tgt]
        if md in (MODE_YIELD, MODE_MUTUAL):
            return f'robot_{self.ids[tgt]}'
        return None

    # ------------------------------------------------------------------ results
    def status(self, r: int) -> str:
        return STATUS[int(self.state.status[r])]

    def mode_dict(self, r: int) -> dict:
        """The mode report of hosted robot r: {mode, target, direction, avoiding}; a robot that
        is not running reports ``hold`` (waiting, hold_parent) or ``stopped``.
        """
        status = int(self.state.status[r])
        if status != RUNNING:
            name = 'hold' if status in (WAITING, HOLD_PARENT) else 'stopped'
            return {'mode': name, 'target': None, 'direction': None, 'avoiding': False}
        md, tgt, sdir = (int(v) for v in self.out.mode[r])
        return {'mode': MODE_NAMES[md], 'target': self._target(md, tgt),
                'direction': None if md == MODE_C else ('ccw' if sdir > 0 else 'cw'),
                'avoiding': md != MODE_C}

    def counters(self, r: int) -> dict:
        """The estimator's counters of hosted robot r, and ``over_stop_speed``."""
        st = self.state
        out = {name: int(v) for name, v in zip(COUNTERS, st.est.counters[r])}
        out['over_stop_speed'] = int(st.counters[r, 1])
        return out

    def camera_age_s(self, r: int, now_s: float) -> float:
        return float(now_s - self.state.est.f[r, F_CAMERA_T])

    def initialized(self, r: int) -> bool:
        return bool(self.state.est.i[r, I_INIT])


class RobotAgent(AgentBatch):
    """One robot's agent (the controller node): an :class:`AgentBatch` of one hosted robot with
    the per-robot API ``tick(now_s) -> (torque (2,), accel (2,))``.
    """

    def __init__(self, scenario, robot_id: int, params: AgentParams | None = None,
                 law: LawParams | None = None):
        super().__init__(scenario, [robot_id], params, law)
        self.robot_id = int(robot_id)

    def tick(self, now_s: float):  # noqa: D102 - see AgentBatch.tick
        super().tick(now_s)
        return self.out.torque[0], self.out.accel[0]
