"""Per-run governor figures (controllers.contract.filter_metrics): hand-computed cases."""

import math

import numpy as np
import pytest

from controllers.contract.filter_metrics import governor_figures


def test_deviation_switches_and_timing_by_hand():
    t = np.arange(5) * 0.1
    u_nom = np.zeros((5, 2))
    u = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [-2.0, 3.0], [2.0, 3.0]])
    filter_us = np.array([10.0, 20.0, 30.0, 40.0, 50.0])
    fig = governor_figures(t, u, u_nom, filter_us)
    assert fig["u_dev_max_hPa"] == 3.0
    assert fig["u_dev_rms_hPa"] == pytest.approx(math.sqrt((1 + 1 + 4 + 9 + 4 + 9) / 10))
    # segment 0: + − (0 skipped) − + → 2 changes; segment 1: none; span 0.4 + 0.1 s
    assert fig["switches_per_s"] == pytest.approx(2 / 0.5)
    assert fig["filter_us_median"] == 30.0
    assert fig["filter_us_p99"] == pytest.approx(np.percentile(filter_us, 99))
    assert fig["blocked_s"] == 0.0


def test_blocked_counts_a_held_command_only_while_u_nom_retreats():
    """1 kHz records, calls every 100 ms (NaN filter time between): u_nom rises to 100 hPa, then
    falls to 0; the filter caps u at 60 while rising (not blocked) and keeps it at 60 for
    0.3 s of the fall (blocked while u_nom < 58)."""
    t = np.arange(2000) * 1e-3
    call_times = np.arange(20) * 0.1
    nominal = np.interp(call_times, [0.0, 1.0, 1.9], [0.0, 100.0, 0.0])
    command = np.minimum(nominal, 60.0)
    command[(call_times >= 1.4) & (call_times < 1.75)] = 60.0  # held for calls at 1.4, 1.5, 1.6, 1.7
    index = np.minimum((t / 0.1).astype(int), 19)
    u_nom, u = nominal[index][:, None], command[index][:, None]
    filter_us = np.where(np.arange(2000) % 100 == 0, 5.0, np.nan)
    fig = governor_figures(t, u, u_nom, filter_us)
    # u_nom at 1.4…1.7 s: 55.6, 44.4, 33.3, 22.2 hPa: all more than 2 hPa below u = 60.
    assert fig["blocked_s"] == pytest.approx(0.4)
    assert fig["blocked_longest_s"] == pytest.approx(0.4)
    assert fig["filter_us_median"] == 5.0
    mirrored = governor_figures(t, -u, -u_nom, filter_us)
    assert mirrored["blocked_s"] == pytest.approx(0.4)
    follows = governor_figures(t, u_nom, u_nom, filter_us)
    assert follows["blocked_s"] == 0.0 and follows["u_dev_max_hPa"] == 0.0


def test_bad_inputs_are_refused():
    t = np.arange(3) * 0.1
    good = np.zeros((3, 2))
    with pytest.raises(ValueError, match="strictly increasing"):
        governor_figures(t[::-1], good, good, np.zeros(3))
    with pytest.raises(ValueError, match=r"u and u_nom must both have shape \(3, N\)"):
        governor_figures(t, good, np.zeros((3, 1)), np.zeros(3))
    with pytest.raises(ValueError, match="filter_us must have shape"):
        governor_figures(t, good, good, np.zeros(2))
    with pytest.raises(ValueError, match="must be finite"):
        governor_figures(t, np.full((3, 2), np.nan), good, np.zeros(3))
