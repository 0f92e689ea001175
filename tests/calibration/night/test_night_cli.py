"""The planned night as the product runs it: ``heliocal campaign run --simulate`` then
``heliocal campaign night --simulate``, each its own process, on the simulated plant whose
night index is the database's count of nights; resumed after ``kill -9``; scored against the
plant's truth through the ``heliocal aim`` contract only."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.calibration.night.daytime import sun_path
from controller.config import load_config
from simplant.daytime import true_errors_mrad
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings
from tests.calibration.campaign.test_campaign_sim import _wait_for_rows
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]
IDS = "H02,H14"  # serial bus 1 and Modbus TCP
SPEEDUP = "50"
KEYS = {"night", "name", "planned", "measured", "failed", "lamps", "daytime_error_predicted_mrad", "status",
        "db"}
RUNS_OF = ("SELECT r.id FROM heliostat_runs r JOIN campaigns c ON c.id = r.campaign_id "
           "WHERE c.name LIKE '%/night-{}/%'")


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "controller.cli", *args], cwd=REPO, capture_output=True,
                          text=True)


def _heliocal(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "controller.cli", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _done(p: subprocess.Popen, timeout: float) -> tuple[int, dict, str]:
    out, err = p.communicate(timeout=timeout)
    return p.returncode, (json.loads(out) if out.strip() else {}), err


def _daytime_rms(config: Path, db: Path, night: int) -> float:
    """Open-loop daytime RMS (mrad) of the fitted models over the sun path, scored with the
    plant's truth of ``night`` through ``heliocal aim`` (the independent score of the issue)."""
    cfg = load_config(config)
    plant = SimulatedPlant(load_config_data(config), db.parent / "score", heliostat_ids=IDS.split(","),
                           settings=SimulationSettings(seed=0))
    plant.set_night(night)
    target = np.asarray(cfg.target().center_enu_m, float)
    path = sun_path(cfg.site)
    errs = []
    for hid in IDS.split(","):
        for k in range(0, len(path.times), 5):
            p = _cli("aim", "--config", str(config), "--db", str(db), "--heliostat", hid, "--sun-az",
                     str(path.azimuth_deg[k]), "--sun-el", str(path.elevation_deg[k]), "--json")
            out = json.loads(p.stdout)
            if "az_steps" not in out:
                continue
            steps = [(out["az_steps"], out["el_steps"])]
            errs.append(true_errors_mrad(plant, hid, steps, path.directions[k:k + 1], target)[0])
    assert len(errs) > 10
    return float(np.sqrt(np.mean(np.square(errs))))


def test_planned_nights_in_separate_processes_resume_and_improve_the_day(small_config, tmp_path):
    db = tmp_path / "campaign.db"
    common = ["--config", str(small_config), "--db", str(db), "--simulate", "--heliostats", IDS,
              "--clock-speedup", SPEEDUP, "--json"]
    code, run, err = _done(_heliocal("campaign", "run", *common), scaled_s(300))
    assert code == 0, err
    assert run["calibrated"] == 2

    code, first, err = _done(_heliocal("campaign", "night", *common), scaled_s(300))
    assert code in (0, 3), err
    assert KEYS <= set(first) and first["night"] == 1 and first["name"].endswith("/night-1")
    assert first["planned"] > 0 and first["measured"] + first["failed"] == first["planned"]
    assert first["lamps"] and all(x["confirmed"] and x["by"] == "panel" for x in first["lamps"])
    assert first["daytime_error_predicted_mrad"]["rms"] > 0 and first["db"] == str(db)

    # kill -9 in the middle of night 2: the rerun resumes the same night with its stored plan.
    p = _heliocal("campaign", "night", *common)
    before = _wait_for_rows(p, db, RUNS_OF.format(2), scaled_s(240))
    assert before and p.poll() is None, "night 2 ended before it could be killed"
    os.kill(p.pid, signal.SIGKILL)
    p.wait(scaled_s(10))
    code, second, err = _done(_heliocal("campaign", "night", *common), scaled_s(300))
    assert code in (0, 3), err
    assert second["night"] == 2 and second["name"] == first["name"].replace("night-1", "night-2")
    with sqlite3.connect(db) as c:
        plans = c.execute("SELECT night, COUNT(*) FROM plan GROUP BY night").fetchall()
        dup = c.execute("SELECT COUNT(*) FROM heliostat_runs GROUP BY campaign_id, heliostat_id "
                        "HAVING COUNT(*) > 1").fetchall()
    assert dict(plans)[second["name"]] == second["planned"] and not dup

    # The records know nights: each pass grouped under its night, measured ones never failures.
    listing = json.loads(_cli("campaign", "list", "--db", str(db), "--json").stdout)
    assert [(n["index"], n["kind"]) for n in listing["nights"]] == [(0, "calibration"), (1, "planned"),
                                                                     (2, "planned")]
    rows = {r["id"]: r for r in listing["campaigns"]}
    night2 = listing["nights"][2]
    assert night2["measured"] == second["measured"] and night2["daytime_error_true_mrad"]["rms"] > 0
    assert sum(rows[i]["measured"] for i in night2["campaigns"]) == second["measured"]
    assert all(rows[i]["calibrated"] == 0 for i in night2["campaigns"])
    text = _cli("campaign", "list", "--db", str(db)).stdout
    assert f"night 2: {second['name']} (planned)" in text and "measured" in text

    # The default morning report is the latest whole night, as a night.
    out = str(tmp_path / "rep")
    rep = json.loads(_cli("report", "campaign", "--db", str(db), "--out", out, "--json").stdout)
    md = Path(rep["report"]).read_text()
    assert rep["night"] == 2 and md.startswith(f"# Morning report: night 2, `{second['name']}`")
    assert f"geometries measured **{second['measured']}** of {second['planned']}" in md
    assert (tmp_path / "rep" / "passes.png").is_file() and "failed" not in md.split("## Passes")[1]

    # What the nights were for, scored independently: the day after night 2 beats night 0's models.
    assert _daytime_rms(small_config, db, 2) < second["daytime_error_mrad"]["rms"] * 1.15 + 0.05


@pytest.mark.parametrize("stop", ["sigint"])
def test_ctrl_c_during_a_night_parks_and_the_rerun_resumes_it(small_config, tmp_path, stop):
    db = tmp_path / "campaign.db"
    common = ["--config", str(small_config), "--db", str(db), "--simulate", "--heliostats", "H02",
              "--clock-speedup", SPEEDUP, "--json"]
    code, _, err = _done(_heliocal("campaign", "run", *common), scaled_s(300))
    assert code == 0, err
    p = _heliocal("campaign", "night", *common)
    assert _wait_for_rows(p, db, RUNS_OF.format(1), scaled_s(240)) and p.poll() is None
    p.send_signal(signal.SIGINT)
    code, out, err = _done(p, scaled_s(60))
    assert code == 130 and "interrupted" in err and "every lamp confirmed dark" in err, (out, err)
    with sqlite3.connect(db) as c:
        name, status, summary = c.execute("SELECT name, status, summary_json FROM nights "
                                          "WHERE idx=1").fetchone()
        measured = c.execute("SELECT COUNT(*) FROM heliostat_runs r JOIN campaigns k ON r.campaign_id=k.id "
                             "WHERE k.name LIKE ? AND r.status='measured'", (name + "/%",)).fetchone()[0]
        lamps = c.execute("SELECT DISTINCT state FROM lamp_states WHERE session=?", (name,)).fetchall()
    assert status == "interrupted"
    assert json.loads(summary)["measured"] == measured  # what its passes measured before Ctrl-C
    assert lamps == [("dark",)]  # lights out, read back and recorded
    code, again, err = _done(_heliocal("campaign", "night", *common), scaled_s(300))
    assert code in (0, 3), err
    assert again["night"] == 1 and again["status"] in ("finished", "partial")
