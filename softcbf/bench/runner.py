"""Running the bench: every selected (filter, case) pair in order, then each filter's worst case found.

`run_bench(out, filters, options, cases)` checks everything before the folder is touched (the case names,
the options, every filter's parameters in every case, which filter cannot be built on a case's arm), takes
the bench folder (softcbf.bench.folder), runs each pair that is selected, not skipped and not kept by
`--resume`, and writes the outputs after every case. `--cases` and `--filters` must name at least one case /
filter (an empty list is refused, not read as the whole battery).

The worst case found (`worst_case_searches`, beside the cases; softcbf.study.worst_found): per filter, a
falsification (`softcbf study falsify`'s search) over the standard mismatch box's physical errors on
mujoco_contact (studies/mismatch_box_contact.toml) with the filter's mujoco_contact parameters, for a fixed
budget of evaluations (`--falsify-budget N`; default `worst_found.BUDGET` = 36 for the whole battery,
`worst_found.QUICK_BUDGET` = 4 of 1 s with --quick, 0 with --cases; 0 turns it off). bench.json's "falsify"
names the box and the budget (and the rest of the search's settings); its "worst_found" holds one entry per
filter: rho_worst_found, the minimum ρ_min_meas over the evaluations, with that evaluation's parameters, and
`beyond_certified`, the box's coordinates wider than the filter certifies (softcbf.bench.certified). Its
folder: DIR/cases/<filter label>/worst_found/ (a falsification folder). A study (the mismatch case, the push
draws) or a falsification whose folder exists continues with `--resume` where it stopped (the study machinery
refuses a folder of another study definition); any other case runs again from scratch.

Progress: a line on stderr (softcbf_mj.outputs.progress) counts the cases to run now ("case k of n", the worst-case
searches included, kept rows not) with an ETA, refreshed while a case runs; each finished case's line on stdout
ends with the same "case k of n, eta …"; a worst case's line says where the box is wider than the filter
certifies (softcbf.bench.tables: `worst_case_text`).
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from controllers.registry import check_filter
from softcbf.bench.cases import (CASES, QUICK_DURATION_S, QUICK_SKIPPED, Case, RunOptions, arm_refusal, case_filter_params,
                                 contact_under_error, skip_key)
from softcbf.bench.certified import beyond_certified
from softcbf.bench.filters import FilterSpec
from softcbf.bench.folder import BENCH_FILE, discard, prepare_bench_dir, stored_results, write_outputs
from softcbf.bench.schema import RESULT_KEYS, WORST_KEYS
from softcbf.bench.tables import fault_text, worst_case_text
from softcbf.study.store import FALSIFY_FILE
from softcbf_mj.outputs.palette import plot_labels
from softcbf_mj.outputs.progress import Progress, duration_text
from softcbf_mj.outputs.runio import release_out_dir, safe_name

WORST_DIR = "worst_found"  # a filter's falsification folder: DIR/cases/<filter label>/worst_found


def run_bench(out: str | Path, filters: Sequence[FilterSpec], options: RunOptions = RunOptions(),
              cases: Sequence[str] | None = None) -> dict[str, Any]:
    """Run `filters` over the battery (or the named `cases`; None: all) into the bench folder `out`
    (`prepare_bench_dir`: a new or empty folder, or with `options.resume` / `options.overwrite` a
    bench folder; locked while the bench runs; a case's folder is replaced); write and return
    bench.json's content (updated after every case). Everything is checked before the folder is
    touched; a fresh bench that stops before its first row leaves nothing behind."""
    out = Path(out)
    names = [c.name for c in CASES]
    selected = checked_selection(filters, options, cases)
    skipped = {name: reason for name, reason in QUICK_SKIPPED.items() if options.quick and name in selected}
    for spec in filters:
        for case in CASES:
            reason = arm_refusal(spec, case) if case.name in selected and case.name not in skipped else None
            if reason is not None:
                skipped[skip_key(spec, case)] = reason
    searches = worst_case_searches(filters, options, cases is None)
    bench = {"battery": names, "quick": options.quick, "mismatch_draws": options.draws,
             "filters": [s.label for s in filters],
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
            run_cases(out, bench, filters, selected, skipped, done, options, bar)
            if searches:
                run_worst_found(out, bench, searches[1], worst_done, options, bar, len(to_run))
        bar.close()
    except BaseException:
        if fresh and not bench["results"] and not bench["worst_found"]:
            discard(out, created)
        raise
    finally:
        release_out_dir(out)
    return {**bench, "contact_under_error": contact_under_error(bench["results"])}


def checked_selection(filters: Sequence[FilterSpec], options: RunOptions, cases: Sequence[str] | None) -> list[str]:
    """The selected case names (`cases`; None: the whole battery) once the selection, the options and every
    filter's parameters in every case are valid; ValueError naming the first that is not (module docstring)."""
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
    return selected


def planned_cases(filters: Sequence[FilterSpec], selected: Sequence[str], skipped: Mapping[str, str],
                  done: Mapping[tuple[str, str], dict[str, Any]] | None = None) -> list[tuple[FilterSpec, Case]]:
    """The (filter, case) pairs the bench runs, in order: selected, not skipped and (with `done`) not kept."""
    return [(spec, case) for spec in filters for case in CASES
            if case.name in selected and case.name not in skipped and skip_key(spec, case) not in skipped
            and (done is None or (spec.label, case.name) not in done)]


def shown_labels(filters: Sequence[FilterSpec]) -> dict[str, str]:
    """{label: the label as progress lines and plots show it} (softcbf_mj.outputs.palette.plot_labels: short, distinct)."""
    labels = [s.label for s in filters]
    return dict(zip(labels, plot_labels(labels)))


def progress_text(bar: Progress, k: int) -> str:
    """"case k of n" and the ETA of the bench's progress `bar` (after k cases)."""
    eta = bar.eta_s()
    return f"case {k} of {bar.total}" + (f", eta {duration_text(eta)}" if eta is not None else "")


def run_cases(out: Path, bench: dict[str, Any], filters: Sequence[FilterSpec], selected: Sequence[str],
              skipped: Mapping[str, str], done: Mapping[tuple[str, str], dict[str, Any]], options: RunOptions,
              bar: Progress) -> None:
    """Run the planned (filter, case) pairs into `bench` (rows kept by --resume are taken as they are), writing
    the outputs after each; a line per case on stdout (a filter by its short label: `shown_labels`)."""
    shown = shown_labels(filters)
    n_run = 0
    for spec, case in planned_cases(filters, selected, skipped):
        if (spec.label, case.name) in done:
            bench["results"].append(done[spec.label, case.name])
            print(f"bench: {shown[spec.label]} x {case.name}: kept from {out / BENCH_FILE} (--resume)", flush=True)
            continue
        bar.update(n_run, f"case {n_run + 1} of {bar.total} running: {shown[spec.label]} x {case.name}")
        folder = out / "cases" / safe_name(spec.label) / case.name
        if folder.exists() and not (options.resume and case.resumable):
            shutil.rmtree(folder)
        start = time.perf_counter()
        row = {"filter": spec.label, "case": case.name, "force_asked_N": case.asked_N, "force_delivered_N": None,
               "force_delivered_ratio": None, "force_delivered_min_ratio": None, "force_delivered_median_ratio": None,
               **case.run(case, spec, folder, options),
               "wall_s": time.perf_counter() - start}
        bench["results"].append({k: row[k] for k in RESULT_KEYS})
        write_outputs(out, bench)
        verdict = (f"filter fault ({fault_text(row)}), no verdict" if row["fault"] else
                   f"rho_min_meas {row['rho_min_meas']:.4f}, t_violation {row['t_violation_s']:.3f} s")
        n_run += 1
        bar.update(n_run, f"case {n_run} of {bar.total} done: {shown[spec.label]} x {case.name}")
        print(f"bench: {shown[spec.label]} x {case.name}: {verdict}, {row['wall_s']:.1f} s ({progress_text(bar, n_run)})",
              flush=True)
    write_outputs(out, bench)


def worst_case_searches(filters: Sequence[FilterSpec], options: RunOptions, whole_battery: bool
                        ) -> tuple[dict[str, Any], dict[str, tuple[Any, list[str]]]] | None:
    """bench.json's "falsify" and {filter label: (its box study, the box's coordinates beyond what it certifies)} of
    the worst-case searches (module docstring), each filter with its parameters of the mujoco_contact case (checked
    here, before the bench starts); None when the budget is 0 (the default with --cases)."""
    from softcbf.study import worst_found  # optuna, SQLAlchemy: 0.64 s (-X importtime), after the bench's first line
    budget = options.falsify_budget
    if budget is None:
        budget = 0 if not whole_battery else worst_found.QUICK_BUDGET if options.quick else worst_found.BUDGET
    if budget == 0:
        return None
    duration = QUICK_DURATION_S if options.quick else None
    case = next(c for c in CASES if c.name == "mujoco_contact")
    studies = {}
    for spec in filters:
        params = case_filter_params(spec, case)
        study = worst_found.box_study(spec.name, params, duration=duration)
        studies[spec.label] = study, beyond_certified(spec.name, params, study)
    return worst_found.settings(budget, duration), studies


def run_worst_found(out: Path, bench: dict[str, Any], studies: Mapping[str, tuple[Any, list[str]]],
                    done: Mapping[str, dict[str, Any]], options: RunOptions, bar: Progress, k: int) -> None:
    """Run each filter's worst-case search (`worst_case_searches`) not kept by --resume into `bench`; a line each."""
    from softcbf.study import worst_found  # optuna, SQLAlchemy: 0.64 s (-X importtime), only where a search runs

    budget = bench["falsify"]["budget"]
    shown = dict(zip(studies, plot_labels(list(studies))))
    for label, (study, beyond) in studies.items():
        if label in done:
            bench["worst_found"].append(done[label])
            print(f"bench: {shown[label]} worst case found: kept from {out / BENCH_FILE} (--resume)", flush=True)
            continue
        folder = out / "cases" / safe_name(label) / WORST_DIR
        resume = options.resume and (folder / FALSIFY_FILE).is_file()
        if folder.exists() and not resume:
            shutil.rmtree(folder)
        bar.update(k, f"case {k + 1} of {bar.total} running: {shown[label]} worst-case search")
        entry = {**worst_found.worst_found(label, study, folder, budget, resume=resume, workers=options.workers,
                                           progress=not options.quick), "beyond_certified": beyond}
        k += 1
        bar.update(k, f"case {k} of {bar.total} done: {shown[label]} worst-case search")
        bench["worst_found"].append({key: entry[key] for key in WORST_KEYS})
        write_outputs(out, bench)
        found = worst_case_text(entry) if entry["fault"] else f"rho_min_meas {worst_case_text(entry)}"
        print(f"bench: {shown[label]} worst case found: {found} in {entry['evaluations']} "
              f"evaluations, {entry['wall_s']:.1f} s ({progress_text(bar, k)})", flush=True)
    write_outputs(out, bench)
