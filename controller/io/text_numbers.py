"""Numbers written as text (command-line options, console fields, CSV cells, ids): ASCII only.

Python's ``int()`` and ``float()`` accept any Unicode digit (``int("١")`` is 1, ``"１"`` too),
underscores (``"1_0"`` is 10) and surrounding whitespace, and ``str.isdigit()`` is true for
``"²"`` although ``int("²")`` fails. A number an operator types must be what it looks like, so
every number read from text goes through here: plain ASCII decimal, or a refusal naming what
was read.
"""

from __future__ import annotations

import re

from controller.errors import InputError

_INT = re.compile(r"[+-]?[0-9]+", re.ASCII)
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:inf|infinity|nan)",
                    re.ASCII | re.IGNORECASE)
MAX_DIGITS = 4300  # Python's own limit on int() of text (sys.int_info.default_max_str_digits)


def is_ascii_int(text: str) -> bool:
    """``text`` is an optionally signed run of ASCII digits (``"12"``, ``"-3"``; not ``"١"``,
    ``"²"``, ``"1_0"``, ``" 1"``)."""
    return isinstance(text, str) and len(text) <= MAX_DIGITS and _INT.fullmatch(text) is not None


def is_ascii_index(text: str) -> bool:
    """``text`` is an unsigned run of ASCII digits: an index, an id, a night number."""
    return is_ascii_int(text) and text[0] not in "+-"


def parse_int(text: str, what: str) -> int:
    """``text`` as an int (:func:`is_ascii_int`); InputError naming ``what`` otherwise."""
    if not is_ascii_int(text):
        raise InputError(f"{what}: {str(text)[:40]!r} is not a whole number (ASCII digits)")
    return int(text)


def parse_float(text: str, what: str) -> float:
    """``text`` as a float written in ASCII (digits, a point, an exponent; ``inf``/``nan`` are
    returned for the caller's range check); InputError naming ``what`` otherwise."""
    if not isinstance(text, str) or len(text) > MAX_DIGITS or _FLOAT.fullmatch(text) is None:
        raise InputError(f"{what}: {str(text)[:40]!r} is not a number (ASCII digits)")
    return float(text)
