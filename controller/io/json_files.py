"""Reading JSON files that may be anything, with the checks of :mod:`controller.io.yaml_files`:
a regular file, size and UTF-8 (:func:`read_text`), then the nesting depth, counted without
recursion before the document is built, and no key twice in one object (``json`` would keep the
last silently), so a hostile or broken file ends in one line naming it (exit 2)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from controller.errors import HeliocalError, InputError
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
        return json.loads(text, object_pairs_hook=_unique, parse_constant=_not_json)
    except _DuplicateKey as dup:
        line, first = _duplicate_lines(text, dup.key)
        raise InputError(f"{source}: line {line}: duplicate key {dup.key!r} "
                         f"(first at line {first})") from None
    except ValueError as exc:  # JSONDecodeError says line and column
        raise InputError(f"{source}: invalid JSON: {str(exc)[:120]}") from None


def _not_json(name: str) -> float:
    # json.loads takes NaN, Infinity and -Infinity, which are not JSON (RFC 8259).
    raise ValueError(f"{name} is not a JSON number")


class NotJsonError(HeliocalError):
    """An output that would hold NaN or ±Infinity, which JSON has no word for (exit 1): the
    writer's bug, said rather than written."""


def dumps_json(obj: Any, *, indent: int | None = None, sort_keys: bool = False,
               what: str = "JSON output") -> str:
    """``json.dumps`` for every JSON heliocal writes (stdout, files, HTTP, events): NaN and
    ±Infinity are refused (``allow_nan=False``) with a :class:`NotJsonError` naming where in
    ``obj`` the value is, never written as invalid JSON."""
    try:
        return json.dumps(obj, indent=indent, sort_keys=sort_keys, allow_nan=False)
    except ValueError:
        where = _non_finite(obj, "")
        if where is None:
            raise
        raise NotJsonError(f"{what}: {where[0] or 'the value'} is {where[1]}, which JSON cannot "
                           "hold") from None


def _non_finite(obj: Any, path: str) -> tuple[str, float] | None:
    """The path and value of the first NaN/±inf float in ``obj`` (dicts, lists, tuples)."""
    stack = [(obj, path)]
    while stack:
        value, where = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            return where, value
        if isinstance(value, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k)) for k, v in reversed(value.items()))
        elif isinstance(value, (list, tuple)):
            stack.extend((v, f"{where}[{i}]") for i, v in reversed(list(enumerate(value))))
    return None


class _DuplicateKey(Exception):
    def __init__(self, key: str) -> None:
        self.key = key


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen = set()
        key = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise _DuplicateKey(key)
    return out


_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}:,]', re.DOTALL)


def _duplicate_lines(text: str, key: str) -> tuple[int, int]:
    """(line of the second occurrence of ``key`` in one object, line of the first), found by a
    scan of the tokens, run only once the parser found the duplicate."""
    stack: list[dict[str, int] | None] = []  # per open bracket: an object's keys and their lines
    previous, line, counted = None, 1, 0
    for m in _TOKEN.finditer(text):
        tok = m.group()
        if tok in "{[":
            stack.append({} if tok == "{" else None)
        elif tok in "}]":
            if stack:
                stack.pop()
        elif tok == ":" and previous is not None and stack and stack[-1] is not None:
            name, at = previous
            line += text.count("\n", counted, at)
            counted = at
            if name == key and name in stack[-1]:
                return line, stack[-1][name]
            stack[-1].setdefault(name, line)
        previous = (json.loads(tok), m.start()) if tok.startswith('"') else None
    return 0, 0  # not reached: the parser found the duplicate


def load_json(path: str | Path, what: str = "JSON file", max_bytes: int = MAX_BYTES) -> Any:
    """Read and parse a JSON file with every check above."""
    return parse_json(read_text(path, what, max_bytes), str(path))
