"""controllers.governors.gain_estimate: the least-squares gain ĝ and its interval [ĝ − e, ĝ + e] ∩ prior contain the true gain
whenever every sample's deviation is within Δ (random and worst-case deviations), in contact too whatever the
unknown forces along the eliminated directions (hypothesis: any N, K, forces), an impossible deviation falls back
to the prior, uninformative samples (x near 0, x along the eliminated forces, a corner) are not kept, and bad input
is refused; tools/gain_contact_samples.py reads the deviation of a recorded rest against the plate; on mujoco_contact
the true gain 1.1 at the prior's end holds while the samples against the plate narrow the interval. The estimator on
the PCC plant (rest and difference samples, in and out of contact) is tested through c-erg in
tests/test_contact_governor.py."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers.governors.gain_estimate import GainEstimator
from controllers.model.params import reference_robot
from controllers.model.pcc import tip_jacobian, tip_position

ROOT = Path(__file__).resolve().parents[1]
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


# -- samples in contact (module docstring, "in contact") -----------------------------------------------------------

def plate_torque(q, normal=(0.36, 1.0)):
    """J_r(q)ᵀn̂ (N,) m: the generalised force per newton of a plate pushing the tip along −n̂ (the paper's facet)."""
    n = np.asarray(normal, dtype=float)
    return tip_jacobian(q, ROBOT.array("lengths")).T @ (n / np.linalg.norm(n))


def contact_sample_at(p, gain, force_N, delta=0.0):
    """The rest sample of the arm of gain `gain` pressing the plate with force_N at pressure p: y = g x − z F + δ,
    z = K⁻¹J_r(q)ᵀn̂ at the rest shape q (a fixed point: q = g x − z(q) F)."""
    x, q = A * p, A * p * gain
    for _ in range(100):
        q = gain * x - plate_torque(q) / K * force_N
    return q + delta, plate_torque(q)[:, None]


def test_free_part_is_k_orthogonal_to_the_eliminated_directions_and_a_projection():
    est = estimator()
    rng = np.random.default_rng(3)
    torques = rng.normal(size=(2, 1))
    x = rng.normal(size=2)
    free = est.free_part(x, torques)
    assert abs(free @ (torques[:, 0])) < 1e-12  # x̃ᵀK z = x̃ᵀ J_rᵀn̂ = 0 (z = K⁻¹J_rᵀn̂)
    assert np.allclose(est.free_part(free, torques), free)  # Π² = Π
    assert np.allclose(est.free_part(x, np.zeros((2, 1))), x)  # a zero direction eliminates nothing
    assert np.array_equal(est.free_part(x, np.zeros((2, 0))), x)  # no direction: x itself
    assert np.allclose(est.free_part(x, rng.normal(size=(2, 2))), 0.0)  # N = 2, two directions: nothing left


def test_a_contact_sample_bounds_the_gain_whatever_the_plate_force_and_ignoring_the_force_does_not():
    """At the reference arm's rest against the plate (74 hPa, 0.2 N, true gain 1.05): the in-contact sample's interval
    holds g for any force; the same numbers taken as a sample out of contact (the force term ignored) give an interval
    that excludes g, so a sample that dropped the force would fail this test."""
    p = np.full(2, 74.0)
    for force in (0.0, 0.05, 0.2, 5.0):
        y, torques = contact_sample_at(p, 1.05, force)
        est = estimator()
        assert est.sample_in_contact(p, y, torques)
        lo, hi = est.interval
        assert lo <= 1.05 <= hi and hi - lo < 0.2 and abs(est.estimate - 1.05) < 1e-9
    y, _ = contact_sample_at(p, 1.05, 0.2)
    ignored = estimator()
    assert ignored.sample(p, y)
    assert not ignored.interval[0] <= 1.05 <= ignored.interval[1]


def test_a_contact_sample_is_refused_where_the_force_direction_leaves_no_information():
    """x along z (the rest shape pushes straight along the plate's generalised force) and two facets at once (N = 2:
    nothing is left after elimination) are not kept; the sample's own bound is Δ w̃/|x̃|²_K otherwise."""
    p = np.full(2, 74.0)
    est = estimator()
    assert not est.sample_in_contact(p, A * p, (A * p)[:, None] * K[:, None])  # z = K⁻¹ torque ∥ x
    assert not est.sample_in_contact(p, A * p, np.array([[1.0, 0.3], [0.2, 1.0]]))
    assert est.samples == 0 and est.interval == (0.9, 1.1)
    y, torques = contact_sample_at(p, 1.0, 0.1)
    assert est.sample_in_contact(p, y, torques)
    free = est.free_part(A * p, torques)
    assert est.bound == pytest.approx(NOISE * np.sum(K * np.abs(free)) / np.sum(K * free * free), abs=1e-11)


def test_bad_contact_input_is_refused():
    with pytest.raises(ValueError, match=r"torques must be a finite \(2, m\) array"):
        estimator().sample_in_contact(np.full(2, 70.0), A * 70.0, np.ones(2))
    with pytest.raises(ValueError, match="torques must be a finite"):
        estimator().sample_in_contact(np.full(2, 70.0), A * 70.0, np.full((2, 1), np.nan))


@st.composite
def contact_worlds(draw):
    """An arm of N = 1…4 segments (stiffness 0.1–10 N·m/rad, rest per hPa 1e-3–1e-2 rad/hPa), a prior around the
    true gain, Δ, and 1–6 samples: pressures, m < N force directions (m = 0: out of contact), forces F_j ≥ 0 up to
    10 N (any plate), deviations within Δ (random or the one-sided worst case)."""
    n = draw(st.integers(1, 4))
    floats = lambda lo, hi: st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    k = np.array(draw(st.lists(floats(0.1, 10.0), min_size=n, max_size=n)))
    a = np.array(draw(st.lists(floats(1e-3, 1e-2), min_size=n, max_size=n)))
    lo = draw(floats(0.5, 1.0))
    hi = lo + draw(floats(0.01, 0.5))
    gain = lo + draw(floats(0.0, 1.0)) * (hi - lo)
    noise = draw(floats(1e-4, 1e-2))
    samples = []
    for _ in range(draw(st.integers(1, 6))):
        p = np.array(draw(st.lists(floats(-150.0, 150.0), min_size=n, max_size=n)))
        m = draw(st.integers(0, n - 1))
        torques = np.array(draw(st.lists(floats(-0.3, 0.3), min_size=n * m, max_size=n * m))).reshape(n, m)
        forces = np.array(draw(st.lists(floats(0.0, 10.0), min_size=m, max_size=m)))
        unit = np.array(draw(st.lists(floats(-1.0, 1.0), min_size=n, max_size=n)))
        delta = noise * (np.sign(unit) if draw(st.booleans()) else unit)
        samples.append((p, torques, forces, delta))
    return k, a, (lo, hi), gain, noise, samples


@settings(max_examples=300, deadline=None, derandomize=True)
@given(contact_worlds())
def test_the_interval_holds_the_true_gain_for_any_plate_forces_and_deviations_within_the_bound(world):
    """y = g x − K⁻¹ Σ_j torque_j F_j + δ with arbitrary F_j ≥ 0 along the passed directions and |δ_i| ≤ Δ: every
    interval (in and out of contact samples mixed) contains g, ĝ is within e of it, and nothing proves inconsistent."""
    k, a, prior, gain, noise, samples = world
    est = GainEstimator(k, a, 0.07 * k, prior, noise)
    for p, torques, forces, delta in samples:
        y = gain * a * p - (torques @ forces) / k + delta
        if torques.shape[1]:
            est.sample_in_contact(p, y, torques)
        else:
            est.sample(p, y)
        lo, hi = est.interval
        assert prior[0] <= lo <= gain <= hi <= prior[1] and not est.inconsistent
        if est.samples:
            assert abs(est.estimate - gain) <= est.bound


def test_the_contact_samples_tool_reads_the_deviation_of_a_recorded_rest_against_the_plate(tmp_path):
    """tools/gain_contact_samples.py on a recorded run at rest against the paper's facet (the exact PCC balance with a
    0.1 N plate force, true gain 1.05): deviation 0 at the steady rows; the estimate offset by 4e-4 rad per segment
    with the signs of x̃ (the worst case of |δ_i| ≤ 4e-4) reads 4e-4; the rows before the pressure is steady, and those clear of the plate, are not read."""
    import importlib.util
    import json as json_module

    from controllers.model.safe_set import paper_environment

    spec = importlib.util.spec_from_file_location("gain_contact_samples", ROOT / "tools" / "gain_contact_samples.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    normal = paper_environment().normals[0]
    p = np.full(2, 74.0)
    x, q = A * p, A * p * 1.05
    for _ in range(200):  # q = g x − K⁻¹J_r(q)ᵀn̂ F: the rest against the plate
        q = 1.05 * x - plate_torque(q, normal) / K * 0.1
    assert normal @ tip_position(q, ROBOT.array("lengths")) > paper_environment().offsets[0] - 5e-3
    t = np.arange(0.0, 1.0, 2e-3)
    worst = 4e-4 * np.sign(estimator().free_part(x, plate_torque(q, normal)[:, None]))
    for offset, expected in ((0.0, 0.0), (worst, 4e-4)):
        run = tmp_path / f"run{expected}"
        (run / "timeseries").mkdir(parents=True)
        (run / "config.json").write_text(json_module.dumps({"scenario": "camera_loop", "params": {
            "robot": "reference", "environment": "paper", "true_gain_scale": 1.05, "tau_p": 0.0}}))
        u = np.where(t[:, None] < 0.5, 0.0, 74.0) * np.ones((1, 2))
        np.savez(run / "timeseries" / "c-erg.npz", t=t, q_est=np.tile(q + offset, (len(t), 1)),
                 qd_est=np.zeros((len(t), 2)), u_applied=u)
        summary = tool.contact_samples(run, 0.02, 0.0, 1e-3, 5e-3, 5e-3, replay=False)
        assert summary["rows"] == int(np.sum(t > 0.5 + tool.HOLD_S + 1e-9))  # p reaches u one row after the step
        # J_r at q̂ = q + offset: the force's direction error F K⁻¹(J_r(q) − J_r(q̂))ᵀn̂ ≈ 1e-7 rad (module docstring)
        assert summary["deviation_max_rad"] == pytest.approx(expected, abs=1e-6)
        assert 20.0 < summary["theta_deg_median"] < 40.0
    qd = np.where((t > 0.7) & (t < 0.72), 0.05, 0.0)[:, None] * np.ones((1, 2))  # moving for 20 ms at 0.7 s
    np.savez(run / "timeseries" / "c-erg.npz", t=t, q_est=np.tile(q + offset, (len(t), 1)), qd_est=qd, u_applied=u)
    rows = [tool.contact_samples(run, 0.02, rest_s, 1e-3, 5e-3, 5e-3, replay=False)["rows"] for rest_s in (0.0, 0.1)]
    at_rest = (t > 0.5 + tool.HOLD_S + 1e-9) & (qd[:, 0] == 0.0)
    assert rows == [int(np.sum(at_rest)), int(np.sum(at_rest & ((t < 0.7) | (t >= 0.72 + 0.1 - 1e-9))))]


@pytest.mark.slow
def test_a_mujoco_push_with_the_true_gain_at_the_prior_end_holds_while_its_samples_against_the_plate_narrow(tmp_path):
    """c-erg certifying [0.9, 1.1] with the gain estimate on mujoco_contact (1 kHz, exact state), the full 150 hPa push
    from rest for 2 s on an arm of true gain 1.1 and a plate 10 % stiffer and 1 mm closer (the bench's worst corner):
    no sample is taken before contact (the arm moves until it rests against the plate), the samples against the plate
    narrow the interval to under 0.05 wide around 1.1, and the measured margin stays > 0 (measured ρ_meas +0.045,
    steady 0.955 F_max)."""
    import json as json_module

    from scenarios import get
    from softcbf_mj.outputs.runio import load_timeseries

    params = ("stiffness_lo_ratio=0.9;stiffness_hi_ratio=1.1;contact_aware=true;gain_lo_ratio=0.9;gain_hi_ratio=1.1;"
              "gain_estimate=true")
    get("mujoco_contact").run(tmp_path, duration=2.0, filter="c-erg", filter_params=params, tunings="c-erg",
                              nominal="step", nominal_params="seed=0;low_hPa=150;high_hPa=150", true_gain_scale=1.1,
                              plate_stiffness=12.276, facet_offset=-0.001, progress=False)
    run = json_module.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))["runs"][0]
    series = load_timeseries(tmp_path / run["timeseries"])[0]
    assert run["rho_min_meas"] > 0.0 and run["t_violation_s"] == 0.0
    lo, hi = series["gain_lo"], series["gain_hi"]
    force = series["contact_force"].reshape(len(lo), -1).sum(axis=1)
    first_contact = int(np.argmax(force > 0.0))
    assert first_contact > 0 and np.all(lo[:first_contact] == 0.9) and np.all(hi[:first_contact] == 1.1)
    assert np.all(lo <= 1.1) and np.all(hi >= 1.1) and hi[-1] - lo[-1] < 0.05
