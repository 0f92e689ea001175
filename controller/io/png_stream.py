"""A PNG file's chunks and compressed pixel stream checked before libpng sees them.

libpng, inside OpenCV's decoder, prints its own ``libpng error: …`` line on the process's
standard error for a corrupt file before OpenCV reports the failure, and no OpenCV setting
silences it: a garbled PNG would end a command with two lines instead of one. Redirecting
file descriptor 2 around the decode would hide other threads' messages, so the file is checked
here instead, with the same rules libpng applies (PNG specification, ISO/IEC 15948:2004):

* chunks: 4-byte big-endian length, 4-byte ASCII-letter type, data, CRC-32 of type and data
  (§5.3); IHDR first, IEND last, IDAT chunks consecutive, PLTE before them for colour type 3;
* the concatenated IDAT data is one zlib stream (§10) that inflates to exactly the filtered
  image's size — per row one filter-type byte (0…4, §9.2) and ⌈width × samples × depth / 8⌉
  bytes, over the seven Adam7 passes when interlaced (§8.2).

:func:`check_png` raises :class:`InputError` naming the file and what is wrong.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from controller.errors import InputError

# Samples per pixel stored in the file for each colour type (§6.1): grey, RGB, palette index,
# grey + alpha, RGBA.
_FILE_SAMPLES = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_CRITICAL = {b"IHDR", b"PLTE", b"IDAT", b"IEND"}  # the others a decoder must understand (§5.4)
# Adam7 passes (§8.2): (first column, first row, column step, row step).
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def check_png(data: bytes, name: str) -> None:
    """Raise :class:`InputError` naming ``name`` unless ``data`` (a whole PNG file whose IHDR
    :mod:`controller.io.image_headers` already accepted) is a well-formed PNG whose pixel stream
    inflates to the size its header states, with valid filter types."""
    chunks = _chunks(data, name)
    types = [t for t, _ in chunks]
    if types[0] != b"IHDR" or types[-1] != b"IEND":
        raise InputError(f"{name}: PNG must start with IHDR and end with IEND "
                         f"(got {types[0]!r} … {types[-1]!r})")
    idat = [i for i, t in enumerate(types) if t == b"IDAT"]
    if not idat:
        raise InputError(f"{name}: PNG holds no image data (no IDAT chunk)")
    if idat[-1] - idat[0] != len(idat) - 1:
        raise InputError(f"{name}: PNG's IDAT chunks are not consecutive")
    width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1][:13])
    if colour == 3 and b"PLTE" not in types[: idat[0]]:
        raise InputError(f"{name}: PNG of colour type 3 has no palette (PLTE) before its image data")
    if interlace not in (0, 1):
        raise InputError(f"{name}: PNG header names interlace method {interlace} (0 or 1)")
    rows = _rows(width, height, _FILE_SAMPLES[colour] * depth, interlace)
    expected = sum(n * (1 + rb) for n, rb in rows)
    stream = zlib.decompressobj()
    try:
        raw = stream.decompress(b"".join(chunks[i][1] for i in idat), expected + 1)
    except zlib.error as exc:
        raise InputError(f"{name}: PNG image data is not a valid zlib stream ({exc})") from None
    if len(raw) != expected or not stream.eof:
        got = (f"more than {expected}" if len(raw) > expected
               else f"{len(raw)} (its zlib stream cut off)" if not stream.eof else str(len(raw)))
        raise InputError(f"{name}: PNG image data inflates to {got} bytes; its header states {expected}")
    at = 0
    for n, rb in rows:
        filters = np.frombuffer(raw, np.uint8, n * (1 + rb), at)[:: 1 + rb] if n else np.empty(0, np.uint8)
        if filters.size and int(filters.max()) > 4:
            raise InputError(f"{name}: PNG row filter type {int(filters.max())} (valid: 0–4)")
        at += n * (1 + rb)


def _chunks(data: bytes, name: str) -> list[tuple[bytes, bytes]]:
    """(type, data) of every chunk up to IEND; the chunk layout and CRCs checked (§5.3)."""
    out: list[tuple[bytes, bytes]] = []
    at = 8
    while True:
        if at + 12 > len(data):
            raise InputError(f"{name}: PNG is cut off at byte {len(data)} (no IEND chunk)")
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        if not kind.isalpha():
            raise InputError(f"{name}: PNG chunk at byte {at} has type {kind!r} (4 ASCII letters expected)")
        end = at + 8 + length
        if length > 0x7FFFFFFF or end + 4 > len(data):
            raise InputError(f"{name}: PNG chunk {kind.decode('ascii')} at byte {at} claims {length} bytes "
                             f"beyond the file's end ({len(data)} bytes)")
        if kind[:1].isupper() and kind not in _CRITICAL:
            raise InputError(f"{name}: PNG chunk {kind.decode('ascii')} at byte {at} is critical and unknown")
        body = data[at + 8:end]
        (crc,) = struct.unpack(">I", data[end:end + 4])
        if zlib.crc32(kind + body) != crc:
            raise InputError(f"{name}: PNG chunk {kind.decode('ascii')} at byte {at} fails its CRC check")
        out.append((kind, body))
        if kind == b"IEND":
            return out
        at = end + 4


def _rows(width: int, height: int, bits_per_pixel: int, interlace: int) -> list[tuple[int, int]]:
    """(rows, bytes per row without its filter byte) of the image or of each Adam7 pass."""
    if interlace == 0:
        return [(height, (width * bits_per_pixel + 7) // 8)]
    out = []
    for x0, y0, dx, dy in _ADAM7:
        w, h = max(0, (width - x0 + dx - 1) // dx), max(0, (height - y0 + dy - 1) // dy)
        out.append((h if w else 0, (w * bits_per_pixel + 7) // 8))
    return out
