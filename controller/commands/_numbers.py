"""Numeric command-line options: every one has a stated range, checked by argparse before any
work (issue 27). ``type=Number(lo, hi)`` refuses text that is not a number, NaN, ±inf (unless
``infinite=True``) and values outside the range, naming the option (exit 2);
``tests/test_cli_numbers.py`` walks every command and fails on a numeric option without one.

Ranges are written as in docs/configuration.md: ``[a, b]`` closed, ``(a, b]`` open at a.
"""

from __future__ import annotations

import argparse
import math

from controller.errors import InputError
from controller.io.text_numbers import parse_float, parse_int

INT32 = 2**31 - 1
SEED_MAX = 2**32 - 1  # numpy's SeedSequence takes any non-negative integer; scripts pass 32-bit ones


class Number:
    """An argparse ``type``: a finite int or float within its range."""

    def __init__(self, lo: float, hi: float, *, integer: bool = False, lo_open: bool = False,
                 hi_open: bool = False, infinite: bool = False) -> None:
        self.lo, self.hi, self.integer = lo, hi, integer
        self.lo_open, self.hi_open, self.infinite = lo_open, hi_open, infinite
        self.__name__ = "integer" if integer else "number"  # argparse's "invalid <name> value"

    def range_text(self) -> str:
        text = f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"
        return text + (" or inf" if self.infinite else "")

    def __call__(self, text: str) -> int | float:
        try:  # ASCII only: int() would take "١" or "１" for 1
            value = parse_int(text, "") if self.integer else parse_float(text, "")
        except InputError:
            kind = "an integer" if self.integer else "a number"
            raise argparse.ArgumentTypeError(f"{text[:40]!r} is not {kind} (ASCII digits)") from None
        if self.infinite and value == math.inf:
            return value
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text} is not a finite number (range {self.range_text()})")
        below = value <= self.lo if self.lo_open else value < self.lo
        above = value >= self.hi if self.hi_open else value > self.hi
        if below or above:
            raise argparse.ArgumentTypeError(f"{text} is outside {self.range_text()}")
        return value

    def __repr__(self) -> str:
        return f"Number{self.range_text()}"


def fraction(*, closed: bool = False) -> Number:
    """(0, 1) — or (0, 1] with ``closed`` (a transmittance, a reflectivity)."""
    return Number(0, 1, lo_open=True, hi_open=not closed)


SEED = Number(0, SEED_MAX, integer=True)
STEPS = Number(-INT32 - 1, INT32, integer=True)  # the wire's int32; soft limits do the rest
EXPOSURE_S = Number(1e-6, 3600)  # 1 µs … 1 h
DNI = Number(0, 1500, lo_open=True)  # W/m²; the solar constant is 1361
PIXELS = Number(0, 65535)  # an image coordinate or length, px
SUN_ANGLE_MRAD = Number(0, 50, lo_open=True)
POSITIVE_RATIO = Number(0, 1e9, lo_open=True)
