"""The paper's filter through the one control step gives the time series it gave before
the step became a plug-in (commit 7ba3f9c), in the three clocks and every tuning.

tests/data/loop_references_7ba3f9c.npz holds every 10th row of the wall-time-free
columns of short runs (tools/loop_references.py: the cases, and how the file was made
on a worktree of 7ba3f9c). Tolerance: rtol 1e-9, atol 1e-9 in each column's unit
(hPa, rad, N, ...), not bit identity: fixes of the filter's own numerical tolerances
may move commands by ~1e-9 hPa. Boolean and integer columns must match exactly.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from scenarios import get
from scenarios.common import data_only
from softcbf_mj.runio import load_timeseries

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("loop_references", REPO / "tools" / "loop_references.py")
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)
CASES, COLUMNS, DECIMATE = references.CASES, references.COLUMNS, references.DECIMATE
REFERENCE = np.load(REPO / "tests" / "data" / "loop_references_7ba3f9c.npz")


@pytest.mark.parametrize("case", list(CASES))
def test_paper_filter_time_series_match_the_reference(case, tmp_path):
    scenario, params = CASES[case]
    with data_only():
        summary = get(scenario).run(tmp_path, progress=False, **params)
    labels = [run["tuning"] for run in summary["runs"]]
    assert labels == params["tunings"].split(",")
    for run in summary["runs"]:
        series, _ = load_timeseries(tmp_path / run["timeseries"])
        for column in COLUMNS:
            expected = REFERENCE[f"{case}/{run['tuning']}/{column}"]
            got = np.asarray(series[column])[::DECIMATE]
            assert got.shape == expected.shape, (case, run["tuning"], column)
            if expected.dtype == bool:
                assert np.array_equal(got, expected), (case, run["tuning"], column)
            else:
                np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9, err_msg=f"{case} {run['tuning']} {column}")
