"""Batched closed loops against today's serial loop on the same samples (PCC and MuJoCo)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from closedloop.step import ControlStep
from controllers.cbf.barrier import TUNINGS
from controllers.cbf.batch import SCALAR_BELOW
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import FilterContext
from softcbf_mj.loops.batch_loop import run_batch_closed_loop
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.outputs.metrics import run_figures
from softcbf_mj.physics.mjcf import ArmModelConfig
from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
from softcbf_mj.physics.pcc_plant import PCCPlant

FIGURES = ("rho_min_pred", "rho_min_meas", "force_max_N", "t_violation_s", "infeasible_steps", "u_peak_abs_hPa")
PEAK = SinusoidNominal((80.0, 80.0), 0.01, (math.pi / 2, math.pi / 2))  # the paper's sinusoid at its peak


def _true_robots(n: int):
    """The reference arm with stiffness and gain off by up to ±10 % (a mismatch study's true arms)."""
    ref = reference_robot()
    scales = np.random.default_rng(4).uniform(0.9, 1.1, (n, 2))
    return [dataclasses.replace(ref, stiffness=tuple(v * s for v in ref.stiffness), gains=tuple(v * g for v in ref.gains))
            for s, g in scales]


def _serial(plant, safety_filter, nominal, safe_set, pressure_limits, duration, q0):
    """The serial loop's log of one sample: the control step clips to the model's limits when `pressure_limits`."""
    context = FilterContext.for_robot(reference_robot(), safe_set, plant.control_dt, pressure_limits)
    log, _ = run_closed_loop(plant, ControlStep(safety_filter, nominal, context), safe_set, duration, q0)
    return log


def _compare(batch, serial_logs, control_dt, filtered):
    for b, log in enumerate(serial_logs):
        want = run_figures(log, control_dt, filtered, 1.0)
        got = batch.run(b)
        for key in FIGURES:
            if isinstance(want[key], int):
                assert got[key] == want[key], (b, key)
            else:
                assert got[key] == pytest.approx(want[key], rel=0.0, abs=1e-9), (b, key)
        np.testing.assert_allclose(batch.commands[:, b], log["u"], rtol=0.0, atol=1e-9)


@pytest.mark.parametrize("tuning, pressure_limits, per_sim_filters",
                         [("Low", False, False), ("HW-High", True, False), ("HW-High", True, True)])
def test_pcc_batch_loop_equals_serial_loops(tuning, pressure_limits, per_sim_filters):
    params, safe_set, robots = reference_robot(), paper_safe_set(), _true_robots(6)
    q0 = np.random.default_rng(5).normal(0.3, 0.1, (6, 2))
    duration = 1.5
    plant = PCCBatchPlant(robots, safe_set, 6)

    def controller():
        return CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=pressure_limits)

    filt = [controller() for _ in range(6)] if per_sim_filters else controller()
    context = FilterContext.for_robot(params, safe_set, plant.control_dt, pressure_limits)
    batch = run_batch_closed_loop(plant, filt, PEAK, context, duration, q0, record_commands=True)
    logs = [_serial(PCCPlant(r, safe_set), controller(), PEAK, safe_set, pressure_limits, duration, q0[b])
            for b, r in enumerate(robots)]
    _compare(batch, logs, plant.control_dt, True)
    assert np.all(batch.figures.force_max_N > 0), "every sample must reach the facet"
    assert np.all(batch.figures.refused == 0)


def test_mujoco_batch_loop_equals_serial_loops():
    params, safe_set = reference_robot(), paper_safe_set()
    configs = [ArmModelConfig(robot=r, plate_stiffness=k, links_per_segment=4, physics_dt=2e-4)
               for r, k in zip(_true_robots(4), (11.16, 13.0, 9.5, 12.0))]
    q0 = np.random.default_rng(6).normal(0.2, 0.05, (4, 2))
    amplitudes = (100.0, 120.0, 140.0, 110.0)
    nominals = [SinusoidNominal((a, a), 0.01, (math.pi / 2, math.pi / 2)) for a in amplitudes]
    duration = 0.6
    plant = MujocoBatchPlant.from_configs(configs, nthread=2)
    controller = CBFFilter(params, safe_set, TUNINGS["HW-High"])
    context = FilterContext.for_robot(params, safe_set, plant.control_dt)
    batch = run_batch_closed_loop(plant, controller, nominals, context, duration, q0, record_commands=True)
    logs = [_serial(MujocoPlant.from_config(c), CBFFilter(params, safe_set, TUNINGS["HW-High"]), nominal, safe_set, True,
                    duration, q0[b]) for b, (c, nominal) in enumerate(zip(configs, nominals))]
    _compare(batch, logs, plant.control_dt, True)
    assert len(configs) >= SCALAR_BELOW, "the batch must take the vectorised filter"
    assert np.all(batch.figures.force_max_N > 0), "every sample must press the plate"


def test_non_finite_commands_are_held_as_in_a_single_run():
    """A NaN command is refused as the serial step refuses it: the last admitted command is held."""
    safe_set = paper_safe_set()
    plant = PCCBatchPlant(reference_robot(), safe_set, 2)

    def broken(estimate, u_nom):
        return np.array([np.nan, 0.0]) if estimate.t >= 0.005 else u_nom

    context = FilterContext.for_robot(reference_robot(), safe_set, plant.control_dt)
    run = run_batch_closed_loop(plant, broken, PEAK, context, 0.01, np.zeros((2, 2)), record_commands=True)
    np.testing.assert_array_equal(run.figures.refused, [5, 5])
    np.testing.assert_array_equal(run.commands[5:], np.broadcast_to(run.commands[4], run.commands[5:].shape))
    assert np.all(run.commands[4] != 0.0)
    assert run.run(0)["rho_min_pred"] is None  # a bare-array filter predicts nothing
    serial = _serial(PCCPlant(reference_robot(), safe_set), broken, PEAK, safe_set, True, 0.01, np.zeros(2))
    np.testing.assert_array_equal(run.commands[:, 0], serial["u"])


def test_a_shared_nominal_batch_gives_the_per_row_calls_bit_for_bit():
    """SinusoidNominal.nominal_batch (one call per period) against the same nominal called row by row (a list of
    B instances has no shared nominal_batch): the same commands, bit for bit."""
    safe_set, robot = paper_safe_set(), reference_robot()
    context = FilterContext.for_robot(robot, safe_set, 1e-3)
    q0 = np.array([[0.1, 0.2], [0.3, -0.1], [0.0, 0.0]])
    push = SinusoidNominal((150.0, 120.0), 0.37, (0.3, 1.1))
    shared = run_batch_closed_loop(PCCBatchPlant(robot, safe_set, 3), lambda e, u: u, push, context, 0.3, q0,
                                   record_commands=True)
    per_row = run_batch_closed_loop(PCCBatchPlant(robot, safe_set, 3), lambda e, u: u, [push] * 3, context, 0.3, q0,
                                    record_commands=True)
    np.testing.assert_array_equal(shared.commands, per_row.commands)
    assert np.any(shared.commands != 0.0)


class BrokenBatchNominal:
    """A nominal whose nominal_batch raises (how = "raise") or returns the wrong shape (how = "shape") from t_bad on."""

    capabilities = Capabilities(batched=True)

    def __init__(self, how: str, t_bad: float) -> None:
        self.how, self.t_bad = how, t_bad

    def __call__(self, t, q, qd):
        return np.full(2, 50.0)

    def nominal_batch(self, t, q, qd):
        if np.any(t >= self.t_bad):
            if self.how == "raise":
                raise KeyError("broken nominal")
            return np.zeros((len(t), 3))
        return np.full((len(t), 2), 50.0)


@pytest.mark.parametrize("how, fault_type", [("raise", "KeyError"), ("shape", "FilterReturnError")])
def test_a_faulty_nominal_batch_is_a_nominal_fault_of_every_row_it_was_called_for(how, fault_type):
    safe_set, robot = paper_safe_set(), reference_robot()
    context = FilterContext.for_robot(robot, safe_set, 1e-3)
    run = run_batch_closed_loop(PCCBatchPlant(robot, safe_set, 2), lambda e, u: u, BrokenBatchNominal(how, 0.01),
                                context, 0.1, np.zeros((2, 2)), record_commands=True)
    for b in range(2):
        fault = run.faults[b]
        assert (fault.type, fault.where, fault.t) == (fault_type, "nominal", 0.01)
        # held for the monitor's hold (0.5 s > the run): every row from the fault on holds the last command
        np.testing.assert_array_equal(run.commands[10:, b], np.broadcast_to([50.0, 50.0], (90, 2)))
        assert run.run(b)["refused_steps"] == 90


def test_a_batch_steps_records_are_its_own_arrays():
    """BatchControlStep's call makes its record's arrays as copies of the step's templates: writing into one
    call's record changes neither the next call's record nor what the step sends, for B = 1 and B = 3, a row
    not stepped and a refused nominal among them."""
    from closedloop.step import BatchControlStep
    from controllers.core.errors import ControllerInputError

    context = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)

    def refuses_row_1(t, q, qd):
        if q[0] == 1.0:
            raise ControllerInputError("row 1 refused")
        return PEAK(t, q, qd)

    for n_sims in (1, 3):
        def make():
            step = BatchControlStep(lambda estimate, u_nom: u_nom, refuses_row_1, context, n_sims)
            step.reset()
            return step

        written, clean = make(), make()
        q = np.zeros((n_sims, 2))
        q[1:, 0] = 1.0
        rows = np.ones(n_sims, dtype=bool)
        rows[-1] = n_sims == 1  # the last of three rows is not stepped
        for k in range(3):
            t = np.full(n_sims, k * 1e-3)
            got, want = written(t, q, q, rows=rows), clean(t, q, q, rows=rows)
            for key in ("u_filter", "rho_pred", "infeasible", "output", "filter_us", "u", "action"):
                value = getattr(got, key)
                if key != "filter_us":  # (wall-clock times)
                    np.testing.assert_array_equal(value, getattr(want, key), err_msg=f"{n_sims} {k} {key}")
                value[...] = 7  # a caller's write into its record
            np.testing.assert_array_equal(got.u_nom, want.u_nom)
            assert np.isnan(got.u_nom[1:]).all() and np.isfinite(got.u_nom[0]).all()
