"""Several beams on one target (calibration.beams_per_target): refused with the sun and in
daylight, the gate's K slots in queue order, the measured-alone hold, slots that keep the
predicted spots apart and inside the view, and whose spot is whose by a known step."""

from __future__ import annotations

import math
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from controller.calibration.beams import slots
from controller.calibration.beams.identity import traced_identity_step
from controller.calibration.beams.policy import beams_allowed
from controller.calibration.beams.slots import (
    GAP_M,
    IDENTITY_STEP_M,
    lamp_rate,
    pass_layout,
    slot_layout,
    spot_reach_m,
    target_frame,
)
from controller.calibration.cycle.gate import TargetGate
from controller.calibration.cycle.observations import Observation
from controller.calibration.night.passes import Pass, lamps_by_rate
from controller.config import load_config
from controller.errors import ConfigError, InputError
from controller.geometry.target_frame import TargetFrame
from controller.imaging.background import subtract_background
from controller.imaging.beam import analyze
from controller.imaging.centroid import energy_centroid
from controller.imaging.spots import (
    Isolated,
    cell_centroids,
    confirm_by_step,
    excess,
    isolate,
    spills,
    window_shifts,
    window_spots,
)
from simplant.far_lamps import far_lamp_config
from tests.calibration.conftest import calibrated_record

ROOT = Path(__file__).resolve().parents[3]
NIGHT = "2026-03-01T22:00:00+00:00"
NOON = "2026-03-01T12:00:00+00:00"


def _config(small_config, tmp_path, **cal):
    data = yaml.safe_load(small_config.read_text())
    data["calibration"].update(cal)
    p = tmp_path / "k.yaml"
    p.write_text(yaml.safe_dump(data))
    return p, data


def test_more_than_one_beam_is_refused_with_the_sun_naming_the_key(small_config, tmp_path):
    p, data = _config(small_config, tmp_path, beams_per_target=4)
    if not any(s["kind"] == "sun" for s in data["light_sources"]):
        data["light_sources"].append({"kind": "sun", "id": "sun"})
    data["calibration"]["light_source"] = next(s["id"] for s in data["light_sources"] if s["kind"] == "sun")
    data["calibration"]["lamps"] = [s["id"] for s in data["light_sources"] if s["kind"] == "lamp"]
    p.write_text(yaml.safe_dump(data))
    with pytest.raises((ConfigError, InputError)) as e:
        load_config(p)
    assert "calibration.beams_per_target" in str(e.value) and "sun" in str(e.value)
    assert str(p) in str(e.value) or p.name in str(e.value)


def test_more_than_one_beam_is_refused_in_daylight_and_allowed_under_a_lamp_at_night(small_config, tmp_path):
    p, _ = _config(small_config, tmp_path, beams_per_target=4)
    cfg = load_config(p)
    lamp = cfg.calibration.light_source
    assert beams_allowed(cfg, lamp, NIGHT) == 4
    with pytest.raises(InputError, match="calibration.beams_per_target.*sun is up"):
        beams_allowed(cfg, lamp, NOON)
    assert beams_allowed(load_config(small_config), lamp, NOON) == 1  # K = 1: as ever


def test_the_gate_admits_k_beams_in_queue_order_each_at_its_slot():
    gate = TargetGate(beams=3)
    never = lambda: False  # noqa: E731
    assert [gate.acquire(t, never) for t in range(3)] == [True, True, True]
    assert [gate.slot(t) for t in range(6)] == [0, 1, 2, 0, 1, 2]
    got = []
    th = threading.Thread(target=lambda: got.append(gate.acquire(3, never)))
    th.start()
    th.join(0.2)
    assert not got  # ticket 3 uses slot 0: it waits for ticket 0
    gate.release(1)
    th.join(0.2)
    assert not got  # slot 1 freed, not slot 0
    gate.release(0)
    th.join(2.0)
    assert got == [True] and gate.holders == {2, 3}
    assert gate.acquire(4, never) and gate.slot(4) == 1
    gate.release(2)
    gate.release(7)  # ticket 7 ends before its turn (skipped): ticket 10 is next at slot 1 …
    assert not gate.acquire(10, lambda: True)  # … but ticket 4 still holds slot 1
    gate.release(4)
    assert gate.acquire(10, never) and gate.holders == {3, 10}


def test_the_first_round_goes_onto_the_target_together_and_nobody_joins_a_round_in_progress():
    gate = TargetGate(beams=3, together=True)
    never = lambda: False  # noqa: E731
    got: dict[int, bool] = {}
    threads = []
    for t in range(3):
        threads.append(threading.Thread(target=lambda t=t: got.update({t: gate.acquire(t, never)})))
        threads[-1].start()
        threads[-1].join(0.2)
        if t < 2:
            assert not got  # the first two wait at standby for the third
    for th in threads:
        th.join(2.0)
    assert got == {0: True, 1: True, 2: True} and gate.holders == {0, 1, 2}
    gate.held = True  # a round's captures
    gate.release(0)
    assert not gate.acquire(3, lambda: True)  # slot 0 is free, but no beam slews in during exposures
    gate.held = False
    assert gate.acquire(3, never) and gate.holders == {1, 2, 3}


def test_a_beam_off_the_target_hands_its_slot_on_while_it_parks_and_holds_up_rounds_until_parked():
    gate = TargetGate(beams=2)
    never, at_once = (lambda: False), (lambda: True)  # noqa: E731
    gate.acquire(0, never), gate.acquire(1, never)
    assert not gate.acquire(2, at_once)  # slot 0 is ticket 0's
    gate.vacate(0)  # its beam left the target on the way to standby
    assert gate.acquire(2, at_once) and gate.holders == {1, 2} and gate.leaving == {0}
    assert not gate.acquire(3, at_once)  # slot 1 is still ticket 1's
    gate.release(2)
    gate.give_back(1)  # to be measured alone
    assert not gate.holders and not gate.acquire_alone(1, at_once)  # ticket 0's beam may be in view
    gate.release(0)  # parked
    assert gate.leaving == set() and gate.acquire_alone(1, never)
    one = TargetGate(beams=1)
    one.acquire(0, never)
    one.vacate(0)  # one beam at a time: the target goes on only once the beam is parked
    assert one.holders == {0} and not one.acquire(1, at_once)



def test_a_gate_wakes_a_waiting_ticket_only_when_it_may_go_on(monkeypatch):
    """Issue 42: with one condition for every waiting ticket, each release woke all of them to
    be put back to sleep (two dozen cycles per target on a 10,000-heliostat night: 670 context
    switches per measurement). Sixteen tickets waiting in turn, one beam at a time: the chain
    of releases admits them in order, and no ticket waits again after it was woken."""
    n, gate, order = 16, TargetGate(beams=1), []
    never = lambda: False  # noqa: E731
    assert gate.acquire(0, never)

    def take(t: int) -> None:
        assert gate.acquire(t, never, poll_s=60.0)
        order.append(t)
        gate.release(t)

    threads = [threading.Thread(target=take, args=(t,), daemon=True) for t in range(1, n + 1)]
    for th in threads:
        th.start()
    with gate.cv:
        while len(gate.waiting) < n:  # each waiter notifies cv as it starts waiting
            gate.cv.wait(5.0)
    waits, wait = [], threading.Condition.wait

    def counted(self, timeout=None):
        if sys._getframe(1).f_code.co_filename.endswith("gate.py"):
            waits.append(threading.get_ident())
        return wait(self, timeout)

    monkeypatch.setattr(threading.Condition, "wait", counted)
    gate.release(0)
    for th in threads:
        th.join(30.0)
    assert order == list(range(1, n + 1))
    assert len(waits) < n // 2, f"{len(waits)} waits again after the chain began"

def test_measured_alone_waits_for_every_other_beam_and_keeps_newcomers_off():
    gate = TargetGate(beams=2)
    never = lambda: False  # noqa: E731
    gate.acquire(0, never), gate.acquire(1, never)
    gate.give_back(0)  # ticket 0 parked: to be measured alone
    alone = []
    th = threading.Thread(target=lambda: alone.append(gate.acquire_alone(0, never)))
    th.start()
    th.join(0.2)
    assert not alone  # ticket 1's beam is still on the target
    gate.release(1)
    th.join(2.0)
    assert alone == [True] and gate.alone == 0
    assert not gate.acquire(2, lambda: True)  # nobody joins a heliostat measured alone
    gate.release(0)
    assert gate.acquire(2, never) and gate.alone is None


def test_those_measured_alone_go_in_the_order_they_asked_the_one_left_at_its_slot_first():
    gate = TargetGate(beams=3)
    never, at_once = (lambda: False), (lambda: True)  # noqa: E731
    for t in range(3):
        gate.acquire(t, never)
    gate.reserve_alone(2)  # stays at its slot, its beam on the target
    assert gate.others_alone(0) and not gate.others_alone(2)
    gate.give_back(1)
    order = []
    th = threading.Thread(target=lambda: order.append((1, gate.acquire_alone(1, never))))
    th.start()
    th.join(0.2)
    gate.give_back(0)  # back for a correction: parked, asks after ticket 1
    assert not gate.acquire_alone(0, at_once)  # ticket 2 goes first, then ticket 1
    assert gate.acquire_alone(2, never) and gate.alone == 2 and not order
    gate.release(2)
    th.join(2.0)
    assert order == [(1, True)] and gate.alone == 1
    gate.release(1)
    assert gate.acquire_alone(0, never) and gate.alone == 0


def test_slots_keep_predicted_spots_apart_and_inside_the_view(small_config, tmp_path):
    near = load_config(small_config)  # a lamp 50-60 m from the mirrors: spots nearly mirror-wide
    models = {h.id: calibrated_record(near, h.id) for h in near.heliostats}
    reach = spot_reach_m(near, near.calibration.target, near.calibration.light_source, models,
                         near.target().center_enu_m)
    assert slot_layout(target_frame(near, near.calibration.target), 4, reach, 0.2).k == 1
    cfg = load_config(far_lamp_config(small_config, tmp_path, 4))
    tid, lamp = cfg.calibration.target, cfg.calibration.light_source
    frame = target_frame(cfg, tid)
    centre = cfg.target().center_enu_m
    models = {h.id: calibrated_record(cfg, h.id) for h in cfg.heliostats}
    reach = spot_reach_m(cfg, tid, lamp, models, centre)
    assert np.all(reach > 0)
    # Without a model the spot's position is too uncertain for more than one slot.
    unknown = spot_reach_m(cfg, tid, lamp, dict.fromkeys(models), centre)
    assert np.all(unknown > reach) and slot_layout(frame, 4, unknown, 0.2).k == 1
    margin = cfg.calibration.planner.view_margin_m
    lay = slot_layout(frame, 4, reach, margin)
    assert 1 < lay.k <= 4
    half = np.array([frame.width_m, frame.height_m]) / 2
    r = reach + lay.step_m
    assert lay.step_m >= IDENTITY_STEP_M
    assert np.all(np.abs(lay.offsets_m) + r + margin <= half + 1e-9)  # inside the view at 3σ
    for i in range(lay.k):
        for j in range(i + 1, lay.k):  # footprints (stepped too) apart on at least one axis
            assert np.any(np.abs(lay.offsets_m[i] - lay.offsets_m[j]) >= 2 * r + GAP_M - 1e-9)
    # A spot too large for several slots: one slot, at the centre.
    one = slot_layout(frame, 4, half, margin)
    assert one.k == 1 and np.allclose(one.offsets_m, 0)


def _spots(shape, centres, sigma=3.0):
    rows, cols = np.indices(shape)
    img = np.full(shape, 10.0) + np.random.default_rng(1).normal(0.0, 1.0, shape)
    for x, y in centres:
        img += 1000.0 * np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * sigma**2))
    return img


WINDOWS = [(10, 60, 10, 60), (10, 60, 90, 140), (70, 120, 10, 60)]  # (r0, r1, c0, c1)


def test_each_window_finds_its_own_spot_and_isolation_keeps_only_one():
    img = _spots((130, 160), [(30.5, 30.2), (120.0, 40.0)])  # windows 0 and 1; window 2 empty
    found = window_spots(img, WINDOWS)
    assert np.allclose(found[0], (30.5, 30.2), atol=0.2) and np.allclose(found[1], (120.0, 40.0), atol=0.2)
    assert np.all(np.isnan(found[2]))
    one = isolate(img, WINDOWS, WINDOWS[1])
    left = window_spots(one, WINDOWS)
    assert np.all(np.isnan(left[0])) and np.allclose(left[1], (120.0, 40.0), atol=0.2)


def test_a_rounds_spots_are_measured_where_their_cells_energy_lies_not_where_the_flattened_view_puts_them(
        small_config):
    """Frame 1 of a round on the 10,000-heliostat simulated field (tests/data/beams): small
    spots (σ ≈ 1.5 px) over an 8-bit ambient. The flattened image's analysis fits its
    background to the fill (the spot-free pixels between windows, raised by the spots' tails)
    and puts one centroid a pixel (0.42 m) from its true hit; the cell's weighed energy
    (``spots.Isolated``, what a round's measurement now takes) is within 0.1 px of every one."""
    d = np.load(ROOT / "tests" / "data" / "beams" / "round_of_four.npz")
    hdr, truth = d["hdr"].astype(float), d["truth_px"]
    wins, cells = [tuple(map(int, w)) for w in d["windows"]], [tuple(map(int, c)) for c in d["cells"]]
    cal = load_config(small_config).calibration
    ex = excess(hdr, wins)
    centres = cell_centroids(ex, cells, wins, cal.centroid_threshold)
    flat, cell = [], []
    for k, c in enumerate(cells):
        spot = Isolated(wins, c, ex.b, tuple(centres[k]), (float(k), 0.0, 0.0))
        img = spot(hdr)
        assert np.array_equal(img, isolate(hdr, wins, c, ex.b))  # the shape: the flattened image
        r = analyze(img, threshold=cal.threshold, background="auto", centroid="segment")
        e = energy_centroid(subtract_background(img, r.background), cal.centroid_threshold)
        obs = spot.measured(Observation((e.x, e.y), (0.0, 0.0, 0.0), np.zeros(7), 1.0))
        flat.append(np.hypot(e.x - truth[k][0], e.y - truth[k][1]))
        cell.append(np.hypot(obs.centroid_px[0] - truth[k][0], obs.centroid_px[1] - truth[k][1]))
        assert obs.centroid_enu == (float(k), 0.0, 0.0)
    assert max(flat) > 1.0  # the defect, as recorded
    assert max(cell) < 0.1, cell


def test_a_window_registers_its_spots_shift_even_when_the_spot_is_larger_than_the_window():
    rows, cols = np.indices((300, 400))

    def shot(x, y, sigma):
        return 10.0 + 1000.0 * np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * sigma**2))

    win = [(50, 250, 50, 250)]
    for sigma in (4.0, 60.0):  # well inside; wider than the 200-px window (clipped at its edges)
        a, b = shot(150.0, 140.0, sigma), shot(167.3, 131.6, sigma)
        assert np.allclose(window_shifts(a, b, win, 30, win)[0], (17.3, -8.4), atol=0.15)
    big = window_spots(b, win)[0] - window_spots(a, win)[0]
    assert np.linalg.norm(big) < 0.8 * np.hypot(17.3, 8.4)  # why not centroids: clipping shrinks them
    far = shot(150.0, 140.0, 4.0), shot(150.0 + 45.0, 140.0, 4.0)  # farther than the 30 px searched
    assert np.all(np.isnan(window_shifts(*far, win, 30, win)[0]))
    # Cut by the window on a side facing another slot, a spot's centroid moves when the window
    # loses its border there; a spot inside its window, or cut only towards the view's edge, not.
    up = [(True, False, False, False)]  # only the first rows face another slot
    assert spills(shot(150.0, 120.0, 60.0), win, up)[0] > 3.0
    assert spills(shot(150.0, 120.0, 8.0), win, up)[0] < 0.01
    assert spills(shot(150.0, 180.0, 60.0), win, [(False, True, False, False)])[0] > 3.0
    assert spills(shot(150.0, 120.0, 60.0), win, [(False, False, False, False)])[0] == 0.0
    # A faint halo (2 % of the peak) reaching past the facing side: too faint for the centroid's
    # threshold (5 % of the peak), so it does not count there, though it moves the full-energy centroid.
    halo = shot(150.0, 150.0, 6.0) + 20.0 * (np.abs(cols - 150.0) < 70) * (rows < 160) * (rows > 20)
    assert spills(halo, win, up)[0] > 3.0 and spills(halo, win, up, floor=0.05)[0] < 0.5


class _LinearPointing:
    """Rays from the origin through (u, v) = J · steps on the plane y = 100 m."""

    def __init__(self, jac) -> None:
        self.jac = np.asarray(jac, float)

    def rays(self, poses):
        uv = np.asarray(poses, float) @ self.jac.T
        hit = np.column_stack([uv[:, 0], np.full(len(uv), 100.0), uv[:, 1]])
        return np.zeros_like(hit), hit / np.linalg.norm(hit, axis=1, keepdims=True)


def test_identity_steps_spread_evenly_over_the_target_whatever_each_axis_gearing():
    frame = SimpleNamespace(center=np.array([0.0, 100.0, 0.0]), normal=np.array([0.0, -1.0, 0.0]),
                            u=np.array([1.0, 0.0, 0.0]), v=np.array([0.0, 0.0, 1.0]))
    # Azimuth moves the spot three times as far per step as elevation, a little skewed.
    pointing = _LinearPointing([[3e-4, 0.2e-4], [0.1e-4, 1e-4]])
    moves = [traced_identity_step(pointing, (1000, 2000), slot, 4, frame) for slot in range(4)]
    for step, disp in moves:
        assert min(step) >= 0  # no axis reverses: the approach's backlash stays taken up
        assert abs(np.linalg.norm(disp) - IDENTITY_STEP_M) < 0.01 * IDENTITY_STEP_M
    # From the azimuth's direction on the target (1.9°) to the elevation's (78.7°), evenly.
    angles = np.degrees([math.atan2(d[1], d[0]) for _, d in moves])
    assert abs(angles[0] - 1.9) < 0.5 and abs(angles[-1] - 78.7) < 0.5
    assert np.ptp(np.diff(angles)) < 5.0, angles


def test_identity_by_step_confirms_each_and_catches_a_swap():
    ang = np.radians([0, 30, 60, 90])
    steps = 0.3 * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    first = np.array([[-2.0, -1.5], [2.0, -1.5], [-2.0, 1.5], [2.0, 1.5]]) + 0.05
    noise = np.random.default_rng(2).normal(0.0, 0.01, first.shape)  # centroid noise, m
    assert confirm_by_step(first, first + steps + noise, steps) == [True] * 4
    moved = first + steps[[1, 0, 2, 3]]  # 0 and 1 exchanged: each window moves with the other's step
    assert confirm_by_step(first, moved, steps) == [False, False, True, True]
    still = first + steps
    still[2] = first[2]  # a spot that did not move is not heliostat 2's
    assert confirm_by_step(first, still, steps) == [True, True, False, True]
    gone = first + steps
    gone[3] = np.nan  # window 3 empty after the step
    assert confirm_by_step(first, gone, steps) == [True, True, True, False]
    one = confirm_by_step(first[:1], first[:1] + 0.2 * steps[:1], steps[:1])  # moved too little
    assert one == [False]


def test_the_plant_truth_counts_a_centroid_of_another_heliostats_spot():
    from simplant.spot_truth import SpotTruth

    truth = SpotTruth()
    a, b = np.array([1.0, 0.0, 30.0]), np.array([-1.5, 0.0, 30.0])
    truth.record({"A": a, "B": b})
    assert not truth.misassigned("A", a + 0.05) and truth.misassigned("A", b + 0.05)
    assert truth.misassigned("C", a)  # no spot of C's in view: whatever it measured was not its own
    assert (truth.checked, truth.misassigned_count) == (3, 2)


def test_a_solo_ticket_takes_only_an_empty_target_and_keeps_it_to_itself():
    gate = TargetGate(beams=3, slots=[0, None, 1, 2])
    assert gate.solo == {1}
    never = lambda: False  # noqa: E731
    assert gate.acquire(0, never)
    got = []
    th = threading.Thread(target=lambda: got.append(gate.acquire(1, never)))
    th.start()
    th.join(0.2)
    assert not got  # ticket 0's beam is on the target
    gate.vacate(0)
    th.join(0.2)
    assert not got  # off it, but not parked yet: a solo heliostat is captured as it arrives
    gate.release(0)
    th.join(2.0)
    assert got == [True] and gate.holders == {1}
    assert not gate.acquire(2, lambda: True)  # nobody joins a solo heliostat
    gate.release(1)
    assert gate.acquire(2, never) and gate.acquire(3, never) and gate.holders == {2, 3}


def test_slots_are_dealt_in_turn_and_a_heliostat_one_slot_does_not_suit_takes_the_next():
    asked = []

    def fits(ticket: int, slot: int) -> bool:
        asked.append((ticket, slot))
        return not (ticket == 4 and slot == 0) and ticket != 6

    assert slots.assign_slots([range(4)] * 4, lambda t, s: True) == [0, 1, 2, 3]
    got = slots.assign_slots([range(4)] * 9, fits)
    # ticket 4 skips slot 0 for slot 1; ticket 5 takes slot 0; ticket 6 fits none: the target alone
    assert got == [0, 1, 2, 3, 1, 0, None, 2, 3]
    assert asked.count((4, 0)) == 1 and (4, 2) not in asked  # asked in turn, no further than needed
    gate = TargetGate(beams=4, together=True, slots=got)
    assert gate.solo == {6} and [gate.slot(t) for t in (4, 5)] == [1, 0]
    never, at_once = (lambda: False), (lambda: True)  # noqa: E731
    for t in range(4):
        threading.Thread(target=gate.acquire, args=(t, never), daemon=True).start()
    with gate.cv:
        assert gate.cv.wait_for(lambda: gate.holders == {0, 1, 2, 3}, 2.0)
    gate.release(0)
    assert not gate.acquire(4, at_once)  # slot 1 is ticket 1's, though slot 0 is free
    assert gate.acquire(5, at_once)  # the one after ticket 0 at its slot
    gate.release(1)
    assert gate.acquire(4, at_once) and gate.holders == {2, 3, 4, 5}


def test_a_pass_is_laid_out_in_tiers_each_spaced_for_its_spots_and_the_largest_take_the_target_alone():
    frame = TargetFrame.from_config(SimpleNamespace(normal=(0.0, 1.0, 0.0), center_enu_m=(0.0, 0.0, 60.0),
                                                    width_m=48.0, height_m=36.0), (96, 128))
    small = np.full((97, 2), 6.0)
    # one spot tall (fits two slots side by side, not four), one badly known model, one out of reach
    reaches = np.vstack([small, [[8.0, 14.0]], [[15.0, 11.0]], [[np.inf, np.inf]]])
    layout, member = pass_layout(frame, 4, reaches, 0.2)
    assert layout.k == 4 and layout.tier_sizes == [4, 2] and layout.slots == 6
    assert (member[:97] == 0).all() and member[97] == 1 and (member[98:] == -1).all()
    assert slot_layout(frame, 4, [15.0, 11.0], 0.2).k == 1 and slot_layout(frame, 4, [8.0, 14.0], 0.2).k == 2
    # each tier spaced for its own spots (Eq. 1), its reach kept per slot for its windows
    assert np.allclose(layout.reach_m[:4], 6.0) and np.allclose(layout.reach_m[4:], [8.0, 14.0])
    assert np.allclose(layout.offsets_m[:4], slot_layout(frame, 4, [6.0, 6.0], 0.2).offsets_m)
    assert layout.rank(5) == (1, 2) and layout.tier_slots(1) == (4, 5) and layout.tier_slots(-1) == ()
    # the left slot of the two overlaps the left column of the four, not the right: never at once
    near = layout.conflicts()
    assert near[4] == {0, 2, 4} and near[5] == {1, 3, 5} and near[0] == {0, 4} and near[1] == {1, 5}
    assert slots.layout_cost(layout, member) == pytest.approx(97 * 1.5 / 4 + 1.5 / 2 + 2)
    # two spots, each the larger on one axis: each in the largest tier it fits
    layout, member = pass_layout(frame, 4, np.array([[9.0, 2.0], [2.0, 8.0]]), 0.2)
    assert member.tolist() == [0, 1] and layout.tier_sizes == [4, 2]
    # nothing in reach: one slot, everybody alone
    layout, member = pass_layout(frame, 4, np.full((3, 2), np.inf), 0.2)
    assert layout.k == 1 and (member == -1).all()


def test_a_slot_of_another_tier_waits_for_the_slots_its_cell_overlaps_and_shares_the_target_with_the_others():
    frame = TargetFrame.from_config(SimpleNamespace(normal=(0.0, 1.0, 0.0), center_enu_m=(0.0, 0.0, 60.0),
                                                    width_m=48.0, height_m=36.0), (96, 128))
    layout, _ = pass_layout(frame, 4, np.array([[6.0, 6.0], [8.0, 14.0]]), 0.2)
    gate = TargetGate(beams=layout.k, slots=[0, 1, 2, 3, 4, 5], conflicts=layout.conflicts())
    at_once = lambda: True  # noqa: E731
    assert all(gate.acquire(t, at_once) for t in range(4)) and gate.holders == {0, 1, 2, 3}
    gate.release(0)
    assert not gate.acquire(4, at_once)  # the left column's slot 2 still holds its beam
    gate.release(2)
    assert gate.acquire(4, at_once) and gate.holders == {1, 3, 4}  # beside the right column's beams
    assert not gate.acquire(5, at_once)
    gate.release(1)
    gate.vacate(3)  # its beam off the target, still parking: the slot goes on
    assert gate.acquire(5, at_once) and gate.holders == {4, 5}


def test_the_next_lamp_is_the_one_whose_passes_the_models_lay_out_best(small_config, tmp_path):
    """A lamp whose spots are uncertain or mirror-wide (one slot: rate 1) waits for one whose
    spots fit several slots (rate K' / ROUND_COST, Eq. 3); a tie keeps the plan's order; one
    beam per target keeps the plan's order without asking."""
    cfg = load_config(far_lamp_config(small_config, tmp_path, 4))
    near = next(s.id for s in cfg.light_sources if s.kind == "lamp" and s.id not in cfg.calibration.lamps)
    far = cfg.calibration.light_source
    ids = [h.id for h in cfg.heliostats]
    calibrated = {h: calibrated_record(cfg, h) for h in ids}
    passes = [Pass("n/near", near, {h: cfg.target().center_enu_m for h in ids}),
              Pass("n/far", far, {h: cfg.target().center_enu_m for h in ids})]
    tid = cfg.calibration.target
    assert lamp_rate(cfg, near, [(tid, ids)], calibrated, 4) == pytest.approx(1.0)
    layout, fit = pass_layout(target_frame(cfg, tid), 4, slots.spot_reaches_m(cfg, tid, far, calibrated,
                                                                              cfg.target().center_enu_m),
                              cfg.calibration.planner.view_margin_m)
    rate = lamp_rate(cfg, far, [(tid, ids)], calibrated, 4)
    assert layout.k > 1 and rate > 1.0 and rate == pytest.approx(len(ids) / slots.layout_cost(layout, fit))
    choose = lamps_by_rate(cfg, lambda hids: {h: calibrated[h] for h in hids})
    assert choose([near, far], passes) == far
    unknown = lamps_by_rate(cfg, lambda hids: dict.fromkeys(hids))  # no model: one slot everywhere
    assert unknown([near, far], passes) == near
    one = load_config(_config(small_config, tmp_path, beams_per_target=1)[0])
    assert lamps_by_rate(one, lambda hids: dict.fromkeys(hids)) is None
