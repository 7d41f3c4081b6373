"""A robot's own switching table (core/control/switching.py, docs/control-law.md S8.7): rows
R1-R4 on obstacles, each guard on a minimal geometric case (the S8.1 entry test, S8.2 more
urgent, S8.3 exit with T_dwell and T_min, S8.4 cool-down, S8.9 the progress monitor and parking,
S16.2 the floor), one sense per obstacle, and the coordinator's assignments applied.
"""

from __future__ import annotations

import math

from law_cases import (
    held_since,
    modes,
    obstacles,
    PRM,
    robot_decision,
    robots,
    set_mode,
)
import numpy as np
import pytest

from ament_formation.core.control.law_params import LawParams
from ament_formation.core.control.limit_cycle import choose_direction
from ament_formation.core.control.switching import (
    apply_assignment,
    begin_episode,
    choose_sense,
    cleared,
    KIND_OBSTACLE,
    KIND_ROBOT,
    MODE_C,
    MODE_MUTUAL,
    MODE_OBSTACLE,
    MODE_YIELD,
    parked,
    stalled,
    threat_test,
)
from ament_formation.core.model.ellipse import ray_time, segment_hits

BAR = obstacles({})  # P: (0.4, 0.15) at the origin; E 1.05 P, L 1.1 P, I 1.15 P, Q 1.8 P
TIMES = np.round(np.arange(0.0, 3.0, 0.1), 10)


def one(p, pd=(0.0, 0.0), goal=(2.0, 0.0), goal_dot=(0.05, 0.0), vc=None):
    """One robot at p; V_c = p_dot unless given."""
    return robots([p], [pd], goal=[goal], goal_dot=[goal_dot], vc=None if vc is None else [vc])


def on_bar(sense=1.0, t_entry=0.0):
    m = modes(1)
    set_mode(m, 0, MODE_OBSTACLE, 0, sense, t_entry)
    return m


def run_until_exit(m, times, vc_of_t, p=(0.6, 0.0), ob=BAR):
    for t in times:
        evs = robot_decision(t, m, one(p, (0.05, 0.0), vc=vc_of_t(t)), ob)
        if any(e[2] == 'exit' for e in evs):
            return t
    return None


# ------------------------------------------------------------------ R3: S8.3 exit


def test_r3_exit_waits_for_the_minimum_time_in_avoidance():
    m = on_bar()
    t_exit = run_until_exit(m, TIMES, lambda t: (0.05, 0.0))
    assert t_exit == pytest.approx(PRM.min_avoid_s)  # items 1-3 held from t = 0: T_min rules
    assert m.mode[0] == MODE_C and m.tgt[0] == -1
    # the S8.4 cool-down record of the exit
    assert (m.last_kind[0], m.last_tgt[0], m.last_exit[0]) == (KIND_OBSTACLE, 0, t_exit)


def test_r3_exit_needs_items_1_to_3_to_hold_for_the_dwell_time():
    m = on_bar()

    def toward(t):  # V_c points at the obstacle until t = 0.9 (item 3 fails), then away
        return (-0.05, 0.0) if t < 0.9 - 1e-9 else (0.05, 0.0)

    assert run_until_exit(m, TIMES, toward) == pytest.approx(0.9 + PRM.dwell_s)


def test_r3_the_dwell_window_restarts_when_the_items_break():
    m = on_bar()

    def vc(t):  # holds from 1.0, breaks at 1.2 (before the 0.3 s dwell), holds again from 1.3
        return (-0.05, 0.0) if (t < 1.0 - 1e-9 or abs(t - 1.2) < 1e-9) else (0.05, 0.0)

    assert run_until_exit(m, TIMES, vc) == pytest.approx(1.3 + PRM.dwell_s)


def test_r3_item_3_blocks_the_exit_while_the_coordination_field_heads_into_the_obstacle():
    m = on_bar()
    # items 1 and 2 hold (segment to the goal clear, outside E) but V_c heads back into I; the
    # robot is parked (its goal's anomaly is its own), so the progress monitor lets it be
    times = np.round(np.arange(0.0, 7.0, 0.1), 10)
    assert run_until_exit(m, times, lambda t: (-0.05, 0.001)) is None
    assert m.mode[0] == MODE_OBSTACLE and m.sdir[0] == 1.0
    assert run_until_exit(m, np.round(np.arange(7.0, 9.0, 0.1), 10), lambda t: (0.05, 0.0)) == (
        pytest.approx(7.0 + PRM.dwell_s))


def test_r3_item_1_a_goal_behind_the_obstacle_blocks_the_exit():
    m = on_bar()
    for t in TIMES:
        rb = one((0.6, 0.0), (0.05, 0.0), goal=(-1.0, 0.0), vc=(0.05, 0.0))
        assert robot_decision(t, m, rb, BAR) == []
    assert m.mode[0] == MODE_OBSTACLE


def test_cleared_items_one_by_one():
    def ok(p, g, vc, c=(0.0, 0.0), cv=(0.0, 0.0), phi_dot=0.0):
        return cleared(*p, *g, *vc, *c, *cv, 0.0, phi_dot, 0.4, 0.15, PRM)

    assert ok((0.6, 0.0), (2.0, 0.0), (0.05, 0.0))
    assert not ok((0.6, 0.0), (-1.0, 0.0), (0.05, 0.0))  # item 1: [p, g] crosses C = P
    assert ok((0.6, 0.2), (-1.0, 0.2), (0.0, 0.05))  # ... passing above it does not
    assert not ok((0.41, 0.0), (2.0, 0.0), (0.05, 0.0))  # item 2: inside E (0.42)
    assert not ok((0.6, 0.0), (2.0, 0.0), (-0.05, 0.0))  # item 3: V_c heads into I
    assert ok((0.6, 0.0), (2.0, 0.0), (0.0, 0.05))  # tangential: the ray misses I
    # item 3 relative to the obstacle's material point: an obstacle receding faster than the
    # robot approaches it lets the robot go; one coming at a robot at rest does not
    assert ok((0.6, 0.0), (2.0, 0.0), (-0.02, 0.0), cv=(-0.05, 0.0))
    assert not ok((0.6, 0.0), (2.0, 0.0), (0.0, 0.0), cv=(0.05, 0.0))


# ------------------------------------------------------------------ R4 from C: S8.1 entry


def test_r4_heading_entry_and_the_cool_down_block_only_that_obstacle_for_t_cool():
    # inside Q, outside E and I, heading at the obstacle: the S8.1 heading test holds
    rb = one((0.6, 0.0), (-0.05, 0.0))
    m = modes(1)
    m.last_kind[0], m.last_tgt[0], m.last_exit[0] = KIND_OBSTACLE, 0, 10.0
    assert robot_decision(10.5, m, rb, BAR) == []  # cooling down
    assert robot_decision(10.0 + PRM.cooldown_s - 0.01, m, rb, BAR) == []
    t = 10.0 + PRM.cooldown_s + 0.01
    assert [e[2:5] for e in robot_decision(t, m, rb, BAR)] == [('enter', 'obstacle', 0)]
    assert (m.mode[0], m.tgt[0], m.t_entry[0]) == (MODE_OBSTACLE, 0, t)
    # the cool-down of another obstacle, or of a robot of that index, does not block it
    for kind, tgt in ((KIND_OBSTACLE, 7), (KIND_ROBOT, 0)):
        other = modes(1)
        other.last_kind[0], other.last_tgt[0], other.last_exit[0] = kind, tgt, 10.0
        assert len(robot_decision(10.2, other, rb, BAR)) == 1


def test_r4_no_entry_when_not_heading_at_the_obstacle_or_outside_q():
    m = modes(1)
    assert robot_decision(0.0, m, one((0.6, 0.0), (0.0, 0.05)), BAR) == []  # ray misses I
    assert robot_decision(0.0, m, one((0.6, 0.0), (0.05, 0.0)), BAR) == []  # receding
    assert robot_decision(0.0, m, one((0.75, 0.0), (-0.05, 0.0)), BAR) == []  # outside Q (0.72)
    assert m.mode[0] == MODE_C


def test_r4_an_emergency_overrides_the_heading_test_and_the_cool_down():
    m = modes(1)
    m.last_kind[0], m.last_tgt[0], m.last_exit[0] = KIND_OBSTACLE, 0, 10.0
    # inside E (rho_em = 1.05) but outside P, moving away, cooling down: it enters
    assert [e[2:5] for e in robot_decision(10.1, m, one((0.41, 0.0), (0.05, 0.0)), BAR)] == [
        ('enter', 'obstacle', 0)]


def test_threat_test_flags_an_imminent_contact_with_p_as_an_emergency():
    # outside E, heading straight at P: P reached in (0.6 - 0.4) / v
    # imminent_s = 1.5 s (S18): 0.2 / 0.14 = 1.43 s is imminent, 0.2 / 0.13 = 1.54 s is not
    for v, em in ((0.2, True), (0.14, True), (0.13, False), (0.1, False), (0.05, False)):
        trig, emergency, lam, h_em, h_l = threat_test(0.6, 0.0, -v, 0.0, 0.0, 0.4, 0.15, 1.8,
                                                      PRM)
        assert trig and emergency == (0.2 / v < PRM.imminent_s), v
        assert lam == pytest.approx((0.6 - 1.15 * 0.4) / v)  # the ray to I
        assert h_em > 0.0 and h_l == pytest.approx((0.6 / 0.44) ** 2 - 1.0)
        assert emergency == em


def test_r4_a_rotating_bar_sweeping_toward_a_standing_robot_triggers_entry():
    """S14.2: the relative velocity of the material point includes the obstacle's rotation."""
    p = (0.35, 0.15)  # inside Q of a 0.4 x 0.1 bar, outside E
    for phi_dot, expect in ((0.0, 0), (-0.3, 0), (0.3, 1)):
        m = modes(1)
        bar = obstacles({'axes': (0.4, 0.1), 'phi_dot': phi_dot})
        assert len(robot_decision(0.0, m, one(p), bar)) == expect, phi_dot


def test_r4_the_most_urgent_obstacle_is_taken_emergencies_first():
    # two bars; the robot heads at the near one (contact later) while inside E of the far one
    two = obstacles({'center': (0.0, 0.0)}, {'center': (1.01, 0.0)})
    rb = one((0.6, 0.0), (-0.05, 0.0))  # 0.41 m from bar 1's centre: inside its E (0.42 m)
    m = modes(1)
    assert [e[2:5] for e in robot_decision(0.0, m, rb, two)] == [('enter', 'obstacle', 1)]
    # without the emergency, the earliest contact with I
    two = obstacles({'center': (0.0, 0.0)}, {'center': (1.3, 0.0)})
    rb = one((0.62, 0.0), (-0.05, 0.0))
    m = modes(1)
    assert [e[4] for e in robot_decision(0.0, m, rb, two)] == [0]


def test_r4_from_a_robot_encounter_waits_the_reason_dwell_unless_an_emergency():
    rb = robots([(0.6, 0.0), (0.6, 0.5)], [(-0.05, 0.0), (0.0, 0.0)])
    m = modes(2)
    set_mode(m, 0, MODE_YIELD, 1, 1.0, t_entry=1.0)
    assert robot_decision(1.0 + PRM.reason_dwell_s - 0.01, m, rb, BAR) == []
    assert m.mode[0] == MODE_YIELD
    t = 1.0 + PRM.reason_dwell_s
    assert [e[1:5] for e in robot_decision(t, m, rb, BAR)] == [
        (0, 'exit', 'yield', 1), (0, 'enter', 'obstacle', 0)]
    # S8.4: the exit from the robot encounter is its cool-down record
    assert (m.last_kind[0], m.last_tgt[0], m.last_exit[0]) == (KIND_ROBOT, 1, t)
    # inside the obstacle's E: at once, and a mutual partner becomes a plain yielder (S8.3)
    rb = robots([(0.41, 0.0), (0.6, 0.5)], [(-0.05, 0.0), (0.0, 0.0)])
    m = modes(2)
    set_mode(m, 0, MODE_MUTUAL, 1, -1.0, t_entry=1.0)
    set_mode(m, 1, MODE_MUTUAL, 0, -1.0, t_entry=1.0)
    assert [e[1:5] for e in robot_decision(1.1, m, rb, BAR)] == [
        (1, 'exit', 'mutual', 0), (1, 'enter', 'yield', 0), (0, 'exit', 'mutual', 1),
        (0, 'enter', 'obstacle', 0)]
    assert (m.mode[1], m.tgt[1], m.sdir[1]) == (MODE_YIELD, 0, -1.0)


# ------------------------------------------------------------------ R2: S8.2 more urgent


def test_r2_an_emergency_does_not_replace_a_target_that_is_itself_an_emergency():
    # two bars whose E overlap: the robot between them is inside both E (outside both P)
    both = obstacles({'axes': (0.4, 0.1)}, {'axes': (0.4, 0.1), 'center': (0.0, 0.205)})
    m = on_bar(t_entry=0.0)
    for t in (0.5, 0.51, 0.52):
        assert robot_decision(t, m, one((0.0, 0.1025), goal=(2.0, 0.1)), both) == []
    assert m.tgt[0] == 0


def test_r2_a_more_urgent_obstacle_replaces_the_current_one():
    # on bar 0 (below, out of its E), the robot closes on bar 1: P reached within imminent_s
    bars = obstacles({'axes': (0.4, 0.1)}, {'axes': (0.4, 0.1), 'center': (0.0, 0.44)})
    up = {'goal': (0.0, 2.0), 'goal_dot': (0.0, 0.0), 'vc': (0.0, 0.05)}
    m = on_bar(sense=-1.0)
    evs = robot_decision(3.0, m, one((0.0, 0.28), (0.0, 0.05), **up), bars)
    # both static: one sweep keeps the sense (S6.6 rule 5)
    assert [e[2:] for e in evs] == [('exit', 'obstacle', 0, -1.0), ('enter', 'obstacle', 1, -1.0)]
    assert (m.t_entry[0], m.since[0]) == (3.0, -1.0)
    # a rotating second obstacle takes its own S6.6 sense
    turning = obstacles({'axes': (0.4, 0.1)},
                        {'axes': (0.4, 0.1), 'center': (0.0, 0.44), 'phi_dot': 0.2})
    rb = one((0.0, 0.28), (0.0, 0.05), **up)
    m = on_bar(sense=-1.0)
    evs = robot_decision(3.0, m, rb, turning)
    assert [e[4] for e in evs] == [0, 1]
    fresh = modes(1)
    assert evs[1][5] == choose_sense(0, 1, rb, turning, fresh, PRM)


def test_r2_takes_a_target_whose_limit_cycle_is_nearer_but_not_a_farther_one():
    # on bar 0; bar 1 triggers its heading test; h_L(bar 1) < h_L(bar 0): re-target
    bars = obstacles({'center': (0.0, 0.0)}, {'center': (1.05, 0.0)})
    m = on_bar()
    evs = robot_decision(2.0, m, one((0.55, 0.0), (0.05, 0.0), goal=(3.0, 0.0)), bars)
    assert [e[2:5] for e in evs] == [('exit', 'obstacle', 0), ('enter', 'obstacle', 1)]
    # nearer to bar 0's L than to bar 1's: kept
    m = on_bar()
    evs = robot_decision(2.0, m, one((0.48, 0.0), (0.05, 0.0), goal=(3.0, 0.0)), bars)
    assert [e[2:5] for e in evs if e[2] == 'enter'] == []


# ------------------------------------------------------------------ R1: S8.9 progress monitor


def test_the_progress_monitor_anchors_re_anchors_on_motion_and_stalls_after_stall_time():
    p = np.array([[1.0, 1.0]])
    anchor, t_anchor = np.full((1, 2), np.nan), np.zeros(1)
    assert not stalled(0, 2.0, p, anchor, t_anchor, PRM)  # first call: anchored here
    assert anchor.tolist() == [[1.0, 1.0]] and t_anchor[0] == 2.0
    p[0, 0] += PRM.stall_distance_m * 0.9  # a little motion is no progress
    assert not stalled(0, 2.0 + PRM.stall_time_s - 0.01, p, anchor, t_anchor, PRM)
    assert stalled(0, 2.0 + PRM.stall_time_s, p, anchor, t_anchor, PRM)
    p[0, 0] += PRM.stall_distance_m * 0.2  # now beyond the distance: progress, re-anchored
    assert not stalled(0, 8.0, p, anchor, t_anchor, PRM)
    assert anchor[0, 0] == p[0, 0] and t_anchor[0] == 8.0


def test_an_avoidance_episode_starts_the_monitor_again_unless_it_follows_another_closely():
    p = np.array([[0.0, 0.0]])
    m = modes(1)
    held_since(m, 0, (5.0, 5.0), 1.0)
    m.last_exit[0] = 8.0 - PRM.stall_time_s  # left an avoidance long enough ago
    begin_episode(0, 8.0, p, m, PRM)
    assert m.anchor[0].tolist() == [0.0, 0.0] and m.t_anchor[0] == 8.0
    held_since(m, 0, (5.0, 5.0), 1.0)
    m.last_exit[0] = 8.0 - PRM.stall_time_s + 0.1  # one episode: flipping between reasons
    begin_episode(0, 8.0, p, m, PRM)
    assert m.anchor[0].tolist() == [5.0, 5.0] and m.t_anchor[0] == 1.0


def _held_on_bar(t, goal, sense=1.0, prm=PRM, p=(0.0, 0.28), ob=None):
    ob = obstacles({'axes': (0.4, 0.1)}) if ob is None else ob
    m = on_bar(sense)
    held_since(m, 0, p, 0.0)
    return m, robot_decision(t, m, one(p, goal=goal, goal_dot=(0.0, 0.0), vc=(0.0, 0.0)), ob, 0,
                             prm)


def test_r1_a_robot_stalled_on_its_obstacle_turns_the_other_way_unless_parked():
    far = (0.0, -1.0)  # its goal on the far side
    m, evs = _held_on_bar(PRM.stall_time_s - 0.01, far)
    assert evs == [] and m.sdir[0] == 1.0
    t = PRM.stall_time_s
    m, evs = _held_on_bar(t, far)
    assert [e[2:] for e in evs] == [('exit', 'obstacle', 0, 1.0), ('enter', 'obstacle', 0, -1.0)]
    assert m.t_anchor[0] == t and m.t_entry[0] == t  # it acted: the monitor starts again
    # parked: its goal's anomaly is its own (the field asks it to wait, S6.5)
    m, evs = _held_on_bar(t, (0.0, 1.0))
    assert evs == [] and m.sdir[0] == 1.0
    assert parked(0.0, 0.28, 0.0, 1.0, 0.0, 0.0, 0.0, 0.4, 0.1, PRM)
    assert not parked(0.0, 0.28, 0.0, -1.0, 0.0, 0.0, 0.0, 0.4, 0.1, PRM)


def test_r1_a_re_target_between_two_static_obstacles_does_not_restart_the_monitor():
    # docs/law-changes.md §26 (crossing-s1-1660): a robot held still between two static
    # obstacles re-targeted between them; the monitor keeps its anchor across R2, so at
    # stall_time_s it turns
    bars = obstacles({'axes': (0.4, 0.1)}, {'axes': (0.4, 0.1), 'center': (0.0, 0.44)})
    up = {'goal': (0.0, 2.0), 'goal_dot': (0.0, 0.0), 'vc': (0.0, 0.05)}
    m = on_bar()
    held_since(m, 0, (0.0, 0.28), 0.0)
    evs = robot_decision(3.0, m, one((0.0, 0.28), (0.0, 0.05), **up), bars)
    assert [(e[2], e[4], e[5]) for e in evs] == [('exit', 0, 1.0), ('enter', 1, 1.0)]
    evs = robot_decision(PRM.stall_time_s, m, one((0.0, 0.28), (0.0, 0.0), **up), bars)
    assert [(e[2], e[4], e[5]) for e in evs] == [('exit', 1, 1.0), ('enter', 1, -1.0)]


def test_r1_a_robot_held_still_does_not_turn_into_a_pass_the_floor_closes():
    # docs/law-changes.md §27 (crossing-s1-1258): held still on top of an obstacle whose limit
    # cycle runs off the floor at its bottom, a robot reversed into the closed pass
    bar = obstacles({'axes': (0.3, 0.15), 'center': (1.5, 0.25)})
    top, goal = (1.5, 0.415), (2.2, 0.3)  # its way, clockwise, stays on the floor

    def held(prm):
        m, evs = _held_on_bar(5.0, goal, sense=-1.0, prm=prm, p=top, ob=bar)
        return [(e[2], e[5]) for e in evs], m.sdir[0]

    assert held(LawParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()) == ([], -1.0)  # waits
    assert held(PRM) == ([('exit', -1.0), ('enter', 1.0)], 1.0)  # no floor: it turns
    low = LawParams(floor_m=(0.0, 3.0, -1.0, 2.5)).compiled()
    assert held(low) == ([('exit', -1.0), ('enter', 1.0)], 1.0)  # the pass is open


def test_r1_a_moving_robot_turns_when_the_floor_closes_its_way_ahead_and_the_other_is_open():
    # formation-s2-528: an obstacle moving toward a corner closed, after the entry, the arc a
    # robot was on; sliding along the wall it kept "moving" and was never stalled, and was
    # pressed off the floor. S16.2 now holds on the obstacle too, once T_min after the entry.
    bar = obstacles({'axes': (0.3, 0.15), 'center': (1.5, 0.25)})
    top, goal = (1.5, 0.415), (2.2, 0.3)  # counter-clockwise runs under the closed bottom
    walled = LawParams(floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()

    def moving(t, prm, sense=1.0, t_entry=0.0):
        m = on_bar(sense, t_entry)
        held_since(m, 0, top, t - 0.5)  # the monitor re-anchored half a second ago
        evs = robot_decision(t, m, one(top, (0.02, 0.0), goal=goal, goal_dot=(0.0, 0.0),
                                       vc=(0.0, 0.0)), bar, 0, prm)
        return [(e[2], e[5]) for e in evs], m.sdir[0]

    t = walled.min_avoid_s
    assert moving(t, walled) == ([('exit', 1.0), ('enter', -1.0)], -1.0)
    assert moving(t - 0.01, walled) == ([], 1.0)  # not within T_min of the entry
    assert moving(t, walled, sense=-1.0) == ([], -1.0)  # its way is the open one
    assert moving(t, PRM) == ([], 1.0)  # no floor, no stall: it keeps its sense
    both = LawParams(floor_m=(0.0, 3.0, 0.2, 2.5)).compiled()  # both ways closed: kept
    assert moving(t, both) == ([], 1.0)
    # another robot goes round the bar its way: one sense per obstacle (S14.6) keeps it
    m = modes(2)
    for i in (0, 1):
        set_mode(m, i, MODE_OBSTACLE, 0, 1.0, 0.0)
    held_since(m, 0, top, t - 0.5)
    rb = robots([top, (1.1, 0.25)], [(0.02, 0.0), (0.0, -0.02)], goal=[goal, (0.5, 0.25)],
                goal_dot=[(0.0, 0.0), (0.0, 0.0)], vc=[(0.0, 0.0), (0.0, 0.0)])
    assert robot_decision(t, m, rb, bar, 0, walled) == [] and m.sdir[0] == 1.0


# ------------------------------------------------------------------ the sense (S6.6, S14.6)


def test_one_sense_per_obstacle_a_robot_takes_the_sense_of_a_known_robot_already_on_it():
    rb = robots([(0.6, 0.0), (-0.6, 0.0)], [(-0.05, 0.0), (0.0, 0.0)],
                goal=[(2.0, 0.6), (-2.0, 0.0)])
    m = modes(2)
    own = choose_sense(0, 0, rb, BAR, m, PRM)
    set_mode(m, 1, MODE_OBSTACLE, 0, -own)
    assert choose_sense(0, 0, rb, BAR, m, PRM) == -own
    rb.known[1] = False  # a robot not heard does not count
    assert choose_sense(0, 0, rb, BAR, m, PRM) == own
    # its own sense is S6.6's: the shorter arc to the goal (the goal up-right: over the top is
    # clockwise seen from the robot on the right? no: counter-clockwise)
    assert own == choose_direction(0.6, 0.0, -0.05, 0.0, 2.0, 0.6, 0.0, 0.0, 0.0, 0.44, 0.165,
                                   2 * 1.8 * 0.4, True)


def test_choose_direction_takes_the_shorter_arc_and_breaks_ties_by_motion():
    s_up = choose_direction(-0.6, 0.0, 0.05, 0.0, 0.3, 0.5, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True)
    s_down = choose_direction(-0.6, 0.0, 0.05, 0.0, 0.3, -0.5, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0,
                              True)
    assert s_up == -1.0 and s_down == 1.0  # over the top = clockwise seen from above
    # the goal straight behind: a tie -> continue the current tangential motion (rule 4) ...
    tie = (-0.6, 0.0, 0.05, 0.02, 0.6, 0.0, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True)
    assert choose_direction(*tie) == -1.0
    assert choose_direction(*tie[:3], -0.02, *tie[4:]) == 1.0
    # ... or +1 for a yielding robot (rule 7)
    assert choose_direction(-0.6, 0.0, 0.05, 0.02, 0.6, 0.0, 0.0, 0.0, 0.0, 0.44, 0.44, 0.0,
                            False) == 1.0


def test_geometry_helpers():
    assert ray_time(1.0, 0.0, -1.0, 0.0, 0.0, 0.5, 0.2) == pytest.approx(0.5)
    assert ray_time(1.0, 0.0, 1.0, 0.0, 0.0, 0.5, 0.2) == math.inf
    assert ray_time(0.1, 0.0, 1.0, 0.0, 0.0, 0.5, 0.2) == 0.0
    assert segment_hits(-1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.2)
    assert not segment_hits(-1.0, 0.3, 1.0, 0.3, 0.0, 0.0, 0.0, 0.5, 0.2)


# ------------------------------------------------------------------ the coordinator's word


def _assign(m, mode, row, sense=1.0, t_entry=2.0, w=(0.0, 0.0), park_at=-math.inf, t=2.5):
    ev = np.zeros((8, 6))
    from law_cases import events

    return events(ev, apply_assignment(0, t, mode, row, sense, t_entry, *w, park_at, m, ev, 0))


def test_an_assignment_is_entered_updated_changed_and_withdrawn():
    m = modes(3)
    assert [e[2:] for e in _assign(m, MODE_MUTUAL, 1, -1.0, w=(0.01, 0.02))] == [
        ('enter', 'mutual', 1, -1.0)]
    assert (m.mode[0], m.tgt[0], m.t_entry[0]) == (MODE_MUTUAL, 1, 2.0)  # the pair's t_entry
    assert m.wc[0].tolist() == [0.01, 0.02] and m.wtgt[0].tolist() == [0.01, 0.02]
    # the same encounter again: no event, the newest drift taken
    assert _assign(m, MODE_MUTUAL, 1, -1.0, w=(0.03, 0.0), t=2.6) == []
    assert m.wc[0].tolist() == [0.03, 0.0]
    # another partner or sense: the old one ends, the new one starts
    assert [e[2:] for e in _assign(m, MODE_YIELD, 2, 1.0, t_entry=3.0, t=3.0)] == [
        ('exit', 'mutual', 1, -1.0), ('enter', 'yield', 2, 1.0)]
    # withdrawn: back to C, the cool-down record of robot 2
    assert [e[2:] for e in _assign(m, MODE_C, -1, t=4.0)] == [('exit', 'yield', 2, 1.0)]
    assert (m.mode[0], m.last_kind[0], m.last_tgt[0], m.last_exit[0]) == (
        MODE_C, KIND_ROBOT, 2, 4.0)
    assert _assign(m, MODE_C, -1, t=4.1) == []


def test_on_an_obstacle_a_robot_keeps_its_mode_and_takes_only_a_request_to_make_way():
    m = modes(2)
    set_mode(m, 0, MODE_OBSTACLE, 0, 1.0, t_entry=1.0)
    assert _assign(m, MODE_YIELD, 1, park_at=12.0) == []  # static obstacles beat robots
    assert (m.mode[0], m.tgt[0], m.park_at[0]) == (MODE_OBSTACLE, 0, 12.0)
    assert _assign(m, MODE_C, -1, park_at=5.0) == []  # a later request never shortens it
    assert m.park_at[0] == 12.0
