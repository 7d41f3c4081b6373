"""Elliptical limit-cycle field (S6.2-S6.6), ray/segment tests (S8) and exact ellipse distance."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from kernel_set import kn
import numpy as np
from oracle_limit_cycle import (
    choose_direction,
    design_gains,
    eccentric_anomaly,
    ellipse_arc_length,
    ellipse_coeffs,
    ellipse_h,
    ellipse_h_dot,
    ellipse_perimeter,
    EllipseGains,
    field,
    gain_schedule,
    parking_factor,
    ray_hits_ellipse,
    segment_hits_ellipse,
)
import pytest

from ament_formation.core.model.ellipse import signed_distance_to_ellipse
from ament_formation.core.params import AvoidanceParams

SEEDS = st.integers(0, 2**31 - 1)
FEW = settings(max_examples=25, deadline=None)


def _ellipses(rng, n):
    r2 = rng.uniform(0.05, 0.5, n)
    r1 = r2 * rng.uniform(1.0, 4.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    return phi, r1, r2


def _motion(rng, n):
    """Random smooth motion: polynomial coefficients (value, rate, second rate) at t = 0."""
    m = {}
    m['p'] = (
        rng.uniform(-2, 2, (n, 2)),
        rng.uniform(-0.3, 0.3, (n, 2)),
        rng.uniform(-0.5, 0.5, (n, 2)),
    )
    m['x'] = (
        rng.uniform(-1, 1, (n, 2)),
        rng.uniform(-0.2, 0.2, (n, 2)),
        rng.uniform(-0.3, 0.3, (n, 2)),
    )
    m['phi'] = (
        rng.uniform(-np.pi, np.pi, n),
        rng.uniform(-0.5, 0.5, n),
        rng.uniform(-0.5, 0.5, n),
    )
    m['psi'] = (rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n))
    m['c'] = (rng.uniform(0.0, 0.2, n), rng.uniform(-0.1, 0.1, n), rng.uniform(-0.05, 0.05, n))
    return m


def _at(m, key, t):
    v0, v1, v2 = m[key]
    return v0 + v1 * t + 0.5 * v2 * t * t, v1 + v2 * t, v2


def _field_at(m, t, r1, r2):
    p, pd, _ = _at(m, 'p', t)
    x, xd, _ = _at(m, 'x', t)
    phi, phid, phidd = _at(m, 'phi', t)
    psi, psid, _ = _at(m, 'psi', t)
    c, cd, _ = _at(m, 'c', t)
    return field(p - x, pd - xd, phi, phid, phidd, r1, r2, psi, psid, c, cd)


@FEW
@given(seed=SEEDS)
def test_h_dot_on_surface_is_minus_2ch_h_plus_1(seed):
    """S6.3(c): along z_dot = F, h_dot = -2 c h (h + 1) for any psi_dot, phi_dot, x~_dot
    (c1 = c2).
    """
    rng = np.random.default_rng(seed)
    n = 64
    phi, r1, r2 = _ellipses(rng, n)
    z = rng.uniform(-3, 3, (n, 2)) * r1[:, None]
    phid = rng.uniform(-1, 1, n)
    psid = rng.uniform(-1, 1, n)
    c = rng.uniform(0.0, 0.5, n)
    out = field(z, np.zeros((n, 2)), phi, phid, 0.0, r1, r2, psid, 0.0, c, 0.0)
    on_surface = field(z, out.f, phi, phid, 0.0, r1, r2, psid, 0.0, c, 0.0)
    expected = -2.0 * c * out.h * (out.h + 1.0)
    scale = 1.0 + np.abs(expected) + np.abs(phid) * np.abs(out.h + 1) + np.abs(psid) * (out.h + 1)
    assert np.max(np.abs(on_surface.h_dot - expected) / scale) < 1e-11
    np.testing.assert_allclose(on_surface.h, ellipse_h(z, phi, r1, r2), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(
        on_surface.h_dot, ellipse_h_dot(z, out.f, phi, phid, r1, r2), atol=1e-12
    )
    # and the closed-form h_dot is the true rate of change of h(z(t), phi(t)) (rotating obstacle)
    zd = rng.uniform(-0.3, 0.3, (n, 2))
    dt = 1e-6
    hp = ellipse_h(z + dt * zd, phi + dt * phid, r1, r2)
    hm = ellipse_h(z - dt * zd, phi - dt * phid, r1, r2)
    np.testing.assert_allclose(
        ellipse_h_dot(z, zd, phi, phid, r1, r2), (hp - hm) / (2 * dt), rtol=1e-6, atol=1e-6
    )


@FEW
@given(seed=SEEDS)
def test_field_derivative_matches_finite_difference(seed):
    """S6.4: F_dot equals dF/dt along random motions (moving centre, phi_dot, phi_ddot, psi_ddot,
    c_dot).
    """
    rng = np.random.default_rng(seed)
    n = 64
    _, r1, r2 = _ellipses(rng, n)
    m = _motion(rng, n)
    h = 1e-3
    f = [_field_at(m, s * h, r1, r2).f for s in (-2, -1, 1, 2)]
    fd = (f[0] - 8 * f[1] + 8 * f[2] - f[3]) / (12 * h)  # 4th-order central difference
    exact = _field_at(m, 0.0, r1, r2).f_dot
    rel = np.linalg.norm(exact - fd, axis=1) / (np.linalg.norm(exact, axis=1) + 1e-3)
    assert np.max(rel) < 1e-6


def test_tangential_term_alone_keeps_h_and_traverses_ccw():
    """S6.3(a): with c = 0, phi_dot = 0 the field is tangent to the level sets; psi_dot > 0 is
    CCW.
    """
    rng = np.random.default_rng(1)
    n = 50
    phi, r1, r2 = _ellipses(rng, n)
    psi = rng.uniform(0, 2 * np.pi, n)
    kk = rng.uniform(0.5, 2.0, n)
    u, w = kk * r1 * np.cos(psi), kk * r2 * np.sin(psi)
    z = np.stack((np.cos(phi) * u - np.sin(phi) * w, np.sin(phi) * u + np.cos(phi) * w), axis=1)
    out = field(z, np.zeros((n, 2)), phi, 0.0, 0.0, r1, r2, 0.7, 0.0, 0.0, 0.0)
    # d/dpsi of the point, times psi_dot
    du, dw = -kk * r1 * np.sin(psi), kk * r2 * np.cos(psi)
    dz = np.stack(
        (np.cos(phi) * du - np.sin(phi) * dw, np.sin(phi) * du + np.cos(phi) * dw), axis=1
    )
    np.testing.assert_allclose(out.f, 0.7 * dz, atol=1e-12)
    assert np.all(z[:, 0] * out.f[:, 1] - z[:, 1] * out.f[:, 0] > 0)  # counter-clockwise
    h1, h2, h3 = ellipse_coeffs(phi, r1, r2)
    np.testing.assert_allclose(h2 * h3 - h1 * h1, (r1 * r2) ** 2, rtol=1e-12)


def test_closed_loop_on_field_converges_to_limit_cycle_without_entering():
    """Integrating z_dot = F around a moving, rotating ellipse: h stays > 0 from outside and
    -> 0.
    """
    rng = np.random.default_rng(4)
    n = 20
    phi0, r1, r2 = _ellipses(rng, n)
    ang = rng.uniform(0, 2 * np.pi, n)
    z = 2.5 * r1[:, None] * np.stack((np.cos(ang), np.sin(ang)), axis=1)
    h0 = ellipse_h(z, phi0, r1, r2)
    dt, c = 0.02, 0.2

    def rhs(t, zz):
        return field(zz, np.zeros((n, 2)), phi0 + 0.3 * t, 0.3, 0.0, r1, r2, 0.5, 0.0, c, 0.0).f

    h_min = np.inf
    for i in range(1000):  # RK4 of z_dot = F(t, z), 20 s
        t = i * dt
        k1 = rhs(t, z)
        k2 = rhs(t + dt / 2, z + dt / 2 * k1)
        k3 = rhs(t + dt / 2, z + dt / 2 * k2)
        k4 = rhs(t + dt, z + dt * k3)
        z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        h_min = min(h_min, ellipse_h(z, phi0 + 0.3 * (t + dt), r1, r2).min())
    h_end = ellipse_h(z, phi0 + 0.3 * 20.0, r1, r2)
    assert h_min > 0
    q = h0 / (1 + h0) * np.exp(-2 * c * 20.0)  # S6.3(c) closed-form solution
    np.testing.assert_allclose(h_end, q / (1 - q), rtol=1e-4)


def test_paper_gains_s6_5():
    av = AvoidanceParams()
    psi_max, c_max = design_gains(0.40, 0.15, av)
    assert round(float(psi_max), 3) == 0.297
    assert round(float(c_max), 3) == 0.054
    g = EllipseGains.design(0.40, 0.15, av)
    assert g.psi_dot_max_radps == pytest.approx(0.2969, abs=1e-4)
    assert g.c_max_per_s == pytest.approx(0.0541, abs=1e-4)
    # inward speed at the boundary of Q ~ v_rad (design rule)
    assert float(c_max) * 1.8 * np.sqrt(0.06) * ((1.8 / 1.1) ** 2 - 1) == pytest.approx(
        0.04, rel=1e-12
    )


def test_gain_schedule_values_and_derivatives():
    t = np.linspace(0.0, 8.0, 41)
    mu = 0.5 + 0.3 * np.sin(t)
    mu_dot = 0.3 * np.cos(t)
    psi, psi_dd, c, c_d = gain_schedule(t, 0.3, 0.05, -1.0, mu, mu_dot, beta0=0.3, tau_g_s=1.5)
    assert psi[0] == pytest.approx(-0.3 * 0.3 * mu[0])
    assert c[0] == pytest.approx(0.3 * 0.05)
    assert np.all(np.diff(c) > 0) and c[-1] < 0.05
    h = 1e-5
    pp = gain_schedule(t + h, 0.3, 0.05, -1.0, 0.5 + 0.3 * np.sin(t + h), 0, 0.3, 1.5)
    pm = gain_schedule(t - h, 0.3, 0.05, -1.0, 0.5 + 0.3 * np.sin(t - h), 0, 0.3, 1.5)
    np.testing.assert_allclose(psi_dd[1:], ((pp[0] - pm[0]) / (2 * h))[1:], atol=1e-8)
    np.testing.assert_allclose(c_d[1:], ((pp[2] - pm[2]) / (2 * h))[1:], atol=1e-8)
    for i in range(0, 41, 5):
        np.testing.assert_allclose(
            kn.gain_schedule_k(t[i], 0.3, 0.05, -1.0, mu[i], mu_dot[i], 0.3, 1.5),
            (psi[i], psi_dd[i], c[i], c_d[i]),
            rtol=1e-12,
            atol=1e-16,
        )


@FEW
@given(seed=SEEDS)
def test_parking_factor_range_and_derivative(seed):
    rng = np.random.default_rng(seed)
    n = 40
    m = _motion(rng, n)
    _, r1, r2 = _ellipses(rng, n)
    g = (rng.uniform(-2, 2, (n, 2)), rng.uniform(-0.2, 0.2, (n, 2)), np.zeros((n, 2)))
    s = rng.choice([-1.0, 1.0], n)

    def at(t):
        p, pd, _ = _at(m, 'p', t)
        x, xd, _ = _at(m, 'x', t)
        gg, gd, _ = g[0] + g[1] * t, g[1], 0
        phi, phid, _ = _at(m, 'phi', t)
        return parking_factor(p - x, pd - xd, gg - x, gd - xd, phi, phid, r1, r2, s, 0.5)

    mu, mu_dot = at(0.0)
    assert np.all(np.abs(mu) <= 1.0)
    h = 1e-6
    fd = (at(h)[0] - at(-h)[0]) / (2 * h)
    lin = np.abs(mu) < 0.99
    np.testing.assert_allclose(mu_dot[lin], fd[lin], rtol=1e-5, atol=1e-6)
    assert np.all(mu_dot[np.abs(mu) == 1.0] == 0.0)
    # kernel twin
    p, pd, _ = _at(m, 'p', 0.0)
    x, xd, _ = _at(m, 'x', 0.0)
    phi, phid, _ = _at(m, 'phi', 0.0)
    for i in range(n):
        res = kn.parking_factor_k(
            *(p[i] - x[i]),
            *(pd[i] - xd[i]),
            *(g[0][i] - x[i]),
            *(g[1][i] - xd[i]),
            phi[i],
            phid[i],
            r1[i],
            r2[i],
            s[i],
            0.5,
        )
        np.testing.assert_allclose(res, (mu[i], mu_dot[i]), rtol=1e-12, atol=1e-14)


def test_parking_factor_is_zero_at_goal_anomaly_and_positive_ahead():
    z = np.array([[1.0, 0.0]])
    goal_ahead = np.array([[0.0, 1.0]])  # 90 deg CCW
    mu, _ = parking_factor(z, 0 * z, goal_ahead, 0 * z, 0.0, 0.0, 1.0, 1.0, 1.0, 0.5)
    assert mu[0] == 1.0
    mu, _ = parking_factor(z, 0 * z, goal_ahead, 0 * z, 0.0, 0.0, 1.0, 1.0, -1.0, 0.5)
    assert mu[0] == -1.0  # goal behind for CW: back up towards it
    mu, _ = parking_factor(z, 0 * z, np.array([[2.0, 0.2]]), 0 * z, 0.0, 0.0, 1.0, 1.0, 1.0, 0.5)
    assert mu[0] == pytest.approx(np.arctan2(0.2, 2.0) / 0.5)


def test_choose_direction_rules():
    r1, r2, phi = 0.44, 0.165, 0.0
    # goal straight behind, agent slightly above the axis moving +x: tie -> continue the motion
    # (CW)
    z = np.array([[-1.0, 0.1], [-1.0, -0.1]])
    zd = np.array([[0.05, 0.0], [0.05, 0.0]])
    goal = np.array([[1.0, 0.0], [1.0, 0.0]])
    gd = np.array([[0.05, 0.0], [0.05, 0.0]])
    s = choose_direction(z, zd, goal, gd, np.zeros((2, 2)), phi, r1, r2, 1.44)
    np.testing.assert_array_equal(s, [-1.0, 1.0])
    # rule 7: yielding agents resolve ties to +1
    s = choose_direction(
        z, zd, goal, gd, np.zeros((2, 2)), phi, r1, r2, 1.44, velocity_tie_break=False
    )
    np.testing.assert_array_equal(s, [1.0, 1.0])
    # clear preference: goal well above -> CW from the left side (over the top), below -> CCW
    goal = np.array([[0.3, 1.0], [0.3, -1.0]])
    s = choose_direction(
        np.array([[-1.0, 0.0]] * 2),
        zd,
        goal,
        np.zeros((2, 2)),
        np.zeros((2, 2)),
        phi,
        r1,
        r2,
        1.44,
    )
    np.testing.assert_array_equal(s, [-1.0, 1.0])
    # rule 1 look-ahead: a goal above the obstacle but moving down fast is taken below it
    args = (
        np.array([[-1.0, 0.05]]),
        np.array([[0.05, 0.0]]),
        np.array([[0.3, 0.5]]),
        np.array([[0.0, -0.1]]),
        np.zeros((1, 2)),
        phi,
        r1,
        r2,
    )
    assert choose_direction(*args, 0.0)[0] == -1.0
    assert choose_direction(*args, 2 * 1.8 * 0.4)[0] == 1.0
    # a moving obstacle: only the goal velocity relative to the centre counts
    args = args[:4] + (np.array([[0.0, -0.1]]),) + args[5:]
    assert choose_direction(*args, 2 * 1.8 * 0.4)[0] == -1.0
    assert ellipse_perimeter(1.0, 1.0) == pytest.approx(2 * np.pi, rel=1e-13)
    assert ellipse_perimeter(0.44, 0.165) == pytest.approx(2.0001774530742, rel=1e-10)


@settings(max_examples=10, deadline=None)
@given(seed=SEEDS)
def test_ray_and_segment_tests_agree_with_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = 60
    phi, r1, r2 = _ellipses(rng, n)
    z = rng.uniform(-3, 3, (n, 2)) * r1[:, None]
    zd = rng.normal(size=(n, 2))
    hit, lam = ray_hits_ellipse(z, zd, phi, r1, r2)
    lams = np.linspace(0.0, 20.0, 8001)
    pts = z[:, None, :] + lams[None, :, None] * zd[:, None, :]
    hh = ellipse_h(pts, phi[:, None], r1[:, None], r2[:, None])
    brute_lam = np.where((hh <= 0).any(axis=1), lams[np.argmax(hh <= 0, axis=1)], np.inf)
    far = 3 * 3 * r1 / np.linalg.norm(zd, axis=1) * 2 < 20.0
    grazing = np.abs(hh.min(axis=1)) < 1e-3
    ok = far & ~grazing
    np.testing.assert_array_equal(hit[ok], np.isfinite(brute_lam)[ok])
    both = ok & hit
    assert np.all(np.abs(lam[both] - brute_lam[both]) <= 20.0 / 8000 + 1e-12)
    h_contact = ellipse_h(z[both] + lam[both, None] * zd[both], phi[both], r1[both], r2[both])
    np.testing.assert_allclose(h_contact * (lam[both] > 0), 0.0, atol=1e-9)
    m = 400  # segments: enough that hits and misses both appear for every seed
    sphi, sr1, sr2 = _ellipses(rng, m)
    p0 = rng.uniform(-2, 2, (m, 2))
    p1 = rng.uniform(-2, 2, (m, 2))
    center = rng.uniform(-0.5, 0.5, (m, 2))
    seg = segment_hits_ellipse(p0, p1, center, sphi, sr1, sr2)
    s = np.linspace(0.0, 1.0, 2001)
    pts = p0[:, None, :] + s[None, :, None] * (p1 - p0)[:, None, :] - center[:, None, :]
    hh = ellipse_h(pts, sphi[:, None], sr1[:, None], sr2[:, None])
    clear = np.abs(hh.min(axis=1)) > 1e-3
    np.testing.assert_array_equal(seg[clear], (hh.min(axis=1) <= 0)[clear])
    assert 0.1 < seg.mean() < 0.9
    for i in range(0, n, 3):
        rl = kn.ray_time(*z[i], *zd[i], phi[i], r1[i], r2[i])
        assert (rl < np.inf) == hit[i]
        assert rl == lam[i] or abs(rl - lam[i]) <= 1e-9 * max(1.0, lam[i])
        hits = kn.segment_hits(*p0[i], *p1[i], *center[i], sphi[i], sr1[i], sr2[i])
        assert hits == seg[i]


@settings(max_examples=8, deadline=None)
@given(seed=SEEDS)
def test_signed_distance_matches_brute_force_sampling(seed):
    rng = np.random.default_rng(seed)
    k = 300
    phi, r1, r2 = _ellipses(rng, 1)
    center = rng.uniform(-1, 1, 2)
    pts = center + rng.uniform(-2.5, 2.5, (k, 2)) * r1[0]
    pts[:10] = center  # centre and on-axis special cases
    pts[10:20, 1] = center[1]
    d = signed_distance_to_ellipse(pts, center, phi[0], r1[0], r2[0])
    c, s = np.cos(phi[0]), np.sin(phi[0])

    def nearest(psi):  # (K, S) anomalies -> (K,) min distance to those boundary samples
        bx, by = r1[0] * np.cos(psi), r2[0] * np.sin(psi)
        gx = center[0] + c * bx - s * by
        gy = center[1] + s * bx + c * by
        dist = np.hypot(pts[:, 0, None] - gx, pts[:, 1, None] - gy)
        return dist.min(axis=1), psi[np.arange(k), dist.argmin(axis=1)]

    coarse = np.broadcast_to(np.linspace(0, 2 * np.pi, 4001), (k, 4001))
    _, best = nearest(coarse)
    step = 2 * np.pi / 4000
    brute, _ = nearest(best[:, None] + np.linspace(-2 * step, 2 * step, 4001)[None, :])
    inside = ellipse_h(pts - center, phi[0], r1[0], r2[0]) < 0
    np.testing.assert_array_equal(d < 0, inside)
    assert np.all(np.abs(d) <= brute + 1e-12)  # exact is never farther than a sample
    assert np.max(brute - np.abs(d)) < 1e-7  # and sampling converges to it
    # centre: distance is the minor semi-axis
    np.testing.assert_allclose(d[:10], -min(r1[0], r2[0]), rtol=1e-12)


def test_kernel_field_matches_numpy():
    rng = np.random.default_rng(9)
    n = 300
    phi, r1, r2 = _ellipses(rng, n)
    args = (
        rng.uniform(-2, 2, (n, 2)),
        rng.uniform(-0.3, 0.3, (n, 2)),
        phi,
        rng.uniform(-1, 1, n),
        rng.uniform(-1, 1, n),
        r1,
        r2,
        rng.uniform(-1, 1, n),
        rng.uniform(-1, 1, n),
        rng.uniform(0, 0.5, n),
        rng.uniform(-0.1, 0.1, n),
    )
    out = field(*args)
    z, zd = args[0], args[1]
    for i in range(n):
        res = kn.ellipse_field_k(*z[i], *zd[i], *(a[i] for a in args[2:]))
        np.testing.assert_allclose(res[0:2], out.f[i], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(res[2:4], out.f_dot[i], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(res[4:6], (out.h[i], out.h_dot[i]), rtol=1e-12, atol=1e-14)
        assert kn.h_value(*z[i], phi[i], r1[i], r2[i]) == pytest.approx(
            out.h[i], rel=1e-12, abs=1e-14
        )


@FEW
@given(seed=SEEDS)
def test_compiled_gain_design_and_direction_match_the_oracle(seed):
    """S6.5/S6.6 as the switching runs them (core/control/limit_cycle.py) against the numpy
    oracle: the same gains; the same rotation sense wherever the arc lengths are not within
    quadrature error of the rule-3 margin (the kernel's 64-node midpoint rule and the oracle's
    Gauss-Legendre agree to 2e-3 of the perimeter on eccentric ellipses).
    """
    from ament_formation.core.control import limit_cycle as lc
    from ament_formation.core.control.law_params import LawParams

    rng = np.random.default_rng(seed)
    law = LawParams()
    av, prm = law.avoidance, law.compiled()
    n = 40
    phi, r1, r2 = _ellipses(rng, n)
    for i in range(n):
        assert lc.design_gains(r1[i], r2[i], av.tangential_speed_mps, prm) == pytest.approx(
            design_gains(r1[i], r2[i], av), rel=1e-14
        )
    big1, big2 = av.limit_cycle_scale * r1, av.limit_cycle_scale * r2
    for i in range(n):
        psi0, dpsi = rng.uniform(-np.pi, np.pi), rng.uniform(0, 2 * np.pi)
        assert lc.arc_length(psi0, dpsi, big1[i], big2[i]) == pytest.approx(
            float(ellipse_arc_length(psi0, dpsi, big1[i], big2[i])),
            abs=2e-3 * float(ellipse_perimeter(big1[i], big2[i])),
        )
    z = rng.uniform(-1.6, 1.6, (n, 2)) * r1[:, None]
    zd = rng.normal(size=(n, 2)) * 0.05
    goal = rng.uniform(-3, 3, (n, 2))
    gd = rng.normal(size=(n, 2)) * 0.05
    cv = rng.normal(size=(n, 2)) * 0.02
    look = 2 * av.protected_scale * r1
    for tie in (True, False):
        want = choose_direction(z, zd, goal, gd, cv, phi, big1, big2, look, tie)
        for i in range(n):
            rel = gd[i] - cv[i]
            sp = float(np.hypot(*rel))
            g_la = goal[i] + (look[i] / sp * rel if sp > 1e-9 else 0.0)
            psi_a = float(eccentric_anomaly(z[i][None], phi[i], big1[i], big2[i])[0])
            psi_g = float(eccentric_anomaly(g_la[None], phi[i], big1[i], big2[i])[0])
            per = float(ellipse_perimeter(big1[i], big2[i]))
            lp = float(ellipse_arc_length(psi_a, (psi_g - psi_a) % (2 * np.pi), big1[i], big2[i]))
            if abs(abs(2 * lp - per) - 0.1 * per) < 1e-2 * per:
                continue  # a tie within quadrature error of the rule-3 margin
            got = lc.choose_direction(
                *z[i], *zd[i], *goal[i], *rel, phi[i], big1[i], big2[i], look[i], tie
            )
            assert got == want[i], i
