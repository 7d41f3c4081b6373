"""RobotController (one robot, for the ROS node) reproduces the simulator: same compiled decision
and law functions, driven robot by robot from Python.
"""

import dataclasses
import math

import numpy as np
import pytest

from ament_formation.core.config_files import config_file
from ament_formation.core.control.assignment import AssignedLaw
from ament_formation.core.control.controller import (
    EncounterAssignment,
    NeighbourState,
    PAIR_CONFIRM_S,
    RobotController,
)
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.disturbance import Disturbance
from ament_formation.core.model.dynamics import rk4_step_k, RobotPlant
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.simulator import simulate


def closed_loop_with_controllers(sc, duration_s, dt=0.001):
    robots = sorted(sc.robots, key=lambda r: r.id)
    graph = FormationGraph.from_scenario(sc)
    ctrls = {}
    for r in robots:
        c = RobotController(
            r.id,
            r.params,
            sc.control,
            sc.avoidance,
            sc.obstacles,
            leader_path=r.path if r.leader else None,
            team=sc.team_leader(r.id),
        )
        p0 = graph.original_parent[r.id]
        off = None if p0 is None else np.asarray(r.slot_m) - np.asarray(sc.slot(p0))
        c.set_graph(p0, off if off is not None else (0, 0), p0, off if off is not None else (0, 0))
        ctrls[r.id] = c
    dist = Disturbance.from_bounds(len(robots), sc.disturbance.accel_bound, sc.disturbance.seed)
    x = {r.id: np.array([*r.initial_pose, 0.0, 0.0]) for r in robots}
    acc = {r.id: np.zeros(2) for r in robots}
    modes = {r.id: ('coordination', None) for r in robots}
    events = []
    for k in range(int(round(duration_s / dt))):
        t = k * dt
        nbs = {
            r.id: NeighbourState(
                x[r.id],
                acc[r.id],
                team=sc.team_leader(r.id),
                mode=modes[r.id][0],
                target=modes[r.id][1],
            )
            for r in robots
        }
        torques = {}
        for r in robots:  # parents first (ids ascending here)
            c = ctrls[r.id]
            p0 = graph.original_parent[r.id]
            nbs[r.id] = NeighbourState(x[r.id], acc[r.id], team=sc.team_leader(r.id))
            out = c.step(
                t,
                x[r.id],
                parent=nbs.get(c._parent),
                original_parent=nbs.get(p0),
                neighbours={i: s for i, s in nbs.items() if i != r.id},
            )
            torques[r.id] = out.torque_nm
            acc[r.id] = out.accel_cmd_mps2
            nbs[r.id] = NeighbourState(
                x[r.id], acc[r.id], team=sc.team_leader(r.id), mode=out.mode, target=out.target
            )
            modes[r.id] = (out.mode, out.target)
            events.extend(out.events)
        g = [dist(t), dist(t + dt / 2), dist(t + dt)]
        for q, r in enumerate(robots):
            p = r.params
            x[r.id] = np.array(
                rk4_step_k(
                    tuple(x[r.id]),
                    tuple(torques[r.id]),
                    tuple(g[0][q]),
                    tuple(g[1][q]),
                    tuple(g[2][q]),
                    dt,
                    RobotPlant(
                        p.mass_tilde_kg,
                        p.inertia_tilde_kgm2,
                        p.wheel_radius_m,
                        p.axle_length_m,
                        p.com_offset_m,
                        p.platform_mass_kg,
                    ),
                )
            )
    return x, events


def test_controllers_reproduce_the_simulator_on_paper_start():
    sc = load_scenario(config_file('scenarios/paper.yaml'))
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
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    r0 = sc.robots[0]
    c = RobotController(0, r0.params, sc.control, sc.avoidance, sc.obstacles, leader_path=r0.path)
    # p on the minor axis of O1 (phi = 2 pi/3), 0.22 m from the centre: inside Q, outside I,
    # heading at the centre
    out = c.step(
        13.0,
        np.array(
            [
                1.0 - 0.22 * math.sin(2 * math.pi / 3),
                -0.2 + 0.22 * math.cos(2 * math.pi / 3),
                math.pi / 6,
                0.05,
                0.0,
            ]
        ),
    )
    assert out.mode == 'obstacle' and out.target == 'O1' and out.direction in ('cw', 'ccw')
    assert [e['event'] for e in out.events] == ['enter']
    assert out.mode_dict() == {'mode': 'obstacle', 'target': 'O1', 'direction': out.direction}
    assert np.all(np.abs(out.torque_nm) <= r0.params.torque_limit_nm)


def test_two_controllers_head_on_form_the_same_mutual_pair():
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    a = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    b = RobotController(7, p, sc.control, sc.avoidance, (), team=7)
    xa = np.array([-0.2, 0.01, 0.0, 0.05, 0.0])
    xb = np.array([0.2, 0.0, math.pi, 0.05, 0.0])
    oa = a.step(5.0, xa, neighbours={7: NeighbourState(xb, team=7)})
    ob = b.step(5.0, xb, neighbours={3: NeighbourState(xa, team=3)})
    assert (oa.mode, oa.target, oa.direction) == ('mutual', 'robot_7', 'ccw')
    assert (ob.mode, ob.target, ob.direction) == ('mutual', 'robot_3', 'ccw')
    np.testing.assert_allclose(a._state.wc[0], b._state.wc[0], atol=1e-12)


def test_a_teammate_closing_on_its_slot_inside_q_is_no_threat_when_the_slots_are_known():
    # docs/law-changes.md §22 through the robot's own controller: teammate 7 stands 0.40 m ahead,
    # robot 3 closes at 50 mm/s (above the S14.3 teammate threshold); their slots lie 0.36 m apart
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    x3 = np.array([0.0, 0.0, 0.0, 0.05, 0.0])
    x7 = np.array([0.40, 0.0, math.pi, 0.0, 0.0])

    def mode(slot3, slot7):
        c = RobotController(3, p, sc.control, sc.avoidance, (), team=3, slot_m=slot3)
        return c.step(5.0, x3, neighbours={7: NeighbourState(x7, team=3, slot_m=slot7)}).mode

    assert mode((0.0, 0.0), (0.0, 0.36)) == 'coordination'
    assert mode(None, (0.0, 0.36)) != 'coordination'  # a slot not known: the full Q
    assert mode((0.0, 0.0), (0.0, 0.60)) != 'coordination'  # slots as far apart as Q
    with pytest.raises(ConfigError, match='slot_m'):
        RobotController(3, p, sc.control, sc.avoidance, (), team=3, slot_m=(0.0, math.nan))


def test_a_coordinated_robot_enters_robot_encounters_by_itself_only_in_emergencies():
    # docs/law-changes.md §23: robot 7 (another team) stands 0.40 m ahead of robot 3, which closes
    # at 50 mm/s: a threat (inside Q, approaching) but no emergency (contact in 3 s, not 1.5 s)
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    x3 = np.array([0.0, 0.0, 0.0, 0.05, 0.0])

    def step(x7, coordinated, assignment=None):
        c = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
        nb = {7: NeighbourState(x7, team=7)}
        return c.step(5.0, x3, neighbours=nb, coordinated=coordinated, assignment=assignment)

    ahead = np.array([0.40, 0.0, math.pi, 0.0, 0.0])
    assert (step(ahead, False).mode, step(ahead, False).target) == ('mutual', 'robot_7')
    assert (step(ahead, True).mode, step(ahead, True).events) == ('coordination', ())
    told = step(ahead, True, EncounterAssignment('yield', 7, direction=1.0))
    assert (told.mode, told.target) == ('yield', 'robot_7')  # the coordinator's decision
    close = np.array([0.30, 0.0, math.pi, 0.0, 0.0])  # inside E: the robot does not wait
    assert (step(close, True).mode, step(close, True).target) == ('mutual', 'robot_7')


def test_a_pair_the_partner_does_not_report_is_left_or_becomes_a_yield():
    """A mutual pair is one both robots report (docs/law-changes.md section 16). Partner 7 left
    the pair it had reported: robot 3 leaves it too, at once. Partner 7 never reports it:
    after PAIR_CONFIRM_S robot 3 yields to 7 instead. Partner 7 yields to robot 3: it leaves.
    """
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    me = np.array([-0.2, 0.01, 0.0, 0.05, 0.0])
    xb = np.array([0.2, 0.0, math.pi, 0.05, 0.0])

    def heard(mode='coordination', target=None, state=xb):
        return {7: NeighbourState(state, team=7, mode=mode, target=target)}

    def pair(t_s=5.0):
        c = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
        out = c.step(t_s, me, neighbours=heard())
        assert (out.mode, out.target) == ('mutual', 'robot_7')
        return c

    def kinds(out):
        return [(e['event'], e['mode'], e['target']) for e in out.events]

    left = pair()
    out = left.step(5.01, me, neighbours=heard('mutual', 'robot_3'))
    assert (out.mode, out.events) == ('mutual', ())
    # they have passed each other and 7 left: a head-on approach would be a new encounter
    away, apart = np.array([-0.2, 0.01, math.pi, 0.05, 0.0]), np.array([0.2, 0, 0, 0.05, 0])
    out = left.step(5.02, away, neighbours=heard(state=apart))
    assert out.mode == 'coordination' and kinds(out) == [('exit', 'mutual', 'robot_7')]
    assert (left._state.last_kind[0], left._state.last_tgt[0]) == (2, 7)  # S8.4 cool-down

    never = pair()
    out = never.step(5.0 + PAIR_CONFIRM_S / 2, me, neighbours=heard())
    assert (out.mode, out.events) == ('mutual', ())  # its report may still be on its way
    out = never.step(5.0 + PAIR_CONFIRM_S, me, neighbours=heard())
    assert (out.mode, out.target, out.direction) == ('yield', 'robot_7', 'ccw')
    assert kinds(out) == [('exit', 'mutual', 'robot_7'), ('enter', 'yield', 'robot_7')]

    stand_on = pair()
    out = stand_on.step(5.0 + PAIR_CONFIRM_S, me, neighbours=heard('yield', 'robot_3'))
    assert out.mode == 'coordination' and kinds(out) == [('exit', 'mutual', 'robot_7')]

    # one step reports its net switch (section 19): demoted to a yield, then released by the
    # coordinator in that same step -- one exit of the pair, not three events
    released = pair()
    out = released.step(5.0 + PAIR_CONFIRM_S, me, neighbours=heard(), release=7)
    assert out.mode == 'coordination' and kinds(out) == [('exit', 'mutual', 'robot_7')]


def test_an_assignment_that_replaces_a_mode_reports_its_exit():
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    c = RobotController(1, p, sc.control, sc.avoidance, (), team=1)
    far = {q: NeighbourState(np.array([3.0, 3.0 + q, 0.0, 0.0, 0.0]), team=q) for q in (2, 4)}
    out = c.step(1.0, np.zeros(5), neighbours=far, assignment=EncounterAssignment('yield', 2))
    assert [(e['event'], e['mode'], e['target']) for e in out.events] == [
        ('enter', 'yield', 'robot_2')
    ]
    out = c.step(1.01, np.zeros(5), neighbours=far, assignment=EncounterAssignment('mutual', 4))
    assert [(e['event'], e['mode'], e['target']) for e in out.events] == [
        ('exit', 'yield', 'robot_2'),
        ('enter', 'mutual', 'robot_4'),
    ]


def _robot_3_in_an_emergency_with_robot_7():
    """(scenario, robot parameters, robot 3's state inside E of robot 7, {7: robot 7})."""
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    me = np.array([-0.13, 0.01, 0.0, 0.05, 0.0])
    x7 = {7: NeighbourState(np.array([0.13, 0.0, math.pi, 0.05, 0.0]), team=7)}
    return sc, sc.robots[0].params, me, x7


def test_a_pair_entered_by_the_robots_own_decision_turns_the_coordinators_way():
    # docs/law-changes.md §23: each robot of a pair may pick the pair's sense on its own
    # estimates; opposite senses push the two the same way (crossing-s1-511, camera: slid along
    # the wall for 50 s). The coordinator's assignment carries the pair's one sense.
    sc, p, me, x7 = _robot_3_in_an_emergency_with_robot_7()
    c = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    out = c.step(5.0, me, neighbours=x7, coordinated=True)
    assert (out.mode, out.target) == ('mutual', 'robot_7')
    other = -1.0 if out.direction == 'ccw' else 1.0
    told = EncounterAssignment('mutual', 7, other, t_entry_s=5.0, drift_mps=(0.01, 0.0))
    out = c.step(5.01, me, neighbours=x7, coordinated=True, assignment=told)
    assert (out.mode, out.direction) == ('mutual', 'ccw' if other > 0 else 'cw')
    kinds = [(e['event'], e['mode']) for e in out.events]
    assert kinds == [('exit', 'mutual'), ('enter', 'mutual')]
    out = c.step(5.02, me, neighbours=x7, coordinated=True, assignment=told)
    assert out.events == () and tuple(c._state.wc[0]) == (0.01, 0.0)  # the pair's w_c, as sent


def test_an_assignment_that_turns_a_yield_into_a_pair_with_the_same_robot_is_not_lost():
    # docs/law-changes.md §23 (crossing-s1-454, camera): robot 3 yields to 7 as assigned; in an
    # emergency its own decision turns that into a mutual pair with 7 at the very step the
    # coordinator assigns the same pair. Releasing the withdrawn yield there ended the pair, and
    # the new assignment, "left at this decision", was never applied.
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    # outside E of robot 7 (a release would end the pair), closing at 0.2 m/s: contact in 0.65 s
    me = np.array([-0.165, 0.01, 0.0, 0.1, 0.0])
    x7 = {7: NeighbourState(np.array([0.165, 0.0, math.pi, 0.1, 0.0]), team=7)}
    robot = AssignedLaw(RobotController(3, p, sc.control, sc.avoidance, (), team=3))
    robot.assignment = EncounterAssignment('yield', 7, 1.0, t_entry_s=1.0)
    out = robot.step(5.0, me, None, None, x7, coordinated=True)
    assert (out.mode, out.target) == ('yield', 'robot_7')
    robot.assignment = EncounterAssignment('mutual', 7, 1.0, t_entry_s=5.01, drift_mps=(0, 0))
    out = robot.step(5.01, me, None, None, x7, coordinated=True)
    assert (out.mode, out.target, out.direction) == ('mutual', 'robot_7', 'ccw')
    out = robot.step(5.02, me, None, None, x7, coordinated=True)
    assert (out.mode, out.target, out.events) == ('mutual', 'robot_7', ())


def test_a_pair_left_and_re_entered_by_the_robots_own_decision_takes_the_assigned_sense():
    # docs/law-changes.md §25 (two_teams-s1-119, camera): R3 left the assigned pair with its
    # leader R2 by its own exit test, then re-entered it in an emergency with the other sense; the
    # assignment, "already left", was never applied again, and the two turned opposite ways
    sc, p, me, near = _robot_3_in_an_emergency_with_robot_7()
    own = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    own_sense = own.step(5.0, me, neighbours=near, coordinated=True).direction
    told_sense = 'ccw' if own_sense == 'cw' else 'cw'
    told = EncounterAssignment(
        'mutual', 7, 1.0 if told_sense == 'ccw' else -1.0, t_entry_s=1.0, drift_mps=(0.0, 0.0)
    )
    far = {  # the partner, far away, in the assigned pair
        7: NeighbourState(
            np.array([3.0, 3.0, 0.0, 0.0, 0.0]),
            team=7,
            mode='mutual',
            target='robot_3',
            direction=told_sense,
        )
    }
    robot = AssignedLaw(RobotController(3, p, sc.control, sc.avoidance, (), team=3))
    robot.assignment = told
    t, out = 2.0, robot.step(2.0, np.zeros(5), None, None, far, coordinated=True)
    assert (out.mode, out.target) == ('mutual', 'robot_7')
    while out.mode == 'mutual' and t < 10.0:  # far apart: its own exit test holds
        t = round(t + 0.01, 2)
        out = robot.step(t, np.zeros(5), None, None, far, coordinated=True)
    assert out.mode == 'coordination'
    t = round(t + 0.01, 2)
    near = {7: dataclasses.replace(far[7], state_m=near[7].state_m)}  # 7 turns in the pair as told
    out = robot.step(t, me, None, None, near, coordinated=True)  # the same assignment, still sent
    assert (out.mode, out.target, out.direction) == ('mutual', 'robot_7', own_sense)
    out = robot.step(round(t + 0.01, 2), me, None, None, near, coordinated=True)
    assert (out.mode, out.target) == ('mutual', 'robot_7')
    assert out.direction == told_sense, "the pair must turn the coordinator's way"
    out = robot.step(round(t + 0.02, 2), me, None, None, near, coordinated=True)
    assert out.direction == told_sense and out.events == ()


def test_without_the_coordinator_a_pair_takes_the_lower_ids_sense():
    # docs/law-changes.md §23: both robots formed the pair by their own decisions, each with its
    # sense; the robot with the higher id turns the other's way (with the coordinator heard, its
    # assignment gives the sense)
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    me = np.array([-0.165, 0.01, 0.0, 0.1, 0.0])
    there = np.array([0.165, 0.0, math.pi, 0.1, 0.0])

    def paired(rid, other, coordinated=False):
        c = RobotController(rid, p, sc.control, sc.avoidance, (), team=rid)
        out = c.step(5.0, me, neighbours={other: NeighbourState(there, team=other)})
        assert (out.mode, out.target) == ('mutual', f'robot_{other}')
        flipped = 'cw' if out.direction == 'ccw' else 'ccw'
        nb = NeighbourState(there, team=other, mode='mutual', target=f'robot_{rid}')
        nb = {other: dataclasses.replace(nb, direction=flipped)}
        return flipped, c.step(5.01, me, neighbours=nb, coordinated=coordinated)

    flipped, out = paired(3, 1)
    kinds = [(e['event'], e['mode']) for e in out.events]
    assert out.direction == flipped and kinds == [('exit', 'mutual'), ('enter', 'mutual')]
    flipped, out = paired(1, 3)  # the lower id keeps its sense
    assert out.direction != flipped and out.events == ()
    flipped, out = paired(3, 1, coordinated=True)  # the coordinator's assignment decides
    assert out.direction != flipped
    with pytest.raises(ConfigError, match='direction'):
        NeighbourState(there, direction='left')


def test_assignment_overrides_robot_decision_and_bad_input_is_named():
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    c = RobotController(1, p, sc.control, sc.avoidance, (), team=1)
    far = NeighbourState(np.array([3.0, 3.0, 0.0, 0.0, 0.0]), team=2)
    out = c.step(
        1.0,
        np.zeros(5),
        neighbours={2: far},
        assignment=EncounterAssignment('yield', 2, direction=-1.0),
    )
    assert (out.mode, out.target, out.direction) == ('yield', 'robot_2', 'cw')
    with pytest.raises(ValueError, match='own_state'):
        c.step(1.01, np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match='mode'):
        EncounterAssignment('dance', 2)


def test_per_robot_controllers_on_the_plant_twin_reproduce_the_simulators_mode_events():
    """Moved from test_robot_law.py: RobotController at 100 Hz, closed robot by robot on the plant
    twin, gives the simulator's mode events (enter/exit O1 within 50 ms) and final errors on the
    shortened paper scenario, with torques within the limit.
    """
    from pathlib import Path

    from ament_formation.core.sim.twin import PlantTwin

    sc = load_scenario(Path(__file__).resolve().parent / 'data' / 'paper_short.yaml')
    ref = simulate(sc, dt_s=0.001)
    twin = PlantTwin(sc)
    twin.start()
    r0, r1 = sc.robot(0), sc.robot(1)
    c0 = RobotController(
        0, r0.params, sc.control, sc.avoidance, sc.obstacles, leader_path=r0.path, team=0
    )
    c1 = RobotController(1, r1.params, sc.control, sc.avoidance, sc.obstacles, team=0)
    c1.set_graph(0, (0.0, 1.2), 0, (0.0, 1.2))
    ev0, ev1, peak = [], [], 0.0
    for k in range(int(round(sc.duration_s / 0.01))):
        t = 0.01 * k
        o0 = c0.step(t, twin.state[0], neighbours={1: NeighbourState(twin.state[1], team=0)})
        lead = NeighbourState(
            twin.state[0], o0.accel_cmd_mps2, team=0, mode=o0.mode, target=o0.target
        )
        o1 = c1.step(t, twin.state[1], parent=lead, original_parent=lead)
        ev0.extend(o0.events)
        ev1.extend(o1.events)
        tau = np.array([o0.torque_nm, o1.torque_nm])
        peak = max(peak, float(np.max(np.abs(tau))))
        twin.advance(0.01, tau)
    ref_ev = [e for e in ref.mode_events if e['robot'] == 0]
    assert (
        [(e['event'], e['target']) for e in ev0]
        == [(e['event'], e['target']) for e in ref_ev]
        == [('enter', 'O1'), ('exit', 'O1')]
    )
    assert all(abs(a['t_s'] - b['t_s']) <= 0.05 for a, b in zip(ev0, ref_ev))  # 100 Hz vs 1 kHz
    assert ev1 == []
    err_lead = np.hypot(*(twin.state[0, :2] - r0.path.reference(sc.duration_s)[0]))
    err_fol = np.hypot(*(twin.state[1, :2] - twin.state[0, :2] - [0.0, 1.2]))
    assert err_lead < 0.02 and err_fol < 0.01
    assert peak <= r0.params.torque_limit_nm


def test_release_ends_an_assigned_encounter_but_never_inside_the_emergency_circle():
    """The coordinator withdraws a mutual assignment (its joint exit, S8.3): ``release`` ends the
    encounter at once (event, S8.4 cool-down record) -- but not while the robot is inside the
    partner's emergency circle (h_em < 0: rho_em R_aa = 1.05 * 0.25 m), where it stays.
    """
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    c = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    mutual = EncounterAssignment('mutual', 7, t_entry_s=1.0, drift_mps=(0.0, 0.0))
    me = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    close = NeighbourState(
        np.array([0.25, 0.0, np.pi, 0.0, 0.0]), team=7, mode='mutual', target='robot_3'
    )
    out = c.step(1.0, me, neighbours={7: close}, assignment=mutual)
    assert (out.mode, out.target) == ('mutual', 'robot_7')
    # inside E (0.25 m < 0.2625 m): the release is refused, the robot stays in the pair
    out = c.step(1.01, me, neighbours={7: close}, release=7)
    assert (out.mode, out.target) == ('mutual', 'robot_7') and out.events == ()
    # a release naming another robot is ignored
    far = NeighbourState(
        np.array([0.27, 0.0, np.pi, 0.0, 0.0]), team=7, mode='mutual', target='robot_3'
    )
    out = c.step(
        1.02, me, neighbours={7: far, 9: NeighbourState(np.array([5.0, 5, 0, 0, 0]))}, release=9
    )
    assert out.mode == 'mutual'
    # just outside E (0.27 m): it leaves, with an exit event and the robot cool-down record
    out = c.step(1.03, me, neighbours={7: far}, release=7)
    assert (out.mode, out.target, out.direction) == ('coordination', None, None)
    assert [(e['event'], e['mode'], e['target']) for e in out.events] == [
        ('exit', 'mutual', 'robot_7')
    ]
    assert (c._state.last_kind[0], c._state.last_tgt[0], c._state.last_exit[0]) == (2, 7, 1.03)
    # the same withdrawn assignment is not re-entered from a stale copy in the same decision
    c2 = RobotController(3, p, sc.control, sc.avoidance, (), team=3)
    c2.step(1.0, me, neighbours={7: close}, assignment=mutual)
    out = c2.step(1.03, me, neighbours={7: far}, assignment=mutual, release=7)
    assert out.mode == 'coordination'  # left at this decision: not re-entered from the copy
    assert [e['event'] for e in out.events] == ['exit']


def test_neighbour_goal_feeds_the_partners_side_of_the_exit_test():
    """The partner's goal (``goal_m``) enters its side of the joint S8.3 exit test: a partner
    that has moved away but whose goal lies beyond this robot (segment [p_k, g_k] crosses the
    robot's circle, item 1) keeps the pair; with its goal unknown (= its position) the pair exits.
    """
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params

    def run(with_goal: bool):
        c = RobotController(
            0, p, sc.control, sc.avoidance, (), team=0, leader_path=sc.robots[0].path
        )
        r, rd, _ = sc.robots[0].path.reference(5.0)
        # me at my goal, moving along; partner 0.6 m behind me, moving away from me
        me = np.array([r[0], r[1], math.atan2(rd[1], rd[0]), float(np.hypot(*rd)), 0.0])
        back = -np.asarray(rd) / np.hypot(*rd)
        xk = np.array(
            [r[0] + 0.6 * back[0], r[1] + 0.6 * back[1], math.atan2(back[1], back[0]), 0.08, 0.0]
        )
        goal = (r - 2.0 * back) if with_goal else None  # 2 m beyond me
        nb = NeighbourState(
            xk,
            team=5,
            mode='mutual',
            target='robot_0',
            goal_m=goal,
            goal_dot_mps=None if goal is None else np.zeros(2),
        )
        c.step(
            3.0, me, neighbours={5: nb}, assignment=EncounterAssignment('mutual', 5, t_entry_s=3.0)
        )
        return [
            c.step(3.0 + 0.01 * k, me, neighbours={5: nb}).mode  # T_min 1 s, T_dwell 0.3 s
            for k in range(1, 160)
        ]

    with_goal, without = run(True), run(False)
    assert without[-1] == 'coordination' and 'coordination' not in without[:95]  # not before T_min
    assert set(with_goal) == {'mutual'}
    with pytest.raises(Exception, match='goal_m'):
        NeighbourState(np.zeros(5), goal_m=(np.nan, 0.0))


@pytest.mark.parametrize('obstacles', ['none', 'paper'])
def test_a_neighbour_busy_with_a_robot_not_heard_is_never_read_as_an_obstacle(
    monkeypatch, obstacles
):
    """A neighbour yielding to a robot this controller does not hear enters the decision as busy
    (MODE_OBSTACLE without an obstacle). The decision must not index the obstacle arrays with it:
    the compiled code has no bounds checks, so without obstacles it read memory past the arrays
    (found by `formation sweep --sensing camera`: a ZeroDivisionError in 7 of 300 runs, depending
    on that memory). Here the decision runs as plain Python: it raises IndexError on such a read.
    """
    from numba.core.registry import CPUDispatcher

    from ament_formation.core.control import controller as controller_module
    from ament_formation.core.control import encounters

    monkeypatch.setattr(controller_module, 'decide', encounters.decide.py_func)
    for name, f in vars(encounters).items():  # its stages and helpers too
        if isinstance(f, CPUDispatcher):
            monkeypatch.setattr(encounters, name, f.py_func)
    sc = load_scenario(config_file('scenarios/paper.yaml'))
    p = sc.robots[0].params
    obs = () if obstacles == 'none' else sc.obstacles
    c = RobotController(1, p, sc.control, sc.avoidance, obs, team=1)
    busy = NeighbourState(
        np.array([1.8, 1.5, 0.0, 0.08, 0.0]), team=2, mode='yield', target='robot_9'
    )
    for k in range(3):
        out = c.step(1.0 + 0.02 * k, np.array([1.7, 0.5, 0.0, 0.0, 0.0]), neighbours={2: busy})
        assert out.mode == 'coordination' and np.all(np.isfinite(out.torque_nm))
