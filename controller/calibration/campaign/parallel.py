"""Several targets at once: one job (a campaign, a sequence of passes) per target, each on its
own thread with its own camera, beam chain and target gate, so each target has at most one
beam at a time while the targets work side by side (docs/campaigns.md, "Several targets");
and how the cycles' threads run while campaigns measure (:func:`campaign_threads`)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from typing import TypeVar

import cv2

from controller.devices.cores import HeldSetting, python_on_one_core

R = TypeVar("R")


def run_per_target(jobs: dict[str, Callable[[], R]],
                   stop_all: Callable[[], None] | None = None) -> dict[str, R]:
    """Run every target's job concurrently and wait for all of them; their results by target.

    Ctrl-C (KeyboardInterrupt) reaches the main thread only: ``stop_all`` then asks every
    job to stop (each campaign parks its beams and records itself interrupted), the jobs are
    waited for, and the interrupt is raised again. A job's exception is raised once all jobs
    have ended (the others are not cut short: their beams are parked by their own cycles)."""
    if len(jobs) == 1:
        ((tid, job),) = jobs.items()
        return {tid: job()}
    results: dict[str, R] = {}
    errors: dict[str, BaseException] = {}
    ended: dict[str, threading.Event] = {tid: threading.Event() for tid in jobs}

    def runner(tid: str, job: Callable[[], R]) -> None:
        try:
            results[tid] = job()
        except BaseException as exc:  # raised by the main thread once every job has ended
            errors[tid] = exc
        finally:
            ended[tid].set()

    # Waited for by their own events, not Thread.join: a Ctrl-C that lands inside join() can
    # leave the thread marked stopped while it still runs (CPython gh-90882), and the next
    # join() would return at once, before that target's beams were parked.
    threads: list[tuple[str, threading.Thread]] = []
    try:
        for tid, job in jobs.items():
            t = threading.Thread(target=runner, args=(tid, job), name=f"target-{tid}", daemon=True)
            # Listed before it starts: a Ctrl-C between the start and the listing would leave a
            # running job nobody waits for.
            threads.append((tid, t))
            t.start()
        for tid, _ in threads:
            while not ended[tid].wait(0.2):  # short waits: the main thread must stay interruptible
                pass
    except KeyboardInterrupt:
        if stop_all is not None:
            stop_all()
        for tid, t in threads:
            if t.ident is not None:  # started (a job interrupted before its start never ran)
                ended[tid].wait()
        raise
    for tid in jobs:
        if tid in errors:
            raise errors[tid]
    return {tid: results[tid] for tid in jobs}


def _opencv_one_thread() -> int:
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    return before


_OPENCV = HeldSetting(_opencv_one_thread, cv2.setNumThreads)


def opencv_single_threaded() -> contextlib.AbstractContextManager[None]:
    """OpenCV on the calling threads only while the block runs (``cv2.setNumThreads(1)``), as
    it was once the last of several overlapping blocks (a night's targets) has ended.

    A campaign's cycles run side by side, one thread each, so OpenCV's own worker pool adds no
    core: each call on a 128 x 96 frame is cut into stripes for it, and its workers spin
    (``sched_yield``) after every call. In a sampled night of a 10,000-heliostat field (3
    targets, K = 4) the pool's worker took 3.6 s of CPU, nearly all of it in the kernel, about
    3 % of the controller's, and 6 % of the night's context switches (issue 42)."""
    return _OPENCV.hold()


@contextlib.contextmanager
def campaign_threads(python_one_core: bool) -> Iterator[None]:
    """How a campaign's cycle threads run while it measures: OpenCV on them alone
    (:func:`opencv_single_threaded`) and, with ``python_one_core`` (``calibration.python_one_core``),
    every Python thread of the process on one core (:func:`controller.devices.cores.python_on_one_core`)."""
    with opencv_single_threaded(), python_on_one_core(python_one_core):
        yield
