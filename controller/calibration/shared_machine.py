"""State timeouts of the calibration cycle without a thread per state.

``transitions``' ``Timeout`` state feature starts a ``threading.Timer`` — a new thread — each
time a state is entered, and cancels it when the state is left. A cycle enters about a dozen
states per measurement, so a night of 30,000 measurements started and stopped some 400,000
threads, a third of the state machine's cost. :class:`SharedTimeout` keeps the feature's
contract (``timeout`` wall seconds, ``on_timeout`` callbacks run on a thread of their own once
the state has been held that long; leaving the state first cancels them) over one scheduler
thread for every cycle of the process (:class:`Deadlines`); a thread is started only when a
timeout actually fires.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable

from transitions.extensions.states import Timeout


class Deadlines:
    """Calls due after a delay (wall seconds), on one daemon thread; each due call runs on a
    thread of its own, so a callback that blocks delays no other."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._heap: list[list] = []  # [due, seq, call, args]; call None once cancelled or fired
        self._cancelled = 0
        self._seq = itertools.count()
        self._thread: threading.Thread | None = None

    def add(self, delay_s: float, call: Callable, *args) -> list:
        """Schedule ``call(*args)`` in ``delay_s`` wall seconds; returns its handle."""
        entry = [time.monotonic() + delay_s, next(self._seq), call, args]
        with self._cv:
            heapq.heappush(self._heap, entry)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="state-timeouts", daemon=True)
                self._thread.start()
            if self._heap[0] is entry:
                self._cv.notify()
        return entry

    def cancel(self, entry: list) -> None:
        """The call of ``entry`` will not be made (nothing if it was already)."""
        with self._cv:
            if entry[2] is None:
                return
            entry[2] = None
            self._cancelled += 1
            if self._cancelled > 64 and self._cancelled > len(self._heap) // 2:
                # Long timeouts cancelled early would otherwise pile up until they are due.
                self._heap = [e for e in self._heap if e[2] is not None]
                heapq.heapify(self._heap)
                self._cancelled = 0

    def _run(self) -> None:
        with self._cv:
            while True:
                while self._heap and self._heap[0][2] is None:
                    heapq.heappop(self._heap)
                    self._cancelled -= 1
                if not self._heap:
                    self._cv.wait()
                    continue
                wait = self._heap[0][0] - time.monotonic()
                if wait > 0:
                    self._cv.wait(wait)
                    continue
                entry = heapq.heappop(self._heap)
                call, args = entry[2], entry[3]
                entry[2] = None
                threading.Thread(target=call, args=args, name="state-timeout", daemon=True).start()


DEADLINES = Deadlines()


class SharedTimeout(Timeout):
    """``transitions``' ``Timeout`` state feature over :data:`DEADLINES` (module docstring)."""

    def enter(self, event_data):
        if self.timeout > 0:
            self.runner[id(event_data.model)] = DEADLINES.add(self.timeout, self._process_timeout, event_data)
        return super(Timeout, self).enter(event_data)

    def exit(self, event_data):
        entry = self.runner.pop(id(event_data.model), None)
        if entry is not None:
            DEADLINES.cancel(entry)
        return super(Timeout, self).exit(event_data)
