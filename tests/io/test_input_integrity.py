"""Issue 27 at the readers: duplicate keys refused in YAML and JSON naming the key and both
lines; only regular files read, their size checked first (a FIFO, a device, a folder, an
oversized file refused at once, naming it)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from controller.commands.common import PACKAGED_CONFIG
from controller.config import load_config
from controller.errors import ConfigError, InputError
from controller.io.files import read_bytes
from controller.io.images import read_image
from controller.io.json_files import load_json, parse_json
from controller.io.yaml_files import load_yaml, parse_yaml


def _demo_with(tmp_path: Path, after: str, insert: str) -> Path:
    """The demo config with ``insert`` (lines) written after the line ``after``."""
    lines = Path(PACKAGED_CONFIG).read_text(encoding="utf-8").splitlines(keepends=True)
    at = next(i for i, ln in enumerate(lines) if ln.rstrip() == after)
    p = tmp_path / "dup.yaml"
    p.write_text("".join(lines[:at + 1]) + insert + "".join(lines[at + 1:]), encoding="utf-8")
    return p


def test_a_second_tolerance_is_refused_naming_both_lines(tmp_path):
    p = _demo_with(tmp_path, "  tolerance_mrad: 0.5", "  tolerance_mrad: 10\n")
    first = next(i for i, ln in enumerate(p.read_text().splitlines(), 1) if "tolerance_mrad: 0.5" in ln)
    with pytest.raises(ConfigError) as err:
        load_config(p)
    assert str(err.value) == f"{p}: line {first + 1}: duplicate key 'tolerance_mrad' (first at line {first})"


def test_a_second_site_block_is_refused(tmp_path):
    p = tmp_path / "two-sites.yaml"
    text = Path(PACKAGED_CONFIG).read_text(encoding="utf-8")
    p.write_text(text + "\nsite:\n  name: elsewhere\n  latitude_deg: -37.0\n", encoding="utf-8")
    first = text.splitlines().index("site:") + 1
    with pytest.raises(ConfigError, match=rf"duplicate key .site. \(first at line {first}\)"):
        load_config(p)


@pytest.mark.parametrize("text,line,first", [
    ("a: 1\nb:\n  c: 2\na: 3\n", 4, 1),
    ("x:\n  - {k: 1, k: 2}\n", 2, 2),
    ("x:\n  y: 1\n  y: 1\n", 3, 2),  # the same value twice is still a mistake
])
def test_yaml_duplicates_at_any_depth(text, line, first):
    with pytest.raises(InputError) as err:
        parse_yaml(text, "f.yaml")
    msg = str(err.value)
    assert msg.startswith(f"f.yaml: line {line}: duplicate key") and msg.endswith(f"(first at line {first})")


def test_yaml_merge_keys_may_still_be_overridden():
    doc = parse_yaml("base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  y: 3\n", "f.yaml")
    assert doc["c"] == {"x": 1, "y": 3}


@pytest.mark.parametrize("text,key,line,first", [
    ('{"a": 1,\n "b": {"a": 2},\n "a": 3}', "a", 3, 1),
    ('[1, {"p": {"q": 1,\n\n "q": 2}}]', "q", 3, 1),
    ('{"k\\u0065y": 1, "key": 2}', "key", 1, 1),  # the same key, escaped differently
])
def test_json_duplicates_name_the_key_and_both_lines(text, key, line, first):
    with pytest.raises(InputError) as err:
        parse_json(text, "f.json")
    assert str(err.value) == f"f.json: line {line}: duplicate key {key!r} (first at line {first})"


def test_a_key_repeated_in_different_objects_is_fine():
    assert parse_json('[{"a": 1}, {"a": 2}]', "f.json") == [{"a": 1}, {"a": 2}]


def _readers():
    return [("yaml", lambda p: load_yaml(p)), ("json", lambda p: load_json(p)), ("image", read_image),
            ("config", load_config), ("bytes", read_bytes)]


@pytest.mark.parametrize("reader", [r for _, r in _readers()], ids=[n for n, _ in _readers()])
def test_special_files_are_refused_at_once_naming_them(reader, tmp_path, scaled):
    fifo = tmp_path / "a_fifo"
    os.mkfifo(fifo)
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "zero").symlink_to("/dev/zero")
    for p, kind in ((fifo, "a FIFO"), (tmp_path / "a_folder", "a directory"),
                    (tmp_path / "zero", "a character device")):
        t0 = time.perf_counter()
        with pytest.raises(InputError) as err:
            reader(p)
        assert time.perf_counter() - t0 < scaled(1.0)
        assert str(err.value).startswith(f"{p}: is {kind}, not a regular file"), err.value


def test_the_size_limit_is_exact(tmp_path):
    p = tmp_path / "sized.yaml"
    p.write_bytes(b"a" * 100)
    assert len(read_bytes(p, max_bytes=100)) == 100
    p.write_bytes(b"a" * 101)
    with pytest.raises(InputError, match=f"{p}: 101 bytes is too large for a file"):
        read_bytes(p, max_bytes=100)
