"""Frame codec of the serial actuator protocol: bytes <-> frames, no I/O (PROTOCOL.md).

Wire format of one frame::

    0x00 | COBS( LEN | ADDR | SEQ | CMD | PAYLOAD[LEN] | CRC16_lo | CRC16_hi ) | 0x00

``LEN`` is the payload length (0..64), the CRC-16/CCITT-FALSE (:mod:`firmware_proto.crc`)
covers ``LEN`` to the end of the payload and is sent low byte first. COBS removes every 0x00
from the body, so 0x00 only ever delimits frames and a receiver resynchronises at the next
0x00 after garbage. :func:`encode` emits a delimiter on both sides, so garbage before a frame
is closed off by the frame's own leading delimiter.

The only exception the decoding functions raise is :class:`FrameError`; its ``reason`` is
one of :data:`REASONS` (the same strings the shared test vectors and the C codec use).

References
----------
.. [1] S. Cheshire, M. Baker, "Consistent Overhead Byte Stuffing", IEEE/ACM Trans.
   Networking 7(2), 159-172, 1999.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

from firmware_proto.crc import crc16

DELIMITER = 0x00
HEADER_LEN = 4  # LEN, ADDR, SEQ, CMD
CRC_LEN = 2
MAX_PAYLOAD = 64
MIN_BODY = HEADER_LEN + CRC_LEN
MAX_BODY = HEADER_LEN + MAX_PAYLOAD + CRC_LEN  # 70
MAX_ENCODED = MAX_BODY + 1  # COBS adds one code byte per 254 bytes: 71
MAX_WIRE = MAX_ENCODED + 2  # with both delimiters: 73

REASONS = ("cobs", "too_long", "short", "crc", "length")


class FrameError(ValueError):
    """A chunk between delimiters is not a valid frame. ``reason`` is one of :data:`REASONS`:

    - ``cobs``: a COBS code byte points past the end of the chunk (or a 0x00 inside it);
    - ``too_long``: more than :data:`MAX_ENCODED` bytes between delimiters;
    - ``short``: fewer than 6 body bytes after COBS decoding;
    - ``crc``: the CRC does not match;
    - ``length``: the CRC matches but ``LEN`` disagrees with the body length.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame. ``address`` 1..247 (0 reserved), ``seq`` 0..255, ``command`` 0..255
    (bit 7 set on replies), ``payload`` at most :data:`MAX_PAYLOAD` bytes."""

    address: int
    seq: int
    command: int
    payload: bytes = b""


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` [1]_: the result contains no 0x00 byte."""
    out = bytearray()
    for block in data.split(b"\x00"):
        while len(block) >= 254:
            out.append(0xFF)
            out += block[:254]
            block = block[254:]
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`FrameError` ("cobs") on a bad code."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if code == 0:
            raise FrameError("cobs", f"0x00 inside a frame at byte {i}")
        if end > n:
            raise FrameError("cobs", f"code byte {code} at byte {i} points past the end ({n} bytes)")
        group = data[i + 1:end]
        if 0 in group:
            raise FrameError("cobs", f"0x00 inside a frame at byte {i + 1 + group.index(0)}")
        out += group
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def encode_body(frame: Frame) -> bytes:
    """The un-stuffed body ``LEN ADDR SEQ CMD PAYLOAD CRC_lo CRC_hi``."""
    payload = bytes(frame.payload)
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    for name in ("address", "seq", "command"):
        value = getattr(frame, name)
        if not 0 <= value <= 255:
            raise ValueError(f"{name}={value} does not fit in one byte")
    head = bytes((len(payload), frame.address, frame.seq, frame.command)) + payload
    crc = crc16(head)
    return head + bytes((crc & 0xFF, crc >> 8))


def encode(frame: Frame) -> bytes:
    """Wire bytes of ``frame``, with a 0x00 delimiter before and after."""
    return b"\x00" + cobs_encode(encode_body(frame)) + b"\x00"


def decode_stuffed(chunk: bytes) -> Frame:
    """Decode the bytes between two delimiters (no 0x00 inside) into a :class:`Frame`.

    Checks, in this order: ``short`` (empty), ``too_long``, ``cobs``, ``short``, ``crc``,
    ``length``. Raises only :class:`FrameError`.
    """
    if not chunk:
        raise FrameError("short", "empty frame")
    if len(chunk) > MAX_ENCODED:
        raise FrameError("too_long", f"{len(chunk)} bytes between delimiters, at most {MAX_ENCODED}")
    body = cobs_decode(chunk)
    if len(body) < MIN_BODY:
        raise FrameError("short", f"{len(body)} body bytes, at least {MIN_BODY}")
    got = body[-2] | (body[-1] << 8)
    want = crc16(body[:-2])
    if got != want:
        raise FrameError("crc", f"CRC 0x{got:04X} received, 0x{want:04X} computed")
    if body[0] != len(body) - MIN_BODY:
        raise FrameError("length", f"LEN byte says {body[0]}, the frame holds {len(body) - MIN_BODY}")
    return Frame(body[1], body[2], body[3], bytes(body[HEADER_LEN:-2]))


def decode(wire: bytes) -> Frame:
    """Decode exactly one frame, with or without its surrounding 0x00 delimiters."""
    return decode_stuffed(bytes(wire).strip(b"\x00"))


class Decoder:
    """Streaming decoder: feed it bytes as they arrive, get complete valid frames back.

    It never raises. Chunks between delimiters that are not valid frames are dropped and
    recorded (``counts[reason]``, the last few in ``errors``); a partial frame longer than
    :data:`MAX_ENCODED` is discarded up to the next delimiter, so memory stays bounded.
    """

    def __init__(self, keep_errors: int = 32) -> None:
        self._buf = bytearray()
        self._overflow = False
        self.errors: deque[FrameError] = deque(maxlen=keep_errors)
        self.counts: Counter[str] = Counter()

    def reset(self) -> None:
        """Forget a partial frame (e.g. after a silence longer than the inter-byte timeout)."""
        self._buf.clear()
        self._overflow = False

    @property
    def pending(self) -> int:
        """Bytes of an unfinished frame held."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        frames: list[Frame] = []
        parts = bytes(data).split(b"\x00")
        last = len(parts) - 1
        for i, part in enumerate(parts):
            if not self._overflow:
                self._buf += part
                if len(self._buf) > MAX_ENCODED:
                    self._overflow = True
                    self._buf.clear()
            if i == last:
                break
            if self._overflow:
                self._reject(FrameError("too_long", f"more than {MAX_ENCODED} bytes between delimiters"))
            elif self._buf:
                try:
                    frames.append(decode_stuffed(bytes(self._buf)))
                except FrameError as exc:
                    self._reject(exc)
            self.reset()
        return frames

    def _reject(self, exc: FrameError) -> None:
        self.counts[exc.reason] += 1
        self.errors.append(exc)
