"""The plant clock: plant seconds run ``speedup`` times faster than wall time, and can stand
still while the simulator works (rendering is the simulator's cost, not the plant's). The CPU
time the simulator spends while the clock stands still is counted (:attr:`PlantClock.frozen_cpu_s`):
a benchmark subtracts it to tell the controller's CPU from the simulated plant's."""

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

    def __call__(self) -> float:
        with self._lock:
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
            if not self._frozen:
                self._frozen_at = self._base + (time.monotonic() - self._wall0) * self._rate()
            self._frozen += 1
        try:
            yield
        finally:
            with self._lock:
                self._frozen -= 1
                if not self._frozen:
                    self._base = self._frozen_at + advance_s
                    self._wall0 = time.monotonic()
                local.depth = depth
                if not depth:
                    self.frozen_cpu_s += time.thread_time() - local.cpu0

    @contextlib.contextmanager
    def realtime(self):
        """Inside the block plant time runs at 1x: the controller's own computing costs the
        plant what it would cost on site, whatever the speedup (nestable, any thread)."""
        with self._lock:
            self._rebase()
            self._realtime += 1
        try:
            yield
        finally:
            with self._lock:
                self._rebase()
                self._realtime -= 1

    def _rebase(self) -> None:
        if not self._frozen:
            now = time.monotonic()
            self._base += (now - self._wall0) * self._rate()
            self._wall0 = now

    def _rate(self) -> float:
        return 1.0 if self._realtime else self.speedup

    def sleep(self, plant_seconds: float) -> None:
        """Sleep for ``plant_seconds`` of plant time (in wall time: divided by the speedup)."""
        time.sleep(max(0.0, plant_seconds) / self.speedup)
