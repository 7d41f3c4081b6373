"""S10 pose fusion: odometry arcs, latency-compensated camera correction, rejection and gating."""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.control.estimator import (
    _Step,
    EstimatorParams,
    fold_steps,
    fold_to_end,
    PoseEstimator,
    wheel_to_body,
    wrap_angle,
)
from ament_formation.core.errors import ConfigError

R, A, D = 0.035, 0.20, 0.05


@settings(max_examples=80, deadline=None)
@given(
    v=st.floats(-0.3, 0.3),
    w=st.floats(-3.0, 3.0),
    th0=st.floats(-3.1, 3.1),
    k=st.integers(1, 50),
    t=st.floats(0.05, 3.0),
)
@example(v=0.25, w=1.629478018614031e-09, th0=1.0, k=1, t=1.0)  # v/w (sin - sin) lost 2e-8
def test_fold_steps_is_exact_for_constant_rates(v, w, th0, k, t):
    axle, th = fold_steps([0.3, -0.2], th0, np.full(k, v * t / k), np.full(k, w * t / k))
    # the arc's chord: length v t sinc(w t / 2) along the mean heading (no cancellation as w -> 0)
    half = w * t / 2.0
    chord = v * t * (math.sin(half) / half if half != 0.0 else 1.0)
    ex, ey = 0.3 + chord * math.cos(th0 + half), -0.2 + chord * math.sin(th0 + half)
    assert axle[-1] == pytest.approx([ex, ey], abs=1e-9)
    assert th[-1] == pytest.approx(th0 + w * t, abs=1e-12)


@settings(max_examples=80, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-0.01, 0.01), st.floats(-0.2, 0.2)), max_size=40),
    th0=st.floats(-3.1, 3.1),
)
def test_scalar_fold_matches_the_array_fold(steps, th0):
    """fold_to_end (the per-sample scalar path) ends where fold_steps ends, tiny arcs included."""
    axle, th = fold_to_end([0.3, -0.2], th0, [_Step(0.0, ds, dth) for ds, dth in steps])
    if not steps:
        assert axle.tolist() == [0.3, -0.2] and th == th0
        return
    ref_axle, ref_th = fold_steps([0.3, -0.2], th0, [s[0] for s in steps], [s[1] for s in steps])
    assert axle == pytest.approx(ref_axle[-1], abs=1e-12) and th == pytest.approx(
        ref_th[-1], abs=1e-12
    )


def test_wheel_to_body_matches_s2_kinematics():
    ds, dth = wheel_to_body([1.0, 3.0], R, A)
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
    ds, dth = wheel_to_body(np.diff(q, axis=0), R, A)
    th0 = 0.4
    axle, th = fold_steps([0.0, 0.0], th0, ds, dth)
    axle = np.vstack([[0.0, 0.0], axle])
    th = np.concatenate([[th0], th])
    pose = np.stack([axle[:, 0] + D * np.cos(th), axle[:, 1] + D * np.sin(th), th], axis=1)
    return t, q, rate, pose


def _run(
    est,
    t,
    q,
    rate,
    pose,
    cam_period_s,
    latency_s,
    noise=(0.0, 0.0),
    scale=1.0,
    seed=1,
    stamp_at_arrival=False,
):
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
    assert est.counters.camera_accepted > 150 and est.counters.rejected_outlier == 0


def test_latency_compensation_beats_applying_late_frames_as_current():
    t, q, rate, pose = _truth(10.0, seed=3)
    prm = EstimatorParams(wheel_radius_m=R, axle_length_m=A, com_offset_m=D, camera_gain=0.5)
    # 4 % wheel-radius error in the estimator's odometry, 4 mm / 0.03 rad camera noise, 150 ms
    # latency
    comp = _run(PoseEstimator(prm), t, q, rate, pose, 1 / 30, 0.15, (0.004, 0.03), scale=1.04)
    naive = _run(
        PoseEstimator(prm),
        t,
        q,
        rate,
        pose,
        1 / 30,
        0.15,
        (0.004, 0.03),
        scale=1.04,
        stamp_at_arrival=True,
    )
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
    assert not est.initialized
    assert est.camera_update(0.0, [np.nan, 0, 0]) == 'rejected_nonfinite'
    assert est.camera_update(0.0, [1.0, 2.0, 0.5]) == 'initialized'
    before = est.state().copy()
    assert not est.wheel_update(0.01, [np.inf, 0.0], [0.0, 0.0])
    assert est.wheel_update(0.01, [0.0, 0.0], [0.0, 0.0])
    assert not est.wheel_update(0.02, [50.0, 0.0], [0.0, 0.0])  # 5000 rad/s: encoder glitch
    assert not est.wheel_update(0.015, [50.0, 0.0], [0.0, 0.0])  # older stamp: stale
    assert est.wheel_update(0.03, [50.0, 0.0], [0.0, 0.0])  # resynchronised: no jump applied
    np.testing.assert_allclose(est.state(), before)
    assert est.camera_update(-1.0, [1.0, 2.0, 0.5]) == 'rejected_stale'
    for k in range(4):
        assert est.camera_update(0.1 + 0.01 * k, [3.0, 2.0, 0.5]) == 'rejected_outlier'
    np.testing.assert_allclose(est.state(), before)
    assert est.camera_update(0.2, [3.0, 2.0, 0.5]) == 'relocked'  # 5th disagreeing frame in a row
    np.testing.assert_allclose(est.pose(), [3.0, 2.0, 0.5])
    c = est.counters
    assert (
        c.rejected_nonfinite,
        c.rejected_glitch,
        c.rejected_stale,
        c.rejected_outlier,
        c.relocks,
    ) == (2, 1, 2, 4, 1)


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
    assert est.camera_age_s(0.25) == pytest.approx(0.2)


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
    assert float(wrap_angle(3 * math.pi)) == pytest.approx(-math.pi)


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
    assert a.counters.as_dict() == {
        **b.counters.as_dict(),
        'rejected_nonfinite': b.counters.rejected_nonfinite - 1,
    }
