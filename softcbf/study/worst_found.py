"""The worst case found over the standard mismatch box at a fixed budget: `softcbf bench`'s rho_worst_found.

What it answers: within N evaluations of a search for the worst case, how close to F_max (or how far past
it) does a filter come when the plant differs from its model by the errors a lab should expect?

The box (`BOX_FILE` = studies/mismatch_box_contact.toml, the standard mismatch box's physical errors):
mujoco_contact (exact state, 1 kHz), the paper's sinusoid for 30 s from t0 = 15 s, plate stiffness
11.16 N/m ± 20 %, plate offset ± 2 mm along its normal, actuator gain, arm stiffness and arm damping
× [0.9, 1.1], [0.9, 1.1], [0.7, 1.3] of the model's (the controller keeps its model), valve lag
τ_p ∈ [0.02, 0.1] s: d = 6 coordinates. `box_study` swaps the file's controller for the filter under
test: tuning_parameter "filter", tunings (the filter's name,), and its parameters (as the bench's
mujoco_contact case gives them) in fixed.filter_params; everything else is the file's, so the box has
one definition.

The search is the study engine's falsification (`softcbf.study.falsify.falsify`, no second optimiser):
CMA-ES (optuna) with the box's vertices first, population 4 + ⌊3 ln 6⌋ = 9, seed the box's (2027), no
uniform baseline; its folder is an ordinary falsification folder (`softcbf study report` reads it, its
worst/ replays with `softcbf run --config`). Budget N evaluations (`BUDGET` = 36: four generations; the
bench's --quick: `QUICK_BUDGET` = 4, each 1 s long).

The figure: rho_worst_found = min_{e ≤ N} ρ_min_meas(x_e) [-] over the evaluations e that finished
(ρ_min_meas: the run's minimum of the measured force margin, < 0 when the measured force exceeded F_max),
with x_e's parameters (`params`), e (`evaluation`, 1-based), the evaluations run and failed and the first
evaluation that violated (null: none). It bounds the box's true worst case from above
(min_{x ∈ box} ρ ≤ rho_worst_found): a negative value is a counterexample that replays, a positive one
is no proof of safety (the search may miss a worse x; for a bound on P(violation) use `softcbf study run
--until-bound`). It is null when no evaluation finished, and when the worst evaluation is a filter fault
(the worst there is: `fault` {type, message, where} then names it, `faulted` counts the evaluations
that faulted; a fault is never a pass).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softcbf.study.definition import DEFAULT_OBJECTIVE, FILTER_PARAMS, Study, load_study
from softcbf.study.falsify import default_population, falsify
from vocabulary.project_files import project_file, shown
from vocabulary.sections import joined

BOX_FILE = project_file("studies/mismatch_box_contact.toml")
BUDGET = 36  # evaluations per filter: four CMA-ES generations of the box's 9
QUICK_BUDGET = 4
SAMPLER = "cmaes"


def box_study(filter_name: str, filter_params: Mapping[str, str], *, duration: float | None = None,
              box_file: str | Path = BOX_FILE) -> Study:
    """The box of `box_file` run with the filter `filter_name` and its `filter_params` (module docstring);
    `duration` (s) replaces the file's fixed duration (the bench's --quick). ValueError when the file's
    objective is not ρ_min_meas (rho_worst_found is its minimum) or it fixes a filter of its own."""
    box = load_study(box_file)
    if box.objective != DEFAULT_OBJECTIVE:
        raise ValueError(f"{box_file}: rho_worst_found minimises {DEFAULT_OBJECTIVE}; the box's objective is "
                         f"{box.objective!r}")
    clash = {"filter", FILTER_PARAMS} & set(box.fixed)
    if clash:
        raise ValueError(f"{box_file}: a box for every filter fixes no controller, it fixes {', '.join(sorted(clash))}")
    fixed = {**box.fixed, FILTER_PARAMS: joined(FILTER_PARAMS, filter_params)}
    if duration is not None:
        fixed["duration"] = duration
    return dataclasses.replace(box, tunings=(filter_name,), tuning_parameter="filter", fixed=fixed)


def settings(budget: int, duration: float | None = None, box_file: str | Path = BOX_FILE) -> dict[str, Any]:
    """bench.json's "falsify": what every filter's search shares (a --resume must repeat it)."""
    box = load_study(box_file)
    return {"budget": budget, "box": box.name, "box_file": shown(box_file), "scenario": box.scenario,
            "duration_s": float(box.fixed["duration"] if duration is None else duration),
            "objective": DEFAULT_OBJECTIVE, "sampler": SAMPLER, "seed": box.seed, "population": default_population(box),
            "baseline": 0}


def worst_found(label: str, study: Study, folder: str | Path, budget: int, *, resume: bool = False,
                workers: int | None = None, progress: bool = False) -> dict[str, Any]:
    """Search `study`'s box for `budget` evaluations into `folder` (a new or empty folder, or with `resume` a
    falsification folder of the same search, continued up to `budget`); bench.json's "worst_found" entry of the filter `label` (module docstring): filter,
    rho_worst_found, params, evaluation, evaluations, failed, first_violation, wall_s (s, this call's), faulted,
    fault. `progress`: falsify's progress line (per evaluation, on stderr)."""
    folder = Path(folder)
    start = time.perf_counter()
    result = falsify(study, folder, budget=budget, sampler=SAMPLER, baseline=0, workers=workers, progress=progress,
                     resume=resume)
    best = result["best"]
    return {"filter": label, "rho_worst_found": best["value"], "params": best["params"], "evaluation": best["evaluation"],
            "evaluations": result["evaluations"], "failed": result["failed"],
            "first_violation": result["first_violation"], "wall_s": time.perf_counter() - start,
            "faulted": result["faulted"], "fault": best["fault"]}
