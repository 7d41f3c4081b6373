"""The robot agent (core/control/agent.py, docs/control-law.md S10.3): everything one robot runs
on board behind one call per control period -- its status (waiting, running and the stops), what
it hears and how it extrapolates it, the coordinator's assignments and progress rates, its own
obstacle modes, the torque clamp -- and an AgentBatch of several robots being one RobotAgent each.
The controlled stop's torque (core/control/stop.py) is tested here too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ament_formation.core.config_files import config_file
from ament_formation.core.control.agent import (
    AgentBatch,
    AgentParams,
    RobotAgent,
    STOPPED_CLOCK,
)
from ament_formation.core.control.coordinator import Coordinator, Publisher
from ament_formation.core.control.rewiring import FormationGraph
from ament_formation.core.control.stop import (delay_scale_k, stop_gains, stop_torque,
                                               stop_torque_k, StopLead)
from ament_formation.core.control.switching import KIND_ROBOT, MODE_C, MODE_MUTUAL, MODE_OBSTACLE
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import PlantCoeffs, rk4_step_k, robot_plant_k, RobotPlant
from ament_formation.core.params import ControlGains, RobotParams
from ament_formation.core.scenario.loader import load_scenario
from ament_formation.core.sim.simulator import simulate
from ament_formation.core.sim.twin import PlantTwin

DATA = Path(__file__).resolve().parent / 'data'
PAPER = load_scenario(config_file('scenarios/paper.yaml'))
HEAD_ON = load_scenario(DATA / 'head_on.yaml')  # two one-robot teams 1.2 m apart, no obstacles
CHAIN = load_scenario(DATA / 'redundant_chain.yaml')  # 4 robots, redundant graph, one obstacle
T0 = 100.0  # the robot's clock at the mission start [s]
# robot 2 of the chain has two parents in the graph; the original one (S9)
CHAIN_PARENT = FormationGraph.from_scenario(CHAIN).original_parent[2]


class Robot:
    """One RobotAgent fed as a node would feed it: wheel samples consistent with (v, omega), a
    camera pose of p moving straight on at v (omega 0) every period unless told otherwise, the
    graph and the coordinator's messages.
    """

    def __init__(self, scenario, rid, params=None, **kw):
        self.agent = RobotAgent(scenario, rid, params, **kw)
        self.rid = rid
        p = scenario.robot(rid).params
        self.r_m, self.a_m = p.wheel_radius_m, p.axle_length_m
        self.q = np.zeros(2)
        self.rate = np.zeros(2)
        self.v = self.w = 0.0
        self.t_wheel = None
        self.pose0, self.t_pose0 = None, None

    def drive(self, v, w=0.0):
        """The wheels turn at (v [m/s], omega [rad/s]) from now on."""
        self.v, self.w = v, w
        self.rate = np.array([(v - 0.5 * self.a_m * w) / self.r_m,
                              (v + 0.5 * self.a_m * w) / self.r_m])

    def wheel(self, t):
        if self.t_wheel is not None:
            self.q = self.q + self.rate * (t - self.t_wheel)
        self.t_wheel = t
        self.agent.wheel(self.rid, t, tuple(self.q), tuple(self.rate))

    def pose_at(self, t):
        x, y, th = self.pose0
        s = self.v * (t - self.t_pose0)
        return (x + s * math.cos(th), y + s * math.sin(th), th)

    def start(self, pose, now=T0, v=0.0, w=0.0, parents=None, assignments=None, rates=None):
        """Every input a robot needs to run at ``now`` (mission start T0); the camera pose was
        captured 5 ms before ``now``.
        """
        self.drive(v, w)
        self.pose0, self.t_pose0 = tuple(pose), now - 0.005
        self.wheel(now - 0.005)
        self.agent.camera(self.rid, now - 0.005, pose)
        self.agent.set_graph(parents or {}, T0)
        self.agent.assign(now, assignments or {}, rates)
        return self.tick(now, camera=False)

    def tick(self, now, camera=True):
        """One period at ``now`` with a wheel sample (and a camera pose: ``True`` the straight
        line's, a pose, or ``False`` none) of that instant.
        """
        self.wheel(now)
        if camera is True:
            assert self.w == 0.0
            camera = self.pose_at(now)
        if camera is not False:
            self.agent.camera(self.rid, now, camera)
        self.agent.tick(now)
        return self.status

    @property
    def status(self):
        return self.agent.status(0)

    @property
    def torque(self):
        return self.agent.out.torque[0].copy()

    @property
    def mode(self):
        return self.agent.mode_dict(0)

    def events(self):
        return [(e['event'], e['mode'], e['target'], e['direction']) for e in self.agent.events]


def point_velocity(x, d):
    """S2.2: velocity of p of state x [x, y, theta, v, omega]."""
    return np.array([x[3] * math.cos(x[2]) - d * x[4] * math.sin(x[2]),
                     x[3] * math.sin(x[2]) + d * x[4] * math.cos(x[2])])


# --------------------------------------------------------------------------- the period


def test_the_period_waits_for_a_pose_the_graph_and_the_coordinator():
    rb = Robot(PAPER, 0)
    a = rb.agent
    tau, accel = a.tick(T0)
    assert rb.status == 'waiting' and not a.initialized(0)
    assert tau.tolist() == [0.0, 0.0] and accel.tolist() == [0.0, 0.0]
    assert rb.mode == {'mode': 'hold', 'target': None, 'direction': None, 'avoiding': False}
    rb.wheel(T0)
    assert rb.tick(T0 + 0.01, camera=False) == 'waiting'  # wheels, no pose
    assert rb.tick(T0 + 0.02, camera=(0.0, 0.0, 0.0)) == 'waiting'  # a pose, no graph
    assert a.initialized(0)
    np.testing.assert_allclose(a.out.state[0], 0.0, atol=1e-15)  # but an estimate
    a.set_graph({}, T0 + 5.0)
    assert rb.tick(T0 + 0.03, camera=False) == 'waiting'  # the mission starts in 5 s
    a.set_graph({}, T0)
    # the graph, no message from the coordinator yet: stopped (it owns the robot encounters)
    assert rb.tick(T0 + 0.04, camera=False) == 'stopped_coordinator'
    assert rb.mode['mode'] == 'stopped' and rb.torque.tolist() == [0.0, 0.0]  # at rest
    a.assign(T0 + 0.05, {}, None)
    assert rb.tick(T0 + 0.05, camera=False) == 'running'
    # the leader stands on r(0) at rest, heading along x; its reference moves on at 0.05 m/s
    # along the sine, whose tangent at r(0) is 32 deg to the left: it drives forward and turns
    # left (the right wheel's torque the larger)
    assert rb.torque.sum() > 0.01 and rb.torque[1] > rb.torque[0] + 0.01
    assert rb.mode == {'mode': 'coordination', 'target': None, 'direction': None,
                       'avoiding': False}
    assert a.out.accel[0, 0] > 0.0 and a.out.accel[0, 1] > 0.0


def test_no_wheel_data_is_zero_torque_until_it_comes_back():
    rb = Robot(PAPER, 0)
    rb.start((0.0, 0.0, 0.0), v=0.05)
    rb.agent.tick(T0 + 0.10)  # the last sample 0.10 s old: still running
    assert rb.status == 'running' and np.abs(rb.torque).max() > 0.0
    rb.agent.tick(T0 + 0.101)  # wheel_timeout_s 0.1 s
    assert rb.status == 'stopped_wheels' and rb.torque.tolist() == [0.0, 0.0]
    assert rb.agent.out.accel[0].tolist() == [0.0, 0.0]
    assert rb.tick(T0 + 0.11) == 'running'


@pytest.mark.parametrize('v', [0.0, 0.1])
def test_camera_loss_stops_in_time_to_be_at_rest_by_the_pose_timeout(v):
    """The stop begins once the camera age exceeds pose_timeout_s minus the time to rest from
    the current (v, omega) plus its margin (docs/safety.md §7); its torque is the camera-loss
    stop law; it holds until a newer pose.
    """
    rb = Robot(HEAD_ON, 0)
    prm = rb.agent.params
    rb.start((0.0, 0.6, 0.0), v=v)
    lead = StopLead(HEAD_ON.robot(0).params, prm.stop_time_s, HEAD_ON.control,
                    HEAD_ON.disturbance.accel_bound, prm.stop_margin_s, prm.stop_speed_max_mps,
                    prm.stop_turn_rate_max_radps, prm.stop_decel_mps2, 0.01)
    expected = prm.pose_timeout_s - lead.lead_s(v, 0.0)  # camera age at which the stop begins
    # docs/safety.md §7 table, "stop begins at age": 0.470 s at rest, 0.209 s at 0.1 m/s
    assert expected == pytest.approx({0.0: 0.470, 0.1: 0.209}[v], abs=1e-3)
    assert expected <= prm.pose_timeout_s - prm.stop_margin_s
    statuses = []  # (camera age [s], status): the pose was captured at T0 - 5 ms
    for k in range(1, 60):
        statuses.append((round(0.01 * k + 0.005, 3), rb.tick(T0 + 0.01 * k, camera=False)))
    first = next(age for age, s in statuses if s == 'stopped_pose')
    assert all(s == 'running' for age, s in statuses if age < first)
    assert all(s == 'stopped_pose' for age, s in statuses if age >= first)  # latched
    assert expected < first <= expected + 0.01 + 1e-9
    # the camera-loss stop law of the estimate (v held by the wheels in this test)
    x = rb.agent.out.state[0].copy()
    assert x[3] == pytest.approx(v, abs=1e-12)
    k = PlantCoeffs.from_params([HEAD_ON.robot(0).params])
    want = stop_torque(x[None], k, prm.stop_time_s, HEAD_ON.control, lead.decel_mps2, 0.01)[0]
    np.testing.assert_allclose(rb.torque, want, rtol=1e-9, atol=1e-15)
    if v > 0:
        assert rb.torque[0] < 0 and rb.torque[1] < 0  # braking
    assert rb.agent.counters(0)['over_stop_speed'] == 0
    # a newer pose ends the stop
    assert rb.tick(T0 + 0.6) == 'running'


def test_faster_than_the_stop_bound_is_counted():
    rb = Robot(HEAD_ON, 0)
    rb.start((0.0, 0.6, 0.0), v=0.2)  # stop_speed_max_mps 0.15
    rb.tick(T0 + 0.01)
    assert rb.agent.counters(0)['over_stop_speed'] == 2


def test_a_follower_whose_parent_is_silent_extrapolates_then_holds():
    rb = Robot(PAPER, 1)
    a = rb.agent
    parent = np.array([0.0, 0.0, 0.0, 0.05, 0.0])
    a.hear(0, parent, np.zeros(2), T0)
    assert rb.start((0.0, 1.2, 0.0), v=0.05, parents={1: 0}) == 'running'
    assert a.needed(1) == [0]
    for k in range(1, 101):  # the parent's last state is 1.0 s old at the end: extrapolated
        assert rb.tick(T0 + 0.01 * k) == 'running'
    assert rb.tick(T0 + 1.01) == 'hold_parent'  # parent_hold_s 1.0 s
    assert rb.mode['mode'] == 'hold'
    # the hold brakes with the formation law's gains
    prm = a.params
    x = a.out.state[0]
    lead = StopLead(PAPER.robot(1).params, prm.stop_time_s, PAPER.control,
                    PAPER.disturbance.accel_bound, prm.stop_margin_s, prm.stop_speed_max_mps,
                    prm.stop_turn_rate_max_radps, prm.stop_decel_mps2, 0.01)
    sk = lead.compiled(PAPER.control)
    k = PlantCoeffs.from_params([PAPER.robot(1).params])
    coeffs = np.stack([k.m_tilde, k.I_tilde, k.r, k.a, k.d, k.m_c, k.tau_max])
    want = stop_torque_k(x[3], x[4], robot_plant_k(coeffs, 0), k.tau_max[0], sk.stop_time_s,
                         sk.hold_gain_v, sk.hold_eps_v, sk.gain_w, sk.eps_w)
    np.testing.assert_allclose(rb.torque, want, rtol=1e-12)
    assert rb.torque[0] < 0 and rb.torque[1] < 0
    a.hear(0, parent, np.zeros(2), T0 + 1.02)
    assert rb.tick(T0 + 1.02) == 'running'


def test_a_robot_that_hears_no_coordinator_stops():
    rb = Robot(HEAD_ON, 0)
    rb.start((0.0, 0.6, 0.0), v=0.05)
    for k in range(1, 251):
        assert rb.tick(T0 + 0.01 * k) == 'running'  # 2.5 s: coordinator_timeout_s
    assert rb.tick(T0 + 2.51) == 'stopped_coordinator'
    assert rb.torque[0] < 0 and rb.torque[1] < 0  # the controlled stop
    assert rb.mode['mode'] == 'stopped'
    rb.agent.assign(T0 + 2.52, {}, None)
    assert rb.tick(T0 + 2.52) == 'running'


def test_a_clock_beyond_the_bound_halts_the_robot():
    rb = Robot(HEAD_ON, 0)
    rb.start((0.0, 0.6, 0.0), v=0.05)
    rb.agent.state.halt[0] = STOPPED_CLOCK  # what the node sets (core/clock.py beyond_bound)
    assert rb.tick(T0 + 0.01) == 'stopped_clock'
    assert rb.torque[0] < 0 and rb.torque[1] < 0 and rb.mode['mode'] == 'stopped'
    rb.agent.state.halt[0] = 0
    assert rb.tick(T0 + 0.02) == 'running'


# --------------------------------------------------------------------------- hearing


def test_a_robot_needs_its_parents_its_partner_and_the_robots_in_range():
    # reach: kappa (R_i + R_k + margin) + hear_margin_m = 1.8 * 0.25 + 0.6 = 1.05 m, kept until
    # 0.3 m beyond (hysteresis)
    rb = Robot(HEAD_ON, 0)
    a = rb.agent
    rb.start((0.0, 0.6, 0.0))
    assert a.needed(0) == []  # robot 1 is 1.2 m away, and not yet seen by the camera
    for x1, heard in [(1.2, False), (1.04, True), (1.3, True), (1.349, True), (1.36, False),
                      (1.3, False), (1.049, True)]:
        a.camera(1, 0.0, (x1, 0.6, math.pi))
        assert a.needed(0) == ([1] if heard else []), x1
    a.camera(1, 0.0, (2.0, 0.6, math.pi))
    a.camera(1, 0.0, (math.nan, 0.6, math.pi))  # a non-finite pose changes nothing
    assert a.needed(0) == []
    a.assign(T0, {0: {'mode': 'yield', 'partner': 1, 'direction': 1.0, 't_entry_s': 0.0,
                      'drift_mps': None, 'park_at_s': -math.inf}}, None)
    assert a.needed(0) == [1]  # the assignment's partner, wherever it is
    follower = Robot(CHAIN, 2)
    follower.start((-1.0, 0.0, 0.0), parents={2: 3})
    assert CHAIN_PARENT in (1, 3)
    assert follower.agent.needed(2) == sorted({3, CHAIN_PARENT})  # current and original parents
    everyone = Robot(HEAD_ON, 0, AgentParams(hear_all=True))
    assert everyone.agent.needed(0) == [1]


@pytest.mark.parametrize(
    'params, cases',
    [
        # parent_timeout_s 0: every heard state extrapolated by its age up to parent_hold_s (1 s)
        (AgentParams(parent_timeout_s=0.0), [(0.01, True, True), (0.04, True, True),
                                             (0.5, True, True), (0.99, True, True),
                                             (1.05, False, False)]),
        # the default: used as heard up to parent_timeout_s (0.1 s), extrapolated up to
        # parent_hold_s
        (AgentParams(), [(0.05, True, False), (0.09, True, False), (0.5, True, True),
                         (0.99, True, True), (1.05, False, False)]),
    ],
)
def test_heard_states_are_extrapolated_with_their_commanded_acceleration(params, cases):
    rb = Robot(HEAD_ON, 0, params)
    a = rb.agent
    rb.start((0.0, 0.6, 0.0))
    x1 = np.array([1.0, 0.6, 2.8, 0.08, 0.3])
    acc = np.array([0.02, -0.04])
    d = HEAD_ON.robot(1).params.com_offset_m
    pd = point_velocity(x1, d)
    k1 = a.row[1]
    for age, known, moved in cases:
        a.hear(1, x1, acc, T0 + 1.0 - age)
        rb.tick(T0 + 1.0)
        assert rb.status == 'running'
        assert bool(a.state.known[0, k1]) is known, age
        if not known:
            continue
        seen = a.state.x[0, k1]
        want = x1[:2] + (pd * age + 0.5 * acc * age * age if moved else 0.0)
        np.testing.assert_allclose(seen[:2], want, atol=1e-12)
        np.testing.assert_array_equal(seen[2:], x1[2:])
        np.testing.assert_allclose(a.state.pd[0, k1], pd, atol=1e-15)
        np.testing.assert_array_equal(a.state.heard_x[0, k1], x1)  # what was heard is kept


def test_the_goal_of_a_follower_whose_original_parent_is_silent_is_where_it_stands():
    # rewired to its other parent, robot 2 of the chain keeps its original parent's goal while it
    # hears it, and has no exit pull (goal on itself) while that parent is silent
    original = CHAIN_PARENT
    other = 1 if original == 3 else 3
    rb = Robot(CHAIN, 2)
    a = rb.agent
    xo = np.array([*CHAIN.robot(original).initial_pose, 0.0, 0.0])
    xr = np.array([*CHAIN.robot(other).initial_pose, 0.0, 0.0])
    a.hear(other, xr, np.zeros(2), T0)
    a.hear(original, xo, np.zeros(2), T0)
    pose = (-1.1, 0.05, 0.0)
    rb.start(pose, parents={2: other})
    offset = np.asarray(CHAIN.robot(2).slot_m) - np.asarray(CHAIN.robot(original).slot_m)
    np.testing.assert_allclose(a.state.goal[0, 2], xo[:2] + offset, atol=1e-12)
    rb.tick(T0 + 1.5)  # the original parent silent 1.5 s; the current one heard
    a.hear(other, xr, np.zeros(2), T0 + 1.5)
    rb.tick(T0 + 1.51)
    assert rb.status == 'running'
    np.testing.assert_allclose(a.state.goal[0, 2], a.out.state[0, :2], atol=1e-12)


# --------------------------------------------------------------------------- assignments


def _encounter(mode, partner=1, direction=1.0, t_entry_s=1.0, drift=None, park_at=-math.inf):
    return {'mode': mode, 'partner': partner, 'direction': direction, 't_entry_s': t_entry_s,
            'drift_mps': drift, 'park_at_s': park_at}


def _facing(gap_m=0.5, v=0.0):
    """Robot 0 of head_on running east at ``v`` from (0, 0.6), robot 1 heard at rest
    ``gap_m`` ahead, facing it.
    """
    rb = Robot(HEAD_ON, 0)
    rb.agent.hear(1, np.array([gap_m, 0.6, math.pi, 0.0, 0.0]), np.zeros(2), T0)
    rb.start((0.0, 0.6, 0.0), v=v)
    return rb


def test_the_coordinators_assignments_are_applied_and_withdrawn():
    rb = _facing()
    a = rb.agent
    assert rb.mode['mode'] == 'coordination' and rb.events() == []
    a.assign(T0 + 0.01, {0: _encounter('yield', direction=-1.0)}, None)
    rb.tick(T0 + 0.01)
    assert rb.mode == {'mode': 'yield', 'target': 'robot_1', 'direction': 'cw', 'avoiding': True}
    assert rb.events() == [('enter', 'yield', 'robot_1', 'cw')]
    assert a.state.modes.t_entry[0, 0] == 1.0  # the coordinator's entry time (scenario time)
    rb.tick(T0 + 0.02)  # the same assignment again: nothing new
    assert rb.events() == [] and rb.mode['mode'] == 'yield'
    # a pair replaces the yield: one exit, one entry, and the pair's drift w_c as sent
    a.assign(T0 + 0.03, {0: _encounter('mutual', drift=[0.01, -0.02], t_entry_s=1.03)}, None)
    rb.tick(T0 + 0.03)
    assert rb.events() == [('exit', 'yield', 'robot_1', 'cw'),
                           ('enter', 'mutual', 'robot_1', 'ccw')]
    m = a.state.modes
    assert m.mode[0, 0] == MODE_MUTUAL and m.wtgt[0, 0].tolist() == [0.01, -0.02]
    # w_c starts from the sent drift and relaxes to its target: here its target, so it stays
    np.testing.assert_allclose(m.wc[0, 0], [0.01, -0.02], atol=1e-12)
    # withdrawn: the encounter ends with an exit and the S8.4 cool-down record
    a.assign(T0 + 0.04, {}, None)
    rb.tick(T0 + 0.04)
    assert rb.events() == [('exit', 'mutual', 'robot_1', 'ccw')]
    assert rb.mode['mode'] == 'coordination'
    row1 = a.row[1]
    assert (m.last_kind[0, 0], m.last_tgt[0, 0]) == (KIND_ROBOT, row1)
    assert m.last_exit[0, 0] == pytest.approx(0.04)


def test_an_assignment_with_a_partner_not_heard_waits_until_it_is():
    rb = Robot(HEAD_ON, 0)
    a = rb.agent
    rb.start((0.0, 0.6, 0.0), assignments={0: _encounter('yield')})
    assert rb.mode['mode'] == 'coordination' and rb.events() == []
    a.hear(1, np.array([0.5, 0.6, math.pi, 0.0, 0.0]), np.zeros(2), T0 + 0.01)
    rb.tick(T0 + 0.01)
    assert rb.events() == [('enter', 'yield', 'robot_1', 'ccw')]
    # the partner falls silent (beyond parent_hold_s): the encounter ends
    a.assign(T0 + 1.02, {0: _encounter('yield')}, None)
    rb.tick(T0 + 1.02)
    assert rb.events() == [('exit', 'yield', 'robot_1', 'ccw')]
    # a partner that is not a robot of the scenario is no assignment
    a.assign(T0 + 1.03, {0: _encounter('yield', partner=9)}, None)
    assert a.state.assigned[0, :2].tolist() == [MODE_C, -1]


def test_a_coordinated_robot_never_enters_a_robot_encounter_by_itself():
    """S7.1: the coordinator alone decides yield/mutual; the robot's own emergency response is
    the barrier. Robot 1 stands 0.30 m ahead (inside Q, inside the barrier's range of R_aa
    = 0.25 m) and robot 0 closes at its reference's speed, 0.08 m/s: no encounter, but a braking
    command (alone, on its line at that speed, it has nothing to brake for).
    """
    near = _facing(gap_m=0.30, v=0.08)
    alone = Robot(HEAD_ON, 0)
    alone.start((0.0, 0.6, 0.0), v=0.08)
    for k in range(1, 20):
        near.agent.hear(1, np.array([0.30, 0.6, math.pi, 0.0, 0.0]), np.zeros(2), T0 + 0.01 * k)
        near.tick(T0 + 0.01 * k)
        alone.tick(T0 + 0.01 * k)
        assert near.mode['mode'] == 'coordination' and near.events() == []
    assert near.agent.out.accel[0, 0] < -0.05  # brakes toward the keep-out circle
    assert alone.agent.out.accel[0, 0] > -0.02  # on its line: nothing to brake for
    assert near.torque.sum() < alone.torque.sum() - 0.01


def test_a_robot_enters_its_obstacle_by_itself_and_keeps_it_against_robot_assignments():
    # p on the minor axis of O1 (phi = 2 pi / 3), 0.22 m from its centre: inside Q, outside I,
    # heading at the centre at 0.05 m/s
    pose = (1.0 - 0.22 * math.sin(2 * math.pi / 3), -0.2 + 0.22 * math.cos(2 * math.pi / 3),
            math.pi / 6)
    rb = Robot(PAPER, 0)
    a = rb.agent
    rb.start(pose, v=0.05)
    assert rb.mode['mode'] == 'obstacle' and rb.mode['target'] == 'O1'
    assert rb.mode['avoiding'] and rb.mode['direction'] in ('cw', 'ccw')
    assert rb.events() == [('enter', 'obstacle', 'O1', rb.mode['direction'])]
    assert np.abs(rb.torque).max() <= PAPER.robot(0).params.torque_limit_nm
    # a robot encounter assigned while on the obstacle is not taken (static obstacles first)
    a.hear(1, np.array([0.0, 1.0, 0.0, 0.0, 0.0]), np.zeros(2), T0 + 0.01)
    a.assign(T0 + 0.01, {0: _encounter('yield')}, None)
    rb.tick(T0 + 0.01)
    assert rb.mode['mode'] == 'obstacle' and rb.events() == []
    # asked to make way: no parking until then
    a.assign(T0 + 0.02, {0: _encounter('make_way', partner=0, park_at=30.0)}, None)
    rb.tick(T0 + 0.02)
    m = a.state.modes
    assert m.mode[0, 0] == MODE_OBSTACLE and m.park_at[0, 0] == 30.0
    a.assign(T0 + 0.03, {}, None)  # a later message without it does not shorten the wait
    rb.tick(T0 + 0.03)
    assert m.park_at[0, 0] == 30.0


def test_mode_reports_are_encoded_or_read_as_coordination():
    a = RobotAgent(PAPER, 0)
    assert a.encode_mode({'mode': 'obstacle', 'target': 'O2', 'direction': 'cw'}) == (
        MODE_OBSTACLE, 1, -1.0)
    assert a.encode_mode({'mode': 'mutual', 'target': 'robot_1', 'direction': 'ccw'}) == (
        MODE_MUTUAL, 1, 1.0)
    for bad in ({'mode': 'yield', 'target': 'robot_9'}, {'mode': 'obstacle', 'target': 'O7'},
                {'mode': 'yield', 'target': 3}, {'mode': 'dance'}, {}):
        assert a.encode_mode(bad) == (MODE_C, -1, 1.0), bad
    # a neighbour busy with a robot this one does not know (or an obstacle it does not avoid)
    # takes part as a robot in coordination, and the law stays finite
    rb = Robot(HEAD_ON, 0)
    rb.agent.hear(1, np.array([0.6, 0.6, math.pi, 0.08, 0.0]), np.zeros(2), T0)
    rb.agent.hear_mode(1, {'mode': 'yield', 'target': 'robot_9', 'direction': 'cw'})
    rb.start((0.0, 0.6, 0.0), v=0.05)
    rb.agent.hear_mode(1, {'mode': 'obstacle', 'target': 'O1', 'direction': 'cw'})
    rb.tick(T0 + 0.01)
    assert rb.agent.state.modes.mode[0, 1] == MODE_C and np.all(np.isfinite(rb.torque))


# --------------------------------------------------------------------------- progress (S17)


def test_a_leaders_progress_follows_the_coordinators_rate():
    rb = Robot(HEAD_ON, 0)
    a = rb.agent
    path = HEAD_ON.robot(0).path  # a line at 0.08 m/s
    rb.start((0.0, 0.6, 0.0), rates={0: 0.0})
    tau = a.law.progress_tau_s
    s, sd = 0.0, 1.0  # the rate at the start is 1; the first period sets s_ddot, moves nothing
    sdd = (0.0 - sd) / tau
    for k in range(1, 101):  # 1 s with the rate target 0: s_dot -> 0 with tau 1 s
        rb.tick(T0 + 0.01 * k)
        s, sd = s + sd * 0.01 + 0.5 * sdd * 1e-4, sd + sdd * 0.01
        sdd = (0.0 - sd) / tau
    pr = a.state.progress
    assert pr.sd[0] == pytest.approx(0.99**100, rel=1e-9)  # 0.366
    assert pr.s[0] == pytest.approx(s, rel=1e-9) and 0.6 < s < 0.7  # not 1 s of path
    assert pr.target[0] == 0.0
    r, rd, _ = path.reference(s)
    np.testing.assert_allclose(a.state.ref[0, 0, :2], r, atol=1e-9)
    np.testing.assert_allclose(a.state.ref[0, 0, 2:4], np.asarray(rd) * sd, atol=1e-9)
    # rates are clamped into [0, 1]
    a.assign(T0 + 1.0, {}, {0: 3.0})
    assert a.state.rate_target[0] == 1.0
    for k in range(101, 601):  # 5 s more at rate 1: s_dot back to within 1 % of 1
        if k % 100 == 0:
            a.assign(T0 + 0.01 * k, {}, None)  # the coordinator heard; the rate unchanged
        rb.tick(T0 + 0.01 * k)
    assert 0.99 < pr.sd[0] <= 1.0
    a.assign(T0 + 6.0, {}, {0: -1.0, 1: 0.5})  # robot 1 is not hosted: ignored
    assert a.state.rate_target[0] == 0.0


# --------------------------------------------------------------------------- limits, inputs


def test_torques_are_clamped_and_non_finite_inputs_are_rejected():
    rb = Robot(HEAD_ON, 0)
    a = rb.agent
    limit = HEAD_ON.robot(0).params.torque_limit_nm
    rb.start((0.0, 1.6, math.pi), v=0.15)  # 1 m off its line, backwards, fast
    assert 0.0 < np.abs(rb.torque).max() <= limit  # S3: the law's acceleration is bounded
    # knocked into a spin (12 rad/s): the law asks for more than the limit; scaled into it (S3.6)
    spun = Robot(HEAD_ON, 0)
    spun.start((0.0, 1.6, math.pi), v=0.15, w=12.0)
    assert np.abs(spun.torque).max() == pytest.approx(limit, rel=1e-12)
    assert spun.agent.out.saturated[0]
    before = a.counters(0)['rejected_nonfinite']
    a.wheel(0, T0 + 0.01, (math.nan, 0.0), (0.0, 0.0))
    a.wheel(0, T0 + 0.01, (0.0, 0.0), (math.inf, 0.0))
    a.camera(0, T0 + 0.01, (math.nan, 0.0, 0.0))
    a.camera(0, math.nan, (0.0, 1.6, math.pi))
    a.tick(T0 + 0.01)
    assert a.counters(0)['rejected_nonfinite'] == before + 4
    assert rb.status == 'running' and np.all(np.isfinite(a.out.state))
    assert np.all(np.isfinite(rb.torque)) and np.abs(rb.torque).max() <= limit


@pytest.mark.parametrize(
    'kwargs, field',
    [
        ({'control_rate_hz': 0.0}, 'control_rate_hz'),
        ({'pose_timeout_s': math.nan}, 'pose_timeout_s'),
        ({'parent_timeout_s': 0.5, 'parent_hold_s': 0.2}, 'parent_hold_s'),
        ({'hear_all': 1}, 'hear_all'),
        ({'camera_gain': 1.5}, 'camera_gain'),
        ({'control_rate_hz': 50.0, 'state_rate_hz': 60.0}, 'state_rate_hz'),
        ({'state_rate_hz': 0.0}, 'state_rate_hz'),
    ],
)
def test_agent_params_name_the_bad_field(kwargs, field):
    with pytest.raises(ConfigError) as err:
        AgentParams(**kwargs)
    assert err.value.field == field


@pytest.mark.parametrize('control_hz, state_hz, every', [(100.0, 25.0, 4), (100.0, 100.0, 1),
                                                         (100.0, 30.0, 3), (50.0, 25.0, 2)])
def test_the_state_goes_out_every_whole_number_of_control_periods(control_hz, state_hz, every):
    assert AgentParams(control_rate_hz=control_hz, state_rate_hz=state_hz).state_every == every


def test_a_stop_that_cannot_end_by_the_pose_timeout_or_an_unknown_robot_is_refused():
    with pytest.raises(ConfigError) as err:
        RobotAgent(PAPER, 0, AgentParams(pose_timeout_s=0.2))
    assert err.value.field == 'pose_timeout_s'
    with pytest.raises(ConfigError) as err:
        AgentBatch(PAPER, [0, 5])
    assert err.value.field == 'robot_id'


# --------------------------------------------------------------------------- batch = agents


def _closed_loop(scenario, seconds):
    """The plant twin with one AgentBatch of every robot and, fed the same inputs, one
    RobotAgent per robot, and the coordinator: (torques of the batch (T, N, 2), of the single
    agents (T, N, 2), events of both, the twin).
    """
    ids = tuple(sorted(r.id for r in scenario.robots))
    twin = PlantTwin(scenario)
    row = [twin.ids.index(rid) for rid in ids]
    batch = AgentBatch(scenario, ids)
    single = {rid: RobotAgent(scenario, rid) for rid in ids}
    coord, publisher = Coordinator(scenario), Publisher(1.0)
    every = [batch, *single.values()]
    for ag in every:
        ag.set_graph(coord.parents, 0.0)
        ag.assign(0.0, {}, None)
    twin.start()
    tb, ts, eb, es, reported = [], [], [], [], {}
    for k in range(int(round(seconds / 0.01))):
        t = 0.01 * k
        for ag in every:
            for q, rid in enumerate(ids):
                i = row[q]
                if rid in ag.hosted:
                    ag.wheel(rid, t, twin.wheel_angle_rad[i], twin.wheel_rate_radps[i])
                if k % 3 == 0:  # a camera frame every 30 ms, no delay
                    ag.camera(rid, t, twin.state[i, :3])
        batch.tick(t)
        batch.share(t)
        for ag in single.values():
            ag.tick(t)
        for rid, ag in single.items():  # the broadcasts of this period
            for other, peer in single.items():
                if other == rid:
                    continue
                if peer.initialized(0) and other in ag.needed(rid):
                    ag.hear(other, peer.out.state[0], peer.out.accel[0], t)
                ag.hear_mode(other, peer.mode_dict(0))
        tb.append(batch.out.torque.copy())
        ts.append(np.array([single[rid].out.torque[0] for rid in ids]))
        eb.extend(batch.events)
        for ag in single.values():
            es.extend(ag.events)
        for r, rid in enumerate(ids):  # the coordinator hears the batch
            coord.state(rid, batch.out.state[r], t)
            mode = batch.mode_dict(r)
            if mode != reported.get(rid):
                reported[rid] = mode
                coord.report(rid, mode)
        parents = coord.reported_avoiding()
        if parents is not None:
            for ag in every:
                ag.set_graph(parents, 0.0)
        if k % 2 == 0:
            assignments, rates = coord.decide(t)
            if publisher.due(t, assignments, rates):
                for ag in every:
                    ag.assign(t, assignments, rates)
        twin.advance(0.01, batch.out.torque[np.argsort(row)])
    return np.array(tb), np.array(ts), eb, es, twin, ids


def test_a_batch_of_robots_is_one_agent_each_and_reproduces_the_simulator():
    """One compiled call for the four robots of the chain gives every robot's torques as its own
    RobotAgent does, bit for bit, through robot 1's detour round O1; the detour is the ideal
    simulator's (enter/exit within 0.1 s) and the formation closes up as there (robot 1 parked
    on O1, where its slot ends).
    """
    tb, ts, eb, es, twin, ids = _closed_loop(CHAIN, 24.0)
    assert tb.shape == (2400, 4, 2)
    np.testing.assert_array_equal(tb, ts)
    key = lambda e: (e['t_s'], e['robot'], e['event'], e['mode'], e['target'])  # noqa: E731
    assert sorted(map(key, eb)) == sorted(map(key, es))
    assert np.abs(tb).max() <= CHAIN.robot(0).params.torque_limit_nm
    ref = simulate(CHAIN)
    mine = [(e['robot'], e['event'], e['target']) for e in eb]
    theirs = [(e['robot'], e['event'], e['target']) for e in ref.mode_events]
    assert mine == theirs and (1, 'enter', 'O1') in mine
    for a, b in zip(eb, ref.mode_events):
        assert abs(a['t_s'] - b['t_s']) <= 0.1
    # at the end every follower is at its slot behind the leader, but robot 1: its slot then lies
    # inside O1 (leader at x = 1 m: slot (0.5, 0.5), 0.1 m from O1's centre, P 0.15 m), so it
    # stays parked on O1 outside P (no exit, as in the ideal run; S17.1 leaves it out of the
    # team's error)
    row = {rid: twin.ids.index(rid) for rid in ids}
    lead = twin.state[row[0], :2]
    assert np.hypot(*(lead - (1.0, 0.0))) < 0.02 and mine[-1] == (1, 'enter', 'O1')
    assert 0.15 < np.hypot(*(twin.state[row[1], :2] - (0.6, 0.5))) < 0.25
    for rid in ids[2:]:
        slot = np.asarray(CHAIN.robot(rid).slot_m) - np.asarray(CHAIN.robot(0).slot_m)
        assert np.hypot(*(twin.state[row[rid], :2] - lead - slot)) < 0.02, rid


# --------------------------------------------------------------------------- the stop's torque

K = PlantCoeffs.from_params([RobotParams()])
GAINS = ControlGains()


def test_stop_torque_is_zero_at_rest_and_brakes_motion():
    rest = np.array([[0.3, -0.2, 1.0, 0.0, 0.0]])
    np.testing.assert_allclose(stop_torque(rest, K, 0.5, GAINS), 0.0, atol=1e-15)
    moving = np.array([[0.0, 0.0, 0.0, 0.2, 0.0]])
    tau = stop_torque(moving, K, 0.5, GAINS)[0]
    assert tau[0] < 0 and tau[1] < 0 and tau[0] == pytest.approx(tau[1])
    fast = np.array([[0.0, 0.0, 0.0, 5.0, 3.0]])
    assert np.max(np.abs(stop_torque(fast, K, 0.5, GAINS))) == pytest.approx(K.tau_max[0])


@pytest.mark.parametrize('x2', [(0.2, 0.0), (-0.1, 1.5), (5.0, 3.0), (0.001, -0.02)])
def test_the_compiled_stop_is_the_stop_law(x2):
    """stop_torque_k (the agent's) is stop_torque of one robot, its omega gains per unit of d."""
    x = np.array([[0.0, 0.0, 0.3, *x2]])
    (k_v, e_v), (k_w, e_w) = stop_gains(GAINS, 0.8, 0.01)
    want = stop_torque(x, K, 0.3, GAINS, 0.8, 0.01)[0]
    coeffs = np.stack([K.m_tilde, K.I_tilde, K.r, K.a, K.d, K.m_c, K.tau_max])
    got = stop_torque_k(x2[0], x2[1], robot_plant_k(coeffs, 0), K.tau_max[0], 0.3, k_v, e_v,
                        k_w / K.d[0], e_w / K.d[0])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_stop_brings_the_wheels_to_rest():
    x = np.array([0.0, 0.0, 0.3, 0.15, 0.8])
    dt = 0.001
    for _ in range(3000):  # 3 s, six stop times
        t1, t2 = stop_torque(x[None], K, 0.5, GAINS)[0]
        k = [K.m_tilde[0], K.I_tilde[0], K.r[0], K.a[0], K.d[0], K.m_c[0]]
        x = np.array(
            rk4_step_k(tuple(x), (t1, t2), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), dt, RobotPlant(*k))
        )
    assert abs(x[3]) < 1e-4 and abs(x[4]) < 1e-3


def _stop_with_late_wheels(delay_s, scaled, seconds=3.0):
    """The camera-loss stop law of the reference robot on the plant, its (v, omega) ``delay_s``
    old (a sample held), commands every 10 ms: (|v|, |omega|) maxima over the last 0.5 s.
    """
    (k_v, e_v), (k_w, e_w) = stop_gains(GAINS, 0.8, 0.01)
    k_w, e_w = k_w / K.d[0], e_w / K.d[0]
    plant = RobotPlant(K.m_tilde[0], K.I_tilde[0], K.r[0], K.a[0], K.d[0], K.m_c[0])
    s = delay_scale_k(0.3, k_v, e_v, k_w, e_w, delay_s - 0.02) if scaled else 1.0
    dt, lag = 0.001, int(round(delay_s / 0.001))
    x, history, tau, tail = (0.0, 0.0, 0.0, 0.1, 1.0), [], (0.0, 0.0), []
    for n in range(int(seconds / dt)):
        history.append(x)
        if n % 10 == 0:
            m = history[max(0, len(history) - 1 - lag)]
            tau = stop_torque_k(m[3], m[4], plant, K.tau_max[0], 0.3 / s, k_v * s, e_v,
                                k_w * s, e_w)
        x = rk4_step_k(x, tau, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), dt, plant)
        if n * dt >= seconds - 0.5:
            tail.append((abs(x[3]), abs(x[4])))
    return max(v for v, _ in tail), max(w for _, w in tail)


@pytest.mark.parametrize('delay_s', [0.035, 0.1, 0.2])
def test_the_stop_comes_to_rest_with_late_wheel_samples(delay_s):
    """The stop law's loop closes through the wheels' telemetry; measured 70 ms late or more it
    did not come to rest (docs/safety.md §7, "A late measurement"). With its rates scaled for the
    sample's age it does; nothing changes for fresh samples.
    """
    v, w = _stop_with_late_wheels(delay_s, scaled=True)
    assert v < 0.0025 and w < 0.025, (v, w)
    if delay_s >= 0.1:  # unscaled, the same loop swings on: the scaling is what holds it
        v0, w0 = _stop_with_late_wheels(delay_s, scaled=False)
        assert w0 > 0.05, (v0, w0)


def test_the_stop_scaling_leaves_fresh_samples_alone_and_shrinks_with_age():
    (k_v, e_v), (k_w, e_w) = stop_gains(GAINS, 0.8, 0.01)
    args = (0.3, k_v, e_v, k_w / K.d[0], e_w / K.d[0])
    assert delay_scale_k(*args, 0.0) == 1.0 and delay_scale_k(*args, 0.014) == 1.0
    assert 0.0 < delay_scale_k(*args, 0.1) < delay_scale_k(*args, 0.05) < 1.0


def test_a_robot_whose_wheel_samples_are_late_brakes_gentler():
    """The agent scales its camera-loss stop by the age of its newest wheel sample."""
    def stop_torque_at(wheel_age_s):
        rb = Robot(HEAD_ON, 0)
        rb.start((0.0, 0.6, 0.0), v=0.1)
        for k in range(1, 60):
            now = T0 + 0.01 * k
            if rb.tick(now, camera=False) == 'stopped_pose':
                break
        last_wheel = now
        while now < last_wheel + wheel_age_s - 1e-9:  # periods without a wheel sample
            now += 0.01
            rb.agent.tick(now)
        assert rb.status == 'stopped_pose'
        return np.abs(rb.torque).max()

    fresh, late = stop_torque_at(0.0), stop_torque_at(0.06)
    assert 0.0 < late < 0.75 * fresh, (fresh, late)
