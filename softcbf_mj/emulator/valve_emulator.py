"""The arm and plate behind an emulated valve board: a MuJoCo `PlantHook` run in real time.

`ValveEmulator(plant, clock)` is the `hardware.board.PlantHook` of a `ValveBoard`: the
board calls `apply(u, t)` when its outputs change (setpoint, VENT, watchdog) and
`measured(t)` for every ACK, with t its clock (s). The plant's time is τ = t − t_start
(t_start: the clock at construction). The board never waits for the physics, as a
real board does not wait for its valves:

- `apply(u, t)` queues (τ, u); the plant applies it at the first step that starts at or
  after τ (the board's outputs are held in between: zero-order hold), so a command acts
  at most Δt late (Δt = `plant.control_dt`, 2 ms in `softcbf_mj.emulator.emulate`);
- `measured(t)` returns the pressure acting in the latest plant state,
  `PlantState.u_applied` (hPa, (N,)), after the plant's own first-order valve dynamics
  (τ_p, MuJoCo's `filterexact`).

A daemon thread (`start()`) advances the plant to the clock every `tick_s`:

    while τ_plant + Δt ≤ clock() − t_start:  apply the queued commands due;  plant.step(u_held)

so the plant never runs ahead of the clock and moves in real time whether or not the
laptop talks to the board. `lag_max_s` is the largest delay of the plant behind the
clock seen after an advance: the machine's load shows there (MujocoPlant alone runs
2.5–5× faster than real time on the development machine). `snapshot()` hands the
virtual camera the current state (its clock time, qpos) after advancing to the clock.

Every plant step is recorded (`record()`: arrays with first axis the plant step, units in
`RECORD_UNITS`): clock time, the board's output u, the pressure acting, the true q and q̇
(sums of the hinge angles), the segment ends (base first, tip last) and each plate's
spring force and displacement; `state_at(times)` samples it. Tests assert on it (the
true plate force stays below F_max).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Callable

import numpy as np

from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.plant import PlantState

DEFAULT_TICK_S = 1e-3

RECORD_UNITS = {
    "t": "s (emulator clock)",
    "u": "hPa",
    "u_applied": "hPa",
    "q": "rad",
    "qd": "rad/s",
    "segment_ends": "m",
    "contact_force": "N",
    "plate_displacement_m": "m",
}


class ValveEmulator:
    """A MujocoPlant driven by a valve board's outputs in real time (see the module docstring)."""

    def __init__(self, plant: MujocoPlant, clock: Callable[[], float] = time.monotonic,
                 tick_s: float = DEFAULT_TICK_S) -> None:
        if not (math.isfinite(tick_s) and tick_s > 0):
            raise ValueError(f"tick_s must be a finite time > 0 s, got {tick_s}")
        self.plant = plant
        self.clock = clock
        self.tick_s = float(tick_s)
        self.n_segments = plant.n_segments
        self.t_start = clock()
        self.lag_max_s = 0.0
        self._lock = threading.Lock()  # the plant and its record
        self._queue_lock = threading.Lock()  # commands from the board: (plant time, u), in order
        self._queue: deque[tuple[float, np.ndarray]] = deque()
        self._u = np.zeros(plant.n_segments)
        self._state: PlantState = plant.state()
        self._rows: list[np.ndarray] = []
        self._record_row(self._state)
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="valve-emulator", daemon=True)

    # -- PlantHook ------------------------------------------------------------------

    def apply(self, u: np.ndarray, t: float) -> None:
        """Hold the board's outputs u (hPa, (N,)) from board time t on (queued; the plant thread applies it)."""
        u = np.array(u, dtype=float)
        if u.shape != (self.n_segments,) or not np.all(np.isfinite(u)):
            raise ValueError(f"u must be {self.n_segments} finite pressures (hPa), got {u.tolist()}")
        with self._queue_lock:
            self._queue.append((t - self.t_start, u))

    def measured(self, t: float) -> np.ndarray:
        """The pressure acting in the latest plant state (hPa, (N,)); never waits for the plant."""
        return self._state.u_applied.copy()

    # -- real time ------------------------------------------------------------------

    def start(self) -> None:
        """Run the plant in real time in a daemon thread until `close()`."""
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.wait(self.tick_s):
                with self._lock:
                    self._advance(self.clock())
        except BaseException as exc:  # close() re-raises it
            self._error = exc

    def _advance(self, t: float) -> None:
        target = t - self.t_start
        dt = self.plant.control_dt
        while self._state.t + dt <= target + 1e-9:
            with self._queue_lock:
                while self._queue and self._queue[0][0] <= self._state.t + 1e-9:
                    self._u = self._queue.popleft()[1]
            self._state = self.plant.step(self._u)
            self._record_row(self._state)
        self.lag_max_s = max(self.lag_max_s, self.clock() - self.t_start - self._state.t)

    def snapshot(self) -> tuple[float, np.ndarray]:
        """(clock time of the current plant state, a copy of its qpos) for rendering."""
        with self._lock:
            self._advance(self.clock())
            return self.t_start + self._state.t, self.plant.data.qpos.copy()

    def close(self) -> None:
        """Stop the real-time thread; re-raises an error it hit."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self._error is not None:
            raise RuntimeError("the valve emulator's plant thread failed") from self._error

    # -- record ---------------------------------------------------------------------

    def _record_row(self, s: PlantState) -> None:
        self._rows.append(np.concatenate(([self.t_start + s.t], self._u, s.u_applied, s.q, s.qd, s.segment_ends.ravel(),
                                          s.contact_forces, s.extras["plate_displacement_m"])))

    def record(self) -> dict[str, np.ndarray]:
        """Every plant step so far as arrays by key (`RECORD_UNITS`), first axis the step."""
        with self._lock:
            rows = np.array(self._rows)
        n, p = self.n_segments, self.plant.n_facets
        shapes = {"t": (), "u": (n,), "u_applied": (n,), "q": (n,), "qd": (n,), "segment_ends": (n + 1, 2),
                  "contact_force": (p,), "plate_displacement_m": (p,)}
        out, start = {}, 0
        for key, shape in shapes.items():
            size = int(np.prod(shape))
            out[key] = rows[:, start:start + size].reshape((len(rows),) + shape)
            start += size
        return out

    def state_at(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """The recorded plant state at clock times `times` (K,): the last step at or before each (zero-order hold)."""
        rec = self.record()
        index = np.clip(np.searchsorted(rec["t"], np.asarray(times, dtype=float), side="right") - 1, 0, len(rec["t"]) - 1)
        return {key: value[index] for key, value in rec.items()}
