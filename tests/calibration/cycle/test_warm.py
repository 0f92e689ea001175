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
from controller.errors import HeliocalError, LimitError
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
        aims = {h: aim for h, aim, _ in reach}
        warm.warm_slews([(p, (current.get(p.heliostat.id), aims[p.heliostat.id])) for p in together
                         if p.heliostat.id in aims])
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


def test_approaches_warmed_in_batches_are_those_checked_one_heliostat_at_a_time(field, monkeypatch):
    """Before it answers, ``aim_steps`` traces the approach from standby to the aim through the
    person zones. ``warm_approaches`` traces a pass's approaches in batches and keeps the aim of
    those that enter no zone; one that enters a zone is not kept, and ``aim_steps`` still
    refuses it, naming the zone."""
    from controller.calibration.cycle.beam_safety import UnsafePath

    t = field.target()
    zones = (*field.person_zones, _landing(field))
    def pointings() -> list[GeometryPointing]:
        return [GeometryPointing(p.heliostat, t, p.source, p.frame, field.calibration.standby_offset_m, None,
                                 field.calibration.model, p.aim_point, others=field.targets, zones=zones,
                                 model=p.model) for p in _pointings(field, "L2", True)]

    alone, together = pointings(), pointings()
    warm.warm_approaches(together)
    kept = refused = 0
    for a, p in zip(alone, together, strict=True):
        # What aim_steps answers without tracing: kept by the batch.
        held = p._poses.get(p._with_model(("aim", p._aim_key(p.aim_point, p.model))))
        try:
            want = a.aim_steps(a.model)
        except UnsafePath as exc:
            assert held is None and "landing" in str(exc)  # not kept: aim_steps refuses, naming the zone
            refused += 1
            continue
        except LimitError:
            assert held is None
            continue
        assert held == want
        kept += 1
    assert kept and refused


def _landing(field):
    """A landing just in front of the target's east half: approaches from the east cross it."""
    from controller.config import PersonZone

    t = field.target()
    c, nrm = np.asarray(t.center_enu_m, float), np.asarray(t.normal, float)
    nrm = nrm / np.linalg.norm(nrm)
    east = np.array([1.0, 0.0, 0.0])
    lo = c + 3.0 * nrm + 0.5 * east - [0, 0, 2.0]
    hi = c + 5.0 * nrm + (t.width_m / 2 + 6.0) * east + [0, 0, 2.0]
    return PersonZone(id="landing", min_enu_m=tuple(np.minimum(lo, hi)), max_enu_m=tuple(np.maximum(lo, hi)),
                      margin_m=0.5)


@pytest.mark.parametrize("lamp", ["L2", "L5"])
def test_waits_warmed_in_batches_are_those_checked_one_heliostat_at_a_time(field, lamp, monkeypatch):
    """As it prepares, a cycle asks whether its heliostat may wait where it stands rather than
    park first (``may_wait_at``): ``warm_waits`` traces a pass's in batches and keeps the answers
    each pointing's own check gives — yes beside the target, no across it or past another
    target — which the cycle then gets without tracing."""
    from controller.calibration.cycle.beam_safety import BeamSafety

    t = field.target()

    def pointings() -> list[GeometryPointing]:
        return [GeometryPointing(p.heliostat, t, p.source, p.frame, field.calibration.standby_offset_m, None,
                                 field.calibration.model, p.aim_point, others=field.targets,
                                 zones=(*field.person_zones, _landing(field)), model=p.model)
                for p in _pointings(field, lamp, True)]

    alone, together = pointings(), pointings()
    reach = {}
    for p in alone:
        try:
            reach[p.heliostat.id] = (p.aim_steps(p.model), p.standby_steps(p.model))
        except HeliocalError:  # out of reach, or its approach enters the landing: parked first
            continue
    answers, traces, real = [], [], BeamSafety.rays
    for where in ("other side", "beside", "across", "below", "above"):
        current = {}
        for p in alone:
            f, s = p.frame, p.standby_point
            point = {"other side": p.side_points()[1], "beside": s + 0.7 * f.v,
                     "across": f.center - 0.3 * (s - f.center), "below": s - 6.0 * f.v,
                     "above": f.center + 9.0 * f.v}[where]
            try:
                current[p.heliostat.id] = p._steps(point, p.model)
            except LimitError:
                continue
        warm.warm_waits(together, current)
        monkeypatch.setattr(BeamSafety, "rays", lambda self, poses: traces.append(1) or real(self, poses))
        for a, p in zip(alone, together, strict=True):
            hid = a.heliostat.id
            if hid not in reach or hid not in current:
                continue
            aim, standby = reach[hid]
            n = len(traces)
            got = p.may_wait_at(current[hid], standby, aim, p.path_margin_m())
            assert len(traces) == n  # answered from the batch
            assert got == a.may_wait_at(current[hid], standby, aim, a.path_margin_m()), (hid, where)
            answers.append(got)
        monkeypatch.undo()
    assert any(answers) and not all(answers)


def test_a_wait_whose_approach_crosses_a_person_zone_is_refused_by_the_batch_too(field):
    """Parked on the far side of the target, a heliostat may be clear where it stands and yet
    not approach from there: a stair landing on the way. ``warm_waits`` refuses it as
    ``may_wait_at`` does, and lets the same heliostat wait without the landing."""
    from controller.config import PersonZone

    refused = 0
    for base in _pointings(field, "L2", True)[:8]:
        try:
            aim, standby = base.aim_steps(base.model), base.standby_steps(base.model)
            pose = base._steps(base.side_points()[1], base.model)
        except LimitError:
            continue
        f = base.frame
        c, b = base.rays([base._sweep(pose, aim)[60]])
        hit = float((f.center - c[0]) @ f.normal) / float(b[0] @ f.normal)
        at = c[0] + (hit - 15.0) * b[0]  # 15 m before the approach's beam meets the target
        stair = PersonZone(id="stair", min_enu_m=tuple(at - 0.3), max_enu_m=tuple(at + 0.3), margin_m=0.0)
        cal = field.calibration
        for zones in ((), (stair,)):
            alone, together = (GeometryPointing(base.heliostat, base.target, base.source, f,
                                                cal.standby_offset_m, None, cal.model, base.aim_point,
                                                zones=zones, model=base.model) for _ in range(2))
            warm.warm_waits([together], {base.heliostat.id: pose})
            key = together.wait_key(pose, standby, aim, together.path_margin_m())
            want = alone.may_wait_at(pose, standby, aim, alone.path_margin_m())
            assert together._waits.get(key, False) == want
            here = alone.clear_to_wait(*alone.rays([pose, standby]), alone.path_margin_m())
            if zones and not want and here:
                refused += 1  # clear where it stands, refused for its approach
    assert refused
