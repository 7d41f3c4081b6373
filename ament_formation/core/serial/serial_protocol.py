"""Serial protocol between the bridge (host) and the motor board: message layouts, frame encoder
and incremental decoder. No I/O. The normative description is ``docs/serial-protocol.md``.

Wire format of one frame (protocol version 2)::

    [0x00]  COBS( header(2) | body(n) | crc32c_le(4) )  0x00
    header byte 0 = (protocol_version << 4) | message_type,  header byte 1 = sequence (uint8)

CRC-32C over header and body, sent little-endian. The header's version nibble selects the check:
1 -> CRC-16/CCITT-FALSE (2 bytes; version 1, kept only so that HELLO / HELLO_ACK can tell a
version-1
peer about the mismatch), 2 and above -> CRC-32C (4 bytes). All multi-byte fields are
little-endian integers in fixed-point units (no floats on the wire); a frame on the wire is at most
``MAX_WIRE_BYTES`` long.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum
import struct
from typing import ClassVar, Union

from ament_formation.core.serial import cobs
from ament_formation.core.serial.crc16 import crc16
from ament_formation.core.serial.crc32c import crc32c

PROTOCOL_VERSION = 2
HANDSHAKE_FRAMING_VERSION = (
    1  # HELLO always goes out in version-1 framing: any board can answer it
)
MAX_WIRE_BYTES = 64  # largest frame on the wire, both delimiters included
MAX_ENCODED_BYTES = 62  # largest COBS block between delimiters
HEADER_BYTES = 2
CRC_BYTES = 4  # CRC-32C (version >= 2); version-1 framing has 2 (CRC-16)

TORQUE_LSB_NM = 1e-4  # torque fields: int16 in units of 1e-4 N·m (±3.2767 N·m)
VELOCITY_LSB_RADPS = 1e-3  # velocity fields: int16 in units of 1e-3 rad/s (±32.767 rad/s)

# Status flag bits (TELEMETRY.flags, STATUS.flags)
FLAG_WATCHDOG = 0x01  # no valid TORQUE_CMD for watchdog_ms: torque is zero
FLAG_CLAMPED = 0x02  # the last TORQUE_CMD exceeded the torque limit and was clamped
FLAG_ESTOP = 0x04  # emergency stop engaged: torque is zero, commands are ignored
FLAG_RX_ERROR = 0x08  # the board rejected a frame since the previous TELEMETRY
FLAG_RESET = 0x10  # the board has not received a HELLO since it booted
FLAG_BRAKING = 0x20  # commands stopped: the board regulates the wheels to rest (version 2)
FLAGS_DEFINED = 0x3F

REJECT_REASONS = ('oversize', 'cobs', 'length', 'crc', 'version', 'type', 'value')


class MsgType(IntEnum):
    """Message type: low nibble of header byte 0."""

    HELLO = 0x1
    HELLO_ACK = 0x2
    TORQUE_CMD = 0x3
    TELEMETRY = 0x4
    STATUS = 0x5
    HEARTBEAT = 0x6
    ESTOP = 0x7
    CONFIG = 0x8
    CONFIG_ACK = 0x9
    STOP = 0xA  # version 2


_LIMITS = {'B': (0, 0xFF), 'H': (0, 0xFFFF), 'I': (0, 0xFFFFFFFF), 'h': (-0x8000, 0x7FFF)}


def _check_ranges(msg) -> None:
    """Raise ValueError naming the field when a value does not fit its wire type."""
    for name, lo, hi in msg._RANGES:
        value = getattr(msg, name)
        if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
            raise ValueError(
                f'{type(msg).__name__}.{name}: {value!r} is not an integer in [{lo}, {hi}]'
            )


class _Message:
    TYPE: ClassVar[MsgType]
    FORMAT: ClassVar[str]
    # per class, set by _layout() below (not dataclass fields): field names in wire order,
    # (name, lo, hi) of each, the compiled struct of FORMAT
    _FIELDS: ClassVar[tuple[str, ...]] = ()
    _RANGES: ClassVar[tuple[tuple[str, int, int], ...]] = ()
    _STRUCT: ClassVar[struct.Struct]

    def __post_init__(self) -> None:
        _check_ranges(self)

    @classmethod
    def from_wire(cls, values: tuple):
        """The message of the values ``struct.unpack(FORMAT, body)`` gave: in range by
        construction (each wire type holds only values of its range), so not checked again.
        """
        obj = object.__new__(cls)
        obj.__dict__.update(zip(cls._FIELDS, values))
        return obj

    def pack(self) -> bytes:
        return self._STRUCT.pack(*[getattr(self, name) for name in self._FIELDS])

    def check_values(self) -> str | None:
        """Why the decoded values are invalid, or None."""
        return None

    def to_dict(self) -> dict:
        return {'type': self.TYPE.name, **{name: getattr(self, name) for name in self._FIELDS}}


@dataclass(frozen=True)
class Hello(_Message):
    """host -> board: start of a session; the board answers HELLO_ACK (any version). Always sent
    in version-1 framing (``HANDSHAKE_FRAMING_VERSION``) so that a board of any version reads it.
    """

    TYPE: ClassVar[MsgType] = MsgType.HELLO
    FORMAT: ClassVar[str] = '<B'
    protocol_version: int = PROTOCOL_VERSION

    def check_values(self):
        return None if self.protocol_version != 0 else 'protocol_version 0'


@dataclass(frozen=True)
class HelloAck(_Message):
    """board -> host: the board's protocol version, firmware version and configuration."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO_ACK
    FORMAT: ClassVar[str] = '<BBBHHHHH'
    protocol_version: int
    firmware_major: int
    firmware_minor: int
    ticks_per_rev: int
    torque_limit_e4nm: int  # current limit [1e-4 N·m]
    hard_torque_limit_e4nm: int  # compiled-in maximum the limit can be set to [1e-4 N·m]
    watchdog_ms: int
    telemetry_period_ms: int

    def check_values(self):
        if self.protocol_version == 0 or self.ticks_per_rev == 0 or self.telemetry_period_ms == 0:
            return 'zero protocol_version, ticks_per_rev or telemetry_period_ms'
        return None


@dataclass(frozen=True)
class TorqueCommand(_Message):
    """host -> board: wheel torques [1e-4 N·m], left then right. Feeds the board's watchdog."""

    TYPE: ClassVar[MsgType] = MsgType.TORQUE_CMD
    FORMAT: ClassVar[str] = '<hh'
    left_e4nm: int
    right_e4nm: int


@dataclass(frozen=True)
class Telemetry(_Message):
    """board -> host, every telemetry_period_ms: encoders, velocities, flags, command echo."""

    TYPE: ClassVar[MsgType] = MsgType.TELEMETRY
    FORMAT: ClassVar[str] = '<hhhhBB'
    left_ticks: int  # encoder count modulo 2**16 (two's complement)
    right_ticks: int
    left_vel_mradps: int  # [1e-3 rad/s]
    right_vel_mradps: int
    cmd_seq: int  # sequence number of the last accepted TORQUE_CMD
    flags: int

    def check_values(self):
        return (
            None if not self.flags & ~FLAGS_DEFINED else f'undefined flag bits 0x{self.flags:02x}'
        )


@dataclass(frozen=True)
class Status(_Message):
    """board -> host, every 200 ms: applied torques, error counters (uint16, wrapping)."""

    TYPE: ClassVar[MsgType] = MsgType.STATUS
    FORMAT: ClassVar[str] = '<IhhHHHHHBB'
    uptime_ms: int
    left_applied_e4nm: int
    right_applied_e4nm: int
    crc_errors: int  # frames rejected for their CRC
    frame_errors: int  # oversize, COBS and length rejections
    type_errors: int  # version, type and value rejections
    rx_gaps: int  # host frames missed, from sequence gaps
    watchdog_trips: int
    flags: int
    cmd_seq: int

    def check_values(self):
        return (
            None if not self.flags & ~FLAGS_DEFINED else f'undefined flag bits 0x{self.flags:02x}'
        )


@dataclass(frozen=True)
class Heartbeat(_Message):
    """host -> board; the board sends it back unchanged (round-trip measurement, liveness)."""

    TYPE: ClassVar[MsgType] = MsgType.HEARTBEAT
    FORMAT: ClassVar[str] = '<I'
    stamp_ms: int


@dataclass(frozen=True)
class EmergencyStop(_Message):
    """host -> board: engage (1) or release (0) the emergency stop."""

    TYPE: ClassVar[MsgType] = MsgType.ESTOP
    FORMAT: ClassVar[str] = '<B'
    engage: int

    def check_values(self):
        return None if self.engage in (0, 1) else f'engage {self.engage} not 0 or 1'


@dataclass(frozen=True)
class Config(_Message):
    """host -> board: limits; the board clamps each into its range and answers CONFIG_ACK."""

    TYPE: ClassVar[MsgType] = MsgType.CONFIG
    FORMAT: ClassVar[str] = '<HHH'
    torque_limit_e4nm: int
    watchdog_ms: int
    telemetry_period_ms: int


@dataclass(frozen=True)
class ConfigAck(_Message):
    """board -> host: the configuration now in force."""

    TYPE: ClassVar[MsgType] = MsgType.CONFIG_ACK
    FORMAT: ClassVar[str] = '<HHH'
    torque_limit_e4nm: int
    watchdog_ms: int
    telemetry_period_ms: int


STOP_UNSPECIFIED, STOP_INPUT_STALE, STOP_HOST_SHUTDOWN = 0, 1, 2


@dataclass(frozen=True)
class Stop(_Message):
    """host -> board (version 2): no torque to apply — brake the wheels to rest, then release
    (docs/safety.md). Feeds the watchdog and is acknowledged like a TORQUE_CMD; it starts the brake
    once per stop (the first STOP or watchdog trip after a TORQUE_CMD), later ones keep it going.
    """

    TYPE: ClassVar[MsgType] = MsgType.STOP
    FORMAT: ClassVar[str] = '<B'
    reason: int = STOP_UNSPECIFIED  # 0 unspecified, 1 input stale, 2 host shutdown

    def check_values(self):
        return None if self.reason <= STOP_HOST_SHUTDOWN else f'reason {self.reason} not in 0..2'


Message = Union[
    Hello,
    HelloAck,
    TorqueCommand,
    Telemetry,
    Status,
    Heartbeat,
    EmergencyStop,
    Config,
    ConfigAck,
    Stop,
]
MESSAGE_CLASSES = {
    cls.TYPE: cls
    for cls in (
        Hello,
        HelloAck,
        TorqueCommand,
        Telemetry,
        Status,
        Heartbeat,
        EmergencyStop,
        Config,
        ConfigAck,
        Stop,
    )
}
BODY_BYTES = {t: struct.calcsize(cls.FORMAT) for t, cls in MESSAGE_CLASSES.items()}


def _layout(cls) -> None:
    names = tuple(f.name for f in fields(cls))
    codes = cls.FORMAT[1:]
    assert len(names) == len(codes), cls
    cls._FIELDS = names
    cls._RANGES = tuple((name, *_LIMITS[code]) for name, code in zip(names, codes))
    cls._STRUCT = struct.Struct(cls.FORMAT)


for _cls in MESSAGE_CLASSES.values():
    _layout(_cls)
del _cls
VERSION_FREE_TYPES = (MsgType.HELLO, MsgType.HELLO_ACK)  # layout frozen across versions
_MSG_TYPES = {int(t): t for t in MsgType}  # type code -> MsgType (decode: no enum call)


@dataclass(frozen=True)
class Frame:
    """One decoded frame: sender's sequence number (uint8), protocol version, message."""

    seq: int
    msg: Message
    version: int = PROTOCOL_VERSION

    def __post_init__(self) -> None:
        if not 0 <= self.seq <= 0xFF:
            raise ValueError(f'Frame.seq: {self.seq} not in [0, 255]')
        if not 1 <= self.version <= 0xF:
            raise ValueError(f'Frame.version: {self.version} not in [1, 15]')

    @classmethod
    def trusted(cls, seq: int, msg: Message, version: int) -> 'Frame':
        """A frame of values already known valid (a decoded header: uint8 seq, version 1..15)."""
        obj = object.__new__(cls)
        obj.__dict__.update(seq=seq, msg=msg, version=version)
        return obj


def crc_bytes(version: int) -> int:
    """Length of the check value in a frame whose header carries ``version``: 2 (CRC-16) for
    version 1, 4 (CRC-32C) for every later version.
    """
    return 2 if version == 1 else 4


def frame_check(head_and_body: bytes, version: int) -> bytes:
    """The check value of a frame of ``version``, little-endian (CRC-16 for 1, CRC-32C after)."""
    if version == 1:
        return crc16(head_and_body).to_bytes(2, 'little')
    return crc32c(head_and_body).to_bytes(4, 'little')


def raw_frame(msg: Message, seq: int, version: int = PROTOCOL_VERSION) -> bytes:
    """Header | body | check (little-endian), before COBS."""
    head = bytes(((version << 4) | int(msg.TYPE), seq & 0xFF)) + msg.pack()
    return head + frame_check(head, version)


def encode_frame(
    msg: Message, seq: int, *, leading_delimiter: bool = False, version: int = PROTOCOL_VERSION
) -> bytes:
    """Wire bytes of one frame: [0x00] COBS(header | body | crc) 0x00.

    The host writes a leading 0x00 so that line noise before a frame never spoils the frame.
    """
    body = cobs.encode(raw_frame(msg, seq, version)) + b'\x00'
    return b'\x00' + body if leading_delimiter else body


def decode_raw(raw: bytes, accepted_version: int = PROTOCOL_VERSION) -> Frame | str:
    """Check and parse one de-COBSed frame: the Frame, or the rejection reason (REJECT_REASONS)."""
    if len(raw) < HEADER_BYTES + 1 + 2:
        return 'length'
    version, type_code = raw[0] >> 4, raw[0] & 0x0F
    if version == 1:
        n_check = 2
        if len(raw) < HEADER_BYTES + 1 + n_check:
            return 'length'
        if crc16(raw[:-2]) != int.from_bytes(raw[-2:], 'little'):
            return 'crc'
    else:
        n_check = 4
        if len(raw) < HEADER_BYTES + 1 + n_check:
            return 'length'
        if crc32c(raw[:-4]) != int.from_bytes(raw[-4:], 'little'):
            return 'crc'
    mtype = _MSG_TYPES.get(type_code)
    if mtype is None:
        return 'type'
    if version != accepted_version and mtype not in VERSION_FREE_TYPES:
        return 'version'
    if version == 0:
        return 'version'
    cls = MESSAGE_CLASSES[mtype]
    if len(raw) - HEADER_BYTES - n_check != cls._STRUCT.size:
        return 'length'
    msg = cls.from_wire(cls._STRUCT.unpack_from(raw, HEADER_BYTES))
    if msg.check_values() is not None:
        return 'value'
    return Frame.trusted(raw[1], msg, version)


class FrameDecoder:
    """Incremental decoder: ``feed(bytes) -> list[Frame]``.

    Survives any split or merge of the byte stream and resynchronises on the next 0x00 after
    garbage. Empty frames (consecutive 0x00) are ignored. Each rejected frame increments
    ``rejected[reason]`` once; ``accepted`` counts good frames.
    """

    def __init__(self, accepted_version: int = PROTOCOL_VERSION) -> None:
        self.accepted_version = accepted_version
        self.rejected = dict.fromkeys(REJECT_REASONS, 0)
        self.accepted = 0
        self._buf = bytearray()
        self._discarding = False

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def reset(self) -> None:
        """Forget a partial frame (after the port was reopened); counters are kept."""
        self._buf.clear()
        self._discarding = False

    def feed(self, data: bytes) -> list[Frame]:
        frames: list[Frame] = []
        start = 0
        n = len(data)
        while start < n:
            zero = data.find(b'\x00', start)
            end = n if zero < 0 else zero
            if zero >= 0 and not self._buf and not self._discarding:
                # a whole block in this chunk (the usual case): decoded without the buffer
                if end - start > MAX_ENCODED_BYTES:
                    self.rejected['oversize'] += 1
                elif end > start:
                    result = self._decode_block(data[start:end])
                    if isinstance(result, str):
                        self.rejected[result] += 1
                    else:
                        self.accepted += 1
                        frames.append(result)
                start = zero + 1
                continue
            if not self._discarding:
                self._buf += data[start:end]
                if len(self._buf) > MAX_ENCODED_BYTES:
                    self.rejected['oversize'] += 1
                    self._buf.clear()
                    self._discarding = True
            if zero < 0:
                break
            if self._buf:
                result = self._decode_block(bytes(self._buf))
                if isinstance(result, str):
                    self.rejected[result] += 1
                else:
                    self.accepted += 1
                    frames.append(result)
                self._buf.clear()
            self._discarding = False
            start = zero + 1
        return frames

    def _decode_block(self, block: bytes) -> Frame | str:
        try:
            raw = cobs.decode(block)
        except cobs.CobsError:
            return 'cobs'
        return decode_raw(raw, self.accepted_version)


def torque_to_wire(torque_nm: float) -> int:
    """N·m -> int16 [1e-4 N·m], rounded to nearest, saturated (caller rejects NaN first)."""
    return max(-0x8000, min(0x7FFF, int(round(torque_nm / TORQUE_LSB_NM))))


def velocity_to_wire(vel_radps: float) -> int:
    """rad/s -> int16 [1e-3 rad/s], rounded to nearest, saturated."""
    return max(-0x8000, min(0x7FFF, int(round(vel_radps / VELOCITY_LSB_RADPS))))


def wrap_int16(value: int) -> int:
    """Two's complement int16 of ``value`` modulo 2**16 (encoder positions on the wire)."""
    return ((value + 0x8000) & 0xFFFF) - 0x8000
