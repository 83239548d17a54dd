"""The laptop's end of the valve-board link: clamp, send, wait for the matching ACK, retry, measure.

One exchange (`send_setpoints(u)`, `vent()`):

1. SETPOINT only: u (hPa, (N,)) is clamped to the laptop's limits (`LinkResult.clamped`);
   a non-finite u raises `NonFiniteCommandError` and nothing is sent (the safety state
   machine must have replaced it; the board's watchdog covers a laptop that stops).
2. The frame gets the next sequence number (u16, wraps) and is written.
3. The link reads until an ACK with the same SEQ arrives or `ack_timeout_s` passes.
   Frames with another SEQ (late, duplicated or reordered ACKs of earlier frames) are
   dropped and counted as stale; garbage and CRC failures are counted by the decoder.
4. On a timeout the same frame (same SEQ) is written again, up to `retries` times; the
   board acknowledges a repeat it already applied with DUPLICATE and does not apply it
   twice. Worst case per exchange: (1 + retries) · ack_timeout_s (defaults: 3 × 20 ms).
5. An exchange with no matching ACK fails; after `lost_after` consecutive failures
   `link_lost` is true until an exchange succeeds again. An ACK with REJECTED (the board
   refused a malformed frame) is not a link failure.

Before its first command the link sends SYNC, so that the board accepts this link's
numbering even when it still holds a previous session's sequence number.

Nothing here raises on bad bytes or on an I/O error of the port (an unplugged USB
adapter): those count as failed attempts. Latency is measured from the first write of
a frame to the arrival of its ACK (so it includes retries), over the last
`LATENCY_WINDOW` acknowledged exchanges.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
import serial

from hardware.protocol import (
    Ack,
    BoardStatus,
    Frame,
    FrameDecoder,
    MsgType,
    PressureLimits,
    ProtocolError,
    encode_frame,
    next_seq,
    parse_ack,
    setpoint_frame,
    sync_frame,
    vent_frame,
)
from hardware.transport import DEFAULT_BAUDRATE, ByteTransport, SerialTransport, open_serial

DEFAULT_ACK_TIMEOUT_S = 0.02
DEFAULT_RETRIES = 2
DEFAULT_LOST_AFTER = 1
LATENCY_WINDOW = 10_000

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LinkResult:
    """The outcome of one exchange.

    status: "acked", "rejected" (the board refused the frame) or "timeout" (no matching
    ACK after every retry). sent: the pressures put on the wire (hPa, (N,)), after the
    laptop's clamping (zeros for VENT). clamped: (N,) mask of entries the laptop clamped.
    ack: the board's answer (measured pressures, flags) or None. attempts: writes of
    this frame (of the SYNC before it, when that failed). latency_s: first write → ACK, or None.
    """

    status: str
    seq: int
    sent: np.ndarray
    clamped: np.ndarray
    ack: Ack | None
    attempts: int
    latency_s: float | None
    link_lost: bool

    @property
    def ok(self) -> bool:
        return self.status == "acked"


@dataclass(frozen=True)
class LinkStats:
    """Link quality so far (times in s). acked_fraction = acked / exchanges (NaN before the first)."""

    exchanges: int
    acked: int
    rejected: int
    failed: int
    acked_fraction: float
    retries: int
    latency_median_s: float
    latency_p99_s: float
    crc_errors: int
    header_errors: int
    truncated_frames: int
    discarded_bytes: int
    stale_acks: int
    unexpected_frames: int
    io_errors: int
    laptop_clamped: int
    board_clamped: int
    watchdog_reports: int
    consecutive_failures: int
    link_lost: bool

    def to_dict(self) -> dict[str, float | int | bool]:
        return asdict(self)


def _as_transport(transport: ByteTransport | serial.Serial | str, baudrate: int) -> ByteTransport:
    if isinstance(transport, str):
        return open_serial(transport, baudrate)
    if isinstance(transport, serial.Serial):
        return SerialTransport(transport)
    if not (callable(getattr(transport, "write", None)) and callable(getattr(transport, "read_some", None))):
        raise TypeError(
            "transport must be a port name, an open serial.Serial or an object with write(bytes) and "
            f"read_some(timeout_s) (see hardware.transport.ByteTransport), got {type(transport).__name__}"
        )
    return transport


class ValveBoardLink:
    """Sends pressure setpoints to a valve board and collects its acknowledgements (see the module docstring)."""

    def __init__(
        self,
        transport: ByteTransport | serial.Serial | str,
        n_segments: int,
        u_min,
        u_max,
        ack_timeout_s: float = DEFAULT_ACK_TIMEOUT_S,
        retries: int = DEFAULT_RETRIES,
        clock: Callable[[], float] = time.monotonic,
        lost_after: int = DEFAULT_LOST_AFTER,
        baudrate: int = DEFAULT_BAUDRATE,
    ) -> None:
        self.limits = PressureLimits.of(n_segments, u_min, u_max)
        if not (math.isfinite(ack_timeout_s) and ack_timeout_s > 0):
            raise ValueError(f"ack_timeout_s must be a finite time > 0 s, got {ack_timeout_s}")
        if not (isinstance(retries, int) and retries >= 0):
            raise ValueError(f"retries must be an int >= 0, got {retries!r}")
        if not (isinstance(lost_after, int) and lost_after >= 1):
            raise ValueError(f"lost_after must be an int >= 1 (failed exchanges before the link counts as lost), got {lost_after!r}")
        self.n_segments = n_segments
        self.ack_timeout_s = float(ack_timeout_s)
        self.retries = retries
        self.lost_after = lost_after
        self.clock = clock
        self.transport = _as_transport(transport, baudrate)
        self.decoder = FrameDecoder()
        self._seq = 0
        self._synced = False
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._counts = dict.fromkeys(
            ("exchanges", "acked", "rejected", "failed", "retries", "stale_acks", "unexpected_frames",
             "io_errors", "laptop_clamped", "board_clamped", "watchdog_reports", "consecutive_failures"),
            0,
        )  # fmt: skip

    @property
    def link_lost(self) -> bool:
        return self._counts["consecutive_failures"] >= self.lost_after

    def send_setpoints(self, u) -> LinkResult:
        """Clamp u (hPa, (N,)) to the laptop's limits, send it, wait for its ACK (with retries)."""
        sent, clamped = self.limits.clamp(u)
        if clamped.any():
            self._counts["laptop_clamped"] += 1
        return self._command(lambda seq: setpoint_frame(seq, sent)[0], sent, clamped)

    def vent(self) -> LinkResult:
        """Ask the board to vent every valve to 0 hPa and wait for its ACK (with retries)."""
        zeros = np.zeros(self.n_segments)
        return self._command(vent_frame, zeros, np.zeros(self.n_segments, dtype=bool))

    def stats(self) -> LinkStats:
        c = self._counts
        lat = np.array(self._latencies) if self._latencies else np.array([math.nan])
        d = self.decoder.stats
        return LinkStats(
            exchanges=c["exchanges"], acked=c["acked"], rejected=c["rejected"], failed=c["failed"],
            acked_fraction=c["acked"] / c["exchanges"] if c["exchanges"] else math.nan,
            retries=c["retries"],
            latency_median_s=float(np.median(lat)), latency_p99_s=float(np.percentile(lat, 99)),
            crc_errors=d.crc_errors, header_errors=d.header_errors, truncated_frames=d.truncated,
            discarded_bytes=d.discarded_bytes,
            stale_acks=c["stale_acks"], unexpected_frames=c["unexpected_frames"], io_errors=c["io_errors"],
            laptop_clamped=c["laptop_clamped"], board_clamped=c["board_clamped"],
            watchdog_reports=c["watchdog_reports"], consecutive_failures=c["consecutive_failures"],
            link_lost=self.link_lost,
        )  # fmt: skip

    def close(self) -> None:
        self.transport.close()

    def _command(self, make_frame: Callable[[int], Frame], sent: np.ndarray, clamped: np.ndarray) -> LinkResult:
        self._counts["exchanges"] += 1
        if not self._synced:
            sync = sync_frame(self._seq)
            self._seq = next_seq(self._seq)
            ack, attempts, _ = self._exchange(sync)
            if ack is None:
                return self._record(sync.seq, sent, clamped, None, attempts, None)
            self._synced = True
        frame = make_frame(self._seq)
        self._seq = next_seq(self._seq)
        ack, attempts, latency = self._exchange(frame)
        return self._record(frame.seq, sent, clamped, ack, attempts, latency)

    def _record(self, seq, sent, clamped, ack: Ack | None, attempts: int, latency) -> LinkResult:
        c = self._counts
        was_lost = self.link_lost
        if ack is None:
            status = "timeout"
            c["failed"] += 1
            c["consecutive_failures"] += 1
        else:
            status = "rejected" if BoardStatus.REJECTED in ack.status else "acked"
            c[status] += 1
            c["consecutive_failures"] = 0
            c["board_clamped"] += BoardStatus.CLAMPED in ack.status
            c["watchdog_reports"] += BoardStatus.WATCHDOG in ack.status
            if status == "acked":
                self._latencies.append(latency)
        if self.link_lost != was_lost:
            log.warning(
                "valve-board link %s (%d of %d exchanges acknowledged)",
                "lost" if self.link_lost else "restored", c["acked"], c["exchanges"],
            )  # fmt: skip
        return LinkResult(status, seq, sent, clamped, ack, attempts, latency, self.link_lost)

    def _exchange(self, frame: Frame) -> tuple[Ack | None, int, float | None]:
        """Write `frame` until its ACK arrives: (ack or None, writes, first write → ACK in s)."""
        data = encode_frame(frame)
        first_write = None
        for attempt in range(1 + self.retries):
            if attempt:
                self._counts["retries"] += 1
            try:
                self.transport.write(data)
            except (OSError, serial.SerialException):
                self._counts["io_errors"] += 1
            now = self.clock()
            first_write = now if first_write is None else first_write
            deadline = now + self.ack_timeout_s
            while (remaining := deadline - self.clock()) > 0:
                try:
                    received = self.transport.read_some(min(remaining, self.decoder.gap_s))
                except (OSError, serial.SerialException):
                    self._counts["io_errors"] += 1
                    break
                ack = self._match(self.decoder.feed(received, self.clock()), frame.seq)
                if ack is not None:
                    return ack, attempt + 1, self.clock() - first_write
        return None, 1 + self.retries, None

    def _match(self, frames: list[Frame], seq: int) -> Ack | None:
        """The ACK for `seq` among `frames` (the others are counted and dropped)."""
        match = None
        for f in frames:
            if f.type is not MsgType.ACK:
                self._counts["unexpected_frames"] += 1
            elif f.seq != seq or match is not None:
                self._counts["stale_acks"] += 1
            else:
                try:
                    match = parse_ack(f, self.n_segments)
                except ProtocolError:
                    self._counts["unexpected_frames"] += 1
        return match
