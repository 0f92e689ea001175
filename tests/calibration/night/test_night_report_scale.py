"""The night's records and morning report for a field of any size, on a small one: what each
heliostat ended the night with (night_heliostats, schema v9), the heliostats with no measurable
geometry, the field map, distributions and the worst heliostats' thumbnails; lamp changes that
make every heliostat of the night safe, planned or not."""

from __future__ import annotations

import csv
import sqlite3

import pytest
import yaml

from controller.calibration.night.planner import plan_field
from controller.commands.cheap_night import calibrate_from_truth, run_cheap_night
from controller.reports import night as night_report
from controller.storage.db import CampaignStore
from controller.storage.nights import NightBook
from controller.storage.schema import MIGRATIONS
from simplant.cheap_night import CheapField, field_data
from tests.calibration.conftest import REPO


@pytest.fixture(scope="module")
def measured_night(tmp_path_factory):
    """A 16-heliostat field after night 0 (from the truth) and a planned night whose plan covers
    only half of it: the other half is in the night, and one has no model (unmeasurable)."""
    base = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    field = CheapField(field_data(base, 16, 2, 2), tmp_path_factory.mktemp("night"), speedup=1000.0)
    calibrate_from_truth(field, "field")
    ids = [h.id for h in field.cfg.heliostats]
    with CampaignStore(field.db_path, readonly=True) as store:
        models = store.latest_models()
    models[ids[-1]] = None  # as if it had been added since night 0
    plan = plan_field(field.cfg, {hid: models.get(hid) for hid in ids}, "field/night-1", night_index=1)
    half = [it for it in plan.items if it.heliostat_id in ids[::2]]
    night = run_cheap_night(field, half, "field/night-1", 8 * 3600.0, heliostat_ids=ids,
                            unmeasurable=plan.unmeasurable)
    return field, ids, plan, half, night


def test_every_heliostat_of_the_night_is_made_safe_for_each_lamp(measured_night):
    field, ids, _, half, night = measured_night
    assert night.summary.status == "finished" and len(night.measured) == len(half)
    assert all(c["checked"] == len(ids) for c in night.summary.lamp_changes)
    assert sum(1 for v in night.beams_in_view.values() for b in v if len(b) > 1) == 0


def test_the_night_records_each_heliostat_and_why_one_had_no_geometry(measured_night):
    field, ids, plan, half, night = measured_night
    assert [u["heliostat"] for u in night.summary.unmeasurable] == [ids[-1]]
    assert "no measurable geometry" in night.summary.unmeasurable[0]["why"]
    with CampaignStore(field.db_path, readonly=True) as store:
        book = NightBook(store)
        rec = next(n for n in book.nights() if n.name == "field/night-1")
        rows = {r["heliostat"]: r for r in book.heliostats(rec.id)}
        assert rec.summary["unmeasurable"] == night.summary.unmeasurable
    assert set(rows) == set(ids)
    assert rows[ids[-1]]["unmeasurable"] and rows[ids[-1]]["planned"] == 0
    for hid in ids[:-1]:
        want = sum(1 for it in half if it.heliostat_id == hid)
        assert rows[hid]["planned"] == rows[hid]["measured"] == want and not rows[hid]["unmeasurable"]
        assert rows[hid]["predicted_rms_mrad"] > 0
    assert rows[ids[0]]["east_m"] == field.cfg.heliostat(ids[0]).position_enu_m[0]


def test_morning_report_has_the_field_map_distributions_and_worst_heliostats(measured_night, tmp_path,
                                                                               monkeypatch):
    field, ids, _, half, _ = measured_night
    monkeypatch.setattr(night_report, "WORST", 12)
    monkeypatch.setattr(night_report, "TABLE_MAX", 10)  # "large": the full table in the CSV only
    with CampaignStore(field.db_path, readonly=True) as store:
        rec = next(n for n in NightBook(store).nights() if n.name == "field/night-1")
        md = night_report.write_night_report(store, tmp_path, rec).read_text()
    for f in ("report.html", "passes.png", "field_map.png", "distributions.png", "heliostats.csv"):
        assert (tmp_path / f).stat().st_size > 0, f
    assert "## The 12 heliostats with the largest predicted daytime error" in md
    assert f"All {len(ids)} heliostats: heliostats.csv." in md
    assert "## No measurable geometry tonight" in md and ids[-1] in md
    # Thumbnails of the worst that have a frame (those measured tonight): never one per heliostat.
    thumbs = sorted(p.name for p in (tmp_path / "thumbs").iterdir())
    assert 1 <= len(thumbs) <= min(12, len({it.heliostat_id for it in half}))
    assert all(f"thumbs/{t}" in md for t in thumbs)
    assert "<img src='thumbs/" in (tmp_path / "report.html").read_text()
    with open(tmp_path / "heliostats.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(ids) and {r["heliostat"] for r in table} == set(ids)


def test_schema_v9_upgrades_an_older_database(tmp_path):
    db = tmp_path / "v8.db"
    with sqlite3.connect(db) as c:
        for m in MIGRATIONS[:8]:
            c.executescript(m)
        c.execute("PRAGMA user_version=8")
    with CampaignStore(db) as store:
        assert store.schema_version == len(MIGRATIONS) >= 9
        names = {r["name"] for r in store.query("SELECT name FROM sqlite_master")}
        assert {"heliostat_runs_heliostat", "corrections_run", "images_measurement",
                "night_heliostats"} <= names
        plan = store.query("EXPLAIN QUERY PLAN SELECT * FROM heliostat_runs WHERE heliostat_id='H1'")
        assert any("heliostat_runs_heliostat" in r["detail"] for r in plan)
