"""/diagnostics (ros/diagnostics.py): stall detection with an injected clock, publication on
change, the naming scheme, and node-level checks on the controller (a stalled executor is
reported with its gap; a safety stop is published when it happens, at the level of the state).
"""

from __future__ import annotations

from pathlib import Path
import time

import numpy as np
import pytest

from ament_formation.ros import diagnostics as diag
from ament_formation.ros.executors import spin_until

DATA = Path(__file__).resolve().parent / 'data'
MS = 1_000_000  # [ns]


class FakeClock:

    def __init__(self, t_ns: int = 1_000 * MS):
        self.t = t_ns

    def __call__(self) -> int:
        return self.t


# --------------------------------------------------------------------------- PeriodWatch
def test_period_watch_counts_stalls_on_its_clock():
    clock = FakeClock()
    stalls = []
    w = diag.PeriodWatch(
        0.01,
        clock,
        late_periods=3.0,
        min_late_s=0.0,
        warn_hold_s=5.0,
        on_stall=lambda watch: stalls.append(watch.last_gap_s),
    )
    rng = np.random.default_rng(3)
    for _ in range(100):  # on time, with jitter up to 2.9 periods
        w.tick()
        clock.t += int(rng.uniform(5, 29) * MS)
    assert w.stalls == 0 and w.status()[0] == diag.OK
    assert w.status()[1] == 'on time'
    clock.t += 200 * MS  # the callback runs 0.2 s + one jitter late
    assert w.tick() is True
    assert w.stalls == 1 and len(stalls) == 1 and 0.2 < stalls[0] < 0.23
    level, message, values = w.status()
    assert level == diag.WARN and 'stalled 0.2' in message and '1 stalls' in message
    assert values['stalls'] == 1 and values['max_gap_s'] == pytest.approx(stalls[0])
    for _ in range(600):  # 6 s on time: back to OK after warn_hold_s, the count stays
        clock.t += 10 * MS
        w.tick()
    assert w.status()[0] == diag.OK and w.status()[1] == 'on time (1 stalls so far)'


def test_period_watch_ignores_clock_start_and_jumps_back():
    clock = FakeClock(0)  # sim time before the first /clock
    w = diag.PeriodWatch(0.01, clock, min_late_s=0.0)
    w.tick()
    clock.t = 5_000 * MS  # /clock arrives: not a stall
    assert w.tick() is False
    clock.t = 1_000 * MS  # time went backward (a replay restarted): not a stall
    assert w.tick() is False
    clock.t += 10 * MS
    assert w.tick() is False and w.stalls == 0


def test_period_watch_reports_work_that_stopped_running():
    clock = FakeClock()
    w = diag.PeriodWatch(0.01, clock, warn_hold_s=5.0)
    assert w.status() == (diag.OK, 'not started', w.status()[2])
    w.tick()
    clock.t += 2_000 * MS  # no tick for 2 s (more than warn_hold_s / 5)
    level, message, _ = w.status()
    assert level == diag.WARN and message.startswith('stalled: not run for 2')


def test_period_watch_floor_and_validation():
    w = diag.PeriodWatch(0.002, FakeClock(), late_periods=3.0, min_late_s=0.02)
    assert w.threshold_ns == 20 * MS  # 3 periods of a 500 Hz poll would be 6 ms
    with pytest.raises(ValueError, match='period_s'):
        diag.PeriodWatch(0.0, FakeClock())
    with pytest.raises(ValueError, match='late_periods'):
        diag.PeriodWatch(0.01, FakeClock(), late_periods=1.0)


def test_naming_helpers():
    assert (
        diag.status_name('formation_controller', 'robot_3 control')
        == 'formation_controller: robot_3 control'
    )
    assert diag.robot_of_namespace('/robot_3') == 'robot_3'
    assert diag.robot_of_namespace('/lab/robot_12/') == 'robot_12'
    assert diag.robot_of_namespace('/') is None and diag.robot_of_namespace('/robot_x') is None
    st = diag.status('n: c', 'robot_1', diag.ERROR, 'm', {'t_s': 1796152600.1234, 'x': 0.5})
    assert diag.level_int(st.level) == diag.ERROR and diag.level_name(st.level) == 'ERROR'
    assert {kv.key: kv.value for kv in st.values} == {'t_s': '1796152600.123', 'x': '0.5'}


# --------------------------------------------------------------------------- Diagnostics publisher
def test_publishes_periodically_and_at_once_on_change(ros_context, executor):
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy

    from ament_formation.ros.qos import QOS_DIAGNOSTICS

    node = rclpy.create_node('widget', namespace='/robot_4', context=ros_context)
    state = {'level': diag.OK, 'message': 'fine', 'n': 0}
    d = diag.Diagnostics(node, period_s=30.0)  # the periodic publication is far away
    d.add(
        'robot_4 widget',
        lambda: (state['level'], state['message'], {'n': state['n']}),
        hardware_id='robot_4',
    )
    probe = rclpy.create_node('probe', context=ros_context)
    got = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', got.append, QOS_DIAGNOSTICS)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: d.pub.get_subscription_count() > 0, 10.0)

    assert d.changed() is True  # never published: published now
    state['n'] = 5
    assert d.changed() is False  # values alone do not make a change
    state['level'], state['message'] = diag.ERROR, 'broken'
    assert d.changed() is True
    assert spin_until(executor, lambda: len(got) == 2, 5.0)
    st = got[-1].status[0]
    assert (st.name, st.hardware_id, diag.level_int(st.level), st.message) == (
        'widget: robot_4 widget',
        'robot_4',
        diag.ERROR,
        'broken',
    )
    assert {kv.key: kv.value for kv in st.values} == {'n': '5'}
    node.destroy_node()
    probe.destroy_node()


# --------------------------------------------------------------------------- node level:
# controller
@pytest.fixture
def controller(ros_context, executor):
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy

    from ament_formation.nodes.controller import ControllerNode, ControllerParams
    from ament_formation.ros.qos import QOS_DIAGNOSTICS

    ctrl = ControllerNode(
        context=ros_context,
        namespace='/robot_1',
        params=ControllerParams(scenario=str(DATA / 'redundant_chain.yaml'), robot_id=1),
    )
    probe = rclpy.create_node('probe', context=ros_context)
    statuses: dict[str, list] = {}

    def on_diag(arr):
        for st in arr.status:
            statuses.setdefault(st.name, []).append((time.monotonic(), st))

    probe.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_DIAGNOSTICS)
    executor.add_node(ctrl)
    executor.add_node(probe)
    names = {f'formation_controller: robot_1 {c}' for c in ('control', 'control loop', 'inputs')}
    assert spin_until(executor, lambda: names <= set(statuses), 30.0), set(statuses)
    for name in names:
        assert statuses[name][-1][1].hardware_id == 'robot_1'
    yield ctrl, probe, statuses
    probe.destroy_node()
    ctrl.destroy_node()


def test_controller_reports_a_stalled_control_loop(controller, executor):
    ctrl, probe, statuses = controller
    name = 'formation_controller: robot_1 control loop'
    watch = ctrl.control_watch
    ticks0 = watch.ticks
    assert spin_until(executor, lambda: watch.ticks > ticks0 + 50, 30.0)
    stalls0 = watch.stalls
    n0 = len(statuses[name])
    blocker = probe.create_timer(0.01, lambda: (time.sleep(0.4), blocker.cancel()))  # 40 periods

    def stall_status():
        for _, st in statuses[name][n0:]:
            values = {kv.key: kv.value for kv in st.values}
            if diag.level_int(st.level) == diag.WARN and int(values['stalls']) > stalls0:
                return st, values
        return None

    assert spin_until(executor, lambda: stall_status() is not None, 5.0)
    st, values = stall_status()
    assert float(values['last_stall_gap_s']) >= 0.35
    assert st.message.startswith('stalled 0.')


def test_controller_safety_stop_is_published_when_it_happens(controller, executor):
    """A robot that stops (its wheel data stops, its parent falls silent, the coordinator falls
    silent, a clock is off) is on /diagnostics at once (ERROR; hold_parent WARN) with why, not at
    the next 1 s sample, and back to OK when it runs again; a brief stop between two samples is
    seen. The control timer runs (100 Hz); only the inputs are fed here.
    """
    from ament_formation.ros import messages as m

    ctrl, probe, statuses = controller
    name = 'formation_controller: robot_1 control'
    now = ctrl.now_s

    def feed(wheels=True):
        t = now()
        if wheels:
            ctrl.wheel_sample((0.0, 0.0), (0.0, 0.0), t)
        ctrl.batch.camera(1, t, (-0.5, 0.5, 0.0))  # its camera pose, fresh

    def seen(n0, *wanted):
        """The statuses published since n0 include ``wanted`` (level, status) in this order."""
        got = [(diag.level_int(st.level), st.message.split(':')[0])
               for _, st in statuses[name][n0:]]
        it = iter(got)
        return all(w in it for w in wanted)

    assert spin_until(executor, lambda: (feed(), ctrl.batch.initialized(ctrl.r))[1], 10.0)
    assert ctrl.safety == 'waiting'  # no graph, no coordinator yet
    n0 = len(statuses[name])
    # the wheel data stops for a moment: stopped_wheels, then waiting again within a second
    assert spin_until(executor, lambda: (feed(wheels=False), ctrl.safety == 'stopped_wheels')[1],
                      5.0)
    t_stop = time.monotonic()
    assert spin_until(executor, lambda: (feed(), ctrl.safety == 'waiting')[1], 5.0)
    assert time.monotonic() - t_stop < 1.0
    assert spin_until(executor, lambda: (feed(), seen(n0, (diag.ERROR, 'stopped_wheels'),
                                                      (diag.OK, 'waiting')))[1], 5.0)
    message = next(st.message for _, st in statuses[name][n0:] if diag.level_int(st.level))
    assert message.startswith('stopped_wheels: no wheel data')
    # the mission starts (graph and coordinator heard) but its parent robot 0 is never heard:
    # hold_parent, WARN
    n0 = len(statuses[name])
    ctrl._on_graph(m.graph_msg(m.GraphMessage(1, {0: None, 1: 0, 2: 1, 3: 0}, {1: (-0.5, 0.5)},
                                              stamp_s=now(), start_s=now() - 1.0)))
    ctrl._on_encounters(m.encounters_msg(m.EncountersMessage(1, {}, {0: 1.0}, now())))
    t_last = time.monotonic()  # the coordinator's last message (the timeout counts from here)
    assert spin_until(executor, lambda: (feed(), seen(n0, (diag.WARN, 'hold_parent')))[1], 5.0)
    values = {kv.key: kv.value for kv in statuses[name][-1][1].values}
    assert values['coordinator_heard'] == 'True' and values['safety'] == 'hold_parent'
    # the coordinator falls silent for coordinator_timeout_s (2.5 s): stopped_coordinator
    assert spin_until(executor, lambda: (feed(), seen(n0, (diag.ERROR, 'stopped_coordinator')))[1],
                      10.0)
    assert time.monotonic() - t_last >= ctrl.prm.coordinator_timeout_s - 0.1
    _, st = next((t, st) for t, st in reversed(statuses[name]) if 'coordinator' in st.message)
    values = {kv.key: kv.value for kv in st.values}
    assert values['coordinator_heard'] == 'False'
    assert 'is formation_coordinator running' in st.message
    # a coordinator whose clock is 5 s ahead (beyond the 2 s bound): stopped_clock, the offset
    # reported
    n0 = len(statuses[name])
    ctrl._on_encounters(m.encounters_msg(m.EncountersMessage(2, {}, {0: 1.0}, now() + 5.0)))
    assert spin_until(executor, lambda: (feed(), seen(n0, (diag.ERROR, 'stopped_clock')))[1], 5.0)
    st = next(st for _, st in statuses[name][n0:] if st.message.startswith('stopped_clock'))
    values = {kv.key: kv.value for kv in st.values}
    assert 4.9 < float(values['clock_offset_coordinator_s']) <= 5.0
    assert 'synchronise the clocks' in st.message


def test_world_reports_each_board_brake_and_its_cause(ros_context, tmp_path):
    """formation_world: one "board robot_<id>" status per emulated board (what formation multihost
    --fault reads): watchdog trips, STOPs, brakes, the cause and times of the last one.
    """
    from ament_formation.core.serial import serial_protocol as sp
    from ament_formation.nodes.world import WorldNode, WorldParams

    world = WorldNode(
        context=ros_context,
        params=WorldParams(
            scenario=str(DATA / 'paper_short.yaml'),
            pty_dir=str(tmp_path / 'pty'),
            camera_enabled=False,
            exit_at_end=False,
        ),
    )
    try:
        board = world.boards[1].board
        now = world.now_s()
        board.receive(sp.encode_frame(sp.TorqueCommand(100, 100), 1), now)
        board.receive(sp.encode_frame(sp.Stop(sp.STOP_INPUT_STALE), 2), now + 0.01)
        statuses = {t.name: (level, values) for t, level, _m, values in world.diag._evaluate()}
        level, values = statuses['formation_world: board robot_1']
        assert level == 0 and values['brake_cause'] == 'stop' and values['brakes'] == 1
        assert values['stops_received'] == 1 and values['brake_started_s'] == now + 0.01
        assert values['last_stop_reason'] == 'input_stale'
        assert statuses['formation_world: board robot_0'][1]['brake_cause'] == 'none'
    finally:
        world.destroy_node()


def test_a_change_during_shutdown_is_not_an_error():
    """A bridge closing its port in destroy_node reports the lost link: after the context is shut
    down this must be a no-op, not an exception that turns a clean exit into a traceback.
    """
    import os

    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    node = rclpy.create_node('closing', context=ctx)
    state = {'level': diag.OK}
    d = diag.Diagnostics(node)
    d.add('link', lambda: (state['level'], str(state['level']), {}))
    assert d.changed() is True
    rclpy.shutdown(context=ctx)
    state['level'] = diag.ERROR
    assert d.changed() is False
    d.publish()
    node.destroy_node()


def test_rejections_warn_for_the_hold_after_the_newest_and_keep_the_counts():
    now = [100.0]
    rej = diag.Rejections(('graph', 'mode'), lambda: now[0], hold_s=10.0)
    assert rej.status() == (diag.OK, 'inputs valid', {'rejected_graph': 0, 'rejected_mode': 0})
    rej.counts['graph'] += 1
    level, message, values = rej.status()
    assert level == diag.WARN and values == {'rejected_graph': 1, 'rejected_mode': 0}
    now[0] = 108.0
    rej.counts['mode'] += 2  # a newer one restarts the hold; the message stays (a flood: once)
    assert rej.status()[:2] == (level, message) and rej.total == 3
    now[0] = 117.0
    assert rej.status()[0] == diag.WARN
    now[0] = 118.5
    assert rej.status() == (
        diag.OK,
        'no input rejected in the last 10 s',
        {'rejected_graph': 1, 'rejected_mode': 2},
    )
