"""One sample in a worker: run the scenario, keep its summary row, never raise for the sample's own errors.

`run_sample(study, index, keep_dir)` resolves sample `index` (`Study.sample`), runs the
scenario with those keyword arguments into a temporary folder (or into `keep_dir`,
which is then kept, with the scenario's report and recording), silences the scenario's
printed table, and returns the sample's row
(columns: `softcbf.study.store`). The scenario must produce exactly one run (one
tuning). An exception inside the scenario becomes a row with status "error" and its
text, so a crashing sample never stops the study; only a dead worker process (a
segfault, a kill) escapes, and the executor handles that. A run that ended on a filter
fault (its row carries `fault`, closedloop.step.FilterFault) is a row with status "fault",
the fault's one line as its error and its fault_type, fault_where, fault_message
(`run_fields`): its figures stop at the fault and are no verdict (a fault is never a pass).

Cost: besides the closed loop, a sample pays for building the scenario (for
`mujoco_contact`: compiling the MuJoCo model) and for writing its summary and time series
to the temporary folder (`scenarios.common.data_only()` skips the per-run report and
recording, 1–3 s per run); `tools/bench_study.py` measures the total against the loop's
`wall_s`.

Batches. `batch_key(study, index)` is the key of the scenario's batch form for sample
`index` (None: the scenario has no batch form or the sample does not batch), and
`run_batch(study, indices, nthread, progress)` runs samples sharing one key in one batched
closed loop (`scenarios.BatchForm`; `progress`, if given, is called with the fraction of the batch's
simulated time done): one row per sample, with the batch form's run
figures (rho_min_pred, rho_min_meas, force_max_N, t_violation_s, infeasible_steps,
u_peak_abs_hPa, refused_steps, sim_s; wall_s and sample_wall_s are the batch's wall
time / B; batch_size), equal to the single run's fields of the same names; the single
run's other figures (chatter, contact figures, …) are not computed. If the batch
raises (e.g. one sample's parameters fail their check), each of its samples is run
alone (`run_sample`), so an error is recorded against the sample that has it.
"""

from __future__ import annotations

import contextlib
import os
import socket
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, Callable

from scenarios import get as get_scenario
from closedloop.step import describe_fault
from scenarios.common import data_only
from softcbf.study.definition import Sample, Study
from softcbf.study.store import FAULT_STATUS, PARAM_PREFIX

_SKIPPED_RUN_FIELDS = ("tuning", "timeseries")  # the row has its own tuning; no time series is kept


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (bool, int, float, str))


def sample_row(sample: Sample) -> dict[str, Any]:
    """The columns that identify `sample`: sample, draw, tuning, scenario_seed, param.*."""
    row: dict[str, Any] = {"sample": sample.index, "draw": sample.draw, "tuning": sample.tuning,
                           "scenario_seed": sample.scenario_seed}
    row.update({PARAM_PREFIX + k: v for k, v in sample.values.items()})
    return row


def run_fields(run: dict[str, Any]) -> dict[str, Any]:
    """A finished run's columns of a sample's row: status ("ok", or "fault" when the run ended on a filter
    fault), error ("" or the fault's one line) and the run's scalar fields (module docstring)."""
    fault = run.get("fault")
    fields: dict[str, Any] = {"status": FAULT_STATUS if fault else "ok", "error": describe_fault(fault) if fault else ""}
    fields.update({k: v for k, v in run.items() if k not in _SKIPPED_RUN_FIELDS and _scalar(v)})
    return fields


def failed_row(study: Study, index: int, error: str) -> dict[str, Any]:
    """The row of a sample whose worker failed outside the scenario (e.g. the process died)."""
    return {**sample_row(study.sample(index)), "status": "error", "error": error, "sample_wall_s": None, "worker": None}


def batch_key(study: Study, index: int) -> Any:
    """The batch-form key of sample `index` (samples with equal keys batch together); None if it does not
    batch (no batch form, or its parameters fail their check: it then runs alone and records the error)."""
    scenario = get_scenario(study.scenario)
    if scenario.batch is None:
        return None
    try:
        return scenario.batch.key(scenario.validate(study.sample(index).kwargs))
    except ValueError:
        return None


def run_batch(study: Study, indices: list[int], nthread: int = 1,
              progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """The rows of samples `indices` (one batch key) run together (module docstring), in that order."""
    start = time.perf_counter()
    scenario = get_scenario(study.scenario)
    samples = [study.sample(i) for i in indices]
    try:
        if scenario.batch is None:
            raise ValueError(f"scenario {study.scenario!r} has no batch form")
        flat = [scenario.validate(s.kwargs) for s in samples]
        runs = scenario.batch.run(flat, nthread) if progress is None else scenario.batch.run(flat, nthread, progress)
    except Exception:  # noqa: BLE001 - run alone, so the error lands on the sample that has it
        return [run_sample(study, i) for i in indices]
    wall = (time.perf_counter() - start) / len(indices)
    worker = f"{socket.gethostname()}:{os.getpid()}"
    return [{**sample_row(s), **run_fields(run), "sample_wall_s": wall, "worker": worker}
            for s, run in zip(samples, runs)]


def run_sample(study: Study, index: int, keep_dir: str | None = None) -> dict[str, Any]:
    """The result row of sample `index` (status "ok" or "fault" with the run's scalar fields, or "error")."""
    start = time.perf_counter()
    sample = study.sample(index)
    row = sample_row(sample)
    try:
        scenario = get_scenario(study.scenario)
        with contextlib.ExitStack() as stack:
            if keep_dir is None:
                folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="softcbf-sample-")))
                stack.enter_context(data_only())  # no per-run report and recording: nobody reads them
            else:
                folder = Path(keep_dir)
                folder.mkdir(parents=True, exist_ok=True)
            with open(os.devnull, "w", encoding="utf-8") as sink, contextlib.redirect_stdout(sink):
                summary = scenario.run(folder, **sample.kwargs)
        runs = summary["runs"]
        if len(runs) != 1:
            raise ValueError(f"scenario {study.scenario!r} returned {len(runs)} runs for one sample; a study needs "
                             f"one run per tuning (check tuning_parameter {study.tuning_parameter!r})")
        row.update(run_fields(runs[0]))
    except Exception as exc:  # noqa: BLE001 - a failing sample is a result, recorded with its error
        tail = "".join(traceback.format_exception(exc)[-3:])
        row.update(status="error", error=f"{type(exc).__name__}: {exc}\n{tail}".strip())
    row["sample_wall_s"] = time.perf_counter() - start
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return row
