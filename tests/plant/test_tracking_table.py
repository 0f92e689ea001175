"""``heliocal export tracking-table`` and ``export models`` (the HFCS interface): the table's
steps are exactly those of ``heliocal aim --time`` at random instants, its rows only while the
sun is up; each model carries its version, which a refit raises."""

from __future__ import annotations

import csv
import json
from datetime import datetime

import numpy as np

from controller.hfcs.tracking_table import COLUMNS
from tests.conftest import run_cli
from tests.plant.conftest import record_models


def test_the_tracking_table_matches_heliocal_aim_at_20_random_instants(fitted, tmp_path):
    config, db = fitted
    out = tmp_path / "table.csv"
    code, _, err = run_cli(["export", "tracking-table", "--config", str(config), "--db", str(db),
                            "--day", "2026-06-21", "--step", "7", "--out", str(out)])
    assert code == 0, err
    assert "H14" in err  # left out: no fitted model
    with out.open(newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == COLUMNS
        rows = list(reader)
    assert {r["heliostat"] for r in rows} == {"H01", "H02"}
    times = [datetime.fromisoformat(r["time_utc"]) for r in rows]
    assert all(t.utcoffset().total_seconds() == 0 for t in times)
    assert all(float(r["sun_elevation_deg"]) > 0 and float(r["predicted_error_mrad"]) > 0 for r in rows)
    # the mean solar day of the site (longitude -2.4°: local midnight is 00:09:36 UTC, 00:10 rounded)
    assert min(times).strftime("%H:%M") > "04:00" and max(times).strftime("%H:%M") < "20:30"
    rng = np.random.default_rng(2026)
    for i in rng.choice(len(rows), size=20, replace=False):
        r = rows[i]
        code, text, err = run_cli(["aim", "--config", str(config), "--db", str(db),
                                   "--heliostat", r["heliostat"], "--time", r["time_utc"], "--json"])
        assert code == 0, err
        aim = json.loads(text)
        assert (aim["az_steps"], aim["el_steps"]) == (int(r["az_steps"]), int(r["el_steps"])), r
        assert abs(aim["sun"]["elevation_deg"] - float(r["sun_elevation_deg"])) < 1e-6


def test_a_named_heliostat_without_a_model_is_refused(fitted, tmp_path):
    config, db = fitted
    code, _, err = run_cli(["export", "tracking-table", "--config", str(config), "--db", str(db),
                            "--day", "2026-06-21", "--heliostats", "H01,H14",
                            "--out", str(tmp_path / "t.csv")])
    assert code == 2 and "H14 has no fitted model" in err and not (tmp_path / "t.csv").exists()
    code, _, err = run_cli(["export", "tracking-table", "--config", str(config), "--db", str(db),
                            "--day", "21.06.2026", "--out", str(tmp_path / "t.csv")])
    assert code == 2 and "--day" in err


def test_models_are_exported_with_their_versions(fitted, tmp_path):
    config, db = fitted
    code, out, err = run_cli(["export", "models", "--db", str(db), "--format", "json"])
    assert code == 0, err
    first = {m["heliostat"]: m for m in json.loads(out)}
    assert {h: m["version"] for h, m in first.items()} == {"H01": 1, "H02": 1}
    record_models(db, config, ["H02"], seed=8, campaign="refit")
    code, out, err = run_cli(["export", "models", "--db", str(db), "--format", "csv", "--out",
                              str(tmp_path / "m.csv")])
    assert code == 0, err
    with (tmp_path / "m.csv").open(newline="") as f:
        rows = {r["heliostat"]: r for r in csv.DictReader(f)}
    assert (rows["H01"]["version"], rows["H02"]["version"]) == ("1", "2")
    assert float(rows["H02"]["az_offset_mrad"]) != first["H02"]["terms"]["az_offset_mrad"]
    assert float(rows["H01"]["az_offset_mrad"]) == first["H01"]["terms"]["az_offset_mrad"]
