"""The `softcbf` command line (installed by pyproject.toml's [project.scripts]).

    softcbf list                                   scenarios, filters and nominal controllers with their parameters
    softcbf run SCENARIO [--PARAM VALUE ...] [--filter SPEC] [--filter-param NAME=VALUE ...]
                         [--nominal SPEC] [--nominal-param NAME=VALUE ...] [--out DIR] [--overwrite] [--spawn]
    softcbf report RUN_DIR [--no-recording]        rebuild plots/, report.md and recording.rrd
    softcbf report STUDY_DIR                       a study folder's report.md and plots/
    softcbf study run STUDY_FILE --out DIR | report DIR   robustness studies (softcbf.study)
    softcbf hardware --config FILE ...             the hardware mode (softcbf.hardware_cli)
    softcbf --version

`run` runs a registered scenario (`scenarios.registry`): its parameters are its keyword
arguments, spelt with dashes (`--pressure-limits true`); `--filter-param NAME=VALUE` and
`--nominal-param NAME=VALUE` (repeatable) add to the scenario's `filter_params` and
`nominal_params` (`scenarios.common`: the controller under test), and `--tuning NAME` is
`--filter-param tuning=NAME` (one run of that paper-cbf preset, or `--tuning custom
--filter-param a_E=5 --filter-param b_E=5 --filter-param gamma=5`); `--out` defaults to
runs/<scenario>-<YYYYmmdd-HHMMSS>. The run folder gets config.json, summary.json,
timeseries/*.npz, plots/*.png, report.md and recording.rrd (softcbf_mj.runio), the report
and the recording rebuilt after every finished tuning, so an interrupted run (Ctrl-C,
exit code 130) leaves them for the tunings it finished. `--spawn` streams each finished
tuning to a rerun viewer when a display is present, and says so when it skips it.
`python -m scenarios` is the same `run` (SPEC §8 spelling: `python -m scenarios NAME
--out DIR ...`, `--list`).

Exit codes: 0 done; 2 usage error (unknown scenario or parameter, a value of the wrong
type or out of range, an existing non-empty --out without --overwrite, a folder that is
not a run folder), with one line on stderr naming the parameter and the valid values;
130 interrupted. A run the scenario rejects (ValueError) before its first finished
tuning leaves no output behind (a folder it created is removed, one that existed empty
is emptied), so the corrected command is not refused.

A subcommand is one `register_command(name, help, add_arguments, handler)` call:
`add_arguments(parser)` declares its options, `handler(args, extra) -> exit code` runs
it (`extra`: tokens the parser did not know, passed only with `extra_args=True`); a
handler raises `UsageError` for bad input. `add_arguments` may be None (no options).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import shutil
import sys
import time
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import softcbf_mj
from controllers import registry as controllers_registry
from scenarios import Scenario, get, registry
from softcbf import hardware_cli
from softcbf_mj.runio import SUMMARY_FILE, OutputDirError, RunFolderError, prepare_out_dir, read_run_folder, versions
from softcbf.study import cli as study_cli
from softcbf.study.store import STUDY_FILE

# softcbf_mj.recording and softcbf_mj.report are imported where they are used: rerun and
# matplotlib take seconds to import, which `list`, `--version` and usage errors should not pay.

USAGE_ERROR = 2
INTERRUPTED = 130
DEFAULT_RUNS_DIR = Path("runs")
_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")
PLUGIN_PARAMS = ("filter_params", "nominal_params")  # scenario parameters also given by repeated --filter-param / --nominal-param


class UsageError(Exception):
    """Bad command-line input; the message names the parameter and the valid values."""


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser that raises UsageError instead of printing usage and exiting."""

    def error(self, message: str) -> typing.NoReturn:
        raise UsageError(f"{self.prog}: {message}")


def _parse_bool(text: str) -> bool:
    low = text.strip().lower()
    if low in _TRUE:
        return True
    if low in _FALSE:
        return False
    raise ValueError(f"expected one of {', '.join(_TRUE + _FALSE)}")


def _converter(annotation: object) -> Callable[[str], object]:
    if annotation is bool:
        return _parse_bool
    if annotation in (int, float, str):
        return annotation  # type: ignore[return-value]
    raise TypeError(f"scenario parameter type {annotation!r} is not supported on the command line")


def _option(name: str) -> str:
    return f"--{name.replace('_', '-')}"


def describe(scenario: Scenario) -> str:
    """The scenario's name, one-line description and parameters (option, type, default)."""
    hints = typing.get_type_hints(scenario.run)
    lines = [f"{scenario.name}: {scenario.description}"]
    for name, p in scenario.parameters().items():
        lines.append(f"    {_option(name)} {hints[name].__name__} (default {p.default!r})")
    return "\n".join(lines)


def scenario_parameters(scenario: Scenario, tokens: Sequence[str]) -> dict[str, object]:
    """Every parameter of `scenario` (defaults overridden by `tokens`: --name value ...).

    Raises UsageError naming the parameter and its type or valid values, or the unknown
    tokens and the valid options.
    """
    hints = typing.get_type_hints(scenario.run)
    params = scenario.parameters()
    parser = _Parser(prog=f"scenario {scenario.name}", add_help=False, allow_abbrev=False)
    for name, p in params.items():
        convert, type_name = _converter(hints[name]), hints[name].__name__

        def typed(text: str, _convert=convert, _type: str = type_name) -> object:
            try:
                return _convert(text)
            except ValueError as exc:
                detail = str(exc) if _convert is _parse_bool else f"expected {_type}"
                raise argparse.ArgumentTypeError(f"{detail}, got {text!r}") from None

        typed.__name__ = type_name
        parser.add_argument(_option(name), dest=name, type=typed, default=p.default)
    repeated = {name: _option(name.removesuffix("s")) for name in params if name in PLUGIN_PARAMS}
    for name, option in repeated.items():
        parser.add_argument(option, dest=f"{name}_items", action="append", default=[], metavar="NAME=VALUE")
    if "filter_params" in repeated and "tuning" not in params:  # --tuning X: the filter's tuning (one run), SPEC §9
        parser.add_argument("--tuning", dest="filter_params_items", action="append", type=lambda v: f"tuning={v}")
    try:
        known, unknown = parser.parse_known_args(list(tokens))
    except UsageError as exc:
        raise UsageError(str(exc).removeprefix(f"{parser.prog}: argument ")) from None
    if unknown:
        valid = ", ".join([*(_option(n) for n in params), *repeated.values()])
        raise UsageError(f"unknown parameter(s) {' '.join(unknown)} for scenario {scenario.name}; valid: {valid}")
    values = vars(known)
    for name, option in repeated.items():
        items = values.pop(f"{name}_items")
        if any("=" not in item for item in items):
            raise UsageError(f"{option} takes NAME=VALUE, got {' '.join(i for i in items if '=' not in i)}")
        values[name] = ";".join(part for part in (values[name], *items) if part)
    return values


def _outputs_summary(out_dir: Path) -> str:
    """What a run folder holds, in a few lines, for the end of a run."""
    from softcbf_mj.recording import RECORDING_FILE
    from softcbf_mj.report import PLOTS_DIR, REPORT_FILE

    folder = read_run_folder(out_dir)
    recording = out_dir / RECORDING_FILE
    plots = sorted(p.name for p in (out_dir / PLOTS_DIR).glob("*.png"))
    rows = [
        ("config.json, summary.json", f"every parameter, versions, seed; one row per run ({', '.join(folder.labels)})"),
        ("timeseries/*.npz", f"{len(folder.runs)} time series (NumPy archives with units)"),
        (f"{PLOTS_DIR}/*.png, {REPORT_FILE}", f"{', '.join(plots)}; summary table"),
        (RECORDING_FILE, f"{recording.stat().st_size / 1e6:.1f} MB; view it with: rerun {recording}"),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join([f"outputs in {out_dir}:", *[f"  {name:<{width}}  {what}" for name, what in rows],
                      f"rebuild the plots, report and recording from the saved data: softcbf report {out_dir}"])


def _finished_runs(out_dir: Path) -> list[str]:
    return read_run_folder(out_dir).labels if (out_dir / SUMMARY_FILE).is_file() else []


def _discard(out_dir: Path, keep_folder: bool) -> None:
    """Remove what a run that was rejected before its first finished run wrote (and the
    folder unless it existed before), so that the corrected command is not refused."""
    for path in out_dir.iterdir():
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
    if not keep_folder:
        out_dir.rmdir()


def run_scenario(name: str, tokens: Sequence[str], out: Path | None, overwrite: bool = False, spawn: bool = False) -> int:
    """Run scenario `name` with parameters from `tokens` into `out` (default
    runs/<name>-<time>); the one implementation behind `softcbf run` and `python -m scenarios`."""
    try:
        scenario = get(name)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    params = scenario_parameters(scenario, tokens)
    if out is None:
        out = DEFAULT_RUNS_DIR / f"{name}-{datetime.datetime.now():%Y%m%d-%H%M%S}"
    existed = out.exists()
    try:
        out_dir = prepare_out_dir(out, overwrite=overwrite)
    except OutputDirError as exc:
        raise UsageError(str(exc)) from None
    from softcbf_mj.recording import live_viewer

    try:
        with live_viewer() if spawn else contextlib.nullcontext("") as message:
            if message:
                print(message, file=sys.stderr)
            scenario.run(out_dir, **params)
    except ValueError as exc:
        if not _finished_runs(out_dir):
            _discard(out_dir, keep_folder=existed)
        raise UsageError(str(exc)) from None
    except KeyboardInterrupt:
        done = _finished_runs(out_dir)
        print(f"\ninterrupted: {len(done)} finished run(s) ({', '.join(done) or 'none'}) are in {out_dir}, "
              "with their report and recording", file=sys.stderr)
        return INTERRUPTED
    print(_outputs_summary(out_dir))
    return 0


@dataclass(frozen=True)
class Command:
    """A `softcbf` subcommand (see the module docstring for the fields)."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None] | None
    handler: Callable[[argparse.Namespace, list[str]], int]
    extra_args: bool = False


COMMANDS: dict[str, Command] = {}


def register_command(name: str, help: str, add_arguments: Callable[[argparse.ArgumentParser], None] | None,
                     handler: Callable[[argparse.Namespace, list[str]], int], extra_args: bool = False) -> Command:
    """Add subcommand `name` to `softcbf` (see the module docstring)."""
    if name in COMMANDS:
        raise ValueError(f"softcbf subcommand {name!r} is registered twice")
    COMMANDS[name] = Command(name, help, add_arguments, handler, extra_args)
    return COMMANDS[name]


def list_text() -> str:
    """`softcbf list`: the scenarios, then the filters and nominal controllers with every parameter's meaning, unit and default."""
    lines = ["scenarios:", *(describe(s) for s in registry().values()), "",
             "filters (--filter NAME, or FILE.py:Factory / package.module:Factory; --filter-param NAME=VALUE; "
             "paper-cbf: --tunings P1,P2 or --tuning PRESET|custom):"]
    lines += [controllers_registry.describe(name, f) for name, f in controllers_registry.FILTERS.items()]
    lines += ["", "nominal controllers (--nominal NAME, or FILE.py:Factory returning (t, q, qd) -> u_nom; --nominal-param NAME=VALUE):"]
    lines += [controllers_registry.describe(name, f) for name, f in controllers_registry.NOMINALS.items()]
    return "\n".join(lines)


def _list(args: argparse.Namespace, extra: list[str]) -> int:
    print(list_text())
    return 0


def _run_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario name (softcbf list)")
    parser.add_argument("--out", type=Path, help="output folder (default runs/<scenario>-<time>; refused if it exists and is not empty)")
    parser.add_argument("--overwrite", action="store_true", help="replace the contents of an existing --out folder")
    parser.add_argument("--spawn", action="store_true", help="stream each finished tuning to a rerun viewer (needs a display)")


def _run(args: argparse.Namespace, extra: list[str]) -> int:
    return run_scenario(args.scenario, extra, args.out, args.overwrite, args.spawn)


def _report_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, help="a run folder written by softcbf run")
    parser.add_argument("--no-recording", action="store_true", help="rebuild the plots and report.md only")


def _report(args: argparse.Namespace, extra: list[str]) -> int:
    if (args.run_dir / STUDY_FILE).is_file():
        from softcbf.study.report import write_report as write_study_report

        print(f"study report: {write_study_report(args.run_dir)}")
        return 0
    from softcbf_mj.recording import write_recording
    from softcbf_mj.report import write_report

    try:
        start = time.perf_counter()
        files = write_report(args.run_dir)
        report_s = time.perf_counter() - start
        print(f"report ({report_s:.1f} s): " + ", ".join(str(p) for p in files.values()))
        if not args.no_recording:
            start = time.perf_counter()
            path = write_recording(args.run_dir)
            print(f"recording ({time.perf_counter() - start:.1f} s): {path} ({path.stat().st_size / 1e6:.1f} MB)")
    except RunFolderError as exc:
        raise UsageError(str(exc)) from None
    return 0


register_command("list", "list the scenarios, filters and nominal controllers with their parameters", None, _list)
register_command("run", "run a scenario: softcbf run SCENARIO [--PARAM VALUE ...] [--out DIR]", _run_args, _run,
                 extra_args=True)
register_command("report", "rebuild a run or study folder's plots and report.md (and a run's recording.rrd) from its saved data",
                 _report_args, _report)
register_command("study", "robustness studies of model mismatch: softcbf study run STUDY_FILE --out DIR | report DIR",
                 study_cli.add_arguments, study_cli.run_command)
register_command("hardware", hardware_cli.HELP, hardware_cli.add_arguments, hardware_cli.run_command)


def version_line() -> str:
    v = versions()
    return (f"softcbf {softcbf_mj.__version__} (MuJoCo {v['mujoco']}, rerun-sdk {v['rerun_sdk']}, "
            f"numpy {v['numpy']}, Python {v['python']})")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="softcbf", description="softcbf-mj: scenarios, reports and recordings.")
    parser.add_argument("--version", action="version", version=version_line())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)
    for command in COMMANDS.values():
        subparser = sub.add_parser(command.name, help=command.help, description=command.help, allow_abbrev=False)
        if command.add_arguments is not None:
            command.add_arguments(subparser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `softcbf`; returns the exit code (0, 2 usage error, 130 interrupted)."""
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        command = COMMANDS[args.command]
        if extra and not command.extra_args:
            raise UsageError(f"softcbf {command.name}: unrecognised arguments: {' '.join(extra)}")
        return command.handler(args, extra)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR


if __name__ == "__main__":
    sys.exit(main())
