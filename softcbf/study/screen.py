"""Multi-fidelity falsification: search the box on a cheap scenario, confirm the worst candidates on the study's own.

Why: every evaluation of a falsification runs the study's scenario (mujoco_contact: about 4× real time on one
quiet core), while the PCC plant runs the same task several times faster. Where the cheap plant's worst cases are
the expensive one's (an error's effect has the same sign on both: a stiffer, nearer plate, a stronger actuator
push harder on either plant), a search on the cheap plant ranks the box and the expensive plant only has to
confirm the candidates it ranked worst.

Mapping (`screened_study`): the screened study is the study with its scenario replaced by the cheap one and
everything else kept: the same box, fixed values, tunings, objective and seed. A setting keeps its name and
meaning across scenarios (vocabulary.settings), so a coordinate maps onto the cheap scenario exactly when that
scenario takes a parameter of the same name. Every varied coordinate, every fixed value and the tuning parameter
must map; the first that does not is refused in one line naming it (e.g. `paper_sim` has no
`assumed_plate_stiffness`: its plate is the controller's, so it cannot represent a plate the controller
misjudges; `pcc_contact`, mujoco_contact's errors on the PCC plant, represents the standard box's physical
errors). Assumption: the cheap scenario means by a name what the expensive one means (true of the scenarios
here: scenarios.pcc_contact builds the true arm and plates with mujoco_contact's functions).

Search (`falsify_screened`): (1) the screen, an ordinary falsification (`softcbf.study.falsify.falsify`, no
baseline) of the screened study with `budget` evaluations into DIR/screen, stopped after the generation of its
first violation with `stop_on_violation` (or with `stop_screen_on_violation` where given: a tuning's inner search
screens its whole budget and stops only its confirmations, `softcbf.study.tune`); (2) the confirmation: the
screen's evaluations with a value, in order of the searched value (the metric, or its negative for "-NAME";
worst first, ties by evaluation), distinct candidates (parameters and tuning) only, the first `confirm` of them,
each run on the study's own scenario as evaluation e of a `CandidateStudy` into DIR/search (its scenario seed
the study's draw e, as falsify's), in chunks of one per worker with `stop_on_violation` (stopping after the
chunk that violated), else all at once; (3) the best confirmed evaluation replayed alone into DIR/worst (one
more expensive run, as falsify's).

A candidate the screen ranked safe may still violate on the expensive plant (the cheap plant leaves out what
scenarios.pcc_contact lists), and the confirmation runs only `confirm` of them: a multi-fidelity search that
confirms no violation is no more a proof of safety than a single-fidelity one.

Resume: the screen resumes as a falsification (DIR/screen); its ranking is a function of its stored rows, so
the confirmation's candidates are the same and `run_study` runs only those not yet stored. A resume must give
the same study, screen scenario, sampler, seed, population and initial design (DIR/falsify.json records them;
`budget` and `confirm` may grow).

DIR/falsify.json holds falsify's keys for the expensive evaluations (objective, best, evaluations, failed,
faulted, first_violation: counts of confirmed evaluations; worst; random_baseline empty: no baseline) and

    "screen": {"scenario", "budget", "confirm", "evaluations", "failed", "faulted", "first_violation",
               "best": {...}}                  the cheap search, as its own falsify.json says
    "confirmed": [{"evaluation", "screen_evaluation", "screen_value", "value", "violated", "fault"}, ...]
                                               every expensive evaluation: which screened evaluation it
                                               confirmed, its value there and here
    "expensive_evaluations"                    the study scenario's runs spent: confirmed + the worst's replay
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

from scenarios import get as get_scenario
from softcbf.study.analysis import violated
from softcbf.study.definition import Study
from softcbf.study.execute import connect_scheduler, run_study
from softcbf.study.falsify import (
    SEARCH_DIR, WORST_DIR, Candidate, CandidateStudy, default_population, falsify, objective_value,
    replay_worst, searched_value, stored_rows, summary,
)
from softcbf.study.store import FALSIFY_FILE, PARAM_PREFIX, fault_of, storage_name, stored_search
from softcbf_mj.outputs.progress import Progress
from softcbf_mj.outputs.runio import write_json

SCREEN_DIR = "screen"
SETTINGS = ("objective", "sampler", "seed", "population", "initial", "study", "screen_scenario")


def screened_study(study: Study, scenario: str) -> Study:
    """`study` on the cheap `scenario` (module docstring: Mapping); ValueError naming the first setting the
    cheap scenario cannot represent."""
    if scenario == study.scenario:
        raise ValueError(f"--screen {scenario}: the study already runs on {scenario}; screen on a cheaper scenario")
    takes = set(get_scenario(scenario).parameters())
    wanted = ([("varied coordinate", d.parameter) for d in study.vary] + [("fixed setting", k) for k in study.fixed]
              + [("tuning parameter", study.tuning_parameter)])
    for kind, name in wanted:
        if name not in takes:
            raise ValueError(f"--screen {scenario} cannot represent the study's {kind} {name!r}: scenario "
                             f"{scenario} has no such parameter")
    return dataclasses.replace(study, scenario=scenario, name=f"{study.name}_screen_{scenario}")


def ranked_candidates(rows: list[dict[str, Any]], objective: str, study: Study) -> list[tuple[int, float, Candidate]]:
    """The screen's evaluations with a value as (evaluation, searched value, candidate), worst first (module
    docstring: Search), distinct candidates only."""
    scored = [(searched_value(r, objective), int(r["sample"]) + 1, r) for r in rows]
    ranked, seen = [], set()
    for value, evaluation, row in sorted((s for s in scored if s[0] is not None), key=lambda s: (s[0], s[1])):
        values = {d.parameter: row[PARAM_PREFIX + d.parameter] for d in study.vary}
        key = (tuple(sorted(values.items())), row["tuning"])
        if key not in seen:
            seen.add(key)
            ranked.append((evaluation, value, Candidate(values, row["tuning"])))
    return ranked


def falsify_screened(
    study: Study,
    out_dir: str | Path,
    *,
    screen: str,
    budget: int,
    confirm: int | None = None,
    sampler: str = "cmaes",
    population: int | None = None,
    initial: str = "vertices",
    seed: int | None = None,
    stop_on_violation: bool = False,
    stop_screen_on_violation: bool | None = None,
    storage: str | None = None,
    resume: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    batch_size: int | None = None,
    progress: bool | Progress = True,
) -> dict[str, Any]:
    """Search `study`'s box on scenario `screen` with `budget` evaluations and confirm the `confirm` worst
    (default one generation: the population) on the study's scenario (module docstring); returns falsify.json's
    content. `stop_screen_on_violation`: whether the screen stops after its first violation (None: as
    `stop_on_violation`, which stops the confirmations). The other arguments are `falsify`'s."""
    confirm = default_population(study) if confirm is None else confirm
    if isinstance(confirm, bool) or not isinstance(confirm, int) or confirm < 1:
        raise ValueError(f"confirm must be an integer >= 1 (evaluations on {study.scenario}), got {confirm!r}")
    study = study if seed is None or seed == study.seed else dataclasses.replace(study, seed=seed)
    cheap = screened_study(study, screen)
    population = default_population(study) if population is None else population
    root = Path(out_dir)
    settings = {"objective": study.objective, "sampler": sampler, "seed": study.seed, "population": population,
                "initial": initial, "study": study.to_dict(), "screen_scenario": screen}
    stored_search(root, FALSIFY_FILE, "falsification", settings, SETTINGS, resume)
    state: dict[str, Any] = {**settings, "budget": budget, "confirm": confirm, "status": "running",
                             "storage": storage_name(storage)}
    root.mkdir(parents=True, exist_ok=True)
    write_json(root / FALSIFY_FILE, state)
    stop_screen = stop_on_violation if stop_screen_on_violation is None else stop_screen_on_violation
    screened = falsify(cheap, root / SCREEN_DIR, budget=budget, sampler=sampler, population=population,
                       initial=initial, baseline=0, stop_on_violation=stop_screen, storage=storage,
                       resume=resume and (root / SCREEN_DIR / FALSIFY_FILE).is_file(), workers=workers,
                       scheduler=scheduler, client=client, batch_size=batch_size, progress=progress)
    screen_rows = stored_rows(root / SCREEN_DIR / SEARCH_DIR, range(screened["evaluations"]))
    ranked = ranked_candidates([screen_rows[i] for i in sorted(screen_rows)], study.objective, study)[:confirm]
    own_client = None
    if scheduler is not None:
        client = own_client = connect_scheduler(scheduler)
    n_workers = sum(client.nthreads().values()) if client is not None else (workers or os.cpu_count() or 1)
    chunk = max(1, n_workers) if stop_on_violation else max(1, len(ranked))
    run = {"workers": workers, "client": client, "batch_size": batch_size or max(1, math.ceil(chunk / n_workers)),
           "progress": False}
    candidates = [c for _, _, c in ranked]
    rows: dict[int, dict[str, Any]] = {}
    shown = progress.enabled if isinstance(progress, Progress) else bool(progress)
    bar = Progress(f"confirm on {study.scenario}", max(1, len(candidates)), enabled=shown,
                   unit="evaluations")
    try:
        done = 0
        while done < len(candidates):
            done = min(len(candidates), done + chunk)
            run_study(CandidateStudy.of(study, candidates[:done]), root / SEARCH_DIR, resume=True, samples=done, **run)
            rows = stored_rows(root / SEARCH_DIR, range(done))
            bar.update(done, f"{sum(1 for r in rows.values() if violated(r))} violated")
            if stop_on_violation and any(violated(r) for r in rows.values()):
                break
        bar.close(len(rows))
        result = summary([rows[i] for i in sorted(rows)], study.objective)
        worst = None
        if result["evaluation"] is not None:
            worst = replay_worst(CandidateStudy.of(study, candidates), result["evaluation"] - 1, root / WORST_DIR,
                                 study.objective)
    finally:
        if own_client is not None:
            own_client.close()
    confirmed = [{"evaluation": e + 1, "screen_evaluation": ranked[e][0],
                  "screen_value": objective_value(screen_rows[ranked[e][0] - 1], study.objective),
                  "value": objective_value(rows[e], study.objective), "violated": bool(violated(rows[e])),
                  "fault": fault_of(rows[e])} for e in sorted(rows)]
    state.update(status="done", stopped="violation" if stop_on_violation and result["first_violation"] else "budget",
                 evaluations=result["evaluations"], failed=result["failed"], faulted=result["faulted"],
                 first_violation=result["first_violation"],
                 best={"value": result["best"], "params": result["params"], "tuning": result["tuning"],
                       "evaluation": result["evaluation"], "fault": result["fault"]},
                 random_baseline=summary([], study.objective), worst=worst,
                 screen={"scenario": screen, "dir": SCREEN_DIR, "budget": budget, "confirm": confirm,
                         **{k: screened[k] for k in ("evaluations", "failed", "faulted", "first_violation", "best")}},
                 confirmed=confirmed, expensive_evaluations=len(rows) + (worst is not None))
    write_json(root / FALSIFY_FILE, state)
    return state
