"""The battery: its cases (`CASES`, in this order), how each runs, and each filter's parameters in it.

| case             | scenario / plant                         | rate   | what                                                    |
|------------------|------------------------------------------|--------|---------------------------------------------------------|
| paper_sim_150    | paper_sim (PCC, exact state)             | 1 kHz  | the paper's sinusoid at ±150 hPa, 0.01 Hz, 100 s        |
| step             | paper_sim (PCC, exact state)             | 1 kHz  | `STEP_STARTS` = 20 steps from rest, nominal "step" seeded 0…19: a constant u_nom ~ U(60, 300) hPa per segment, 5 s each |
| mujoco_contact   | mujoco_contact at its defaults           | 1 kHz  | the paper's sinusoid (80 hPa, 0.01 Hz), 100 s           |
| camera_loop      | camera_loop at its defaults              | 10 Hz  | rendered AprilTags at 12.8 fps, 100 s                   |
| camera_stiff_close | camera_loop                            | 10 Hz  | true plate 10 % stiffer (12.276 N/m) and 1 mm closer (facet_offset −1 mm), 100 s |
| hardware_emulator | `softcbf hardware` on the emulator      | 10 Hz  | examples/hardware_emulated.toml with the reference arm (--robot reference), 20 s in real time |
| camera_mismatch  | a study (softcbf.study) on camera_loop   | 10 Hz  | `MISMATCH_DRAWS` = 100 Monte Carlo draws (seed 2026): true plate stiffness U(±10 %), actuator gain scale U(0.9, 1.1), facet offset U(±1 mm); `MISMATCH_DURATION_S` = 30 s from t0 = `MISMATCH_T0_S` = 15 s (the first contact), as studies/paper_tunings_plate_errors.toml |
| mujoco_push_030 … _120, mujoco_push_150hPa, mujoco_force_target | mujoco_contact | 1 kHz | contact tasks (docs/beyond-the-paper.md#contact-tasks, `PUSHES`): a constant push from rest asking 0.3, 0.6, 0.9, 1.2 F_max, the full 150 hPa push, the force-target nominal (target 0.6 F_max); `PUSH_DURATION_S` = 6 s |
| camera_push_030 … _120, camera_push_150hPa, camera_force_target | camera_loop | 10 Hz | the same contact tasks on the camera loop |
| paper_sim_3seg   | paper_sim (PCC, exact state), robot "three-segment" | 1 kHz | `THREE_SEGMENT_PUSH_HPA` = 40 hPa on every segment from rest, `PUSH_DURATION_S` = 6 s |
| mujoco_3seg      | mujoco_contact, robot "three-segment"    | 1 kHz  | the same push on the MuJoCo plant (the plate on its spring) |
| mujoco_push_box, camera_push_box | a study (softcbf.study) on mujoco_contact / camera_loop | 1 kHz / 10 Hz | contact under error (`PUSH_BOX_FILES`): the 150 hPa push, `PUSH_DURATION_S` from rest, under `PUSH_BOX_DRAWS` = 100 Monte Carlo draws of the standard box (studies/mismatch_box_contact.toml, studies/mismatch_box_camera.toml) |
| mujoco_push_flexure | mujoco_contact, `plate` = "flexure"   | 1 kHz  | the 150 hPa push on the clamped sheet in its gauge, as on the hardware, `PUSH_DURATION_S` |

The step case runs on paper_sim (the PCC plant at 1 kHz with the exact state): a step is a test of the
filter's own response to a sudden, large command, which the camera path's latency would mix with perception
effects that the camera cases already cover.

Contact tasks. "Asking for F" means the unfiltered plant's steady measured force is F (softcbf.bench.figures:
`steady_force`); the step levels (the same on both segments) are found once by tools/force_levels.py and
stored with the cases (`PUSHES`: the nominal's parameters and the asked force). Their rows hold
`force_asked_N` and `force_delivered_N` (the run's steady measured force), `force_delivered_ratio` =
delivered / min(asked, F_max).

The 3-segment cases (`THREE_SEGMENT_CASES`). The arm is models/robots/three_segment.json
(`controllers.model.params.uniform_robot(3)`: three reference segments, reach 0.366 m); at rest its tip lies 17 mm
inside the paper's facet 0.36 x + y ≤ 0.15 m, and the 40 hPa push bends it through the plate: unfiltered,
ρ_meas −6.6 (paper_sim) and −3.2 (mujoco_contact), F max 1.22 and 0.67 N against F_max = 0.16 N, in contact
from ≈ 0.1 s (1 s runs), so the short --quick runs test the filter in contact too. A filter that cannot be
built for a case's arm (e-erg: its escape-energy table is a q-space grid, N ≤ 2) is not run there:
`arm_refusal` builds every selected filter once on the case's arm (the paper's safe set at the scenario's
defaults, 1 kHz) before the bench starts, and bench.json's "skipped" records the pair under the key
"FILTER x CASE" (`skip_key`) with the filter's own message.

Contact under error (docs/results.md#contact-under-error-benchjson-contact_under_error; the pushes above run on
exact plates). The push-draw cases run the 150 hPa
push of `PUSHES` under draws of the standard mismatch box as its file states it (`push_box_study`: the box's
`vary` and seed, its fixed parameters but t0, which only the sinusoid reads; the filter under test and its
parameters of the case as in `case_filter_params`; one definition of the box, read from the file): on
mujoco_contact the physical errors (plate stiffness ±20 %, offset ±2 mm, actuator gain ±10 %, arm stiffness
±10 %, damping ±30 %, valve lag 0.02–0.1 s), on camera_loop also the sensing errors of its box (delay
0–60 ms, pixel noise 0–8 grey levels, dropped frames 0–20 %). Each runs as a study (continued with
--resume) and is pooled over its draws like the mismatch case (softcbf.bench.figures: `draw_figures`): a
faulted draw counts as a violation, never a pass; the row adds the violations, their exact one-sided 95 %
upper bound and the delivered force's minimum and median over the draws (/ F_max). The flexure case is the
same push on the clamped sheet (`plate` = "flexure", scenarios.ground_truth), whose local stiffness varies
along it: its asked force `FLEXURE_ASKED_N` is the unfiltered sheet's steady force (measured as
tools/force_levels.py measures `PUSHES`: filter "none", 6 s), far above F_max, so the case
asks F_max.

`--quick` (CI) cuts every duration to `QUICK_DURATION_S` = 1 s, except the contact tasks' pushes, which last
`QUICK_PUSH_DURATION_S` = 3 s (the length tools/force_levels.py measured the asked forces over: a delivered
force of a shorter push is still the transient), the steps to 3 starts of 0.5 s, the mismatch study to 2
draws of 1 s, the push draws to `QUICK_PUSH_BOX_DRAWS` = 3 draws of 3 s, and skips the emulator
(`QUICK_SKIPPED`: it runs in real time after a start-up of several
seconds).

Parameters per case (`case_filter_params`; a spec's own parameters win): paper-cbf the tuning its case is
about (`PAPER_TUNINGS`: "Low" in the 1 kHz cases, "HW-High" in the 10 Hz camera cases: the paper's tables I
and II); e-erg contact_aware=true with the true plate stiffness in [0.9, 1.1] × the model's (`EERG_PARAMS`:
the mismatch study's interval, which also holds the stiff-plate case); c-erg (its presets included:
`c-erg:recommended`) contact_aware as the plant is, and nothing else: false on the PCC plant (paper_sim_150,
step, paper_sim_3seg: the tip passes through the plate, which pushes back nowhere), true on the MuJoCo plants
(the plate on its spring); other filters their own defaults.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controllers.contract.filter_parameters import parse_text
from controllers.registry import PluginLoadError, build_filter, find_preset
from controllers.contract.safety_filter import FilterContext
from scenarios import get
from scenarios.common import build_safe_set, load_robot
from scenarios.run import FILTER_FAULT
from softcbf.bench.figures import draw_figures, f_max_of, pooled_figures, run_figures, study_draws, study_figures
from softcbf.bench.filters import FilterSpec
from softcbf.study.definition import Distribution, Study
from softcbf.study.execute import run_study
from softcbf.study.store import faulted
from softcbf_mj.outputs.push_force import steady_force_of_folder
from softcbf_mj.outputs.runio import read_run_folder, safe_name
from vocabulary.project_files import project_file
from vocabulary.sections import joined
from vocabulary.settings import default

PAPER_TUNINGS = {"1kHz": "Low", "camera": "HW-High"}
EERG_PARAMS = {"contact_aware": "true", "stiffness_lo_ratio": "0.9", "stiffness_hi_ratio": "1.1"}
STEP_STARTS, STEP_DURATION_S = 20, 5.0
MISMATCH_DRAWS, MISMATCH_SEED = 100, 2026
MISMATCH_T0_S, MISMATCH_DURATION_S = 15.0, 30.0  # s: from the first contact on (module docstring)
ASSUMED_PLATE_N_PER_M = default("assumed_plate_stiffness", "camera_loop")  # the camera cases' model plate (N/m)
QUICK_DURATION_S = 1.0
QUICK_PUSH_DURATION_S = 3.0  # s: a contact task's push with --quick (module docstring)
QUICK_STEP_STARTS, QUICK_STEP_DURATION_S, QUICK_MISMATCH_DRAWS = 3, 0.5, 2
EMULATOR_CONFIG = project_file("examples/hardware_emulated.toml")
EMULATOR_DURATION_S = 20.0
PUSH_PLANTS = ("mujoco_contact", "camera_loop")
PUSH_RATIOS = (0.3, 0.6, 0.9, 1.2)
FORCE_TARGET_RATIO = 0.6
PUSH_DURATION_S = 6.0
THREE_SEGMENT_ROBOT, THREE_SEGMENT_PUSH_HPA = "three-segment", 40.0
PUSH_BOX_DRAWS, QUICK_PUSH_BOX_DRAWS = 100, 3
PUSH_BOX_FILES = {"mujoco_contact": "studies/mismatch_box_contact.toml", "camera_loop": "studies/mismatch_box_camera.toml"}
BOX_PUSH = "push_150hPa"  # the push of `PUSHES` that the push draws and the flexure case run
FLEXURE_ASKED_N = 1.48154  # N: the unfiltered 150 hPa push on the flexure sheet (module docstring)


@dataclass(frozen=True)
class RunOptions:
    """How a case runs: quick (CI) or full, local worker processes of the study and the falsifications, mismatch draws
    (None: `MISMATCH_DRAWS`), the falsification budget; and what happens to a bench folder in --out
    (softcbf.bench.folder: `prepare_bench_dir`): resume it, or overwrite it."""

    quick: bool = False
    workers: int = 1
    mismatch_draws: int | None = None
    resume: bool = False
    overwrite: bool = False
    falsify_budget: int | None = None
    """Evaluations of each filter's worst-case search (softcbf.bench.runner); None: the default, 0: none."""

    @property
    def push_draws(self) -> int:
        """The push-draw cases' draws: `QUICK_PUSH_BOX_DRAWS` with quick, else `PUSH_BOX_DRAWS`."""
        return QUICK_PUSH_BOX_DRAWS if self.quick else PUSH_BOX_DRAWS

    @property
    def draws(self) -> int:
        """The mismatch study's draws: `QUICK_MISMATCH_DRAWS` with quick, else the given number or `MISMATCH_DRAWS`."""
        return QUICK_MISMATCH_DRAWS if self.quick else (self.mismatch_draws or MISMATCH_DRAWS)


@dataclass(frozen=True)
class Case:
    """One battery case: its name, the loop rate class ("1kHz" or "camera"), how it runs
    (`run(case, spec, folder, options) -> figures`) and its fixed scenario parameters
    ("scenario": the registered scenario when it is not the case's name)."""

    name: str
    rate: str
    run: Callable[["Case", FilterSpec, Path, RunOptions], dict[str, Any]]
    scenario_params: dict[str, Any] = field(default_factory=dict)
    asked_N: float | None = None
    """A contact task's asked force (N): the unfiltered plant's steady measured force (`PUSHES`); None: no force asked."""
    resumable: bool = False
    """Whether `--resume` continues the case's folder (a study) instead of running it again from scratch."""

    def quick_duration_s(self) -> float:
        """The case's duration (s) with --quick: `QUICK_PUSH_DURATION_S` for a contact task, else `QUICK_DURATION_S`."""
        return QUICK_PUSH_DURATION_S if self.asked_N is not None else QUICK_DURATION_S


def case_filter_params(spec: FilterSpec, case: Case) -> dict[str, str]:
    """The filter's parameters in `case`: the per-case defaults (module docstring) updated with the spec's own."""
    pushes_back = case.scenario_params.get("scenario", "") != "paper_sim" and case.name != "step"
    preset = find_preset(spec.name)
    defaults = {"paper-cbf": {"tuning": PAPER_TUNINGS[case.rate]}, "e-erg": dict(EERG_PARAMS),
                "c-erg": {"contact_aware": "true" if pushes_back else "false"}}.get(
        spec.name if preset is None else preset.filter, {})
    return {**defaults, **spec.params}


def plant_parameters(plant: str) -> dict[str, Any]:
    """A contact task's scenario parameters besides the nominal: the plant at its defaults (camera_loop saves no frames)."""
    return {"saved_frames_hz": 0.0} if plant == "camera_loop" else {}


def scenario_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """A case that is one run of a registered scenario; a contact task's row adds the delivered force."""
    params = {k: v for k, v in case.scenario_params.items() if k != "scenario"}
    params.update(filter=spec.name, filter_params=joined("filter_params", case_filter_params(spec, case)), progress=False)
    if options.quick:
        params["duration"] = case.quick_duration_s()
    out.mkdir(parents=True)
    get(case.scenario_params.get("scenario", case.name)).run(out, **params)
    figures = pooled_figures(run_figures(out), f_max_of(out))
    if case.asked_N is None or figures["fault"]:  # a push cut short by a fault delivered no steady force
        return figures
    delivered = steady_force_of_folder(out)
    return {**figures, "force_delivered_N": delivered,
            "force_delivered_ratio": delivered / min(case.asked_N, figures["f_max_N"])}


def step_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """The step case: seeded step commands from rest on paper_sim, pooled (module docstring)."""
    starts, duration = (QUICK_STEP_STARTS, QUICK_STEP_DURATION_S) if options.quick else (STEP_STARTS, STEP_DURATION_S)
    runs = []
    for seed in range(starts):
        folder = out / f"seed-{seed:02d}"
        folder.mkdir(parents=True)
        get("paper_sim").run(folder, duration=duration, filter=spec.name,
                             filter_params=joined("filter_params", case_filter_params(spec, case)),
                             nominal="step", nominal_params=f"seed={seed};low_hPa=60;high_hPa=300", progress=False)
        runs += run_figures(folder)
    return pooled_figures(runs, f_max_of(folder))


def emulator_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """The hardware mode on the emulator (`softcbf hardware`), its figures from the 1 kHz ground truth."""
    from hardware.config import HardwareConfig  # OpenCV, 0.16 s to import (-X importtime): only where the emulator runs
    from softcbf import hardware_cli  # the hardware mode, 0.18 s more (-X importtime): only here

    out.mkdir(parents=True)
    argv = [str(EMULATOR_CONFIG), "--robot", "reference", "--port", "emulated", "--camera", "virtual", "--filter", spec.name,
            "--duration", str(EMULATOR_DURATION_S), "--out", str(out / "run")]
    for name, value in case_filter_params(spec, case).items():
        argv += ["--filter-param", f"{name}={value}"]
    code = hardware_cli.main(argv)
    ended_on_fault = code == FILTER_FAULT and (out / "run").is_dir() and any(
        faulted(row) for row in read_run_folder(out / "run").runs)
    if code != 0 and not ended_on_fault:  # a filter fault is the row's result (softcbf.bench.figures)
        raise RuntimeError(f"softcbf hardware {' '.join(argv)} exited with {code}")
    return pooled_figures(run_figures(out / "run"), HardwareConfig.load(EMULATOR_CONFIG).safe_set().f_max,
                          force_key="force_max_emulator_N", violation_key="t_violation_emulator_s")


def mismatch_study(spec: FilterSpec, case: Case, draws: int, duration: float) -> Study:
    """The camera_mismatch case's `softcbf.study.definition.Study` for `spec` (module docstring), each sample
    `duration` s long (`MISMATCH_DURATION_S`; --quick: `QUICK_DURATION_S`)."""
    k = ASSUMED_PLATE_N_PER_M
    fixed = {"t0": MISMATCH_T0_S, "duration": duration, "saved_frames_hz": 0.0, "progress": False,
             "assumed_plate_stiffness": k, "filter_params": joined("filter_params", case_filter_params(spec, case))}
    vary = (Distribution("plate_stiffness", "uniform", low=0.9 * k, high=1.1 * k),
            Distribution("true_gain_scale", "uniform", low=0.9, high=1.1),
            Distribution("facet_offset", "uniform", low=-1e-3, high=1e-3))
    return Study(name=f"bench_camera_mismatch_{safe_name(spec.name)}", scenario="camera_loop", tunings=(spec.name,),
                 tuning_parameter="filter", vary=vary, fixed=fixed, draws=draws, seed=MISMATCH_SEED,
                 description="softcbf bench: camera_loop with plate stiffness ±10 %, actuator gain ±10 %, facet offset ±1 mm")


def mismatch_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """The camera_mismatch case: its study run (continued with --resume) and pooled over its samples."""
    study = mismatch_study(spec, case, options.draws, QUICK_DURATION_S if options.quick else MISMATCH_DURATION_S)
    run_study(study, out, workers=options.workers, keep_runs=True, progress=not options.quick,
              resume=options.resume and out.exists())
    return study_figures(out)


PUSHES: dict[str, dict[str, tuple[str, float]]] = {  # plant → {case suffix: (nominal_params, asked N)}: tools/force_levels.py
    "mujoco_contact": {
        "push_030": ("seed=0;low_hPa=56.983;high_hPa=56.983", 0.04823),
        "push_060": ("seed=0;low_hPa=62.516;high_hPa=62.516", 0.09584),
        "push_090": ("seed=0;low_hPa=68.215;high_hPa=68.215", 0.14400),
        "push_120": ("seed=0;low_hPa=74.018;high_hPa=74.018", 0.19200),
        "push_150hPa": ("seed=0;low_hPa=150;high_hPa=150", 0.63757),
        "force_target": ("target_N=0.096", 0.0941),
    },
    "camera_loop": {
        "push_030": ("seed=0;low_hPa=57.015;high_hPa=57.015", 0.04823),
        "push_060": ("seed=0;low_hPa=62.551;high_hPa=62.551", 0.09583),
        "push_090": ("seed=0;low_hPa=68.258;high_hPa=68.258", 0.14400),
        "push_120": ("seed=0;low_hPa=74.07;high_hPa=74.07", 0.19200),
        "push_150hPa": ("seed=0;low_hPa=150;high_hPa=150", 0.63433),
        "force_target": ("target_N=0.096", 0.09405),
    },
}
"""The contact tasks (docs/beyond-the-paper.md#contact-tasks): per plant, the constant pushes asking 0.3, 0.6, 0.9 and 1.2 F_max (nominal "step" with
low_hPa = high_hPa = the level found by tools/force_levels.py), the full 150 hPa push and the force-target nominal
(target 0.6 F_max of the model's predicted force); asked: the unfiltered plant's steady measured force (`steady_force`
of a 3 s push, the tool's output, copied here)."""
PUSH_PREFIX = {"mujoco_contact": "mujoco", "camera_loop": "camera"}


def push_cases() -> tuple[Case, ...]:
    """The contact-task cases of `PUSHES`: `PUSH_DURATION_S` from rest (quick: `QUICK_PUSH_DURATION_S`)."""
    return tuple(
        Case(f"{PUSH_PREFIX[plant]}_{suffix}", "1kHz" if plant == "mujoco_contact" else "camera", scenario_case,
             {"scenario": plant, "duration": PUSH_DURATION_S, "nominal": "force-target" if suffix == "force_target" else "step",
              "nominal_params": nominal_params, **plant_parameters(plant)}, asked)
        for plant, tasks in PUSHES.items() for suffix, (nominal_params, asked) in tasks.items())


def push_box_study(spec: FilterSpec, case: Case, draws: int, duration: float) -> Study:
    """A push-draw case's `softcbf.study.definition.Study` for `spec` (module docstring): the standard box of its
    plant's file (`PUSH_BOX_FILES`) with the filter under test, `draws` draws of the `BOX_PUSH` push, each
    `duration` s long from rest (`PUSH_DURATION_S`; --quick: `QUICK_PUSH_DURATION_S`)."""
    from softcbf.study.worst_found import box_study  # optuna, 0.25 s to import (-X importtime): only for a push-draw case

    plant = case.scenario_params["scenario"]
    box = box_study(spec.name, case_filter_params(spec, case), duration=duration,
                    box_file=project_file(PUSH_BOX_FILES[plant]))
    fixed = {**{k: v for k, v in box.fixed.items() if k != "t0"}, "nominal": "step",
             "nominal_params": parse_text(PUSHES[plant][BOX_PUSH][0]),
             "progress": False, **plant_parameters(plant)}
    return dataclasses.replace(
        box, name=f"bench_{case.name}_{safe_name(spec.name)}", fixed=fixed, sampling="monte_carlo", draws=draws,
        description=f"softcbf bench: the {BOX_PUSH} push on {plant} under the standard box ({PUSH_BOX_FILES[plant]})")


def push_box_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """A push-draw case: its study run (continued with --resume) and pooled over its draws (`draw_figures`)."""
    study = push_box_study(spec, case, options.push_draws,
                           QUICK_PUSH_DURATION_S if options.quick else PUSH_DURATION_S)
    run_study(study, out, workers=options.workers, keep_runs=True, progress=not options.quick,
              resume=options.resume and out.exists())
    return draw_figures(*study_draws(out))


def contact_error_cases() -> tuple[Case, ...]:
    """The contact cases under error (module docstring): a push-draw case per plant, the push on the flexure sheet."""
    box = tuple(Case(f"{PUSH_PREFIX[plant]}_push_box", "1kHz" if plant == "mujoco_contact" else "camera", push_box_case,
                     {"scenario": plant}, PUSHES[plant][BOX_PUSH][1], resumable=True) for plant in PUSH_PLANTS)
    flexure = Case("mujoco_push_flexure", "1kHz", scenario_case,
                   {"scenario": "mujoco_contact", "plate": "flexure", "duration": PUSH_DURATION_S, "nominal": "step",
                    "nominal_params": PUSHES["mujoco_contact"][BOX_PUSH][0]}, FLEXURE_ASKED_N)
    return (*box, flexure)


THREE_SEGMENT_CASES: tuple[Case, ...] = tuple(
    Case(name, "1kHz", scenario_case,
         {"scenario": plant, "robot": THREE_SEGMENT_ROBOT, "duration": PUSH_DURATION_S, "nominal": "step",
          "nominal_params": f"seed=0;low_hPa={THREE_SEGMENT_PUSH_HPA:g};high_hPa={THREE_SEGMENT_PUSH_HPA:g}"})
    for name, plant in (("paper_sim_3seg", "paper_sim"), ("mujoco_3seg", "mujoco_contact")))
"""The 3-segment cases (module docstring): a constant push on the "three-segment" arm, on the PCC and the MuJoCo plant."""

CASES: tuple[Case, ...] = (
    Case("paper_sim_150", "1kHz", scenario_case, {"scenario": "paper_sim", "amplitude": 150.0}),
    Case("step", "1kHz", step_case),
    Case("mujoco_contact", "1kHz", scenario_case),
    Case("camera_loop", "camera", scenario_case, {"saved_frames_hz": 0.0}),
    Case("camera_stiff_close", "camera", scenario_case,
         {"scenario": "camera_loop", "plate_stiffness": 1.1 * ASSUMED_PLATE_N_PER_M, "facet_offset": -1e-3, "saved_frames_hz": 0.0}),
    Case("hardware_emulator", "camera", emulator_case),
    Case("camera_mismatch", "camera", mismatch_case, resumable=True),
) + push_cases() + contact_error_cases() + THREE_SEGMENT_CASES
QUICK_SKIPPED = {"hardware_emulator": "--quick: the emulator runs in real time after a start-up of several seconds"}


CONTACT_KEYS = ("filter", "plant", "draws", "violations", "violation_cp95_upper", "rho_min_meas", "faulted",
                "delivered_nominal_ratio", "delivered_min_ratio", "delivered_median_ratio", "flexure_rho_min_meas",
                "flexure_ratio")


def contact_under_error(results: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """bench.json's "contact_under_error" from its result rows: per filter and plant (`PUSH_PLANTS`, where any of
    its rows below ran), from the push-draw row: the draws, the violations (a faulted draw is one), their
    one-sided 95 % upper bound, the least ρ_meas (null when a draw faulted) and the faulted draws; the delivered
    force / F_max at the nominal plate (the `BOX_PUSH` row), its minimum and median over the draws; on
    mujoco_contact the flexure sheet's ρ_meas and delivered force / F_max (null where a row is absent or faulted)."""
    rows = {(r["filter"], r["case"]): r for r in results}
    out = []
    for label in dict.fromkeys(r["filter"] for r in results):
        for plant in PUSH_PLANTS:
            prefix = PUSH_PREFIX[plant]
            box, nominal, flexure = (rows.get((label, f"{prefix}_{suffix}"))
                                     for suffix in ("push_box", BOX_PUSH, "push_flexure"))
            if box is None and nominal is None and flexure is None:
                continue
            out.append({
                "filter": label, "plant": plant,
                **{k: None if box is None else box[src] for k, src in (
                    ("draws", "draws"), ("violations", "violations"), ("violation_cp95_upper", "violation_cp95_upper"),
                    ("rho_min_meas", "rho_min_meas"), ("faulted", "faulted"),
                    ("delivered_min_ratio", "force_delivered_min_ratio"),
                    ("delivered_median_ratio", "force_delivered_median_ratio"))},
                "delivered_nominal_ratio": delivered_over_f_max(nominal),
                "flexure_rho_min_meas": None if flexure is None else flexure["rho_min_meas"],
                "flexure_ratio": delivered_over_f_max(flexure)})
    return [{k: e[k] for k in CONTACT_KEYS} for e in out]


def delivered_over_f_max(row: Mapping[str, Any] | None) -> float | None:
    """A push row's delivered force / F_max (None: no row, or no steady force: a fault)."""
    if row is None or row["force_delivered_N"] is None:
        return None
    return row["force_delivered_N"] / row["f_max_N"]


def skip_key(spec: FilterSpec, case: Case) -> str:
    """bench.json's "skipped" key of a (filter, case) pair that is not run: "FILTER x CASE"."""
    return f"{spec.label} x {case.name}"


def arm_refusal(spec: FilterSpec, case: Case) -> str | None:
    """Why `spec` cannot run in `case`, a case on another arm than the reference (its scenario parameter "robot"):
    the filter built on that arm's context (the paper's safe set with the scenario's defaults, 1 kHz, the arm's
    pressure limits) raises `PluginLoadError` (e-erg on N > 2); its message then, None when it builds or the
    case runs the scenario's own arm."""
    if "robot" not in case.scenario_params:
        return None
    plant = case.scenario_params["scenario"]
    stiffness = "assumed_plate_stiffness" if plant == "mujoco_contact" else "plate_stiffness"
    safe_set = build_safe_set(*(case.scenario_params.get(name, default(name, plant))
                                for name in ("environment", stiffness, "f_max", "row_scaling")))
    robot = load_robot(case.scenario_params["robot"])
    try:
        build_filter(spec.name, case_filter_params(spec, case), FilterContext.for_robot(robot, safe_set, 1e-3))
    except PluginLoadError as exc:
        return f"{spec.label} cannot be built for the {robot.n_segments}-segment arm {case.scenario_params['robot']!r}: {exc}"
    return None
