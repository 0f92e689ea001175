"""The field benchmark's machinery on a few heliostats: a planned night through the real runner
over in-process drives and cheap cameras (simplant.cheap_night), checked against the plant's
truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.planner import plan_night
from controller.commands._cheap_night import run_cheap_night
from controller.devices.drive import AxisLimits, DriveLimits
from controller.errors import LimitError
from controller.storage.db import CampaignStore
from simplant.cheap_night import CheapField, field_data
from simplant.inproc import InProcPool

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def base() -> dict:
    return yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())


def test_small_field_night_one_beam_per_target(base, tmp_path):
    field = CheapField(field_data(base, 6, 2, 1), tmp_path, speedup=1000.0)
    plan = plan_night(field.cfg, {h.id: None for h in field.cfg.heliostats}, "n1")
    assert len(plan) == 6  # one geometry per heliostat
    night = run_cheap_night(field, plan, "n1", budget_s=8 * 3600.0)

    assert not night.stopped_by_budget
    assert [r.status for r in night.results] == ["finished", "finished"]
    assert sorted(night.measured) == sorted(
        (it.heliostat_id, f"n1/{it.geometry.lamp}/1@{it.geometry.target}") for it in plan)
    assert night.per_target == {"T1": 3, "T2": 3}
    assert night.plant_s > 0
    # The plant's truth: every capture saw exactly one beam on its target.
    for tid, captures in night.beams_in_view.items():
        assert captures and all(len(b) == 1 for b in captures), tid
    # The recorded centroid is where the hidden heliostat's true beam hit (cheap camera's truth).
    store = CampaignStore(field.db_path, readonly=True)
    try:
        got = {m.heliostat_id: np.asarray(m.centroid_enu) for m in store.measurements()}
    finally:
        store.close()
    truth = {hid: np.asarray(p) for cam in field.cameras.values() for hits in cam.hits
             for hid, p in hits.items()}
    assert set(got) == {h.id for h in field.cfg.heliostats}
    for hid, c in got.items():
        assert np.linalg.norm(c - truth[hid]) < 0.1, hid  # m, about one pixel (7 cm)


def test_inproc_drive_firmware_enforces_its_soft_limits(base, tmp_path):
    field = CheapField(field_data(base, 1, 1, 1), tmp_path)
    h = field.cfg.heliostats[0]
    fw = h.axes.azimuth.soft_limits
    # The controller's limits wider than the firmware's: the firmware refuses, nothing moves.
    wide = DriveLimits(AxisLimits(0, fw.max_steps + 400), AxisLimits(0, 68700))
    drive = InProcPool.for_plant(field.plant).drive(h.link, wide)
    before = drive.status()
    with pytest.raises(LimitError, match="OUT_OF_RANGE"):
        drive.move_abs(fw.max_steps + 200, before.el_steps)
    after = drive.status()
    assert (after.az_target, after.el_target) == (before.az_target, before.el_target)
    drive.move_abs(fw.max_steps, before.el_steps)
    assert drive.status().az_target == fw.max_steps
