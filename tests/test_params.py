"""Robot parameters: reference values (docs/model.md#rppr-dynamics), validation messages, file round trip."""

import math

import numpy as np
import pytest

from controllers.model.dynamics import PCCDynamics
from controllers.model.params import RobotParams, mass_condition_bound, reference_robot, uniform_robot


def test_reference_robot_matches_spec():
    p = reference_robot()
    assert p.n_segments == 2
    assert p.lengths == (0.122, 0.122) and p.masses == (0.13, 0.13)
    assert p.stiffness == (1.0, 1.0) and p.damping == (0.07, 0.07)
    np.testing.assert_allclose(p.gains, math.radians(25) / 80, rtol=1e-12)
    np.testing.assert_allclose(p.inertias, 0.13 * 0.122**2 / 12, rtol=1e-12)
    assert p.u_min == (-150.0, -150.0) and p.u_max == (150.0, 150.0)
    # ±25° quasi-static bending at 80 hPa: q = λ u / k.
    np.testing.assert_allclose(p.array("gains") * 80 / p.array("stiffness"), math.radians(25))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"lengths": (0.1, -0.1)}, r"lengths\[1\] must be > 0, got -0.1"),
        ({"masses": (0.1,)}, r"masses must have one value per segment \(2\), got 1"),
        ({"damping": (0.0, -1.0)}, r"damping\[1\] must be >= 0, got -1.0"),
        ({"gains": (float("nan"), 1.0)}, r"gains\[0\] must be finite, got nan"),
        ({"u_min": (10.0, -150.0), "u_max": (5.0, 150.0)}, r"u_min\[0\] must be < u_max\[0\], got u_min=10.0, u_max=5.0"),
        ({"stiffness": "abc"}, r"stiffness must be a sequence of numbers"),
        # C5: these raised ZeroDivisionError (in the dynamics), OverflowError, or passed with a ComplexWarning
        ({"masses": (1e-300, 1e-300)}, r"masses\[0\] must be in \[1e-30, 1e\+30\] kg, got 1e-300"),
        ({"masses": (10**400, 0.13)}, r"masses must be a sequence of numbers \(real\)"),
        ({"gains": (1e-3 + 1e-3j, 1e-3)}, r"gains must be a sequence of numbers \(real\)"),
        ({"u_max": (1e31, 150.0)}, r"u_min\[0\] and u_max\[0\] must be within ±1e\+30 hPa"),
        ({"masses": (1e3, 1e-6)}, r"the mass matrix's condition number may reach 2.28e\+12"),
    ],
)
def test_invalid_values_name_field_value_and_range(change, message):
    with pytest.raises(ValueError, match=message):
        reference_robot().replace(**change)


def test_mass_condition_bound_holds_at_random_configurations():
    """κ(M(q)) ≤ mass_condition_bound for random q, robots and N = 1..4 (the bound the validation uses)."""
    rng = np.random.default_rng(5)
    for _ in range(40):
        n = int(rng.integers(1, 5))
        robot = RobotParams(lengths=rng.uniform(0.01, 1.0, n), masses=10 ** rng.uniform(-3, 1, n), stiffness=np.ones(n),
                            damping=np.zeros(n), gains=np.ones(n), u_min=-np.ones(n), u_max=np.ones(n))
        dyn = PCCDynamics(robot)
        for q in rng.uniform(-3, 3, (5, n)):
            assert np.linalg.cond(dyn.mass_matrix(q)) <= mass_condition_bound(robot)


def test_uniform_robot_validation():
    with pytest.raises(ValueError, match="n_segments must be an integer >= 1, got 0"):
        uniform_robot(0)
    with pytest.raises(ValueError, match="u_limit must be > 0, got -5"):
        uniform_robot(2, u_limit=-5)
    assert uniform_robot(4).n_segments == 4


def test_save_load_round_trip(tmp_path):
    p = uniform_robot(3, stiffness=0.8)
    p.save(tmp_path / "robot.json")
    assert RobotParams.load(tmp_path / "robot.json") == p


def test_from_dict_rejects_unknown_and_missing_fields():
    data = reference_robot().to_dict()
    with pytest.raises(ValueError, match="unknown robot parameter"):
        RobotParams.from_dict({**data, "colour": [1, 2]})
    data.pop("gains")
    with pytest.raises(ValueError, match=r"missing robot parameter\(s\) \['gains'\]"):
        RobotParams.from_dict(data)


def test_replace_recomputes_default_inertia():
    p = reference_robot().replace(masses=(0.26, 0.26))
    np.testing.assert_allclose(p.inertias, 0.26 * 0.122**2 / 12)
