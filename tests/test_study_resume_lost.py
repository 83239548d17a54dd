"""A Dask scheduler lost mid-study (its process killed: the machine that held it went away) and the study resumed on
a new one: every finished sample is stored exactly once and not run again, and the samples that were in flight are
stored by the resume, never as failed (before, each came back cancelled and was stored as a "CancelledError" row,
which a resume keeps as finished). The same for a falsification through the command line on the journal storage,
the default with --scheduler: each evaluation once in the folder and once, told, in the journal.

The cluster: a `dask scheduler` and a `dask worker --nworkers 2` process started here (a LocalCluster's scheduler
lives in the test's own process and cannot be killed alone). The study: paper_sim, 1 s from t0 = 0, over the
sinusoid's amplitude; every sample alone, so several tasks are in flight when the scheduler dies.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import optuna
import pytest

from softcbf.study import Distribution, Study, StudyStore, run_study
from softcbf.study.cli import main
from softcbf.study.execute import SchedulerLostError
from softcbf.study.store import JOURNAL_FILE, SQLITE_FILE, optuna_storage

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

REPO = Path(__file__).resolve().parents[1]
STUDY = Study("lost", "paper_sim", ("Low",), draws=8, seed=3, fixed={"duration": 1.0},
              vary=(Distribution("amplitude", "uniform", low=20.0, high=150.0),))
STUDY_FILE = """name = "lost"
scenario = "paper_sim"
seed = 3
tunings = ["Low"]
draws = 1
[fixed]
duration = 1.0
[vary.amplitude]
dist = "uniform"
low = 20.0
high = 150.0
"""


@contextlib.contextmanager
def dask_cluster(folder: Path) -> Iterator[tuple[str, subprocess.Popen]]:
    """A scheduler and two single-threaded workers, each its own process group, ended on exit: (address, scheduler)."""
    from distributed import Client

    folder.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    file = folder / "scheduler.json"
    options = dict(cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    started = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                 "--port", "0", "--no-dashboard", "--scheduler-file", str(file)], **options)]
    try:
        deadline = time.monotonic() + 120.0
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        started.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
                                         str(file), "--nworkers", "2", "--nthreads", "1", "--no-dashboard"], **options))
        with Client(scheduler_file=str(file), timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            address = client.scheduler.address
        yield address, started[0]
    finally:
        for process in reversed(started):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)  # the group this test started: the process and its workers
            process.wait()


def kill_after_first_part(results: Path, process: subprocess.Popen) -> threading.Thread:
    """A thread that SIGKILLs `process` once the first part is stored in `results`."""
    def kill() -> None:
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline and not list(results.glob("sample-*.parquet")):
            time.sleep(0.02)
        process.kill()

    thread = threading.Thread(target=kill, daemon=True)
    thread.start()
    return thread


def test_a_lost_scheduler_stores_nothing_for_the_samples_in_flight_and_the_resume_runs_them_once(tmp_path):
    out = tmp_path / "s"
    with dask_cluster(tmp_path / "first") as (address, scheduler):
        killer = kill_after_first_part(out / "results", scheduler)
        with pytest.raises(SchedulerLostError, match=r"lost \d+ sample\(s\) in flight .*continue with --resume"):
            run_study(STUDY, out, scheduler=address, batch_size=1, progress=False)
        killer.join(5)
    before = StudyStore.open(out).load_rows()
    assert 0 < len(before) < STUDY.n_samples
    assert all(r["status"] == "ok" for r in before), [r["error"] for r in before]  # no row for a lost sample
    with dask_cluster(tmp_path / "second") as (address, _):
        outcome = run_study(STUDY, out, scheduler=address, batch_size=1, resume=True, progress=False)
    assert (outcome.skipped, outcome.ran, outcome.failed) == (len(before), STUDY.n_samples - len(before), 0)
    rows = StudyStore.open(out).load_rows()
    assert [r["sample"] for r in rows] == list(range(STUDY.n_samples))  # each sample once
    assert all(r["status"] == "ok" for r in rows)
    assert [r for r in rows if r["sample"] in {b["sample"] for b in before}] == before  # not run again


def test_a_falsification_on_the_journal_resumes_after_its_scheduler_was_lost_each_evaluation_once(tmp_path, capsys):
    study_file = tmp_path / "study.toml"
    study_file.write_text(STUDY_FILE, encoding="utf-8")
    out = tmp_path / "f"
    args = ["falsify", str(study_file), "--out", str(out), "--budget", "6", "--population", "6", "--sampler", "tpe",
            "--baseline", "0", "--batch-size", "1", "--no-progress"]
    with dask_cluster(tmp_path / "first") as (address, scheduler):
        killer = kill_after_first_part(out / "search" / "results", scheduler)
        code = main([*args, "--scheduler", address])
        killer.join(5)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: the Dask scheduler ") and err.count("\n") == 1, err
    assert (out / JOURNAL_FILE).is_file() and not (out / SQLITE_FILE).exists()  # the journal: the default on Dask
    before = StudyStore.open(out / "search").load_rows()
    assert 0 < len(before) < 6 and all(r["status"] == "ok" for r in before), [r["error"] for r in before]
    with dask_cluster(tmp_path / "second") as (address, _):
        assert main([*args, "--scheduler", address, "--resume"]) == 0, capsys.readouterr().err
    result = json.loads((out / "falsify.json").read_text(encoding="utf-8"))
    assert result["evaluations"] == 6 and result["failed"] == 0 and result["storage"] == JOURNAL_FILE
    rows = StudyStore.open(out / "search").load_rows()
    assert [r["sample"] for r in rows] == list(range(6))  # each evaluation once in the folder
    assert [r for r in rows if r["sample"] in {b["sample"] for b in before}] == before  # not run again
    search = optuna.load_study(study_name=result["optuna_study"], storage=optuna_storage(out, "journal", resume=True))
    assert [t.number for t in search.trials] == list(range(6))  # each evaluation once in the journal, told
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in search.trials)
    assert [t.params["amplitude"] for t in search.trials] == [r["param.amplitude"] for r in rows]
    assert [t.value for t in search.trials] == [r["rho_min_meas"] for r in rows]
