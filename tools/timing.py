"""Timing for the benchmarks (tools/bench_*.py, tools/speed_record.py): the clocks, repeats, summaries and the one
JSON line each benchmark ends with.

Clocks. CPU time is `time.process_time()`: user + system time of this process, all its threads (MuJoCo's thread
pool included), in s. Wall time is `time.perf_counter()`. A child process's CPU time is the growth of
`resource.getrusage(RUSAGE_CHILDREN)` across its run (counted once the child has been waited for).

Repeats. On a machine shared with other work, interference only adds time: a process that waits for a core accrues
wall time, and cache and memory-bus contention add CPU time too. The minimum over repeats is therefore the estimate
least disturbed by load (`best_of`, `per_call_us`); where the spread of single calls matters (a filter's p99), the
calls' own times are summarised (`summary_us`). The CPU figure is the one to compare across runs on a loaded
machine; `machine()` records the load beside it so a figure taken under load can be recognised.

Output. Every benchmark ends with one JSON line on stdout (`emit`): the figures of the run, so that a script can read
the last line (`json.loads(stdout.splitlines()[-1])`).

Where it lives. The tools are scripts, not a package: `python tools/NAME.py` puts tools/ first on sys.path, so a
tool imports this module (and its sibling tools) as `from timing import ...`. Several benchmarks measure another
checkout side by side (`--against TREE`: a child process with that tree first on PYTHONPATH); the timing helper must
not come from the tree under measurement, which may predate it, so it is a tool beside them and not in the package.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import statistics
import subprocess
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TypeVar

T = TypeVar("T")

CLOCKS_NS = {"cpu": time.thread_time_ns, "wall": time.perf_counter_ns}  # per-call clocks (ns): this thread's CPU, wall


@dataclass(frozen=True)
class Timing:
    """Wall and CPU time, s (`timed`: one call; `best_of`: each the minimum over repeats)."""

    wall: float
    cpu: float


def timed(call: Callable[[], T]) -> tuple[T, Timing]:
    """call()'s result and its wall and CPU time."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = call()
    return result, Timing(time.perf_counter() - wall, time.process_time() - cpu)


def best_of(repeats: int, call: Callable[[], T]) -> tuple[T, Timing]:
    """call() `repeats` times; its last result and the shortest wall and CPU times (each its own minimum)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    walls, cpus = [], []
    for _ in range(repeats):
        result, timing = timed(call)
        walls.append(timing.wall)
        cpus.append(timing.cpu)
    return result, Timing(min(walls), min(cpus))


def per_call_us(call: Callable[[int], object], count: int, repeats: int = 1) -> float:
    """CPU µs per call of call(i), i = 0 … count − 1: the best of `repeats` passes of `count` calls."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")

    def one_pass() -> None:
        for i in range(count):
            call(i)

    return best_of(repeats, one_pass)[1].cpu / count * 1e6


def clock_ns(clock: str) -> Callable[[], int]:
    """The per-call clock named `clock` ("cpu": this thread's CPU time; "wall"), in ns."""
    if clock not in CLOCKS_NS:
        raise ValueError(f"clock must be one of {', '.join(CLOCKS_NS)}, got {clock!r}")
    return CLOCKS_NS[clock]


def call_us(call: Callable[[], T], clock: str = "wall") -> tuple[T, float]:
    """call()'s result and its time in µs on `clock`."""
    now = clock_ns(clock)
    start = now()
    result = call()
    return result, (now() - start) / 1e3


def calls_us(call: Callable[..., object], args_list: Sequence[tuple], clock: str = "wall") -> list[float]:
    """The time in µs on `clock` of call(*args) for each args of `args_list`, in order (the clock read right
    around each call, nothing else between)."""
    now = clock_ns(clock)
    out = []
    for args in args_list:
        start = now()
        call(*args)
        out.append((now() - start) / 1e3)
    return out


def summary_us(times_us: Sequence[float], keys: Sequence[str] = ("median", "p99"), digits: int = 2) -> dict[str, float]:
    """`{key}_us` for each of `keys` ("median", "p99", "mean", "min", "max") of single-call times in µs, rounded."""
    if not times_us:
        raise ValueError("no times to summarise")
    ordered = sorted(times_us)

    def p99() -> float:  # linear interpolation between order statistics, as numpy.percentile's default
        position = 0.99 * (len(ordered) - 1)
        low = int(position)
        high = min(low + 1, len(ordered) - 1)
        return ordered[low] + (ordered[high] - ordered[low]) * (position - low)

    figures = {"median": lambda: statistics.median(ordered), "p99": p99, "mean": lambda: statistics.fmean(ordered),
               "min": lambda: ordered[0], "max": lambda: ordered[-1]}
    unknown = [key for key in keys if key not in figures]
    if unknown:
        raise ValueError(f"unknown summary {unknown[0]!r}; known: {', '.join(figures)}")
    return {f"{key}_us": round(float(figures[key]()), digits) for key in keys}


def child_timing(command: Sequence[str], cwd: str | None = None, env: dict[str, str] | None = None) -> Timing:
    """Wall and CPU time (user + system) of one run of `command`, its output discarded; it must exit 0."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(list(command), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return Timing(wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))


def machine() -> dict[str, Any]:
    """What a figure was measured on: the architecture, the processor's name, the cores and the 1-minute load."""
    return {"machine": platform.machine(), "processor": processor_name(), "cpus": os.cpu_count(),
            "load_1min": round(os.getloadavg()[0], 2)}


def processor_name() -> str:
    """The processor's model name (Linux: /proc/cpuinfo), else `platform.processor()`."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def emit(report: dict[str, Any]) -> None:
    """Print the benchmark's one JSON line (its last line on stdout)."""
    print(json.dumps(report), flush=True)
