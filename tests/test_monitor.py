"""The laptop's safe-action state machine: each flag's action, the hold → vent timing, latching."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from closedloop.monitor import ACTIONS, NOT_STEPPED, BatchSafetyMonitor, SafeAction, SafetyFlags, SafetyMonitor

U = np.array([40.0, -20.0])
DT = 0.1  # the 10 Hz loop


def _run(monitor, t0, cycles, u=U, flags=SafetyFlags()):
    return [monitor.step(t0 + k * DT, u, flags) for k in range(cycles)]


def test_runs_the_command_when_nothing_is_wrong():
    m = SafetyMonitor(2, hold_s=0.5)
    (d,) = _run(m, 0.0, 1)
    assert d.action is SafeAction.RUN and d.reasons == ()
    np.testing.assert_array_equal(d.u, U)


@pytest.mark.parametrize("flag", ["interrupted", "link_lost"])
def test_interrupt_and_link_loss_vent_in_the_same_cycle_and_latch(flag):
    m = SafetyMonitor(2, hold_s=0.5)
    _run(m, 0.0, 3)
    d = m.step(0.3, U, SafetyFlags(**{flag: True}))
    assert d.action is SafeAction.VENT and d.reasons == (flag,)
    np.testing.assert_array_equal(d.u, [0.0, 0.0])
    d = m.step(0.4, U)  # the flag cleared, the vent stays
    assert d.action is SafeAction.VENT and d.reasons == (flag,) and m.vent_latched
    m.reset()
    assert m.step(0.5, U).action is SafeAction.RUN


@pytest.mark.parametrize(
    "flags, u_cmd",
    [(SafetyFlags(perception_stale=True), U + 5), (SafetyFlags(command_nonfinite=True), None), (SafetyFlags(), [np.nan, 0.0])],
)
def test_stale_perception_or_bad_command_hold_then_vent(flags, u_cmd):
    m = SafetyMonitor(2, hold_s=0.25)
    _run(m, 0.0, 2)  # last RUN command: U at t = 0.1
    held = [m.step(0.2 + k * DT, u_cmd, flags) for k in range(5)]  # t = 0.2 … 0.6
    # Hold starts at 0.2; 0.2 + 0.25 = 0.45 → cycles at 0.2, 0.3, 0.4 hold, 0.5 vents.
    assert [d.action for d in held] == [SafeAction.HOLD] * 3 + [SafeAction.VENT] * 2
    for d in held[:3]:
        np.testing.assert_array_equal(d.u, U)  # the last command that ran, not the new one
    np.testing.assert_array_equal(held[3].u, [0.0, 0.0])
    expected = flags.raised() or ("command_nonfinite",)
    assert held[0].reasons == expected


def test_short_hold_returns_to_run_and_restarts_its_timer():
    m = SafetyMonitor(2, hold_s=0.25)
    _run(m, 0.0, 1)
    stale = SafetyFlags(perception_stale=True)
    assert [m.step(t, U, stale).action for t in (0.1, 0.2)] == [SafeAction.HOLD] * 2
    assert m.step(0.3, U + 1).action is SafeAction.RUN
    assert [m.step(t, U, stale).action for t in (0.4, 0.5, 0.6)] == [SafeAction.HOLD] * 3  # a full hold again
    assert m.step(0.7, U, stale).action is SafeAction.VENT
    np.testing.assert_array_equal(m.step(0.65 + 0.1, U, stale).u, [0.0, 0.0])


def test_nothing_to_hold_vents_at_once_and_priorities():
    m = SafetyMonitor(2)
    d = m.step(0.0, U, SafetyFlags(perception_stale=True))
    assert d.action is SafeAction.VENT  # no command ever ran
    m2 = SafetyMonitor(2)
    _run(m2, 0.0, 1)
    d = m2.step(0.1, None, SafetyFlags(perception_stale=True, link_lost=True, interrupted=True))
    assert d.action is SafeAction.VENT
    assert d.reasons == ("perception_stale", "link_lost", "command_nonfinite", "interrupted")


def test_reset_refused_while_flagged_and_validation():
    m = SafetyMonitor(2)
    m.step(0.0, U, SafetyFlags(interrupted=True))
    with pytest.raises(ValueError, match="cannot clear the vent while interrupted is raised"):
        m.reset(SafetyFlags(interrupted=True))
    with pytest.raises(ValueError, match="t must be finite and non-decreasing, got -1"):
        m.step(-1.0, U)
    with pytest.raises(ValueError, match=r"u_cmd must have shape \(2,\), got \(3,\)"):
        m.step(1.0, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="hold_s must be a finite time >= 0 s"):
        SafetyMonitor(2, hold_s=-0.1)


def test_restart_starts_the_clock_again_and_clears_hold_and_vent():
    m = SafetyMonitor(2, hold_s=0.5)
    _run(m, 0.0, 3)
    m.step(0.3, U, SafetyFlags(link_lost=True))
    assert m.vent_latched
    m.restart()
    assert not m.vent_latched
    # the clock starts again at the new run's first time, and nothing was sent in this run: a stale
    # estimate vents at once instead of holding the last run's command
    assert m.step(0.0, U, SafetyFlags(perception_stale=True)).action is SafeAction.VENT
    m.restart()
    (d,) = _run(m, 0.0, 1)
    assert d.action is SafeAction.RUN and np.array_equal(d.u, U)


SEQUENCE = [(SafetyFlags(), U), (SafetyFlags(perception_stale=True), U + 1), (SafetyFlags(), U + 2), (SafetyFlags(), None),
            (SafetyFlags(), U + 3), (SafetyFlags(interrupted=True), U + 4), (SafetyFlags(), U + 5)]


def test_admitted_commands_get_the_same_decisions_and_the_monitor_keeps_its_own_copy():
    checked, trusted = SafetyMonitor(2, hold_s=0.5), SafetyMonitor(2, hold_s=0.5)
    for k, (flags, u) in enumerate(SEQUENCE):
        a = checked.step(k * DT, u, flags)
        b = trusted.step(k * DT, None if u is None else u.copy(), flags, admitted=True)
        assert (a.action, a.reasons) == (b.action, b.reasons), k
        np.testing.assert_array_equal(a.u, b.u)
    for admitted in (True, False):
        u, monitor = U.copy(), SafetyMonitor(2, hold_s=0.5)
        d = monitor.step(0.0, u, admitted=admitted)
        assert d.action is SafeAction.RUN and d.u is not u and np.array_equal(d.u, U)
        u[:] = 999.0  # the caller's array changes after the call: the hold sends what was sent with RUN
        held = monitor.step(0.1, None)
        assert held.action is SafeAction.HOLD and np.array_equal(held.u, U)


FLAG_CHOICES = (SafetyFlags(), SafetyFlags(), SafetyFlags(), SafetyFlags(perception_stale=True),
                SafetyFlags(command_nonfinite=True), SafetyFlags(filter_fault=True), SafetyFlags(interrupted=True),
                SafetyFlags(link_lost=True))


@settings(max_examples=60, deadline=None)
@given(events=st.lists(st.tuples(st.integers(0, 2), st.integers(0, 4), st.sampled_from(FLAG_CHOICES),
                                 st.booleans(), st.integers(0, 3)), min_size=1, max_size=60),
       hold_s=st.sampled_from([0.0, 0.15, 0.3]))
def test_property_batch_monitor_row_b_is_the_monitor_of_run_b(events, hold_s):
    """Each row of a BatchSafetyMonitor decides, bit for bit, what a SafetyMonitor of that run alone decides,
    whatever the other rows do: random commands (refused or admitted), flags, row subsets and restarts."""
    n_sims = 3
    batch = BatchSafetyMonitor(n_sims, 2, hold_s=hold_s)
    alone = [SafetyMonitor(2, hold_s=hold_s) for _ in range(n_sims)]
    clock = [0.0] * n_sims
    for k, (row, u_pick, flags, restart, dt_steps) in enumerate(events):
        if restart and k % 7 == 0:
            batch.restart(np.arange(n_sims) == row)
            alone[row].restart()
        rows = np.ones(n_sims, dtype=bool)
        rows[(row + 1) % n_sims] = k % 3 != 0  # some calls step only some rows
        t = np.array([clock[b] + dt_steps * DT / 2 for b in range(n_sims)])
        u = np.array([U + 10.0 * u_pick + b for b in range(n_sims)])
        admitted = np.array([u_pick != 0] * n_sims)
        fault = np.array([flags.filter_fault if b == row else False for b in range(n_sims)])
        row_flags = [SafetyFlags(**{**vars(flags), "filter_fault": False}) if b == row else SafetyFlags()
                     for b in range(n_sims)]
        got = batch.step(t, u, admitted, fault, rows, row_flags)
        for b in range(n_sims):
            if not rows[b]:
                assert got.action[b] == NOT_STEPPED and got.reasons[b] == () and not got.u[b].any()
                continue
            clock[b] = float(t[b])
            flags_b = row_flags[b] if not fault[b] else SafetyFlags(**{**vars(row_flags[b]), "filter_fault": True})
            want = alone[b].step(float(t[b]), u[b].copy() if admitted[b] else None, flags_b, admitted=True)
            assert (ACTIONS[got.action[b]], got.reasons[b]) == (want.action, want.reasons), (k, b)
            np.testing.assert_array_equal(got.u[b], want.u)
            assert batch.latched[b] == alone[b].vent_latched


def test_batch_monitor_refuses_time_going_back_and_bad_sizes():
    m = BatchSafetyMonitor(2, 2)
    rows, no = np.ones(2, dtype=bool), np.zeros(2, dtype=bool)
    m.step(np.array([1.0, 1.0]), np.zeros((2, 2)), rows, no, rows)
    with pytest.raises(ValueError, match="non-decreasing"):
        m.step(np.array([1.0, 0.5]), np.zeros((2, 2)), rows, no, rows)
    with pytest.raises(ValueError, match="n_sims must be an int >= 1"):
        BatchSafetyMonitor(0, 2)
    with pytest.raises(ValueError, match="hold_s must be a finite time"):
        BatchSafetyMonitor(2, 2, hold_s=math.nan)
