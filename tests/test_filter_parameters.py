"""The declared filter parameters (controllers.filter_parameters): one check for check_arguments and
the constructors, through controllers.bounds.check_number, and the docs built from the same table."""

import math

import numpy as np
import pytest

from controllers.energy_governor import PARAMETERS as EERG
from controllers.filter import PARAMETERS as PAPER_CBF
from controllers.filter_parameters import FilterParameter, check_parameters, parameter_docs
from controllers.quasi_static_governor import PARAMETERS as QSG
from controllers.registry import FILTERS, parameters
from vocabulary.settings import Bound, SettingError

DELAY = FilterParameter("a delay", "s", bound=Bound(0.0, 1.0, unit="s"), optional=True)
STEPS = FilterParameter("halvings", "1", int, Bound(1, 52))


def test_values_are_checked_and_normalised():
    assert check_parameters({"d": DELAY, "n": STEPS}, {"d": 1, "n": np.int64(12), "other": "left alone"}) == {"d": 1.0, "n": 12}
    assert DELAY.check("d", np.float32(0.5)) == 0.5 and DELAY.check("d", None) is None
    for value, message in ((-0.01, "d must be in [0, 1] s, got -0.01"), (math.nan, "d must be finite and in [0, 1] s, got nan"),
                           (True, "d must be a number in [0, 1] s, got True"), ("0.1", "d must be a number in [0, 1] s, got '0.1'"),
                           (10**400, "d must be a finite number in [0, 1] s, got an integer of 401 digits")):
        with pytest.raises(SettingError) as info:
            DELAY.check("d", value)
        assert str(info.value) == message
    with pytest.raises(SettingError, match=r"^n must be an integer in \[1, 52\], got 2\.0$"):
        STEPS.check("n", 2.0)
    with pytest.raises(ValueError, match="needs a bound"):
        FilterParameter("x", "m")


def test_every_builtin_parameter_is_declared_once_with_its_bound_in_the_docs():
    """paper-cbf, qsg and e-erg declare every signature parameter (context aside) in their table, and
    `parameter_docs` (softcbf list, docs/parameters.md) is built from it: "meaning; range [unit]"."""
    tables = {"paper-cbf": PAPER_CBF, "qsg": QSG, "e-erg": EERG}
    for name, table in tables.items():
        factory = FILTERS[name]
        assert [p.name for p in parameters(factory)] == list(table), name
        assert factory.parameter_docs == parameter_docs(table)
        for key, declared in table.items():
            doc = factory.parameter_docs[key]
            assert doc.endswith("]") and (declared.bound is None or str(declared.bound) in doc), (name, key, doc)
