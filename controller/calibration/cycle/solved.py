"""Results a night solves again and again, kept once: a heliostat's steps onto a point, its
standby clearance. The same heliostat, model, source and point come back many times in a
night (its lamp change, its pass's queue, slot and cycle)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any


class Solved:
    """A thread-safe store of at most ``kept`` results, least recently used dropped first.
    A key may name objects by ``id()``; each result is kept with those objects (``owners``) and
    found only for the very same ones, since an id is reused once its object is gone."""

    def __init__(self, kept: int) -> None:
        self.kept = kept
        self._items: OrderedDict[tuple, tuple[tuple, Any]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple, owners: tuple, solve: Callable[[], Any]) -> Any:
        """The result kept for ``key`` and ``owners``, else ``solve()``'s (never None), kept (an
        exception is raised and nothing kept)."""
        value = self.peek(key, owners)
        if value is None:
            value = solve()
            self.put(key, owners, value)
        return value

    def peek(self, key: tuple, owners: tuple) -> Any:
        """The result kept for ``key`` and ``owners``, else None."""
        with self._lock:
            hit = self._items.get(key)
            if hit is None or not all(a is b for a, b in zip(hit[0], owners, strict=True)):
                return None
            self._items.move_to_end(key)
            return hit[1]

    def put(self, key: tuple, owners: tuple, value: Any) -> None:
        """Keep ``value`` for ``key`` and ``owners``."""
        with self._lock:
            self._items[key] = (owners, value)
            if len(self._items) > self.kept:
                self._items.popitem(last=False)


_SOURCES = Solved(64)


def source_key(source) -> str:
    """``repr(source)`` (a lamp's or the sun's config, frozen), kept per object: the clearances'
    key names the source by it, and a pydantic repr costs tens of µs, asked for a few times per
    heliostat and slot (1 % of a whole-plan night's controller CPU; issue 42)."""
    return _SOURCES.get((id(source),), (source,), lambda: repr(source))
