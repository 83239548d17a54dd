"""Progress of long runs on stderr: a live line on a terminal, a line per 10 % otherwise.

The line starts with its label cut to LABEL_LIMIT characters (`softcbf_mj.palette.short_label`: a run of the
recommended filter is labelled with all seven of its parameters), so that it fits a 120-column terminal.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from softcbf_mj.palette import short_label

LABEL_LIMIT = 40  # characters of the label at the start of a progress line


class Progress:
    """Report `done` out of `total` units of work under a label; `close()` prints the final line.

    With `unit_s` (simulated seconds per unit, e.g. the control period) the line also shows
    the simulated time done / total (s) and the real-time factor (simulated s per wall s).
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
            self.stream.write("\r" + self._line(frac, now))
        else:
            decile = int(frac * 10)
            if decile == self._last_decile:
                return
            self._last_decile = decile
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
