"""Valve-board protocol: CRC check value, byte layout, fixed point, and a decoder that survives bad input."""

import numpy as np
import pytest

from controllers.core.errors import NonFiniteCommandError
from hardware.protocol import (
    COUNTS_PER_HPA,
    MAX_SEGMENTS,
    PRESSURE_RANGE_HPA,
    BoardStatus,
    Frame,
    FrameDecoder,
    MsgType,
    PressureLimits,
    ProtocolError,
    ack_frame,
    crc16_ccitt_false,
    decode_frame,
    encode_frame,
    next_seq,
    parse_ack,
    parse_setpoint,
    seq_is_newer,
    setpoint_frame,
    sync_frame,
    vent_frame,
)


def _crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE straight from its definition, one bit at a time (independent of the table)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def _frames(rng, count, n=2):
    frames = []
    for k in range(count):
        kind = k % 4
        seq = int(rng.integers(0, 1 << 16))
        if kind == 0:
            frames.append(setpoint_frame(seq, rng.uniform(-200, 200, n))[0])
        elif kind == 1:
            frames.append(ack_frame(seq, BoardStatus(int(rng.integers(0, 32))), rng.uniform(-200, 200, n)))
        else:
            frames.append(vent_frame(seq) if kind == 2 else sync_frame(seq))
    return frames


def test_crc_check_value_and_residue():
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogue's check value
    assert crc16_ccitt_false(b"") == 0xFFFF
    rng = np.random.default_rng(1)
    for _ in range(50):
        data = rng.integers(0, 256, int(rng.integers(1, 70)), dtype=np.uint8).tobytes()
        assert crc16_ccitt_false(data) == _crc_bitwise(data)
    wire = encode_frame(setpoint_frame(7, [1.0, 2.0])[0])
    assert crc16_ccitt_false(wire[1:]) == 0  # CRC sent MSB first: LEN…CRC has residue 0


def test_setpoint_byte_layout():
    frame, clamped = setpoint_frame(0x0102, [1.0, -1.0])
    wire = encode_frame(frame)
    body = bytes([0x04, 0x01, 0x02, 0x01, 0x0A, 0x00, 0xF6, 0xFF])  # LEN, TYPE, SEQ LE, +10, -10 counts LE
    assert wire == bytes([0xA5]) + body + _crc_bitwise(body).to_bytes(2, "big")
    assert not clamped.any()


@pytest.mark.parametrize("seq", [0, 1, 0x7FFF, 0xFFFF])
def test_round_trip_every_type(seq):
    rng = np.random.default_rng(seq)
    u = rng.uniform(-PRESSURE_RANGE_HPA, PRESSURE_RANGE_HPA, 3)
    sp, _ = setpoint_frame(seq, u)
    got = decode_frame(encode_frame(sp))
    assert got == sp
    # Fixed point: 0.1 hPa counts, rounded to nearest → error ≤ half a count.
    np.testing.assert_allclose(parse_setpoint(got, 3), u, atol=0.5 / COUNTS_PER_HPA + 1e-12)
    for frame in (vent_frame(seq), sync_frame(seq)):
        assert decode_frame(encode_frame(frame)) == frame
    measured = np.array([12.34, np.nan, -0.05])
    ack = parse_ack(decode_frame(encode_frame(ack_frame(seq, BoardStatus.CLAMPED | BoardStatus.WATCHDOG, measured))), 3)
    assert ack.seq == seq and ack.status == BoardStatus.CLAMPED | BoardStatus.WATCHDOG
    np.testing.assert_allclose(ack.measured, [12.3, np.nan, -0.0], atol=1e-12)  # NaN = not available


def test_fixed_point_range_and_non_finite():
    frame, clamped = setpoint_frame(0, [5000.0, -5000.0, 3276.7])
    np.testing.assert_array_equal(clamped, [True, True, False])
    np.testing.assert_allclose(parse_setpoint(frame, 3), [3276.7, -3276.7, 3276.7], atol=1e-9)
    for bad in ([np.nan, 0.0], [0.0, np.inf]):
        with pytest.raises(NonFiniteCommandError):
            setpoint_frame(0, bad)
    with pytest.raises(ProtocolError, match=rf"1 … {MAX_SEGMENTS} pressures, got {MAX_SEGMENTS + 1}"):
        setpoint_frame(0, np.zeros(MAX_SEGMENTS + 1))
    reserved = Frame(MsgType.SETPOINT, 0, (-32768).to_bytes(2, "little", signed=True) * 2)
    with pytest.raises(ProtocolError, match="reserved value -32768"):
        parse_setpoint(reserved, 2)
    with pytest.raises(ProtocolError, match="SETPOINT carries 2 pressures, this board drives 3"):
        parse_setpoint(setpoint_frame(0, [1.0, 2.0])[0], 3)


def test_frame_validation_messages():
    with pytest.raises(ProtocolError, match=r"seq must be an int in \[0, 65535\], got 65536"):
        Frame(MsgType.VENT, 65536)
    with pytest.raises(ProtocolError, match="unknown message type 7"):
        Frame(7, 0)
    with pytest.raises(ProtocolError, match="a VENT payload of 2 bytes is invalid"):
        Frame(MsgType.VENT, 0, b"\x00\x00")
    wire = bytearray(encode_frame(vent_frame(3)))
    wire[-1] ^= 0x01
    with pytest.raises(ProtocolError, match="CRC mismatch"):
        decode_frame(bytes(wire))
    with pytest.raises(ProtocolError, match="LEN = 0 needs 7 bytes, got 8"):
        decode_frame(encode_frame(vent_frame(3)) + b"\x00")


def test_sequence_arithmetic_wraps():
    assert next_seq(0xFFFF) == 0
    assert seq_is_newer(0, 0xFFFF) and seq_is_newer(0x7FFE, 0xFFFF)
    assert not seq_is_newer(0xFFFF, 0) and not seq_is_newer(5, 5)
    assert not seq_is_newer(0x8000 + 5, 5)  # half the ring away counts as old


def test_decoder_concatenated_and_byte_by_byte():
    frames = _frames(np.random.default_rng(2), 40)
    stream = b"".join(encode_frame(f) for f in frames)
    dec = FrameDecoder()
    assert dec.feed(stream) == frames
    dec2 = FrameDecoder()
    got = [f for i in range(len(stream)) for f in dec2.feed(stream[i : i + 1])]
    assert got == frames
    assert dec2.stats.crc_errors == dec2.stats.header_errors == dec2.stats.discarded_bytes == 0


def test_decoder_recovers_from_truncated_frame():
    a, b = (encode_frame(setpoint_frame(s, [10.0 * s, -1.0])[0]) for s in (1, 2))
    dec = FrameDecoder()
    assert dec.feed(a[:6]) == [] and dec.pending == 6  # waits for the rest
    got = dec.feed(b)  # the rest never comes: the truncated frame is dropped, b is found
    assert [f.seq for f in got] == [2]
    assert dec.stats.crc_errors == 1 and dec.pending == 0


def test_decoder_abandons_incomplete_frame_after_gap():
    a, b = (encode_frame(setpoint_frame(s, [1.0, 2.0])[0]) for s in (1, 2))
    dec = FrameDecoder(gap_s=0.005)
    assert dec.feed(a[:-3], t=1.000) == []
    assert dec.feed(b"", t=1.004) == [] and dec.pending == len(a) - 3  # within the gap: still waiting
    assert dec.feed(b"", t=1.0051) == [] and dec.pending == 0  # gap passed: abandoned
    assert dec.stats.truncated == 1
    assert [f.seq for f in dec.feed(b, t=1.2)] == [2]
    with pytest.raises(ValueError, match="gap_s must be a finite time > 0 s, got 0"):
        FrameDecoder(gap_s=0)


def test_decoder_every_single_bit_error_is_caught():
    good = encode_frame(setpoint_frame(42, [55.5, -66.6])[0])
    nxt = encode_frame(vent_frame(43))
    for bit in range(8 * len(good)):
        bad = bytearray(good)
        bad[bit // 8] ^= 1 << (bit % 8)
        dec = FrameDecoder(gap_s=0.005)
        got = dec.feed(bytes(bad) + nxt, t=0.0)
        got += dec.feed(b"", t=0.006)  # a corrupted LEN may wait for more bytes: the gap ends it
        assert [f.seq for f in got] == [43], f"bit {bit}"
        errors = dec.stats.crc_errors + dec.stats.header_errors + dec.stats.truncated
        assert errors >= (bit >= 8) and dec.pending == 0  # a flipped START byte is just garbage


def test_decoder_survives_garbage_and_finds_every_frame():
    rng = np.random.default_rng(3)
    frames = _frames(rng, 200)
    chunks = []
    for f in frames:
        chunks.append(rng.integers(0, 256, int(rng.integers(0, 30)), dtype=np.uint8).tobytes())  # START bytes included
        chunks.append(encode_frame(f))
    stream = b"".join(chunks)
    dec = FrameDecoder()
    got = []
    pos = 0
    while pos < len(stream):  # random chunking
        step = int(rng.integers(1, 40))
        got += dec.feed(stream[pos : pos + step])
        pos += step
    assert got == frames
    assert dec.stats.discarded_bytes > 0
    # Pure noise never crashes and, with this seed, yields no false frame.
    noise = FrameDecoder()
    assert noise.feed(rng.integers(0, 256, 20000, dtype=np.uint8).tobytes()) == []
    assert noise.pending < 5 + 64 + 2


def test_decoder_passes_duplicates_and_order_through():
    a, b = (encode_frame(vent_frame(s)) for s in (5, 4))
    assert [f.seq for f in FrameDecoder().feed(a + a + b)] == [5, 5, 4]  # dedup/ordering is the link's job


def test_pressure_limits():
    lim = PressureLimits.of(2, -150, [150, 100])
    u, clipped = lim.clamp([200.0, 50.0])
    np.testing.assert_array_equal(u, [150.0, 50.0])
    np.testing.assert_array_equal(clipped, [True, False])
    with pytest.raises(ValueError, match=r"segment 0 must satisfy .* got u_min=10.0, u_max=5.0"):
        PressureLimits.of(1, 10, 5)
    with pytest.raises(ValueError, match="got u_min=-4000.0"):
        PressureLimits.of(1, -4000, 5)
    with pytest.raises(ValueError, match=r"one value per segment \(2\)"):
        PressureLimits.of(2, [-1, -1, -1], 1)
    with pytest.raises(NonFiniteCommandError):
        lim.clamp([np.nan, 0.0])
