"""Progress of long runs on stderr: a live line on a terminal, a line per 10 % otherwise.

The line starts with its label cut to LABEL_LIMIT characters (`softcbf_mj.palette.short_label`: a run of the
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

from softcbf_mj.palette import short_label

LABEL_LIMIT = 40  # characters of the label at the start of a progress line
HEARTBEAT_S = 0.5  # s of silence after which a starting run says what it is doing
_SPOKEN = threading.Event()


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
    """

    def __init__(self, label: str, total: int, stream: TextIO | None = None, enabled: bool = True,
                 unit_s: float | None = None) -> None:
        if total < 1:
            raise ValueError(f"total must be >= 1, got {total}")
        if unit_s is not None and not unit_s > 0:
            raise ValueError(f"unit_s must be > 0 s (or None), got {unit_s}")
        self.label, self.total, self.unit_s = short_label(label, LABEL_LIMIT), total, unit_s
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.live = enabled and self.stream.isatty()
        self.start = time.perf_counter()
        self._last_decile = -1
        self._last_draw = 0.0
        self._note = ""
        if unit_s is not None:
            self.update(0)

    def update(self, done: int, note: str = "") -> None:
        """Report `done` units; `note` (e.g. '2 failed') is appended to the line."""
        if not self.enabled:
            return
        self._note = note
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
            if decile == self._last_decile:
                return
            self._last_decile = decile
            _SPOKEN.set()
            self.stream.write(self._line(frac, now) + "\n")
        self.stream.flush()

    def _line(self, frac: float, now: float) -> str:
        elapsed = now - self.start
        eta = f"{elapsed * (1 - frac) / frac:5.1f} s" if frac > 0 else "    - s"
        bar = "#" * int(frac * 20)
        note = f", {self._note}" if self._note else ""
        sim = ""
        if self.unit_s is not None:
            sim_s, total_s = frac * self.total * self.unit_s, self.total * self.unit_s
            rtf = f"{sim_s / elapsed:5.1f}x real time" if elapsed > 0 else "  -  x real time"
            sim = f"  sim {sim_s:.1f}/{total_s:g} s, {rtf},"
        return f"[{self.label}] |{bar:<20}| {100 * frac:5.1f}%{sim}  {elapsed:6.1f} s elapsed, eta {eta}{note}"

    def close(self) -> None:
        self.update(self.total, self._note)
        if self.live:
            self.stream.write("\n")
            self.stream.flush()
