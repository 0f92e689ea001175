"""Long fuzz run of the frame codec; prints JSON counts (issue 5 robustness bars).

Four campaigns of ``--cases`` each (default 100,000), seeded:

- ``random``: arbitrary bytes to :func:`decode` and the streaming decoder; any exception
  other than :class:`FrameError` is counted in ``foreign_exceptions`` (must be 0);
- ``burst``: a valid frame with up to 16 consecutive bits of its body (LEN..CRC) altered;
  ``accepted`` must be 0 (CRC-16 detects every burst of length <= 16);
- ``wire_flips``: 1 to 4 random byte changes anywhere in the stuffed frame; ``accepted_altered``
  counts frames accepted that differ from the original (expected ~2**-16 per multi-byte hit);
- ``resync``: garbage, then a valid frame, cut at random read boundaries; ``lost`` counts
  runs where the streaming decoder did not deliver the frame last (must be 0).

Usage: .venv/bin/python benchmarks/bench_fuzz_codec.py [--cases N] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from firmware_proto.codec import (  # noqa: E402
    MAX_PAYLOAD,
    Decoder,
    Frame,
    FrameError,
    cobs_encode,
    decode,
    encode,
    encode_body,
)


def random_frame(rng: random.Random) -> Frame:
    return Frame(rng.randrange(256), rng.randrange(256), rng.randrange(256),
                 rng.randbytes(rng.randrange(MAX_PAYLOAD + 1)))


def campaign_random(rng, n) -> dict:
    c = Counter()
    for _ in range(n):
        data = rng.randbytes(rng.randrange(120))
        if rng.random() < 0.5:  # half without delimiters, to reach the CRC and LEN checks
            data = data.replace(b"\x00", b"")
        try:
            decode(data)
            c["accepted"] += 1
        except FrameError as exc:
            c[f"rejected_{exc.reason}"] += 1
        except Exception:  # exactly what the bar forbids: count it
            c["foreign_exceptions"] += 1
        try:
            Decoder().feed(data)
        except Exception:
            c["foreign_exceptions"] += 1
    c.setdefault("foreign_exceptions", 0)
    return dict(c)


def campaign_burst(rng, n) -> dict:
    c = Counter(accepted=0)
    for _ in range(n):
        body = encode_body(random_frame(rng))
        nbits = len(body) * 8
        width = rng.randint(1, 16)
        start = rng.randrange(nbits - width + 1)
        pattern = rng.getrandbits(width) | 1 | (1 << (width - 1))
        value = int.from_bytes(body, "big") ^ (pattern << (nbits - start - width))
        altered = value.to_bytes(len(body), "big")
        try:
            decode(cobs_encode(altered))
            c["accepted"] += 1
        except FrameError as exc:
            c[f"rejected_{exc.reason}"] += 1
    return dict(c)


def campaign_wire_flips(rng, n) -> dict:
    c = Counter(accepted_altered=0)
    for _ in range(n):
        frame = random_frame(rng)
        wire = bytearray(encode(frame))
        for _ in range(rng.randint(1, 4)):
            wire[rng.randrange(1, len(wire) - 1)] ^= rng.randrange(1, 256)
        got = Decoder().feed(bytes(wire))
        c["accepted_altered"] += sum(1 for f in got if f != frame)
        c["delivered_intact"] += sum(1 for f in got if f == frame)
    return dict(c)


def campaign_resync(rng, n) -> dict:
    c = Counter(lost=0)
    for _ in range(n):
        frame = random_frame(rng)
        stream = rng.randbytes(rng.randrange(300)) + encode(frame)
        dec, got, pos = Decoder(), [], 0
        while pos < len(stream):
            step = rng.randint(1, 64)
            got += dec.feed(stream[pos:pos + step])
            pos += step
        if not got or got[-1] != frame:
            c["lost"] += 1
    return dict(c)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=100_000, help="cases per campaign (default 100000)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    t0 = time.perf_counter()
    out = {"benchmark": "fuzz_codec", "seed": args.seed, "cases_per_campaign": args.cases}
    for name, fn in (("random", campaign_random), ("burst", campaign_burst),
                     ("wire_flips", campaign_wire_flips), ("resync", campaign_resync)):
        out[name] = fn(rng, args.cases)
    out["total_cases"] = 4 * args.cases
    out["ok"] = (out["random"]["foreign_exceptions"] == 0 and out["burst"]["accepted"] == 0
                 and out["resync"]["lost"] == 0)
    out["seconds"] = round(time.perf_counter() - t0, 2)
    print(json.dumps(out))
    sys.exit(0 if out["ok"] else 1)


if __name__ == "__main__":
    main()
