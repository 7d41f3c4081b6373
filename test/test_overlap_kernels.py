"""The validator's geometry kernels against their plain definitions.

* ``ellipses_overlap`` (a kernel that stops at the first sample inside and skips pairs a line
  separates) says what the sampled definition says: a boundary sample of one ellipse
  (``boundary_points``) or a centre lies in the other (``points_inside``).
* The limit-cycle check S13 #3 (``loader._check_limit_cycles``: boxes, then bounding circles, then
  the kernel) names the same pair at the same instant as testing every pair at every instant.
* ``convex_hull`` is the convex hull.
* Obstacles that move near each other for longer than the check's budget are refused in one
  short line, before any large allocation.
"""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import (
    boundary_points,
    convex_hull,
    ellipses_overlap,
    points_inside,
)
from ament_formation.core.model.obstacles import ObstacleField, ObstacleSpec
from ament_formation.core.params import AvoidanceParams
from ament_formation.core.scenario import loader

MAX_LINE_CHARS = 300


def sampled_overlap(c1, phi1, axes1, c2, phi2, axes2) -> np.ndarray:
    """The definition, in numpy: every sample of both boundaries and both centres tested."""
    hit = np.any(points_inside(boundary_points(c1, phi1, axes1), c2, phi2, axes2), axis=1)
    hit |= np.any(points_inside(boundary_points(c2, phi2, axes2), c1, phi1, axes1), axis=1)
    hit |= points_inside(c1[:, None, :], c2, phi2, axes2)[:, 0]
    hit |= points_inside(c2[:, None, :], c1, phi1, axes1)[:, 0]
    return hit


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), thin=st.booleans())
def test_the_overlap_kernel_says_what_the_sampled_definition_says(seed, thin):
    rng = np.random.default_rng(seed)
    k = 2000
    c1, c2 = rng.uniform(-1, 1, (k, 2)), rng.uniform(-1, 1, (k, 2))
    a1, a2 = rng.uniform(0.02, 0.8, (k, 2)), rng.uniform(0.02, 0.8, (k, 2))
    if thin:  # slats: separated by a line far more often, and touching at shallow angles
        a1[:, 1], a2[:, 1] = 0.01, 0.01
    p1, p2 = rng.uniform(-4, 4, k), rng.uniform(-4, 4, k)
    want = sampled_overlap(c1, p1, a1, c2, p2, a2)
    assert 0 < want.sum() < k  # both answers drawn
    np.testing.assert_array_equal(ellipses_overlap(c1, p1, a1, c2, p2, a2), want)


@pytest.mark.parametrize('scale', [1.0 - 1e-12, 1.0, 1.0 + 1e-12])
def test_the_overlap_kernel_agrees_where_two_ellipses_touch(scale):
    """Centres r1 + r1' apart on the major axes: the boundaries touch at a sample point, where
    rounding decides; the kernel's separation test must not decide it differently.
    """
    rng = np.random.default_rng(7)
    k = 5000
    a1, a2 = rng.uniform(0.05, 0.8, (k, 2)), rng.uniform(0.05, 0.8, (k, 2))
    zero = np.zeros(k)
    c2 = np.column_stack([(a1[:, 0] + a2[:, 0]) * scale, zero])
    want = sampled_overlap(np.zeros((k, 2)), zero, a1, c2, zero, a2)
    got = ellipses_overlap(np.zeros((k, 2)), zero, a1, c2, zero, a2)
    np.testing.assert_array_equal(got, want)


def _every_pair_every_instant(obstacles, avoidance, duration_s):
    """S13 #3 the plain way: (a, b, first instant or None when both stand still) of the first
    pair, in index order, whose limit cycles overlap; None if none does.
    """
    fld = ObstacleField(obstacles)
    dynamic = [o.moves or o.rotates for o in obstacles]
    times = np.arange(0.0, duration_s + loader._OVERLAP_STEP_S, loader._OVERLAP_STEP_S)
    times[-1] = min(times[-1], duration_s)
    states = [fld.at(float(t)) for t in times]
    centres = np.stack([s.center_m for s in states])
    phis = np.stack([s.phi_rad for s in states])
    axes = np.asarray([o.semi_axes_m for o in obstacles]) * avoidance.limit_cycle_scale
    for a in range(len(obstacles)):
        for b in range(a + 1, len(obstacles)):
            n = len(times) if dynamic[a] or dynamic[b] else 1
            hit = sampled_overlap(
                centres[:n, a],
                phis[:n, a],
                np.repeat(axes[a:a + 1], n, 0),
                centres[:n, b],
                phis[:n, b],
                np.repeat(axes[b:b + 1], n, 0),
            )
            if hit.any():
                return a, b, (float(times[np.argmax(hit)]) if n > 1 else None)
    return None


def _random_obstacles(rng) -> list[ObstacleSpec]:
    obstacles = []
    side = rng.uniform(1.0, 4.0)
    for j in range(int(rng.integers(2, 9))):
        r1 = rng.uniform(0.05, 0.4)
        kind = int(rng.integers(0, 4))
        motion = {}
        if kind == 1:
            motion['velocity_mps'] = tuple(rng.uniform(-0.05, 0.05, 2))
        elif kind == 2:
            motion['angular_velocity_radps'] = rng.uniform(-0.5, 0.5)
        elif kind == 3:
            motion['oscillation_amplitude_m'] = tuple(rng.uniform(-0.3, 0.3, 2))
            motion['oscillation_period_s'] = rng.uniform(2.0, 20.0)
        obstacles.append(
            ObstacleSpec(
                f'o{j}',
                tuple(rng.uniform(0.0, side, 2)),
                (r1, rng.uniform(0.03, r1)),
                rng.uniform(0.0, math.pi),
                **motion,
            )
        )
    return obstacles


def _named(err: ConfigError):
    """(a, b, instant or None) of the validator's limit-cycle refusal."""
    text = str(err)
    names = text.split('of obstacles ')[1].split(' overlap')[0].replace("'", '').split(' and ')
    when = float(text.split('at t = ')[1].split(' s')[0]) if 'at t = ' in text else None
    return int(names[0][1:]), int(names[1][1:]), when


@pytest.mark.parametrize('seed', range(4))
def test_the_culled_limit_cycle_check_names_the_pair_and_instant_of_the_plain_one(seed):
    rng = np.random.default_rng(seed)
    avoidance = AvoidanceParams()
    refused = 0
    for _ in range(40):
        obstacles, duration = _random_obstacles(rng), float(rng.uniform(1.0, 40.0))
        want = _every_pair_every_instant(obstacles, avoidance, duration)
        try:
            loader._check_limit_cycles(obstacles, avoidance, duration)
            got = None
        except ConfigError as err:
            got = _named(err)
            refused += 1
        assert (got is None) == (want is None), (got, want)
        if want is not None:
            assert got[:2] == want[:2]
            assert (got[2] is None) == (want[2] is None)
            if want[2] is not None:
                assert got[2] == pytest.approx(want[2], abs=0.006)  # printed to 0.01 s
    assert 0 < refused < 40  # both answers drawn


def test_obstacles_moving_side_by_side_for_a_day_are_checked_or_refused_in_one_line():
    """Thin slats oscillating side by side, never touching: their bounding circles overlap at
    every instant, so every instant is tested. 4 for a day are checked; 40 are over the budget
    and refused in one line naming it.
    """
    avoidance = AvoidanceParams()

    def slats(n):
        return [
            ObstacleSpec(
                f'w{i}',
                (0.2 * i, 0.0),
                (0.15, 0.02),
                math.pi / 2,
                oscillation_amplitude_m=(0.0, 0.3),
                oscillation_period_s=7.0,
            )
            for i in range(n)
        ]

    loader._check_limit_cycles(slats(4), avoidance, 86_400.0)
    with pytest.raises(ConfigError, match='pair-samples of the limit-cycle check') as info:
        loader._check_limit_cycles(slats(40), avoidance, 86_400.0)
    assert len(str(info.value)) < MAX_LINE_CHARS and '\n' not in str(info.value)
    # one of them lying across towards its neighbour: found, at its first instant
    touching = slats(4)
    touching[2] = ObstacleSpec('w2', (0.35, 0.0), (0.15, 0.02), 0.0)
    with pytest.raises(ConfigError, match="'w1' and 'w2' overlap at t = 0.00 s"):
        loader._check_limit_cycles(touching, avoidance, 86_400.0)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 80), grid=st.booleans())
def test_convex_hull_is_the_convex_hull(seed, n, grid):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 2))
    if grid:  # duplicates and collinear points
        pts = np.round(pts)
    hull = convex_hull(pts)
    assert all(any(np.array_equal(v, p) for p in pts) for v in hull)  # vertices are points
    assert len({tuple(v) for v in hull}) == len(hull)
    if len(hull) < 3:  # every point the same, or on the segment between the two
        if len(hull) == 1:
            assert np.all(pts == hull[0])
            return
        d, u = hull[1] - hull[0], pts - hull[0]
        assert np.all(np.abs(u[:, 0] * d[1] - u[:, 1] * d[0]) < 1e-9)
        along = u @ d / (d @ d)
        assert np.all((along >= -1e-12) & (along <= 1 + 1e-12))
        return
    edges = np.roll(hull, -1, axis=0) - hull
    for v, e in zip(hull, edges):  # counter-clockwise, every point on the left or on an edge
        side = e[0] * (pts[:, 1] - v[1]) - e[1] * (pts[:, 0] - v[0])
        assert np.all(side >= -1e-9)
    turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(
        edges, -1, axis=0
    )[:, 0]
    assert np.all(turns > 0)  # strictly convex: no collinear vertex kept
