"""Consistent Overhead Byte Stuffing (COBS): remove every 0x00 from a frame so that 0x00 can
delimit frames on a byte stream (Cheshire & Baker 1999). Strict decoding: a frame whose code
bytes do not end exactly at its last byte, or that contains 0x00, is rejected.
"""

from __future__ import annotations


class CobsError(ValueError):
    """The bytes are not a valid COBS encoding."""


def encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (any bytes); the result contains no 0x00 and no delimiter.

    Overhead: one byte per started run of 254 non-zero bytes (one byte for frames < 254 bytes).
    """
    out = bytearray()
    code_index = 0
    out.append(0)  # placeholder for the first code byte
    code = 1
    for byte in data:
        if byte == 0:
            out[code_index] = code
            code_index = len(out)
            out.append(0)
            code = 1
        else:
            out.append(byte)
            code += 1
            if code == 0xFF:
                out[code_index] = code
                code_index = len(out)
                out.append(0)
                code = 1
    out[code_index] = code
    return bytes(out)


def decode(data: bytes) -> bytes:
    """Decode one COBS-encoded frame (without its 0x00 delimiter).

    Raises
    ------
    CobsError
        ``data`` is empty, contains 0x00, or a code byte points past the end of the frame.
    """
    n = len(data)
    if n == 0:
        raise CobsError('empty frame')
    out = bytearray()
    i = 0
    while i < n:
        code = data[i]
        if code == 0:
            raise CobsError(f'0x00 inside frame at byte {i}')
        end = i + code
        if end > n:
            raise CobsError(f'code byte {code} at {i} runs past the frame end ({n} bytes)')
        block = data[i + 1: end]
        if 0 in block:
            raise CobsError(f'0x00 inside frame after byte {i}')
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)
