"""The simulated plant's clock: a sleep lasts its plant seconds whatever the clock's rate does
meanwhile (1x while the controller computes, still while the simulator works)."""

from __future__ import annotations

import threading
import time

import pytest

from simplant.clock import PlantClock
from tests.conftest import scaled_s

SPEEDUP = 1000.0


class Held:
    """A thread inside one of the clock's blocks (``realtime`` or ``frozen``) until released."""

    def __init__(self, block) -> None:
        self.inside, self.release = threading.Event(), threading.Event()
        self.thread = threading.Thread(target=self._hold, args=(block,), daemon=True)
        self.thread.start()
        assert self.inside.wait(scaled_s(5))

    def _hold(self, block) -> None:
        with block():
            self.inside.set()
            self.release.wait()

    def end(self) -> None:
        self.release.set()
        self.thread.join(scaled_s(5))


def sleeping(clock: PlantClock, plant_s: float) -> tuple[threading.Event, dict]:
    """Start a thread sleeping ``plant_s`` on ``clock``; (done, {"slept": plant seconds})."""
    done, out = threading.Event(), {}

    def run() -> None:
        t0 = clock()
        clock.sleep(plant_s)
        out["slept"] = clock() - t0
        done.set()

    threading.Thread(target=run, daemon=True).start()
    return done, out


def asleep_slow(clock: PlantClock) -> bool:
    """Wait until a sleep timed at 1x waits on the clock (bounded)."""
    gate = threading.Event()
    for _ in range(1000):
        with clock._lock:
            if clock._slow:
                return True
        gate.wait(scaled_s(0.002))
    return False


@pytest.mark.parametrize("block", ["realtime", "frozen"])
def test_sleep_lasts_its_plant_seconds_and_wakes_when_the_clock_speeds_up(block):
    """Begun while another thread computes (1x) or the simulator works (still), a sleep of
    20 plant s neither ends after 20 / speedup s of wall time (the plant would have moved on
    only that far at 1x) nor waits 20 s of wall time once the clock runs fast again."""
    clock = PlantClock(SPEEDUP)
    held = Held(getattr(clock, block))
    done, out = sleeping(clock, 20.0)
    assert asleep_slow(clock)
    assert not done.is_set()
    held.end()
    assert done.wait(scaled_s(3.0)), "the sleep was not woken when the clock sped up"
    assert out["slept"] >= 20.0


def test_a_short_sleep_at_full_speed_keeps_its_plant_seconds():
    clock = PlantClock(SPEEDUP)
    done, out = sleeping(clock, 0.5)
    assert done.wait(scaled_s(3.0))
    assert out["slept"] >= 0.5


def test_a_slow_sleep_is_woken_only_when_the_clock_runs_fast_again():
    """A block that ends while another still holds the clock at 1x or still does not wake the
    sleeps timed at 1x (they would only wait again: a hand-over of the interpreter each); the
    end of the last block wakes them, and the sleep keeps its plant seconds."""
    clock = PlantClock(SPEEDUP)
    wakes = []
    notify_all = clock._faster.notify_all
    clock._faster.notify_all = lambda: (wakes.append(1), notify_all())
    computing, working = Held(clock.realtime), Held(clock.frozen)
    done, out = sleeping(clock, 20.0)
    assert asleep_slow(clock)
    working.end()
    assert not wakes and not done.is_set()
    computing.end()
    assert done.wait(scaled_s(3.0)), "the sleep was not woken when the clock sped up"
    assert len(wakes) == 1 and out["slept"] >= 20.0


def busy(cpu_s: float) -> None:
    """Spend ``cpu_s`` of this thread's CPU."""
    t0 = time.thread_time()
    while time.thread_time() - t0 < cpu_s:
        pass


def test_the_clocks_machinery_is_counted_and_not_the_work_inside_its_blocks():
    """``clock_cpu_s`` counts what the clock itself costs a thread (a sleep, the bookkeeping of
    a computing block), never the computing inside ``realtime`` nor the simulator's work inside
    ``frozen`` (``frozen_cpu_s``), and a sleep inside a frozen block only once."""
    clock = PlantClock(SPEEDUP)
    with clock.realtime():
        busy(0.05)
    assert 0.0 < clock.clock_cpu_s < 0.01
    with clock.frozen():
        busy(0.05)
        before = clock.clock_cpu_s
        clock.sleep(0.0)
        assert clock.clock_cpu_s == before  # frozen_cpu_s counts it
    assert clock.frozen_cpu_s >= 0.05
    before = clock.clock_cpu_s
    clock.sleep(0.5)
    assert clock.clock_cpu_s > before
