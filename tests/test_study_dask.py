"""Studies on Dask (a LocalCluster on the loopback interface, 2 worker processes) and worker
deaths: the same rows as the local pool, and every sample stored exactly once when a worker
is killed mid-study (Dask and the local pool).

The study: `mujoco_contact`, 4 draws × 2 tunings of 0.6 s from the sinusoid's peak; a sample
takes ≈ 0.3 s of CPU, so several are in flight when a worker is killed.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import threading
import time
from pathlib import Path

import distributed
import pytest

import softcbf.study.execute
from softcbf.cli import main
from softcbf.study import WALL_CLOCK_COLUMNS, Distribution, Study, StudyStore, run_study

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

STUDY = Study("kill", "mujoco_contact", ("None", "Low"), draws=4, seed=11, fixed={"t0": 25.0, "duration": 0.6},
              vary=(Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
                    Distribution("facet_offset", "uniform", low=-0.003, high=0.002)))


def comparable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in rows]


def kill_after_first_part(out: Path, pids, timeout: float = 60.0) -> threading.Thread:
    """A thread that SIGKILLs one worker process (pids() gives the candidates) once the first row is stored."""
    state = {}

    def kill() -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if list((out / "results").glob("sample-*.parquet")):
                victim = pids()[0]
                os.kill(victim, signal.SIGKILL)
                state["killed"] = victim
                return
            time.sleep(0.02)

    thread = threading.Thread(target=kill, daemon=True)
    thread.state = state
    thread.start()
    return thread


def assert_complete(out: Path) -> list[dict]:
    names = sorted(p.name for p in (out / "results").glob("sample-*.parquet"))
    assert names == [f"sample-{i:07d}.parquet" for i in range(STUDY.n_samples)]
    rows = StudyStore.open(out).load_rows()
    assert [r["sample"] for r in rows] == list(range(STUDY.n_samples))
    return rows


@pytest.fixture(scope="module")
def local_rows(tmp_path_factory):
    """The study on the local pool (2 workers), with one pool worker killed mid-study."""
    out = tmp_path_factory.mktemp("local") / "study"
    killer = kill_after_first_part(out, lambda: [p.pid for p in multiprocessing.active_children()])
    outcome = run_study(STUDY, out, workers=2, progress=False)
    killer.join(1)
    assert "killed" in killer.state and outcome.ran == STUDY.n_samples
    rows = assert_complete(out)
    assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]  # in flight once: resubmitted
    return rows


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    with LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


def test_dask_gives_the_same_rows_as_the_local_pool(local_rows, client, tmp_path):
    # local_rows first: its killer picks among this process's children, which must not yet include the cluster's workers
    outcome = run_study(STUDY, tmp_path / "s", client=client, progress=False)
    assert (outcome.backend, outcome.workers, outcome.ran, outcome.failed) == ("dask", 2, 8, 0)
    rows = assert_complete(tmp_path / "s")
    assert comparable(rows) == comparable(local_rows)
    assert len({r["worker"] for r in rows}) == 2  # both workers took part


def test_dask_worker_killed_mid_study_every_sample_once(local_rows, client, tmp_path):
    out = tmp_path / "s"
    killer = kill_after_first_part(out, lambda: list(client.run(os.getpid).values()))
    outcome = run_study(STUDY, out, client=client, progress=False)
    killer.join(1)
    assert "killed" in killer.state and outcome.ran == STUDY.n_samples
    rows = assert_complete(out)
    assert comparable(rows) == comparable(local_rows)  # rescheduled samples reproduce exactly


STUDY_FILE = """name = "unreachable"
scenario = "paper_sim"
seed = 1
tunings = ["None"]
draws = 1
[fixed]
duration = 0.01
[vary.plate_stiffness]
dist = "uniform"
low = 10.0
high = 12.0
"""


@pytest.mark.parametrize("address, reason", [
    ("tcp://127.0.0.1:1", "Timed out trying to connect to tcp://127.0.0.1:1 after 1 s"),
    ("tcp://nowhere.invalid:1", "Timed out trying to connect"),
    ("http://host:8786", "unknown address scheme 'http'"),
    ("tcp://", "missing port number"),
])
def test_a_scheduler_that_does_not_answer_is_one_line_exit_2_and_no_folder(tmp_path, capfd, monkeypatch, address, reason):
    """N12: `softcbf study run FILE --scheduler tcp://nowhere:1` gave a traceback after Dask's 30 s."""
    monkeypatch.setattr(softcbf.study.execute, "SCHEDULER_CONNECT_TIMEOUT_S", 1.0, raising=False)
    study = tmp_path / "study.toml"
    study.write_text(STUDY_FILE, encoding="utf-8")
    start = time.perf_counter()
    assert main(["study", "run", str(study), "--scheduler", address, "--out", str(tmp_path / "out")]) == 2
    assert time.perf_counter() - start < 10.0
    err = capfd.readouterr().err
    assert err.startswith(f"error: cannot connect to the Dask scheduler {address!r}: ") and err.count("\n") == 1, err
    assert reason in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_the_default_connect_timeout_is_short():
    start = time.perf_counter()
    with pytest.raises(ValueError, match="after 5 s"):
        softcbf.study.execute.connect_scheduler("tcp://127.0.0.1:1")
    assert time.perf_counter() - start < 10.0


def test_a_scheduler_address_runs_the_study(local_rows, client, tmp_path):
    """The address is tried, then used; before the fix this raised 'IOLoop is closed' at the end (the executor was
    shut down after its client closed)."""
    outcome = run_study(STUDY, tmp_path / "s", scheduler=client.scheduler.address, samples=2, progress=False)
    assert (outcome.backend, outcome.ran, outcome.failed) == ("dask", 2, 0)
    rows = StudyStore.open(tmp_path / "s").load_rows()
    assert [(r["sample"], r["status"]) for r in rows] == [(0, "ok"), (1, "ok")]
    assert [r["rho_min_meas"] for r in rows] == [r["rho_min_meas"] for r in local_rows[:2]]


def test_a_local_pool_whose_worker_cannot_exit_is_closed_in_bounded_time():
    """`close_local_pool`: a worker that does not exit at shutdown (here busy in a task for 1000 s; in the wild, blocked
    on the call-queue lock of a worker killed while holding it) is terminated after the timeout instead of being
    joined forever, as `shutdown(wait=True)` would."""
    import concurrent.futures

    from softcbf.study.execute import close_local_pool

    pool = concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
    pool.submit(time.sleep, 1000.0)
    deadline = time.monotonic() + 30.0
    while not pool._processes and time.monotonic() < deadline:  # the worker is spawned on submit  # noqa: SLF001
        time.sleep(0.01)
    (worker,) = pool._processes.values()  # noqa: SLF001
    time.sleep(0.5)  # the worker has taken the task
    start = time.monotonic()
    close_local_pool(pool, timeout_s=1.0)
    assert time.monotonic() - start < 10.0
    assert not worker.is_alive()


FALSIFY_FILE = """name = "recipe"
scenario = "paper_sim"
seed = 5
tunings = ["Low"]
draws = 1
[fixed]
duration = 1.0
[vary.amplitude]
dist = "uniform"
low = 20.0
high = 150.0
"""


def test_the_cluster_recipe_on_a_local_cluster_worker_killed_then_resumed_each_evaluation_once(client, tmp_path, capsys):
    """docs/studies.md#beyond-one-machine with this LocalCluster standing in for dask-jobqueue's SLURMCluster:
    `study falsify --scheduler ADDRESS` keeps its trials in the journal (the default on Dask); a worker killed
    mid-search has its task rerun; the resumed search runs only new evaluations, and each is stored and told once."""
    import optuna

    from softcbf.study.store import JOURNAL_FILE, SQLITE_FILE, optuna_storage

    study_file = tmp_path / "study.toml"
    study_file.write_text(FALSIFY_FILE, encoding="utf-8")
    out = tmp_path / "f"
    args = ["study", "falsify", str(study_file), "--out", str(out), "--population", "4", "--sampler", "tpe",
            "--baseline", "0", "--batch-size", "1", "--no-progress", "--scheduler", client.scheduler.address]
    killer = kill_after_first_part(out / "search", lambda: list(client.run(os.getpid).values()))
    assert main([*args, "--budget", "4"]) == 0, capsys.readouterr().err
    killer.join(1)
    assert "killed" in killer.state
    assert (out / JOURNAL_FILE).is_file() and not (out / SQLITE_FILE).exists()
    before = StudyStore.open(out / "search").load_rows()
    assert [(r["sample"], r["status"]) for r in before] == [(i, "ok") for i in range(4)]
    assert main([*args, "--budget", "8", "--resume"]) == 0, capsys.readouterr().err
    rows = StudyStore.open(out / "search").load_rows()
    assert [r["sample"] for r in rows] == list(range(8)) and rows[:4] == before  # once each; the first 4 not rerun
    name = json.loads((out / "falsify.json").read_text(encoding="utf-8"))["optuna_study"]
    trials = optuna.load_study(study_name=name, storage=optuna_storage(out, "journal", resume=True)).trials
    assert [t.number for t in trials] == list(range(8))
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    assert [t.params["amplitude"] for t in trials] == [r["param.amplitude"] for r in rows]
