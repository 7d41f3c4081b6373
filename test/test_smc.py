"""Sliding-mode law (S3.1, S3.2, S3.5, S3.6) and the finite-time reaching bound (S3.3, S3.4)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from kernel_set import kn
import numpy as np
from oracle_dynamics import point_accel, point_velocity, rk4_step, s1_inv
from oracle_smc import (
    reaching_time_bound,
    saturate_torque,
    sliding_mode_torque,
    sliding_mode_torque_raw,
    switching_gain_for,
)

from ament_formation.core.model.disturbance import Disturbance
from ament_formation.core.model.dynamics import PlantCoeffs, RobotPlant
from ament_formation.core.params import ControlGains, RobotParams

GAINS = ControlGains()


def _states(rng, n, w_max=2.0):
    x = np.empty((n, 5))
    x[:, :2] = rng.uniform(-2, 2, (n, 2))
    x[:, 2] = rng.uniform(-np.pi, np.pi, n)
    x[:, 3] = rng.uniform(-0.3, 0.3, n)
    x[:, 4] = rng.uniform(-w_max, w_max, n)
    return x


def _coeffs(n, tau_max=0.15):
    return PlantCoeffs.from_params([RobotParams(torque_limit_nm=tau_max)] * n)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), eps=st.sampled_from([0.0, 0.002, 0.01, 0.05]))
def test_inverse_dynamics_reproduce_commanded_acceleration(seed, eps):
    """S3.2 torques through S2.2 dynamics give p_ddot = V_d_dot - K sat(sigma/eps)
    (unsaturated).
    """
    rng = np.random.default_rng(seed)
    n = 16
    k = _coeffs(n, tau_max=1e6)
    x = _states(rng, n)
    v_d = rng.uniform(-0.2, 0.2, (n, 2))
    v_d_dot = rng.uniform(-0.3, 0.3, (n, 2))
    out = sliding_mode_torque_raw(x, v_d, v_d_dot, k, GAINS.switching_gain_mps2, eps)
    assert not out.saturated.any()
    sigma = point_velocity(x, k.d) - v_d
    np.testing.assert_allclose(out.sigma_mps, sigma, atol=1e-15)
    sw = np.sign(sigma) if eps == 0 else np.clip(sigma / eps, -1, 1)
    target = v_d_dot - GAINS.switching_gain_mps2 * sw
    np.testing.assert_allclose(point_accel(x, out.torque_nm, None, k), target, atol=1e-12)
    np.testing.assert_allclose(out.accel_cmd_mps2, target, atol=1e-12)
    # independent check: differentiate the simulated point velocity (ZOH torque, no disturbance)
    h = 1e-5
    fwd = rk4_step(x, out.torque_nm, None, 0.0, h, k)
    bwd = rk4_step(x, out.torque_nm, None, 0.0, -h, k)
    fd = (point_velocity(fwd, k.d) - point_velocity(bwd, k.d)) / (2 * h)
    np.testing.assert_allclose(fd, target, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tau_max=st.floats(0.01, 0.3))
def test_torque_saturation_keeps_ratio_and_never_exceeds_limit(seed, tau_max):
    rng = np.random.default_rng(seed)
    n = 32
    k = _coeffs(n, tau_max=tau_max)
    x = _states(rng, n, w_max=5.0)
    v_d = rng.uniform(-1, 1, (n, 2))
    v_d_dot = rng.uniform(-3, 3, (n, 2))
    free = sliding_mode_torque_raw(x, v_d, v_d_dot, _coeffs(n, tau_max=1e9), 0.27, 0.01).torque_nm
    out = sliding_mode_torque_raw(x, v_d, v_d_dot, k, 0.27, 0.01)
    peak = np.max(np.abs(free), axis=1)
    assert np.all(np.max(np.abs(out.torque_nm), axis=1) <= tau_max * (1 + 1e-12))
    np.testing.assert_array_equal(out.saturated, peak > tau_max)
    # uniform scaling: same direction, factor min(1, tau_max/peak)
    scale = np.minimum(1.0, tau_max / peak)
    np.testing.assert_allclose(out.torque_nm, free * scale[:, None], rtol=1e-12, atol=1e-15)
    cross = out.torque_nm[:, 0] * free[:, 1] - out.torque_nm[:, 1] * free[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)
    # unsaturated rows keep exactly the free torque
    np.testing.assert_array_equal(out.torque_nm[~out.saturated], free[~out.saturated])
    # the reported commanded acceleration is the one of the applied (scaled) torque
    np.testing.assert_allclose(
        out.accel_cmd_mps2, point_accel(x, out.torque_nm, None, k), atol=1e-12
    )
    tq, flag = saturate_torque(np.array([[0.3, -0.1], [0.05, 0.02]]), np.array([0.15, 0.15]))
    np.testing.assert_allclose(tq, [[0.15, -0.05], [0.05, 0.02]])
    np.testing.assert_array_equal(flag, [True, False])


def test_gain_condition_s3_3_defaults():
    k = switching_gain_for(0.15, 0.05, 0.5, 0.05, delta_a_bound_mps2=0.056)
    # 0.15 + sqrt(0.05^2 + 0.05^2 0.5^2) + 0.056 = 0.2619; the default K = 0.27 covers it
    assert abs(k - (0.15 + np.sqrt(0.0025 + 0.000625) + 0.056)) < 1e-12
    assert abs(k - 0.2619) < 1e-4
    assert GAINS.switching_gain_mps2 >= k


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_reaching_time_never_exceeds_s3_4_bound(seed):
    """Closed loop (dynamics + S3.2 + RK4 + bounded g): |sigma_k| <= eps within
    (|sigma_k0| - eps)/lambda.
    """
    rng = np.random.default_rng(seed)
    n, dt = 48, 1e-3
    lam, eps = GAINS.reaching_rate_mps2, GAINS.boundary_layer_mps
    k = _coeffs(n)
    dist = Disturbance.from_bounds(n, (0.05, 0.5), seed=int(rng.integers(1 << 30)), f_max_hz=2.0)
    # a smooth time-varying desired velocity V_d(t) = v0 + A sin(w t) with exact derivative
    v0 = rng.uniform(-0.08, 0.08, (n, 2))
    amp = rng.uniform(-0.03, 0.03, (n, 2))
    om = rng.uniform(0.2, 1.0, (n, 1))
    sigma0 = rng.uniform(-0.1, 0.1, (n, 2))
    x = np.zeros((n, 5))
    x[:, :2] = rng.uniform(-1, 1, (n, 2))
    x[:, 2] = rng.uniform(-np.pi, np.pi, n)
    x[:, 3:] = np.einsum('nij,nj->ni', s1_inv(x[:, 2], k.d), v0 + sigma0)  # sigma(0) = sigma0
    bound_k = np.maximum(np.abs(sigma0) - eps, 0.0) / lam
    horizon = float(bound_k.max()) + 0.3
    reached = np.where(np.abs(sigma0) <= eps, 0.0, np.inf)
    first = None
    max_after = np.zeros((n, 2))
    for i in range(int(horizon / dt) + 1):
        t = i * dt
        v_d = v0 + amp * np.sin(om * t)
        v_d_dot = amp * om * np.cos(om * t)
        out = sliding_mode_torque(x, v_d, v_d_dot, k, GAINS)
        if first is None:
            first = out.sigma_mps
        assert not out.saturated.any()
        inside = np.abs(out.sigma_mps) <= eps
        reached = np.where(np.isinf(reached) & inside, t, reached)
        max_after = np.where(
            np.isfinite(reached), np.maximum(max_after, np.abs(out.sigma_mps)), max_after
        )
        x = rk4_step(x, out.torque_nm, dist, t, dt, k)
    np.testing.assert_allclose(first, sigma0, atol=1e-14)
    assert np.all(np.isfinite(reached))
    assert np.all(reached <= bound_k + dt)  # componentwise (boundary layer)
    t_reach = reached.max(axis=1)
    assert np.all(t_reach <= np.max(np.abs(sigma0), axis=1) / lam)  # S3.4 bound
    np.testing.assert_allclose(reaching_time_bound(sigma0, lam, eps), bound_k.max(axis=1))
    assert np.all(max_after <= eps * (1 + 1e-9))  # stays in the layer afterwards
    # the reaching phase is not trivially short: the bound is tight to within a factor ~2
    assert np.max(t_reach / np.maximum(bound_k.max(axis=1), 1e-9)) > 0.5


def test_kernel_matches_numpy_law():
    rng = np.random.default_rng(21)
    n = 300
    params = [
        RobotParams(com_offset_m=rng.uniform(0.02, 0.1), torque_limit_nm=rng.uniform(0.02, 0.3))
        for _ in range(n)
    ]
    k = PlantCoeffs.from_params(params)
    x = _states(rng, n, w_max=4.0)
    v_d = rng.uniform(-0.5, 0.5, (n, 2))
    v_d_dot = rng.uniform(-1, 1, (n, 2))
    for eps in (0.0, 0.01):
        ref = sliding_mode_torque_raw(x, v_d, v_d_dot, k, 0.27, eps)
        assert 0 < ref.saturated.sum() < n
        for i in range(n):
            res = kn.smc_torque_k(
                x[i, 2],
                x[i, 3],
                x[i, 4],
                *v_d[i],
                *v_d_dot[i],
                RobotPlant(k.m_tilde[i], k.I_tilde[i], k.r[i], k.a[i], k.d[i], k.m_c[i]),
                k.tau_max[i],
                0.27,
                0.27,
                eps,
            )
            np.testing.assert_allclose(res[0:2], ref.torque_nm[i], rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(res[2:4], ref.sigma_mps[i], rtol=1e-12, atol=1e-15)
            assert res[4] == ref.saturated[i]
            np.testing.assert_allclose(res[5:7], ref.accel_cmd_mps2[i], rtol=1e-12, atol=1e-14)
