"""`formation board-check`: direction, encoder sign and motor constant of each wheel, on the
emulated board (in process on a simulated clock, and on a pty) and on the firmware in simavr,
wired right and with one wheel reversed.

Stated: the motor constant within 5 % of the real motor's (+1.7 % expected: the wheel's viscous
friction, core/serial/board_check.py) for wheels whose motor and encoder agree; a motor 30 %
stronger or 20 % weaker than config.h says is found within 5 points and fails the 15 %
tolerance; a reversed motor or encoder is named, with the operator's observation, as the one to
swap. The check's times are the board's own (STATUS uptime), so the simavr firmware gives the
same findings when the loaded build machine runs it slower than real time.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys
import time

from firmware_sim import build_firmware, config_constants, Harness, toolchain_missing
import numpy as np
import pytest

from ament_formation.core.errors import ConfigError
from ament_formation.core.serial import board_check as bc
from ament_formation.core.serial.motor_board import BoardConfig, MotorBoard, Wiring
from ament_formation.core.serial.motor_constants import (
    CONFIG_NAMES,
    load_config_h,
    MotorConstants,
    parse_config_h,
)
from ament_formation.tools import cli
from ament_formation.tools.board_check_cmd import BoardSession, check

ROOT = Path(__file__).resolve().parents[1]
CONFIG_H = ROOT / 'firmware' / 'src' / 'config.h'
K = MotorConstants().torque_constant_nm_per_a
BOTH_FORWARD = {'left': 'forward', 'right': 'forward'}


class SimTransport:
    """An emulated board on a simulated clock: the board check's transport without a port."""

    def __init__(self, board: MotorBoard) -> None:
        self.board, self.t, self.out = board, 0.0, bytearray()

    def now(self) -> float:
        return self.t

    def wait(self, timeout_s: float) -> None:
        end = self.t + timeout_s
        while self.t < end - 1e-12:
            self.t = min(end, self.t + 1e-3)
            self.board.step(self.t)
            self.out += self.board.take_output()

    def read(self) -> bytes:
        data = bytes(self.out)
        self.out.clear()
        return data

    def write(self, data: bytes) -> None:
        self.board.receive(data, self.t)
        self.out += self.board.take_output()

    def close(self) -> None:
        pass


def _sim_check(seen=BOTH_FORWARD, **board_kw):
    cfg = BoardConfig(motor=MotorConstants(), wheel_inertia_kgm2=1.6e-3, wheel_damping_nms=2e-3,
                      **board_kw)
    session = BoardSession(SimTransport(MotorBoard(cfg, 0.0, standalone=True)), 0.04)
    lines = []
    reports, _ = check(session, bc.CheckParams(), MotorConstants(), seen, say=lines.append)
    return reports, lines


def test_motor_constants_are_config_h():
    parsed = load_config_h(CONFIG_H)
    assert parsed == MotorConstants()  # the built-in defaults are the firmware's
    c = config_constants()
    assert parsed.supply_v == c['MOTOR_SUPPLY_V'] and parsed.ticks_per_rev == 1440
    m = parse_config_h(CONFIG_H.read_text(), overrides={'MOTOR_SUPPLY_V': 7.4})
    assert m.supply_v == 7.4 and m.duty(0.0, m.no_load_speed_radps) == pytest.approx(1.0)
    # the firmware's duty and the real motor's torque invert each other below saturation
    assert m.torque(m.duty(0.05, 3.0), 3.0) == pytest.approx(0.05, rel=1e-9)
    with pytest.raises(ConfigError, match='--define MOTOR_VOLTS'):
        parse_config_h('', overrides={'MOTOR_VOLTS': 7.4})
    with pytest.raises(ConfigError, match='no #define MOTOR_GEAR_RATIO'):
        parse_config_h('\n'.join(f'#define {n} 1' for n in CONFIG_NAMES
                                 if n != 'MOTOR_GEAR_RATIO'), 'x.h')


def test_a_well_wired_board_matches_on_a_simulated_clock():
    reports, lines = _sim_check()
    assert [r.ok for r in reports] == [True, True], lines
    for r in reports:
        assert r.agree and r.direction == 'forward' and r.encoder_sign == 1
        print(f'\n[board-check sim] {r.line()}')
        assert 0.0 < r.kt_error < 0.05  # + b R / (k^2 G^2 eta) = +1.7 %
        assert abs(r.friction_nm) < 0.002
    assert lines[0].startswith('left: OK: turns forward, encoder counts up')


@pytest.mark.parametrize('wiring, seen, wheel, reason', [
    (Wiring((True, False), (False, False)), {'left': 'backward', 'right': 'forward'}, 0,
     "turns backward for a positive command: swap the motor's two leads"),
    (Wiring((False, False), (False, True)), BOTH_FORWARD, 1,
     'encoder counts down while the wheel turns forward: swap its A and B lines'),
    (Wiring((False, False), (False, True)), {}, 1,
     'encoder counts down for a positive command: the motor or the encoder is reversed'),
])
def test_one_wheel_reversed_is_named_on_a_simulated_clock(wiring, seen, wheel, reason):
    reports, lines = _sim_check(seen, wiring=wiring)
    bad, good = reports[wheel], reports[1 - wheel]
    assert good.ok and abs(good.kt_error) < 0.05, lines
    assert not bad.ok and bad.agree is False and bad.reasons[0].startswith(reason), lines
    assert len(bad.reasons) == 1  # the (rough) motor constant is not judged then
    assert abs(bad.kt_error) < 0.15  # in the emulated board's motor model
    if seen:
        assert bad.direction == seen[bc.WHEELS[wheel]]
        assert bad.encoder_sign == (-1 if wiring.encoder_reversed[wheel] else 1)
    else:
        assert bad.direction == 'unknown' and bad.encoder_sign is None


def test_a_wrong_motor_constant_is_found_on_a_simulated_clock():
    reports, lines = _sim_check(plant_kt_scale=(1.3, 0.8))
    assert [r.ok for r in reports] == [False, False]
    assert reports[0].kt_error == pytest.approx(0.3, abs=0.05)
    assert reports[1].kt_error == pytest.approx(-0.2, abs=0.05)
    assert 'MOTOR_TORQUE_CONSTANT_NM_PER_A' in reports[0].reasons[0]


def test_a_wheel_that_does_not_turn_is_reported():
    t = np.linspace(0.0, 1.0, 100)
    spins = [bc.Spin(0, tau, t, np.zeros(100), 'time') for tau in (0.02, 0.04)]
    r = bc.assess(0, spins, MotorConstants(), bc.CheckParams(), 'forward')
    assert not r.ok and r.reasons[0].startswith('did not turn (+0 encoder counts for 0.04 N·m)')


def test_bad_input_is_refused_in_one_line(tmp_path, capsys):
    for args, field in (
        (['--port', '/nonexistent/tty'], '--port'),
        (['--port', 'loop://', '--seen', 'left=sideways'], '--seen'),
        (['--port', 'loop://', '--torque-nm', '9'], '--torque-nm'),
        (['--port', 'loop://', '--define', 'MOTOR_SUPPLY_V=x'], '--define'),
        (['--port', 'loop://', '--firmware-config', str(tmp_path / 'no.h')], '--firmware-config'),
    ):
        assert cli.main(['board-check', '--no-ask', *args]) == 2
        err = capsys.readouterr().err.strip()
        assert '\n' not in err and field in err, err


def test_a_port_without_a_board_is_one_line_and_status_1(capsys):
    assert cli.main(['board-check', '--no-ask', '--port', 'loop://']) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('formation board-check: loop://: no answer to HELLO') and '\n' not in err


# --------------------------------------------------------------------------- real time: a pty
def _formation(*args, **kw) -> list[str]:
    return [sys.executable, '-m', 'ament_formation.tools.cli', *args]


def _run_check(port: str, seen: str, tmp_path: Path, name: str):
    out = tmp_path / f'{name}.json'
    res = subprocess.run(
        _formation('board-check', '--port', port, '--seen', seen, '--json', str(out)),
        capture_output=True, text=True, timeout=180,
    )
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith(('left:', 'right:'))]
    print(f'\n[board-check {name}] exit {res.returncode}\n' + '\n'.join(lines))
    assert len(lines) == 2, res.stdout + res.stderr
    return res.returncode, lines, json.loads(out.read_text())['wheels']


@pytest.mark.parametrize('fault, seen, name', [
    ((), 'left=forward,right=forward', 'pty'),
    (('--reverse-encoder', 'right'), 'left=forward,right=forward', 'pty-encoder-right'),
])
def test_emulated_board_on_a_pty(tmp_path, fault, seen, name):
    link = tmp_path / 'board.tty'
    board = subprocess.Popen(
        _formation('board', '--pty', '--motor', '--link', str(link), '--duration', '120', *fault),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        deadline = time.monotonic() + 60.0
        while not link.exists() and board.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.exists(), board.stderr.read() if board.poll() is not None else 'no pty'
        code, lines, wheels = _run_check(str(link), seen, tmp_path, name)
    finally:
        board.terminate()
        board.wait(timeout=10)
    left, right = wheels
    assert left['ok'] and abs(left['kt_estimate'] / K - 1.0) < 0.05
    if not fault:
        assert code == 0 and right['ok'] and abs(right['kt_estimate'] / K - 1.0) < 0.05
    else:
        assert code == 1 and not right['ok'] and right['encoder_sign'] == -1
        assert lines[1].startswith('right: FAIL: encoder counts down while the wheel turns '
                                   'forward: swap its A and B lines')


# --------------------------------------------------------------------------- simavr firmware
@pytest.fixture(scope='module')
def build_dir(tmp_path_factory):
    missing = toolchain_missing()
    if missing:
        if os.environ.get('AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN'):
            pytest.skip(
                f'firmware toolchain unavailable ({", ".join(missing)}) and apt unusable here'
            )
        pytest.fail(
            f'firmware toolchain missing ({", ".join(missing)}): '
            'run scripts/install_firmware_deps.sh'
        )
    out = tmp_path_factory.mktemp('firmware_build')
    build_firmware(out)
    return out


@pytest.mark.parametrize('fault, seen, name', [
    ((), 'left=forward,right=forward', 'simavr'),
    (('--reverse-motor', 'left'), 'left=backward,right=forward', 'simavr-motor-left'),
    (('--kt-scale', '1.3,1'), 'left=forward,right=forward', 'simavr-kt-1.3'),
])
def test_firmware_in_simavr(build_dir, tmp_path, fault, seen, name):
    harness = Harness(build_dir, tmp_path, extra_args=fault)
    try:
        code, lines, wheels = _run_check(harness.pty, seen, tmp_path, name)
        last = harness.latest()
    finally:
        harness.close()
    print(f'[board-check {name}] emulated {last["t_s"]:.1f} s in {last["wall_s"]:.1f} s wall')
    left, right = wheels
    assert right['ok'] and abs(right['kt_estimate'] / K - 1.0) < 0.05
    if name == 'simavr':
        assert code == 0 and left['ok'] and abs(left['kt_estimate'] / K - 1.0) < 0.05
    elif name == 'simavr-motor-left':
        assert code == 1 and left['direction'] == 'backward' and left['encoder_sign'] == 1
        assert lines[0].startswith('left: FAIL: turns backward for a positive command: swap the '
                                   "motor's two leads")
    else:
        assert code == 1 and left['kt_estimate'] / K - 1.0 == pytest.approx(0.3, abs=0.06)
        assert 'MOTOR_TORQUE_CONSTANT_NM_PER_A' in lines[0]
