"""A pass's slot checks (``slot_parks``) answered from what ``warm_slot_checks`` solved and traced
in batches: the same answers, the same identity steps, and far fewer traces one at a time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from controller.calibration.beams.group import slot_parks
from controller.calibration.beams.identity import identity_step, kept_identity_step, warm_slot_checks
from controller.calibration.beams.slots import pass_layout, spot_reaches_m
from controller.calibration.cycle.beam_safety import BeamSafety
from controller.calibration.cycle.pointing import GeometryPointing
from controller.config import parse_config
from controller.errors import LimitError
from controller.geometry.target_frame import TargetFrame
from simplant.cheap_night import field_data
from tests.calibration.conftest import calibrated_record

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def field():
    base = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    return parse_config(field_data(base, 300, 3, 3, beams=4), "field.yaml")


@pytest.mark.parametrize("lamp", ["L2", "L5"])
def test_slot_checks_warmed_in_batches_answer_as_checked_one_at_a_time(field, lamp, monkeypatch):
    cfg, target = field, field.target()
    frame = TargetFrame.from_config(target, (cfg.camera.height_px, cfg.camera.width_px))
    ids = [h.id for h in cfg.heliostats[::6]]
    models = {h: calibrated_record(cfg, h) for h in ids}
    layout, _ = pass_layout(frame, 4, spot_reaches_m(cfg, target.id, lamp, models, target.center_enu_m),
                            cfg.calibration.planner.view_margin_m)
    assert layout.k > 1
    cal = cfg.calibration

    def at_slot() -> dict:
        return {(t, t % layout.k): GeometryPointing(
            cfg.heliostat(h), target, cfg.light_source(lamp), frame, cal.standby_offset_m, None, cal.model,
            layout.aim(t % layout.k), others=cfg.targets, zones=cfg.person_zones, model=models[h])
            for t, h in enumerate(ids)}

    # Where each stands: beside its standby, across the target, or unknown.
    current = {}
    for i, p in enumerate(at_slot().values()):
        try:
            point = (p.standby_point, frame.center - 2.0 * (p.standby_point - frame.center), None)[i % 3]
            current[p.heliostat.id] = None if point is None else p._steps(point, p.model)
        except LimitError:
            continue
    traces = []
    real = BeamSafety.rays
    monkeypatch.setattr(BeamSafety, "rays", lambda self, poses: traces.append(np.size(poses) // 2)
                        or real(self, poses))
    alone = at_slot()
    want = {key: slot_parks(p, *layout.rank(key[1]), frame, current.get(p.heliostat.id), layout.step_m)
            for key, p in alone.items()}
    one_at_a_time = len(traces)
    together = at_slot()
    warm_slot_checks(together, layout, frame, current)
    traces.clear()
    got = {key: slot_parks(p, *layout.rank(key[1]), frame, current.get(p.heliostat.id), layout.step_m)
           for key, p in together.items()}
    # What is left to trace one at a time: the detours of slews whose direct way is not clear.
    assert len(traces) < one_at_a_time / 2, (len(traces), one_at_a_time)
    assert got == want and any(want.values()) and not all(want.values())
    for key, p in together.items():
        if want[key]:  # the step its round's capture takes, kept: the one traced alone
            rank, a = layout.rank(key[1]), alone[key]
            step, disp = kept_identity_step(p, p.aim_steps(p.model), *rank, frame, layout.step_m)
            alone_step, alone_disp = identity_step(a, a.aim_steps(a.model), *rank, frame, layout.step_m)
            assert step == alone_step and np.array_equal(disp, alone_disp)
