"""Scenario `paper_sim`: the paper's simulation (§V, Table I) on the PCC plant.

The paper's sinusoid u_nom,j = A sin(2π f (t + t0)) drives both segments into one facet;
the controller sees the exact state at the control rate; None/Low/High tunings of the
paper's filter by default, any filter and nominal controller by `filter`, `nominal`
(scenarios.common).
By default there are no pressure limits, as in the paper (docs/model.md#control-barrier-function).

Batch form (studies, docs/studies.md#batches): samples that differ only in q0 (`seed`,
`q0_std`) and the nominal (`amplitude`, `frequency`, `nominal_params`) run together on
`PCCBatchPlant` (`run_paper_batch`); both paths build a sample with `paper_setup`.

The spec (`PaperSim`, scenarios.spec) holds the sections `run`, `filter`, `nominal` and `model`
(the controller's robot is also the PCC plant's, its damping × `damping_scale`: the same numbers, never
the same objects, for the plant integrates arrays of its own and each plug-in is handed its own copy of the
context, `scenarios.common.control_step`) and three
settings of its own: `plate_stiffness` (N/m, the true plate's and the controller's ψ),
`integrator` and `control_rate` (Hz).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from controllers.model.params import RobotParams
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import FilterContext
from scenarios import BatchForm, register
from scenarios.batch_form import run_batch_tuning
from scenarios.common import (
    Controller, ControllerRun, check_choice, check_controller, control_step, controller_row, initial_configuration,
    run_tuning, scene_record, stop_after,
)
from scenarios.spec import Filter, Model, Nominal, Run, scenario_spec
from softcbf_mj.loops.loop import check_duration
from softcbf_mj.outputs.metrics import write_table
from softcbf_mj.outputs.runio import SummaryWriter

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_min", "rho_min_meas", ".4f"),
    ("F peak [N]", "force_max_N", ".4f"),
    ("t_viol [s]", "t_violation_s", ".3f"),
    ("|u|peak [hPa]", "u_peak_abs_hPa", ".1f"),
    ("infeasible", "infeasible_steps", "d"),
    ("recovery", "recovery_steps", "d"),
    ("chatter [1/s]", "chatter_per_s", ".1f"),
    ("u HF [%]", "u_hf_fraction", ".1f", 100.0),
    ("filter med [us]", "filter_us_median", ".1f"),
    ("filter p99 [us]", "filter_us_p99", ".1f"),
    ("RTF", "realtime_factor", ".1f"),
)



def check_spec(spec: PaperSim) -> Controller:
    """The checks of a `paper_sim` spec beyond its values' (scenarios.spec): the controller, the integrator;
    returns the controller it built (`spec.built`)."""
    from softcbf_mj.physics.pcc_plant import INTEGRATORS  # the compiled model (numba): +2.3 s to import, where a run starts
    controller = check_controller(spec.filter, spec.nominal, spec.model, spec.plate_stiffness)
    check_choice("integrator", spec.integrator, INTEGRATORS)
    return controller


PaperSim = scenario_spec(
    "PaperSim", "The spec of scenario `paper_sim` (module docstring): the run, the controller under test, the nominal, "
                "the controller's model (also the PCC plant's), the plate's spring (true and assumed), the integrator "
                "and the control rate.",
    "paper_sim", {"run": Run, "filter": Filter, "nominal": Nominal, "model": Model},
    {"plate_stiffness": "plate_stiffness", "integrator": "integrator", "control_rate": "control_rate"},
    check=check_spec, module=__name__)


@dataclass(frozen=True, eq=False)
class PaperSetup:
    """What one `paper_sim` sample builds before its plant: robot (the plant's and the
    controller's), safe set, controllers, nominal parameters, q0 (N,) rad, control period (s)."""

    robot: RobotParams
    safe_set: ForceSafeSet
    runs: tuple[ControllerRun, ...]
    nominal_kwargs: dict[str, object]
    q0: np.ndarray
    control_dt: float

    def context(self, pressure_limits: bool) -> FilterContext:
        """The loop's context: what the filters and the nominal are told (each its own copy, `control_step`)."""
        return FilterContext.for_robot(self.robot, self.safe_set, self.control_dt, pressure_limits,
                                       actuator_tau=0.0, command_delay=0.0)


def paper_setup(spec: PaperSim) -> PaperSetup:
    """What the single run and the batch form of the (checked) `spec` share: the controller its check built
    (`spec.built`), q0 and the control period."""
    controller, control_dt = spec.built, 1.0 / spec.control_rate
    check_duration(spec.run.duration, control_dt, controller.robot.n_segments, controller.safe_set)
    q0 = initial_configuration(controller.robot.n_segments, spec.run.seed, spec.run.q0_std)
    return PaperSetup(controller.robot, controller.safe_set, controller.runs, controller.nominal_kwargs, q0,
                      control_dt)


PAPER_BATCH_VARYING = frozenset({"seed", "q0_std", "amplitude", "frequency", "t0", "nominal_params", "filter_params",
                                 "progress"})
"""Parameters that may differ between the samples of one batch (q0, the nominal, the filter's parameters:
`scenarios.batch_form.run_batch_tuning`)."""


def paper_batch_key(params: Mapping[str, Any]) -> tuple:
    """What the samples of one batch share: every flat parameter but `PAPER_BATCH_VARYING`."""
    return tuple(sorted((k, v) for k, v in params.items() if k not in PAPER_BATCH_VARYING))


def run_paper_batch(samples: Sequence[Mapping[str, Any]], nthread: int = 1,
                    progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """Run `paper_sim` samples (flat parameters) that share `paper_batch_key` (each one tuning) on one
    `PCCBatchPlant` (numpy, `nthread` unused); one row of run figures per sample
    (`scenarios.batch_form.run_batch_tuning`)."""
    if len({paper_batch_key(p) for p in samples}) != 1:
        raise ValueError("samples of one batch must share paper_batch_key")
    specs = [PaperSim.from_flat(p) for p in samples]
    setups = [paper_setup(s) for s in specs]
    if any(len(s.runs) != 1 for s in setups):
        raise ValueError("each sample of a batch must run exactly one tuning")
    first, spec = setups[0], specs[0]
    from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant  # the compiled model (numba): +2.3 s to import, where a run starts
    plant = PCCBatchPlant(first.robot, first.safe_set, len(setups), control_dt=first.control_dt,
                          integrator=spec.integrator)
    return run_batch_tuning(plant, [s.runs[0] for s in setups], first.context(spec.filter.pressure_limits), spec.nominal.name,
                            [s.nominal_kwargs for s in setups], spec.run.duration, np.array([s.q0 for s in setups]),
                            progress)


@register("paper_sim", "the paper's Table I: PCC simulation, sinusoid into one facet, None/Low/High",
          PaperSim, BatchForm(paper_batch_key, run_paper_batch))
def paper_sim(out_dir: Path, spec: PaperSim) -> dict:
    """Run each controller (tuning) of `spec` for its duration; write summary.json and one time series per run."""
    from softcbf_mj.physics.pcc_plant import PCCPlant  # the compiled model (numba): +2.3 s to import, where a run starts
    setup = paper_setup(spec)
    summary = SummaryWriter(out_dir, "paper_sim", spec.flat(), scene_record(setup.robot, setup.safe_set,
                                                                            spec.plate_stiffness))
    for run in setup.runs:
        plant = PCCPlant(setup.robot, setup.safe_set, control_dt=setup.control_dt, integrator=spec.integrator)
        step = control_step(run, spec.nominal.name, setup.nominal_kwargs, setup.context(spec.filter.pressure_limits))
        row = run_tuning(out_dir, summary, run.label, plant, step, setup.safe_set, spec.run.duration, setup.q0,
                         spec.run.progress, row=controller_row(run, spec.nominal.name, setup.nominal_kwargs))
        if stop_after(row):
            break
    print(f"paper_sim: {spec.run.duration:g} s, pressure limits {'on' if spec.filter.pressure_limits else 'off'}; "
          f"outputs in {out_dir}")
    print(write_table(out_dir, summary.data["runs"], TABLE))
    return summary.data
