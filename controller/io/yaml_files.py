"""Reading YAML files that may be anything: a regular file only, size, encoding and nesting are
checked before the document is built, and a key given twice in one mapping is refused naming
both lines (YAML would silently keep the last), so a hostile or broken file ends in one clear
line naming it (exit 2)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from controller.errors import InputError
from controller.io.files import read_bytes

MAX_BYTES = 8 << 20  # configs, libraries and CRFs are kilobytes; anything this big is not one
MAX_DEPTH = 32  # the deepest legitimate heliocal YAML nests 5 levels

_OPEN = (yaml.BlockMappingStartToken, yaml.BlockSequenceStartToken, yaml.FlowMappingStartToken,
         yaml.FlowSequenceStartToken)
_CLOSE = (yaml.BlockEndToken, yaml.FlowMappingEndToken, yaml.FlowSequenceEndToken)


def read_text(path: str | Path, what: str = "file", max_bytes: int = MAX_BYTES) -> str:
    """The UTF-8 text of ``path``; InputError naming the file when it is missing, too large or
    not text."""
    p = Path(path)
    data = read_bytes(p, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: not a text {what} (byte {exc.start} is not UTF-8)") from None


def parse_yaml(text: str, source: str, max_depth: int = MAX_DEPTH) -> Any:
    """``yaml.safe_load`` of ``text`` after an iterative scan that bounds the nesting (the
    composer recurses per level, so a deep document would exhaust the stack)."""
    try:
        depth = 0
        for token in yaml.scan(text, Loader=yaml.SafeLoader):
            if isinstance(token, _OPEN):
                depth += 1
                if depth > max_depth:
                    line = token.start_mark.line + 1
                    raise InputError(f"{source}: line {line}: nested deeper than {max_depth} levels")
            elif isinstance(token, _CLOSE):
                depth -= 1
        loader = _UniqueKeyLoader(text)
        loader.source = source
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = (getattr(exc, "problem", None) or str(exc)).splitlines()[0]  # one line, even for a
        # ReaderError (a control character), whose text goes on to a second line
        raise InputError(f"{source}: {where}invalid YAML: {problem}") from None


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` refusing a key written twice in one mapping (merge keys ``<<`` may
    still be overridden, as YAML intends)."""

    source = "<yaml>"

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            lines: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    first = lines.get(key)
                except TypeError:
                    continue  # an unhashable key: the base constructor reports it
                if first is not None:
                    raise InputError(f"{self.source}: line {line}: duplicate key {key!r} "
                                     f"(first at line {first})")
                lines[key] = line
        return super().construct_mapping(node, deep)


def load_yaml(path: str | Path, what: str = "YAML file", max_bytes: int = MAX_BYTES) -> Any:
    """Read and parse a YAML file with every check above."""
    return parse_yaml(read_text(path, what, max_bytes), str(path))
