"""A model is never applied to the wrong field (issue 40; docs/campaigns.md, "A model and its
field"). A calibration campaign on the simulated plant records what its heliostat's model was
fitted on; ``aim``, ``campaign night``, ``export``, ``report campaign`` and the console refuse a
configuration whose heliostat moved, whose kinematics or target changed (exit 2, one line naming
the heliostat or target and the key) unless ``--accept-field-change``; ``aim`` without
``--config`` does not fall back to the demo plant on another field's database; ``aim`` without a
model says so (exit 5)."""

from __future__ import annotations

import json
import sqlite3

import pytest
import yaml

from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.planned import calibration_night
from controller.commands.field import open_store
from controller.commands.simulated import simulated_field
from controller.config import load_config
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST, small_demo_data
from tests.conftest import run_cli

HID = "H02"
SUN = ["--sun-az", "180", "--sun-el", "45", "--json"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A database whose H02 has a model fitted on the small demo plant, and that plant's file."""
    tmp = tmp_path_factory.mktemp("field-change")
    data = small_demo_data()
    path = tmp / "plant.yaml"
    path.write_text(yaml.safe_dump(data))
    store = open_store(tmp / "c.db")
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=4)
    with simulated_field(load_config(path), str(path), store, tmp / "sim", [HID], settings, night=0,
                         library=None) as fs:
        calibration_night(fs.book, Campaign(fs.field, CampaignOptions(name="n"), heliostat_ids=[HID]))
    assert store.latest_model(HID) is not None
    store.close()
    return tmp, data, path, tmp / "c.db"


def _variant(tmp, data: dict, name: str, change) -> str:
    doc = yaml.safe_load(yaml.safe_dump(data))
    change(doc)
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump(doc))
    return str(p)


def _heliostat(doc: dict, hid: str = HID) -> dict:
    return next(h for h in doc["heliostats"] if h["id"] == hid)


def _refused(code: int, out: str, err: str, *words: str) -> None:
    """Exit 2 with one line (stderr; with --json the error object on stdout) holding ``words``."""
    line = json.loads(out)["error"] if out.strip() else err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) <= 1, err
    for w in words:
        assert w in line, line


def test_aim_applies_the_model_to_its_own_field_and_refuses_another(fitted):
    tmp, data, path, db = fitted
    code, out, err = run_cli(["aim", "--config", str(path), "--db", str(db), "--heliostat", HID, *SUN])
    assert code == 0, err
    same = json.loads(out)
    assert same["model"] is not None

    def moved(doc):
        _heliostat(doc)["position_enu_m"][0] += 80.0

    moved_cfg = _variant(tmp, data, "moved", moved)
    code, out, err = run_cli(["aim", "--config", moved_cfg, "--db", str(db), "--heliostat", HID, *SUN])
    _refused(code, out, err, f"heliostat {HID}", "position_enu_m", "--accept-field-change")
    assert json.loads(out)["ok"] is False  # no steps
    code, out, err = run_cli(["aim", "--config", moved_cfg, "--db", str(db), "--heliostat", HID,
                              "--accept-field-change", *SUN])
    assert code == 0 and "1 difference(s) accepted" in err
    assert json.loads(out)["az_steps"] != same["az_steps"]  # the operator's choice, said on stderr

    def kinematics(doc):  # the axes are one YAML anchor shared by every heliostat: copy H02's
        h = _heliostat(doc)
        az = dict(h["axes"]["azimuth"], increment=h["axes"]["azimuth"]["increment"] * 1.01)
        h["axes"] = {**h["axes"], "azimuth": az}

    code, out, err = run_cli(["aim", "--config", _variant(tmp, data, "kin", kinematics), "--db", str(db),
                              "--heliostat", HID, *SUN])
    _refused(code, out, err, f"heliostat {HID}", "axes.azimuth.increment")

    def target(doc):
        doc["targets"][0]["center_enu_m"][2] += 1.0

    code, out, err = run_cli(["aim", "--config", _variant(tmp, data, "target", target), "--db", str(db),
                              "--heliostat", HID, *SUN])
    _refused(code, out, err, f"target {data['targets'][0]['id']}", "center_enu_m")


def test_aim_without_a_model_or_without_config_says_so(fitted):
    tmp, data, path, db = fitted
    other = next(h["id"] for h in data["heliostats"] if h["id"] != HID)
    code, out, err = run_cli(["aim", "--config", str(path), "--db", str(db), "--heliostat", other, *SUN])
    assert code == 5 and json.loads(out)["model"] is None
    assert f"{other} has no fitted model" in err
    # No --config: the packaged demo plant is not the configuration this database was made with.
    code, out, err = run_cli(["aim", "--db", str(db), "--heliostat", HID, *SUN])
    _refused(code, out, "", "was made with the configuration", "pass --config FILE")
    assert "using configuration" in err  # which default it was, said as before


def test_every_command_reading_models_refuses_a_moved_heliostat(fitted, tmp_path):
    tmp, data, path, db = fitted

    def moved(doc):
        _heliostat(doc)["position_enu_m"][1] += 80.0

    moved_cfg = _variant(tmp, data, "moved-north", moved)
    for argv in (["campaign", "night", "--simulate", "--heliostats", HID],
                 ["campaign", "run", "--simulate", "--heliostats", HID],
                 ["console", "--simulate", "--heliostats", HID, "--port", "0"],
                 ["export", "--format", "paint", "--out", str(tmp_path / "paint")]):
        code, out, err = run_cli([*argv, "--config", moved_cfg, "--db", str(db)])
        _refused(code, out, err, f"heliostat {HID}", "position_enu_m")
    assert not (tmp_path / "paint").exists()
    # The report predicts with the campaign's recorded configuration file: moved since, refused.
    saved = path.read_text()
    try:
        path.write_text(open(moved_cfg).read())
        code, out, err = run_cli(["report", "campaign", "--db", str(db), "--out", str(tmp_path / "r")])
        _refused(code, out, err, f"heliostat {HID}", "position_enu_m")
        assert not (tmp_path / "r").exists()
        assert run_cli(["report", "campaign", "--db", str(db), "--out", str(tmp_path / "r"),
                        "--accept-field-change"])[0] == 0
    finally:
        path.write_text(saved)


def test_a_model_recorded_before_fingerprints_is_checked_by_its_configuration(fitted, tmp_path):
    tmp, data, path, db = fitted
    old = tmp_path / "old.db"
    with sqlite3.connect(db) as src, sqlite3.connect(old) as dst:
        src.backup(dst)
        dst.execute("DELETE FROM field_prints")
    code, _, err = run_cli(["aim", "--config", str(path), "--db", str(old), "--heliostat", HID, *SUN])
    assert code == 0, err  # the configuration its campaign recorded: the same file

    def comment(doc):
        doc["site"]["name"] += " (resurveyed)"

    code, out, err = run_cli(["aim", "--config", _variant(tmp, data, "renamed", comment), "--db", str(old),
                              "--heliostat", HID, *SUN])
    _refused(code, out, err, f"heliostat {HID}", "another configuration", "no fingerprint")
