"""Several targets at once: one job (a campaign, a sequence of passes) per target, each on its
own thread with its own camera, beam chain and target gate, so each target has at most one
beam at a time while the targets work side by side (docs/campaigns.md, "Several targets")."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

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

    def runner(tid: str, job: Callable[[], R]) -> None:
        try:
            results[tid] = job()
        except BaseException as exc:  # raised by the main thread once every job has ended
            errors[tid] = exc

    threads: list[threading.Thread] = []
    try:
        for tid, job in jobs.items():
            t = threading.Thread(target=runner, args=(tid, job), name=f"target-{tid}", daemon=True)
            # Listed before it starts: a Ctrl-C between the start and the listing would leave a
            # running job nobody waits for.
            threads.append(t)
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(0.2)  # short joins: the main thread must stay interruptible by Ctrl-C
    except KeyboardInterrupt:
        if stop_all is not None:
            stop_all()
        for t in threads:
            if t.ident is not None:  # started (a job interrupted before its start never ran)
                t.join()
        raise
    for tid in jobs:
        if tid in errors:
            raise errors[tid]
    return {tid: results[tid] for tid in jobs}
