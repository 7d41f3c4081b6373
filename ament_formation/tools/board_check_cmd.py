"""`formation board-check`: spin each wheel of a new robot in turn and check its wiring and motor.

    formation board-check --port /dev/ttyACM0 [--seen left=forward,right=forward]
                          [--torque-nm 0.04] [--spin-s 1.0] [--firmware-config config.h]
                          [--define MOTOR_SUPPLY_V=7.4] [--tolerance 0.15] [--json FILE]

Put the robot on blocks (wheels free) first. For each wheel (left, then right) the check commands
half of ``--torque-nm`` and then ``--torque-nm`` (the board's torque limit is set to it), each
from rest for at most ``--spin-s`` or until the wheel reaches 60 % of its no-load speed, with zero
torque to the other wheel and between spins; it reads the encoder from TELEMETRY and fits the
runs (core/serial/board_check.py). Per wheel one line: the way the encoder counts for a positive
command, the direction and encoder sign (with ``--seen``, or asked on a terminal), the motor
constant against the firmware's (firmware/src/config.h, or ``--firmware-config``) and the
friction. Exit status 0 when every wheel matches, 1 otherwise (one line of reasons per wheel, or
one line when the board does not answer), 2 on bad input.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
from pathlib import Path
import select
import sys
import time

import numpy as np

from ament_formation.core.errors import ConfigError
from ament_formation.core.serial import board_check as bc
from ament_formation.core.serial import serial_link as sl
from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.motor_constants import load_config_h, MotorConstants

_REFRESH_S = 2.0  # the commanded torque is handed to the link this often (keep-alive 100 Hz)
_INPUT_TIMEOUT_S = 5.0  # the link's input staleness (the board's own watchdog is 0.2 s)
_REST_WINDOW_S = 0.2  # at rest: no encoder count changed for this long
# a spin lasts spin_s of the board's clock: an emulator running slower than real time (a loaded
# host) gets its whole spin, up to this many times spin_s of the host's clock
_SLOW_BOARD_FACTOR = 10.0


class BoardUnavailable(RuntimeError):
    """The board does not answer (one line, exit status 1)."""


def firmware_config_path() -> Path | None:
    """firmware/src/config.h of the source tree, if this is one."""
    p = Path(__file__).resolve().parents[2] / 'firmware' / 'src' / 'config.h'
    return p if p.is_file() else None


class SerialTransport:
    """A serial port (pyserial, non-blocking) as the session's byte transport."""

    def __init__(self, port: str, baud: int) -> None:
        import serial

        try:
            self.port = serial.serial_for_url(port, baud, timeout=0, write_timeout=0.5)
        except (serial.SerialException, OSError, ValueError) as err:
            raise ConfigError(f'cannot open ({err})', '--port') from None
        try:
            self._fd = self.port.fileno()
        except (AttributeError, OSError, ValueError):  # a URL without a file descriptor
            self._fd = None

    @staticmethod
    def now() -> float:
        return time.monotonic()

    def wait(self, timeout_s: float) -> None:
        """Until bytes may be waiting, at most ``timeout_s``."""
        if self._fd is not None:
            select.select([self._fd], [], [], timeout_s)
        else:
            time.sleep(timeout_s)

    def read(self) -> bytes:
        return self.port.read(4096)

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self) -> None:
        try:
            self.port.flush()
        except OSError:
            pass
        self.port.close()


class BoardSession:
    """The host end of the protocol (core/serial/serial_link.LinkHost) over a transport (a
    serial port, or a simulated board in tests), driven by a wait loop; every TELEMETRY becomes a
    sample (host time, encoder angles, speeds).
    """

    def __init__(self, transport, torque_limit_nm: float, port: str = 'board') -> None:
        try:
            params = sl.LinkParams(
                port=port, torque_limit_nm=torque_limit_nm, input_timeout_s=_INPUT_TIMEOUT_S,
                link_timeout_s=1.0,
            )
        except ValueError as err:
            raise ConfigError(str(err)) from None
        self.transport = transport
        self.link = sl.LinkHost(params)
        self.samples: list[sl.WheelSample] = []
        # the board's clock: (position in self.samples - 0.5, STATUS uptime [s]) in stream order
        self.anchors: list[tuple[float, float]] = []
        self._order = sp.FrameDecoder()
        self._uptime_wraps = 0
        self._last_uptime_ms = None
        self._last_input_s = -math.inf
        self._torque = (0.0, 0.0)

    def _write(self, data: bytes) -> None:
        if data:
            self.transport.write(data)

    def pump(self, until, timeout_s: float) -> bool:
        """Run the link until ``until()`` or ``timeout_s``; True when ``until()`` held."""
        now_fn = self.transport.now
        end = now_fn() + timeout_s
        while True:
            if until():
                return True
            now = now_fn()
            if now >= end - 1e-9:
                return False
            self.transport.wait(min(0.002, end - now))
            now = now_fn()
            data = self.transport.read()
            if data:
                samples, out = self.link.receive(data, now)
                self._take(data, samples)
                self._write(out)
            if self.link.state == sl.UP and now - self._last_input_s >= _REFRESH_S:
                self.link.set_input(self._torque, now)
                self._last_input_s = now
                self._write(self.link.command_now(now))
            self._write(self.link.poll(now))

    def _take(self, data: bytes, samples: list) -> None:
        """Append the link's samples, and an anchor of board time per STATUS frame at its place
        among them (a second decoder on the same bytes keeps the frames' order).
        """
        frames = self._order.feed(data)
        tel = [f for f in frames if isinstance(f.msg, sp.Telemetry)]
        skip = len(tel) - len(samples)  # telemetry before the handshake gave no sample
        it = iter(samples)
        for f in frames:
            if isinstance(f.msg, sp.Telemetry):
                if skip > 0:
                    skip -= 1
                    continue
                self.samples.append(next(it))
            elif isinstance(f.msg, sp.Status):
                ms = f.msg.uptime_ms
                if self._last_uptime_ms is not None and ms < self._last_uptime_ms - 0x7FFFFFFF:
                    self._uptime_wraps += 1
                self._last_uptime_ms = ms
                up_s = (ms + self._uptime_wraps * 2**32) * 1e-3
                self.anchors.append((len(self.samples) - 0.5, up_s))

    def board_times(self, indices) -> np.ndarray | None:
        """Board time [s] of samples ``indices``: the STATUS uptimes, interpolated linearly in
        sample order between them (and extrapolated with the nearest interval's rate); None with
        fewer than two anchors. The board emits TELEMETRY at a steady rate (an acknowledgement per
        command at 100 Hz, or every 10 ms when idle), so the order places a sample in time within
        a few milliseconds whatever the host's scheduling or an emulator's speed.
        """
        if len(self.anchors) < 2:
            return None
        pos, up = (np.array(v, float) for v in zip(*self.anchors))
        keep = np.concatenate([[True], np.diff(pos) > 0])  # two STATUS in a row: the first
        pos, up = pos[keep], up[keep]
        if len(pos) < 2:
            return None
        x = np.asarray(indices, float)
        t = np.interp(x, pos, up)
        lo, hi = x < pos[0], x > pos[-1]
        t[lo] = up[0] + (x[lo] - pos[0]) * (up[1] - up[0]) / (pos[1] - pos[0])
        t[hi] = up[-1] + (x[hi] - pos[-1]) * (up[-1] - up[-2]) / (pos[-1] - pos[-2])
        return t

    def _board_elapsed(self, first: int) -> float | None:
        """Board seconds from sample ``first`` to the newest (0 before it came; None without
        the board's clock).
        """
        if len(self.samples) <= first:
            return 0.0
        t = self.board_times([first, len(self.samples) - 1])
        return None if t is None else float(t[1] - t[0])

    def handshake(self, timeout_s: float = 5.0) -> int:
        """HELLO until the board is configured: its counts per revolution; raises
        BoardUnavailable otherwise.
        """
        self._write(self.link.connected(self.transport.now()))
        self.pump(lambda: self.link.state in (sl.UP, sl.VERSION_MISMATCH), timeout_s)
        if self.link.state == sl.VERSION_MISMATCH:
            raise BoardUnavailable(self.link.version_mismatch_text())
        if self.link.state != sl.UP:
            raise BoardUnavailable(
                f'no answer to HELLO within {timeout_s:g} s (is the motor board on this port, '
                'flashed with the firmware, at this baud rate?)'
            )
        return self.link.ticks_per_rev

    def command(self, left_nm: float, right_nm: float) -> None:
        """Torques to apply from now on."""
        self._torque = (float(left_nm), float(right_nm))
        self._last_input_s = -math.inf

    def rest(self, timeout_s: float) -> bool:
        """Zero torque until no encoder count changed for 0.2 s; False after ``timeout_s``."""
        self.command(0.0, 0.0)
        start = len(self.samples)
        tick = 2 * math.pi / self.link.ticks_per_rev

        def still() -> bool:
            new = self.samples[start:]
            if not new or new[-1].received_s - new[0].received_s < _REST_WINDOW_S:
                return False
            t_end = new[-1].received_s
            window = [s.position_rad for s in new if s.received_s >= t_end - _REST_WINDOW_S]
            arr = np.array(window)
            return bool(np.all(arr.max(axis=0) - arr.min(axis=0) < 0.5 * tick))

        return self.pump(still, timeout_s)

    def spin(self, wheel: int, torque_nm: float, spin_s: float, speed_limit_radps: float):
        """``torque_nm`` on ``wheel`` (0 on the other) for up to ``spin_s`` or until the wheel's
        reported speed reaches ``speed_limit_radps``; a record for :meth:`make_spin` (once a
        STATUS frame after the spin has come: call it after the next :meth:`rest`).
        """
        base = self.samples[-1].position_rad[wheel]
        start = len(self.samples)
        torques = [0.0, 0.0]
        torques[wheel] = torque_nm
        self.command(*torques)
        t0 = self.transport.now()
        ended = {'by': 'time'}

        def done() -> bool:
            if len(self.samples) > start and abs(self.samples[-1].velocity_radps[wheel]) >= (
                speed_limit_radps
            ):
                ended['by'] = 'speed'
                return True
            board_s = self._board_elapsed(start)
            if board_s is None:  # too few STATUS frames for the board's clock: the host's
                return self.transport.now() - t0 >= spin_s
            return board_s >= spin_s

        self.pump(done, spin_s * _SLOW_BOARD_FACTOR)
        self.command(0.0, 0.0)
        first = next((i for i in range(start, len(self.samples))
                      if self.samples[i].received_s >= t0), len(self.samples))
        return (wheel, torque_nm, base, first, len(self.samples), t0, ended['by'])

    def make_spin(self, record) -> bc.Spin:
        """The :class:`~board_check.Spin` of a :meth:`spin` record, on the board's clock (the
        host's when the board sent too few STATUS frames); time 0: the first sample after the
        command was sent.
        """
        wheel, torque_nm, base, first, end, t0, ended = record
        idx = np.arange(first, end)
        t = self.board_times(idx) if len(idx) else None
        if t is None or not np.all(np.isfinite(t)):
            t = np.array([self.samples[i].received_s for i in idx]) - t0
        else:
            t = t - t[0]
        return bc.Spin(
            wheel,
            torque_nm,
            np.asarray(t, float),
            np.array([self.samples[i].position_rad[wheel] - base for i in idx]),
            ended,
        )

    def close(self) -> None:
        """STOP frames (the board brakes to rest and releases), then close the port."""
        try:
            self._write(self.link.stop_commands(3))
        except OSError:
            pass
        self.transport.close()


def _ask(wheel: str) -> str | None:
    while True:
        print(f'did the {wheel} wheel turn forward (the way the robot drives)? '
              '[f]orward / [b]ackward / [n]ot seen: ', end='', flush=True)
        answer = sys.stdin.readline().strip().lower()
        if answer in ('f', 'forward'):
            return 'forward'
        if answer in ('b', 'backward'):
            return 'backward'
        if answer in ('n', '', 'not seen'):
            return None


def _motor(args: argparse.Namespace) -> tuple[MotorConstants, str]:
    overrides = {}
    for item in args.define:
        name, _, value = item.partition('=')
        try:
            overrides[name.strip()] = float(value.rstrip('fFuUlL'))
        except ValueError:
            raise ConfigError(f'expected NAME=NUMBER (got {item!r})', '--define') from None
    path = Path(args.firmware_config) if args.firmware_config else firmware_config_path()
    if path is None:
        if overrides:
            raise ConfigError('--define needs --firmware-config (no source tree here)', '--define')
        return MotorConstants(), 'built-in defaults (= firmware/src/config.h)'
    if not path.is_file():
        raise ConfigError('no such file', '--firmware-config', str(path))
    return load_config_h(path, overrides), str(path)


def check(session: BoardSession, params: bc.CheckParams, motor: MotorConstants, seen: dict,
          ask: bool = False, say=print) -> tuple[list[bc.WheelReport], list[list[bc.Spin]]]:
    """Handshake, then per wheel: rest, spin at each torque, assess (``say`` each line).

    Raises BoardUnavailable when the board does not answer or the wheels do not come to rest.
    """
    ticks = session.handshake()
    if ticks != motor.ticks_per_rev:
        say(f'note: the board counts {ticks} per revolution, the firmware config '
            f"{motor.ticks_per_rev}: using the board's")
        motor = replace(motor, ticks_per_rev=ticks)
    limit = params.speed_fraction * motor.no_load_speed_radps
    reports, raw = [], []
    for wheel, name in enumerate(bc.WHEELS):
        if ask:
            say(f'watch the {name} wheel: it turns for about {2 * params.spin_s:g} s')
        records = []
        for torque in params.torques_nm:
            if not session.rest(params.rest_timeout_s):
                raise BoardUnavailable(
                    f'the wheels did not come to rest within {params.rest_timeout_s:g} s of '
                    'zero torque'
                )
            records.append(session.spin(wheel, torque, params.spin_s, limit))
        session.rest(params.rest_timeout_s)  # and the board's clock past the last spin
        spins = [session.make_spin(r) for r in records]
        observed = _ask(name) if ask else seen.get(name)
        report = bc.assess(wheel, spins, motor, params, observed)
        reports.append(report)
        raw.append(spins)
        say(report.line())
    return reports, raw


def run(args: argparse.Namespace) -> int:
    params = bc.CheckParams(
        torque_nm=args.torque_nm, spin_s=args.spin_s, tolerance=args.tolerance,
        rest_timeout_s=args.rest_timeout_s,
    )
    seen = bc.parse_seen(args.seen) if args.seen else {}
    motor, motor_source = _motor(args)
    ask = not args.seen and not args.no_ask and sys.stdin.isatty()
    if args.json and not Path(args.json).parent.is_dir():
        raise ConfigError('no such folder', '--json', str(Path(args.json).parent))
    print(
        f'board on {args.port}; firmware motor model ({motor_source}): {motor.supply_v:g} V, '
        f'k {motor.torque_constant_nm_per_a:g} N·m/A, R {motor.resistance_ohm:g} ohm, '
        f'G {motor.gear_ratio:g}, eta {motor.gear_efficiency:g}, '
        f'{motor.ticks_per_rev} counts/rev', flush=True
    )
    session = BoardSession(SerialTransport(args.port, args.baud), params.torque_nm, args.port)
    try:
        reports, raw = check(session, params, motor, seen, ask,
                             lambda line: print(line, flush=True))
    except BoardUnavailable as err:
        print(f'formation board-check: {args.port}: {err}', file=sys.stderr)
        return 1
    finally:
        session.close()
    if args.json:
        _write_json(Path(args.json), reports, raw, motor)
    return 0 if all(r.ok for r in reports) else 1


def _write_json(path: Path, reports, raw, motor: MotorConstants) -> None:
    out = {'motor': motor.__dict__, 'wheels': []}
    for r, spins in zip(reports, raw):
        fit = r.fit
        out['wheels'].append({
            'wheel': r.wheel, 'ok': r.ok, 'reasons': list(r.reasons), 'counts': r.counts,
            'agree': r.agree, 'direction': r.direction, 'encoder_sign': r.encoder_sign,
            'kt_estimate': r.kt_estimate, 'kt_firmware': r.kt_firmware,
            'apparent_damping_nms': r.apparent_damping_nms, 'friction_nm': r.friction_nm,
            'fit': None if fit is None else {
                'decay_per_s': fit.decay_per_s, 'accel_radps2': list(fit.accel_radps2),
                'delay_s': list(fit.delay_s), 'rms_rad': fit.rms_rad},
            'spins': [{'torque_nm': s.torque_nm, 'ended_by': s.ended_by,
                       't_s': s.t_s.tolist(), 'angle_rad': s.angle_rad.tolist()} for s in spins],
        })
    text = json.dumps(out, indent=1, default=lambda v: None if v != v else v)
    path.write_text(text.replace('NaN', 'null'))


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'board-check',
        help='spin each wheel of a robot on blocks: direction, encoder sign, motor constant',
        description='Spin each wheel in turn (robot on blocks) through the motor board, read its '
        'encoder and report per wheel the direction, encoder sign and motor constant against the '
        "firmware's. Exit status 0: all match; 1: a wheel does not (one line each); 2: bad input.",
    )
    p.add_argument('--port', required=True, help='serial port of the motor board (or a URL)')
    p.add_argument('--baud', type=int, default=115200, help='baud rate (115200)')
    p.add_argument('--seen', default='', metavar='left=forward,right=backward',
                   help='which way each wheel turned (watch them); asked on a terminal if absent')
    p.add_argument('--no-ask', action='store_true', help='never ask, even on a terminal')
    p.add_argument('--torque-nm', type=float, default=0.04,
                   help='larger test torque [N·m] (0.04; the smaller is half); the board limit')
    p.add_argument('--spin-s', type=float, default=1.0, help='longest spin per torque [s] (1)')
    p.add_argument('--tolerance', type=float, default=0.15,
                   help='allowed relative error of the motor constant (0.15)')
    p.add_argument('--rest-timeout-s', type=float, default=5.0,
                   help='longest wait for the wheels to stop between spins [s] (5)')
    p.add_argument('--firmware-config', default='', metavar='config.h',
                   help='the firmware configuration the board was built with '
                   '(default: firmware/src/config.h of the source tree)')
    p.add_argument('--define', action='append', default=[], metavar='NAME=VALUE',
                   help='a constant built with make CFLAGS_EXTRA=-DNAME=VALUE (repeatable)')
    p.add_argument('--json', default='', metavar='FILE', help='also write the findings and runs')
    p.set_defaults(func=run)
