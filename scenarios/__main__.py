"""Command line: `python -m scenarios --list` and `python -m scenarios NAME --out DIR [--param value ...]`.

docs/run-outputs.md's spelling of `softcbf list` / `softcbf run NAME --out DIR ...`: the same
implementation (`scenarios.run.run_scenario`), the same outputs, errors and exit codes,
except that --out is required here. A closed stdout (`python -m scenarios --list | head`) ends
quietly with 141 (scenarios.pipe).
"""

from __future__ import annotations

import argparse
import sys

from scenarios import registry
from scenarios.pipe import quiet_on_closed_pipe
from scenarios.run import UsageError, describe, exit_code, run_scenario


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m scenarios`; returns the exit code (module docstring)."""
    return quiet_on_closed_pipe(lambda: command_line(argv))


def command_line(argv: list[str] | None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scenarios", description="Run a registered softcbf-mj scenario.",
                                     allow_abbrev=False)
    parser.add_argument("name", nargs="?", help="scenario name (see --list)")
    parser.add_argument("--list", action="store_true", help="list scenarios with their parameters")
    parser.add_argument("--out", help="output folder (refused if it exists and is not empty)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the contents of an existing run folder (one written by softcbf)")
    parser.add_argument("--spawn", action="store_true", help="stream each finished tuning to a rerun viewer (needs a display)")
    parser.add_argument("--data-only", action="store_true",
                        help="write config.json, summary.json and the time series only (softcbf report DIR draws the rest)")
    args, rest = parser.parse_known_args(argv)

    if args.list:
        print("\n".join(describe(s) for s in registry().values()))
        return 0
    if not args.name:
        parser.error("give a scenario name or --list")

    def run() -> int:
        if args.out is None and args.name in registry():
            raise UsageError("--out DIR is required to run a scenario")
        return run_scenario(args.name, rest, args.out, args.overwrite, args.spawn, report=not args.data_only)

    return exit_code(run, process=argv is None)  # argv None: this process's own command line


if __name__ == "__main__":
    sys.exit(main())
