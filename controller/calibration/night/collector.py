"""The garbage collector's pace while a night runs.

A night allocates container objects without pause (records, observations, frames of the cycle
threads) and keeps, all night, a large heap that never becomes garbage: the field, its models,
the plan, the stores' caches. With CPython's default thresholds (700, 10, 10) a young
collection runs every 700 allocations, objects that live a few cycles are promoted, and each
of the frequent full collections walks that whole heap again. :data:`THRESHOLDS` let what lives
a cycle die young; collection is not switched off: cyclic garbage is still freed, less often.
What it saves on a 10,000-heliostat night: docs/results.md (the benchmark's ``gc``).
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

# (young, middle, old): a young collection every 20,000 net allocations; gc.set_threshold's meaning.
THRESHOLDS = (20_000, 20, 10)

_lock = threading.Lock()
_running = [0, None]  # nights running in this process, the thresholds before the first


@contextmanager
def night_collector() -> Iterator[None]:
    """:data:`THRESHOLDS` while the night runs (also usable as a decorator); the thresholds as
    they were once the last of the process's running nights has ended (the console can run a
    night beside other work)."""
    with _lock:
        if _running[0] == 0:
            _running[1] = gc.get_threshold()
            gc.set_threshold(*THRESHOLDS)
        _running[0] += 1
    try:
        yield
    finally:
        with _lock:
            _running[0] -= 1
            if _running[0] == 0:
                gc.set_threshold(*_running[1])
