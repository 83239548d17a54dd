"""`softcbf calibrate-camera RUN_DIR`: a camera's error at rest from a recorded run, printed.

The command line of `controllers.governors.camera_delta` (the measurement, numpy only, which the hardware mode can use as it
is): this module parses the arguments, turns a bad folder into one line and exit 2, and prints each tuning's Δ and ε
(`controllers.governors.camera_delta.report_lines`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from controllers.governors.camera_delta import measure_folder, report_lines
from scenarios.run import UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`softcbf calibrate-camera RUN_DIR [--window-s S] [--rest-rad-s R] [--risk P]`."""
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a camera_loop run folder")
    parser.add_argument("--window-s", type=float, default=1.0, help="rest window (c-erg's gain_window_s; default 1)")
    parser.add_argument("--rest-rad-s", type=float, default=3e-3,
                        help="largest fitted slope of a window at rest (c-erg's gain_rest_rad_s; default 3e-3)")
    parser.add_argument("--risk", type=float, default=1e-6,
                        help="ε's probability per segment and sample (c-erg's gain_scatter_risk; default 1e-6)")


def run_command(args: argparse.Namespace, extra: list[str]) -> int:
    """Handler of `softcbf calibrate-camera`: prints each tuning's Δ and ε; UsageError (exit 2) on bad input."""
    try:
        results = measure_folder(args.run_dir, args.window_s, args.rest_rad_s, args.risk)
    except (ValueError, OSError, KeyError) as exc:
        raise UsageError(f"calibrate-camera: {exc}") from None
    for result in results:
        print("\n".join(report_lines(result)))
    return 0
