"""Scenario `mujoco_contact`: the paper's sinusoid against the compliant plate in MuJoCo (SPEC §7).

The ground truth is `MujocoPlant` (the discretised rod of the reference robot, SPEC §3,
and the paper's plate on a spring of `plate_stiffness` N/m, SPEC §4). The controller
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

Per run, besides the SPEC §8 fields (ρ_meas and t_violation_s from the plate's spring
force: ρ_meas = 1 − F/F_max for linear ψ, violation while F > F_max), summary.json holds
`softcbf_mj.metrics.contact_figures`: the force the controller predicts, ψ of its own
predicted penetration, against the measured plate force (RMS and max error), and the
loaded-rod penetration bias, predicted − measured penetration while in contact (m and %
of n_max; SPEC §7: a loaded rod is not constant-curvature), the solver's peak contact
force (impacts on the 10 g plate) and how often the arm touches and leaves the plate;
and `switches_per_s`, how often the filter's correction turns on and off. Time series
add the plant's extras `plate_displacement_m` and `force_solver_N` (and `warning_*`
counts if any). Results and the benchmark: models/softcbf_arm/README.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from controllers.params import RobotParams, reference_robot
from controllers.safe_set import Environment
from controllers.safety_filter import FilterContext
from scenarios import register
from scenarios.common import (
    PAPER_FILTER, build_safe_set, control_step, controller_row, controller_runs, initial_configuration, load_robot,
    nominal_arguments, run_tuning, scene_record,
)
from softcbf_mj.metrics import contact_figures, format_table
from softcbf_mj.model_builder import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT, DEFAULT_TAU_P
from softcbf_mj.mujoco_plant import EXTRAS_UNITS, MujocoPlant
from softcbf_mj.runio import SummaryWriter

CONTROL_DT = 1e-3  # s, the paper's 1 kHz

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_pred", "rho_min_pred", ".4f"),
    ("rho_meas", "rho_min_meas", ".4f"),
    ("F_max [N]", "force_max_N", ".4f"),
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
    ("chatter [1/s]", "chatter_per_s", ".2f"),
    ("on/off [1/s]", "switches_per_s", ".1f"),
    ("touch on/off [1/s]", "contact_switches_per_s", ".1f"),
    ("F solver [N]", "force_solver_max_N", ".3f"),
    ("filter med [us]", "filter_us_median", ".1f"),
    ("RTF", "realtime_factor", ".2f"),
)


@register("mujoco_contact", "the paper's sinusoid against the MuJoCo plate, exact rod state, None/Low/High")
def mujoco_contact(
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
    t0: float = 0.0,
    pressure_limits: bool = True,
    robot: str = "reference",
    environment: str = "paper",
    links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT,
    tau_p: float = DEFAULT_TAU_P,
    physics_dt: float = DEFAULT_PHYSICS_DT,
    plate_stiffness: float = 11.16,
    assumed_plate_stiffness: float = 11.16,
    f_max: float = 0.16,
    row_scaling: str = "paper",
    qp_backend: str = "native",
    seed: int = 0,
    q0_std: float = 0.0,
    true_stiffness_scale: float = 1.0,
    true_damping_scale: float = 1.0,
    true_gain_scale: float = 1.0,
    true_length_scale: float = 1.0,
    facet_offset: float = 0.0,
    facet_angle: float = 0.0,
    progress: bool = True,
) -> dict:
    """Run each controller (tuning) for `duration` s; write summary.json and one time series per run.

    `robot` is the controller's model only. The MuJoCo arm is the reference robot with
    its k, d, λ and L multiplied by `true_stiffness_scale`, `true_damping_scale`,
    `true_gain_scale` and `true_length_scale` (inertias by the length scale squared, as
    for a rod; defaults 1: the reference robot itself). `plate_stiffness` is the true
    plate's (N/m), `assumed_plate_stiffness` the controller's. The true plates sit on the
    `environment` facets moved by `facet_offset` (m) along their outward normals (> 0:
    farther from the base) and then turned by `facet_angle` (rad, counter-clockwise seen
    from +z) about the foot of the perpendicular from the base; the controller keeps the
    unmoved facets. Model mismatch studies vary these (softcbf.study).
    """
    params = dict(locals())
    params.pop("out_dir")
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    if not math.isfinite(t0):
        raise ValueError(f"t0 must be finite, got {t0}")
    for name in ("true_stiffness_scale", "true_damping_scale", "true_gain_scale", "true_length_scale"):
        if not (math.isfinite(params[name]) and params[name] > 0):
            raise ValueError(f"{name} must be > 0 (1: the reference robot), got {params[name]}")
    if not (math.isfinite(facet_offset) and math.isfinite(facet_angle) and abs(facet_angle) < math.pi / 2):
        raise ValueError(f"facet_offset (m) must be finite and |facet_angle| < pi/2 rad, got {facet_offset}, {facet_angle}")
    model_robot = load_robot(robot)
    safe_set = build_safe_set(environment, assumed_plate_stiffness, f_max, row_scaling)
    env = safe_set.environment
    ref = reference_robot()
    true_robot = RobotParams(
        lengths=ref.array("lengths") * true_length_scale, masses=ref.masses,
        stiffness=ref.array("stiffness") * true_stiffness_scale, damping=ref.array("damping") * true_damping_scale,
        gains=ref.array("gains") * true_gain_scale, u_min=ref.u_min, u_max=ref.u_max,
        inertias=ref.array("inertias") * true_length_scale**2,
    )
    # True facets: row k of H turned by facet_angle; the line through the foot of the
    # perpendicular (h_k/‖H_k‖ + facet_offset) n̂_k. Exact (bit-identical) at 0 and 0.
    cos_a, sin_a = math.cos(facet_angle), math.sin(facet_angle)
    true_H = np.column_stack((env.H[:, 0] * cos_a - env.H[:, 1] * sin_a, env.H[:, 0] * sin_a + env.H[:, 1] * cos_a))
    true_h = (env.h + facet_offset * np.hypot(env.H[:, 0], env.H[:, 1])) * cos_a
    plant = MujocoPlant.from_config(
        control_dt=CONTROL_DT, robot=true_robot, H=true_H, h=true_h, plate_stiffness=plate_stiffness,
        links_per_segment=links_per_segment, tau_p=tau_p, physics_dt=physics_dt,
    )
    if model_robot.n_segments != plant.n_segments:
        raise ValueError(f"robot has {model_robot.n_segments} segments, the MuJoCo arm {plant.n_segments}")
    runs = controller_runs(filter, filter_params, tunings, qp_backend)
    nominal_kwargs = nominal_arguments(nominal, nominal_params, amplitude=amplitude, frequency=frequency, t0=t0)
    n = plant.n_segments
    q0 = initial_configuration(n, seed, q0_std)
    context = FilterContext.for_robot(model_robot, safe_set, CONTROL_DT, pressure_limits, command_delay=0.0, actuator_tau=tau_p)

    def figures(log: dict[str, np.ndarray]) -> dict:
        return contact_figures(log, safe_set, plant.control_dt)

    summary = SummaryWriter(out_dir, "mujoco_contact", params,
                            scene_record(true_robot, safe_set, plate_stiffness, Environment(true_H, true_h)))
    for run in runs:
        run_tuning(out_dir, summary, run.label, plant, control_step(run, nominal, nominal_kwargs, context), safe_set,
                   duration, q0, progress, extra_figures=figures, extra_units=EXTRAS_UNITS,
                   row=controller_row(run, nominal, nominal_kwargs))
    print(f"mujoco_contact: {duration:g} s from t0 = {t0:g} s, controller model {robot!r}, pressure limits "
          f"{'on' if pressure_limits else 'off (the MuJoCo ctrlrange still clamps to ±150 hPa)'}, "
          f"plate {plate_stiffness:g} N/m (assumed {assumed_plate_stiffness:g}), F_max {f_max:g} N, n_max {safe_set.n_max * 1e3:.2f} mm; "
          f"outputs in {out_dir}")
    print(format_table(summary.data["runs"], TABLE))
    return summary.data
