"""EncounterArbiter (core/control/arbiter.py): the coordinator's S7 arbitration over all robots,
fed the robots' states step by step.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from ament_formation.core.control.arbiter import (
    AssignmentSender,
    DRIFT_RESEND_MPS,
    EncounterArbiter,
    REPORT_LAG_S,
)
from ament_formation.core.control.controller import EncounterAssignment
from ament_formation.core.scenario.loader import parse_scenario
from ament_formation.core.sim.simulator import simulate

DATA = Path(__file__).resolve().parent / 'data'


@pytest.fixture(scope='module')
def three_robots():
    """test/data/head_on.yaml (robots 0 and 1 head-on on y = 0.6) plus a robot 2 far away
    (5 m north, driving east), and the simulator's run of it (1 kHz, recorded at 50 Hz).
    """
    mapping = yaml.safe_load((DATA / 'head_on.yaml').read_text())
    mapping['robots'].append(
        {
            'id': 2,
            'leader': True,
            'slot_m': [0.0, 0.0],
            'marker_id': 2,
            'initial_pose': [0.0, 5.6, 0.0],
            'path': {'type': 'line', 'start_m': [0.0, 5.6], 'heading_rad': 0.0, 'speed_mps': 0.08},
        }
    )
    sc = parse_scenario(mapping, 'head_on+far')
    return sc, simulate(sc, record_every_s=0.02)


def test_arbiter_assigns_and_releases_a_head_on_mutual_pair(three_robots):
    sc, res = three_robots
    arb = EncounterArbiter(sc)
    modes = {
        rid: {'mode': 'coordination', 'target': None, 'direction': None} for rid in res.robot_ids
    }
    history = []  # (t, assignments) at every call
    for k, t in enumerate(res.t_s):
        states = {rid: res.state[k, q] for q, rid in enumerate(res.robot_ids)}
        history.append((float(t), arb.decide(float(t), states, modes)))
    held = [(t, a) for t, a in history if a]
    assert held, 'no assignment'
    t_first, first = held[0]
    # the pair: mutual, reciprocal, same entry time and the same w_c for both robots (S7, S14.1)
    assert set(first) == {0, 1}
    a0, a1 = first[0], first[1]
    assert (a0.mode, a0.partner, a1.mode, a1.partner) == ('mutual', 1, 'mutual', 0)
    assert a0.direction == a1.direction == 1.0
    assert a0.t_entry_s == a1.t_entry_s == pytest.approx(t_first)
    assert a0.drift_mps == a1.drift_mps
    for _, a in held:  # every later update too
        assert set(a) == {0, 1} and a[0].drift_mps == a[1].drift_mps
        assert a[0].t_entry_s == a[1].t_entry_s == a0.t_entry_s
    # the simulator's own decision entered the same pair within a decision period or two
    sim_enter = [e['t_s'] for e in res.mode_events if e['event'] == 'enter' and e['robot'] == 0]
    assert sim_enter and abs(sim_enter[0] - t_first) <= 0.05
    # held while they pass each other, released after they passed (joint exit, S8.3)
    t_last = held[-1][0]
    release_k = next(k for k, (t, a) in enumerate(history) if t > t_last)
    assert history[release_k][1] == {}
    assert all(a == {} for _, a in history[release_k:])
    x = res.state[release_k]
    assert x[0, 0] > x[1, 0]  # robot 0 is east of robot 1: passed
    assert np.hypot(*(x[0, :2] - x[1, :2])) > 0.25  # outside R_aa
    sim_exit = [e['t_s'] for e in res.mode_events if e['event'] == 'exit' and e['robot'] == 0]
    assert sim_exit and abs(sim_exit[0] - history[release_k][0]) <= 0.05  # as the simulator
    assert t_last - t_first >= 1.0  # T_min (S8.3)
    # robot 2 (far away) never gets an assignment; the events name only the pair
    assert all(2 not in a for _, a in history)
    assert {(e['robot'], e['event'], e['mode']) for e in arb.events} == {
        (0, 'enter', 'mutual'),
        (1, 'enter', 'mutual'),
        (0, 'exit', 'mutual'),
        (1, 'exit', 'mutual'),
    }
    print(
        f'arbiter: pair {t_first:.2f} s .. {t_last:.2f} s, '
        f'released at {history[release_k][0]:.2f} s'
    )


def test_arbiter_leaves_out_robots_without_a_state(three_robots):
    """A robot without a known state is left out of the decision: no encounter with it until it
    is heard, then the pair is assigned at once.
    """
    sc, res = three_robots
    enter = next(e['t_s'] for e in res.mode_events if e['event'] == 'enter')
    k = int(np.searchsorted(res.t_s, enter))  # the simulator enters the pair here
    states = {rid: res.state[k, q] for q, rid in enumerate(res.robot_ids)}
    arb = EncounterArbiter(sc)
    assert arb.decide(float(res.t_s[k]), {0: states[0], 2: states[2]}, {}) == {}
    assert (
        arb.decide(
            float(res.t_s[k]) + 0.01, {0: states[0], 1: np.full(5, np.nan), 2: states[2]}, {}
        )
        == {}
    )  # a non-finite state counts as unknown
    out = arb.decide(float(res.t_s[k]) + 0.02, states, {})
    assert set(out) == {0, 1} and out[0].partner == 1 and out[1].partner == 0
    assert out[0].t_entry_s == pytest.approx(float(res.t_s[k]) + 0.02)


def test_a_robots_own_encounter_is_taken_and_a_loop_it_closes_is_a_pair_for_both(three_robots):
    # docs/law-changes.md §24: the arbiter did not know the robots' own (emergency) encounters;
    # a robot's own yield to the robot the coordinator made yield to it closed a loop that each
    # robot broke against the other's late report, and the coordinator assigned it again
    sc, _ = three_robots
    arb = EncounterArbiter(sc)
    states = {rid: np.array([0.0, y, 0.0, 0.0, 0.0]) for rid, y in ((0, 0.6), (1, 2.0), (2, 5.6))}
    free = {rid: {'mode': 'coordination', 'target': None, 'direction': None} for rid in states}
    assert arb.decide(0.0, states, free) == {}  # 1.4 m apart at rest: no encounter of its own
    # robot 1 reports a yield to robot 0 of its own: the arbiter takes it as it is
    modes = {**free, 1: {'mode': 'yield', 'target': 'robot_0', 'direction': 'cw'}}
    out = arb.decide(1.0, states, modes)
    assert set(out) == {1}
    assert (out[1].mode, out[1].partner, out[1].direction, out[1].t_entry_s) == (
        'yield', 0, -1.0, 1.0
    )
    # robot 0 reports a yield to robot 1: the loop becomes one mutual pair of both (S14.5)
    modes[0] = {'mode': 'yield', 'target': 'robot_1', 'direction': 'ccw'}
    out = arb.decide(1.5, states, modes)
    assert set(out) == {0, 1}
    assert (out[0].mode, out[0].partner, out[1].mode, out[1].partner) == (
        'mutual', 1, 'mutual', 0
    )
    assert out[0].t_entry_s == out[1].t_entry_s == 1.5 and out[0].direction == out[1].direction
    # the pair ends here (joint exit, S8.3) while both robots still report it: their reports are
    # late echoes for REPORT_LAG_S, then a robot still in the pair is in it by its own decision
    modes = {rid: {'mode': 'mutual', 'target': f'robot_{1 - rid}', 'direction': 'ccw'}
             for rid in (0, 1)}  # fmt: skip
    modes[2] = free[2]
    t, out = 1.5, {0: None}
    while out:
        t = round(t + 0.02, 9)
        assert t < 10.0, 'the pair never ended'
        out = arb.decide(t, states, modes)
    t_exit = t
    while t < t_exit + REPORT_LAG_S - 0.03:
        t = round(t + 0.02, 9)
        assert arb.decide(t, states, modes) == {}, t
    out = arb.decide(t_exit + REPORT_LAG_S + 0.01, states, modes)
    assert {rid: (a.mode, a.partner) for rid, a in out.items()} == {
        0: ('mutual', 1),
        1: ('mutual', 0),
    }


def test_the_sender_resends_a_pair_whose_drift_moved_and_republishes_the_newest():
    # docs/law-changes.md §23: the robots take a pair's w_c from its assignment; sent only on a
    # new decision, a w_c frozen at the pair's entry drove pairs into the floor's edge
    def pair(wx, direction=1.0):
        a = [EncounterAssignment('mutual', 1 - rid, direction, 3.0, (wx, 0.0)) for rid in (0, 1)]
        return dict(enumerate(a))

    sender = AssignmentSender()
    assert sender.update({}) is None and sender.current == {}
    assert sender.update(pair(-0.05)) == 'revision'  # a new decision
    step = 0.4 * DRIFT_RESEND_MPS
    assert sender.update(pair(-0.05 + step)) is None  # moved less than the threshold
    assert sender.current[0].drift_mps == (-0.05 + step, 0.0)  # ... but the newest is kept
    assert sender.update(pair(-0.05 + 2 * step)) is None
    assert sender.update(pair(-0.05 + 3 * step)) == 'drift'  # 1.2 x the threshold since sent
    assert sender.update(pair(-0.05 + 4 * step)) is None  # measured from what was sent
    assert sender.republish()[1].drift_mps == (-0.05 + 4 * step, 0.0)  # the newest, as sent
    assert sender.update(pair(-0.05 + 5 * step)) is None
    assert sender.update(pair(-0.05 + 5 * step, direction=-1.0)) == 'revision'  # another sense
    assert sender.update({}) == 'revision'  # released
    yields = {0: EncounterAssignment('yield', 1, 1.0, 3.0)}
    assert sender.update(yields) == 'revision' and sender.update(yields) is None
