"""Valve-board logic without a transport: clamping, ACKs, duplicates, order, watchdog, the pressure model."""

import math

import numpy as np
import pytest

from hardware.board import FirstOrderPressure, ValveBoard
from hardware.protocol import (
    BoardStatus,
    Frame,
    FrameDecoder,
    MsgType,
    encode_frame,
    parse_ack,
    setpoint_frame,
    sync_frame,
    vent_frame,
)


def _sp(seq, u):
    return encode_frame(setpoint_frame(seq, u)[0])


def _acks(replies, n=2):
    return [parse_ack(f, n) for f in FrameDecoder().feed(b"".join(replies))]


def _board(**kw):
    kw.setdefault("plant_hook", FirstOrderPressure(2, tau_s=0.0))
    return ValveBoard(2, -150.0, 150.0, **kw)


def test_boot_is_vented_and_accepts_any_seq():
    board = _board()
    np.testing.assert_array_equal(board.output, [0.0, 0.0])
    (ack,) = _acks(board.step(0.0, encode_frame(sync_frame(40000))))
    assert ack.seq == 40000 and ack.status == BoardStatus.VENTED
    (ack,) = _acks(board.step(0.01, _sp(40001, [10.0, -20.0])))
    assert ack.status == BoardStatus.NONE
    np.testing.assert_allclose(ack.measured, [10.0, -20.0])  # ideal valves (τ = 0)


def test_clamps_to_its_own_limits_and_logs_every_change():
    board = _board()
    (ack,) = _acks(board.step(0.5, _sp(1, [200.0, -10.0])))
    assert ack.status == BoardStatus.CLAMPED
    np.testing.assert_allclose(ack.measured, [150.0, -10.0])
    board.step(0.6, _sp(2, [-400.0, 5.0]))
    t, u = board.applied_arrays()
    np.testing.assert_array_equal(t, [0.5, 0.6])
    np.testing.assert_allclose(u, [[150.0, -10.0], [-150.0, 5.0]])
    assert [a.reason for a in board.applied()] == ["setpoint", "setpoint"]
    assert board.stats.clamped == 2


def test_duplicates_acked_not_reapplied_and_old_frames_ignored():
    board = _board()
    frame = _sp(7, [30.0, 40.0])
    board.step(0.0, frame)
    (dup,) = _acks(board.step(0.05, frame))
    assert dup.seq == 7 and dup.status == BoardStatus.DUPLICATE
    assert board.step(0.06, _sp(6, [99.0, 99.0])) == []  # out of order: no ACK, not applied
    assert len(board.applied()) == 1 and board.stats.duplicates == 1 and board.stats.stale_frames == 1
    np.testing.assert_allclose(board.output, [30.0, 40.0])
    # Wrap-around: 65535 → 0 is newer.
    board.step(0.07, encode_frame(sync_frame(65535)))
    (ack,) = _acks(board.step(0.08, _sp(0, [1.0, 2.0])))
    assert ack.seq == 0 and ack.status == BoardStatus.NONE
    np.testing.assert_allclose(board.output, [1.0, 2.0])


def test_watchdog_vents_after_silence_and_reports_once():
    board = _board(watchdog_s=0.15)
    board.step(1.0, _sp(1, [80.0, 80.0]))
    board.step(1.15, b"")  # exactly the deadline: still holding
    np.testing.assert_allclose(board.output, [80.0, 80.0])
    board.step(1.151, b"")
    np.testing.assert_array_equal(board.output, [0.0, 0.0])
    last = board.applied()[-1]
    assert (last.t, last.u, last.reason) == (1.151, (0.0, 0.0), "watchdog")
    board.step(1.2, b"")  # no second vent
    assert board.stats.watchdog_vents == 1 and len(board.applied()) == 2
    (ack,) = _acks(board.step(2.0, _sp(2, [10.0, 10.0])))
    assert ack.status == BoardStatus.WATCHDOG  # latched until reported; the new setpoint is applied
    (ack,) = _acks(board.step(2.05, _sp(3, [10.0, 10.0])))
    assert ack.status == BoardStatus.NONE


def test_watchdog_not_fed_by_duplicates():
    board = _board(watchdog_s=0.1)
    frame = _sp(1, [50.0, 50.0])
    board.step(0.0, frame)
    board.step(0.08, frame)
    board.step(0.101, b"")
    assert board.vented and board.applied()[-1].reason == "watchdog"


def test_vent_and_rejected_frames():
    board = _board()
    board.step(0.0, _sp(1, [60.0, 60.0]))
    (ack,) = _acks(board.step(0.1, encode_frame(vent_frame(2))))
    assert ack.status == BoardStatus.VENTED
    assert board.applied()[-1].reason == "vent" and board.applied()[-1].u == (0.0, 0.0)
    (ack,) = _acks(board.step(0.2, _sp(3, [1.0, 2.0, 3.0])))  # wrong N
    assert ack.status == BoardStatus.REJECTED | BoardStatus.VENTED
    reserved = Frame(MsgType.SETPOINT, 3, (-32768).to_bytes(2, "little", signed=True) * 2)
    (ack,) = _acks(board.step(0.3, encode_frame(reserved)))  # SEQ 3 was not taken by the rejected frame
    assert BoardStatus.REJECTED in ack.status and board.stats.rejected == 2
    assert len(board.applied()) == 2


def test_garbage_and_corruption_get_no_reply():
    board = _board()
    rng = np.random.default_rng(0)
    assert board.step(0.0, rng.integers(0, 256, 5000, dtype=np.uint8).tobytes()) == []
    bad = bytearray(_sp(1, [10.0, 10.0]))
    bad[6] ^= 0x10
    assert board.step(0.1, bytes(bad)) == []
    assert board.step(0.2, encode_frame(Frame(MsgType.ACK, 1, b"\x00" * 5))) == []  # boards ignore ACKs
    assert board.applied() == [] and board.decoder.stats.crc_errors >= 1
    assert board.stats.unexpected_frames == 1
    # and then a good frame is still understood
    (ack,) = _acks(board.step(0.3, _sp(2, [10.0, 10.0])))
    assert ack.seq == 2


def test_first_order_pressure_exact():
    plant = FirstOrderPressure(2, tau_s=0.05)
    plant.apply(np.array([100.0, -40.0]), 0.0)
    np.testing.assert_allclose(plant.measured(0.05), [100 * (1 - math.exp(-1)), -40 * (1 - math.exp(-1))], rtol=1e-12)
    plant.apply(np.zeros(2), 0.05)
    p1 = 100 * (1 - math.exp(-1))
    np.testing.assert_allclose(plant.measured(0.15)[0], p1 * math.exp(-2), rtol=1e-12)
    # The ACK reports it in 0.1 hPa counts.
    board = ValveBoard(1, -150, 150, plant_hook=FirstOrderPressure(1, tau_s=0.05))
    board.step(0.0, _sp(1, [100.0]))
    (ack,) = _acks(board.step(0.05, encode_frame(sync_frame(1))), n=1)
    np.testing.assert_allclose(ack.measured, [100 * (1 - math.exp(-1))], atol=0.05)


def test_validation_messages():
    with pytest.raises(ValueError, match="watchdog_s must be a finite time > 0 s, got 0"):
        ValveBoard(2, -150, 150, watchdog_s=0)
    with pytest.raises(ValueError, match="n_segments must be an int >= 1, got 0"):
        ValveBoard(0, -150, 150)
    with pytest.raises(ValueError, match="tau_s must be a finite time constant >= 0 s, got -1"):
        FirstOrderPressure(2, tau_s=-1)
