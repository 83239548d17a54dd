"""The gain estimate with a noisy camera (`controllers.governors.gain_estimate`, "averaged frames"; c-erg's `gain_window_s`)
and the camera's Δ measured from a recorded run (`controllers.governors.camera_delta`, `softcbf calibrate-camera`)."""

import math

import numpy as np
import pytest

from controllers.governors.energy_governor import ContactEnergyGovernor, new_state, step
from controllers.governors.gain_estimate import ROUNDING, GainEstimator, RestWindow, student_t_quantile, student_t_tail
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext
from controllers.governors.camera_delta import measure, measure_folder, report_lines
from softcbf.cli import main

ROBOT = reference_robot()
K, A, D = ROBOT.array("stiffness"), ROBOT.array("gains") / ROBOT.array("stiffness"), ROBOT.array("damping")
SIGMA = 1e-3  # rad: the frame noise of camera_loop with pixel noise 8 (0.7–1.1e-3 rad measured)
RECOMMENDED_REST = {"gain_lo_ratio": 0.9, "gain_hi_ratio": 1.1, "gain_estimate": True, "gain_noise_rad": 1.5e-3,
                    "gain_rest_rad_s": 3e-3, "gain_rest_s": 0.2}


def test_student_t_quantile_matches_scipy_and_its_tail():
    """The t quantile (closed-form tail, bisection) against scipy's, for small and large degrees of freedom, and
    rounded to the safe side: its tail is at most the risk asked."""
    stats = pytest.importorskip("scipy.stats")
    for dof in (1, 2, 3, 4, 7, 8, 30, 200):
        for risk in (0.5, 0.05, 1e-3, 1e-6, 1e-9):
            t = student_t_quantile(risk, dof)
            assert t == pytest.approx(stats.t.ppf(1.0 - risk / 2.0, dof), rel=1e-7)
            assert 2.0 * stats.t.sf(t, dof) <= risk
            assert student_t_tail(t, dof) == pytest.approx(risk, rel=1e-6)
    with pytest.raises(ValueError, match="risk must lie in"):
        student_t_quantile(0.0, 5)


def test_the_window_fit_is_numpys_line_and_pools_its_residuals():
    """`RestWindow.fit` against numpy's polyfit (brute force): the mean, the slope and the residuals' sum of squares;
    a repeated capture time is ignored; the pool adds n − 2 degrees of freedom per window."""
    rng = np.random.default_rng(3)
    window = RestWindow(2)
    times = np.sort(rng.uniform(0.0, 1.0, 9))
    frames = np.array([0.3, -0.2]) + np.outer(times, [0.01, -0.02]) + rng.normal(0.0, SIGMA, (9, 2))
    for t, q in zip(times, frames):
        assert window.add(t, q)
    assert not window.add(times[-1], frames[-1] + 1.0)
    mean, slope, rss, n = window.fit()
    for i in range(2):
        coefficients, residual, *_ = np.polyfit(times, frames[:, i], 1, full=True)
        assert slope[i] == pytest.approx(coefficients[0], rel=1e-9) and rss[i] == pytest.approx(residual[0], rel=1e-9)
        assert mean[i] == pytest.approx(frames[:, i].mean(), rel=1e-12)
    window.pool(rss, n)
    window.pool(rss, n)
    assert window.pooled_dof == 14
    np.testing.assert_allclose(window.scatter_bound(4, 1e-3),
                               student_t_quantile(1e-3, 14) * np.sqrt(rss / 7.0) / 2.0, rtol=1e-12)
    np.testing.assert_allclose(window.scatter_bound(4, 1e-3, sigma=1e-3), 3.2905267 * 1e-3 / 2.0, rtol=1e-7)


def test_the_scatter_bound_covers_the_mean_noise_at_its_risk():
    """Brute force over 4000 simulated windows of 6–12 frames (Gaussian noise, σ 1e-3 and 2e-3 rad, a slow drift):
    the mean's noise exceeds ε in about `risk` of the segment-samples (binomial 5σ band) at risk 0.05, and never at
    risk 1e-6; a bound from the first window's scatter alone (ν = n − 2) holds too, and is the wider."""
    rng = np.random.default_rng(11)
    sigma = np.array([1e-3, 2e-3])
    window, misses, wide, windows = RestWindow(2), 0, 0, 4000
    for w in range(windows):
        n = int(rng.integers(6, 13))
        times = np.sort(rng.uniform(0.0, 0.8, n)) + w
        truth = np.array([0.25, 0.35]) + 1e-3 * (times - w)[:, None]
        for t, q in zip(times, truth + rng.normal(0.0, 1.0, (n, 2)) * sigma):
            window.add(t, q)
        mean, _, rss, n = window.fit()
        window.pool(rss, n)
        error = np.abs(mean - truth.mean(axis=0))
        misses += int(np.sum(error > window.scatter_bound(n, 0.05)))
        wide += int(np.sum(error > window.scatter_bound(n, 1e-6)))
        window.clear()
    cases = 2 * windows
    assert abs(misses - 0.05 * cases) <= 5.0 * math.sqrt(0.05 * 0.95 * cases)
    assert wide == 0


def test_an_averaged_sample_is_trusted_to_delta_plus_its_scatter_bound_and_holds_g_at_the_worst_case():
    """A sample with scatter ε: e = (Δ w + Σ k_i|x_i| ε_i)/|x|²_K, reached by the deviation (Δ + ε_i) sign(k_i x_i),
    which leaves g at the interval's end; without ε the sums are those of a sample without it, bit for bit."""
    p, g, eps = np.full(2, 74.0), 1.02, np.array([1e-3, 2e-3])
    x = A * p
    est = GainEstimator(K, A, D, (0.9, 1.1), 1.5e-3)
    assert est.sample(p, g * x + (1.5e-3 + eps) * np.sign(K * x), scatter=eps)
    want = (1.5e-3 * np.sum(K * np.abs(x)) + np.sum(K * np.abs(x) * eps)) / np.sum(K * x * x)
    assert est.bound == pytest.approx(want + ROUNDING, rel=1e-12)
    lo, hi = est.interval
    assert lo <= g <= hi and lo == pytest.approx(g, abs=1e-9)
    plain, zero = GainEstimator(K, A, D, (0.9, 1.1), 1.5e-3), GainEstimator(K, A, D, (0.9, 1.1), 1.5e-3)
    plain.sample(p, g * x)
    zero.sample(p, g * x, scatter=None)
    assert (plain.interval, plain.bound) == (zero.interval, zero.bound)
    with pytest.raises(ValueError, match="scatter must be a finite"):
        est.sample(p, g * x, scatter=np.array([-1e-3, 0.0]))


def noisy_camera_run(params: dict, true_gain: float, seed: int, duration_s: float = 8.0, u_push: float = 40.0):
    """A c-erg asked for u_push hPa on both segments (the arm at rest out of contact), its estimates from a camera at
    12.8 Hz (20 % of frames dropped, latency 0.03 s, Gaussian noise SIGMA per segment, q̂̇ the frames' difference)
    of an arm at the rest shape g·K⁻¹Λ p of its valves' pressure (τ_p 0.05 s, 1 ms steps), called at 10 Hz; the
    gain intervals the governor certified after each call."""
    governor = ContactEnergyGovernor(FilterContext.for_robot(ROBOT, paper_safe_set(), 0.1), command_delay_s=0.0,
                                     actuator_tau_s=0.05, grid_hPa=10.0, escape_spacing_rad=8e-3, **params)
    model, rng = governor.model, np.random.default_rng(seed)
    state = new_state(model)
    pressure, command, frame, previous, intervals = np.zeros(2), np.zeros(2), None, None, []
    frame_times = np.arange(0.0, duration_s, 1.0 / 12.8)
    for ms in range(int(duration_s * 1000)):
        t = ms * 1e-3
        pressure += (command - pressure) * (1.0 - math.exp(-1e-3 / 0.05))
        exposed = frame_times[np.abs(frame_times - t) < 5e-4]
        if exposed.size and rng.uniform() >= 0.2:
            q = true_gain * A * pressure + rng.normal(0.0, SIGMA, 2)
            qd = np.zeros(2) if previous is None else (q - previous[1]) / (t - previous[0])
            previous, frame = (t, q), Estimate(t + 0.03, q, qd, t)
        if ms % 100 == 0 and frame is not None and frame.t <= t:
            state, out = step(model, state, Estimate(t, frame.q, frame.qd, frame.t_capture), np.full(2, u_push))
            command = np.asarray(out.u, dtype=float)
            intervals.append((state.ends.lo, state.ends.hi))
    return intervals


def test_a_noisy_camera_narrows_the_gain_interval_with_averaged_windows():
    """Camera noise 1e-3 rad and 20 % drops: with the recommended rest test (|q̂̇| ≤ 3e-3 rad/s for 0.2 s) no sample
    is taken and the interval stays [0.9, 1.1]; averaging 1 s windows it narrows below half the prior and holds the
    true gain (1.07, 0.93) at every call, with the pooled scatter and with a calibrated σ (its first sample narrows
    more: z = 4.9 against t_8 = 13.3 at risk 1e-6)."""
    assert set(noisy_camera_run(RECOMMENDED_REST, 1.07, seed=1)) == {(0.9, 1.1)}
    first = {}
    for true_gain, seed, sigma in ((1.07, 1, None), (0.93, 2, None), (1.07, 1, 1.2e-3)):
        intervals = noisy_camera_run({**RECOMMENDED_REST, "gain_window_s": 1.0, "gain_frame_sigma_rad": sigma},
                                     true_gain, seed)
        assert all(lo <= true_gain <= hi for lo, hi in intervals)
        lo, hi = intervals[-1]
        assert hi - lo < 0.1
        first[(seed, sigma)] = next((lo, hi) for lo, hi in intervals if hi - lo < 0.2)
    calibrated, pooled = first[(1, 1.2e-3)], first[(1, None)]
    assert calibrated[1] - calibrated[0] < pooled[1] - pooled[0]


def frames_of_a_resting_camera(seed: int, bias: np.ndarray, sigma: np.ndarray, seconds: float = 20.0):
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, seconds, 1.0 / 12.8)
    truth = np.array([0.3, 0.35]) + 0.02 * (times >= seconds / 2)[:, None]  # two poses at rest, a step between
    camera = truth + bias + rng.normal(0.0, 1.0, truth.shape) * sigma
    return times, camera, truth, rng.uniform(size=times.size) >= 0.2


def test_the_calibration_measures_the_scatter_and_the_error_of_a_windows_mean():
    """Simulated frames at rest (bias 4e-4 / −2e-4 rad, σ 8e-4 / 1.1e-3 rad, 20 % dropped): σ within 15 %, Δ the
    largest error of a window's mean (brute force over the same windows: at least the bias, at most bias + 4σ/√n),
    and without truth no Δ; a run that never rests is refused."""
    bias, sigma = np.array([4e-4, -2e-4]), np.array([8e-4, 1.1e-3])
    times, camera, truth, usable = frames_of_a_resting_camera(5, bias, sigma)
    result = measure(times, camera, truth, usable, window_s=1.0, rest_rad_s=3e-3, risk=1e-6)
    assert result.windows >= 12 and 8 <= result.frames <= 13
    np.testing.assert_allclose(result.sigma, sigma, rtol=0.15)
    assert np.all(result.delta >= np.abs(bias) * 0.5)
    assert np.all(result.delta <= np.abs(bias) + 4.0 * sigma / math.sqrt(result.frames - 2))
    assert measure(times, camera, None, usable, 1.0, 3e-3, 1e-6).delta is None
    moving = truth + np.outer(times, [0.05, 0.0])
    with pytest.raises(ValueError, match="no window of 1 s at rest"):
        measure(times, moving, moving, usable, 1.0, 3e-3, 1e-6)


def test_calibrate_camera_prints_delta_from_a_run_folder(tmp_path, capsys):
    """`softcbf calibrate-camera RUN_DIR` reads timeseries/*_frames.npz and prints σ, ε and Δ with how each was
    measured; a folder without frames is a usage error (exit 2) naming what it needs."""
    times, camera, truth, usable = frames_of_a_resting_camera(6, np.zeros(2), np.full(2, 1e-3))
    (tmp_path / "run" / "timeseries").mkdir(parents=True)
    np.savez(tmp_path / "run" / "timeseries" / "c-erg_frames.npz", t=times, q_camera=camera, q_true=truth,
             dropped=~usable, complete=np.ones_like(usable))
    assert main(["calibrate-camera", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith("c-erg: ") and "frame scatter σ" in out and "Δ (gain_noise_rad) ≥" in out
    assert "for gain_frame_sigma_rad = " in out
    assert "\n".join(report_lines(measure_folder(tmp_path / "run", 1.0, 3e-3, 1e-6)[0])) in out
    (tmp_path / "empty").mkdir()
    assert main(["calibrate-camera", str(tmp_path / "empty")]) == 2
    assert "has no camera frames" in capsys.readouterr().err
