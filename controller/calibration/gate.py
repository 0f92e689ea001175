"""One beam on the target at a time: the target is handed out in queue order."""

from __future__ import annotations

import threading
from collections.abc import Callable


class TargetGate:
    """Hands the target to one heliostat at a time, in queue order (tickets 0, 1, 2, …).

    ``acquire(ticket)`` blocks until every smaller ticket was released (or skipped);
    ``blocked`` becomes True when a beam may have been left on the target, after which nobody
    gets the target again.
    """

    def __init__(self, first_ticket: int = 0) -> None:
        self._cv = threading.Condition()
        self._next = first_ticket
        self._done: set[int] = set()
        self.holder: int | None = None
        self.blocked = False

    def acquire(self, ticket: int, cancelled: Callable[[], bool], poll_s: float = 0.05) -> bool:
        with self._cv:
            while not (self._next == ticket and self.holder is None) or self.blocked:
                if cancelled() or self.blocked:
                    return False
                self._cv.wait(poll_s)
            self.holder = ticket
            return True

    def release(self, ticket: int, beam_off_target: bool = True) -> None:
        """Give the target back (or skip this ticket if it never held it)."""
        with self._cv:
            if not beam_off_target:
                self.blocked = True
            if self.holder == ticket:
                self.holder = None
            self._done.add(ticket)
            while self._next in self._done:
                self._next += 1
            self._cv.notify_all()
