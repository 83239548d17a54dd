"""The energy governor (e-erg) and the quasi-static governor (qsg) command what they commanded
before their speed-ups (commit 45eacd9; the benchmark's step case: commit 266e431), in closed
loop on the tests' PCC loop, on a plate that pushes back, through a detected violation, in the
mujoco_contact scenario and in paper_sim's step case.

tests/data/eerg_references_45eacd9.npz and eerg_references_step_266e431.npz hold every call's command
and action (tools/eerg_references.py: the cases, and how the files were made). Here each loop case runs over the first
half of its duration (the loops are causal: its calls are a prefix of the stored ones; every case
governs in that half); `python tools/eerg_references.py` checks the full durations. Tolerance
1e-9 hPa (the speed-ups keep the arithmetic: measured 0), actions exactly.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("eerg_references", REPO / "tools" / "eerg_references.py")
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)
REFERENCE = references.load_references()

# Closed loops of seconds of simulated time: the fast tier (-m "not slow") leaves them out.
pytestmark = pytest.mark.slow
SCALE = 0.5


def _assert_matches(case: str, arrays: dict) -> None:
    for column, got in arrays.items():
        expected = REFERENCE[f"{case}/{column}"][: len(got)]
        assert got.shape == expected.shape and len(got) > 0, (case, column, got.shape, expected.shape)
        if column == "action":
            assert np.array_equal(got, expected), case
        else:
            np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-9, err_msg=case)


@pytest.mark.parametrize("case", list(references.LOOP_CASES))
def test_loop_commands_match_the_reference(case):
    arrays = references.run_loop_case(case, SCALE)
    assert np.any(arrays["action"] == references.ACTIONS.index("governed")), case  # the case exercises the governor
    _assert_matches(case, arrays)


def test_recovery_commands_match_the_reference():
    arrays = references.run_recovery_case()
    assert np.any(arrays["action"] == references.ACTIONS.index("recover"))
    _assert_matches("recovery", arrays)


@pytest.mark.parametrize("case", list(references.SCENARIO_CASES))
def test_scenario_commands_match_the_reference(case):
    _assert_matches(case, references.run_scenario_case(case))
