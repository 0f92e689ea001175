"""Campaigns end to end against the embedded simulated plant: real serial and Modbus drivers,
the simulated double-CCD camera, HDR merge, beam analysis, library matching, SQLite records.

Small camera (256x192) and few heliostats keep these fast; the plant clock runs 50x. Faults are
injected from the campaign's observer hooks or the simulated firmware's commands, never after
a delay."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

from controller.calibration.campaign.runner import Campaign, CampaignObserver, CampaignOptions
from controller.commands.simulated import plant_field
from controller.config import load_config
from controller.devices.factory import LinkPool
from controller.storage.db import CampaignStore
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]
IDS = ["H02", "H08", "H14"]  # serial bus1, serial bus2, Modbus TCP


def _heliocal(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "controller.cli", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def _wait_for_rows(p: subprocess.Popen, db: Path, sql: str, seconds: float) -> list[tuple]:
    """Poll ``db`` until ``sql`` returns rows (a state of the campaign), while ``p`` runs."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and p.poll() is None:
        if db.is_file():
            try:
                with sqlite3.connect(db) as c:
                    rows = c.execute(sql).fetchall()
            except sqlite3.OperationalError:
                rows = []  # the schema is not there yet
            if rows:
                return rows
        time.sleep(0.05)
    return []


def test_campaign_end_to_end(small_config, tmp_path):
    from controller.commands.simulated import simulated_campaign
    from controller.storage.paint.export import export_paint

    cfg = load_config(small_config)
    db = tmp_path / "c.db"
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=3)
    summary, sim = simulated_campaign(cfg, str(small_config), tmp_path / "run", db, IDS, settings, "t1")
    assert summary["heliostats"] == 3 and summary["calibrated"] == 3 and summary["failed"] == 0
    # quality bar: <= 0.5 mrad true reflected-beam error after calibration (closed loop)
    assert summary["error_after_mrad"]["max"] <= 0.5
    assert summary["error_before_mrad"]["mean"] > 1.0  # there was something to correct
    assert sim.safety["violations"] == 0 and sim.safety["samples"] > 10
    assert {r.heliostat_id for r in sim.result.runs} == set(IDS) == set(sim.truth)
    with CampaignStore(db) as store:
        n_meas = store.count("measurements")
        assert n_meas == sum(r.iterations for r in store.runs(sim.result.campaign_id))
        assert store.count("images") == 2 * n_meas
        assert store.count("model_params") == 3
        for r in store.runs(sim.result.campaign_id):
            m = store.latest_model(r.heliostat_id)
            assert set(m.params) >= {"az_offset_mrad", "el_offset_mrad"}
        assert len(export_paint(store, tmp_path / "paint")) == n_meas
    # the truth lives in the simulator's own table, not in the product's records
    with sqlite3.connect(db) as c:
        truth_rows = c.execute("SELECT heliostat_id, truth_label FROM sim_truth").fetchall()
        run_cols = {row[1] for row in c.execute("PRAGMA table_info(heliostat_runs)")}
    assert len(truth_rows) == 3 and not any("true" in col or "truth" in col for col in run_cols)
    rep = tmp_path / "run" / "report"
    for f in ("report.md", "report.html", "errors_hist.png", "centroids.png", "time_per_heliostat.png",
              "confusion.png"):
        assert (rep / f).is_file(), f
    assert "injected truth" in (rep / "report.md").read_text()
    page = (rep / "report.html").read_text()
    assert "`" not in page and "<code>" in page and "**" not in page
    thumbs = rep / "thumbs"
    assert len(list(thumbs.glob("*-first.png"))) == 3 == len(list(thumbs.glob("*-last.png")))
    table = (rep / "heliostats.csv").read_text().splitlines()
    assert table[0].startswith("heliostat,status,") and len(table) == 4


def test_kill_9_mid_campaign_then_resume(small_config, tmp_path):
    out = tmp_path / "demo"
    args = ["demo", "--config", str(small_config), "--heliostats", "4", "--seed", "5", "--out", str(out),
            "--nights", "0", "--json"]
    p = _heliocal(*args)
    db = out / "campaign.db"
    before = _wait_for_rows(p, db, "SELECT id, heliostat_id FROM heliostat_runs ORDER BY id", scaled_s(90))
    assert p.poll() is None, "the campaign finished before it could be killed"
    os.kill(p.pid, signal.SIGKILL)
    p.wait(scaled_s(10))
    assert 1 <= len(before) < 4
    q = _heliocal(*args)
    stdout, stderr = q.communicate(timeout=scaled_s(120))
    assert q.returncode == 0, stderr
    summary = json.loads(stdout)
    assert summary["heliostats"] == 4 and summary["calibrated"] + summary["failed"] == 4
    with sqlite3.connect(db) as c:
        runs = c.execute("SELECT id, heliostat_id FROM heliostat_runs ORDER BY id").fetchall()
        n_meas = c.execute("SELECT COUNT(*) FROM measurements").fetchone()[0]
        iters = c.execute("SELECT SUM(iterations) FROM heliostat_runs").fetchone()[0]
    assert len(runs) == 4 and len({h for _, h in runs}) == 4  # nothing lost, nothing duplicated
    # the records written before the kill are untouched, and no orphan measurements remain
    assert [r for r in runs if r[0] <= before[-1][0]][: len(before)] == before
    assert n_meas == iters


class _OnState(CampaignObserver):
    """Calls ``action(heliostat_id)`` once, when the first heliostat enters ``state``."""

    def __init__(self, state: str, action) -> None:
        self.state, self.action, self.hit = state, action, []

    def state_changed(self, heliostat_id: str, state: str) -> None:
        if state == self.state and not self.hit:
            self.hit.append(heliostat_id)
            self.action(heliostat_id)


def _campaign(plant, store, pcfg, small_config, pool, ids, name, observer):
    return Campaign(plant_field(plant, small_config, store, pool), CampaignOptions(name=name),
                    heliostat_ids=ids, observers=[observer])


def test_serial_link_lost_mid_approach_halts_the_campaign(small_config, tmp_path):
    """The bus of the heliostat on the target dies and stays dead: the heliostat cannot be
    parked or stowed, its record says so, and nobody else is put on the target."""
    ids = ["H02", "H03"]  # both on serial bus1
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "p", heliostat_ids=ids, settings=FAST,
                           seed=1)
    # The firmware stops serving as the heliostat starts onto the target (stop() joins the
    # serving thread, so it runs beside the cycle, not inside it).
    cut = _OnState("slewing", lambda hid: threading.Thread(target=plant.serial_firmware(hid).stop,
                                                           daemon=True).start())
    with plant, CampaignStore(tmp_path / "c.db") as store:
        pcfg = plant.start()
        with LinkPool(timeout_s=scaled_s(0.1), retries=1) as pool:
            result = _campaign(plant, store, pcfg, small_config, pool, ids, "cut", cut).run()
        assert result.status == "aborted" and "beam may have been left" in result.cause
        assert result.exit_code == 1
        runs = {r.heliostat_id: r for r in store.runs(result.campaign_id)}
        first = runs[cut.hit[0]]
        assert first.status == "failed" and first.final_state == "aborted"
        assert "LinkError" in first.fault_cause and "stow failed" in first.fault_cause
        assert first.on_target_s is not None and first.off_target_s is None  # beam maybe left on it
        # the other heliostat on the dead bus fails too, without ever being sent to the target:
        # the dead link stops it on its way to standby, or the blocked target while it waits there
        for r in runs.values():
            if r is not first:
                assert r.status == "failed" and r.on_target_s is None
                assert "LinkError" in r.fault_cause or "target blocked" in r.fault_cause, r.fault_cause
        camp = store.campaign(result.campaign_id)
        assert camp.status == "aborted" and camp.cause == result.cause


def test_firmware_power_cycle_mid_approach_is_recorded_and_parked(small_config, tmp_path):
    """The firmware of the heliostat on its way onto the target restarts right after it took
    the approach move: motion stops, POWER_CYCLE latches. The cycle records the fault, clears
    it, parks at standby; the next heliostat is calibrated normally."""
    ids = ["H02", "H03"]
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "p", heliostat_ids=ids, settings=FAST,
                           seed=2)
    def arm(hid: str) -> None:
        # The next MOVE_ABS this controller executes (the approach) is followed by a restart.
        ctl = plant.hidden[hid].controller
        move = ctl.move_abs

        def move_then_power_cycle(az, el):
            r = move(az, el)
            ctl.move_abs = move
            ctl.power_cycle()
            return r
        ctl.move_abs = move_then_power_cycle

    hit = _OnState("slewing", arm)
    with plant, CampaignStore(tmp_path / "c.db") as store:
        pcfg = plant.start()
        with LinkPool(timeout_s=scaled_s(0.3), retries=2) as pool:
            result = _campaign(plant, store, pcfg, small_config, pool, ids, "pc", hit).run()
        runs = {r.heliostat_id: r for r in store.runs(result.campaign_id)}
        r = runs[hit.hit[0]]
        assert r.status == "failed" and r.fault_state == "slewing"
        assert "power_cycle" in r.fault_cause
        assert r.final_state == "done" and r.off_target_s is not None  # parked again
        other = next(v for k, v in runs.items() if k != hit.hit[0])
        assert other.status == "calibrated"
        assert result.status == "partial" and hit.hit[0] in result.cause and result.exit_code == 3
        ctl = plant.hidden[hit.hit[0]].controller
        assert ctl.faults == 0 and any(e.command == "POWER_CYCLE" for e in ctl.log)


def test_ctrl_c_mid_campaign_parks_records_and_says_how_to_resume(small_config, tmp_path):
    db = tmp_path / "night.db"
    args = ["campaign", "run", "--config", str(small_config), "--db", str(db), "--simulate", "--heliostats",
            "H02,H03,H08", "--name", "n1", "--json"]
    p = _heliocal(*args)
    _wait_for_rows(p, db, "SELECT 1 FROM campaigns WHERE status='running'", scaled_s(120))
    assert p.poll() is None, "the campaign ended before it could be interrupted"
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=scaled_s(120))
    assert p.returncode == 130, err
    summary = json.loads(out)
    assert summary["status"] == "interrupted" and "Rerun the same command to resume" in err
    with sqlite3.connect(db) as c:
        status, cause = c.execute("SELECT status, cause FROM campaigns").fetchone()
    assert status == "interrupted" and "interrupted by the operator" in cause
    q = _heliocal(*args)
    out, err = q.communicate(timeout=scaled_s(180))
    assert q.returncode in (0, 3), err
    assert json.loads(out)["resumed"] is True and json.loads(out)["heliostats"] == 3


def test_planned_night_measures_other_geometries_and_explains_them(small_config, tmp_path):
    """``demo --nights 1``: after the calibration, the planner's geometries run as one campaign
    per lamp pass, each heliostat measured once per pass (status ``measured``), every choice
    stored in ``plan`` with its expected gain, and the night's daytime error reported."""
    out = tmp_path / "demo"
    p = _heliocal("demo", "--config", str(small_config), "--heliostats", "2", "--seed", "1",
                  "--out", str(out), "--nights", "1", "--json")
    stdout, stderr = p.communicate(timeout=scaled_s(300))
    assert p.returncode in (0, 3), stderr
    summary = json.loads(stdout)
    (night,) = summary["nights"]
    assert night["night"] == 1 and night["planned"] >= 2 and 1 <= night["measured"] <= night["planned"]
    assert set(night["daytime_error_mrad"]) == {"rms", "p95", "max"}
    assert summary["daytime_error_mrad"] == night["daytime_error_mrad"]
    with sqlite3.connect(out / "campaign.db") as c:
        plan = c.execute("SELECT night, heliostat_id, lamp, expected_gain, predicted_before_mrad, "
                         "predicted_after_mrad FROM plan").fetchall()
        passes = c.execute("SELECT c.name, r.heliostat_id, r.status, r.iterations FROM heliostat_runs r "
                           "JOIN campaigns c ON c.id = r.campaign_id "
                           "WHERE c.name LIKE '%/night-1/%'").fetchall()
        measured = c.execute("SELECT DISTINCT m.source_e, m.source_n FROM measurements m").fetchall()
    assert len(plan) == night["planned"]
    # Every lamp of the plan was preceded by a lamp change in the dark covering the night's heliostats.
    assert sorted(c["lamp"] for c in night["lamp_changes"]) == sorted({lamp for _, _, lamp, *_ in plan})
    assert all(c["checked"] == len({h for _, h, *_ in plan}) for c in night["lamp_changes"])
    assert all(gain > 0 and after < before for _, _, _, gain, before, after in plan)
    assert len(passes) == len(plan)
    assert all(status in ("measured", "failed") and it <= 1 for _, _, status, it in passes)
    assert sum(status == "measured" for _, _, status, _ in passes) == night["measured"]
    assert len(measured) > 2  # light from more than one lamp reached the fit
    rep = out / "report"
    md = (rep / "report.md").read_text()
    assert "## Tracking model and daytime pointing" in md and "after night 1" in md
    assert (rep / "geometries.png").is_file() and (rep / "daytime.png").is_file()
    terms = (rep / "model_terms.csv").read_text().splitlines()
    assert terms[0].startswith("heliostat,az_offset_mrad,az_offset_mrad_sigma") and len(terms) == 3
    assert "<h2>Tracking model and daytime pointing</h2>" in (rep / "report.html").read_text()


def test_demo_uncalibrated_field_compares_the_coarse_correction_with_centroid_only(small_config, tmp_path):
    """``demo --uncalibrated 12`` on four heliostats (seed 1: first spots at the view's edge): the
    block's figures are those of its two campaigns' databases, the centroid-only one has no coarse
    move, and both calibrated the same heliostats on the same hidden errors."""
    out = tmp_path / "demo"
    p = _heliocal("demo", "--config", str(small_config), "--heliostats", "4", "--seed", "1", "--nights", "0",
                  "--uncalibrated", "12", "--out", str(out), "--json")
    stdout, stderr = p.communicate(timeout=scaled_s(300))
    assert p.returncode == 0, stderr
    u = json.loads(stdout)["coarse_correction_uncalibrated"]
    assert (u["tracking_error_mrad"], u["heliostats"]) == (12.0, 4)

    def runs(name):
        with contextlib.closing(sqlite3.connect(out / "uncalibrated" / "12mrad" / name / "campaign.db")) as c:
            rows = c.execute("SELECT id, heliostat_id, iterations FROM heliostat_runs").fetchall()
            coarse = {r for (r,) in c.execute("SELECT run_id FROM corrections WHERE kind = 'coarse'")}
            first = len(c.execute("SELECT DISTINCT run_id FROM corrections WHERE iteration = 0").fetchall())
        return rows, coarse, first

    with_rows, with_coarse, clipped = runs("coarse")
    plain_rows, plain_coarse, _ = runs("centroid-only")
    assert sorted(h for _, h, _ in with_rows) == sorted(h for _, h, _ in plain_rows)
    assert len(with_coarse) == u["applied"] >= 1 and not plain_coarse
    assert sorted(h for i, h, _ in with_rows if i in with_coarse) == sorted(u["applied_heliostats"])
    assert u["clipped_first_looks"] == clipped >= u["applied"]
    assert u["iterations_mean"] == round(sum(n for *_, n in with_rows) / 4, 3)
    assert u["iterations_centroid_only_mean"] == round(sum(n for *_, n in plain_rows) / 4, 3)

    # another scale in the same folder is another field: run, not refused as a changed
    # configuration, and the first field's files untouched
    first = {f: f.read_bytes() for f in (out / "uncalibrated" / "12mrad").rglob("config.yaml")}
    p = _heliocal("demo", "--config", str(small_config), "--heliostats", "4", "--seed", "1", "--nights", "0",
                  "--uncalibrated", "real", "--out", str(out), "--json")
    stdout, stderr = p.communicate(timeout=scaled_s(300))
    assert p.returncode == 0, stderr
    assert json.loads(stdout)["coarse_correction_uncalibrated"]["tracking_error_mrad"] == "real"
    assert (out / "uncalibrated" / "real" / "coarse" / "campaign.db").is_file()
    assert first and all(f.read_bytes() == b for f, b in first.items())
