"""core/robot_law.py: one robot's law, closed on the plant twin per robot, reproduces the
vectorised simulator (same mode events, same final errors) on the shortened paper scenario."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ament_formation.core.robot_law import SingleRobotLaw
from ament_formation.core.scenario import load_scenario
from ament_formation.core.simulator import simulate
from ament_formation.core.twin import PlantTwin

DATA = Path(__file__).resolve().parent / "data"


def test_per_robot_laws_match_the_simulator():
    sc = load_scenario(DATA / "paper_short.yaml")
    ref = simulate(sc, dt_s=0.001)
    twin = PlantTwin(sc)
    twin.start()
    laws = {r.id: SingleRobotLaw(sc, r.id) for r in sc.robots}
    peak = 0.0
    for k in range(int(round(sc.duration_s / 0.01))):
        t = 0.01 * k
        o0 = laws[0].step(t, twin.state[0])
        o1 = laws[1].step(t, twin.state[1], parent=0, parent_state=twin.state[0], parent_accel=o0.accel_cmd_mps2,
                          offset=np.array([0.0, 1.2]), original_parent_state=twin.state[0])
        tau = np.array([o0.torque_nm, o1.torque_nm])
        peak = max(peak, float(np.max(np.abs(tau))))
        twin.advance(0.01, tau)
    ev = [(e["t_s"], e["event"], e["target"]) for e in laws[0].events]
    ref_ev = [(e["t_s"], e["event"], e["target"]) for e in ref.mode_events if e["robot"] == 0]
    assert [e[1:] for e in ev] == [e[1:] for e in ref_ev] == [("enter", "O1"), ("exit", "O1")]
    assert all(abs(a[0] - b[0]) <= 0.05 for a, b in zip(ev, ref_ev))   # 100 Hz law vs 1 kHz
    assert laws[1].events == []
    err_lead = np.hypot(*(twin.state[0, :2] - sc.robot(0).path.reference(sc.duration_s)[0]))
    err_fol = np.hypot(*(twin.state[1, :2] - twin.state[0, :2] - [0.0, 1.2]))
    assert err_lead < 0.02 and err_fol < 0.01
    assert peak <= 0.15
