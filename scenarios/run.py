"""Running a registered scenario from command-line tokens: the one implementation behind
`softcbf run` (softcbf/cli.py) and `python -m scenarios` (scenarios/__main__.py).

`scenario_parameters` turns `--name value` tokens into the scenario's flat parameters (its
spec's settings by name, `scenarios.spec`) over the defaults or the `base` values of a run configuration file (scenarios.config_file;
spelt with dashes; `--filter-param NAME=VALUE` and `--nominal-param NAME=VALUE`,
repeatable, one parameter each (the value may hold ';' and '='), add to the mappings `filter_params`
and `nominal_params`, which the plug-in types (`controllers.registry.typed_params`); `--tuning NAME` is
`--filter-param tuning=NAME`; a NAME given twice on one command line is refused,
`command_line_params`, while one of `base` is overridden). `run_scenario` checks every parameter
and builds the scenario's spec (every value checked, `scenarios.spec`) before the run folder exists,
then makes it absolute (a filter that changes the working folder cannot move the outputs), locks
it (`softcbf_mj.outputs.runio`) and runs the spec into it.

The error boundary. Only validation errors are usage errors (`UsageError`, exit code
`USAGE_ERROR`, one line): a parameter refused while the spec is built, and, raised while the
scenario runs, a setting refused by the vocabulary (`SettingError`: e.g. a duration whose time
series would not fit in memory) or a plug-in that cannot be loaded or built (`PluginLoadError`);
on those, or Ctrl-C, before the first finished run nothing is left behind (the folders it created
are removed, one that existed is emptied). Any other exception is a bug of the testbed (its
metrics, report or plant code): it propagates (a traceback, exit 1) and the folder is kept as it
is, the evidence, which the traceback names; a SystemExit (or another BaseException but Ctrl-C)
that user code raised outside the control step's boundary becomes such an error, never exit 0. Ctrl-C after a finished run keeps the finished runs
and brings the report and the recording up to them (a second Ctrl-C skips that and says what to
run); interrupts return `INTERRUPTED`. A run that ended on a filter fault (closedloop.step)
keeps its folder and returns `FILTER_FAULT` (1) after one line naming the fault.

The process (`exit_code(..., process=True)`: the command line's own process). Ctrl-C is told from
a filter's own KeyboardInterrupt from the start (`controllers.core.interrupts.watch`); and when the
command has finished (its outputs written) while non-daemon threads are still running (a filter
that started one and never ended it), the process says so in one line and ends with the command's
exit code instead of waiting for them forever.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import sys
import threading
import typing
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

from closedloop.step import describe_fault, fault_log_name
from controllers.core.bounds import SettingError
from controllers.core.interrupts import watch
from controllers.contract.filter_parameters import OLD_TEXT_WARNING, Params, add_pair, read_params
from controllers.registry import FILTERS, NOMINALS, PluginLoadError, did_you_mean, is_builtin, parameter_names
from scenarios import Scenario, get
from scenarios.run_outputs import data_only, once_at_end, outputs_on
from vocabulary.settings import setting
from softcbf_mj.loops.kernels import compile_notes
from softcbf_mj.outputs.progress import heartbeat
from softcbf_mj.outputs.runio import SUMMARY_FILE, OutputDirError, new_run_dir, prepare_out_dir, read_run_folder, release_out_dir

# softcbf_mj.outputs.recording and softcbf_mj.outputs.report are imported where they are used: rerun and
# matplotlib take seconds to import, which usage errors should not pay.

USAGE_ERROR = 2
FILTER_FAULT = 1  # a run ended on a filter fault (closedloop.step); its record is kept
INTERRUPTED = 130
DEFAULT_RUNS_DIR = Path("runs")
_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")
PLUGIN_PARAMS = ("filter_params", "nominal_params")  # scenario parameters also given by repeated --filter-param / --nominal-param


class UsageError(Exception):
    """Bad command-line input; the message names the parameter and the valid values."""


def exit_code(command: Callable[[], int], process: bool = False) -> int:
    """`command()`'s exit code, or USAGE_ERROR after "error: MESSAGE" on stderr for a
    UsageError, or INTERRUPTED after "interrupted" for Ctrl-C: the exit codes of every
    command line (`softcbf`, `python -m scenarios`). With `process` (the command line's own
    process, not a caller's): Ctrl-C is watched from the start, and threads left running end
    with the process (module docstring, `end_if_threads_left`)."""
    if process:
        watch()
    try:
        code = command()
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = USAGE_ERROR
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        code = INTERRUPTED
    if process:
        end_if_threads_left(code)
    return code


def end_if_threads_left(code: int) -> None:
    """When non-daemon threads other than the main one are still running (started by user code:
    Python would wait for them at exit, forever if they never end), say so on stderr and end the
    process now with exit code `code`, stdout and stderr flushed; return otherwise."""
    left = [t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if not left:
        return
    names = ", ".join(sorted(t.name for t in left))
    print(f"warning: {len(left)} non-daemon thread(s) still running after the command finished ({names}), "
          f"started by the filter or nominal; ending the process without waiting for them", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class UsageParser(argparse.ArgumentParser):
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


def option_type(annotation: type) -> Callable[[str], object]:
    """The argparse `type` of a command-line option for a setting of type `annotation` (bool,
    int, float, str; a bool takes true/false, yes/no, on/off, 1/0): an unreadable value is an
    argparse error "expected float, got 'x'"."""
    convert, type_name = _converter(annotation), annotation.__name__

    def typed(text: str) -> object:
        try:
            return convert(text)
        except ValueError as exc:
            detail = str(exc) if convert is _parse_bool else f"expected {type_name}"
            raise argparse.ArgumentTypeError(f"{detail}, got {text!r}") from None

    typed.__name__ = type_name
    return typed


def option_name(name: str) -> str:
    """The command-line option of setting `name`: f_max → --f-max."""
    return f"--{name.replace('_', '-')}"


def describe(scenario: Scenario) -> str:
    """The scenario's name, one-line description and parameters: option, type, default and
    unit, then meaning and valid values (vocabulary.settings)."""
    hints = typing.get_type_hints(scenario.run)
    lines = [f"{scenario.name}: {scenario.description}"]
    for name, p in scenario.parameters().items():
        doc = setting(name)
        unit = f" [{doc.unit}]" if doc.unit else ""
        lines.append(f"    {option_name(name)} {hints[name].__name__} (default {p.default!r}){unit}: {doc.meaning}; "
                     f"valid: {scenario.valid(name)}")
    return "\n".join(lines)


def scenario_parameters(scenario: Scenario, tokens: Sequence[str],
                        base: typing.Mapping[str, object] | None = None) -> dict[str, object]:
    """Every parameter of `scenario`: its defaults, overridden by `base` (a run configuration
    file's values), overridden by `tokens` (--name value ...).

    Raises UsageError naming the parameter and its type or valid values, or the unknown
    tokens and the valid options.
    """
    hints = typing.get_type_hints(scenario.run)
    params = scenario.parameters()
    try:
        given = {name: scenario.coerce(name, value) for name, value in (base or {}).items()}
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    parser = UsageParser(prog=f"scenario {scenario.name}", add_help=False, allow_abbrev=False)
    for name, p in params.items():  # a plug-in's parameter string: None when the command line does not give it
        default = None if name in PLUGIN_PARAMS else given.get(name, p.default)
        kind = str if name in PLUGIN_PARAMS else hints[name]  # --filter-params TEXT: the old joined form
        parser.add_argument(option_name(name), dest=name, type=option_type(kind), default=default)
    repeated = {name: option_name(name.removesuffix("s")) for name in params if name in PLUGIN_PARAMS}
    for name, option in repeated.items():
        parser.add_argument(option, dest=f"{name}_items", action="append", default=[], metavar="NAME=VALUE")
    if "filter_params" in repeated and "tuning" not in params:  # --tuning X: the filter's tuning (one run), docs/extending.md
        parser.add_argument("--tuning", dest="filter_params_items", action="append", type=lambda v: f"tuning={v}")
    try:
        known, unknown = parser.parse_known_args(list(tokens))
    except UsageError as exc:
        raise UsageError(str(exc).removeprefix(f"{parser.prog}: argument ")) from None
    if unknown:
        valid = ", ".join([*(option_name(n) for n in params), *repeated.values()])
        raise UsageError(f"unknown parameter(s) {' '.join(unknown)} for scenario {scenario.name}"
                         f"{did_you_mean(unknown[0], valid.split(', '))}; valid: {valid}")
    values = vars(known)
    for name, option in repeated.items():
        items, text = values.pop(f"{name}_items"), values[name]
        given_here = ([(option_name(name), text)] if text else []) + [(option, item) for item in items]
        try:  # the command line's parameters override the file's: a merge of mappings (a name twice on one line: refused)
            here = command_line_params(given_here, declared_names(name, values))
            recorded = read_params(given.get(name, params[name].default)) if text is None else Params()
            values[name] = Params({**recorded, **here})
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    return values


def declared_names(setting_name: str, values: typing.Mapping[str, object]) -> frozenset[str]:
    """The parameter names the plug-in of `setting_name` ("filter_params": `values["filter"]`, "nominal_params":
    `values["nominal"]`) declares (`controllers.registry.parameter_names`); none for a plug-in of a file that runs
    isolated (the parent never imports it) or that cannot be resolved (the spec's check says why)."""
    builtins, spec = (FILTERS, values.get("filter")) if setting_name == "filter_params" else (NOMINALS, values.get("nominal"))
    if not isinstance(spec, str) or (values.get("isolate") and not is_builtin(spec, builtins)):
        return frozenset()
    try:
        return parameter_names(spec, builtins)
    except ValueError:
        return frozenset()


def _old_joined(text: str, names: typing.Collection[str]) -> bool:
    """Whether one --filter-param item is the old joined form "a=1;b=2": two or more ';'-separated parts, each
    NAME=VALUE with NAME one the plug-in declares (`names`); anything else is one parameter whose value may hold
    ';' and '=' ("note=a;b=c" for a plug-in without a parameter b)."""
    parts = [part for part in text.split(";") if part.strip()]
    return len(parts) > 1 and all(part.partition("=")[1] and part.partition("=")[0].strip() in names for part in parts)


def command_line_params(items: Sequence[tuple[str, str]], names: typing.Collection[str] = ()) -> dict[str, str]:
    """The plug-in parameters one command line gives, as (option, "NAME=VALUE") pairs, as {name: value}: one
    parameter per item, its value everything after the first '=' (it may hold ';' and '='); the plug-in
    types it (`controllers.registry.typed_params`). An item in the old joined form "a=1;b=2" of the plug-in's
    declared `names` (`_old_joined`) is read as several, with a DeprecationWarning. ValueError naming the option
    for an item that is not NAME=VALUE, or for a NAME given twice (the last would silently win)."""
    out: dict[str, str] = {}
    for option, text in items:
        parts = [text]
        if _old_joined(text, names):
            warnings.warn(f"{option} {text!r}: {OLD_TEXT_WARNING}", DeprecationWarning, stacklevel=2)
            parts = [part for part in text.split(";") if part.strip()]
        for part in parts:
            add_pair(out, part, option)
    return out


def _outputs_summary(out_dir: Path, report: bool) -> str:
    """What a run folder holds, in a few lines, for the end of a run (`report`: with its report and recording)."""
    folder = read_run_folder(out_dir)
    rows = [
        ("config.json, summary.json", f"every parameter, versions, seed; one row per run ({', '.join(folder.labels)})"),
        ("timeseries/*.npz", f"{len(folder.runs)} time series (NumPy archives with units)"),
    ]
    draw = "no plots, report or recording (--data-only): draw them from the saved data"
    if report:
        # +6.7 s (softcbf_mj.outputs.recording: rerun, MuJoCo) and +1.1 s (softcbf_mj.outputs.report: matplotlib) to
        # import, under load: after a run that drew them, never at `softcbf --help`, `list` or a usage error (below too)
        from softcbf_mj.outputs.recording import RECORDING_FILE, viewer_command
        from softcbf_mj.outputs.report import PLOTS_DIR, REPORT_FILE

        recording = out_dir / RECORDING_FILE
        plots = sorted(p.name for p in (out_dir / PLOTS_DIR).glob("*.png"))
        rows += [(f"{PLOTS_DIR}/*.png, {REPORT_FILE}", f"{', '.join(plots)}; summary table"),
                 (RECORDING_FILE, f"{recording.stat().st_size / 1e6:.1f} MB; view it with: {viewer_command(recording)}")]
        draw = "rebuild the plots, report and recording from the saved data"
    width = max(len(name) for name, _ in rows)
    return "\n".join([f"outputs in {out_dir}:", *[f"  {name:<{width}}  {what}" for name, what in rows],
                      f"{draw}: softcbf report {out_dir}"])


def _finished_runs(out_dir: Path) -> list[str]:
    return read_run_folder(out_dir).labels if (out_dir / SUMMARY_FILE).is_file() else []


def _missing_folders(path: Path) -> list[Path]:
    """`path` and those of its parents that do not exist yet, deepest first."""
    return [p for p in (path, *path.parents) if not os.path.lexists(p)]


def _remove_empty(folders: Sequence[Path]) -> None:
    """Remove the folders this run created (deepest first) as far as they are empty."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def _discard(out_dir: Path, created: Sequence[Path]) -> None:
    """Remove what a run that stopped before its first finished run wrote (and the folders
    it created), so that the corrected command is not refused."""
    for path in out_dir.iterdir():
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    _remove_empty(created)


def _stale_outputs(out_dir: Path) -> list[str]:
    """Which of the report and the recording do not show every finished run: missing, or
    older than summary.json (rewritten after each run, before both are rebuilt)."""
    from softcbf_mj.outputs.recording import RECORDING_FILE  # +6.7 s, +1.1 s (rerun, matplotlib): `_outputs_summary`
    from softcbf_mj.outputs.report import REPORT_FILE

    summary_ns = (out_dir / SUMMARY_FILE).stat().st_mtime_ns
    return [name for name in (REPORT_FILE, RECORDING_FILE)
            if not (out_dir / name).is_file() or (out_dir / name).stat().st_mtime_ns < summary_ns]


def _interrupted(out_dir: Path, done: list[str], report: bool) -> int:
    """After Ctrl-C with `done` finished runs: bring the report and the recording up to
    them (a second Ctrl-C skips that; `report` False, `--data-only`: nothing drawn), say what the folder holds,
    return 130."""
    runs = f"{len(done)} finished run(s) ({', '.join(done)})"
    if not report:
        print(f"\ninterrupted: {runs} are in {out_dir} (no report or recording: --data-only)", file=sys.stderr)
        return INTERRUPTED
    from softcbf_mj.outputs.recording import RECORDING_FILE, write_recording  # +6.7 s, +1.1 s: `_outputs_summary`
    from softcbf_mj.outputs.report import write_report

    stale = _stale_outputs(out_dir)
    if stale:
        print(f"\ninterrupted: rebuilding {' and '.join(stale)} for the {runs} (Ctrl-C again to skip)", file=sys.stderr)
        try:
            for name in stale:
                (write_recording if name == RECORDING_FILE else write_report)(out_dir)
        except KeyboardInterrupt:
            print(f"\ninterrupted again: the {runs} are in {out_dir}; {' and '.join(_stale_outputs(out_dir))} "
                  f"may not show them all: rebuild with: softcbf report {out_dir}", file=sys.stderr)
            return INTERRUPTED
    print(f"\ninterrupted: {runs} are in {out_dir}, with their report and recording", file=sys.stderr)
    return INTERRUPTED


def run_scenario(name: str, tokens: Sequence[str], out: str | Path | None, overwrite: bool = False,
                 spawn: bool = False, base: typing.Mapping[str, object] | None = None, report: bool = True) -> int:
    """Run scenario `name` with parameters from `base` (a run configuration file's) and
    `tokens` (which override them) into `out` (default runs/<name>-<time>, made unique); the
    one implementation behind `softcbf run` and `python -m scenarios`. Every parameter is
    checked, and the spec built, before anything is written; the run folder is absolute (module docstring).
    `report`: draw the report and the recording once, at the end (False: `--data-only`, the data alone,
    `scenarios.run_outputs`; `softcbf report DIR` draws them later)."""
    if spawn and not report:
        raise UsageError("--spawn streams the runs to a viewer, --data-only draws nothing: give one of them")
    try:
        scenario = get(name)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    params = scenario_parameters(scenario, tokens, base)
    try:
        spec = scenario.spec.from_flat(params)  # the parameters are typed: the spec's checks only
    except ValueError as exc:  # the vocabulary's and the scenario's checks (scenarios.spec)
        raise UsageError(str(exc)) from None
    try:
        if out is None:
            runs_dir = Path(os.path.abspath(DEFAULT_RUNS_DIR))
            missing = _missing_folders(runs_dir)
            out = new_run_dir(runs_dir, name)
            created = [out, *missing]
        else:
            out = Path(os.path.abspath(out))
            created = _missing_folders(out)
        try:
            out_dir = prepare_out_dir(out, overwrite=overwrite)
        except BaseException:
            _remove_empty(created)
            raise
    except OutputDirError as exc:
        raise UsageError(str(exc)) from None
    try:
        return _run_locked(scenario, spec, out_dir, created, spawn, report)
    finally:
        release_out_dir(out_dir)


VALIDATION_ERRORS = (UsageError, SettingError, PluginLoadError)  # raised while a scenario runs: exit 2 (module docstring)


def _run_locked(scenario: Scenario, spec: object, out_dir: Path, created: list[Path], spawn: bool,
                report: bool) -> int:
    report = report and outputs_on()  # the command line called inside `data_only()` (a test, a study) draws nothing
    try:
        viewer = contextlib.nullcontext("")
        if spawn:  # rerun, matplotlib: +6.7 s to import, only for the viewer, so the run talks at once
            from softcbf_mj.outputs.recording import live_viewer

            viewer = live_viewer()
        start = (heartbeat(f"{scenario.name}: setting up, {spec.run.duration:g} s per run into {out_dir}")
                 if spec.run.progress else contextlib.nullcontext())  # a line within a second
        outputs = once_at_end(out_dir) if report else data_only()  # the report drawn once, at the end, or never
        with viewer as message, outputs, compile_notes(), start:
            if message:
                print(message, file=sys.stderr)
            summary = scenario.function(out_dir, spec)
    except BaseException as exc:
        if not isinstance(exc, (Exception, KeyboardInterrupt)):  # SystemExit & co. from user code the step did not call
            raise RuntimeError(f"{type(exc).__name__} raised while the scenario ran, by user code outside the control "
                               f"step (a filter's attribute?); the run folder {out_dir} is kept as it was") from exc
        if not isinstance(exc, (KeyboardInterrupt, *VALIDATION_ERRORS)):  # a bug: the folder is the evidence
            exc.add_note(f"softcbf: the run folder {out_dir} is kept as it was when this error was raised")
            raise
        done = _finished_runs(out_dir)
        if not done:
            _discard(out_dir, created)
        if isinstance(exc, KeyboardInterrupt):
            if not done:
                print(f"\ninterrupted before the first run finished; nothing kept in {out_dir}", file=sys.stderr)
                return INTERRUPTED
            return _interrupted(out_dir, done, report)
        raise UsageError(str(exc)) from None
    print(_outputs_summary(out_dir, report))
    fault = summary.get("fault") if isinstance(summary, dict) else None
    if fault:
        print(f"error: run {fault['run']!r}: {describe_fault(fault)}; the record up to it is in {out_dir} "
              f"(traceback: {fault_log_name(fault['run'])})", file=sys.stderr)
        return FILTER_FAULT
    return 0


