"""S7 robot-robot encounters: mutual pairs (one common sense, shared w_c, reciprocal field),
yielding to stand-on robots, the acyclic reacts-to rule, S14.3 teammates, and closed-loop tie
cases where only safety and settling are checked (S14.4: never which way a robot went round).
"""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.control.automaton import (
    AutomatonState,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    SwitchingParams,
)
from ament_formation.core.control.encounters import decide_once, reacts_to
from ament_formation.core.control.law import Gains, LawRobots, robot_law, Tracking
from ament_formation.core.control.limit_cycle import design_gains, ellipse_field_k, gain_schedule_k
from ament_formation.core.model.obstacles import ObstacleSnapshot
from ament_formation.core.scenario.loader import parse_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate

PRM = SwitchingParams().compiled()
NO_OBS = (
    np.zeros((0, 2)),
    np.zeros((0, 2)),
    np.zeros(0),
    np.zeros(0),
    np.zeros((0, 2)),
    np.zeros(0, bool),
)
R_AA = 0.25


def decide(
    state, t, p, pd, team=None, goal=None, goal_dot=None, vc=None, obs=NO_OBS, slot=None
):
    p = np.asarray(p, float)
    pd = np.asarray(pd, float)
    n = len(p)
    goal = p + 3.0 * pd if goal is None else goal
    goal_dot = pd if goal_dot is None else goal_dot
    vc = pd if vc is None else vc
    team = np.arange(n) if team is None else np.asarray(team)
    return decide_once(
        t, state, p, pd, goal, goal_dot, vc, team, np.full(n, 0.1), obs, PRM, slot=slot
    )


def test_head_on_free_robots_form_a_mutual_pair_with_common_sense_and_drift():
    st_ = AutomatonState(2)
    p = [(-0.2, 0.01), (0.2, 0.0)]
    pd = [(0.05, 0.0), (-0.04, 0.002)]
    events = decide(st_, 3.0, p, pd)
    assert sorted((e[1], e[2], e[3]) for e in events) == [
        (0, 'enter', MODE_MUTUAL),
        (1, 'enter', MODE_MUTUAL),
    ]
    assert list(st_.mode) == [MODE_MUTUAL, MODE_MUTUAL] and list(st_.tgt) == [1, 0]
    assert list(st_.sdir) == [1.0, 1.0] and st_.t_entry[0] == st_.t_entry[1] == 3.0
    np.testing.assert_allclose(st_.wc[0], st_.wc[1])
    np.testing.assert_allclose(st_.wc[0], 0.5 * (np.array(pd[0]) + np.array(pd[1])))


@pytest.mark.parametrize(
    'goals, sense',
    [
        (((0.3, 0.6), (-0.3, -0.6)), -1.0),  # each goes round the other clockwise
        (((0.3, -0.6), (-0.3, 0.6)), 1.0),  # each goes round the other counter-clockwise
        (((0.3, 0.6), (-0.3, 0.6)), 1.0),  # they disagree: s = +1 as in S7
    ],
    ids=['both_cw', 'both_ccw', 'disagree'],
)
def test_a_mutual_pair_turns_the_way_both_robots_goals_agree_on(goals, sense):
    # docs/law-changes.md section 14: the S6.6 sense of each robot round the other, when they agree
    st_ = AutomatonState(2)
    p = [(-0.2, 0.01), (0.2, 0.0)]
    pd = [(0.05, 0.0), (-0.04, 0.002)]
    decide(st_, 3.0, p, pd, goal=np.array(goals), goal_dot=np.zeros((2, 2)))
    assert list(st_.mode) == [MODE_MUTUAL, MODE_MUTUAL]
    assert list(st_.sdir) == [sense, sense]


@pytest.mark.parametrize('paired', [True, False])
def test_a_mutual_pair_is_not_left_for_a_merely_closer_robot(paired):
    # docs/law-changes.md section 15: robot 2 drives at robot 0, closer than robot 1 but outside
    # robot 0's emergency circle. Paired with robot 1, robot 0 keeps the pair (robot 2 yields
    # to it); yielding to robot 1, it re-targets to the closer robot 2 (S8.2)
    st_ = AutomatonState(3)
    st_.set_mode(0, MODE_MUTUAL if paired else MODE_YIELD, 1, 1.0, 1.0)
    if paired:
        st_.set_mode(1, MODE_MUTUAL, 0, 1.0, 1.0)
    p, pd = [(0.0, 0.0), (0.0, 0.6), (0.38, 0.0)], [(0.0, 0.0), (0.0, 0.0), (-0.06, 0.0)]
    decide(st_, 2.0, p, pd)
    if paired:
        assert list(st_.mode) == [MODE_MUTUAL, MODE_MUTUAL, MODE_YIELD]
        assert list(st_.tgt) == [1, 0, 0]
    else:
        assert (st_.mode[0], st_.tgt[0]) == (MODE_MUTUAL, 2)


def test_mutual_law_is_reciprocal_relative_motion_follows_f():
    """V_d,i - V_d,k = F(z_ik) and V_d,i + V_d,k = 2 w_c (S7), from the law actually used."""
    n = 2
    x = np.array([[-0.2, 0.03, 0.1, 0.05, 0.2], [0.15, -0.02, 3.0, 0.04, -0.1]])
    d = 0.05
    pd = np.array(
        [
            [
                x[i, 3] * math.cos(x[i, 2]) - d * x[i, 4] * math.sin(x[i, 2]),
                x[i, 3] * math.sin(x[i, 2]) + d * x[i, 4] * math.cos(x[i, 2]),
            ]
            for i in range(n)
        ]
    )
    st_ = AutomatonState(n)
    st_.set_mode(0, MODE_MUTUAL, 1, 1.0, 1.0)
    st_.set_mode(1, MODE_MUTUAL, 0, 1.0, 1.0)
    st_.wc[:] = [0.01, -0.02]
    st_.wtgt[:] = [0.03, 0.0]
    coeffs = np.array(
        [
            [2.8, 2.8],
            [0.02598, 0.02598],
            [0.035, 0.035],
            [0.2, 0.2],
            [d, d],
            [2.5, 2.5],
            [0.15, 0.15],
        ]
    )
    gains = Gains(0.27, 0.01, 0.5, 0.05, 0.15)
    zeros = np.zeros((0, 2))
    zeros = np.zeros((0, 2))
    args = (
        LawRobots(x, pd, np.zeros((n, 2)), np.full(n, 0.1), coeffs),
        Tracking(
            np.full(n, -1), np.zeros((n, 2)), np.zeros((n, 6)), np.zeros((n, 2)), np.zeros((n, 2))
        ),
        st_.arrays(),
        ObstacleSnapshot(
            zeros, zeros, zeros, np.zeros(0), np.zeros(0), np.zeros(0), zeros, np.zeros(0, bool)
        ),
        gains,
        PRM,
    )
    t = 2.2
    out = [robot_law(i, t, *args) for i in range(n)]
    vd = [pd[i] - np.array(out[i][2:4]) for i in range(n)]  # sigma = p_dot - V_d
    r = 0.1 + 0.1 + PRM.agent_keepout_margin_m
    psi_max, c_max = design_gains(r, r, PRM.agent_tangential_speed_mps, PRM)
    psd, psdd, c, cd = gain_schedule_k(
        t - 1.0, psi_max, c_max, 1.0, 1.0, 0.0, PRM.gain_start_fraction, PRM.gain_time_constant_s
    )
    z = x[0, :2] - x[1, :2]
    zd = pd[0] - pd[1]
    f = ellipse_field_k(
        z[0],
        z[1],
        zd[0],
        zd[1],
        0.0,
        0.0,
        0.0,
        PRM.limit_cycle_scale * r,
        PRM.limit_cycle_scale * r,
        psd,
        psdd,
        c,
        cd,
    )
    np.testing.assert_allclose(vd[0] - vd[1], f[:2], atol=1e-12)
    np.testing.assert_allclose(vd[0] + vd[1], 2 * st_.wc[0], atol=1e-12)
    # both robots integrate the same w_c derivative, so their w_c stay identical
    np.testing.assert_allclose(out[0][7:9], out[1][7:9])


def test_free_robot_yields_to_stand_on_robot():
    st_ = AutomatonState(2)
    far = (
        np.array([[5.0, 5.0]]),
        np.zeros((1, 2)),
        np.zeros(1),
        np.zeros(1),
        np.array([[0.3, 0.2]]),
        np.array([True]),
    )
    st_.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)  # robot 0 is stand-on
    events = decide(st_, 2.0, [(0.0, 0.0), (0.35, 0.02)], [(0.0, 0.0), (-0.05, 0.0)], obs=far)
    assert st_.mode[1] == MODE_YIELD and st_.tgt[1] == 0
    assert st_.mode[0] == MODE_OBSTACLE
    assert [e[1] for e in events if e[2] == 'enter'] == [1]


def test_robot_does_not_react_to_a_robot_that_already_yields_to_it():
    st_ = AutomatonState(2)
    st_.set_mode(1, MODE_YIELD, 0, 1.0, 0.0)  # 1 reacts to 0
    # closing at 4 cm/s: a threat (contact with I in 1.6 s) but no emergency (P in 2.5 s)
    decide(st_, 2.0, [(0.0, 0.0), (0.35, 0.02)], [(0.02, 0.0), (-0.02, 0.0)])
    assert st_.mode[0] == MODE_C  # 1 is responsible
    none = np.full(2, -1)
    assert reacts_to(1, 0, st_.mode, st_.tgt, none) and not reacts_to(
        0, 1, st_.mode, st_.tgt, none
    )


def test_emergency_converts_yield_into_mutual_pair():
    st_ = AutomatonState(2)
    st_.set_mode(1, MODE_YIELD, 0, -1.0, 0.0)
    decide(st_, 2.0, [(0.0, 0.0), (0.25, 0.0)], [(0.05, 0.0), (-0.05, 0.0)])  # inside E
    assert list(st_.mode) == [MODE_MUTUAL, MODE_MUTUAL] and list(st_.sdir) == [1.0, 1.0]


def test_formation_links_count_in_the_acyclicity_check():
    # S14.5: 1 yields to 0, 2 follows 1 (formation parent): 0 must not yield to 2 (the loop
    # 0 -> 2 -> 1 -> 0 of velocity feed-forwards); 2 is threatened by 0 and reacts instead
    st_ = AutomatonState(3)
    st_.set_mode(1, MODE_YIELD, 0, 1.0, 0.0)
    p = np.array([(0.0, 0.0), (0.0, 0.6), (0.35, 0.02)])
    pd = np.array([(0.02, 0.0), (0.0, 0.0), (-0.02, 0.0)])
    parent = np.array([-1, -1, 1])
    team = np.arange(3)
    decide_once(
        2.0, st_, p, pd, p + 3 * pd, pd, pd, team, np.full(3, 0.1), NO_OBS, PRM, parent=parent
    )
    assert reacts_to(2, 0, st_.mode, st_.tgt, parent) or st_.mode[2] != MODE_C
    assert not (st_.mode[0] == MODE_YIELD and st_.tgt[0] == 2)


def test_a_loop_closed_by_a_re_parenting_becomes_a_mutual_pair():
    # 0 yields to 2, 1 yields to 0, and 2 was just re-parented to 1: the loop is broken
    st_ = AutomatonState(3)
    st_.set_mode(0, MODE_YIELD, 2, 1.0, 0.0)
    st_.set_mode(1, MODE_YIELD, 0, 1.0, 0.0)
    p = np.array([(0.0, 0.0), (0.0, 0.6), (0.6, 0.0)])
    pd = np.zeros((3, 2))
    parent = np.array([-1, -1, 1])
    decide_once(
        5.0, st_, p, pd, p, pd, pd, np.arange(3), np.full(3, 0.1), NO_OBS, PRM, parent=parent
    )
    for i in range(3):
        if st_.mode[i] == MODE_YIELD:
            assert not reacts_to(st_.tgt[i], i, st_.mode, st_.tgt, parent)


def test_teammates_holding_slots_are_not_threats_but_strangers_are():
    p = [(0.0, 0.0), (0.35, 0.0)]
    pd = [(0.05, 0.0), (0.042, 0.0)]  # closing at 8 mm/s: contact with I in ~8 s
    same = AutomatonState(2)
    assert decide(same, 1.0, p, pd, team=[0, 0]) == []
    other = AutomatonState(2)
    assert len(decide(other, 1.0, p, pd, team=[0, 1])) == 2


def test_a_busy_teammate_moving_with_us_is_no_threat_but_an_emergency_still_counts():
    # S14.3 in every mode (docs/law-changes.md §11): robot 1 yields to robot 2 (another team);
    # its teammate 0 beside it, closing at 8 mm/s, does not yield to it ...
    p = [(0.0, 0.0), (0.35, 0.0), (0.35, 0.6)]
    pd = [(0.05, 0.0), (0.042, 0.0), (0.0, 0.0)]
    st_ = AutomatonState(3)
    st_.set_mode(1, MODE_YIELD, 2, 1.0, 0.5)
    events = decide(st_, 1.0, p, pd, team=[0, 0, 2])
    assert [e for e in events if e[1] == 0] == []
    assert st_.mode[0] == MODE_C
    # ... a stranger in its place would be yielded to, and a teammate inside E is an emergency
    other = AutomatonState(3)
    other.set_mode(1, MODE_YIELD, 2, 1.0, 0.5)
    decide(other, 1.0, p, pd, team=[0, 1, 2])
    assert other.mode[0] == MODE_YIELD and other.tgt[0] == 1
    close = AutomatonState(3)
    close.set_mode(1, MODE_YIELD, 2, 1.0, 0.5)
    decide(close, 1.0, [(0.095, 0.0), (0.35, 0.0), (0.35, 0.6)], pd, team=[0, 0, 2])
    assert close.mode[0] == MODE_YIELD and close.tgt[0] == 1


def test_teammates_released_from_each_other_stay_exempt_up_to_the_release_speed():
    # S14.3 hysteresis (§11): closing at 30 mm/s is a threat between teammates (> 20 mm/s) ...
    p = [(0.0, 0.0), (0.35, 0.0)]
    pd = [(0.05, 0.0), (0.02, 0.0)]
    fresh = AutomatonState(2)
    assert len(decide(fresh, 5.0, p, pd, team=[0, 0])) == 2
    # ... but not for a pair that left an encounter with each other (up to 40 mm/s) ...
    released = AutomatonState(2)
    released.last_kind[:] = 2  # KIND_AGENT
    released.last_tgt[:] = [1, 0]
    released.last_exit[:] = 1.0
    assert decide(released, 5.0, p, pd, team=[0, 0]) == []
    # ... above which it is one again
    faster = [(0.05, 0.0), (0.0, 0.0)]
    assert len(decide(released, 5.0, p, faster, team=[0, 0])) == 2


def test_teammates_whose_slots_lie_inside_q_meet_only_inside_the_slot_distance():
    # docs/law-changes.md §22: slots 0.36 m apart, so a teammate's Q shrinks from 0.45 m to
    # 0.36 - 0.05 = 0.31 m (still outside I, 0.2875 m); closing at 50 mm/s, above every teammate
    # threshold, 0.40 m apart (ray to P in 3 s: no emergency) ...
    pd = [(0.05, 0.0), (0.0, 0.0)]
    slot = [(0.0, 0.0), (0.0, 0.36)]
    at = [(0.0, 0.0), (0.40, 0.0)]
    assert decide(AutomatonState(2), 5.0, at, pd, team=[0, 0], slot=slot) == []
    # ... is an encounter with the slots unknown, with another team, or with slots as far apart
    # as Q ...
    assert len(decide(AutomatonState(2), 5.0, at, pd, team=[0, 0])) == 2
    assert len(decide(AutomatonState(2), 5.0, at, pd, team=[0, 1], slot=slot)) == 2
    apart = [(0.0, 0.0), (-0.3, 0.5)]
    assert len(decide(AutomatonState(2), 5.0, at, pd, team=[0, 0], slot=apart)) == 2
    # ... and inside the shrunk Q, 0.30 m apart, it is one again
    near = [(0.0, 0.0), (0.30, 0.0)]
    assert len(decide(AutomatonState(2), 5.0, near, pd, team=[0, 0], slot=slot)) == 2


def _check_invariants(state):
    n = state.n
    for i in range(n):
        if state.mode[i] == MODE_MUTUAL:
            k = state.tgt[i]
            assert state.mode[k] == MODE_MUTUAL and state.tgt[k] == i
            assert state.sdir[i] == state.sdir[k] and abs(state.sdir[i]) == 1.0
            assert state.t_entry[i] == state.t_entry[k]
            np.testing.assert_array_equal(state.wc[i], state.wc[k])
        if state.mode[i] == MODE_YIELD:
            # the reacts-to graph is acyclic apart from mutual pairs
            assert not reacts_to(state.tgt[i], i, state.mode, state.tgt, np.full(n, -1))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 9))
def test_reacts_to_graph_stays_acyclic_over_random_encounters(seed, n):
    rng = np.random.default_rng(seed)
    state = AutomatonState(n)
    p = rng.uniform(-0.6, 0.6, (n, 2))
    team = rng.integers(0, 3, n)
    for tick in range(40):
        pd = rng.normal(0, 0.05, (n, 2))
        toward = -p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-3) * 0.04
        pd = np.where(rng.random((n, 1)) < 0.5, toward, pd)
        decide(state, 0.1 * tick, p, pd, team=team)
        _check_invariants(state)
        p = p + 0.1 * pd


def _meeting(n_robots, radius=1.5, duration=75.0, seed=3):
    robots = []
    for i in range(n_robots):
        ang = 2 * math.pi * i / n_robots
        start = [radius * math.cos(ang), radius * math.sin(ang)]
        head = ang + math.pi
        robots.append(
            {
                'id': i,
                'leader': True,
                'slot_m': [0, 0],
                'marker_id': i,
                'initial_pose': [start[0], start[1], head],
                'path': {'type': 'line', 'start_m': start, 'heading_rad': head, 'speed_mps': 0.05},
            }
        )
    return parse_scenario(
        {
            'name': f'meet{n_robots}',
            'duration_s': duration,
            'robots': robots,
            'graph': {'edges': []},
            'obstacles': [],
            'disturbance': {'accel_bound': [0.05, 0.5], 'seed': seed},
        }
    )


@pytest.fixture(scope='module')
def meetings():
    out = {}
    for n in (2, 3, 4):
        sc = _meeting(n)
        res = simulate(sc)
        out[n] = (res, compute_metrics(res, sc))
    return out


@pytest.mark.parametrize('n', [2, 3, 4])
def test_symmetric_meetings_are_safe_and_settle(meetings, n):
    """Exact ties (S6.6 rule 4, S14.4) and 3-4 robots meeting at once (S14.1): safety +
    settling.
    """
    res, m = meetings[n]
    assert m['prohibited_entries'] == 0
    assert m['min_inter_robot_distance_m'] > R_AA
    assert all(r['final_error_m'] < 0.01 for r in m['robots'].values())
    assert not res.avoiding[-1].any()  # everybody exited: no livelock
    assert any(e['mode'] == 'mutual' for e in res.mode_events)
    done = [r for r in res.reaching if r['completed']]
    assert done and all(r['t_reach_s'] <= r['bound_s'] + 1e-9 for r in done)
    assert all(r['t_reach_s'] <= r['bound_s'] + 1e-9 for r in res.reaching if not r['completed'])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 400), size=st.floats(0.3, 40.0))
def test_grid_culling_finds_exactly_the_close_pairs(seed, n, size):
    from ament_formation.core.control.encounters import candidate_pairs

    q = np.random.default_rng(seed).uniform(0.0, size, (n, 2))
    got = {tuple(r) for r in candidate_pairs(q, 0.45)}
    d = np.linalg.norm(q[:, None] - q[None], axis=2)
    want = {(i, k) for i in range(n) for k in range(i + 1, n) if d[i, k] < 0.45}
    assert got == want


def test_a_mutual_pair_at_a_floor_edge_drifts_away_from_it():
    # docs/law-changes.md §20: both coordination fields lean into the wall at x = 0; the pair's
    # circle (R_aa / 2 + R_body + gap = 0.235 m round its centre at x = 0.15) needs room, so the
    # shared drift target points away from the wall (and, without a floor, into it as before)
    p = [(0.15, 1.0), (0.15, 1.36)]
    pd = [(0.0, 0.05), (0.0, -0.05)]
    vc = [(-0.02, 0.05), (-0.02, -0.05)]
    walled = SwitchingParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()
    for prm, away in ((walled, True), (PRM, False)):
        st_ = AutomatonState(2)
        n = len(p)
        decide_once(1.0, st_, p, pd, p, np.zeros((2, 2)), vc, [0, 1], np.full(n, 0.1), NO_OBS, prm)
        assert list(st_.mode) == [MODE_MUTUAL, MODE_MUTUAL]
        np.testing.assert_array_equal(st_.wtgt[0], st_.wtgt[1])
        assert (st_.wtgt[0, 0] > 0.0) == away, st_.wtgt[0]
        assert math.hypot(*st_.wtgt[0]) <= SwitchingParams().mutual_drift_cap_mps + 1e-12
    # away from the edge the floor changes nothing
    mid = [(1.5, 1.0), (1.5, 1.36)]
    a, b = AutomatonState(2), AutomatonState(2)
    for st_, prm in ((a, walled), (b, PRM)):
        z = np.zeros((2, 2))
        decide_once(1.0, st_, mid, pd, mid, z, vc, [0, 1], np.full(2, 0.1), NO_OBS, prm)
    np.testing.assert_array_equal(a.wtgt, b.wtgt)


def test_a_yielder_held_still_turns_the_other_way_round_its_robot():
    # docs/law-changes.md §21 (as §8 on an obstacle): robot 0 has yielded to robot 1 since t = 0
    # and is still; its goal is on the far side of robot 1
    p = [(0.0, 0.0), (0.3, 0.0)]
    still = np.zeros((2, 2))
    far_side = [(0.6, 0.0), (0.3, 0.0)]

    def run(t, goal):
        st_ = AutomatonState(2)
        st_.set_mode(0, MODE_YIELD, 1, 1.0, 0.0)
        return st_, decide(st_, t, p, still, goal=goal, goal_dot=still, vc=still)

    early, events = run(4.9, far_side)  # not yet STUCK_S (5 s)
    assert events == [] and early.sdir[0] == 1.0
    held, events = run(5.0, far_side)
    assert [(e[1], e[2], e[3], e[4], e[5]) for e in events] == [
        (0, 'exit', MODE_YIELD, 1, 1.0),
        (0, 'enter', MODE_YIELD, 1, -1.0),
    ]
    assert held.mode[0] == MODE_YIELD and held.tgt[0] == 1 and held.t_entry[0] == 5.0
    # parked: its goal, seen from robot 1, is where it is (the field asks for no tangential motion)
    parked, events = run(5.0, [(-0.2, 0.01), (0.3, 0.0)])
    assert events == [] and parked.sdir[0] == 1.0
