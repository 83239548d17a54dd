"""Robust tuning: the filter setting that delivers the most force and that a falsifier cannot break (docs/studies.md#robust-tuning).

Problem. A tune file is a study file (`softcbf.study.definition`: the scenario, the task in
`fixed`, the filter and its fixed `filter_params`, one tuning, the error box `[vary]` and the
inner objective; or, instead of `[vary]`, `error_box = "FILE"`: the `[vary]` of that study file,
relative to the tune file, so a lab states its box once) with a `[tune]` table: a tuning box Θ
over the filter's own parameters (`[tune.NAME]`, dist "uniform", "loguniform" or "choice", as
`[vary.NAME]`) and `objective`, the metric to maximise (default "force_delivered_N"). For a setting θ ∈ Θ:

- the nominal evaluation runs the task once with θ at the nominal point x₀ (the fixed values,
  each varied parameter at the scenario's default: for the standard box the nominal plate,
  gain, arm and valve); F(θ) is its objective: "force_delivered_N" is the steady measured force
  of the run (`softcbf_mj.outputs.push_force.steady_force_of_folder`: the mean of the largest plate force over
  the run's last third, N, as the bench's pushes report it), any other name a numeric column of
  the run's summary row;
- the inner search is a falsification of the error box X with θ fixed (`falsify.falsify`: the
  study's objective, default ρ_min_meas, minimised; its vertex design first; `inner_budget`
  evaluations, stopped at the first violation);
- θ is safe when the nominal run and every inner evaluation finished cleanly without violation
  (`analysis.violated`: ρ_min_meas < 0 or a filter fault); a faulted run makes θ unsafe (a fault
  is never a pass), and so does an evaluation that failed outside the filter (no verdict: no
  certificate). Safe means "no violation found in the inner budget", not a proof: the
  independent check is a larger falsification of the winner (`winner.json` below).
- ρ_worst(θ) = min over the nominal and the inner evaluations of ρ_min_meas (−∞ with a fault).

The tuning problem is max {F(θ) : θ ∈ Θ, θ safe}. A setting's continuous values run rounded to
`DIGITS` significant digits (and kept within the box): a setting a user types, and a run label
(which names its time series file) of bounded length; the search is told the value of the
rounded setting, which is the one stored and replayed. The outer search is optuna's TPE
(multivariate, constant liar; or CMA-ES) over Θ, minimising the told value
J(θ) = −F(θ) for a safe θ and J(θ) = UNSAFE_OFFSET + min(−ρ_worst(θ), RHO_CAP) for an unsafe
one: every unsafe setting ranks behind every safe one (assumption: |F| < UNSAFE_OFFSET), and
among the unsafe the least violating first, which leads the search towards the boundary where
the most force sits. A θ without a value (its nominal run failed) is a failed trial.

Screened inner searches (`screen`, `confirm`; `softcbf.study.screen`). Every inner evaluation above is a run
of the study's scenario (mujoco_contact: tens of seconds a run), so a tuning's cost is its budget times the inner
budget in those runs. With `screen` = a cheaper scenario (pcc_contact: mujoco_contact's errors on the PCC plant)
each inner search is `screen.falsify_screened` (the same implementation as `softcbf study falsify --screen`): its
`inner_budget` evaluations run on the cheap scenario, all of them (a cheap violation does not stop the screen: it
is a candidate, not a verdict), and its `confirm` worst distinct candidates run on the study's scenario, stopped
at the first violation there, the worst confirmed replayed once. θ is then safe when the nominal run and every
confirmation finished cleanly without violation, at least one confirmation ran (a screen that ranks nothing, its
runs all failed, confirms nothing: no verdict, not safe), the screen ran its whole budget, and no run of either
scenario faulted or failed (a filter fault on the cheap plant is the filter's). A violation found only on the
cheap plant does not make θ unsafe (the cheap plant leaves out what scenarios.pcc_contact lists); ρ_worst(θ) is
over the study scenario's runs. Assumption: the cheap plant's worst cases are the expensive one's (screen.py);
where they are not, a screened verdict is weaker than a single-fidelity one of the same inner budget.

Evaluation and engine (no second engine). Generation g asks `population` settings; their
nominal runs are one study (`falsify.CandidateStudy` of the tuning box as `filter_param.NAME`
coordinates) run by `execute.run_study` into DIR/nominal with `keep_runs` (each run's folder
kept: its time series gives the delivered force, its config.json replays it); then each
setting's inner search runs into DIR/inner/EEEE (a falsification folder), whose generations are
batched by the scenario's batch form (one `filter_batch` instance where the filter has one) on
the local pool or Dask. The nominal runs are kept runs (the time series gives the delivered
force, config.json the replay), so each runs alone, the generation's runs in parallel over the
workers. On Dask, DIR must lie on a disk the workers share (the kept runs are written where they
run).

Resume (one driver per folder). The outer trials live in optuna's storage: SQLite DIR/optuna.db or
the journal DIR/optuna.journal (`storage`, `store.search_storage`: the journal is the command line's
default on Dask, where DIR lies on a shared disk; each inner search keeps its trials in the same
kind of storage in its own folder; `falsify.open_search`, the optuna study's name in tune.json);
the nominal rows are study parts, the inner searches falsification folders. Evaluation e is the
e-th outer trial whose parameters cover Θ. On resume, an evaluation already told is read back from
its folders (never run again, and the sampler is seeded anew from the seed and the trials so far,
`falsify.make_sampler`); one asked but not told runs its missing parts (run_study skips the stored
nominal run, an inner search resumes from its own storage, a finished one is read) and is told; then
the search goes on up to the budget, which may grow. A resume must repeat the study, tuning box,
objectives, sampler, seed, population, inner budget, screen and confirm (tune.json records them).

Outputs of a tune folder DIR:

    DIR/tune.json      {"objective", "inner_objective", settings ("screen", "confirm": null unscreened),
                        "evaluations": [{"evaluation", "params", "value", "safe", "worst_rho",
                        "nominal_status", "inner_evaluations" (screened: the confirmations),
                        "first_violation" (on the study's scenario: 0 the nominal run, k inner evaluation or
                        confirmation k, null none), "faulted", "failed", "fault" (both scenarios),
                        "expensive_runs" (the study scenario's runs: nominal, inner or confirmations, the
                        worst's replay), screened only "screen": {"evaluations", "violations",
                        "first_violation", "faulted", "worst_rho"} (on the cheap scenario)}],
                        "expensive_runs" (their sum), "best": {"evaluation", "params", "value",
                        "worst_rho", "filter", "filter_params", "command", "replay", "check"} | null,
                        "safe", "status"}
    DIR/nominal/       study folder of the nominal runs (sample = evaluation − 1), runs/ kept
    DIR/inner/EEEE/    falsification folder of evaluation EEEE's inner search (screened: its screen/ in it)
    DIR/best/          the winner's nominal run folder: `softcbf run --config DIR/best/config.json`
    DIR/winner.json    a study file of the error box with the winner's filter_params fixed, for an
                       independent check: `softcbf study falsify DIR/winner.json --budget 300 …`
    DIR/tune.png       objective against ρ_worst for every evaluation (`plot_front`)
    DIR/optuna.db      the outer search's storage (or DIR/optuna.journal, `storage` "journal")
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from controllers.contract.filter_parameters import read_params
from softcbf.study.analysis import clean, violated
from softcbf.study.definition import (FILTER_PARAM_PREFIX, FILTER_PARAMS, Distribution, Study, apply_settings,
                                      distributions_of, fold_values)
from softcbf.study.store import FALSIFY_FILE, TUNE_FILE, StudyStore, fault_of, faulted, storage_name, stored_search
from softcbf_mj.outputs.palette import BLUISH_GREEN, LIMIT_COLOR, NEUTRAL_COLOR, ORANGE
from softcbf_mj.outputs.progress import Progress, significant
from softcbf_mj.outputs.push_force import steady_force_of_folder
from softcbf_mj.outputs.runio import write_json
from vocabulary.files import read_settings_file

DEFAULT_OBJECTIVE = "force_delivered_N"  # the steady measured force of the nominal run (module docstring)
DEFAULT_INNER_BUDGET = 40  # inner falsification evaluations per setting
DEFAULT_POPULATION = 4  # settings per outer generation
SAMPLERS = ("tpe", "cmaes")
UNSAFE_OFFSET = 1e6  # told value of an unsafe setting, before its violation (module docstring)
RHO_CAP = 1e3  # the largest violation −ρ_worst told (a fault's −∞ included)
NOMINAL_DIR, INNER_DIR, BEST_DIR = "nominal", "inner", "best"
WINNER_FILE, FIGURE_FILE = "winner.json", "tune.png"
DIGITS = 4  # significant digits of a setting's continuous values (module docstring)
ERROR_BOX_KEY = "error_box"  # a tune file's key naming the study file whose [vary] is its error box
TUNE_KEYS = ("objective",)  # [tune] keys that are not a parameter's table
SETTINGS = ("objective", "inner_objective", "sampler", "seed", "population", "inner_budget", "screen", "confirm",
            "study", "tune")


@dataclass(frozen=True)
class TuneFile:
    """A checked tune file (module docstring): the study (task, filter, error box, inner objective), the tuning
    box (`box`: distributions of `filter_param.NAME`) and the objective maximised at the nominal point."""

    study: Study
    box: tuple[Distribution, ...]
    objective: str = DEFAULT_OBJECTIVE

    def __post_init__(self) -> None:
        study = self.study
        if not isinstance(self.objective, str) or not self.objective or self.objective.startswith("-"):
            raise ValueError(f'tune.objective must name a metric to maximise, such as "force_delivered_N", got '
                             f"{self.objective!r}")
        if "filter" not in study.fixed:
            raise ValueError('a tune file names the filter to tune (filter = "c-erg" at the top level)')
        if len(study.tunings) != 1:
            raise ValueError(f"a tune file runs one tuning (the filter's), got tunings = {list(study.tunings)}")
        if not self.box:
            raise ValueError("a tune file needs a tuning box: [tune.NAME] tables over the filter's parameters "
                             "(dist = 'uniform' with low and high)")
        for d in self.box:
            if d.kind == "normal":
                raise ValueError(f"tune.{d.parameter.removeprefix(FILTER_PARAM_PREFIX)}: the tuning box needs bounds; "
                                 "give dist = 'uniform' (or 'loguniform', 'choice'), not 'normal'")
        varied = {d.parameter for d in study.vary}
        tuned = {d.parameter for d in self.box}
        if varied & tuned:
            both = sorted(p.removeprefix(FILTER_PARAM_PREFIX) for p in varied & tuned)
            raise ValueError(f"filter parameter(s) {both} "
                             "are both tuned ([tune]) and varied ([vary]); the error box holds the plant's errors")
        nominal_study(self)  # the tuning box's ends through the scenario's (and the filter's) checks
        inner_study(self, {})  # and the error box with the fixed filter parameters


def tune_box(table: Any) -> tuple[tuple[Distribution, ...], str]:
    """The tuning box and objective of a file's `[tune]` table (module docstring)."""
    if not isinstance(table, dict):
        raise ValueError(f"tune must be a table ([tune.NAME] with dist = ...), got {table!r}")
    objective = table.get("objective", DEFAULT_OBJECTIVE)
    params = {k: v for k, v in table.items() if k not in TUNE_KEYS}
    box = distributions_of(params, "tune", FILTER_PARAM_PREFIX)
    return box, objective


def load_tune(path: str | Path, settings: Sequence[str] = ()) -> TuneFile:
    """Read a tune file (TOML: a study file with a [tune] table) with the command line's `settings`
    ("dotted.key=VALUE", applied before the checks); errors name the file."""
    path = Path(path)
    data = read_settings_file(path, "tune file")
    try:
        data = apply_settings(data, settings)
        if "tune" not in data:
            raise ValueError("a tune file needs a [tune] table: the tuning box over the filter's parameters "
                             "([tune.NAME] with dist, low, high) and optionally objective")
        box, objective = tune_box(data.pop("tune"))
        if ERROR_BOX_KEY in data:
            data["vary"] = error_box(path, data.pop(ERROR_BOX_KEY), data.get("vary"))
        data.setdefault("draws", 1)  # a study's Monte Carlo size: unused by a tuning (its budgets count)
        return TuneFile(Study.from_dict(data), box, objective)
    except ValueError as exc:
        raise ValueError(f"tune file {path}: {exc}") from None


def error_box(path: Path, name: Any, vary: Any) -> dict[str, Any]:
    """The `[vary]` tables of the study file that a tune file's `error_box` names (a path relative to the tune
    file): the error box stated once, for the falsifier and the tuning alike (docs/studies.md, the standard box)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"{ERROR_BOX_KEY} must name a study file whose [vary] is the error box, got {name!r}")
    if vary is not None:
        raise ValueError(f"give the error box once: {ERROR_BOX_KEY} = {name!r} or [vary] tables, not both")
    source = path.parent / name
    tables = read_settings_file(source, f"{ERROR_BOX_KEY} file").get("vary")
    if not isinstance(tables, dict) or not tables:
        raise ValueError(f"{ERROR_BOX_KEY} file {source} has no [vary] tables (the error box)")
    return tables


def nominal_study(tune: TuneFile) -> Study:
    """The study of the nominal runs: the task at the nominal point, the tuning box as its coordinates."""
    study = tune.study
    return dataclasses.replace(study, name=f"{study.name}_nominal", vary=tune.box, sampling="monte_carlo", draws=1)


def inner_study(tune: TuneFile, values: dict[str, Any]) -> Study:
    """The error box with the setting `values` ({filter_param.NAME: value}) folded into the fixed filter_params."""
    study = tune.study
    fixed = fold_values(study.fixed, values)
    return dataclasses.replace(study, fixed=fixed)


def typed_setting(params: dict[str, Any], box: Sequence[Distribution]) -> dict[str, Any]:
    """A setting the outer search asked for, as it runs: each continuous value to `DIGITS` significant digits
    (module docstring), within its box; a choice as it is."""
    out = {}
    for d in box:
        value = params[d.parameter]
        out[d.parameter] = value if d.kind == "choice" else min(max(float(f"{value:.{DIGITS}g}"), d.low), d.high)
    return out


def told_value(record: dict[str, Any]) -> float | None:
    """The value the outer search minimises for an evaluation's `record` (module docstring); None: failed."""
    if record["safe"]:
        return -record["value"]
    if record["value"] is None and not record["faulted"] and record["worst_rho"] is None:
        return None
    rho = record["worst_rho"]
    violation = RHO_CAP if rho is None else min(max(-rho, 0.0), RHO_CAP)
    return UNSAFE_OFFSET + violation


def nominal_value(row: dict[str, Any], run_dir: Path, objective: str) -> float | None:
    """The objective of a clean nominal run (module docstring); None when it has none."""
    if not clean(row):
        return None
    if objective == DEFAULT_OBJECTIVE:
        return steady_force_of_folder(run_dir)
    if objective not in row:  # a misspelt metric: no setting would ever have a value
        numeric = sorted(k for k, v in row.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
                         and not k.startswith("param.") and k not in ("sample", "draw", "scenario_seed"))
        raise ValueError(f"tune.objective {objective!r}: the nominal run's row has no such column; numeric columns: "
                         f"{', '.join(numeric)} (or {DEFAULT_OBJECTIVE})")
    value = row.get(objective)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def evaluation_record(e: int, params: dict[str, Any], row: dict[str, Any], value: float | None,
                      inner_rows: list[dict[str, Any]] | None, inner_budget: int,
                      screen_rows: list[dict[str, Any]] | None = None, replays: int = 0) -> dict[str, Any]:
    """Evaluation e's entry of tune.json from its nominal `row` and `value`, its inner search's rows on the study's
    scenario (`inner_rows`: the evaluations, or a screened search's confirmations; None: not run, the nominal run
    already failed the setting), a screened search's rows on the cheap scenario (`screen_rows`; None: not
    screened) and its replays of the worst on the study's scenario (`replays`) (module docstring)."""
    rows = [row, *(inner_rows or [])]  # the study scenario's verdicts
    cheap = screen_rows or []
    n_faulted = sum(1 for r in rows + cheap if faulted(r))
    failed = sum(1 for r in rows + cheap if not clean(r) and not faulted(r))
    rhos = [r["rho_min_meas"] for r in rows if clean(r) and r.get("rho_min_meas") is not None]
    worst = None if n_faulted or not rhos else float(min(rhos))
    first = next((i for i, r in enumerate(rows) if violated(r)), None)
    if screen_rows is None:
        complete = inner_rows is not None and len(inner_rows) == inner_budget
    else:  # the whole screen, and at least one confirmation on the study's scenario
        complete = inner_rows is not None and len(inner_rows) >= 1 and len(screen_rows) == inner_budget
    safe = value is not None and complete and first is None and failed == 0 and n_faulted == 0
    fault = next((fault_of(r) for r in rows + cheap if faulted(r)), None)
    record = {"evaluation": e + 1, "params": {k.removeprefix(FILTER_PARAM_PREFIX): v for k, v in params.items()},
              "value": value, "safe": bool(safe), "worst_rho": worst, "nominal_status": row.get("status"),
              "inner_evaluations": len(inner_rows or []), "first_violation": first,  # 0: the nominal run, k: inner k
              "faulted": n_faulted, "failed": failed, "fault": fault,
              "error": next((str(r.get("error") or "").splitlines()[0] for r in rows + cheap
                             if r.get("status") == "error"), None),
              "expensive_runs": len(rows) + replays}
    if screen_rows is not None:
        cheap_rhos = [r["rho_min_meas"] for r in cheap if clean(r) and r.get("rho_min_meas") is not None]
        record["screen"] = {"evaluations": len(cheap), "violations": sum(1 for r in cheap if violated(r)),
                            "first_violation": next((i + 1 for i, r in enumerate(cheap) if violated(r)), None),
                            "faulted": sum(1 for r in cheap if faulted(r)),
                            "worst_rho": float(min(cheap_rhos)) if cheap_rhos else None}
    return record


def filter_spec(tune: TuneFile, params: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """The filter spec and its parameters ({name: value}, the fixed ones and the setting's) of a setting."""
    fixed = inner_study(tune, {FILTER_PARAM_PREFIX + k: v for k, v in params.items()}).fixed
    return str(fixed["filter"]), dict(read_params(fixed.get(FILTER_PARAMS)))


def command_text(spec: str, params: dict[str, Any]) -> str:
    """The setting as a user types it: `--filter SPEC --filter-param NAME=VALUE …` (bools as true/false)."""
    text = " ".join(f"--filter-param {k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in params.items())
    return f"--filter {spec}" + (f" {text}" if text else "")


def tune(
    tune_file: TuneFile,
    out_dir: str | Path,
    *,
    budget: int,
    inner_budget: int = DEFAULT_INNER_BUDGET,
    sampler: str = "tpe",
    population: int = DEFAULT_POPULATION,
    seed: int | None = None,
    resume: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    storage: str | None = None,
    screen: str | None = None,
    confirm: int | None = None,
    progress: bool | Progress = True,
) -> dict[str, Any]:
    """Search the tuning box for the safe setting with the most objective (module docstring); returns tune.json.

    `budget`: outer evaluations (settings); `inner_budget`: falsification evaluations per setting; `seed`: of the
    outer sampler (default the study's; the inner searches use the study's seed, the same for every setting);
    `workers`, `scheduler`, `client`: as `run_study`; `storage`: of the outer and the inner searches' trials, as
    `falsify`'s ("journal", a URL, None: SQLite in the folders); `screen`, `confirm`: each inner search screened on
    that cheaper scenario with `confirm` confirmations (default its population) on the study's (module docstring:
    Screened inner searches); `progress`: the line (one per evaluation, with its
    ETA), or the `Progress` to report into."""
    # optuna and the search machinery: +1.4 s to import (falsify; screen +0.96 s, execute +0.25 s), when the
    # search starts, so that `study tune` reads and checks its file and says so first
    import optuna
    from optuna.trial import TrialState

    from softcbf.study.execute import connect_scheduler, run_study
    from softcbf.study.falsify import (Candidate, CandidateStudy, asked_trials, default_population, make_sampler,
                                       open_search, retire_interrupted, search_space)
    from softcbf.study.screen import screened_study

    for name, value, low in (("budget", budget, 1), ("inner_budget", inner_budget, 1), ("population", population, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    if sampler == "cmaes" and population < 4:
        raise ValueError(f"population must be >= 4 with sampler cmaes, got {population}; or use sampler tpe")
    if workers is not None and (scheduler is not None or client is not None):
        raise ValueError("give local workers or a Dask scheduler, not both")
    seed = tune_file.study.seed if seed is None else seed
    study = tune_file.study
    if screen is None:
        if confirm is not None:
            raise ValueError("confirm counts the confirmations of a screened inner search; give screen with it")
    else:
        screened_study(study, screen)  # the error box on the cheap scenario, or one line naming what does not map
        confirm = default_population(study) if confirm is None else confirm
        if isinstance(confirm, bool) or not isinstance(confirm, int) or confirm < 1:
            raise ValueError(f"confirm must be an integer >= 1 (evaluations on {study.scenario}), got {confirm!r}")
    nominal = nominal_study(tune_file)
    space = search_space(nominal)
    root = Path(out_dir)
    settings = {"objective": tune_file.objective, "inner_objective": study.objective, "sampler": sampler,
                "seed": seed, "population": population, "inner_budget": inner_budget, "screen": screen,
                "confirm": confirm, "study": study.to_dict(),
                "tune": {d.parameter.removeprefix(FILTER_PARAM_PREFIX): d.to_dict() for d in tune_file.box}}
    stored = stored_search(root, TUNE_FILE, "tuning", settings, SETTINGS, resume)
    name = stored.get("optuna_study") or f"softcbf-tune-{study.name}-{uuid.uuid4().hex[:12]}"
    state: dict[str, Any] = {**settings, "budget": budget, "status": "running", "optuna_study": name,
                             "storage": storage_name(storage)}
    bar = progress if isinstance(progress, Progress) else Progress(f"tune {study.name}", budget, enabled=progress,
                                                                    unit="evaluations")
    own_client = connect_scheduler(scheduler) if scheduler is not None else None  # before the folder is made
    client = own_client if own_client is not None else client
    run = {"workers": workers, "client": client}
    records: dict[int, dict[str, Any]] = {}
    try:
        if not resume:
            root.mkdir(parents=True, exist_ok=True)
            write_json(root / TUNE_FILE, state)
        optuna.logging.set_verbosity(logging.WARNING)
        search = open_search(root, storage, name, make_sampler(sampler, seed, population), resume)
        trials, asked = asked_trials(search, space, root)
        if trials:  # a resumed search draws new random settings (`falsify.make_sampler`)
            search.sampler = make_sampler(sampler, seed, population, len(trials))
        numbers = [t.number for t in asked]
        retire_interrupted(search, trials, numbers)
        settings_of = [typed_setting(t.params, tune_file.box) for t in asked]
        pending = [e for e, t in enumerate(asked) if t.state == TrialState.RUNNING]
        for e, trial in enumerate(asked):  # told before: read back from the folders, never run again
            if trial.state != TrialState.RUNNING:
                records[e] = read_record(tune_file, root, e, settings_of[e], inner_budget)
        before = len(records)  # read back: the line counts this call's evaluations, so its ETA is theirs
        if before:
            bar = Progress(bar.label, max(1, budget - before), enabled=bar.enabled, unit="evaluations")
        bar.update(0, f"{progress_note(records)}; {before} evaluations stored" if before else progress_note(records))
        while True:
            if not pending:
                if len(settings_of) >= budget:
                    break
                for _ in range(min(population, budget - len(settings_of))):
                    trial = search.ask(space)
                    numbers.append(trial.number)
                    settings_of.append(typed_setting(trial.params, tune_file.box))
                    pending.append(len(settings_of) - 1)
            candidates = [Candidate({d.parameter: p[d.parameter] for d in nominal.vary}, nominal.tunings[0])
                          for p in settings_of]
            bar.update(len(records) - before, f"{progress_note(records)}; nominal runs of settings "
                                     f"{pending[0] + 1}-{pending[-1] + 1}")
            run_study(CandidateStudy.of(nominal, candidates), root / NOMINAL_DIR, resume=True,
                      samples=len(candidates), keep_runs=True, progress=False, **run)
            for e in pending:
                bar.update(len(records) - before, f"{progress_note(records)}; inner search of setting {e + 1}")
                records[e] = evaluate(tune_file, root, e, settings_of[e], inner_budget, run, storage, screen,
                                      confirm)
                value = told_value(records[e])
                if value is None:
                    search.tell(numbers[e], state=TrialState.FAIL)
                else:
                    search.tell(numbers[e], value)
                bar.update(len(records) - before, progress_note(records))
            pending = []
        bar.close(len(records) - before)
    finally:
        if own_client is not None:
            own_client.close()
    ordered = [records[e] for e in sorted(records)]
    best = max((r for r in ordered if r["safe"]), key=lambda r: r["value"], default=None)
    state.update(status="done", evaluations=ordered, safe=sum(r["safe"] for r in ordered),
                 expensive_runs=sum(r["expensive_runs"] for r in ordered),
                 best=None if best is None else winner(tune_file, root, best))
    plot_front(ordered, root / FIGURE_FILE, tune_file.objective, best)
    write_json(root / TUNE_FILE, state)
    return state


def inner_dir(root: Path, e: int) -> Path:
    return root / INNER_DIR / f"{e + 1:04d}"


def nominal_of(tune_file: TuneFile, root: Path, e: int) -> tuple[dict[str, Any], float | None]:
    """Evaluation e's stored nominal row and its objective value."""
    from softcbf.study.falsify import stored_rows  # loaded by `tune` (optuna, +1.4 s at this module's import)

    store = StudyStore.open(root / NOMINAL_DIR)
    row = stored_rows(root / NOMINAL_DIR, range(e, e + 1))[e]
    return row, nominal_value(row, store.run_dir(e), tune_file.objective)


def evaluate(tune_file: TuneFile, root: Path, e: int, params: dict[str, Any], inner_budget: int,
             run: dict[str, Any], storage: str | None = None, screen: str | None = None,
             confirm: int | None = None) -> dict[str, Any]:
    """Evaluation e (its nominal run stored): its inner search unless the nominal run already failed the
    setting (module docstring), run or resumed into DIR/inner/EEEE on `storage` (`falsify`'s), screened on
    scenario `screen` with `confirm` confirmations where given (`screen.falsify_screened`); its record."""
    from softcbf.study.falsify import falsify  # loaded by `tune` (optuna, +1.4 s at this module's import)
    from softcbf.study.screen import falsify_screened

    row, value = nominal_of(tune_file, root, e)
    folder = inner_dir(root, e)
    if value is not None and not violated(row):
        state = folder / FALSIFY_FILE
        done = state.is_file() and json.loads(state.read_text(encoding="utf-8")).get("status") == "done"
        if not done:
            if folder.exists() and not state.is_file():  # made, nothing stored yet: started again
                shutil.rmtree(folder)
            options = {"budget": inner_budget, "stop_on_violation": True, "resume": state.is_file(),
                       "storage": storage, "progress": False, **run}
            if screen is None:
                falsify(inner_study(tune_file, params), folder, baseline=0, **options)
            else:  # the whole screen; the confirmations stop at the first violation on the study's scenario
                falsify_screened(inner_study(tune_file, params), folder, screen=screen, confirm=confirm,
                                 stop_screen_on_violation=False, **options)
    return read_record(tune_file, root, e, params, inner_budget)


def read_record(tune_file: TuneFile, root: Path, e: int, params: dict[str, Any], inner_budget: int) -> dict[str, Any]:
    """Evaluation e's record from its stored nominal row and inner search (module docstring: resume)."""
    from softcbf.study.falsify import SEARCH_DIR, stored_rows  # as above: loaded by `tune`
    from softcbf.study.screen import SCREEN_DIR

    def rows_of(folder: Path, n: int) -> list[dict[str, Any]]:
        rows = stored_rows(folder / SEARCH_DIR, range(n))
        return [rows[i] for i in sorted(rows)]

    row, value = nominal_of(tune_file, root, e)
    folder = inner_dir(root, e)
    state = json.loads((folder / FALSIFY_FILE).read_text(encoding="utf-8")) if (folder / FALSIFY_FILE).is_file() \
        else {}
    if state.get("status") != "done":  # no inner search: the nominal run already failed the setting
        return evaluation_record(e, params, row, value, None, inner_budget)
    replays = int(state.get("worst") is not None)
    if "screen" not in state:
        return evaluation_record(e, params, row, value, rows_of(folder, inner_budget), inner_budget, replays=replays)
    return evaluation_record(e, params, row, value, rows_of(folder, state["evaluations"]), inner_budget,
                             rows_of(folder / SCREEN_DIR, state["screen"]["evaluations"]), replays)


def winner(tune_file: TuneFile, root: Path, best: dict[str, Any]) -> dict[str, Any]:
    """tune.json's best: the setting, its figures, the filter spec to type, DIR/best (its nominal run folder,
    replayable) and DIR/winner.json (its error box, for an independent falsification)."""
    e = best["evaluation"] - 1
    spec, params = filter_spec(tune_file, best["params"])
    target = root / BEST_DIR
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(StudyStore.open(root / NOMINAL_DIR).run_dir(e), target)
    check = inner_study(tune_file, {FILTER_PARAM_PREFIX + k: v for k, v in best["params"].items()})
    write_json(root / WINNER_FILE, {**check.to_dict(), "name": f"{tune_file.study.name}_winner"})
    return {"evaluation": best["evaluation"], "params": best["params"], "value": best["value"],
            "worst_rho": best["worst_rho"], "filter": spec, "filter_params": params,
            "command": command_text(spec, params),
            "replay": f"softcbf run --config {BEST_DIR}/config.json",
            "check": f"softcbf study falsify {WINNER_FILE} --budget 300 --baseline 0 --seed 1 --out check"}


def progress_note(records: dict[int, dict[str, Any]]) -> str:
    """The progress line's note: settings found safe, the best safe objective so far."""
    safe = [r for r in records.values() if r["safe"]]
    best = max((r["value"] for r in safe), default=None)
    return f"{len(safe)} safe" + (f", best safe {significant(best)}" if best is not None else "")


def plot_front(records: list[dict[str, Any]], path: Path, objective: str, best: dict[str, Any] | None) -> Path:
    """The objective of every evaluated setting against the worst ρ_meas found for it (module docstring): safe,
    unsafe and faulted settings apart, the winner marked, the legend outside the axes."""
    import matplotlib  # +0.5 s, and pyplot +1.7 s, to import: only for this plot

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    label = ("delivered force at the nominal plate [N]" if objective == DEFAULT_OBJECTIVE
             else f"{objective} at the nominal point")
    finite = [r["worst_rho"] for r in records if r["worst_rho"] is not None]
    fault_x = (min(finite) if finite else 0.0) - 0.1 * (max(finite) - min(finite) if len(finite) > 1 else 1.0)
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    groups = (("safe (no violation found)", lambda r: r["safe"], "o", BLUISH_GREEN),
              ("unsafe (a violation found)", lambda r: not r["safe"] and r["worst_rho"] is not None, "x", ORANGE),
              ("filter fault (ρ = −∞, drawn at the left)", lambda r: r["faulted"] > 0, "v", LIMIT_COLOR))
    for name, keep, marker, color in groups:
        chosen = [r for r in records if keep(r) and r["value"] is not None]
        if chosen:
            x = [fault_x if r["faulted"] else r["worst_rho"] for r in chosen]
            ax.scatter(x, [r["value"] for r in chosen], marker=marker, color=color, label=name, zorder=3)
    if best is not None:
        ax.scatter([best["worst_rho"]], [best["value"]], marker="*", s=220, facecolor="none", edgecolor="black",
                   label=f"best safe setting (evaluation {best['evaluation']})", zorder=4)
    ax.axvline(0.0, color=NEUTRAL_COLOR, linestyle="--", label="ρ = 0 (force = F_max)")
    ax.set_xlabel("worst ρ_meas found (nominal run and inner search) [-]")
    ax.set_ylabel(label)
    ax.set_title(f"{len(records)} settings: objective against the worst margin found")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
