"""The paper's filter through the one control step gives the stored time series, in the three clocks and every
tuning: a result, compared within a stated tolerance, not a pin on floats.

tests/data/loop_references.npz holds every 10th row of the wall-time-free columns of short runs
(tests/references/loop_references.py: the cases, how the file is regenerated when a change moves it, and the tolerance
RTOL, ATOL in each column's unit with its derivation). Boolean and integer columns must match exactly.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from scenarios import get
from scenarios.common import data_only
from softcbf_mj.outputs.runio import load_timeseries

sys.path.insert(0, str(Path(__file__).parent))
from references import loop_references as references  # noqa: E402

CASES, COLUMNS, DECIMATE = references.CASES, references.COLUMNS, references.DECIMATE
REFERENCE = np.load(references.REFERENCE_FILE)


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
            if expected.dtype.kind in "biu":
                assert np.array_equal(got, expected), (case, run["tuning"], column)
            else:
                np.testing.assert_allclose(got, expected, rtol=references.RTOL, atol=references.ATOL,
                                           err_msg=f"{case} {run['tuning']} {column}")


def test_the_comparison_reports_the_largest_movement():
    """`differences` (the CHANGELOG's figures) finds a moved float and a flipped flag, and refuses other files."""
    old = {"a/Low/u": np.array([[1.0, 2.0], [3.0, 4.0]]), "a/Low/active": np.array([True, False])}
    new = {"a/Low/u": np.array([[1.0, 2.5], [3.0, 3.9]]), "a/Low/active": np.array([True, True])}
    result = references.differences(old, new)
    assert result["u"]["max_abs"] == pytest.approx(0.5) and result["active"]["differing"] == 1
    with pytest.raises(ValueError, match="different series"):
        references.differences(old, {"a/Low/u": new["a/Low/u"]})
