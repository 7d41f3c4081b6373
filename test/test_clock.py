"""Remote clock offsets estimated from what a machine sends (core/clock.py, issue 33): the offset
within the smallest latency seen, the deadband, the window, the bound a robot stops beyond.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ament_formation.core.clock import ClockOffsets, ClockParams
from ament_formation.core.errors import ConfigError

MIN_LATENCY_S = 0.004  # the network's fastest delivery [s]


def _feed(clocks, source, offset_s, t0_s, seconds, rate_hz=30.0, seed=0):
    """Messages sent every 1/rate_hz [s] of true time from ``t0_s``, stamped by a clock
    ``offset_s`` ahead of ours, delivered after MIN_LATENCY_S plus an exponential jitter (mean
    15 ms, tail to ~0.1 s); returns the smallest latency drawn.
    """
    rng = np.random.default_rng(seed)
    t_send = t0_s + np.arange(int(seconds * rate_hz)) / rate_hz
    latency = MIN_LATENCY_S + rng.exponential(0.015, t_send.size)
    for t, lat in zip(t_send, latency):
        clocks.observe(source, t + offset_s, t + lat)
    return float(latency.min())


@pytest.mark.parametrize('offset_s', [0.2, -0.2, 0.9, -0.9, 5.0, -5.0])
def test_an_offset_is_estimated_within_the_smallest_latency(offset_s):
    clocks = ClockOffsets()
    lat_min = _feed(clocks, 'camera', offset_s, 1000.0, 8.0, seed=int(10 * abs(offset_s)))
    est = clocks.offset_s('camera')
    # received - stamp = latency - offset: the window's minimum is lat_min - offset
    assert est == pytest.approx(offset_s - lat_min, abs=1e-9)
    assert -MIN_LATENCY_S - 0.002 < est - offset_s <= -MIN_LATENCY_S
    # a stamp of the camera on our clock: its capture time, read a few ms late at worst
    stamp = 1005.0 + offset_s
    assert clocks.local('camera', stamp) - 1005.0 == pytest.approx(lat_min, abs=1e-9)
    bad = clocks.beyond_bound()
    if abs(offset_s) > clocks.p.bound_s:  # 2 s: beyond it, the robot stops (stopped_clock)
        assert bad is not None and bad[0] == 'camera'
        assert bad[1] == pytest.approx(offset_s, abs=MIN_LATENCY_S + 0.002)
    else:
        assert bad is None
    assert clocks.report() == {'clock_offset_camera_s': round(est, 4)}


def test_sources_are_kept_apart_and_the_worst_one_is_named():
    clocks = ClockOffsets()
    _feed(clocks, 'camera', 0.9, 0.0, 3.0, seed=1)
    _feed(clocks, 'coordinator', -5.0, 0.0, 3.0, seed=2)
    _feed(clocks, 'robot_3', 3.0, 0.0, 3.0, seed=3)
    assert clocks.offset_s('camera') == pytest.approx(0.9, abs=0.01)
    assert clocks.offset_s('coordinator') == pytest.approx(-5.0, abs=0.01)
    assert clocks.offset_s('robot_7') == 0.0  # never heard: no correction
    assert clocks.local('robot_7', 12.5) == 12.5
    src, off = clocks.beyond_bound()
    assert src == 'coordinator' and off == pytest.approx(-5.0, abs=0.01)
    assert sorted(clocks.report()) == ['clock_offset_camera_s', 'clock_offset_coordinator_s',
                                       'clock_offset_robot_3_s']


def test_another_robots_clock_beyond_the_bound_is_its_fault_not_ours():
    # robot 0's view when robot 1's host runs 5 s ahead: the base machines agree with robot 0,
    # so robot 0 keeps driving (robot 1 sees the base 5 s off and stops itself)
    clocks = ClockOffsets()
    _feed(clocks, 'camera', 0.0, 0.0, 3.0, seed=7)
    _feed(clocks, 'coordinator', 0.0, 0.0, 3.0, seed=8)
    _feed(clocks, 'robot_1', 5.0, 0.0, 3.0, seed=9)
    assert clocks.beyond_bound() is None
    (src, off), = clocks.peers_beyond_bound()
    assert src == 'robot_1' and off == pytest.approx(5.0, abs=0.01)
    # its stamps are still read on our clock, within the smallest latency
    assert clocks.local('robot_1', 17.0) == pytest.approx(12.0, abs=0.01)
    # robot 1's view of the same run: the base is 5 s behind it, robot 0 too; it stops
    clocks = ClockOffsets()
    _feed(clocks, 'camera', -5.0, 0.0, 3.0, seed=10)
    _feed(clocks, 'robot_0', -5.0, 0.0, 3.0, seed=11)
    src, off = clocks.beyond_bound()
    assert src == 'camera' and off == pytest.approx(-5.0, abs=0.01)
    assert [s for s, _ in clocks.peers_beyond_bound()] == ['robot_0']
    # each such robot is named once
    assert [s for s, _ in clocks.newly_beyond_bound()] == ['robot_0']
    assert clocks.newly_beyond_bound() == []


def test_a_late_joiners_first_latched_message_is_not_taken_for_offset():
    # the coordinator's graph (transient local) was sent 0.9 s before we joined: its age is
    # not an offset; the next messages, fresh, give the offset (0 here: one clock)
    clocks = ClockOffsets()
    clocks.observe_latched('graph', 'coordinator', 100.0, 100.9)
    assert 'coordinator' not in clocks.sources
    assert clocks.beyond_bound() is None
    clocks.observe_latched('encounters', 'coordinator', 99.5, 100.9)  # its own first: history
    assert 'coordinator' not in clocks.sources
    clocks.observe_latched('graph', 'coordinator', 101.0, 101.003)
    assert clocks.offset_s('coordinator') == 0.0 and clocks.sources['coordinator'].count == 1
    clocks.observe_latched('graph', 'coordinator', 102.0 + 1.5, 102.004)  # 1.5 s ahead
    assert clocks.offset_s('coordinator') == pytest.approx(1.5 - 0.004)


@pytest.mark.parametrize('offset_s', [0.0, 0.01, -0.01])
def test_one_machine_or_synchronised_clocks_are_left_alone(offset_s):
    # within the 20 ms deadband (latency included) the offset is 0: ages are read as stamped
    clocks = ClockOffsets()
    _feed(clocks, 'camera', offset_s, 50.0, 2.0, seed=4)
    assert clocks.offset_s('camera') == 0.0
    assert clocks.local('camera', 51.0) == 51.0
    assert clocks.beyond_bound() is None
    # just beyond the deadband, it is corrected
    _feed(clocks, 'robot_1', 0.03, 50.0, 2.0, seed=5)
    assert 0.03 - MIN_LATENCY_S - 0.002 < clocks.offset_s('robot_1') <= 0.03 - MIN_LATENCY_S


def test_a_clock_step_is_followed_at_once_ahead_and_after_the_window_behind():
    clocks = ClockOffsets(ClockParams(window_s=4.0))
    _feed(clocks, 'camera', 0.5, 0.0, 6.0, seed=6)
    assert clocks.offset_s('camera') == pytest.approx(0.5, abs=0.01)
    # the sender's clock jumps 0.4 s ahead: the very next message shows a smaller difference
    lat = 0.01
    clocks.observe('camera', 6.0 + 0.9, 6.0 + lat)
    assert clocks.offset_s('camera') == pytest.approx(0.9 - lat, abs=1e-12)
    # ... and 1.4 s back: the old minimum holds for the window (4 s), then the new one
    seen = []
    for k in range(1, 300):  # 30 Hz for ~10 s
        t = 6.0 + k / 30.0
        clocks.observe('camera', t - 0.5, t + lat)
        seen.append((t, clocks.offset_s('camera')))
    before = [off for t, off in seen if t < 6.0 + 4.0 - 0.05]
    after = [off for t, off in seen if t > 6.0 + 4.0 + 0.05]
    assert before and all(off == pytest.approx(0.9 - lat, abs=1e-12) for off in before)
    assert after and all(off == pytest.approx(-0.5 - lat, abs=1e-12) for off in after)


def test_non_finite_stamps_are_ignored():
    clocks = ClockOffsets()
    clocks.observe('camera', math.nan, 1.0)
    clocks.observe('camera', 1.0, math.inf)
    assert clocks.sources == {} and clocks.offset_s('camera') == 0.0
    clocks.observe('camera', 3.0, 1.0)  # 2 s ahead (+ no latency): exactly at the bound
    clocks.observe('camera', math.nan, 1.1)
    assert clocks.offset_s('camera') == 2.0 and clocks.sources['camera'].count == 1
    assert clocks.beyond_bound() is None  # the bound itself is compensated


@pytest.mark.parametrize(
    'kwargs, field',
    [
        ({'window_s': -1.0}, 'window_s'),
        ({'deadband_s': math.nan}, 'deadband_s'),
        ({'bound_s': math.inf}, 'bound_s'),
        ({'bound_s': 0.01}, 'bound_s'),  # not above the deadband (0.02 s)
        ({'window_s': 'ten'}, 'window_s'),
    ],
)
def test_bad_clock_params_name_the_field(kwargs, field):
    with pytest.raises(ConfigError) as err:
        ClockParams(**kwargs)
    assert err.value.field == field
