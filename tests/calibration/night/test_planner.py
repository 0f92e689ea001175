"""The nightly planner: candidates, expected-gain picks against round-robin, passes, age weights."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from controller.calibration.cycle.model_update import age_weights
from controller.calibration.night.passes import night_passes
from controller.calibration.night.planner import candidates, plan_heliostat, plan_night, planner_sun
from controller.calibration.records import ModelRecord
from controller.config import parse_config
from controller.errors import ConfigError
from controller.geometry.design import daytime_variance, posterior
from controller.geometry.model.tracking import TERMS, TrackingModel
from tests.calibration.conftest import REPO, calibrated_record


@pytest.fixture(scope="module")
def cfg():
    return parse_config(yaml.safe_load((REPO / "configs" / "demo.yaml").read_text()), "demo.yaml")


def test_candidates_span_lamps_and_aim_points(cfg):
    geos = candidates(cfg, "H02", TrackingModel.zero())
    lamps = {g.lamp for g in geos}
    assert len(lamps) >= 4 and {g.cell for g in geos} == {(r, c) for r in range(3) for c in range(3)}
    g = cfg.heliostat("H02").axes
    for geo in geos:  # every candidate is within the soft limits
        assert g.azimuth.soft_limits.min_steps <= geo.steps[0] <= g.azimuth.soft_limits.max_steps
        assert g.elevation.soft_limits.min_steps <= geo.steps[1] <= g.elevation.soft_limits.max_steps


def test_each_pick_lowers_the_predicted_daytime_error(cfg):
    items = plan_heliostat(cfg, "H03", calibrated_record(cfg, "H03"), "n1", planner_sun(cfg))
    assert len(items) == cfg.calibration.planner.geometries_per_night
    assert [i.rank for i in items] == list(range(1, len(items) + 1))
    for a, b in zip(items, items[1:], strict=False):
        assert b.predicted_before_mrad == pytest.approx(a.predicted_after_mrad)
    assert all(i.gain > 0 and i.predicted_after_mrad < i.predicted_before_mrad for i in items)
    assert len({(i.geometry.lamp, i.geometry.cell) for i in items}) == len(items)  # no geometry twice


def test_design_beats_round_robin_on_predicted_daytime_error(cfg):
    sun = planner_sun(cfg)
    for hid in ("H01", "H09", "H16"):
        rec = calibrated_record(cfg, hid)
        design = plan_heliostat(cfg, hid, rec, "n", sun)
        fixed = plan_heliostat(cfg, hid, rec, "n", sun, strategy="round-robin")
        assert len(design) == len(fixed)
        assert design[-1].predicted_after_mrad < fixed[-1].predicted_after_mrad


def test_greedy_gain_matches_the_covariance_update(cfg):
    """The planner's reported 'after' is the posterior of Eq. (1) propagated by Eq. (2)."""
    from controller.calibration.night.daytime import model_covariance
    from controller.geometry.design import beam_jacobians, normal_jacobian
    from controller.geometry.kinematics import HeliostatKinematics

    sun = planner_sun(cfg)
    rec = calibrated_record(cfg, "H05")
    item = plan_heliostat(cfg, "H05", rec, "n", sun)[0]
    model, cov = model_covariance(rec, cfg.calibration.model)
    kin = HeliostatKinematics.from_config(cfg.heliostat("H05"))
    a = beam_jacobians(kin, model, sun, np.asarray(cfg.target().center_enu_m, float))
    lamp = np.asarray(cfg.light_source(item.geometry.lamp).position_enu_m, float)
    h = normal_jacobian(kin, model, *item.geometry.steps, None, np.asarray(item.geometry.aim_enu), lamp)
    after = posterior(cov, h, cfg.calibration.model.noise_mrad * 1e-3)
    assert 1e3 * np.sqrt(daytime_variance(a, after)) == pytest.approx(item.predicted_after_mrad, rel=1e-6)


def test_a_well_known_heliostat_gets_only_a_check(cfg):
    tiny = np.diag(np.full(len(TERMS), 1e-5)) ** 2  # σ 10 µrad / 10 µm on every term
    rec = ModelRecord(TrackingModel.zero().to_dict(), {}, 0.1, 20, {"covariance_si": tiny.tolist()})
    items = plan_night(cfg, {"H04": rec, "H05": calibrated_record(cfg, "H05")}, "n")
    per = {h: sum(1 for i in items if i.heliostat_id == h) for h in ("H04", "H05")}
    assert per == {"H04": cfg.calibration.planner.check_geometries,
                   "H05": cfg.calibration.planner.geometries_per_night}


def test_passes_group_by_lamp_with_one_run_per_heliostat(cfg):
    items = plan_night(cfg, {h: calibrated_record(cfg, h) for h in ("H01", "H02", "H03")}, "night-1")
    passes = night_passes(items, "night-1")
    assert sum(len(p.aims) for p in passes) == len(items)
    lamps = [p.lamp for p in passes]
    assert lamps == sorted(lamps, key=lamps.index)  # each lamp's passes together: one switch per lamp
    for p in passes:
        assert p.name.startswith(f"night-1/{p.lamp}/")
        planned = {(i.heliostat_id, i.geometry.aim_enu) for i in items if i.geometry.lamp == p.lamp}
        assert {(h, a) for h, a in p.aims.items()} <= planned


def test_age_weights_halve_per_half_life():
    w = age_weights(["2026-03-01T20:00:00+00:00", "2026-03-31T20:00:00+00:00", "2026-04-30T20:00:00+00:00",
                     "garbled"], 30.0)
    assert w == pytest.approx([0.25, 0.5, 1.0, 1.0])


def test_unknown_or_non_lamp_in_calibration_lamps_is_refused():
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    data["calibration"]["lamps"] = ["lamp", "sun"]
    with pytest.raises(ConfigError, match=r"calibration.lamps\[1\]: 'sun' is not the id of a lamp"):
        parse_config(data, "x.yaml")
