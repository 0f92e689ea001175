"""A lamp change's and a pass's pointings solved in batches (controller.calibration.cycle.warm)
give what each pointing solves alone: the same park clearance and the same steps onto its aim
and standby points — so warming changes how fast, not where a heliostat points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.cycle import pointing as pointing_mod
from controller.calibration.cycle import warm
from controller.calibration.cycle.pointing import GeometryPointing, steps_to_aim
from controller.calibration.cycle.solved import Solved
from controller.config import parse_config
from controller.errors import LimitError
from controller.geometry.pose_batch import aim_steps
from controller.geometry.target_frame import TargetFrame
from simplant.cheap_night import field_data
from tests.calibration.conftest import calibrated_record

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def field():
    base = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    return parse_config(field_data(base, 300, 3, 3, beams=4), "field.yaml")


def _pointings(cfg, lamp: str, models: bool) -> list[GeometryPointing]:
    frame = TargetFrame.from_config(cfg.target(), (cfg.camera.height_px, cfg.camera.width_px))
    aim = np.asarray(cfg.target().center_enu_m, float) + [2.0, 0.0, 1.0]
    cal = cfg.calibration
    return [GeometryPointing(h, cfg.target(), cfg.light_source(lamp), frame, cal.standby_offset_m, None,
                             cal.model, aim, model=calibrated_record(cfg, h.id) if models else None)
            for h in cfg.heliostats[::15]]


@pytest.mark.parametrize("lamp", ["L2", "L5"])
def test_warmed_clearances_and_steps_are_those_solved_one_at_a_time(field, lamp, monkeypatch):
    monkeypatch.setattr(pointing_mod, "_CLEARANCES", Solved(10_000))
    alone = {id(p.heliostat): p.park_clearance_m(p.source, p.model) for p in _pointings(field, lamp, True)}
    for name in ("_CLEARANCES", "_AIMS"):  # empty stores, the same for both modules
        store = Solved(10_000)
        monkeypatch.setattr(pointing_mod, name, store)
        monkeypatch.setattr(warm, name, store)
    ps = _pointings(field, lamp, True)
    batches = []
    monkeypatch.setattr(warm, "aim_steps", lambda *a, **k: batches.append(1) or aim_steps(*a, **k))
    warm.warm_aims(ps)
    assert len(batches) == 1  # one lamp: one batch (each heliostat's direction to it differs)
    solved = 0
    for p in ps:
        key = p._clearance_key(p.source, p.model)
        assert warm._CLEARANCES.peek(key, (p.heliostat, p.model_settings)) == pytest.approx(
            alone[id(p.heliostat)], abs=1e-9)
        for point in (p.aim_point, *p.side_points()):
            kept = warm._AIMS.peek(p._aim_key(point, p.model), (p.heliostat,))
            try:
                scalar = steps_to_aim(p.kin, p.model, p.source_dir, point, p.source_pos)
            except LimitError:
                assert kept is None  # out of reach: left to the scalar solve, which names the axis
                continue
            assert kept == scalar
            solved += 1
    assert solved >= 2 * len(ps)


def test_heliostats_without_a_model_are_left_to_the_scalar_solve(field, monkeypatch):
    monkeypatch.setattr(warm, "_AIMS", Solved(10_000))
    monkeypatch.setattr(warm, "_CLEARANCES", Solved(10_000))
    ps = _pointings(field, "L2", False)
    warm.warm_aims(ps)
    assert all(warm._AIMS.peek(p._aim_key(p.aim_point, None), (p.heliostat,)) is None for p in ps)
    warm.warm_clearances(ps)  # clearances do not need the aim solve: kept for them too
    assert all(warm._CLEARANCES.peek(p._clearance_key(p.source, None), (p.heliostat, p.model_settings))
               is not None for p in ps)
