"""Run-output contract (docs/run-outputs.md): output folders, summary.json, time series."""

import json

import numpy as np
import pytest

from softcbf_mj.runio import (
    OutputDirError,
    SummaryWriter,
    load_timeseries,
    prepare_out_dir,
    safe_name,
    save_timeseries,
)


def test_existing_nonempty_folder_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("data")
    with pytest.raises(OutputDirError, match="not empty.*--overwrite"):
        prepare_out_dir(out)
    assert (out / "keep.txt").read_text() == "data"
    prepare_out_dir(out, overwrite=True)
    assert list(out.iterdir()) == []


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
