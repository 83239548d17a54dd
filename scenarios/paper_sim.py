"""Scenario `paper_sim`: the paper's simulation (§V, Table I) on the PCC plant.

The paper's sinusoid u_nom,j = A sin(2π f t) drives both segments into one facet;
the controller sees the exact state at the control rate; None/Low/High tunings of the
paper's filter by default, any filter and nominal controller by `filter`, `nominal`
(scenarios.common).
By default there are no pressure limits, as in the paper (docs/model.md#control-barrier-function).

Batch form (studies, docs/studies.md#batches): samples that differ only in q0 (`seed`,
`q0_std`) and the nominal (`amplitude`, `frequency`, `nominal_params`) run together on
`PCCBatchPlant` (`run_paper_batch`); both paths build a sample with `paper_setup`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from controllers.dynamics import PCCDynamics
from controllers.params import RobotParams
from controllers.safe_set import ForceSafeSet
from controllers.safety_filter import FilterContext
from scenarios import BatchForm, register
from scenarios.batch_form import run_batch_tuning
from scenarios.common import (
    ControllerRun, build_safe_set, check_bounds, check_choice, check_controller_parameters, control_step, controller_row,
    controller_runs, initial_configuration, load_robot, nominal_arguments, run_tuning, stop_after, scene_record,
)
from softcbf_mj.loop import check_duration
from softcbf_mj.metrics import format_table
from softcbf_mj.pcc_batch_plant import PCCBatchPlant
from softcbf_mj.pcc_plant import INTEGRATORS, PCCPlant
from softcbf_mj.runio import SummaryWriter
from vocabulary.settings import default

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_min", "rho_min_meas", ".4f"),
    ("F_max [N]", "force_max_N", ".4f"),
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



def check_parameters(params: Mapping[str, Any]) -> None:
    """The checks `paper_sim` makes before it builds anything (`scenarios.Scenario.validate`)."""
    check_bounds(params)
    check_controller_parameters(params, "plate_stiffness")
    check_choice("integrator", params["integrator"], INTEGRATORS)


@dataclass(frozen=True, eq=False)
class PaperSetup:
    """What one `paper_sim` sample builds before its plant: robot (the plant's and the
    controller's), safe set, controllers, nominal parameters, q0 (N,) rad, control period (s)."""

    robot: RobotParams
    safe_set: ForceSafeSet
    runs: list[ControllerRun]
    nominal_kwargs: dict[str, object]
    q0: np.ndarray
    control_dt: float

    def context(self, pressure_limits: bool, dynamics: PCCDynamics | None = None) -> FilterContext:
        """What the filters and the nominal are told (`dynamics`: the plant's, shared when given)."""
        return FilterContext.for_robot(self.robot, self.safe_set, self.control_dt, pressure_limits,
                                       actuator_tau=0.0, command_delay=0.0, dynamics=dynamics)


def paper_setup(params: Mapping[str, Any]) -> PaperSetup:
    """Check `params` (all of `paper_sim`'s keyword arguments) and build what the single run
    and the batch form share."""
    check_parameters(params)
    robot_params = load_robot(params["robot"])
    safe_set = build_safe_set(params["environment"], params["plate_stiffness"], params["f_max"], params["row_scaling"])
    control_dt = 1.0 / params["control_rate"]
    check_duration(params["duration"], control_dt, robot_params.n_segments, safe_set)
    runs = controller_runs(params["filter"], params["filter_params"], params["tunings"], params["qp_backend"])
    nominal_kwargs = nominal_arguments(params["nominal"], params["nominal_params"], amplitude=params["amplitude"],
                                       frequency=params["frequency"])
    q0 = initial_configuration(robot_params.n_segments, params["seed"], params["q0_std"])
    return PaperSetup(robot_params, safe_set, runs, nominal_kwargs, q0, control_dt)


PAPER_BATCH_VARYING = frozenset({"seed", "q0_std", "amplitude", "frequency", "nominal_params", "progress"})
"""Parameters that may differ between the samples of one batch (q0 and the nominal)."""


def paper_batch_key(params: Mapping[str, Any]) -> tuple:
    """What the samples of one batch share: every parameter but `PAPER_BATCH_VARYING`."""
    return tuple(sorted((k, v) for k, v in params.items() if k not in PAPER_BATCH_VARYING))


def run_paper_batch(samples: Sequence[Mapping[str, Any]], nthread: int = 1) -> list[dict[str, Any]]:
    """Run `paper_sim` samples that share `paper_batch_key` (each one tuning) on one `PCCBatchPlant`
    (numpy, `nthread` unused); one row of run figures per sample (`scenarios.batch_form.run_batch_tuning`)."""
    if len({paper_batch_key(p) for p in samples}) != 1:
        raise ValueError("samples of one batch must share paper_batch_key")
    setups = [paper_setup(p) for p in samples]
    if any(len(s.runs) != 1 for s in setups):
        raise ValueError("each sample of a batch must run exactly one tuning")
    first, params = setups[0], samples[0]
    plant = PCCBatchPlant(first.robot, first.safe_set, len(setups), control_dt=first.control_dt,
                          integrator=params["integrator"])
    return run_batch_tuning(plant, first.runs[0], first.context(params["pressure_limits"]), params["nominal"],
                            [s.nominal_kwargs for s in setups], params["duration"],
                            np.array([s.q0 for s in setups]))


@register("paper_sim", "the paper's Table I: PCC simulation, sinusoid into one facet, None/Low/High",
          check_parameters, batch=BatchForm(paper_batch_key, run_paper_batch))
def paper_sim(
    out_dir: Path,
    *,
    duration: float = default("duration", "paper_sim"),
    tunings: str = default("tunings", "paper_sim"),
    filter: str = default("filter", "paper_sim"),
    filter_params: str = default("filter_params", "paper_sim"),
    nominal: str = default("nominal", "paper_sim"),
    nominal_params: str = default("nominal_params", "paper_sim"),
    amplitude: float = default("amplitude", "paper_sim"),
    frequency: float = default("frequency", "paper_sim"),
    pressure_limits: bool = default("pressure_limits", "paper_sim"),
    environment: str = default("environment", "paper_sim"),
    f_max: float = default("f_max", "paper_sim"),
    plate_stiffness: float = default("plate_stiffness", "paper_sim"),
    row_scaling: str = default("row_scaling", "paper_sim"),
    robot: str = default("robot", "paper_sim"),
    integrator: str = default("integrator", "paper_sim"),
    control_rate: float = default("control_rate", "paper_sim"),
    qp_backend: str = default("qp_backend", "paper_sim"),
    seed: int = default("seed", "paper_sim"),
    q0_std: float = default("q0_std", "paper_sim"),
    progress: bool = default("progress", "paper_sim"),
) -> dict:
    """Run each controller (tuning) for `duration` s; write summary.json and one time series per run."""
    params = dict(locals())
    params.pop("out_dir")
    setup = paper_setup(params)
    summary = SummaryWriter(out_dir, "paper_sim", params, scene_record(setup.robot, setup.safe_set, plate_stiffness))
    for run in setup.runs:
        plant = PCCPlant(setup.robot, setup.safe_set, control_dt=setup.control_dt, integrator=integrator)
        step = control_step(run, nominal, setup.nominal_kwargs, setup.context(pressure_limits, plant.dynamics))
        row = run_tuning(out_dir, summary, run.label, plant, step, setup.safe_set, duration, setup.q0, progress,
                         row=controller_row(run, nominal, setup.nominal_kwargs))
        if stop_after(row):
            break
    print(f"paper_sim: {duration:g} s, pressure limits {'on' if pressure_limits else 'off'}; outputs in {out_dir}")
    print(format_table(summary.data["runs"], TABLE))
    return summary.data
