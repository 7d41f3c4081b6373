"""Host link logic (core/serial/serial_link.py) against the emulated board
(core/serial/motor_board.py) in simulated time, no ports and no ROS: deterministic numbers for
the protocol rules.
"""

from __future__ import annotations

import collections

import numpy as np
import pytest

from ament_formation.core.serial import serial_link as sl
from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.byte_faults import ByteFaults, FaultSpec
from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard


def run_link(
    n_inputs: int,
    faults: FaultSpec = FaultSpec(),
    board_cfg: BoardConfig = BoardConfig(),
    dt_s: float = 0.0005,
    seed: int = 3,
    **params,
):
    rng = np.random.default_rng(seed)
    log: list = []
    board = MotorBoard(board_cfg, command_log=log)
    host = sl.LinkHost(sl.LinkParams(**params))
    host.sent_log = collections.deque()
    rx, tx = ByteFaults(faults, rng), ByteFaults(faults, rng)
    to_board = host.connected(0.0)
    t, k = 0.0, 0
    while t < 0.2 + n_inputs * 0.01 + 0.05:
        t += dt_s
        if k < n_inputs and t >= 0.2 + k * 0.01:
            k += 1
            host.set_input((k * 1e-4, -k * 1e-4), t)
            to_board += host.command_now(t)
        board.receive(rx.pass_bytes(to_board, t), t)
        board.step(t)
        _, answer = host.receive(tx.pass_bytes(board.take_output(), t), t)
        to_board = answer + host.poll(t)
    applied = {(l, r) for _, _, l, r in log}
    kept = sum((v, -v) in applied for v in range(1, n_inputs + 1)) / n_inputs
    sent = set(host.sent_log)
    corrupt = [(s, l, r) for _, s, l, r in log if (s, l, r) not in sent]
    return host, board, kept, corrupt


def test_clean_link_applies_every_command_without_retransmission():
    host, board, kept, corrupt = run_link(300)
    assert host.state == sl.UP and kept == 1.0 and corrupt == []
    assert host.stats['retransmissions'] == 0 and board.decoder.rejected_total == 0
    assert host.decoder.rejected_total == 0 and board.watchdog_trips == 0


def test_one_percent_corruption_keeps_96_percent_and_applies_nothing_corrupt():
    # 1 % of bytes corrupted hits ~12 % of the 13-byte commands (version 2: CRC-32C, 2 bytes more
    # than version 1); one retransmission per input recovers most: 0.968-0.99 over seeds 3-8
    host, board, kept, corrupt = run_link(1000, FaultSpec(corrupt_prob=0.01))
    assert board.decoder.rejected_total > 50  # ~12 % of frames were hit
    assert kept >= 0.96, kept
    assert corrupt == []
    assert host.stats['retransmissions'] > 50


def test_bridge_limit_and_rounding_never_exceed_the_wire_limit():
    host = sl.LinkHost(sl.LinkParams(torque_limit_nm=0.12345))
    assert not host.set_input((float('nan'), 0.0), 0.0) and not host.set_input((0.0,), 0.0)
    assert host.set_input((1.0, -1.0), 0.0)
    host.state = sl.UP
    frame = sp.FrameDecoder().feed(host.command_now(0.0))[0]
    assert (frame.msg.left_e4nm, frame.msg.right_e4nm) == (1234, -1234)
    assert host.stats['inputs_rejected'] == 2 and host.stats['inputs_clamped'] == 1


def test_stale_input_is_sent_as_stop():
    host = sl.LinkHost(sl.LinkParams(input_timeout_s=0.1))
    host.state = sl.UP
    host.set_input((0.05, 0.05), 0.0)
    dec = sp.FrameDecoder()
    assert dec.feed(host.poll(0.05))[0].msg == sp.TorqueCommand(500, 500)
    assert dec.feed(host.poll(0.11))[0].msg == sp.Stop(sp.STOP_INPUT_STALE)  # brake, never coast
    assert host.stats['stale_stops'] == 1
    assert [f.msg for f in dec.feed(host.stop_commands(2))] == [sp.Stop(sp.STOP_HOST_SHUTDOWN)] * 2


def test_controller_silence_brakes_the_wheels_once_then_releases():
    """Input goes stale on a driving robot: the bridge sends STOP, the board brakes at once (no
    watchdog delay), releases at rest, and the STOPs that keep coming do not brake again.
    """
    board = MotorBoard(
        BoardConfig(wheel_inertia_kgm2=1.6e-3, wheel_damping_nms=2e-3), standalone=True
    )
    host = sl.LinkHost(sl.LinkParams(input_timeout_s=0.1))
    out, t = host.connected(0.0), 0.0
    last_input_s = 1.0
    while t < 3.0:
        t += 0.0005
        if t < last_input_s and round(t / 0.0005) % 20 == 0:
            host.set_input((0.1, 0.1), t)
            out += host.command_now(t)
        board.receive(out, t)
        board.step(t)
        _, out = host.receive(board.take_output(), t)
        out += host.poll(t)
    assert board.brakes == 1 and board.stops_received > 100 and board.watchdog_trips == 0
    assert last_input_s + 0.1 <= board.brake_started_s <= last_input_s + 0.1 + 0.011
    assert board.brake_released_s - board.brake_started_s < 1.0  # at rest, not timed out
    assert abs(board.wheel_vel_radps[0]) < 0.44 and board.applied_e4nm == [0, 0]
    assert host.state == sl.UP and host.stats['retransmissions'] == 0


@pytest.mark.parametrize('board_version', [1, 3])
def test_version_mismatch_sends_no_torque(board_version):
    # a version-1 board answers the (version-1 framed) HELLO in version-1 framing, a version-3
    # board
    # in its own: either way the host reads its version, says so, and never sends a command
    host, board, kept, _ = run_link(50, board_cfg=BoardConfig(protocol_version=board_version))
    assert host.state == sl.VERSION_MISMATCH and host.board_version == board_version
    assert kept == 0.0 and host.stats['commands_sent'] == 0 and board.accepted_commands == 0
    assert f'board speaks version {board_version}' in host.version_mismatch_text()


def test_version_1_host_reads_the_mismatch_from_a_version_2_board():
    board = MotorBoard()
    v1_host = sp.FrameDecoder(accepted_version=1)
    board.receive(sp.encode_frame(sp.Hello(1), 0, leading_delimiter=True, version=1), 0.0)
    frames = v1_host.feed(board.take_output())
    assert [f.msg.protocol_version for f in frames] == [2] and frames[0].version == 1
    # its version-1 torque commands are rejected, never applied
    board.receive(
        sp.encode_frame(sp.TorqueCommand(500, 500), 1, leading_delimiter=True, version=1), 0.01
    )
    assert board.accepted_commands == 0 and board.decoder.rejected['version'] == 1


def test_board_reset_triggers_a_new_handshake():
    log: list = []
    board = MotorBoard(command_log=log)
    host = sl.LinkHost(sl.LinkParams())
    out, t = host.connected(0.0), 0.0
    for _ in range(200):
        t += 0.001
        board.receive(out, t)
        board.step(t)
        _, out = host.receive(board.take_output(), t)
        out += host.poll(t)
        if t > 0.1 and host.stats['board_resets'] == 0 and board.flags & sp.FLAG_RESET == 0:
            board.boot(t)  # e.g. a DTR reset of an Arduino
    assert host.stats['board_resets'] == 1 and host.state == sl.UP


@pytest.mark.parametrize(
    'field,value',
    [
        ('torque_limit_nm', 0.0),
        ('watchdog_s', 1.0),
        ('port', ''),
        ('reconnect_initial_s', 2.0),
        ('baud_rate', 10),
    ],
)
def test_bad_parameters_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        sl.LinkParams(**{field: value})
