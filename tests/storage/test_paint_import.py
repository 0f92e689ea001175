"""``heliocal import paint`` (issue 44, item 4): the real PAINT records of tests/data/real/paint-field
into a store, then the product's commands on them; re-import; bad files; a wrong properties file."""

from __future__ import annotations

import json
import math
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from controller.calibration.night.planner import plan_field
from controller.config import load_config
from controller.geometry.aiming import aim_normal
from controller.geometry.frames import wgs84_to_enu
from controller.geometry.paint_io import kinematics_from_properties, read_towers
from controller.storage.db import open_existing
from tests.conftest import run_cli

FIELD = Path(__file__).resolve().parents[1] / "data" / "real" / "paint-field"


def raw(folder: Path) -> dict[str, dict[str, dict]]:
    """Every record of ``folder`` as parsed JSON: heliostat -> record id -> record."""
    return {p.name: {f.name.split("_")[0]: json.loads(f.read_text())
                     for f in (p / "calibration").glob("*.json")} for p in folder.iterdir() if p.is_dir()}


def subset(tmp_path: Path, ids: list[str]) -> Path:
    """A PAINT folder holding heliostats ``ids`` of the shared one, its times and targets."""
    folder = tmp_path / "paint"
    folder.mkdir()
    for hid in ids:
        shutil.copytree(FIELD / hid, folder / hid)
    for name in ("timestamps.json", "tower-measurements.json"):
        shutil.copy(FIELD / name, folder / name)
    return folder


def import_json(folder: Path, db: Path, *extra: str) -> tuple[int, dict | str]:
    code, out, err = run_cli(["import", "paint", str(folder), "--db", str(db), *extra, "--json"])
    return code, json.loads(out) if code == 0 else err + out


def count(db: Path, table: str) -> int:
    with sqlite3.connect(db) as c:
        return c.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0]


def test_the_shared_folder_imports_and_refit_and_aim_work_on_it(tmp_path):
    db = tmp_path / "field.db"
    code, r = import_json(FIELD, db)
    assert code == 0, r
    records = raw(FIELD)
    times = json.loads((FIELD / "timestamps.json").read_text())
    timed = {h: [i for i in rs if f"{h}_{i}" in times] for h, rs in records.items()}
    assert r["imported"] == sum(map(len, timed.values())) == count(db, "measurements")
    assert r["campaign"] == "paint-import-1" and r["config_written"] and r["refused"] == {}
    for hid, rs in records.items():
        h = r["heliostats"][hid]
        assert h["imported"] == len(timed[hid]) and sorted(h["no_time"]) == sorted(set(rs) - set(timed[hid]))
        assert sorted(h["helios_only"]) == sorted(i for i, d in rs.items() if "UTIS" not in d["focal_spot"])
        assert h["outside_soft_limits"] == h["outside_triangle"] == 0

    # The configuration written beside the store is the folder's field: the nominal kinematics
    # it gives misses each measured normal (bisector of heliostat→sun and heliostat→spot) as the
    # properties file read by the PAINT reader does.
    cfg = load_config(tmp_path / "field.config.yaml")
    assert r["config"] == str(tmp_path / "field.config.yaml")
    assert {h.id for h in cfg.heliostats} == set(records)
    towers = read_towers(FIELD / "tower-measurements.json")
    for hid in ("BE61", "BK20"):
        kin = kinematics_from_properties(json.loads((FIELD / hid / f"{hid}_properties.json").read_text()),
                                         towers.origin_wgs84, hid)
        miss = []
        for rid in timed[hid]:
            d = records[hid][rid]
            mp = d["motor_position"]
            steps = (mp["axis_2_motor_position"], mp["axis_1_motor_position"])  # (azimuth, elevation)
            az, el = math.radians(180.0 - d["sun_azimuth"]), math.radians(d["sun_elevation"])
            sun = [math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)]
            spot = d["focal_spot"].get("UTIS", d["focal_spot"].get("HeliOS"))
            measured = aim_normal(sun, kin.mirror_center(*steps), wgs84_to_enu(*spot, *towers.origin_wgs84))
            miss.append(math.acos(min(1.0, float(kin.normal(*steps) @ measured))) * 1e3)
        assert r["heliostats"][hid]["nominal_miss_mrad"] == pytest.approx(np.median(miss), abs=0.02)

    # The product's commands on the real field: refit (two heliostats, to stay fast), then aim.
    c = str(tmp_path / "field.config.yaml")
    code, out, err = run_cli(["model", "refit", "--config", c, "--db", str(db), "--heliostats", "BF17,BK20",
                              "--workers", "1", "--json"])
    assert code == 0, err
    assert json.loads(out)["refitted"] == 2 and json.loads(out)["measurements"] == len(timed["BF17"]) + 8
    code, out, err = run_cli(["aim", "--config", c, "--db", str(db), "--heliostat", "BK20", "--time",
                              "2024-06-21T12:00:00+00:00", "--json"])
    assert code == 0, err
    aim = json.loads(out)
    assert aim["model"]["n_measurements"] == len(timed["BK20"])
    ax = cfg.heliostat("BK20").axes
    assert ax.azimuth.soft_limits.min_steps <= aim["az_steps"] <= ax.azimuth.soft_limits.max_steps
    assert ax.elevation.soft_limits.min_steps <= aim["el_steps"] <= ax.elevation.soft_limits.max_steps
    # The planner reads the field and its refitted models; with the sun only (no lamp written in
    # yet) it says so for each heliostat, with the daytime error its model predicts.
    with open_existing(db) as store:
        models = store.latest_models(["BF17", "BK20"])
    plan = plan_field(cfg, models, "next", workers=1)
    assert plan.items == [] and {u.heliostat_id for u in plan.unmeasurable} == {"BF17", "BK20"}
    assert all("no lamp" in u.why and 0 < u.predicted_mrad < 100 for u in plan.unmeasurable)


def test_an_import_exports_back_and_a_reimport_adds_only_new_records(tmp_path):
    folder = subset(tmp_path, ["BK20", "BG29"])
    held = [p.name for p in sorted((folder / "BK20" / "calibration").glob("*.json"))[-2:]]
    for name in held:
        (folder / "BK20" / "calibration" / name).rename(tmp_path / name)
    db = tmp_path / "f.db"
    code, first = import_json(folder, db)
    assert code == 0, first
    n = first["imported"]
    # The PAINT export of the imported campaign gives back each record: steps, target, sun, spot
    # under its own method, and its time.
    code, out, err = run_cli(["export", "--db", str(db), "--format", "paint", "--out", str(tmp_path / "x"),
                              "--campaign", "paint-import-1"])
    assert code == 0, err
    records = raw(folder)
    times = json.loads((folder / "timestamps.json").read_text())
    back = [json.loads(p.read_text()) for p in sorted((tmp_path / "x").glob("BK20-*.json"))]
    assert len(back) == len(records["BK20"])  # the held-back records are not in the folder now
    for e in back:
        rid = e["heliocal"]["paint_record_id"]
        d = records["BK20"][rid]
        assert e["motor_position"] == d["motor_position"] and e["target_name"] == d["target_name"]
        assert e["sun_azimuth"] == pytest.approx(d["sun_azimuth"], abs=1e-9)
        assert e["sun_elevation"] == pytest.approx(d["sun_elevation"], abs=1e-9)
        (method, spot), = e["focal_spot"].items()
        assert method == ("UTIS" if "UTIS" in d["focal_spot"] else "HeliOS")
        assert spot == pytest.approx(d["focal_spot"][method], abs=1e-9)
        assert e["heliocal"]["measured_utc"][:19] == times[f"BK20_{rid}"][:19]

    code, again = import_json(folder, db)
    assert code == 0, again
    assert again["imported"] == 0 and again["already_imported"] == n and again["campaign"] is None
    assert again["config_sha256"] == first["config_sha256"] and not again["config_written"]
    assert count(db, "measurements") == n and count(db, "campaigns") == 1
    for name in held:
        (tmp_path / name).rename(folder / "BK20" / "calibration" / name)
    code, more = import_json(folder, db)
    assert code == 0, more
    assert more["imported"] == 2 and more["campaign"] == "paint-import-2"
    assert count(db, "measurements") == n + 2
    assert more["heliostats"]["BK20"]["imported"] == 2 and more["heliostats"]["BG29"]["imported"] == 0

    changed = held[0]
    rec = folder / "BK20" / "calibration" / changed
    d = json.loads(rec.read_text())
    d["motor_position"]["axis_1_motor_position"] += 10
    rec.write_text(json.dumps(d))
    code, err = import_json(folder, db)
    assert code == 2 and changed in err and "imported" in err and len(err.strip().splitlines()) == 1
    assert count(db, "measurements") == n + 2 and count(db, "campaigns") == 2


def test_an_existing_configuration_is_used_as_it_is_and_never_overwritten(tmp_path):
    folder = subset(tmp_path, ["BK20", "BG29"])
    code, first = import_json(folder, tmp_path / "a.db")
    assert code == 0, first
    config = tmp_path / "a.config.yaml"
    code, r = import_json(folder, tmp_path / "b.db", "--config", str(config))
    assert code == 0, r
    assert r["imported"] == first["imported"] == count(tmp_path / "b.db", "measurements")
    assert r["config"] == str(config) and not r["config_written"]
    assert r["config_sha256"] == first["config_sha256"]
    text = config.read_text()
    shutil.copytree(FIELD / "BF17", folder / "BF17")  # a heliostat the configuration does not have
    for args in ([], ["--config", str(config)]):
        code, err = import_json(folder, tmp_path / "a.db", *args)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert ("a.config.yaml: exists and is not the field configuration" in err if not args
                else "BF17_properties.json: heliostat 'BF17' is not in" in err)
    assert config.read_text() == text and count(tmp_path / "a.db", "measurements") == first["imported"]


def _no_utis_nor_helios(d: dict) -> None:
    d["focal_spot"] = {}


def _no_axis_1(d: dict) -> None:
    del d["motor_position"]["axis_1_motor_position"]


def _unknown_target(d: dict) -> None:
    d["target_name"] = "no_such_target"


@pytest.mark.parametrize("spoil,named", [(_no_utis_nor_helios, "focal_spot.UTIS"),
                                         (_no_axis_1, "axis_1_motor_position"),
                                         (_unknown_target, "no_such_target")])
def test_a_bad_record_is_named_and_nothing_is_written(tmp_path, spoil, named):
    folder = subset(tmp_path, ["BK20"])
    db = tmp_path / "f.db"
    assert import_json(folder, db)[0] == 0
    bad = sorted((folder / "BK20" / "calibration").glob("*.json"))[3]
    d = json.loads(bad.read_text())
    spoil(d)
    bad.write_text(json.dumps(d))
    shutil.copytree(FIELD / "BG29", folder / "BG29")  # new records, not imported either
    before = (db.read_bytes(), (tmp_path / "f.config.yaml").read_bytes())
    code, err = import_json(folder, db)
    assert code == 2 and len(err.strip().splitlines()) == 1 and bad.name in err and named in err, err
    assert "Traceback" not in err
    assert (db.read_bytes(), (tmp_path / "f.config.yaml").read_bytes()) == before


def test_bad_times_properties_and_layout_are_named_before_anything_is_created(tmp_path):
    folder = subset(tmp_path, ["BK20"])
    ts = tmp_path / "ts.json"
    ts.write_text(json.dumps({"BK20_273973": "yesterday"}))
    code, err = import_json(folder, tmp_path / "a.db", "--timestamps", str(ts))
    assert code == 2 and "ts.json" in err and "BK20_273973" in err
    props = folder / "BK20" / "BK20_properties.json"
    d = json.loads(props.read_text())
    del d["kinematics_properties"]["actuators"][1]["pivot_radius"]
    props.write_text(json.dumps(d))
    code, err = import_json(folder, tmp_path / "a.db")
    assert code == 2 and "BK20_properties.json" in err and "pivot_radius" in err
    props.unlink()
    code, err = import_json(folder, tmp_path / "a.db")
    assert code == 2 and "BK20_properties.json: missing" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paint", "ts.json"]  # no store, no configuration


def test_a_properties_file_that_leaves_the_actuator_triangle_is_imported_with_a_note(tmp_path):
    """The README's wrong properties file (strokes of 0.236 m, −0.22 rad) on BH58: its soft limits
    are narrowed to where the stroke closes the triangle, the records beyond are counted, and
    aim only gives steps inside them. A heliostat whose stroke never closes it is refused."""
    folder = subset(tmp_path, ["BH58", "BK20"])
    props = folder / "BH58" / "BH58_properties.json"
    d = json.loads(props.read_text())
    for a in d["kinematics_properties"]["actuators"]:
        a["initial_stroke_length"] = 0.236
    d["kinematics_properties"]["actuators"][0]["initial_angle"] = -0.22
    props.write_text(json.dumps(d))
    props = folder / "BK20" / "BK20_properties.json"
    d = json.loads(props.read_text())
    d["kinematics_properties"]["actuators"][0]["initial_stroke_length"] = 0.7
    props.write_text(json.dumps(d))
    db = tmp_path / "f.db"
    code, r = import_json(folder, db)
    assert code == 0, r
    assert "BK20_properties.json" in r["refused"]["BK20"] and "actuators[0]" in r["refused"]["BK20"]
    assert r["heliostats"]["BK20"]["imported"] == 0 and r["imported"] == r["heliostats"]["BH58"]["imported"]
    h = r["heliostats"]["BH58"]
    steps = [json.loads(p.read_text())["motor_position"]["axis_2_motor_position"]
             for p in (folder / "BH58" / "calibration").glob("*.json")]
    cfg = load_config(tmp_path / "f.config.yaml")
    az = cfg.heliostat("BH58").axes.azimuth
    reach = (0.3191 + 0.340771 - 0.236) * az.increment  # longest stroke of the triangle, in steps
    assert az.soft_limits.max_steps == pytest.approx(reach, abs=2) and "azimuth" in h["note"]
    assert h["outside_triangle"] == h["outside_soft_limits"] == sum(s > reach for s in steps) > 0
    assert [x.id for x in cfg.heliostats] == ["BH58"]
    code, out, err = run_cli(["aim", "--config", str(tmp_path / "f.config.yaml"), "--db", str(db),
                              "--heliostat", "BH58", "--sun-az", "150", "--sun-el", "40", "--json"])
    if code in (0, 5):  # 5: no model yet, the nominal kinematics' steps (said on stderr)
        assert az.soft_limits.min_steps <= json.loads(out)["az_steps"] <= az.soft_limits.max_steps
    else:
        assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
