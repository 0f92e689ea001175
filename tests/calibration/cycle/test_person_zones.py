"""Person zones (config ``person_zones``): no reflected beam may enter them — at standby, on a
slew, on the approach or at a planned aim point. Checked against the simulated plant's truth
(its own sampled ray, simplant.safety) over the in-process drives of simplant.cheap_night."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.campaign.lamp_change import LampChanger, Standby
from controller.calibration.cycle.beam_safety import UnsafePath
from controller.calibration.night.planner import plan_night
from controller.commands.cheap_night import cheap_field
from controller.config import load_config
from controller.errors import ConfigError, LimitError
from controller.storage.db import CampaignStore
from simplant.cheap_night import CheapField, field_data
from tests.calibration.conftest import calibrated_record

ROOT = Path(__file__).resolve().parents[3]
# Beside the upper target, where standby beams on its east side pass (a stair landing).
LANDING = {"id": "landing", "min_enu_m": [10.0, -2.0, 37.0], "max_enu_m": [14.0, 3.0, 43.0], "margin_m": 1.0}


@pytest.fixture(scope="module")
def base() -> dict:
    return yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())


def _field(base, tmp_path, zones, n=8, targets=1):
    data = field_data(base, n, targets, 1, span_deg=70.0)  # the zones below are placed for this layout
    data["person_zones"] = zones
    return CheapField(data, tmp_path)


def _park_all_at_standby(field, cfg, lamp="L1"):
    """Every heliostat that can, at its standby under ``lamp`` as ``cfg`` (the controller's
    view of the plant) places it; the ids parked."""
    plant = field.plant
    plant.set_light(lamp)
    product = replace(cheap_field(field, CampaignStore(field.db_path)), cfg=cfg)
    drive_of = product.drive
    changer = LampChanger(product)
    parked = []
    for h in cfg.heliostats:
        st = drive_of(h.id).status()
        try:
            pose = changer.pointing(h.id, lamp, Standby(), (st.az_steps, st.el_steps)).standby_steps(None)
        except (LimitError, UnsafePath):
            continue
        drive_of(h.id).move_and_wait(*pose, timeout_s=600, time=field.time)
        parked.append(h.id)
    return parked


def test_standby_poses_keep_their_beams_out_of_a_person_zone(base, tmp_path):
    # A controller that does not know the zone parks standby beams across the landing (the
    # plant's truth, against the bare box); knowing it, none, and every heliostat still parks.
    blind = _field(base, tmp_path / "blind", [LANDING])
    unaware = blind.cfg.model_copy(update={"person_zones": ()})
    assert len(_park_all_at_standby(blind, unaware)) == len(blind.cfg.heliostats)
    assert blind.plant.safety.in_person_zones()

    field = _field(base, tmp_path / "zoned", [LANDING])
    assert len(_park_all_at_standby(field, field.cfg)) == len(field.cfg.heliostats)
    assert field.plant.safety.in_person_zones() == []


def _crosses(a, b, box, step_m=0.05) -> bool:
    """Whether the segment a→b (m ENU) passes through ``box`` (config mapping), sampled."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(2, int(np.linalg.norm(b - a) / step_m))
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    return bool(np.all((pts >= box["min_enu_m"]) & (pts <= box["max_enu_m"]), axis=1).any())


def test_planned_geometries_keep_their_beams_out_of_a_person_zone(base, tmp_path):
    # A crane between the west heliostats and the target, across their beams.
    crane = {"id": "crane", "min_enu_m": [-22.0, 4.0, 14.0], "max_enu_m": [-12.0, 14.0, 26.0],
             "margin_m": 0.5}
    field = _field(base, tmp_path, [crane])
    pos = {h.id: h.position_enu_m for h in field.cfg.heliostats}
    unaware = field.cfg.model_copy(update={"person_zones": ()})
    models = {h.id: calibrated_record(field.cfg, h.id) for h in field.cfg.heliostats}
    blind = plan_night(unaware, models, "n1")
    assert any(_crosses(pos[i.heliostat_id], i.geometry.aim_enu, crane) for i in blind)
    plan = plan_night(field.cfg, models, "n1")
    assert plan and not any(_crosses(pos[i.heliostat_id], i.geometry.aim_enu, crane) for i in plan)


def test_an_approach_through_a_person_zone_is_refused_before_anything_moves(base, tmp_path):
    # A platform in front of the target's east half: the approach from the east standby sweeps
    # the beam through it on its way onto the target.
    platform = {"id": "platform", "min_enu_m": [4.5, 0.1, 38.0], "max_enu_m": [11.0, 0.4, 42.0],
                "margin_m": 0.0}
    field = _field(base, tmp_path, [platform])
    cfg = field.cfg
    changer = LampChanger(cheap_field(field, CampaignStore(field.db_path)))
    refused = 0
    for h in cfg.heliostats:
        p = changer.pointing(h.id, "L1", Standby(), (500, 500))
        unaware = changer.pointing(h.id, "L1", Standby(), (500, 500))
        unaware.zones, unaware.zone_ids = unaware.zones[:0], []
        if p.standby_point[0] > 0:  # approaching from the east, across the platform
            for _ in range(2):  # refused again when asked again (the pointing keeps its answer)
                with pytest.raises(UnsafePath, match=f"{h.id}: the approach .* person zone 'platform'"):
                    p.aim_steps(None)
            refused += 1
        else:
            assert p.aim_steps(None) == unaware.aim_steps(None)
    assert refused


def test_slews_go_around_a_person_zone(base, tmp_path):
    # A small platform just in front of the tower, west of the target: the diagonal slew from
    # the west standby to a point low on the east passes some beams through it; going down
    # first, then across, does not.
    platform = {"id": "platform", "min_enu_m": [-13.4, 0.1, 34.6], "max_enu_m": [-11.9, 0.4, 35.7],
                "margin_m": 0.0}
    field = _field(base, tmp_path, [platform])
    cfg = field.cfg
    changer = LampChanger(cheap_field(field, CampaignStore(field.db_path)))
    crossing = detoured = 0
    for h in cfg.heliostats:
        p = changer.pointing(h.id, "L1", Standby(), (500, 500))
        start = p.kin.aim(p.source_dir, p.aim_point + np.array([-12.0, 0.0, 0.0]))
        end = p.kin.aim(p.source_dir, p.aim_point + np.array([12.0, 0.0, -12.0]))
        if not any(p.beam_in_zone(*q) is not None for q in p._sweep(start, end)):
            continue
        crossing += 1
        path = p.path_to(start, end)
        detoured += len(path) > 1
        a = np.asarray(start, float)
        speed = np.array([h.axes.azimuth.speed_steps_per_s, h.axes.elevation.speed_steps_per_s])
        for wp in path:  # each axis at its own speed, sampled here
            b = np.asarray(wp, float)
            dur = np.abs(b - a) / speed
            for t in np.linspace(0.0, dur.max(), 300):
                pose = a + np.minimum(1.0, t / np.maximum(dur, 1e-12)) * (b - a)
                assert p.beam_in_zone(*pose) is None, (h.id, wp)
            a = b
    assert crossing and detoured == crossing, (crossing, detoured)


@pytest.mark.parametrize("zone, message", [
    ({"id": "z", "min_enu_m": [0, 0, 5], "max_enu_m": [1, 1, 5]}, "min_enu_m must lie below max_enu_m"),
    ({"id": "z", "min_enu_m": [0, 0, 0], "max_enu_m": [1, 1, 1], "margin_m": -1}, "margin_m"),
    ({"id": "z", "min_enu_m": [0, 0, 0], "max_enu_m": [1, 1, 1], "height": 3}, "height"),
])
def test_a_bad_person_zone_is_refused_naming_the_file_and_key(base, tmp_path, zone, message):
    data = dict(base, person_zones=[zone])
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=rf"{path}.*(person_zones.*{message}|{message}.*person_zones)"):
        load_config(path)


def test_duplicate_person_zone_ids_are_refused(base, tmp_path):
    data = dict(base, person_zones=[LANDING, LANDING])
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"person_zones\[1\]\.id: duplicate id 'landing'"):
        load_config(path)
