"""Say when numba compiles, so that a first run is never a silent minute.

The testbed's numba kernels are `@njit(cache=True)`: the first process that calls one compiles it and
writes it to numba's cache (`__pycache__` beside the source, or NUMBA_CACHE_DIR); later processes load
it in well under a second. On a fresh clone the first run compiles for up to COLD_COMPILE_S (about
40 s for a mujoco_contact run of the energy governors on the 2-core reference machine, about 15 s
for the paper's CBF, and a minute for paper_sim's PCC integrator under load).

Which kernels a command compiles depends on its filter, plant and loop, and whether a kernel is cached
depends on its signature and its source's stamp, which numba alone decides: so the note is not predicted
from the files but taken from numba itself. `compile_notes(stream)` listens to numba's "numba:compile"
event (numba.core.event), which numba raises only after a cache miss, just before it compiles; the first
one prints COMPILE_NOTE on `stream`, and leaving the context says how many kernels compiled and how long
they took (outermost compiles: a kernel's inlined callees count with it); the note counts as the run having
spoken (`softcbf_mj.outputs.progress.mark_spoken`). `scenarios.run` (behind `softcbf run` and `python -m scenarios`)
and `softcbf demo` run within it: nothing is printed when every kernel loads from the cache.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from typing import TextIO

from softcbf_mj.outputs.progress import mark_spoken

COLD_COMPILE_S = 40  # s, the first mujoco_contact run with c-erg on a fresh clone (2 cores)
COMPILE_NOTE = (f"compiling numba kernels, once: up to ~{COLD_COMPILE_S} s "
                "(first use on this machine; later runs load them from numba's cache)")


@contextlib.contextmanager
def compile_notes(stream: TextIO | None = None) -> Iterator[None]:
    """Within this context, numba's first compile prints COMPILE_NOTE on `stream` (stderr) before it starts and a
    line with its duration when it ends (module docstring)."""
    from numba.core import event  # numba: 0.84 s (-X importtime), after the command's first line

    out = stream if stream is not None else sys.stderr

    class Note(event.Listener):
        def __init__(self) -> None:
            self.depth, self.start, self.total_s, self.count = 0, 0.0, 0.0, 0

        def on_start(self, ev: event.Event) -> None:
            if self.depth == 0:
                self.start = time.perf_counter()
                if self.count == 0:
                    mark_spoken()
                    print(COMPILE_NOTE, file=out, flush=True)
            self.depth += 1

        def on_end(self, ev: event.Event) -> None:
            self.depth = max(self.depth - 1, 0)
            if self.depth == 0:
                self.total_s += time.perf_counter() - self.start
                self.count += 1

    note = Note()
    with event.install_listener("numba:compile", note):
        yield
    if note.count:
        print(f"compiled {note.count} numba kernel(s) in {note.total_s:.0f} s, cached for later runs", file=out,
              flush=True)
