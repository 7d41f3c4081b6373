"""The coordinator's table of robot-robot encounters (core/control/arbitration.py, docs/control-
law.md S7, S8.8): rows C1-C9 each on a minimal geometric case, pairing (S7.3), the acyclicity
rule (S7.4, S14.5), the teammate rules (S14.3), right of way between teams (S7.5), the exits
(S8.3), the progress monitor of the robots it owns (S8.9); then the coordinator core that runs
the table on what robots send (core/control/coordinator.py) and closed-loop meetings (S14.4:
only safety and settling are checked there, never which way a robot went round).
"""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from law_cases import (
    coordinator_decision,
    held_since,
    modes,
    PRM,
    robots,
    set_mode,
)
import numpy as np
import pytest
import yaml

from ament_formation.core.control.arbitration import (
    candidate_pairs,
    new_teams,
    reacts_to,
    right_of_way,
)
from ament_formation.core.control.coordinator import (
    Coordinator,
    DRIFT_RESEND_MPS,
    Publisher,
    RATE_RESEND,
    SILENT_S,
)
from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.switching import (
    KIND_ROBOT,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
)
from ament_formation.core.scenario.loader import parse_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate

DATA = Path(__file__).resolve().parent / 'data'
R_AA = 0.25  # keep-out circle of two robots of 0.1 m: 0.1 + 0.1 + 0.05
INF = math.inf


def entered(evs):
    return [(e[1], e[3], e[4]) for e in evs if e[2] == 'enter']


# ------------------------------------------------------------------ C6: pairing (S7.3)


HEAD_ON_P = [(-0.2, 0.01), (0.2, 0.0)]
HEAD_ON_PD = [(0.05, 0.0), (-0.04, 0.002)]


def test_c6_teammates_meeting_head_on_form_a_mutual_pair_with_one_sense_and_drift():
    m = modes(2)
    evs = coordinator_decision(3.0, m, robots(HEAD_ON_P, HEAD_ON_PD, team=[0, 0]))
    assert sorted(entered(evs)) == [(0, 'mutual', 1), (1, 'mutual', 0)]
    assert list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL] and list(m.tgt) == [1, 0]
    assert m.sdir[0] == m.sdir[1] and abs(m.sdir[0]) == 1.0
    assert m.t_entry[0] == m.t_entry[1] == 3.0
    np.testing.assert_array_equal(m.wc[0], m.wc[1])
    np.testing.assert_allclose(m.wc[0], 0.5 * (np.array(HEAD_ON_PD[0]) + HEAD_ON_PD[1]))


@pytest.mark.parametrize(
    'goals, sense',
    [
        (((0.3, 0.6), (-0.3, -0.6)), -1.0),  # each goes round the other clockwise
        (((0.3, -0.6), (-0.3, 0.6)), 1.0),  # each goes round the other counter-clockwise
        (((0.3, 0.6), (-0.3, 0.6)), 1.0),  # they disagree: s = +1 as in S7
    ],
    ids=['both_cw', 'both_ccw', 'disagree'],
)
def test_c6_a_mutual_pair_turns_the_way_both_robots_goals_agree_on(goals, sense):
    # S14.1: the S6.6 sense of each robot round the other, when they agree
    m = modes(2)
    coordinator_decision(3.0, m, robots(HEAD_ON_P, HEAD_ON_PD, goal=goals, goal_dot=np.zeros(
        (2, 2)), team=[0, 0]))
    assert list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL]
    assert list(m.sdir) == [sense, sense]


def test_c6_robots_of_two_teams_do_not_pair_one_gives_way_out_of_the_way():
    # crossing: robot 0 (team 0) eastward is 0.125 m from the meeting point, robot 1 (team 1)
    # northward 0.15 m: team 0 is further into it and ranks first (S7.5)
    p, pd = [(-0.05, 0.0), (0.2, -0.3)], [(0.05, 0.0), (0.0, 0.05)]
    m, teams = modes(2), new_teams(2)
    evs = coordinator_decision(1.0, m, robots(p, pd), teams)
    assert entered(evs) == [(1, 'yield', 0)]
    assert m.mode[0] == MODE_C
    assert teams.rank[0] < teams.rank[1] < INF
    assert m.park_at[1] == INF  # giving way: it goes round, it does not wait (park) in the way
    assert list(teams.way_rate) == [1.0, 0.0]  # team 1's reference waits (S17)


def test_c6_an_emergency_pairs_robots_of_any_team_and_turns_a_yield_into_a_pair():
    m = modes(2)
    set_mode(m, 1, MODE_YIELD, 0, -1.0, t_entry=0.0)
    # 0.25 m apart, inside E (0.2625 m), closing at 0.1 m/s
    coordinator_decision(2.0, m, robots([(0.0, 0.0), (0.25, 0.0)], [(0.05, 0.0), (-0.05, 0.0)]))
    assert list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL] and list(m.tgt) == [1, 0]
    assert m.sdir[0] == m.sdir[1] and m.t_entry[0] == m.t_entry[1] == 2.0


def test_c6_a_free_robot_yields_to_a_robot_on_an_obstacle():
    m = modes(2)
    set_mode(m, 0, MODE_OBSTACLE, 0, 1.0)  # stand-on: its own decision
    evs = coordinator_decision(2.0, m, robots([(0.0, 0.0), (0.35, 0.02)],
                                              [(0.0, 0.0), (-0.05, 0.0)]))
    assert entered(evs) == [(1, 'yield', 0)]
    assert m.mode[0] == MODE_OBSTACLE


@pytest.mark.parametrize('paired', [True, False])
def test_c6_a_mutual_pair_is_not_left_for_a_merely_closer_robot(paired):
    # docs/law-changes.md §15: robot 2 (robot 0's teammate) drives at robot 0, closer than
    # robot 1 but outside robot 0's E. Paired with robot 1, robot 0 keeps the pair (robot 2
    # yields to it); yielding to robot 1, it re-targets to the clearly closer robot 2 (S8.2)
    m = modes(3)
    set_mode(m, 0, MODE_MUTUAL if paired else MODE_YIELD, 1, 1.0, t_entry=1.0)
    if paired:
        set_mode(m, 1, MODE_MUTUAL, 0, 1.0, t_entry=1.0)
    rb = robots([(0.0, 0.0), (0.0, 0.6), (0.38, 0.0)], [(0.0, 0.0), (0.0, 0.0), (-0.06, 0.0)],
                team=[0, 1, 0])
    coordinator_decision(2.0, m, rb)
    if paired:
        assert list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL, MODE_YIELD]
        assert list(m.tgt) == [1, 0, 0]
    else:
        assert (m.mode[0], m.tgt[0]) == (MODE_MUTUAL, 2)


def test_c6_a_robot_in_an_encounter_re_targets_only_after_the_dwell():
    m = modes(3)
    set_mode(m, 0, MODE_YIELD, 1, 1.0, t_entry=2.0 - PRM.dwell_s + 0.05)
    rb = robots([(0.0, 0.0), (0.0, 0.6), (0.38, 0.0)], [(0.0, 0.0), (0.0, 0.0), (-0.06, 0.0)],
                team=[0, 1, 0])
    coordinator_decision(2.0, m, rb)
    assert (m.mode[0], m.tgt[0]) == (MODE_YIELD, 1)


# ------------------------------------------------------------------ S7.4: acyclicity


def test_a_robot_does_not_react_to_a_robot_that_already_yields_to_it():
    m = modes(2)
    set_mode(m, 1, MODE_YIELD, 0, 1.0)  # 1 reacts to 0
    # closing at 4 cm/s: a threat (contact with I in 1.6 s) but no emergency (P in 2.5 s)
    evs = coordinator_decision(2.0, m, robots([(0.0, 0.0), (0.35, 0.02)],
                                              [(0.02, 0.0), (-0.02, 0.0)]))
    assert evs == [] and m.mode[0] == MODE_C  # 1 is responsible
    none = np.full(2, -1)
    assert reacts_to(1, 0, m, none) and not reacts_to(0, 1, m, none)


def test_formation_links_count_in_the_acyclicity_rule():
    # S14.5: 1 yields to 0, 2 follows 1 (formation parent): 0 must not yield to 2 (the loop
    # 0 -> 2 -> 1 -> 0 of velocity feed-forwards); 2 reacts to 0 instead
    m = modes(3)
    set_mode(m, 1, MODE_YIELD, 0, 1.0)
    rb = robots([(0.0, 0.0), (0.0, 0.6), (0.35, 0.02)], [(0.02, 0.0), (0.0, 0.0), (-0.02, 0.0)],
                parent=[-1, -1, 1])
    assert reacts_to(2, 0, m, rb.parent)
    coordinator_decision(2.0, m, rb)
    assert m.mode[0] == MODE_C
    assert reacts_to(2, 0, m, rb.parent)
    # a mutual pair only reacts within itself: a chain reaches a pair's partner (S7.4: a pair's
    # partner is a reacts-to edge) and stops there, it never comes back out of the pair
    set_mode(m, 0, MODE_MUTUAL, 1, 1.0)
    set_mode(m, 1, MODE_MUTUAL, 0, 1.0)
    assert reacts_to(2, 0, m, rb.parent) and not reacts_to(0, 2, m, rb.parent)
    m2 = modes(3)
    set_mode(m2, 0, MODE_YIELD, 1, 1.0)
    set_mode(m2, 1, MODE_MUTUAL, 2, 1.0)
    set_mode(m2, 2, MODE_MUTUAL, 1, 1.0)
    none = np.full(3, -1)
    assert reacts_to(0, 1, m2, none) and reacts_to(0, 2, m2, none)
    assert not reacts_to(1, 0, m2, none) and not reacts_to(2, 0, m2, none)


def test_c2_a_loop_closed_by_a_re_parenting_becomes_a_mutual_pair():
    # 0 yields to 2, 1 yields to 0, and 2 was just re-parented to 1: 2 -> 1 -> 0 -> 2
    m = modes(3)
    set_mode(m, 0, MODE_YIELD, 2, 1.0)
    set_mode(m, 1, MODE_YIELD, 0, 1.0)
    rb = robots([(0.0, 0.0), (0.0, 0.6), (0.6, 0.0)], parent=[-1, -1, 1])
    evs = coordinator_decision(5.0, m, rb)
    assert (m.mode[0], m.tgt[0], m.mode[2], m.tgt[2]) == (MODE_MUTUAL, 2, MODE_MUTUAL, 0)
    assert sorted(entered(evs)) == [(0, 'mutual', 2), (2, 'mutual', 0)]
    for i in range(3):
        if m.mode[i] == MODE_YIELD:
            assert not reacts_to(m.tgt[i], i, m, rb.parent)


def test_c1_a_pair_whose_partner_went_onto_an_obstacle_becomes_a_yield_to_it():
    m = modes(2)
    set_mode(m, 0, MODE_MUTUAL, 1, -1.0, t_entry=1.0)
    set_mode(m, 1, MODE_OBSTACLE, 0, 1.0, t_entry=1.5)  # robot 1's own decision (R4)
    evs = coordinator_decision(1.6, m, robots([(0.0, 0.0), (0.6, 0.0)]))
    assert [e[1:] for e in evs[:2]] == [(0, 'exit', 'mutual', 1, -1.0),
                                        (0, 'enter', 'yield', 1, -1.0)]
    assert (m.mode[0], m.tgt[0], m.sdir[0], m.t_entry[0]) == (MODE_YIELD, 1, -1.0, 1.0)


# ------------------------------------------------------------------ S14.3: teammates


def test_teammates_holding_slots_are_not_threats_but_strangers_are():
    # S7.2: robots moving together (relative speed below teammate_speed_mps) are no threat,
    # teammates or not; closing faster, teammates pair and strangers give way (S7.5)
    p, pd = [(0.0, 0.0), (0.35, 0.0)], [(0.05, 0.0), (0.042, 0.0)]  # closing at 8 mm/s
    assert coordinator_decision(1.0, modes(2), robots(p, pd, team=[0, 0])) == []
    assert coordinator_decision(1.0, modes(2), robots(p, pd)) == []
    fast = [(0.05, 0.0), (0.02, 0.0)]  # closing at 30 mm/s
    m = modes(2)
    assert sorted(entered(coordinator_decision(1.0, m, robots(p, fast, team=[0, 0])))) == [
        (0, 'mutual', 1), (1, 'mutual', 0)]
    m = modes(2)
    evs = coordinator_decision(1.0, m, robots(p, fast))
    # team 1 is past the meeting point (it ranks first): robot 0 gives way
    assert entered(evs) == [(0, 'yield', 1)]


def test_a_busy_teammate_moving_with_us_is_no_threat_but_an_emergency_still_counts():
    # robot 1 yields to robot 2 (another team); its teammate 0 beside it, closing at 8 mm/s,
    # does not yield to it ...
    p = [(0.0, 0.0), (0.35, 0.0), (0.35, 0.6)]
    pd = [(0.05, 0.0), (0.042, 0.0), (0.0, 0.0)]

    def run(team, p=p, pd=pd):
        m = modes(3)
        set_mode(m, 1, MODE_YIELD, 2, 1.0, t_entry=0.5)
        evs = coordinator_decision(1.0, m, robots(p, pd, team=team))
        return m, evs

    m, evs = run([0, 0, 2])
    assert [e for e in evs if e[1] == 0] == [] and m.mode[0] == MODE_C
    # ... a stranger in its place closing faster than teammate_speed_mps (S7.2: a stranger
    # moving with us is exempt as well) is yielded to, and a teammate inside E is an emergency
    m, _ = run([0, 1, 2])
    assert m.mode[0] == MODE_C
    m, _ = run([0, 1, 2], pd=[(0.05, 0.0), (0.02, 0.0), (0.0, 0.0)])
    assert (m.mode[0], m.tgt[0]) == (MODE_YIELD, 1)
    m, _ = run([0, 0, 2], p=[(0.095, 0.0), (0.35, 0.0), (0.35, 0.6)])
    assert (m.mode[0], m.tgt[0]) == (MODE_YIELD, 1)


def test_teammates_released_from_each_other_stay_exempt_up_to_the_release_speed():
    # closing at 30 mm/s is a threat between teammates (> 20 mm/s) ...
    p = [(0.0, 0.0), (0.35, 0.0)]
    assert len(coordinator_decision(5.0, modes(2), robots(p, [(0.05, 0.0), (0.02, 0.0)],
                                                          team=[0, 0]))) == 2

    def released():
        m = modes(2)
        m.last_kind[:] = KIND_ROBOT
        m.last_tgt[:] = [1, 0]
        m.last_exit[:] = 1.0
        return m

    # ... not for a pair that left an encounter with each other (up to 40 mm/s) ...
    assert coordinator_decision(5.0, released(), robots(p, [(0.05, 0.0), (0.02, 0.0)],
                                                        team=[0, 0])) == []
    # ... above which it is one again
    assert len(coordinator_decision(5.0, released(), robots(p, [(0.05, 0.0), (0.0, 0.0)],
                                                            team=[0, 0]))) == 2


def test_teammates_whose_slots_lie_inside_q_meet_only_inside_the_slot_distance():
    # docs/law-changes.md §22: slots 0.36 m apart, so a teammate's Q shrinks from 0.45 m to
    # 0.36 - 0.05 = 0.31 m (still outside I, 0.2875 m); closing at 50 mm/s, 0.40 m apart
    pd = [(0.05, 0.0), (0.0, 0.0)]
    slot = [(0.0, 0.0), (0.0, 0.36)]
    at = [(0.0, 0.0), (0.40, 0.0)]

    def n_events(p, team, slot):
        return len(coordinator_decision(5.0, modes(2), robots(p, pd, team=team, slot=slot)))

    assert n_events(at, [0, 0], slot) == 0
    # ... an encounter with the slots unknown, with another team, or slots as far apart as Q
    assert n_events(at, [0, 0], None) == 2  # a pair (teammates)
    assert n_events(at, [0, 1], slot) == 1  # a yield (strangers)
    assert n_events(at, [0, 0], [(0.0, 0.0), (-0.3, 0.5)]) == 2
    # ... and inside the shrunk Q, 0.30 m apart, it is one again
    assert n_events([(0.0, 0.0), (0.30, 0.0)], [0, 0], slot) == 2


# ------------------------------------------------------------------ C7, C8: exits (S8.3)


def test_c7_a_yielder_leaves_when_s8_3_holds_for_the_dwell_and_t_min():
    m = modes(2)
    set_mode(m, 0, MODE_YIELD, 1, 1.0, t_entry=0.0)
    # robot 1 at rest 0.4 m east; robot 0's goal and V_c lead away west
    rb = robots([(0.0, 0.0), (0.4, 0.0)], [(-0.05, 0.0), (0.0, 0.0)],
                goal=[(-1.0, 0.0), (0.4, 0.0)])
    t_exit = None
    for t in np.round(np.arange(0.0, 2.0, 0.1), 10):
        evs = coordinator_decision(t, m, rb)
        if any(e[2] == 'exit' for e in evs):
            t_exit = t
            break
    assert t_exit == pytest.approx(PRM.min_avoid_s)
    assert (m.mode[0], m.last_kind[0], m.last_tgt[0]) == (MODE_C, KIND_ROBOT, 1)
    # with its goal on the far side of robot 1 (item 1) it stays
    m = modes(2)
    set_mode(m, 0, MODE_YIELD, 1, 1.0, t_entry=0.0)
    far = robots([(0.0, 0.0), (0.4, 0.0)], goal=[(1.0, 0.0), (0.4, 0.0)])
    for t in np.round(np.arange(0.0, 2.0, 0.1), 10):
        assert coordinator_decision(t, m, far) == []


@pytest.mark.parametrize('both', [True, False])
def test_c8_a_pair_leaves_jointly_when_s8_3_holds_for_both(both):
    m = modes(2)
    set_mode(m, 0, MODE_MUTUAL, 1, 1.0, t_entry=0.0)
    set_mode(m, 1, MODE_MUTUAL, 0, 1.0, t_entry=0.0)
    # passed each other: each one's goal and V_c lead away from the other (or, for robot 1, its
    # goal lies back across robot 0's circle: S8.3 item 1 fails for robot 1 alone; item 3 is
    # tested with the other's V_c, so it holds or fails for both sides alike)
    goal1 = (1.4, 0.0) if both else (-1.4, 0.0)
    rb = robots([(0.0, 0.0), (0.4, 0.0)], vc=[(-0.05, 0.0), (0.05, 0.0)],
                goal=[(-1.0, 0.0), goal1])
    exits = []
    for t in np.round(np.arange(0.0, 2.0, 0.1), 10):
        exits += [(e[0], e[1]) for e in coordinator_decision(t, m, rb) if e[2] == 'exit']
    if both:
        assert exits == [(PRM.min_avoid_s, 0), (PRM.min_avoid_s, 1)]
        assert list(m.mode) == [MODE_C, MODE_C]
    else:
        assert exits == [] and list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL]


# ------------------------------------------------------------------ C3-C5, C9: S8.9


def _yielder_held(t, goal, park_at=-INF):
    # robot 0 has yielded to robot 1 since t = 0 and is still
    p = [(0.0, 0.0), (0.3, 0.0)]
    m = modes(2)
    set_mode(m, 0, MODE_YIELD, 1, 1.0, t_entry=0.0)
    m.park_at[0] = park_at
    held_since(m, 0, p[0], 0.0)
    evs = coordinator_decision(t, m, robots(p, goal=[goal, (0.3, 0.0)]))
    return m, evs


def test_c3_a_yielder_held_still_turns_the_other_way_round_its_robot():
    far_side = (0.6, 0.0)  # its goal beyond robot 1
    m, evs = _yielder_held(PRM.stall_time_s - 0.01, far_side)
    assert evs == [] and m.sdir[0] == 1.0
    t = PRM.stall_time_s
    m, evs = _yielder_held(t, far_side)
    assert [e[1:] for e in evs] == [(0, 'exit', 'yield', 1, 1.0), (0, 'enter', 'yield', 1, -1.0)]
    assert (m.mode[0], m.tgt[0], m.t_entry[0], m.t_anchor[0]) == (MODE_YIELD, 1, t, t)
    # parked: its goal, seen from robot 1, is where it is (the field asks it to wait there)
    parked_goal = (-0.2, 0.01)
    m, evs = _yielder_held(t, parked_goal)
    assert evs == [] and m.sdir[0] == 1.0
    # ... unless it gives way (no parking): then it turns, and still does not park
    m, evs = _yielder_held(t, parked_goal, park_at=INF)
    assert [e[5] for e in evs] == [1.0, -1.0] and m.park_at[0] == INF


@pytest.mark.parametrize('first', [None, 0, 1])
def test_c4_a_stalled_pair_ends_the_robot_of_the_later_team_yields(first):
    p = [(0.0, 0.0), (0.3, 0.0)]
    m, teams = modes(2), new_teams(2)
    for i in (0, 1):
        set_mode(m, i, MODE_MUTUAL, 1 - i, 1.0, t_entry=0.0)
        held_since(m, i, p[i], 0.0)
    team = [0, 0]
    if first is not None:  # two teams; `first` met the other first (S7.5)
        team = [0, 1]
        teams.rank[first], teams.rank[1 - first] = 1.0, 2.0
    t = PRM.stall_time_s
    evs = coordinator_decision(t, m, robots(p, team=team), teams)
    yielder = 1 if first in (None, 0) else 0  # one team: the later id
    assert sorted(e[1:4] for e in evs if e[2] == 'exit') == [(0, 'exit', 'mutual'),
                                                             (1, 'exit', 'mutual')]
    assert entered(evs) == [(yielder, 'yield', 1 - yielder)]
    assert m.mode[1 - yielder] == MODE_C
    assert m.t_anchor[0] == m.t_anchor[1] == t


def test_c5_a_robot_stalled_short_of_its_goal_yields_to_the_robot_in_its_way():
    p = [(0.0, 0.0), (0.4, 0.0)]

    def held(goal, blocker_mode=MODE_C):
        m = modes(2)
        held_since(m, 0, p[0], 0.0)
        if blocker_mode == MODE_YIELD:
            set_mode(m, 1, MODE_YIELD, 0, 1.0)
        return m, coordinator_decision(PRM.stall_time_s, m, robots(p, goal=[goal, p[1]]))

    m, evs = held((1.0, 0.0))
    assert entered(evs) == [(0, 'yield', 1)] and m.t_anchor[0] == PRM.stall_time_s
    # at its goal, or the robot at rest behind it, or beyond the barrier's range: nothing
    assert held((0.05, 0.0))[1] == []
    assert held((-1.0, 0.0))[1] == []
    # the blocker yields to it already but waits (parks) in its way: it stops parking
    m, evs = held((1.0, 0.0), MODE_YIELD)
    assert entered(evs) == [] and m.park_at[1] == INF and m.mode[0] == MODE_C


def test_c9_robots_at_rest_beside_a_robot_stalled_on_its_obstacle_make_way():
    # robot 0 on its obstacle held still for stall_time_s (the coordinator's own watch);
    # robot 1 at rest beside it in C; robot 2 parked on an obstacle of its own beside it;
    # robot 3 beside it but moving; robot 4 at rest but far
    p = [(0.0, 0.0), (0.4, 0.0), (-0.3, 0.2), (0.0, -0.4), (2.0, 0.0)]
    pd = [(0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.05, 0.0), (0.0, 0.0)]
    m, teams = modes(5), new_teams(5)
    set_mode(m, 0, MODE_OBSTACLE, 0, 1.0, t_entry=0.0)
    set_mode(m, 2, MODE_OBSTACLE, 1, 1.0, t_entry=0.0)
    teams.anchor[0], teams.t_anchor[0] = p[0], 0.0
    rb = robots(p, pd, goal=p, goal_dot=np.zeros((5, 2)), vc=np.zeros((5, 2)))
    t = PRM.stall_time_s
    evs = coordinator_decision(t - 0.01, m, rb, teams)
    assert evs == [] and m.park_at[2] == -INF
    evs = coordinator_decision(t, m, rb, teams)
    assert entered(evs) == [(1, 'yield', 0)]
    assert m.park_at[1] == INF  # it circles robot 0 until S8.3 lets it back
    assert m.park_at[2] == pytest.approx(t + PRM.make_way_s)  # it goes round its own obstacle
    assert m.mode[2] == MODE_OBSTACLE and m.mode[3] == MODE_C and m.mode[4] == MODE_C
    assert teams.t_anchor[0] == t  # the watch starts again


# ------------------------------------------------------------------ S7.5: right of way


def test_right_of_way_keys_the_team_at_rest_first_then_the_earlier_meeting_then_further_in():
    # team 0 (robots 0, 1) and team 2 (robot 2) meet at t = 1; team 3 (robot 3) is far away
    p = [(0.0, 0.0), (-0.4, 0.0), (0.5, -0.3), (5.0, 5.0)]
    gd = [(0.05, 0.0), (0.05, 0.0), (0.0, 0.05), (0.05, 0.0)]
    rb = robots(p, gd, team=[0, 0, 2, 3])
    teams = new_teams(4)
    pairs = candidate_pairs(rb.p, rb.known, 1.0)
    right_of_way(1.0, rb, pairs, teams, PRM)
    # meeting point (0.25, -0.15): 0.25 m ahead of leader 0, 0.15 m ahead of leader 2
    assert teams.rank[2] < teams.rank[0] < INF and teams.rank[3] == INF
    assert 1.0 <= teams.rank[2] < teams.rank[0] <= 1.0 + 1e-4
    # the keys stay while the teams meet, whatever their motion does since
    first = teams.rank.copy()
    right_of_way(3.0, robots(p, -np.array(gd), team=[0, 0, 2, 3]), pairs, teams, PRM)
    np.testing.assert_array_equal(teams.rank, first)
    # a team at rest at the end of its reference goes first
    teams.done[0] = True
    right_of_way(3.0, rb, pairs, teams, PRM)
    assert teams.rank[0] == -1.0 < teams.rank[2]
    # apart by right_of_way_release_m: the keys are gone
    apart = robots([(0.0, 0.0), (-0.4, 0.0), (0.0, -PRM.right_of_way_release_m - 0.01),
                    (5.0, 5.0)], gd, team=[0, 0, 2, 3])
    right_of_way(4.0, apart, candidate_pairs(apart.p, apart.known, 1.0), teams, PRM)
    assert list(teams.rank) == [INF] * 4


def test_right_of_way_teams_that_meet_later_rank_after():
    p = [(0.0, 0.0), (0.5, -0.3), (-0.6, 0.3)]
    gd = [(0.05, 0.0), (0.0, 0.05), (0.05, 0.0)]
    teams = new_teams(3)
    two = robots(p[:2] + [(9.0, 9.0)], gd)
    right_of_way(1.0, two, candidate_pairs(two.p, two.known, 1.0), teams, PRM)
    three = robots(p, gd)
    right_of_way(2.0, three, candidate_pairs(three.p, three.known, 1.0), teams, PRM)
    assert max(teams.rank[:2]) < teams.rank[2] < INF


def test_a_team_passing_a_team_at_rest_goes_round_it_and_its_reference_does_not_wait():
    # S7.5: it yields to the team at rest (which ranks first); that team does not move on, so
    # the yielder keeps its parking factor (it may wait at its goal's anomaly beside it), unlike
    # a robot giving way to a moving team (test_c6_robots_of_two_teams_do_not_pair...)
    p, pd = [(0.0, 0.0), (0.4, 0.02)], [(0.0, 0.0), (-0.05, 0.0)]
    m, teams = modes(2), new_teams(2)
    teams.done[0] = True
    evs = coordinator_decision(1.0, m, robots(p, pd, goal=[p[0], (-1.0, 0.0)]), teams)
    assert entered(evs) == [(1, 'yield', 0)] and m.park_at[1] < INF
    assert m.mode[0] == MODE_C
    assert teams.rank[0] == -1.0 and (teams.way_rate == 1.0).all()


def _headway(p_k, pd_k, heading=(1.0, 0.0), done=False, on_obstacle=False):
    """Robot 0 (team 0, ranked first) at p_k moving at pd_k (in C, or round an obstacle);
    robot 1 (team 1, its path along ``heading``) at rest at the origin, in C: team 1's way_rate
    after one decision.
    """
    m, teams = modes(2), new_teams(2)
    if on_obstacle:
        set_mode(m, 0, MODE_OBSTACLE, 0)
    teams.rank[:] = [0.0, 1.0]  # team 0 goes first (S7.5)
    teams.heading[1] = heading
    teams.done[0] = done
    coordinator_decision(1.0, m, robots([p_k, (0.0, 0.0)], [pd_k, (0.0, 0.0)],
                                        goal=[p_k, (2.0, 0.0)]), teams)
    assert teams.way_rate[0] == 1.0  # the team that goes first is never held by the other
    return teams.way_rate[1]


def test_headway_a_team_slows_and_waits_for_a_moving_team_that_goes_first_in_its_way():
    # S7.5 headway: a robot of the first team crossing team 1's way ahead of its robot: the cap
    # falls linearly from headway_go_m to headway_stop_m (0.3 m of span by default)
    go, stop = PRM.headway_go_m, PRM.headway_stop_m
    assert _headway((go + 0.05, 0.0), (0.0, 0.05)) == 1.0
    mid = 0.5 * (go + stop)
    assert _headway((mid, 0.0), (0.0, 0.05)) == pytest.approx(0.5)
    assert _headway((stop - 0.02, 0.1), (0.0, 0.05)) == 0.0
    assert _headway((mid, 0.0), (0.05, 0.0)) == pytest.approx(0.5)  # ahead, going the same way
    # ... and is the least over the pairs: a second team-0 robot nearer ahead caps harder
    m, teams = modes(3), new_teams(3)
    teams.rank[:] = [0.0, 1.0, INF]
    teams.heading[1] = (1.0, 0.0)
    rb = robots([(go - 0.05, 0.2), (0.0, 0.0), (stop + 0.03, -0.1)],
                [(0.0, 0.05), (0.0, 0.0), (0.0, 0.05)], team=[0, 1, 0])
    coordinator_decision(1.0, m, rb, teams)
    d = math.hypot(stop + 0.03, 0.1)
    assert teams.way_rate[1] == pytest.approx((d - stop) / (go - stop))


def test_headway_does_not_hold_a_team_for_a_robot_behind_beside_at_rest_coming_circling_or_done():
    mid = 0.5 * (PRM.headway_go_m + PRM.headway_stop_m)
    assert _headway((-mid, 0.0), (0.0, 0.05)) == 1.0  # behind
    q = PRM.protected_scale * R_AA
    assert _headway((mid, q + 0.02), (0.05, 0.0)) == 1.0  # beside the way, beyond Q's radius
    assert _headway((mid, 0.0), (0.0, 0.5 * PRM.teammate_speed_mps)) == 1.0  # at rest: go round
    assert _headway((mid, 0.0), (-0.05, 0.0)) == 1.0  # coming at it: waiting stands in its way
    assert _headway((mid, 0.0), (0.0, 0.05), done=True) == 1.0  # a team at its end
    assert _headway((mid, 0.0), (0.0, 0.05), on_obstacle=True) == 1.0  # circling: not going by
    assert _headway((mid, 0.0), (0.0, 0.05), heading=(np.nan, np.nan)) == 1.0  # no way known
    # the same robot ahead in the way of a team that goes first holds nobody
    m, teams = modes(2), new_teams(2)
    teams.rank[:] = [1.0, 0.0]
    teams.heading[1] = (1.0, 0.0)
    coordinator_decision(1.0, m, robots([(mid, 0.0), (0.0, 0.0)], [(0.0, 0.05), (0.0, 0.0)]),
                         teams)
    assert list(teams.way_rate) == [1.0, 1.0]


def test_headway_the_coordinator_holds_a_crossing_team_back_in_the_closed_loop():
    # two one-robot teams crossing at right angles, team 1 arriving later: its reference waits
    # short of the crossing (its robot never yields: it stops, with its reference's lag, about
    # 0.1 m inside headway_stop_m), then goes
    sc = parse_scenario({
        'name': 'cross_headway', 'duration_s': 30.0,
        'robots': [
            {'id': 0, 'leader': True, 'slot_m': [0.0, 0.0], 'marker_id': 0,
             'initial_pose': [-0.9, 0.0, 0.0],
             'path': {'type': 'line', 'start_m': [-0.9, 0.0], 'heading_rad': 0.0,
                      'speed_mps': 0.06}},
            {'id': 1, 'leader': True, 'slot_m': [0.0, 0.0], 'marker_id': 1,
             'initial_pose': [0.0, -0.95, math.pi / 2],
             'path': {'type': 'line', 'start_m': [0.0, -0.95], 'heading_rad': math.pi / 2,
                      'speed_mps': 0.06}},
        ],
        'graph': {'edges': []}, 'obstacles': [],
    })
    res = simulate(sc, record_every_s=0.05)
    x = res.state
    gap = np.hypot(x[:, 0, 0] - x[:, 1, 0], x[:, 0, 1] - x[:, 1, 1])
    assert [e for e in res.mode_events if e['mode'] in ('yield', 'mutual')] == []
    assert PRM.headway_stop_m - 0.15 < gap.min() < PRM.headway_stop_m
    metrics = compute_metrics(res, sc)
    assert max(r['final_error_m'] for r in metrics['robots'].values()) < 0.05


def _triangle(n=3, radius=0.28):
    ang = 2 * np.pi * np.arange(n) / n
    p = radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    return p, -0.05 * p / radius


def test_no_three_teams_wait_on_each_other_in_a_circle():
    # three one-robot teams meeting at one point: the keys order them all; the first goes,
    # the others yield to robots of teams before them, and no yield closes a loop
    p, pd = _triangle()
    m, teams = modes(3), new_teams(3)
    rb = robots(p, pd, goal=p + 3 * pd)
    coordinator_decision(1.0, m, rb, teams)
    keys = sorted(teams.rank)
    assert keys[0] < keys[1] < keys[2] < INF or len(set(keys)) == 3
    first = int(np.argmin(teams.rank))
    assert m.mode[first] == MODE_C
    for i in range(3):
        if m.mode[i] == MODE_YIELD:
            assert not teams.rank[m.tgt[i]] > teams.rank[i]  # toward a team before it
            assert not reacts_to(m.tgt[i], i, m, rb.parent)


# ------------------------------------------------------------------ invariants


def _check_invariants(m, parent):
    n = len(m.mode)
    for i in range(n):
        if m.mode[i] == MODE_MUTUAL:
            k = m.tgt[i]
            assert m.mode[k] == MODE_MUTUAL and m.tgt[k] == i
            assert m.sdir[i] == m.sdir[k] and abs(m.sdir[i]) == 1.0
            assert m.t_entry[i] == m.t_entry[k]
            np.testing.assert_array_equal(m.wc[i], m.wc[k])
        if m.mode[i] == MODE_YIELD:
            # the reacts-to graph is acyclic apart from mutual pairs
            assert not reacts_to(m.tgt[i], i, m, parent)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 9))
def test_pairs_stay_reciprocal_and_the_reacts_to_graph_acyclic_over_random_encounters(seed, n):
    rng = np.random.default_rng(seed)
    m, teams = modes(n), new_teams(n)
    p = rng.uniform(-0.6, 0.6, (n, 2))
    team = rng.integers(0, 3, n)
    team = np.array([int(np.flatnonzero(team == team[i])[0]) for i in range(n)])  # leader rows
    for tick in range(40):
        pd = rng.normal(0, 0.05, (n, 2))
        toward = -p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-3) * 0.04
        pd = np.where(rng.random((n, 1)) < 0.5, toward, pd)
        coordinator_decision(0.1 * tick, m, robots(p, pd, team=team), teams)
        _check_invariants(m, np.full(n, -1))
        p = p + 0.1 * pd


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 400), size=st.floats(0.3, 40.0))
def test_grid_culling_finds_exactly_the_close_pairs_of_known_robots(seed, n, size):
    rng = np.random.default_rng(seed)
    q = rng.uniform(0.0, size, (n, 2))
    known = rng.random(n) < 0.9
    got = {tuple(r) for r in candidate_pairs(q, known, 0.45)}
    d = np.linalg.norm(q[:, None] - q[None], axis=2)
    want = {(i, k) for i in range(n) for k in range(i + 1, n)
            if d[i, k] < 0.45 and known[i] and known[k]}
    assert got == want


def test_a_robot_not_heard_takes_no_part():
    m = modes(2)
    rb = robots(HEAD_ON_P, HEAD_ON_PD, team=[0, 0], known=[True, False])
    assert coordinator_decision(3.0, m, rb) == [] and list(m.mode) == [MODE_C, MODE_C]


# ------------------------------------------------------------------ S16.3: drift off edges


def test_a_mutual_pair_at_a_floor_edge_drifts_away_from_it():
    # docs/law-changes.md §20: both coordination fields lean into the wall at x = 0; the pair's
    # circle (R_aa / 2 + R_body + gap = 0.235 m round its centre at x = 0.15) needs room, so the
    # shared drift target points away from the wall (and, without a floor, into it as before)
    p = [(0.15, 1.0), (0.15, 1.36)]
    pd = [(0.0, 0.05), (0.0, -0.05)]
    vc = [(-0.02, 0.05), (-0.02, -0.05)]
    walled = LawParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()
    for prm, away in ((walled, True), (PRM, False)):
        m = modes(2)
        coordinator_decision(1.0, m, robots(p, pd, goal=p, goal_dot=np.zeros((2, 2)), vc=vc,
                                            team=[0, 0]), prm=prm)
        assert list(m.mode) == [MODE_MUTUAL, MODE_MUTUAL]
        np.testing.assert_array_equal(m.wtgt[0], m.wtgt[1])
        assert (m.wtgt[0, 0] > 0.0) == away, m.wtgt[0]
        assert math.hypot(*m.wtgt[0]) <= PRM.mutual_drift_cap_mps + 1e-12
    # away from the edge the floor changes nothing
    mid = [(1.5, 1.0), (1.5, 1.36)]
    a, b = modes(2), modes(2)
    for m, prm in ((a, walled), (b, PRM)):
        coordinator_decision(1.0, m, robots(mid, pd, goal=mid, goal_dot=np.zeros((2, 2)), vc=vc,
                                            team=[0, 0]), prm=prm)
    np.testing.assert_array_equal(a.wtgt, b.wtgt)


# ------------------------------------------------------------------ the coordinator core


@pytest.fixture(scope='module')
def three_robots():
    """test/data/head_on.yaml (robots 0 and 1 head-on on y = 0.6, two teams) plus a robot 2 far
    away (5 m north, driving east), and the simulator's run of it (recorded at 50 Hz).
    """
    mapping = yaml.safe_load((DATA / 'head_on.yaml').read_text())
    mapping['robots'].append({
        'id': 2, 'leader': True, 'slot_m': [0.0, 0.0], 'marker_id': 2,
        'initial_pose': [0.0, 5.6, 0.0],
        'path': {'type': 'line', 'start_m': [0.0, 5.6], 'heading_rad': 0.0, 'speed_mps': 0.08},
    })
    sc = parse_scenario(mapping, 'head_on+far')
    return sc, simulate(sc, record_every_s=0.02)


def _robot_events(events):
    return [e for e in events if e['mode'] in ('yield', 'mutual')]


def test_the_coordinator_assigns_and_releases_the_encounter_the_simulator_decided(three_robots):
    sc, res = three_robots
    coord = Coordinator(sc)
    sim = _robot_events(res.mode_events)
    assert sim, 'the simulator decided no robot encounter'
    history = []  # (t, assignments) of every decision
    for k, t in enumerate(res.t_s):
        for q, rid in enumerate(res.robot_ids):
            coord.state(rid, res.state[k, q], float(t))
            coord.report(rid, {'mode': 'coordination', 'target': None, 'direction': None,
                               'avoiding': False})
        history.append((float(t), coord.decide(float(t))[0]))
    held = [(t, a) for t, a in history if a]
    assert held, 'no assignment'
    t_first, first = held[0]
    enter = sim[0]
    assert enter['event'] == 'enter' and abs(enter['t_s'] - t_first) <= 0.05
    assert {(rid, a['mode'], a['partner']) for rid, a in first.items()} == {
        (e['robot'], e['mode'], int(e['target'].split('_')[1])) for e in sim
        if e['event'] == 'enter' and abs(e['t_s'] - enter['t_s']) < 1e-9}
    for rid, a in first.items():
        assert a['t_entry_s'] == pytest.approx(t_first) and abs(a['direction']) == 1.0
        if a['mode'] == 'mutual':
            assert a['drift_mps'] == first[a['partner']]['drift_mps']
    # released as the simulator released it, after T_min; robot 2 never takes part
    t_last = held[-1][0]
    t_exit = next(e['t_s'] for e in sim if e['event'] == 'exit')
    assert abs(t_exit - (t_last + 0.02)) <= 0.05 and t_last - t_first >= PRM.min_avoid_s
    assert all(2 not in a for _, a in history)
    release = next(k for k, (t, _a) in enumerate(history) if t > t_last)
    x = res.state[release]
    assert np.hypot(*(x[0, :2] - x[1, :2])) > R_AA  # outside R_aa
    # every leader's rate target in [0, 1]; the mission ends as the simulator's did
    rates = coord.rates()
    assert set(rates) == {0, 1, 2} and all(0.0 <= r <= 1.0 for r in rates.values())
    print(f'coordinator: encounter {t_first:.2f} s .. {t_last:.2f} s, simulator exit '
          f'{t_exit:.2f} s')


def test_the_coordinator_leaves_out_robots_it_has_not_heard_lately(three_robots):
    sc, res = three_robots
    enter = _robot_events(res.mode_events)[0]['t_s']
    k = int(np.searchsorted(res.t_s, enter))
    t = float(res.t_s[k])
    coord = Coordinator(sc)
    for q, rid in enumerate(res.robot_ids):
        if rid != 1:
            coord.state(rid, res.state[k, q], t)
    assert coord.decide(t)[0] == {}  # robot 1 never heard
    coord.state(1, res.state[k, 1], t - SILENT_S - 0.01)
    assert coord.decide(t + 0.01)[0] == {}  # heard too long ago
    coord.state(1, res.state[k, 1], t + 0.02)
    out = coord.decide(t + 0.02)[0]
    assert {0, 1} <= set(out) and out[min(out)]['t_entry_s'] == pytest.approx(t + 0.02)


def test_the_coordinator_takes_a_robots_obstacle_mode_as_given_and_asks_others_to_yield():
    sc = parse_scenario({
        'name': 'stand_on', 'duration_s': 20.0,
        'robots': [
            {'id': 0, 'leader': True, 'initial_pose': [0.0, 0.0, 0.0],
             'path': {'type': 'line', 'start_m': [0.0, 0.0], 'heading_rad': 0.0,
                      'speed_mps': 0.05}},
            {'id': 1, 'leader': True, 'initial_pose': [0.35, 0.02, math.pi],
             'path': {'type': 'line', 'start_m': [0.35, 0.02], 'heading_rad': math.pi,
                      'speed_mps': 0.05}},
        ],
        'obstacles': [{'name': 'O', 'center_m': [0.0, -0.6], 'semi_axes_m': [0.2, 0.2]}],
    })
    coord = Coordinator(sc)
    coord.state(0, np.array([0.0, 0.0, 0.0, 0.0, 0.0]), 1.0)
    coord.state(1, np.array([0.35, 0.02, math.pi, 0.05, 0.0]), 1.0)
    coord.report(0, {'mode': 'obstacle', 'target': 'O', 'direction': 'cw', 'avoiding': True})
    coord.report(1, {'mode': 'coordination', 'avoiding': False})
    out, _ = coord.decide(1.0)
    assert coord.modes.mode[0] == MODE_OBSTACLE and coord.modes.sdir[0] == -1.0
    assert out[1]['mode'] == 'yield' and out[1]['partner'] == 0
    assert coord.events == [{'t_s': 1.0, 'robot': 1, 'event': 'enter', 'mode': 'yield',
                             'target': 'robot_0'}]
    # S9: the reports of avoiding robots rewire the graph once per change
    assert coord.reported_avoiding() == coord.parents and coord.reported_avoiding() is None
    # robot 0 leaves its obstacle: the cool-down record is the obstacle's
    coord.report(0, {'mode': 'coordination', 'avoiding': False})
    coord.decide(1.1)
    assert coord.modes.mode[0] == MODE_C and coord.modes.last_exit[0] == 1.1


def test_the_publisher_sends_new_decisions_moved_drifts_and_rates_and_republishes():
    def pair(wx, direction=1.0):
        return {rid: {'mode': 'mutual', 'partner': 1 - rid, 'direction': direction,
                      't_entry_s': 3.0, 'drift_mps': [wx, 0.0], 'park_at_s': -INF}
                for rid in (0, 1)}

    pub = Publisher(republish_s=1.0)
    rates = {0: 1.0}
    assert pub.due(0.0, {}, rates)  # the first
    assert not pub.due(0.1, {}, rates)
    assert pub.due(0.2, pair(-0.05), rates)  # a new decision
    step = 0.4 * DRIFT_RESEND_MPS
    assert not pub.due(0.3, pair(-0.05 + step), rates)  # moved less than the threshold
    assert not pub.due(0.4, pair(-0.05 + 2 * step), rates)
    assert pub.due(0.5, pair(-0.05 + 3 * step), rates)  # 1.2 x the threshold since sent
    assert not pub.due(0.6, pair(-0.05 + 4 * step), rates)  # measured from what was sent
    assert pub.due(0.7, pair(-0.05 + 4 * step, direction=-1.0), rates)  # another sense
    assert not pub.due(0.8, pair(-0.05 + 4 * step, direction=-1.0), {0: 1.0 - RATE_RESEND / 2})
    assert pub.due(0.9, pair(-0.05 + 4 * step, direction=-1.0), {0: 1.0 - 2 * RATE_RESEND})
    assert pub.due(1.9, pair(-0.05 + 4 * step, direction=-1.0), {0: 1.0 - 2 * RATE_RESEND})
    assert pub.due(2.0, {}, rates)  # released


# ------------------------------------------------------------------ closed loop (S14.4)


def _meeting(n_robots, radius=1.5, duration=75.0, seed=3):
    robots_ = []
    for i in range(n_robots):
        ang = 2 * math.pi * i / n_robots
        start = [radius * math.cos(ang), radius * math.sin(ang)]
        head = ang + math.pi
        robots_.append({
            'id': i, 'leader': True, 'slot_m': [0, 0], 'marker_id': i,
            'initial_pose': [start[0], start[1], head],
            'path': {'type': 'line', 'start_m': start, 'heading_rad': head, 'speed_mps': 0.05},
        })
    return parse_scenario({
        'name': f'meet{n_robots}', 'duration_s': duration, 'robots': robots_,
        'graph': {'edges': []}, 'obstacles': [],
        'disturbance': {'accel_bound': [0.05, 0.5], 'seed': seed},
    })


@pytest.fixture(scope='module')
def meetings():
    out = {}
    for n in (2, 3, 4):
        sc = _meeting(n)
        res = simulate(sc)
        out[n] = (sc, res, compute_metrics(res, sc))
    return out


@pytest.mark.parametrize('n', [2, 3, 4])
def test_symmetric_meetings_are_safe_and_settle(meetings, n):
    """Exact ties (S6.6 rule 4, S14.4) and 3-4 teams meeting at once (S7.5): safety, no
    livelock, the mission ends, everyone back on its path.
    """
    sc, res, m = meetings[n]
    assert m['prohibited_entries'] == 0
    assert m['min_inter_robot_distance_m'] > R_AA
    assert res.mission_end_s is not None and res.mission_end_s >= sc.duration_s
    assert all(r['final_error_m'] < 0.01 for r in m['robots'].values())
    assert not res.avoiding[-1].any()  # everybody exited: no livelock
    met = {e['robot'] for e in res.mode_events if e['mode'] in ('yield', 'mutual')}
    assert len(met) >= n - 1  # all but (at most) the team that went first gave way
    assert all(r['t_reach_s'] <= r['bound_s'] + 1e-9 for r in res.reaching)
    print(f'meet{n}: mission {res.mission_end_s:.1f} s of {sc.duration_s:.0f} s, min distance '
          f'{m["min_inter_robot_distance_m"]:.3f} m')
