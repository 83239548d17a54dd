"""When a scenario draws its run folder's report and recording (plots/, report.md, recording.rrd).

Both are drawn from the folder alone (softcbf_mj.outputs.report, softcbf_mj.outputs.recording: summary.json, config.json
and the time series), so they can be drawn whenever the folder holds finished runs. Three modes, per context (a
ContextVar: a thread or task of its own keeps its own):

- after each finished run (`scenarios.common.save_run`'s default, a scenario function called directly);
- once, when the scenario ends (`once_at_end(out_dir)`: the flat entry point `Scenario.run`, which the command line,
  run files and the API use). A report of k runs is drawn once instead of k times (with 1, 2, …, k runs): the plots
  are most of a short run's CPU time (a 0.2 s `softcbf run paper_sim` of three tunings: 7.5 CPU s, 4.5 drawn once). The
  scenario's end includes an exception after a finished run (a bug of the testbed: the folder is kept as the
  evidence, with the report of its finished runs; a failure to draw it is added to the exception as a note, never
  hides it). Ctrl-C draws nothing here: the command line brings both up to the finished runs after it, which a
  second Ctrl-C skips (scenarios.run);
- never (`data_only()`, or `softcbf run --data-only`): summary.json and the time series only, for studies, tests and
  users who draw them later with `softcbf report DIR`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path

from softcbf_mj.outputs.runio import SUMMARY_FILE, read_run_folder

EACH_RUN, AT_END, NEVER = "each run", "at the end", "never"
_MODE: ContextVar[str] = ContextVar("scenarios_run_outputs", default=EACH_RUN)


@contextlib.contextmanager
def data_only() -> Iterator[None]:
    """Within this context a scenario writes summary.json and the time series only, not the report and the recording
    (1–3 s per tuning): for studies and tests that run many short scenarios. `softcbf report DIR` builds both later
    from the folder."""
    token = _MODE.set(NEVER)
    try:
        yield
    finally:
        _MODE.reset(token)


def outputs_on() -> bool:
    """False within `data_only()`: no report, no recording, no live stream."""
    return _MODE.get() != NEVER


def after_each_run() -> bool:
    """True where a finished run redraws the report and the recording at once (module docstring)."""
    return _MODE.get() == EACH_RUN


def write_outputs(out_dir: Path) -> None:
    """Draw `out_dir`'s report and recording from the folder, when it holds a finished run."""
    if not (out_dir / SUMMARY_FILE).is_file() or not read_run_folder(out_dir).runs:
        return
    # Imported here: rerun and matplotlib, +6.8 s and +4.3 s to import, which listing scenarios
    # and rejecting bad arguments should not pay.
    from softcbf_mj.outputs.recording import write_recording
    from softcbf_mj.outputs.report import write_report

    write_report(out_dir)
    write_recording(out_dir)


@contextlib.contextmanager
def once_at_end(out_dir: Path) -> Iterator[None]:
    """Within: no finished run draws the report and the recording; at the block's end, or when it raises an
    Exception, they are drawn once for the folder's finished runs (module docstring). Inside `data_only()` or
    another `once_at_end` it changes nothing."""
    if _MODE.get() != EACH_RUN:
        yield
        return
    token = _MODE.set(AT_END)
    try:
        yield
    except Exception as error:
        _MODE.reset(token)
        try:
            write_outputs(out_dir)
        except Exception as failure:  # the scenario's own error is the one to see: this one goes with it
            error.add_note(f"the report and recording of the finished runs in {out_dir} were not drawn: "
                           f"{type(failure).__name__}: {failure}")
        raise
    except BaseException:
        _MODE.reset(token)
        raise
    _MODE.reset(token)
    write_outputs(out_dir)
