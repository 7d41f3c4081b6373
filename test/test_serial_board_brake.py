"""The emulated board's stop brake (core/serial/motor_board.py, docs/safety.md): when commands
stop it regulates the wheels to rest with a bounded torque, then releases; the numbers are the
firmware's.
"""

from __future__ import annotations

from firmware_sim import config_constants
import numpy as np
import pytest

from ament_formation.core.serial import motor_board as mb
from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard

DT_S = 0.001


def _drive(board: MotorBoard, torque_e4nm: int, until_s: float, t: float) -> float:
    """Commands every 10 ms until ``until_s``; returns the time reached."""
    seq = 0
    while t < until_s:
        if round(t / DT_S) % 10 == 0:
            board.receive(
                sp.encode_frame(sp.TorqueCommand(torque_e4nm, -torque_e4nm), seq & 0xFF), t
            )
            seq += 1
        board.step(t)
        board.take_output()
        t += DT_S
    return t


def _run_silent(
    board: MotorBoard, t: float, duration_s: float
) -> list[tuple[float, float, float, int, int]]:
    """No commands for ``duration_s``: rows (t_s, left_radps, left_rad, left_applied_e4nm,
    flags).
    """
    rows = []
    end = t + duration_s
    while t < end:
        board.step(t)
        board.take_output()
        rows.append(
            (
                t,
                float(board.wheel_vel_radps[0]),
                float(board.wheel_pos_rad[0]),
                board.applied_e4nm[0],
                board.flags,
            )
        )
        t += DT_S
    return rows


def test_constants_are_the_firmwares():
    c = config_constants()
    assert mb.BRAKE_GAIN_NM_PER_RADPS == pytest.approx(c['BRAKE_GAIN_NM_PER_RADPS'])
    assert mb.BRAKE_TORQUE_LIMIT_NM == pytest.approx(c['BRAKE_TORQUE_LIMIT_NM'])
    assert mb.BRAKE_REST_S == pytest.approx(c['BRAKE_REST_MS'] * 1e-3)
    assert mb.BRAKE_MAX_S == pytest.approx(c['BRAKE_MAX_MS'] * 1e-3)
    assert mb.CONTROL_PERIOD_S == pytest.approx(c['CONTROL_PERIOD_MS'] * 1e-3)
    assert BoardConfig().watchdog_s == pytest.approx(c['COMMAND_WATCHDOG_MS'] * 1e-3)


def test_command_loss_brakes_to_rest_with_bounded_torque_then_releases():
    cfg = BoardConfig(
        wheel_inertia_kgm2=1.6e-3, wheel_damping_nms=2e-3
    )  # the simavr harness's wheel
    board = MotorBoard(cfg, standalone=True)
    t = _drive(board, 1500, 1.0, 0.0)
    speed0 = float(board.wheel_vel_radps[0])
    assert speed0 > 10.0
    t_loss = t - DT_S * 10  # roughly: the last command was < 10 ms ago
    rows = _run_silent(board, t, 2.0)
    ts, w, ang, tau, flags = (np.array(c) for c in zip(*rows))
    braking = (flags & sp.FLAG_BRAKING) != 0
    assert braking.any() and board.brakes == 1
    assert board.brake_cause == 'watchdog'  # what the world's diagnostics report
    t_brake = ts[braking][0]
    assert 0.19 <= t_brake - t_loss <= 0.21  # after the 200 ms watchdog
    assert np.all(tau[ts < t_brake] == 1500)  # the command holds until then
    assert np.all(np.abs(tau[braking]) <= 1000)  # bounded: 0.10 N m
    fast = braking & (np.abs(w) > 0.5)  # beyond the one-count quantum (0.44 rad/s) of the speed
    assert np.all(tau[fast] * w[fast] < 0)  # against the motion
    released = board.brake_released_s
    assert released is not None and not board.braking and board.flags & sp.FLAG_WATCHDOG
    assert released - t_brake < mb.BRAKE_MAX_S - 0.1  # at rest, not timed out
    after = ts >= released
    assert np.all(tau[after] == 0) and abs(w[after][0]) < 0.44  # H-bridge off, wheel at rest
    # against coasting: the same wheel without the brake turns for seconds (J / b = 0.8 s)
    decel = mb.BRAKE_TORQUE_LIMIT_NM / cfg.wheel_inertia_kgm2
    assert released - t_brake < speed0 / decel + 0.25
    print(
        f'emulated brake: {speed0:.1f} rad/s -> released {released - t_loss:.3f} s '
        'after command loss, '
        f'wheel turned {ang[after][0] - ang[0]:.2f} rad'
    )


def test_brake_gives_way_to_commands_and_estop():
    board = MotorBoard(
        BoardConfig(wheel_inertia_kgm2=1.6e-3, wheel_damping_nms=2e-3), standalone=True
    )
    t = _drive(board, 800, 0.5, 0.0)
    rows = _run_silent(board, t, 0.25)
    assert board.braking and rows[-1][3] < 0
    t = rows[-1][0] + DT_S
    board.receive(sp.encode_frame(sp.TorqueCommand(300, -300), 200), t)  # commands are back
    assert not board.braking and board.applied_e4nm == [300, -300]
    assert not board.flags & sp.FLAG_BRAKING
    _run_silent(board, t, 0.25)
    assert board.braking and board.brakes == 2
    board.receive(sp.encode_frame(sp.EmergencyStop(1), 201), t + 0.25)
    assert not board.braking and board.applied_e4nm == [0, 0]


def test_brake_cause_is_the_bridges_stop_or_the_watchdog():
    """What the world's board diagnostics report (formation multihost --fault)."""
    board = MotorBoard(
        BoardConfig(wheel_inertia_kgm2=1.6e-3, wheel_damping_nms=2e-3), standalone=True
    )
    assert board.brake_cause is None
    t = _drive(board, 800, 0.5, 0.0)
    board.receive(sp.encode_frame(sp.Stop(), 200), t)  # the bridge's STOP brakes at once
    assert board.braking and board.brakes == 1 and board.brake_cause == 'stop'
    t += DT_S
    board.receive(sp.encode_frame(sp.TorqueCommand(300, -300), 201), t)
    _run_silent(board, t, 0.25)
    assert board.braking and board.brakes == 2 and board.brake_cause == 'watchdog'


def test_no_brake_at_boot_and_bounded_by_a_lowered_limit():
    board = MotorBoard(standalone=True)
    _run_silent(board, 0.0, 0.5)
    assert board.brakes == 0 and board.applied_e4nm == [0, 0]  # never commanded: nothing to stop
    board.receive(sp.encode_frame(sp.Config(400, 200, 10), 0), 0.5)  # limit 0.04 N m
    t = _drive(board, 400, 1.0, 0.5)
    rows = _run_silent(board, t, 0.4)
    braking = [r for r in rows if r[4] & sp.FLAG_BRAKING]
    assert braking and max(abs(r[3]) for r in braking) == 400


def test_wheels_that_do_not_stop_are_released_after_brake_max():
    board = MotorBoard()  # plant-fed: the "plant" keeps the wheels turning
    t = _drive(board, 500, 0.3, 0.0)
    rows = []
    for k in range(1500):  # 1.5 s at 5 rad/s whatever the torque
        tk = t + k * DT_S
        board.set_wheel_state([5.0 * k * DT_S, -5.0 * k * DT_S], [5.0, -5.0])
        board.step(tk)
        board.take_output()
        rows.append((tk, 5.0, 0.0, board.applied_e4nm[0], board.flags))
    assert board.brake_released_s is not None and not board.braking
    assert board.brake_released_s - board.brake_started_s == pytest.approx(
        mb.BRAKE_MAX_S, abs=0.011
    )
    assert (
        max(abs(r[3]) for r in rows) == 1000
    )  # 0.05 N m/(rad/s) x 4.8 rad/s: at the 0.10 N m bound


def test_brake_torque_law():
    assert mb.brake_torque_e4nm(1.0, 1500) == -500
    assert mb.brake_torque_e4nm(-30.0, 1500) == 1000
    assert mb.brake_torque_e4nm(30.0, 600) == -600
    assert mb.brake_torque_e4nm(0.0, 1500) == 0
