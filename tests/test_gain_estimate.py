"""controllers.gain_estimate: the least-squares gain ĝ and its interval [ĝ − e, ĝ + e] ∩ prior contain the true gain
whenever every sample's deviation is within Δ (random and worst-case deviations), an impossible deviation falls back
to the prior, uninformative samples are not kept, and bad input is refused. The estimator on the PCC plant (rest and
difference samples, none in contact) is tested through c-erg in tests/test_contact_governor.py."""

import math

import numpy as np
import pytest

from controllers.gain_estimate import GainEstimator
from controllers.params import reference_robot

ROBOT = reference_robot()
K, A, D = ROBOT.array("stiffness"), ROBOT.array("gains") / ROBOT.array("stiffness"), ROBOT.array("damping")
NOISE = 5e-3


def estimator(prior=(0.9, 1.1), noise=NOISE):
    return GainEstimator(K, A, D, prior, noise)


@pytest.mark.parametrize("true_gain", [0.9, 0.95, 1.0, 1.05, 1.1])
def test_interval_contains_the_true_gain_under_deviations_within_the_bound(true_gain):
    """Random pressures (20–150 hPa) and deviations uniform in [−Δ, Δ] per segment, and the worst case (every
    deviation Δ with the sign of k x, the most one-sided): the interval always contains g and ends within the prior."""
    rng = np.random.default_rng(7)
    for trial in range(200):
        est = estimator()
        for _ in range(20):
            p = rng.uniform(20.0, 150.0, size=2)
            delta = NOISE * np.sign(K * A * p) if trial % 2 else rng.uniform(-NOISE, NOISE, size=2)
            est.sample(p, true_gain * A * p + delta)
            lo, hi = est.interval
            assert 0.9 <= lo <= true_gain <= hi <= 1.1 and not est.inconsistent
        assert abs(est.estimate - true_gain) <= est.bound


def test_bound_is_delta_over_the_largest_rest_shape_and_narrows_the_prior():
    """One sample at 74 hPa on both segments (the reference arm's 1.2 F_max push, rest shape ≈ 0.4 rad): e = Δ_K/|x|_K,
    the interval [ĝ − e, ĝ + e] within the prior; a sample at a smaller rest shape is not kept (it would widen e)."""
    est = estimator()
    p = np.full(2, 74.0)
    assert est.sample(p, 1.05 * A * p) and est.samples == 1
    x = A * p
    assert est.bound == pytest.approx(NOISE * math.sqrt(K.sum()) / math.sqrt(np.sum(K * x * x)))
    assert est.interval == pytest.approx((1.05 - est.bound, 1.05 + est.bound)) and est.bound < 0.02
    assert not est.sample(np.full(2, 60.0), 1.05 * A * 60.0) and est.samples == 1


def test_uninformative_samples_near_the_vented_arm_are_not_kept():
    """A sample alone bounding g no better than a quarter of the prior's width (x near 0) is not kept."""
    est = estimator()
    p = np.full(2, 2.0)
    assert not est.sample(p, A * p + 0.01) and est.samples == 0 and math.isnan(est.estimate)
    assert est.interval == (0.9, 1.1) and est.bound == math.inf


def test_an_impossible_deviation_falls_back_to_the_prior_for_good():
    """Samples that no gain fits within Δ (an assumption is false: contact, a wrong model) give the prior back,
    and no later sample narrows it until reset."""
    est = estimator()
    assert est.sample(np.full(2, 60.0), 1.0 * A * 60.0)
    assert est.interval[1] < 1.05
    est.sample(np.full(2, 80.0), 1.1 * A * 80.0)  # 10 % off at a larger rest shape: no common gain within Δ
    assert est.inconsistent and est.interval == (0.9, 1.1)
    assert not est.sample(np.full(2, 100.0), A * 100.0) and est.interval == (0.9, 1.1)
    est.reset()
    assert est.sample(np.full(2, 100.0), A * 100.0) and est.interval != (0.9, 1.1) and not est.inconsistent


def test_rest_residual_adds_the_damping_torque():
    est = estimator()
    q, qd = np.array([0.1, -0.2]), np.array([0.3, 0.4])
    assert np.allclose(est.rest_residual(q, qd), q + D / K * qd)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="prior gain interval"):
        estimator(prior=(1.1, 0.9))
    with pytest.raises(ValueError, match="noise_rad"):
        estimator(noise=-1.0)
    with pytest.raises(ValueError, match="stiffness > 0"):
        GainEstimator(-K, A, D, (0.9, 1.1), NOISE)
