"""S10.1 pose fusion (core/control/estimator.py): odometry arcs, latency-compensated camera
correction, rejection and gating; the compiled kernels on rows of many robots and the
PoseEstimator wrapper.
"""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.control.estimator import (
    arc_step,
    CAMERA_OUTCOMES,
    camera_update_k,
    COUNTERS,
    EstimatorParams,
    HISTORY,
    I_COUNT,
    new_estimates,
    PoseEstimator,
    state_at_k,
    wheel_update_k,
    wrap,
)
from ament_formation.core.errors import ConfigError

R, A, D = 0.035, 0.20, 0.05


def wheel_to_body(dq_rad, r_m=R, a_m=A):
    """S2.2 kinematics: wheel angle increments (..., 2) [left, right] -> (ds [m], dtheta
    [rad]).
    """
    dq = np.asarray(dq_rad, dtype=float)
    return r_m * 0.5 * (dq[..., 1] + dq[..., 0]), r_m * (dq[..., 1] - dq[..., 0]) / a_m


def fold(axle_xy, theta, ds, dth):
    """Axle poses after each step of ``arc_step`` (the readable oracle of the ring fold):
    (K, 2) positions and (K,) headings.
    """
    x, y, th = float(axle_xy[0]), float(axle_xy[1]), float(theta)
    out = np.empty((len(ds), 3))
    for q, (a, b) in enumerate(zip(ds, dth)):
        x, y, th = arc_step(x, y, th, float(a), float(b))
        out[q] = x, y, th
    return out[:, :2], out[:, 2]


@settings(max_examples=80, deadline=None)
@given(
    v=st.floats(-0.3, 0.3),
    w=st.floats(-3.0, 3.0),
    th0=st.floats(-3.1, 3.1),
    k=st.integers(1, 50),
    t=st.floats(0.05, 3.0),
)
@example(v=0.25, w=1.629478018614031e-09, th0=1.0, k=1, t=1.0)  # v/w (sin - sin) lost 2e-8
def test_arc_steps_are_exact_for_constant_rates(v, w, th0, k, t):
    axle, th = fold([0.3, -0.2], th0, np.full(k, v * t / k), np.full(k, w * t / k))
    # the arc's chord: length v t sinc(w t / 2) along the mean heading (no cancellation as w -> 0)
    half = w * t / 2.0
    chord = v * t * (math.sin(half) / half if half != 0.0 else 1.0)
    ex, ey = 0.3 + chord * math.cos(th0 + half), -0.2 + chord * math.sin(th0 + half)
    assert axle[-1] == pytest.approx([ex, ey], abs=1e-9)
    assert th[-1] == pytest.approx(th0 + w * t, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-0.01, 0.01), st.floats(-0.2, 0.2)), min_size=1,
                   max_size=40),
    th0=st.floats(-3.1, 3.1),
)
def test_the_odometry_ring_folds_as_the_arc_steps(steps, th0):
    """The estimate after encoder samples (the ring and its anchor) is the pose the arc steps of
    their increments give, tiny arcs included.
    """
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    est.initialize([0.3 + D * math.cos(th0), -0.2 + D * math.sin(th0), th0], 0.0)
    ql = qr = 0.0
    est.wheel_update(0.0, [ql, qr], [0.0, 0.0])
    ds, dth = [], []
    for q, (a, b) in enumerate(steps):  # (ds, dth) -> wheel increments
        dl, dr = (a - 0.5 * A * b) / R, (a + 0.5 * A * b) / R
        ql, qr = ql + dl, qr + dr
        assert est.wheel_update(0.01 * (q + 1), [ql, qr], [0.0, 0.0])
        step_ds, step_dth = wheel_to_body([dl, dr])
        ds.append(step_ds)
        dth.append(step_dth)
    axle, th = fold([0.3, -0.2], th0, ds, dth)
    pose = est.pose()
    assert pose[0] - D * math.cos(pose[2]) == pytest.approx(axle[-1, 0], abs=1e-12)
    assert pose[1] - D * math.sin(pose[2]) == pytest.approx(axle[-1, 1], abs=1e-12)
    assert abs(wrap(pose[2] - th[-1])) < 1e-12


def test_wheel_rates_give_s2_velocities():
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    est.initialize([0.0, 0.0, 0.0], 0.0)
    assert est.wheel_update(0.01, [0.0, 0.0], [1.0, 3.0])
    v, w = est.state()[3:]
    assert v == pytest.approx(R * 2.0) and w == pytest.approx(R * 2.0 / A)
    ds, dth = wheel_to_body([1.0, 3.0])
    assert ds == pytest.approx(R * 2.0) and dth == pytest.approx(R * 2.0 / A)


def _truth(t_end_s, dt_s=0.001, seed=0):
    """Fine (1 kHz) truth: wheel angles q (T, 2) and p-poses (T, 3) for smooth varying wheel
    rates.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, t_end_s + 1e-12, dt_s)
    f = rng.uniform(0.1, 0.6, size=2)
    ph = rng.uniform(0, 2 * np.pi, size=2)
    rate = np.stack(
        [
            2.0 + 1.5 * np.sin(2 * np.pi * f[0] * t + ph[0]),
            2.4 + 1.5 * np.sin(2 * np.pi * f[1] * t + ph[1]),
        ],
        axis=1,
    )  # rad/s
    q = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt_s, axis=0)])
    ds, dth = wheel_to_body(np.diff(q, axis=0))
    th0 = 0.4
    axle, th = fold([0.0, 0.0], th0, ds, dth)
    axle = np.vstack([[0.0, 0.0], axle])
    th = np.concatenate([[th0], th])
    pose = np.stack([axle[:, 0] + D * np.cos(th), axle[:, 1] + D * np.sin(th), th], axis=1)
    return t, q, rate, pose


def _run(est, t, q, rate, pose, cam_period_s, latency_s, noise=(0.0, 0.0), scale=1.0, seed=1,
         stamp_at_arrival=False):
    """Feed 100 Hz encoders and delayed camera frames; return |position error| at every 10 ms."""
    rng = np.random.default_rng(seed)
    errs = []
    queue = []  # (arrival_t, capture_t, pose)
    next_cam = 0.0
    for k in range(0, len(t), 10):
        now = t[k]
        if now >= next_cam - 1e-9:
            noisy = pose[k] + np.array(
                [rng.normal(0, noise[0]), rng.normal(0, noise[0]), rng.normal(0, noise[1])]
            )
            queue.append((now + latency_s, now, noisy))
            next_cam += cam_period_s
        est.wheel_update(now, q[k] * scale, rate[k] * scale)
        while queue and queue[0][0] <= now + 1e-9:
            arrival, capture, cam = queue.pop(0)
            est.camera_update(arrival if stamp_at_arrival else capture, cam)
        if est.initialized and now > 1.0:
            errs.append(np.hypot(*(est.pose()[:2] - pose[k, :2])))
    return np.array(errs)


def test_exact_inputs_give_the_truth_despite_latency():
    t, q, rate, pose = _truth(6.0)
    est = PoseEstimator(
        EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D, camera_gain=1.0)
    )
    errs = _run(est, t, q, rate, pose, cam_period_s=1 / 30, latency_s=0.12)
    assert errs.max() < 2e-5
    assert est.counters['camera_accepted'] > 150 and est.counters['rejected_outlier'] == 0


def test_latency_compensation_beats_applying_late_frames_as_current():
    t, q, rate, pose = _truth(10.0, seed=3)
    prm = EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D, camera_gain=0.5)
    # 4 % wheel-radius error in the estimator's odometry, 4 mm / 0.03 rad camera noise, 150 ms
    # latency
    comp = _run(PoseEstimator(prm), t, q, rate, pose, 1 / 30, 0.15, (0.004, 0.03), scale=1.04)
    naive = _run(PoseEstimator(prm), t, q, rate, pose, 1 / 30, 0.15, (0.004, 0.03), scale=1.04,
                 stamp_at_arrival=True)
    odo_only = PoseEstimator(prm)
    odo_only.initialize(pose[0], 0.0)
    drift = 0.0
    for k in range(0, len(t), 10):
        odo_only.wheel_update(t[k], q[k] * 1.04, rate[k] * 1.04)
        drift = max(drift, np.hypot(*(odo_only.pose()[:2] - pose[k, :2])))
    assert np.sqrt(np.mean(comp**2)) < 0.006
    assert np.sqrt(np.mean(naive**2)) > 2.0 * np.sqrt(np.mean(comp**2))
    assert drift > 4.0 * np.sqrt(np.mean(comp**2))  # odometry alone drifts (4 % of 0.8 m)


def test_two_fps_camera_with_odometry_stays_within_a_centimetre():
    t, q, rate, pose = _truth(12.0, seed=5)
    prm = EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D, camera_gain=0.7)
    errs = _run(PoseEstimator(prm), t, q, rate, pose, 0.5, 0.3, (0.004, 0.03), scale=1.02)
    assert errs.max() < 0.02


def test_rejections_are_counted_and_leave_the_estimate_alone():
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    assert not est.initialized and est.last_camera_s is None and est.odometry_time_s is None
    assert est.camera_update(0.0, [np.nan, 0, 0]) == 'rejected_nonfinite'
    assert est.camera_update(0.0, [1.0, 2.0, 0.5]) == 'initialized'
    before = est.state().copy()
    assert not est.wheel_update(0.01, [np.inf, 0.0], [0.0, 0.0])
    assert est.wheel_update(0.01, [0.0, 0.0], [0.0, 0.0])
    assert not est.wheel_update(0.02, [50.0, 0.0], [0.0, 0.0])  # 5000 rad/s: encoder glitch
    assert not est.wheel_update(0.015, [50.0, 0.0], [0.0, 0.0])  # older stamp: stale
    assert est.wheel_update(0.03, [50.0, 0.0], [0.0, 0.0])  # resynchronised: no jump applied
    assert not est.wheel_update(0.04, [50.0, 0.0], [300.0, 0.0])  # a rate beyond 200 rad/s
    np.testing.assert_allclose(est.state(), before)
    assert est.camera_update(-1.0, [1.0, 2.0, 0.5]) == 'rejected_stale'
    for k in range(4):
        assert est.camera_update(0.1 + 0.01 * k, [3.0, 2.0, 0.5]) == 'rejected_outlier'
    np.testing.assert_allclose(est.state(), before)
    assert est.camera_update(0.2, [3.0, 2.0, 0.5]) == 'relocked'  # 5th disagreeing frame in a row
    np.testing.assert_allclose(est.pose(), [3.0, 2.0, 0.5])
    assert est.camera_update(0.2, [3.0, 2.0, 0.5]) == 'rejected_stale'  # the same stamp again
    c = est.counters
    assert set(c) == set(COUNTERS)
    assert (
        c['rejected_nonfinite'],
        c['rejected_glitch'],
        c['rejected_stale'],
        c['rejected_outlier'],
        c['relocks'],
        c['camera_accepted'],
    ) == (2, 2, 3, 4, 1, 2)
    assert est.last_camera_s == 0.2 and est.odometry_time_s == 0.03


def test_samples_batched_under_one_stamp_are_all_applied():
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    est.initialize([0.0, 0.0, 0.0], 0.0)
    est.wheel_update(0.0, [0.0, 0.0], [2.0, 2.0])
    for q in (0.02, 0.04, 0.06):  # three telemetry frames read in one poll
        assert est.wheel_update(0.03, [q, q], [2.0, 2.0])
    assert est.pose()[0] == pytest.approx(R * 0.06)


def test_odometry_before_the_first_frame_is_replayed_after_it():
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    for k in range(11):  # straight ahead at 2 rad/s on both wheels: 0.07 m/s
        est.wheel_update(0.01 * k, [0.02 * k, 0.02 * k], [2.0, 2.0])
    assert est.camera_update(0.05, [0.0, 0.0, 0.0]) == 'initialized'
    np.testing.assert_allclose(est.state(), [0.07 * 0.05, 0.0, 0.0, 0.07, 0.0], atol=1e-12)
    np.testing.assert_allclose(est.state_at(0.12)[:2], [0.07 * 0.07, 0.0], atol=1e-12)
    np.testing.assert_allclose(
        est.state_at(5.0)[:2], [0.07 * 0.1, 0.0], atol=1e-12
    )  # capped at 50 ms
    np.testing.assert_allclose(est.state_at(0.0)[:2], [0.07 * 0.1, 0.0], atol=1e-12)  # no going
    # back
    assert est.camera_age_s(0.25) == pytest.approx(0.2)


def test_odometry_older_than_the_history_is_not_replayed():
    # 2 s of samples before the first frame: only history_s (1 s) before it is kept, so the frame
    # at t = 1.5 s replays the 0.5 s after it (the older steps are dropped, not folded in)
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    for k in range(201):
        est.wheel_update(0.01 * k, [0.02 * k, 0.02 * k], [2.0, 2.0])
    assert est._e.i[0, I_COUNT] <= 101
    assert est.camera_update(1.5, [1.0, 0.0, 0.0]) == 'initialized'
    np.testing.assert_allclose(est.pose(), [1.0 + 0.07 * 0.5, 0.0, 0.0], atol=1e-12)


def test_a_late_frame_corrects_the_pose_it_saw_after_the_ring_wrapped():
    """Many more samples than the ring holds (HISTORY) at 500 Hz: the steps older than
    history_s are folded into the anchor, and a frame 0.3 s late still lands at its stamp.
    """
    prm = EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D, camera_gain=1.0)
    t, q, rate, _pose = _truth(8.0, seed=11)
    t, q, rate = t[::2], q[::2], rate[::2]  # 500 Hz: HISTORY = 256 steps hold 0.51 s
    assert t.size > 10 * HISTORY
    ds, dth = wheel_to_body(np.diff(q, axis=0))
    axle, th = fold([0.0, 0.0], 0.4, ds, dth)  # the oracle: every step folded in turn
    axle, th = np.vstack([[0.0, 0.0], axle]), np.concatenate([[0.4], th])
    pose = np.stack([axle[:, 0] + D * np.cos(th), axle[:, 1] + D * np.sin(th), wrap_all(th)],
                    axis=1)
    est = PoseEstimator(prm)
    est.initialize(pose[0], 0.0)
    for k in range(t.size):
        assert est.wheel_update(t[k], q[k], rate[k])
    assert est._e.i[0, I_COUNT] == HISTORY
    np.testing.assert_allclose(est.pose(), pose[-1], atol=1e-12)
    # a frame older than the ring (0.6 s > 0.51 s) is before the anchor: stale
    assert est.camera_update(t[-1 - 300], pose[-1 - 300]) == 'rejected_stale'
    # a frame captured 0.3 s ago, 2 cm off in x: with gain 1 the pose it saw moves by 2 cm and
    # the odometry since is replayed from there (a translation: the same 2 cm now)
    assert est.camera_update(t[-1 - 150], pose[-1 - 150] + [0.02, 0.0, 0.0]) == 'accepted'
    np.testing.assert_allclose(est.pose(), pose[-1] + [0.02, 0.0, 0.0], atol=1e-9)


def wrap_all(a):
    return np.array([float(wrap(v)) for v in a])


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(['wheel', 'camera']),
            st.floats(allow_nan=True, allow_infinity=True, width=32),
            st.floats(allow_nan=True, allow_infinity=True, width=32),
        ),
        max_size=60,
    )
)
def test_garbage_never_makes_the_estimate_non_finite(events):
    est = PoseEstimator(EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D))
    est.initialize([0.0, 0.0, 0.0], 0.0)
    t = 0.0
    for kind, a, b in events:
        t += 0.01
        if kind == 'wheel':
            est.wheel_update(t, [a, b], [a, b])
        else:
            est.camera_update(t, [a, b, a])
        assert np.all(np.isfinite(est.state()))
        assert -math.pi <= est.state()[2] < math.pi


def test_params_validate():
    with pytest.raises(ConfigError, match='camera_gain'):
        EstimatorParams(camera_gain=0.0)
    with pytest.raises(ConfigError, match='gate_position_m'):
        EstimatorParams(gate_position_m=float('nan'))
    with pytest.raises(ConfigError, match='relock_after'):
        EstimatorParams(relock_after=2.5)
    with pytest.raises(ConfigError, match='max_extrapolation_s'):
        EstimatorParams(max_extrapolation_s=-0.01)
    with pytest.raises(ValueError, match='pose_xyt'):
        PoseEstimator(EstimatorParams()).initialize([0.0, math.nan, 0.0], 0.0)
    assert float(wrap(3 * math.pi)) == pytest.approx(-math.pi)
    assert float(wrap(-math.pi)) == pytest.approx(-math.pi)


def test_wheel_samples_as_pairs_of_floats_give_the_same_estimate():
    """The bridge hands its samples over as (left, right) tuples: the same estimate, bit for bit,
    as from arrays; a tuple that is not a pair is rejected as before.
    """
    rng = np.random.default_rng(7)
    a = PoseEstimator(EstimatorParams())
    b = PoseEstimator(EstimatorParams())
    for est in (a, b):
        est.camera_update(0.0, np.array([0.1, 0.2, 0.3]))
    q = np.zeros(2)
    for k in range(1, 300):
        rate = rng.normal(3.0, 1.0, 2)
        q = q + 0.01 * rate
        t = 0.01 * k
        assert a.wheel_update(t, q.copy(), rate.copy())
        assert b.wheel_update(t, (float(q[0]), float(q[1])), (float(rate[0]), float(rate[1])))
        if k % 3 == 0:
            pose = a.state_at(t)[:3] + rng.normal(0.0, 0.002, 3)
            assert a.camera_update(t - 0.02, pose) == b.camera_update(t - 0.02, pose)
        assert a.state_at(t + 0.004).tobytes() == b.state_at(t + 0.004).tobytes()
    assert not b.wheel_update(3.5, (0.0, 0.0, 0.0), (0.0, 0.0))
    assert b.camera_update(3.5, (0.0, 0.0)) == 'rejected_nonfinite'
    assert a.counters == {
        **b.counters,
        'rejected_nonfinite': b.counters['rejected_nonfinite'] - 2,
    }


def test_the_kernels_on_rows_of_many_robots_are_one_estimator_each():
    """The agent's layout: R robots in one EstimatorArrays, each row fused by the kernels, gives
    each robot's PoseEstimator bit for bit; a row's inputs never touch another row.
    """
    n = 3
    prm = [EstimatorParams(wheel_radius_m=R * (1 + 0.1 * r), camera_gain=0.3 + 0.2 * r)
           for r in range(n)]
    k = [p.compiled() for p in prm]
    e = new_estimates(n)
    alone = [PoseEstimator(p) for p in prm]
    rng = np.random.default_rng(9)
    q = np.zeros((n, 2))
    out = np.empty(5)
    for step in range(400):
        t = 0.01 * step
        rate = rng.normal(3.0, 1.0, (n, 2))
        q += 0.01 * rate
        for r in range(n):
            if step % (r + 2) == 0:  # each robot its own wheel rate
                ok = wheel_update_k(e, r, t, q[r, 0], q[r, 1], rate[r, 0], rate[r, 1], k[r])
                assert ok == alone[r].wheel_update(t, q[r], rate[r])
            if step % 4 == r and step > 0:
                pose = rng.normal(0.0, 0.5, 3)
                got = CAMERA_OUTCOMES[camera_update_k(e, r, t - 0.03, *pose, k[r])]
                assert got == alone[r].camera_update(t - 0.03, pose)
            state_at_k(e, r, t, k[r], out)
            assert out.tobytes() == alone[r].state_at(t).tobytes()
    for r in range(n):
        assert dict(zip(COUNTERS, e.counters[r].tolist())) == alone[r].counters
    assert len({tuple(e.f[r]) for r in range(n)}) == n  # three different estimates
