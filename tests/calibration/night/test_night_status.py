"""Status never hides a failure (issue 40; docs/nights.md). On the simulated plant, one heliostat
and one target: a night whose lamps confirm but give no light is ``partial``, its passes read
``measured 0/1`` (never ``calibrated``), the frames of its looks are archived and in the report;
the same geometry failing on two nights is flagged, shown, not planned again, and cleared with
``heliocal campaign flags``; a night stopped by Ctrl-C counts what its passes measured; the
demo's exit status is its worst night's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.campaign.outcome import CampaignResult
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.daytime import PredictedDaytime
from controller.calibration.night.planned import NightSummary, PlannedNight, calibration_night
from controller.calibration.night.planner import geometry_key
from controller.commands.field import open_store
from controller.commands.simulated import NightReport, SimulatedRun, simulated_field
from controller.config import load_config
from controller.reports.night import write_night_report
from controller.storage.nights import NightBook
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST
from tests.conftest import run_cli

HID = "H02"


@pytest.fixture
def field(small_config, tmp_path):
    """The simulated plant with one target (every night plans on it), H02 calibrated."""
    data = yaml.safe_load(small_config.read_text())
    data["calibration"]["targets"] = [data["calibration"]["target"]]
    path = tmp_path / "one-target.yaml"
    path.write_text(yaml.safe_dump(data))
    store = open_store(tmp_path / "c.db")
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=5)
    with simulated_field(load_config(path), str(path), store, tmp_path / "sim", [HID], settings, night=0,
                         library=None) as fs:
        assert calibration_night(fs.book, Campaign(fs.field, CampaignOptions(name="n"),
                                                   heliostat_ids=[HID])).status == "finished"
        yield fs
    store.close()


def _night(fs, k: int, **kw):
    fs.plant.set_night(k)
    return PlannedNight(fs.field, fs.book, f"n/night-{k}", k, heliostat_ids=[HID], **kw).run()


def test_failed_geometries_are_shown_flagged_not_planned_again_and_cleared(field, tmp_path):
    fs = field
    db = str(fs.field.store.path)
    for lamp in fs.field.cfg.calibration.lamps:  # confirmed lit by the panel, no light (a lying sensor)
        fs.plant.lamp_panel.no_light.add(lamp)
    first = _night(fs, 1)
    assert first.status == "partial" and first.exit_code == 3
    assert first.measured == 0 and first.failed == first.planned > 0 and first.flagged == []
    passes = [c for c in json.loads(run_cli(["campaign", "list", "--db", db, "--json"])[1])["campaigns"]
              if c["name"].startswith("n/night-1/")]
    assert passes and all(c["pass"] and c["measured"] == 0 for c in passes)
    listing = run_cli(["campaign", "list", "--db", db])[1]
    assert "measured" in listing and " 0/1 calibrated" not in listing  # a pass measures
    # What the camera saw: each look's frame is archived with its run and shown in the report.
    frames = fs.field.store.query("SELECT f.path FROM run_frames f JOIN heliostat_runs r ON f.run_id=r.id "
                                  "WHERE r.status='no_beam'")
    assert len(frames) == 2 * first.planned  # LOW and HIGH of each geometry's look
    assert all((Path(db).parent / r["path"]).is_file() for r in frames)
    night = NightBook(fs.field.store).nights()[-1]
    report = write_night_report(fs.field.store, tmp_path / "r1", night).read_text()
    assert "## Captures that gave no measurement" in report
    assert len(list((tmp_path / "r1" / "thumbs").glob("nomeasure-*.png"))) == first.planned

    second = _night(fs, 2)  # the same model, the same plan: the same geometries fail again
    keys = {(g["lamp"], g["target"], tuple(g["cell"])) for g in second.flagged}
    assert second.status == "partial" and len(second.flagged) == second.planned == first.planned
    assert all(g["heliostat"] == HID and g["nights"] == ["n/night-1", "n/night-2"] for g in second.flagged)
    night = NightBook(fs.field.store).nights()[-1]
    assert "## Flagged geometries" in write_night_report(fs.field.store, tmp_path / "r2", night).read_text()

    third = _night(fs, 3)  # flagged: not planned again
    planned = {geometry_key(it.geometry, fs.field.cfg.calibration.target) for it in fs.book.plan("n/night-3")}
    assert not planned & keys
    assert third.planned == len(planned)

    code, out, err = run_cli(["campaign", "flags", "--db", db, "--clear", HID])
    assert code == 2 and "in use" in err  # the night's process holds the database: nothing cleared
    fs.field.store.campaign_lock.release()
    code, out, err = run_cli(["campaign", "flags", "--db", db, "--clear", HID, "--json"])
    assert code == 0, err
    assert {(g["lamp"], g["target"], tuple(g["cell"])) for g in json.loads(out)["cleared"]} >= keys
    assert json.loads(run_cli(["campaign", "flags", "--db", db, "--json"])[1])["flagged"] == []
    code, _, err = run_cli(["campaign", "flags", "--db", db, "--clear", HID])
    assert code == 2 and "no flagged geometry of H02" in err


class _CtrlC(CampaignObserver):
    """Ctrl-C as the first planned geometry is recorded (the cycle's thread raises it; the
    campaign's main thread gets it as from a SIGINT)."""

    def run_recorded(self, campaign_id, run) -> None:
        if run.status == "measured":
            raise KeyboardInterrupt


def test_an_interrupted_night_counts_what_its_passes_measured(field):
    fs = field
    with pytest.raises(KeyboardInterrupt):
        _night(fs, 1, observers=[_CtrlC()])
    book = NightBook(fs.field.store)
    night = book.nights()[-1]
    stored = sum(book.measured("n/night-1").values())
    assert night.status == "interrupted" and stored >= 1
    assert night.summary["measured"] == stored
    assert sum(r["measured"] for r in book.heliostats(night.id)) == stored
    assert {x["state"] for x in night.summary["lights_out"]} == {"dark"}


def _summary(status: str) -> NightSummary:
    return NightSummary(1, "n/night-1", 1, 3, 3 if status == "finished" else 1, 0, [], {"rms": 1.0}, status)


@pytest.mark.parametrize(("campaign", "nights", "code"), [
    ("finished", ["finished", "finished"], 0),
    ("finished", ["finished", "partial"], 3),
    ("partial", ["finished"], 3),
    ("finished", ["partial", "aborted"], 1),
    ("finished", ["interrupted"], 130),
])
def test_the_demo_exits_with_its_worst_night(campaign, nights, code):
    result = CampaignResult(1, "n", False, [], 0.0, 0.0, campaign)
    none = PredictedDaytime.__new__(PredictedDaytime)
    run = SimulatedRun(result, {}, {}, None, Path("c.db"), Path("."), None, None, none,
                       [NightReport(_summary(s), None, none) for s in nights])
    assert run.exit_code == code
