"""Formations that re-form (core/control/progress.py, docs/control-law.md S17): a leader's
reference r(s) at its progress s and its derivatives, the teams' errors, the rate targets (slow
down, wait, give way, a parked leader moves on, the finish rule), the bounded progress rate, and
the mission's end (the coordinator's decision, core/control/arbitration.coordinate).
"""

from __future__ import annotations

import math

from law_cases import modes, obstacles, PRM, robots
import numpy as np
import pytest

from ament_formation.core.control.arbitration import coordinate, new_teams
from ament_formation.core.control.progress import (
    at,
    finish_wait_s,
    leader_reference,
    max_time_s,
    max_wait_s,
    new_progress,
    rate_target,
    rate_targets,
    step,
    tabulate,
    team_errors,
)
from ament_formation.core.model.paths import path_from_config

SINE = path_from_config({'type': 'sinusoid', 'start_m': [0.0, 0.0], 'amplitude_m': 0.2,
                         'wavenumber_radpm': math.pi, 'speed_mps': 0.05})
WAYPOINTS = path_from_config({'type': 'waypoints', 'points_m': [[0, 0], [1.0, 0.0], [1.0, 1.0]],
                              'speed_mps': 0.08})
LINE = path_from_config({'type': 'line', 'start_m': [0.0, 0.0], 'heading_rad': 0.5,
                         'speed_mps': 0.05})
NOTHING = obstacles()


def _ref(refs, i, s, sd, sdd):
    out = np.zeros(6)
    leader_reference(refs, i, s, sd, sdd, out)
    return out


@pytest.mark.parametrize('path', [SINE, WAYPOINTS, LINE], ids=['sinusoid', 'waypoints', 'line'])
def test_r_of_s_at_the_nominal_rate_is_the_path_itself(path):
    refs = tabulate([path, None], 30.0)
    assert list(refs.row) == [0, -1] and refs.s_end == 30.0
    for s in (0.0, 3.21, 7.77, 19.3):
        r, rd, rdd = (np.asarray(v) for v in path.reference(s))
        out = _ref(refs, 0, s, 1.0, 0.0)
        np.testing.assert_allclose(out[:2], r, atol=1e-9)
        np.testing.assert_allclose(out[2:4], rd, atol=1e-8)
        np.testing.assert_allclose(out[4:6], rdd, atol=2e-6)


@pytest.mark.parametrize('path', [SINE, WAYPOINTS], ids=['sinusoid', 'waypoints'])
def test_r_dot_and_r_ddot_along_a_varying_progress_match_finite_differences(path):
    # s(t) slowing and speeding up: s_dot = 0.6 + 0.4 cos(t), s_ddot = -0.4 sin(t)
    refs = tabulate([path], 30.0)

    def s_of(t):
        return 0.6 * t + 0.4 * math.sin(t), 0.6 + 0.4 * math.cos(t), -0.4 * math.sin(t)

    h = 1e-3
    for t in (1.0, 4.0, 7.3, 11.0, 16.9):
        out = _ref(refs, 0, *s_of(t))
        before, after = _ref(refs, 0, *s_of(t - h)), _ref(refs, 0, *s_of(t + h))
        np.testing.assert_allclose(out[2:4], (after[:2] - before[:2]) / (2 * h), atol=2e-6)
        np.testing.assert_allclose(out[4:6], (after[2:4] - before[2:4]) / (2 * h), atol=2e-5)


def test_the_reference_rests_at_its_end():
    refs = tabulate([LINE], 10.0)
    end = _ref(refs, 0, 10.0, 1.0, 0.0)
    np.testing.assert_allclose(end[:2], LINE.reference(10.0)[0], atol=1e-9)
    np.testing.assert_allclose(_ref(refs, 0, 12.0, 0.0, 0.0)[:2], end[:2])  # clamped to s_end
    pr = new_progress(1)
    pr.s[0], pr.sd[0], pr.sdd[0] = 9.9, 1.0, 0.0
    assert at(pr, 0, 0.5, 10.0) == (10.0, 0.0, 0.0)  # reached within the interval: rest
    s, sd, sdd = at(pr, 0, 0.05, 10.0)
    assert (s, sd, sdd) == (pytest.approx(9.95), 1.0, 0.0)


# ------------------------------------------------------------------ S17.1 rate targets


def test_the_rate_target_slows_from_reform_start_to_a_wait_at_reform_stop():
    lo, hi = PRM.reform_start_m, PRM.reform_stop_m
    assert rate_target(0.0, 1.0, PRM) == 1.0
    assert rate_target(lo, 1.0, PRM) == pytest.approx(1.0)
    assert rate_target(0.5 * (lo + hi), 1.0, PRM) == pytest.approx(0.5)
    assert rate_target(hi, 1.0, PRM) == pytest.approx(0.0)
    assert rate_target(2.0, 1.0, PRM) == 0.0
    assert rate_target(0.0, 0.0, PRM) == 0.0  # giving way to a team before it (S7.5)
    e = np.linspace(0.0, 1.0, 201)
    r = np.array([rate_target(v, 1.0, PRM) for v in e])
    assert np.all(np.diff(r) <= 1e-15) and r.min() == 0.0 and r.max() == 1.0  # monotone


def _targets(e_team, s, giving=None, s_end=30.0, t=None):
    n = len(e_team)
    pr = new_progress(n)
    pr.s[:] = s
    out = np.full(n, np.nan)
    leaders = np.arange(n, dtype=np.int64)
    way = np.ones(n) if giving is None else 1.0 - np.array(giving, float)  # the S7.5 cap
    t = max(s) if t is None else t  # no lag unless asked
    rate_targets(t, np.array(e_team, float), way, pr, leaders, s_end, PRM, out)
    return out.tolist()


def test_a_reference_waits_at_most_its_budget_then_moves_on():
    # S17.2: max(20 s, max_wait_fraction * s_end) of lag in all, then the target is 1 whatever
    # the team's error or giving way
    budget = max_wait_s(30.0, PRM)
    assert budget == pytest.approx(max(20.0, PRM.max_wait_fraction * 30.0))
    far = PRM.reform_stop_m + 0.1
    assert _targets([far, far], [5.0, 5.0], giving=[False, True], t=5.0 + budget - 0.01) == [
        0.0, 0.0]
    assert _targets([far, far], [5.0, 5.0], giving=[False, True], t=5.0 + budget) == [1.0, 1.0]


def test_the_finish_wait_outlasts_the_budget_and_still_ends_within_the_runs_cap():
    # S17.3: at its finish a reference waits for the teams past the S17.2 budget (a leader held
    # up on an obstacle is not left 0.9 m short of its goal, pairsense65), up to finish_wait_s
    budget, room = max_wait_s(30.0, PRM), finish_wait_s(30.0, PRM)
    assert budget < room
    assert 30.0 + room + PRM.finish_s + PRM.progress_tau_s < max_time_s(30.0)
    assert finish_wait_s(5.0, PRM) > max_wait_s(5.0, PRM)  # short missions too
    far = PRM.reform_stop_m + 0.1
    near_end = 30.0 - PRM.finish_s + 0.1
    assert _targets([far, 0.0], [near_end, near_end], t=near_end + budget + 1.0) == [0.0, 0.0]
    assert _targets([far, 0.0], [near_end, near_end], t=near_end + room + 0.01) == [1.0, 1.0]
    # away from the finish, the budget alone counts (the S17.2 test above)
    assert _targets([far, 0.0], [20.0, 20.0], t=20.0 + budget) == [1.0, 1.0]


def test_rate_targets_per_team_a_parked_leader_moves_on_and_the_finish_rule():
    mid = 0.5 * (PRM.reform_start_m + PRM.reform_stop_m)
    assert _targets([0.0, mid, 0.3], [5.0, 5.0, 5.0], giving=[False, False, True]) == [
        1.0, pytest.approx(0.5), 0.0]
    # E < 0: the leader's own goal lies in an obstacle's Q; it is parked there by design, its
    # reference must carry it out, however far its team is
    assert _targets([-0.8, 0.0], [5.0, 5.0]) == [1.0, 1.0]
    # within finish_s of its end, a reference waits while some team is not re-formed ...
    near_end = 30.0 - PRM.finish_s + 0.1
    assert _targets([0.0, 0.5], [near_end, 10.0]) == [0.0, 0.0]
    # ... not before it, and not once every team is within reform_stop_m
    assert _targets([0.0, 0.5], [30.0 - PRM.finish_s - 0.1, 10.0]) == [1.0, 0.0]
    assert _targets([0.0, 0.3], [near_end, 10.0])[0] == 1.0


def test_the_progress_rate_follows_its_target_with_a_bounded_acceleration():
    pr = new_progress(1)
    dt, s_end = 0.01, 100.0
    rates, accels = [], []
    for k in range(600):
        target = 0.0 if k < 300 else 1.0
        step(pr, 0, dt, target, s_end, PRM)
        rates.append(pr.sd[0])
        accels.append(pr.sdd[0])
    rates, accels = np.array(rates), np.array(accels)
    assert np.abs(accels).max() <= 1.0 / PRM.progress_tau_s + 1e-12  # |s_ddot| <= 1 / tau
    assert rates.min() >= 0.0 and rates.max() <= 1.0
    # first order: after tau the rate has come 1 - 1/e of the way (to the step's accuracy)
    k_tau = int(round(PRM.progress_tau_s / dt))
    assert rates[k_tau - 1] == pytest.approx(math.exp(-1.0), abs=0.01)
    assert rates[299] < 0.06 and rates[300 + k_tau - 1] == pytest.approx(1 - math.exp(-1.0) *
                                                                         (1 - rates[299]),
                                                                         abs=0.01)
    # s is the integral of the rate
    sd = np.concatenate([[1.0], rates])
    assert pr.s[0] == pytest.approx(np.sum(sd[:-1] + sd[1:]) * dt / 2, rel=1e-9)


# ------------------------------------------------------------------ S17.1 the team's error


def test_the_teams_error_is_its_worst_robot_with_a_free_goal_and_a_parked_leader_is_negative():
    # team 0: robots 0 (leader), 1, 2; team 3: robot 3 alone
    p = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (5.0, 5.0)]
    goal = [(0.05, 0.0), (1.0, 0.3), (2.0, 0.1), (5.0, 5.0)]
    team = np.array([0, 0, 0, 3])
    out = np.zeros(4)
    known = np.ones(4, bool)
    team_errors(np.array(p, float), np.array(goal, float), team, known, NOTHING, PRM, out)
    assert out.tolist() == pytest.approx([0.3, 0.0, 0.0, 0.0])  # at the leader rows
    known[1] = False  # a robot not heard does not count
    team_errors(np.array(p, float), np.array(goal, float), team, known, NOTHING, PRM, out)
    assert out[0] == pytest.approx(0.1)
    # robot 1's goal inside an obstacle's Q: it is parked on the limit cycle, not behind
    known[1] = True
    ob = obstacles({'center': (1.0, 0.55), 'axes': (0.2, 0.2)})  # Q: radius 0.36
    team_errors(np.array(p, float), np.array(goal, float), team, known, ob, PRM, out)
    assert out[0] == pytest.approx(0.1)
    # the leader's own goal inside Q: -E (its reference must carry it out)
    ob = obstacles({'center': (0.2, 0.3), 'axes': (0.2, 0.2)})
    team_errors(np.array(p, float), np.array(goal, float), team, known, ob, PRM, out)
    assert out[0] == pytest.approx(-0.3)


# ------------------------------------------------------------------ S17.3 the mission's end


class _Mission:
    """Two one-robot teams on lines; robots placed by hand (the decision reads goals as given)."""

    def __init__(self, s_end=6.0):
        self.refs = tabulate([LINE, LINE], s_end)
        self.progress = new_progress(2)
        self.teams = new_teams(2)
        self.m = modes(2)
        self.e_team = np.zeros(2)
        self.leaders = np.arange(2, dtype=np.int64)
        self.ev = np.zeros((64, 6))

    def decide(self, t, dt, p, goal):
        rb = robots(p, goal=goal, goal_dot=np.zeros((2, 2)))
        _nev, done = coordinate(t, dt, rb, NOTHING, self.m, self.teams, self.progress,
                                self.refs, self.leaders, self.e_team, PRM, self.ev, 0)
        return done


def test_the_mission_ends_when_every_reference_reached_its_end():
    ms = _Mission(s_end=6.0)
    p = [(0.0, 0.0), (0.0, 5.0)]  # far apart: no encounter
    t, dt, end = 0.0, 0.1, None
    while end is None and t < 20.0:
        t = round(t + dt, 9)
        if ms.decide(t, dt, p, p):
            end = t
    # at the nominal rate from the start: s reaches 6 s of path time at t = 6 (+ one period)
    assert end == pytest.approx(6.0, abs=dt + 1e-9)
    assert ms.teams.done.all() and list(ms.progress.s) == [6.0, 6.0]


def test_a_team_that_fell_apart_holds_its_reference_and_every_team_waits_at_the_finish():
    ms = _Mission(s_end=6.0)
    at_goal = [(0.0, 0.0), (0.0, 5.0)]
    behind = [(0.0, 0.0), (0.0, 5.6)]  # team 1 is 0.6 m from its goal: beyond reform_stop_m
    t, dt = 0.0, 0.1
    for _ in range(150):  # 15 s: team 0 runs to its finish window, team 1 waits
        t = round(t + dt, 9)
        assert not ms.decide(t, dt, at_goal, behind)
    s0, s1 = ms.progress.s
    assert s1 < 2.0 * PRM.progress_tau_s  # team 1 slowed to a stop at once (lag tau)
    assert 6.0 - PRM.finish_s - 0.05 <= s0 < 6.0  # team 0 waits within finish_s of its end
    assert ms.progress.target.tolist() == [0.0, 0.0]
    # team 1 re-formed: both go on and the mission ends
    for _ in range(150):
        t = round(t + dt, 9)
        if ms.decide(t, dt, at_goal, at_goal):
            break
    assert ms.teams.done.all()
    print(f'mission: waited at s = {s0:.2f} / {s1:.2f} s, ended at t = {t:.1f} s (6 s free)')


def test_a_run_gives_up_on_a_mission_after_three_times_its_free_traversal():
    assert max_time_s(55.0) == 165.0
    assert max_time_s(10.0) == 40.0  # at least 30 s more
