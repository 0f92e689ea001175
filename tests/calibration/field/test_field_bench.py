"""The field benchmark's machinery on a few heliostats: a planned night through the real runner
over in-process drives and cheap cameras (simplant.cheap_night), checked against the plant's
truth."""

from __future__ import annotations

import dataclasses
import os
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from controller.calibration.beams.slots import pass_layout, spot_reaches_m, target_frame
from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.campaign.runner import Campaign, CampaignOptions
from controller.calibration.night.passes import night_passes
from controller.calibration.night.planner import plan_field
from controller.commands.cheap_night import WATCH_S, cheap_field, run_cheap_night, watch_budget
from controller.commands.field import open_store
from controller.commands.sim.field import OnTarget, run_planned_night, seed_from_truth, strays
from controller.devices.drive import AxisLimits, DriveLimits
from controller.errors import LimitError
from controller.storage.db import CampaignStore
from simplant.cheap_night import CheapField, field_data
from simplant.devices.inproc import InProcPool
from tests.conftest import scaled_s

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def base() -> dict:
    return yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())


def test_night_stopped_by_its_budget(base, tmp_path):
    """A night whose budget ends before its work does is stopped by the budget watcher (which
    waits the rest of the budget at the clock's fastest rate rather than checking every 20 ms):
    it says so, and it was asked to stop no later than WATCH_S x speedup plant s after the end,
    plus the parking of the heliostats it had in flight."""
    field = CheapField(field_data(base, 6, 2, 1), tmp_path, speedup=1000.0)
    whole = run_cheap_night(field, None, "n1", budget_s=8 * 3600.0)
    assert not whole.stopped_by_budget
    field = CheapField(field_data(base, 6, 2, 1), tmp_path / "short", speedup=1000.0)
    budget = 0.25 * whole.plant_s
    night = run_cheap_night(field, None, "n1", budget_s=budget)
    assert night.stopped_by_budget
    assert len(night.measured) < len(whole.measured)
    assert budget <= night.plant_s < whole.plant_s


def test_a_nights_cycles_run_opencv_on_their_own_threads_and_python_on_one_core(base, tmp_path):
    """While a night's cycles measure, OpenCV keeps no worker pool of its own (it would only
    spin between the cycles' calls) and every cycle runs on one core (where the machine has
    two); the process's settings are back once the night is over."""

    class Threads(CampaignObserver):
        def __init__(self) -> None:
            self.seen: list[int] = []
            self.cores: set[frozenset[int]] = set()

        def measured(self, heliostat_id, measurement) -> None:
            self.seen.append(cv2.getNumThreads())
            self.cores.add(frozenset(os.sched_getaffinity(0)))

    before = cv2.getNumThreads()
    everywhere = os.sched_getaffinity(0)
    cv2.setNumThreads(2)
    try:
        field = CheapField(field_data(base, 4, 2, 1), tmp_path, speedup=1000.0)
        threads = Threads()
        night = run_planned_night(field, None, "n1", budget_s=8 * 3600.0, observers=[threads])
        assert len(night.measured) == 4 and len(threads.seen) >= 4
        assert set(threads.seen) == {1}
        assert cv2.getNumThreads() == 2
        if len(everywhere) > 1:  # each pass's campaign takes the core its first thread runs on
            assert threads.cores and all(len(c) == 1 and c <= everywhere for c in threads.cores)
        assert os.sched_getaffinity(0) == everywhere
    finally:
        cv2.setNumThreads(before)


def test_budget_watcher_ends_with_the_night(base, tmp_path):
    """A night that ends first ends its watcher at once, however far the budget's end is, and
    the night is not stopped; one whose end is reached is stopped once, on plant time."""
    field = CheapField(field_data(base, 2, 1, 1), tmp_path, speedup=1000.0)
    done, stops = threading.Event(), []
    watcher, over = watch_budget(field, field.time.now() + 1e7, done, lambda: stops.append(1), "w")
    done.set()
    watcher.join(scaled_s(5.0))
    assert not watcher.is_alive() and not over.is_set() and stops == []
    end = field.time.now() + 2.0
    watcher, over = watch_budget(field, end, threading.Event(), lambda: stops.append(1), "w")
    assert over.wait(scaled_s(5.0))
    watcher.join(scaled_s(5.0))
    assert stops == [1] and field.time.now() >= end
    assert WATCH_S * field.plant.clock.speedup <= 20.0  # the most a stop may come late, plant s


def test_small_field_night_one_beam_per_target(base, tmp_path):
    """The product's night from scratch: no model yet, so the heliostats are calibrated at the
    calibration lamp first, then planned and measured; every capture sees one beam, and every
    recorded centroid is where the hidden heliostat's beam truly hit."""
    field = CheapField(field_data(base, 6, 2, 1), tmp_path, speedup=1000.0)
    night = run_cheap_night(field, None, "n1", budget_s=8 * 3600.0)

    assert not night.stopped_by_budget
    assert night.summary.first_calibrated == [h.id for h in field.cfg.heliostats]
    assert night.results[0].name == "n1/calibration" and night.summary.unmeasurable == []
    assert all(r.status == "finished" for r in night.results)
    assert night.planned == 6  # one geometry per heliostat, all measurable after the calibration
    assert len(night.measured) == 6
    assert {h for h, _ in night.measured} == {h.id for h in field.cfg.heliostats}
    assert night.per_target == {"T1": 3, "T2": 3}
    assert night.plant_s > 0
    # The plant's truth: every capture saw exactly one beam on its target.
    for tid, captures in night.beams_in_view.items():
        assert captures and all(len(b) <= 1 for b in captures), tid
        assert sum(len(b) == 1 for b in captures) >= 3, tid
    # The recorded centroid is where the hidden heliostat's true beam hit (cheap camera's truth).
    store = CampaignStore(field.db_path, readonly=True)
    try:
        got = [(m.heliostat_id, np.asarray(m.centroid_enu)) for m in store.measurements()]
    finally:
        store.close()
    truth = {tuple(np.round(p, 6)) for cam in field.cameras.values() for hits in cam.hits
             for p in hits.values()}
    truth = np.array(sorted(truth))
    assert len(got) >= 12  # the calibration's and the night's
    for hid, c in got:
        assert np.min(np.linalg.norm(truth - c, axis=1)) < 0.1, hid  # m, about one pixel (7 cm)


def test_inproc_drive_firmware_enforces_its_soft_limits(base, tmp_path):
    field = CheapField(field_data(base, 1, 1, 1), tmp_path)
    h = field.cfg.heliostats[0]
    fw = h.axes.azimuth.soft_limits
    # The controller's limits wider than the firmware's: the firmware refuses, nothing moves.
    wide = DriveLimits(AxisLimits(0, fw.max_steps + 400), AxisLimits(0, 68700))
    drive = InProcPool.for_plant(field.plant).drive(h.link, wide)
    before = drive.status()
    with pytest.raises(LimitError, match="OUT_OF_RANGE"):
        drive.move_abs(fw.max_steps + 200, before.el_steps)
    after = drive.status()
    assert (after.az_target, after.el_target) == (before.az_target, before.el_target)
    drive.move_abs(fw.max_steps, before.el_steps)
    assert drive.status().az_target == fw.max_steps


def test_several_beams_on_the_cheap_field_and_a_beam_not_the_captures_is_counted(base, tmp_path):
    """K = 2 on the cheap field: rounds share captures, every spot is measured where its own
    beam hit, and no capture holds a beam that is not the capture's; a watcher that expects no
    beam on the targets counts every beam of every capture as a stray."""
    field = CheapField(field_data(base, 10, 1, 1, beams=2), tmp_path, speedup=1000.0)
    seed_from_truth(field, "n0")
    watch = OnTarget(field, None)
    night = run_planned_night(field, None, "n1", budget_s=8 * 3600.0, observers=[watch])
    store = CampaignStore(field.db_path, readonly=True)
    try:
        rounds = [store.campaign_by_name(r.name).meta.get("beams", {}).get("rounds", 0)
                  for r in night.results]
    finally:
        store.close()
    # Two start stowed where no safe slew leaves the targets' plane (UnsafePath): parked, not measured.
    assert len(night.measured) >= 8 and sum(rounds) >= 2
    assert max(len(b) for b in field.cameras["T1"].beams_in_view) == 2  # two beams shared a capture
    assert strays(field, 2, {})[0] == 0 and watch.strays_by_heliostat() == []
    assert watch.elsewhere == []  # every spot was credited to its own beam (the plant's truth)
    acc = watch.centroid_errors()  # every measurement's centroid against its own beam's true hit
    assert acc["measurements"] == len(night.measured) and 0 <= acc["p50"] <= acc["p99"] <= acc["max"] <= 1.0
    assert watch.cpu_s > 0.0  # the truth watcher's CPU, kept apart from the controller's
    watch.on.clear()
    last = dict(watch.state)
    watch.state_changed = lambda *_: None  # a watcher that expects no beam anywhere
    for cam in field.cameras.values():
        cam.beams_in_view, cam.strays = [], []
    field.cameras["T1"].capture()  # the beams parked off the target: nothing in view, nothing stray
    assert strays(field, 2, {}) == (0, 1, [])

    # One heliostat back at its last measured pose under that measurement's lamp: a stray the
    # watcher explains — which heliostat, on which target, under which lamp, in which state.
    store = CampaignStore(field.db_path, readonly=True)
    try:
        m = store.measurements()[-1]
    finally:
        store.close()
    lamp = next(s.id for s in field.cfg.light_sources
                if s.kind == "lamp" and np.allclose(s.position_enu_m, m.source_pos_enu))
    h = field.cfg.heliostat(m.heliostat_id)
    drive = InProcPool.for_plant(field.plant).drive(h.link, DriveLimits.from_axes(h.axes))
    field.plant.switch_lamp(lamp, True)
    drive.move_and_wait(m.az_steps, m.el_steps, timeout_s=600.0, time=field.time)
    field.cameras["T1"].capture()
    field.cameras["T1"].capture()
    assert m.heliostat_id in field.cameras["T1"].strays[-1]
    got = [s for s in watch.strays_by_heliostat() if s["heliostat"] == m.heliostat_id]
    runs = [run for res in night.results for run in res.runs if run.heliostat_id == m.heliostat_id]
    assert got == [{"heliostat": m.heliostat_id, "target": "T1", "lamp": lamp, "captures": 2,
                    "first_plant_s": got[0]["first_plant_s"], "last_plant_s": got[0]["last_plant_s"],
                    "meant_targets": ["T1"], "states": {last[m.heliostat_id]: 2},
                    "first_hit_enu_m": [round(v, 3) for v in field.cameras["T1"].hits[-2][m.heliostat_id]],
                    "steps": got[0]["steps"], "last_run": got[0]["last_run"]}]
    brief = got[0]["last_run"]
    assert (brief["status"], brief["end_plant_s"]) == (runs[-1].status, runs[-1].end_s)
    st, slack = drive.status(), max(h.axes.azimuth.backlash_steps, h.axes.elevation.backlash_steps)
    assert np.abs(np.subtract(got[0]["steps"], (st.az_steps, st.el_steps))).max() <= slack
    assert got[0]["last_plant_s"] >= got[0]["first_plant_s"] > 0

    # A spot credited to the wrong beam: a measurement of another heliostat at this one's true hit.
    other = next(h.id for h in field.cfg.heliostats if h.id != m.heliostat_id)
    hit = field.cameras["T1"].hits[-1][m.heliostat_id]
    watch.measured(other, dataclasses.replace(m, centroid_enu=hit))
    watch.measured(m.heliostat_id, dataclasses.replace(m, centroid_enu=hit))  # its own: not counted
    (got,) = watch.elsewhere
    assert got["own_hit_m"] is None or got["own_hit_m"] > 1.0  # its own beam nowhere near, if in view
    assert {k: got[k] for k in ("heliostat", "plant_s", "nearest", "nearest_hit_m")} == {
        "heliostat": other, "plant_s": round(m.plant_time_s, 1), "nearest": m.heliostat_id,
        "nearest_hit_m": 0.0}


class _FreezeSecond(CampaignObserver):
    """Freezes the spot of the campaign's second heliostat in the queue (``SpotTruth.freeze``):
    its spot never moves with its identity step, so it is measured alone, staying at its slot."""

    def __init__(self, field) -> None:
        self.field, self.queue = field, []

    def campaign_started(self, campaign_id, queue, done) -> None:
        self.queue = list(queue)
        self.field.plant.spot_truth.freeze(self.queue[1])


def test_a_beam_back_for_a_correction_leaves_the_target_to_one_waiting_to_be_measured_alone(base, tmp_path):
    """Several beams (K = 4, at least two slots) and a correction after every look: the first round's
    second spot cannot be told apart (frozen) and waits at its slot to be measured alone, while
    the first heliostat, measured in the round, comes back for its correction. It must leave the
    target: the one waiting cannot take it while its beam is on it, and no round forms without
    the one waiting (the K-slot stall: both waited until the capturing state's timeout)."""
    data = field_data(base, 16, 1, 1, beams=4)
    data["calibration"].update(tolerance_mrad=0.01, max_iterations=2)  # every look is corrected once
    field = CheapField(data, tmp_path, speedup=1000.0)
    seed_from_truth(field, "n0")
    ids = [h.id for h in field.cfg.heliostats]
    frozen, watch = _FreezeSecond(field), OnTarget(field, None)
    store = open_store(field.db_path)
    try:
        c = Campaign(cheap_field(field, store), CampaignOptions(
            name="c1", timeouts={"capturing": scaled_s(20.0), "standby": scaled_s(30.0)}),
            heliostat_ids=ids, observers=[frozen, watch])
        r = c.run()
    finally:
        store.close()
    # The first two of the queue share the first round, each at its own slot.
    assert c.slots is not None and c.slots.k >= 2 and c.group.gate.slot(1) != c.group.gate.slot(0)
    # Nobody stalled: every run measured; a look within the 0.01 mrad tolerance (rare, under a
    # loaded machine's timing) ends its cycle calibrated without a correction.
    ended = {run.status for run in r.runs}
    assert ended <= {"not_converged", "calibrated"}, [run.fault_cause for run in r.runs]
    assert all(run.iterations == (1 if run.status == "calibrated" else 2) for run in r.runs)
    # The frozen one measured alone where it stood first, the first one's correction alone after it.
    first = next(run for run in r.runs if run.heliostat_id == frozen.queue[0])
    assert c.group.alone[0] == frozen.queue[1]
    assert frozen.queue[0] in c.group.alone[1:] or first.status == "calibrated"
    assert strays(field, 4, {})[0] == 0  # never a beam in view that was not the capture's


def test_a_pass_in_two_tiers_of_slots_measures_every_spot_where_its_own_beam_hit(base, tmp_path):
    """K = 4 under a far lamp: the pass's smaller spots share rounds of four slots, the larger
    ones rounds of two spaced for them (slots.pass_layout), the tiers in turn; every beam is
    measured, no capture holds a beam that is not the capture's, and every recorded centroid
    is where the heliostat's own beam hit (the cheap camera's truth)."""
    field = CheapField(field_data(base, 60, 1, 1, beams=4), tmp_path, speedup=1000.0)
    ids = [h.id for h in field.cfg.heliostats]
    seed_from_truth(field, "n0")
    store = CampaignStore(field.db_path, readonly=True)
    try:
        models = store.latest_models(ids)
    finally:
        store.close()
    plan = plan_field(field.cfg, {h: models.get(h) for h in ids}, "n0/night-1", night_index=1)
    tiered = None
    for p in night_passes(plan.items, "n0/night-1"):
        reach = spot_reaches_m(field.cfg, p.target, p.lamp, {h: models.get(h) for h in p.aims},
                               field.cfg.target(p.target).center_enu_m)
        layout, member = pass_layout(target_frame(field.cfg, p.target), 4, reach,
                                     field.cfg.calibration.planner.view_margin_m)
        if len(layout.tier_sizes) > 1 and min(np.bincount(member[member >= 0])) > 0:
            tiered = (p.lamp, layout.tier_sizes)
            break
    assert tiered is not None, "the 60-heliostat field has no pass of two tiers to measure"
    items = [it for it in plan.items if it.geometry.lamp == tiered[0]]
    watch = OnTarget(field, items)
    night = run_planned_night(field, items, "n0/night-1", 8 * 3600.0, heliostat_ids=ids,
                              unmeasurable=plan.unmeasurable, observers=[watch])
    store = CampaignStore(field.db_path, readonly=True)
    try:
        campaigns = [store.campaign_by_name(r.name) for r in night.results]
        got = [(m.heliostat_id, np.asarray(m.centroid_enu)) for m in store.measurements()
               if m.campaign_id in {c.id for c in campaigns}]
    finally:
        store.close()
    beams = [c.meta["beams"] for c in campaigns if "beams" in c.meta]
    assert [b["tiers"] for b in beams] == [tiered[1]]
    assert len(got) >= len(items) - 1 and sum(b["rounds"] for b in beams) >= 2
    assert max(len(b) for b in field.cameras["T1"].beams_in_view) >= 2  # beams shared captures
    assert strays(field, 4, {})[0] == 0
    own: dict[str, list] = {}
    for cam in field.cameras.values():
        for hits in cam.hits:
            for hid, p in hits.items():
                own.setdefault(hid, []).append(p)
    for hid, c in got:  # m, about one pixel (7 cm)
        assert np.min(np.linalg.norm(np.asarray(own[hid]) - c, axis=1)) < 0.1, hid
