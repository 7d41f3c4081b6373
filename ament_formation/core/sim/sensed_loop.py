"""The compiled loop of the camera-sensing simulator (core/sim/sensed.py, issue 34).

:func:`run_k` runs the closed loop of :func:`~ament_formation.core.sim.sensed.simulate_sensed`
step by step in one compiled call: the camera's captures (noise and drops drawn beforehand by
the caller, in the generator's order) and their delivery after the latency, every control
period of every robot's agent (the same kernels :class:`~ament_formation.core.control.agent.
AgentBatch` calls: wheels_k, frame_k, broadcast_k, agent_tick_k), the coordinator at its rate
(:func:`~ament_formation.core.control.coordinator.decide_k`, :func:`publish_due_k`,
:func:`~ament_formation.core.control.agent.assign_k`), the record and the plant twin (the twin's
RK4 kernel with the disturbance at every half step). It returns to Python only for what Python
does: the S9 rewiring when the set of avoiding robots changes (:data:`REWIRE`; the loop goes on
from the same period's coordinator decision), more camera noise (:data:`NOISE`), a full record
or event buffer, the end of a chunk (progress) and the end of the run.

Rows: the robots in id order throughout (agents, coordinator, camera, record); the twin's rows
through ``TwinK.rows`` (its row of each robot) and ``TwinK.inv``.
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import njit
import numpy as np

from ament_formation.core.borrowed import borrowed
from ament_formation.core.control.agent import (
    agent_tick_k,
    assign_k,
    broadcast_k,
    frame_k,
    RUNNING,
    wheels_k,
)
from ament_formation.core.control.coordinator import decide_k, publish_due_k
from ament_formation.core.control.progress import leader_reference
from ament_formation.core.control.switching import MODE_C, MODE_OBSTACLE
from ament_formation.core.model.disturbance import disturbance_k
from ament_formation.core.model.obstacles import obstacle_states
from ament_formation.core.sim.twin import _advance_k

# why run_k returned
DONE, CHUNK_END, NOISE, RECORD_FULL, FLUSH, REWIRE, QUEUE_FULL = range(7)

# registers (int64) of the loop
(K, K_END, K_CAP, K_STOP, PHASE, NEXT_FRAME, NOISE_POS, CQ_HEAD, CQ_N, REC_N, EV_N, ERR_N,
 FRAMES, SENT, DROPPED, ERR_COUNT) = range(16)
N_REG = 16
# float registers
B_T, ERR_SQ, ERR_MAX = range(3)
N_FREG = 3

ClockK = namedtuple('ClockK', ['dt', 'ctrl_every', 'rec_every', 'arb_every', 'cap_every',
                               'step', 'hold_steps', 'hear_all', 'hysteresis', 'blas_error',
                               'state_every'])
ClockK.__doc__ = """The loop's constants: ``dt`` [s]; control, record and coordinator periods
and the camera's (float) in steps; ``step`` the gcd of the control and record periods;
``hold_steps`` the steps run past the mission's end (+1); the agents' ``hear_all`` and
``hysteresis``; ``blas_error``: the estimate errors go to ``LoopK.err`` for the caller (N >= 16:
numpy's dot of them is BLAS's, summed in another order than a loop's); ``state_every``: the
robots' states go out every this many control periods (AgentParams.state_every)."""

TwinK = namedtuple('TwinK', ['state', 'wheel', 't', 'rows', 'inv', 'mt', 'It', 'r', 'a', 'd',
                             'mc', 'tau_max', 'd_amp', 'd_freq', 'd_phase', 'obstacles', 'ob',
                             'tau', 'g'])
TwinK.__doc__ = """The plant twin's arrays (its rows): ``state`` (N, 5), ``wheel`` (N, 2) angles,
``t`` (1,) its scenario time [s]; ``rows`` (N,) the twin row of each robot (id order), ``inv``
(N,) the robot of each twin row; plant coefficients, torque limits, the disturbance's terms;
``obstacles`` the scenario's obstacles' motion (obstacle_arrays, 6) and ``ob`` their state's
buffers (6); buffers ``tau`` (N, 2) and ``g`` (2 step + 1, N, 2)."""

CameraK = namedtuple('CameraK', ['arrive', 'stamp', 'pose', 'kept', 'u', 'e', 'noise_m',
                                 'noise_rad', 'drop_prob', 'latency_s'])
CameraK.__doc__ = """The frames on their way (a ring: ``arrive``, ``stamp`` (Q,) [s], ``pose``
(Q, N, 3), ``kept`` (Q, N)) and the frames' draws (``u`` (F, N) uniform, ``e`` (F, N, 3)
standard normal, in the order the camera's generator gives them); the camera's figures."""

LoopK = namedtuple('LoopK', ['angle', 'rate', 'bx', 'ba', 'bmode', 'sent', 'avoid_now',
                             'avoid_set', 'ob_map', 'is_leader', 'events', 'err'])
LoopK.__doc__ = """The loop's buffers: the wheel samples (N, 2); the previous period's broadcasts
(``bx`` (N, 5), ``ba`` (N, 2), ``bmode`` (N, 3), ``sent`` (N,)); ``avoid_now`` (N,) the robots
the reports show avoiding, ``avoid_set`` (N,) the coordinator's set (its graph); ``ob_map`` the
coordinator's index of each agent obstacle index; ``is_leader`` (N,); ``events`` (E, 7) the
agents' mode events [hosted row, t, robot row, enter, mode, target, sense]; ``err`` (P, N) the
estimate errors of the periods (``ClockK.blas_error``)."""

RecordK = namedtuple('RecordK', ['state', 'torque', 'avoid', 'sat', 'oc', 'ophi', 'progress'])


@njit(cache=True, error_model='numpy')
def _capture(t, reg, cam, tw):
    """A frame at ``t`` of every robot's TRUE pose of p, noised and thinned (_Camera.capture)."""
    q = (reg[CQ_HEAD] + reg[CQ_N]) % cam.arrive.shape[0]
    cam.arrive[q] = t + cam.latency_s
    cam.stamp[q] = t
    f = reg[NOISE_POS]
    u, e = cam.u[f], cam.e[f]
    pose, kept = cam.pose[q], cam.kept[q]
    n = pose.shape[0]
    nk = 0
    for p in range(n):
        x = tw.state[tw.rows[p]]
        pose[p, 0] = x[0] + cam.noise_m * e[p, 0]
        pose[p, 1] = x[1] + cam.noise_m * e[p, 1]
        pose[p, 2] = (x[2] + cam.noise_rad * e[p, 2] + math.pi) % (2 * math.pi) - math.pi
        kept[p] = u[p] >= cam.drop_prob
        if kept[p]:
            nk += 1
    reg[FRAMES] += 1
    reg[SENT] += nk
    reg[DROPPED] += n - nk
    reg[NOISE_POS] = f + 1
    reg[CQ_N] += 1


@njit(cache=True, error_model='numpy')
def _states_sent(t, clock):
    """Whether the robots send their states in the control period at ``t`` [s]: every
    ``clock.state_every``-th (AgentParams.state_rate_hz).
    """
    return int(round(t / (clock.dt * clock.ctrl_every))) % clock.state_every == 0


@njit(cache=True, error_model='numpy')
def _tick(t, reg, fl, clock, st, sc, out, ck, tw, cam, lb):
    """A control period's robot side (_Loop.tick up to the coordinator's decision): wheel
    samples, the frames arrived, the previous period's broadcasts, every agent's period, the
    estimate errors, the mode events, this period's broadcasts and what the coordinator hears.
    Returns whether the set of avoiding robots changed (the caller rewires).
    """
    n = tw.state.shape[0]
    for p in range(n):
        tr = tw.rows[p]
        v, w = tw.state[tr, 3], tw.state[tr, 4]
        half = 0.5 * tw.a[tr]
        lb.angle[p, 0], lb.angle[p, 1] = tw.wheel[tr, 0], tw.wheel[tr, 1]
        lb.rate[p, 0] = (v - half * w) / tw.r[tr]
        lb.rate[p, 1] = (v + half * w) / tw.r[tr]
    wheels_k(t, lb.angle, lb.rate, st, sc)
    cap = cam.arrive.shape[0]
    while reg[CQ_N] > 0 and cam.arrive[reg[CQ_HEAD]] <= t + 1e-12:
        h = reg[CQ_HEAD]
        frame_k(cam.stamp[h], cam.pose[h], cam.kept[h], st, sc, clock.hear_all,
                clock.hysteresis)
        reg[CQ_HEAD] = (h + 1) % cap
        reg[CQ_N] -= 1
    # the previous period's broadcasts (stamped fl[B_T])
    broadcast_k(fl[B_T], lb.bx, lb.ba, lb.bmode, lb.sent, st, sc, clock.hear_all,
                _states_sent(fl[B_T], clock))
    st.nev[:] = 0
    agent_tick_k(t, st, sc, out)
    nr = sc.rows.shape[0]
    for r in range(nr):
        i = sc.rows[r]
        for e in range(min(st.nev[r], st.ev.shape[1])):
            if int(st.ev[r, e, 1]) != i:
                continue
            row = lb.events[reg[EV_N]]
            row[0] = r
            for c in range(6):
                row[1 + c] = st.ev[r, e, c]
            reg[EV_N] += 1
    # |p_hat - p| (np.hypot; summed as numpy's dot of up to 15 values, a loop from 0)
    err = lb.err[reg[ERR_N]] if clock.blas_error else lb.err[0]
    for r in range(nr):
        x = tw.state[tw.rows[r]]
        err[r] = math.hypot(out.state[r, 0] - x[0], out.state[r, 1] - x[1])
    if clock.blas_error:
        reg[ERR_N] += 1
    else:
        s = 0.0
        top = -np.inf
        nan = False
        for r in range(nr):
            s += err[r] * err[r]
            if err[r] != err[r]:
                nan = True
            elif err[r] > top:
                top = err[r]
        fl[ERR_SQ] += s
        top = np.nan if nan else top
        if top > fl[ERR_MAX]:  # max(err_max, e.max())
            fl[ERR_MAX] = top
        reg[ERR_COUNT] += nr
    sent_now = _states_sent(t, clock)
    for r in range(nr):
        for q in range(5):
            lb.bx[r, q] = out.state[r, q]
        lb.ba[r, 0], lb.ba[r, 1] = out.accel[r, 0], out.accel[r, 1]
        running = st.status[r] == RUNNING
        if running:
            lb.bmode[r, 0], lb.bmode[r, 1], lb.bmode[r, 2] = out.mode[r, 0], out.mode[r, 1], \
                out.mode[r, 2]
        else:
            lb.bmode[r, 0], lb.bmode[r, 1], lb.bmode[r, 2] = 0.0, -1.0, 1.0
        # the coordinator hears the state (in a period of state_rate_hz) and the mode report
        # (AgentBatch.mode_dict)
        q = sc.rows[r]
        if sent_now:
            for c in range(5):
                ck.x[q, c] = out.state[r, c]
            ck.stamp[q] = t
        md = int(out.mode[r, 0])
        ck.rep_has[q] = True
        ck.rep_ob[q] = lb.ob_map[int(out.mode[r, 1])] if running and md == MODE_OBSTACLE else -1
        ck.rep_sdir[q] = -1.0 if running and md != MODE_C and not int(out.mode[r, 2]) > 0 \
            else 1.0
        lb.avoid_now[q] = running and md != MODE_C
    fl[B_T] = t
    changed = False
    for q in range(n):
        if lb.avoid_now[q] != lb.avoid_set[q]:
            changed = True
    return changed


@njit(cache=True, error_model='numpy')
def _record(reg, out, ck, tw, rec):
    """The record's sample of now (_Record.add): the TRUE state, torques, flags, obstacles, the
    coordinator's progress of every leader's reference.
    """
    q = reg[REC_N]
    for p in range(tw.state.shape[0]):
        x = tw.state[tw.rows[p]]
        for c in range(5):
            rec.state[q, p, c] = x[c]
        rec.torque[q, p, 0], rec.torque[q, p, 1] = out.torque[p, 0], out.torque[p, 1]
        rec.avoid[q, p] = out.mode[p, 0] != 0
        rec.sat[q, p] = out.saturated[p]
        rec.progress[q, p] = ck.progress.s[p] if ck.refs.row[p] >= 0 else 0.0
    if rec.oc.shape[1]:
        o, b = tw.obstacles, tw.ob
        obstacle_states(tw.t[0], o[0], o[1], o[2], o[3], o[4], o[5], b[0], b[1], b[2], b[3],
                        b[4], b[5])
        for j in range(rec.oc.shape[1]):
            rec.oc[q, j, 0], rec.oc[q, j, 1] = b[0][j, 0], b[0][j, 1]
            rec.ophi[q, j] = b[3][j]
    reg[REC_N] = q + 1


@njit(cache=True, error_model='numpy')
def _advance(n_steps, dt, out, tw):
    """PlantTwin.advance: ``n_steps`` RK4 steps with the agents' torques held (clamped; NaN
    -> 0), the disturbance at every half step.
    """
    for q in range(tw.state.shape[0]):
        lim = tw.tau_max[q]
        for c in range(2):
            v = out.torque[tw.inv[q], c]
            if v == v:  # np.clip: max(v, -lim) then min(., lim), NaN kept
                v = v if v > -lim else -lim
                v = v if v < lim else lim
            tw.tau[q, c] = v if math.isfinite(v) else 0.0
    if n_steps <= 0:
        return
    h = 0.5 * dt
    t0 = tw.t[0]
    g = tw.g[:2 * n_steps + 1]
    for s in range(g.shape[0]):
        ts = t0 + h * s
        for i in range(tw.state.shape[0]):
            g1, g2 = disturbance_k(ts, tw.d_amp[i], tw.d_freq[i], tw.d_phase[i])
            g[s, i, 0] = g1
            g[s, i, 1] = g2
    _advance_k(tw.state, tw.wheel, tw.tau, g, dt, tw.mt, tw.It, tw.r, tw.a, tw.d, tw.mc)
    tw.t[0] += n_steps * dt


@njit(cache=True, error_model='numpy')
def run_k(reg, fl, clock, st, sc, out, ck, pub, tw, cam, lb, rec):
    """The loop of simulate_sensed from step ``reg[K]`` (module docstring); returns why it
    stopped (:data:`DONE` when ``reg[K]`` reached ``reg[K_END]``). Each return is at the top of
    a step (``reg[PHASE]`` 0) but :data:`REWIRE` (1: the period goes on with the coordinator).
    """
    # the loop reads every array without reference counting (core/borrowed.py): they are all
    # the caller's, and only an int is returned
    reg, fl, clock, st, sc, out, ck, pub, tw, cam, lb, rec = borrowed(
        (reg, fl, clock, st, sc, out, ck, pub, tw, cam, lb, rec))
    dt = clock.dt
    nr = sc.rows.shape[0]
    while True:
        k = reg[K]
        t = k * dt
        if reg[PHASE] == 0:
            if k >= reg[K_END]:
                return DONE
            if k >= reg[K_STOP]:
                return CHUNK_END
            frame = k >= reg[NEXT_FRAME] * clock.cap_every - 1e-9
            if frame and reg[NOISE_POS] >= cam.u.shape[0]:
                return NOISE
            if frame and reg[CQ_N] >= cam.arrive.shape[0]:
                return QUEUE_FULL
            if k % clock.rec_every == 0 and reg[REC_N] >= rec.state.shape[0]:
                return RECORD_FULL
            tick = k % clock.ctrl_every == 0
            if tick and (reg[EV_N] + nr * st.ev.shape[1] > lb.events.shape[0]
                         or (clock.blas_error and reg[ERR_N] >= lb.err.shape[0])):
                return FLUSH
            if frame:
                _capture(t, reg, cam, tw)
                reg[NEXT_FRAME] += 1
            if tick:
                reg[PHASE] = 1
                if _tick(t, reg, fl, clock, st, sc, out, ck, tw, cam, lb):
                    return REWIRE
            else:
                reg[PHASE] = 2
        if reg[PHASE] == 1:
            if clock.arb_every > 0 and k % clock.arb_every == 0:
                decide_k(t, ck)
                if publish_due_k(t, ck, pub):
                    assign_k(t, sc.rows, pub.kind, pub.partner, pub.val, lb.is_leader,
                             pub.rate, st.coord_s, st.assigned, st.assigned_w, st.rate_target)
            if ck.end_s[0] == ck.end_s[0] and reg[K_END] == reg[K_CAP]:
                reg[K_END] = k + clock.hold_steps  # the hold in full (S17.3)
        if k % clock.rec_every == 0:
            _record(reg, out, ck, tw, rec)
        nxt = min(reg[K_END], (k // clock.step + 1) * clock.step,
                  int(math.ceil(reg[NEXT_FRAME] * clock.cap_every - 1e-9)))
        _advance(nxt - k, dt, out, tw)
        reg[K] = nxt
        reg[PHASE] = 0


@njit(cache=True, error_model='numpy')
def leader_goals_k(refs, i, progress, out):
    """A leader's formation goal r(s) (s_dot = 0) at every progress of ``progress`` (T,) ->
    ``out`` (T, 2).
    """
    buf = np.zeros(6)
    for q in range(progress.shape[0]):
        leader_reference(refs, i, progress[q], 0.0, 0.0, buf)
        out[q, 0], out[q, 1] = buf[0], buf[1]
