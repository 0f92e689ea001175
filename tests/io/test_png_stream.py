"""PNG files are checked before libpng decodes them (controller/io/png_stream.py): every valid
file OpenCV writes, and an interlaced one built here, still decodes; a garbled pixel stream is
one InputError and libpng never prints its own line on the process's standard error."""

from __future__ import annotations

import struct
import subprocess
import sys
import zlib

import cv2
import numpy as np
import pytest
from badfiles import png, png_chunk

from controller.errors import InputError
from controller.io.images import decode_image
from controller.io.png_stream import check_png

RNG = np.random.default_rng(45)


@pytest.mark.parametrize("shape,dtype", [((5, 7), np.uint8), ((33, 17), np.uint16), ((9, 11, 3), np.uint8),
                                         ((6, 5, 4), np.uint16), ((1, 1), np.uint8)])
def test_what_opencv_writes_passes_and_decodes(shape, dtype):
    img = RNG.integers(0, np.iinfo(dtype).max, shape, dtype=dtype, endpoint=True)
    data = cv2.imencode(".png", img)[1].tobytes()
    check_png(data, "x.png")
    out = decode_image(data, "x.png")
    assert out.shape == shape[:2] and out.dtype == dtype


def adam7_png(img: np.ndarray) -> bytes:
    """An 8-bit grey interlaced PNG of ``img``, each pass's rows with filter 0 (§8.2), written
    independently of the code under test."""
    raw = b""
    for x0, y0, dx, dy in ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
                           (0, 1, 1, 2)):
        sub = img[y0::dy, x0::dx]
        if sub.size:
            raw += b"".join(b"\0" + row.tobytes() for row in sub)
    ihdr = struct.pack(">IIBBBBB", img.shape[1], img.shape[0], 8, 0, 0, 0, 1)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", zlib.compress(raw))
            + png_chunk(b"IEND", b""))


@pytest.mark.parametrize("shape", [(13, 11), (1, 3), (3, 1), (8, 8)])
def test_an_interlaced_png_passes_and_decodes_to_its_pixels(shape):
    img = RNG.integers(0, 255, shape, dtype=np.uint8)
    data = adam7_png(img)
    check_png(data, "i.png")
    assert np.array_equal(decode_image(data, "i.png"), img)


_FLIPS = """
import sys, cv2, numpy as np
from controller.errors import InputError
from controller.io.images import decode_image
good = cv2.imencode(".png", np.arange(48, dtype=np.uint8).reshape(6, 8))[1].tobytes()
refused = decoded = 0
for at in range(8, len(good)):
    for bit in (0x01, 0x80):
        data = good[:at] + bytes([good[at] ^ bit]) + good[at + 1:]
        try:
            decode_image(data, "flip.png")
            decoded += 1
        except InputError as exc:
            assert "\\n" not in str(exc) and "flip.png" in str(exc), exc
            refused += 1
print(refused, decoded)
"""


def test_no_flipped_bit_makes_libpng_print():
    """Every single-bit flip after the signature, decoded in a child process whose file
    descriptor 2 is captured: refused (or decoded) with nothing printed there."""
    r = subprocess.run([sys.executable, "-c", _FLIPS], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    refused, decoded = map(int, r.stdout.split())
    assert refused > 0.9 * (refused + decoded)


@pytest.mark.parametrize("name,idat,what", [
    ("z.png", b"\x78\x9cnot deflate", "not a valid zlib stream"),
    ("s.png", zlib.compress(b"\0abcd" * 2), "inflates to 10 bytes"),
    ("l.png", zlib.compress(b"\0abcd" * 4), "inflates to more than 15"),
    ("c.png", zlib.compress(b"\0abcd" * 3)[:-6], "cut off"),
    ("f.png", zlib.compress(b"\x05abcd" * 3), "filter type 5"),
])
def test_a_garbled_stream_is_named(name, idat, what):
    data = png(4, 3, idat=idat)
    with pytest.raises(InputError, match=what) as exc:
        decode_image(data, name)
    assert str(exc.value).startswith(f"{name}: ")
