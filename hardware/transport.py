"""Byte paths between the laptop and a valve board: a serial port, and a pseudo-terminal line with a board behind it.

The link (`hardware/link.py`) needs only a `ByteTransport`: `write(bytes)`,
`read_some(timeout_s) -> bytes` (whatever has arrived, waiting at most timeout_s for the
first byte) and `close()`. `SerialTransport` gives that over pyserial (POSIX: it waits
with select on the port's file descriptor); `open_serial(port)` opens a real port.

`PtyBoardLine` is the same byte path without hardware: `os.openpty()` gives a
master/slave pair; a `ValveBoard` runs in a background thread on the master side
(stepped at every received chunk and at least every `tick_s`, so its watchdog has
millisecond resolution) and the laptop opens the slave with pyserial, exactly as it
opens a USB serial port. `LineFaults` make the line lossy: laptop → board chunks can be
dropped or corrupted (one bit flipped) before the board sees them; board → laptop frames
can be dropped, corrupted, duplicated or reordered (held back and sent after the next
frame). `LineFaults.cut()` loses everything in both directions (a pulled cable),
`LineFaults.silent()` a board that never answers. Faults can be changed while the line runs.
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, fields
from typing import Callable, Protocol

import numpy as np
import serial

from hardware.board import ValveBoard

DEFAULT_BAUDRATE = 115200
DEFAULT_WRITE_TIMEOUT_S = 0.05
DEFAULT_TICK_S = 1e-3


class ByteTransport(Protocol):
    """What the link needs from a byte path."""

    def write(self, data: bytes) -> None: ...

    def read_some(self, timeout_s: float) -> bytes: ...

    def close(self) -> None: ...


class SerialTransport:
    """A `ByteTransport` over an open pyserial port (POSIX: select on its file descriptor)."""

    def __init__(self, port: serial.Serial) -> None:
        if not port.is_open:
            raise ValueError(f"serial port {port.port!r} is not open; open it first (serial.Serial(port, baudrate))")
        self.port = port
        self.port.timeout = 0  # reads never block; read_some waits with select

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def read_some(self, timeout_s: float) -> bytes:
        ready, _, _ = select.select([self.port.fileno()], [], [], max(0.0, timeout_s))
        if not ready:
            return b""
        return self.port.read(max(1, self.port.in_waiting))

    def close(self) -> None:
        self.port.close()


def open_serial(port: str, baudrate: int = DEFAULT_BAUDRATE, write_timeout_s: float = DEFAULT_WRITE_TIMEOUT_S) -> SerialTransport:
    """Open `port` (e.g. /dev/ttyACM0 or a pty's slave) 8N1 at `baudrate` as a SerialTransport."""
    return SerialTransport(serial.Serial(port, baudrate=baudrate, timeout=0, write_timeout=write_timeout_s))


@dataclass(frozen=True)
class LineFaults:
    """Probabilities (0 … 1) of each fault: per chunk laptop → board, per frame board → laptop."""

    drop_in: float = 0.0
    corrupt_in: float = 0.0
    drop_out: float = 0.0
    corrupt_out: float = 0.0
    duplicate_out: float = 0.0
    reorder_out: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            p = getattr(self, f.name)
            if not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
                raise ValueError(f"LineFaults.{f.name} must be a probability in [0, 1], got {p!r}")

    @classmethod
    def cut(cls) -> "LineFaults":
        """Nothing gets through in either direction."""
        return cls(drop_in=1.0, drop_out=1.0)

    @classmethod
    def silent(cls) -> "LineFaults":
        """The board hears everything and nothing it says arrives."""
        return cls(drop_out=1.0)


@dataclass
class FaultCounts:
    dropped_in: int = 0
    corrupted_in: int = 0
    dropped_out: int = 0
    corrupted_out: int = 0
    duplicated_out: int = 0
    reordered_out: int = 0
    overflowed_out: int = 0  # frames the laptop side had no room for (it stopped reading)


class _FaultInjector:
    def __init__(self, faults: LineFaults, seed: int) -> None:
        self.faults = faults
        self.counts = FaultCounts()
        self._rng = np.random.default_rng(seed)
        self._held: bytes | None = None

    def _flip_bit(self, data: bytes) -> bytes:
        out = bytearray(data)
        out[int(self._rng.integers(len(out)))] ^= 1 << int(self._rng.integers(8))
        return bytes(out)

    def inbound(self, data: bytes) -> bytes:
        f, rng = self.faults, self._rng
        if not data:
            return data
        if rng.random() < f.drop_in:
            self.counts.dropped_in += 1
            return b""
        if rng.random() < f.corrupt_in:
            self.counts.corrupted_in += 1
            return self._flip_bit(data)
        return data

    def outbound(self, frames: list[bytes]) -> list[bytes]:
        f, rng = self.faults, self._rng
        out: list[bytes] = []
        for frame in frames:
            if rng.random() < f.drop_out:
                self.counts.dropped_out += 1
                continue
            if rng.random() < f.corrupt_out:
                self.counts.corrupted_out += 1
                frame = self._flip_bit(frame)
            copies = [frame]
            if rng.random() < f.duplicate_out:
                self.counts.duplicated_out += 1
                copies.append(frame)
            if self._held is None and rng.random() < f.reorder_out:
                self.counts.reordered_out += 1
                self._held = frame
                copies.pop(0)
            elif self._held is not None:
                copies.append(self._held)
                self._held = None
            out.extend(copies)
        return out


class PtyBoardLine:
    """A ValveBoard behind a pseudo-terminal: the laptop opens `port_name` with pyserial.

    The board runs in a daemon thread until `close()` (or the end of a `with` block).
    `clock` is the board's time source (s). `faults` can be reassigned while it runs.
    """

    def __init__(
        self,
        board: ValveBoard,
        faults: LineFaults = LineFaults(),
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        tick_s: float = DEFAULT_TICK_S,
    ) -> None:
        if not (math.isfinite(tick_s) and tick_s > 0):
            raise ValueError(f"tick_s must be a finite time > 0 s, got {tick_s}")
        self.board = board
        self.clock = clock
        self.tick_s = float(tick_s)
        self._injector = _FaultInjector(faults, seed)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port_name = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=f"valve-board {self.port_name}", daemon=True)
        self._thread.start()

    @property
    def faults(self) -> LineFaults:
        return self._injector.faults

    @faults.setter
    def faults(self, faults: LineFaults) -> None:
        if not isinstance(faults, LineFaults):
            raise TypeError(f"faults must be a LineFaults, got {type(faults).__name__}")
        self._injector.faults = faults

    @property
    def fault_counts(self) -> FaultCounts:
        return self._injector.counts

    def open_transport(self, baudrate: int = DEFAULT_BAUDRATE) -> SerialTransport:
        """The laptop's end: the slave side opened with pyserial."""
        return open_serial(self.port_name, baudrate)

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([self._master], [], [], self.tick_s)
                data = os.read(self._master, 4096) if ready else b""
                frames = self.board.step(self.clock(), self._injector.inbound(data))
                for frame in self._injector.outbound(frames):
                    try:
                        os.write(self._master, frame)
                    except BlockingIOError:
                        self._injector.counts.overflowed_out += 1
        except BaseException as exc:  # reported by close(), never lost silently
            self._error = exc

    def close(self) -> None:
        """Stop the board thread and close the pty; re-raises an error the board thread hit."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=1.0)
        os.close(self._master)
        os.close(self._slave)
        if self._error is not None:
            raise RuntimeError(f"the valve-board thread on {self.port_name} failed") from self._error

    def __enter__(self) -> "PtyBoardLine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
