"""A planned night killed with ``kill -9`` mid-pass resumes: the stored plan is reused, recorded
heliostats are not measured again, nothing is lost or duplicated."""

from __future__ import annotations

import json
import os
import signal
import sqlite3

from tests.calibration.campaign.test_campaign_sim import _heliocal, _wait_for_rows
from tests.conftest import scaled_s


def test_kill_9_mid_planned_night_then_resume(small_config, tmp_path):
    out = tmp_path / "demo"
    db = out / "campaign.db"
    args = ["demo", "--config", str(small_config), "--heliostats", "3", "--seed", "2", "--out", str(out),
            "--nights", "1", "--json"]
    p = _heliocal(*args)
    night_runs = ("SELECT r.id, c.name, r.heliostat_id FROM heliostat_runs r JOIN campaigns c "
                  "ON c.id = r.campaign_id WHERE c.name LIKE '%/night-1/%'")
    first = _wait_for_rows(p, db, night_runs, scaled_s(240))
    assert first and p.poll() is None, "the planned night ended before it could be killed"
    os.kill(p.pid, signal.SIGKILL)
    p.wait(scaled_s(10))
    with sqlite3.connect(db) as c:
        plan_before = c.execute("SELECT heliostat_id, rank, lamp, aim_e, aim_n, aim_u FROM plan "
                                "ORDER BY id").fetchall()
    assert plan_before, "the plan is stored before its first pass"
    q = _heliocal(*args)
    stdout, stderr = q.communicate(timeout=scaled_s(300))
    assert q.returncode in (0, 3), stderr
    (night,) = json.loads(stdout)["nights"]
    with sqlite3.connect(db) as c:
        plan_after = c.execute("SELECT heliostat_id, rank, lamp, aim_e, aim_n, aim_u FROM plan "
                               "ORDER BY id").fetchall()
        runs = c.execute("SELECT c.name, r.heliostat_id FROM heliostat_runs r JOIN campaigns c "
                         "ON c.id = r.campaign_id WHERE c.name LIKE '%/night-1/%'").fetchall()
        marks = ",".join("?" * len(first))
        kept = c.execute(f"SELECT id FROM heliostat_runs WHERE id IN ({marks})",
                         [r[0] for r in first]).fetchall()
        n_meas = c.execute("SELECT COUNT(*) FROM measurements").fetchone()[0]
        iters = c.execute("SELECT SUM(iterations) FROM heliostat_runs").fetchone()[0]
    assert plan_after == plan_before  # the resumed night ran the stored plan, not a new one
    assert len(runs) == len(set(runs)) == len(plan_before)  # each planned geometry once, none lost
    assert len(kept) == len(first)  # runs recorded before the kill are still there
    assert n_meas == iters and night["planned"] == len(plan_before)
