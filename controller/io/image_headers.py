"""What an image file claims to hold, read from its header before anything is decoded.

A 1 KB PNG may claim 10⁶ × 10⁶ pixels, a 100-byte ``.npy`` header a 37 GiB array, and a
zlib stream of zeros inflates a thousandfold: the decoder would allocate first and fail (or
exhaust memory) later. :func:`image_header` parses the header of the formats the product
reads — PNG (IHDR), TIFF (first IFD, both byte orders) and ``.npy`` (format 1.0/2.0) — and
:func:`check_header` refuses a claim beyond :data:`MAX_PIXELS` or :data:`MAX_DECODED_BYTES`
with one line naming the file. Anything else (JPEG, BMP, BigTIFF, text) is refused by its
first bytes, so the decoder only ever sees a file whose size is known.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import PurePath

import numpy as np

from controller.errors import InputError

MAX_PIXELS = 1 << 26  # 64 Mpx; the plant's cameras deliver ≤ 5 Mpx
MAX_DECODED_BYTES = 1 << 28  # 256 MiB decoded: 64 Mpx of float32 grey
MAX_FILE_BYTES = MAX_DECODED_BYTES + (1 << 20)  # no larger than what it decodes to, plus headers

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NPY_MAGIC = b"\x93NUMPY"
TIFF_MAGIC = (b"II*\x00", b"MM\x00*")
BIGTIFF_MAGIC = (b"II+\x00", b"MM\x00+")

# Samples per pixel as OpenCV decodes each PNG colour type (palette may carry alpha: count 4).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 4, 4: 4, 6: 4}
_PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}


@dataclass(frozen=True)
class ImageHeader:
    """What the header claims: format (``png``/``tiff``/``npy``), width × height in pixels,
    samples per pixel as decoded, and bytes per sample."""

    format: str
    width: int
    height: int
    channels: int
    sample_bytes: int
    npy_dtype: np.dtype | None = None
    npy_shape: tuple[int, ...] | None = None

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def decoded_bytes(self) -> int:
        return self.pixels * self.channels * self.sample_bytes


_SUFFIX_FORMAT = {".png": "png", ".tif": "tiff", ".tiff": "tiff", ".npy": "npy"}


def image_header(data: bytes, name: str) -> ImageHeader:
    """Parse the header of ``data`` (the whole file); InputError naming ``name`` when it is no
    PNG, TIFF or ``.npy`` file, its header is truncated or inconsistent, or its suffix names
    another of these formats (a file without such a suffix is taken by its content)."""
    if not data:
        raise InputError(f"{name}: file is empty")
    if data.startswith(PNG_MAGIC):
        header = _png(data, name)
    elif data[:4] in TIFF_MAGIC:
        header = _tiff(data, name)
    elif data.startswith(NPY_MAGIC):
        header = _npy(data, name)
    else:
        header = None
    suffix = PurePath(name).suffix.lower()
    named = _SUFFIX_FORMAT.get(suffix)
    if header is not None:
        if named is not None and named != header.format:
            raise InputError(f"{name}: named {suffix} but holds a {header.format.upper()} image")
        return header
    if data[:4] in BIGTIFF_MAGIC:
        raise InputError(f"{name}: BigTIFF is not supported (write a classic TIFF, PNG or .npy)")
    raise InputError(f"{name}: not a PNG, TIFF or .npy image (starts with {data[:8]!r})")


def check_header(h: ImageHeader, name: str) -> None:
    """Refuse an empty image or one beyond the pixel or decoded-size limit."""
    what = f"{h.format.upper()} header claims {h.width}×{h.height} px"
    if h.pixels == 0:
        raise InputError(f"{name}: {what}: the image is empty")
    if h.pixels > MAX_PIXELS:
        raise InputError(f"{name}: {what} (limit {MAX_PIXELS} px)")
    if h.decoded_bytes > MAX_DECODED_BYTES:
        raise InputError(f"{name}: {what} × {h.channels} × {h.sample_bytes} bytes = {h.decoded_bytes} bytes "
                         f"decoded (limit {MAX_DECODED_BYTES})")


def _png(data: bytes, name: str) -> ImageHeader:
    # The IHDR chunk must come first: length 13, type, then width, height, depth, colour type.
    if len(data) < 33 or data[12:16] != b"IHDR":
        # (the wording of the decoder's failure below, which scripts already match)
        raise InputError(f"{name}: not a readable image (corrupt file or unsupported format)")
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    if depth not in _PNG_DEPTHS.get(colour, ()):
        raise InputError(f"{name}: PNG header has bit depth {depth} with colour type {colour} (invalid)")
    return ImageHeader("png", width, height, _PNG_CHANNELS[colour], 2 if depth == 16 else 1)


_TIFF_TYPES = {3: ("H", 2), 4: ("I", 4)}  # SHORT, LONG: the types of the tags read here


def _tiff(data: bytes, name: str) -> ImageHeader:
    order = "<" if data[:2] == b"II" else ">"
    if len(data) < 8:
        raise InputError(f"{name}: truncated TIFF header")
    (ifd,) = struct.unpack(order + "I", data[4:8])
    if ifd < 8 or ifd + 2 > len(data):
        raise InputError(f"{name}: TIFF directory at byte {ifd} is outside the file ({len(data)} bytes)")
    (n,) = struct.unpack(order + "H", data[ifd:ifd + 2])
    if ifd + 2 + 12 * n > len(data):
        raise InputError(f"{name}: truncated TIFF directory ({n} entries at byte {ifd})")
    tags: dict[int, int] = {}
    for i in range(n):
        at = ifd + 2 + 12 * i
        tag, typ, count = struct.unpack(order + "HHI", data[at:at + 8])
        if tag not in (256, 257, 258, 277) or typ not in _TIFF_TYPES or count < 1:
            continue
        fmt, size = _TIFF_TYPES[typ]
        where = at + 8 if count * size <= 4 else struct.unpack(order + "I", data[at + 8:at + 12])[0]
        if where + size > len(data):
            raise InputError(f"{name}: TIFF tag {tag} points outside the file")
        tags[tag] = struct.unpack(order + fmt, data[where:where + size])[0]  # first value
    if 256 not in tags or 257 not in tags:
        raise InputError(f"{name}: TIFF directory has no ImageWidth/ImageLength")
    bits = tags.get(258, 1)
    if not 1 <= bits <= 64:
        raise InputError(f"{name}: TIFF header claims {bits} bits per sample")
    return ImageHeader("tiff", tags[256], tags[257], max(1, tags.get(277, 1)), (bits + 7) // 8)


def _npy(data: bytes, name: str) -> ImageHeader:
    from numpy.lib import format as npy

    fh = io.BytesIO(data)
    try:
        version = npy.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = npy.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, fortran, dtype = npy.read_array_header_2_0(fh)
        else:
            raise InputError(f"{name}: .npy format version {version[0]}.{version[1]} is not supported")
    except InputError:
        raise
    except Exception as exc:  # numpy parses the header text with ast and tokenize: ValueError,
        # SyntaxError, tokenize.TokenError, ... (found by the hypothesis test); all mean "not a header"
        raise InputError(f"{name}: not a readable .npy header ({str(exc).splitlines()[0][:80]})") from None
    if dtype.hasobject or dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise InputError(f"{name}: .npy pixel type {dtype} is not supported (integer or float only)")
    if len(shape) != 2:
        raise InputError(f"{name}: expected a 2-D grey image, the .npy header says shape {shape}")
    header = ImageHeader("npy", shape[1], shape[0], 1, dtype.itemsize, dtype, tuple(shape))
    check_header(header, name)  # before the size check below, which multiplies the claim out
    need = fh.tell() + header.decoded_bytes
    if len(data) < need:
        raise InputError(f"{name}: truncated .npy ({len(data)} bytes, the header needs {need})")
    return header
