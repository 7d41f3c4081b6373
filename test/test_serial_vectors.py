"""docs/serial-protocol-vectors.json: every vector decodes and re-encodes byte for byte, invalid
ones are rejected for the stated reason, and the file is what the codec generates today.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ament_formation.core.serial import cobs
from ament_formation.core.serial import serial_protocol as sp
from ament_formation.core.serial.crc16 import crc16
from ament_formation.core.serial.crc32c import crc32c
from ament_formation.tools import serial_vectors

PATH = Path(__file__).resolve().parents[1] / 'docs' / 'serial-protocol-vectors.json'
DATA = json.loads(PATH.read_text())


def test_file_is_up_to_date_with_the_codec():
    assert PATH.read_text() == serial_vectors.render(), (
        'regenerate: python -m ament_formation.tools.serial_vectors'
    )


def test_vector_counts():
    assert len(DATA['valid']) >= 15 and len(DATA['invalid']) >= 10
    assert {v['message']['type'] for v in DATA['valid']} == {t.name for t in sp.MsgType}
    assert {v['reject'] for v in DATA['invalid']} == set(sp.REJECT_REASONS)


@pytest.mark.parametrize('vec', DATA['valid'], ids=lambda v: v['name'])
def test_valid_vector_decodes_and_reencodes(vec):
    wire = bytes.fromhex(vec['hex'])
    assert len(wire) <= sp.MAX_WIRE_BYTES
    dec = sp.FrameDecoder(accepted_version=sp.PROTOCOL_VERSION)
    frames = dec.feed(wire)
    assert len(frames) == 1 and dec.rejected_total == 0
    frame = frames[0]
    assert frame.msg.to_dict() == vec['message']
    assert (frame.seq, frame.version) == (vec['seq'], vec['version'])
    again = sp.encode_frame(
        frame.msg, frame.seq, leading_delimiter=vec['leading_delimiter'], version=frame.version
    )
    assert again == wire
    raw = bytes.fromhex(vec['raw_hex'])
    assert cobs.decode(wire.strip(b'\x00')) == raw
    if vec['version'] == 1:
        assert int(vec['check'], 16) == crc16(raw[:-2]) == int.from_bytes(raw[-2:], 'little')
    else:
        assert int(vec['check'], 16) == crc32c(raw[:-4]) == int.from_bytes(raw[-4:], 'little')


@pytest.mark.parametrize('vec', DATA['invalid'], ids=lambda v: v['name'])
def test_invalid_vector_rejected_for_its_reason(vec):
    dec = sp.FrameDecoder()
    assert dec.feed(bytes.fromhex(vec['hex'])) == []
    assert {k: n for k, n in dec.rejected.items() if n} == {vec['reject']: 1}


@pytest.mark.parametrize('vec', DATA['streams'], ids=lambda v: v['name'])
def test_stream_vectors(vec):
    dec = sp.FrameDecoder()
    got = [f.msg.to_dict() for f in dec.feed(bytes.fromhex(vec['hex']))]
    assert got == vec['frames']
    assert {k: n for k, n in dec.rejected.items() if n} == vec['rejected']


def test_meaning_in_si_units_matches_wire_values():
    by_name = {v['name']: v for v in DATA['valid']}
    cmd = by_name['torque_cmd']
    assert cmd['message']['left_e4nm'] * sp.TORQUE_LSB_NM == pytest.approx(
        cmd['meaning']['left_nm']
    )
    tel = by_name['telemetry']
    assert tel['message']['left_ticks'] * 2 * 3.141592653589793 / 1440 == pytest.approx(
        tel['meaning']['left_rad'], abs=1e-6
    )
