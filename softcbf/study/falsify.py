"""Falsification: search a study's parameter box for its worst case (docs/studies.md#falsification).

Problem. A study file's `[vary]` table spans a box X = Π_j X_j: a uniform distribution's
[low, high] (searched on its own scale), a loguniform one's [low, high] (searched on ln x),
a choice's finite set of values; with T > 1 tunings the tuning is one more, categorical,
coordinate. A normal distribution has no box and is refused. Filter parameters
(`vary."filter_param.NAME"`) are coordinates like any other, so the same search tunes a
filter. An evaluation of x ∈ X is one sample of the study (the fixed values, x and the
tuning; `Study.sample_of`), run on the study engine, and J(x) is the sample's row's
`objective` column (a summary metric; default ρ_min_meas [-], so J(x) < 0 is a
counterexample: the measured force exceeded F_max; "-NAME" maximises NAME). Falsification
approximates J* = min_{x ∈ X} J(x) and the x that attains it within a budget of N
evaluations. J is deterministic in x (the scenario's own seed is fixed per evaluation, below).

Initial design (`initial`, default "vertices"): failures hide in corners (an error's effect is
often monotone, so the worst case sits at a vertex of the box), so generation 0 holds the
vertices of the box's continuous coordinates, all 2^d in a seeded random order when they fit
in the population, else `population` distinct ones drawn at random (seeded); the categorical
coordinates and the rest of the generation come from the sampler. Where the effects are
monotone this finds the worst corner at once; where they are not it costs the sampler one
generation (TPE learns from it; CMA-ES starts from the centre either way). "random": the
sampler's own start (CMA-ES and TPE draw their first trials at random).

Search: optuna's ask-and-tell interface with a well-kept sampler: CMA-ES (`cmaes`, default:
covariance-matrix adaptation on the box mapped to [0, 1]^d, starting at its centre with
σ0 = 1/6; categorical coordinates are drawn at random) or TPE (`tpe`, multivariate, with a
constant liar for candidates in flight). Generation g asks `population` candidates (default
the CMA-ES population 4 + ⌊3 ln d⌋ for d coordinates), runs them together (below) and tells
each its J; a sample that failed (status "error", or no finite objective) is told as a failed
trial, which the sampler skips. A sample whose filter (or nominal) faulted is a violation and
takes the metric's unsafe extreme (`fault_value`; a fault is never a pass): −∞ for a margin
(names starting "rho": ρ_min_meas, larger is safer), +∞ for an excess (force_max…, t_violation…,
force_budget_used: larger is less safe); its own metric, cut short at the fault, is no value. So a
falsification (minimising ρ_min_meas, or maximising a force) is told −∞ for it and takes it as its
best as soon as one faults (best.value null, best.fault {type, message, where}), while a search for
the best setting ("-rho_min_meas", "force_max_N") is told +∞ and never picks a setting that
faulted while another finished. A metric of neither kind has no unsafe side known here: a faulted
sample is then a failed trial for the sampler, still counted in `faulted` and as a violation.
The search stops after N evaluations or, with
`stop_on_violation`, after the generation in which an evaluation violated (ρ_min_meas < 0 or a
filter fault, `analysis.violated`, whatever the objective).

Evaluation on the study engine (no second engine): `CandidateStudy` is the study whose sample
e is candidate e (evaluation e = optuna trial e; draw e; the scenario seed of the study's
draw e, `definition.draw_generator`), and each generation is `execute.run_study` of the
candidates so far into DIR/search with resume, so it runs only the new ones, batched by the
scenario's batch form (`batch_size`, default ⌈population / workers⌉ so every worker gets a
batch), on the local pool or Dask, and stores one Parquet part per evaluation
(softcbf.study.store). A generation's cost is one pool start plus ⌈population / workers⌉
samples of batched closed loop per worker.

Baseline: the same budget of uniform draws of the box, i.e. the study's own Monte Carlo
samples with its seed (every distribution is uniform over its box, log-uniform for
loguniform), run into DIR/random (an ordinary study folder; with `stop_on_violation` in chunks
of `population`, stopping at the first violation). Both report best-so-far J against the
number of evaluations (`report.write_report`, plots/best_so_far) and the evaluation of their
first violation.

Resume: optuna keeps the trials in its storage (SQLite in DIR/optuna.db by default, or a
server database's URL, which is never written to the folder; the optuna study's name, unique
per falsification, is kept in falsify.json, so a folder may move), the parts keep the rows.
Evaluation e is the e-th trial whose parameters cover the box, in trial order (a trial that
stopped inside optuna's `ask()` has none or part of them and is no evaluation). On resume the
trials asked but never told (the driver died) are run again (run_study skips the ones already
stored) and told; one interrupted inside `ask()` is told failed and its candidate asked again
(a vertex of generation 0 is enqueued again);
then the search goes on up to the budget, which may grow, its sampler seeded anew from the seed and the trials so
far (`make_sampler`: optuna keeps no sampler's random state). One driver per folder. A resume must
give the same study, objective, sampler, seed and population (DIR/falsify.json records them),
and its storage must hold the search: a missing, empty or unreadable optuna.db, or a storage
without the study, is refused with one line (`OutputDirError`) before anything is written, so a
refused resume leaves falsify.json as it was.

Outputs of a falsification folder DIR:

    DIR/falsify.json     {"objective", "best": {"value", "params", "tuning", "evaluation", "fault"},
                          "evaluations", "failed", "faulted", "first_violation", "random_baseline":
                          {"best", "params", "tuning", "evaluations", "failed", "faulted", "fault",
                          "first_violation"}, "worst": {...}, the settings, "stopped"}; best.value
                          is the metric's own value (for "-NAME" the largest NAME), null with
                          best.fault {type, message, where} when the best evaluation faulted;
                          evaluations are counted from 1, first_violation is the count at the
                          first violation (null: none); failed: evaluations without a value
                          (status "error"), faulted: evaluations whose filter faulted
    DIR/search/          study folder of the evaluations (sample = evaluation − 1)
    DIR/random/          study folder of the baseline
    DIR/worst/           run folder of the best evaluation (run alone, with the scenario's
                         report): `softcbf run --config DIR/worst/config.json` replays it bit
                         for bit; falsify.json's worst.value is that run's J, equal to best.value
    DIR/optuna.db        optuna's storage (the default SQLite one)
    DIR/report.md, DIR/plots/best_so_far.<fmt>   written by `softcbf study report DIR`

Multi-fidelity (a cheap scenario's search confirmed on this one) and campaigns over seeds build on `falsify`:
`softcbf.study.screen`, `softcbf.study.campaign`.
"""

from __future__ import annotations

import dataclasses
import itertools
import contextlib
import logging
import math
import os
import shutil
import sqlite3
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import optuna
import sqlalchemy.exc
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution
from optuna.trial import TrialState

from softcbf.study.analysis import clean, violated
from softcbf.study.definition import Sample, Study, draw_generator
from softcbf.study.execute import connect_scheduler, run_study
from softcbf.study.runner import run_sample
from softcbf.study.store import FALSIFY_FILE, PARAM_PREFIX, StudyStore, fault_of, faulted, part_name, read_part, stored_search
from softcbf.study.store import SQLITE_FILE, optuna_storage, storage_name
from softcbf_mj.outputs.progress import Progress, significant
from softcbf_mj.outputs.runio import OutputDirError, write_json

SAMPLERS = ("cmaes", "tpe")
SEARCH_DIR = "search"
BASELINE_DIR = "random"
WORST_DIR = "worst"
STORAGE_FILE = SQLITE_FILE
TUNING_COORDINATE = "@tuning"  # the tuning's coordinate in the search space (no scenario parameter has an @)
INITIALS = ("vertices", "random")
CMAES_MIN_POPULATION = 4  # CMA-ES's μ = ⌊population / 2⌋ parents must be >= 2 (its covariance update divides by them)
VERTEX_STREAM = 1  # the vertex design's generator: SeedSequence([seed, VERTEX_STREAM])
SETTINGS = ("objective", "sampler", "seed", "population", "initial", "study")  # what a resume must repeat
MARGINS = ("rho",)  # metrics whose larger values are safer (ρ ≥ 0 ⇔ F ≤ F_max): a fault takes −∞
EXCESSES = ("force_max", "t_violation", "force_budget_used")  # metrics whose larger values are less safe: +∞


@dataclass(frozen=True)
class Candidate:
    """One point of the box: a value per varied parameter, and the tuning it runs with."""

    values: dict[str, Any]
    tuning: str


@dataclass(frozen=True)
class CandidateStudy(Study):
    """The study whose sample e is `candidates[e]` (module docstring): draw e, the scenario seed of draw e.

    Its checks: the study's own (`Study`), then every candidate names each varied parameter once, holds a value
    within that parameter's box and a tuning of the study. `to_dict` is the study's, so its folder resumes."""

    candidates: tuple[Candidate, ...] = ()

    def __post_init__(self) -> None:
        checked = Study(**{f.name: getattr(self, f.name) for f in dataclasses.fields(Study)})
        for f in dataclasses.fields(Study):
            object.__setattr__(self, f.name, getattr(checked, f.name))
        object.__setattr__(self, "candidates", tuple(self.candidates))
        space = {d.parameter: d for d in self.vary}
        for e, candidate in enumerate(self.candidates):
            if set(candidate.values) != set(space):
                raise ValueError(f"candidate {e} gives {sorted(candidate.values)}, the study varies {sorted(space)}")
            if candidate.tuning not in self.tunings:
                raise ValueError(f"candidate {e}: tuning must be one of {list(self.tunings)}, got {candidate.tuning!r}")
            for name, value in candidate.values.items():
                d = space[name]
                inside = value in d.values if d.kind == "choice" else d.low <= value <= d.high
                if not inside:
                    raise ValueError(f"candidate {e}: {name} must lie in its box {box_text(d)}, got {value!r}")

    @classmethod
    def of(cls, study: Study, candidates: list[Candidate] | tuple[Candidate, ...]) -> "CandidateStudy":
        return cls(**{f.name: getattr(study, f.name) for f in dataclasses.fields(Study)}, candidates=tuple(candidates))

    @property
    def n_draws(self) -> int:
        return len(self.candidates)

    @property
    def n_samples(self) -> int:
        return len(self.candidates)

    def sample(self, index: int) -> Sample:
        if not 0 <= index < len(self.candidates):
            raise IndexError(f"evaluation index must lie in [0, {len(self.candidates)}), got {index}")
        candidate = self.candidates[index]
        _, scenario_seed = draw_generator(self.seed, index)
        return self.sample_of(index, index, candidate.tuning, scenario_seed, dict(candidate.values))


def box_text(d: Any) -> str:
    return f"{list(d.values)}" if d.kind == "choice" else f"[{d.low:g}, {d.high:g}]"


def search_space(study: Study) -> dict[str, BaseDistribution]:
    """The box of `study` as optuna distributions (module docstring); ValueError naming what has no box."""
    space: dict[str, BaseDistribution] = {}
    for d in study.vary:
        if d.kind == "choice":
            space[d.parameter] = CategoricalDistribution(d.values)
        elif d.kind in ("uniform", "loguniform"):
            space[d.parameter] = FloatDistribution(d.low, d.high, log=d.kind == "loguniform")
        else:
            raise ValueError(f"vary.{d.parameter}: falsify searches a box and dist {d.kind!r} has no bounds; "
                             "give it dist = 'uniform' with low and high")
    if len(study.tunings) > 1:
        space[TUNING_COORDINATE] = CategoricalDistribution(study.tunings)
    if not space:
        raise ValueError("falsify needs a box to search: the study varies no parameter and has one tuning")
    return space


def default_population(study: Study) -> int:
    """CMA-ES's default population 4 + ⌊3 ln d⌋ for the d coordinates of the study's box."""
    return 4 + int(3 * math.log(len(search_space(study))))


def vertex_design(space: dict[str, BaseDistribution], population: int, seed: int) -> list[dict[str, float]]:
    """Generation 0's vertices of the box's continuous coordinates (module docstring), in evaluation order."""
    names = [name for name, d in space.items() if isinstance(d, FloatDistribution)]
    if not names:
        return []
    rng = np.random.default_rng(np.random.SeedSequence([seed, VERTEX_STREAM]))
    if 2 ** len(names) <= population:
        patterns = [tuple(p) for p in itertools.product((0, 1), repeat=len(names))]
        patterns = [patterns[i] for i in rng.permutation(len(patterns))]
    else:
        chosen: dict[tuple[int, ...], None] = {}
        while len(chosen) < population:
            chosen[tuple(int(b) for b in rng.integers(0, 2, len(names)))] = None
        patterns = list(chosen)
    return [{n: (space[n].high if bit else space[n].low) for n, bit in zip(names, pattern)} for pattern in patterns]


def objective_value(row: dict[str, Any], objective: str) -> float | None:
    """The metric `objective` names ("NAME" or "-NAME") in a clean row (`analysis.clean`), as stored (None:
    failed, faulted or not finite)."""
    value = row.get(objective.removeprefix("-")) if clean(row) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def minimised(value: float, objective: str) -> float:
    """The value the search minimises: the metric, or its negative for "-NAME"."""
    return -value if objective.startswith("-") else value


def fault_value(metric: str) -> float | None:
    """The value a faulted sample takes for `metric` (module docstring): −∞ for a margin, +∞ for an excess, None
    when its unsafe side is not known."""
    if metric.startswith(MARGINS):
        return -math.inf
    if metric.startswith(EXCESSES):
        return math.inf
    return None


def searched_value(row: dict[str, Any], objective: str) -> float | None:
    """What the search is told for `row` (module docstring): the minimised metric of a clean row, or of a faulted
    row's `fault_value`; None when it has none (a failed trial)."""
    value = fault_value(objective.removeprefix("-")) if faulted(row) else objective_value(row, objective)
    return None if value is None else minimised(value, objective)


def make_sampler(name: str, seed: int, population: int, n_trials: int = 0) -> optuna.samplers.BaseSampler:
    """Optuna's sampler `name` (SAMPLERS: module docstring) with `population` for CMA-ES, seeded with `seed` for a
    new search and, for one resumed after `n_trials` trials, with a seed drawn from (seed, n_trials): optuna keeps
    no sampler's random state, so the search's own seed would draw again the random candidates it drew at its
    start (TPE's startup trials, CMA-ES's independent draws) instead of new ones."""
    if n_trials:
        seed = int(np.random.SeedSequence([seed, n_trials]).generate_state(1)[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if name == "cmaes":
            return optuna.samplers.CmaEsSampler(seed=seed, popsize=population, warn_independent_sampling=False)
        return optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)


def _candidate(params: dict[str, Any], study: Study) -> Candidate:
    values = {d.parameter: params[d.parameter] for d in study.vary}
    return Candidate(values, params.get(TUNING_COORDINATE, study.tunings[0]))


def stored_rows(store_dir: Path, indices: range) -> dict[int, dict[str, Any]]:
    """The stored rows of samples `indices` of a study folder (each part read and checked once)."""
    results = Path(store_dir) / "results"
    return {i: read_part(results / part_name(i)).to_pylist()[0] for i in indices if (results / part_name(i)).is_file()}


def summary(rows: list[dict[str, Any]], objective: str) -> dict[str, Any]:
    """Best row (by the searched sense, `searched_value`), failures (no value, no fault), faults and the
    evaluation count at the first violation (a fault included)."""
    scored = [(searched_value(r, objective), r) for r in rows]
    ok = [(v, r) for v, r in scored if v is not None]
    first = next((int(r["sample"]) + 1 for r in rows if violated(r)), None)
    out: dict[str, Any] = {"best": None, "params": None, "tuning": None, "evaluation": None, "fault": None,
                           "evaluations": len(rows), "failed": sum(1 for v, r in scored if v is None and not faulted(r)),
                           "faulted": sum(1 for r in rows if faulted(r)), "first_violation": first}
    if ok:
        _, row = min(ok, key=lambda vr: vr[0])
        out.update(best=objective_value(row, objective), fault=fault_of(row),
                   params={k.removeprefix(PARAM_PREFIX): v for k, v in row.items() if k.startswith(PARAM_PREFIX)},
                   tuning=row["tuning"], evaluation=int(row["sample"]) + 1)
    return out


def falsify(
    study: Study,
    out_dir: str | Path,
    *,
    budget: int,
    sampler: str = "cmaes",
    population: int | None = None,
    initial: str = "vertices",
    seed: int | None = None,
    baseline: int | None = None,
    stop_on_violation: bool = False,
    storage: str | None = None,
    resume: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    batch_size: int | None = None,
    progress: bool | Progress = True,
) -> dict[str, Any]:
    """Search `study`'s box for the minimum of its objective (module docstring); returns falsify.json's content.

    `budget`: evaluations of the search; `baseline`: uniform draws (default `budget`, 0: none); `seed`: of the
    sampler, the evaluations' scenario seeds and the baseline (default the study's); `storage`: "journal"
    (DIR/optuna.journal), an optuna storage URL, or None: SQLite in DIR (`store.search_storage`); `workers`,
    `scheduler`, `client`, `batch_size`: as `run_study`. `progress`: the
    progress line (per evaluation, with its ETA) or not, or the `Progress` to report into (the command line's,
    whose first line came before optuna was imported).
    """
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ValueError(f"budget must be an integer >= 1 (evaluations), got {budget!r}")
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    if initial not in INITIALS:
        raise ValueError(f"initial must be one of {', '.join(INITIALS)}, got {initial!r}")
    if scheduler is not None and client is not None:
        raise ValueError("give a Dask scheduler address or a client, not both")
    study = study if seed is None or seed == study.seed else dataclasses.replace(study, seed=seed)
    space = search_space(study)
    population = default_population(study) if population is None else population
    if isinstance(population, bool) or not isinstance(population, int) or population < 1:
        raise ValueError(f"population must be an integer >= 1 (candidates per generation), got {population!r}")
    if sampler == "cmaes" and population < CMAES_MIN_POPULATION:
        raise ValueError(f"population must be >= {CMAES_MIN_POPULATION} with sampler cmaes (CMA-ES recombines the best "
                         f"half, which needs two), got {population}; or use sampler tpe")
    baseline = budget if baseline is None else baseline
    if isinstance(baseline, bool) or not isinstance(baseline, int) or baseline < 0:
        raise ValueError(f"baseline must be an integer >= 0 (uniform draws; 0: none), got {baseline!r}")
    objective = study.objective
    root = Path(out_dir)
    settings = {"objective": objective, "sampler": sampler, "seed": study.seed, "population": population,
                "initial": initial, "study": study.to_dict()}
    stored = stored_search(root, FALSIFY_FILE, "falsification", settings, SETTINGS, resume)
    name = stored.get("optuna_study") or f"softcbf-falsify-{study.name}-{uuid.uuid4().hex[:12]}"
    state: dict[str, Any] = {**settings, "budget": budget, "status": "running", "optuna_study": name,
                             "storage": storage_name(storage)}
    fresh_bar = not isinstance(progress, Progress)
    bar = Progress(f"falsify {study.name}", budget, enabled=progress, unit="evaluations") if fresh_bar else progress
    if not resume:  # a falsification folder from the start, so a search that stops can be resumed
        root.mkdir(parents=True, exist_ok=True)
        write_json(root / FALSIFY_FILE, state)
        if fresh_bar:
            bar.update(0, "opening the search")  # its storage takes seconds; a resume's first line follows its checks
    optuna.logging.set_verbosity(logging.WARNING)
    search = open_search(root, storage, name, make_sampler(sampler, study.seed, population), resume)
    search_dir, baseline_dir = root / SEARCH_DIR, root / BASELINE_DIR
    trials, asked = asked_trials(search, space, root)
    if trials:  # a resumed search draws new random candidates (`make_sampler`)
        search.sampler = make_sampler(sampler, study.seed, population, len(trials))
    parts = StudyStore(search_dir, study).part_paths()
    if len(parts) > len(asked):
        raise OutputDirError(f"{root} holds {len(parts)} evaluations but its optuna storage {len(asked)} trials "
                             f"of study {name!r}: resume with the --storage that the search started with")
    write_json(root / FALSIFY_FILE, state)  # the resume is accepted: nothing was written before

    own_client = None
    if scheduler is not None:
        client = own_client = connect_scheduler(scheduler)
    if batch_size is None:
        n_workers = sum(client.nthreads().values()) if client is not None else (workers or os.cpu_count() or 1)
        batch_size = max(1, math.ceil(population / max(1, n_workers)))
    run = {"workers": workers, "client": client, "batch_size": batch_size, "progress": False}
    try:
        numbers = [t.number for t in asked]  # evaluation e is optuna trial numbers[e]
        retire_interrupted(search, trials, numbers)
        if initial == "vertices" and not trials:  # a fresh search
            for vertex in vertex_design(space, population, study.seed):
                search.enqueue_trial(vertex)
        candidates = [_candidate(t.params, study) for t in asked]
        pending = [e for e, t in enumerate(asked) if t.state == TrialState.RUNNING]  # asked, never told
        evaluated = stored_rows(search_dir, range(len(asked)))  # evaluation index → row, as they are told
        violation = any(violated(r) for r in evaluated.values())
        stopped = "budget"
        note = search_note(evaluated, objective) if evaluated else "first generation"
        bar.update(len(evaluated), note)
        while True:
            if not pending:
                if stop_on_violation and violation:
                    stopped = "violation"
                    break
                if len(candidates) >= budget:
                    break
                for _ in range(min(population, budget - len(candidates))):
                    trial = search.ask(space)
                    if numbers and trial.number <= numbers[-1]:
                        raise OutputDirError(f"optuna gave trial {trial.number} after trial {numbers[-1]}: the study "
                                             "in its storage was changed outside falsify (one driver per folder)")
                    numbers.append(trial.number)
                    candidates.append(_candidate(trial.params, study))
                    pending.append(len(candidates) - 1)
            before = len(candidates) - len(pending)  # evaluations told before this generation
            run_study(CandidateStudy.of(study, candidates), search_dir, resume=True, samples=len(candidates),
                      report=lambda done_now: bar.update(before + done_now, note), **run)
            rows = stored_rows(search_dir, range(pending[0], pending[-1] + 1))
            evaluated.update(rows)
            for e in pending:
                row = rows.get(e, {})
                value = searched_value(row, objective)
                violation = violation or bool(violated(row))
                if value is None:
                    search.tell(numbers[e], state=TrialState.FAIL)
                else:
                    search.tell(numbers[e], value)
            if all(objective_value(r, objective) is None for r in rows.values()) and len(candidates) == len(pending):
                _refuse_unknown_objective(rows, objective)
            pending = []
            note = search_note(evaluated, objective)
            bar.update(len(candidates), note)
        bar.close(len(candidates))
        result = summary([evaluated[i] for i in sorted(evaluated)], objective)
        base = []
        if baseline:
            base_bar = Progress(f"falsify {study.name} baseline", baseline, enabled=bar.enabled, unit="draws")
            base_bar.update(0, "uniform draws of the box")
            base = uniform_baseline(study, baseline_dir, baseline, population if stop_on_violation else None, run,
                                    report=lambda done_now: base_bar.update(done_now, "uniform draws of the box"))
            base_bar.close(len(base))
        base_summary = summary(base, objective)
        worst = None
        if result["evaluation"] is not None:
            worst = replay_worst(CandidateStudy.of(study, candidates), result["evaluation"] - 1, root / WORST_DIR,
                                  objective)
    finally:
        if own_client is not None:
            own_client.close()
    state.update(status="done", stopped=stopped, evaluations=result["evaluations"], failed=result["failed"],
                 faulted=result["faulted"], first_violation=result["first_violation"],
                 best={"value": result["best"], "params": result["params"], "tuning": result["tuning"],
                       "evaluation": result["evaluation"], "fault": result["fault"]},
                 random_baseline={k: base_summary[k] for k in ("best", "params", "tuning", "evaluation", "evaluations",
                                                              "failed", "faulted", "fault", "first_violation")},
                 worst=worst)
    write_json(root / FALSIFY_FILE, state)
    return state


def open_search(root: Path, storage: str | None, name: str, sampler: optuna.samplers.BaseSampler,
                resume: bool) -> optuna.Study:
    """The optuna study `name`: created (a new search) or, with `resume`, loaded from its storage (`storage`, a
    URL; "journal": DIR/optuna.journal; None: DIR/optuna.db). A storage that is missing, empty, unreadable or
    without the study is refused with one line (`OutputDirError`); the default SQLite file is first read
    read-only, so a refused resume writes nothing (module docstring)."""
    url = optuna_storage(root, storage, resume)
    shown = "the --storage database" if storage not in (None, "journal") else str(root / storage_name(storage))
    hint = ("the search's trials are lost: start a new falsification in another --out (its evaluations stay in "
            f"{root / SEARCH_DIR})")
    if resume and storage is None:
        path = root / STORAGE_FILE
        if not path.is_file():
            raise OutputDirError(f"{path} is missing (or the search ran on a server database: resume with its "
                                 f"--storage); without it {hint}")
        try:
            with contextlib.closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
                names = {n for (n,) in db.execute("SELECT study_name FROM studies")}
        except sqlite3.Error as exc:
            raise OutputDirError(f"{path} is not a readable optuna storage ({exc}); {hint}") from None
        if name not in names:
            raise OutputDirError(f"{path} holds no optuna study {name!r} (the one falsify.json names); {hint}")
    try:
        if resume:
            return optuna.load_study(study_name=name, storage=url, sampler=sampler)
        return optuna.create_study(study_name=name, storage=url, direction="minimize", sampler=sampler)
    except KeyError:
        raise OutputDirError(f"{shown} holds no optuna study {name!r} (the one falsify.json names); resume with "
                             "the --storage that the search started with") from None
    except (sqlalchemy.exc.SQLAlchemyError, optuna.exceptions.StorageInternalError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise OutputDirError(f"cannot open {shown} as an optuna storage: {first}") from None


def asked_trials(search: optuna.Study, space: dict[str, BaseDistribution],
                 root: Path) -> tuple[list[optuna.trial.FrozenTrial], list[optuna.trial.FrozenTrial]]:
    """The search's trials (enqueued ones left out) and its evaluations: the trials whose parameters cover
    `space`, in trial order (module docstring); OutputDirError when the trial numbers have gaps."""
    trials = [t for t in search.get_trials(deepcopy=False) if t.state != TrialState.WAITING]  # WAITING: enqueued
    if [t.number for t in trials] != list(range(len(trials))):
        raise OutputDirError(f"the optuna study of {root} has gaps in its trial numbers; it was changed outside "
                             "the search (one driver per folder)")
    return trials, [t for t in trials if set(space) <= set(t.params)]


def retire_interrupted(search: optuna.Study, trials: list[optuna.trial.FrozenTrial], numbers: list[int]) -> None:
    """Tell failed the trials that stopped inside `ask()` (running, not among the evaluations' `numbers`), and
    enqueue again an enqueued vertex among them (module docstring: resume)."""
    for trial in trials:
        if trial.state == TrialState.RUNNING and trial.number not in numbers:  # stopped inside ask(): asked anew
            search.tell(trial.number, state=TrialState.FAIL)
            vertex = trial.system_attrs.get("fixed_params")  # an enqueued vertex (optuna's key): enqueued again
            if vertex:
                search.enqueue_trial(vertex)


def search_note(evaluated: dict[int, dict[str, Any]], objective: str) -> str:
    """The progress line's note of a search: the best objective so far (`significant` digits), faults and the
    first violation."""
    done = summary([evaluated[i] for i in sorted(evaluated)], objective)
    best = "a filter fault" if done["fault"] else significant(done["best"])
    return (f"best {objective} {best}" + (f", {done['faulted']} faulted" if done["faulted"] else "")
            + (f", first violation at evaluation {done['first_violation']}" if done["first_violation"] else ""))


def _refuse_unknown_objective(rows: dict[int, dict[str, Any]], objective: str) -> None:
    """Every sample of the first generation ran but none has the objective's column: a misspelt metric."""
    ok = [r for r in rows.values() if r.get("status") == "ok"]
    name = objective.removeprefix("-")
    if ok and all(name not in r for r in ok):
        numeric = sorted(k for k, v in ok[0].items() if isinstance(v, (int, float)) and not isinstance(v, bool)
                         and k not in ("sample", "draw", "scenario_seed") and not k.startswith("param."))
        raise ValueError(f"objective {objective!r}: the scenario's rows have no column {name!r}; numeric columns: "
                         f"{', '.join(numeric)}")


def uniform_baseline(study: Study, folder: Path, budget: int, chunk: int | None, run: dict[str, Any],
                     report: Callable[[float], None] | None = None) -> list[dict]:
    """Uniform draws of the box: the study's Monte Carlo samples 0 … budget−1 (module docstring); `report` is
    called with the draws done so far (fractional, as `run_study`'s)."""
    draws = math.ceil(budget / len(study.tunings))
    uniform = dataclasses.replace(study, sampling="monte_carlo", draws=draws)
    rows: dict[int, dict[str, Any]] = {}
    done = 0
    while done < budget:
        start, done = done, (budget if chunk is None else min(budget, done + chunk))
        chunk_report = None if report is None else (lambda done_now, start=start: report(start + done_now))
        run_study(uniform, folder, resume=True, samples=done, report=chunk_report, **run)
        new = stored_rows(folder, range(start, done))
        rows.update(new)
        if chunk is not None and any(violated(r) for r in new.values()):
            break
    return [rows[i] for i in sorted(rows)]


def replay_worst(study: CandidateStudy, index: int, folder: Path, objective: str) -> dict[str, Any]:
    """Run evaluation `index` alone into `folder` (a full run folder, replaced if there) and return its J."""
    if folder.exists():
        shutil.rmtree(folder)
    row = run_sample(study, index, str(folder))
    return {"dir": WORST_DIR, "evaluation": index + 1, "value": objective_value(row, objective),
            "status": row["status"], "fault": fault_of(row), "replay": f"softcbf run --config {WORST_DIR}/config.json"}
