"""The bench folder on disk: DIR/bench.json, DIR/bench.md, DIR/plots/ and DIR/cases/, taken, resumed and written.

The bench folder (`prepare_bench_dir`, as `softcbf run`'s run folders, softcbf_mj.outputs.runio). DIR is new or empty,
or it is a bench folder (it holds bench.json) and `--resume` continues it or `--overwrite` replaces its
contents; any other non-empty folder (a user's, a run folder) is refused, also with `--overwrite`, as is
overwriting the working folder, one above it or home. DIR is locked while the bench runs (a second bench into
it is refused). A fresh bench writes bench.json with no rows first (so a bench that stops later can be
resumed) and, when it stops before its first row, removes what it wrote (`discard`).

Resume (`stored_results`): a (filter, case) whose row is in DIR/bench.json keeps it and is not run again (its
row must come from a run with the same quick flag, mismatch draws and "falsify" settings), as does a filter's
worst_found entry; bench.json is checked first (softcbf.bench.schema: `check_bench_json`), and a file that
fails is refused with one line naming the field, before anything runs.

Outputs (`write_outputs`, after every case): DIR/bench.json, DIR/bench.md (softcbf.bench.tables),
DIR/plots/bench.png and, with contact tasks, DIR/plots/force_budget.png (softcbf.bench.plots); each case's run
or study folder lies under DIR/cases/<filter label>/<case>/.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softcbf.bench.cases import RunOptions, contact_under_error
from softcbf.bench.schema import RESULT_KEYS, WORST_KEYS, check_bench_json
from softcbf.bench.tables import FORCE_PLOT_FILE, PLOT_FILE, table_markdown
from softcbf_mj.outputs.runio import RUN_MARKER, OutputDirError, prepare_out_dir, release_out_dir, remove_if_unused

BENCH_FILE, TABLE_FILE = "bench.json", "bench.md"


def is_bench_folder(path: str | Path) -> bool:
    """Whether `path` is a folder written by `softcbf bench`: it holds a bench.json."""
    return (Path(path) / BENCH_FILE).is_file()


def prepare_bench_dir(out: Path, options: RunOptions) -> Path:
    """Take the bench folder `out` and lock it for this process (softcbf_mj.outputs.runio, as `softcbf run`'s run folders:
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


def discard(out: Path, created: bool) -> None:
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


def write_outputs(out: Path, bench: Mapping[str, Any]) -> None:
    """DIR/bench.json, DIR/bench.md and DIR/plots/bench.png (and force_budget.png with contact tasks) from `bench`
    (its "contact_under_error" derived from its rows here: softcbf.bench.cases, `contact_under_error`)."""
    bench = {**bench, "contact_under_error": contact_under_error(bench["results"])}
    out.mkdir(parents=True, exist_ok=True)
    (out / BENCH_FILE).write_text(json.dumps(bench, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    (out / TABLE_FILE).write_text(table_markdown(bench), encoding="utf-8")
    if bench["results"]:
        from softcbf.bench.plots import write_force_plot, write_plot  # matplotlib, 0.55 s (-X importtime): from the first row on

        write_plot(out / PLOT_FILE, bench)
    if any(r["force_delivered_N"] is not None for r in bench["results"]):
        write_force_plot(out / FORCE_PLOT_FILE, bench)
