"""Frame codec: CRC check values, the shared vectors, a hand-worked frame, and fuzzing."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_proto.codec import (
    MAX_PAYLOAD,
    MAX_WIRE,
    Decoder,
    Frame,
    FrameError,
    cobs_decode,
    cobs_encode,
    decode,
    encode,
    encode_body,
)
from firmware_proto.crc import crc16, crc16_bitwise

FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])

frames = st.builds(Frame, st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
                   st.binary(max_size=MAX_PAYLOAD))


@pytest.mark.parametrize("data, want", [
    (b"123456789", 0x29B1),  # published check value of CRC-16/CCITT-FALSE (IBM-3740)
    (b"", 0xFFFF),  # the initial value, nothing shifted in
    (b"A", 0xB915),  # Williams' guide / CRC catalogue worked value for "A"
])
def test_crc_check_values(data, want):
    assert crc16(data) == want
    assert crc16_bitwise(data) == want


@pytest.mark.parametrize("raw, stuffed", [
    # Examples from Cheshire & Baker (1999) / the COBS Wikipedia table.
    (b"\x00", b"\x01\x01"),
    (b"\x00\x00", b"\x01\x01\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
    (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
    (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
])
def test_cobs_published_examples(raw, stuffed):
    assert cobs_encode(raw) == stuffed
    assert cobs_decode(stuffed) == raw


def test_hand_worked_frame():
    """GET_STATUS to address 1, seq 0 (PROTOCOL.md worked example): body 00 01 00 03,
    CRC 0x8393 sent low byte first, COBS groups [] [01] [03 93 83]."""
    assert crc16(bytes([0, 1, 0, 3])) == 0x8393
    assert crc16_bitwise(bytes([0, 1, 0, 3])) == 0x8393
    wire = bytes.fromhex("00 01 02 01 04 03 93 83 00")
    assert encode(Frame(1, 0, 3)) == wire
    assert decode(wire) == Frame(1, 0, 3, b"")


def test_shared_vectors_valid(vectors):
    for v in vectors["valid"]:
        frame = Frame(v["address"], v["seq"], v["command"], bytes.fromhex(v["payload"]))
        wire = bytes.fromhex(v["wire"])
        assert encode(frame) == wire, v["name"]
        assert decode(wire) == frame, v["name"]
        assert len(wire) <= MAX_WIRE
        assert 0 not in wire[1:-1], v["name"]


def test_shared_vectors_invalid(vectors):
    for v in vectors["invalid"]:
        with pytest.raises(FrameError) as info:
            decode(bytes.fromhex(v["wire"]))
        assert info.value.reason == v["reason"], v["name"]


def test_shared_vector_crc(vectors):
    for c in vectors["crc"]["checks"]:
        assert crc16_bitwise(bytes.fromhex(c["data"])) == c["crc"]


def test_encode_refuses_oversized_payload():
    with pytest.raises(ValueError, match="exceeds 64"):
        encode(Frame(1, 0, 1, bytes(65)))


def test_decoder_reports_reasons_and_keeps_going():
    good = encode(Frame(5, 1, 3, b"\x01\x00"))
    dec = Decoder()
    got = dec.feed(b"\x00\x05\x01\x02" + bytes(range(1, 100)) + good + b"\x00\x00" + good)
    assert got == [Frame(5, 1, 3, b"\x01\x00")] * 2
    assert dec.counts["too_long"] == 1 and sum(dec.counts.values()) == 1


@FUZZ
@given(st.binary(max_size=200))
def test_decode_raises_only_frame_error(data):
    try:
        decode(data)
    except FrameError as exc:
        assert exc.reason in ("cobs", "too_long", "short", "crc", "length")
    Decoder().feed(data)  # never raises at all


@FUZZ
@given(frames, st.data())
def test_altered_crc_covered_bytes_are_rejected(frame, data):
    """Any change of up to 16 consecutive bits of the body (LEN..CRC) is a burst the CRC-16
    always detects, so the frame must be refused."""
    body = bytearray(encode_body(frame))
    nbits = len(body) * 8
    start = data.draw(st.integers(0, nbits - 1))
    width = data.draw(st.integers(1, min(16, nbits - start)))
    pattern = data.draw(st.integers(1, (1 << width) - 1)) | 1 | (1 << (width - 1))
    value = int.from_bytes(body, "big") ^ (pattern << (nbits - start - width))
    altered = value.to_bytes(len(body), "big")
    with pytest.raises(FrameError):
        decode(b"\x00" + cobs_encode(altered) + b"\x00")


@FUZZ
@given(frames, st.integers(0, 1 << 30), st.integers(0, 255))
def test_flipped_wire_byte_is_never_accepted_as_a_different_frame(frame, pos, mask):
    wire = bytearray(encode(frame))
    i = 1 + pos % (len(wire) - 2)
    wire[i] ^= mask or 1
    for got in Decoder().feed(bytes(wire)):
        assert got == frame  # only possible if the flip hit a byte COBS ignores; it has none


@FUZZ
@given(st.binary(max_size=300), frames, st.lists(st.integers(1, 80), max_size=8))
def test_resynchronises_on_next_valid_frame(garbage, frame, cuts):
    stream = garbage + encode(frame)
    dec = Decoder()
    got = []
    pos = 0
    for c in cuts:  # arbitrary read boundaries
        got += dec.feed(stream[pos:pos + c])
        pos += c
    got += dec.feed(stream[pos:])
    assert got and got[-1] == frame
