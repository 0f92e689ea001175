"""The bad-input corpus, built at test time (a few KB on disk; nothing committed but this code).

Each file is named after what is wrong with it, and every name is unique, so an error line
can be checked for it. ``write_corpus(folder)`` writes them all and returns their paths.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from pathlib import Path

import numpy as np

DEEP = 100_000  # nesting levels of the deep YAML/JSON files


def png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png(width: int, height: int, depth: int = 8, colour: int = 0, idat: bytes = b"") -> bytes:
    """A PNG whose IHDR says ``width``×``height`` (CRCs right), with ``idat`` as its data."""
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", idat)
            + png_chunk(b"IEND", b""))


def tiff(width: int, height: int, order: str = "<", bits: int = 8) -> bytes:
    """A classic TIFF header with one IFD claiming ``width``×``height`` grey pixels, no strips."""
    magic = b"II*\x00" if order == "<" else b"MM\x00*"
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, bits), (277, 3, 1, 1)]
    ifd = struct.pack(order + "H", len(entries))
    for tag, typ, count, value in entries:
        packed = struct.pack(order + "H", value) + b"\0\0" if typ == 3 else struct.pack(order + "I", value)
        ifd += struct.pack(order + "HHI", tag, typ, count) + packed
    return magic + struct.pack(order + "I", 8) + ifd + b"\0\0\0\0"


def npy_header(shape: tuple[int, ...], descr: str = "<f8") -> bytes:
    """Only the header of a ``.npy`` file claiming ``shape`` (version 1.0, padded to 64)."""
    text = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape!r}, }}"
    text += " " * (-(10 + len(text) + 1) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text.encode("latin1")


def npy(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=allow_pickle)
    return buf.getvalue()


def bomb_png() -> bytes:
    """36 Mpx of 16-bit RGBA zeros — 288 MB decoded from a file of a few hundred KB: under the
    pixel limit, over the decoded-size limit."""
    w = h = 6000
    row = b"\0" * (1 + w * 8)  # filter byte + 4 samples × 2 bytes
    z = zlib.compressobj(9)
    idat = b"".join(z.compress(row) for _ in range(h)) + z.flush()
    return png(w, h, 16, 6, idat)


def corpus() -> dict[str, bytes]:
    """File name → content."""
    rng = np.random.default_rng(16)
    good_png = png(4, 3, idat=zlib.compress(b"\0\x10\x20\x30\x40" * 3))
    return {
        "empty.png": b"",
        "truncated.png": good_png[:20],
        "huge_header.png": png(1_000_000, 1_000_000),
        "bomb.png": bomb_png(),
        "huge_header_le.tif": tiff(1_000_000, 1_000_000, "<"),
        "huge_header_be.tif": tiff(1_000_000, 1_000_000, ">"),
        "truncated.tif": tiff(64, 64)[:12],
        "huge_header.npy": npy_header((100_000, 100_000)),
        "truncated.npy": npy(np.ones((100, 100), np.float32))[:200],
        "three_d.npy": npy(np.ones((2, 3, 4), np.float32)),
        "complex.npy": npy(np.ones((4, 4), np.complex64)),
        "pickled.npy": npy(np.array([[{"a": 1}]], dtype=object), allow_pickle=True),
        # garbled pixel streams libpng would report on stderr itself (controller/io/png_stream.py)
        "crc_flipped.png": good_png[:45] + bytes([good_png[45] ^ 0x20]) + good_png[46:],
        "not_zlib.png": png(4, 3, idat=b"\x78\x9cgarbage, not deflate"),
        "short_stream.png": png(4, 3, idat=zlib.compress(b"\0\x10\x20\x30\x40" * 2)),
        "bad_filter.png": png(4, 3, idat=zlib.compress(b"\x07\x10\x20\x30\x40" * 3)),
        "yaml_named.png": b"sensors:\n  - name: ccd1\n",
        "png_named.yaml": good_png,
        "png_named.json": good_png,
        "png_named.csv": good_png,
        "binary.bin": rng.integers(0, 256, 4096, dtype=np.uint8).tobytes(),
        "deep_flow.yaml": b"[" * DEEP + b"]" * DEEP,
        "deep_block.yaml": b"- " * DEEP + b"x\n",
        "deep.json": b'{"a": ' * DEEP + b"1" + b"}" * DEEP,
        "latin1.txt": "image,label\ncafé.png,ok\n".encode("latin-1"),
    }


def write_corpus(folder: Path) -> list[Path]:
    """The corpus as files, plus what only a file system holds: a FIFO (reading it blocks
    forever), a directory, a link to ``/dev/zero`` (it never ends) and a sparse file over every
    size limit; and the duplicate-key files."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in {**corpus(), **DUPLICATES}.items():
        (folder / name).write_bytes(data)
        paths.append(folder / name)
    os.mkfifo(folder / "a_fifo")
    (folder / "a_folder").mkdir()
    (folder / "dev_zero_link").symlink_to("/dev/zero")
    with open(folder / "oversized_sparse", "wb") as f:  # costs no disk
        f.truncate(OVERSIZED)
    paths += [folder / n for n in SPECIAL]
    return paths


NOT_REGULAR = ("a_fifo", "a_folder", "dev_zero_link")
SPECIAL = (*NOT_REGULAR, "oversized_sparse")
OVERSIZED = (1 << 28) + (2 << 20)  # over the largest limit of any reader (images: 257 MiB)
# A key twice in one mapping: YAML and JSON keep the last silently; the readers refuse it.
DUPLICATES = {
    "dup_key.yaml": b"sensors:\n  - {name: ccd1}\ntolerance_mrad: 10\nsite: {a: 1}\ntolerance_mrad: 0.1\n",
    "dup_key.json": b'{"a": 1,\n "b": {"c": 2},\n "a": 3}\n',
}
