"""Energy-certified reference governor (controllers.governors.energy_governor) and its parts: the
escape-energy table against brute force, Ẇ ≤ 0 along the model, the state predictor
against a fine integration, and closed loops on the PCC plant at 10 Hz with camera timing
(estimate 0.03–0.1 s old, command delay 20 ms) and a first-order valve."""

import inspect
import math
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from controllers.model.dynamics import PCCDynamics
from controllers.model import pcc
from controllers.governors.energy_governor import TIP_TOLERANCE_M, EnergyGovernor, ray_may_come_nearer
from controllers.energy.escape_energy import EscapeEnergyTable
from controllers.contract.filter_metrics import governor_figures
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.pcc import tip_positions
from controllers.model.safe_set import Environment, ForceSafeSet, paper_environment, paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext
from controllers.model.state_predictor import StatePredictor
from softcbf_mj.physics.pcc_plant import PCCPlant

sys.path.insert(0, str(Path(__file__).parent))
from governor_loop import PushingPlatePlant, context, run_loop  # noqa: E402

ROBOT = reference_robot()
SAFE = paper_safe_set()
PERIOD, DELAY = 0.1, 0.02


@pytest.fixture(scope="module")
def governor_lag():
    return EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05))


@pytest.fixture(scope="module")
def governor_ideal():
    return EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.0))


def certificate_slack(gov: EnergyGovernor, rec) -> np.ndarray:
    """Γ(u_k) − W_{u_k} at the TRUE state (q, q̇, p) when each command u_k starts to act (J)."""
    slack = []
    for tick, u in zip(rec.apply_ticks, rec.commands):
        if not 1 <= tick <= len(rec.t):
            continue
        i = tick - 1  # the state at the end of tick i is the state when tick `tick` starts
        base, _ = gov.model.state_energy(rec.q[i], rec.qd[i])
        slack.append(gov.model.escape(u.tolist()) - gov.model.energy(base, rec.q[i].tolist(), rec.p[i].tolist(), u.tolist()))
    return np.array(slack)


# -- the escape-energy table ------------------------------------------------------------
def test_escape_table_is_a_lower_bound_close_to_brute_force():
    table = EscapeEnergyTable(ROBOT, SAFE, ROBOT.array("u_min"), ROBOT.array("u_max"))
    axis = np.linspace(-2.6, 2.6, 1734)  # 3 mrad: the brute force's own error ≤ 2.1e-3 J^½ in √(2Γ)
    q = np.stack([m.ravel() for m in np.meshgrid(axis, axis, indexing="ij")], axis=1)
    g = (tip_positions(q, ROBOT.array("lengths")) @ SAFE.H_prime.T - SAFE.h_prime)[:, 0]
    unsafe = q[(g >= 0) & (g <= 0.01)]  # unsafe samples within 1 cm of the row's line: any subset bounds Γ above
    gain, k = ROBOT.array("gains") / ROBOT.array("stiffness"), ROBOT.array("stiffness")
    rng = np.random.default_rng(4)
    commands = np.vstack((rng.uniform(-150, 150, (40, 2)), [[0, 0], [80, 80], [150, 150], [-150, 150], [37.3, 81.1]]))
    def brute_force(u):  # ≥ Γ (a sampled minimum); 0 when the rest shape itself is outside
        rest = gain * u
        if (tip_positions(rest[None], ROBOT.array("lengths")) @ SAFE.H_prime.T - SAFE.h_prime)[0, 0] >= 0:
            return 0.0
        return 0.5 * np.min(np.sum(k * (unsafe - rest) ** 2, axis=1))

    for u in commands:
        brute = brute_force(u)
        tabulated = table.values(u)[0]
        assert tabulated <= brute
        # looseness in √(2Γ) (J^½), measured on 150 random commands: ≤ 0.0134 (the band's
        # near side + half a cell diagonal in ‖·‖_w); Γ saturates at ½ k reach² (1.2 rad, k = 1)
        assert min(math.sqrt(2 * brute), 1.2) - math.sqrt(2 * tabulated) <= 0.016
    # at the grid points (measured on 150 of them: ≤ 0.0096)
    for u in table.grid_commands()[::997]:
        brute = brute_force(u)
        assert table.values(u)[0] <= brute
        assert min(math.sqrt(2 * brute), 1.2) - math.sqrt(2 * table.values(u)[0]) <= 0.011
    with pytest.raises(ValueError, match="supports N <= 2 segments"):
        EscapeEnergyTable(uniform_robot(3), SAFE, -np.ones(3), np.ones(3))


# -- the certificate --------------------------------------------------------------------
def rk4_with_lag(dyn: PCCDynamics, q, qd, p, u, tau, h, steps):
    """Fine RK4 of (q, q̇, p) with ṗ = (u − p)/τ; yields every state."""
    x = np.concatenate((q, qd, p))
    n = len(q)

    def rhs(x):
        acc = dyn.acceleration(x[:n], x[n:2 * n], x[2 * n:])
        return np.concatenate((x[n:2 * n], acc, (u - x[2 * n:]) / tau))

    for _ in range(steps):
        k1 = rhs(x)
        k2 = rhs(x + 0.5 * h * k1)
        k3 = rhs(x + 0.5 * h * k2)
        k4 = rhs(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        yield x[:n], x[n:2 * n], x[2 * n:]


def test_certified_energy_never_grows_along_the_model(governor_lag):
    """W_u along fine RK4 trajectories of the model with the valve lag (τ_p = 0.05 s) from
    random states: nonincreasing, and its rate matches −Σ(√d q̇ − λ(p − u)/(2√d))².
    Without the pressure term (β = 0) W grows: the term is needed."""
    gov, dyn = governor_lag, governor_lag.model.dynamics
    d, lam, tau = ROBOT.array("damping"), ROBOT.array("gains"), 0.05
    rng = np.random.default_rng(6)
    grew_without_beta = False
    for _ in range(4):
        q, qd = rng.uniform(-0.8, 0.8, 2), rng.uniform(-3, 3, 2)
        p, u = rng.uniform(-150, 150, 2), rng.uniform(-150, 150, 2)

        def energy(q, qd, p, beta=True):
            base = dyn.kinetic_energy(q, qd)
            w = gov.model.energy(base, q.tolist(), p.tolist(), u.tolist())
            return w if beta else w - 0.5 * float(np.sum(gov.model.beta * (p - u) ** 2))

        h = 2e-5
        states = [(q, qd, p)] + list(rk4_with_lag(dyn, q, qd, p, u, tau, h, 1500))
        values = np.array([energy(*x) for x in states])
        plain = np.array([energy(*x, beta=False) for x in states])
        assert np.all(np.diff(values) <= 1e-12 * max(values[0], 1e-9))
        grew_without_beta |= bool(np.any(np.diff(plain) > 1e-9))
        for i in (0, 200, 1000):  # Ẇ = ∇W·ẋ by a central difference along the vector field
            q_i, qd_i, p_i = states[i]
            flow = (qd_i, dyn.acceleration(q_i, qd_i, p_i), (u - p_i) / tau)
            e = 1e-6
            rate = (energy(*(x + e * v for x, v in zip(states[i], flow)))
                    - energy(*(x - e * v for x, v in zip(states[i], flow)))) / (2 * e)
            expected = -np.sum((np.sqrt(d) * qd_i - lam * (p_i - u) / (2 * np.sqrt(d))) ** 2)
            assert rate == pytest.approx(expected, rel=1e-5, abs=1e-8)
    assert grew_without_beta


# -- the predictor ----------------------------------------------------------------------
@pytest.mark.parametrize("tau", [0.0, 0.05])
def test_predictor_agrees_with_a_fine_integration(tau):
    """Commands (±150 hPa) switching every 50 ms (offset 13 ms) for 0.6 s; predictions over
    1–170 ms from states of forward Euler at 1e-5 s (the plant's reference) agree to 5e-4 rad
    and in kinetic energy to 2 % + 1e-6 J (ROS2 at 1 ms; segment 2's velocity carries the
    fast mode, ≈ 0.07 rad/s off at 0.6 rad/s, but its inertia is small), and the pressure to
    1e-9 hPa (exact)."""
    rng = np.random.default_rng(7)
    plant = PCCPlant(ROBOT, SAFE, control_dt=1e-3, integrator="euler", physics_dt=1e-5, tau_p=tau)
    states = [plant.reset(np.array([0.1, -0.2]))]
    dyn = PCCDynamics(ROBOT)
    predictor = StatePredictor(dyn, tau)
    times = np.arange(0.0, 0.6, 0.05) + 0.013
    commands = rng.uniform(-150, 150, (len(times), 2))
    for t_a, u in zip(times, commands):
        predictor.record(t_a, u)
    for k in range(600):
        i = np.searchsorted(times, k * 1e-3 + 1e-12, side="right") - 1
        states.append(plant.step(commands[i] if i >= 0 else np.zeros(2)))
    for k0, k1 in ((100, 230), (250, 251), (300, 420), (431, 599)):
        q, qd, p = predictor.predict(k0 * 1e-3, states[k0].q, states[k0].qd, k1 * 1e-3)
        assert np.max(np.abs(q - states[k1].q)) < 5e-4
        kinetic = dyn.kinetic_energy(states[k1].q, states[k1].qd)
        assert abs(dyn.kinetic_energy(q, qd) - kinetic) <= 0.02 * kinetic + 1e-6
        np.testing.assert_allclose(p, states[k1].u_applied, atol=1e-9)
        np.testing.assert_allclose(predictor.pressure_at(k1 * 1e-3), states[k1].u_applied, atol=1e-9)
    with pytest.raises(ValueError, match="t_apply must not decrease"):
        predictor.record(0.1, np.zeros(2))


def per_step_plate_prediction(dyn, plate, x, u, p, h, steps, decay, mean):
    """The oracle: the contact-aware predictor's per-step Python loop that `controllers.model.plate_prediction`
    compiled (the model terms, q̈, the plate's force and M⁻¹τ as Python and numpy floats)."""
    from controllers.model import pcc_model

    n = dyn.n
    normals = plate.environment.normals.tolist()

    def acceleration(state, acting):
        xs = state.tolist()
        core = dyn.model_terms(xs[:n], xs[n:])
        acc = dyn.acceleration_from_terms(core, acting)
        tip = core.kin[core.layout.tip_terms.start].item()
        forces = plate.force_at(tip.real, tip.imag).tolist()
        if any(forces):
            tau = [-sum(f * (nx * j.real + ny * j.imag) for f, (nx, ny) in zip(forces, normals))
                   for j in core.kin[core.layout.tip_jac].tolist()]
            acc = [a + sum(m * t for m, t in zip(row, tau)) for a, row in zip(acc, core.mass_inv.tolist())]
        return np.array(acc), core.dyn

    x, p, u = x.copy(), list(p), list(u)
    for _ in range(steps):
        acting = [v + (pi - v) * mean for v, pi in zip(u, p)]
        p = [v + (pi - v) * decay for v, pi in zip(u, p)]
        acc, dyn_row = acceleration(x, acting)
        k1, x2, schur_inv = pcc_model.ros2_first(x, acc, dyn_row, dyn.parameter_rows[0], h)
        acc2, _ = acceleration(x2, acting)
        x = pcc_model.ros2_second(x, x2, k1, acc2, dyn_row, schur_inv, dyn.parameter_rows[0], h)
    return x, np.array(p)


@pytest.mark.parametrize("law", ["linear", "power"])
def test_the_compiled_plate_prediction_is_the_per_step_loop_bit_for_bit(law):
    """`controllers.model.plate_prediction.advance_with_plate` (the contact-aware predictor's steps) gives the floats
    of the per-step Python loop it replaced, pressing the plate and off it: bit for bit with a linear ψ, to
    rounding with a power law (the pow functions of numba and numpy)."""
    from controllers.model import plate_prediction
    from controllers.model.safe_set import LinearStiffness, PowerLawStiffness

    stiffness = LinearStiffness(11.16) if law == "linear" else PowerLawStiffness(300.0, 1.5)
    plate = ForceSafeSet(SAFE.environment, stiffness, SAFE.f_max, "paper")
    dyn = PCCDynamics(ROBOT)
    predictor = StatePredictor(dyn, 0.05, plate=plate)
    pressed = 0
    for q, u in (([0.45, 0.5], [150.0, 150.0]), ([0.1, -0.2], [-40.0, 60.0]), ([0.5, 0.55], [20.0, 0.0])):
        x0 = np.array(q + [0.3, -0.4])
        p0 = np.array([30.0, 70.0])
        h, steps, decay, mean = 1e-3, 80, math.exp(-1e-3 / 0.05), 0.05 / 1e-3 * -math.expm1(-1e-3 / 0.05)
        want_x, want_p = per_step_plate_prediction(dyn, plate, x0, np.array(u), p0, h, steps, decay, mean)
        x, p = x0.copy(), p0.copy()
        plate_prediction.advance_with_plate(x, np.array(u), p, dyn.parameter_rows, h, steps, decay, mean,
                                            predictor._facets, *predictor._law)
        if law == "linear":  # the same IEEE operations in the same order
            assert np.array_equal(x, want_x) and np.array_equal(p, want_p), (q, u, x - want_x)
        else:  # n^p: numba's pow and numpy's may differ in the last bit (measured: ≤ 7e-16 after 80 steps)
            np.testing.assert_allclose(x, want_x, rtol=1e-13, atol=1e-15)
            assert np.array_equal(p, want_p)
        tip = pcc.tip_position(want_x[:2], ROBOT.array("lengths"))
        pressed += bool(np.any(plate.penetration(tip) > 0))
    assert pressed >= 1  # the plate pushed in at least one case

    class OwnLaw(LinearStiffness):  # a law of the user's: not compiled, refused by name
        pass

    with pytest.raises(ValueError, match="must be LinearStiffness or PowerLawStiffness .* got OwnLaw"):
        StatePredictor(dyn, 0.05, plate=ForceSafeSet(SAFE.environment, OwnLaw(11.16), SAFE.f_max, "paper"))


def test_the_predictor_caps_its_span_at_the_horizon():
    """A prediction over more than horizon_s is refused (it cost ⌈span/step_s⌉ model steps: 10⁶ for an
    estimate 1000 s old from the vented start), and `can_predict` says so beforehand."""
    predictor = StatePredictor(PCCDynamics(ROBOT), 0.05, horizon_s=2.0)
    rest = np.zeros(2)
    assert predictor.oldest_time == -math.inf and predictor.latest_time == -math.inf
    assert predictor.can_predict(0.0, 2.0) and not predictor.can_predict(0.0, 2.0 + 1e-9)
    assert not predictor.can_predict(1.0, 0.5) and not predictor.can_predict(math.nan, 1.0)
    with pytest.raises(ValueError, match="t_end - t_start must be <= horizon_s = 2.0 s, got 1000.0 s"):
        predictor.predict(0.0, rest, rest, 1000.0)
    for k in range(40):
        predictor.record(0.1 * k, np.full(2, 10.0))
    assert predictor.latest_time == pytest.approx(3.9) and not predictor.can_predict(1.0, 2.0)  # before the history
    latest = predictor.latest_time
    assert predictor.oldest_time <= latest - 2.0 and predictor.can_predict(latest - 1.5, latest)


# -- closed loops on the PCC plant --------------------------------------------------------
@pytest.mark.parametrize("tau", [0.0, 0.05])
def test_worst_step_stays_in_P_and_the_certificate_holds_at_the_true_state(tau, governor_lag, governor_ideal):
    gov = governor_lag if tau else governor_ideal
    rec = run_loop(gov, ROBOT, SAFE, lambda t: np.array([150.0, 150.0]), 4.0, PERIOD, DELAY, tau_p=tau, seed=1)
    assert rec.rho.min() >= 0.0
    assert certificate_slack(gov, rec).min() >= 0.0
    assert np.all(np.abs(rec.u) <= 150.0)
    assert not any(o.diagnostics["violation"] for o in rec.outputs)
    # it reaches the target (rest tip 5 mm inside P: ρ ≈ 0.35) and stays there
    assert rec.outputs[-1].action == "free"
    assert 0.3 < rec.rho[-1] < 0.4


def test_random_steps_from_rest_stay_in_P(governor_lag):
    rng = np.random.default_rng(20)
    worst_rho, worst_slack = np.inf, np.inf
    for seed in range(20):
        u_nom = rng.uniform(60.0, 300.0, 2)
        rec = run_loop(governor_lag, ROBOT, SAFE, lambda t: u_nom, 2.0, PERIOD, DELAY, tau_p=0.05, seed=seed)
        worst_rho = min(worst_rho, rec.rho.min())
        worst_slack = min(worst_slack, certificate_slack(governor_lag, rec).min())
        assert np.all(np.abs(rec.u) <= 150.0)
    assert worst_rho >= 0.0
    assert worst_slack >= 0.0


@pytest.mark.parametrize("period_s", [8.0])
def test_never_holds_a_retreating_nominal_for_long(governor_lag, period_s):
    """u_nom = 150 sin(2πt/T) hPa on both segments for 1.5 T: pushes into the plate, retreats
    (the target slides along P's boundary first). Measured: longest hold 0.4 s (T = 8 s), 0.1 s
    (T = 20 s, tools/bench_governors.py) at the default 5 mm target margin; 0.7–0.8 s with 1 mm."""
    def nominal(t):
        return np.full(2, 150.0 * math.sin(2 * math.pi * t / period_s))

    rec = run_loop(governor_lag, ROBOT, SAFE, nominal, 1.5 * period_s, PERIOD, DELAY, tau_p=0.05, seed=3)
    assert rec.rho.min() >= 0.0
    assert certificate_slack(governor_lag, rec).min() >= 0.0
    t = (np.array(rec.apply_ticks) - int(round(DELAY / 1e-3))) * 1e-3
    u_nom = np.array([nominal(s) for s in t])
    figures = governor_figures(t, np.array(rec.commands), u_nom, np.array([o.diagnostics["solve_us"] for o in rec.outputs]))
    assert figures["blocked_longest_s"] <= 0.5
    assert figures["u_dev_max_hPa"] > 10.0  # it did govern near the plate


def test_reset_replays_the_same_run_and_stale_estimates_hold(governor_ideal):
    gov = governor_ideal
    first = run_loop(gov, ROBOT, SAFE, lambda t: np.array([120.0, 90.0]), 1.0, PERIOD, DELAY, tau_p=0.0, seed=5)
    again = run_loop(gov, ROBOT, SAFE, lambda t: np.array([120.0, 90.0]), 1.0, PERIOD, DELAY, tau_p=0.0, seed=5)
    np.testing.assert_array_equal(np.array(first.commands), np.array(again.commands))
    gov.reset()
    rest = np.zeros(2)
    gov(Estimate(0.0, rest, rest, 0.0), np.array([100.0, 100.0]))
    held = gov(Estimate(5.0, rest, rest, 5.0), np.array([100.0, 100.0])).u  # history now starts at 0.02 s
    old = gov(Estimate(5.1, rest, rest, 0.01), np.array([0.0, 0.0]))  # captured before the kept history
    assert old.action == "stale" and old.infeasible
    np.testing.assert_array_equal(old.u, held)
    gov.reset()
    assert gov.state.predictor.oldest_time == -math.inf


def test_contact_aware_terms_and_robust_n_max():
    ctx = context(ROBOT, SAFE, PERIOD, DELAY, 0.05)
    plain = EnergyGovernor(ctx, grid_hPa=10.0)
    aware = EnergyGovernor(ctx, contact_aware=True, stiffness_lo_ratio=0.9, stiffness_hi_ratio=1.1, grid_hPa=10.0)
    assert aware.model.safe_set.n_max == pytest.approx(0.16 / (11.16 * 1.1))
    credit = 0.9 * 0.5 * 11.16 * aware.model.safe_set.n_max**2
    robust = EnergyGovernor(ctx, stiffness_hi_ratio=1.1, grid_hPa=10.0)
    u = [40.0, 100.0]
    assert aware.model.escape(u) == pytest.approx(robust.model.escape(u) + credit, rel=1e-12)
    assert robust.model.escape(u) < plain.model.escape(u)  # the stiffer plate shrinks P
    q = np.array([0.6, 0.9])  # the tip pressed into the plate
    n = SAFE.penetration(tip_positions(q[None], ROBOT.array("lengths"))[0])[0]
    assert n > 0
    plain_base, _ = plain.model.state_energy(q, np.zeros(2))
    aware_base, _ = aware.model.state_energy(q, np.zeros(2))
    assert plain_base == 0.0
    assert aware_base == pytest.approx(1.1 * 0.5 * 11.16 * n**2)


def test_state_energy_is_the_array_path_in_and_out_of_contact():
    """`state_energy`'s scalar tip (the early exit clear of the plate) against the array path's:
    they differ by ≤ 1e-15 m (TIP_TOLERANCE_M is 1e-9 m), and the energy and ρ are the floats of
    ½q̇ᵀM(q)q̇ (+ hi·ΣE(n)) and margin_at at the array path's tip, in contact and out of it."""
    plain = EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), grid_hPa=10.0)
    aware = EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), contact_aware=True, stiffness_lo_ratio=0.9,
                           stiffness_hi_ratio=1.1, grid_hPa=10.0)
    lengths = ROBOT.array("lengths")
    rng = np.random.default_rng(4)
    touching, worst = 0, 0.0
    for q in np.vstack((rng.uniform(-2.5, 2.5, (300, 2)), rng.uniform(0.3, 1.2, (300, 2)))):
        qd = rng.normal(0.0, 2.0, 2)
        tip = pcc.kinematics(q, lengths, order=0).points[-1]
        worst = max(worst, abs(tip - pcc.step_kinematics(q.tolist(), [0.0, 0.0], lengths.tolist()).tip))
        n = SAFE.penetration_at(tip.real, tip.imag)
        touching += any(n)
        kinetic = plain.model.dynamics.kinetic_energy(q, qd)
        assert plain.model.state_energy(q, qd) == (kinetic, SAFE.margin_at(tip.real, tip.imag))
        assert aware.model.state_energy(q, qd) == (kinetic + 1.1 * float(np.sum(SAFE.stiffness.energy(n))),
                                             SAFE.margin_at(tip.real, tip.imag))
    assert worst <= 1e-15 and TIP_TOLERANCE_M >= 1e6 * worst
    assert 50 < touching < 550  # both branches


BAD_PARAMETERS = [
    ({"kappa": -0.1}, "kappa must be in [0, 1000], got -0.1"),
    ({"kappa": -1}, "kappa must be in [0, 1000], got -1.0"),
    ({"margin_m": -0.5}, "margin_m must be >= 0 m, got -0.5"),
    ({"energy_margin_J": math.inf}, "energy_margin_J must be finite and >= 0 J, got inf"),
    ({"stiffness_lo_ratio": 1.2, "stiffness_hi_ratio": 1.1}, "stiffness_lo_ratio must be <= stiffness_hi_ratio = 1.1, got 1.2"),
    ({"stiffness_hi_ratio": 0.0}, "stiffness_hi_ratio must be in [0.001, 1000], got 0.0"),
    ({"bisection_steps": 0}, "bisection_steps must be in [1, 52], got 0"),
    ({"bisection_steps": 2.5}, "bisection_steps must be an integer in [1, 52], got 2.5"),
    ({"command_delay_s": -0.01}, "command_delay_s must be in [0, 1] s, got -0.01"),
    ({"command_delay_s": 100.0}, "command_delay_s must be in [0, 1] s, got 100.0"),
    ({"command_delay_s": 1e6}, "command_delay_s must be in [0, 1] s, got 1000000.0"),
    ({"actuator_tau_s": math.nan}, "actuator_tau_s must be finite and in [0, 10] s, got nan"),
    ({"grid_hPa": 0.0}, "grid_hPa must be > 0 hPa, got 0.0"),
    ({"predictor_step_s": 1e-9}, "predictor_step_s must be in [0.0001, 0.01] s, got 1e-09"),
    ({"contact_aware": 2}, "contact_aware must be true or false, got 2"),
]


@pytest.mark.parametrize("params, message", BAD_PARAMETERS)
def test_bad_parameters_are_refused_before_and_at_construction(params, message):
    """The same declared bound refuses the value in `check_filter` (nothing built: a study checks
    its runs this way before any sample runs) and in the constructor, with the same message."""
    from controllers.registry import check_filter

    pattern = re.escape(message)
    with pytest.raises(ValueError, match=pattern):
        check_filter("e-erg", params)
    with pytest.raises(ValueError, match=pattern):
        EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), **params)


@pytest.mark.parametrize("params, message", [
    ({"grid_hPa": 1e-6}, r"grid_hPa must be >= 0\.5871 hPa over the box \[300\.0, 300\.0\] hPa wide \(at most 262144 "
                         r"table commands\), got 1e-06 \(9e\+16 commands\)"),
    ({"energy_margin_J": 1e300}, r"energy_margin_J must be < 0\.72 J \(½ k_min reach², the escape energy the table "
                                 r"resolves\), got 1e\+300"),
])
def test_parameters_bounded_by_the_context_are_refused_at_construction(params, message):
    """grid_hPa = 1e-6 asked for 639 PiB; ε = 1e300 certified nothing but reported "hold" as certified."""
    with pytest.raises(ValueError, match=message):
        EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), **params)
    with pytest.raises(ValueError, match="command_delay_s \\(the context's\\) must be in \\[0, 1\\] s, got 5.0"):
        EnergyGovernor(context(ROBOT, SAFE, PERIOD, 5.0, 0.05))


def test_bad_models_are_refused():
    undamped = ROBOT.replace(damping=(0.0, 0.07))
    with pytest.raises(ValueError, match="needs damping > 0 on every segment"):
        EnergyGovernor(context(undamped, SAFE, PERIOD, DELAY, 0.05))

    class NoEnergy:
        def force(self, n):
            return 11.16 * np.maximum(n, 0.0)

        def penetration(self, force):
            return np.maximum(force, 0.0) / 11.16

    odd = ForceSafeSet(paper_environment(), NoEnergy(), 0.16, row_scaling="paper")
    with pytest.raises(ValueError, match="has no energy"):
        EnergyGovernor(FilterContext(ROBOT, odd, ROBOT.array("u_min"), ROBOT.array("u_max"), PERIOD))


def test_parameter_docs_cover_the_signature():
    names = set(inspect.signature(EnergyGovernor).parameters) - {"context"}
    assert set(EnergyGovernor.parameter_docs) == names
    assert all(doc.endswith("]") for doc in EnergyGovernor.parameter_docs.values())


def test_a_failed_certificate_is_detected_and_recovered(governor_ideal):
    """An estimate the held command cannot certify (the tip beyond P, moving at 4 rad/s
    towards the plate): a detected violation, no certified candidate (infeasible), a command
    whose rest shape lies inside P, inside the box; then, at rest inside P, certified again."""
    gov = governor_ideal
    gov.reset()
    rest = np.zeros(2)
    gov(Estimate(0.0, rest, rest, 0.0), np.array([150.0, 150.0]))
    out = gov(Estimate(0.1, np.array([0.35, 0.8]), np.array([4.0, 4.0]), 0.1), np.array([150.0, 150.0]))
    assert out.action == "recover" and out.diagnostics["violation"] == 1.0 and out.infeasible
    assert out.rho_pred < 0
    assert np.all(np.abs(out.u) <= 150.0)
    assert out.diagnostics["Gamma_J"] >= gov.params.energy_margin_J
    assert gov.state.target_governor.rest_margins(out.u).min() + gov.state.target_governor.margin_m > 0  # it settles inside P
    calm_state = 0.5 * gov.state.target_governor.rest_shape(out.u)
    calm = gov(Estimate(0.2, calm_state, rest, 0.2), np.array([150.0, 150.0]))
    assert not calm.infeasible and calm.diagnostics["margin_J"] >= 0.0
    gov.reset()


def test_contact_aware_on_a_plate_that_pushes_back():
    """The plate pushes back, 10 % stiffer than the model (the governor is told [0.9, 1.12]);
    worst step with the valve lag at 10 Hz with camera timing: the true force stays below
    F_max at every tick, and W_u + E_true ≤ Γ(u) + lo·E(n_max) holds at the true state when
    each command starts to act."""
    gov = EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), contact_aware=True,
                         stiffness_lo_ratio=0.9, stiffness_hi_ratio=1.12)
    ratio = 1.1
    plant = PushingPlatePlant(ROBOT, SAFE, 11.16 * ratio, 0.05)
    rec = run_loop(gov, ROBOT, SAFE, lambda t: np.array([150.0, 150.0]), 2.0, PERIOD, DELAY, tau_p=0.05,
                   seed=2, plant=plant)
    assert rec.force.max() <= SAFE.f_max
    assert rec.force.max() > 0.02  # it does press on the plate
    slack = []
    for tick, u in zip(rec.apply_ticks, rec.commands):
        i = tick - 1
        if not 0 <= i < len(rec.t):
            continue
        n = SAFE.penetration(tip_positions(rec.q[i][None], ROBOT.array("lengths"))[0])
        base = gov.model.dynamics.kinetic_energy(rec.q[i], rec.qd[i]) + ratio * float(np.sum(SAFE.stiffness.energy(n)))
        slack.append(gov.model.escape(u.tolist()) - gov.model.energy(base, rec.q[i].tolist(), rec.p[i].tolist(), u.tolist()))
    assert min(slack) >= 0.0


def _ray_distances(start, goal, aim, steps):
    """The governor's computed squared distances to `aim` of the ray's points σ = j 2^-steps, j = 1 … 2^steps."""
    direction = tuple(g - a for a, g in zip(start, goal))
    points = (tuple(a + sigma * d for a, d in zip(start, direction)) for sigma in (j * 0.5**steps for j in range(1, 2**steps + 1)))
    return direction, [sum((c - t) * (c - t) for c, t in zip(point, aim)) for point in points]


def test_ray_skip_keeps_every_ray_with_a_nearer_point():
    """`ray_may_come_nearer` may only answer False when no bisection end point σ ∈ [2^-s, 1] of the
    ray has a computed distance below `best`: with best just above the least computed distance
    (relative 1e-15, within rounding of it) it must answer True, on random rays, rays through the
    aim and rays tangent to a circle about it; it answers False for rays that move away."""
    rng = np.random.default_rng(13)
    steps = 8
    rays = [tuple(map(tuple, rng.uniform(-300.0, 300.0, (3, 2)))) for _ in range(200)]
    for _ in range(100):  # through the aim, and tangent: (start − aim) ⟂ direction
        start, aim = rng.uniform(-300.0, 300.0, 2), rng.uniform(-300.0, 300.0, 2)
        rays.append((tuple(start), tuple(aim + rng.uniform(0.0, 2.0) * (aim - start)), tuple(aim)))
        normal = np.array([-(start - aim)[1], (start - aim)[0]])
        rays.append((tuple(start), tuple(start + rng.uniform(-1.0, 1.0) * normal), tuple(aim)))
    for start, goal, aim in rays:
        direction, distances = _ray_distances(start, goal, aim, steps)
        best = min(distances) * (1.0 + 1e-15)
        assert ray_may_come_nearer(start, goal, direction, aim, best, 0.5**steps), (start, goal, aim)
    start, goal, aim = (100.0, 50.0), (0.0, 0.0), (200.0, 120.0)
    direction, distances = _ray_distances(start, goal, aim, steps)
    held = sum((a - t) ** 2 for a, t in zip(start, aim))
    assert min(distances) > held and not ray_may_come_nearer(start, goal, direction, aim, held, 0.5**steps)
    assert not ray_may_come_nearer(start, start, (0.0, 0.0), aim, held, 0.5**steps)  # d = 0: every point is the start


# -- issue 22 N5/N6: bad times, old estimates, certificates consistent with their diagnostics ----
@pytest.mark.parametrize("t, t_capture", [(math.nan, 0.0), (0.0, math.nan), (0.0, 1.0), (math.inf, 0.0),
                                          (1e300, 1e300), (0.0, -math.inf)])
def test_nan_future_and_absurd_times_are_refused_without_changing_the_governor(governor_lag, t, t_capture):
    """NaN t or t_capture and estimates from the future were labelled certified ("free"/"governed");
    t = 1e300 was accepted and every later call raised until reset. Now all are refused with
    ControllerInputError, and the next valid call runs as if the refused one had not happened."""
    from controllers.core.errors import ControllerInputError

    gov = governor_lag
    gov.reset()
    rest, u_nom = np.zeros(2), np.array([50.0, 50.0])
    before = gov(Estimate(0.0, rest, rest, 0.0), u_nom)
    with pytest.raises(ControllerInputError, match="t_capture <= t <= 1e\\+09 s"):
        gov(Estimate(t, rest, rest, t_capture), u_nom)
    after = gov(Estimate(0.1, rest, rest, 0.05), u_nom)
    gov.reset()
    gov(Estimate(0.0, rest, rest, 0.0), u_nom)
    clean = gov(Estimate(0.1, rest, rest, 0.05), u_nom)
    assert after.action == clean.action and after.u.tolist() == clean.u.tolist() and before.action != "stale"


def test_time_going_backwards_is_refused(governor_lag):
    from controllers.core.errors import ControllerInputError

    gov = governor_lag
    gov.reset()
    rest, u_nom = np.zeros(2), np.array([50.0, 50.0])
    gov(Estimate(1.0, rest, rest, 1.0), u_nom)
    with pytest.raises(ControllerInputError, match="t must not go backwards: got t = 0.5 s after a call at t = 1.0 s"):
        gov(Estimate(0.5, rest, rest, 0.5), u_nom)
    assert gov(Estimate(1.0, rest, rest, 1.0), u_nom).action != "stale"  # the same time again is fine


@pytest.mark.parametrize("age", [2.5, 1000.0, 1e8])
def test_an_estimate_older_than_the_horizon_is_stale_at_once(governor_lag, age):
    """An estimate 1000 s old took 8–20 s per call (10⁶ prediction steps from the vented start),
    although the docstring promised "stale". Now any estimate whose prediction span t_a − t_c exceeds
    the predictor's horizon is "stale" (held command, infeasible), in well under a millisecond of prediction."""
    from controllers.governors.energy_governor import PREDICTION_HORIZON_S

    gov = governor_lag
    gov.reset()
    rest = np.zeros(2)
    out = gov(Estimate(age, rest, rest, 0.0), np.array([50.0, 50.0]))
    assert age + DELAY > PREDICTION_HORIZON_S
    assert out.action == "stale" and out.infeasible and out.u.tolist() == [0.0, 0.0]
    assert out.diagnostics["solve_us"] < 0.5e6 and out.diagnostics["prediction_s"] == pytest.approx(age + DELAY)


def test_the_largest_command_delay_stays_cheap():
    """command_delay_s = 100 s took 19.7 s for 10 calls; 1e6 s more than 90 s. Both are refused now
    (test_bad_parameters_are_refused_before_and_at_construction); the largest accepted delay costs a
    prediction over at most the horizon: 10 calls at the default 1 ms predictor step well under 2 s."""
    from controllers.governors.energy_governor import MAX_COMMAND_DELAY_S

    gov = EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), command_delay_s=MAX_COMMAND_DELAY_S)
    rest = np.zeros(2)
    started = time.perf_counter()
    actions = [gov(Estimate(0.1 * k, rest, rest, 0.1 * k - 0.05), np.array([80.0, 80.0])).action for k in range(10)]
    assert time.perf_counter() - started < 2.0 and "stale" not in actions


@pytest.mark.parametrize("params", [{}, {"energy_margin_J": 0.3}, {"kappa": 50.0}])
def test_no_certificate_is_contradicted_by_its_own_margin(governor_lag, params):
    """energy_margin_J = 1e300 returned "hold", not infeasible, with margin_J = −1e300: the held command's
    hysteresis test (Γ − (1+κ)W − ε) + ε ≥ 0 absorbed any W. Now the held command is tested as
    Γ − (1+κ)W > 0 and margin_J reports that for "hold" (ε for new commands): over a governed loop
    every "free", "governed" and "hold" has margin_J ≥ 0, and every negative margin is flagged infeasible."""
    gov = EnergyGovernor(context(ROBOT, SAFE, PERIOD, DELAY, 0.05), **params) if params else governor_lag
    rec = run_loop(gov, ROBOT, SAFE, lambda t: np.array([150.0, 150.0]) * math.sin(2 * math.pi * t / 4.0), 4.0)
    actions = {o.action for o in rec.outputs}
    assert actions & {"hold", "governed"}, actions
    for out in rec.outputs:
        margin = out.diagnostics["margin_J"]
        if out.action in ("free", "governed", "hold"):
            assert margin >= 0.0 and not out.infeasible, (out.action, margin)
        elif out.action == "recover":
            assert out.infeasible or margin >= -1e-12, margin


def test_facets_out_of_reach_have_no_escape_energy_limit():
    """Issue 24: a facet whose line lies beyond the arm's reach crashed the table (`zero-size array to
    reduction operation minimum`). Such a row has no unsafe set: Γ = +inf; beside a reachable facet
    the governor behaves as with that facet alone (the same commands), and alone it passes the target."""
    far = ForceSafeSet(Environment(np.array([[1.0, 0.0], [0.36, 1.0]]), np.array([10.0, 0.15])),
                       SAFE.stiffness, SAFE.f_max, row_scaling="paper")
    table = EscapeEnergyTable(ROBOT, far, ROBOT.array("u_min"), ROBOT.array("u_max"))
    assert np.all(np.isinf(table.distance[0])) and math.isinf(table.values([0.0, 0.0])[0])
    alone = EscapeEnergyTable(ROBOT, SAFE, ROBOT.array("u_min"), ROBOT.array("u_max"))
    np.testing.assert_array_equal(table.distance[1], alone.distance[0])
    only_far = ForceSafeSet(Environment(np.array([[1.0, 0.0]]), np.array([10.0])), SAFE.stiffness, SAFE.f_max,
                            row_scaling="paper")
    gov = EnergyGovernor(context(ROBOT, only_far, PERIOD, DELAY, 0.05))
    out = gov(Estimate(0.0, np.zeros(2), np.zeros(2), 0.0), np.array([150.0, 150.0]))
    assert out.action == "free" and out.u.tolist() == [150.0, 150.0] and math.isinf(out.diagnostics["Gamma_J"])
