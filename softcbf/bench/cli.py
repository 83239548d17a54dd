"""`softcbf bench`'s command line: its options (`add_arguments`) and handler (`run_command`).

    softcbf bench --out DIR [--filters SPEC,SPEC,...] [--quick] [--cases NAME,...] [--mismatch-draws N] [--workers N]
                  [--falsify-budget N] [--resume | --overwrite]

After the bench, a table of contact under error (softcbf.bench.tables: `contact_text`, within 120 columns; every
column in bench.md). Without --filters it runs the recommended filter beside the baselines (softcbf.bench.filters: `DEFAULT_FILTERS`).
Exit codes: 0 done, 2 a usage error (one line on stderr), 130 on Ctrl-C after one line that says what is
stored and to continue with `--resume` (or that nothing was: a fresh bench interrupted before its first row
leaves nothing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scenarios.run import INTERRUPTED
from softcbf.bench.cases import CASES, MISMATCH_DRAWS, RunOptions
from softcbf.bench.filters import BASELINES, DEFAULT_FILTERS, RECOMMENDED_FILTER, parse_filters
from softcbf.bench.folder import BENCH_FILE, TABLE_FILE, is_bench_folder
from softcbf.bench.tables import PLOT_FILE, contact_text
from softcbf.bench.runner import run_bench, shown_labels

HELP = "run safety filters over the fixed benchmark battery: softcbf bench --out DIR [--filters SPEC,...] [--quick]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output folder (bench.json, bench.md, plots/, cases/)")
    parser.add_argument("--filters", default=DEFAULT_FILTERS,
                        help="NAME or NAME(param=value,...), comma separated (default: the recommended filter "
                             f"{RECOMMENDED_FILTER.name} and the baselines {', '.join(BASELINES)})")
    parser.add_argument("--quick", action="store_true",
                        help="short durations (1 s, the contact tasks' pushes 3 s), 2 mismatch draws and 3 push draws, "
                             "emulator skipped (CI)")
    parser.add_argument("--cases", default=None, help=f"run only these cases (comma separated; default all: {', '.join(c.name for c in CASES)})")
    parser.add_argument("--mismatch-draws", type=int, default=None, help=f"draws of the mismatch study (default {MISMATCH_DRAWS})")
    parser.add_argument("--workers", type=int, default=1,
                        help="local processes of the mismatch study and the worst-case searches (default 1)")
    parser.add_argument("--falsify-budget", type=int, default=None, metavar="N",
                        help="evaluations of each filter's worst-case search over studies/mismatch_box_contact.toml "
                             "(bench.json's worst_found; default 36 for the whole battery, 4 with --quick, 0 with "
                             "--cases; 0: none: softcbf.study.worst_found's BUDGET and QUICK_BUDGET)")
    parser.add_argument("--resume", action="store_true",
                        help="continue a bench in --out: keep its finished (filter, case) rows, continue its mismatch studies")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the contents of a bench folder in --out (one holding a bench.json)")


def run_command(args: argparse.Namespace, extra: list[str] | None = None) -> int:
    """Handler of `softcbf bench` (module docstring: exit codes)."""
    try:
        filters = parse_filters(args.filters)
        cases = None if args.cases is None else [c.strip() for c in args.cases.split(",")]
        bench = run_bench(args.out, filters, RunOptions(args.quick, args.workers, args.mismatch_draws, args.resume, args.overwrite,
                                                args.falsify_budget), cases)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        stored = (f"finished cases are stored in {args.out}; continue with --resume"
                  if is_bench_folder(args.out) else "nothing was stored")
        print(f"\ninterrupted: {stored}", file=sys.stderr)
        return INTERRUPTED
    if bench["contact_under_error"]:
        print(f"bench: contact under error (forces / F_max; every column: {args.out / TABLE_FILE})")
        print("\n".join(contact_text(bench["contact_under_error"], shown_labels(filters))))
    print(f"bench: {args.out / BENCH_FILE}, {args.out / TABLE_FILE}, {args.out / PLOT_FILE}")
    return 0
