"""Run-output contract (docs/run-outputs.md): output folders, summary.json, time series."""

import json
import os
import stat
import subprocess
import sys

import numpy as np
import pytest

from softcbf_mj.outputs.runio import (
    RUN_MARKER,
    OutputDirError,
    RunFolderError,
    SummaryWriter,
    atomic_path,
    load_timeseries,
    new_run_dir,
    prepare_out_dir,
    release_out_dir,
    safe_name,
    save_timeseries,
)


def test_existing_nonempty_folder_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "run"
    SummaryWriter(prepare_out_dir(out), "demo", {})
    release_out_dir(out)
    (out / "keep.txt").write_text("data")
    with pytest.raises(OutputDirError, match="not empty.*--overwrite"):
        prepare_out_dir(out)
    assert (out / "keep.txt").read_text() == "data"
    prepare_out_dir(out, overwrite=True)
    assert [p.name for p in out.iterdir()] == [RUN_MARKER]
    release_out_dir(out)


def test_overwrite_refuses_a_folder_softcbf_did_not_write(tmp_path):
    """L1: --overwrite used to delete any folder (keep.txt, the checkout...)."""
    (tmp_path / "keep.txt").write_text("data")
    with pytest.raises(OutputDirError, match="is not a run folder .*--overwrite only replaces folders written by softcbf"):
        prepare_out_dir(tmp_path, overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]  # nothing deleted, no marker left behind
    with pytest.raises(OutputDirError, match="must name a folder"):
        prepare_out_dir("", overwrite=True)


@pytest.mark.parametrize("where", ["cwd", "parent", "home"])
def test_overwrite_never_empties_the_working_folder_its_parents_or_home(tmp_path, monkeypatch, where):
    """L1: even a run folder is not emptied when it is (or holds) the working folder, or is home."""
    run = tmp_path / "run"
    SummaryWriter(prepare_out_dir(run), "demo", {})
    release_out_dir(run)
    inside = run / "sub"
    inside.mkdir()
    monkeypatch.chdir({"cwd": run, "parent": inside, "home": tmp_path}[where])
    monkeypatch.setenv("HOME", str(run))
    reason = {"cwd": "it is the working folder", "parent": "the working folder lies inside it",
              "home": "it is the home folder"}[where]
    with pytest.raises(OutputDirError, match=f"refusing to overwrite .*: {reason}"):
        prepare_out_dir(run, overwrite=True)
    assert (run / "summary.json").is_file() and inside.is_dir()


def test_a_locked_run_folder_is_refused_to_another_process_until_released(tmp_path):
    """L2: two runs into one folder used to both succeed and mix their files."""
    out = tmp_path / "run"
    prepare_out_dir(out)
    other = [sys.executable, "-c", "import sys; from softcbf_mj.outputs.runio import prepare_out_dir, OutputDirError\n"
             "try:\n    prepare_out_dir(sys.argv[1])\nexcept OutputDirError as e:\n    sys.exit(str(e))", str(out)]
    res = subprocess.run(other, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1 and f"{out} is in use by another run (process {os.getpid()})" in res.stderr
    assert prepare_out_dir(out) == out  # this process may take it again
    release_out_dir(out)
    res = subprocess.run(other, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_a_killed_run_leaves_no_stale_lock(tmp_path):
    """The lock is an flock: it dies with its process, whatever the marker file says."""
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from softcbf_mj.outputs.runio import prepare_out_dir\n"
                               "prepare_out_dir(sys.argv[1]); print('locked', flush=True); time.sleep(600)", str(out)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputDirError, match=f"in use by another run \\(process {holder.pid}\\)"):
            prepare_out_dir(out)
    finally:
        holder.kill()
        holder.wait()
    assert prepare_out_dir(out) == out
    release_out_dir(out)


def test_new_run_dirs_are_unique_within_one_second(tmp_path):
    """L2: the default runs/<scenario>-<time> collided for runs started in the same second."""
    folders = [new_run_dir(tmp_path / "runs", "paper_sim") for _ in range(3)]
    assert len(set(folders)) == 3 and all(f.is_dir() and not any(f.iterdir()) for f in folders)
    assert all(f.name.startswith("paper_sim-") for f in folders)


def test_json_and_timeseries_get_the_mode_umask_gives_new_files(tmp_path):
    """L8: config.json and summary.json were 0600 (mkstemp), every other output 0644."""
    old = os.umask(0o022)
    try:
        SummaryWriter(tmp_path, "demo", {"duration": 1.0})
        save_timeseries(tmp_path, "r", {"t": np.zeros(3)}, {"t": "s"})
    finally:
        os.umask(old)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in tmp_path.rglob("*") if p.is_file()}
    assert modes == {"config.json": 0o644, "summary.json": 0o644, "r.npz": 0o644}


def test_an_interrupted_write_leaves_no_temp_file(tmp_path):
    """L7: Ctrl-C while a file is written leaves neither a torn file nor its temp file."""
    target = tmp_path / "force.png"
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"\x89PNG half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_a_truncated_timeseries_is_a_run_folder_error_naming_the_file(tmp_path):
    """L4: a truncated .npz raised zipfile.BadZipFile."""
    path = save_timeseries(tmp_path, "r", {"t": np.arange(1000.0)}, {"t": "s"})
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(RunFolderError, match=f"time series {path} cannot be read"):
        load_timeseries(path)


def test_empty_or_missing_folder_is_accepted_and_file_is_refused(tmp_path):
    assert prepare_out_dir(tmp_path / "a" / "b").is_dir()
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputDirError, match="not a folder"):
        prepare_out_dir(tmp_path / "f", overwrite=True)


def test_summary_is_rewritten_after_every_run_with_nonfinite_as_null(tmp_path):
    writer = SummaryWriter(tmp_path, "demo", {"duration": 1.0})
    first = json.loads((tmp_path / "summary.json").read_text())
    assert first["runs"] == [] and first["versions"]["softcbf_mj"]
    writer.add_run({"tuning": "Low", "rho_min_pred": np.float64(0.5), "filter_us_p99": float("nan")})
    data = json.loads((tmp_path / "summary.json").read_text())
    assert data["runs"] == [{"tuning": "Low", "rho_min_pred": 0.5, "filter_us_p99": None}]
    assert not list(tmp_path.glob(".*tmp"))


def test_timeseries_round_trip_with_units(tmp_path):
    series = {"t": np.arange(5) * 1e-3, "q": np.ones((5, 2)), "flag": np.array([0, 1, 0, 1, 1], bool)}
    path = save_timeseries(tmp_path, "HW High/1", series, {"t": "s", "q": "rad", "flag": "bool"})
    assert path.name == "HW_High_1.npz"
    arrays, units = load_timeseries(path)
    for key, value in series.items():
        np.testing.assert_array_equal(arrays[key], value)
    assert units == {"t": "s", "q": "rad", "flag": "bool"}


def test_timeseries_rejects_ragged_or_unitless_signals(tmp_path):
    with pytest.raises(ValueError, match="different lengths"):
        save_timeseries(tmp_path, "r", {"t": np.zeros(3), "q": np.zeros(4)}, {"t": "s", "q": "rad"})
    with pytest.raises(ValueError, match="lack units"):
        save_timeseries(tmp_path, "r", {"t": np.zeros(3)}, {})


def test_safe_name():
    assert safe_name("None") == "None"
    assert safe_name("a b/c") == "a_b_c"
    assert safe_name("///") == "run"
