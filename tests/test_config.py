"""Configuration validation: each kind of bad config exits 2 with ONE line naming the file,
the key path and the rule, through ``heliocal demo --config BAD`` (and ``load_config``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from controller.cli import main
from controller.config import load_config
from controller.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "configs" / "demo.yaml"


def _demo_data() -> dict:
    # JSON round trip: plain dicts without the YAML anchors' shared objects, so one edit
    # changes one heliostat only.
    return json.loads(json.dumps(yaml.safe_load(DEMO.read_text())))


def _set(path: str, value):
    def edit(d: dict) -> None:
        *parents, last = path.split(".")
        for p in parents:
            d = d[int(p)] if isinstance(d, list) else d[p]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value
    return edit


def _drop(path: str):
    def edit(d: dict) -> None:
        *parents, last = path.split(".")
        for p in parents:
            d = d[int(p)] if isinstance(d, list) else d[p]
        del d[last]
    return edit


# (case id, edit of the demo config, expected key path, expected rule fragment)
CASES = [
    ("missing key", _drop("site.latitude_deg"), "site.latitude_deg", "required key is missing"),
    ("missing section", _drop("camera"), "camera", "required key is missing"),
    ("wrong type", _set("heliostats.2.position_enu_m", "north"), "heliostats[2].position_enu_m",
     "valid tuple"),
    ("wrong type int", _set("camera.width_px", "wide"), "camera.width_px", "valid integer"),
    ("out of range", _set("site.latitude_deg", 95), "site.latitude_deg", "less than or equal to 90"),
    ("out of range link", _set("heliostats.3.link.address", 999), "heliostats[3].link.address",
     "less than or equal to 247"),
    ("unknown key", _set("camera.colour", "blue"), "camera.colour", "unknown key"),
    ("unknown section", _set("weather", {}), "weather", "unknown key"),
    ("bad cross-reference target", _set("calibration.target", "nope"), "calibration.target",
     "'nope' is not the id of any entry of targets"),
    ("bad cross-reference source", _set("calibration.light_source", "moon"), "calibration.light_source",
     "'moon' is not the id of any entry of light_sources"),
    ("duplicate id", _set("heliostats.1.id", "H01"), "heliostats[1].id", "duplicate id 'H01'"),
    ("soft limits outside hard range", _set("heliostats.0.axes.azimuth.soft_limits.max_steps", 80000),
     "heliostats[0].axes.azimuth", "must lie inside the hard range [0, 75308]"),
    ("non-unit normal", _set("targets.0.normal", [0, 0.8, 0]), "targets[0].normal", "must be a unit vector"),
    ("unknown source kind", _set("light_sources.1.kind", "laser"), "light_sources[1]", "'laser'"),
    ("typo", _set("calibration.tolerence_mrad", 1.0), "calibration.tolerence_mrad",
     "unknown key (did you mean 'tolerance_mrad'?)"),
    ("simulation is not plant config", _set("simulation", {"seed": 1}), "simulation", "unknown key"),
    ("beyond the int32 wire range", _set("heliostats.0.axes.azimuth.max_increment", 5000000000),
     "heliostats[0].axes.azimuth.max_increment", "less than or equal to 2147483647"),
    ("stroke outside the actuator triangle", _set("heliostats.0.axes.elevation.initial_stroke_length", 0.3),
     "heliostats[0].axes.elevation", "m, outside the actuator triangle [0.0028, 0.6734] m"),
]


@pytest.mark.parametrize("case, edit, key, rule", CASES, ids=[c[0] for c in CASES])
def test_bad_config_via_demo_cli(tmp_path, capsys, case, edit, key, rule):
    data = _demo_data()
    edit(data)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert main(["demo", "--config", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"heliocal demo: error: {bad}: {key}: ")
    assert rule in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("text, fragment", [
    ("site: [unclosed\n", "line 2, column 1: invalid YAML"),
    ("site:\n\tname: x\n", "line 2, column 1: invalid YAML"),
    ("- a\n- b\n", "(top level): must be a mapping of sections, got list"),
    ("", "the configuration is empty"),
    ("site: " + "[" * 3000 + "\n", "line 1: nested deeper than 32 levels"),
    ("site:\n" + "".join("  " * i + f"k{i}:\n" for i in range(1, 60)), "nested deeper than 32 levels"),
    (b"\x89PNG\r\n\x1a\n\x00\xff", "not a text configuration (byte 0 is not UTF-8)"),
])
def test_unparsable_yaml(tmp_path, capsys, text, fragment):
    bad = tmp_path / "bad.yaml"
    if isinstance(text, bytes):
        bad.write_bytes(text)
    else:
        bad.write_text(text)
    assert main(["demo", "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and fragment in err


def test_unreadable_file(tmp_path, capsys):
    missing = tmp_path / "missing.yaml"
    assert main(["demo", "--config", str(missing)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{missing}: cannot read configuration" in err and len(err.splitlines()) == 1
    with pytest.raises(ConfigError, match="is a directory, not a regular file"):
        load_config(tmp_path)


def test_bad_config_json_error(tmp_path, capsys):
    data = _demo_data()
    data["site"]["pressure_mbar"] = -5
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert main(["demo", "--config", str(bad), "--json"]) == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    msg = json.loads(out[0])
    assert msg["ok"] is False and str(bad) in msg["error"] and "site.pressure_mbar" in msg["error"]


def test_bad_config_subprocess_exit_code(tmp_path):
    """The installed console script: exit status 2, one line on stderr, no traceback."""
    data = _demo_data()
    del data["heliostats"][0]["mirror"]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    res = subprocess.run([sys.executable, "-m", "controller.cli", "demo", "--config", str(bad)],
                         capture_output=True, text=True, timeout=60, check=False)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"heliocal demo: error: {bad}: heliostats[0].mirror: required key is missing"]


def test_demo_config_is_valid_and_x_keys_are_ignored():
    cfg = load_config(DEMO)
    assert len(cfg.heliostats) == 18
    assert cfg.light_source().kind == "lamp" and cfg.target().id == "tower-target"
    assert cfg.heliostats[0].axes.azimuth.increment == pytest.approx(154166.6667)


def test_unknown_tracking_model_term_is_refused_before_any_work(tmp_path, capsys):
    """``calibration.model.prior_sigma`` keys are checked against the model's terms before a
    campaign starts (a misspelt term would otherwise fail every fit of the night)."""
    data = _demo_data()
    data["calibration"]["model"]["prior_sigma"] = {"base_yawn_mrad": 5.0}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    assert main(["demo", "--config", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "'base_yawn_mrad'" in err
    assert not out.exists()


def test_link_none_is_a_heliostat_nothing_can_drive(tmp_path):
    """``link: none`` (a field known by its records, docs/import.md): several heliostats may have
    it; opening its drive and simulating it are refused in one ConfigError."""
    from controller.config import parse_config
    from controller.devices.drive import DriveLimits
    from controller.devices.factory import LinkPool
    from simplant.plant import SimulatedPlant

    data = _demo_data()
    for h in data["heliostats"][:2]:
        h["link"] = {"kind": "none"}
    h = parse_config(data).heliostats[1]
    with LinkPool() as pool, pytest.raises(ConfigError, match="link: none: this heliostat has no link"):
        pool.drive(h.link, DriveLimits.from_axes(h.axes))
    with pytest.raises(ConfigError, match="H01 has link: none"):
        SimulatedPlant(data, tmp_path / "run")
