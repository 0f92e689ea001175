"""SQLite record store: schema/migrations, WAL, atomic per-heliostat records, PAINT export."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from controller.calibration.records import (
    CorrectionRecord,
    ImageRecord,
    MeasurementRecord,
    ModelRecord,
    RunRecord,
)
from controller.errors import InputError
from controller.geometry.frames import wgs84_to_enu
from controller.storage.db import CampaignStore
from controller.storage.paint.export import export_paint, paint_azimuth
from controller.storage.schema import MIGRATIONS, SCHEMA_VERSION


def _run(hid: str, n_meas: int = 2, sha: str | None = "ab" * 32) -> RunRecord:
    ms = [
        MeasurementRecord(
            iteration=i + 1,
            az_steps=1000 + i,
            el_steps=2000 + i,
            source_dir=(0.0, -0.6, 0.8),
            source_az_deg=180.0,
            source_el_deg=53.13,
            aim_enu=(0.0, 0.0, 30.0),
            plant_time_s=10.0 + i,
            centroid_enu=(0.1 / (i + 1), 0.0, 30.05),
            error_mrad=2.0 / (i + 1),
            matched_label="wind-load",
            match_distance=0.5,
            images=[ImageRecord("low", f"/x/{hid}-{i}.png", sha, (0.01, 0.02))],
        )
        for i in range(n_meas)
    ]
    return RunRecord(
        hid,
        0,
        "calibrated",
        "done",
        n_meas,
        0.0,
        20.0,
        error_before_mrad=2.0,
        error_after_mrad=1.0,
        measurements=ms,
        corrections=[CorrectionRecord(1, "fine", 0.01, -0.02, 5, -9)],
        model=ModelRecord({"az_offset_mrad": 1.5}, {"az_offset_mrad": 0.1}, 0.05, n_meas),
    )


@pytest.fixture
def store(tmp_path):
    with CampaignStore(tmp_path / "c.db") as s:
        yield s


def _open(store, name="night-1", sha="0" * 64, queue=("H1", "H2")):
    return store.open_campaign(
        name,
        config_path="c.yaml",
        config_sha256=sha,
        light_source="lamp",
        target="t",
        queue=list(queue),
        meta={"site": [37.0, -2.4, 500.0]},
    )


def test_schema_version_and_wal(store):
    assert store.schema_version == SCHEMA_VERSION == len(MIGRATIONS)
    assert store._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    tables = {r[0] for r in store._db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"campaigns", "heliostat_runs", "measurements", "corrections", "model_params", "images"} <= tables


def test_reopen_keeps_data_and_refuses_newer_schema(tmp_path):
    p = tmp_path / "c.db"
    with CampaignStore(p) as s:
        cid, resumed = _open(s)
        assert not resumed
        s.record_run(cid, _run("H1"))
    with CampaignStore(p) as s:
        assert s.count("heliostat_runs") == 1
        s._db.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    with pytest.raises(InputError, match="newer"):
        CampaignStore(p)


def test_not_a_database(tmp_path):
    p = tmp_path / "junk.db"
    p.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(InputError, match="junk.db"):
        CampaignStore(p)


def test_run_is_written_atomically(store):
    cid, _ = _open(store)
    with pytest.raises(sqlite3.IntegrityError):
        store.record_run(cid, _run("H1", sha=None))  # images.sha256 NOT NULL fails after the run row
    for table in ("heliostat_runs", "measurements", "corrections", "model_params", "images"):
        assert store.count(table) == 0, table
    store.record_run(cid, _run("H1"))
    assert (store.count("heliostat_runs"), store.count("measurements"), store.count("images")) == (1, 2, 2)


def test_no_duplicate_heliostat_record(store):
    cid, _ = _open(store)
    store.record_run(cid, _run("H1"))
    with pytest.raises(sqlite3.IntegrityError):
        store.record_run(cid, _run("H1"))
    assert store.count("heliostat_runs") == 1 and store.count("measurements") == 2
    assert store.done_heliostats(cid) == {"H1"}


def test_resume_needs_same_config(store):
    cid, resumed = _open(store)
    cid2, resumed2 = _open(store)
    assert (cid2, resumed2) == (cid, True)
    with pytest.raises(InputError, match="different configuration"):
        _open(store, sha="1" * 64)


def test_latest_model(store):
    cid, _ = _open(store)
    store.record_run(cid, _run("H1"))
    m = store.latest_model("H1")
    assert m.params == {"az_offset_mrad": 1.5} and m.n_measurements == 2
    assert store.latest_model("H9") is None


def test_latest_models_parse_each_row_once(store, tmp_path):
    """A model row is decoded once per open store (``ModelRows``); a newer row of a heliostat
    replaces it, and another open of the file reads the same records afresh."""
    cid, _ = _open(store, queue=("H1", "H2", "H3"))
    for hid in ("H1", "H2"):
        store.record_run(cid, _run(hid))
    first = store.latest_models()
    assert sorted(first) == ["H1", "H2"]
    again = store.latest_models(["H2", "H9"])
    assert list(again) == ["H2"] and again["H2"] is first["H2"]  # not parsed again
    assert store.latest_model("H1") is first["H1"]
    newer = _run("H3")
    newer.model = ModelRecord({"az_offset_mrad": -0.5}, {"az_offset_mrad": 0.2}, 0.04, 3)
    store.record_run(cid, newer)
    with store.tx() as db:  # a second model of H1, as a refit of the field writes it
        db.execute("INSERT INTO model_params (heliostat_id, campaign_id, run_id, params_json, sigma_json, "
                   "residual_mrad, n_measurements, created_utc) SELECT heliostat_id, campaign_id, run_id, "
                   "'{\"az_offset_mrad\": 2.5}', sigma_json, residual_mrad, 7, created_utc FROM model_params "
                   "WHERE heliostat_id='H1'")
    now = store.latest_models()
    assert now["H1"].params == {"az_offset_mrad": 2.5} and now["H1"].n_measurements == 7
    assert now["H3"].params == {"az_offset_mrad": -0.5} and now["H2"] is first["H2"]
    with CampaignStore(tmp_path / "c.db", readonly=True) as other:
        fresh = other.latest_models()
        assert fresh["H2"] is not first["H2"] and fresh["H2"] == first["H2"]
        assert {h: m.params for h, m in fresh.items()} == {h: m.params for h, m in now.items()}


def test_a_model_recorded_is_read_back_as_written_without_its_row_decoded(store, tmp_path):
    """The model a run records is the record the next ask for the heliostat's latest returns (a
    night's next run of it: nothing decoded); read back afresh it is equal. A transaction that
    fails keeps nothing: the heliostat's latest model is still the one before."""
    cid, _ = _open(store, queue=("H1", "H2"))
    run = _run("H1")
    store.record_run(cid, run)
    assert store.latest_model("H1") is run.model
    with CampaignStore(tmp_path / "c.db", readonly=True) as other:
        assert other.latest_model("H1") == run.model
    again = _run("H1")  # the same heliostat twice in a campaign: refused, nothing kept
    again.model = ModelRecord({"az_offset_mrad": 9.0}, {"az_offset_mrad": 0.1}, 0.1, 5)
    with pytest.raises(sqlite3.IntegrityError):
        store.record_run(cid, again)
    assert store.latest_model("H1") is run.model


@pytest.mark.parametrize(
    "north, paint", [(265.60, -85.60), (180.0, 0.0), (90.0, 90.0), (0.0, 180.0), (270.0, -90.0)]
)
def test_paint_azimuth_convention(north, paint):
    # README of tests/data/real: record -85.60 deg <-> 265.60 deg from north; south = 0, east positive.
    assert paint_azimuth(north) == pytest.approx(paint, abs=1e-9)


def test_paint_export_round_trip(store, tmp_path):
    cid, _ = _open(store)
    store.record_run(cid, _run("H1"))
    paths = export_paint(store, tmp_path / "paint")
    assert len(paths) == 2
    rec = json.loads(paths[0].read_text())
    assert set(rec) >= {"motor_position", "target_name", "focal_spot", "sun_azimuth", "sun_elevation"}
    assert rec["motor_position"] == {"axis_1_motor_position": 2000, "axis_2_motor_position": 1000}
    assert rec["sun_azimuth"] == pytest.approx(0.0)  # light from due south
    lat, lon, alt = rec["focal_spot"]["heliocal"]
    enu = wgs84_to_enu(lat, lon, alt, 37.0, -2.4, 500.0)
    np.testing.assert_allclose(enu, [0.1, 0.0, 30.05], atol=1e-3)


def test_export_cli_missing_db(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller.cli",
            "export",
            "--db",
            str(tmp_path / "no.db"),
            "--format",
            "paint",
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "no.db" in r.stderr and "Traceback" not in r.stderr
