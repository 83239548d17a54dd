"""The control step's arithmetic over a batch axis, compiled: the admission (`admit`) and the safety
monitor's common case (`run_plain`), the one implementation of each for every loop (one run is B = 1).

Why compiled (numba, `@njit(cache=True)`, no fastmath: IEEE operations in the written order;
`admit` and `run_plain` inline="always", so `admit_and_run` is one function without inner calls,
0.2–0.3 µs less at B = 1). The
same code must serve a serial run (B = 1, every control call of the simulated, camera and hardware
loops and of the environment) and a batched study (B in the hundreds). In numpy each operation on a
(1, N) array costs about 0.5–1 µs of call overhead, so the admission and the monitor's RUN case
written as numpy expressions cost more at B = 1 than the whole scalar step they replace; one compiled
call does either for all B rows in about 1 µs plus a few ns a row (tools/bench_batch.py's `step_us`).
Loaded on the first call (`controllers.core.lazy_import`): `softcbf list` never imports numba.

Few arguments, packed (each array argument costs about 0.1 µs of the call's dispatch): the limits
(2, N) hPa (lo, hi), the monitor's state (B, 2 + N) (its clock s, hold_since s, last_run hPa) and
bits (B, 2) bool (has_run, latched), of which `closedloop.monitor.BatchSafetyMonitor`'s attributes
are views; a row without a filter output has u_filter NaN (refused as any non-finite command).

`admit(u_filter, limits, command, admitted)`, per row b (docs/safety-filter.md):
  admitted[b] = every u_filter[b, j] is finite;
  command[b, j] = min(max(u_filter[b, j], lo[j]), hi[j]) (Python's min and max: max(v, lo) is lo only
  if lo > v, min(v, hi) is hi only if hi < v, so a v in range is kept as it is, −0.0 included; with
  lo = −inf and hi = +inf, no limits, every float is kept as it is, NaN included). u_filter (B, N)
  hPa, lo, hi = limits (N,) hPa each; command (B, N) and admitted (B,) are written.

`run_plain(t, u, admitted, fault, rows, quiet, state, bits, sent, action)`: the monitor's RUN case
(closedloop.monitor; u may be `sent` itself). Checks first that every stepped row's t (s) is finite and not before its clock (returns −1 − b for the first row b that is not, nothing changed);
then per row: not stepped (rows[b] False) → action NOT_STEPPED, sent 0; stepped, admitted, no fault,
no flag raised (quiet) and no latched vent → RUN: sent = last_run = u[b], has_run, no hold, action 0;
any other stepped row → action PENDING, sent untouched (the caller decides it with `decide`). Every
stepped row's clock becomes t[b]. Returns the number of PENDING rows.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from closedloop.monitor_layout import CLOCK, HAS_RUN, HOLD_SINCE, LAST_RUN, LATCHED, NOT_STEPPED, PENDING


@njit(cache=True, inline="always")
def admit(u_filter: np.ndarray, limits: np.ndarray, command: np.ndarray, admitted: np.ndarray) -> None:
    n_rows, n = u_filter.shape
    for b in range(n_rows):
        ok = True
        for j in range(n):
            v = u_filter[b, j]
            if not math.isfinite(v):
                ok = False
            if limits[0, j] > v:
                v = limits[0, j]
            if limits[1, j] < v:
                v = limits[1, j]
            command[b, j] = v
        admitted[b] = ok


@njit(cache=True, inline="always")
def run_plain(t: np.ndarray, u: np.ndarray, admitted: np.ndarray, fault: np.ndarray, rows: np.ndarray,
              quiet: np.ndarray, state: np.ndarray, bits: np.ndarray, sent: np.ndarray, action: np.ndarray) -> int:
    n_rows, n = sent.shape
    for b in range(n_rows):
        if rows[b] and not (math.isfinite(t[b]) and t[b] >= state[b, CLOCK]):
            return -1 - b
    pending = 0
    for b in range(n_rows):
        if not rows[b]:
            action[b] = NOT_STEPPED
            for j in range(n):
                sent[b, j] = 0.0
            continue
        state[b, CLOCK] = t[b]
        if admitted[b] and not fault[b] and quiet[b] and not bits[b, LATCHED]:
            for j in range(n):
                sent[b, j] = u[b, j]
                state[b, LAST_RUN + j] = u[b, j]
            bits[b, HAS_RUN] = True
            state[b, HOLD_SINCE] = math.nan
            action[b] = 0
        else:
            action[b] = PENDING
            pending += 1
    return pending


@njit(cache=True)
def admit_and_run(u_filter: np.ndarray, limits: np.ndarray, t: np.ndarray, fault: np.ndarray, rows: np.ndarray,
                  quiet: np.ndarray, state: np.ndarray, bits: np.ndarray, sent: np.ndarray, admitted: np.ndarray,
                  action: np.ndarray) -> int:
    admit(u_filter, limits, sent, admitted)
    return run_plain(t, sent, admitted, fault, rows, quiet, state, bits, sent, action)
