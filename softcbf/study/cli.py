"""Command line of robustness studies: `python -m softcbf.study run|report`.

    python -m softcbf.study run STUDY_FILE --out DIR [--workers N | --scheduler tcp://host:8786]
                                   [--resume] [--samples N] [--batch-size N] [--keep-runs] [--no-progress] [--set KEY=VALUE ...]
    python -m softcbf.study report DIR [--level 0.05] [--bins 6] [--figure-format png|svg|pdf] [--dpi 110]

`run` runs the study file's samples (all, or the first N with --samples; sample order is
draw-major, so N = draws × tunings runs whole draws) into DIR, one Parquet part per sample;
`--batch-size N` runs up to N samples that share a model structure in one batched
closed loop (default 128 where the scenario has a batch form, e.g. mujoco_contact;
1: every sample alone, with all of the scenario's figures; docs/studies.md#batches);
`--resume` continues a study folder; Ctrl-C stops it and leaves every finished sample
stored. It ends with the report. `--set fixed.duration=10` (repeatable) sets a dotted key
of the study file (`softcbf.study.definition.load_study`) without copying the file.
`report` (re)writes DIR/report.md and DIR/plots/.
`softcbf study …` is the same (`add_arguments` and `run_command`, mounted by softcbf.cli).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from softcbf_mj.runio import OutputDirError

# The study machinery (pyarrow, Dask, matplotlib) is imported by the handlers, so that
# `softcbf --version`, `list` and usage errors do not pay for it.


def _run(args: argparse.Namespace) -> int:
    from softcbf.study.definition import load_study
    from softcbf.study.execute import run_study
    from softcbf.study.report import write_report

    try:
        study = load_study(args.study_file, args.set)
        outcome = run_study(study, args.out, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                            samples=args.samples, keep_runs=args.keep_runs, progress=not args.no_progress,
                            batch_size=args.batch_size)
        print(f"study {study.name}: ran {outcome.ran} samples ({outcome.failed} failed), {outcome.skipped} already "
              f"stored" + (f", {outcome.corrupted} corrupted part(s) run again" if outcome.corrupted else "")
              + f", {outcome.wall_s:.1f} s on {outcome.workers} {outcome.backend} worker(s); folder {args.out}")
        print(f"report: {write_report(args.out)}")
    except (ValueError, OutputDirError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished samples are stored in {args.out}; continue with --resume", file=sys.stderr)
        return 130
    return 0


def _report(args: argparse.Namespace) -> int:
    from softcbf.study.report import write_report

    try:
        path = write_report(args.dir, level=args.level, bins=args.bins, figure_format=args.figure_format, dpi=args.dpi)
    except (ValueError, OutputDirError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(path.read_text(encoding="utf-8"))
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the `run` and `report` sub-commands on `parser` (`softcbf study`, `python -m softcbf.study`)."""
    commands = parser.add_subparsers(dest="study_command", required=True)
    run = commands.add_parser("run", help="run a study file into a study folder")
    run.add_argument("study_file", type=Path, help="study definition (TOML), e.g. studies/paper_tunings_plate_errors.toml")
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
    run.set_defaults(study_handler=_run)
    report = commands.add_parser("report", help="write report.md and plots/ for a study folder")
    report.add_argument("dir", type=Path, help="study folder")
    report.add_argument("--level", type=float, default=0.05, help="violation probability to locate (default 0.05)")
    report.add_argument("--bins", type=int, default=6, help="bins per varied parameter (default 6)")
    report.add_argument("--figure-format", choices=("png", "svg", "pdf"), default="png", help="plot file format (default png)")
    report.add_argument("--dpi", type=float, default=110.0, help="raster resolution of the plots (default 110)")
    report.set_defaults(study_handler=_report)


def run_command(args: argparse.Namespace, extra: list[str]) -> int:
    """Handler of `softcbf study`: runs the chosen sub-command; returns the exit code."""
    return args.study_handler(args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softcbf.study", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    return run_command(parser.parse_args(argv), [])
