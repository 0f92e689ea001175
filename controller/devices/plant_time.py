"""Plant time: the one clock every wait, deadline and time stamp of the controller reads.

On a real field it is the wall clock. A simulated plant hands in its own (plant seconds that
may run faster than wall time, and that run at 1x while the controller computes, so that the
controller's own work costs the plant what it would cost on site). Drivers, the calibration
cycle, lamp changes and the console all take one :class:`PlantTime` instead of separate
clock, sleep, UTC and polling parameters.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from datetime import UTC, datetime


def utc_now() -> str:
    """The wall clock as an ISO 8601 UTC stamp with milliseconds."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class PlantTime:
    """``now()``: plant seconds (monotonic); ``sleep(s)``: wait ``s`` plant seconds; ``utc()``:
    the plant's calendar time (ISO 8601, UTC) stamped on records; ``computing()``: a context
    manager around the controller's own computing (a simulated plant lets its clock run at 1x
    there; on a real field it does nothing); ``poll_s``: how often a wait polls a device, in
    plant seconds."""

    now: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    utc: Callable[[], str] = utc_now
    computing: Callable[[], AbstractContextManager] = field(default=nullcontext)
    poll_s: float = 0.1

    def deadline(self, timeout_s: float) -> float:
        """The plant time ``timeout_s`` plant seconds from now."""
        return self.now() + timeout_s

    def wait_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Poll ``done()`` every ``poll_s`` until it is true (True) or ``timeout_s`` plant seconds
        have passed (False); ``done`` is asked once more at the deadline."""
        end = self.deadline(timeout_s)
        while not done():
            if self.now() >= end:
                return bool(done())
            self.sleep(self.poll_s)
        return True


WALL = PlantTime()
