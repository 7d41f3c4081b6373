"""Robot dynamics (S2.2), derived inertias (S2.3), RK4 with ZOH torque, bounded disturbance."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from kernel_set import kn
import numpy as np
from oracle_dynamics import (
    commanded_point_accel,
    point_accel,
    point_velocity,
    rk4_step,
    s1,
    s1_inv,
    s1dot_x2,
    state_derivative,
)
import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.disturbance import Disturbance
from ament_formation.core.model.dynamics import (
    b2,
    b2_inv,
    f2,
    PlantCoeffs,
)
from ament_formation.core.params import RobotParams

DEFAULT = RobotParams()
SETTINGS = settings(max_examples=30, deadline=None)


def _coeffs(n=1, params=DEFAULT):
    return PlantCoeffs.from_params([params] * n)


def _random_states(rng, n):
    st_ = np.empty((n, 5))
    st_[:, :2] = rng.uniform(-2, 2, (n, 2))
    st_[:, 2] = rng.uniform(-np.pi, np.pi, n)
    st_[:, 3] = rng.uniform(-0.3, 0.3, n)
    st_[:, 4] = rng.uniform(-2.0, 2.0, n)
    return st_


def _random_coeffs(rng, n):
    params = [
        RobotParams(
            platform_mass_kg=rng.uniform(1, 4),
            wheel_mass_kg=rng.uniform(0.05, 0.3),
            wheel_radius_m=rng.uniform(0.02, 0.06),
            axle_length_m=rng.uniform(0.1, 0.4),
            com_offset_m=rng.uniform(0.02, 0.1),
            platform_inertia_kgm2=rng.uniform(0.005, 0.05),
        )
        for _ in range(n)
    ]
    return PlantCoeffs.from_params(params)


def test_derived_inertias_match_spec_s2_3():
    assert DEFAULT.mass_tilde_kg == pytest.approx(2.800, abs=5e-4)
    assert DEFAULT.inertia_tilde_kgm2 == pytest.approx(0.0260, abs=5e-5)
    k = _coeffs(3)
    assert k.n == 3
    np.testing.assert_allclose(k.m_tilde, 2.8, atol=5e-4)


def test_plant_coeffs_reject_bad_values_naming_field():
    k = _coeffs(2)
    with pytest.raises(ConfigError, match='^d: must be finite and > 0'):
        PlantCoeffs(k.m_tilde, k.I_tilde, k.r, k.a, np.array([0.05, 0.0]), k.m_c, k.tau_max)
    with pytest.raises(ConfigError, match='^r: must have 2 entries'):
        PlantCoeffs(k.m_tilde, k.I_tilde, np.ones(3), k.a, k.d, k.m_c, k.tau_max)


@SETTINGS
@given(seed=st.integers(0, 2**31 - 1))
def test_matrix_identities(seed):
    rng = np.random.default_rng(seed)
    n = 8
    k = _random_coeffs(rng, n)
    x = _random_states(rng, n)
    eye = np.broadcast_to(np.eye(2), (n, 2, 2))
    np.testing.assert_allclose(b2(k) @ b2_inv(k), eye, atol=1e-12)
    np.testing.assert_allclose(s1(x[:, 2], k.d) @ s1_inv(x[:, 2], k.d), eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(s1(x[:, 2], k.d)), k.d, rtol=1e-12)
    np.testing.assert_allclose(
        np.linalg.det(b2(k)), k.a / (k.m_tilde * k.I_tilde * k.r**2), rtol=1e-12
    )
    # point velocity = S1 x2 = first two rows of (16)-(17)
    pv = point_velocity(x, k.d)
    np.testing.assert_allclose(pv, np.einsum('nij,nj->ni', s1(x[:, 2], k.d), x[:, 3:]), atol=1e-15)
    np.testing.assert_allclose(
        state_derivative(x, np.zeros((n, 2)), None, k)[:, :2], pv, atol=1e-15
    )


@SETTINGS
@given(seed=st.integers(0, 2**31 - 1))
def test_s1dot_x2_is_the_time_derivative_of_s1(seed):
    rng = np.random.default_rng(seed)
    n = 6
    k = _random_coeffs(rng, n)
    x = _random_states(rng, n)
    h = 1e-6
    plus = s1(x[:, 2] + h * x[:, 4], k.d)
    minus = s1(x[:, 2] - h * x[:, 4], k.d)
    fd = np.einsum('nij,nj->ni', (plus - minus) / (2 * h), x[:, 3:])
    np.testing.assert_allclose(s1dot_x2(x, k.d), fd, atol=1e-8)


@SETTINGS
@given(seed=st.integers(0, 2**31 - 1))
def test_power_balance_kinetic_energy_rate_equals_wheel_power(seed):
    """T = 1/2 m~ v^2 + 1/2 I~ w^2 (S2.2 derivation): dT/dt = tau1 (v - L w)/r + tau2
    (v + L w)/r.
    """
    rng = np.random.default_rng(seed)
    n = 8
    k = _random_coeffs(rng, n)
    x = _random_states(rng, n)
    tau = rng.uniform(-0.2, 0.2, (n, 2))
    xd = state_derivative(x, tau, None, k)
    v, w = x[:, 3], x[:, 4]
    t_dot = k.m_tilde * v * xd[:, 3] + k.I_tilde * w * xd[:, 4]
    half = 0.5 * k.a
    power = tau[:, 0] * (v - half * w) / k.r + tau[:, 1] * (v + half * w) / k.r
    np.testing.assert_allclose(t_dot, power, rtol=1e-10, atol=1e-13)
    # the drift f2 does no work
    f = f2(x, k)
    np.testing.assert_allclose(k.m_tilde * v * f[:, 0] + k.I_tilde * w * f[:, 1], 0.0, atol=1e-14)


def test_rk4_is_fourth_order_and_conserves_energy_without_torque():
    rng = np.random.default_rng(3)
    k = _coeffs(4)
    x0 = _random_states(rng, 4)
    tau = rng.uniform(-0.05, 0.05, (4, 2))
    dist = Disturbance.from_bounds(4, (0.05, 0.5), seed=1)

    def run(dt, torque):
        x = x0.copy()
        steps = int(round(0.4 / dt))
        for i in range(steps):
            x = rk4_step(x, torque, dist, i * dt, dt, k)
        return x

    ref = run(0.4 / 256, tau)
    e1 = np.max(np.abs(run(0.4 / 16, tau) - ref))
    e2 = np.max(np.abs(run(0.4 / 32, tau) - ref))
    assert 12.0 < e1 / e2 < 20.0  # ratio 2^4 = 16 for a 4th-order method

    def energy(x):
        return 0.5 * k.m_tilde * x[:, 3] ** 2 + 0.5 * k.I_tilde * x[:, 4] ** 2

    x = x0.copy()
    for i in range(500):
        x = rk4_step(x, np.zeros((4, 2)), None, i * 1e-3, 1e-3, k)
    np.testing.assert_allclose(energy(x), energy(x0), rtol=1e-9)


def test_commanded_accel_differs_from_true_accel_by_s1_g():
    rng = np.random.default_rng(5)
    k = _coeffs(5)
    x = _random_states(rng, 5)
    tau = rng.uniform(-0.1, 0.1, (5, 2))
    g = rng.uniform(-0.5, 0.5, (5, 2))
    diff = point_accel(x, tau, g, k) - commanded_point_accel(x, tau, k)
    np.testing.assert_allclose(diff, np.einsum('nij,nj->ni', s1(x[:, 2], k.d), g), atol=1e-14)


def test_disturbance_is_bounded_smooth_and_deterministic():
    bound = np.array([0.05, 0.5])
    dist = Disturbance.from_bounds(20, bound, seed=7)
    ts = np.linspace(0.0, 60.0, 6001)
    g = np.stack([dist(t) for t in ts])  # (T, N, 2)
    assert np.all(np.abs(g) <= bound + 1e-15)
    assert np.max(np.abs(g[..., 0])) > 0.6 * bound[0]  # not trivially small
    assert (
        np.max(np.abs(np.diff(g, axis=0))) / 0.01 < 2 * np.pi * 1.0 * 0.5 + 1e-9
    )  # |g'| <= 2 pi f A
    again = Disturbance.from_bounds(20, bound, seed=7)
    np.testing.assert_array_equal(again(12.3), dist(12.3))
    assert not np.allclose(Disturbance.from_bounds(20, bound, seed=8)(12.3), dist(12.3))
    np.testing.assert_allclose(dist.bound, np.broadcast_to(bound, (20, 2)), rtol=1e-12)
    assert np.all(Disturbance.zero(3)(4.0) == 0.0)
    np.testing.assert_array_equal(dist.take([2, 5])(1.5), dist(1.5)[[2, 5]])
    with pytest.raises(ConfigError, match='^bound: must be finite and >= 0'):
        Disturbance.from_bounds(2, (-0.1, 0.5), seed=0)


def test_kernels_match_numpy_dynamics():
    rng = np.random.default_rng(11)
    n = 200
    k = _random_coeffs(rng, n)
    x = _random_states(rng, n)
    tau = rng.uniform(-0.15, 0.15, (n, 2))
    dist = Disturbance.from_bounds(n, (0.05, 0.5), seed=3)
    t, dt = 2.345, 1e-3
    g0, gh, g1 = dist(t), dist(t + 0.5 * dt), dist(t + dt)
    for i in range(n):
        np.testing.assert_allclose(
            kn.disturbance_k(t, dist.amplitude[i], dist.freq_hz[i], dist.phase_rad[i]),
            g0[i],
            rtol=0,
            atol=1e-15,
        )
    ref_xd = state_derivative(x, tau, g0, k)
    ref_pv = point_velocity(x, k.d)
    ref_acc = commanded_point_accel(x, tau, k)
    co = (k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c)
    for i in range(n):
        c = tuple(a[i] for a in co)
        xd = kn.state_derivative_k(*x[i], *tau[i], *g0[i], *c)
        np.testing.assert_allclose(xd, ref_xd[i], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(
            kn.point_velocity_k(x[i, 2], x[i, 3], x[i, 4], k.d[i]),
            ref_pv[i],
            rtol=1e-12,
            atol=1e-15,
        )
        np.testing.assert_allclose(
            kn.commanded_point_accel_k(x[i, 2], x[i, 3], x[i, 4], *tau[i], *c),
            ref_acc[i],
            rtol=1e-12,
            atol=1e-15,
        )
    ref = rk4_step(x, tau, dist, t, dt, k)
    out = kn.rk4_step_all(x.copy(), tau, g0, gh, g1, dt, *co, np.empty_like(x))
    np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-15)


def test_disturbance_at_times_is_the_sum_of_sinusoids():
    """Disturbance.at_times / __call__ (disturbance_k over a grid) against the numpy formula."""
    dist = Disturbance.from_bounds(5, (0.05, 0.5), seed=3)
    t = np.linspace(0.0, 30.0, 301)
    oracle = np.sum(
        dist.amplitude[None]
        * np.sin(2 * np.pi * dist.freq_hz[None] * t[:, None, None, None] + dist.phase_rad[None]),
        axis=3,
    )
    np.testing.assert_allclose(dist.at_times(t), oracle, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(dist(t[17]), dist.at_times(t)[17])


def test_phasor_disturbance_kernels_track_the_exact_disturbance():
    dist = Disturbance.from_bounds(3, (0.05, 0.5), seed=9)
    dt = 1e-3
    cos_h, sin_h = dist.step_rotation(0.5 * dt)
    s_st = np.empty((3, 2, 4))
    c_st = np.empty((3, 2, 4))
    t0 = 1.25
    for i in range(3):
        kn.disturbance_phasor_init_k(t0, dist.freq_hz[i], dist.phase_rad[i], s_st[i], c_st[i])
    worst = 0.0
    for step in range(1, 20001):  # 10 s in half steps
        t = t0 + 0.5 * dt * step
        g = np.array(
            [
                kn.disturbance_phasor_advance_k(
                    dist.amplitude[i], s_st[i], c_st[i], cos_h[i], sin_h[i]
                )
                for i in range(3)
            ]
        )
        if step % 500 == 0:
            worst = max(worst, np.max(np.abs(g - dist(t))))
    assert worst < 1e-12
