"""Progress of long runs on stderr: a live line on a terminal, otherwise a line per 10 % and a line whenever the
run has been quiet for a while (`quiet_limit_s`), so a log shows the run is alive from its first second.

Every long command reports through `Progress` (scenario runs, studies, falsify, bench, the hardware mode, the
examples): one line format, "[label] |bar| pct  done/total unit  elapsed, eta". The ETA extrapolates linearly
from the fraction done (elapsed × (1 − f) / f): it assumes the remaining units cost what the done ones did on
average, and is shown as soon as any work is done (work may be fractional, e.g. a batch of samples half way
through its simulated time). Numbers a person reads are shown to `SIGNIFICANT` digits (`significant`).

The line starts with its label cut to LABEL_LIMIT characters (`softcbf_mj.outputs.palette.short_label`: a run of the
recommended filter is labelled with all seven of its parameters), so that it fits a 120-column terminal.

No silent start: a run's set-up (building the filter, calibrating the camera, importing the recording's
libraries) may take seconds before its first bar. `heartbeat(line)` prints `line` once after HEARTBEAT_S
unless something has spoken by then (a bar drew, or `mark_spoken()`: numba's compile note), and never
after its context ends: input refused within HEARTBEAT_S stays one line.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Iterator
from typing import TextIO

from softcbf_mj.outputs.palette import short_label

LABEL_LIMIT = 40  # characters of the label at the start of a progress line
HEARTBEAT_S = 0.5  # s of silence after which a starting run says what it is doing
_SPOKEN = threading.Event()
SIGNIFICANT = 4  # significant digits of the figures a progress line shows (a best objective, a force)
QUIET_MIN_S = 1.0  # a non-terminal log gets a line at latest this long after the start …
QUIET_MAX_S = 60.0  # … and then at latest every quarter of the elapsed time, never less often than this, s


def significant(value: float | None, digits: int = SIGNIFICANT) -> str:
    """`value` to `digits` significant digits ("-0.6312", "1.235e+04"); "-" for None."""
    if value is None:
        return "-"
    return f"{value:.{digits}g}"


def duration_text(seconds: float) -> str:
    """A duration as a person reads it: "8.2 s", "3 min 05 s", "2 h 04 min"."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    whole = int(round(seconds))
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


def quiet_limit_s(elapsed: float) -> float:
    """How long a non-terminal log may go without a line after `elapsed` s: a quarter of the elapsed time,
    within [QUIET_MIN_S, QUIET_MAX_S] (lines at about 1, 2, 3, 4, 5, 6.3 … s, then every minute)."""
    return min(QUIET_MAX_S, max(QUIET_MIN_S, 0.25 * elapsed))


def mark_spoken() -> None:
    """Something has told the user what runs (module docstring): a pending `heartbeat` stays quiet."""
    _SPOKEN.set()


@contextlib.contextmanager
def heartbeat(line: str, after_s: float = HEARTBEAT_S, stream: TextIO | None = None) -> Iterator[None]:
    """Within this context, print `line` on `stream` (stderr) once, `after_s` s after entering, unless a progress
    bar drew or `mark_spoken` was called first (module docstring)."""
    _SPOKEN.clear()
    lock = threading.Lock()

    def speak() -> None:
        with lock:
            if not _SPOKEN.is_set():
                _SPOKEN.set()
                print(line, file=stream if stream is not None else sys.stderr, flush=True)

    timer = threading.Timer(after_s, speak)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        with lock:  # a speak() under way finishes first; none starts after
            _SPOKEN.set()


class Progress:
    """Report `done` out of `total` units of work under a label; `close()` prints the final line.

    With `unit_s` (simulated seconds per unit, e.g. the control period) the line also shows
    the simulated time done / total (s) and the real-time factor (simulated s per wall s), and the
    bar draws its 0 % line when it is made: a run's first line, before its first step, which may
    wait a second or more for the recording's imports and numba's kernels.
    With `unit` (e.g. "samples", "cases") it shows the units done / total ("12/150 samples").
    `done` may be fractional (work part done); the count shown is its whole part.
    """

    def __init__(self, label: str, total: int, stream: TextIO | None = None, enabled: bool = True,
                 unit_s: float | None = None, unit: str | None = None) -> None:
        if total < 1:
            raise ValueError(f"total must be >= 1, got {total}")
        if unit_s is not None and not unit_s > 0:
            raise ValueError(f"unit_s must be > 0 s (or None), got {unit_s}")
        self.label, self.total, self.unit_s, self.unit = short_label(label, LABEL_LIMIT), total, unit_s, unit
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.live = enabled and self.stream.isatty()
        self.start = time.perf_counter()
        self._last_decile = -1
        self._last_draw = 0.0
        self._last_line = self.start
        self._note = ""
        self._done = 0.0
        self._printed: tuple[float, str] | None = None  # (done, note) of the last line a log got
        self._lock = threading.Lock()  # `ticking`'s thread and the caller's both update
        if unit_s is not None:
            self.update(0)

    def update(self, done: float, note: str = "") -> None:
        """Report `done` units; `note` (e.g. '2 failed') is appended to the line."""
        if not self.enabled:
            return
        with self._lock:
            self._update(done, note)

    def _update(self, done: float, note: str) -> None:
        self._note = note
        self._done = done
        now = time.perf_counter()
        frac = min(done / self.total, 1.0)
        if self.live:
            if now - self._last_draw < 0.2 and done < self.total:
                return
            self._last_draw = now
            _SPOKEN.set()
            self.stream.write("\r" + self._line(frac, now))
        else:
            decile = int(frac * 10)
            quiet = now - self._last_line >= quiet_limit_s(now - self.start)
            if decile == self._last_decile and not quiet:
                return
            self._last_decile = decile
            self._last_line = now
            self._printed = (done, note)
            _SPOKEN.set()
            self.stream.write(self._line(frac, now) + "\n")
        self.stream.flush()

    def _line(self, frac: float, now: float) -> str:
        elapsed = now - self.start
        eta = duration_text(elapsed * (1 - frac) / frac) if frac > 0 else "-"
        bar = "#" * int(frac * 20)
        note = f", {self._note}" if self._note else ""
        sim = ""
        if self.unit_s is not None:
            sim_s, total_s = frac * self.total * self.unit_s, self.total * self.unit_s
            rtf = f"{sim_s / elapsed:5.1f}x real time" if elapsed > 0 else "  -  x real time"
            sim = f"  sim {sim_s:.1f}/{total_s:g} s, {rtf},"
        count = f"  {int(min(self._done, self.total))}/{self.total} {self.unit}" if self.unit else ""
        return (f"[{self.label}] |{bar:<20}| {100 * frac:5.1f}%{count}{sim}  {duration_text(elapsed)} elapsed, "
                f"eta {eta}{note}")

    def eta_s(self) -> float | None:
        """The time left (s) at the last `done` (module docstring), None before any work is done."""
        frac = min(self._done / self.total, 1.0)
        return (time.perf_counter() - self.start) * (1 - frac) / frac if frac > 0 else None

    def tick(self, note: str | None = None) -> None:
        """Report the last `done` again (a line on a log that has been quiet for long; a fresh elapsed time);
        `note` replaces the note when given."""
        self.update(self._done, self._note if note is None else note)

    @contextlib.contextmanager
    def ticking(self, every_s: float = QUIET_MIN_S) -> Iterator["Progress"]:
        """Within the block a daemon thread calls `tick()` every `every_s` s, so a unit of work that takes
        minutes (a bench case) still refreshes the line (and a log gets its `quiet_limit_s` lines)."""
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(every_s):
                self.tick()

        thread = threading.Thread(target=beat, name=f"progress {self.label}", daemon=True)
        thread.start()
        try:
            yield self
        finally:
            stop.set()
            thread.join()

    def close(self, done: float | None = None) -> None:
        """Print the final line: at `total` units, or at `done` for work that stopped early (e.g. a search
        that stopped on its first violation). A log gets it unless its last line said the same."""
        done = self.total if done is None else done
        if not self.live and self._printed != (done, self._note):
            self._last_decile = -1
        self.update(done, self._note)
        if self.live:
            self.stream.write("\n")
            self.stream.flush()
