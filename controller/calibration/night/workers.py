"""Work that is the same for every heliostat, shared over a pool of processes.

Planning a heliostat's night, refitting its model or predicting its daytime error depends on
that heliostat alone (and on what the whole field shares: the configuration). A field of
thousands is therefore cut into chunks and handed to worker processes, each of which builds
the shared context once (``setup``). The result is the same as one at a time — the same
function on the same inputs, in order — only sooner: ``fn(context, chunk)`` must not depend
on anything but its arguments.

Workers are started with ``spawn`` (a fresh interpreter, not a fork of a process that may run
device threads, whose locks a fork would copy mid-use); starting them costs about a second,
so a small field is done in this process (:data:`POOL_MIN_TASKS`). A spawned worker imports
the main script again: a script without the ``if __name__ == "__main__":`` guard breaks its
workers, and the work is then done in this process (same result, slower).
"""

from __future__ import annotations

import math
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

POOL_MIN_TASKS = 400  # below this a pool's start-up costs more than it saves
CHUNKS_PER_WORKER = 8  # small enough to balance the workers, large enough to pay the pickling

_CONTEXT: dict[str, Any] = {}


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on every platform
        return max(1, os.cpu_count() or 1)


def map_chunks(fn: Callable[[Any, list], list], tasks: Sequence, *, setup: Callable[..., Any],
               setup_args: tuple = (), workers: int | None = None) -> list:
    """``fn(setup(*setup_args), chunk)`` over chunks of ``tasks``, concatenated in order.
    ``workers``: processes (None: :func:`default_workers` when there are at least
    :data:`POOL_MIN_TASKS` tasks, else 1 — in this process)."""
    tasks = list(tasks)
    if workers is None:
        workers = default_workers() if len(tasks) >= POOL_MIN_TASKS else 1
    if workers <= 1 or len(tasks) < 2:
        return list(fn(setup(*setup_args), tasks))
    size = max(1, math.ceil(len(tasks) / (workers * CHUNKS_PER_WORKER)))
    chunks = [tasks[i:i + size] for i in range(0, len(tasks), size)]
    try:
        with ProcessPoolExecutor(max_workers=min(workers, len(chunks)),
                                 mp_context=multiprocessing.get_context("spawn"),
                                 initializer=_init, initargs=(setup, setup_args)) as pool:
            return [r for part in pool.map(_call, [fn] * len(chunks), chunks) for r in part]
    except BrokenProcessPool:  # the workers could not start (see the module docstring)
        return list(fn(setup(*setup_args), tasks))


def _init(setup: Callable[..., Any], args: tuple) -> None:
    _CONTEXT["ctx"] = setup(*args)


def _call(fn: Callable[[Any, list], list], chunk: list) -> list:
    return list(fn(_CONTEXT["ctx"], chunk))
