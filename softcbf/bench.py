"""`softcbf bench`: every selected safety filter over one fixed battery (docs/beyond-the-paper.md#filter-benchmark).

    softcbf bench --out DIR [--filters SPEC,SPEC,...] [--quick] [--cases NAME,...] [--mismatch-draws N] [--workers N]
                  [--falsify-budget N] [--resume | --overwrite]

Battery (`CASES`, in this order; each case runs registered scenarios with fixed parameters):

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

The worst case found (`softcbf.study.worst_found`, beside the cases): per filter, a falsification
(`softcbf study falsify`'s search) over the standard mismatch box's physical errors on mujoco_contact
(studies/mismatch_box_contact.toml) with the filter's mujoco_contact parameters, for a fixed budget of
evaluations (`--falsify-budget N`; default `worst_found.BUDGET` = 36 for the whole battery,
`worst_found.QUICK_BUDGET` = 4 of 1 s with --quick, 0 with --cases; 0 turns it off). bench.json's
"falsify" names the box and the budget (and the rest of the search's settings); its "worst_found" holds
one entry per filter (`WORST_KEYS`): rho_worst_found, the minimum ρ_min_meas over the evaluations, with
that evaluation's parameters. Its folder: DIR/cases/<filter label>/worst_found/ (a falsification folder).

The 3-segment cases (`THREE_SEGMENT_CASES`). The arm is models/robots/three_segment.json
(`controllers.params.uniform_robot(3)`: three reference segments, reach 0.366 m); at rest
its tip lies 17 mm inside the paper's facet 0.36 x + y ≤ 0.15 m, and the 40 hPa push bends
it through the plate: unfiltered, ρ_meas −6.6 (paper_sim) and −3.2 (mujoco_contact), F max
1.22 and 0.67 N against F_max = 0.16 N, in contact from ≈ 0.1 s (1 s runs), so the short
--quick runs test the filter in contact too. A filter that cannot be built for a case's arm
(e-erg: its escape-energy table is a q-space grid, N ≤ 2) is not run there: `arm_refusal`
builds every selected filter once on the case's arm (the paper's safe set at the scenario's
defaults, 1 kHz) before the bench starts, and bench.json's "skipped" records the pair under
the key "FILTER x CASE" with the filter's own message.

Contact tasks. "Asking for F" means the unfiltered plant's steady measured force is F (the
mean over the last third of the push, `steady_force`); the step levels (the same on both
segments) are found once by tools/force_levels.py and stored with the cases (`PUSHES`: the
nominal's parameters and the asked force). Their rows hold `force_asked_N` and
`force_delivered_N` (the run's steady measured force), `force_delivered_ratio` = delivered /
min(asked, F_max); every row holds `force_budget_used` = F max / F_max and `f_max_N` (the
scenario's F_max); the other cases have null in the three force_* fields of a push.
bench.md links plots/force_budget.png: delivered against asked, per plant, every filter.

The step case runs on paper_sim (the PCC plant at 1 kHz with the exact state): a step is
a test of the filter's own response to a sudden, large command, which the camera path's
latency would mix with perception effects that the camera cases already cover.
`--quick` (CI) cuts every duration to `QUICK_DURATION_S` = 1 s (the contact tasks' pushes too), the steps to 3 starts of
0.5 s, the mismatch study to 2 draws of 1 s and skips the emulator (it runs in real
time after a start-up of several seconds); bench.json says "quick": true and lists the
skipped cases with the reason ("skipped": {case or "FILTER x CASE": reason}).

Filters. `--filters` is a comma list of specs `NAME` or `NAME(param=value,...)` (NAME: a
registry spec, `controllers.registry`: "paper-cbf", "none", "qsg", "e-erg",
FILE.py:Factory, package.module:Factory), e.g. `"e-erg(contact_aware=true),paper-cbf(tuning=HW-High)"`;
default "e-erg,paper-cbf". Parameters not given take the per-case defaults of
`case_filter_params`: paper-cbf the tuning its case is about (`PAPER_TUNINGS`: "Low" in
the 1 kHz cases, "HW-High" in the 10 Hz camera cases: the paper's tables I and II);
e-erg contact_aware=true with the true plate stiffness in [0.9, 1.1] × the model's
(`EERG_PARAMS`: the mismatch study's interval, which also holds the stiff-plate case);
c-erg the same interval (`CERG_PARAMS`) and contact_aware as the plant is: false on the PCC
plant (paper_sim_150, step, paper_sim_3seg: the tip passes through the plate, which pushes back nowhere), true
on the MuJoCo plants (the plate on its spring); other filters their own defaults.

Figures per (filter, case): ρ_meas min, t_violation, F max from the scenario's summary row
(the emulator: F max and t_violation from its 1 kHz ground truth, ρ_meas at the control
cycles); u_dev_rms_hPa, blocked_s, switches_per_s, filter_us_median and filter_us_p99 from
`controllers.filter_metrics.governor_figures` over the filter's call rows of the run's time
series (u: the command sent). Cases of several runs (step, camera_mismatch) pool them:
ρ_meas min and F max over the runs, t_violation_s and blocked_s summed, u_dev_rms the RMS
over every run's calls, switches_per_s the mean over runs, the compute time quantiles
over every call; violation_probability = k/n runs with ρ_meas < 0 and its 95 % Wilson
interval (`softcbf.study.analysis`), draws = n; single runs have null there. wall_s: the
case's wall time.

A fault is never a pass (docs/studies.md#faulted-samples). A run whose filter (or nominal) faulted stops at the vent
after its fault, so its figures cover only the rows before it (a filter that raises at its
first call leaves ρ_meas min 1.0 and t_violation 0 over a few milliseconds). Every row says how
many of its runs faulted (`faulted`, 0: none) and the first run's fault (`fault`: {type,
message, where}, null: none); a row with a fault has no verdict: rho_min_meas and t_violation_s
are null, violation_probability counts each faulted run as a violation, and the figures of the
filter's calls (u_dev_rms_hPa, blocked_s, switches_per_s: null when no run made two calls;
filter_us_*: null when none made one) and F max cover the rows up to the fault; a contact
task's force_delivered_N and force_delivered_ratio are null (no steady push). bench.md's
"filter fault" column names it, and the worst case found holds the same two fields (a
search's evaluation that faulted is its worst: rho_worst_found null, `fault` set;
`softcbf.study.falsify`).

The bench folder (`prepare_bench_dir`, as `softcbf run`'s run folders, softcbf_mj.runio). DIR
is new or empty, or it is a bench folder (it holds bench.json) and `--resume` continues it or
`--overwrite` replaces its contents; any other non-empty folder (a user's, a run folder) is
refused, also with `--overwrite`, as is overwriting the working folder, one above it or home.
DIR is locked while the bench runs (a second bench into it is refused). A fresh bench writes
bench.json with no rows first (so a bench that stops later can be resumed) and, when it stops
before its first row, removes what it wrote. `--cases` and `--filters` must name at least one
case / filter (an empty list is refused, not read as the whole battery), and a filter's
parameter may be given once.

Resume. The full battery takes hours (the mismatch study dominates). `--resume` continues
an interrupted `softcbf bench` in the same DIR: a (filter, case) whose row is in DIR/bench.json
keeps it and is not run again (its row must come from a run with the same quick flag,
mismatch draws and "falsify" settings), as does a filter's worst_found entry; a mismatch study or
a falsification whose folder exists continues where it stopped (the study machinery refuses a
folder of another study definition); any other case runs again from
scratch. bench.json is checked first (`check_bench_json`: the fields and types of docs/beyond-the-paper.md#filter-benchmark, numbers
finite, times, RMS and compute times >= 0, probabilities in [0, 1], known cases, filters of its
own list, each (filter, case) once; the same for "worst_found"); a file that fails is refused with one line naming the
field, and nothing runs. Ctrl-C exits with 130 after one line that says what is stored and to continue with
`--resume` (or that nothing was: a fresh bench interrupted before its first row leaves nothing).

Progress: a line on stderr (softcbf_mj.progress) counts the cases to run now ("case k of n", the worst-case
searches included, kept rows not) with an ETA, refreshed while a case runs; each finished case's line on stdout
ends with the same "case k of n, eta …".

Outputs: DIR/bench.json (`{"battery", "quick", "mismatch_draws", "filters", "skipped", "results", "falsify",
"worst_found"}`; every result row holds `RESULT_KEYS`, every worst_found entry `WORST_KEYS`), DIR/bench.md (the
tables), DIR/plots/bench.png,
DIR/plots/force_budget.png (with contact tasks), and each
case's run or study folder under DIR/cases/<filter label>/<case>/.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controllers.filter_metrics import governor_figures
from controllers.registry import FILTERS, check_filter, resolve
from softcbf.study.store import fault_of, faulted
from softcbf_mj.progress import Progress, duration_text
from softcbf_mj.runio import (
    RUN_MARKER, OutputDirError, load_timeseries, prepare_out_dir, read_run_folder, release_out_dir, remove_if_unused,
    safe_name,
)
from vocabulary.project_files import project_file
from vocabulary.sections import joined
from vocabulary.settings import Bound, check_number, default, non_negative

RESULT_KEYS = ("filter", "case", "rho_min_meas", "t_violation_s", "force_max_N", "violation_probability", "violation_ci95",
               "draws", "u_dev_rms_hPa", "blocked_s", "switches_per_s", "filter_us_median", "filter_us_p99", "wall_s",
               "force_asked_N", "force_delivered_N", "force_delivered_ratio", "force_budget_used", "f_max_N",
               "faulted", "fault")
VERDICT_KEYS = ("rho_min_meas", "t_violation_s")  # null exactly when a run of the row faulted (module docstring)
CALL_KEYS = ("u_dev_rms_hPa", "blocked_s", "switches_per_s", "filter_us_median", "filter_us_p99")  # null only then
WORST_KEYS = ("filter", "rho_worst_found", "params", "evaluation", "evaluations", "failed", "first_violation", "wall_s",
              "faulted", "fault")
WORST_DIR = "worst_found"  # a filter's falsification folder: DIR/cases/<filter label>/worst_found
DEFAULT_FILTERS = "e-erg,paper-cbf"
PAPER_TUNINGS = {"1kHz": "Low", "camera": "HW-High"}
EERG_PARAMS = {"contact_aware": "true", "stiffness_lo_ratio": "0.9", "stiffness_hi_ratio": "1.1"}
CERG_PARAMS = {"stiffness_lo_ratio": "0.9", "stiffness_hi_ratio": "1.1"}
STEP_STARTS, STEP_DURATION_S = 20, 5.0
MISMATCH_DRAWS, MISMATCH_SEED = 100, 2026
MISMATCH_T0_S, MISMATCH_DURATION_S = 15.0, 30.0  # s: from the first contact on (module docstring)
ASSUMED_PLATE_N_PER_M = default("assumed_plate_stiffness", "camera_loop")  # the camera cases' model plate (N/m)
QUICK_DURATION_S = 1.0
QUICK_STEP_STARTS, QUICK_STEP_DURATION_S, QUICK_MISMATCH_DRAWS = 3, 0.5, 2
EMULATOR_CONFIG = project_file("examples/hardware_emulated.toml")
EMULATOR_DURATION_S = 20.0
BENCH_FILE, TABLE_FILE, PLOT_FILE, FORCE_PLOT_FILE = "bench.json", "bench.md", "plots/bench.png", "plots/force_budget.png"
PUSH_PLANTS = ("mujoco_contact", "camera_loop")
PUSH_RATIOS = (0.3, 0.6, 0.9, 1.2)
FORCE_TARGET_RATIO = 0.6
PUSH_DURATION_S = 6.0
THREE_SEGMENT_ROBOT, THREE_SEGMENT_PUSH_HPA = "three-segment", 40.0
FORCE_PLOT_TOP = 1.5


def plant_parameters(plant: str) -> dict[str, Any]:
    """A contact task's scenario parameters besides the nominal: the plant at its defaults (camera_loop saves no frames)."""
    return {"saved_frames_hz": 0.0} if plant == "camera_loop" else {}


def steady_force(force: np.ndarray) -> float:
    """The steady measured force of a push (N): the mean over the last third of the run's samples of the
    largest facet force per sample (`force`: (T,) or (T, plates) N)."""
    force = np.asarray(force, dtype=float)
    per_sample = force.max(axis=1) if force.ndim == 2 else force
    if per_sample.size == 0:
        raise ValueError("a push needs at least one force sample")
    return float(np.mean(per_sample[-max(1, per_sample.size // 3):]))


def steady_force_of_folder(folder: Path) -> float:
    """`steady_force` of the one run in a run folder (its time series' `contact_force`)."""
    run_folder = read_run_folder(folder)
    if len(run_folder.runs) != 1:
        raise ValueError(f"{folder} holds {len(run_folder.runs)} runs; a push is one run")
    series, _ = load_timeseries(folder / run_folder.runs[0]["timeseries"])
    return steady_force(series["contact_force"])


@dataclass(frozen=True)
class FilterSpec:
    """A filter under test: a registry spec and the parameters given for it ({name: text})."""

    name: str
    params: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        args = ",".join(f"{k}={v}" for k, v in self.params.items())
        return f"{self.name}({args})" if args else self.name


def parse_filters(text: str) -> list[FilterSpec]:
    """`"NAME,NAME(param=value,...),..."` → filter specs (module docstring); ValueError naming the bad item."""
    items, depth, start = [], 0, 0
    for i, char in enumerate(text + ","):
        depth += {"(": 1, ")": -1}.get(char, 0)
        if depth < 0:
            raise ValueError(f"--filters has an unmatched ')' at position {i}: {text!r}")
        if char == "," and depth == 0:
            items.append(text[start:i].strip())
            start = i + 1
    if depth:
        raise ValueError(f"--filters has an unclosed '(': {text!r}")
    specs = []
    for item in items:
        match = re.fullmatch(r"([^()]+?)\s*(?:\((.*)\))?", item)
        if not item or match is None:
            raise ValueError(f"--filters takes NAME or NAME(param=value,...) separated by commas, got {item!r} in {text!r}")
        params = {}
        for pair in filter(None, (p.strip() for p in (match.group(2) or "").split(","))):
            name, sep, value = pair.partition("=")
            if not sep or not name.strip():
                raise ValueError(f"filter parameters must be name=value, got {pair!r} in {item!r}")
            if name.strip() in params:
                raise ValueError(f"filter parameter {name.strip()} is given twice in {item!r}; give it once")
            params[name.strip()] = value.strip()
        resolve(match.group(1), FILTERS)
        specs.append(FilterSpec(match.group(1), params))
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"--filters names a filter twice: {text!r}")
    return specs


@dataclass(frozen=True)
class Case:
    """One battery case: its name, the loop rate class ("1kHz" or "camera"), how it runs
    (`run(case, spec, folder, options) -> figures`) and its fixed scenario parameters
    ("scenario": the registered scenario when it is not the case's name)."""

    name: str
    rate: str
    run: Callable[["Case", FilterSpec, Path, "RunOptions"], dict[str, Any]]
    scenario_params: dict[str, Any] = field(default_factory=dict)
    asked_N: float | None = None
    """A contact task's asked force (N): the unfiltered plant's steady measured force (`PUSHES`); None: no force asked."""


def case_filter_params(spec: FilterSpec, case: Case) -> dict[str, str]:
    """The filter's parameters in `case`: the per-case defaults (module docstring) updated with the spec's own."""
    pushes_back = case.scenario_params.get("scenario", "") != "paper_sim" and case.name != "step"
    defaults = {"paper-cbf": {"tuning": PAPER_TUNINGS[case.rate]}, "e-erg": dict(EERG_PARAMS),
                "c-erg": {**CERG_PARAMS, "contact_aware": "true" if pushes_back else "false"}}.get(spec.name, {})
    return {**defaults, **spec.params}


def _call_rows(path: Path) -> dict[str, np.ndarray]:
    """A run's time series restricted to the filter's call rows (t, u, u_nom, filter_us, rho_meas)."""
    series, _ = load_timeseries(path)
    calls = np.isfinite(series["filter_us"])
    return {k: np.asarray(series[k])[calls] for k in ("t", "u", "u_nom", "filter_us")}


def _run_figures(folder: Path) -> list[tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """(summary row, call rows) of every run in a run folder."""
    run_folder = read_run_folder(folder)
    return [(row, _call_rows(folder / row["timeseries"])) for row in run_folder.runs]


def _f_max(folder: Path) -> float:
    """The force limit F_max (N) of a scenario's run folder (its parameters' f_max)."""
    return float(read_run_folder(folder).summary["params"]["f_max"])


def pooled_figures(runs: Sequence[tuple[Mapping[str, Any], Mapping[str, np.ndarray]]], f_max: float,
                   force_key: str = "force_max_N", violation_key: str = "t_violation_s") -> dict[str, Any]:
    """The figures of one case from its runs' summary rows and call rows (module docstring: pooling and faults);
    `f_max` (N): the case's force limit (force_budget_used = F max / f_max)."""
    from softcbf.study.analysis import wilson_interval

    if not runs:
        raise ValueError("a case needs at least one run")
    timed = [c for _, c in runs if c["t"].size >= 2]  # a run that faulted early may have made fewer calls
    per_run = [governor_figures(c["t"], c["u"], c["u_nom"], c["filter_us"]) for c in timed]
    calls = np.concatenate([np.asarray(c["filter_us"], dtype=float) for _, c in runs])
    weights = np.array([c["t"].size for c in timed], dtype=float)
    rho = [float(r["rho_min_meas"]) for r, _ in runs]
    faults = [fault_of(r) for r, _ in runs if faulted(r)]
    force_max = max(float(r[force_key]) for r, _ in runs)
    out = {
        "rho_min_meas": None if faults else min(rho),
        "t_violation_s": None if faults else float(sum(float(r[violation_key]) for r, _ in runs)),
        "force_max_N": force_max, "f_max_N": f_max, "force_budget_used": force_max / f_max,
        "violation_probability": None, "violation_ci95": None, "draws": None,
        "u_dev_rms_hPa": float(math.sqrt(np.average([f["u_dev_rms_hPa"] ** 2 for f in per_run], weights=weights)))
        if per_run else None,
        "blocked_s": float(sum(f["blocked_s"] for f in per_run)) if per_run else None,
        "switches_per_s": float(np.mean([f["switches_per_s"] for f in per_run])) if per_run else None,
        "filter_us_median": float(np.median(calls)) if calls.size else None,
        "filter_us_p99": float(np.percentile(calls, 99)) if calls.size else None,
        "faulted": len(faults), "fault": faults[0] if faults else None,
    }
    if len(runs) > 1:
        violations = sum(faulted(r) or float(r["rho_min_meas"]) < 0 for r, _ in runs)
        out.update(violation_probability=violations / len(runs), violation_ci95=list(wilson_interval(violations, len(runs))),
                   draws=len(runs))
    return out


@dataclass(frozen=True)
class RunOptions:
    """How a case runs: quick (CI) or full, local worker processes of the study and the falsifications, mismatch draws
    (None: `MISMATCH_DRAWS`), the falsification budget; and what happens to a bench folder in --out
    (`prepare_bench_dir`): resume it, or overwrite it."""

    quick: bool = False
    workers: int = 1
    mismatch_draws: int | None = None
    resume: bool = False
    overwrite: bool = False
    falsify_budget: int | None = None
    """Evaluations of each filter's worst-case search (module docstring); None: the default, 0: none."""


def _scenario_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    from scenarios import get

    params = {k: v for k, v in case.scenario_params.items() if k != "scenario"}
    params.update(filter=spec.name, filter_params=joined("filter_params", case_filter_params(spec, case)), progress=False)
    if options.quick:
        params["duration"] = QUICK_DURATION_S
    out.mkdir(parents=True)
    get(case.scenario_params.get("scenario", case.name)).run(out, **params)
    figures = pooled_figures(_run_figures(out), _f_max(out))
    if case.asked_N is None or figures["fault"]:  # a push cut short by a fault delivered no steady force
        return figures
    delivered = steady_force_of_folder(out)
    return {**figures, "force_delivered_N": delivered,
            "force_delivered_ratio": delivered / min(case.asked_N, figures["f_max_N"])}


def _step_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    from scenarios import get

    starts, duration = (QUICK_STEP_STARTS, QUICK_STEP_DURATION_S) if options.quick else (STEP_STARTS, STEP_DURATION_S)
    runs = []
    for seed in range(starts):
        folder = out / f"seed-{seed:02d}"
        folder.mkdir(parents=True)
        get("paper_sim").run(folder, duration=duration, filter=spec.name, filter_params=joined("filter_params", case_filter_params(spec, case)),
                             nominal="step", nominal_params=f"seed={seed};low_hPa=60;high_hPa=300", progress=False)
        runs += _run_figures(folder)
    return pooled_figures(runs, _f_max(folder))


def _emulator_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    from softcbf import hardware_cli

    out.mkdir(parents=True)
    argv = [str(EMULATOR_CONFIG), "--robot", "reference", "--port", "emulated", "--camera", "virtual", "--filter", spec.name,
            "--duration", str(EMULATOR_DURATION_S), "--out", str(out / "run")]
    for name, value in case_filter_params(spec, case).items():
        argv += ["--filter-param", f"{name}={value}"]
    code = hardware_cli.main(argv)
    from scenarios.run import FILTER_FAULT

    ended_on_fault = code == FILTER_FAULT and (out / "run").is_dir() and any(
        faulted(row) for row in read_run_folder(out / "run").runs)
    if code != 0 and not ended_on_fault:  # a filter fault is the row's result (module docstring)
        raise RuntimeError(f"softcbf hardware {' '.join(argv)} exited with {code}")
    from hardware.config import HardwareConfig

    return pooled_figures(_run_figures(out / "run"), HardwareConfig.load(EMULATOR_CONFIG).safe_set().f_max,
                          force_key="force_max_emulator_N", violation_key="t_violation_emulator_s")


def mismatch_study(spec: FilterSpec, case: Case, draws: int, duration: float):
    """The camera_mismatch case's `softcbf.study.definition.Study` for `spec` (module docstring), each sample
    `duration` s long (`MISMATCH_DURATION_S`; --quick: `QUICK_DURATION_S`)."""
    from softcbf.study.definition import Distribution, Study

    k = ASSUMED_PLATE_N_PER_M
    fixed = {"t0": MISMATCH_T0_S, "duration": duration, "saved_frames_hz": 0.0, "progress": False,
             "assumed_plate_stiffness": k, "filter_params": joined("filter_params", case_filter_params(spec, case))}
    vary = (Distribution("plate_stiffness", "uniform", low=0.9 * k, high=1.1 * k),
            Distribution("true_gain_scale", "uniform", low=0.9, high=1.1),
            Distribution("facet_offset", "uniform", low=-1e-3, high=1e-3))
    return Study(name=f"bench_camera_mismatch_{safe_name(spec.name)}", scenario="camera_loop", tunings=(spec.name,),
                 tuning_parameter="filter", vary=vary, fixed=fixed, draws=draws, seed=MISMATCH_SEED,
                 description="softcbf bench: camera_loop with plate stiffness ±10 %, actuator gain ±10 %, facet offset ±1 mm")


def study_figures(folder: Path) -> dict[str, Any]:
    """A mismatch study folder (run with keep_runs) → the case's figures over its samples that ran (ok or faulted:
    a fault is never a pass, module docstring)."""
    from softcbf.study.analysis import clean
    from softcbf.study.store import StudyStore

    store = StudyStore.open(folder)
    rows = [r for r in store.load_rows() if clean(r) or faulted(r)]
    if not rows:
        raise RuntimeError(f"study {folder} has no finished sample")
    runs = []
    for row in rows:
        runs += _run_figures(store.run_dir(int(row["sample"])))
    return pooled_figures(runs, _f_max(store.run_dir(int(rows[0]["sample"]))))


def _mismatch_case(case: Case, spec: FilterSpec, out: Path, options: RunOptions) -> dict[str, Any]:
    from softcbf.study.execute import run_study

    draws = QUICK_MISMATCH_DRAWS if options.quick else (options.mismatch_draws or MISMATCH_DRAWS)
    study = mismatch_study(spec, case, draws, QUICK_DURATION_S if options.quick else MISMATCH_DURATION_S)
    run_study(study, out, workers=options.workers, keep_runs=True, progress=not options.quick,
              resume=options.resume and out.exists())
    return study_figures(out)


CASES: tuple[Case, ...] = (
    Case("paper_sim_150", "1kHz", _scenario_case, {"scenario": "paper_sim", "amplitude": 150.0}),
    Case("step", "1kHz", _step_case),
    Case("mujoco_contact", "1kHz", _scenario_case),
    Case("camera_loop", "camera", _scenario_case, {"saved_frames_hz": 0.0}),
    Case("camera_stiff_close", "camera", _scenario_case,
         {"scenario": "camera_loop", "plate_stiffness": 1.1 * ASSUMED_PLATE_N_PER_M, "facet_offset": -1e-3, "saved_frames_hz": 0.0}),
    Case("hardware_emulator", "camera", _emulator_case),
    Case("camera_mismatch", "camera", _mismatch_case),
)
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
    """The contact-task cases of `PUSHES`: `PUSH_DURATION_S` from rest (quick: `QUICK_DURATION_S`)."""
    return tuple(
        Case(f"{PUSH_PREFIX[plant]}_{suffix}", "1kHz" if plant == "mujoco_contact" else "camera", _scenario_case,
             {"scenario": plant, "duration": PUSH_DURATION_S, "nominal": "force-target" if suffix == "force_target" else "step",
              "nominal_params": nominal_params, **plant_parameters(plant)}, asked)
        for plant, tasks in PUSHES.items() for suffix, (nominal_params, asked) in tasks.items())


THREE_SEGMENT_CASES: tuple[Case, ...] = tuple(
    Case(name, "1kHz", _scenario_case,
         {"scenario": plant, "robot": THREE_SEGMENT_ROBOT, "duration": PUSH_DURATION_S, "nominal": "step",
          "nominal_params": f"seed=0;low_hPa={THREE_SEGMENT_PUSH_HPA:g};high_hPa={THREE_SEGMENT_PUSH_HPA:g}"})
    for name, plant in (("paper_sim_3seg", "paper_sim"), ("mujoco_3seg", "mujoco_contact")))
"""The 3-segment cases (module docstring): a constant push on the "three-segment" arm, on the PCC and the MuJoCo plant."""
CASES = CASES + push_cases() + THREE_SEGMENT_CASES
QUICK_SKIPPED = {"hardware_emulator": "--quick: the emulator runs in real time after a start-up of several seconds"}


def skip_key(spec: FilterSpec, case: Case) -> str:
    """bench.json's "skipped" key of a (filter, case) pair that is not run: "FILTER x CASE"."""
    return f"{spec.label} x {case.name}"


def arm_refusal(spec: FilterSpec, case: Case) -> str | None:
    """Why `spec` cannot run in `case`, a case on another arm than the reference (its scenario parameter "robot"):
    the filter built on that arm's context (the paper's safe set with the scenario's defaults, 1 kHz, the arm's
    pressure limits) raises `PluginLoadError` (e-erg on N > 2); its message then, None when it builds or the
    case runs the scenario's own arm."""
    from controllers.registry import PluginLoadError, build_filter
    from controllers.safety_filter import FilterContext
    from scenarios.common import build_safe_set, load_robot
    from vocabulary.settings import default

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


def run_bench(out: str | Path, filters: Sequence[FilterSpec], options: RunOptions = RunOptions(),
              cases: Sequence[str] | None = None) -> dict[str, Any]:
    """Run `filters` over the battery (or the named `cases`; None: all) into the bench folder `out`
    (`prepare_bench_dir`: a new or empty folder, or with `options.resume` / `options.overwrite` a
    bench folder; locked while the bench runs; a case's folder is replaced); write and return
    bench.json's content (updated after every case). Everything is checked before the folder is
    touched; a fresh bench that stops before its first row leaves nothing behind."""
    out = Path(out)
    names = [c.name for c in CASES]
    selected = names if cases is None else list(cases)
    if not selected or not all(selected):
        raise ValueError(f"--cases must name at least one case and no empty one, got {','.join(selected)!r}; "
                         f"the battery: {', '.join(names)}")
    unknown = [c for c in selected if c not in names]
    if unknown:
        raise ValueError(f"unknown case(s) {', '.join(unknown)}; the battery: {', '.join(names)}")
    if options.mismatch_draws is not None and options.mismatch_draws < 1:
        raise ValueError(f"--mismatch-draws must be >= 1, got {options.mismatch_draws}")
    if options.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {options.workers}")
    if options.falsify_budget is not None and options.falsify_budget < 0:
        raise ValueError(f"--falsify-budget must be >= 0 (evaluations per filter; 0: none), got {options.falsify_budget}")
    if not filters:
        raise ValueError("--filters names no filter")
    for spec in filters:
        for case in CASES:
            check_filter(spec.name, case_filter_params(spec, case))
    skipped = {name: reason for name, reason in QUICK_SKIPPED.items() if options.quick and name in selected}
    for spec in filters:
        for case in CASES:
            reason = arm_refusal(spec, case) if case.name in selected and case.name not in skipped else None
            if reason is not None:
                skipped[skip_key(spec, case)] = reason
    draws = QUICK_MISMATCH_DRAWS if options.quick else (options.mismatch_draws or MISMATCH_DRAWS)
    searches = worst_case_searches(filters, options, cases is None)
    bench = {"battery": names, "quick": options.quick, "mismatch_draws": draws, "filters": [s.label for s in filters],
             "skipped": skipped, "results": [], "falsify": searches[0] if searches else None, "worst_found": []}
    created = not os.path.lexists(out)
    prepare_bench_dir(out, options)
    fresh = not (out / BENCH_FILE).is_file()
    try:
        done, worst_done = stored_results(out, bench) if options.resume else ({}, {})
        if fresh:
            write_outputs(out, bench)  # a bench folder from the start: a bench that stops can be resumed
        to_run = planned_cases(filters, selected, skipped, done)
        new_searches = [label for label in (searches[1] if searches else {}) if label not in worst_done]
        bar = Progress("bench", max(1, len(to_run) + len(new_searches)), enabled=bool(to_run or new_searches),
                       unit="cases")
        bar.update(0, "starting")
        with bar.ticking():  # a case may take minutes: the line's elapsed time goes on
            _run_cases(out, bench, filters, selected, skipped, done, options, bar)
            if searches:
                _run_worst_found(out, bench, searches[1], worst_done, options, bar, len(to_run))
        bar.close()
    except BaseException:
        if fresh and not bench["results"] and not bench["worst_found"]:
            _discard(out, created)
        raise
    finally:
        release_out_dir(out)
    return bench


def planned_cases(filters: Sequence[FilterSpec], selected: Sequence[str], skipped: Mapping[str, str],
                  done: Mapping[tuple[str, str], dict[str, Any]] | None = None) -> list[tuple[FilterSpec, Case]]:
    """The (filter, case) pairs the bench runs, in order: selected, not skipped and (with `done`) not kept."""
    return [(spec, case) for spec in filters for case in CASES
            if case.name in selected and case.name not in skipped and skip_key(spec, case) not in skipped
            and (done is None or (spec.label, case.name) not in done)]


def progress_text(bar: Progress, k: int) -> str:
    """"case k of n" and the ETA of the bench's progress `bar` (after k cases)."""
    eta = bar.eta_s()
    return f"case {k} of {bar.total}" + (f", eta {duration_text(eta)}" if eta is not None else "")


def _run_cases(out: Path, bench: dict[str, Any], filters: Sequence[FilterSpec], selected: Sequence[str],
               skipped: Mapping[str, str], done: Mapping[tuple[str, str], dict[str, Any]], options: RunOptions,
               bar: Progress) -> None:
    n_run = 0
    for spec, case in planned_cases(filters, selected, skipped):
        if (spec.label, case.name) in done:
            bench["results"].append(done[spec.label, case.name])
            print(f"bench: {spec.label} x {case.name}: kept from {out / BENCH_FILE} (--resume)", flush=True)
            continue
        bar.update(n_run, f"case {n_run + 1} of {bar.total} running: {spec.label} x {case.name}")
        folder = out / "cases" / safe_name(spec.label) / case.name
        if folder.exists() and not (options.resume and case.run is _mismatch_case):
            shutil.rmtree(folder)
        start = time.perf_counter()
        row = {"filter": spec.label, "case": case.name, "force_asked_N": case.asked_N, "force_delivered_N": None,
               "force_delivered_ratio": None, **case.run(case, spec, folder, options),
               "wall_s": time.perf_counter() - start}
        bench["results"].append({k: row[k] for k in RESULT_KEYS})
        write_outputs(out, bench)
        verdict = (f"filter fault ({fault_text(row)}), no verdict" if row["fault"] else
                   f"rho_min_meas {row['rho_min_meas']:.4f}, t_violation {row['t_violation_s']:.3f} s")
        n_run += 1
        bar.update(n_run, f"case {n_run} of {bar.total} done: {spec.label} x {case.name}")
        print(f"bench: {spec.label} x {case.name}: {verdict}, {row['wall_s']:.1f} s ({progress_text(bar, n_run)})",
              flush=True)
    write_outputs(out, bench)


def worst_case_searches(filters: Sequence[FilterSpec], options: RunOptions, whole_battery: bool
                        ) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """bench.json's "falsify" and {filter label: its box study} of the worst-case searches (module docstring), each
    filter with its parameters of the mujoco_contact case (checked here, before the bench starts); None when the
    budget is 0 (the default with --cases)."""
    from softcbf.study import worst_found

    budget = options.falsify_budget
    if budget is None:
        budget = 0 if not whole_battery else worst_found.QUICK_BUDGET if options.quick else worst_found.BUDGET
    if budget == 0:
        return None
    duration = QUICK_DURATION_S if options.quick else None
    case = next(c for c in CASES if c.name == "mujoco_contact")
    studies = {spec.label: worst_found.box_study(spec.name, case_filter_params(spec, case), duration=duration)
               for spec in filters}
    return worst_found.settings(budget, duration), studies


def _run_worst_found(out: Path, bench: dict[str, Any], studies: Mapping[str, Any],
                     done: Mapping[str, dict[str, Any]], options: RunOptions, bar: Progress, k: int) -> None:
    from softcbf.study.store import FALSIFY_FILE
    from softcbf.study.worst_found import worst_found

    budget = bench["falsify"]["budget"]
    for label, study in studies.items():
        if label in done:
            bench["worst_found"].append(done[label])
            print(f"bench: {label} worst case found: kept from {out / BENCH_FILE} (--resume)", flush=True)
            continue
        folder = out / "cases" / safe_name(label) / WORST_DIR
        resume = options.resume and (folder / FALSIFY_FILE).is_file()
        if folder.exists() and not resume:
            shutil.rmtree(folder)
        bar.update(k, f"case {k + 1} of {bar.total} running: {label} worst-case search")
        entry = worst_found(label, study, folder, budget, resume=resume, workers=options.workers,
                            progress=not options.quick)
        k += 1
        bar.update(k, f"case {k} of {bar.total} done: {label} worst-case search")
        bench["worst_found"].append({k: entry[k] for k in WORST_KEYS})
        write_outputs(out, bench)
        found = f"a filter fault ({fault_text(entry)})" if entry["fault"] else f"rho_min_meas {entry['rho_worst_found']}"
        print(f"bench: {label} worst case found: {found} in {entry['evaluations']} "
              f"evaluations, {entry['wall_s']:.1f} s ({progress_text(bar, k)})", flush=True)
    write_outputs(out, bench)


def is_bench_folder(path: str | Path) -> bool:
    """Whether `path` is a folder written by `softcbf bench`: it holds a bench.json."""
    return (Path(path) / BENCH_FILE).is_file()


def prepare_bench_dir(out: Path, options: RunOptions) -> Path:
    """Take the bench folder `out` and lock it for this process (softcbf_mj.runio, as `softcbf run`'s run folders:
    a second bench into it is refused while this one runs). A new or empty folder is made a bench folder; one that
    holds anything must be a bench folder (`is_bench_folder`) and is continued with `options.resume` (nothing
    deleted) or replaced with `options.overwrite` (its contents deleted, never the working folder, one above it
    or home), and is refused otherwise. ValueError naming the folder and the fix; nothing is deleted then."""
    if options.resume and options.overwrite:
        raise ValueError("--resume continues the bench in --out and --overwrite replaces it: give one of them")
    try:
        try:
            holds = out.is_dir() and any(entry.name != RUN_MARKER for entry in out.iterdir())
        except OSError as exc:
            raise OutputDirError(f"cannot read the bench folder {out}: {exc.strerror or exc}") from None
        if not holds:
            return prepare_out_dir(out)
        if not is_bench_folder(out):
            raise ValueError(f"{out} is not empty and is not a bench folder (it has no {BENCH_FILE}); "
                             "choose another --out (--overwrite only replaces a bench folder)")
        if not (options.resume or options.overwrite):
            raise ValueError(f"{out} holds a bench ({BENCH_FILE}); pass --resume to continue it or --overwrite "
                             "to replace it, or choose another --out")
        prepare_out_dir(out, keep=True)  # marks a bench folder written before the marker existed as softcbf's
        if options.overwrite:
            try:
                prepare_out_dir(out, overwrite=True)
            except OutputDirError:
                release_out_dir(out)
                raise
        return out
    except OutputDirError as exc:
        raise ValueError(str(exc)) from None


def _discard(out: Path, created: bool) -> None:
    """Remove what a fresh bench that stopped before its first row wrote (and the folder, when it made it)."""
    shutil.rmtree(out / "cases", ignore_errors=True)
    shutil.rmtree((out / PLOT_FILE).parent, ignore_errors=True)
    for name in (BENCH_FILE, TABLE_FILE):
        (out / name).unlink(missing_ok=True)
    if created:
        remove_if_unused(out)


def stored_results(out: Path, bench: Mapping[str, Any]
                   ) -> tuple[dict[tuple[str, str], dict[str, Any]], dict[str, dict[str, Any]]]:
    """What `--resume` keeps of out/bench.json: its rows {(filter label, case): row} and its worst_found entries
    {filter label: entry} (both {} when there is no file); ValueError when that file is not a bench.json
    (`check_bench_json`) or came from a run with another quick flag, number of mismatch draws or "falsify"."""
    path = out / BENCH_FILE
    if not path.exists():
        return {}, {}
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"--resume: {path} cannot be read as JSON ({exc})") from None
    try:
        check_bench_json(stored)
    except ValueError as exc:
        raise ValueError(f"--resume: {path} is not a bench.json of softcbf bench: {exc}") from None
    quick, draws = stored["quick"], stored["mismatch_draws"]
    if quick != bench["quick"] or draws != bench["mismatch_draws"]:
        raise ValueError(f"--resume: {path} holds a run with quick={quick}, mismatch draws {draws}; "
                         f"this one has quick={bench['quick']}, mismatch draws {bench['mismatch_draws']}")
    if stored["falsify"] != bench["falsify"]:
        raise ValueError(f"--resume: {path} holds worst-case searches with falsify = {json.dumps(stored['falsify'])}; "
                         f"this one has {json.dumps(bench['falsify'])} (--falsify-budget)")
    return ({(r["filter"], r["case"]): {k: r[k] for k in RESULT_KEYS} for r in stored["results"]},
            {e["filter"]: {k: e[k] for k in WORST_KEYS} for e in stored["worst_found"]})


_FRACTION = Bound(0.0, 1.0)
ROW_SCHEMA: dict[str, Callable[[str, Any], None]] = {  # bench.json's row fields (docs/beyond-the-paper.md#filter-benchmark), each checked by key and value
    "filter": lambda key, v: _check_text(key, v),
    "case": lambda key, v: _check_text(key, v, [c.name for c in CASES]),
    "rho_min_meas": lambda key, v: v is None or _check_finite(key, v),
    **{name: (lambda key, v: check_number(key, v, non_negative())) for name in ("force_max_N", "wall_s")},
    **{name: (lambda key, v: v is None or check_number(key, v, non_negative()))  # null: `_check_row_fault`
       for name in ("t_violation_s", *CALL_KEYS)},
    "violation_probability": lambda key, v: v is None or check_number(key, v, _FRACTION),
    "violation_ci95": lambda key, v: v is None or _check_interval(key, v),
    "draws": lambda key, v: v is None or check_number(key, v, Bound(1), integer=True),
    **{name: (lambda key, v: v is None or check_number(key, v, non_negative()))
       for name in ("force_asked_N", "force_delivered_N", "force_delivered_ratio")},
    "force_budget_used": lambda key, v: check_number(key, v, non_negative()),
    "f_max_N": lambda key, v: check_number(key, v, Bound(0.0, low_open=True, unit="N")),
    "faulted": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "fault": lambda key, v: _check_fault(key, v),
}


_COUNT = Bound(1)
WORST_SCHEMA: dict[str, Callable[[str, Any], None]] = {  # bench.json's worst_found entries, checked by key and value
    "filter": lambda key, v: _check_text(key, v),
    "rho_worst_found": lambda key, v: v is None or _check_finite(key, v),
    "params": lambda key, v: v is None or _check_params(key, v),
    "evaluation": lambda key, v: v is None or check_number(key, v, _COUNT, integer=True),
    "evaluations": lambda key, v: check_number(key, v, _COUNT, integer=True),
    "failed": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "first_violation": lambda key, v: v is None or check_number(key, v, _COUNT, integer=True),
    "wall_s": lambda key, v: check_number(key, v, non_negative()),
    "faulted": lambda key, v: check_number(key, v, non_negative(), integer=True),
    "fault": lambda key, v: _check_fault(key, v),
}
FALSIFY_TEXT = ("box", "box_file", "scenario", "objective", "sampler")
FALSIFY_COUNTS = ("budget", "population", "seed", "baseline")


def _check_fault(key: str, value: Any) -> None:
    if value is None:
        return
    if not (isinstance(value, dict) and set(value) == {"type", "message", "where"}
            and all(isinstance(v, str) for v in value.values())):
        raise ValueError(f"{key} must be null or {{\"type\", \"message\", \"where\"}} (texts), got {value!r}")


def _check_row_fault(where: str, row: Mapping[str, Any]) -> None:
    """A result row's fault fields agree (module docstring): fault set exactly when faulted > 0, the verdict
    (`VERDICT_KEYS`) null exactly then, the call figures (`CALL_KEYS`) set when no run faulted."""
    if (row["fault"] is None) != (row["faulted"] == 0):
        raise ValueError(f"{where}: fault must be set exactly when faulted > 0, got faulted {row['faulted']!r}, "
                         f"fault {row['fault']!r}")
    for key in VERDICT_KEYS:
        if row["faulted"] and row[key] is not None:
            raise ValueError(f"{where}.{key} must be null in a row whose filter faulted (no verdict), got {row[key]!r}")
    for key in (*VERDICT_KEYS, *CALL_KEYS) if not row["faulted"] else ():
        if row[key] is None:
            raise ValueError(f"{where}.{key} must be a number (null only in a row whose filter faulted), got None")


def _check_params(key: str, value: Any) -> None:
    if not (isinstance(value, dict) and all(isinstance(k, str) and k for k in value)):
        raise ValueError(f"{key} must be null or {{parameter: value}}, got {value!r}")
    for name, v in value.items():
        if not isinstance(v, str):
            _check_finite(f"{key}.{name}", v)


def _check_falsify(data: Mapping[str, Any]) -> None:
    """bench.json's "falsify" (null, or the searches' settings) and "worst_found" (one entry per filter)."""
    settings, entries = data["falsify"], data["worst_found"]
    if settings is None:
        if entries != []:
            raise ValueError(f"worst_found must be [] when falsify is null (no search ran), got {entries!r}")
        return
    if not isinstance(settings, dict):
        raise ValueError(f"falsify must be null or an object of the searches' settings, got {settings!r}")
    missing = [k for k in (*FALSIFY_TEXT, *FALSIFY_COUNTS, "duration_s") if k not in settings]
    if missing:
        raise ValueError(f"falsify lacks {', '.join(missing)}")
    for key in FALSIFY_TEXT:
        _check_text(f"falsify.{key}", settings[key])
    for key in FALSIFY_COUNTS:
        check_number(f"falsify.{key}", settings[key], _COUNT if key in ("budget", "population") else non_negative(),
                     integer=True)
    check_number("falsify.duration_s", settings["duration_s"], Bound(0.0, low_open=True, unit="s"))
    for where, entry in _checked_items(data, "worst_found", WORST_SCHEMA, ("an entry", "entries"), lambda e: e["filter"]):
        _null_together(where, entry, ("params", "evaluation"))
        if (entry["rho_worst_found"] is None) != (entry["params"] is None or entry["fault"] is not None):
            raise ValueError(f"{where}: rho_worst_found must be null exactly when no evaluation finished or the worst "
                             f"one faulted (fault set), got {entry['rho_worst_found']!r} with params "
                             f"{entry['params']!r}, fault {entry['fault']!r}")
        if entry["fault"] is not None and not entry["faulted"]:
            raise ValueError(f"{where}: a fault needs faulted >= 1, got {entry['faulted']!r}")
        if entry["evaluations"] > settings["budget"] or entry["failed"] > entry["evaluations"]:
            raise ValueError(f"{where}: needs failed <= evaluations <= falsify.budget, got {entry['failed']}, "
                             f"{entry['evaluations']}, {settings['budget']}")
        for key in ("evaluation", "first_violation"):
            if entry[key] is not None and entry[key] > entry["evaluations"]:
                raise ValueError(f"{where}.{key} must be <= evaluations ({entry['evaluations']}), got {entry[key]}")


def _check_finite(key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{key} must be a finite number, got {value!r}")


def _check_text(key: str, value: Any, known: Sequence[str] | None = None) -> None:
    if not isinstance(value, str) or not value or (known is not None and value not in known):
        raise ValueError(f"{key} must be {'one of ' + ', '.join(known) if known else 'a non-empty string'}, got {value!r}")


def _check_interval(key: str, value: Any) -> None:
    if not (isinstance(value, list) and len(value) == 2):
        raise ValueError(f"{key} must be null or [lo, hi], got {value!r}")
    lo, hi = (check_number(f"{key}[{i}]", v, _FRACTION) for i, v in enumerate(value))
    if lo > hi:
        raise ValueError(f"{key} must have lo <= hi, got {value!r}")


def check_bench_json(data: Any) -> None:
    """ValueError naming the first field of `data` (a parsed bench.json) that does not hold the module docstring's
    schema: "battery" and "filters" lists of names, "quick" true/false, "mismatch_draws" an integer >= 1, "skipped"
    {case: reason}, "results" rows with every `RESULT_KEYS` field of its type (numbers finite, counts, durations,
    RMS and compute times >= 0, probabilities in [0, 1]; the three violation fields null together), a known case,
    a filter of "filters", each (filter, case) once; "falsify" null or the searches' settings and "worst_found"
    entries with every `WORST_KEYS` field (`WORST_SCHEMA`), a filter of "filters" each once (none when falsify
    is null), failed <= evaluations <= budget."""
    if not isinstance(data, dict):
        raise ValueError(f"it must be a JSON object, got {type(data).__name__}")
    missing = [k for k in ("battery", "quick", "mismatch_draws", "filters", "skipped", "results", "falsify", "worst_found")
               if k not in data]
    if missing:
        raise ValueError(f"it lacks {', '.join(missing)}")
    for key in ("battery", "filters"):
        if not isinstance(data[key], list):
            raise ValueError(f"{key} must be a list of names, got {data[key]!r}")
        for i, name in enumerate(data[key]):
            _check_text(f"{key}[{i}]", name)
    if not isinstance(data["quick"], bool):
        raise ValueError(f"quick must be true or false, got {data['quick']!r}")
    check_number("mismatch_draws", data["mismatch_draws"], Bound(1), integer=True)
    if not (isinstance(data["skipped"], dict) and all(isinstance(v, str) for v in data["skipped"].values())):
        raise ValueError(f"skipped must be an object {{case or 'FILTER x CASE': reason}}, got {data['skipped']!r}")
    for where, row in _checked_items(data, "results", ROW_SCHEMA, ("a row", "rows"), lambda r: f"({r['filter']}, {r['case']})"):
        _null_together(where, row, ("violation_probability", "violation_ci95", "draws"))
        _check_row_fault(where, row)
    _check_falsify(data)


def _checked_items(data: Mapping[str, Any], name: str, schema: Mapping[str, Callable[[str, Any], None]],
                   noun: tuple[str, str], identity: Callable[[dict[str, Any]], str]):
    """Yield ("NAME[i]", item) for every item of the list data[name] once it is an object holding every key of
    `schema`, each value passing its check, a filter of data["filters"], and `identity(item)` first seen;
    ValueError naming the item and the field otherwise (`noun`: an item, items)."""
    if not isinstance(data[name], list):
        raise ValueError(f"{name} must be a list of {noun[1]}, got {data[name]!r}")
    seen = set()
    for i, item in enumerate(data[name]):
        where = f"{name}[{i}]"
        if not isinstance(item, dict):
            raise ValueError(f"{where} must be an object, got {item!r}")
        missing = [k for k in schema if k not in item]
        if missing:
            raise ValueError(f"{where} lacks {', '.join(missing)}")
        for key, check in schema.items():
            check(f"{where}.{key}", item[key])
        if item["filter"] not in data["filters"]:
            raise ValueError(f"{where}.filter {item['filter']!r} is not one of its filters ({', '.join(data['filters'])})")
        if identity(item) in seen:
            raise ValueError(f"{where}: {identity(item)} has {noun[0]} already")
        seen.add(identity(item))
        yield where, item


def _null_together(where: str, item: Mapping[str, Any], keys: Sequence[str]) -> None:
    nulls = [item[k] is None for k in keys]
    if any(nulls) and not all(nulls):
        raise ValueError(f"{where}: {', '.join(keys[:-1])} and {keys[-1]} must be null together, got "
                         f"{', '.join(repr(item[k]) for k in keys)}")


TABLE = (("filter", "filter", ""), ("case", "case", ""), ("filter fault", "fault", ""), ("ρ_meas min", "rho_min_meas", ".4f"),
         ("t_viol [s]", "t_violation_s", ".3f"), ("F max [N]", "force_max_N", ".4f"),
         ("P(viol) [95 % CI] (n)", None, ""), ("u_dev RMS [hPa]", "u_dev_rms_hPa", ".1f"), ("blocked [s]", "blocked_s", ".2f"),
         ("switches [1/s]", "switches_per_s", ".2f"), ("filter med [µs]", "filter_us_median", ".0f"),
         ("filter p99 [µs]", "filter_us_p99", ".0f"), ("wall [s]", "wall_s", ".0f"), ("F asked [N]", "force_asked_N", ".4f"),
         ("F delivered [N]", "force_delivered_N", ".4f"), ("delivered / min(asked, F_max)", "force_delivered_ratio", ".3f"),
         ("F max / F_max", "force_budget_used", ".3f"))


def fault_text(item: Mapping[str, Any]) -> str:
    """A bench row's or worst_found entry's fault in words: "TYPE in the WHERE (n runs)", "" without one."""
    fault, n = item["fault"], item["faulted"]
    if fault is None:
        return ""
    return f"{fault['type']} in the {fault['where']} ({n} run{'s' if n != 1 else ''})"


def _cell(row: Mapping[str, Any], key: str | None, spec: str) -> str:
    if key == "fault":
        return fault_text(row) or "–"
    if key is None:
        p = row["violation_probability"]
        if p is None:
            return "–"
        lo, hi = row["violation_ci95"]
        return f"{p:.3f} [{lo:.3f}, {hi:.3f}] ({row['draws']})"
    value = row[key]
    if value is None:
        return "–"
    return format(value, spec) if isinstance(value, float) and math.isfinite(value) else str(value)


def table_markdown(bench: Mapping[str, Any]) -> str:
    """bench.md: the results as one Markdown table, the quick flag and the skipped cases."""
    lines = [f"# Filter benchmark{' (quick: shortened for CI, not the battery)' if bench['quick'] else ''}", "",
             f"Battery: {', '.join(bench['battery'])}. Filters: {', '.join(bench['filters'])}.", "",
             "A fault is never a pass: a row whose filter faulted in some run names the fault and has no ρ_meas min "
             "or t_viol (its runs stopped at the fault); P(viol) counts each faulted run as a violation.", "",
             "| " + " | ".join(h for h, _, _ in TABLE) + " |", "|" + "---|" * len(TABLE)]
    lines += ["| " + " | ".join(_cell(r, k, s) for _, k, s in TABLE) + " |" for r in bench["results"]]
    lines += [f"\nSkipped: {name}: {reason}" for name, reason in bench["skipped"].items()]
    if any(r["force_delivered_N"] is not None for r in bench["results"]):
        lines += ["", "Contact tasks: force delivered against force asked, every filter:", "",
                  f"![delivered against asked]({FORCE_PLOT_FILE})"]
    return "\n".join(lines + worst_found_markdown(bench)) + "\n"


def worst_found_markdown(bench: Mapping[str, Any]) -> list[str]:
    """bench.md's lines on the worst-case searches: the box and budget, then one row per filter (none: no search)."""
    f = bench["falsify"]
    if f is None:
        return []
    lines = ["", "## Worst case found", "",
             f"Per filter: {f['budget']} evaluations of a falsification ({f['sampler']}, the box's vertices first, seed "
             f"{f['seed']}) over the box {f['box']} ({f['box_file']}: {f['scenario']}, {f['duration_s']:g} s each); "
             "ρ_meas worst found = the least ρ_min_meas of those evaluations, or a filter fault, the worst there "
             "is (< 0 or a fault: a violation found; ≥ 0 proves "
             "nothing). Each search's folder: cases/<filter>/worst_found/ (its worst/ replays with `softcbf run "
             "--config`).", "",
             "| filter | ρ_meas worst found | at evaluation | first violation | evaluations (failed) | its parameters |",
             "|---|---|---|---|---|---|"]
    for e in bench["worst_found"]:
        rho = (f"filter fault: {fault_text(e)}" if e["fault"] else
               "–" if e["rho_worst_found"] is None else f"{e['rho_worst_found']:.4f}")
        params = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                           for k, v in (e["params"] or {}).items()) or "–"
        lines.append(f"| {e['filter']} | {rho} | {e['evaluation'] or '–'} | {e['first_violation'] or '–'} | "
                     f"{e['evaluations']} ({e['failed']}) | {params} |")
    return lines


def write_force_plot(path: Path, bench: Mapping[str, Any]) -> None:
    """The contact tasks' delivered force against the asked force (both / F_max), one panel per plant of `PUSHES`,
    one line per filter through its pushes, a cross for its force-target case; the dashed line is min(asked, F_max),
    the dotted ones the goals (docs/beyond-the-paper.md#contact-tasks); a delivered force
    above FORCE_PLOT_TOP × F_max is drawn at the top with its value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(PUSHES), figsize=(5 * len(PUSHES), 4), sharey=True, squeeze=False)
    for ax, plant in zip(axes[0], PUSHES):
        prefix = PUSH_PREFIX[plant] + "_"
        for name in bench["filters"]:
            rows = sorted((r for r in bench["results"] if r["filter"] == name and r["case"].startswith(prefix)
                           and r["force_delivered_N"] is not None), key=lambda r: r["force_asked_N"])
            if rows:
                pushes = [r for r in rows if "_push_" in r["case"]]
                line, = ax.plot([r["force_asked_N"] / r["f_max_N"] for r in pushes],
                                [min(r["force_delivered_N"] / r["f_max_N"], FORCE_PLOT_TOP) for r in pushes], "o-", label=name)
                for r in rows:
                    if "_push_" not in r["case"]:  # the force-target nominal: a cross of the same colour
                        ax.plot(r["force_asked_N"] / r["f_max_N"], min(r["force_delivered_N"] / r["f_max_N"], FORCE_PLOT_TOP),
                                "x", color=line.get_color(), ms=8)
                x = [r["force_asked_N"] / r["f_max_N"] for r in rows]
                y = [r["force_delivered_N"] / r["f_max_N"] for r in rows]
                for xi, yi in zip(x, y):
                    if yi > FORCE_PLOT_TOP:  # beyond the axis: drawn at its top with the value
                        ax.annotate(f"{yi:.2f}", (xi, FORCE_PLOT_TOP), textcoords="offset points", xytext=(3, -10),
                                    fontsize=7, color=line.get_color())
        top = max([4.0] + [r["force_asked_N"] / r["f_max_N"] for r in bench["results"]
                           if r["case"].startswith(prefix) and r["force_asked_N"] is not None])
        ax.plot([0.0, 1.0, top], [0.0, 1.0, 1.0], "k--", lw=0.8, label="min(asked, F_max)")
        ax.plot([0.0, 0.8, 0.8, top], [0.0, 0.76, 0.8, 0.8], "k:", lw=0.8, label="goal")
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_ylim(0.0, FORCE_PLOT_TOP * 1.02)
        ax.set_title(plant)
        ax.set_xlabel("asked / F_max")
    axes[0][0].set_ylabel("delivered / F_max (mean over the last third)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


PLOTTED = (("rho_min_meas", "ρ_meas min [1]"), ("force_max_N", "F max [N]"), ("u_dev_rms_hPa", "|u − u_nom| RMS [hPa]"),
           ("filter_us_p99", "filter p99 [µs]"))


def write_plot(path: Path, bench: Mapping[str, Any]) -> None:
    """One bar panel per figure of `PLOTTED` (each label with its unit; ρ is dimensionless, [1]): cases along x, one
    bar per filter; the legend outside the panels, right of the top one, so no bar hides behind it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = [c for c in bench["battery"] if any(r["case"] == c for r in bench["results"])]
    filters = bench["filters"]
    fig, axes = plt.subplots(len(PLOTTED), 1, figsize=(11, 2.4 * len(PLOTTED)), sharex=True, layout="constrained")
    width = 0.8 / max(1, len(filters))
    for ax, (key, title) in zip(axes, PLOTTED):
        for j, name in enumerate(filters):
            values = {r["case"]: r[key] for r in bench["results"] if r["filter"] == name and r[key] is not None}
            x = [i + j * width for i, c in enumerate(cases) if c in values]
            ax.bar(x, [values[c] for c in cases if c in values], width, label=name)
        if key == "rho_min_meas":
            ax.axhline(0.0, color="k", lw=0.8)
        if key == "filter_us_p99":
            ax.set_yscale("log")
        ax.set_ylabel(title)
    axes[0].legend(fontsize=8, title="filter", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    axes[-1].set_xticks([i + 0.4 - width / 2 for i in range(len(cases))], cases, rotation=20, fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_outputs(out: Path, bench: Mapping[str, Any]) -> None:
    """DIR/bench.json, DIR/bench.md and DIR/plots/bench.png from `bench`."""
    out.mkdir(parents=True, exist_ok=True)
    (out / BENCH_FILE).write_text(json.dumps(bench, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    (out / TABLE_FILE).write_text(table_markdown(bench), encoding="utf-8")
    if bench["results"]:
        write_plot(out / PLOT_FILE, bench)
    if any(r["force_delivered_N"] is not None for r in bench["results"]):
        write_force_plot(out / FORCE_PLOT_FILE, bench)


HELP = "run safety filters over the fixed benchmark battery: softcbf bench --out DIR [--filters SPEC,...] [--quick]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output folder (bench.json, bench.md, plots/, cases/)")
    parser.add_argument("--filters", default=DEFAULT_FILTERS, help=f"NAME or NAME(param=value,...), comma separated (default {DEFAULT_FILTERS})")
    parser.add_argument("--quick", action="store_true", help="short durations and 2 mismatch draws, emulator skipped (CI)")
    parser.add_argument("--cases", default=None, help=f"run only these cases (comma separated; default all: {', '.join(c.name for c in CASES)})")
    parser.add_argument("--mismatch-draws", type=int, default=None, help=f"draws of the mismatch study (default {MISMATCH_DRAWS})")
    parser.add_argument("--workers", type=int, default=1,
                        help="local processes of the mismatch study and the worst-case searches (default 1)")
    parser.add_argument("--falsify-budget", type=int, default=None, metavar="N",
                        help="evaluations of each filter's worst-case search over studies/mismatch_box_contact.toml "
                             "(bench.json's worst_found; default 36 for the whole battery, 4 with --quick, 0 with "
                             "--cases; 0: none)")
    parser.add_argument("--resume", action="store_true",
                        help="continue a bench in --out: keep its finished (filter, case) rows, continue its mismatch studies")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the contents of a bench folder in --out (one holding a bench.json)")


def run_command(args: argparse.Namespace, extra: list[str] | None = None) -> int:
    """Handler of `softcbf bench`: 0 done, 2 usage error (one line on stderr), 130 on Ctrl-C (after a line that
    says what is stored and how to continue: `--resume`)."""
    import sys

    from scenarios.run import INTERRUPTED

    try:
        filters = parse_filters(args.filters)
        cases = None if args.cases is None else [c.strip() for c in args.cases.split(",")]
        run_bench(args.out, filters, RunOptions(args.quick, args.workers, args.mismatch_draws, args.resume, args.overwrite,
                                                args.falsify_budget), cases)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        stored = (f"finished cases are stored in {args.out}; continue with --resume"
                  if is_bench_folder(args.out) else "nothing was stored")
        print(f"\ninterrupted: {stored}", file=sys.stderr)
        return INTERRUPTED
    print(f"bench: {args.out / BENCH_FILE}, {args.out / TABLE_FILE}, {args.out / PLOT_FILE}")
    return 0
