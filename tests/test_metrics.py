"""Chatter figures (softcbf_mj.outputs.metrics) on synthetic commands with known answers."""

import numpy as np
import pytest

from softcbf_mj.outputs.metrics import (
    CHATTER_THRESHOLD_HPA,
    HF_CUTOFF_HZ,
    RunningFigures,
    chatter_per_s,
    high_frequency_fraction,
    run_figures,
    switches_per_s,
)

DT = 1e-3
T = np.arange(10_000) * DT  # 10 s at 1 kHz


def _paper_nominal() -> np.ndarray:
    return np.column_stack([80.0 * np.sin(2 * np.pi * 0.01 * T)] * 2)


def _alternating() -> tuple[np.ndarray, np.ndarray]:
    """u alternates every step between u_nom and u_nom + (58.7, −360.4) hPa (High at t = 25 s)."""
    u_nom = _paper_nominal()
    u = u_nom.copy()
    u[1::2] += [58.7, -360.4]
    return u, u_nom


def test_a_command_alternating_every_step_switches_once_per_step_and_segment():
    u, u_nom = _alternating()
    duration = len(T) * DT
    # 9999 step-to-step changes per segment in 10 s
    assert chatter_per_s(u, u_nom, duration) == pytest.approx(2 * 9999 / 10.0)
    assert switches_per_s(u, u_nom, duration) == pytest.approx(9999 / 10.0)
    assert high_frequency_fraction(u, DT) > 0.9


def test_one_segment_alternating_half_the_time_counts_only_its_switches():
    u_nom = _paper_nominal()
    u = u_nom.copy()
    u[5000::2, 0] += 20.0  # segment 1 alternates in the second half only
    assert chatter_per_s(u, u_nom, 10.0) == pytest.approx(5000 / 10.0)  # on at step 5000, then every step


def test_a_sign_reversal_counts_once():
    u_nom = np.zeros((4, 1))
    u = np.array([[0.0], [5.0], [-5.0], [-5.0]])
    assert chatter_per_s(u, u_nom, 1.0) == 2.0  # on (0 → +), reversal (+ → −)
    assert switches_per_s(u, u_nom, 1.0) == 1.0  # on once, never off


def test_a_smooth_command_and_a_correction_that_stays_on_do_not_chatter():
    u_nom = _paper_nominal()
    assert chatter_per_s(u_nom, u_nom, 10.0) == 0.0
    assert high_frequency_fraction(u_nom, DT) < 1e-6  # 1.5e-7: the mirror extension leaves no leakage
    u = u_nom.copy()
    u[3000:] -= 40.0 * (1 - np.exp(-(T[3000:] - T[3000]) / 0.5))[:, None]  # one smooth correction, on at 3 s
    u[3000] = u_nom[3000]
    assert chatter_per_s(u, u_nom, 10.0) == pytest.approx(2 / 10.0)  # both segments turn on once
    assert high_frequency_fraction(u, DT) < 1e-3


def test_corrections_below_the_threshold_are_ignored():
    u_nom = _paper_nominal()
    u = u_nom + 0.5 * CHATTER_THRESHOLD_HPA * np.where(np.arange(len(T)) % 2, 1.0, -1.0)[:, None]
    assert chatter_per_s(u, u_nom, 10.0) == 0.0
    assert chatter_per_s(u, u_nom, 10.0, threshold_hPa=0.0) == pytest.approx(2 * 9999 / 10.0)


def test_high_frequency_fraction_of_a_sum_of_sines_is_its_power_share():
    # 1 Hz at amplitude 3 and 50 Hz at amplitude 4: variances 4.5 and 8, whole periods in 10 s
    u = (3 * np.sin(2 * np.pi * 1.0 * T) + 4 * np.sin(2 * np.pi * 50.0 * T))[:, None]
    # the mirror extension puts a kink at the ends of a sine: its leakage shifts the share by 1.7e-4
    assert high_frequency_fraction(u, DT) == pytest.approx(8 / 12.5, abs=5e-4)
    assert high_frequency_fraction(u, DT, cutoff_hz=60.0) == pytest.approx(0.0, abs=5e-4)
    assert high_frequency_fraction(np.ones((100, 2)), DT) is None
    assert high_frequency_fraction(u, 0.1, cutoff_hz=HF_CUTOFF_HZ) is None  # cut-off at Nyquist


def test_bad_arguments_name_the_parameter():
    u, u_nom = _alternating()
    with pytest.raises(ValueError, match="duration must be > 0 s, got 0"):
        chatter_per_s(u, u_nom, 0.0)
    with pytest.raises(ValueError, match="threshold_hPa must be >= 0 hPa, got -1"):
        chatter_per_s(u, u_nom, 1.0, threshold_hPa=-1.0)
    with pytest.raises(ValueError, match="cutoff_hz must be > 0 Hz, got 0"):
        high_frequency_fraction(u, DT, cutoff_hz=0.0)


def test_run_figures_report_the_chatter_of_the_log():
    u, u_nom = _alternating()
    n = len(T)
    log = {"t": T, "u": u, "u_nom": u_nom, "filter_us": np.full(n, 30.0), "rho_pred": np.ones(n), "rho_meas": np.ones(n),
           "contact_force": np.zeros((n, 1)), "infeasible": np.zeros(n, bool), "recovery": np.zeros(n, bool),
           "active": np.zeros((n, 1), bool)}
    row = run_figures(log, DT, True, 1.0)
    assert row["chatter_per_s"] == pytest.approx(2 * 9999 / 10.0)
    assert row["switches_per_s"] == pytest.approx(9999 / 10.0)
    assert row["u_hf_fraction"] > 0.9
    assert row["u_dev_max_hPa"] == pytest.approx(360.4)
    assert row["u_dev_rms_hPa"] == pytest.approx(np.sqrt((58.7**2 + 360.4**2) / 4), rel=1e-9)


def _numpy_figures(blocks, n_sims: int, f_max, force_floor: float) -> dict[str, np.ndarray]:
    """The running figures' definitions (RunningFigures' docstring) as numpy expressions over whole blocks: the
    reference the compiled update must equal bit for bit (the numpy update it replaced)."""
    out = {"rows": np.zeros(n_sims, dtype=int), "rho_min_pred": np.full(n_sims, np.nan),
           "rho_min_meas": np.full(n_sims, np.inf), "force_max_N": np.full(n_sims, force_floor),
           "violations": np.zeros(n_sims, dtype=int), "infeasible": np.zeros(n_sims, dtype=int),
           "refused": np.zeros(n_sims, dtype=int), "vented": np.zeros(n_sims, dtype=bool),
           "u_peak_abs_hPa": np.zeros(n_sims), "force_excess": np.zeros(n_sims)}
    for margin, forces, u, rho_pred, infeasible, action, rows in blocks:
        force, peak = np.max(forces, axis=-1), np.max(np.abs(u), axis=-1)
        excess = np.max(np.maximum(forces - (f_max or 1.0), 0.0), axis=-1) / (f_max or 1.0)
        if rows is not None:
            margin, force, peak = np.where(rows, margin, np.inf), np.where(rows, force, -np.inf), np.where(rows, peak, 0.0)
            rho_pred, infeasible = np.where(rows, rho_pred, np.nan), infeasible & rows
            action, excess = (None if action is None else np.where(rows, action, 0)), np.where(rows, excess, 0.0)
            out["rows"] += np.count_nonzero(rows, axis=0)
        else:
            out["rows"] += len(margin)
        out["rho_min_pred"] = np.fmin(out["rho_min_pred"], np.fmin.reduce(rho_pred, axis=0))
        out["rho_min_meas"] = np.minimum(out["rho_min_meas"], np.min(margin, axis=0))
        out["force_max_N"] = np.maximum(out["force_max_N"], np.max(force, axis=0))
        out["violations"] += np.count_nonzero(margin < 0.0, axis=0)
        out["infeasible"] += np.count_nonzero(infeasible, axis=0)
        if action is not None:
            out["refused"] += np.count_nonzero(action != 0, axis=0)
            out["vented"] |= np.any(action == 2, axis=0)
        out["u_peak_abs_hPa"] = np.fmax(out["u_peak_abs_hPa"], np.max(peak, axis=0))
        if f_max is not None:
            out["force_excess"] += np.sum(excess, axis=0)
    return out


@pytest.mark.parametrize("block", [1, 37])
@pytest.mark.parametrize("f_max", [None, 0.5])
def test_running_figures_equal_their_numpy_definitions(block, f_max):
    """The compiled update against the figures' numpy definitions, bit for bit: blocks of 1 and 37 rows, some
    rows masked, NaN predictions and forces, signed commands, refused and vented rows."""
    rng = np.random.default_rng(block)
    n_sims, n_facets, n_seg = 7, 3, 2
    blocks = []
    for k in range(6):
        margin = rng.normal(0.2, 0.3, (block, n_sims))
        forces = rng.exponential(0.3, (block, n_sims, n_facets))
        forces[rng.random(forces.shape) < 0.05] = np.nan
        rho_pred = np.where(rng.random((block, n_sims)) < 0.3, np.nan, rng.normal(0.2, 0.3, (block, n_sims)))
        u = rng.normal(0.0, 100.0, (block, n_sims, n_seg))
        infeasible = rng.random((block, n_sims)) < 0.2
        action = rng.choice(np.array([0, 0, 0, 1, 2], dtype=np.int8), (block, n_sims))
        rows = None if k % 2 else rng.random((block, n_sims)) < 0.7
        blocks.append((margin, forces, u, rho_pred, infeasible, None if k == 3 else action, rows))
    running = RunningFigures(n_sims, DT, f_max=f_max, force_floor=0.0)
    for blk in blocks:
        running.update(*blk)
    want = _numpy_figures(blocks, n_sims, f_max, 0.0)
    for name, value in want.items():
        np.testing.assert_array_equal(getattr(running, name), value, err_msg=name)
        assert getattr(running, name).dtype == value.dtype
