"""How a campaign ends: status and cause in the database, exit codes, throughput over
calibrated heliostats only, a report without runs, and the campaign list."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from controller.calibration.campaign.outcome import CampaignResult, outcome
from controller.calibration.records import RunRecord
from controller.reports.campaign import write_report
from controller.reports.summary import summarize
from controller.storage.db import CampaignStore

REPO = Path(__file__).resolve().parents[3]
OPEN = {"config_path": "c.yaml", "config_sha256": "ab", "light_source": "lamp", "target": "t"}


def _run(hid: str, status: str, start: float, end: float, cause: str | None = None) -> RunRecord:
    return RunRecord(hid, 0, status, "done", 2, start, end, fault_cause=cause)


@pytest.mark.parametrize("statuses, blocked, expected, code", [
    (["calibrated", "calibrated"], False, "finished", 0),
    (["calibrated", "failed"], False, "partial", 3),
    (["calibrated", "not_converged"], False, "partial", 3),
    (["calibrated"], False, "partial", 3),  # one of two never recorded
    (["calibrated", "calibrated"], True, "aborted", 1),
])
def test_outcome_and_exit_code(statuses, blocked, expected, code):
    runs = [_run(f"H{i}", s, 0.0, 1.0, "ActuatorFault: stall_az" if s == "failed" else None)
            for i, s in enumerate(statuses)]
    status, cause = outcome(runs, ["H0", "H1"], blocked)
    assert status == expected and (cause is None) == (expected == "finished")
    if "failed" in statuses:
        assert "H1: ActuatorFault: stall_az" in cause
    assert CampaignResult(1, "n", False, runs, 1.0, 1.0, status, cause).exit_code == code


def test_throughput_counts_calibrated_heliostats_only(tmp_path):
    with CampaignStore(tmp_path / "c.db") as store:
        cid, _ = store.open_campaign("n", queue=["H1", "H2", "H3"], **OPEN)
        store.record_run(cid, _run("H1", "calibrated", 0.0, 600.0))
        store.record_run(cid, _run("H2", "failed", 600.0, 1200.0, "LinkError: gone"))
        store.record_run(cid, _run("H3", "failed", 1200.0, 1800.0, "LinkError: gone"))
        store.finish_campaign(cid, "partial", "2 of 3 heliostats not calibrated")
        s = summarize(store, cid)
    assert s["heliostats_per_hour"] == pytest.approx(2.0)  # 1 calibrated in 1800 s, not 3
    assert (s["status"], s["calibrated"], s["failed"]) == ("partial", 1, 2)


def test_report_without_runs_says_so_instead_of_empty_plots(tmp_path):
    with CampaignStore(tmp_path / "c.db") as store:
        cid, _ = store.open_campaign("n", queue=["H1"], **OPEN)
        store.finish_campaign(cid, "aborted", "SerialException: cannot open /dev/ttyUSB9")
        md = write_report(store, tmp_path / "rep", cid).read_text()
    assert "status **aborted**: SerialException: cannot open /dev/ttyUSB9" in md
    assert "nothing to plot" in md and not list((tmp_path / "rep").glob("*.png"))


def test_finish_refuses_an_unknown_status(tmp_path):
    with CampaignStore(tmp_path / "c.db") as store:
        cid, _ = store.open_campaign("n", queue=["H1"], **OPEN)
        with pytest.raises(ValueError, match="halted"):
            store.finish_campaign(cid, "halted")


def test_campaign_list_and_lookup_by_name(tmp_path):
    db = tmp_path / "c.db"
    with CampaignStore(db) as store:
        a, _ = store.open_campaign("night-1", queue=["H1"], **OPEN)
        store.record_run(a, _run("H1", "calibrated", 0.0, 1.0))
        store.finish_campaign(a, "finished")
    with CampaignStore(db) as store:
        b, _ = store.open_campaign("night-2", queue=["H1", "H2"], **OPEN)
        store.finish_campaign(b, "interrupted", "interrupted by the operator")
        assert store.find_campaign("night-1").id == a and store.find_campaign(str(b)).name == "night-2"
        assert store.find_campaign(None).id == b
    r = subprocess.run([sys.executable, "-m", "controller.cli", "campaign", "list", "--db", str(db),
                        "--json"], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["campaigns"]
    assert [(c["name"], c["status"], c["calibrated"], c["heliostats"]) for c in rows] == [
        ("night-1", "finished", 1, 1), ("night-2", "interrupted", 0, 2)]
    r = subprocess.run([sys.executable, "-m", "controller.cli", "report", "campaign", "--db", str(db),
                        "--out", str(tmp_path / "rep"), "--campaign", "night-9", "--json"],
                       cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 2 and "night-9" in json.loads(r.stdout)["error"]
    assert not (tmp_path / "rep").exists()


def test_campaign_list_fits_120_columns_and_long_says_everything(tmp_path):
    from controller.storage.nights import NightBook

    db = tmp_path / "c.db"
    lamps = [f"lamp-on-the-{k}th-mast-of-the-northern-field" for k in range(8)]
    cause = "; ".join(f"H{k:03d}: BeamNotFound: beam spot clipped by the right edge of the camera view"
                      for k in range(12))
    with CampaignStore(db) as store:
        book = NightBook(store)
        night, _ = book.open_night("field-2026-11-28/night-1", "planned")
        cid, _ = store.open_campaign("field-2026-11-28/night-1/lamp-on-the-0th-mast@tower-target",
                                     queue=[f"H{k:03d}" for k in range(12)], **OPEN)
        store.finish_campaign(cid, "partial", cause)
        book.finish_night(night.id, "partial", cause, {
            "planned": 24, "measured": 12, "lamps": [{"lamp": x, "confirmed": True} for x in lamps],
            "daytime_error_predicted_mrad": {"rms": 0.61, "p95": 1.1}})

    def listing(*extra):
        r = subprocess.run([sys.executable, "-m", "controller.cli", "campaign", "list", "--db", str(db),
                            *extra], cwd=REPO, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        return r.stdout

    short = listing().splitlines()
    assert len(short) == 2 and max(len(line) for line in short) <= 120
    assert short[0].startswith("night 0: field-2026-11-28/night-1 (planned), partial; 12/24 measured; "
                               "8 lamps")
    assert short[1].endswith("…") and "H000: BeamNotFound" in short[1]
    full = listing("--long")
    assert all(x in full for x in lamps) and cause in full and f"({cause})" in full.splitlines()[0]
    data = json.loads(listing("--json"))
    assert set(data) == {"nights", "campaigns"}
    assert set(data["nights"][0]) == {"index", "name", "kind", "status", "cause", "started_utc",
                                      "finished_utc", "planned", "measured", "lamps",
                                      "daytime_error_predicted_mrad", "daytime_error_true_mrad", "campaigns"}
    assert data["nights"][0]["lamps"] == lamps and data["campaigns"][0]["cause"] == cause


@pytest.mark.parametrize("args, fragment", [
    (["--heliostats", ","], "--heliostats: no heliostat id"),
    (["--heliostats", "H01,H01"], "given twice"),
    (["--simulate", "--camera-manifest", "m.yaml"], "--camera-manifest cannot be given"),
    (["--simulate", "--report", "no/such/dir/rep"], "--report no/such/dir/rep: parent folder"),
])
def test_campaign_run_bad_options_exit_2_before_work(tmp_path, args, fragment):
    r = subprocess.run([sys.executable, "-m", "controller.cli", "campaign", "run", "--config",
                        str(REPO / "configs" / "demo.yaml"), "--db", str(tmp_path / "c.db"), *args, "--json"],
                       cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 2 and fragment in json.loads(r.stdout)["error"], r.stdout + r.stderr
    assert not (tmp_path / "c.db").exists()


def test_report_shows_the_trend_across_campaigns(tmp_path):
    db = tmp_path / "c.db"
    for night, err in (("night-1", 0.4), ("night-2", 0.2)):
        with CampaignStore(db) as store:
            cid, _ = store.open_campaign(night, queue=["H1"], **OPEN)
            run = _run("H1", "calibrated", 0.0, 1.0)
            run.error_after_mrad = err
            store.record_run(cid, run)
            store.finish_campaign(cid, "finished")
    with CampaignStore(db) as store:
        md = write_report(store, tmp_path / "one", store.find_campaign("night-1").id).read_text()
        assert "trend" not in md  # a single campaign has no trend
        md = write_report(store, tmp_path / "two", cid).read_text()
    assert "Per-heliostat trend across campaigns" in md and (tmp_path / "two" / "trend.png").is_file()
