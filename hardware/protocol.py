"""The valve-board serial protocol: frames, CRC, fixed-point pressures, a resynchronising decoder.

Every message is one frame (all multi-byte fields little-endian except the CRC):

| offset  | size | field   | meaning                                                        |
|---------|------|---------|----------------------------------------------------------------|
| 0       | 1    | START   | 0xA5                                                           |
| 1       | 1    | LEN     | payload length in bytes, 0 … 64                                |
| 2       | 1    | TYPE    | message type (`MsgType`)                                       |
| 3       | 2    | SEQ     | sequence number, u16, wraps 65535 → 0                          |
| 5       | LEN  | PAYLOAD | type-specific                                                  |
| 5 + LEN | 2    | CRC     | CRC-16/CCITT-FALSE of LEN…PAYLOAD, most significant byte first |

CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no reflection, no final
XOR; check value CRC("123456789") = 0x29B1. Sent MSB first, so the CRC of LEN…CRC is 0.

Message types and payloads (N = number of segments):

| type     | code | direction      | payload                              | LEN      |
|----------|------|----------------|--------------------------------------|----------|
| SETPOINT | 0x01 | laptop → board | N × int16 pressure setpoints         | 2N       |
| VENT     | 0x02 | laptop → board | none: all valves to 0 hPa            | 0        |
| SYNC     | 0x03 | laptop → board | none: the board takes SEQ as its last sequence number | 0 |
| ACK      | 0x81 | board → laptop | u8 status flags (`BoardStatus`), N × int16 measured pressures | 1 + 2N |

Pressures are fixed point: int16 counts of 0.1 hPa (`COUNTS_PER_HPA` = 10), so the
representable range is ±3276.7 hPa with 0.1 hPa resolution (setpoints round to the
nearest count). −32768 is reserved: in an ACK it marks a measured pressure that is not
available (decoded as NaN); in a SETPOINT it is invalid and the board rejects the frame.
A non-finite setpoint cannot be encoded (`NonFiniteCommandError`); one outside ±3276.7
hPa is clamped and flagged.

Resynchronisation (length + CRC): the decoder scans for START, reads the 5-byte header
and rejects it at once if LEN > 64 or TYPE is unknown or LEN is impossible for TYPE
(odd for SETPOINT, even for ACK, non-zero for VENT/SYNC). Otherwise it waits for the
whole frame and checks the CRC. On any rejection it drops only the START byte and scans
again from the next byte, so a genuine frame that follows garbage, a truncated frame or a
false START is found. A frame is sent in one burst, so when the bytes of an incomplete
frame stop for more than `DEFAULT_GAP_S` (5 ms) it is abandoned the same way; without
that rule a corrupted LEN would hold back the frames behind it until up to 71 bytes
arrived. Nothing raises on bad input; errors are counted (`DecoderStats`).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np

from controllers.core.errors import NonFiniteCommandError, as_vector

START = 0xA5
HEADER_SIZE = 5  # START, LEN, TYPE, SEQ (2)
CRC_SIZE = 2
MAX_PAYLOAD = 64
SEQ_MODULUS = 1 << 16
COUNTS_PER_HPA = 10
INT16_MAX = 32767
RESERVED_COUNT = -32768  # "not available" in an ACK, invalid in a SETPOINT
PRESSURE_RANGE_HPA = INT16_MAX / COUNTS_PER_HPA  # ±3276.7 hPa
MAX_SEGMENTS = (MAX_PAYLOAD - 1) // 2  # an ACK carries 1 + 2N bytes
DEFAULT_GAP_S = 0.005  # silence that ends an incomplete frame (58 byte times at 115200 baud)


class MsgType(IntEnum):
    SETPOINT = 0x01
    VENT = 0x02
    SYNC = 0x03
    ACK = 0x81


class BoardStatus(IntFlag):
    """Status flags carried by every ACK (u8)."""

    NONE = 0
    CLAMPED = 0x01  # the acknowledged SETPOINT was clamped to the board's limits
    VENTED = 0x02  # the valves are at 0 hPa (boot, VENT or watchdog) and no SETPOINT has been applied since
    WATCHDOG = 0x04  # the watchdog vented the valves since the previous ACK (latched until reported)
    DUPLICATE = 0x08  # this SEQ was already accepted; the frame was not applied again
    REJECTED = 0x10  # the SETPOINT was malformed (wrong N or a reserved value) and not applied


class ProtocolError(ValueError):
    """A frame or payload that does not follow the protocol."""


def _length_ok(msg_type: MsgType, length: int) -> bool:
    if msg_type is MsgType.SETPOINT:
        return length >= 2 and length % 2 == 0
    if msg_type is MsgType.ACK:
        return length >= 3 and length % 2 == 1
    return length == 0


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0) of `data`."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


def next_seq(seq: int) -> int:
    """The sequence number after `seq` (u16, wraps)."""
    return (seq + 1) % SEQ_MODULUS


def seq_is_newer(seq: int, reference: int) -> bool:
    """True when `seq` follows `reference` by 1 … 32767 steps (serial-number arithmetic mod 2¹⁶)."""
    return 0 < (seq - reference) % SEQ_MODULUS < SEQ_MODULUS // 2


@dataclass(frozen=True)
class Frame:
    """One protocol message: its type, sequence number (0 … 65535) and raw payload."""

    type: MsgType
    seq: int
    payload: bytes = b""

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "type", MsgType(self.type))
        except ValueError as exc:
            valid = ", ".join(f"{m.name}=0x{m.value:02X}" for m in MsgType)
            raise ProtocolError(f"unknown message type {self.type!r}; valid: {valid}") from exc
        if not (isinstance(self.seq, int) and 0 <= self.seq < SEQ_MODULUS):
            raise ProtocolError(f"seq must be an int in [0, {SEQ_MODULUS - 1}], got {self.seq!r}")
        object.__setattr__(self, "payload", bytes(self.payload))
        if len(self.payload) > MAX_PAYLOAD or not _length_ok(self.type, len(self.payload)):
            raise ProtocolError(
                f"a {self.type.name} payload of {len(self.payload)} bytes is invalid "
                f"(SETPOINT: 2N, ACK: 1 + 2N, VENT/SYNC: 0; at most {MAX_PAYLOAD})"
            )


def encode_frame(frame: Frame) -> bytes:
    """The bytes of `frame` on the wire (START … CRC)."""
    body = struct.pack("<BBH", len(frame.payload), frame.type, frame.seq) + frame.payload
    return bytes((START,)) + body + crc16_ccitt_false(body).to_bytes(2, "big")


def decode_frame(data: bytes) -> Frame:
    """The frame that is exactly `data`; raises ProtocolError naming what is wrong."""
    if len(data) < HEADER_SIZE + CRC_SIZE:
        raise ProtocolError(f"a frame has at least {HEADER_SIZE + CRC_SIZE} bytes, got {len(data)}")
    if data[0] != START:
        raise ProtocolError(f"a frame starts with 0x{START:02X}, got 0x{data[0]:02X}")
    length = data[1]
    if len(data) != HEADER_SIZE + length + CRC_SIZE:
        raise ProtocolError(f"LEN = {length} needs {HEADER_SIZE + length + CRC_SIZE} bytes, got {len(data)}")
    if crc16_ccitt_false(data[1:]) != 0:
        raise ProtocolError(f"CRC mismatch: frame carries 0x{data[-2:].hex().upper()}, computed 0x{crc16_ccitt_false(data[1:-2]):04X}")
    (seq,) = struct.unpack_from("<H", data, 3)
    return Frame(data[2], seq, data[HEADER_SIZE:-CRC_SIZE])


def _pressure_vector(name: str, values, n: int | None) -> np.ndarray:
    return as_vector(name, values, n, NonFiniteCommandError)


def pressures_to_counts(u_hpa) -> tuple[np.ndarray, np.ndarray]:
    """Finite pressures (hPa, (N,)) → int16 counts of 0.1 hPa, rounded, clamped to ±3276.7 hPa.

    Returns (counts (N,) int16, clamped (N,) bool). Raises NonFiniteCommandError for NaN/inf.
    """
    u = _pressure_vector("pressure setpoints", u_hpa, None)
    counts = np.rint(u * COUNTS_PER_HPA)
    clamped = np.abs(counts) > INT16_MAX
    return np.clip(counts, -INT16_MAX, INT16_MAX).astype(np.int16), clamped


def _counts_payload(counts: np.ndarray) -> bytes:
    return counts.astype("<i2").tobytes()


def _payload_counts(payload: bytes) -> np.ndarray:
    return np.frombuffer(payload, dtype="<i2").astype(np.int64)


def setpoint_frame(seq: int, u_hpa) -> tuple[Frame, np.ndarray]:
    """A SETPOINT frame for pressures u (hPa, (N,)) and the (N,) mask of values clamped to ±3276.7 hPa."""
    counts, clamped = pressures_to_counts(u_hpa)
    if not 1 <= counts.size <= MAX_SEGMENTS:
        raise ProtocolError(f"a SETPOINT carries 1 … {MAX_SEGMENTS} pressures, got {counts.size}")
    return Frame(MsgType.SETPOINT, seq, _counts_payload(counts)), clamped


def vent_frame(seq: int) -> Frame:
    return Frame(MsgType.VENT, seq)


def sync_frame(seq: int) -> Frame:
    return Frame(MsgType.SYNC, seq)


def parse_setpoint(frame: Frame, n_segments: int) -> np.ndarray:
    """The setpoints (hPa, (N,)) of a SETPOINT frame; ProtocolError for a wrong N or a reserved value."""
    if frame.type is not MsgType.SETPOINT:
        raise ProtocolError(f"expected a SETPOINT frame, got {frame.type.name}")
    counts = _payload_counts(frame.payload)
    if counts.size != n_segments:
        raise ProtocolError(f"SETPOINT carries {counts.size} pressures, this board drives {n_segments}")
    if (counts == RESERVED_COUNT).any():
        raise ProtocolError(f"SETPOINT carries the reserved value {RESERVED_COUNT}: {counts.tolist()}")
    return counts / COUNTS_PER_HPA


@dataclass(frozen=True)
class Ack:
    """A decoded ACK: the acknowledged sequence number, the board's flags, measured pressures (hPa, (N,), NaN = n/a)."""

    seq: int
    status: BoardStatus
    measured: np.ndarray


def ack_frame(seq: int, status: BoardStatus, measured_hpa) -> Frame:
    """An ACK for `seq`; NaN measured pressures go out as 'not available', others clamp to ±3276.7 hPa."""
    measured = np.asarray(measured_hpa, dtype=float).reshape(-1)
    if not 1 <= measured.size <= MAX_SEGMENTS:
        raise ProtocolError(f"an ACK carries 1 … {MAX_SEGMENTS} pressures, got {measured.size}")
    counts = np.clip(np.rint(np.nan_to_num(measured, nan=0.0) * COUNTS_PER_HPA), -INT16_MAX, INT16_MAX)
    counts[np.isnan(measured)] = RESERVED_COUNT
    return Frame(MsgType.ACK, seq, bytes((int(status) & 0xFF,)) + _counts_payload(counts.astype(np.int16)))


def parse_ack(frame: Frame, n_segments: int) -> Ack:
    """The Ack in an ACK frame; ProtocolError for another type or a wrong N."""
    if frame.type is not MsgType.ACK:
        raise ProtocolError(f"expected an ACK frame, got {frame.type.name}")
    counts = _payload_counts(frame.payload[1:])
    if counts.size != n_segments:
        raise ProtocolError(f"ACK carries {counts.size} pressures, expected {n_segments}")
    measured = np.where(counts == RESERVED_COUNT, math.nan, counts / COUNTS_PER_HPA)
    return Ack(frame.seq, BoardStatus(frame.payload[0] & 0x1F), measured)


@dataclass
class DecoderStats:
    """Counters of a FrameDecoder: good frames, CRC failures, rejected headers, frames abandoned after a gap, bytes thrown away."""

    frames: int = 0
    crc_errors: int = 0
    header_errors: int = 0
    truncated: int = 0
    discarded_bytes: int = 0


class FrameDecoder:
    """Streaming decoder: `feed(bytes, t)` returns the complete, CRC-checked frames found so far.

    Survives garbage, corrupted, truncated and concatenated input (see the module's
    resynchronisation rule); keeps at most one incomplete frame between calls. With
    arrival times t (s), an incomplete frame whose bytes stopped for more than `gap_s`
    is abandoned (a frame is sent in one burst), so a corrupted LEN cannot hold back the
    frames after it until 64 more bytes arrive.
    """

    def __init__(self, gap_s: float = DEFAULT_GAP_S) -> None:
        if not (math.isfinite(gap_s) and gap_s > 0):
            raise ValueError(f"gap_s must be a finite time > 0 s, got {gap_s}")
        self.gap_s = float(gap_s)
        self._buf = bytearray()
        self._last_t = -math.inf
        self.stats = DecoderStats()

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def _discard(self, count: int) -> None:
        del self._buf[:count]
        self.stats.discarded_bytes += count

    def feed(self, data: bytes, t: float | None = None) -> list[Frame]:
        """Frames completed by `data` (received at time t in s; None: no gap rule)."""
        buf = self._buf
        if t is not None:
            if buf and t - self._last_t > self.gap_s:
                self.stats.truncated += 1
                self._discard(1)  # the dead frame's START; what follows is scanned again
            if data:
                self._last_t = t
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(START)
            if start < 0:
                self._discard(len(buf))
                return frames
            if start:
                self._discard(start)
            if len(buf) < HEADER_SIZE:
                return frames
            length, code = buf[1], buf[2]
            if length > MAX_PAYLOAD or code not in _TYPES or not _length_ok(_TYPES[code], length):
                self.stats.header_errors += 1
                self._discard(1)
                continue
            total = HEADER_SIZE + length + CRC_SIZE
            if len(buf) < total:
                return frames
            if crc16_ccitt_false(memoryview(buf)[1:total]) != 0:
                self.stats.crc_errors += 1
                self._discard(1)
                continue
            (seq,) = struct.unpack_from("<H", buf, 3)
            frames.append(Frame(_TYPES[code], seq, bytes(buf[HEADER_SIZE : total - CRC_SIZE])))
            del buf[:total]
            self.stats.frames += 1


_TYPES = {m.value: m for m in MsgType}


@dataclass(frozen=True)
class PressureLimits:
    """Per-segment pressure limits (hPa), inside the protocol's ±3276.7 hPa; both ends of the link clamp to theirs."""

    u_min: tuple[float, ...]
    u_max: tuple[float, ...]

    def __post_init__(self) -> None:
        u_min = tuple(_pressure_vector("u_min", self.u_min, None).tolist())
        u_max = tuple(_pressure_vector("u_max", self.u_max, len(u_min)).tolist())
        if not 1 <= len(u_min) <= MAX_SEGMENTS:
            raise ValueError(f"pressure limits need 1 … {MAX_SEGMENTS} segments, got {len(u_min)}")
        for i, (lo, hi) in enumerate(zip(u_min, u_max)):
            if not -PRESSURE_RANGE_HPA <= lo < hi <= PRESSURE_RANGE_HPA:
                raise ValueError(
                    f"limits of segment {i} must satisfy -{PRESSURE_RANGE_HPA} <= u_min < u_max <= "
                    f"{PRESSURE_RANGE_HPA} hPa, got u_min={lo}, u_max={hi}"
                )
        object.__setattr__(self, "u_min", u_min)
        object.__setattr__(self, "u_max", u_max)

    @classmethod
    def of(cls, n_segments: int, u_min, u_max) -> "PressureLimits":
        """Limits for `n_segments` segments from scalars (the same for every segment) or (N,) sequences."""
        if not (isinstance(n_segments, int) and n_segments >= 1):
            raise ValueError(f"n_segments must be an int >= 1, got {n_segments!r}")
        try:
            lo, hi = (np.broadcast_to(np.asarray(v, dtype=float), (n_segments,)) for v in (u_min, u_max))
        except ValueError as exc:
            raise ValueError(
                f"u_min and u_max must be scalars or have one value per segment ({n_segments}), got {u_min!r}, {u_max!r}"
            ) from exc
        return cls(tuple(lo.tolist()), tuple(hi.tolist()))

    @property
    def n_segments(self) -> int:
        return len(self.u_min)

    def clamp(self, u_hpa) -> tuple[np.ndarray, np.ndarray]:
        """Finite u (hPa, (N,)) clipped to the limits, and the (N,) mask of clipped entries."""
        u = _pressure_vector("pressure command", u_hpa, self.n_segments)
        clipped = np.clip(u, self.u_min, self.u_max)
        return clipped, clipped != u
