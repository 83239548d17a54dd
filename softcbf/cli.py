"""The `softcbf` command line (installed by pyproject.toml's [project.scripts]).

    softcbf demo [--out DIR] [--duration S]       the paper's CBF against the recommended filter on the MuJoCo
                                                   plate: one contact figure in under a minute (softcbf.demo)
    softcbf list                                   scenarios, filters and nominal controllers with their parameters
    softcbf run SCENARIO [--PARAM VALUE ...] [--filter SPEC] [--filter-param NAME=VALUE ...]
                         [--nominal SPEC] [--nominal-param NAME=VALUE ...] [--out DIR] [--overwrite] [--spawn]
    softcbf run --config FILE.toml|RUN_DIR/config.json [--PARAM VALUE ...] [--out DIR]
    softcbf run SCENARIO --help                    the scenario's parameters: meaning, unit, valid values
    softcbf report RUN_DIR [--no-recording]        rebuild plots/, report.md and recording.rrd
    softcbf report STUDY_DIR                       a study (or falsification) folder's report.md and plots/
    softcbf study run STUDY_FILE --out DIR | falsify STUDY_FILE --out DIR | report DIR
                                                   robustness studies and worst-case search (softcbf.study)
    softcbf hardware --config FILE ...             the hardware mode (softcbf.hardware_cli)
    softcbf bench --out DIR [--filters SPEC,...] [--quick]   the filter benchmark battery (softcbf.bench)
    softcbf calibrate-camera RUN_DIR [--window-s S]   a camera's Δ and frame scatter at rest from a recorded run
                                                   (controllers.governors.camera_delta)
    softcbf examples DIR [--overwrite]             copy the shipped examples, studies and hardware configurations
                                                   into DIR (softcbf.shipped; STUDY_FILE and CONFIG above may be
                                                   their names, e.g. mismatch_box_contact, hardware_emulated)
    softcbf --version

`run` runs a registered scenario (`scenarios.registry`, through `scenarios.run.run_scenario`): its parameters are the
settings of its spec by their flat names (`scenarios.spec`), spelt with dashes (`--pressure-limits true`); `--filter-param NAME=VALUE` and
`--nominal-param NAME=VALUE` (repeatable) add to the scenario's `filter_params` and
`nominal_params` (`scenarios.common`: the controller under test), and `--tuning NAME` is
`--filter-param tuning=NAME` (one run of that paper-cbf preset, or `--tuning custom
--filter-param a_E=5 --filter-param b_E=5 --filter-param gamma=5`); `--out` defaults to
runs/<scenario>-<YYYYmmdd-HHMMSS> (-2, -3, ... when runs start in the same second). The
run folder gets config.json, summary.json, timeseries/*.npz, plots/*.png, report.md and
recording.rrd (softcbf_mj.outputs.runio), the report and the recording rebuilt after every
finished tuning. `--spawn` streams each tuning to a rerun viewer while it runs when a
display is present, and says so when it skips it. `python -m scenarios` is the same `run`
(docs/run-outputs.md spelling: `python -m scenarios NAME --out DIR ...`, `--list`).
`--config FILE` takes the scenario and its parameters from a run configuration file
(`scenarios.config_file`: a TOML file, or a run folder's config.json, which replays that
run, with one warning line on stderr for each recorded version that differs from the
running one and for a --seed that changes the recorded seed: such a replay is not
bit-identical; a filter or nominal FILE.py runs from its recorded location and is refused
when its SHA-256 differs from the recorded one, unless --allow-changed-filter); parameters on the command line override the file's, and a SCENARIO given
as well must be the file's. `softcbf run SCENARIO --help` lists the scenario's parameters with
their meaning, unit, default and valid values (docs/parameters.md).

The run folder is locked while a run writes it (softcbf_mj.outputs.runio: a second run into it is
refused, naming the process that holds it). `--overwrite` replaces the contents of a run
folder (one softcbf wrote: its .softcbf-run marker or a summary.json of docs/run-outputs.md), never any
other folder, nor the working folder, a folder above it or the home folder.

A misspelt name (command, scenario, parameter, filter, nominal) is answered with the closest
valid ones (`controllers.registry.did_you_mean`): "unknown command 'rnu' (did you mean 'run'?)".
A run talks within a second or two (its progress bar, or the heartbeat of a longer set-up), and
numba's compiles are announced as they start (scenarios.run, softcbf_mj.outputs.progress, softcbf_mj.loops.kernels).

Exit codes: 0 done; 2 usage error (unknown scenario or parameter, a value of the wrong
type, not finite or out of range, a duration whose time series would not fit in memory,
an --out that is in use, not writable, or non-empty without --overwrite, a folder that is
not a run folder, a time series that cannot be read), with one line on stderr naming the
parameter (or file) and the valid values; 1 a run that ended on a filter fault (one line, its
record kept) or an error of the testbed itself (a traceback; the run folder kept as it was, the
evidence); 130 interrupted; 141, silently, when stdout's reader has gone (`softcbf list | head`:
scenarios.pipe). Scenarios check every parameter before they write anything; a run
that stops before its first finished tuning (rejected or interrupted) leaves no output behind
(folders it created are removed, one that existed is emptied), so the corrected command is not
refused. Ctrl-C
after a finished tuning keeps the finished tunings and brings the report and the
recording up to them if they lag behind (a second Ctrl-C skips that and says what to run).

A subcommand is one `register_command(name, help, add_arguments, handler)` call:
`add_arguments(parser)` declares its options, `handler(args, extra) -> exit code` runs
it (`extra`: tokens the parser did not know, passed only with `extra_args=True`); a
handler raises `UsageError` for bad input. `add_arguments` may be None (no options).
`help` may be a function returning the text, and `lazy(module, name)` stands for the
function `name` of `module`, imported when first called: `demo`, `hardware`, `bench`, `study` and `examples`
are registered so, and `main` builds only the subcommand it runs (the others get their
name, and their help only for `softcbf --help`), so `softcbf list` imports neither OpenCV
nor the hardware mode nor the governors' benchmark, and the scenario modules import MuJoCo and
OpenCV only where a scenario is checked or run, so neither `list` nor `run NAME --help` imports
them (tests/test_cli_lazy.py; tools/bench_cli_list.py measures their CPU time).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

try:  # Ctrl-C while the command line starts (these imports take about a second): one line, exit 130
    import softcbf_mj
    from controllers import registry as controllers_registry
    from controllers.registry import did_you_mean
    from scenarios import get as get_scenario, registry
    from scenarios.config_file import load_run_config, replay_sources, replay_warnings
    from scenarios.pipe import quiet_on_closed_pipe
    from scenarios.run import UsageError, UsageParser, describe, exit_code, run_scenario, scenario_parameters
    from softcbf_mj.outputs.runio import RunFolderError, versions
except KeyboardInterrupt:
    print("\ninterrupted", file=sys.stderr)
    raise SystemExit(130) from None  # scenarios.run.INTERRUPTED, which could not be imported

# softcbf_mj.outputs.recording and softcbf_mj.outputs.report are imported where they are used: rerun and
# matplotlib take seconds to import, which `list`, `--version` and usage errors should not pay;
# softcbf.hardware_cli (OpenCV, the hardware mode), softcbf.bench and softcbf.study.cli through `lazy`.


@dataclass(frozen=True)
class Command:
    """A `softcbf` subcommand (see the module docstring for the fields)."""

    name: str
    help: str | Callable[[], str]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None
    handler: Callable[[argparse.Namespace, list[str]], int]
    extra_args: bool = False
    add_help: bool = True  # False: the command declares its own -h/--help

    def help_text(self) -> str:
        return self.help if isinstance(self.help, str) else self.help()


COMMANDS: dict[str, Command] = {}


def lazy(module: str, name: str) -> Callable[..., Any]:
    """The function `name` of `module`, imported at its first call (module docstring)."""

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args)

    call.__qualname__ = f"lazy({module}.{name})"
    return call


def register_command(name: str, help: str | Callable[[], str], add_arguments: Callable[[argparse.ArgumentParser], None] | None,
                     handler: Callable[[argparse.Namespace, list[str]], int], extra_args: bool = False,
                     add_help: bool = True) -> Command:
    """Add subcommand `name` to `softcbf` (see the module docstring)."""
    if name in COMMANDS:
        raise ValueError(f"softcbf subcommand {name!r} is registered twice")
    COMMANDS[name] = Command(name, help, add_arguments, handler, extra_args, add_help)
    return COMMANDS[name]


def list_text() -> str:
    """`softcbf list`: the scenarios, then the filters, their presets and the nominal controllers with every parameter's meaning, unit and default."""
    lines = ["scenarios:", *(describe(s) for s in registry().values()), "",
             "filters (--filter NAME, or FILE.py:Factory / package.module:Factory; --filter-param NAME=VALUE; "
             "paper-cbf: --tunings P1,P2 or --tuning PRESET|custom):"]
    lines += [controllers_registry.describe(name, f) for name, f in controllers_registry.FILTERS.items()]
    lines += ["", "filter presets (--filter NAME:PRESET; an explicit --filter-param overrides the preset's value):"]
    lines += [controllers_registry.describe_preset(name) for name in controllers_registry.PRESETS]
    lines += ["", "nominal controllers (--nominal NAME, or FILE.py:Factory returning (t, q, qd) -> u_nom; --nominal-param NAME=VALUE):"]
    lines += [controllers_registry.describe(name, f) for name, f in controllers_registry.NOMINALS.items()]
    return "\n".join(lines)


def _list(args: argparse.Namespace, extra: list[str]) -> int:
    print(list_text())
    return 0


def _run_args(parser: argparse.ArgumentParser) -> None:
    # SCENARIO is the first of the tokens the parser leaves (`_run`): a positional would take
    # the value of a scenario option that follows --config (`--config F --tunings Low`).
    parser.usage = ("softcbf run [SCENARIO] [--config FILE] [--PARAM VALUE ...] [--out DIR] [--overwrite] [--spawn] "
                    "[--data-only]")
    parser.epilog = "SCENARIO: a scenario name (softcbf list); optional with --config, which names one."
    parser.add_argument("-h", "--help", action="store_true", help="show this help and the scenario's parameters, then exit")
    parser.add_argument("--config", type=Path, metavar="FILE",
                        help="run configuration: a TOML file (scenario = NAME and parameters) or a run folder's "
                             "config.json (replays that run); command-line parameters override it")
    parser.add_argument("--allow-changed-filter", action="store_true",
                        help="replay a config.json even though its filter or nominal FILE.py changed since the run "
                             "(refused without it; the replay then warns that it is not the recorded run)")
    parser.add_argument("--out", help="output folder (default runs/<scenario>-<time>; refused if it exists and is not empty)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the contents of an existing run folder (one written by softcbf)")
    parser.add_argument("--spawn", action="store_true", help="stream each tuning to a rerun viewer while it runs (needs a display)")
    parser.add_argument("--data-only", action="store_true",
                        help="write config.json, summary.json and the time series only, no plots, report or recording "
                             "(softcbf report DIR draws them later)")


def _run(args: argparse.Namespace, extra: list[str]) -> int:
    name = extra[0] if extra and not extra[0].startswith("-") else None
    tokens = extra[1:] if name is not None else extra
    base = None
    if args.config is not None:
        try:
            config = load_run_config(args.config)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if name is not None and name != config.scenario:
            raise UsageError(f"scenario {name!r} given, but the run configuration {args.config} is for {config.scenario!r}; "
                             "give one of them")
        name, base = config.scenario, config.params
    if args.help:
        return _run_help(args, name)
    if name is None:
        raise UsageError("softcbf run: give a scenario name (softcbf list) or --config FILE")
    replay = args.config is not None and config.versions is not None
    if args.allow_changed_filter and not replay:
        raise UsageError("--allow-changed-filter applies to a replay: softcbf run --config RUN_DIR/config.json")
    if replay:  # run the recorded filter and nominal files, and say where the replay departs from the recorded run
        try:
            params = scenario_parameters(get_scenario(name), tokens, base)
            base, source_lines = replay_sources(config, params, args.allow_changed_filter)
        except KeyError as exc:
            raise UsageError(exc.args[0]) from None
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        for line in [*replay_warnings(config, params, versions()), *source_lines]:
            print(line, file=sys.stderr)
    return run_scenario(name, tokens, args.out, args.overwrite, args.spawn, base=base, report=not args.data_only)


def _run_help(args: argparse.Namespace, name: str | None) -> int:
    """`softcbf run [SCENARIO] --help`: the options, then the scenario's parameters (all scenarios' without one)."""
    args.print_help()
    names = [name] if name else list(registry())
    try:
        print("\nparameters (--NAME VALUE; docs/parameters.md):")
        print("\n".join(describe(get_scenario(name)) for name in names))
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    return 0


def _report_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, help="a run folder written by softcbf run")
    parser.add_argument("--no-recording", action="store_true", help="rebuild the plots and report.md only")
    # figure options (softcbf_mj.outputs.report.write_report / softcbf.study.report.write_report parameters)
    parser.add_argument("--figure-format", choices=("png", "svg", "pdf"), default="png", help="plot file format (default png)")
    parser.add_argument("--dpi", type=float, default=None,
                        help="raster resolution of the plots, dots per inch (default: a run's 200, a study's 100)")


def _report(args: argparse.Namespace, extra: list[str]) -> int:
    from softcbf.study.store import FALSIFY_FILE, STUDY_FILE  # 0.15 s (-X importtime): not at every command's start

    resolution = {} if args.dpi is None else {"dpi": args.dpi}  # each report's own default otherwise
    print(f"report: rebuilding {args.run_dir}'s plots and report.md"
          + ("" if args.no_recording else " and recording"), flush=True)
    if (args.run_dir / STUDY_FILE).is_file() or (args.run_dir / FALSIFY_FILE).is_file():
        from softcbf.study.report import write_report as write_study_report  # matplotlib, pandas: 1.9 s (-X importtime)

        print(f"study report: {write_study_report(args.run_dir, figure_format=args.figure_format, **resolution)}")
        return 0
    from softcbf_mj.outputs.recording import write_recording  # MuJoCo, rerun: 2.8 s (-X importtime), only to report
    from softcbf_mj.outputs.report import write_report  # matplotlib: 1.5 s (-X importtime), only to report

    try:
        start = time.perf_counter()
        files = write_report(args.run_dir, figure_format=args.figure_format, **resolution)
        report_s = time.perf_counter() - start
        print(f"report ({report_s:.1f} s): " + ", ".join(str(p) for p in files.values()))
        if not args.no_recording:
            start = time.perf_counter()
            path = write_recording(args.run_dir)
            print(f"recording ({time.perf_counter() - start:.1f} s): {path} ({path.stat().st_size / 1e6:.1f} MB)")
    except RunFolderError as exc:
        raise UsageError(str(exc)) from None
    return 0


register_command("demo", lambda: importlib.import_module("softcbf.demo").HELP,
                 lazy("softcbf.demo", "add_arguments"), lazy("softcbf.demo", "run_command"))
register_command("list", "list the scenarios, filters and nominal controllers with their parameters", None, _list)
register_command("run", "run a scenario: softcbf run SCENARIO [--PARAM VALUE ...] [--out DIR] | --config FILE",
                 _run_args, _run, extra_args=True, add_help=False)
register_command("report", "rebuild a run or study folder's plots and report.md (and a run's recording.rrd) from its saved data",
                 _report_args, _report)
register_command("study", "robustness studies of model mismatch: softcbf study run STUDY_FILE --out DIR | "
                 "falsify STUDY_FILE --out DIR | report DIR",
                 lazy("softcbf.study.cli", "add_arguments"), lazy("softcbf.study.cli", "run_command"))
register_command("hardware", lambda: importlib.import_module("softcbf.hardware_cli").HELP,
                 lazy("softcbf.hardware_cli", "add_arguments"), lazy("softcbf.hardware_cli", "run_command"))
register_command("examples", "copy the shipped examples, studies and hardware configurations into DIR: softcbf examples DIR",
                 lazy("softcbf.shipped", "add_arguments"), lazy("softcbf.shipped", "run_command"))
register_command("bench", lambda: importlib.import_module("softcbf.bench").HELP,
                 lazy("softcbf.bench", "add_arguments"), lazy("softcbf.bench", "run_command"))
register_command("calibrate-camera", "measure a camera's error at rest (Δ and the frame scatter that c-erg's gain "
                 "estimate trusts) from a run folder: softcbf calibrate-camera RUN_DIR",
                 lazy("softcbf.calibrate_camera", "add_arguments"), lazy("softcbf.calibrate_camera", "run_command"))


def version_line() -> str:
    v = versions()
    return (f"softcbf {softcbf_mj.__version__} (MuJoCo {v['mujoco']}, rerun-sdk {v['rerun_sdk']}, "
            f"numpy {v['numpy']}, Python {v['python']})")


class VersionAction(argparse.Action):
    """`--version`: print `version_line()` (read only when asked: it reads every package's metadata) and exit."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show the versions and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(version_line())
        parser.exit()


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The `softcbf` parser; with `selected` (a command name) only that subcommand gets its options and help."""
    parser = argparse.ArgumentParser(prog="softcbf", description="softcbf-mj: scenarios, reports and recordings.")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=UsageParser)
    for command in COMMANDS.values():
        if selected is not None and command.name != selected:
            sub.add_parser(command.name, allow_abbrev=False, add_help=command.add_help)  # a name only: never parsed
            continue
        text = command.help_text()
        subparser = sub.add_parser(command.name, help=text, description=text, allow_abbrev=False,
                                   add_help=command.add_help)
        if command.add_arguments is not None:
            command.add_arguments(subparser)
        subparser.set_defaults(print_help=subparser.print_help)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `softcbf`; returns the exit code (0, 2 usage error, 130 interrupted, 141 stdout's reader gone:
    `softcbf list | head`, scenarios.pipe)."""
    tokens = sys.argv[1:] if argv is None else list(argv)
    first = next((token for token in tokens if not token.startswith("-")), None)  # the command (the top level has no values)
    parser = build_parser(first if first in COMMANDS else None)

    def run() -> int:
        if first is not None and first not in COMMANDS:
            raise UsageError(f"unknown command {first!r}{did_you_mean(first, COMMANDS)}; "
                             f"commands: {', '.join(COMMANDS)}")
        args, extra = parser.parse_known_args(argv)
        command = COMMANDS[args.command]
        if extra and not command.extra_args:
            raise UsageError(f"softcbf {command.name}: unrecognised arguments: {' '.join(extra)}")
        return command.handler(args, extra)

    return quiet_on_closed_pipe(lambda: exit_code(run, process=argv is None))  # argv None: this process's own command line


if __name__ == "__main__":
    sys.exit(main())
