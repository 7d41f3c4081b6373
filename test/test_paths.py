"""Leader reference paths (S4): closed-form derivatives against finite differences, constant path
speed, bounded acceleration of the waypoint path.
"""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.paths import (
    HeldPath,
    LinePath,
    path_from_config,
    SinusoidPath,
    WaypointPath,
)


def _fd(path, t, h=1e-4):
    r1, v1, _ = path.reference(t + h)
    r0, v0, _ = path.reference(t - h)
    return (r1 - r0) / (2 * h), (v1 - v0) / (2 * h)


def test_paper_sinusoid_matches_spec_s4_formulas():
    p = SinusoidPath((0.0, 0.0), 0.2, math.pi, 0.05)
    t = np.linspace(0.0, 55.0, 2001)
    r, rd, rdd = p.reference(t)
    x = r[:, 0]
    k = 0.2 * math.pi
    xd = 0.05 / np.sqrt(1 + k**2 * np.cos(math.pi * x) ** 2)
    xdd = (
        0.05
        * k**2
        * math.pi
        * np.cos(math.pi * x)
        * np.sin(math.pi * x)
        * xd
        / (1 + k**2 * np.cos(math.pi * x) ** 2) ** 1.5
    )
    np.testing.assert_allclose(r[:, 1], 0.2 * np.sin(math.pi * x), atol=1e-15)
    np.testing.assert_allclose(rd[:, 0], xd, atol=1e-15)
    np.testing.assert_allclose(rd[:, 1], k * np.cos(math.pi * x) * xd, atol=1e-15)
    np.testing.assert_allclose(rdd[:, 0], xdd, atol=1e-15)
    np.testing.assert_allclose(
        rdd[:, 1],
        -0.2 * math.pi**2 * np.sin(math.pi * x) * xd**2 + k * np.cos(math.pi * x) * xdd,
        atol=1e-15,
    )
    np.testing.assert_allclose(np.linalg.norm(rd, axis=1), 0.05, atol=1e-14)  # constant path speed
    # arc length travelled equals v0 t (trapezoid on a fine grid)
    tf = np.linspace(0.0, 20.0, 40001)
    rf, _, _ = p.reference(tf)
    assert np.sum(np.linalg.norm(np.diff(rf, axis=0), axis=1)) == pytest.approx(
        0.05 * 20.0, rel=1e-7
    )
    assert p.reference(0.0)[0] == pytest.approx([0.0, 0.0], abs=1e-15)


@settings(max_examples=40, deadline=None)
@given(
    amp=st.floats(0.0, 0.5),
    k=st.floats(0.5, 8.0),
    v=st.floats(0.01, 0.3),
    heading=st.floats(-math.pi, math.pi),
    t=st.floats(-30.0, 200.0),
)
@example(amp=0.5, k=8.0, v=0.25, heading=0.0, t=42.0)  # failed the plain difference's tolerance
@example(amp=0.5, k=7.0, v=0.25, heading=0.0, t=11.0)
def test_sinusoid_derivatives_match_finite_differences(amp, k, v, heading, t):
    p = SinusoidPath((0.3, -0.1), amp, k, v, heading)
    r, rd, rdd = p.reference(t)
    # Richardson-extrapolated central differences (error O(h^4)): the plain O(h^2) difference
    # misses by ~h^2 |r'''| / 6, up to 7e-7 m/s for amp 0.5 m, k 8 rad/m, v 0.25 m/s
    (fv1, fa1), (fv2, fa2) = _fd(p, t, h=2e-3), _fd(p, t, h=1e-3)
    fd_v, fd_a = (4 * fv2 - fv1) / 3, (4 * fa2 - fa1) / 3
    assert np.allclose(rd, fd_v, atol=1e-8)
    assert np.allclose(rdd, fd_a, atol=1e-7)
    assert np.linalg.norm(rd) == pytest.approx(v, rel=1e-12)
    # scalar and array evaluation agree
    ra, _, _ = p.reference(np.array([t, t]))
    np.testing.assert_allclose(ra[0], r, atol=1e-12)


def test_line_path():
    p = LinePath((4.2, 0.4), math.pi, 0.05)
    r, rd, rdd = p.reference(46.0)
    np.testing.assert_allclose(r, [4.2 - 2.3, 0.4], atol=1e-12)
    np.testing.assert_allclose(rd, [-0.05, 0.0], atol=1e-15)
    np.testing.assert_array_equal(rdd, [0.0, 0.0])


def test_waypoints_bounded_acceleration_c1_and_stop_at_the_end():
    p = WaypointPath(((0, 0), (1, 0), (1, 1), (2, 1.5)), speed_mps=0.05, accel_mps2=0.02)
    t = np.linspace(-2.0, p.arrival_time_s + 5.0, 40001)
    r, rd, rdd = p.reference(t)
    assert np.linalg.norm(rdd, axis=1).max() <= 0.02 + 1e-12
    assert np.linalg.norm(rdd, axis=1).max() >= 0.02 - 1e-12  # the bound is used in the turns
    np.testing.assert_allclose(r[0], [-0.1, 0.0], atol=1e-12)  # before t = 0: back along segment 0
    np.testing.assert_allclose(r[-1], [2.0, 1.5], atol=1e-12)  # rests on the last waypoint
    np.testing.assert_allclose(rd[-1], [0.0, 0.0], atol=1e-15)
    # continuous position and velocity (C1): no jumps larger than the grid step allows
    dt = t[1] - t[0]
    assert np.abs(np.diff(r, axis=0)).max() <= 0.05 * dt + 1e-12
    assert np.abs(np.diff(rd, axis=0)).max() <= 0.02 * dt + 1e-9
    # velocity is the derivative of position, acceleration of velocity (away from arc joints)
    fd_v, _ = _fd(p, t[::97], h=1e-5)
    np.testing.assert_allclose(rd[::97], fd_v, atol=1e-6)
    # passes within R tan(turn/2)-rounded corners: the corner (1, 0) is missed by R (sqrt2 - 1)
    radius = 0.05**2 / 0.02
    d_corner = np.linalg.norm(r - [1.0, 0.0], axis=1).min()
    assert d_corner == pytest.approx(radius * (math.sqrt(2) - 1), rel=1e-3)


def test_a_held_path_stops_at_its_end_time_and_rests_there():
    base = SinusoidPath((0.0, 0.0), 0.1, 3.0, 0.05)
    held = HeldPath(base, 10.0)
    t = np.array([-1.0, 3.0, 10.0, 10.001, 25.0])
    r, rd, rdd = held.reference(t)
    r0, rd0, rdd0 = base.reference(t[:3])
    np.testing.assert_array_equal(r[:3], r0)  # the path itself up to its end time
    np.testing.assert_array_equal(rd[:3], rd0)
    np.testing.assert_array_equal(rdd[:3], rdd0)
    end, _, _ = base.reference(10.0)
    np.testing.assert_allclose(r[3:], [end, end], atol=1e-15)  # then at rest at r(t_end)
    np.testing.assert_array_equal(rd[3:], 0.0)
    np.testing.assert_array_equal(rdd[3:], 0.0)
    for k, tk in enumerate(t):  # scalar times agree with the rows
        rs, rds, rdds = held.reference(float(tk))
        assert rs.shape == rds.shape == rdds.shape == (2,)
        np.testing.assert_allclose(rs, r[k], atol=1e-12)
        np.testing.assert_allclose(rds, rd[k], atol=1e-12)
        np.testing.assert_allclose(rdds, rdd[k], atol=1e-12)


def test_a_path_with_stop_s_is_held_and_written_back_with_it():
    from ament_formation.core.scenario.loader import _path_to_mapping

    cfg = {'type': 'line', 'start_m': [0, 0], 'heading_rad': 0.0, 'speed_mps': 0.05, 'stop_s': 8}
    p = path_from_config(cfg)
    assert isinstance(p, HeldPath) and isinstance(p.path, LinePath) and p.t_end_s == 8.0
    np.testing.assert_allclose(p.reference(20.0)[0], [0.4, 0.0], atol=1e-12)
    assert path_from_config(_path_to_mapping(p)) == p
    refused = ((-1, 'must be >= 0'), ('soon', 'must be a number'), (math.nan, 'must be finite'))
    for bad, what in refused:
        with pytest.raises(ConfigError, match=f'stop_s: {what}'):
            path_from_config({**cfg, 'stop_s': bad})


def test_path_from_config_and_errors():
    p = path_from_config({'type': 'waypoints', 'points_m': [[0, 0], [2, 0]], 'speed_mps': 0.05})
    assert isinstance(p, WaypointPath) and p.length_m == pytest.approx(2.0)
    with pytest.raises(ConfigError, match="type: unknown path type 'circle'"):
        path_from_config({'type': 'circle'})
    with pytest.raises(ConfigError, match='amplitude_m: must be a number'):
        path_from_config(
            {
                'type': 'sinusoid',
                'start_m': [0, 0],
                'amplitude_m': 'big',
                'wavenumber_radpm': 3.0,
                'speed_mps': 0.05,
            }
        )
    with pytest.raises(ConfigError, match=r'points_m\[2\]: repeats the previous point'):
        WaypointPath(((0, 0), (1, 0), (1, 0)), 0.05)
    with pytest.raises(ConfigError, match='reverses'):
        WaypointPath(((0, 0), (1, 0), (0, 0)), 0.05)
