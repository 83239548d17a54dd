"""A governor's fresh state (`controllers.governors.energy_governor.state.new_state`) holds each part in its own field."""

import numpy as np

from controllers.governors.energy_governor import ContactEnergyGovernor, new_state, step
from controllers.governors.energy_governor.pressure_interval import PressureInterval
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext


def test_a_valve_lag_interval_gives_the_state_its_pressure_interval_not_the_recovery_rows():
    """With τ_p in [0.02, 0.1] s the fresh state's `pressures` is the lag's pressure interval (it was passed into
    `scan_rows`, so the certificate ran without the pressure's hull and a recovery read an interval as its grid rows);
    a call then uses it: the acting pressure's interval has advanced to the call."""
    governor = ContactEnergyGovernor(FilterContext.for_robot(reference_robot(), paper_safe_set(), 0.1),
                                     command_delay_s=0.02, actuator_tau_s=0.05, actuator_tau_lo_s=0.02,
                                     actuator_tau_hi_s=0.1, grid_hPa=10.0, escape_spacing_rad=8e-3)
    state = new_state(governor.model)
    assert isinstance(state.pressures, PressureInterval) and state.scan_rows is None
    assert state.gain_window is None
    before = state.pressures.copy()
    state, out = step(governor.model, state, Estimate(0.1, np.zeros(2), np.zeros(2), 0.1), np.full(2, 40.0))
    assert np.all(np.isfinite(out.u)) and state.pressures is not None
    assert not np.array_equal(np.array(state.pressures.at(1.0)), np.array(before.at(1.0)))
