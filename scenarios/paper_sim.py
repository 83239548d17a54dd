"""Scenario `paper_sim`: the paper's simulation (§V, Table I) on the PCC plant.

The paper's sinusoid u_nom,j = A sin(2π f t) drives both segments into one facet;
the controller sees the exact state at the control rate; None/Low/High tunings of the
paper's filter by default, any filter and nominal controller by `filter`, `nominal`
(scenarios.common).
By default there are no pressure limits, as in the paper (docs/model.md#control-barrier-function).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from controllers.safety_filter import FilterContext
from scenarios import register
from scenarios.common import (
    COMMON_BOUNDS, PAPER_FILTER, build_safe_set, check_bounds, check_choice, check_controller_parameters, control_step, controller_row,
    controller_runs, initial_configuration, load_robot, non_negative, nominal_arguments, positive, run_tuning, scene_record,
)
from softcbf_mj.loop import check_duration
from softcbf_mj.metrics import format_table
from softcbf_mj.pcc_plant import INTEGRATORS, PCCPlant
from softcbf_mj.runio import SummaryWriter

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


BOUNDS = {"duration": positive("s"), "frequency": non_negative("Hz"), "f_max": positive("N"),
          "plate_stiffness": positive("N/m"), "control_rate": positive("Hz")}


def check_parameters(params: Mapping[str, Any]) -> None:
    """The checks `paper_sim` makes before it builds anything (`scenarios.Scenario.validate`)."""
    check_bounds(params, BOUNDS)
    check_controller_parameters(params, "plate_stiffness")
    check_choice("integrator", params["integrator"], INTEGRATORS)


@register("paper_sim", "the paper's Table I: PCC simulation, sinusoid into one facet, None/Low/High",
          check_parameters, {**COMMON_BOUNDS, **BOUNDS})
def paper_sim(
    out_dir: Path,
    *,
    duration: float = 100.0,
    tunings: str = "None,Low,High",
    filter: str = PAPER_FILTER,
    filter_params: str = "",
    nominal: str = "sinusoid",
    nominal_params: str = "",
    amplitude: float = 80.0,
    frequency: float = 0.01,
    pressure_limits: bool = False,
    environment: str = "paper",
    f_max: float = 0.16,
    plate_stiffness: float = 11.16,
    row_scaling: str = "paper",
    robot: str = "reference",
    integrator: str = "ros2",
    control_rate: float = 1000.0,
    qp_backend: str = "native",
    seed: int = 0,
    q0_std: float = 0.0,
    progress: bool = True,
) -> dict:
    """Run each controller (tuning) for `duration` s; write summary.json and one time series per run."""
    params = dict(locals())
    params.pop("out_dir")
    check_parameters(params)
    robot_params = load_robot(robot)
    safe_set = build_safe_set(environment, plate_stiffness, f_max, row_scaling)
    check_duration(duration, 1.0 / control_rate, robot_params.n_segments, safe_set)
    runs = controller_runs(filter, filter_params, tunings, qp_backend)
    nominal_kwargs = nominal_arguments(nominal, nominal_params, amplitude=amplitude, frequency=frequency)
    q0 = initial_configuration(robot_params.n_segments, seed, q0_std)
    summary = SummaryWriter(out_dir, "paper_sim", params, scene_record(robot_params, safe_set, plate_stiffness))
    for run in runs:
        plant = PCCPlant(robot_params, safe_set, control_dt=1.0 / control_rate, integrator=integrator)
        context = FilterContext.for_robot(robot_params, safe_set, plant.control_dt, pressure_limits,
                                          actuator_tau=0.0, command_delay=0.0, dynamics=plant.dynamics)
        step = control_step(run, nominal, nominal_kwargs, context)
        run_tuning(out_dir, summary, run.label, plant, step, safe_set, duration, q0, progress,
                   row=controller_row(run, nominal, nominal_kwargs))
    print(f"paper_sim: {duration:g} s, pressure limits {'on' if pressure_limits else 'off'}; outputs in {out_dir}")
    print(format_table(summary.data["runs"], TABLE))
    return summary.data
