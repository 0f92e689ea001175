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


def _pointings(cfg, lamp: str, models: bool, zones: bool = False) -> list[GeometryPointing]:
    frame = TargetFrame.from_config(cfg.target(), (cfg.camera.height_px, cfg.camera.width_px))
    aim = np.asarray(cfg.target().center_enu_m, float) + [2.0, 0.0, 1.0]
    cal = cfg.calibration
    return [GeometryPointing(h, cfg.target(), cfg.light_source(lamp), frame, cal.standby_offset_m, None,
                             cal.model, aim, model=calibrated_record(cfg, h.id) if models else None,
                             **({"others": cfg.targets, "zones": cfg.person_zones} if zones else {}))
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


@pytest.mark.parametrize("lamp", ["L2", "L5"])
def test_slews_warmed_in_batches_are_those_traced_one_heliostat_at_a_time(field, lamp, monkeypatch):
    """A pass's slot checks ask for each heliostat's slews to standby from where it stands and
    from its aim (``slot_parks``): ``warm_slews`` traces them for all heliostats in a few
    evaluations of the model and keeps exactly what each pointing's own ``warm_paths`` keeps —
    the clear direct slews, not those that cross a target or pass its corner inside the path's
    margin (each heliostat's own) — so the checks answer the same."""
    traces = []
    real = warm.normal_and_center
    monkeypatch.setattr(warm, "normal_and_center", lambda *a: traces.append(1) or real(*a))
    monkeypatch.setattr(warm, "SLEW_BATCH", 7)
    alone, together = _pointings(field, lamp, True), _pointings(field, lamp, True)
    reach = []
    for p in alone:
        try:
            reach.append((p.heliostat.id, p.aim_steps(p.model), p.standby_steps(p.model)))
        except LimitError:  # out of reach: left to its slot's check, which says why
            continue
    # Where each stands: across the target (its slew crosses it), 0.5 to 6 m below it (its slew to
    # the side passes the target's corner inside the path's margin or not), at standby, unknown.
    wheres = [lambda p: p.frame.center - 3.0 * (p.standby_point - p.frame.center), None]
    wheres += [lambda p, d=d: p.frame.center - (p.target.height_m / 2 + d) * p.frame.v
               for d in (0.5, 1.0, 2.0, 3.0, 4.5, 6.0)]
    for n, where in enumerate(wheres):
        current = {}
        for p in alone:
            try:
                current[p.heliostat.id] = None if where is None else p._steps(where(p), p.model)
            except LimitError:
                continue
        warm.warm_slews(together, current)
        if not n:
            assert len(traces) == -(-len(reach) // 7)  # one group: a lamp, the targets, the zones
        for a in alone:
            if (hit := next((r for r in reach if r[0] == a.heliostat.id), None)) is not None:
                a.warm_paths((current.get(a.heliostat.id), hit[1]), hit[2])

    def paths(p) -> dict:
        return {k: v for k, v in p._poses.items() if k[0] == "path"}

    kept = unkept = 0
    for a, t in zip(alone, together, strict=True):
        assert paths(t) == paths(a), a.heliostat.id
        kept += len(paths(t))
        unkept += sum(len(t.direct_slews((t._steps(w(t), t.model),), t.standby_steps(t.model))[0])
                      for w in wheres[2:]) if any(r[0] == t.heliostat.id for r in reach) else 0
    assert kept and unkept  # clear slews kept; the others left to path_to's detours


@pytest.mark.parametrize("lamp", ["L2", "L5"])
def test_approaches_warmed_in_batches_are_those_traced_one_heliostat_at_a_time(field, lamp, monkeypatch):
    """A pass asks each pointing for its aim, whose approach from standby is traced through the
    person zones (``aim_steps``): ``warm_aims(..., approaches=True)`` traces them for all heliostats
    in a few evaluations of the model and keeps the aims whose approach enters no zone — the
    aims each pointing finds alone — so that ``aim_steps`` then traces nothing."""
    assert field.person_zones  # the demo's zones: every approach is traced through them
    alone, together = _pointings(field, lamp, True, zones=True), _pointings(field, lamp, True, zones=True)
    expected = {}
    for p in alone:
        try:
            expected[p.heliostat.id] = p.aim_steps(p.model)
        except LimitError:
            continue
    traces = []
    real = warm.normal_and_center
    monkeypatch.setattr(warm, "normal_and_center", lambda *a: traces.append(1) or real(*a))
    monkeypatch.setattr(warm, "SLEW_BATCH", 5)
    warm.warm_aims(together, approaches=True)
    assert len(traces) == -(-len(expected) // 5)  # one group: a lamp, the targets, the zones
    for p in together:
        monkeypatch.setattr(p, "in_zone", lambda *_: pytest.fail("an approach traced again"))
        if p.heliostat.id in expected:
            assert p.aim_steps(p.model) == expected[p.heliostat.id], p.heliostat.id
    assert len(expected) > 5
