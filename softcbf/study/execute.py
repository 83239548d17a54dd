"""Run a study's samples on a local process pool or a Dask cluster; stream rows to the study folder.

Backends, both driven through the `concurrent.futures` executor interface:

- local (default): `concurrent.futures.ProcessPoolExecutor` with `workers` processes
  (default: every core, `os.cpu_count()`), started with "spawn" so no parent state
  (MuJoCo, threads) leaks into a worker;
- Dask: `distributed.Client(scheduler)` for a cluster address such as
  "tcp://host:8786", or a `Client` passed in (e.g. on a `LocalCluster`), through Dask's
  `client.get_executor(pure=False)`. Every worker needs this package and the same
  versions installed (the rows record the versions only once, in study.json).

The driver keeps a window of submitted samples (local: one per worker; Dask: two per
worker thread), writes each finished sample's row itself, once (`StudyStore.write`,
named by the sample index: a task that Dask reruns after a worker death cannot add a
second row), and updates the progress line (samples done, failed, ETA) on stderr.

Failures: an exception inside the scenario is a row with status "error" (`runner`). A
Dask task whose worker dies is rescheduled by Dask; after Dask gives up
(`distributed.scheduler.allowed-failures`) the sample is a row with the error. A local
worker that dies breaks the whole process pool: the driver starts a new pool and
resubmits the samples that were in flight; a sample in flight at `MAX_ATTEMPTS` pool
breaks is recorded as an error (it is the likely culprit, though an innocent sample
sharing both breaks would be recorded too).

Resume: samples with a sound part in the folder are skipped, so an interrupted study
(Ctrl-C, a killed driver, a lost cluster) continues with `resume=True`; nothing is lost
beyond the samples then running, and nothing is stored twice. A part that fails its
check (`StudyStore.scan`: unreadable, or its row digest does not match) is run again.

Memory: the sample indices are streamed (`range` filtered by the stored parts), so the
driver holds the stored indices, the window and the retries, never a list of the
study's size: `draws = 10**12` starts its first sample at once.

Orphans: a local worker exits within `PARENT_POLL_S` when its driver dies, even by
SIGKILL (which runs no clean-up): a daemon thread in every worker compares
`os.getppid()` with the driver's pid and calls `os._exit` once they differ (the worker
was reparented). Dask workers belong to their cluster and are not affected.
"""

from __future__ import annotations

import collections
import multiprocessing
import os
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from softcbf_mj.progress import Progress
from softcbf.study.definition import Study
from softcbf.study.runner import failed_row, run_sample
from softcbf.study.store import StudyStore

MAX_ATTEMPTS = 2  # local pool breaks a sample may be in flight for before it is recorded as failed
PARENT_POLL_S = 0.5  # how often a local worker checks that its driver is alive, s
ORPHAN_EXIT_CODE = 70  # a local worker's exit status when its driver died


@dataclass(frozen=True)
class StudyOutcome:
    """What one `run_study` call did: samples of the study, already stored, run now, failed now, wall time (s),
    and how many stored parts were corrupted (and so run again)."""

    n_samples: int
    skipped: int
    ran: int
    failed: int
    wall_s: float
    backend: str
    workers: int
    corrupted: int = 0


def exit_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """In a worker process: start a daemon thread that ends this process (`os._exit`) once its
    parent is no longer `parent_pid` (the parent died and the worker was reparented)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(ORPHAN_EXIT_CODE)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _local_pool(workers: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=exit_with_parent, initargs=(os.getpid(),))


def pending_indices(limit: int, done: set[int]) -> Iterator[int]:
    """The indices 0 … limit−1 not in `done`, in order, one at a time (nothing of size `limit` is built)."""
    return (i for i in range(limit) if i not in done)


def run_study(
    study: Study,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    resume: bool = False,
    samples: int | None = None,
    keep_runs: bool = False,
    progress: bool = True,
) -> StudyOutcome:
    """Run the study's samples 0 … `samples`−1 (default: all) that the folder does not hold yet.

    `workers`: local processes (default: all cores); ignored with Dask. `scheduler`: a
    Dask scheduler address; `client`: a `distributed.Client` to use (not closed here).
    `keep_runs` keeps each scenario's own outputs under DIR/runs/.
    """
    if scheduler is not None and client is not None:
        raise ValueError("give a Dask scheduler address or a client, not both")
    if workers is not None and (workers < 1 or scheduler is not None or client is not None):
        raise ValueError(f"workers must be >= 1 and is for the local pool only, got workers={workers} "
                         f"with scheduler={scheduler!r}")
    limit = study.n_samples if samples is None else samples
    if not 1 <= limit <= study.n_samples:
        raise ValueError(f"samples must lie in [1, {study.n_samples}] (the study's draws × tunings), got {samples}")
    store = StudyStore.create(out_dir, study, resume=resume)
    done, corrupted = store.scan()
    fresh = pending_indices(limit, done)
    retry: collections.deque[int] = collections.deque()  # samples of a broken pool, run before fresh ones
    skipped = sum(1 for i in done if i < limit)
    n_todo = limit - skipped

    own_client = None
    if scheduler is not None:
        from distributed import Client

        client = own_client = Client(scheduler)
    if client is not None:
        backend = "dask"
        n_workers = max(1, sum(client.nthreads().values()))
        window = 2 * n_workers
        executor: Executor = client.get_executor(pure=False)
    else:
        backend = "local"
        n_workers = workers or os.cpu_count() or 1
        window = n_workers
        executor = _local_pool(n_workers)

    start = time.perf_counter()
    ran = failed = 0
    bar = Progress(f"study {study.name}", max(n_todo, 1), enabled=progress and n_todo > 0)
    pending: dict[Future, int] = {}
    attempts: collections.Counter[int] = collections.Counter()

    def record(row: dict[str, Any]) -> None:
        nonlocal ran, failed
        store.write(row)
        ran += 1
        failed += row["status"] != "ok"
        bar.update(ran, f"{ran}/{n_todo} done, {failed} failed")

    try:
        while True:
            while len(pending) < window:
                index = retry.popleft() if retry else next(fresh, None)
                if index is None:
                    break
                keep = str(store.run_dir(index)) if keep_runs else None
                pending[executor.submit(run_sample, study, index, keep)] = index
            if not pending:
                break
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            broken: list[int] = []
            for future in finished:
                index = pending.pop(future)
                try:
                    row = future.result()
                except BrokenProcessPool:
                    broken.append(index)
                    continue
                except Exception as exc:  # noqa: BLE001 - e.g. Dask's KilledWorker: the sample failed, the study goes on
                    row = failed_row(study, index, f"{type(exc).__name__}: {exc}")
                record(row)
            if broken:
                broken += list(pending.values())  # the whole pool is gone
                pending.clear()
                executor.shutdown(wait=True, cancel_futures=True)
                executor = _local_pool(n_workers)
                for index in sorted(broken, reverse=True):
                    attempts[index] += 1
                    if attempts[index] >= MAX_ATTEMPTS:
                        record(failed_row(study, index, f"the worker process died {attempts[index]} times while "
                                                        "running this sample (crash or kill outside Python)"))
                    else:
                        retry.appendleft(index)
    except BaseException:
        for future in pending:
            future.cancel()
        executor.shutdown(wait=False)
        raise
    finally:
        if own_client is not None:
            own_client.close()
    executor.shutdown(wait=True)
    bar.close()
    return StudyOutcome(study.n_samples, skipped, ran, failed, time.perf_counter() - start, backend, n_workers,
                        len(corrupted))
