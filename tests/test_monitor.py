"""The laptop's safe-action state machine: each flag's action, the hold → vent timing, latching."""

import numpy as np
import pytest

from closedloop.monitor import SafeAction, SafetyFlags, SafetyMonitor

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


def test_admitted_commands_get_the_same_decisions_and_are_kept_without_a_copy():
    checked, trusted = SafetyMonitor(2, hold_s=0.5), SafetyMonitor(2, hold_s=0.5)
    for k, (flags, u) in enumerate(SEQUENCE):
        a = checked.step(k * DT, u, flags)
        b = trusted.step(k * DT, None if u is None else u.copy(), flags, admitted=True)
        assert (a.action, a.reasons) == (b.action, b.reasons), k
        np.testing.assert_array_equal(a.u, b.u)
    u = U.copy()
    d = SafetyMonitor(2).step(0.0, u, admitted=True)
    assert d.action is SafeAction.RUN and d.u is u  # trusted: not copied
    d = SafetyMonitor(2).step(0.0, u)
    assert d.u is not u and np.array_equal(d.u, u)  # checked: the monitor keeps its own copy
