"""The valve board's firmware logic as a transport-agnostic state machine (pure Python).

`ValveBoard.step(t, data)` takes the bytes received since the last call and the board
clock t (s), and returns the encoded frames to send back, in order. The rules (the
protocol is in `hardware/protocol.py` and `hardware/README.md`):

- Boot: valves at 0 hPa (VENTED), no last sequence number, so any SEQ is accepted.
- SETPOINT with a SEQ newer than the last accepted one (1 … 32767 ahead mod 2¹⁶), or any
  SEQ before the first: the setpoints are clamped to the board's own limits
  (CLAMPED flag), applied, logged with t, and acknowledged; the watchdog restarts.
  Malformed (wrong N, reserved value): ACK with REJECTED, nothing applied, SEQ not taken.
- The last accepted SEQ again: ACK with DUPLICATE and the current state; not applied
  again and the watchdog is not fed (the original already did).
- An older SEQ (delayed or reordered frame): ignored, no ACK, counted.
- VENT: valves to 0 hPa, logged, ACK with VENTED. SYNC: the board takes its SEQ as the
  last accepted one (a restarted laptop starts its own numbering) and acknowledges.
- Watchdog: when valves are pressurised and no SETPOINT has been accepted for more than
  `watchdog_s`, the board vents at the first step after the deadline (the transport
  steps it every millisecond) and reports WATCHDOG in its next ACK.
- Every ACK carries the measured pressures of the plant hook at t (hPa, (N,)).

Measured pressures come from a plant hook (`apply(u, t)`, `measured(t)`):
`FirstOrderPressure` (τ dp/dt = u − p) for tests, a MuJoCo-backed hook for the emulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hardware.protocol import (
    BoardStatus,
    FrameDecoder,
    MsgType,
    PressureLimits,
    ProtocolError,
    ack_frame,
    encode_frame,
    parse_setpoint,
    seq_is_newer,
)

DEFAULT_WATCHDOG_S = 0.15  # 1.5 periods of the 10 Hz loop: vents half a period after the first missed command
DEFAULT_PRESSURE_TAU_S = 0.05  # docs/ground-truth.md's default τ_p


class PlantHook(Protocol):
    """What the board drives and measures: pressures in hPa, shape (N,), time in s (non-decreasing)."""

    def apply(self, u: np.ndarray, t: float) -> None: ...

    def measured(self, t: float) -> np.ndarray: ...


class FirstOrderPressure:
    """Chamber pressures p (hPa, (N,)) following the applied setpoints u with τ dp/dt = u − p, p(0) = 0.

    Solved exactly between calls: p(t) = u + (p(t₀) − u)·exp(−(t − t₀)/τ); τ = 0 is an ideal valve.
    """

    def __init__(self, n_segments: int, tau_s: float = DEFAULT_PRESSURE_TAU_S) -> None:
        if not (isinstance(n_segments, int) and n_segments >= 1):
            raise ValueError(f"n_segments must be an int >= 1, got {n_segments!r}")
        if not (math.isfinite(tau_s) and tau_s >= 0.0):
            raise ValueError(f"tau_s must be a finite time constant >= 0 s, got {tau_s}")
        self.tau_s = float(tau_s)
        self._u = np.zeros(n_segments)
        self._p = np.zeros(n_segments)
        self._t: float | None = None

    def _advance(self, t: float) -> None:
        dt = 0.0 if self._t is None else t - self._t
        if dt < 0.0:
            raise ValueError(f"time must not go backwards: got t = {t} s after {self._t} s")
        decay = math.exp(-dt / self.tau_s) if self.tau_s > 0 else 0.0
        self._p = self._u + (self._p - self._u) * decay
        self._t = t

    def apply(self, u: np.ndarray, t: float) -> None:
        self._advance(t)
        self._u = np.array(u, dtype=float)

    def measured(self, t: float) -> np.ndarray:
        self._advance(t)
        return self._p.copy()


@dataclass(frozen=True)
class AppliedPressure:
    """One change of the valve outputs: board time t (s), pressures u (hPa, (N,)), why."""

    t: float
    u: tuple[float, ...]
    reason: str  # "setpoint", "vent" or "watchdog"


@dataclass
class BoardStats:
    setpoints_applied: int = 0
    clamped: int = 0
    duplicates: int = 0
    stale_frames: int = 0
    rejected: int = 0
    vents: int = 0
    watchdog_vents: int = 0
    syncs: int = 0
    unexpected_frames: int = 0  # frames a board never receives (ACK)


class ValveBoard:
    """The board's logic: clamps to its limits, acknowledges, ignores duplicates, vents on its watchdog."""

    def __init__(
        self,
        n_segments: int,
        u_min,
        u_max,
        watchdog_s: float = DEFAULT_WATCHDOG_S,
        plant_hook: PlantHook | None = None,
    ) -> None:
        self.limits = PressureLimits.of(n_segments, u_min, u_max)
        if not (math.isfinite(watchdog_s) and watchdog_s > 0.0):
            raise ValueError(f"watchdog_s must be a finite time > 0 s, got {watchdog_s}")
        self.n_segments = n_segments
        self.watchdog_s = float(watchdog_s)
        self.plant = plant_hook if plant_hook is not None else FirstOrderPressure(n_segments)
        self.decoder = FrameDecoder()
        self.stats = BoardStats()
        self._log: list[AppliedPressure] = []
        self._output = np.zeros(n_segments)
        self._vented = True
        self._watchdog_latched = False
        self._last_seq: int | None = None
        self._last_setpoint_t = -math.inf

    @property
    def output(self) -> np.ndarray:
        """The setpoints the valves hold now (hPa, (N,))."""
        return self._output.copy()

    @property
    def vented(self) -> bool:
        return self._vented

    def applied(self) -> list[AppliedPressure]:
        """Every change of the outputs so far, oldest first."""
        return list(self._log)

    def applied_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The log as arrays: times (K,) s and pressures (K, N) hPa."""
        log = self.applied()
        return np.array([a.t for a in log]), np.array([a.u for a in log]).reshape(len(log), self.n_segments)

    def step(self, t: float, data: bytes = b"") -> list[bytes]:
        """Advance to board time t with the bytes received; return the encoded frames to send."""
        if not self._vented and t - self._last_setpoint_t > self.watchdog_s:
            self._set_output(np.zeros(self.n_segments), t, "watchdog")
            self._watchdog_latched = True
            self.stats.watchdog_vents += 1
        replies: list[bytes] = []
        for frame in self.decoder.feed(data, t):
            reply = self._handle(frame, t)
            if reply is not None:
                replies.append(reply)
        return replies

    def _set_output(self, u: np.ndarray, t: float, reason: str) -> None:
        self._output = u
        self._vented = reason != "setpoint"
        self.plant.apply(u.copy(), t)
        self._log.append(AppliedPressure(t, tuple(u.tolist()), reason))

    def _ack(self, seq: int, t: float, flags: BoardStatus = BoardStatus.NONE) -> bytes:
        if self._vented:
            flags |= BoardStatus.VENTED
        if self._watchdog_latched:
            flags |= BoardStatus.WATCHDOG
            self._watchdog_latched = False
        return encode_frame(ack_frame(seq, flags, self.plant.measured(t)))

    def _handle(self, frame, t: float) -> bytes | None:
        if frame.type is MsgType.ACK:
            self.stats.unexpected_frames += 1
            return None
        if frame.type is MsgType.SYNC:
            self._last_seq = frame.seq
            self.stats.syncs += 1
            return self._ack(frame.seq, t)
        if self._last_seq is not None and frame.seq == self._last_seq:
            self.stats.duplicates += 1
            return self._ack(frame.seq, t, BoardStatus.DUPLICATE)
        if self._last_seq is not None and not seq_is_newer(frame.seq, self._last_seq):
            self.stats.stale_frames += 1
            return None
        if frame.type is MsgType.VENT:
            self._last_seq = frame.seq
            self._set_output(np.zeros(self.n_segments), t, "vent")
            self.stats.vents += 1
            return self._ack(frame.seq, t)
        try:
            requested = parse_setpoint(frame, self.n_segments)
        except ProtocolError:
            self.stats.rejected += 1
            return self._ack(frame.seq, t, BoardStatus.REJECTED)
        self._last_seq = frame.seq
        u, clipped = self.limits.clamp(requested)
        self._last_setpoint_t = t
        self._set_output(u, t, "setpoint")
        self.stats.setpoints_applied += 1
        flags = BoardStatus.NONE
        if clipped.any():
            flags |= BoardStatus.CLAMPED
            self.stats.clamped += 1
        return self._ack(frame.seq, t, flags)
