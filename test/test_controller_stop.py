"""Camera loss → at rest by ``pose_timeout_s`` (+ one control period): the controlled stop begins
``lead(v, omega)`` before ``pose_timeout_s``, lead = time to rest from the current speed under the
stop law + ``stop_margin_s`` (core/control/stop.py StopLead, docs/safety.md §7).

Deterministic: the closed form against the stop law integrated on the plant, and the node driven
through ``control_tick(now_s)`` with synthetic camera and wheel samples (no sleeps, no timers).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from oracle_dynamics import rk4_step
import pytest

from ament_formation.core.control.stop import REST_SPEED_MPS, stop_torque, StopLead
from ament_formation.core.errors import ConfigError
from ament_formation.core.model.dynamics import PlantCoeffs
from ament_formation.core.scenario.loader import load_scenario

SCENARIO = Path(__file__).resolve().parent / 'data' / 'paper_short.yaml'
PERIOD_S = 0.01  # the controller's period (100 Hz): torques held between ticks


@pytest.fixture(scope='module')
def scenario():
    return load_scenario(SCENARIO)


DECEL_MPS2 = 0.8  # stop_decel_mps2's default


def _lead(sc, **kw) -> StopLead:
    robot = sc.robot(1).params
    kw.setdefault('decel_mps2', DECEL_MPS2)
    return StopLead(robot, 0.3, sc.control, sc.disturbance.accel_bound, **kw)


def _simulated_time_to_rest(
    sc, v0: float, w0: float, decel_mps2: float, delay_periods: int = 0, horizon_s: float = 2.0
) -> float:
    """The stop law at 100 Hz (ZOH) on the plant, the disturbance at its bound pushing along the
    initial motion (the worst case of the closed form): time until both wheels' rim speeds stay
    below REST_SPEED_MPS. ``delay_periods``: each command computed from the state that many
    periods old (the loop through the board's telemetry, the bridge and the estimator).
    """
    robot = sc.robot(1).params
    k = PlantCoeffs.from_params([robot])
    g = np.array([[math.copysign(b, s) for b, s in zip(sc.disturbance.accel_bound, (v0, w0))]])
    x = np.array([[0.0, 0.0, 0.3, v0, w0]])
    half_axle = 0.5 * robot.axle_length_m
    dt, t, last_moving = 0.001, 0.0, 0.0
    seen = [x.copy()] * (delay_periods + 1)
    while t < horizon_s:
        if round(t / dt) % round(PERIOD_S / dt) == 0:
            seen = seen[1:] + [x.copy()]
            u = stop_torque(seen[0], k, 0.3, sc.control, decel_mps2, PERIOD_S)
        x = rk4_step(x, u, lambda _t: g, t, dt, k)
        t += dt
        if abs(x[0, 3]) + half_axle * abs(x[0, 4]) >= REST_SPEED_MPS:
            last_moving = t
    return last_moving


@pytest.mark.parametrize('decel', [0.0, DECEL_MPS2])  # 0: the formation law's gain (hold_parent)
@pytest.mark.parametrize(
    'v0, w0',
    [(0.05, 0.0), (0.2, 0.0), (0.25, 0.0), (0.08, 1.4), (-0.1, -1.0), (0.0, 2.5), (0.003, 0.0)],
)
def test_time_to_rest_bounds_the_stop_law_on_the_plant(scenario, v0, w0, decel):
    """The closed form is an upper bound of the sampled stop law (one period of slack for the ZOH)
    and tight: within 60 ms.
    """
    lead = _lead(scenario, decel_mps2=decel)
    predicted = lead.time_to_rest(v0, w0)
    simulated = _simulated_time_to_rest(scenario, v0, w0, lead.decel_mps2)
    assert simulated <= predicted + PERIOD_S
    assert predicted - simulated < 0.06, (predicted, simulated)


@pytest.mark.parametrize('decel', [0.0, DECEL_MPS2])
@pytest.mark.parametrize('v0, w0', [(0.08, 0.3), (0.0, 1.0), (0.15, -2.5)])
def test_the_stop_comes_to_rest_through_a_loop_three_periods_late(scenario, v0, w0, decel):
    """The commands act on wheel speeds about 3.5 control periods old (board telemetry, bridge,
    estimator; measured in the twin). With boundary layers of 1.85 K T_s the stop chattered there
    at up to 0.15 rad/s and never came to rest; with STOP_LAYER_PERIODS it rests, and stays so.
    """
    lead = _lead(scenario, decel_mps2=decel)
    for delay in (1, 2, 3):
        late = _simulated_time_to_rest(scenario, v0, w0, lead.decel_mps2, delay, horizon_s=4.0)
        assert late < 2.0, f'{delay} periods late: still moving after 2 s (the loop chatters)'
        assert late <= lead.lead_s(v0, w0) + PERIOD_S, (delay, late)  # margin: the path


def test_lead_grows_with_speed_and_is_capped_at_its_worst_case(scenario):
    lead = _lead(scenario, margin_s=0.03, speed_max_mps=0.15, turn_rate_max_radps=2.5)
    for leads in (
        [lead.lead_s(v, 0.0) for v in (0.0, 0.02, 0.05, 0.1, 0.15)],
        [lead.lead_s(0.0, w) for w in (0.0, 0.5, 1.0, 2.0, 2.5)],
    ):
        assert leads == sorted(leads) and leads[0] == pytest.approx(0.03)
    assert lead.lead_s(0.15, 2.5) == pytest.approx(lead.max_s)
    assert lead.lead_s(0.6, 3.0) == lead.max_s  # beyond the bounds: capped (and counted)
    assert lead.over_bound(0.16, 0.0) and lead.over_bound(0.0, -2.6)
    assert not lead.over_bound(-0.15, 2.5)
    # defaults: worst case 0.429 s to rest (from 0.15 m/s and 2.5 rad/s) + 0.03 s fits in 0.5 s
    assert lead.max_s == pytest.approx(0.459, abs=0.002)
    lead.check(0.5)
    # the harder brake on v shortens the lead at the speeds the formation drives
    gentle = _lead(scenario, decel_mps2=0.0)
    assert gentle.max_s == pytest.approx(0.478, abs=0.002)
    assert lead.lead_s(0.08, 0.2) < 0.8 * gentle.lead_s(0.08, 0.2)


def test_a_weaker_robot_gets_the_decel_its_torque_limit_allows(scenario):
    import dataclasses

    weak = dataclasses.replace(scenario.robot(1).params, torque_limit_nm=0.12)
    lead = StopLead(weak, 0.3, scenario.control, scenario.disturbance.accel_bound, decel_mps2=0.8)
    assert scenario.control.switching_gain_mps2 < lead.decel_mps2 < 0.8
    assert 0.119 < lead.peak_torque_nm <= 0.12


def test_parameters_whose_worst_case_lead_exceeds_pose_timeout_are_refused(scenario):
    lead = _lead(scenario, margin_s=0.03)
    with pytest.raises(ConfigError, match=r'pose_timeout_s: must be >= 0\.45\d s') as err:
        lead.check(0.3)
    for name in ('stop_speed_max_mps', 'stop_turn_rate_max_radps', 'stop_margin_s'):
        assert name in str(err.value)
    with pytest.raises(ConfigError, match='stop_speed_max_mps: .* more than the torque limit'):
        _lead(scenario, speed_max_mps=0.8)  # the law would saturate: no closed form there
    robot = scenario.robot(1).params
    with pytest.raises(ConfigError, match='stop_time_s: .* disturbance bound'):
        StopLead(robot, 0.3, scenario.control, (0.3, 0.5))  # g1_bar > switching gain


def _node(ctx, **params):
    from ament_formation.nodes.controller import ControllerNode, ControllerParams

    return ControllerNode(
        context=ctx,
        namespace='/robot_1',
        tick_timer=False,
        params=ControllerParams(scenario=str(SCENARIO), robot_id=1, **params),
    )


def _node_lead(node) -> StopLead:
    """The stop lead the node's agent runs (AgentBatch: from the node's parameters)."""
    p, sc = node.prm, node.scenario
    return StopLead(sc.robot(node.rid).params, p.stop_time_s, sc.control,
                    sc.disturbance.accel_bound, p.stop_margin_s, p.stop_speed_max_mps,
                    p.stop_turn_rate_max_radps, p.stop_decel_mps2, 1.0 / p.control_rate_hz)


def _camera(node, t_s: float) -> None:
    """Robot 1's camera pose captured at ``t_s`` (its initial pose), as the pose topic gives it."""
    node.batch.camera(node.rid, t_s, (0.0, 1.0, 0.0))


def _drive(node, t0: float, v: float, w: float, ticks: int, start: int = 0) -> list[str]:
    """Ticks ``start`` .. ``start + ticks - 1`` at PERIOD_S, wheel samples at rates giving
    (v, w) before each; the safety state after each tick.
    """
    p = node.scenario.robot(node.rid).params
    r, a = p.wheel_radius_m, p.axle_length_m
    rates = ((v - 0.5 * a * w) / r, (v + 0.5 * a * w) / r)
    states = []
    for i in range(start, start + ticks):
        now = t0 + i * PERIOD_S
        q = (rates[0] * i * PERIOD_S, rates[1] * i * PERIOD_S)
        node.wheel_sample(q, rates, now)  # as the bridge's samples reach it
        node.control_tick(now)
        states.append(node.safety)
    return states


@pytest.mark.parametrize(
    'v, w', [(0.0, 0.0), (0.1, 0.0), (0.149, 0.0), (0.05, 1.5), (-0.1, -2.49), (0.149, 2.49)]
)
def test_node_begins_the_stop_lead_before_pose_timeout(ros_context, v, w):
    """The node's camera-loss stop begins at the first tick whose camera age exceeds
    pose_timeout_s - lead(v, w): at rest by pose_timeout_s + one period - stop_margin_s.
    """
    node = _node(ros_context)
    try:
        lead = _node_lead(node)
        t0 = 1000.0
        _camera(node, t0)  # the last pose, captured at t0
        states = _drive(node, t0, v, w, 60)
        first = states.index('stopped_pose')
        age = first * PERIOD_S
        threshold = 0.5 - lead.lead_s(v, w)
        assert threshold < age <= threshold + PERIOD_S + 1e-9
        assert age + lead.time_to_rest(v, w) <= 0.5 + PERIOD_S - 0.03 + 1e-9
        assert set(states[:first]) == {'waiting'}  # no graph yet: standing by until then
        assert node.mode['mode'] == 'stopped'  # /robot_i/mode as before
        assert node.batch.counters(node.r)['over_stop_speed'] == 0
        # braking: the stop's torque opposes the motion (zero from rest)
        torque = node.batch.out.torque[node.r]
        if v > 0.0:
            assert torque.sum() < 0.0
        elif v == 0.0 and w == 0.0:
            np.testing.assert_allclose(torque, 0.0, atol=1e-9)
    finally:
        node.destroy_node()


def test_node_counts_speeds_beyond_the_bounds_and_caps_the_lead(ros_context):
    node = _node(ros_context)
    try:
        lead = _node_lead(node)
        t0 = 1000.0
        _camera(node, t0)
        states = _drive(node, t0, 0.2, 3.0, 30)  # both beyond the bounds (0.15 m/s, 2.5 rad/s)
        first = states.index('stopped_pose')
        threshold = 0.5 - lead.max_s  # the cap: 0.041 s
        assert threshold == pytest.approx(0.041, abs=0.002)
        assert threshold < first * PERIOD_S <= threshold + PERIOD_S + 1e-9
        # every tick driven faster than the bound, the one that began the stop included
        assert node.batch.counters(node.r)['over_stop_speed'] == first + 1
        assert node._control_status()[2]['over_stop_speed'] == first + 1
    finally:
        node.destroy_node()


def test_node_stop_is_latched_until_a_new_pose(ros_context):
    """Braking shrinks the lead, but the stop stays until a newer camera pose arrives; then the
    robot is released at once.
    """
    node = _node(ros_context)
    try:
        t0 = 1000.0
        _camera(node, t0)
        states = _drive(node, t0, 0.15, 0.0, 40)
        first = states.index('stopped_pose')
        assert set(states[first:]) == {'stopped_pose'}
        # slower now (lead 0.03 s only) but the pose is as stale as before: still stopped
        assert _drive(node, t0, 0.0, 0.0, 5, start=40) == ['stopped_pose'] * 5
        _camera(node, t0 + 0.44)  # a fresh pose
        assert _drive(node, t0, 0.0, 0.0, 1, start=45) == ['waiting']  # no graph yet: waiting
    finally:
        node.destroy_node()


def test_node_refuses_a_pose_timeout_shorter_than_the_worst_case_lead(ros_context):
    with pytest.raises(ConfigError, match=r'pose_timeout_s: must be >= 0\.45'):
        _node(ros_context, pose_timeout_s=0.3)
    node = _node(
        ros_context,
        pose_timeout_s=0.3,
        stop_speed_max_mps=0.05,
        stop_turn_rate_max_radps=0.5,
        stop_margin_s=0.02,
    )
    try:
        assert _node_lead(node).max_s <= 0.3
        # the agent's compiled lead is this one: the stop begins 0.3 - lead(0.05, 0) after the
        # last pose
        t0 = 1000.0
        _camera(node, t0)
        states = _drive(node, t0, 0.05, 0.0, 40)
        threshold = 0.3 - _node_lead(node).lead_s(0.05, 0.0)
        assert threshold < states.index('stopped_pose') * PERIOD_S <= threshold + PERIOD_S + 1e-9
    finally:
        node.destroy_node()


def test_node_without_wheel_data_sends_no_torque_so_the_board_brakes(ros_context):
    """With no wheel data the agent has nothing to brake with and outputs zero torque; a zero
    torque lets a torque-controlled robot coast (in the frictionless twin, spinning it up: a
    process-per-node run on an overloaded machine reached 0.6-1.8 m/s). So the node sends no
    command at all, and the bridge's input timeout has the board brake with its own encoders
    (docs/safety.md, "No wheel data"). Commands resume with the wheel data.
    """
    node = _node(ros_context)
    sent: list[str] = []
    publish = node.pub_torque.publish
    node.pub_torque.publish = lambda msg: (sent.append(node.safety), publish(msg))
    try:
        t0 = 1000.0
        _camera(node, t0)
        states = _drive(node, t0, 0.05, 0.0, 5)
        assert states == ['waiting'] * 5 and len(sent) == 5
        for i in range(5, 30):  # the wheel samples stop; poses go on
            node.batch.camera(node.rid, t0 + i * PERIOD_S, (0.0, 1.0, 0.0))
            node.control_tick(t0 + i * PERIOD_S)
            states.append(node.safety)
        assert states[-1] == 'stopped_wheels'
        first = states.index('stopped_wheels')
        assert first * PERIOD_S >= node.prm.wheel_timeout_s - 1e-9
        assert len(sent) == first and 'stopped_wheels' not in sent  # nothing from then on
        _drive(node, t0, 0.05, 0.0, 3, start=30)  # the wheel data is back: commands again
        assert len(sent) == first + 3
    finally:
        node.destroy_node()
