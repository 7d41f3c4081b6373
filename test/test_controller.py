"""RobotController (one robot, for the ROS node) reproduces the simulator: same compiled decision
and law functions, driven robot by robot from Python."""
import math

import numpy as np
import pytest

from ament_formation.core.controller import EncounterAssignment, NeighbourState, RobotController
from ament_formation.core.disturbance import Disturbance
from ament_formation.core.graph import FormationGraph
from ament_formation.core.kernels import rk4_step_k
from ament_formation.core.paths_config import config_file
from ament_formation.core.scenario import load_scenario
from ament_formation.core.simulator import simulate


def closed_loop_with_controllers(sc, duration_s, dt=0.001):
    robots = sorted(sc.robots, key=lambda r: r.id)
    graph = FormationGraph.from_scenario(sc)
    ctrls = {}
    for r in robots:
        c = RobotController(r.id, r.params, sc.control, sc.avoidance, sc.obstacles,
                            leader_path=r.path if r.leader else None, team=sc.team_leader(r.id))
        p0 = graph.original_parent[r.id]
        off = None if p0 is None else np.asarray(r.slot_m) - np.asarray(sc.slot(p0))
        c.set_graph(p0, off if off is not None else (0, 0), p0, off if off is not None else (0, 0))
        ctrls[r.id] = c
    dist = Disturbance.from_bounds(len(robots), sc.disturbance.accel_bound, sc.disturbance.seed)
    x = {r.id: np.array([*r.initial_pose, 0.0, 0.0]) for r in robots}
    acc = {r.id: np.zeros(2) for r in robots}
    modes = {r.id: ("coordination", None) for r in robots}
    events = []
    for k in range(int(round(duration_s / dt))):
        t = k * dt
        nbs = {r.id: NeighbourState(x[r.id], acc[r.id], team=sc.team_leader(r.id),
                                    mode=modes[r.id][0], target=modes[r.id][1]) for r in robots}
        torques = {}
        for r in robots:                       # parents first (ids ascending here)
            c = ctrls[r.id]
            p0 = graph.original_parent[r.id]
            nbs[r.id] = NeighbourState(x[r.id], acc[r.id], team=sc.team_leader(r.id))
            out = c.step(t, x[r.id], parent=nbs.get(c._parent), original_parent=nbs.get(p0),
                         neighbours={i: s for i, s in nbs.items() if i != r.id})
            torques[r.id] = out.torque_nm
            acc[r.id] = out.accel_cmd_mps2
            nbs[r.id] = NeighbourState(x[r.id], acc[r.id], team=sc.team_leader(r.id),
                                       mode=out.mode, target=out.target)
            modes[r.id] = (out.mode, out.target)
            events.extend(out.events)
        g = [dist(t), dist(t + dt / 2), dist(t + dt)]
        for q, r in enumerate(robots):
            p = r.params
            x[r.id] = np.array(rk4_step_k(*x[r.id], *torques[r.id], *g[0][q], *g[1][q], *g[2][q], dt,
                                          p.mass_tilde_kg, p.inertia_tilde_kgm2, p.wheel_radius_m,
                                          p.axle_length_m, p.com_offset_m, p.platform_mass_kg))
    return x, events


def test_controllers_reproduce_the_simulator_on_paper_start():
    sc = load_scenario(config_file("scenarios/paper.yaml"))
    import dataclasses
    short = dataclasses.replace(sc, duration_s=2.0)
    res = simulate(short)
    x, _ = closed_loop_with_controllers(short, 2.0)
    # simulator record at t = 1.99 s vs the controller loop at 2.0 s: compare the state one step on
    # by re-running the controllers' loop to the same sample time
    x199, _ = closed_loop_with_controllers(short, 1.99)
    for q, rid in enumerate(res.robot_ids):
        np.testing.assert_allclose(x199[rid], res.state[-1, q], atol=1e-7)


def test_controller_enters_and_reports_obstacle_mode():
    sc = load_scenario(config_file("scenarios/paper.yaml"))
    r0 = sc.robots[0]
    c = RobotController(0, r0.params, sc.control, sc.avoidance, sc.obstacles, leader_path=r0.path)
    # p on the minor axis of O1 (phi = 2 pi/3), 0.22 m from the centre: inside Q, outside I,
    # heading at the centre
    out = c.step(13.0, np.array([1.0 - 0.22 * math.sin(2 * math.pi / 3),
                                 -0.2 + 0.22 * math.cos(2 * math.pi / 3), math.pi / 6, 0.05, 0.0]))
    assert out.mode == "obstacle" and out.target == "O1" and out.direction in ("cw", "ccw")
    assert [e["event"] for e in out.events] == ["enter"]
    assert out.mode_dict() == {"mode": "obstacle", "target": "O1", "direction": out.direction}
    assert np.all(np.abs(out.torque_nm) <= r0.params.torque_limit_nm)


def test_two_controllers_head_on_form_the_same_mutual_pair():
    sc = load_scenario(config_file("scenarios/paper.yaml"))
    p = sc.robots[0].params
    a = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    b = RobotController(7, p, sc.control, sc.avoidance, (), team=7)
    xa = np.array([-0.2, 0.01, 0.0, 0.05, 0.0])
    xb = np.array([0.2, 0.0, math.pi, 0.05, 0.0])
    oa = a.step(5.0, xa, neighbours={7: NeighbourState(xb, team=7)})
    ob = b.step(5.0, xb, neighbours={3: NeighbourState(xa, team=3)})
    assert (oa.mode, oa.target, oa.direction) == ("mutual", "robot_7", "ccw")
    assert (ob.mode, ob.target, ob.direction) == ("mutual", "robot_3", "ccw")
    np.testing.assert_allclose(a._state.wc[0], b._state.wc[0], atol=1e-12)


def test_assignment_overrides_robot_decision_and_bad_input_is_named():
    sc = load_scenario(config_file("scenarios/paper.yaml"))
    p = sc.robots[0].params
    c = RobotController(1, p, sc.control, sc.avoidance, (), team=1)
    far = NeighbourState(np.array([3.0, 3.0, 0.0, 0.0, 0.0]), team=2)
    out = c.step(1.0, np.zeros(5), neighbours={2: far},
                 assignment=EncounterAssignment("yield", 2, direction=-1.0))
    assert (out.mode, out.target, out.direction) == ("yield", "robot_2", "cw")
    with pytest.raises(ValueError, match="own_state"):
        c.step(1.01, np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="mode"):
        EncounterAssignment("dance", 2)


def test_per_robot_controllers_on_the_plant_twin_reproduce_the_simulators_mode_events():
    """Moved from test_robot_law.py: RobotController at 100 Hz, closed robot by robot on the plant
    twin, gives the simulator's mode events (enter/exit O1 within 50 ms) and final errors on the
    shortened paper scenario, with torques within the limit."""
    from pathlib import Path

    from ament_formation.core.twin import PlantTwin

    sc = load_scenario(Path(__file__).resolve().parent / "data" / "paper_short.yaml")
    ref = simulate(sc, dt_s=0.001)
    twin = PlantTwin(sc)
    twin.start()
    r0, r1 = sc.robot(0), sc.robot(1)
    c0 = RobotController(0, r0.params, sc.control, sc.avoidance, sc.obstacles, leader_path=r0.path, team=0)
    c1 = RobotController(1, r1.params, sc.control, sc.avoidance, sc.obstacles, team=0)
    c1.set_graph(0, (0.0, 1.2), 0, (0.0, 1.2))
    ev0, ev1, peak = [], [], 0.0
    for k in range(int(round(sc.duration_s / 0.01))):
        t = 0.01 * k
        o0 = c0.step(t, twin.state[0], neighbours={1: NeighbourState(twin.state[1], team=0)})
        lead = NeighbourState(twin.state[0], o0.accel_cmd_mps2, team=0, mode=o0.mode, target=o0.target)
        o1 = c1.step(t, twin.state[1], parent=lead, original_parent=lead)
        ev0.extend(o0.events)
        ev1.extend(o1.events)
        tau = np.array([o0.torque_nm, o1.torque_nm])
        peak = max(peak, float(np.max(np.abs(tau))))
        twin.advance(0.01, tau)
    ref_ev = [e for e in ref.mode_events if e["robot"] == 0]
    assert [(e["event"], e["target"]) for e in ev0] == [(e["event"], e["target"]) for e in ref_ev] \
        == [("enter", "O1"), ("exit", "O1")]
    assert all(abs(a["t_s"] - b["t_s"]) <= 0.05 for a, b in zip(ev0, ref_ev))   # 100 Hz vs 1 kHz
    assert ev1 == []
    err_lead = np.hypot(*(twin.state[0, :2] - r0.path.reference(sc.duration_s)[0]))
    err_fol = np.hypot(*(twin.state[1, :2] - twin.state[0, :2] - [0.0, 1.2]))
    assert err_lead < 0.02 and err_fol < 0.01
    assert peak <= r0.params.torque_limit_nm
