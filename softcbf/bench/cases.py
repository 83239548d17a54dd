"""The battery: its cases (`CASES`, in the order of softcbf/bench/battery.toml), how each runs, and each filter's
parameters in it.

The cases and every number of the battery live in the data file `battery.toml` (softcbf.bench.battery: read and
checked there; its table of cases is generated into docs/results.md#filter-benchmark-softcbf-bench). Each case is a
registered scenario with fixed parameters, or a study of one: a case's table uses a study file's keys (`scenario`,
`fixed`, and for a study `seed`, `sampling`, `draws`, `vary`), and its study cases become
`softcbf.study.definition.Study`s through `Study.from_dict`, the study file's own reader and checks. How a case
runs (its `run` kind, `RUNS`):

- "scenario" (`scenario_case`): one run of the scenario with the case's fixed parameters (a `push` case with its
  contact task's nominal too);
- "step" (`step_case`): `starts` runs of paper_sim from rest, the "step" nominal seeded 0, 1, …: a test of the
  filter's own response to a sudden, large command, which the camera path's latency would mix with perception
  effects that the camera cases already cover;
- "emulator" (`emulator_case`): `softcbf hardware` on the emulator, its figures from the 1 kHz ground truth;
- "study" (`mismatch_case`, `mismatch_study`): the case's table as a study file, with the filter under test as its
  one tuning (`tuning_parameter = "filter"`), run (continued with --resume) and pooled over its samples;
- "box" (`push_box_case`, `push_box_study`): the standard mismatch box as its file states it (`box_study`: the
  box's `vary` and seed, its fixed parameters but t0, which only the sinusoid reads; one definition of the box,
  read from the file) running the case's contact task `push` from rest, pooled over its draws
  (softcbf.bench.figures: `draw_figures`): a faulted draw counts as a violation, never a pass; the row adds the
  violations, their exact one-sided 95 % upper bound and the delivered force's minimum and median over the draws
  (/ F_max).

Contact tasks (docs/beyond-the-paper.md#contact-tasks; cases with a `task`, `PUSHES`). "Asking for F" means the
unfiltered plant's steady measured force is F (softcbf.bench.figures: `steady_force`); the step levels (the same on
both segments) are found once by tools/force_levels.py and stored with the cases (the nominal's parameters and
`asked_N`). Their rows hold `force_asked_N` and `force_delivered_N` (the run's steady measured force),
`force_delivered_ratio` = delivered / min(asked, F_max). The flexure case is the 150 hPa push on the clamped sheet
(`plate` = "flexure", scenarios.ground_truth), whose local stiffness varies along it: its asked force
(`FLEXURE_ASKED_N`) is the unfiltered sheet's steady force, far above F_max, so the case asks F_max.

The 3-segment cases (`THREE_SEGMENT_CASES`: those with a `robot`). The arm is models/robots/three_segment.json
(`controllers.model.params.uniform_robot(3)`: three reference segments, reach 0.366 m); at rest its tip lies 17 mm
inside the paper's facet 0.36 x + y ≤ 0.15 m, and the 40 hPa push bends it through the plate: unfiltered,
ρ_meas −6.6 (paper_sim) and −3.2 (mujoco_contact), F max 1.22 and 0.67 N against F_max = 0.16 N, in contact
from ≈ 0.1 s (1 s runs), so the short --quick runs test the filter in contact too. A filter that cannot be
built for a case's arm (e-erg: its escape-energy table is a q-space grid, N ≤ 2) is not run there:
`arm_refusal` builds every selected filter once on the case's arm (the paper's safe set at the scenario's
defaults, 1 kHz) before the bench starts, and bench.json's "skipped" records the pair under the key
"FILTER x CASE" (`skip_key`) with the filter's own message.

`--quick` (CI) takes the file's `[quick]`: every duration `QUICK_DURATION_S`, except the contact tasks' pushes
(`QUICK_PUSH_DURATION_S`: the length tools/force_levels.py measured the asked forces over: a delivered force of a
shorter push is still the transient), fewer and shorter steps, fewer study and box draws (`QUICK_PUSH_BOX_DRAWS`),
and skips the cases of `QUICK_SKIPPED` (the emulator runs in real time after a start-up of several seconds).

Parameters per case (`case_filter_params`; a spec's own parameters win): paper-cbf the tuning its case's rate is
about (`PAPER_TUNINGS`: the paper's tables I and II); e-erg `EERG_PARAMS` (contact aware, the true plate stiffness
in an interval around the model's that holds the mismatch study's and the stiff-plate case's); c-erg (its presets
included: `c-erg:recommended`) contact_aware as the plant is, and nothing else: false on the PCC plant (paper_sim:
the tip passes through the plate, which pushes back nowhere), true on the MuJoCo plants (the plate on its spring);
other filters their own defaults.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controllers.registry import PluginLoadError, build_filter, find_preset
from controllers.contract.safety_filter import FilterContext
from scenarios import get
from scenarios.common import build_safe_set, load_robot
from scenarios.run import FILTER_FAULT
from softcbf.bench.battery import load_battery
from softcbf.bench.figures import draw_figures, f_max_of, pooled_figures, run_figures, study_draws, study_figures
from softcbf.bench.filters import FilterSpec
from softcbf.study.definition import Study
from softcbf.study.execute import run_study
from softcbf.study.store import faulted
from softcbf_mj.outputs.push_force import steady_force_of_folder
from softcbf_mj.outputs.runio import read_run_folder, safe_name
from vocabulary.project_files import project_file
from vocabulary.sections import joined
from vocabulary.settings import default

BATTERY = load_battery()
PAPER_TUNINGS: dict[str, str] = BATTERY.bench["paper_tunings"]
EERG_PARAMS: dict[str, str] = BATTERY.bench["eerg_params"]
PUSH_PREFIX: dict[str, str] = BATTERY.bench["push_plants"]  # a contact task's plant → its cases' prefix
PUSH_PLANTS = tuple(PUSH_PREFIX)
PUSH_RATIOS = tuple(BATTERY.bench["push_ratios"])
FORCE_TARGET_RATIO: float = BATTERY.bench["force_target_ratio"]
PUSH_DURATION_S: float = BATTERY.bench["push_duration"]
QUICK_DURATION_S: float = BATTERY.quick["duration"]
QUICK_PUSH_DURATION_S: float = BATTERY.quick["push_duration"]
QUICK_PUSH_BOX_DRAWS: int = BATTERY.quick["box_draws"]
QUICK_SKIPPED: dict[str, str] = BATTERY.quick["skipped"]


@dataclass(frozen=True)
class RunOptions:
    """How a case runs: quick (CI) or full, local worker processes of the study and the falsifications, the study
    cases' draws (None: each case's own), the falsification budget; and what happens to a bench folder in --out
    (softcbf.bench.folder: `prepare_bench_dir`): resume it, or overwrite it."""

    quick: bool = False
    workers: int = 1
    mismatch_draws: int | None = None
    resume: bool = False
    overwrite: bool = False
    falsify_budget: int | None = None
    """Evaluations of each filter's worst-case search (softcbf.bench.runner); None: the default, 0: none."""

    @property
    def draws(self) -> int:
        """bench.json's "mismatch_draws": the study case's draws (`Case.draws`; `MISMATCH_DRAWS` unless given)."""
        return BATTERY.quick["study_draws"] if self.quick else (self.mismatch_draws or MISMATCH_DRAWS)


@dataclass(frozen=True)
class Case:
    """One battery case: its name, the loop rate class ("1kHz" or "camera"), how it runs
    (`run(case, spec, folder, options) -> figures`), its fixed scenario parameters ("scenario": the registered
    scenario; a `push` case's include its contact task's), its asked force and its table in battery.toml."""

    name: str
    rate: str
    run: Callable[["Case", FilterSpec, Path, RunOptions], dict[str, Any]]
    scenario_params: dict[str, Any] = field(default_factory=dict)
    asked_N: float | None = None
    """A contact task's asked force (N): the unfiltered plant's steady measured force; None: no force asked."""
    resumable: bool = False
    """Whether `--resume` continues the case's folder (a study) instead of running it again from scratch."""
    table: Mapping[str, Any] = field(default_factory=dict)
    """The case's table in battery.toml, as read (softcbf.bench.battery)."""

    def quick_duration_s(self) -> float:
        """The case's duration (s) with --quick: `QUICK_PUSH_DURATION_S` for a contact task, else `QUICK_DURATION_S`."""
        return QUICK_PUSH_DURATION_S if self.asked_N is not None else QUICK_DURATION_S

    def draws(self, options: RunOptions) -> int:
        """A study or box case's draws: --quick's (`[quick]` study_draws, box_draws), else the case's own (a study
        case's: `options.mismatch_draws` when given)."""
        study = self.table["run"] == "study"
        if options.quick:
            return BATTERY.quick["study_draws" if study else "box_draws"]
        return (options.mismatch_draws if study else None) or self.table["draws"]


def case_filter_params(spec: FilterSpec, case: Case) -> dict[str, str]:
    """The filter's parameters in `case`: the per-case defaults (module docstring) updated with the spec's own."""
    pushes_back = case.scenario_params.get("scenario") != "paper_sim"
    preset = find_preset(spec.name)
    defaults = {"paper-cbf": {"tuning": PAPER_TUNINGS[case.rate]}, "e-erg": dict(EERG_PARAMS),
                "c-erg": {"contact_aware": "true" if pushes_back else "false"}}.get(
        spec.name if preset is None else preset.filter, {})
    return {**defaults, **spec.params}


def scenario_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """A case that is one run of a registered scenario; a contact task's row adds the delivered force."""
    params = {k: v for k, v in case.scenario_params.items() if k != "scenario"}
    params.update(filter=spec.name, filter_params=joined("filter_params", case_filter_params(spec, case)), progress=False)
    if options.quick:
        params["duration"] = case.quick_duration_s()
    out.mkdir(parents=True)
    get(case.scenario_params["scenario"]).run(out, **params)
    figures = pooled_figures(run_figures(out), f_max_of(out))
    if case.asked_N is None or figures["fault"]:  # a push cut short by a fault delivered no steady force
        return figures
    delivered = steady_force_of_folder(out)
    return {**figures, "force_delivered_N": delivered,
            "force_delivered_ratio": delivered / min(case.asked_N, figures["f_max_N"])}


def step_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """The step case: seeded step commands from rest, pooled (module docstring)."""
    quick = BATTERY.quick
    starts = quick["step_starts"] if options.quick else case.table["starts"]
    duration = quick["step_duration"] if options.quick else case.scenario_params["duration"]
    runs = []
    for seed in range(starts):
        folder = out / f"seed-{seed:02d}"
        folder.mkdir(parents=True)
        get(case.scenario_params["scenario"]).run(
            folder, duration=duration, filter=spec.name, filter_params=joined("filter_params", case_filter_params(spec, case)),
            nominal="step", nominal_params={"seed": str(seed), **case.scenario_params["nominal_params"]}, progress=False)
        runs += run_figures(folder)
    return pooled_figures(runs, f_max_of(folder))


def emulator_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """The hardware mode on the emulator (`softcbf hardware`), its figures from the 1 kHz ground truth."""
    from hardware.config import HardwareConfig  # OpenCV, 0.16 s to import (-X importtime): only where the emulator runs
    from softcbf import hardware_cli  # the hardware mode, 0.18 s more (-X importtime): only here

    out.mkdir(parents=True)
    argv = [str(EMULATOR_CONFIG)]
    for name, value in case.table["options"].items():
        argv += [f"--{name}", str(value)]
    argv += ["--filter", spec.name, "--duration", str(case.table["duration"]), "--out", str(out / "run")]
    for name, value in case_filter_params(spec, case).items():
        argv += ["--filter-param", f"{name}={value}"]
    code = hardware_cli.main(argv)
    ended_on_fault = code == FILTER_FAULT and (out / "run").is_dir() and any(
        faulted(row) for row in read_run_folder(out / "run").runs)
    if code != 0 and not ended_on_fault:  # a filter fault is the row's result (softcbf.bench.figures)
        raise RuntimeError(f"softcbf hardware {' '.join(argv)} exited with {code}")
    return pooled_figures(run_figures(out / "run"), HardwareConfig.load(EMULATOR_CONFIG).safe_set().f_max,
                          force_key="force_max_emulator_N", violation_key="t_violation_emulator_s")


def study_name(spec: FilterSpec, case: Case) -> str:
    """The study of a study or box case with `spec`: "bench_CASE_FILTER"."""
    return f"bench_{case.name}_{safe_name(spec.name)}"


def mismatch_study(spec: FilterSpec, case: Case, draws: int, duration: float) -> Study:
    """A study case's `softcbf.study.definition.Study` for `spec` (module docstring): its table read as a study file
    (`Study.from_dict`) with the filter under test, `draws` samples, each `duration` s long (the case's; --quick:
    `QUICK_DURATION_S`)."""
    table = case.table
    return Study.from_dict({
        **{key: table[key] for key in ("description", "scenario", "seed", "sampling", "vary")},
        "name": study_name(spec, case), "tunings": [spec.name], "tuning_parameter": "filter", "draws": draws,
        "fixed": {**table["fixed"], "duration": duration}, "filter_params": case_filter_params(spec, case)})


def mismatch_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """A study case: its study run (continued with --resume) and pooled over its samples."""
    study = mismatch_study(spec, case, case.draws(options),
                           QUICK_DURATION_S if options.quick else case.scenario_params["duration"])
    run_study(study, out, workers=options.workers, keep_runs=True, progress=not options.quick,
              resume=options.resume and out.exists())
    return study_figures(out)


def push_box_study(spec: FilterSpec, case: Case, draws: int, duration: float) -> Study:
    """A box case's `softcbf.study.definition.Study` for `spec` (module docstring): the standard box of its file with
    the filter under test, `draws` draws of its contact task's push, each `duration` s long from rest
    (`PUSH_DURATION_S`; --quick: `QUICK_PUSH_DURATION_S`)."""
    from softcbf.study.worst_found import box_study  # optuna, 0.25 s to import (-X importtime): only for a box case

    plant, table = case.scenario_params["scenario"], case.table
    box = box_study(spec.name, case_filter_params(spec, case), duration=duration, box_file=project_file(table["box"]))
    task = TASKS[plant, table["push"]].scenario_params
    push = {"nominal": task["nominal"], "nominal_params": dict(task["nominal_params"]),
            **{k: v for k, v in task.items() if k not in ("scenario", "duration", "nominal", "nominal_params")}}
    return dataclasses.replace(
        box, name=study_name(spec, case), fixed={**{k: v for k, v in box.fixed.items() if k != "t0"}, **push, **table["fixed"]},
        sampling=table["sampling"], draws=draws, description=table["description"])


def push_box_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    """A box case: its study run (continued with --resume) and pooled over its draws (`draw_figures`)."""
    study = push_box_study(spec, case, case.draws(options), QUICK_PUSH_DURATION_S if options.quick else PUSH_DURATION_S)
    run_study(study, out, workers=options.workers, keep_runs=True, progress=not options.quick,
              resume=options.resume and out.exists())
    return draw_figures(*study_draws(out))


RUNS: dict[str, Callable[[Case, FilterSpec, Path, RunOptions], dict[str, Any]]] = {
    "scenario": scenario_case, "step": step_case, "emulator": emulator_case, "study": mismatch_case, "box": push_box_case}
"""How a case of each run kind (battery.toml's `run`) runs."""


def case_of(table: Mapping[str, Any], tasks: Mapping[tuple[str, str], Case]) -> Case:
    """The `Case` of a battery.toml case table (its contact tasks so far by (plant, task): a `push` case's nominal
    settings and asked force are its task's)."""
    params = dict(table.get("fixed", {}))
    asked = table.get("asked_N")
    if "push" in table:
        task = tasks[table["scenario"], table["push"]]
        asked = task.asked_N if asked is None else asked
        if table["run"] == "scenario":
            params.update({k: v for k, v in task.scenario_params.items() if k != "scenario"})
    scenario = {"scenario": table["scenario"]} if "scenario" in table else {}
    return Case(table["name"], table["rate"], RUNS[table["run"]], {**scenario, **params}, asked,
                resumable=table["run"] in ("study", "box"), table=table)


def battery_cases() -> tuple[Case, ...]:
    """The battery's cases, in the file's order (a `push` names a task of an earlier case: softcbf.bench.battery)."""
    tasks: dict[tuple[str, str], Case] = {}
    cases = []
    for table in BATTERY.cases:
        case = case_of(table, tasks)
        if "task" in table:
            tasks[table["scenario"], table["task"]] = case
        cases.append(case)
    return tuple(cases)


CASES = battery_cases()
TASKS = {(c.table["scenario"], c.table["task"]): c for c in CASES if "task" in c.table}
"""The contact tasks by (plant, task name)."""
PUSHES: dict[str, dict[str, tuple[dict[str, str], float]]] = {
    plant: {task: (case.scenario_params["nominal_params"], case.asked_N) for (p, task), case in TASKS.items() if p == plant}
    for plant in PUSH_PLANTS}
"""The contact tasks (docs/beyond-the-paper.md#contact-tasks): per plant, {task: (nominal_params, asked N)}: the
constant pushes asking `PUSH_RATIOS` × F_max (nominal "step" with low_hPa = high_hPa = the level found by
tools/force_levels.py), the full 150 hPa push and the force-target nominal (target `FORCE_TARGET_RATIO` F_max of
the model's predicted force); asked: the unfiltered plant's steady measured force."""
BOX_CASES = tuple(c for c in CASES if c.table["run"] == "box")
BOX_PUSH = BOX_CASES[0].table["push"]  # the contact task that the box cases and the flexure case run
PUSH_BOX_FILES = {c.scenario_params["scenario"]: c.table["box"] for c in BOX_CASES}
PUSH_BOX_DRAWS = min(c.table["draws"] for c in BOX_CASES)
FLEXURE_ASKED_N = next(c.asked_N for c in CASES if c.scenario_params.get("plate") == "flexure")
THREE_SEGMENT_CASES = tuple(c for c in CASES if "robot" in c.scenario_params)
"""The 3-segment cases (module docstring): a constant push on the "three-segment" arm, on the PCC and the MuJoCo plant."""
MISMATCH_DRAWS = next(c.table["draws"] for c in CASES if c.table["run"] == "study")  # --mismatch-draws' default
EMULATOR_CONFIG = project_file(next(c.table["config"] for c in CASES if c.table["run"] == "emulator"))


def plant_parameters(plant: str) -> dict[str, Any]:
    """A contact task's scenario parameters on `plant` besides its duration and nominal (camera_loop saves no frames)."""
    task = next(c for (p, _), c in TASKS.items() if p == plant)
    return {k: v for k, v in task.scenario_params.items() if k not in ("scenario", "duration", "nominal", "nominal_params")}


def push_cases() -> tuple[Case, ...]:
    """The contact-task cases (`PUSHES`), in the battery's order."""
    return tuple(TASKS.values())


def contact_error_cases() -> tuple[Case, ...]:
    """The contact cases under error (module docstring): a box case per plant, the push on the flexure sheet."""
    return tuple(c for c in CASES if "push" in c.table)


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
