"""Reading JSON files that may be anything, with the checks of :mod:`controller.io.yaml_files`:
size and UTF-8 (:func:`read_text`), then the nesting depth, counted without recursion before
the document is built, so a hostile or broken file ends in one line naming it (exit 2)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from controller.errors import InputError
from controller.io.yaml_files import MAX_BYTES, read_text

MAX_DEPTH = 32  # PAINT records and model files nest 4 levels

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_BRACKET = re.compile(r"[\[\]{}]")


def nesting_depth(text: str) -> int:
    """Deepest bracket nesting of a JSON text, strings skipped (an unbalanced text counts as
    far as it goes; the parser reports it)."""
    depth = deepest = 0
    for m in _BRACKET.finditer(_STRING.sub('""', text)):
        depth += 1 if m.group() in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


def parse_json(text: str, source: str, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads`` of ``text`` after the depth check; InputError naming ``source``."""
    depth = nesting_depth(text)
    if depth > max_depth:
        raise InputError(f"{source}: nested {depth} levels deep (at most {max_depth})")
    try:
        return json.loads(text)
    except ValueError as exc:  # JSONDecodeError says line and column
        raise InputError(f"{source}: invalid JSON: {str(exc)[:120]}") from None


def load_json(path: str | Path, what: str = "JSON file", max_bytes: int = MAX_BYTES) -> Any:
    """Read and parse a JSON file with every check above."""
    return parse_json(read_text(path, what, max_bytes), str(path))
