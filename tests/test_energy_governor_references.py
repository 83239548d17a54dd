"""The energy governors (e-erg, c-erg) and the quasi-static governor (qsg) command the stored results, in closed
loop on the tests' PCC loop, on a plate that pushes back, through a detected violation, in the mujoco_contact
scenario and in paper_sim's step case: results compared within stated tolerances, not a pin on floats.

tests/data/eerg_references.npz holds every call's command and action and every tick's ρ and contact force
(tests/references/eerg_references.py: the cases, how the file is regenerated when a change moves it, and the tolerances
COMMAND_TOL_HPA, RHO_TOL, FORCE_TOL_N with their derivation; actions exactly). Here each loop case runs over the
first half of its duration (the loops are causal: its calls are a prefix of the stored ones; every case governs
in that half); `python tests/references/eerg_references.py` checks the full durations.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from references import eerg_references as references  # noqa: E402

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
            np.testing.assert_allclose(got, expected, rtol=0.0, atol=references.TOLERANCES[column],
                                       err_msg=f"{case} {column}")


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


def test_the_comparison_flags_what_moves_beyond_the_tolerances():
    """`compare` and `within_tolerances` (the tool's verdict): a command moved past COMMAND_TOL_HPA, an action
    flipped, or ρ moved past RHO_TOL fails; movements within them pass; a column the reference lacks is left out."""
    stored = {"c/u": np.zeros((3, 2)), "c/action": np.array([0, 1, 1]), "c/rho": np.ones(5)}
    near = {"c/u": np.full((3, 2), 0.5 * references.COMMAND_TOL_HPA), "c/action": np.array([0, 1, 1]),
            "c/rho": np.ones(5) + 0.5 * references.RHO_TOL, "c/force": np.zeros(5)}
    assert references.within_tolerances(references.compare(near, stored))
    for key, value in (("c/u", np.full((3, 2), 2 * references.COMMAND_TOL_HPA)), ("c/action", np.array([0, 1, 2])),
                       ("c/rho", np.ones(5) - 2 * references.RHO_TOL)):
        assert not references.within_tolerances(references.compare({**near, key: value}, stored)), key
