"""Scenario `pcc_contact`: `mujoco_contact`'s model errors on the PCC plant, the cheap twin for screening.

Why: a MuJoCo evaluation of the paper's sinusoid runs at about 4× real time, the PCC plant at about 24×
(docs/studies.md#multi-fidelity-falsification). A falsification can search the error box on this plant and
confirm its worst candidates on MuJoCo (`softcbf.study.screen`) only if this plant carries the same errors,
under the same names and meanings, as `mujoco_contact`.

The plant (`PCCPlant`, docs/model.md#rppr-dynamics) is the true arm: the controller's robot with, per segment,
L_i × `true_length_scale` (I_i × its square), k_i × `true_stiffness_scale`, d_i × `true_damping_scale` and
λ_i × `true_gain_scale` (`softcbf_mj.physics.ground_truth.scaled_robot`, the construction `mujoco_contact` uses), its
valve a first-order lag of `tau_p` s behind a command delay of `command_delay` s (whole 1 ms control periods, a FIFO:
softcbf_mj.physics.plant), as the MuJoCo plant's; the filter is told `assumed_tau_p` and `assumed_command_delay`, as there.
The true plates
are the controller's facets moved by `facet_offset` (m) along their outward normals and turned by
`facet_angle` (rad) (`softcbf_mj.physics.ground_truth.moved_facets`), each a linear spring of `plate_stiffness` N/m:
the plant's contact force is ψ_true(n_true(r)) at the PCC tip r. The controller keeps its model: robot,
facets and ψ(n) = `assumed_plate_stiffness` · n; ρ_meas is its margin of the plant's force.

Assumptions (what the cheap plant leaves out, so what a screen cannot see): the arm is constant curvature
(no rod bending under load: MuJoCo's loaded-rod penetration bias), the plate is massless (no impact peak) and
ideal (no flexure sheet), no gravity and no friction. These settings are not parameters here, so a study that
varies or fixes one cannot be screened on this plant (`softcbf.study.screen` names it).

Settings: the sections `run`, `filter`, `nominal` and `model` (scenarios.spec), the true arm's scales,
`tau_p`, `command_delay`, `facet_offset`, `facet_angle`, `plate_stiffness`, `assumed_plate_stiffness`, `assumed_tau_p`,
`assumed_command_delay` and the PCC plant's
`integrator`; the controller runs at 1 kHz (`CONTROL_DT`, as `mujoco_contact`'s); pressure limits on by
default (as `mujoco_contact`).

Batch form (studies, docs/studies.md#batches): samples that differ only in the true arm's scales, q0, the
nominal and the filter's parameters run together on `PCCBatchPlant` (one true robot per simulation); the
plates, the valve and the command delay are the batch's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from controllers.model.params import RobotParams
from controllers.model.safe_set import ForceSafeSet, LinearStiffness
from controllers.contract.safety_filter import FilterContext
from scenarios import BatchForm, register
from scenarios.batch_form import run_batch_tuning
from scenarios.common import (
    Controller, ControllerRun, check_choice, check_controller, control_step, controller_row,
    initial_configuration, run_tuning, scene_record, stop_after,
)
from scenarios.spec import Filter, Model, Nominal, Run, scenario_spec
from softcbf_mj.physics.ground_truth import moved_facets, scaled_robot
from softcbf_mj.loops.loop import check_duration
from softcbf_mj.outputs.metrics import write_table
from softcbf_mj.physics.plant import delay_periods
from softcbf_mj.outputs.runio import SummaryWriter

CONTROL_DT = 1e-3  # s, the paper's 1 kHz (mujoco_contact's)

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_meas", "rho_min_meas", ".4f"),
    ("F peak [N]", "force_max_N", ".4f"),
    ("t_viol [s]", "t_violation_s", ".3f"),
    ("|u|peak [hPa]", "u_peak_abs_hPa", ".1f"),
    ("infeasible", "infeasible_steps", "d"),
    ("filter med [us]", "filter_us_median", ".1f"),
    ("RTF", "realtime_factor", ".1f"),
)


def check_spec(spec: PccContact) -> Controller:
    """The checks of a `pcc_contact` spec beyond its values' (scenarios.spec): the controller (its model and the
    assumed plate), the integrator and the true plates (the moved facets still bound a free space); returns the
    controller it built (`spec.built`)."""
    from softcbf_mj.physics.pcc_plant import INTEGRATORS  # the compiled model (numba): +2.3 s to import, where a run starts
    controller = check_controller(spec.filter, spec.nominal, spec.model, spec.assumed_plate_stiffness)
    check_choice("integrator", spec.integrator, INTEGRATORS)
    delay_periods(spec.command_delay, CONTROL_DT)
    true_plates(spec, controller.safe_set)
    return controller


PccContact = scenario_spec(
    "PccContact", "The spec of scenario `pcc_contact` (module docstring): the run, the controller under test, the "
                  "nominal, the controller's model, the true arm's scales and valve lag, the true plates' pose and "
                  "stiffness, the plate stiffness the controller assumes and the PCC integrator.",
    "pcc_contact", {"run": Run, "filter": Filter, "nominal": Nominal, "model": Model},
    {"true_stiffness_scale": "true_stiffness_scale", "true_damping_scale": "true_damping_scale",
     "true_gain_scale": "true_gain_scale", "true_length_scale": "true_length_scale", "tau_p": "tau_p",
     "command_delay": "command_delay",
     "facet_offset": "facet_offset", "facet_angle": "facet_angle", "plate_stiffness": "plate_stiffness",
     "assumed_plate_stiffness": "assumed_plate_stiffness", "assumed_tau_p": "assumed_tau_p",
     "assumed_command_delay": "assumed_command_delay", "integrator": "integrator"},
    check=check_spec, module=__name__)


def true_plates(spec: PccContact, safe_set: ForceSafeSet) -> ForceSafeSet:
    """The plant's plates (module docstring): the controller's facets moved and turned, ψ_true = `plate_stiffness`."""
    moved = moved_facets(safe_set.environment, spec.facet_offset, spec.facet_angle)
    return ForceSafeSet(moved, LinearStiffness(spec.plate_stiffness), safe_set.f_max,
                        row_scaling=safe_set.row_scaling)


def true_robot(spec: PccContact, model_robot: RobotParams) -> RobotParams:
    """The plant's arm (module docstring): the controller's robot with the `true_*_scale` factors."""
    return scaled_robot(model_robot, spec.true_length_scale, spec.true_stiffness_scale, spec.true_damping_scale,
                        spec.true_gain_scale)


@dataclass(frozen=True, eq=False)
class PccContactSetup:
    """What one `pcc_contact` sample builds before its plant: the controller's safe set, the true arm and plates,
    the controllers, the nominal's parameters, q0 (N,) rad and the filters' context."""

    safe_set: ForceSafeSet
    robot: RobotParams
    plates: ForceSafeSet
    runs: tuple[ControllerRun, ...]
    nominal_kwargs: dict[str, object]
    q0: np.ndarray
    context: FilterContext


def pcc_contact_setup(spec: PccContact) -> PccContactSetup:
    """What the single run and the batch form of the (checked) `spec` share (its check built the controller)."""
    controller = spec.built
    safe_set = controller.safe_set
    check_duration(spec.run.duration, CONTROL_DT, controller.robot.n_segments, safe_set)
    q0 = initial_configuration(controller.robot.n_segments, spec.run.seed, spec.run.q0_std)
    context = FilterContext.for_robot(controller.robot, safe_set, CONTROL_DT, spec.filter.pressure_limits,
                                      command_delay=spec.assumed_command_delay, actuator_tau=spec.assumed_tau_p)
    return PccContactSetup(safe_set, true_robot(spec, controller.robot), true_plates(spec, safe_set), controller.runs,
                           controller.nominal_kwargs, q0, context)


BATCH_VARYING = frozenset({
    "true_stiffness_scale", "true_damping_scale", "true_gain_scale", "true_length_scale", "seed", "q0_std",
    "amplitude", "frequency", "t0", "nominal_params", "filter_params", "progress",
})
"""Parameters that may differ between the samples of one batch (the true arm per simulation, q0, the nominal, the
filter's parameters: `scenarios.batch_form.run_batch_tuning`); the plates, the valve and the command delay are
shared."""


def pcc_contact_batch_key(params: Mapping[str, Any]) -> tuple:
    """What the samples of one batch share: every flat parameter but `BATCH_VARYING`."""
    return tuple(sorted((k, v) for k, v in params.items() if k not in BATCH_VARYING))


def run_pcc_contact_batch(samples: Sequence[Mapping[str, Any]], nthread: int = 1,
                          progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """Run `pcc_contact` samples (flat parameters) that share `pcc_contact_batch_key` (each one tuning) on one
    `PCCBatchPlant` (numpy, `nthread` unused); one row of run figures per sample."""
    if len({pcc_contact_batch_key(p) for p in samples}) != 1:
        raise ValueError("samples of one batch must share pcc_contact_batch_key")
    specs = [PccContact.from_flat(p) for p in samples]
    setups = [pcc_contact_setup(s) for s in specs]
    if any(len(s.runs) != 1 for s in setups):
        raise ValueError("each sample of a batch must run exactly one tuning")
    first, spec = setups[0], specs[0]
    from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant  # the compiled model (numba): +2.3 s to import, where a run starts
    plant = PCCBatchPlant([s.robot for s in setups], first.plates, len(setups), control_dt=CONTROL_DT,
                          integrator=spec.integrator, tau_p=spec.tau_p, command_delay=spec.command_delay)
    return run_batch_tuning(plant, [s.runs[0] for s in setups], first.context, spec.nominal.name,
                            [s.nominal_kwargs for s in setups], spec.run.duration, np.array([s.q0 for s in setups]),
                            progress)


@register("pcc_contact", "mujoco_contact's model errors (arm, valve, plate) on the PCC plant: a cheap screen",
          PccContact, BatchForm(pcc_contact_batch_key, run_pcc_contact_batch))
def pcc_contact(out_dir: Path, spec: PccContact) -> dict:
    """Run each controller (tuning) of `spec` for its duration; write summary.json and one time series per run."""
    from softcbf_mj.physics.pcc_plant import PCCPlant  # the compiled model (numba): +2.3 s to import, where a run starts
    setup = pcc_contact_setup(spec)
    summary = SummaryWriter(out_dir, "pcc_contact", spec.flat(),
                            scene_record(setup.robot, setup.safe_set, spec.plate_stiffness, setup.plates.environment))
    nominal = spec.nominal.name
    for run in setup.runs:
        plant = PCCPlant(setup.robot, setup.plates, control_dt=CONTROL_DT, integrator=spec.integrator,
                         tau_p=spec.tau_p, command_delay=spec.command_delay)
        row = run_tuning(out_dir, summary, run.label, plant, control_step(run, nominal, setup.nominal_kwargs,
                                                                          setup.context),
                         setup.safe_set, spec.run.duration, setup.q0, spec.run.progress,
                         row=controller_row(run, nominal, setup.nominal_kwargs))
        if stop_after(row):
            break
    print(f"pcc_contact: {spec.run.duration:g} s from t0 = {spec.nominal.t0:g} s on the PCC plant, plate "
          f"{spec.plate_stiffness:.4g} N/m (assumed {spec.assumed_plate_stiffness:g}) moved "
          f"{spec.facet_offset * 1e3:g} mm, "
          f"pressure limits {'on' if spec.filter.pressure_limits else 'off'}; outputs in {out_dir}")
    print(write_table(out_dir, summary.data["runs"], TABLE))
    return summary.data
