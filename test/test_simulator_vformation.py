"""Closed loop on config/scenarios/v_formation.yaml (spec S12 scenario 2): five-robot V through
static, rotating, moving and wall obstacles plus a head-on sixth robot, with S9 rewiring.
"""

import pytest

from ament_formation.core.config_files import config_file
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate


@pytest.fixture(scope='module')
def run():
    sc = load_scenario(config_file('scenarios/v_formation.yaml'))
    res = simulate(sc)
    return sc, res, compute_metrics(res, sc)


def test_no_prohibited_entry_for_any_robot_and_obstacle(run):
    sc, _, m = run
    assert m['prohibited_entries'] == 0
    for rid, r in m['robots'].items():
        for name, dist in r['min_clearance_m'].items():
            assert dist > 0.0, (rid, name, dist)
    # every obstacle kind is actually avoided by someone (static A, rotating B, moving C, wall D)
    assert {e['target'] for e in m['mode_events'] if e['mode'] == 'obstacle'} == {
        'A',
        'B',
        'C',
        'D',
    }


def test_robots_never_inside_the_robot_keepout_circle(run):
    sc, _, m = run
    r = sc.robots[0].params.body_radius_m
    keepout = 2 * r + sc.avoidance.agent_keepout_margin_m
    assert keepout == pytest.approx(0.25)
    assert m['min_inter_robot_distance_m'] > keepout


def test_head_on_robot_resolved_by_the_coordinator_one_team_gives_way(run):
    # S7.1, S7.5: R1 (the V) and R5 (a team of its own) meet head-on; the coordinator has the
    # later-ranked team's robot yield (no mutual pair between teams outside an emergency), the
    # robot with the right of way does not react to it, and the yield ends (S8.3)
    _, res, _ = run
    robot = [e for e in res.mode_events if e['mode'] in ('yield', 'mutual')]
    assert not [e for e in robot if e['mode'] == 'mutual']
    head_on = [e for e in robot if (e['robot'], e['target']) in ((1, 'robot_5'), (5, 'robot_1'))]
    assert head_on and {e['robot'] for e in head_on} == {head_on[0]['robot']}, head_on
    assert all(e['mode'] == 'yield' for e in head_on)
    # every yield ends: enters and exits alternate, starting with an enter
    assert [e['event'] for e in head_on] == ['enter', 'exit'] * (len(head_on) // 2)
    assert len(head_on) <= 4  # once, or once more after the cool-down: no chattering
    assert not res.avoiding[-1].any()


def test_downstream_robot_reparented_while_its_parent_avoids(run):
    sc, res, _ = run
    original = {int(c): p for c, p in res.graph_events[0]['parents'].items()}
    found = []
    for g in res.graph_events[1:]:
        avoiding_now = {rid for rid in original if _avoiding_at(res, rid, g['t_s'])}
        for c, p in g['parents'].items():
            c = int(c)
            p0 = original[c]
            if p is not None and p0 is not None and p != p0 and p0 in avoiding_now:
                found.append((g['t_s'], c, p0, p))
    assert found, 'no robot was re-parented away from an avoiding parent'
    assert any(c == 3 and p0 == 1 and p == 4 for _t, c, p0, p in found)  # S12: R3 to R4
    assert res.graph_events[-1]['parents'] == res.graph_events[0]['parents']  # restored


def _avoiding_at(res, rid, t_s):
    state = False
    for e in sorted(res.mode_events, key=lambda e: e['t_s']):
        if e['robot'] == rid and e['t_s'] <= t_s + 1e-9:
            state = e['event'] == 'enter'
    return state


def test_formation_settles_within_two_centimetres(run):
    _, res, m = run
    for rid, r in m['robots'].items():
        assert r['formation_rms_settled_m'] is not None and r['formation_rms_settled_m'] <= 0.02, (
            rid
        )
    assert not res.avoiding[-1].any()


def test_reaching_time_within_s3_4_bound_for_every_phase(run):
    _, res, _ = run
    assert len([r for r in res.reaching if r['completed']]) >= 20
    for r in res.reaching:
        assert r['t_reach_s'] <= r['bound_s'] + 1e-9, r


def test_peak_torque_below_limit(run):
    sc, _, m = run
    limit = sc.robots[0].params.torque_limit_nm
    assert all(max(r['peak_torque_nm']) < limit for r in m['robots'].values())
