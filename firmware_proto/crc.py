"""CRC-16 of the serial frame protocol: CRC-16/CCITT-FALSE (a.k.a. CRC-16/IBM-3740).

Parameters (Rocksoft model): width 16, poly 0x1021, init 0xFFFF, refin false, refout false,
xorout 0x0000, check 0x29B1 (the CRC of the ASCII bytes ``"123456789"``).
The CRC is sent **low byte first**, like every other multi-byte field (PROTOCOL.md).

References
----------
.. [1] R. N. Williams, "A painless guide to CRC error detection algorithms", 1993.
.. [2] G. Cook, "Catalogue of parametrised CRC algorithms", entry CRC-16/IBM-3740.
"""

from __future__ import annotations

import binascii

CHECK_INPUT = b"123456789"
CHECK_VALUE = 0x29B1


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (int in 0..0xFFFF).

    ``binascii.crc_hqx`` is the same MSB-first 0x1021 shift register; starting it at 0xFFFF
    gives the CCITT-FALSE variant [2]_.
    """
    return binascii.crc_hqx(data, 0xFFFF)


def crc16_bitwise(data: bytes) -> int:
    """Bit-by-bit reference of :func:`crc16` (the loop the C codec implements), for tests."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc
