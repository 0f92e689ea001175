"""Several targets at once: one job (a campaign, a sequence of passes) per target, each on its
own thread with its own camera, beam chain and target gate, so each target has at most one
beam at a time while the targets work side by side (docs/campaigns.md, "Several targets")."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
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
    with ThreadPoolExecutor(max_workers=len(jobs), thread_name_prefix="target") as pool:
        futures = {}
        try:
            for tid, job in jobs.items():
                futures[tid] = pool.submit(job)
            # Short waits: the main thread must stay interruptible by Ctrl-C.
            while wait(futures.values(), timeout=0.2).not_done:
                pass
        except KeyboardInterrupt:
            if stop_all is not None:
                stop_all()
            pool.shutdown(wait=True)
            raise
    return {tid: f.result() for tid, f in futures.items()}
