"""The plant clock: plant seconds run ``speedup`` times faster than wall time, and can stand
still while the simulator works (rendering is the simulator's cost, not the plant's). The CPU
time the simulator spends while the clock stands still is counted (:attr:`PlantClock.frozen_cpu_s`),
and so is the CPU of the clock's own machinery in the threads that sleep on it or compute
(:attr:`PlantClock.clock_cpu_s`): a benchmark subtracts both to tell the controller's CPU from
the simulated plant's."""

from __future__ import annotations

import contextlib
import threading
import time


class PlantClock:
    """Plant time in seconds: ``speedup`` x wall time, which :meth:`frozen` can stop."""

    def __init__(self, speedup: float = 1.0, start: float = 0.0) -> None:
        self.speedup = float(speedup)
        self._lock = threading.Lock()
        self._base = start
        self._wall0 = time.monotonic()
        self._frozen = 0
        self._frozen_at = start
        self._realtime = 0
        self._local = threading.local()  # per thread: depth of frozen blocks, CPU time at the outermost
        self.frozen_cpu_s = 0.0  # CPU seconds spent inside frozen blocks, every thread
        # CPU seconds of the clock's machinery outside frozen blocks: sleeps waking to wait
        # again as the rate changes, and realtime()'s bookkeeping. A plant's controller sleeps
        # once per pause and its computing() is nothing: on the simulated plant a night's pause
        # is woken again whenever a thread stops computing (counted as the controller's before
        # 2026-11-30; issue 42).
        self.clock_cpu_s = 0.0
        self._faster = threading.Condition(self._lock)  # the clock may run faster (sleep)
        self._slow = 0  # sleeps timed at 1x or begun while still, waiting on _faster

    def __call__(self) -> float:
        with self._lock:
            return self._now()

    def _now(self) -> float:
        if self._frozen:
            return self._frozen_at
        return self._base + (time.monotonic() - self._wall0) * self._rate()

    @contextlib.contextmanager
    def frozen(self, advance_s: float = 0.0):
        """Stop plant time inside the block; afterwards continue ``advance_s`` later."""
        local = self._local
        depth = getattr(local, "depth", 0)
        local.depth = depth + 1
        if not depth:
            local.cpu0 = time.thread_time()
        with self._lock:
            self._frozen_at = self._now()  # unchanged inside an outer frozen block
            self._frozen += 1
        try:
            yield
        finally:
            with self._lock:
                self._frozen -= 1
                if not self._frozen:
                    self._base = self._frozen_at + advance_s
                    self._wall0 = time.monotonic()
                    self._wake_slow()
                local.depth = depth
                if not depth:
                    self.frozen_cpu_s += time.thread_time() - local.cpu0

    @contextlib.contextmanager
    def realtime(self):
        """Inside the block plant time runs at 1x: the controller's own computing costs the
        plant what it would cost on site, whatever the speedup (nestable, any thread)."""
        cpu0 = time.thread_time()
        with self._lock:
            self._rebase()
            self._realtime += 1
            self._count_cpu(cpu0)
        try:
            yield
        finally:
            cpu0 = time.thread_time()
            with self._lock:
                self._rebase()
                self._realtime -= 1
                self._wake_slow()
                self._count_cpu(cpu0)

    def _count_cpu(self, cpu0: float) -> None:
        """Add this thread's CPU since ``cpu0`` to :attr:`clock_cpu_s` (the caller holds the lock),
        unless a frozen block of this thread counts it already."""
        if not getattr(self._local, "depth", 0):
            self.clock_cpu_s += time.thread_time() - cpu0

    def _wake_slow(self) -> None:
        """The clock runs fast again (nobody computes, the simulator does not work): sleeps timed
        at 1x (or begun while it stood still) wait again for what is left at the new rate. Only
        then: while it still runs at 1x or stands still, a woken sleep would only wait again
        (each end of a block woke every such sleep before 2026-11-30: 4 wake-ups per sleep in
        a night of several beams per target, each one a hand-over of the interpreter)."""
        if self._slow and not self._frozen and not self._realtime:
            self._faster.notify_all()

    def _rebase(self) -> None:
        if not self._frozen:
            now = time.monotonic()
            self._base += (now - self._wall0) * self._rate()
            self._wall0 = now

    def _rate(self) -> float:
        return 1.0 if self._realtime else self.speedup

    def sleep(self, plant_seconds: float) -> None:
        """Sleep until ``plant_seconds`` of plant time have passed. The clock's rate changes while
        the sleep lasts — 1x while any thread computes (:meth:`realtime`), still while the
        simulator works (:meth:`frozen`) — so the sleep waits again for what is left at the rate
        of the moment; a sleep begun at 1x or still is timed at 1x and woken when that ends. (Before
        2026-11-29 it slept ``plant_seconds / speedup`` of wall time: with a night's cycles
        computing in turn, a 0.1 s poll pause lasted about 0.01 plant s, and a drive's wait read
        its status 23 times on average where 3.4 do now; issue 42.)"""
        cpu0 = time.thread_time()
        with self._lock:
            end = self._now() + max(0.0, plant_seconds)
            try:
                while (left := end - self._now()) > 0:
                    slow = bool(self._realtime or self._frozen)  # timed at 1x: woken when that ends
                    self._slow += slow
                    try:
                        self._faster.wait(left if slow else left / self.speedup)
                    finally:
                        self._slow -= slow
            finally:
                self._count_cpu(cpu0)
