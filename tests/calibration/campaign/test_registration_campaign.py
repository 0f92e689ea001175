"""The campaign's registration step against the simulated plant (small camera, real drivers):
recorded in the campaign's metadata when it succeeds; a refused one stops the campaign before
it opens, and the fiducial lamps are off again either way. The plant's config has a lamp panel
with the target's fiducials channel, so the fiducials are switched (and confirmed) through it,
not through the campaign observer's hook."""

from __future__ import annotations

import numpy as np
import pytest

from controller.calibration.campaign.runner import Campaign, CampaignObserver, CampaignOptions
from controller.calibration.cycle.registration_step import RegistrationError, nominal_camera
from controller.commands.simulated import plant_field
from controller.devices.factory import LinkPool
from controller.imaging.registration import CameraModel
from controller.storage.db import CampaignStore
from simplant.plant import SimulatedPlant, load_config_data
from tests.calibration.conftest import FAST


class _Lamps(CampaignObserver):
    """Switches the plant's fiducial lamps and logs it (a hook the panel's channel overrides)."""

    def __init__(self, plant) -> None:
        self.plant, self.calls = plant, []

    def fiducial_lamps(self, on: bool) -> None:
        self.calls.append(on)
        self.plant.set_fiducials(on)

    def light_source_needed(self, source_id: str) -> None:
        self.plant.set_light(source_id)


def _fiducial_writes(plant, pcfg) -> list[bool]:
    """What the lamp panel was told for the calibration target's fiducials, in order."""
    channel = "fiducials:" + pcfg.calibration.target
    return [on for name, on in plant.lamp_panel.writes if name == channel]


def _run(plant, small_config, tmp_path, lamps: _Lamps, ids: list[str], no_light: bool = False):
    with plant, CampaignStore(tmp_path / "c.db") as store:
        pcfg = plant.start()
        if no_light:  # the fiducials confirm lit but give no light
            plant.lamp_panel.no_light.add("fiducials:" + pcfg.calibration.target)
        with LinkPool() as pool:
            campaign = Campaign(plant_field(plant, small_config, store, pool), CampaignOptions(name="reg"),
                                heliostat_ids=ids, observers=[lamps])
            result = campaign.run()
        return result, store.campaign(result.campaign_id), pcfg


def test_a_campaign_registers_the_camera_and_records_it(small_config, tmp_path):
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "p", heliostat_ids=["H02"],
                           settings=FAST, seed=2)
    lamps = _Lamps(plant)
    result, camp, pcfg = _run(plant, small_config, tmp_path, lamps, ["H02"])
    assert result.status == "finished"
    reg = camp.meta["camera_registration"]
    assert reg["fiducials"] == 9
    # A 4x binned sensor undersamples the fiducials: over seeds 0-7 the RMS spreads over
    # 0.15-0.31 px (LOW) and 0.11-0.26 px (HIGH) with either shot-noise law of the simulated
    # sensors; the pose check below is the accuracy test.
    assert reg["low"]["rms_px"] < 0.4 and reg["high"]["rms_px"] < 0.4
    assert _fiducial_writes(plant, pcfg) == [False, True, False] and not plant.camera.fiducials_lit
    assert lamps.calls == []  # the panel's channel, not the observer's hook
    # the recorded pose, with the configured intrinsics, is the simulator's true camera
    nominal = nominal_camera(pcfg)
    truth = plant.camera.view.truth
    x, z = np.meshgrid(np.linspace(-3.8, 3.8, 5), np.linspace(26.7, 33.3, 5))
    pts = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    for sensor, name in enumerate(("low", "high")):
        rec = CameraModel(nominal.K, nominal.dist, np.array(reg[name]["rvec"]), np.array(reg[name]["tvec_m"]),
                          nominal.image_size)
        err = np.hypot(*(rec.project(pts) - truth.project(pts, sensor)).T)
        # Within half a pixel: on this 4x binned sensor the 2 cm fiducial lamps are undersampled
        # (the full-size camera is held to 0.1 px in test_registration_sim).
        assert err.max() < 0.5, (name, err.max())
        assert np.hypot(*(nominal.project(pts) - truth.project(pts, sensor)).T).max() > 3.0


def test_unlit_fiducials_stop_the_campaign_before_it_opens(small_config, tmp_path):
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "p", heliostat_ids=["H02"],
                           settings=FAST, seed=2)
    lamps = _Lamps(plant)
    with pytest.raises(RegistrationError, match="LOW sensor sees 0 of 9 fiducials") as exc:
        _run(plant, small_config, tmp_path, lamps, ["H02"], no_light=True)
    assert exc.value.exit_code == 1
    assert _fiducial_writes(plant, plant.config) == [False, True, False]
    with CampaignStore(tmp_path / "c.db") as store:
        assert store.campaign_by_name("reg") is None  # nothing recorded
