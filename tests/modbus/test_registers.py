"""The register map: required content, hand-computed word encodings, loader validation,
and agreement between registers.yaml and the human-readable MODBUS.md."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.faults import Fault
from firmware_proto.registers import (
    DEFAULT_MAP,
    Register,
    RegisterMapError,
    load_register_map,
    parse_register_map,
)

REQUIRED = {
    "az_actual_steps": "input", "el_actual_steps": "input", "status_bits": "input",
    "fault_code": "input", "az_target_steps": "holding", "el_target_steps": "holding",
    "command": "holding", "az_soft_min_steps": "holding", "az_soft_max_steps": "holding",
    "el_soft_min_steps": "holding", "el_soft_max_steps": "holding",
    "jog_az_steps": "holding", "jog_el_steps": "holding", "device_type": "input",
    "fw_version_major": "input",
}


@pytest.fixture(scope="module")
def regmap():
    return load_register_map()


@pytest.mark.parametrize(("name", "table"), sorted(REQUIRED.items()))
def test_required_registers_present(regmap, name, table):
    assert regmap[name].table == table


def test_command_codes_and_status_bits(regmap):
    assert set(regmap["command"].codes) >= {"move", "stop", "home", "stow", "clear_fault", "jog"}
    assert len(set(regmap["command"].codes.values())) == len(regmap["command"].codes)
    assert set(regmap["status_bits"].bits) >= {"moving", "in_position", "limit_az", "limit_el", "fault"}
    assert regmap.bit("status_bits", "moving") == 1 and regmap.bit("status_bits", "fault") == 16


def test_every_entry_has_the_issue_fields():
    doc = yaml.safe_load(DEFAULT_MAP.read_text())
    for entry in doc["registers"]:
        for key in ("name", "table", "address", "type", "scale", "unit", "access"):
            assert key in entry, (entry["name"], key)
        if entry["type"] in ("int32", "uint32"):
            assert entry["word_order"] in ("big", "little")


def test_fault_code_is_16_bit_and_fits_fault_bits(regmap):
    reg = regmap["fault_code"]
    assert reg.type == "uint16"
    assert max(Fault) <= reg.limits()[1]


def _reg(type_: str, order: str = "big") -> Register:
    return Register("x", "holding", 0, type_, 1.0, "steps", "rw", word_order=order)


@pytest.mark.parametrize(("type_", "order", "value", "words"), [
    ("int32", "big", 70000, [0x0001, 0x1170]),      # 70000 = 0x0001_1170
    ("int32", "little", 70000, [0x1170, 0x0001]),
    ("int32", "big", -2, [0xFFFF, 0xFFFE]),          # two's complement
    ("int32", "big", -(2 ** 31), [0x8000, 0x0000]),
    ("uint32", "big", 0xDEADBEEF, [0xDEAD, 0xBEEF]),
    ("int16", "big", -1, [0xFFFF]),
    ("uint16", "big", 0x4843, [0x4843]),
])
def test_encode_decode_hand_computed(type_, order, value, words):
    reg = _reg(type_, order)
    assert reg.encode(value) == words
    assert reg.decode(words) == value


@pytest.mark.parametrize(("type_", "value"), [
    ("uint16", -1), ("uint16", 65536), ("int16", 32768), ("int32", 2 ** 31), ("uint32", -1),
])
def test_encode_refuses_values_that_do_not_fit(type_, value):
    with pytest.raises(ValueError, match="does not fit"):
        _reg(type_).encode(value)


def test_block_encode_and_decode(regmap):
    address, words = regmap.encode({"el_target_steps": 5, "az_target_steps": 70000})
    assert (address, words) == (0, [0x0001, 0x1170, 0x0000, 0x0005])
    assert regmap.decode("holding", 0, words) == {"az_target_steps": 70000, "el_target_steps": 5}
    with pytest.raises(ValueError, match="not adjacent"):
        regmap.encode({"az_target_steps": 1, "jog_az_steps": 2})


_GOOD = {"name": "a", "table": "holding", "address": 0, "type": "int32", "word_order": "big",
         "scale": 1, "unit": "steps", "access": "rw"}


@pytest.mark.parametrize(("change", "message"), [
    ({"table": "coils"}, "table must be one of"),
    ({"type": "float32"}, "type must be one of"),
    ({"word_order": None}, "needs word_order"),
    ({"access": "w"}, "access must be one of"),
    ({"table": "input"}, "read-only"),
    ({"addres": 3}, "unknown key"),
    ({"scale": 0}, "scale must be"),
])
def test_loader_rejects_bad_entries(change, message):
    entry = {**_GOOD, **change}
    if entry.get("word_order") is None:
        entry.pop("word_order")
    with pytest.raises(RegisterMapError, match=message) as exc:
        parse_register_map({"registers": [entry]}, "test.yaml")
    assert "test.yaml: registers[0] (a)" in str(exc.value)


def test_loader_rejects_overlap_and_duplicates():
    b = {**_GOOD, "name": "b", "address": 1}
    with pytest.raises(RegisterMapError, match="b at holding 1 overlaps a"):
        parse_register_map({"registers": [_GOOD, b]})
    with pytest.raises(RegisterMapError, match="duplicate name 'a'"):
        parse_register_map({"registers": [_GOOD, {**_GOOD, "address": 4}]})


def test_loader_names_unreadable_file(tmp_path):
    with pytest.raises(RegisterMapError, match="missing.yaml: cannot read"):
        load_register_map(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("registers: [\n")
    with pytest.raises(RegisterMapError, match="bad.yaml: invalid YAML"):
        load_register_map(bad)


def test_modbus_md_lists_every_register_at_its_address(regmap):
    text = (Path(DEFAULT_MAP).parent / "MODBUS.md").read_text()
    for reg in regmap.registers:
        span = f"{reg.address}" if reg.count == 1 else f"{reg.address}–{reg.end - 1}"
        row = re.search(rf"^\|\s*{re.escape(span)}\s*\|\s*`{reg.name}`\s*\|\s*{reg.type}", text, re.M)
        assert row, f"MODBUS.md has no row '| {span} | `{reg.name}` | {reg.type} ...'"
    for name, code in regmap["command"].codes.items():
        assert re.search(rf"\|\s*{code}\s*\|\s*{name.upper()}\s*\|", text), name


@given(st.integers(-(2 ** 31), 2 ** 31 - 1), st.sampled_from(["big", "little"]))
def test_int32_round_trip(value, order):
    reg = _reg("int32", order)
    words = reg.encode(value)
    assert all(0 <= w <= 0xFFFF for w in words)
    assert reg.decode(words) == value
    # the high word carries the sign: compare with struct's big-endian packing
    hi_first = list(struct.unpack(">HH", struct.pack(">i", value)))
    assert words == (hi_first if order == "big" else hi_first[::-1])
