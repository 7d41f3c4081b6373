"""Closed loop on config/scenarios/paper.yaml (spec S12 scenario 1): safety, one avoidance entry
per robot on its own obstacle, settled formation accuracy, torque limits, S3.4 reaching bound.
"""

import numpy as np
import pytest

from ament_formation.core.config_files import config_file
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.metrics import compute_metrics
from ament_formation.core.sim.simulator import simulate


@pytest.fixture(scope='module')
def run():
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    res = simulate(sc)
    return sc, res, compute_metrics(res, sc)


def test_never_enters_a_prohibited_region(run):
    _, _, m = run
    assert m['prohibited_entries'] == 0
    assert m['min_clearance_m'] > 0.0
    # the reference simulation reaches the limit cycle: +0.039 m (R0/O1) and +0.069 m (R1/O2)
    assert 0.02 < m['robots']['0']['min_clearance_m']['O1'] < 0.06
    assert 0.04 < m['robots']['1']['min_clearance_m']['O2'] < 0.09


def test_leader_avoids_o1_and_follower_o2_once_each(run):
    _, res, m = run
    enters = {
        rid: [e['target'] for e in res.mode_events if e['robot'] == rid and e['event'] == 'enter']
        for rid in (0, 1)
    }
    assert enters == {0: ['O1'], 1: ['O2']}
    assert (
        m['robots']['0']['avoidance_entries'] == 1 and m['robots']['1']['avoidance_entries'] == 1
    )
    exits = [e for e in res.mode_events if e['event'] == 'exit']
    assert len(exits) == 2 and not res.avoiding[-1].any()


def test_follower_is_a_root_while_avoiding_and_restored_after(run):
    _, res, _ = run
    parents = [g['parents']['1'] for g in res.graph_events]
    assert parents == [0, None, 0]


def test_formation_settles_within_one_centimetre(run):
    _, _, m = run
    for rid in ('0', '1'):
        assert m['robots'][rid]['formation_rms_settled_m'] <= 0.01
        assert m['robots'][rid]['final_error_m'] < 0.005


def test_peak_torque_below_limit_and_never_saturated(run):
    sc, res, m = run
    limit = sc.robots[0].params.torque_limit_nm
    for rid in ('0', '1'):
        assert max(m['robots'][rid]['peak_torque_nm']) < limit
        assert m['robots'][rid]['saturated_fraction'] == 0.0
    assert np.isfinite(res.state).all()


def test_reaching_time_within_s3_4_bound_for_every_phase(run):
    _, res, _ = run
    done = [r for r in res.reaching if r['completed']]
    # t = 0 for both robots, one enter and one exit each, the follower's re-parenting
    assert len(done) >= 6
    for r in res.reaching:
        assert r['t_reach_s'] <= r['bound_s'] + 1e-9, r
