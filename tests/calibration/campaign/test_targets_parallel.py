"""Several targets in parallel (issue #13): configuration, beam-safe slews past the other
targets, the planned night's passes per (lamp, target) run side by side, the record store's
target column, and the whole night on the simulated plant, judged on the plant clock by the
plant's own beam-safety monitor (its truth, not the controller's records)."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from controller.calibration.campaign.parallel import opencv_single_threaded
from controller.calibration.campaign.runner import CampaignResult
from controller.calibration.cycle.beam_safety import UnsafePath
from controller.calibration.cycle.pointing import GeometryPointing
from controller.calibration.night.passes import run_night
from controller.calibration.night.planner import plan_night
from controller.config import load_config, parse_config
from controller.errors import ConfigError
from controller.geometry.aiming import source_direction
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.target_frame import TargetFrame
from controller.storage.db import CampaignStore
from controller.storage.schema import MIGRATIONS
from tests.calibration.conftest import calibrated_record
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]


def _demo() -> dict:
    return yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())


# -- configuration --------------------------------------------------------------------------------
def test_demo_plant_has_two_targets_each_with_its_camera():
    cfg = parse_config(_demo(), "demo.yaml")
    assert cfg.calibration.parallel_targets() == ("tower-target", "tower-lower")
    assert cfg.camera_of("tower-target") == cfg.camera  # the top-level camera stays the default's
    lower = cfg.for_target("tower-lower")
    assert lower.camera.position_enu_m != cfg.camera.position_enu_m
    assert lower.calibration.target == "tower-lower" and lower.targets == cfg.targets


def test_a_one_target_config_keeps_working_unchanged():
    data = _demo()
    data["targets"] = data["targets"][:1]
    del data["calibration"]["targets"]
    cfg = parse_config(data, "old.yaml")
    assert cfg.calibration.parallel_targets() == ("tower-target",)
    assert cfg.camera_of() is cfg.camera


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["calibration"].update(targets=["tower-target", "nope"]),
     "old.yaml: calibration.targets[1]: 'nope' is not the id of an entry of targets"),
    (lambda d: d["calibration"].update(targets=["tower-lower", "tower-lower"]),
     "old.yaml: calibration.targets[1]: 'tower-lower' is not the id of an entry of targets, or is listed"),
    (lambda d: d["targets"][1]["camera"].update(width_px=-3), "old.yaml: targets[1].camera.width_px: "),
    (lambda d: d["targets"][1]["camera"].update(zoom=2), "old.yaml: targets[1].camera.zoom: unknown key"),
])
def test_bad_target_keys_name_file_key_and_rule(edit, message):
    data = _demo()
    edit(data)
    with pytest.raises(ConfigError) as e:
        parse_config(data, "old.yaml")
    assert str(e.value).startswith(message)


# -- beam-safe slews ----------------------------------------------------------------------------------
def _lands_on(kin, s, pose, target) -> bool:
    """Independent check: the nominal central ray's hit on ``target``'s plane, inside it."""
    f = TargetFrame.from_config(target, (1, 1))
    hit = kin.spot(*pose, s, f.center, f.normal) - f.center
    return abs(hit @ f.u) <= target.width_m / 2 and abs(hit @ f.v) <= target.height_m / 2


def _sweep(h, a, b, n: int = 300) -> list[np.ndarray]:
    """Poses of a leg from ``a`` to ``b`` with each axis at its own configured speed (the
    motion model of ``path_to``'s docstring)."""
    speed = np.array([h.axes.azimuth.speed_steps_per_s, h.axes.elevation.speed_steps_per_s])
    a_, b_ = np.asarray(a, float), np.asarray(b, float)
    dur = np.abs(b_ - a_) / speed
    times = np.linspace(0, dur.max(), n)
    return [a_ + np.minimum(1.0, t / np.maximum(dur, 1e-12)) * (b_ - a_) for t in times]


def test_slew_to_standby_goes_around_the_other_target():
    """Poses below the lower target, slewing to the upper target's standby: where the slew a
    one-target plant would take sweeps across the lower target, the path goes around it."""
    cfg = load_config(REPO / "configs" / "demo.yaml")
    upper, lower = cfg.target("tower-target"), cfg.target("tower-lower")
    lamp = cfg.light_source("lamp")
    frame = TargetFrame.from_config(upper, (768, 1024))
    rerouted = refused = 0
    for hid in ("H01", "H09"):
        h = cfg.heliostat(hid)
        kin = HeliostatKinematics.from_config(h)
        s = np.asarray(source_direction(lamp, np.asarray(h.position_enu_m, float)), float)
        blind = GeometryPointing(h, upper, lamp, frame, 8.0)
        safe = GeometryPointing(h, upper, lamp, frame, 8.0, others=cfg.targets)
        end = blind.standby_steps(None)
        for du in np.linspace(-6.0, 6.0, 5):
            start = kin.aim(s, np.asarray(lower.center_enu_m) + du * frame.u + np.array([0.0, 0.0, -8.0]))
            legs = blind.path_to(start, end)
            crossed = any(_lands_on(kin, s, p, lower)
                          for a, b in zip([start, *legs[:-1]], legs, strict=True) for p in _sweep(h, a, b))
            try:
                path = safe.path_to(start, end)
            except UnsafePath:  # no path of the three shapes: nothing is sent, also safe
                refused += 1
                continue
            assert path[-1] == end
            assert not any(_lands_on(kin, s, p, lower)
                           for a, b in zip([start, *path[:-1]], path, strict=True) for p in _sweep(h, a, b))
            rerouted += crossed
    assert rerouted > refused  # the lower target was in the way of some slews, and mostly avoidable


# -- the night's passes ---------------------------------------------------------------------------------
def test_a_nights_queue_is_shared_by_the_targets():
    cfg = load_config(REPO / "configs" / "demo.yaml")
    ids = [h.id for h in cfg.heliostats][:6]
    plan = plan_night(cfg, {h: calibrated_record(cfg, h) for h in ids}, "n")
    per = {t: {i.heliostat_id for i in plan if i.geometry.target == t}
           for t in cfg.calibration.parallel_targets()}
    assert len(per["tower-target"]) == len(per["tower-lower"]) == 3
    lower = cfg.target("tower-lower")
    for i in plan:
        if i.geometry.target == "tower-lower":  # aim points on the lower target's grid
            assert abs(i.geometry.aim_enu[2] - lower.center_enu_m[2]) <= lower.height_m / 2


def _plan(cfg):
    return plan_night(cfg, {h.id: calibrated_record(cfg, h.id) for h in cfg.heliostats[:4]}, "n")


def test_targets_of_a_lamp_run_side_by_side_and_a_failed_pass_stops_the_night():
    cfg = load_config(REPO / "configs" / "demo.yaml")
    plan = _plan(cfg)
    first_lamp = plan and min(plan, key=lambda i: 0).geometry.lamp
    both = threading.Barrier(2, timeout=scaled_s(10))  # broken unless both targets are in a pass at once
    ran: list[str] = []

    def run_pass(p):
        ran.append(p.name)
        if p.name.endswith("/1@tower-target") or p.name.endswith("/1@tower-lower"):
            both.wait()
        status = "aborted" if p.target == "tower-lower" else "finished"
        return CampaignResult(0, p.name, False, [], 0.0, 0.0, status)

    results = run_night(plan, "n", run_pass)
    assert {r.name.split("@")[1] for r in results} == {"tower-target", "tower-lower"}
    assert not both.broken
    assert all(r.name.split("/")[1] == results[0].name.split("/")[1] for r in results)  # no second lamp lit
    assert first_lamp is not None and len(ran) == len(results) < len({(i.geometry.lamp, i.geometry.target)
                                                                       for i in plan})


# -- record store ----------------------------------------------------------------------------------------
def test_migration_gives_old_measurements_their_campaigns_target(tmp_path):
    db = tmp_path / "old.db"
    with sqlite3.connect(db) as c:
        for m in MIGRATIONS[:6]:
            c.executescript(m)
        c.execute("PRAGMA user_version=6")
        c.execute("INSERT INTO campaigns (id, name, config_path, config_sha256, light_source, target, "
                  "queue_json, started_utc) "
                  "VALUES (1, 'old', 'c.yaml', 'x', 'lamp', 'tower-target', '[]', 'now')")
        c.execute("INSERT INTO heliostat_runs (id, campaign_id, heliostat_id, queue_index, status, "
                  "final_state, iterations, start_s, end_s, finished_utc) "
                  "VALUES (1, 1, 'H01', 0, 'measured', 'done', 1, 0, 1, 'x')")
        c.execute("INSERT INTO measurements (run_id, iteration, az_steps, el_steps, source_e, source_n, "
                  "source_u, source_az_deg, source_el_deg, aim_e, aim_n, aim_u, plant_time_s, measured_utc) "
                  "VALUES (1, 0, 1, 2, 0, 0, 1, 0, 90, 0, 0, 30, 0.5, 'x')")
    with CampaignStore(db) as store:
        assert store.query("SELECT target FROM measurements")[0]["target"] == "tower-target"
        assert len(store.measurements(heliostat_id="H01")) == 1  # the old rows still read back


# -- the simulated plant ------------------------------------------------------------------------------------
def _overlap(a, b) -> bool:
    return a[0] < b[1] and b[0] < a[1]


def test_two_targets_work_in_parallel_on_the_simulated_plant(small_config, tmp_path):
    from controller.commands.simulated import simulated_run
    from simplant.settings import SimulationSettings
    from tests.calibration.conftest import FAST

    cfg = load_config(small_config)
    ids = ["H01", "H02", "H07", "H13"]
    settings = SimulationSettings(clock_speedup=FAST.clock_speedup, seed=2)
    sim = simulated_run(cfg, str(small_config), tmp_path / "run", tmp_path / "c.db", ids, settings=settings,
                        name="t", nights=1)
    # The plant's truth, sampled on its own clock: never two beams on one target ...
    assert sim.safety["violations"] == 0 and sim.safety["max_beams_on_target"] == 1
    upper, lower = sim.on_target["tower-target"], sim.on_target["tower-lower"]
    # ... while the two targets each had a beam at the same time.
    assert any(_overlap(a, b) for a in upper for b in lower)
    # The controller's own records (plant clock): per target one beam at a time, targets overlapping.
    with CampaignStore(tmp_path / "c.db") as store:
        rows = store.query("SELECT c.target, r.on_target_s AS a, r.off_target_s AS b FROM heliostat_runs r "
                           "JOIN campaigns c ON c.id = r.campaign_id WHERE c.name LIKE 't/night-1/%' "
                           "AND r.on_target_s IS NOT NULL AND r.off_target_s IS NOT NULL")
        per_target = {t: sorted((r["a"], r["b"]) for r in rows if r["target"] == t)
                      for t in ("tower-target", "tower-lower")}
        measured = dict(tuple(r) for r in store.query(
            "SELECT m.target, COUNT(*) FROM measurements m JOIN heliostat_runs r ON r.id = m.run_id "
            "JOIN campaigns c ON c.id = r.campaign_id WHERE c.name LIKE 't/night-1/%' GROUP BY m.target"))
    for spans in per_target.values():
        assert spans and all(a[1] <= b[0] for a, b in zip(spans, spans[1:], strict=False))
    assert any(_overlap(a, b) for a in per_target["tower-target"] for b in per_target["tower-lower"])
    assert measured.get("tower-target", 0) > 0 and measured.get("tower-lower", 0) > 0
    # Throughput: the targets' occupancy took less plant time than it would one after the other.
    busy = sum(b - a for spans in per_target.values() for a, b in spans)
    covered, end = 0.0, -np.inf
    for a, b in sorted(span for s in per_target.values() for span in s):
        covered += max(0.0, b - max(a, end))
        end = max(end, b)
    assert covered < 0.9 * busy


def test_ctrl_c_asks_every_target_to_stop_and_waits_for_them():
    import _thread

    from controller.calibration.campaign.parallel import run_per_target

    stop = threading.Event()
    ended: list[str] = []
    started = threading.Barrier(2, timeout=scaled_s(10))

    def job(name: str, interrupt: bool):
        def run():
            started.wait()
            if interrupt:
                _thread.interrupt_main()  # Ctrl-C, delivered to the main thread as a signal would be
            assert stop.wait(scaled_s(10)), "nobody asked this target to stop"
            ended.append(name)
            return name
        return run

    with pytest.raises(KeyboardInterrupt):
        run_per_target({"upper": job("upper", True), "lower": job("lower", False)}, stop.set)
    assert sorted(ended) == ["lower", "upper"]  # both parked and ended before the interrupt went on


def test_opencv_runs_on_the_calling_threads_until_the_last_campaign_ends():
    """Campaigns side by side (a night's targets) each make OpenCV single-threaded; the thread
    count it had comes back when the last of them ends, not when the first does."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(3)
    try:
        first_in, second_out = threading.Event(), threading.Event()
        seen: list[int] = []

        def second() -> None:
            first_in.wait(scaled_s(10.0))
            with opencv_single_threaded():
                seen.append(cv2.getNumThreads())
            second_out.set()

        t = threading.Thread(target=second)
        t.start()
        with opencv_single_threaded():
            first_in.set()
            assert second_out.wait(scaled_s(10.0))
            assert cv2.getNumThreads() == 1  # the second ended; this one has not
        t.join(scaled_s(10.0))
        assert seen == [1] and cv2.getNumThreads() == 3
        with pytest.raises(RuntimeError), opencv_single_threaded():
            raise RuntimeError("a campaign that fails")
        assert cv2.getNumThreads() == 3
    finally:
        cv2.setNumThreads(before)
