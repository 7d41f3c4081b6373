"""Host side of the motor-board protocol (docs/serial-protocol.md §5), without I/O: handshake,
torque commands with input staleness and clamping, retransmission when the board's
acknowledgement (TELEMETRY echoing the command) is missing, wheel-state unwrapping, link
statistics. The bridge node owns the port; it feeds bytes and times in and writes what comes out.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

import numpy as np

from ament_formation.core.params import param
from ament_formation.core.serial import serial_protocol as sp

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class LinkParams:
    """Bridge parameters (also the ROS parameters of ``formation_bridge``)."""

    port: str = param('/dev/ttyACM0', 'device path or pyserial URL of the motor board')
    baud_rate: int = param(115200, 'serial baud rate [baud]', range=(1200, 4_000_000))
    torque_limit_nm: float = param(
        0.15, 'bridge clamp per wheel, also sent to the board [N m]', range=(0.0, 3.2767)
    )
    watchdog_s: float = param(0.2, 'board watchdog, sent in CONFIG [s]', range=(0.02, 0.5))
    input_timeout_s: float = param(
        0.2, 'wheel_torque older than this -> STOP: the board brakes [s]', range=(0.0, 5.0)
    )
    command_rate_hz: float = param(100.0, 'keep-alive TORQUE_CMD rate [Hz]', range=(1.0, 1000.0))
    telemetry_period_s: float = param(
        0.01, 'board TELEMETRY period when idle, sent in CONFIG [s]', range=(0.005, 1.0)
    )
    ack_timeout_s: float = param(
        0.006, 'no echo of a command after this -> resend once [s]', range=(0.0, 1.0)
    )
    link_timeout_s: float = param(
        0.5, 'no valid frame this long -> link down, reopen [s], > 2 telemetry periods'
    )
    hello_retry_s: float = param(0.2, 'HELLO retry period [s]', range=(0.0, 5.0))
    heartbeat_period_s: float = param(1.0, 'heartbeat period [s]', range=(0.0, 60.0))
    reconnect_initial_s: float = param(
        0.05, 'reopen backoff, initial, doubling [s]', range=(0.0, 60.0)
    )
    reconnect_max_s: float = param(0.5, 'reopen backoff, maximum [s]', range=(0.0, 60.0))
    poll_rate_hz: float = param(
        500.0, 'non-blocking port read/write timer [Hz]', range=(10.0, 5000.0)
    )
    diagnostics_period_s: float = param(1.0, '/diagnostics period [s]', range=(0.05, 60.0))
    wait_for_port: bool = param(
        False,
        'a port that cannot be opened at start: wait for it (reopen '
        'with backoff) instead of exiting with one line on stderr',
    )

    def __post_init__(self) -> None:
        def need(ok: bool, field: str, what: str) -> None:
            if not ok:
                raise ValueError(f'{field}: {getattr(self, field)!r} {what}')

        need(
            isinstance(self.port, str) and self.port != '',
            'port',
            'must be a device path or pyserial URL',
        )
        need(
            isinstance(self.baud_rate, int) and 1200 <= self.baud_rate <= 4_000_000,
            'baud_rate',
            'must be an integer in [1200, 4000000] baud',
        )
        need(0.0 < self.torque_limit_nm <= 3.2767, 'torque_limit_nm', 'N·m not in (0, 3.2767]')
        need(0.02 <= self.watchdog_s <= 0.5, 'watchdog_s', 's not in [0.02, 0.5]')
        need(0.0 < self.input_timeout_s <= 5.0, 'input_timeout_s', 's not in (0, 5]')
        need(1.0 <= self.command_rate_hz <= 1000.0, 'command_rate_hz', 'Hz not in [1, 1000]')
        need(0.005 <= self.telemetry_period_s <= 1.0, 'telemetry_period_s', 's not in [0.005, 1]')
        need(0.0 < self.ack_timeout_s <= 1.0, 'ack_timeout_s', 's not in (0, 1]')
        need(
            self.link_timeout_s > 2 * self.telemetry_period_s,
            'link_timeout_s',
            's must exceed two telemetry periods',
        )
        need(0.0 < self.hello_retry_s <= 5.0, 'hello_retry_s', 's not in (0, 5]')
        need(0.0 < self.heartbeat_period_s <= 60.0, 'heartbeat_period_s', 's not in (0, 60]')
        need(
            0.0 < self.reconnect_initial_s <= self.reconnect_max_s,
            'reconnect_initial_s',
            's must be > 0 and <= reconnect_max_s',
        )
        need(self.reconnect_max_s <= 60.0, 'reconnect_max_s', 's must be <= 60')
        need(10.0 <= self.poll_rate_hz <= 5000.0, 'poll_rate_hz', 'Hz not in [10, 5000]')
        need(
            0.05 <= self.diagnostics_period_s <= 60.0,
            'diagnostics_period_s',
            's not in [0.05, 60]',
        )


class Backoff:
    """Exponential reconnect delay: ``initial_s`` doubling to ``max_s``; ``reset()`` on success."""

    def __init__(self, initial_s: float, max_s: float) -> None:
        self.initial_s, self.max_s = initial_s, max_s
        self.delay_s = initial_s

    def next_delay(self) -> float:
        delay = self.delay_s
        self.delay_s = min(self.delay_s * 2.0, self.max_s)
        return delay

    def reset(self) -> None:
        self.delay_s = self.initial_s


@dataclass(frozen=True)
class WheelSample:
    """Wheel state from one TELEMETRY: positions [rad] and velocities [rad/s], each a pair
    (left, right) of floats.
    """

    position_rad: tuple[float, float]
    velocity_radps: tuple[float, float]
    flags: int
    cmd_seq: int
    received_s: float


DOWN, HANDSHAKE, CONFIGURING, UP, VERSION_MISMATCH = (
    'down',
    'handshake',
    'configuring',
    'up',
    'version_mismatch',
)


class LinkHost:
    """State machine of the host end of the link. All times are ``now_s`` [s, monotonic]."""

    def __init__(self, params: LinkParams) -> None:
        self.p = params
        self.decoder = sp.FrameDecoder()
        self.state = DOWN
        self._seq = 0
        self.ticks_per_rev: int | None = None
        self.board_config: sp.ConfigAck | None = None
        self.board_status: sp.Status | None = None
        self.board_version: int | None = None
        self.flags = 0
        self._unwrap_ticks: tuple[int, int] | None = None  # kept across reconnects
        self._last_ticks = (0, 0)
        self._input: tuple[float, float] | None = None  # latest valid input [N·m]
        self._input_s = -math.inf
        self._input_id = 0
        self._sent: dict[
            int, tuple[float, int, tuple[int, int]]
        ] = {}  # seq -> (t, input_id, wire)
        self._pending_ack: tuple[int, float, int] | None = None  # (seq, sent_s, input_id)
        self._retransmitted_id = -1
        self._last_cmd_sent_s = -math.inf
        self._sent_input_id = 0
        self._min_gap_s = 0.25 / params.command_rate_hz
        self._wire_limit = int(math.floor(params.torque_limit_nm / sp.TORQUE_LSB_NM + 1e-9))
        self._last_rx_s = -math.inf
        self._last_hello_s = -math.inf
        self._last_heartbeat_s = -math.inf
        self._last_echo: int | None = None
        self._last_board_seq: int | None = None
        self.rtt_s: deque[float] = deque(maxlen=1000)
        self._rtt_ewma_s: float | None = None
        self.stats = {
            'tx_frames': 0,
            'rx_frames': 0,
            'commands_sent': 0,
            'retransmissions': 0,
            'inputs': 0,
            'inputs_rejected': 0,
            'inputs_clamped': 0,
            'stale_stops': 0,
            'rx_gaps': 0,
            'connects': 0,
            'link_timeouts': 0,
            'board_resets': 0,
        }
        self.sent_log: deque[tuple[int, int, int]] | None = None  # (seq, left_e4nm, right_e4nm)

    # -- connection ----------------------------------------------------------------------------
    def connected(self, now_s: float) -> bytes:
        """The port was (re)opened: start the handshake; returns bytes to write."""
        self.decoder.reset()
        self.state = HANDSHAKE
        self.stats['connects'] += 1
        self._last_rx_s = now_s
        self._pending_ack = None
        self._last_echo = None
        self._last_board_seq = None
        self._last_hello_s = now_s
        return b'\x00' + self._hello()

    def disconnected(self) -> None:
        self.state = DOWN
        self._pending_ack = None

    def timed_out(self, now_s: float) -> bool:
        """No valid frame from the board for link_timeout_s while connected."""
        if self.state in (DOWN, VERSION_MISMATCH):
            return False
        if now_s - self._last_rx_s > self.p.link_timeout_s:
            self.stats['link_timeouts'] += 1
            return True
        return False

    # -- input ---------------------------------------------------------------------------------
    def set_input(self, torques_nm, now_s: float) -> bool:
        """New wheel torques [N·m] (left, right) from the controller; False if rejected
        (NaN/inf/size).
        """
        self.stats['inputs'] += 1
        try:
            left, right = torques_nm
            left, right = float(left), float(right)
        except (TypeError, ValueError):
            self.stats['inputs_rejected'] += 1
            return False
        if not (math.isfinite(left) and math.isfinite(right)):
            self.stats['inputs_rejected'] += 1
            return False
        lim = self.p.torque_limit_nm
        clamped = (min(max(left, -lim), lim), min(max(right, -lim), lim))
        if clamped != (left, right):
            self.stats['inputs_clamped'] += 1
        self._input = clamped
        self._input_s = now_s
        self._input_id += 1
        return True

    def command_now(self, now_s: float) -> bytes:
        """Bytes to write right after a new input (at most 4x command_rate_hz; a new input that
        comes sooner is sent by the next ``poll``).
        """
        if self.state != UP or now_s - self._last_cmd_sent_s < self._min_gap_s:
            return b''
        return self._command(now_s)

    def input_fresh(self, now_s: float) -> bool:
        return self._input is not None and now_s - self._input_s <= self.p.input_timeout_s

    def _command(self, now_s: float) -> bytes:
        if not self.input_fresh(now_s):
            # no fresh torque: STOP (the board brakes the wheels to rest, then releases) instead of
            # zero torque, which would let the robot coast; acknowledged, never retransmitted
            self.stats['stale_stops'] += 1
            seq = self._seq
            data = self._frame(sp.Stop(sp.STOP_INPUT_STALE))
            self._sent[seq] = (now_s, -1, None)
            self._pending_ack = (seq, now_s, -1)
            self._last_cmd_sent_s = now_s
            return data
        wire = (sp.torque_to_wire(self._input[0]), sp.torque_to_wire(self._input[1]))
        input_id = self._input_id
        # the bridge clamp in wire units too, so rounding can never exceed the limit
        lim = self._wire_limit
        wire = (max(-lim, min(lim, wire[0])), max(-lim, min(lim, wire[1])))
        seq = self._seq
        data = self._frame(sp.TorqueCommand(*wire))
        self._sent[seq] = (now_s, input_id, wire)
        self._pending_ack = (seq, now_s, input_id)
        self._last_cmd_sent_s = now_s
        self._sent_input_id = max(self._sent_input_id, input_id)
        self.stats['commands_sent'] += 1
        if self.sent_log is not None:
            self.sent_log.append((seq, wire[0], wire[1]))
        return data

    def stop_commands(self, count: int = 3) -> bytes:
        """STOP frames for shutdown (sent whatever the link state): the board brakes to rest."""
        self._input = None
        out = b''
        for _ in range(count):
            out += self._frame(sp.Stop(sp.STOP_HOST_SHUTDOWN))
        return out

    # -- periodic ------------------------------------------------------------------------------
    def poll(self, now_s: float) -> bytes:
        """Bytes due at ``now_s``: handshake retries, keep-alive/zero/retransmitted commands,
        heartbeat.
        """
        p = self.p
        if self.state == HANDSHAKE and now_s - self._last_hello_s >= p.hello_retry_s:
            self._last_hello_s = now_s
            return self._hello()
        if self.state == CONFIGURING and now_s - self._last_hello_s >= p.hello_retry_s:
            self._last_hello_s = now_s
            return self._config_frame()
        if self.state != UP:
            return b''
        out = b''
        pend = self._pending_ack
        if (
            pend is not None
            and now_s - pend[1] >= self.ack_timeout_s()
            and self._may_retransmit(now_s)
        ):
            out += self._retransmit(now_s)
        elif now_s - self._last_cmd_sent_s >= 1.0 / p.command_rate_hz or (
            self._sent_input_id != self._input_id
            and now_s - self._last_cmd_sent_s >= self._min_gap_s
        ):
            out += self._command(now_s)
        if now_s - self._last_heartbeat_s >= p.heartbeat_period_s:
            self._last_heartbeat_s = now_s
            out += self._frame(sp.Heartbeat(int(now_s * 1000) & 0xFFFFFFFF))
        return out

    def ack_timeout_s(self) -> float:
        """Wait for a command's echo before resending: ack_timeout_s, or twice the mean round trip
        if that is longer (a board that only echoes in periodic TELEMETRY is not flooded).
        """
        if self._rtt_ewma_s is None:
            return self.p.ack_timeout_s
        return max(self.p.ack_timeout_s, 2.0 * self._rtt_ewma_s)

    def _may_retransmit(self, now_s: float) -> bool:
        """Resend once per input, only the newest one, only while it is fresh."""
        pend = self._pending_ack
        return (
            self.state == UP
            and pend is not None
            and pend[2] == self._input_id
            and pend[2] != self._retransmitted_id
            and self.input_fresh(now_s)
        )

    def _retransmit(self, now_s: float) -> bytes:
        self._retransmitted_id = self._pending_ack[2]
        self.stats['retransmissions'] += 1
        return self._command(now_s)

    # -- receive -------------------------------------------------------------------------------
    def receive(self, data: bytes, now_s: float) -> tuple[list[WheelSample], bytes]:
        """Process bytes from the board: wheel samples to publish and bytes to write in answer."""
        samples: list[WheelSample] = []
        out = b''
        for frame in self.decoder.feed(data):
            self._last_rx_s = now_s
            self.stats['rx_frames'] += 1
            if self._last_board_seq is not None:
                self.stats['rx_gaps'] += (frame.seq - self._last_board_seq - 1) & 0xFF
            self._last_board_seq = frame.seq
            msg = frame.msg
            if isinstance(msg, sp.HelloAck):
                out += self._on_hello_ack(msg, now_s)
            elif isinstance(msg, sp.ConfigAck) and self.state == CONFIGURING:
                self.board_config = msg
                self.state = UP
            elif isinstance(msg, sp.Telemetry) and self.ticks_per_rev is not None:
                samples.append(self._on_telemetry(msg, now_s))
                if msg.flags & sp.FLAG_RX_ERROR and self._may_retransmit(now_s):  # negative ack
                    out += self._retransmit(now_s)
                if (
                    msg.flags & sp.FLAG_RESET and self.state == UP
                ):  # the board rebooted: handshake again
                    self.stats['board_resets'] += 1
                    self.state = HANDSHAKE
                    self._last_hello_s = now_s
                    out += self._hello()
            elif isinstance(msg, sp.Status):
                self.board_status = msg
        return samples, out

    def _on_hello_ack(self, msg: sp.HelloAck, now_s: float) -> bytes:
        if self.state not in (HANDSHAKE, CONFIGURING):
            return b''
        self.board_version = msg.protocol_version
        if msg.protocol_version != sp.PROTOCOL_VERSION:
            self.state = VERSION_MISMATCH  # the bridge reports it; no torque is ever sent
            return b''
        self.ticks_per_rev = msg.ticks_per_rev
        self.state = CONFIGURING
        self._last_hello_s = now_s
        return self._config_frame()

    def _config_frame(self) -> bytes:
        p = self.p
        return self._frame(
            sp.Config(
                torque_limit_e4nm=int(math.floor(p.torque_limit_nm / sp.TORQUE_LSB_NM + 1e-9)),
                watchdog_ms=int(round(p.watchdog_s * 1000)),
                telemetry_period_ms=int(round(p.telemetry_period_s * 1000)),
            )
        )

    def _on_telemetry(self, msg: sp.Telemetry, now_s: float) -> WheelSample:
        # scalars (two wheels: numpy costs more than it saves); the same float64 operations
        left, right = msg.left_ticks, msg.right_ticks
        if self._unwrap_ticks is None:
            self._unwrap_ticks = (left, right)
        else:
            last_l, last_r = self._last_ticks
            unwrap_l, unwrap_r = self._unwrap_ticks
            self._unwrap_ticks = (
                unwrap_l + ((left - last_l + 0x8000) & 0xFFFF) - 0x8000,
                unwrap_r + ((right - last_r + 0x8000) & 0xFFFF) - 0x8000,
            )
        self._last_ticks = (left, right)
        self.flags = msg.flags
        if msg.cmd_seq != self._last_echo:
            self._last_echo = msg.cmd_seq
            sent = self._sent.get(msg.cmd_seq)
            if sent is not None:
                rtt = now_s - sent[0]
                self.rtt_s.append(rtt)
                self._rtt_ewma_s = (
                    rtt if self._rtt_ewma_s is None else 0.9 * self._rtt_ewma_s + 0.1 * rtt
                )
            if self._pending_ack is not None and self._pending_ack[0] == msg.cmd_seq:
                self._pending_ack = None
        rad_per_tick = TWO_PI / self.ticks_per_rev
        lsb = sp.VELOCITY_LSB_RADPS
        unwrap_l, unwrap_r = self._unwrap_ticks
        return WheelSample(
            position_rad=(float(unwrap_l) * rad_per_tick, float(unwrap_r) * rad_per_tick),
            velocity_radps=(float(msg.left_vel_mradps) * lsb, float(msg.right_vel_mradps) * lsb),
            flags=msg.flags,
            cmd_seq=msg.cmd_seq,
            received_s=now_s,
        )

    # -- helpers -------------------------------------------------------------------------------
    def _hello(self) -> bytes:
        """HELLO in version-1 framing, which a board of any version reads (its body says 2)."""
        return self._frame(sp.Hello(sp.PROTOCOL_VERSION), version=sp.HANDSHAKE_FRAMING_VERSION)

    def version_mismatch_text(self) -> str:
        """One line for the log and diagnostics when the board speaks another protocol version."""
        return (
            'protocol version mismatch: '
            f'the board speaks version {self.board_version}, this bridge '
            f'speaks {sp.PROTOCOL_VERSION}; no torque is sent (flash firmware of protocol version '
            f'{sp.PROTOCOL_VERSION}: make -C firmware flash)'
        )

    def _frame(self, msg: sp.Message, version: int = sp.PROTOCOL_VERSION) -> bytes:
        data = sp.encode_frame(msg, self._seq, leading_delimiter=True, version=version)
        self._seq = (self._seq + 1) & 0xFF
        self.stats['tx_frames'] += 1
        return data

    def rtt_percentiles_s(self) -> tuple[float, float]:
        """(p50, p99) command -> telemetry echo round trip [s]; NaN without samples."""
        if not self.rtt_s:
            return math.nan, math.nan
        arr = np.fromiter(self.rtt_s, dtype=float)
        return float(np.percentile(arr, 50)), float(np.percentile(arr, 99))
