"""formation_team (nodes/team.py): several robots' bridge and controller nodes in one process.
The closed loop through a team is tested in test_system.py (head-on encounter, both layouts).
"""

from __future__ import annotations

from pathlib import Path
import subprocess

import numpy as np
from processes import program
import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.nodes.team import TeamNode, TeamParams

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'test' / 'data' / 'paper_short.yaml'


@pytest.mark.parametrize(
    'kwargs, field',
    [
        ({}, 'scenario'),
        ({'scenario': 'x.yaml', 'robot_ids': (0, 0)}, 'robot_ids'),
        ({'scenario': 'x.yaml', 'robot_ids': (-1,)}, 'robot_ids'),
        ({'scenario': 'x.yaml', 'port_template': '/dev/ttyACM0'}, 'port_template'),
    ],
)
def test_team_params_are_validated(kwargs, field):
    with pytest.raises(ConfigError) as err:
        TeamParams(**kwargs)
    assert err.value.field == field


def test_unknown_robot_is_rejected(ros_context):
    with pytest.raises(ConfigError, match='robot_ids.*not robots of'):
        TeamNode(context=ros_context, params=TeamParams(scenario=str(SCENARIO), robot_ids=(0, 7)))


def test_one_tick_runs_every_hosted_controller_and_peers_read_in_process(ros_context):
    """One team tick = one control period of every hosted robot's agent (one AgentBatch, one
    compiled call); a hosted robot hears its hosted peer's state, accel and mode exactly as the
    peer's agent made them, in process (no DDS subscription between them).
    """
    from ament_formation.core.control.agent import RUNNING
    from ament_formation.core.control.switching import MODE_C, MODE_OBSTACLE
    from ament_formation.core.scenario.loader import load_scenario

    sc = load_scenario(SCENARIO)
    team = TeamNode(
        context=ros_context, params=TeamParams(scenario=str(SCENARIO)), control_thread=False
    )
    try:
        assert sorted(team.controllers) == [0, 1] and team.bridges == {}
        c0, c1 = team.controllers[0], team.controllers[1]
        b, st = team.batch, team.batch.state
        assert c0.batch is b and c1.batch is b and b.hosted == (0, 1)
        r0, r1, k0 = c0.r, c1.r, b.row[0]
        # no DDS subscription to a hosted peer: robot 1 hears its parent 0 in process
        c1.update_hearing()
        topics = {s.topic_name for c in (c0, c1) for s in c.subscriptions}
        assert not any(t.startswith(('/robot_0/', '/robot_1/')) and not t.endswith('/pose')
                       and not t.endswith('wheel_state') for t in topics), topics
        assert c1._full == {} and b.needed(1) == [0]
        now = c0.now_s()
        for c in (c0, c1):  # a camera pose and wheel data for each
            b.wheel(c.rid, now, np.zeros(2), np.zeros(2))
            b.camera(c.rid, now - 0.03, np.asarray(sc.robot(c.rid).initial_pose, dtype=float))
        # the period runs at a fixed time 1 ms after the inputs: a loaded machine's delay between
        # these lines must not age the pose or wheel data beyond their timeouts
        t = now + 0.001
        team._now_ns = lambda: int(t * 1e9)
        team._control()
        assert (c0.ticks, c1.ticks) == (1, 1)
        assert (c0.safety, c1.safety) == ('waiting', 'waiting')  # no graph, no coordinator yet
        np.testing.assert_allclose(b.out.torque, 0.0)
        # what robot 0's agent made of the period is what robot 1 hears, stamped with the period
        np.testing.assert_allclose(b.out.state[r0, :2], sc.robot(0).initial_pose[:2], atol=1e-3)
        np.testing.assert_array_equal(st.heard_x[r1, k0], b.out.state[r0])
        assert st.stamp[r1, k0] == pytest.approx(t, abs=1e-6)
        assert (st.rep_mode[r1, k0], st.rep_tgt[r1, k0]) == (MODE_C, -1)  # not running yet
        # a running robot 0 on obstacle O1 (cw) with a commanded acceleration: in process at once
        st.status[r0] = RUNNING
        b.out.mode[r0] = (MODE_OBSTACLE, 0, -1.0)
        b.out.accel[r0] = (0.01, -0.02)
        b.share(t + 0.01)
        assert (st.rep_mode[r1, k0], st.rep_tgt[r1, k0], st.rep_sdir[r1, k0]) == (
            MODE_OBSTACLE, 0, -1.0)
        np.testing.assert_array_equal(st.heard_a[r1, k0], [0.01, -0.02])
        assert st.stamp[r1, k0] == pytest.approx(t + 0.01, abs=1e-6)
    finally:
        team.destroy_node()
    assert team.controllers == {}


def test_the_control_loop_runs_the_callbacks_that_take_the_team_lock(ros_context):
    """The control loop holds the team's lock for a whole period and, within it, hands the hosted
    bridges' wheel samples to the controllers and takes the heard robots' state; those callbacks
    take the lock too (the executor thread may run them), so the loop must get it again, not
    wait for itself forever (a team whose loop hung drove no robot).
    """
    import threading

    team = TeamNode(context=ros_context, params=TeamParams(scenario=str(SCENARIO)))
    try:
        assert team.loop is not None and team.lock is not None  # wall clock: the loop thread
        c1 = team.controllers[1]
        done = threading.Event()
        queued = []

        def period():  # what ControlLoop does: the lock held, then a hosted bridge's sample
            with team.lock:
                c1.wheel_sample(np.zeros(2), np.zeros(2), c1.now_s())
                c1._on_state(0, _odometry(c1.now_s()))
                # read under the lock: the team's own loop may take the sample right after it
                # (seen with two CPU-bound processes beside the suite)
                queued.append(int(team.batch.state.nwheel[c1.r]))
            done.set()

        worker = threading.Thread(target=period, daemon=True)
        worker.start()
        assert done.wait(5.0), 'the control loop deadlocked on its own lock'
        assert queued[0] >= 1
        assert team.batch.state.stamp[c1.r, team.batch.row[0]] > 0.0
    finally:
        team.destroy_node()


def _odometry(stamp_s: float):
    from ament_formation.ros import messages as msgs

    return msgs.odometry(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), msgs.stamp_from_s(stamp_s),
                         'robot_0')


def test_process_exits_2_on_bad_parameters(tmp_path):
    exe = program('formation_team')
    proc = subprocess.run(
        [str(exe), '--ros-args', '-p', f'scenario:={SCENARIO}', '-p', 'robot_ids:=[0, 9]'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and 'robot_ids' in lines[0] and '9' in lines[0], proc.stderr


class _FakeBridge:
    """A hosted bridge as ControlLoop sees it: a port with a file descriptor and poll()."""

    def __init__(self, fd: int, drain: bool):
        import types

        self._port = types.SimpleNamespace(fileno=lambda: fd)
        self.fd, self.drain, self.polls = fd, drain, []

    def poll(self) -> None:
        import os
        import time

        self.polls.append(time.monotonic())
        if self.drain:
            try:
                os.read(self.fd, 4096)
            except BlockingIOError:
                pass


class _FakeTeam:
    """What ControlLoop uses of a TeamNode."""

    def __init__(self, bridge: _FakeBridge):
        import threading
        import types

        self.bridges = {0: bridge}
        self.lock = threading.Lock()
        self.ticks: list[float] = []
        self.context = types.SimpleNamespace(ok=lambda: True)

    def _control(self) -> None:
        import time

        self.ticks.append(time.monotonic())

    def get_logger(self):
        import logging

        return logging.getLogger('test_team')


def test_control_loop_reads_telemetry_as_it_arrives_and_never_spins_on_a_hung_port():
    """ControlLoop: data on a port is read when it arrives, between the periods; a port that
    stays readable without data (a hung-up pty: here a pipe whose writer is gone) is read at most
    once per MIN_READ_GAP_S, not in a busy loop.
    """
    import os
    import time

    from ament_formation.nodes.team import ControlLoop

    r, w = os.pipe()
    os.set_blocking(r, False)
    bridge = _FakeBridge(r, drain=True)
    team = _FakeTeam(bridge)
    loop = ControlLoop(team, rate_hz=5.0)  # periods of 0.2 s
    t0 = time.monotonic()
    loop.start()
    try:
        time.sleep(0.05)
        os.write(w, b'\x00telemetry\x00')
        deadline = time.monotonic() + 5.0
        while not bridge.polls and time.monotonic() < deadline:
            time.sleep(0.005)
        assert bridge.polls, 'the data was never read'
        # read on readiness, before the first period's poll (0.2 s after the start)
        assert not team.ticks or bridge.polls[0] < team.ticks[0]
        assert bridge.polls[0] - t0 < 0.2 + 0.1
    finally:
        loop.stop()
        os.close(w)
        os.close(r)

    r, w = os.pipe()
    os.close(w)  # the read end is readable (end of file) for ever
    bridge = _FakeBridge(r, drain=False)
    team = _FakeTeam(bridge)
    loop = ControlLoop(team, rate_hz=100.0)
    cpu0 = time.process_time()
    t0 = time.monotonic()
    loop.start()
    try:
        time.sleep(0.5)
    finally:
        loop.stop()
        os.close(r)
    elapsed = time.monotonic() - t0
    reads = len(bridge.polls) - len(team.ticks)  # polls on readiness (each period polls too)
    assert len(team.ticks) >= 1 and reads >= 1
    assert reads <= elapsed / ControlLoop.MIN_READ_GAP_S + 2, (reads, elapsed)
    assert time.process_time() - cpu0 < 0.5 * elapsed  # not a busy loop


def test_a_fresh_pose_runs_the_period_at_once_and_the_next_a_full_period_later():
    """ControlLoop.pose_arrived (a team of one robot: the robot's computer, tick_on_pose): the
    period runs at once instead of at the schedule's next one, and the schedule restarts from it.
    Periods of 1 s, so that "at once" and "a full period later" are far apart under load.
    """
    import os
    import time

    from ament_formation.nodes.team import ControlLoop

    r, w = os.pipe()
    os.set_blocking(r, False)
    team = _FakeTeam(_FakeBridge(r, drain=True))
    loop = ControlLoop(team, rate_hz=1.0)

    def wait_ticks(n: int) -> float:
        deadline = time.monotonic() + 5.0
        while len(team.ticks) < n and time.monotonic() < deadline:
            time.sleep(0.005)
        assert len(team.ticks) >= n, f'{len(team.ticks)} periods, {n} expected'
        return team.ticks[n - 1]

    loop.start()
    try:
        first = wait_ticks(1)
        while time.monotonic() < first + 0.4:  # the pose comes mid-period
            time.sleep(0.005)
        sent = time.monotonic()
        loop.pose_arrived()
        at_pose = wait_ticks(2)
        after = wait_ticks(3)
        assert at_pose - sent < 0.3  # not at the schedule's next period (0.6 s away)
        assert after - at_pose > 0.8  # the schedule restarted from the pose's period
        assert loop.pose_periods == 1
    finally:
        loop.stop()
        os.close(w)
        os.close(r)
    loop.pose_arrived()  # after stop: writes nowhere, raises nothing
