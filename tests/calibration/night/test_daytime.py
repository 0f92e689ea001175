"""Daytime tracking after a night: ``heliocal aim`` with the fitted models, scored by an
independent script that uses only the aim contract and ``SimulatedPlant.true_normal_at``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from controller.calibration.night.daytime import sun_path
from controller.cli import main
from controller.config import load_config
from simplant.daytime import true_errors_mrad
from simplant.plant import SimulatedPlant, load_config_data
from simplant.settings import SimulationSettings
from tests.calibration.conftest import FAST

IDS = ["H02", "H08", "H14"]


def test_sun_path_is_four_days_of_daylight():
    cfg = load_config(Path(__file__).resolve().parents[3] / "configs" / "demo.yaml")
    path = sun_path(cfg.site)
    assert {t.month for t in path.times} == {3, 6, 9, 12}
    assert np.all(path.elevation_deg > 15) and len(path.times) > 60
    assert np.allclose(np.linalg.norm(path.directions, axis=1), 1.0)


def test_aim_contract_scored_independently_matches_the_reported_daytime_error(small_config, tmp_path, capsys):
    from controller.commands.simulated import simulated_campaign

    cfg = load_config(small_config)
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=4)
    db = tmp_path / "c.db"
    summary, sim = simulated_campaign(cfg, str(small_config), tmp_path / "run", db, IDS, settings, "n1")
    reported = summary["daytime_error_mrad"]
    assert reported["rms"] < sim.daytime_uncalibrated.rms  # the night helped the day

    # The independent score: the plant rebuilt from the seed, the controller asked through its
    # CLI contract only, the beam reflected about the plant's true normal.
    plant = SimulatedPlant(load_config_data(small_config), tmp_path / "again", heliostat_ids=IDS,
                           settings=settings)
    target = np.asarray(cfg.target().center_enu_m, float)
    path = sun_path(cfg.site)
    errs = []
    for hid in IDS:
        for k in range(0, len(path.times), 7):
            sun = ["--sun-az", str(path.azimuth_deg[k]), "--sun-el", str(path.elevation_deg[k])]
            ask = ["aim", "--config", str(small_config), "--db", str(db), "--heliostat", hid, *sun, "--json"]
            code = main(ask)
            assert code in (0, 2)
            out = json.loads(capsys.readouterr().out)
            if "az_steps" not in out:
                continue  # out of the soft limits at this sun position
            assert out["model"] is not None and out["target"] == cfg.target().id
            steps = [(out["az_steps"], out["el_steps"])]
            errs.append(true_errors_mrad(plant, hid, steps, path.directions[k:k + 1], target)[0])
    independent = float(np.sqrt(np.mean(np.square(errs))))
    assert len(errs) > 20
    assert independent == pytest.approx(reported["rms"], rel=0.10)


def test_repeatability_draw_depends_on_the_pose_not_on_who_looked_before(small_config, tmp_path):
    """A seed gives one figure: the landing error at a pose is the same however often the
    plant was sampled on the way there (the safety monitor samples by wall-clock time)."""
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=4)
    plants = [SimulatedPlant(load_config_data(small_config), tmp_path / f"p{i}", heliostat_ids=IDS,
                             settings=settings) for i in range(2)]
    pose = (20000.0, 30000.0)
    first = plants[0].hidden["H02"].settle(pose, 1)
    for k in range(50):  # a slew seen by the monitor: many poses on the way
        plants[1].hidden["H02"].settle((19000.0 + 20 * k, 29000.0 + 20 * k), 1)
    assert plants[1].hidden["H02"].settle(pose, 1) == first
    assert plants[0].hidden["H02"].settle(pose, 2) != first  # another night, another landing
    assert plants[0].hidden["H02"].settle((20001.0, 30000.0), 1) != first
    assert plants[0].hidden["H08"].settle(pose, 1) != first
