"""The motor board's firmware rules, emulated (docs/serial-protocol.md §4): decode host frames,
clamp torques, 200 ms command watchdog followed by the stop brake (docs/safety.md), e-stop,
configuration, encoder quantisation, TELEMETRY as the answer to each command (and periodically when
idle), STATUS every 200 ms.

No I/O and no clock: bytes and the time ``now_s`` [s] are passed in, bytes to send come out.
In the simulated twin the plant feeds wheel angles/velocities (``set_wheel_state``) and reads
``applied_torque_nm``; standalone, the board integrates a first-order wheel model itself: an
ideal torque source (J dω/dt = τ − b ω), or, with ``BoardConfig.motor``, the firmware's DC-motor
drive (core/serial/motor_constants.py: duty from the configured constants and the speed measured
from the encoder each 10 ms control period, as firmware/src/board.c does) driving motors whose
torque constant may differ (``plant_kt_scale``) and which may be wired reversed (``wiring``):
what `formation board-check` identifies.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.motor_constants import MotorConstants

TWO_PI = 2.0 * math.pi

# Stop brake (docs/safety.md; the same numbers as firmware/src/config.h BRAKE_*): when the command
# watchdog trips after commands were flowing, each wheel is regulated to zero speed with
# tau = clamp(-BRAKE_GAIN * omega, +-min(BRAKE_TORQUE_LIMIT, torque limit)), omega measured as the
# firmware does (encoder counts in the last control period: 0, 1, 0, 1 ... for a slow wheel); the
# H-bridge is released (coast, torque 0) once both wheels stayed within one encoder count of a
# reference position for BRAKE_REST_S (at rest: dithering by one count included), or after
# BRAKE_MAX_S whatever the speed.
BRAKE_GAIN_NM_PER_RADPS = 0.05
BRAKE_TORQUE_LIMIT_NM = 0.10
BRAKE_REST_S = 0.05
BRAKE_MAX_S = 1.0
CONTROL_PERIOD_S = 0.01  # the firmware's control step (speed measurement, brake update)


def brake_torque_e4nm(speed_radps: float, limit_e4nm: int) -> int:
    """Brake torque [1e-4 N·m] for a measured wheel speed [rad/s]: -gain * speed, rounded, clamped
    to +-min(BRAKE_TORQUE_LIMIT_NM, limit).
    """
    bound = min(int(round(BRAKE_TORQUE_LIMIT_NM / sp.TORQUE_LSB_NM)), limit_e4nm)
    tau = int(round(-BRAKE_GAIN_NM_PER_RADPS * speed_radps / sp.TORQUE_LSB_NM))
    return max(-bound, min(bound, tau))


@dataclass(frozen=True)
class Wiring:
    """How a standalone emulated board's wheels are wired, per wheel (left, right): a reversed
    motor turns its wheel backward for a positive duty, a reversed encoder counts down while its
    wheel turns forward (the faults a new robot has and `formation board-check` finds).
    """

    motor_reversed: tuple[bool, bool] = (False, False)
    encoder_reversed: tuple[bool, bool] = (False, False)

    @property
    def motor_sign(self) -> np.ndarray:
        return np.where(np.array(self.motor_reversed, bool), -1.0, 1.0)

    @property
    def encoder_sign(self) -> np.ndarray:
        return np.where(np.array(self.encoder_reversed, bool), -1.0, 1.0)


@dataclass(frozen=True)
class BoardConfig:
    """Compiled-in settings of a board; the host may lower the limit and change periods
    (CONFIG).
    """

    ticks_per_rev: int = 1440
    hard_torque_limit_nm: float = 0.15
    watchdog_s: float = 0.2
    telemetry_period_s: float = 0.01
    status_period_s: float = 0.2
    firmware_major: int = 2
    firmware_minor: int = 0
    protocol_version: int = sp.PROTOCOL_VERSION
    wheel_inertia_kgm2: float = 5e-4  # standalone wheel model: J dω/dt = τ − b ω
    wheel_damping_nms: float = 1e-2
    # standalone only: the firmware's DC-motor drive (None: an ideal torque source), the real
    # motors' torque constants relative to it (left, right), and the wiring
    motor: MotorConstants | None = None
    plant_kt_scale: tuple[float, float] = (1.0, 1.0)
    wiring: Wiring = Wiring()

    def __post_init__(self) -> None:
        if not 1 <= self.ticks_per_rev <= 0xFFFF:
            raise ValueError(f'BoardConfig.ticks_per_rev: {self.ticks_per_rev} not in [1, 65535]')
        if not 0.0 < self.hard_torque_limit_nm <= 0xFFFF * sp.TORQUE_LSB_NM:
            raise ValueError(
                f'BoardConfig.hard_torque_limit_nm: {self.hard_torque_limit_nm} N·m '
                'not in (0, 6.5535]'
            )
        if not 0.02 <= self.watchdog_s <= 0.5:
            raise ValueError(f'BoardConfig.watchdog_s: {self.watchdog_s} s not in [0.02, 0.5]')
        if not 0.005 <= self.telemetry_period_s <= 1.0:
            raise ValueError(
                f'BoardConfig.telemetry_period_s: {self.telemetry_period_s} s not in [0.005, 1]'
            )
        if not 0.01 <= self.status_period_s <= 10.0:
            raise ValueError(
                f'BoardConfig.status_period_s: {self.status_period_s} s not in [0.01, 10]'
            )
        if self.wheel_inertia_kgm2 <= 0 or self.wheel_damping_nms < 0:
            raise ValueError(
                'BoardConfig.wheel_inertia_kgm2 must be > 0 and wheel_damping_nms >= 0'
            )
        if len(self.plant_kt_scale) != 2 or not all(
            math.isfinite(v) and 0.1 <= v <= 10.0 for v in self.plant_kt_scale
        ):
            raise ValueError(
                f'BoardConfig.plant_kt_scale: {self.plant_kt_scale} not two values in [0.1, 10]'
            )


WATCHDOG_RANGE_MS = (20, 500)
TELEMETRY_RANGE_MS = (5, 1000)


def _clamp(value: int, lo: int, hi: int) -> int:
    return lo if value < lo else hi if value > hi else value


class MotorBoard:
    """Emulated motor board. Call ``receive`` with bytes from the host and ``step`` regularly
    (≥ 1 kHz for 1 ms watchdog resolution); both return nothing, ``take_output`` the bytes to send.

    ``command_log`` (optional list) gets ``(now_s, seq, left_e4nm, right_e4nm)`` for every accepted
    TORQUE_CMD: the tests use it to prove that no corrupted command is ever applied.
    """

    def __init__(
        self,
        config: BoardConfig = BoardConfig(),
        now_s: float = 0.0,
        standalone: bool = False,
        command_log: list | None = None,
    ) -> None:
        self.config = config
        self.standalone = standalone
        self.command_log = command_log
        self.boot(now_s)

    # -- lifecycle -----------------------------------------------------------------------------
    def boot(self, now_s: float) -> None:
        """Power-on state (also what a DTR reset of an Arduino does)."""
        cfg = self.config
        self.decoder = sp.FrameDecoder(cfg.protocol_version)
        self._boot_s = now_s
        self._out = bytearray()
        self._seq = 0
        self.hard_limit_e4nm = int(round(cfg.hard_torque_limit_nm / sp.TORQUE_LSB_NM))
        self.limit_e4nm = self.hard_limit_e4nm
        self.watchdog_ms = int(round(cfg.watchdog_s * 1000))
        self.telemetry_period_ms = int(round(cfg.telemetry_period_s * 1000))
        self.applied_e4nm = [0, 0]
        self.flags = sp.FLAG_WATCHDOG | sp.FLAG_RESET
        self.cmd_seq = 0
        self.estop = False
        self.watchdog_trips = 0
        self.rx_gaps = 0
        self.accepted_commands = 0
        self._last_host_seq: int | None = None
        self._last_cmd_s: float | None = None
        self._last_telemetry_s = -math.inf
        self._next_status_s = now_s + cfg.status_period_s
        self._rx_error_seen = self.decoder.rejected_total
        self.watchdog_tripped_at_s: float | None = None
        self.braking = False
        self.brake_started_s: float | None = None
        self.brake_released_s: float | None = None
        self.brakes = 0
        self.brake_cause: str | None = None  # what started the last brake: 'watchdog' | 'stop'
        self._rest_since_s: float | None = None
        self._next_brake_step_s = now_s
        self._brake_armed = False  # a TORQUE_CMD since the last brake: the next stop brakes
        self.stops_received = 0
        self.last_stop_reason: int | None = None  # sp.STOP_* of the last STOP
        if not hasattr(self, 'wheel_pos_rad'):
            self.wheel_pos_rad = np.zeros(2)
            self.wheel_vel_radps = np.zeros(2)
        self._last_step_s = now_s
        # the firmware's own speed measurement and duty (standalone with a motor model)
        self._fw_speed_radps = np.zeros(2)
        self._fw_ticks = self.encoder_ticks.astype(float)
        self._plant_s = now_s
        self._next_control_s = now_s + CONTROL_PERIOD_S

    # -- plant interface -----------------------------------------------------------------------
    def set_wheel_state(self, pos_rad, vel_radps) -> None:
        """Wheel angles [rad] and velocities [rad/s], shape (2,) [left, right], from the plant."""
        self.wheel_pos_rad = np.array(pos_rad, dtype=float).reshape(2)
        self.wheel_vel_radps = np.array(vel_radps, dtype=float).reshape(2)

    @property
    def last_command_s(self) -> float | None:
        """When the last TORQUE_CMD or STOP was accepted [s], None before the first."""
        return self._last_cmd_s

    @property
    def applied_torque_nm(self) -> np.ndarray:
        """Torque the motors apply now [N·m], shape (2,) [left, right]."""
        return np.array(self.applied_e4nm, dtype=float) * sp.TORQUE_LSB_NM

    @property
    def encoder_ticks(self) -> np.ndarray:
        """Quantised encoder counts (int64, not wrapped), shape (2,) (standalone: as wired)."""
        counts = self.wheel_pos_rad * (self.config.ticks_per_rev / TWO_PI)
        if self.standalone:
            counts = counts * self.config.wiring.encoder_sign
        return np.floor(counts).astype(np.int64)

    @property
    def reported_velocity_radps(self) -> np.ndarray:
        """Wheel speeds the board reports [rad/s], shape (2,): the plant's (twin), the wheel's
        as its encoder is wired (standalone), the encoder-measured speed (with a motor model).
        """
        if not self.standalone:
            return self.wheel_vel_radps
        if self.config.motor is not None:
            return self._fw_speed_radps
        return self.wheel_vel_radps * self.config.wiring.encoder_sign

    # -- byte interface ------------------------------------------------------------------------
    def receive(self, data: bytes, now_s: float) -> None:
        """Process bytes from the host. A rejected frame is answered at once by a TELEMETRY with
        RX_ERROR (a negative acknowledgement; at most one per half telemetry period).
        """
        rejected_before = self.decoder.rejected_total
        for frame in self.decoder.feed(data):
            self._count_gap(frame.seq)
            self._handle(frame.msg, now_s)
        if (
            self.decoder.rejected_total != rejected_before
            and now_s - self._last_telemetry_s >= 0.5e-3 * self.telemetry_period_ms
        ):
            self._send_telemetry(now_s)

    def step(self, now_s: float) -> None:
        """Advance the board to ``now_s``: watchdog, wheel model (standalone), periodic frames."""
        dt = now_s - self._last_step_s
        self._last_step_s = now_s
        if self._last_cmd_s is None or now_s - self._last_cmd_s >= self.watchdog_ms / 1000.0:
            if not self.flags & sp.FLAG_WATCHDOG:
                self.flags |= sp.FLAG_WATCHDOG
                self.watchdog_trips += 1
                self.watchdog_tripped_at_s = now_s
                if self._brake_armed and not self.estop:
                    self._start_brake(now_s, 'watchdog')
            if not self.braking:
                self.applied_e4nm = [0, 0]
        if self.braking and now_s >= self._next_brake_step_s:
            self._brake_step(now_s)
            self._next_brake_step_s = max(self._next_brake_step_s + CONTROL_PERIOD_S, now_s)
        if self.standalone and dt > 0:
            # the motor model steps itself in 1 ms steps: it keeps the board's time over a stall
            self._integrate_wheels(min(dt, 1.0 if self.config.motor is not None else 0.05))
        period_s = self.telemetry_period_ms / 1000.0
        idle = self._last_cmd_s is None or now_s - self._last_cmd_s >= 2.0 * period_s
        if idle and now_s - self._last_telemetry_s >= period_s:
            self._send_telemetry(now_s)
        if now_s >= self._next_status_s:
            self._send(self.status(now_s))
            self._next_status_s = max(self._next_status_s + self.config.status_period_s, now_s)

    # -- stop brake (docs/safety.md)
    # ---------------------------------------------------------------
    def measured_speed_radps(self) -> np.ndarray:
        """Wheel speed [rad/s] as the firmware measures it, shape (2,): the encoder counts of the
        last control period (the quantised angle now minus the quantised angle one period ago,
        at the present speed) over the period; a count is 2 pi / ticks_per_rev.
        """
        if self.standalone and self.config.motor is not None:
            return self._fw_speed_radps.copy()
        counts_per_rad = self.config.ticks_per_rev / TWO_PI
        now = np.floor(self.wheel_pos_rad * counts_per_rad)
        before = np.floor(
            (self.wheel_pos_rad - self.wheel_vel_radps * CONTROL_PERIOD_S) * counts_per_rad
        )
        speed = (now - before) / (counts_per_rad * CONTROL_PERIOD_S)
        return speed * self.config.wiring.encoder_sign if self.standalone else speed

    def _stop(self, now_s: float) -> None:
        """STOP: acknowledged and feeding the watchdog like a command; brakes once per stop."""
        self.cmd_seq = self._last_host_seq if self._last_host_seq is not None else 0
        self.stops_received += 1
        self.flags &= ~sp.FLAG_WATCHDOG
        self._last_cmd_s = now_s
        if self._brake_armed and not self.estop:
            self._start_brake(now_s, 'stop')
            self._brake_step(now_s)
            self._next_brake_step_s = now_s + CONTROL_PERIOD_S
        elif not self.braking:
            self.applied_e4nm = [0, 0]
        self._send_telemetry(now_s)

    def _start_brake(self, now_s: float, cause: str) -> None:
        self._brake_armed = False
        self.braking = True
        self.brakes += 1
        self.brake_cause = cause
        self.brake_started_s = now_s
        self.brake_released_s = None
        self._rest_since_s = now_s
        self._next_brake_step_s = now_s
        self.flags |= sp.FLAG_BRAKING

    def _stop_brake(self, now_s: float | None) -> None:
        """Leave the brake: H-bridge off (``now_s`` None: a command or e-stop took over)."""
        if self.braking and now_s is not None:
            self.brake_released_s = now_s
        self.braking = False
        self.flags &= ~sp.FLAG_BRAKING
        self.applied_e4nm = [0, 0]

    def _brake_step(self, now_s: float) -> None:
        """One control step of the brake: regulate each wheel's speed to 0, release at rest."""
        speed = self.measured_speed_radps()
        # the firmware's test: within one count of a reference for BRAKE_REST_S; here the counts a
        # wheel turning at its present speed makes in BRAKE_REST_S (the plant's angles come in
        # steps: a plant that stalled between updates is not a wheel at rest)
        counts_per_rad = self.config.ticks_per_rev / TWO_PI
        window = np.floor(self.wheel_pos_rad * counts_per_rad) - np.floor(
            (self.wheel_pos_rad - self.wheel_vel_radps * BRAKE_REST_S) * counts_per_rad
        )
        if np.any(np.abs(window) > 1):  # moving: restart the rest window
            self._rest_since_s = now_s
        at_rest = now_s - self._rest_since_s >= BRAKE_REST_S - 1e-9
        if at_rest or now_s - self.brake_started_s >= BRAKE_MAX_S - 1e-9:
            self._stop_brake(now_s)
            return
        self.applied_e4nm = [brake_torque_e4nm(float(w), self.limit_e4nm) for w in speed]

    def take_output(self) -> bytes:
        """Bytes the board has queued for the host since the last call."""
        out = bytes(self._out)
        self._out.clear()
        return out

    # -- messages ------------------------------------------------------------------------------
    def status(self, now_s: float) -> sp.Status:
        rej = self.decoder.rejected
        u16 = 0xFFFF
        return sp.Status(
            uptime_ms=int((now_s - self._boot_s) * 1000) & 0xFFFFFFFF,
            left_applied_e4nm=self.applied_e4nm[0],
            right_applied_e4nm=self.applied_e4nm[1],
            crc_errors=rej['crc'] & u16,
            frame_errors=(rej['oversize'] + rej['cobs'] + rej['length']) & u16,
            type_errors=(rej['type'] + rej['version'] + rej['value']) & u16,
            rx_gaps=self.rx_gaps & u16,
            watchdog_trips=self.watchdog_trips & u16,
            flags=self._flags_now(),
            cmd_seq=self.cmd_seq,
        )

    def telemetry(self) -> sp.Telemetry:
        ticks = self.encoder_ticks
        return sp.Telemetry(
            left_ticks=sp.wrap_int16(int(ticks[0])),
            right_ticks=sp.wrap_int16(int(ticks[1])),
            left_vel_mradps=sp.velocity_to_wire(float(self.reported_velocity_radps[0])),
            right_vel_mradps=sp.velocity_to_wire(float(self.reported_velocity_radps[1])),
            cmd_seq=self.cmd_seq,
            flags=self._flags_now(),
        )

    def _flags_now(self) -> int:
        flags = self.flags
        if self.decoder.rejected_total != self._rx_error_seen:
            flags |= sp.FLAG_RX_ERROR
        return flags

    def _send(self, msg: sp.Message, version: int | None = None) -> None:
        version = self.config.protocol_version if version is None else version
        self._out += sp.encode_frame(msg, self._seq, version=version)
        self._seq = (self._seq + 1) & 0xFF

    def _send_telemetry(self, now_s: float) -> None:
        self._send(self.telemetry())
        self._rx_error_seen = self.decoder.rejected_total
        self._last_telemetry_s = now_s

    def _count_gap(self, seq: int) -> None:
        if self._last_host_seq is not None:
            self.rx_gaps += (seq - self._last_host_seq - 1) & 0xFF
        self._last_host_seq = seq

    def _handle(self, msg: sp.Message, now_s: float) -> None:
        if isinstance(msg, sp.TorqueCommand):
            self._torque(msg, now_s)
        elif isinstance(msg, sp.Stop):
            self.last_stop_reason = msg.reason
            self._stop(now_s)
        elif isinstance(msg, sp.Hello):
            self.flags &= ~sp.FLAG_RESET
            # a version-1 host reads only version-1 framing: answer it in that, so it can report
            # the mismatch; every other host gets the board's own framing
            self._send(self.hello_ack(), version=1 if msg.protocol_version == 1 else None)
        elif isinstance(msg, sp.Config):
            self.limit_e4nm = _clamp(msg.torque_limit_e4nm, 0, self.hard_limit_e4nm)
            self.watchdog_ms = _clamp(msg.watchdog_ms, *WATCHDOG_RANGE_MS)
            self.telemetry_period_ms = _clamp(msg.telemetry_period_ms, *TELEMETRY_RANGE_MS)
            lim = self.limit_e4nm
            self.applied_e4nm = [_clamp(t, -lim, lim) for t in self.applied_e4nm]
            self._send(sp.ConfigAck(self.limit_e4nm, self.watchdog_ms, self.telemetry_period_ms))
        elif isinstance(msg, sp.Heartbeat):
            self._send(sp.Heartbeat(msg.stamp_ms))
        elif isinstance(msg, sp.EmergencyStop):
            self.estop = bool(msg.engage)
            if self.estop:
                self.flags |= sp.FLAG_ESTOP
                self._stop_brake(None)
            else:
                self.flags &= ~sp.FLAG_ESTOP
        # board -> host types arriving at the board are valid frames with nothing to do

    def hello_ack(self) -> sp.HelloAck:
        cfg = self.config
        return sp.HelloAck(
            cfg.protocol_version,
            cfg.firmware_major,
            cfg.firmware_minor,
            cfg.ticks_per_rev,
            self.limit_e4nm,
            self.hard_limit_e4nm,
            self.watchdog_ms,
            self.telemetry_period_ms,
        )

    def _torque(self, msg: sp.TorqueCommand, now_s: float) -> None:
        self.cmd_seq = self._last_host_seq if self._last_host_seq is not None else 0
        if self.braking:
            self._stop_brake(None)
        self._brake_armed = True
        self.accepted_commands += 1
        if self.command_log is not None:
            self.command_log.append((now_s, self.cmd_seq, msg.left_e4nm, msg.right_e4nm))
        if self.estop:
            self.applied_e4nm = [0, 0]
        else:
            lim = self.limit_e4nm
            applied = [_clamp(msg.left_e4nm, -lim, lim), _clamp(msg.right_e4nm, -lim, lim)]
            clamped = applied != [msg.left_e4nm, msg.right_e4nm]
            self.flags = (
                (self.flags | sp.FLAG_CLAMPED) if clamped else (self.flags & ~sp.FLAG_CLAMPED)
            )
            self.applied_e4nm = applied
        self.flags &= ~sp.FLAG_WATCHDOG
        self._last_cmd_s = now_s
        self._send_telemetry(now_s)  # the acknowledgement: TELEMETRY echoing this command

    def _integrate_wheels(self, dt_s: float) -> None:
        """Standalone wheel model J dω/dt = τ − b ω, semi-implicit Euler (τ: the applied torque,
        or the DC-motor drive's, :meth:`_integrate_motor`).
        """
        cfg = self.config
        if cfg.motor is not None:
            self._integrate_motor(dt_s)
            return
        tau = self.applied_torque_nm * cfg.wiring.motor_sign
        self.wheel_vel_radps = (self.wheel_vel_radps + dt_s * tau / cfg.wheel_inertia_kgm2) / (
            1.0 + dt_s * cfg.wheel_damping_nms / cfg.wheel_inertia_kgm2
        )
        self.wheel_pos_rad = self.wheel_pos_rad + dt_s * self.wheel_vel_radps

    def _integrate_motor(self, dt_s: float) -> None:
        """The firmware's DC-motor drive on motors of torque constant ``plant_kt_scale`` times
        the configured one, wired as ``wiring`` says, in steps of at most 1 ms: each 10 ms control
        period the speed is measured from the encoder counts of the period; the duty follows the
        applied torque and that speed (firmware/src/motor_model.c); the wheel obeys
        J dω/dt = s (d V − k' G s ω) k' G η / R − b ω (s: motor wiring sign; duty 0 shorts the
        winding, as the simavr harness models a bridge at duty 0), implicit in ω.
        """
        cfg, fw = self.config, self.config.motor
        end = self._plant_s + dt_s
        sign = cfg.wiring.motor_sign
        kg = fw.torque_constant_nm_per_a * fw.gear_ratio * np.asarray(cfg.plant_kt_scale)
        gain = kg * fw.gear_efficiency / fw.resistance_ohm  # torque per volt [N·m/V]
        damping = gain * kg + cfg.wheel_damping_nms  # [N·m·s/rad]
        j = cfg.wheel_inertia_kgm2
        while self._plant_s < end - 1e-12:
            if self._plant_s >= self._next_control_s - 1e-12:  # firmware control step
                ticks = self.encoder_ticks.astype(float)
                self._fw_speed_radps = (ticks - self._fw_ticks) * (
                    TWO_PI / cfg.ticks_per_rev / CONTROL_PERIOD_S
                )
                self._fw_ticks = ticks
                self._next_control_s += CONTROL_PERIOD_S
            h = min(end - self._plant_s, 1e-3, self._next_control_s - self._plant_s)
            applied = self.applied_torque_nm
            duty = np.array(
                [0.0 if a == 0.0 else fw.duty(a, w) for a, w in zip(applied, self._fw_speed_radps)]
            )
            drive = sign * duty * fw.supply_v * gain
            self.wheel_vel_radps = (self.wheel_vel_radps + h * drive / j) / (1.0 + h * damping / j)
            self.wheel_pos_rad = self.wheel_pos_rad + h * self.wheel_vel_radps
            self._plant_s += h
        if self._next_control_s < self._plant_s - CONTROL_PERIOD_S:  # a long stall: catch up
            self._next_control_s = self._plant_s
