"""A planned night with several beams per target ends at sunrise: no further lamp is lit and
no further pass starts once the sun is up (K > 1 is for lamps at night), the night ends
``partial`` naming the daylight, every lamp dark, and the next night is a new one that plans
again (not a resumption of this one)."""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path

import yaml

from controller.calibration.beams.policy import DAYLIGHT_ELEVATION_DEG, night_over, sun_elevation_deg
from controller.calibration.campaign.observers import CampaignObserver
from controller.commands.field import open_store
from controller.commands.sim.field import run_planned_night, seed_from_truth
from controller.storage.nights import NightBook
from simplant.cheap_night import CheapField, field_data

ROOT = Path(__file__).resolve().parents[3]


class _DawnAfterFirstPass(CampaignObserver):
    """When the night's first pass ends, the plant's clock jumps to an hour after sunrise (the
    rest of a long night, as plant time would have run on): the sun's elevation at the site,
    not a flag, is what the night sees."""

    def __init__(self, field) -> None:
        self.field, self.jumped_at, self.started = field, None, []

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        self.started.append(self.field.plant.utc())

    def campaign_finished(self, campaign_id: int, status: str) -> None:
        if self.jumped_at is not None:
            return
        now = datetime.fromisoformat(self.field.plant.utc())
        later = now
        while sun_elevation_deg(self.field.cfg, later.isoformat()) <= DAYLIGHT_ELEVATION_DEG:
            later += timedelta(minutes=10)
        later += timedelta(hours=1)
        with self.field.plant.clock.frozen(advance_s=(later - now).total_seconds()):
            pass
        self.jumped_at = self.field.plant.utc()


def test_a_night_of_several_beams_ends_at_sunrise_partial_with_its_rest_left_to_the_next_night(tmp_path):
    base = yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())
    field = CheapField(field_data(base, 10, 1, 1, beams=2), tmp_path, speedup=1000.0)
    seed_from_truth(field, "n0")
    dawn = _DawnAfterFirstPass(field)
    night = run_planned_night(field, None, "n1", budget_s=48 * 3600.0, observers=[dawn])

    assert dawn.jumped_at is not None and night_over(field.cfg, dawn.jumped_at) is not None
    # One pass ran, in the night; none started after sunrise.
    assert len(night.results) == 1 and len(dawn.started) == 1
    assert night_over(field.cfg, dawn.started[0]) is None
    s = night.summary
    assert s.status == "partial" and s.cause.startswith("daylight: the sun is up")
    assert "planned again by the next night" in s.cause
    assert 0 < s.measured < s.planned  # the first pass measured; the rest was not started
    assert s.lights_out and all(e["state"] == "dark" for e in s.lights_out) and field.plant.lit is None
    store = open_store(field.db_path)
    try:
        book = NightBook(store)
        assert book.unfinished("planned") is None  # the next night plans anew, it does not resume this one
        (rec,) = [r for r in store.query("SELECT status, cause FROM nights WHERE name='n1'")]
        assert (rec["status"], rec["cause"]) == ("partial", s.cause)
    finally:
        store.close()
