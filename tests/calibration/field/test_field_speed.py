"""Pieces that make a large field's night and its reprocessing cheap, each checked for doing
what it replaced: state timeouts on one scheduler thread, reprocessing tasks sized from the
measured cost."""

from __future__ import annotations

import threading
import time

import pytest

from controller.calibration.cycle.shared_machine import Deadlines
from controller.calibration.reprocess.plan import (
    FIRST_TASK_PAIRS,
    MAX_TASK_PAIRS,
    TASK_S,
    TaskSizer,
    take_task,
)
from tests.conftest import scaled_s


def test_a_due_call_runs_on_its_own_thread_and_a_cancelled_one_never():
    d = Deadlines()
    fired: list[tuple[str, str]] = []
    done = threading.Event()

    def call(name: str) -> None:
        fired.append((name, threading.current_thread().name))
        done.set()

    keep = d.add(0.05, call, "kept")
    dropped = d.add(0.02, call, "dropped")
    d.cancel(dropped)
    assert done.wait(scaled_s(5))
    time.sleep(0.1)  # the cancelled call was due before the kept one
    assert [n for n, _ in fired] == ["kept"]
    assert fired[0][1] == "state-timeout"
    d.cancel(keep)  # after it fired: nothing happens


def test_many_cancelled_long_timeouts_do_not_pile_up():
    d = Deadlines()
    for _ in range(1000):
        d.cancel(d.add(1800.0, print))
    assert len(d._heap) < 200


def test_tasks_last_the_aimed_time_at_the_measured_cost_and_keep_to_one_campaign():
    s = TaskSizer()
    assert s.size == FIRST_TASK_PAIRS
    s.tell(4, 0.04)  # 10 ms a pair
    assert s.size == pytest.approx(TASK_S / 0.01, abs=1) and s.size * 0.01 >= 0.1
    s.tell(4, 40.0)  # very slow pairs: at least one a task
    assert s.size == 1
    fast = TaskSizer()
    fast.tell(1000, 0.001)
    assert fast.size == MAX_TASK_PAIRS
    todo = iter([("a", 1), ("a", 2), ("a", 3), ("b", 4), ("b", 5)])
    assert take_task(todo, 2) == (("a", (1, 2)),)
    assert take_task(todo, 4) == (("a", (3,)), ("b", (4, 5)))  # a task may span campaigns
    assert take_task(todo, 4) == ()
