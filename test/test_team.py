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
    """One team tick = one control period of every hosted controller, in id order; a controller
    sees its peer's state, accel and mode exactly as the peer published them (no DDS subscription).
    """
    from ament_formation.core.scenario.loader import load_scenario
    from ament_formation.ros import messages as msgs

    sc = load_scenario(SCENARIO)
    team = TeamNode(
        context=ros_context, params=TeamParams(scenario=str(SCENARIO)), control_thread=False
    )
    try:
        assert sorted(team.controllers) == [0, 1] and team.bridges == {}
        c0, c1 = team.controllers[0], team.controllers[1]
        assert (
            c1.neighbours[0] is team.peers.records[0] and c0.neighbours[1] is team.peers.records[1]
        )
        assert (
            c1.neighbours[0].subs == [] and c1.neighbours[0].state is None
        )  # nothing published yet
        now = c0.now_s()
        for c in (c0, c1):  # a camera pose and wheel data for each
            c.estimator.wheel_update(now, np.zeros(2), np.zeros(2))
            c.last_wheel_s = now
            c.estimator.camera_update(
                now - 0.03, np.asarray(sc.robot(c.rid).initial_pose, dtype=float)
            )
        # the period runs at a fixed time 1 ms after the inputs: a loaded machine's delay between
        # these lines must not age the pose or wheel data beyond their timeouts
        team._now_ns = lambda: int((now + 0.001) * 1e9)
        team._control()
        assert (c0.ticks, c1.ticks) == (1, 1)
        seen = c1.neighbours[0]
        published, stamp_s = msgs.state_from_odometry(
            c0._msg_state
        )  # what went out on robot_0/state
        np.testing.assert_allclose(seen.state, published, atol=1e-12)
        np.testing.assert_allclose(seen.state[:2], sc.robot(0).initial_pose[:2], atol=1e-3)
        # the message carries whole nanoseconds, a float of epoch seconds ~2.4e-7 s: the two
        # agree to the float's resolution, not to a nanosecond
        assert seen.stamp_s == pytest.approx(stamp_s, abs=1e-6) and seen.stamp_s >= now
        assert (seen.mode, seen.target) == ('coordination', None)
        c0.mode = {'mode': 'obstacle', 'target': 'O1', 'direction': 'cw', 'avoiding': True}
        c0._send(np.zeros(2), np.array([0.01, -0.02]), c0.now_s())
        assert (seen.mode, seen.target) == ('obstacle', 'O1')
        np.testing.assert_array_equal(seen.accel, [0.01, -0.02])
    finally:
        team.destroy_node()
    assert team.controllers == {}


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
