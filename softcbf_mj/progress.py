"""Progress of long runs on stderr: a live line on a terminal, a line per 10 % otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Report `done` out of `total` units of work under a label; `close()` prints the final line."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None, enabled: bool = True) -> None:
        if total < 1:
            raise ValueError(f"total must be >= 1, got {total}")
        self.label, self.total = label, total
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.live = enabled and self.stream.isatty()
        self.start = time.perf_counter()
        self._last_decile = -1
        self._last_draw = 0.0

    def update(self, done: int) -> None:
        if not self.enabled:
            return
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
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        bar = "#" * int(frac * 20)
        return f"[{self.label}] |{bar:<20}| {100 * frac:5.1f}%  {elapsed:6.1f} s elapsed, eta {eta:5.1f} s"

    def close(self) -> None:
        self.update(self.total)
        if self.live:
            self.stream.write("\n")
            self.stream.flush()
