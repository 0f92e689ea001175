"""Every number of the plant configuration is finite and inside its stated range (issue 27).

The schema is walked (:func:`controller.config_rules.numeric_keys`): every numeric key must
carry both bounds, must be present in the maximal configuration below (so it is exercised),
and must be refused — NaN, ±inf, ±1e308 and the first value beyond each bound — with the key
path named. The generated range table in docs/configuration.md must match the schema.
"""

from __future__ import annotations

import copy
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from controller.commands.common import PACKAGED_CONFIG
from controller.config import PlantConfig, parse_config
from controller.config_rules import NumericKey, numeric_keys
from controller.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
KEYS = numeric_keys(PlantConfig)
SOURCE = "maximal.yaml"


LAMP_DRIVERS = {"modbus-tcp": {"host": "127.0.0.1", "port": 1502, "unit": 1, "timeout_s": 1.0},
                "modbus-rtu": {"device": "/dev/ttyUSB2", "baud": 19200, "unit": 1, "timeout_s": 1.0},
                "command": {"command": ["/usr/local/bin/lamps"], "timeout_s": 30.0}}


def maximal_config(lamp_driver: str = "modbus-tcp") -> dict:
    """The demo plant cut to three heliostats (one per link kind), with every optional section
    that holds numbers filled in: ΔT, a GigE camera with a principal point and a look-at point,
    person zones, a gain, a lamp panel of ``lamp_driver``; every key left to its default written
    out."""
    doc = yaml.safe_load(Path(PACKAGED_CONFIG).read_text(encoding="utf-8"))
    doc = json.loads(json.dumps(doc))  # YAML aliases share one dict; unshare them
    doc = {k: v for k, v in doc.items() if not k.startswith("x-")}
    doc["site"]["delta_t_s"] = 69.2
    helios = doc["heliostats"][:3]
    helios[0]["link"] = {"kind": "serial", "device": "/dev/ttyUSB0", "address": 1, "baud": 115200}
    helios[1]["link"] = {"kind": "modbus-tcp", "host": "127.0.0.1", "port": 1502, "unit": 1}
    helios[2]["link"] = {"kind": "modbus-rtu", "device": "/dev/ttyUSB1", "unit": 1, "baud": 19200}
    helios[0]["concentrator_translation_m"] = [0.0, 0.175, 0.0]
    doc["heliostats"] = helios
    cam = doc["camera"]
    cam["driver"] = "gige"
    cam["gige"] = {"low": "cam-low", "high": "cam-high", "gain": 3.0, "roi_offset_px": [8, 8],
                   "packet_size": 1500}
    cam["registration"]["principal_point_px"] = [512.0, 384.0]
    cam["registration"]["look_at_enu_m"] = [0.0, 0.0, 30.0]
    doc["person_zones"] = [{"id": "entrance", "min_enu_m": [-4.0, 0.0, 0.0], "max_enu_m": [4.0, 6.0, 3.0]}]
    lamps = [s["id"] for s in doc["light_sources"] if s["kind"] == "lamp"]
    doc["lamps"] = {"driver": lamp_driver, **LAMP_DRIVERS[lamp_driver], "confirm_timeout_s": 10.0,
                    "channels": {lamp: i for i, lamp in enumerate(lamps)}}
    return parse_config(doc, SOURCE).model_dump(mode="json")  # every default written out


def maximal_field_config() -> dict:
    """The maximal configuration with its heliostats in a field file (tests/data/field): one
    design, a bus of each kind."""
    doc = maximal_config()
    helios = doc.pop("heliostats")
    doc["field"] = {"file": str(REPO / "tests" / "data" / "field" / "three.csv"),
                    "kinematics": {"aa39": {"mirror": helios[0]["mirror"], "axes": helios[0]["axes"]}},
                    "buses": {"rs485": {"kind": "serial", "device": "/dev/ttyUSB0", "baud": 115200},
                              "gateway": {"kind": "modbus-tcp", "host": "127.0.0.1", "port": 1502},
                              "rtu": {"kind": "modbus-rtu", "device": "/dev/ttyUSB1", "baud": 19200}}}
    out = parse_config(doc, SOURCE).model_dump(mode="json")
    del out["heliostats"]  # they are the file's
    return out


MAXIMALS = [maximal_config(driver) for driver in LAMP_DRIVERS] + [maximal_field_config()]
MAXIMAL = MAXIMALS[0]


def holding(key: NumericKey) -> dict:
    """A copy of the first maximal configuration (one per lamp driver) that holds ``key``."""
    for doc in MAXIMALS:
        try:
            locate(doc, key)
        except AssertionError:
            continue
        return copy.deepcopy(doc)
    raise AssertionError(f"{key.path}: not in any maximal configuration (add it to maximal_config)")
_OP = re.compile(r"\.?([^.\[(]+)|\[(\d*)\]|\(([^)]+)\)")


def locate(doc: dict, key: NumericKey) -> tuple[object, object, str]:
    """(container, index, key path as the error message writes it) of one instance of ``key``
    in ``doc``: the first list entry (of the right ``kind``) that holds it."""
    ops = []
    for name, index, kind in _OP.findall(key.path):
        ops.append(("any", None) if name == "<key>" else ("key", name) if name
                   else ("kind", kind) if kind else ("index", int(index) if index else None))
    found = _find(doc, ops, "")
    assert found is not None, f"{key.path}: not in the maximal configuration (add it to maximal_config)"
    return found


def _find(node, ops, where):
    op, arg = ops[0]
    if op == "kind":  # the entry type a kind (or driver) selects: the node itself must be of that kind
        of_kind = isinstance(node, dict) and arg in (node.get("kind"), node.get("driver"))
        return _find(node, ops[1:], where) if of_kind else None
    if op in ("key", "any"):
        if not isinstance(node, dict):
            return None
        candidates = [arg] if op == "key" else list(node)
        candidates = [c for c in candidates if node.get(c) is not None]
    else:
        if not isinstance(node, list):
            return None
        candidates = [arg] if arg is not None else list(range(len(node)))
    for c in candidates:
        here = f"{where}[{c}]" if op == "index" else f"{where}.{c}" if where else c
        if len(ops) == 1:
            return node, c, here
        found = _find(node[c], ops[1:], here)
        if found is not None:
            return found
    return None


def bad_values(key: NumericKey) -> list[float]:
    values = [math.nan, math.inf, -math.inf, 1e308, -1e308]
    step = 1 if key.integer else max(abs(key.lower or 0), abs(key.upper or 0), 1.0) * 1e-6
    values.append(key.lower if key.lower_open else key.lower - step)
    values.append(key.upper if key.upper_open else key.upper + step)
    return values


def test_the_maximal_configurations_are_valid():
    for doc in MAXIMALS:
        parse_config(copy.deepcopy(doc), SOURCE)


@pytest.mark.parametrize("key", KEYS, ids=[k.path for k in KEYS])
def test_every_numeric_key_has_both_bounds_and_is_in_the_maximal_configuration(key):
    assert key.lower is not None and key.upper is not None, f"{key.path}: needs a lower and an upper bound"
    assert math.isfinite(key.lower) and math.isfinite(key.upper) and key.lower < key.upper
    holding(key)


@pytest.mark.parametrize("key", KEYS, ids=[k.path for k in KEYS])
def test_non_finite_and_out_of_range_values_are_refused_naming_the_key(key):
    for value in bad_values(key):
        doc = holding(key)
        container, index, path = locate(doc, key)
        container[index] = value
        with pytest.raises(ConfigError) as exc:
            parse_config(doc, SOURCE)
        assert str(exc.value).startswith(f"{SOURCE}: {path}: "), f"{key.path} = {value}: {exc.value}"


def test_the_walk_finds_keys_nested_in_tuples_unions_and_mappings():
    paths = {k.path for k in KEYS}
    assert {"heliostats[].position_enu_m[0]", "light_sources[](lamp).diameter_m",
            "heliostats[].link(modbus-rtu).baud", "camera.registration.fiducials_enu_m[][2]",
            "calibration.model.prior_sigma.<key>", "site.delta_t_s"} <= paths
    assert len(KEYS) >= 100


def range_table() -> str:
    rows = ["| key | type | range |", "| --- | --- | --- |"]
    rows += [f"| `{k.path}` | {'integer' if k.integer else 'number'} | {k.range_text()} |" for k in KEYS]
    return "\n".join(rows)


def test_docs_state_the_range_of_every_numeric_key():
    text = (REPO / "docs" / "configuration.md").read_text(encoding="utf-8")
    assert range_table() in text, ("docs/configuration.md: the table of numeric keys differs from the "
                                   "schema; regenerate it with: python tests/test_config_ranges.py")


def test_a_nan_in_the_file_is_refused_at_load_with_exit_2_before_anything_runs(tmp_path):
    text = Path(PACKAGED_CONFIG).read_text(encoding="utf-8").replace("temperature_c: 15.0",
                                                                       "temperature_c: .nan")
    bad = tmp_path / "nan.yaml"
    bad.write_text(text, encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "controller.cli", "sun", "--config", str(bad),
                        "--time", "2026-06-21T12:00:00Z"], capture_output=True, text=True, cwd=tmp_path,
                       timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines() == [f"heliocal sun: error: {bad}: site.temperature_c: Input should be a "
                                     "finite number"]
    assert r.stdout == ""


if __name__ == "__main__":
    print(range_table())
