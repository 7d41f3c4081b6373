"""CRC-32C (Castagnoli): reflected polynomial 0x82F63B78 (normal 0x1EDC6F41), initial value
0xFFFFFFFF, input and output reflected, final XOR 0xFFFFFFFF — the CRC of iSCSI, ext4 and SCTP.

Check value: ``crc32c(b"123456789") == 0xE3069283``. For the frames of the serial protocol
(version 2: at most 22 bytes of header and body, 176 bits) its Hamming distance is 8: every error
of up to 7 flipped bits is detected, as is every burst of at most 32 bits; any other error passes
with probability 2**-32 (Koopman, "32-bit cyclic redundancy codes for Internet applications",
2002).
"""

from __future__ import annotations

POLY_REFLECTED = 0x82F63B78


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ POLY_REFLECTED if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


TABLE = _make_table()


def crc32c(data: bytes, crc: int = 0) -> int:
    """CRC-32C of ``data``; continue a running CRC by passing the previous result as ``crc``."""
    table = TABLE
    crc ^= 0xFFFFFFFF
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc ^ 0xFFFFFFFF
