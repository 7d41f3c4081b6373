"""Serial codec (core/serial/cobs.py, core/serial/crc16.py, core/serial/crc32c.py,
core/serial/serial_protocol.py): properties and corruption.

- any sequence of valid frames, split and merged at random and interleaved with noise, decodes to
  exactly those frames;
- no corrupted frame is ever accepted: 120 000 random corruptions (bit flips, substitutions,
  insertions, deletions, bursts) of frames of every type.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from ament_formation.core.serial import cobs
from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.crc16 import crc16
from ament_formation.core.serial.crc32c import crc32c

_RANGES = {'B': (0, 0xFF), 'H': (0, 0xFFFF), 'I': (0, 0xFFFFFFFF), 'h': (-0x8000, 0x7FFF)}


def _message_strategy(cls):
    import dataclasses

    args = []
    for f, code in zip(dataclasses.fields(cls), cls.FORMAT[1:]):
        lo, hi = _RANGES[code]
        if f.name == 'flags':
            args.append(st.integers(0, sp.FLAGS_DEFINED))
        elif f.name == 'engage':
            args.append(st.integers(0, 1))
        elif f.name == 'reason':
            args.append(st.integers(0, sp.STOP_HOST_SHUTDOWN))
        elif f.name in ('protocol_version', 'ticks_per_rev', 'telemetry_period_ms') and cls in (
            sp.Hello,
            sp.HelloAck,
        ):
            args.append(st.integers(1, hi))
        else:
            args.append(st.integers(lo, hi))
    return st.builds(cls, *args)


messages = st.one_of(*[_message_strategy(c) for c in sp.MESSAGE_CLASSES.values()])
frames = st.builds(sp.Frame, seq=st.integers(0, 255), msg=messages)


def _random_message(rng: np.random.Generator) -> sp.Message:
    import dataclasses

    cls = list(sp.MESSAGE_CLASSES.values())[rng.integers(len(sp.MESSAGE_CLASSES))]
    values = []
    for f, code in zip(dataclasses.fields(cls), cls.FORMAT[1:]):
        lo, hi = _RANGES[code]
        if f.name == 'flags':
            hi = sp.FLAGS_DEFINED
        if f.name == 'engage':
            hi = 1
        if f.name == 'reason':
            hi = sp.STOP_HOST_SHUTDOWN
        if f.name in ('protocol_version', 'ticks_per_rev', 'telemetry_period_ms') and cls in (
            sp.Hello,
            sp.HelloAck,
        ):
            lo = 1
        # half the fields small (many zero bytes -> many COBS code bytes), half anywhere
        values.append(
            int(rng.integers(lo, hi + 1))
            if rng.random() < 0.5
            else int(rng.integers(max(lo, -3), min(hi, 3) + 1))
        )
    return cls(*values)


def test_crc_check_value():
    assert crc16(b'123456789') == 0x29B1
    assert crc16(b'') == 0xFFFF
    assert crc32c(b'123456789') == 0xE3069283  # CRC-32C check value (RFC 3720 B.4)
    assert crc32c(b'') == 0
    assert crc32c(bytes(32)) == 0x8A9136AA  # RFC 3720 B.4: 32 bytes of zeros
    assert crc32c(b'\xff' * 32) == 0x62A8AB43  # RFC 3720 B.4: 32 bytes of ones


@given(st.binary(max_size=600))
def test_cobs_round_trip_and_no_zero(data):
    enc = cobs.encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + 1 + len(data) // 254
    assert cobs.decode(enc) == data


@pytest.mark.parametrize('bad', [b'', b'\x05\x01\x02', b'\x02\x00', b'\x03\x01\x00'])
def test_cobs_rejects_malformed(bad):
    with pytest.raises(cobs.CobsError):
        cobs.decode(bad)


def test_every_frame_fits_64_bytes():
    for t, n in sp.BODY_BYTES.items():
        assert n + 4 + 3 <= sp.MAX_WIRE_BYTES, t


@settings(max_examples=150, deadline=None)
@given(st.lists(frames, max_size=30), st.data())
def test_split_merge_and_noise_decode_exactly_the_frames(frame_list, data):
    """Host-style frames (leading 0x00) with noise bursts between them, fed in random pieces."""
    stream = bytearray()
    for fr in frame_list:
        if data.draw(st.booleans()):
            stream += data.draw(st.binary(min_size=1, max_size=80))  # noise, may contain 0x00
        stream += sp.encode_frame(fr.msg, fr.seq, leading_delimiter=True)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
    dec = sp.FrameDecoder()
    out = []
    prev = 0
    for cut in cuts + [len(stream)]:
        out += dec.feed(bytes(stream[prev:cut]))
        prev = cut
    assert out == frame_list
    assert dec.accepted == len(frame_list)


@settings(max_examples=100, deadline=None)
@given(st.lists(frames, min_size=1, max_size=30), st.data())
def test_board_style_frames_split_and_merged(frame_list, data):
    """Without leading delimiters (as the board sends) any split decodes exactly too."""
    stream = b''.join(sp.encode_frame(f.msg, f.seq) for f in frame_list)
    sizes = data.draw(st.lists(st.integers(1, 40), max_size=40))
    dec = sp.FrameDecoder()
    out, pos = [], 0
    for size in sizes:
        out += dec.feed(stream[pos: pos + size])
        pos += size
    out += dec.feed(stream[pos:])
    assert out == frame_list and dec.rejected_total == 0


@settings(max_examples=100, deadline=None)
@given(
    st.lists(frames, min_size=2, max_size=20),
    st.binary(min_size=1, max_size=30).filter(lambda b: 0 not in b),
)
def test_noise_glued_to_a_frame_loses_it_but_invents_nothing(frame_list, noise):
    stream = b''.join(sp.encode_frame(f.msg, f.seq) for f in frame_list)
    first_len = len(sp.encode_frame(frame_list[0].msg, frame_list[0].seq))
    dec = sp.FrameDecoder()
    out = dec.feed(noise + stream)
    assert (
        out == frame_list[1:] or out == frame_list
    )  # the glued frame is lost (or survives if noise ended it)
    assert dec.rejected_total == len(frame_list) - len(out)
    assert first_len > 0


def test_oversize_is_dropped_and_counted_once_then_resynchronises():
    dec = sp.FrameDecoder()
    good = sp.encode_frame(sp.TorqueCommand(1, 2), 3, leading_delimiter=True)
    out = dec.feed(bytes(range(1, 200)) + good)
    assert [f.msg for f in out] == [sp.TorqueCommand(1, 2)]
    assert dec.rejected['oversize'] == 1 and dec.rejected_total == 1


def test_rejection_reasons_are_counted_individually():
    dec = sp.FrameDecoder()
    raw = sp.raw_frame(sp.TorqueCommand(5, 6), 1)
    bad_crc = bytes([raw[0], raw[1] ^ 1]) + raw[2:]

    def with_crc(b):  # the check the version nibble selects: CRC-16 for 1, CRC-32C for 2
        return b + sp.frame_check(b, b[0] >> 4)

    blocks = [
        bad_crc,
        with_crc(b'\x2b\x00\x01'),
        with_crc(b'\x13\x00\x01\x02\x03\x04'),
        with_crc(b'\x23\x00\x01'),
        with_crc(b'\x27\x00\x09'),
        b'\x01\x02',
    ]
    stream = b''.join(cobs.encode(b) + b'\x00' for b in blocks) + b'\x05\x01\x00'
    assert dec.feed(stream) == []
    assert dec.rejected == {
        'oversize': 0,
        'cobs': 1,
        'length': 2,
        'crc': 1,
        'version': 1,
        'type': 1,
        'value': 1,
    }


def _corrupt(wire: bytes, rng: np.random.Generator) -> bytes:
    """One random corruption of the frame's COBS block (delimiters excluded)."""
    b = bytearray(wire)
    kind = rng.integers(6)
    n = len(b)
    if kind <= 1:  # 1..3 bit flips
        for pos in rng.choice(n * 8, size=int(rng.integers(1, 4)), replace=False):
            b[pos // 8] ^= 1 << (pos % 8)
    elif kind == 2:  # one byte replaced
        b[rng.integers(n)] ^= int(rng.integers(1, 256))
    elif kind == 3:  # byte inserted
        b.insert(int(rng.integers(n + 1)), int(rng.integers(1, 256)))
    elif kind == 4:  # byte deleted
        del b[int(rng.integers(n))]
    else:  # burst of up to 16 bits
        start = int(rng.integers(n * 8))
        for pos in range(start, min(start + int(rng.integers(2, 17)), n * 8)):
            if rng.random() < 0.5 or pos == start:
                b[pos // 8] ^= 1 << (pos % 8)
    return bytes(b)


def test_no_corrupted_frame_is_ever_accepted():
    rng = np.random.default_rng(20261123)
    n_trials = 120_000
    dec = sp.FrameDecoder()
    accepted = []
    changed = 0
    pool = [
        cobs.encode(sp.raw_frame(_random_message(rng), int(rng.integers(256))))
        for _ in range(3000)
    ]
    picks = rng.integers(len(pool), size=n_trials)
    for k in picks:
        block = pool[k]
        bad = _corrupt(block, rng)
        if bad == block:
            continue
        changed += 1
        out = dec.feed(b'\x00' + bad + b'\x00')
        if out:
            accepted.append((block.hex(), bad.hex(), out))
    assert changed >= 100_000
    assert accepted == [], accepted[:3]
    assert (
        dec.rejected_total >= changed
    )  # each corrupted frame rejected (a created 0x00 may split it in two)
