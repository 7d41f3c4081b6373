"""S8 switching automaton: exit dwell and T_min, cool-down, emergency override, exit item 3, the
S14.2 rotating-obstacle entry test (decisions evaluated with the compiled ``decide``).
"""

import numpy as np
import pytest

from ament_formation.core.control.automaton import (
    AutomatonState,
    exit_conditions,
    MODE_C,
    MODE_OBSTACLE,
    SwitchingParams,
)
from ament_formation.core.control.encounters import decide_once, KIND_OBSTACLE
from ament_formation.core.control.limit_cycle import choose_direction
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.ellipse import ray_time, segment_hits

PRM = SwitchingParams().compiled()
AV = SwitchingParams().avoidance


def obstacle(axes=(0.4, 0.15), phi=0.0, phi_dot=0.0, center=(0.0, 0.0), vel=(0.0, 0.0)):
    static = phi_dot == 0.0 and vel == (0.0, 0.0)
    return (
        np.array([center], float),
        np.array([vel], float),
        np.array([phi]),
        np.array([phi_dot]),
        np.array([axes], float),
        np.array([static]),
    )


def two_static(second, axes):
    """Two static obstacles of semi-axes ``axes``, at the origin and at ``second``."""
    return (
        np.array([[0.0, 0.0], second], float),
        np.zeros((2, 2)),
        np.zeros(2),
        np.zeros(2),
        np.array([axes, axes], float),
        np.array([True, True]),
    )


def step(state, t, p, pd, goal=(2.0, 0.0), goal_dot=(0.05, 0.0), vc=None, obs=None):
    vc = pd if vc is None else vc
    return decide_once(
        t,
        state,
        np.array([p], float),
        np.array([pd], float),
        np.array([goal], float),
        np.array([goal_dot], float),
        np.array([vc], float),
        np.zeros(1, np.int64),
        np.array([0.1]),
        obs or obstacle(),
        PRM,
    )


def run_until_exit(state, times, vc_of_t, p=(0.6, 0.0)):
    for t in times:
        events = step(state, t, p, (0.05, 0.0), vc=vc_of_t(t))
        if any(e[2] == 'exit' for e in events):
            return t
    return None


def test_exit_waits_for_min_time_in_avoidance():
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    t_exit = run_until_exit(st, np.round(np.arange(0.0, 3.0, 0.1), 10), lambda t: (0.05, 0.0))
    assert t_exit == pytest.approx(AV.min_avoid_s)  # conditions held from t = 0: T_min rules
    assert st.mode[0] == MODE_C


def test_exit_needs_dwell_of_continuously_holding_conditions():
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)

    # V_c points at the obstacle until t = 0.9 (item 3 fails), then away
    def toward(t):
        return (-0.05, 0.0) if t < 0.9 - 1e-9 else (0.05, 0.0)

    t_exit = run_until_exit(st, np.round(np.arange(0.0, 3.0, 0.1), 10), toward)
    assert t_exit == pytest.approx(0.9 + AV.dwell_s)


def test_dwell_window_restarts_when_conditions_break():
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)

    # holds from 1.0, breaks at 1.2 (before the 0.3 s dwell), holds again from 1.3
    def vc(t):
        return (-0.05, 0.0) if (t < 1.0 - 1e-9 or abs(t - 1.2) < 1e-9) else (0.05, 0.0)

    t_exit = run_until_exit(st, np.round(np.arange(0.0, 3.0, 0.1), 10), vc)
    assert t_exit == pytest.approx(1.3 + AV.dwell_s)


def test_exit_item3_blocks_exit_while_coordination_field_heads_into_obstacle():
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    # items 1 and 2 hold (segment to the goal clear, outside E) but V_c heads back into I
    assert (
        run_until_exit(st, np.round(np.arange(0.0, 5.0, 0.1), 10), lambda t: (-0.05, 0.001))
        is None
    )
    assert st.mode[0] == MODE_OBSTACLE
    # the same geometry with V_c pointing away: exit
    assert (
        run_until_exit(st, np.round(np.arange(5.0, 7.0, 0.1), 10), lambda t: (0.05, 0.0))
        is not None
    )


def test_item1_goal_behind_obstacle_blocks_exit():
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    for t in np.round(np.arange(0.0, 3.0, 0.1), 10):
        events = step(st, t, (0.6, 0.0), (0.05, 0.0), goal=(-1.0, 0.0), vc=(0.05, 0.0))
        assert events == []
    assert st.mode[0] == MODE_OBSTACLE


def test_heading_entry_and_cooldown_block_only_that_obstacle_for_t_cool():
    # inside Q, outside E and I, heading at the obstacle: the S8.1 heading test holds
    p, pd = (0.6, 0.0), (-0.05, 0.0)
    st = AutomatonState(1)
    st.last_kind[0], st.last_tgt[0], st.last_exit[0] = KIND_OBSTACLE, 0, 10.0
    assert step(st, 10.5, p, pd) == []  # in cool-down
    assert step(st, 10.0 + AV.cooldown_s - 0.01, p, pd) == []
    events = step(st, 10.0 + AV.cooldown_s + 0.01, p, pd)
    assert [(e[2], e[3], e[4]) for e in events] == [('enter', MODE_OBSTACLE, 0)]
    # a different obstacle is not blocked by the cool-down of obstacle 0
    st2 = AutomatonState(1)
    st2.last_kind[0], st2.last_tgt[0], st2.last_exit[0] = KIND_OBSTACLE, 7, 10.0
    assert len(step(st2, 10.2, p, pd)) == 1


def test_no_entry_when_not_heading_toward_obstacle():
    st = AutomatonState(1)
    assert step(st, 0.0, (0.6, 0.0), (0.0, 0.05)) == []  # tangential: ray misses I
    assert step(st, 0.0, (0.6, 0.0), (0.05, 0.0)) == []  # receding: h_dot > 0
    assert st.mode[0] == MODE_C


def test_emergency_overrides_heading_and_cooldown():
    st = AutomatonState(1)
    st.last_kind[0], st.last_tgt[0], st.last_exit[0] = KIND_OBSTACLE, 0, 10.0
    # inside E (rho_em = 1.05) but outside P, moving away, in cool-down: avoidance is forced
    events = step(st, 10.1, (0.41, 0.0), (0.05, 0.0))
    assert [(e[2], e[3]) for e in events] == [('enter', MODE_OBSTACLE)]


def test_rotating_bar_sweeping_toward_a_standing_robot_triggers_entry():
    """S14.2: the relative velocity of the material point includes the obstacle's rotation."""
    p, pd = (0.35, 0.15), (0.0, 0.0)  # inside Q of a 0.4 x 0.1 bar, outside E
    for phi_dot, expect in ((0.0, 0), (-0.3, 0), (0.3, 1)):
        st = AutomatonState(1)
        events = step(st, 0.0, p, pd, obs=obstacle(axes=(0.4, 0.1), phi_dot=phi_dot))
        assert len(events) == expect, phi_dot


def test_emergency_does_not_replace_a_target_that_is_itself_an_emergency():
    obs = two_static((0.0, 0.44), (0.4, 0.1))
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    # p is inside E of both bars: keep the current target (no flip every decision)
    for t in (0.5, 0.51, 0.52):
        assert step(st, t, (0.0, 0.22), (0.0, 0.0), obs=obs) == []
    assert st.tgt[0] == 0


def test_geometry_helpers():
    assert ray_time(1.0, 0.0, -1.0, 0.0, 0.0, 0.5, 0.2) == pytest.approx(0.5)
    assert ray_time(1.0, 0.0, 1.0, 0.0, 0.0, 0.5, 0.2) == np.inf
    assert ray_time(0.1, 0.0, 1.0, 0.0, 0.0, 0.5, 0.2) == 0.0
    assert segment_hits(-1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.2)
    assert not segment_hits(-1.0, 0.3, 1.0, 0.3, 0.0, 0.0, 0.0, 0.5, 0.2)
    assert exit_conditions(
        0.6, 0.0, 2.0, 0.0, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.15, PRM
    )


def test_direction_choice_takes_shorter_arc_and_breaks_ties_by_motion():
    # robot left of an ellipse (z = (-0.6, 0)), goal up-right: CW (over the top) is shorter? The
    # goal at anomaly ~ +60 deg is reached CW from 180 deg through 90 deg: that is the CCW... check
    # both
    s_up = choose_direction(-0.6, 0.0, 0.05, 0.0, 0.3, 0.5, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True)
    s_down = choose_direction(
        -0.6, 0.0, 0.05, 0.0, 0.3, -0.5, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True
    )
    assert s_up == -1.0 and s_down == 1.0  # over the top = clockwise seen from above
    # goal straight behind: tie -> continue the current tangential motion (rule 4) ...
    assert (
        choose_direction(-0.6, 0.0, 0.05, 0.02, 0.6, 0.0, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True)
        == -1.0
    )
    assert (
        choose_direction(-0.6, 0.0, 0.05, -0.02, 0.6, 0.0, 0.0, 0.0, 0.0, 0.44, 0.165, 0.0, True)
        == 1.0
    )
    # ... or +1 for a yielding robot (rule 7)
    assert (
        choose_direction(-0.6, 0.0, 0.05, 0.02, 0.6, 0.0, 0.0, 0.0, 0.0, 0.44, 0.44, 0.0, False)
        == 1.0
    )


def test_switching_params_compile_and_check_the_teammate_hysteresis():
    # docs/law-changes.md §11: the release threshold reaches the compiled law, and it is a
    # hysteresis: never below the plain teammate threshold
    prm = SwitchingParams(teammate_release_speed_mps=0.05).compiled()
    assert prm.teammate_release_speed_mps == 0.05
    assert PRM.teammate_release_speed_mps >= PRM.teammate_rel_speed_mps
    with pytest.raises(ConfigError, match='teammate_release_speed_mps'):
        SwitchingParams(teammate_release_speed_mps=0.01)
    with pytest.raises(ConfigError, match='teammate_release_speed_mps'):
        SwitchingParams(teammate_release_speed_mps=float('nan'))


def test_one_sweep_round_static_obstacles_keeps_its_time_so_a_robot_held_still_turns():
    # docs/law-changes.md §26 (crossing-s1-1660, camera and ideal): two robots met in the gap
    # between two static obstacles and re-targeted between them every second (S8.2, then the
    # S8.4 cool-down); each re-targeting restarted the time in avoidance, so the liveness rule
    # (§8, STUCK_S = 5 s) never turned them, and they stayed there to the end
    bars = two_static((0.0, 0.44), (0.4, 0.1))
    up = {'goal': (0.0, 2.0), 'goal_dot': (0.0, 0.0), 'vc': (0.0, 0.05)}
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    events = step(st, 3.0, (0.0, 0.28), (0.0, 0.05), obs=bars, **up)
    assert [(e[2], e[4], e[5]) for e in events] == [('exit', 0, 1.0), ('enter', 1, 1.0)]
    # one sweep (S6.6 rule 5): for liveness, timed from its first obstacle; its entry time (S8.3
    # T_min, the gain schedule) is the new obstacle's
    assert (st.t_entry[0], st.sweep_s[0]) == (3.0, 3.0)
    events = step(st, 5.0, (0.0, 0.28), (0.0, 0.0), obs=bars, **up)  # held still since 0.0
    assert [(e[2], e[4], e[5]) for e in events] == [('exit', 1, 1.0), ('enter', 1, -1.0)]
    # a rotating second obstacle is a new avoidance, timed from its entry
    c, v, phi, phi_dot, axes, _static = bars
    turning = (c, v, phi, np.array([0.0, 0.2]), axes, np.array([True, False]))
    st = AutomatonState(1)
    st.set_mode(0, MODE_OBSTACLE, 0, 1.0, 0.0)
    step(st, 3.0, (0.0, 0.28), (0.0, 0.05), obs=turning, **up)
    assert st.tgt[0] == 1 and (st.t_entry[0], st.sweep_s[0]) == (3.0, 0.0)


def test_a_robot_held_still_does_not_turn_into_a_pass_the_floor_closes():
    # docs/law-changes.md §27 (crossing-s1-1258, ideal): held still on top of an obstacle whose
    # limit cycle runs off the floor at its bottom, a robot reversed (§8) into the closed pass
    # and then reversed every 5 s there, 0.88 m from its goal, to the end of the run
    import dataclasses

    bar = obstacle(axes=(0.3, 0.15), center=(1.5, 0.25))
    top, goal = (1.5, 0.415), (2.2, 0.3)  # its way, clockwise, stays on the floor

    def held(prm):
        st = AutomatonState(1)
        st.set_mode(0, MODE_OBSTACLE, 0, -1.0, 0.0)
        events = decide_once(
            5.0,
            st,
            np.array([top]),
            np.zeros((1, 2)),
            np.array([goal]),
            np.zeros((1, 2)),
            np.array([(0.05, 0.0)]),
            np.zeros(1, np.int64),
            np.array([0.1]),
            bar,
            prm,
        )
        return [(e[2], e[5]) for e in events], st.sdir[0]

    floor = dataclasses.replace(SwitchingParams(), floor_m=(0.0, 3.0, 0.0, 2.5)).compiled()
    assert held(floor) == ([], -1.0)  # it waits on its open side
    assert held(PRM) == ([('exit', -1.0), ('enter', 1.0)], 1.0)  # no floor: §8 as before
    low_floor = dataclasses.replace(SwitchingParams(), floor_m=(0.0, 3.0, -1.0, 2.5)).compiled()
    assert held(low_floor) == ([('exit', -1.0), ('enter', 1.0)], 1.0)  # the pass is open
