"""The ``lamps:`` section: valid panels load; every broken rule is one ConfigError naming the
file and the key."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from controller.config import load_config, parse_config
from controller.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
LAMPS = ["lamp", "lamp-west", "lamp-east", "lamp-low", "lamp-far-west", "lamp-far-east", "lamp-tower-mid"]


@pytest.fixture(scope="module")
def demo() -> dict:
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    data["lamps"] = {"driver": "modbus-tcp", "host": "10.0.4.20", "port": 502, "unit": 3,
                     "channels": {**{lamp: i for i, lamp in enumerate(LAMPS)}, "fiducials:tower-lower": 9}}
    return data


def test_every_driver_loads_with_its_defaults(demo, tmp_path):
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(demo))
    cfg = load_config(path)
    assert cfg.lamps.driver == "modbus-tcp" and cfg.lamps.channels["fiducials:tower-lower"] == 9
    assert cfg.lamps.confirm_timeout_s == 10 and cfg.lamps.timeout_s == 1
    channels = demo["lamps"]["channels"]
    rtu = {**demo, "lamps": {"driver": "modbus-rtu", "device": "/dev/ttyUSB1", "channels": channels}}
    assert parse_config(rtu).lamps.baud == 19200
    cmd = {**demo, "lamps": {"driver": "command", "command": ["/usr/local/bin/lamps", "--site", "x"],
                             "channels": channels, "confirm_timeout_s": 30}}
    assert parse_config(cmd).lamps.command[0] == "/usr/local/bin/lamps"
    assert parse_config({k: v for k, v in demo.items() if k != "lamps"}).lamps is None


def _broken(demo: dict, change) -> str:
    data = copy.deepcopy(demo)
    change(data["lamps"], data)
    with pytest.raises(ConfigError) as e:
        parse_config(data, "plant.yaml")
    assert e.value.exit_code == 2
    return str(e.value)


@pytest.mark.parametrize("change, said", [
    (lambda c, d: c["channels"].pop("lamp-west"),
     "plant.yaml: lamps.channels: lamp 'lamp-west' (calibration.light_source or calibration.lamps) "
     "has no channel"),
    (lambda c, d: c["channels"].update({"lamp-north": 12}),
     "plant.yaml: lamps.channels.lamp-north: 'lamp-north' is neither the id of a lamp of light_sources nor "
     "fiducials:<target id>"),
    (lambda c, d: c["channels"].update({"sun": 12}), "lamps.channels.sun: 'sun' is neither"),
    (lambda c, d: c["channels"].update({"fiducials:roof": 12}),
     "plant.yaml: lamps.channels.fiducials:roof: 'roof' is not the id of any entry of targets"),
    (lambda c, d: c["channels"].update({"lamp-east": 0}),
     "plant.yaml: lamps.channels: lamp-east: index 0 is already the channel of 'lamp'"),
    (lambda c, d: c["channels"].update({"lamp-east": -1}),
     "plant.yaml: lamps.channels.lamp-east: Input should be greater than or equal to 0"),
    (lambda c, d: c["channels"].update({"lamp-east": 65536}),
     "lamps.channels.lamp-east: Input should be less"),
    (lambda c, d: c["channels"].update({"lamp-east": True}),
     "lamps.channels.lamp-east: Input should be a valid"),
    (lambda c, d: c.update(port=0), "plant.yaml: lamps.port: Input should be greater than or equal to 1"),
    (lambda c, d: c.update(port=70000), "lamps.port: Input should be less than or equal to 65535"),
    (lambda c, d: c.update(unit=248), "lamps.unit: Input should be less than or equal to 247"),
    (lambda c, d: c.update(timeout_s=float("nan")), "lamps.timeout_s: Input should be"),
    (lambda c, d: c.update(confirm_timeout_s=float("inf")), "lamps.confirm_timeout_s: Input should be"),
    (lambda c, d: c.update(confirm_timeout_s=0), "lamps.confirm_timeout_s: Input should be greater"),
    (lambda c, d: c.update(driver="plc"), "lamps: Input tag 'plc' found using 'driver' does not match"),
    (lambda c, d: c.update(hots="x"), "lamps.hots: unknown key"),
    (lambda c, d: c.pop("host"), "plant.yaml: lamps.host: required key is missing"),
    (lambda c, d: c.update(channels={}), "lamps.channels: Dictionary should have at least 1 item"),
    (lambda c, d: (c.clear(), c.update(driver="command", command=[], channels={"lamp": 0})),
     "plant.yaml: lamps.command: Tuple should have at least 1 item"),
    (lambda c, d: c.update(host="a" * 64 + ".example"),
     "plant.yaml: lamps.host: 'aaaa"),
    (lambda c, d: c.update(host="panel 4.plant"), "is neither an IP address nor a host name"),
    (lambda c, d: c.update(host="panel..plant"), "is neither an IP address nor a host name"),
    (lambda c, d: (c.clear(), c.update(driver="command", command=["/usr/bin/lamps", "a\0b"],
                                       channels={"lamp": 0})),
     "plant.yaml: lamps.command: element 1 holds a NUL character"),
    (lambda c, d: (c["channels"].update({"fiducials:tower-target": 8}),
                       d["camera"]["registration"].update(lamp_command=["/usr/bin/fid"])),
     "lamps.channels.fiducials:tower-target: the fiducial lamps of 'tower-target' are switched by "
     "camera.registration.lamp_command too; configure one of them"),
])
def test_a_broken_lamps_section_names_the_file_and_key(demo, change, said):
    assert said in _broken(demo, change)


def test_the_fiducial_rule_reads_the_target_s_own_camera(demo):
    # tower-lower has its own registering camera: the top-level camera's lamp_command is
    # tower-target's, so a panel channel for tower-lower's fiducials does not clash with it.
    data = copy.deepcopy(demo)
    lower = next(t for t in data["targets"] if t["id"] == "tower-lower")
    assert lower["camera"]["registration"] is not None
    data["camera"]["registration"]["lamp_command"] = ["/usr/bin/fid"]
    assert parse_config(data, "plant.yaml").lamps.channels["fiducials:tower-lower"] == 9
