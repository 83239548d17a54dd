"""Command line of robustness studies: `python -m softcbf.study run|falsify|report`.

    python -m softcbf.study run STUDY_FILE --out DIR [--workers N | --scheduler tcp://host:8786]
                                   [--resume] [--samples N] [--batch-size N] [--keep-runs] [--no-progress] [--set KEY=VALUE ...]
                                   [--until-bound 0.01]
    python -m softcbf.study falsify STUDY_FILE --out DIR [--budget 100] [--sampler cmaes|tpe] [--population N]
                                   [--initial vertices|random]
                                   [--seed S] [--baseline N] [--stop-on-violation] [--storage journal|sqlite|URL]
                                   [--workers N | --scheduler tcp://host:8786] [--resume] [--batch-size N] [--set ...]
                                   [--screen SCENARIO [--confirm K]] [--seeds N]
    python -m softcbf.study tune TUNE_FILE --out DIR [--budget 20] [--inner-budget 40] [--sampler tpe|cmaes]
                                   [--population 4] [--seed S] [--workers N | --scheduler tcp://host:8786] [--resume]
                                   [--storage journal|sqlite|URL] [--screen SCENARIO [--confirm K]] [--set ...]
    python -m softcbf.study report DIR [--level 0.05] [--bins 6] [--figure-format png|svg|pdf] [--dpi 110]

`run` runs the study file's samples (all, or the first N with --samples; sample order is
draw-major, so N = draws × tunings runs whole draws) into DIR, one Parquet part per sample;
`--batch-size N` runs up to N samples that share a model structure in one batched
closed loop (default 128 where the scenario has a batch form, e.g. mujoco_contact;
1: every sample alone, with all of the scenario's figures; docs/studies.md#batches);
`--resume` continues a study folder; Ctrl-C stops it and leaves every finished sample
stored. It ends with the report. `--set fixed.duration=10` (repeatable) sets a dotted key
of the study file (`softcbf.study.definition.load_study`) without copying the file.
`--until-bound P` is the sequential stop (`softcbf.study.sequential`): it draws in chunks
until every tuning's one-sided 95 % Clopper–Pearson bound on P(violation) is below P or
that tuning has violated (at most the file's draws). A sample whose filter faulted counts as a
violation everywhere (a fault is never a pass); the lines printed say how many faulted.
`falsify` searches the file's [vary] box for the minimum of its objective (default
ρ_min_meas) with optuna's CMA-ES or TPE, beside a uniform baseline of the same budget, into
DIR (`softcbf.study.falsify`: DIR/falsify.json, DIR/worst/, …); it ends with the report.
`--screen SCENARIO` searches on a cheaper scenario and confirms its worst K (`--confirm`) on the
file's (`softcbf.study.screen`); `--seeds N` repeats the search per filter over N seeds and
reports the falsification rate and evaluations to the first counterexample (`softcbf.study.campaign`).
`tune` searches a tune file's tuning box (its [tune] table over the filter's parameters) for the setting with the
most force at the nominal point that an inner falsification of its [vary] box cannot break
(`softcbf.study.tune`: DIR/tune.json, DIR/tune.png, DIR/best/, DIR/winner.json); its `--screen SCENARIO
[--confirm K]` screens every inner falsification as falsify's does.
Both keep their optuna trials in DIR (`--storage`, `softcbf.study.store.search_storage`): optuna's journal
DIR/optuna.journal, the default with --scheduler (a folder on a disk that machines share, where SQLite's locks
are not to be trusted), or SQLite DIR/optuna.db, the default on the local pool; --resume uses the kind the
folder holds (a folder without optuna.journal resumes on SQLite).
`report` (re)writes DIR/report.md and DIR/plots/ (of a study folder or a falsification folder).
`softcbf study …` is the same (`add_arguments` and `run_command`, mounted by softcbf.cli).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from softcbf.shipped import resolve as shipped_or_file
from softcbf.study.definition import load_study
from softcbf_mj.outputs.progress import Progress, significant
from softcbf_mj.outputs.runio import OutputDirError

# The study machinery (pyarrow, Dask, matplotlib) is imported by the handlers, so that
# `softcbf --version`, `list` and usage errors do not pay for it.

STORAGE_HELP = ("where optuna keeps the search's trials: journal (--out/optuna.journal, the default with --scheduler: "
                "safe on a shared disk), sqlite (--out/optuna.db, the default on the local pool) or a database URL "
                "such as postgresql://host/db; --resume: the kind the folder holds")


def _run(args: argparse.Namespace) -> int:
    from softcbf.study.execute import run_study  # +0.28 s to import: `study run` only

    def body() -> None:
        study = load_study(shipped_or_file("study", args.study_file), args.set)
        options = {"workers": args.workers, "scheduler": args.scheduler, "resume": args.resume,
                   "keep_runs": args.keep_runs, "progress": not args.no_progress, "batch_size": args.batch_size}
        if args.until_bound is not None:
            from softcbf.study.sequential import run_until_bound  # +0.41 s to import: --until-bound only

            if args.samples is not None:
                raise ValueError("--until-bound chooses the number of samples itself; give it or --samples, not both")
            sequential = run_until_bound(study, args.out, args.until_bound, **options)
            outcome = sequential.outcome
            for tuning, p in sequential.violation.items():
                faults = sequential.faulted[tuning]
                verdict = (f"P(violation) < {p.upper:.4g} at 95 % (one-sided Clopper–Pearson)"
                           if sequential.bounded[tuning] else
                           "violated: no bound below the target" if p.k else
                           f"not bounded: the study's draws ran out at P < {p.upper:.4g}")
                print(f"{tuning}: {p.k}/{p.n} violations ({faults} of them filter faults); {verdict}")
        else:
            outcome = run_study(study, args.out, samples=args.samples, **options)
        print(f"study {study.name}: ran {outcome.ran} samples ({outcome.failed} failed, {outcome.faulted} filter "
              f"faults, counted as violations), {outcome.skipped} already "
              f"stored" + (f", {outcome.corrupted} corrupted part(s) run again" if outcome.corrupted else "")
              + f", {outcome.wall_s:.1f} s on {outcome.workers} {outcome.backend} worker(s); folder {args.out}")
        from softcbf.study.report import write_report  # pandas, matplotlib: +1.6 s, after the run, so its first line is early

        print(f"report: {write_report(args.out)}")

    return _resumable(body, args.out, "samples")


def _resumable(body, out: Path, stored: str) -> int:
    """`body()`'s exit code as a resumable command's: 0, 2 after "error: MESSAGE" for a bad input
    or folder, 130 after saying that the finished `stored` are in `out` for Ctrl-C."""
    try:
        body()
    except (ValueError, OutputDirError, ConnectionError) as exc:  # ConnectionError: e.g. a lost Dask scheduler
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished {stored} are stored in {out}; continue with --resume", file=sys.stderr)
        return 130
    return 0


def _falsify(args: argparse.Namespace) -> int:

    def shown(value: Any) -> str:
        """A figure or parameter to `significant` digits (a tuning, a flag: as it is)."""
        return significant(value) if isinstance(value, float) else str(value)

    def body() -> None:
        study = load_study(shipped_or_file("study", args.study_file), args.set)
        bar = Progress(f"falsify {study.name}", max(1, args.budget), enabled=not args.no_progress, unit="evaluations")
        if args.budget >= 1 and not args.resume:  # a resume's first line follows its checks (`falsify`)
            bar.update(0, "starting the search")
        if args.confirm is not None and args.screen is None:
            raise ValueError("--confirm counts the evaluations that confirm a screen; give --screen SCENARIO with it")
        if args.seeds is not None:
            _falsify_seeds(study, args, bar)
            return
        # optuna: falsify +0.74 s, screen +1.0 s (with falsify), store +0.22 s to import, after the first line
        from softcbf.study.falsify import falsify
        from softcbf.study.screen import SCREEN_DIR
        from softcbf.study.store import search_storage

        searched = Path(args.out) / SCREEN_DIR if args.screen is not None else Path(args.out)  # optuna's folder
        storage = search_storage(searched, args.storage, args.resume, on_dask=args.scheduler is not None)
        options = {"budget": args.budget, "sampler": args.sampler, "population": args.population,
                   "initial": args.initial, "seed": args.seed, "stop_on_violation": args.stop_on_violation,
                   "storage": storage, "resume": args.resume, "workers": args.workers,
                   "scheduler": args.scheduler, "batch_size": args.batch_size, "progress": bar}
        if args.screen is not None:
            from softcbf.study.screen import falsify_screened  # loaded above (SCREEN_DIR)
            if args.baseline:
                raise ValueError("--baseline draws on the study's own scenario; a screened search (--screen) has none")
            result = falsify_screened(study, args.out, screen=args.screen, confirm=args.confirm, **options)
        else:
            result = falsify(study, args.out, baseline=args.baseline, **options)
        best, base = result["best"], result["random_baseline"]
        found = (f"a filter fault ({best['fault']['type']} in the {best['fault']['where']}: {best['fault']['message']})"
                 if best["fault"] else f"{result['objective']} = {shown(best['value'])}")
        params = ", ".join(f"{k} = {shown(v)}" for k, v in (best["params"] or {}).items())
        print(f"falsify {study.name}: best {found} at evaluation "
              f"{best['evaluation']} of {result['evaluations']} ({best['tuning']}; {params}; "
              f"{result['faulted']} faulted); first violation: "
              f"{result['first_violation'] or 'none'}; {baseline_text(base, shown)}; folder {args.out}")
        if args.screen is not None:
            screen = result["screen"]
            print(f"screened on {args.screen}: {screen['evaluations']} evaluations (first violation there: "
                  f"{screen['first_violation'] or 'none'}); confirmed {len(result['confirmed'])} on {study.scenario}; "
                  f"expensive evaluations spent: {result['expensive_evaluations']} (the worst's replay included)")
        from softcbf.study.report import write_report  # pandas, matplotlib: +1.6 s, after the search (its first line early)

        print(f"report: {write_report(args.out)}")

    return _resumable(body, args.out, "evaluations")


def baseline_text(base: dict[str, Any], shown: Any = str) -> str:
    """The uniform baseline's part of falsify's printed summary (`base`: falsify.json's random_baseline;
    `shown` formats a figure): "no uniform baseline" when it ran no draw (--baseline 0, a screened search)."""
    if not base["evaluations"]:
        return "no uniform baseline"
    best = "a filter fault" if base["fault"] else ("no value (every draw failed)" if base["best"] is None
                                                    else shown(base["best"]))
    return (f"uniform baseline: best {best} in {base['evaluations']} ({base['faulted']} faulted), "
            f"first violation: {base['first_violation'] or 'none'}")


def _falsify_seeds(study: Any, args: argparse.Namespace, bar: Any) -> None:
    """`falsify --seeds N`: the campaign of `softcbf.study.campaign`, its table printed and in the report."""
    from softcbf.study.campaign import falsify_seeds  # +0.95 s to import (optuna): --seeds only

    if args.baseline or args.storage:
        raise ValueError("--seeds runs its falsifications without --baseline and in SQLite files of their own "
                         "(no --storage)")
    bar.close(0)
    state = falsify_seeds(study, args.out, seeds=args.seeds, budget=args.budget, seed=args.seed, screen=args.screen,
                          confirm=args.confirm, sampler=args.sampler, population=args.population,
                          initial=args.initial, stop_on_violation=args.stop_on_violation, resume=args.resume,
                          workers=args.workers, scheduler=args.scheduler, batch_size=args.batch_size,
                          progress=not args.no_progress)
    for row in state["table"]:
        first = row["first_counterexample"]
        print(f"{row['filter']} on {row['box']}: falsified {row['falsified']} of {row['runs']} seeds"
              + (f", evaluations to the first counterexample median {first['median']:g} "
                 f"[{first['min']}, {first['max']}]" if first else ""))
    from softcbf.study.report import write_report  # pandas, matplotlib: +1.6 s, after the searches

    print(f"report: {write_report(args.out)}")


def _tune(args: argparse.Namespace) -> int:
    from softcbf.study.tune import load_tune, tune  # +0.19 s to import: `study tune` only (its optuna when it starts)

    def body() -> None:
        tune_file = load_tune(args.tune_file, args.set)
        bar = Progress(f"tune {tune_file.study.name}", max(1, args.budget), enabled=not args.no_progress,
                       unit="evaluations")
        bar.update(0, "starting the search")
        if args.confirm is not None and args.screen is None:
            raise ValueError("--confirm counts the confirmations of a screened inner search; give --screen SCENARIO "
                             "with it")
        from softcbf.study.store import search_storage  # +0.22 s to import (pyarrow): after the first line

        storage = search_storage(args.out, args.storage, args.resume, on_dask=args.scheduler is not None)
        result = tune(tune_file, args.out, budget=args.budget, inner_budget=args.inner_budget, sampler=args.sampler,
                      population=args.population, seed=args.seed, resume=args.resume, workers=args.workers,
                      scheduler=args.scheduler, storage=storage, screen=args.screen, confirm=args.confirm,
                      progress=bar)
        best = result["best"]
        scenario = tune_file.study.scenario
        inner = (f"no violation in {args.inner_budget} inner evaluations" if args.screen is None else
                 f"no violation on {scenario} among the confirmations of {args.inner_budget} inner evaluations on "
                 f"{args.screen}")
        print(f"tune {tune_file.study.name}: {result['safe']} of {len(result['evaluations'])} settings safe "
              f"({inner}); runs on {scenario}: {result['expensive_runs']}; folder {args.out}")
        if best is None:
            failed = [r for r in result["evaluations"] if r["error"]]
            print("no safe setting found" + (f" ({len(failed)} settings' runs failed outside the filter, the first: "
                                             f"{failed[0]['error']})" if failed else "")
                  + "; widen the tuning box towards more cautious settings")
            return
        print(f"best safe setting: evaluation {best['evaluation']}, {result['objective']} = {significant(best['value'])}, "
              f"worst rho_min_meas found {significant(best['worst_rho'])}")
        print(f"as a filter: {best['command']}")
        print(f"replay: {best['replay']} (in {args.out}); independent check: {best['check']}")

    return _resumable(body, args.out, "evaluations")


def _report(args: argparse.Namespace) -> int:
    print(f"study report: rebuilding {args.dir}'s tables and plots", flush=True)
    from softcbf.study.report import write_report  # pandas, matplotlib: +1.6 s, after the command's first line

    try:
        path = write_report(args.dir, level=args.level, bins=args.bins, figure_format=args.figure_format, dpi=args.dpi)
    except (ValueError, OutputDirError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(path.read_text(encoding="utf-8"))
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the `run`, `falsify`, `tune` and `report` sub-commands on `parser` (`softcbf study`, `python -m softcbf.study`)."""
    commands = parser.add_subparsers(dest="study_command", required=True)
    run = commands.add_parser("run", help="run a study file into a study folder")
    run.add_argument("study_file", type=Path, help="study definition (TOML) or a shipped study's name, e.g. studies/paper_tunings_plate_errors.toml, mismatch_box_contact")
    run.add_argument("--out", type=Path, required=True, help="study folder (refused if not empty, unless --resume)")
    backend = run.add_mutually_exclusive_group()
    backend.add_argument("--workers", type=int, help="local worker processes (default: every core)")
    backend.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786 (instead of the local pool)")
    run.add_argument("--resume", action="store_true", help="continue the study stored in --out")
    run.add_argument("--samples", type=int, help="run only samples 0..N-1 (draw-major); --resume runs the rest later")
    run.add_argument("--batch-size", type=int, help="samples per batched closed loop (default 128 where the scenario "
                                                    "has a batch form; 1: every sample alone)")
    run.add_argument("--keep-runs", action="store_true", help="keep every sample's scenario outputs in DIR/runs/")
    run.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="set a dotted key of the study file, e.g. fixed.duration=10 "
                          "(TOML value; repeatable; --resume needs the same)")
    run.add_argument("--until-bound", type=_probability, metavar="P",
                     help="sequential stop: draw until every tuning's one-sided 95 %% Clopper–Pearson bound on "
                          "P(violation) is below P, or it violated (at most the file's draws)")
    run.set_defaults(study_handler=_run)
    falsify = commands.add_parser("falsify", help="search a study file's [vary] box for its worst case")
    falsify.add_argument("study_file", type=Path, help="study definition (TOML) or a shipped study's name, e.g. studies/paper_low_plate_corner.toml, mismatch_box_contact")
    falsify.add_argument("--out", type=Path, required=True, help="falsification folder (refused if not empty, unless --resume)")
    falsify.add_argument("--budget", type=int, default=100, help="evaluations of the search (default 100)")
    falsify.add_argument("--sampler", choices=("cmaes", "tpe"), default="cmaes", help="optuna sampler (default cmaes)")
    falsify.add_argument("--population", type=int, help="candidates per generation (default 4 + 3 ln d, CMA-ES's)")
    falsify.add_argument("--initial", choices=("vertices", "random"), default="vertices",
                         help="generation 0: the box's vertices (default; all 2^d when they fit in the population) "
                              "or the sampler's random start")
    falsify.add_argument("--seed", type=int, help="seed of the sampler, the scenario seeds and the baseline "
                                                  "(default the study's)")
    falsify.add_argument("--baseline", type=int, help="uniform draws of the box beside the search (default --budget; 0: none)")
    falsify.add_argument("--stop-on-violation", action="store_true",
                         help="stop the search and the baseline at their first violation (rho_min_meas < 0)")
    falsify.add_argument("--storage", metavar="journal|sqlite|URL", help=STORAGE_HELP)
    backend = falsify.add_mutually_exclusive_group()
    backend.add_argument("--workers", type=int, help="local worker processes (default: every core)")
    backend.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786 (instead of the local pool)")
    falsify.add_argument("--resume", action="store_true", help="continue the falsification stored in --out")
    falsify.add_argument("--batch-size", type=int, help="samples per batched closed loop (default: a generation "
                                                        "shared out over the workers)")
    falsify.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    falsify.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                         help="set a dotted key of the study file, e.g. vary.plate_stiffness.high=12 (repeatable)")
    falsify.add_argument("--screen", metavar="SCENARIO",
                         help="multi-fidelity: search on this cheaper scenario (e.g. pcc_contact, the PCC plant with "
                              "mujoco_contact's errors), then confirm its worst candidates on the file's scenario")
    falsify.add_argument("--confirm", type=int, metavar="K",
                         help="with --screen: the most candidates confirmed on the file's scenario (default the "
                              "population)")
    falsify.add_argument("--seeds", type=int, metavar="N",
                         help="repeat the search per filter over N seeds (from --seed) and report the falsification "
                              "rate and evaluations to the first counterexample (ARCH-COMP)")
    falsify.set_defaults(study_handler=_falsify)
    tune = commands.add_parser("tune", help="search a filter's parameters for the most force that stays safe over "
                                            "an error box")
    tune.add_argument("tune_file", type=Path, help="tune definition (TOML: a study file with a [tune] table), e.g. "
                                                   "studies/tune_cerg_box.toml")
    tune.add_argument("--out", type=Path, required=True, help="tune folder (refused if not empty, unless --resume)")
    tune.add_argument("--budget", type=int, default=20, help="settings of the filter to evaluate (default 20)")
    tune.add_argument("--inner-budget", type=int, default=40,
                      help="falsification evaluations of the error box per setting (default 40)")
    tune.add_argument("--sampler", choices=("tpe", "cmaes"), default="tpe", help="outer optuna sampler (default tpe)")
    tune.add_argument("--population", type=int, default=4, help="settings per outer generation (default 4)")
    tune.add_argument("--seed", type=int, help="seed of the outer sampler (default the file's)")
    backend = tune.add_mutually_exclusive_group()
    backend.add_argument("--workers", type=int, help="local worker processes (default: every core)")
    backend.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786 (instead of the local pool)")
    tune.add_argument("--resume", action="store_true", help="continue the tuning stored in --out")
    tune.add_argument("--storage", metavar="journal|sqlite|URL", help=STORAGE_HELP)
    tune.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    tune.add_argument("--screen", metavar="SCENARIO",
                      help="multi-fidelity inner searches: each setting's error box searched on this cheaper scenario "
                           "(e.g. pcc_contact), its worst candidates confirmed on the file's scenario")
    tune.add_argument("--confirm", type=int, metavar="K",
                      help="with --screen: the most candidates of a setting confirmed on the file's scenario (default "
                           "the inner population)")
    tune.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                      help="set a dotted key of the tune file, e.g. tune.gain_lo_ratio.low=0.8 (repeatable)")
    tune.set_defaults(study_handler=_tune)
    report = commands.add_parser("report", help="write report.md and plots/ for a study or falsification folder")
    report.add_argument("dir", type=Path, help="study folder, or a falsification folder (study falsify)")
    report.add_argument("--level", type=float, default=0.05, help="violation probability to locate (default 0.05)")
    report.add_argument("--bins", type=int, default=6, help="bins per varied parameter (default 6)")
    report.add_argument("--figure-format", choices=("png", "svg", "pdf"), default="png", help="plot file format (default png)")
    report.add_argument("--dpi", type=float, default=110.0, help="raster resolution of the plots (default 110)")
    report.set_defaults(study_handler=_report)


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must lie in (0, 1), got {text}")
    return value


def run_command(args: argparse.Namespace, extra: list[str]) -> int:
    """Handler of `softcbf study`: runs the chosen sub-command; returns the exit code."""
    return args.study_handler(args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softcbf.study", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    return run_command(parser.parse_args(argv), [])
