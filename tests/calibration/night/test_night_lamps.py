"""A planned night's lamps on the simulated plant, switched through the product's lamp-panel
driver (Modbus TCP): a lamp that does not confirm stops the night's passes naming it, nothing
is measured under it; a stopped night leaves every lamp off."""

from __future__ import annotations

import pytest

from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.night.planned import PlannedNight
from controller.commands.field import open_store
from controller.commands.simulated import simulated_field
from controller.config import load_config
from controller.storage.nights import NightBook
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST

IDS = ["H02"]


@pytest.fixture
def field(small_config, tmp_path):
    store = open_store(tmp_path / "c.db")
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=5)
    with simulated_field(load_config(small_config), str(small_config), store, tmp_path / "sim", IDS, settings,
                         night=1, library=None) as fs:
        yield fs
    store.close()


def test_a_lamp_that_does_not_confirm_stops_the_night_naming_it(field):
    plant, lamp = field.plant, field.field.cfg.calibration.light_source
    plant.lamp_panel.no_confirm.add(lamp)  # its coil is written, it stays dark (a blown lamp)
    night = PlannedNight(field.field, field.book, "n/night-1", 1, heliostat_ids=IDS)
    s = night.run()
    assert s.status == "aborted" and s.exit_code == 1
    assert f"lamp {lamp} did not confirm lit within" in s.cause  # one line naming the lamp
    assert s.planned == 0 and s.measured == 0  # no pass ran under a lamp that was not seen lit
    assert field.field.store.measurements() == []
    assert plant.lit is None
    rec = NightBook(field.field.store).nights()[-1]
    assert rec.status == "aborted" and rec.cause == s.cause


class _StopAtFirstMeasurement(CampaignObserver):
    def __init__(self) -> None:
        self.night: PlannedNight | None = None

    def measured(self, heliostat_id, measurement) -> None:
        self.night.request_stop()


def test_a_stopped_night_parks_every_beam_and_leaves_every_lamp_off(field):
    stop = _StopAtFirstMeasurement()
    night = PlannedNight(field.field, field.book, "n/night-1", 1, heliostat_ids=IDS, observers=[stop])
    stop.night = night
    s = night.run()
    assert s.status == "interrupted" and s.exit_code == 130
    plant = field.plant
    assert plant.lit is None and not any(plant.lamp_panel.coils)  # every lamp commanded off, and dark
    st = field.field.drive("H02").status()
    assert not st.moving
    assert all(not v for v in (plant.safety.on_target(t.id) for t in field.field.cfg.targets))
    # The rerun resumes the same night (the calibration of the model-less heliostat first).
    again = PlannedNight(field.field, field.book, "n/night-1", 1, heliostat_ids=IDS).run()
    assert again.status in ("finished", "partial") and again.measured > 0
