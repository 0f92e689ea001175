"""Archive reprocessing on Dask: the cluster, the tasks and the single writer (docs/reprocess.md).

* **Cluster**: ``dask.distributed`` — a scheduler given by address (``tcp://HOST:PORT``, any
  cluster whose workers run this project's environment and see the archive's paths), or a
  local cluster of worker processes on 127.0.0.1.
* **Tasks**: one per chunk of pairs (:func:`controller.calibration.reprocess.tasks.analyse_chunk`:
  the worker reads the frames from their paths, only paths and small results travel through
  the scheduler), sized from the measured cost per pair to last about 0.3 s (Dask's scheduler
  costs ~1 ms a task) and submitted as earlier ones finish, then one per heliostat refit
  (:func:`controller.calibration.reprocess.tasks.refit_heliostat`).
* **One writer**: results come back to this process, which alone writes the output database
  (a :class:`ReprocessSink`), one transaction per chunk or batch of refits. A worker that dies
  loses only the task it held: the scheduler runs it again elsewhere; a rerun of the command
  skips what was committed.
"""

from __future__ import annotations

import itertools
import logging
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from controller.calibration.records import ModelRecord
from controller.calibration.reprocess.plan import (
    Archive,
    Configs,
    TaskSizer,
    plan_pairs,
    refit_specs,
    take_task,
)
from controller.calibration.reprocess.scheduler import ClusterError, check_scheduler
from controller.calibration.reprocess.tasks import (
    PairResult,
    RefitResult,
    analyse_timed,
    outcome,
    refit_heliostat,
)

REFIT_BATCH = 64  # refits committed per transaction
TASKS_PER_WORKER = 3  # pair tasks in flight per worker: one running, the next ones queued on it
# A local cluster's workers (docs/reprocess.md, "On a cluster", for workers started by hand):
# * the nanny's MALLOC_TRIM_THRESHOLD_ fixes glibc's mmap threshold, so every image-sized array
#   is mapped and faulted in afresh: the same pairs cost 45 % more CPU (6.3 instead of 4.3 s
#   for 1,020 pairs in one process; twice the loop's CPU on the workers);
# * the statistical profiler samples the task's thread every 10 ms for a dashboard a local
#   cluster does not serve.
# * Dask's own log lines (a task's traceback, a worker lost) would reach the user's stderr beside
#   the command's one line: the workers start with Dask's loggers at "critical".
LOCAL_WORKERS = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                 "distributed.nanny.pre-spawn-environ.DASK_LOGGING__DISTRIBUTED": "critical",
                 "distributed.worker.profile.enabled": False}
CONNECT_TIMEOUT_S = 10.0  # --connect-timeout's default
WORKER_WAIT_S = 60.0  # for the first worker of a cluster (all of a local one)


class ReprocessSink(Protocol):
    """Where results go (:class:`controller.storage.reprocess.db.ReprocessDb`); called from the
    client's thread only."""

    def done_pairs(self) -> set[int]: ...
    def record_pairs(self, results: list[PairResult], old: dict) -> None: ...
    def pair_results(self) -> dict[int, PairResult]: ...
    def done_models(self) -> set[str]: ...
    def record_models(self, results: list[RefitResult], old: dict[str, ModelRecord]) -> None: ...


@dataclass
class Cluster:
    """A connected Dask client: ``workers`` at the start, the scheduler's ``address``,
    ``local`` when this process started it."""

    client: Any
    workers: int
    address: str
    local: bool


@contextmanager
def quiet_dask() -> Iterator[None]:
    """Dask's log output (distributed's and tornado's handlers, asyncio's warnings) silenced
    while the cluster is used: what goes wrong reaches the user as the command's one line."""
    handlers = [(h, h.level) for name in ("distributed", "tornado")
                for h in logging.getLogger(name).handlers]
    loggers = [(lg, lg.level) for lg in (logging.getLogger("asyncio"), logging.getLogger("distributed"))]
    try:
        for h, _ in handlers:
            h.setLevel(logging.CRITICAL + 1)
        for lg, _ in loggers:
            lg.setLevel(logging.CRITICAL + 1)
        yield
    finally:
        for h, level in handlers:
            h.setLevel(level)
        for lg, level in loggers:
            lg.setLevel(level)


@contextmanager
def open_cluster(scheduler: str | None, workers: int, *, connect_timeout_s: float = CONNECT_TIMEOUT_S,
                 timeout_s: float = WORKER_WAIT_S) -> Iterator[Cluster]:
    """Connect to ``scheduler`` — checked to be a Dask scheduler within ``connect_timeout_s``
    (:func:`controller.calibration.reprocess.scheduler.check_scheduler`) before anything is
    sent — and wait (up to ``timeout_s``) for a worker, or start a local cluster of ``workers``
    single-threaded worker processes on 127.0.0.1; closed on exit."""
    from dask.distributed import Client, LocalCluster

    with quiet_dask():
        if scheduler:
            check_scheduler(scheduler, connect_timeout_s)
            try:
                client = Client(scheduler, timeout=connect_timeout_s, set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise ClusterError(f"--scheduler {scheduler}: answered the check, then no Dask client "
                                   f"could connect ({exc})") from None
            try:
                try:
                    client.wait_for_workers(1, timeout=timeout_s)
                except TimeoutError:
                    raise ClusterError(f"--scheduler {scheduler}: no Dask worker connected within "
                                       f"{timeout_s:g} s") from None
                yield Cluster(client, len(client.scheduler_info()["workers"]), scheduler, False)
            finally:
                client.close()
            return
        import dask

        with dask.config.set(LOCAL_WORKERS), \
                LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                             dashboard_address=None, silence_logs=logging.CRITICAL + 1) as cluster, \
                Client(cluster, set_as_default=False) as client:
            client.wait_for_workers(workers, timeout=timeout_s)
            yield Cluster(client, workers, cluster.scheduler_address, True)


def reprocess(cluster: Cluster, archive: Archive, configs: Configs, scope: list, sink: ReprocessSink, *,
              images_dir: str | None, progress: Callable[[str, int, int], None] = lambda *a: None) -> None:
    """Re-analyse every pair of ``scope`` (measurements) not yet in ``sink``, then refit every
    heliostat not yet refitted. ``progress(phase, done, total)`` after each commit."""
    client = cluster.client
    token = uuid.uuid4().hex[:12]
    planned = plan_pairs(archive, configs, scope, images_dir)
    done = sink.done_pairs()
    todo = [(s, p) for s, p in planned if p.measurement_id not in done]
    old = {m.id: m for m in archive.measurements}
    progress("pairs", len(planned) - len(todo), len(planned))
    n = len(planned) - len(todo)
    for results in _streamed(client, iter(todo), cluster.workers, token):
        sink.record_pairs(results, old)
        n += len(results)
        progress("pairs", n, len(planned))

    specs = refit_specs(archive, configs, sink.pair_results())
    fitted = sink.done_models()
    todo_fits = [s for s in specs if s.heliostat_id not in fitted]
    k = len(specs) - len(todo_fits)
    progress("refits", k, len(specs))
    futures = [client.submit(refit_heliostat, s, key=f"reprocess-refit-{token}-{i}", pure=False)
               for i, s in enumerate(todo_fits)]
    batch: list[RefitResult] = []
    for i, r in enumerate(_completed(client, futures)):
        batch.append(r)
        if len(batch) >= REFIT_BATCH or i == len(futures) - 1:
            sink.record_models(batch, archive.models)
            k += len(batch)
            batch = []
            progress("refits", k, len(specs))


def _streamed(client, todo: Iterator, workers: int, token: str) -> Iterator[list[PairResult]]:
    """The pairs of ``todo`` analysed, a task's results at a time as tasks finish. Tasks are
    sized by a :class:`TaskSizer` from the cost measured so far and submitted as others finish,
    :data:`TASKS_PER_WORKER` per worker in flight: neither the tasks nor their results are held
    for the whole archive. On a failure the tasks in flight are cancelled and the task's
    exception is raised here (what was committed stays)."""
    from dask.distributed import as_completed

    sizer, live, ids = TaskSizer(), set(), itertools.count()
    running = as_completed(loop=client.loop)

    def submit() -> bool:
        task = take_task(todo, sizer.size)
        if not task:
            return False
        fut = client.submit(analyse_timed, task, key=f"reprocess-pairs-{token}-{next(ids)}", pure=False)
        live.add(fut)
        running.add(fut)
        return True

    try:
        for _ in range(TASKS_PER_WORKER * max(1, workers)):
            if not submit():
                break
        for fut in running:
            live.discard(fut)
            results, seconds = outcome(fut.result())  # raises the worker's exception
            fut.release()
            sizer.tell(len(results), seconds)
            submit()
            yield results
    finally:
        client.cancel([f for f in live if not f.done()])


def _completed(client, futures: list) -> Iterator[Any]:
    """Results as tasks finish; on any failure the remaining tasks are cancelled and the task's
    exception is raised here (what was committed stays)."""
    from dask.distributed import as_completed

    try:
        for fut in as_completed(futures, loop=client.loop):
            yield outcome(fut.result())  # raises the worker's exception
            fut.release()
    finally:
        client.cancel([f for f in futures if not f.done()])
