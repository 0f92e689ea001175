"""The controller's Python threads on one core while campaigns measure, and back after
(controller.devices.cores), on this machine's own scheduler."""

from __future__ import annotations

import os
import threading

import pytest

from controller.devices.cores import HeldSetting, all_cores, python_on_one_core
from tests.conftest import scaled_s

EVERYWHERE = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
needs_two = pytest.mark.skipif(len(EVERYWHERE) < 2, reason="the process may use fewer than two cores here")


class Parked:
    """A Python thread that waits until told to go, reporting its cores when asked."""

    def __init__(self) -> None:
        self.ask, self.told, self.go = threading.Event(), threading.Event(), threading.Event()
        self.cores: set[int] = set()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while self.ask.wait():
            self.ask.clear()
            if self.go.is_set():
                return
            self.cores = os.sched_getaffinity(0)
            self.told.set()

    def cores_now(self) -> set[int]:
        self.told.clear()
        self.ask.set()
        assert self.told.wait(scaled_s(5.0))
        return self.cores

    def end(self) -> None:
        self.go.set()
        self.ask.set()
        self.thread.join(scaled_s(5.0))


def _started_thread_cores() -> set[int]:
    seen: list[set[int]] = []
    t = threading.Thread(target=lambda: seen.append(os.sched_getaffinity(0)))
    t.start()
    t.join(scaled_s(5.0))
    return seen[0]


@needs_two
def test_every_python_thread_shares_one_core_until_the_last_block_ends():
    other = Parked()
    try:
        with python_on_one_core():
            core = os.sched_getaffinity(0)
            assert len(core) == 1 and core <= EVERYWHERE
            assert other.cores_now() == core  # a thread already running is moved too
            assert _started_thread_cores() == core  # one started meanwhile inherits it
            with python_on_one_core():  # a second campaign (another target) keeps the core
                assert os.sched_getaffinity(0) == core
            assert os.sched_getaffinity(0) == core  # the first has not ended
            late = Parked()
            assert late.cores_now() == core
        assert os.sched_getaffinity(0) == EVERYWHERE
        assert other.cores_now() == EVERYWHERE
        assert late.cores_now() == EVERYWHERE  # started while held: given the process's cores
        late.end()
        with pytest.raises(RuntimeError), python_on_one_core():
            raise RuntimeError("a campaign that fails")
        assert os.sched_getaffinity(0) == EVERYWHERE
    finally:
        other.end()


@needs_two
def test_a_thread_keeps_its_own_narrower_cores():
    """A thread someone put on its own cores gets those back, not the process's."""
    own = {min(EVERYWHERE)}
    other = Parked()
    try:
        os.sched_setaffinity(other.thread.native_id, own)
        with python_on_one_core():
            assert len(other.cores_now()) == 1
        assert other.cores_now() == own
    finally:
        other.end()


@needs_two
def test_nothing_moves_when_switched_off():
    with python_on_one_core(enabled=False):
        assert os.sched_getaffinity(0) == EVERYWHERE
        assert _started_thread_cores() == EVERYWHERE


@needs_two
def test_threads_started_under_all_cores_run_everywhere():
    """What a camera's native threads get when it is opened while Python is on one core."""
    assert _started_thread_cores() == EVERYWHERE
    with all_cores():  # outside a hold: nothing changes
        assert os.sched_getaffinity(0) == EVERYWHERE
    with python_on_one_core():
        core = os.sched_getaffinity(0)
        with all_cores():
            assert _started_thread_cores() == EVERYWHERE
        assert os.sched_getaffinity(0) == core and len(core) == 1


def test_a_held_setting_is_applied_once_and_restored_by_the_last_block():
    calls: list[str] = []
    setting = HeldSetting(lambda: calls.append("apply") or "saved", lambda s: calls.append(f"restore {s}"))
    with setting.hold():
        with setting.hold():
            assert setting.held and setting.saved == "saved"
        assert calls == ["apply"]
    assert calls == ["apply", "restore saved"] and not setting.held and setting.saved is None


SPAWNERS = 4


@needs_two
def test_threads_started_while_the_block_begins_are_moved_too():
    """A thread not moved yet that starts threads while the first block moves the others: every
    thread it started is on the one core once the block has begun (a thread inherits its
    creator's cores, so one started just after the threads were listed would otherwise keep
    every core for the whole block)."""
    stop, release = threading.Event(), threading.Event()
    started: list[threading.Thread] = []

    def spawn() -> None:
        while not stop.is_set():
            t = threading.Thread(target=release.wait, daemon=True)
            t.start()
            started.append(t)

    spawners = [threading.Thread(target=spawn, daemon=True) for _ in range(SPAWNERS)]
    for s in spawners:
        s.start()
    try:
        with python_on_one_core():
            stop.set()
            for s in spawners:
                s.join(scaled_s(5.0))
            cores = {frozenset(os.sched_getaffinity(t.native_id)) for t in started}
            assert len(started) > SPAWNERS and len(cores) == 1 and len(next(iter(cores))) == 1, cores
    finally:
        stop.set()
        release.set()
        for s in spawners:
            s.join(scaled_s(5.0))
