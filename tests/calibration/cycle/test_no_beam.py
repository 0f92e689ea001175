"""No beam on the target: the cycle records ``no_beam`` and never corrects from the frame, and a
pass whose light source silently stays dark stops (controller/calibration/campaign/no_beam.py)."""

from __future__ import annotations

import itertools

import pytest

from controller.calibration.campaign.field import LampLit
from controller.calibration.campaign.no_beam import NO_BEAM, STOP_AFTER, NoBeamWatch
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.records import MeasurementRecord, RunRecord
from controller.commands.simulated import plant_field
from controller.devices.factory import LinkPool
from controller.storage.db import CampaignStore
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import FAST
from tests.conftest import scaled_s

IDS = ["H02", "H08", "H14", "H03"]


@pytest.mark.parametrize("depth", [1, 3])
def test_a_lamp_that_silently_fails_gives_no_beam_and_no_correction(small_config, tmp_path, depth):
    """The lamp panel confirms the calibration lamp lit, the lamp gives no light (the simulated
    panel's ``no_light``: a confirmation input that lies). With a pipeline of 3 the fourth
    heliostat is already at standby when the third is refused: it is held back there."""
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "p", heliostat_ids=IDS, settings=FAST,
                           seed=4)
    with plant, CampaignStore(tmp_path / "c.db") as store:
        pcfg = plant.start()
        lamp = pcfg.calibration.light_source
        plant.lamp_panel.no_light.add(lamp)
        with LinkPool(timeout_s=scaled_s(0.5), retries=2) as pool:
            start = {h: _steps(plant, h) for h in IDS}
            field = plant_field(plant, small_config, store, pool)
            campaign = Campaign(field, CampaignOptions(name="dark", pipeline_depth=depth), heliostat_ids=IDS)
            result = campaign.run()
        assert campaign.lamp.confirmed and plant.lit is None  # confirmed by the panel, and dark
        runs = {r.heliostat_id: r for r in store.runs(result.campaign_id)}
        assert set(runs) == set(IDS)
        assert {r.status for r in runs.values()} == {NO_BEAM}
        # Nothing was computed from a frame without a beam: no measurement, no correction, no model.
        assert all(not r.measurements and not r.corrections and r.model is None for r in runs.values())
        assert store.count("measurements") == 0 and store.count("model_params") == 0
        looked = [r for r in runs.values() if r.on_target_s is not None]
        assert len(looked) == STOP_AFTER  # then the pass stopped: the rest were not moved at all
        for r in looked:
            assert r.fault_state == "analysing" and r.final_state == "done" and r.off_target_s is not None
            assert "NoBeam: no beam on the target" in r.fault_cause and "light source" in r.fault_cause
        skipped = [r for r in runs.values() if r.on_target_s is None]
        assert len(skipped) == len(IDS) - STOP_AFTER
        for r in skipped:
            assert f"light source {lamp} was confirmed lit by the lamp panel" in r.fault_cause
            if depth == 1:
                assert r.final_state == "idle" and "not moved" in r.fault_cause
                assert _steps(plant, r.heliostat_id) == start[r.heliostat_id]
            else:  # parked at standby by the fault path, its beam never on the target
                assert r.final_state == "done" and "not put on the target" in r.fault_cause
                assert r.off_target_s is None
        assert result.status == "partial" and result.exit_code == 3
        assert f"{len(IDS)} of {len(IDS)} heliostats" in result.cause


def _steps(plant: SimulatedPlant, hid: str) -> tuple[int, int]:
    st = plant.hidden[hid].controller.status()
    return st["az_steps"], st["el_steps"]


_HELIOSTATS = itertools.count(1)  # each run its own heliostat: a heliostat counts once


def _run(status: str, measured: bool, hid: str | None = None) -> RunRecord:
    r = RunRecord(hid or f"H{next(_HELIOSTATS):02d}", 0, status, "done", 1, 0.0, 1.0)
    if measured:
        r.measurements.append(MeasurementRecord.__new__(MeasurementRecord))
    return r


def test_one_heliostat_without_a_beam_does_not_stop_the_pass():
    w = NoBeamWatch("lamp-1", "tower")
    for _ in range(STOP_AFTER - 1):
        w.ended(_run(NO_BEAM, False))
    w.ended(_run("calibrated", True))  # a beam was seen: the lamp is lit
    for _ in range(STOP_AFTER - 1):
        w.ended(_run(NO_BEAM, False))
    assert not w.stopped
    w.ended(_run("failed", False))  # a drive fault says nothing about the lamp
    assert not w.stopped
    w.ended(_run(NO_BEAM, False))
    assert w.stopped
    r = w.not_measured("H07", 5, 12.0)
    assert r.status == NO_BEAM and r.queue_index == 5
    assert "lamp-1 is lit and confirmed (it was not confirmed by a lamp panel)" in r.fault_cause
    w.lit = LampLit("lamp-1", True, "panel", "2026-01-01T20:00:00Z")
    cause = w.not_measured("H07", 5, 1.0).fault_cause
    assert "lamp-1 was confirmed lit by the lamp panel at 2026-01-01T20:00:00Z" in cause


def test_a_refused_frame_counts_once_before_its_run_ends():
    w = NoBeamWatch("lamp-1", "tower")
    for hid in ("H01", "H02"):
        w.refused(hid)  # told as each cycle enters fault, before it parks
        w.ended(_run(NO_BEAM, False, hid))  # its run ends later: not counted again
    assert not w.stopped
    w.refused("H03")
    assert w.stopped  # before H03 has parked and handed the target on
