"""The garbage collector's pace during a night (controller.calibration.night.collector): the
night's thresholds while any night of the process runs, the process's own once the last has
ended — also when a night ends by an exception, and when two nights overlap in threads."""

from __future__ import annotations

import gc
import threading
from pathlib import Path

import pytest

from controller.calibration.campaign.runner import CampaignResult
from controller.calibration.night.collector import THRESHOLDS, night_collector
from controller.calibration.night.passes import run_night
from controller.calibration.night.planner import plan_night
from controller.config import load_config
from tests.calibration.conftest import calibrated_record
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def own_thresholds():
    before = gc.get_threshold()
    gc.set_threshold(901, 11, 12)  # the process's own: not CPython's default, not the night's
    yield (901, 11, 12)
    gc.set_threshold(*before)


def test_a_night_runs_its_passes_at_the_nights_pace_and_gives_the_process_its_own_back(own_thresholds):
    cfg = load_config(REPO / "configs" / "demo.yaml")
    plan = plan_night(cfg, {h.id: calibrated_record(cfg, h.id) for h in cfg.heliostats[:2]}, "n")
    seen = []

    def run_pass(p):
        seen.append(gc.get_threshold())
        return CampaignResult(0, p.name, False, [], 0.0, 0.0, "finished")

    run_night(plan, "n", run_pass)
    assert seen and set(seen) == {THRESHOLDS}
    assert gc.get_threshold() == own_thresholds


def test_a_night_that_fails_still_gives_the_thresholds_back(own_thresholds):
    with pytest.raises(KeyboardInterrupt), night_collector():
        assert gc.get_threshold() == THRESHOLDS
        raise KeyboardInterrupt
    assert gc.get_threshold() == own_thresholds


def test_overlapping_nights_keep_the_pace_until_the_last_ends(own_thresholds):
    first_in, second_out = threading.Event(), threading.Event()
    during: list[tuple[int, ...]] = []

    def first():
        with night_collector():
            first_in.set()
            second_out.wait(scaled_s(10))
            during.append(gc.get_threshold())  # the second night ended: this one still runs

    t = threading.Thread(target=first)
    t.start()
    assert first_in.wait(scaled_s(10))
    with night_collector():
        during.append(gc.get_threshold())
    second_out.set()
    t.join(scaled_s(10))
    assert during == [THRESHOLDS, THRESHOLDS]
    assert gc.get_threshold() == own_thresholds
