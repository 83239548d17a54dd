"""Scenario `mujoco_contact`: the paper's sinusoid against the compliant plate in MuJoCo (docs/ground-truth.md).

The ground truth is `MujocoPlant` (the discretised rod of the reference robot, docs/model.md#rppr-dynamics,
and the paper's plate on a spring of `plate_stiffness` N/m, docs/model.md#force-safe-set). The controller
under test (`CBFFilter`) runs at 1 kHz with zero-order hold and sees the exact rod state
(q_i = Σ hinge angles, q̇_i likewise: `exact_state`); its model is `robot` (the reference
parameters, or a calibration JSON from tools/calibrate.py) and its force-safe set assumes
ψ(n) = `assumed_plate_stiffness` · n with limit `f_max`. The nominal command is
u_nom,j(t) = A sin(2π f (t + t0)) on both segments (paper: A = 80 hPa, f = 0.01 Hz,
t0 = 0; t0 > 0 starts later in the cycle, e.g. t0 = 25 s starts at the peak).

Pressure limits are ON by default (the filter's QP holds the ±150 hPa box). The
MuJoCo actuators clamp to the same ctrlrange in every case, so with
`pressure_limits=False` the filter may ask for more than the arm receives
(`u` vs `u_applied` in the time series).

Per run, besides the docs/run-outputs.md fields (ρ_meas and t_violation_s from the plate's spring
force: ρ_meas = 1 − F/F_max for linear ψ, violation while F > F_max), summary.json holds
`softcbf_mj.outputs.metrics.contact_figures`: the force the controller predicts, ψ of its own
predicted penetration, against the measured plate force (RMS and max error), and the
loaded-rod penetration bias, predicted − measured penetration while in contact (m and %
of n_max; docs/ground-truth.md: a loaded rod is not constant-curvature), the solver's peak contact
force (impacts on the 10 g plate) and how often the arm touches and leaves the plate;
and `switches_per_s`, how often the filter's correction turns on and off. Time series
add the plant's extras `plate_displacement_m`, `force_solver_N` and `force_tangential_N`
(and `warning_*` counts if any). With `plate="flexure"` (docs/beyond-the-paper.md#flexure-plate) the measured force is
the sheet's gauge reading and the run also records where along the sheet the arm touches
and the sheet's stiffness there (`softcbf_mj.outputs.metrics.plate_figures`; time series
`contact_s_m`, `contact_stiffness_N_per_m`). With `table_friction` μ > 0 the arm's links slide on the
table with Coulomb friction (`softcbf_mj.physics.table_friction`; time series `table_friction_power_W`);
such samples have no batch form. Results and the benchmark: models/softcbf_arm/README.md.

The spec (`MujocoContact`, scenarios.spec) holds the sections `run`, `filter`, `nominal`,
`model` (the controller's robot, damping × `damping_scale`, and force-safe set), `arm` and
`plate` (the ground truth, softcbf_mj.physics.ground_truth: the true arm's k, d, λ and L scaled by
`true_*_scale`, the true plates moved by `facet_offset` and turned by `facet_angle` while the
controller keeps the unmoved facets, `gravity`, `tip_friction`, `table_friction`, the ideal
plate's `plate_stiffness` or the flexure's `sheet_*`, whose calibrated k is recorded as the
scene's plate stiffness) and its own `assumed_plate_stiffness` (N/m, the controller's ψ) and `assumed_tau_p` (s,
the valve lag the filter's context states; the true valves' is the arm's `tau_p`, so a study that varies `tau_p`
tells the filter nothing of it), and `assumed_command_delay` (s, the command delay its context states; the true one
is the arm's `command_delay`, a FIFO of whole 1 ms control periods in the plant, softcbf_mj.physics.plant: a delay between
two periods is refused). Model mismatch studies vary these (softcbf.study); samples with different true command
delays run in different batches (the batch key holds `command_delay`: `MujocoBatchPlant` has one per batch).

Imports: MuJoCo (the plants, the model builder) is imported inside the functions that run the
scenario or its batch form, not at load, so that registering the scenario and reading its
parameters (`softcbf list`, `softcbf run NAME --help`) stay cheap (tests/test_cli_lazy.py).
"""

from __future__ import annotations

from pathlib import Path
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import FilterContext
from scenarios import BatchForm, register
from scenarios.batch_form import run_batch_tuning
from scenarios.common import (
    Controller, ControllerRun, check_controller, control_step, controller_row, initial_configuration, run_tuning,
    scene_record, stop_after,
)
from scenarios.spec import Filter, Model, Nominal, Plate, Run, TrueArm, scenario_spec
from softcbf_mj.physics.ground_truth import Truth, build_truth, check_true_arm
from softcbf_mj.loops.loop import check_duration
from softcbf_mj.outputs.certified_truth import certified_truth_figures
from softcbf_mj.outputs.metrics import contact_figures, plate_figures, write_table
from softcbf_mj.physics.plant import delay_periods, steps_per_control
from softcbf_mj.outputs.runio import SummaryWriter
from vocabulary.settings import Bound

CONTROL_DT = 1e-3  # s, the paper's 1 kHz

BOUNDS = {"physics_dt": Bound(1e-6, CONTROL_DT, unit="s")}  # narrower than the vocabulary's: it divides the control period

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_pred", "rho_min_pred", ".4f"),
    ("rho_meas", "rho_min_meas", ".4f"),
    ("F peak [N]", "force_max_N", ".4f"),
    ("t_viol [s]", "t_violation_s", ".3f"),
    ("t_contact [s]", "t_contact_s", ".2f"),
    ("F err rms [mN]", "force_err_rms_N", ".2f", 1e3),
    ("F err max [mN]", "force_err_max_N", ".2f", 1e3),
    ("bias mean [mm]", "penetration_bias_mean_m", ".3f", 1e3),
    ("bias max [mm]", "penetration_bias_max_m", ".3f", 1e3),
    ("bias mean [%]", "penetration_bias_mean_pct", ".1f"),
    ("bias max [%]", "penetration_bias_max_pct", ".1f"),
    ("infeasible", "infeasible_steps", "d"),
    ("recovery", "recovery_steps", "d"),
    ("chatter [1/s]", "chatter_per_s", ".1f"),
    ("u HF [%]", "u_hf_fraction", ".1f", 100.0),
    ("on/off [1/s]", "switches_per_s", ".1f"),
    ("touch on/off [1/s]", "contact_switches_per_s", ".1f"),
    ("F solver [N]", "force_solver_max_N", ".3f"),
    ("F tang [N]", "force_tangential_max_N", ".3f"),
    ("s at F max [mm]", "contact_s_at_force_max_m", ".1f", 1e3),
    ("k there [N/m]", "contact_stiffness_at_force_max_N_per_m", ".2f"),
    ("filter med [us]", "filter_us_median", ".1f"),
    ("RTF", "realtime_factor", ".2f"),
)


def check_spec(spec: MujocoContact) -> Controller:
    """The checks of a `mujoco_contact` spec beyond its values' (scenarios.spec): the controller, the ground
    truth, the physics step dividing the control period; returns the controller it built (`spec.built`)."""
    controller = check_controller(spec.filter, spec.nominal, spec.model, spec.assumed_plate_stiffness)
    check_true_arm(spec.arm, spec.plate, controller.robot)
    steps_per_control(CONTROL_DT, spec.arm.physics_dt)
    delay_periods(spec.arm.command_delay, CONTROL_DT)
    return controller


MujocoContact = scenario_spec(
    "MujocoContact", "The spec of scenario `mujoco_contact` (module docstring): the run, the controller under test, "
                     "the nominal, the controller's model, the MuJoCo arm and plate, and the plate stiffness the "
                     "controller assumes.",
    "mujoco_contact", {"run": Run, "filter": Filter, "nominal": Nominal, "model": Model, "arm": TrueArm, "plate": Plate},
    {"assumed_plate_stiffness": "assumed_plate_stiffness", "assumed_tau_p": "assumed_tau_p",
     "assumed_command_delay": "assumed_command_delay"}, BOUNDS, check_spec, __name__)


@dataclass(frozen=True, eq=False)
class ContactSetup:
    """What one `mujoco_contact` sample builds before its closed loop (`contact_setup`).

    truth: the MuJoCo ground truth (`softcbf_mj.physics.ground_truth.build_truth`); runs: the controllers
    under test; q0 (N,) rad; context: what the filters and the nominal are told.
    """

    safe_set: ForceSafeSet
    truth: Truth
    runs: tuple[ControllerRun, ...]
    nominal_kwargs: dict[str, object]
    q0: np.ndarray
    context: FilterContext


def contact_setup(spec: MujocoContact) -> ContactSetup:
    """The (checked) `spec`'s controller model, controllers and nominal parameters (built by its check:
    `spec.built`), ground truth, q0 and context: the construction shared by the single run (`mujoco_contact`)
    and the batch form (`run_contact_batch`)."""
    controller = spec.built
    safe_set = controller.safe_set
    check_duration(spec.run.duration, CONTROL_DT, controller.robot.n_segments, safe_set)
    truth = build_truth(spec.arm, spec.plate, controller.robot, safe_set.environment, spec.model.damping_scale)
    q0 = initial_configuration(truth.robot.n_segments, spec.run.seed, spec.run.q0_std)  # the true arm's segments
    context = FilterContext.for_robot(controller.robot, safe_set, CONTROL_DT, spec.filter.pressure_limits,
                                      command_delay=spec.assumed_command_delay, actuator_tau=spec.assumed_tau_p)
    return ContactSetup(safe_set, truth, controller.runs, controller.nominal_kwargs, q0, context)


BATCH_VARYING = frozenset({
    "plate_stiffness", "facet_offset", "facet_angle", "true_stiffness_scale", "true_damping_scale", "true_gain_scale",
    "true_length_scale", "tau_p", "seed", "q0_std", "amplitude", "frequency", "t0", "nominal_params", "filter_params",
    "progress",
})
"""Parameters that may differ between the samples of one batch (per-simulation models, the valve lag `tau_p` among
them: the filter's context holds `assumed_tau_p`, not it; q0, nominal, the filter's parameters:
`scenarios.batch_form.run_batch_tuning`). Not the true `command_delay`: the batch plant has one."""


def contact_batch_key(params: Mapping[str, Any]) -> tuple | None:
    """What the samples of one batch share: every parameter but `BATCH_VARYING` (scenario
    structure, duration, physics step, the filter's spec and the controller's model).
    None for the flexure plate (no batch form: its calibration is per model) and with table
    friction (`MujocoBatchPlant` refuses it)."""
    if params["plate"] != "ideal" or params["table_friction"]:
        return None
    return tuple(sorted((k, v) for k, v in params.items() if k not in BATCH_VARYING))


def run_contact_batch(samples: Sequence[Mapping[str, Any]], nthread: int = 1,
                      progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """Run `mujoco_contact` samples (flat parameters) that share `contact_batch_key` (each one tuning) in
    one batched closed loop (`MujocoBatchPlant.from_configs`, nthread MuJoCo threads); one row of
    run figures per sample (`scenarios.batch_form.run_batch_tuning`)."""
    from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant  # MuJoCo: +3.1 s to import, when run (module docstring)

    keys = {contact_batch_key(p) for p in samples}
    if len(keys) != 1 or None in keys:
        raise ValueError(f"samples of one batch must share contact_batch_key and use the ideal plate, got {len(keys)} keys")
    specs = [MujocoContact.from_flat(p) for p in samples]
    setups = [contact_setup(s) for s in specs]
    if any(len(s.runs) != 1 for s in setups):
        raise ValueError("each sample of a batch must run exactly one tuning")
    first = setups[0]
    plant = MujocoBatchPlant.from_configs([s.truth.config for s in setups], control_dt=CONTROL_DT,
                                          nthread=nthread)
    return run_batch_tuning(plant, [s.runs[0] for s in setups], first.context, specs[0].nominal.name,
                            [s.nominal_kwargs for s in setups], specs[0].run.duration,
                            np.array([s.q0 for s in setups]), progress)


@register("mujoco_contact", "the paper's sinusoid against the MuJoCo plate, exact rod state, None/Low/High",
          MujocoContact, BatchForm(contact_batch_key, run_contact_batch))
def mujoco_contact(out_dir: Path, spec: MujocoContact) -> dict:
    """Run each controller (tuning) of `spec` for its duration; write summary.json and one time series per run."""
    from softcbf_mj.physics.mjcf import build_model  # MuJoCo: +2.5 s to import, when run (module docstring)
    from softcbf_mj.physics.mujoco_plant import EXTRAS_UNITS, MujocoPlant

    setup = contact_setup(spec)
    safe_set, true_plate_stiffness, nominal_kwargs = setup.safe_set, setup.truth.plate_stiffness, setup.nominal_kwargs
    plant = MujocoPlant(build_model(setup.truth.config), CONTROL_DT)

    certified = setup.truth.certified(spec.built.robot, spec.assumed_plate_stiffness)

    def figures(log: dict[str, np.ndarray]) -> dict:
        return {**contact_figures(log, safe_set, plant.control_dt), **plate_figures(log),
                **certified_truth_figures(log, certified, plant.control_dt)}

    summary = SummaryWriter(out_dir, "mujoco_contact", spec.flat(),
                            scene_record(setup.truth.robot, safe_set, true_plate_stiffness, setup.truth.plates))
    nominal = spec.nominal.name
    for run in setup.runs:
        row = run_tuning(out_dir, summary, run.label, plant, control_step(run, nominal, nominal_kwargs, setup.context),
                         safe_set, spec.run.duration, setup.q0, spec.run.progress, extra_figures=figures,
                         extra_units=EXTRAS_UNITS, row=controller_row(run, nominal, nominal_kwargs))
        if stop_after(row):
            break
    plate = spec.plate.kind
    print(f"mujoco_contact: {spec.run.duration:g} s from t0 = {spec.nominal.t0:g} s, controller model "
          f"{spec.model.robot!r}, pressure limits "
          f"{'on' if spec.filter.pressure_limits else 'off (the MuJoCo ctrlrange still clamps to ±150 hPa)'}, "
          f"{plate} plate {true_plate_stiffness:.4g} N/m{' (calibrated)' if plate != 'ideal' else ''} "
          f"(assumed {spec.assumed_plate_stiffness:g}), F_max {spec.model.f_max:g} N, "
          f"n_max {safe_set.n_max * 1e3:.2f} mm; outputs in {out_dir}")
    print(write_table(out_dir, summary.data["runs"], TABLE))
    return summary.data
