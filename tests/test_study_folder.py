"""Study runs at scale and under damage: streamed sample indices, corrupted parts, a killed driver.

Samples here run `paper_sim` for a few ms (the PCC plant, no MuJoCo model to compile).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import pytest

from softcbf.study import WALL_CLOCK_COLUMNS, Distribution, Study, StudyStore, execute, run_study
from softcbf.study.execute import PARENT_POLL_S, pending_indices
from softcbf.study.report import write_report
from softcbf.study.store import CorruptPartError, part_name, read_part

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]
ORPHAN_GRACE_S = 5.0  # a worker of a killed driver must be gone by then (it polls every PARENT_POLL_S)


def _quick(draws: int, name: str = "quick") -> Study:
    return Study(name, "paper_sim", ("None", "Low"), draws=draws, seed=5, fixed={"duration": 0.005},
                 vary=(Distribution("plate_stiffness", "uniform", low=9.0, high=14.0),))


def _children(pid: int) -> dict[int, str]:
    """Processes whose parent is `pid`: {pid: command line}."""
    out = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out[int(entry)] = cmdline
    return out


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie (an exited child nobody reaped yet)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


# -- S1: the driver streams the sample indices -----------------------------------


def test_pending_indices_stream_without_building_the_range():
    stream = pending_indices(10**12, {0, 2})
    assert [next(stream) for _ in range(3)] == [1, 3, 4]


def test_a_study_of_a_million_draws_starts_without_materialising_its_indices(tmp_path, monkeypatch):
    """2·10⁶ samples: the old driver built a deque of every index before the first sample (here
    80 MB held by softcbf/study/execute.py, measured; 3.2 GB for 10⁹ draws). Measured when the first
    row is stored: the memory the driver's module holds then stays below 1 MB."""
    held = []
    write = StudyStore.write

    def write_then_stop(self, row):
        path = write(self, row)
        snapshot = tracemalloc.take_snapshot().filter_traces([tracemalloc.Filter(True, execute.__file__)])
        held.append((path.name, sum(stat.size for stat in snapshot.statistics("filename"))))
        raise KeyboardInterrupt  # Ctrl-C after the first stored sample

    monkeypatch.setattr(StudyStore, "write", write_then_stop)
    study = _quick(10**6)
    tracemalloc.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_study(study, tmp_path / "big", workers=1, progress=False)
    finally:
        tracemalloc.stop()
    assert study.n_samples == 2 * 10**6 and [name for name, _ in held] == [part_name(0)]
    assert held[0][1] < 1e6


# -- S3: corrupted parts are detected, named and run again -----------------------


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 4-sample study folder and its rows."""
    out = tmp_path_factory.mktemp("finished") / "study"
    outcome = run_study(_quick(2), out, workers=1, progress=False)
    assert (outcome.ran, outcome.failed) == (4, 0)
    return out, StudyStore.open(out).load_rows()


def _copy(folder: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(folder, tmp_path / "copy"))


def comparable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in rows]


def _flip_bytes(path: Path, step: int):
    """Yield once per `step`-th byte position of `path` with that byte's lowest bit flipped (restored after)."""
    original = path.read_bytes()
    for i in range(0, len(original), step):
        damaged = bytearray(original)
        damaged[i] ^= 0x01
        path.write_bytes(bytes(damaged))
        yield i
    path.write_bytes(original)


def test_every_single_bit_flip_in_a_part_is_detected_or_harmless(finished, tmp_path):
    """Flip bit 0 of every 5th byte of a part in turn: the part is refused naming its file, or it
    still reads back exactly the row that was written (a flip in statistics, padding or unused
    metadata; measured over every byte of a 7.5 kB part: 61 % detected, 39 % harmless, none wrong)."""
    out = _copy(finished[0], tmp_path)
    row = finished[1][1]
    path = out / "results" / part_name(1)
    detected = harmless = 0
    for _ in _flip_bytes(path, 5):
        try:
            back = read_part(path).to_pylist()[0]
        except CorruptPartError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
            detected += 1
        else:
            assert back == row
            harmless += 1
    assert detected > 0 and harmless > 0


def test_resume_runs_corrupted_and_truncated_parts_again(finished, tmp_path):
    out = _copy(finished[0], tmp_path)
    (out / "results" / part_name(1)).write_bytes((out / "results" / part_name(1)).read_bytes()[:-100])  # truncated
    raw = bytearray((out / "results" / part_name(2)).read_bytes())
    raw[len(raw) // 3] ^= 0x10  # one bit inside the data
    (out / "results" / part_name(2)).write_bytes(bytes(raw))
    store = StudyStore.open(out)
    done, corrupted = store.scan()
    assert done == {0, 3} and [p.name for p in corrupted] == [part_name(1), part_name(2)]
    with pytest.raises(CorruptPartError, match=rf"study part {out / 'results' / part_name(1)} is corrupted"):
        write_report(out)
    outcome = run_study(store.study, out, workers=1, resume=True, progress=False)
    assert (outcome.skipped, outcome.ran, outcome.corrupted) == (2, 2, 2)
    assert comparable(store.load_rows()) == comparable(finished[1])
    assert write_report(out).is_file()


def test_cli_report_names_the_corrupted_part_and_exits_2(finished, tmp_path):
    out = _copy(finished[0], tmp_path)
    path = out / "results" / part_name(3)
    raw = bytearray(path.read_bytes())
    raw[raw.index(b"Low")] ^= 0x01  # the tuning in the data page (its statistics come later, in the footer): "Mow"
    path.write_bytes(bytes(raw))
    proc = subprocess.run([sys.executable, "-m", "softcbf.study", "report", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"error: study part {path} is corrupted") and proc.stderr.count("\n") == 1


# -- S4: the workers of a killed driver exit --------------------------------------

DRIVER = """
import sys
from softcbf.study import Distribution, Study, run_study
if __name__ == "__main__":
    study = Study("long", "paper_sim", ("None", "Low"), draws=2, fixed={"duration": 10000.0})
    run_study(study, sys.argv[1], workers=2, progress=PROGRESS)
"""


@pytest.mark.parametrize("progress, children", [(False, 2), (True, 3)], ids=["workers", "workers_and_manager"])
def test_sigkill_of_the_driver_ends_its_workers(tmp_path, progress, children):
    """With the progress line the driver has a third spawned child, the batches' progress manager
    (softcbf.study.execute.start_manager): it ends with the driver too."""
    script = tmp_path / "driver.py"
    script.write_text(DRIVER.replace("PROGRESS", str(progress)), encoding="utf-8")
    driver = subprocess.Popen([sys.executable, str(script), str(tmp_path / "study")], cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 90
        while len(workers) < children and time.monotonic() < deadline and driver.poll() is None:
            workers = [p for p, cmd in _children(driver.pid).items() if "spawn_main" in cmd]
            time.sleep(0.2)
        assert len(workers) == children, "the driver did not start its two workers (and its progress manager)"
        time.sleep(3 * PARENT_POLL_S)  # the workers are past their start-up, running their samples
        assert all(_alive(p) for p in workers)
        driver.send_signal(signal.SIGKILL)
        driver.wait(timeout=10)
        killed = time.monotonic()
        while any(_alive(p) for p in workers) and time.monotonic() - killed < ORPHAN_GRACE_S:
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers)
    finally:
        if driver.poll() is None:
            driver.kill()
        for pid in workers:  # do not leave a worker behind when the test fails
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
