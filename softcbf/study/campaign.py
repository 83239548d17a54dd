"""Falsification over seeds, reported as the falsification community reads it (ARCH-COMP's falsification track).

Why: one falsification is one draw of a randomised search (its sampler's and, through the scenario seeds, its
evaluations' randomness). ARCH-COMP reports a falsifier per requirement (here: per filter and box) by repeating
it over seeds: the falsification rate (the fraction of runs that found a counterexample within the budget) and
the evaluations to the first counterexample over the runs that found one (its median and range). A low rate
with a small budget says the box is hard to falsify for this search, not that the filter is safe.

Campaign (`falsify_seeds`): for every tuning t of the study (the filters it compares) and every seed
s = s0, s0 + 1, …, s0 + n − 1 (s0: `seed`, default the study's), one falsification of the study restricted to
t with seed s (its sampler, its vertex order and its evaluations' scenario seeds; `softcbf.study.falsify`,
no uniform baseline), or a multi-fidelity one with `screen` (`softcbf.study.screen`: its counts are the
expensive evaluations), into DIR/filter_<i>/seed_<s> (i: t's index in the study's tunings). A counterexample
is a violation (ρ_min_meas < 0 or a filter fault: `analysis.violated`), whatever the objective.

Per filter (tuning) and box (the study's name), DIR/campaign.json's "table" holds: runs, falsified (runs with
a counterexample), rate = falsified / runs, first_counterexample {median, min, max} over the falsified runs
(evaluations, counted from 1; null when none falsified), evaluations (the evaluations the runs spent, summed),
and per run (seed, first_violation, evaluations, best value); report.py writes it as a Markdown table in
DIR/report.md. The median of an even count is the mean of the middle two (numpy.median).

Resume: every run is a falsification folder; with `resume` a run whose falsify.json says "done" is read, one
that stopped is resumed, one not started is started. A resume must give the same study, seeds, budget,
sampler, population, initial design, stop rule and screen (DIR/campaign.json records them).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from softcbf.study.definition import Study
from softcbf.study.falsify import falsify
from softcbf.study.screen import falsify_screened
from softcbf.study.store import FALSIFY_FILE, stored_search
from softcbf_mj.outputs.runio import write_json

CAMPAIGN_FILE = "campaign.json"
SETTINGS = ("study", "seeds", "budget", "sampler", "population", "initial", "stop_on_violation", "screen", "confirm")


def run_folder(root: Path, tuning_index: int, seed: int) -> Path:
    """The falsification folder of tuning `tuning_index` and `seed` in campaign folder `root`."""
    return root / f"filter_{tuning_index}" / f"seed_{seed}"


def campaign_row(tuning: str, box: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The table row of one filter and box from its runs' falsify.json contents (module docstring)."""
    firsts = [r["first_violation"] for r in runs if r["first_violation"] is not None]
    return {"filter": tuning, "box": box, "runs": len(runs), "falsified": len(firsts),
            "rate": len(firsts) / len(runs) if runs else None,
            "first_counterexample": ({"median": float(np.median(firsts)), "min": min(firsts), "max": max(firsts)}
                                     if firsts else None),
            "evaluations": sum(r["evaluations"] for r in runs),
            "per_seed": [{"seed": r["seed"], "first_violation": r["first_violation"], "evaluations": r["evaluations"],
                          "best": r["best"]["value"], "fault": r["best"]["fault"]} for r in runs]}


def falsify_seeds(study: Study, out_dir: str | Path, *, seeds: int, budget: int, seed: int | None = None,
                  screen: str | None = None, confirm: int | None = None, sampler: str = "cmaes",
                  population: int | None = None, initial: str = "vertices", stop_on_violation: bool = False,
                  resume: bool = False, workers: int | None = None, scheduler: str | None = None,
                  batch_size: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Falsify `study` per tuning over `seeds` seeds (module docstring); returns campaign.json's content."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds must be an integer >= 1 (falsifications per filter), got {seeds!r}")
    if confirm is not None and screen is None:
        raise ValueError("confirm counts the expensive evaluations of a screened search; give --screen with it")
    first = study.seed if seed is None else seed
    root = Path(out_dir)
    settings = {"study": study.to_dict(), "seeds": list(range(first, first + seeds)), "budget": budget,
                "sampler": sampler, "population": population, "initial": initial,
                "stop_on_violation": stop_on_violation, "screen": screen, "confirm": confirm}
    stored_search(root, CAMPAIGN_FILE, "falsification campaign", settings, SETTINGS, resume)
    root.mkdir(parents=True, exist_ok=True)
    state: dict[str, Any] = {**settings, "status": "running"}
    write_json(root / CAMPAIGN_FILE, state)
    options = {"budget": budget, "sampler": sampler, "population": population, "initial": initial,
               "stop_on_violation": stop_on_violation, "workers": workers, "scheduler": scheduler,
               "batch_size": batch_size, "progress": progress}
    table = []
    for i, tuning in enumerate(study.tunings):
        single = dataclasses.replace(study, tunings=(tuning,))
        runs = []
        for s in settings["seeds"]:
            folder = run_folder(root, i, s)
            state_file = folder / FALSIFY_FILE
            stored = json.loads(state_file.read_text(encoding="utf-8")) if state_file.is_file() else None
            if stored is not None and stored.get("status") == "done" and stored.get("budget") == budget:
                runs.append(stored)
                continue
            again = stored is not None
            if screen is None:
                runs.append(falsify(single, folder, seed=s, baseline=0, resume=again, **options))
            else:
                runs.append(falsify_screened(single, folder, screen=screen, confirm=confirm, seed=s, resume=again,
                                             **options))
        table.append(campaign_row(tuning, study.name, runs))
    state.update(status="done", table=table)
    write_json(root / CAMPAIGN_FILE, state)
    return state
