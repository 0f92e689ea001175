"""A field of thousands, tested on a few: plans only of measurable geometries (and why not),
planning, refits and the daytime prediction in worker processes with the same results as one
at a time, standby offsets that grow with the spot, the records of a whole field at once."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from controller.calibration.cycle.model_update import fit_measurements
from controller.calibration.cycle.pointing import PARK_MARGIN_M, GeometryPointing
from controller.calibration.night import daytime
from controller.calibration.night.candidates import FieldGeometry, evaluate, evaluate_many
from controller.calibration.night.daytime import model_covariance, predicted_daytime, sun_path
from controller.calibration.night.planner import aim_points, plan_field, plan_heliostat, planner_sun
from controller.calibration.night.refit import refit_models
from controller.config import parse_config
from controller.errors import ConfigError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.target_frame import TargetFrame
from controller.geometry.zones import rays_enter_any, zone_entered
from simplant.cheap_night import field_data
from tests.calibration.conftest import REPO, calibrated_record


@pytest.fixture(scope="module")
def base() -> dict:
    return yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())


@pytest.fixture(scope="module")
def demo(base):
    return parse_config(base, "demo.yaml")


@pytest.fixture(scope="module")
def large(base):
    """The configuration of a 2,000-heliostat cheap field (no plant: configuration only)."""
    return parse_config(field_data(base, 2000, 3, 3), "field.yaml")


def test_no_model_no_measurable_geometry_and_the_plan_says_why(demo):
    """With the prior only (no calibration yet), a spot's position is uncertain by metres: no
    aim point keeps it in the view at 3σ, the heliostat is not planned and its entry says so."""
    plan = plan_field(demo, {"H01": None, "H02": calibrated_record(demo, "H02")}, "n")
    assert {i.heliostat_id for i in plan.items} == {"H02"}
    [lost] = plan.unmeasurable
    assert lost.heliostat_id == "H01" and lost.predicted_mrad > 2.0
    assert "no measurable geometry on tower-" in lost.why and "3σ spot leaves the camera's view" in lost.why
    assert "position σ" in lost.why and lost.to_json()["heliostat"] == "H01"


def test_every_planned_spot_stays_in_view_and_a_narrow_view_drops_outer_aim_points(demo):
    hid, rec = "H13", calibrated_record(demo, "H13")
    model, cov = model_covariance(rec, demo.calibration.model)
    geo = FieldGeometry(demo, planner_sun(demo), aim_points)
    view = geo.views["tower-target"]
    wide = evaluate(geo, hid, model, cov, "tower-target")
    assert len(wide.lamps) and np.all(wide.spots.reach_m() + geo.margin_m <= view.half_view_m)
    # A larger margin from the view's edge: the spots reaching farthest out (outer aim points,
    # wide spots) no longer fit, the others stay.
    slack = np.min(view.half_view_m - wide.spots.reach_m(), axis=1)
    margin = float(np.median(slack))
    planner = demo.calibration.planner.model_copy(update={"view_margin_m": margin})
    narrow_cfg = demo.model_copy(update={"calibration": demo.calibration.model_copy(
        update={"planner": planner})})
    narrow = evaluate(FieldGeometry(narrow_cfg, planner_sun(demo), aim_points), hid, model, cov,
                      "tower-target")
    assert len(narrow.lamps) == int(np.sum(slack >= margin)) and 0 < len(narrow.lamps) < len(wide.lamps)
    assert np.all(narrow.spots.reach_m() + margin <= view.half_view_m)


def test_candidates_of_many_heliostats_at_once_equal_one_at_a_time(large):
    geo = FieldGeometry(large, planner_sun(large), aim_points)
    ids = [h.id for h in large.heliostats][::97][:12]
    tasks = [(hid, *model_covariance(calibrated_record(large, hid), large.calibration.model.prior_sigma),
              ("T1", "T2", "T3")[i % 3]) for i, hid in enumerate(ids)]
    together = evaluate_many(geo, tasks)
    for task, got in zip(tasks, together, strict=True):
        alone = evaluate(geo, *task)
        assert got.lamps == alone.lamps and got.cells == alone.cells
        assert np.array_equal(got.steps, alone.steps)
        assert got.h == pytest.approx(alone.h, rel=1e-9, abs=1e-12)
        assert got.m == pytest.approx(alone.m, rel=1e-9, abs=1e-15)
        assert got.spots.position_sigma_m == pytest.approx(alone.spots.position_sigma_m, rel=1e-9)


def test_planning_in_worker_processes_equals_one_at_a_time(large):
    ids = [h.id for h in large.heliostats][::50][:24]
    models = {hid: calibrated_record(large, hid) for hid in ids}
    serial = plan_field(large, models, "n", workers=1)
    pooled = plan_field(large, models, "n", workers=2)
    assert len(serial.items) >= 2 * len(ids) and serial.decisions == pooled.decisions == len(ids)
    assert pooled.items == serial.items and pooled.unmeasurable == serial.unmeasurable
    one = plan_heliostat(large, ids[3], models[ids[3]], "n", planner_sun(large), targets=("T1",))
    assert [i.geometry for i in one] == [i.geometry for i in serial.items if i.heliostat_id == ids[3]]


def test_refits_in_worker_processes_equal_one_at_a_time(tmp_path, base):
    from controller.commands.cheap_night import calibrate_from_truth
    from controller.storage.db import CampaignStore
    from controller.storage.field_records import measurements_by_heliostat, record_models
    from simplant.cheap_night import CheapField

    field = CheapField(field_data(base, 12, 1, 3), tmp_path)
    calibrate_from_truth(field, "f")
    with CampaignStore(field.db_path) as store:
        history = measurements_by_heliostat(store)
        assert set(history) == {h.id for h in field.cfg.heliostats}
        assert all(len(v) == 1 and v[0].run_id is not None for v in history.values())
        pooled = refit_models(field.cfg, history, workers=2)
        for hid, ms in history.items():
            alone = fit_measurements(HeliostatKinematics.from_config(field.cfg.heliostat(hid)), ms,
                                     field.cfg.calibration.model)
            assert pooled.models[hid].params == alone.params
            assert pooled.models[hid].detail["covariance_si"] == alone.detail["covariance_si"]
        before = store.count("model_params")
        assert record_models(store, {hid: (history[hid][-1], m) for hid, m in pooled.models.items()}) == 12
        assert store.count("model_params") == before + 12
        latest = store.latest_models()
        assert latest == {h.id: store.latest_model(h.id) for h in field.cfg.heliostats}
        assert latest[field.cfg.heliostats[0].id].params == pooled.models[field.cfg.heliostats[0].id].params


def test_daytime_prediction_pooled_and_bounded_equals_one_at_a_time(demo, monkeypatch):
    ids = [h.id for h in demo.heliostats][:6]
    models = {hid: calibrated_record(demo, hid) for hid in ids}
    path = sun_path(demo.site)
    exact = predicted_daytime(demo, models, path, workers=1)
    pooled = predicted_daytime(demo, models, path, workers=2)
    assert pooled == exact
    # A field too large to keep every draw: the p95 from the histogram is within a bin.
    monkeypatch.setattr(daytime, "EXACT_MAGNITUDES", 0)
    binned = predicted_daytime(demo, models, path, workers=1)
    assert binned.rms == pytest.approx(exact.rms, rel=1e-12)
    assert binned.p95 == pytest.approx(exact.p95, rel=4e-3)
    tally = daytime.DaytimeTally(demo, path)
    tally.update(models)
    assert tally.rms == pytest.approx(exact.rms, rel=1e-12)


def test_standby_offset_grows_with_the_spot_and_its_uncertainty(large):
    """A far heliostat's spot is wide and its position uncertain by more without a model: its
    standby moves out until the parked spot, at 3σ, ends outside the camera's view."""
    cam = large.camera
    frame = TargetFrame.from_config(large.target(), (cam.height_px, cam.width_px))
    near, far = large.heliostats[0], large.heliostats[-1]
    offsets = {}
    for h in (near, far):
        for name, rec in (("prior", None), ("calibrated", calibrated_record(large, h.id))):
            # A configured offset of 1 m: the least; the spot decides how far beyond.
            p = GeometryPointing(h, large.target(), large.light_source(), frame, 1.0, model=rec)
            offsets[h.id, name] = p.standby_offset_m
            assert p.standby_offset_m == pytest.approx(p.park_clearance_m(large.light_source(), rec))
            assert p.standby_offset_m > frame.width_m / 2 + PARK_MARGIN_M
    assert offsets[far.id, "prior"] > offsets[far.id, "calibrated"] > offsets[near.id, "calibrated"]
    assert offsets[far.id, "prior"] > offsets[near.id, "prior"] > offsets[near.id, "calibrated"]


def test_rays_enter_any_box_equals_one_ray_at_a_time():
    rng = np.random.default_rng(0)
    boxes = np.array([[[-4.0, 0.0, 0.0], [4.0, 6.0, 3.0]], [[10.0, 10.0, 0.0], [12.0, 20.0, 5.0]]])
    origins = rng.uniform(-30.0, 30.0, (2000, 3))
    dirs = rng.normal(0.0, 1.0, (2000, 3))
    dirs[::7, 1] = 0.0  # parallel to a pair of slabs
    for max_t in (1.0, 20.0, np.inf):
        want = [zone_entered(o, d, boxes, max_t) is not None for o, d in zip(origins, dirs, strict=True)]
        got = rays_enter_any(origins, dirs, boxes, max_t)
        assert got.tolist() == want and 0 < sum(want) < len(want)


def test_a_large_fields_heliostats_are_found_by_id_and_a_missing_one_named_briefly(large):
    ids = [h.id for h in large.heliostats]
    assert [large.heliostat(hid).id for hid in ids[::397]] == ids[::397]
    with pytest.raises(ConfigError, match=r"no heliostat 'X1' in the configuration \(known: F0001, .*, … "
                                          r"\(2000 in all\)\)"):
        large.heliostat("X1")


def test_model_refit_command_refits_every_heliostat_as_one_at_a_time(tmp_path, base):
    """``heliocal model refit``: the models it records are the fits one at a time, with the
    configuration's fit settings; bad input is one line and exit 2, nothing written."""
    import json
    import subprocess
    import sys

    from controller.commands.cheap_night import calibrate_from_truth
    from controller.storage.db import CampaignStore
    from controller.storage.field_records import measurements_by_heliostat
    from simplant.cheap_night import CheapField

    field = CheapField(field_data(base, 8, 1, 3), tmp_path)
    calibrate_from_truth(field, "f")
    # A different noise setting: the refit must follow the configuration, not the old models.
    data = yaml.safe_load(field.config_path.read_text())
    data["calibration"]["model"] = {**data["calibration"].get("model", {}), "noise_mrad": 0.9}
    config = tmp_path / "refit.yaml"
    config.write_text(yaml.safe_dump(data))
    cfg = parse_config(data, str(config))

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "controller.cli", "model", "refit", *args],
                              cwd=REPO, capture_output=True, text=True)

    r = cli("--config", str(config), "--db", str(field.db_path), "--workers", "2", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["heliostats"] == out["refitted"] == 8 and out["no_model"] == [] and out["measurements"] == 8
    with CampaignStore(field.db_path, readonly=True) as store:
        history = measurements_by_heliostat(store)
        latest = store.latest_models()
    for hid, ms in history.items():
        kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
        alone = fit_measurements(kin, ms, cfg.calibration.model)
        assert latest[hid].params == alone.params and latest[hid].sigma == alone.sigma
    bad = cli("--config", str(config), "--db", str(field.db_path), "--heliostats", "F0001,NOPE")
    assert bad.returncode == 2 and "NOPE" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    with CampaignStore(field.db_path, readonly=True) as store:
        assert store.latest_models() == latest
