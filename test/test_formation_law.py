"""Coordination mode (S4): Phi/DPhi, leader and follower fields, closed-loop formation keeping."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from kernel_set import kn
import numpy as np
from oracle_dynamics import point_velocity
from oracle_formation import (
    dphi,
    follower_field,
    leader_field,
    phi,
    tracking_field,
)
from oracle_smc import sliding_mode_torque

from ament_formation.core.model.disturbance import Disturbance
from ament_formation.core.model.dynamics import PlantCoeffs, RobotPlant
from ament_formation.core.params import ControlGains, RobotParams

GAINS = ControlGains()
SEEDS = st.integers(0, 2**31 - 1)


@settings(max_examples=30, deadline=None)
@given(seed=SEEDS, alpha=st.floats(0.1, 3.0), v_cap=st.floats(0.01, 0.5))
def test_phi_bounded_and_dphi_is_its_jacobian(seed, alpha, v_cap):
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(32, 2)) * rng.choice([1e-3, 0.1, 3.0], (32, 1))
    f = phi(e, alpha, v_cap)
    assert np.all(np.linalg.norm(f, axis=1) < v_cap)
    h = 1e-4 * v_cap / alpha  # well inside the scale v_cap/alpha of the nonlinearity
    fd = np.stack(
        [
            (phi(e + h * ev, alpha, v_cap) - phi(e - h * ev, alpha, v_cap)) / (2 * h)
            for ev in np.eye(2)
        ],
        axis=-1,
    )  # (N, 2, 2) columns d/de_j
    jac = dphi(e, alpha, v_cap)
    assert np.max(np.abs(jac - fd)) < 1e-7 * alpha
    np.testing.assert_allclose(jac, np.swapaxes(jac, 1, 2), atol=1e-15)  # symmetric
    small = phi(np.array([[1e-8, -2e-8]]), alpha, v_cap)  # linear for small e: Phi ~ alpha e
    np.testing.assert_allclose(small, alpha * np.array([[1e-8, -2e-8]]), rtol=1e-9)


def _poly(rng, n):
    return (
        rng.uniform(-1, 1, (n, 2)),
        rng.uniform(-0.1, 0.1, (n, 2)),
        rng.uniform(-0.1, 0.1, (n, 2)),
        rng.uniform(-0.1, 0.1, (n, 2)),
    )


def _eval(c, t):
    a0, a1, a2, a3 = c
    return (
        a0 + a1 * t + a2 * t**2 + a3 * t**3,
        a1 + 2 * a2 * t + 3 * a3 * t**2,
        2 * a2 + 6 * a3 * t,
    )


@settings(max_examples=20, deadline=None)
@given(seed=SEEDS)
def test_leader_and_follower_v_d_dot_are_total_derivatives(seed):
    rng = np.random.default_rng(seed)
    n = 32
    p_i, r, p_j = _poly(rng, n), _poly(rng, n), _poly(rng, n)
    delta = rng.uniform(-1, 1, (n, 2))
    h = 1e-4

    def lead(t):
        p, pd, _ = _eval(p_i, t)
        rr, rd, rdd = _eval(r, t)
        return leader_field(p, pd, rr, rd, rdd, GAINS)

    def follow(t):
        p, pd, _ = _eval(p_i, t)
        q, qd, qdd = _eval(p_j, t)
        return follower_field(p, pd, q, qd, qdd, delta, GAINS)

    for fn in (lead, follow):
        vd = [fn(s * h)[0] for s in (-2, -1, 1, 2)]
        fd = (vd[0] - 8 * vd[1] + 8 * vd[2] - vd[3]) / (12 * h)
        exact = fn(0.0)[1]
        assert np.max(np.abs(exact - fd)) < 1e-9
    # the follower field is the leader field with the parent slot as reference
    p, pd, _ = _eval(p_i, 0.0)
    q, qd, qdd = _eval(p_j, 0.0)
    lf = leader_field(p, pd, q + delta, qd, qdd, GAINS)
    ff = follower_field(p, pd, q, qd, qdd, delta, GAINS)
    np.testing.assert_allclose(lf[0], ff[0], atol=1e-15)
    np.testing.assert_allclose(lf[1], ff[1], atol=1e-15)


def test_kernel_matches_numpy_tracking_field():
    rng = np.random.default_rng(2)
    n = 300
    args = [rng.normal(size=(n, 2)) * s for s in (0.5, 0.1, 0.1, 0.1)]
    alpha = rng.uniform(0.1, 2, n)
    v_cap = rng.uniform(0.01, 0.3, n)
    v_d, v_d_dot = tracking_field(*args, alpha, v_cap)
    for i in range(n):
        res = kn.tracking_field_k(*(a[i, j] for a in args for j in range(2)), alpha[i], v_cap[i])
        np.testing.assert_allclose(res[:2], v_d[i], rtol=1e-12, atol=1e-16)
        np.testing.assert_allclose(res[2:], v_d_dot[i], rtol=1e-12, atol=1e-16)


def test_closed_loop_leader_follower_formation_converges():
    """Leader on a circle-like reference and a follower at offset (0, 1.2) m under disturbance:
    both errors settle below 1 cm (S4 with S3.2), torques stay below the limit.
    """
    k = PlantCoeffs.from_params([RobotParams()] * 2)
    dist = Disturbance.from_bounds(2, (0.05, 0.5), seed=4)
    dt, t_end = 2e-3, 30.0
    delta = np.array([0.0, 1.2])
    om = 0.05

    def ref(t):
        r = np.array([[t * 0.04, 0.2 * np.sin(om * t)]])
        rd = np.array([[0.04, 0.2 * om * np.cos(om * t)]])
        rdd = np.array([[0.0, -0.2 * om * om * np.sin(om * t)]])
        return r, rd, rdd

    x = np.array([[0.05, -0.05, 0.3, 0.0, 0.0], [-0.1, 1.05, -0.2, 0.0, 0.0]])
    co = [(k.m_tilde[i], k.I_tilde[i], k.r[i], k.a[i], k.d[i], k.m_c[i]) for i in range(2)]
    kk, eps = GAINS.switching_gain_mps2, GAINS.boundary_layer_mps
    al, vc = GAINS.formation_gain_per_s, GAINS.formation_speed_cap_mps
    peak = 0.0
    errs = []
    # the numpy law (checked against these kernels elsewhere) is run for the first second too
    for i in range(int(t_end / dt)):
        t = i * dt
        r, rd, rdd = ref(t)
        pl = kn.point_velocity_k(x[0, 2], x[0, 3], x[0, 4], co[0][4])
        pf = kn.point_velocity_k(x[1, 2], x[1, 3], x[1, 4], co[1][4])
        vl = kn.tracking_field_k(
            x[0, 0] - r[0, 0], x[0, 1] - r[0, 1], *rd[0], *rdd[0], *pl, al, vc
        )
        tl = kn.smc_torque_k(
            x[0, 2], x[0, 3], x[0, 4], *vl, RobotPlant(*co[0]), k.tau_max[0], kk, kk, eps
        )
        vf = kn.tracking_field_k(
            x[1, 0] - x[0, 0] - delta[0],
            x[1, 1] - x[0, 1] - delta[1],
            *pl,
            tl[5],
            tl[6],
            *pf,
            al,
            vc,
        )
        tf = kn.smc_torque_k(
            x[1, 2], x[1, 3], x[1, 4], *vf, RobotPlant(*co[1]), k.tau_max[1], kk, kk, eps
        )
        torque = np.array([[tl[0], tl[1]], [tf[0], tf[1]]])
        if t < 1.0:
            pd = point_velocity(x, k.d)
            nl = sliding_mode_torque(
                x[:1], *leader_field(x[:1, :2], pd[:1], r, rd, rdd, GAINS), k.take([0]), GAINS
            )
            nf = sliding_mode_torque(
                x[1:],
                *follower_field(
                    x[1:, :2], pd[1:], x[:1, :2], pd[:1], nl.accel_cmd_mps2, delta, GAINS
                ),
                k.take([1]),
                GAINS,
            )
            np.testing.assert_allclose(np.vstack((nl.torque_nm, nf.torque_nm)), torque, atol=1e-13)
        peak = max(peak, np.abs(torque).max())
        errs.append((np.linalg.norm(x[0, :2] - r[0]), np.linalg.norm(x[1, :2] - x[0, :2] - delta)))
        g0, gh, g1 = dist(t), dist(t + dt / 2), dist(t + dt)
        for j in range(2):
            x[j] = kn.rk4_step_k(
                tuple(x[j]),
                tuple(torque[j]),
                tuple(g0[j]),
                tuple(gh[j]),
                tuple(g1[j]),
                dt,
                RobotPlant(*co[j]),
            )
    errs = np.array(errs)
    assert errs[0].max() > 0.05
    settled = errs[int(20.0 / dt):]
    assert np.sqrt(np.mean(settled**2, axis=0)).max() < 0.01
    assert peak < 0.15
