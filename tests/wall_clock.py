"""Wall-clock deadlines on a shared machine: a process's elapsed time less the time it waited for a core.

Linux accounts, per task, the time it ran and the time it was runnable but waited on a run queue for a core
(/proc/PID/schedstat: on-CPU ns, run-queue wait ns, time slices). A deadline on the wall time from a process's start
to an event (its first output line) holds on an idle machine when the elapsed time less that wait is within it: what
remains is the process's own work, sleeps and I/O, none of which other jobs cause, so a command that does too much
(or waits on something) before it talks still fails, while one that only waited for a core on a loaded machine (or
beside another pytest-xdist worker) does not. Only the process's main thread is read: its other threads' waits are
not subtracted, so the figure errs towards the plain wall time. Where /proc/PID/schedstat cannot be read (not Linux,
or the process already reaped) the wait counts as 0, the plain wall time.
"""

from __future__ import annotations

from pathlib import Path


def runqueue_wait_s(pid: int) -> float:
    """Seconds process `pid`'s main thread has waited on a run queue for a core since it started (0 if unknown)."""
    try:
        fields = Path(f"/proc/{pid}/schedstat").read_text(encoding="ascii").split()
        return int(fields[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return 0.0
