"""Run a study's samples on a local process pool or a Dask cluster; stream rows to the study folder.

Backends, both driven through the `concurrent.futures` executor interface:

- local (default): `concurrent.futures.ProcessPoolExecutor` with `workers` processes
  (default: every core, `os.cpu_count()`), started with "spawn" so no parent state
  (MuJoCo, threads) leaks into a worker;
- Dask: `distributed.Client(scheduler)` for a cluster address such as
  "tcp://host:8786", or a `Client` passed in (e.g. on a `LocalCluster`), through Dask's
  `client.get_executor(pure=False)`. Every worker needs this package and the same
  versions installed (the rows record the versions only once, in study.json). The
  address is tried first, within `SCHEDULER_CONNECT_TIMEOUT_S`, before the study folder
  is made: a malformed or unreachable address is a ValueError naming it and the reason
  (`connect_scheduler`; Dask's own default waits 30 s).

Batches (docs/studies.md#batches). With `batch_size` B > 1 (default `DEFAULT_BATCH_SIZE`
when the scenario has a batch form, else 1) the driver groups the streamed samples by
their batch key (`runner.batch_key`: what one batched closed loop must share, e.g. the
tuning, duration and physics step; the drawn plant parameters, q0 and nominal may
differ) and submits each group of B as one task (`runner.run_batch`, MuJoCo on
`cores // workers` threads locally, 1 on Dask); a group is submitted when it holds B
samples, when the driver holds `BATCH_BUFFER` × B unsubmitted samples (the largest
group goes), or at the end of the stream. A sample whose key is None runs alone
(`runner.run_sample`), as does every sample with B = 1. A task is a unit of work and of
failure: its rows are stored when it finishes, a task cut short (a killed driver or
worker) stores nothing and its samples run again, whole, on resume or retry.

The driver keeps a window of submitted tasks (local: one per worker; Dask: two per
worker thread), writes each finished sample's row itself, once (`StudyStore.write`,
named by the sample index: a task that Dask reruns after a worker death cannot add a
second row), and updates the progress line (samples done, failed, faulted, ETA) on stderr.

Progress per sample, not per task. A batch of B samples finishes all at once, after B
samples' worth of simulated time (minutes), so counting finished tasks alone would leave
the line at 0 for that long. A local batch reports the fraction of its simulated time done
(`softcbf_mj.loops.batch_loop.run_batch_closed_loop`'s callback) through a queue of a
`multiprocessing` manager (`start_manager`: it ignores Ctrl-C, which the driver handles, and
exits with its driver as the workers do; started only when the progress is shown or reported) to the driver, at most every `BATCH_REPORT_S`; the driver counts
a batch at fraction f as f·B samples done (the samples of a batch advance together), polls
every `POLL_S` and prints the first line (0 done) before any worker starts. A Dask task, or
a sample run alone, counts when it finishes. `report`, if given, is called with the same
count (e.g. falsify's line over many `run_study` calls).

Failures: an exception inside the scenario is a row with status "error" (`runner`); a run that
ended on a filter fault is a row with status "fault", counted apart (`StudyOutcome.faulted`). A
Dask task whose worker dies is rescheduled by Dask; after Dask gives up
(`distributed.scheduler.allowed-failures`) the sample is a row with the error. A local
worker that dies breaks the whole process pool: the driver starts a new pool and
resubmits the tasks that were in flight; a sample in flight at `MAX_ATTEMPTS` pool
breaks is recorded as an error with the rest of its task (it is the likely culprit,
though an innocent sample or batch sharing both breaks would be recorded too).
A Dask task that comes back cancelled (`CancelledError`: the client lost its scheduler, which
cancels every task in flight, or the scheduler dropped it) has no result, neither the
sample's nor an error of its own: nothing is stored for it, and the run stops with
`SchedulerLostError` (one line: how many samples were lost, continue with --resume) once the
tasks that finished are stored, so a resume runs the lost samples instead of keeping them as
failed. A client that closes under the driver (its scheduler did not come back) is the same.

Resume: samples with a sound part in the folder are skipped, so an interrupted study
(Ctrl-C, a killed driver, a lost cluster) continues with `resume=True`; nothing is lost
beyond the samples then running, and nothing is stored twice. A part that fails its
check (`StudyStore.scan`: unreadable, or its row digest does not match) is run again.

Memory: the sample indices are streamed (`range` filtered by the stored parts), so the
driver holds the stored indices, the window, the retries and at most `BATCH_BUFFER` × B
samples waiting for their batch, never a list of the study's size: `draws = 10**12`
starts its first task at once.

Orphans: a local worker (and the batches' progress manager) exits within `PARENT_POLL_S` when its driver dies, even by
SIGKILL (which runs no clean-up): a daemon thread in every worker compares
`os.getppid()` with the driver's pid and calls `os._exit` once they differ (the worker
was reparented). Dask workers belong to their cluster and are not affected.
"""

from __future__ import annotations

import collections
import multiprocessing
import os
import queue
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, CancelledError, Executor, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.managers import SyncManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Hashable, Iterator

from scenarios import get as get_scenario
from softcbf_mj.outputs.progress import Progress
from softcbf.study.definition import Study
from softcbf.study.runner import batch_key, failed_row, run_batch, run_sample
from softcbf.study.store import StudyStore, faulted

MAX_ATTEMPTS = 2  # local pool breaks a sample may be in flight for before it is recorded as failed
PARENT_POLL_S = 0.5  # how often a local worker checks that its driver is alive, s
ORPHAN_EXIT_CODE = 70  # a local worker's exit status when its driver died
DEFAULT_BATCH_SIZE = 128  # samples per batch where the scenario has a batch form (tools/bench_batch.py)
BATCH_BUFFER = 8  # batches' worth of samples the driver may hold while their groups fill
SCHEDULER_CONNECT_TIMEOUT_S = 5.0  # how long a Dask scheduler address is tried before the study is refused, s
POOL_EXIT_S = 5.0  # how long a local pool's workers have to exit at its shutdown before they are terminated, s
POLL_S = 0.25  # how often the driver reads the batches' progress and refreshes the line, s
BATCH_REPORT_S = 0.5  # how often a local batch sends the fraction of its simulated time done, s


class SchedulerLostError(ConnectionError):
    """The Dask scheduler lost the tasks in flight (module docstring: failures); the finished samples are stored."""


def scheduler_lost(client: Any, samples: int) -> SchedulerLostError:
    """The one-line error of a run whose Dask client lost `samples` samples in flight (module docstring)."""
    address = getattr(getattr(client, "scheduler", None), "address", None) or "of the client"
    return SchedulerLostError(f"the Dask scheduler {address} lost {samples} sample(s) in flight (its connection closed "
                              "or it cancelled them); the finished samples are stored: start the scheduler again "
                              "and continue with --resume, which runs the lost ones")


def connect_scheduler(address: str, timeout: float | None = None) -> Any:
    """A `distributed.Client` on the scheduler at `address`; ValueError "cannot connect to the Dask scheduler
    ADDRESS: REASON" when the address is malformed or nothing answers there within `timeout` s (default
    `SCHEDULER_CONNECT_TIMEOUT_S`). The address is
    tried with one bare connection first: a Client that fails to start blocks for twice its timeout when it is
    collected and prints a traceback, so no Client is made for an address that does not answer."""
    # distributed (Dask, the optional `cluster` dependency): +2.5 s to import, asyncio +0.11 s: with --scheduler only
    import asyncio

    from distributed import Client
    from distributed.comm import connect

    async def probe() -> None:
        comm = await connect(address, timeout=timeout)
        await comm.close()

    timeout = SCHEDULER_CONNECT_TIMEOUT_S if timeout is None else timeout
    hint = "start one there (dask scheduler) or give its address, e.g. tcp://host:8786"
    try:
        asyncio.run(probe())
        return Client(address, timeout=timeout)
    except (OSError, ValueError, TypeError) as exc:  # Dask: OSError (timed out, refused), ValueError (bad address)
        raise ValueError(f"cannot connect to the Dask scheduler {address!r}: {exc}; {hint}") from None


@dataclass(frozen=True)
class Task:
    """Samples submitted as one unit: `indices` run in one batch (`batched`) or, alone, one sample."""

    indices: tuple[int, ...]
    batched: bool


@dataclass(frozen=True)
class StudyOutcome:
    """What one `run_study` call did: samples of the study, already stored, run now, failed now (outside the
    filter), wall time (s), how many stored parts were corrupted (and so run again), and how many of the samples
    run now ended on a filter fault (`store.faulted`; not in `failed`)."""

    n_samples: int
    skipped: int
    ran: int
    failed: int
    wall_s: float
    backend: str
    workers: int
    corrupted: int = 0
    faulted: int = 0


def exit_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """In a worker process: start a daemon thread that ends this process (`os._exit`) once its
    parent is no longer `parent_pid` (the parent died and the worker was reparented)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(ORPHAN_EXIT_CODE)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def start_manager(parent_pid: int) -> None:
    """In the batches' progress manager process: Ctrl-C is the driver's to handle (the manager stays until the
    driver shuts it down), and the manager ends with its driver as a worker does (`exit_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent_pid)


def _local_pool(workers: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=exit_with_parent, initargs=(os.getpid(),))


def close_local_pool(executor: ProcessPoolExecutor, timeout_s: float = POOL_EXIT_S) -> None:
    """Shut a local pool down without waiting forever on a worker that cannot exit, then end its workers.

    A worker killed (SIGKILL, the OOM killer) while it holds the pool's call-queue lock leaves every other worker
    blocked on that lock, so `shutdown(wait=True)` joins them forever (seen with CPython 3.11 in
    tests/test_study_dask.py: the study's rows all stored, the driver in `shutdown`, the surviving worker in
    `Queue.get`). The pool is shut down without waiting; each worker then has until `timeout_s` to exit and is
    terminated if it has not. The worker processes are read from the executor's `_processes` (CPython's
    ProcessPoolExecutor has no public accessor)."""
    processes = list((getattr(executor, "_processes", None) or {}).values())
    executor.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + timeout_s
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.terminate()
            process.join()


def pending_indices(limit: int, done: set[int]) -> Iterator[int]:
    """The indices 0 … limit−1 not in `done`, in order, one at a time (nothing of size `limit` is built)."""
    return (i for i in range(limit) if i not in done)


def group_tasks(indices: Iterator[int], key: Callable[[int], Hashable | None], batch_size: int,
                buffer: int) -> Iterator[Task]:
    """Tasks of the streamed `indices`: samples with equal non-None `key` in batches of up to
    `batch_size`, the others alone; at most `buffer` samples are held (then the largest group goes)."""
    groups: dict[Hashable, list[int]] = {}
    held = 0
    for index in indices:
        group_key = key(index) if batch_size > 1 else None
        if group_key is None:
            yield Task((index,), False)
            continue
        group = groups.setdefault(group_key, [])
        group.append(index)
        held += 1
        if len(group) == batch_size or held >= buffer:
            largest = group_key if len(group) == batch_size else max(groups, key=lambda k: len(groups[k]))
            held -= len(groups[largest])
            yield Task(tuple(groups.pop(largest)), True)
    for group in groups.values():
        yield Task(tuple(group), True)


class BatchReporter:
    """In a worker: sends (the task's first index, fraction of its simulated time done) to the driver's
    `channel`, at most every `BATCH_REPORT_S` (module docstring)."""

    def __init__(self, channel: Any, first: int) -> None:
        self.channel, self.first, self.last = channel, first, 0.0

    def __call__(self, fraction: float) -> None:
        now = time.monotonic()
        if self.channel is not None and now - self.last >= BATCH_REPORT_S:
            self.last = now
            try:
                self.channel.put((self.first, fraction))
            except (OSError, EOFError):  # the driver's manager is gone (it is ending): the batch goes on, unreported
                self.channel = None


def run_task(study: Study, task: Task, keep_dir: str | None, nthread: int,
             channel: Any = None) -> list[dict[str, Any]]:
    """In a worker: the rows of `task` (`run_batch`, or `run_sample` for a sample alone); a batch reports its
    progress to `channel` (a queue, or None: no reports)."""
    if task.batched:
        reporter = BatchReporter(channel, task.indices[0]) if channel is not None else None
        return run_batch(study, list(task.indices), nthread, reporter)
    return [run_sample(study, task.indices[0], keep_dir)]


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
    batch_size: int | None = None,
    report: Callable[[float], None] | None = None,
) -> StudyOutcome:
    """Run the study's samples 0 … `samples`−1 (default: all) that the folder does not hold yet.

    `workers`: local processes (default: all cores); ignored with Dask. `scheduler`: a
    Dask scheduler address; `client`: a `distributed.Client` to use (not closed here).
    `keep_runs` keeps each scenario's own outputs under DIR/runs/ (and runs every sample
    alone). `batch_size`: samples per batch (module docstring; 1: every sample alone).
    `report`: called with the samples done by this call so far (fractional, module docstring).
    """
    if scheduler is not None and client is not None:
        raise ValueError("give a Dask scheduler address or a client, not both")
    if workers is not None and (workers < 1 or scheduler is not None or client is not None):
        raise ValueError(f"workers must be >= 1 and is for the local pool only, got workers={workers} "
                         f"with scheduler={scheduler!r}")
    if batch_size is None:
        batch_size = DEFAULT_BATCH_SIZE if get_scenario(study.scenario).batch is not None else 1
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1 (1: every sample alone), got {batch_size}")
    if keep_runs:
        batch_size = 1  # a batch writes no per-sample outputs
    limit = study.n_samples if samples is None else samples
    if not 1 <= limit <= study.n_samples:
        raise ValueError(f"samples must lie in [1, {study.n_samples}] (the study's draws × tunings), got {samples}")
    own_client = connect_scheduler(scheduler) if scheduler is not None else None  # before the folder is made
    if own_client is not None:
        client = own_client
    manager = None  # a local run's channel for the batches' progress
    try:  # the client made here is closed on every way out
        store = StudyStore.create(out_dir, study, resume=resume)
        done, corrupted = store.scan()
        fresh = group_tasks(pending_indices(limit, done), lambda i: batch_key(study, i), batch_size,
                            BATCH_BUFFER * batch_size)
        retry: collections.deque[Task] = collections.deque()  # tasks of a broken pool, run before fresh ones
        skipped = sum(1 for i in done if i < limit)
        n_todo = limit - skipped
        bar = Progress(f"study {study.name}", max(n_todo, 1), enabled=progress and n_todo > 0, unit="samples")
        where = "on Dask" if client is not None else f"{workers or os.cpu_count() or 1} local worker(s)"
        bar.update(0, f"starting {where}")
        if client is not None:
            backend = "dask"
            n_workers = max(1, sum(client.nthreads().values()))
            window = 2 * n_workers
            nthread = 1
            executor: Executor = client.get_executor(pure=False)
        else:
            backend = "local"
            n_workers = workers or os.cpu_count() or 1
            window = n_workers
            nthread = max(1, (os.cpu_count() or 1) // n_workers)
            if batch_size > 1 and n_todo > 0 and (progress or report is not None):  # batches report (docstring)
                manager = SyncManager(ctx=multiprocessing.get_context("spawn"))
                manager.start(start_manager, (os.getpid(),))
            executor = _local_pool(n_workers)
    except BaseException:
        if manager is not None:
            manager.shutdown()
        if own_client is not None:
            own_client.close()
        raise

    start = time.perf_counter()
    ran = failed = faults = 0
    pending: dict[Future, Task] = {}
    attempts: collections.Counter[int] = collections.Counter()
    channel = manager.Queue() if manager is not None else None
    partial: dict[int, float] = {}  # a running batch's first index → its samples' worth done (module docstring)
    sizes: dict[int, int] = {}  # a running batch's first index → its size

    def show() -> None:
        """Read the batches' reports, then update the progress line (and `report`) with the samples done."""
        while channel is not None:
            try:
                first, fraction = channel.get_nowait()
            except (queue.Empty, OSError, EOFError):  # nothing more, or the manager is gone (its close)
                break
            if first in sizes:
                partial[first] = fraction * sizes[first]
        done_now = ran + sum(partial.values())
        bar.update(done_now, f"{failed} failed, {faults} faulted")
        if report is not None:
            report(done_now)

    def record(task: Task, rows: list[dict[str, Any]]) -> None:
        """Store a task's rows, then update the progress line once (per row, a batch's first row
        would extrapolate the ETA from one sample of a task that finished many)."""
        nonlocal ran, failed, faults
        partial.pop(task.indices[0], None)
        sizes.pop(task.indices[0], None)
        for row in rows:
            store.write(row)
            ran += 1
            faults += faulted(row)
            failed += row["status"] != "ok" and not faulted(row)
        show()

    try:
        while True:
            while len(pending) < window:
                task = retry.popleft() if retry else next(fresh, None)
                if task is None:
                    break
                keep = str(store.run_dir(task.indices[0])) if keep_runs else None
                if task.batched:
                    sizes[task.indices[0]] = len(task.indices)
                try:
                    pending[executor.submit(run_task, study, task, keep, nthread, channel)] = task
                except Exception:
                    if client is not None and client.status in ("closing", "closed"):  # the scheduler is gone
                        in_flight = sum(len(t.indices) for t in (task, *pending.values()))
                        raise scheduler_lost(client, in_flight) from None
                    raise
            if not pending:
                break
            finished, _ = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            if not finished:
                show()
                continue
            broken: list[Task] = []
            lost: list[Task] = []
            for future in finished:
                task = pending.pop(future)
                try:
                    rows = future.result()
                except BrokenProcessPool:
                    broken.append(task)
                    continue
                except CancelledError:  # Dask lost it: no result, run again on resume (module docstring)
                    lost.append(task)
                    continue
                except Exception as exc:  # noqa: BLE001 - e.g. Dask's KilledWorker: the task failed, the study goes on
                    rows = [failed_row(study, index, f"{type(exc).__name__}: {exc}") for index in task.indices]
                record(task, rows)
            if lost:
                raise scheduler_lost(client, sum(len(t.indices) for t in (*lost, *pending.values())))
            if broken:
                broken += list(pending.values())  # the whole pool is gone
                pending.clear()
                close_local_pool(executor)
                executor = _local_pool(n_workers)
                for task in sorted(broken, key=lambda t: t.indices[0], reverse=True):
                    partial.pop(task.indices[0], None)
                    for index in task.indices:
                        attempts[index] += 1
                    tries = max(attempts[index] for index in task.indices)
                    if tries >= MAX_ATTEMPTS:
                        record(task, [failed_row(study, index, f"the worker process died {tries} times while "
                                                               "running this sample or its batch (crash or kill "
                                                               "outside Python)") for index in task.indices])
                    else:
                        retry.appendleft(task)
        if isinstance(executor, ProcessPoolExecutor):
            close_local_pool(executor)
        else:
            executor.shutdown(wait=True)  # before its client closes (a Dask executor needs the client's loop)
    except BaseException:
        if client is None or client.status not in ("closing", "closed"):  # a closed client cannot cancel
            for future in pending:
                future.cancel()
            executor.shutdown(wait=False)
        raise
    finally:
        if manager is not None:
            manager.shutdown()
        if own_client is not None:
            own_client.close()
    bar.close()
    return StudyOutcome(study.n_samples, skipped, ran, failed, time.perf_counter() - start, backend, n_workers,
                        len(corrupted), faults)
