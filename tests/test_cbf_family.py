"""The standard CBF family (controllers.cbf.family): derivatives, the constraint's algebra, the closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.cbf.backup import BackupCBF
from controllers.cbf.family import (ISS_PARAMETERS, SAMPLED_PARAMETERS, ExponentialCBF, SampledDataCBF,
                                    barrier_derivatives, ecbf, isscbf, sdcbf)
from controllers.model.dynamics import PCCDynamics
from controllers.model.params import reference_robot
from controllers.cbf.qp import solve_qp
from controllers.registry import FILTERS, build_filter, check_filter
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext
from scenarios.common import load_robot
from softcbf.cli import main
from softcbf_mj.outputs.runio import load_timeseries, read_run_folder

SEGMENTS = (2, 3)


def _robot(n: int):
    return reference_robot() if n == 2 else load_robot("three-segment")


def _context(n: int, bounded: bool = True) -> FilterContext:
    return FilterContext.for_robot(_robot(n), paper_safe_set(), 1e-3, pressure_limits=bounded)


def _rows():
    safe_set = paper_safe_set()
    return np.array(safe_set.H_prime).tolist(), np.array(safe_set.h_prime).tolist()


def _states(n: int):
    rng = np.random.default_rng(7 + n)
    return [(rng.uniform(-1.2, 1.2, n), rng.uniform(-2.0, 2.0, n), rng.uniform(-150, 150, n)) for _ in range(4)]


@pytest.mark.parametrize("n", SEGMENTS)
def test_barrier_derivatives_match_finite_differences_along_the_flow(n):
    """ḃ and b̈ = b̈₀ − a·u against central differences of b and ḃ along ẋ = f + g u (tolerance 1e-6 relative)."""
    dynamics, (rows, hs) = PCCDynamics(_robot(n)), _rows()

    def terms(q, qd):
        return barrier_derivatives(dynamics.evaluate_floats(list(q), list(qd)).tip, rows, hs)

    tau = 1e-6
    for q, qd, u in _states(n):
        qdd = dynamics.acceleration(q, qd, u)
        (b, bdot, bdd0, a), = terms(q, qd)
        (bp, bdp, _, _), = terms(q + tau * qd, qd + tau * qdd)
        (bm, bdm, _, _), = terms(q - tau * qd, qd - tau * qdd)
        assert bdot == pytest.approx((bp - bm) / (2 * tau), rel=1e-6, abs=1e-9)
        assert bdd0 - np.dot(a, u) == pytest.approx((bdp - bdm) / (2 * tau), rel=1e-6, abs=1e-7)


@pytest.mark.parametrize("n", SEGMENTS)
def test_input_row_is_the_derivative_of_bddot_in_u(n):
    """a = −∂b̈/∂u: b̈ at u ± δ e_j from the model's accelerations and the tip Jacobians."""
    dynamics, (rows, hs) = PCCDynamics(_robot(n)), _rows()
    for q, qd, u in _states(n):
        ev = dynamics.evaluate(q, qd)
        (_, _, bdd0, a), = barrier_derivatives(ev.tip, rows, hs)
        h = np.array(rows[0])

        def bddot(v):  # −H'(J_r q̈ + J̇_r q̇), straight from q̈ of the model
            acc = ev.tip_jac @ dynamics.acceleration(q, qd, v) + ev.tip_jac_dot @ qd
            return -(h[0] * acc.real + h[1] * acc.imag)

        numeric = [-(bddot(u + 0.5 * e) - bddot(u - 0.5 * e)) for e in np.eye(n)]
        np.testing.assert_allclose(a, numeric, rtol=1e-7, atol=1e-9)
        assert bddot(np.zeros(n)) == pytest.approx(bdd0, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("factory", [ecbf, isscbf])
@pytest.mark.parametrize("n", SEGMENTS)
def test_constraint_and_command_against_brute_force(factory, n):
    """The row is ψ₂ − m = b̈ + k₁ḃ + k₀b − m written out term by term, and the command solves the QP: no
    box point meeting the rows is nearer to u_nom (a grid search), and u = u_nom whenever u_nom meets them."""
    context = _context(n)
    filt = factory(context)
    for q, qd, u_nom in _states(n):
        out = filt(Estimate(0.0, q, qd, 0.0), u_nom)
        (b, bdot, bdd0, a), = filt.terms(list(q), list(qd))
        margin = 0.0 if filt.epsilon is None else np.dot(a, a) / filt.epsilon
        psi2 = bdd0 - np.dot(a, out.u) + (filt.alpha1 + filt.alpha2) * bdot + filt.alpha1 * filt.alpha2 * b
        assert out.diagnostics["constraint"][0] == pytest.approx(psi2 - margin, rel=1e-9, abs=1e-9)
        assert out.diagnostics["psi1"][0] == pytest.approx(bdot + filt.alpha1 * b)
        assert out.diagnostics["margin"][0] == pytest.approx(margin)
        row, rhs = np.array([a]), np.array([bdd0 + (filt.alpha1 + filt.alpha2) * bdot + filt.alpha1 * filt.alpha2 * b
                                            - margin])
        if (row @ u_nom <= rhs).all():
            assert out.action == "nominal" and np.array_equal(out.u, u_nom)
            continue
        reference = solve_qp(u_nom, row, rhs, context.u_min, context.u_max)
        if not reference.feasible:
            assert out.infeasible and out.action in ("clipped", "vent")
            continue
        assert out.action == "qp" and not out.infeasible
        grid = np.stack(np.meshgrid(*[np.linspace(-150, 150, 61)] * n, indexing="ij"), -1).reshape(-1, n)
        feasible = grid[(grid @ row.T <= rhs).all(axis=1)]
        best = np.min(np.linalg.norm(feasible - u_nom, axis=1))
        assert np.linalg.norm(out.u - u_nom) <= best + 1e-9
        assert (row @ out.u - rhs <= 1e-6 * np.linalg.norm(row)).all()


def test_far_from_the_boundary_the_command_is_u_nom():
    """At rest at the rest shape q = K⁻¹Λu_nom, with the tip more than 20 mm inside P, u_nom passes unchanged
    ("nominal": no force taken away; there b̈ = 0 and ψ₂ = α₁α₂ b). Three commands per arm and filter."""
    for n in SEGMENTS:
        robot = _robot(n)
        static_gain = robot.array("gains") / robot.array("stiffness")
        for factory in (ecbf, isscbf):
            filt = factory(_context(n))
            for u_nom in (np.zeros(n), np.full(n, -150.0), np.full(n, -60.0)):
                q = static_gain * u_nom
                (b, _, _, _), = filt.terms(list(q), [0.0] * n)
                assert b > 0.02
                out = filt(Estimate(0.0, q, np.zeros(n), 0.0), u_nom)
                assert out.action == "nominal" and np.array_equal(out.u, u_nom) and not out.infeasible


def test_bad_parameters_are_one_error():
    context = _context(2)
    with pytest.raises(ValueError, match=r"alpha1 must be in \(0, 10000\] 1/s, got -1"):
        ecbf(context, alpha1=-1.0)
    with pytest.raises(ValueError, match=r"epsilon must be in \(0, 1e\+12\]"):
        isscbf(context, epsilon=0.0)
    with pytest.raises(ValueError, match="qp_backend must be one of"):
        ecbf(context, qp_backend="nosuch")
    with pytest.raises(ValueError, match="alpha2"):
        check_filter("isscbf", {"alpha2": "0"})
    with pytest.raises(ValueError, match="unknown parameter"):
        build_filter("ecbf", {"epsilon": "1"}, context)


def test_registered_with_documented_parameters():
    assert FILTERS["ecbf"] is ecbf and FILTERS["isscbf"] is isscbf
    assert set(isscbf.parameter_docs) == set(ISS_PARAMETERS) and "[1/s]" in ecbf.parameter_docs["alpha1"]
    filt = build_filter("isscbf", {"alpha1": "4", "epsilon": "20"}, _context(3))
    assert isinstance(filt, ExponentialCBF) and (filt.alpha1, filt.epsilon, filt.n) == (4.0, 20.0, 3)


def _paper_sim(tmp_path, name, robot):
    out = tmp_path / f"{name}-{robot}"
    assert main(["run", "paper_sim", "--filter", name, "--robot", robot, "--duration", "5", "--frequency", "0.1",
                 "--out", str(out), "--progress", "false", "--data-only"]) == 0
    (row,) = read_run_folder(out).summary["runs"]
    series, _ = load_timeseries(out / row["timeseries"])
    return series


@pytest.mark.parametrize("robot", ["reference", "three-segment"])
def test_isscbf_keeps_the_tip_in_p_on_the_paper_sinusoid(tmp_path, robot):
    """PCC plant = model, exact state, 1 kHz, 0.1 Hz sinusoid: the tip stays in P (the unfiltered run leaves it by
    ρ −0.77 with two segments, −9.16 with three) and the filter acts (u ≠ u_nom somewhere)."""
    series = _paper_sim(tmp_path, "isscbf", robot)
    assert series["rho_meas"].min() >= 0.0
    assert not np.array_equal(series["u"], series["u_nom"])
    if robot == "reference":  # from rest, 77 mm inside P: the first second passes u_nom unchanged
        assert np.array_equal(series["u"][:1000], series["u_nom"][:1000])


@pytest.mark.parametrize("robot", ["reference", "three-segment"])
def test_ecbf_brakes_the_tip_but_the_hold_biases_it_out(tmp_path, robot):
    """The continuous-time ECBF under the 1 kHz hold brakes the tip (no filter: ρ −0.77 / −9.16) but the sampling
    bias of the arm's fast mode lets b drift below 0 (module docstring: ρ_min −0.083 / −1.07); pinned here so that
    a change shows. With two segments the first second passes u_nom unchanged."""
    series = _paper_sim(tmp_path, "ecbf", robot)
    worst = series["rho_meas"].min()
    assert (-0.1 < worst < 0.0) if robot == "reference" else (-1.2 < worst < -0.9)
    if robot == "reference":
        assert np.array_equal(series["u"][:1000], series["u_nom"][:1000])


@pytest.mark.parametrize("n", SEGMENTS)
def test_sampled_data_margin_rate_box_and_command_against_brute_force(n):
    """sdcbf: m = T (k₁|b̈(ū)| + k₀|ḃ| + r‖a‖₁) written out, the box |u − u_prev| ≤ rT (u_prev = 0 after reset, then
    the command sent), and no point of that box meeting the row is nearer to ū (a grid search)."""
    filt = sdcbf(_context(n), rate_hPa_per_s=500.0)
    for q, qd, u_nom in _states(n):
        filt.reset()
        for _ in range(2):  # after reset (u_prev = 0), then after one command
            lb, ub = filt.bounds()
            u_bar = np.clip(u_nom, lb, ub)
            out = filt(Estimate(0.0, q, qd, 0.0), u_nom)
            (b, bdot, bdd0, a), = filt.terms(list(q), list(qd))
            margin = 1e-3 * ((filt.k1 * abs(bdd0 - np.dot(a, u_bar))) + filt.k0 * abs(bdot) + 500.0 * np.abs(a).sum())
            assert out.diagnostics["margin"][0] == pytest.approx(margin, rel=1e-12)
            assert np.all(out.u >= np.array(lb) - 1e-12) and np.all(out.u <= np.array(ub) + 1e-12)
            row = np.array(a)
            rhs = bdd0 + filt.k1 * bdot + filt.k0 * b - margin
            if out.action == "nominal":
                assert np.array_equal(out.u, u_bar) and row @ u_bar <= rhs
            elif out.action == "qp":
                grid = np.stack(np.meshgrid(*[np.linspace(l, h, 41) for l, h in zip(lb, ub)], indexing="ij"),
                                -1).reshape(-1, n)
                feasible = grid[grid @ row <= rhs]
                assert np.linalg.norm(out.u - u_bar) <= np.min(np.linalg.norm(feasible - u_bar, axis=1)) + 1e-9
            else:  # no box point meets the row (its best corner included): flagged
                assert out.infeasible and out.action == "clipped" and row @ np.where(row > 0, lb, ub) > rhs
            assert np.array_equal(np.array(filt.bounds()[0]) + 0.5, out.u)  # the next box is centred on u sent


def test_sampled_data_parameters_are_one_error():
    with pytest.raises(ValueError, match=r"rate_hPa_per_s must be in \(0, 1e\+06\] hPa/s, got 0"):
        sdcbf(_context(2), rate_hPa_per_s=0.0)
    with pytest.raises(ValueError, match="lipschitz_factor"):
        check_filter("sdcbf", {"lipschitz_factor": "0.5"})
    assert FILTERS["sdcbf"] is sdcbf and set(sdcbf.parameter_docs) == set(SAMPLED_PARAMETERS)
    assert isinstance(build_filter("sdcbf", {"rate_hPa_per_s": "200"}, _context(3)), SampledDataCBF)


@pytest.mark.parametrize("robot", ["reference", "three-segment"])
def test_sdcbf_keeps_the_tip_in_p_on_the_paper_sinusoid(tmp_path, robot):
    """PCC plant = model, 1 kHz: the tip stays in P, every step within the rate box; with two segments the first
    300 steps pass u_nom unchanged."""
    series = _paper_sim(tmp_path, "sdcbf", robot)
    assert series["rho_meas"].min() >= 0.0 and not series["infeasible"].any()
    assert np.abs(np.diff(series["u"], axis=0)).max() <= 1.0 + 1e-9  # r T = 1000 hPa/s × 1 ms
    if robot == "reference":
        assert np.array_equal(series["u"][:300], series["u_nom"][:300])


# -- backup CBF -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", SEGMENTS)
def test_backup_energy_and_its_decay_along_the_held_flow(n):
    """W_v = ½q̇ᵀMq̇ + ½(q − q_v)ᵀK(q − q_v) against the model's M, and Ẇ_v = −q̇ᵀDq̇ ≤ 0 under v held (a central
    difference along the flow): the backup set's invariance."""
    robot = _robot(n)
    filt = BackupCBF(_context(n))
    dynamics = PCCDynamics(robot)
    static_gain, stiffness, damping = robot.array("gains") / robot.array("stiffness"), robot.array("stiffness"), \
        robot.array("damping")

    def energy(q, qd, v):
        core = dynamics.model_terms(list(q), list(qd))
        return filt.energy(core.kin[None, :], core.dyn[None, :], np.concatenate((q, qd))[None, :], v[None, :])[0]

    for q, qd, v in _states(n):
        e = q - static_gain * v
        assert energy(q, qd, v) == pytest.approx(0.5 * qd @ dynamics.mass_matrix(q) @ qd + 0.5 * e @ (stiffness * e))
        qdd, tau = dynamics.acceleration(q, qd, v), 1e-6
        rate = (energy(q + tau * qd, qd + tau * qdd, v) - energy(q - tau * qd, qd - tau * qdd, v)) / (2 * tau)
        assert rate == pytest.approx(-qd @ (damping * qd), rel=1e-5, abs=1e-9)


@pytest.mark.parametrize("n", SEGMENTS)
def test_backup_barrier_and_escape_bound_against_brute_force(n):
    """b from the rollout rows equals h' − H' r(q); Γ̲(v) is below ½(q − q_v)ᵀK(q − q_v) at every boundary point found
    by a dense search (the backup set lies inside P)."""
    robot, safe_set = _robot(n), paper_safe_set()
    filt = BackupCBF(_context(n))
    dynamics = PCCDynamics(robot)
    H, h = np.array(safe_set.H_prime), np.array(safe_set.h_prime)
    rng = np.random.default_rng(3)
    static_gain, stiffness = robot.array("gains") / robot.array("stiffness"), robot.array("stiffness")
    for q, qd, v in _states(n):
        core = dynamics.model_terms(list(q), list(qd))
        tip = core.kin[dynamics.layout.tip_terms.start]
        np.testing.assert_allclose(filt.barrier(core.kin[None, :])[0], h - H @ [tip.real, tip.imag], atol=1e-15)
        gamma = filt.escape(v[None, :])[0]
        rest = static_gain * v

        def b_at(config):
            tip = dynamics.model_terms(list(config), [0.0] * n).kin[dynamics.layout.tip_terms.start]
            return h[0] - H[0] @ [tip.real, tip.imag]

        found = []
        for s in rest + rng.normal(0.0, 0.6, (300, n)):  # boundary points by bisection on segments from q_v
            lo, hi = 0.0, 1.0
            if np.sign(b_at(rest)) == np.sign(b_at(s)):
                continue
            for _ in range(50):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if np.sign(b_at(rest + mid * (s - rest))) == np.sign(b_at(rest)) else (lo, mid)
            e = hi * (s - rest)
            found.append(0.5 * e @ (stiffness * e))
        assert found and gamma <= min(found) + 1e-12


def test_backup_passes_u_nom_at_rest_far_inside_and_refuses_bad_parameters():
    """From rest, straight (the tip 33–77 mm inside P), commands that bend the arm away from P pass unchanged."""
    for n in SEGMENTS:
        for backup in ("vent", "hold"):
            for u_nom in (np.full(n, -60.0), np.full(n, -150.0), np.full(n, -20.0)):
                out = BackupCBF(_context(n), backup=backup)(Estimate(0.0, np.zeros(n), np.zeros(n), 0.0), u_nom)
                assert out.action == "nominal" and np.array_equal(out.u, u_nom) and not out.infeasible
    with pytest.raises(ValueError, match="backup must be one of vent, hold, got 'brake'"):
        BackupCBF(_context(2), backup="brake")
    with pytest.raises(ValueError, match="horizon_s must be in"):
        check_filter("backup-cbf", {"horizon_s": "-1"})
    with pytest.raises(ValueError, match="levels"):
        BackupCBF(_context(2), levels=0)
    assert FILTERS["backup-cbf"] is BackupCBF and set(BackupCBF.parameter_docs) == {"backup", "horizon_s", "levels"}


@pytest.mark.slow
@pytest.mark.parametrize("backup", ["vent", "hold"])
@pytest.mark.parametrize("robot", ["reference", "three-segment"])
def test_backup_cbf_keeps_the_tip_in_p_on_the_paper_sinusoid(tmp_path, robot, backup):
    """PCC plant = model, exact state, 1 kHz: the tip stays in P with either backup; with two segments (5 s, the tip
    reaches P's boundary) the first second passes u_nom unchanged; three segments for 2 s (slower: 7–8 ms a call)."""
    out = tmp_path / "run"
    assert main(["run", "paper_sim", "--filter", "backup-cbf", "--filter-param", f"backup={backup}", "--robot", robot,
                 "--duration", "5" if robot == "reference" else "2", "--frequency", "0.1", "--out", str(out),
                 "--progress", "false"]) == 0
    (row,) = read_run_folder(out).summary["runs"]
    series, _ = load_timeseries(out / row["timeseries"])
    assert series["rho_meas"].min() >= 0.0 and not series["infeasible"].any()
    assert not np.array_equal(series["u"], series["u_nom"])
    if robot == "reference":
        assert series["rho_meas"].min() < 0.01  # it let the tip reach the plate: F_max, not less
        assert np.array_equal(series["u"][:1000], series["u_nom"][:1000])
