"""Where the controller's threads run: its Python threads on one core while campaigns measure.

Every Python thread of a process runs under the one interpreter lock, so at most one of them
runs Python at a time, whatever the cores. A night of a 10,000-heliostat field runs some eighty
(a cycle per beam of each target's pipeline, a job per target, the state timeouts): spread over
two cores, every hand-over of the lock wakes the next thread on the other core (on a virtual
machine an exit to the hypervisor) and moves its working set between caches. Kept on one core,
the hand-over is a run-queue change on that core. In sampled nights of the 10,000-heliostat
field the night's voluntary context switches fell to a third and its kernel time to half, its
wall time unchanged (it used 1.1 cores; docs/results.md, issue 42).

Native threads keep every core: a camera's GigE stream thread (Aravis) receives packets at line
rate and must never wait behind Python. Only the threads Python knows are moved, and a thread
inherits its creator's cores, so a stream started while Python is held on one core is started
under :func:`all_cores`.

Linux only (``os.sched_setaffinity``); elsewhere, and where the process may use one core only,
nothing is moved. The setting is a performance hint: a thread that ends while it is moved is
left alone.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

PIN_ROUNDS = 1000  # listings of the threads when pinning, at most (threads that keep starting others)


class HeldSetting:
    """A process-wide setting held while any of several overlapping blocks runs (a night's
    targets each run a campaign): ``apply()`` when the first block enters, returning what to
    give back; ``restore(that)`` when the last one leaves, also on an exception."""

    def __init__(self, apply: Callable[[], Any], restore: Callable[[Any], None]) -> None:
        self._apply, self._restore = apply, restore
        self._lock = threading.Lock()
        self._users = 0
        self._saved: Any = None

    @property
    def held(self) -> bool:
        return self._users > 0

    @property
    def saved(self) -> Any:
        """What ``apply()`` returned for the blocks inside now (None outside them)."""
        return self._saved

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        with self._lock:
            if not self._users:
                self._saved = self._apply()
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if not self._users:
                    saved, self._saved = self._saved, None
                    self._restore(saved)


def _current_cpu() -> int | None:
    """The core the calling thread runs on now (``/proc/thread-self/stat``, field 39), None
    where it cannot be read. The scheduler placed the thread there for the load it saw, so
    processes that pin themselves at different times spread over the cores."""
    try:
        with open("/proc/thread-self/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[36])
    except (OSError, ValueError, IndexError):
        return None


def _set(tid: int, cpus: set[int]) -> None:
    with contextlib.suppress(OSError):  # the thread ended meanwhile
        os.sched_setaffinity(tid, cpus)


def _python_threads() -> list[int]:
    return [t.native_id for t in threading.enumerate() if t.native_id is not None]


def _pin_python() -> tuple[set[int], dict[int, set[int]]] | None:
    """Every Python thread onto the calling thread's core; (the cores the calling thread may
    use, taken as the process's; each moved thread's own) to give back, None when nothing was
    moved."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    everywhere = os.sched_getaffinity(0)
    if len(everywhere) < 2:
        return None
    cpu = _current_cpu()
    core = {cpu if cpu in everywhere else min(everywhere)}
    before: dict[int, set[int]] = {}
    seen: set[int] = set()
    # A thread not moved yet may start another meanwhile, which inherits its cores: threads are
    # listed again until every one is moved (those still starting have no id yet: waited for).
    for _ in range(PIN_ROUNDS):
        threads = threading.enumerate()
        new = [t.native_id for t in threads if t.native_id is not None and t.native_id not in seen]
        seen.update(new)
        moved = 0
        for tid in new:
            with contextlib.suppress(OSError):
                before[tid] = os.sched_getaffinity(tid)
                if before[tid] != core:  # else started by a thread moved already
                    os.sched_setaffinity(tid, core)
                    moved += 1
        if not moved and all(t.native_id is not None for t in threads):
            break
        if not new:
            time.sleep(0)  # let a starting thread run to where it has an id
    return everywhere, before


def _unpin_python(saved: tuple[set[int], dict[int, set[int]]] | None) -> None:
    """Every Python thread back onto its own cores (those started meanwhile onto the process's)."""
    if saved is None:
        return
    everywhere, before = saved
    for tid in _python_threads():
        _set(tid, before.get(tid, everywhere))


_ONE_CORE = HeldSetting(_pin_python, _unpin_python)


@contextlib.contextmanager
def python_on_one_core(enabled: bool = True) -> Iterator[None]:
    """Every Python thread of the process on one core while the block runs (the core the first
    of several overlapping blocks runs on), back on its own cores once the last has ended; the
    threads started meanwhile inherit the core and are given the process's cores back. Nothing
    moves when not ``enabled`` (``calibration.python_one_core: false``)."""
    if not enabled:
        yield
        return
    with _ONE_CORE.hold():
        yield


@contextlib.contextmanager
def all_cores() -> Iterator[None]:
    """The calling thread on every core the process may use while the block runs, so the native
    threads it starts (a GigE stream's) never inherit the one core of :func:`python_on_one_core`;
    nothing changes outside such a block."""
    saved = _ONE_CORE.saved
    if saved is None:
        yield
        return
    own = os.sched_getaffinity(0)
    os.sched_setaffinity(0, saved[0])
    try:
        yield
    finally:
        # The last hold may have ended meanwhile and given every Python thread its cores back.
        os.sched_setaffinity(0, own if _ONE_CORE.held else saved[0])
