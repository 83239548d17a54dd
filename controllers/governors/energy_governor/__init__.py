"""Energy-certified explicit reference governor (E-ERG, docs/beyond-the-paper.md#filters-beyond-the-paper) with a
state predictor: the e-erg and c-erg filters.

The elastic arm is its own stabilising controller: for a held command u (N,) hPa, its rest shape q_u = K⁻¹Λu
(rad) is an equilibrium, and an energy about q_u can only fall. The governor issues a new command only where
that energy, at the state the command will act from, stays below the least energy that takes the tip out of
the force-safe set P.

The parts, one concept per module (each derives its part of the maths):

- `parameters`: the parameters, one frozen typed declaration (`GovernorParams`; `ContactGovernorParams`, the
  c-erg's defaults), validated once; `RECOMMENDED`, c-erg's recommended setting;
- `certificate`: the certificate (the energy W_u, the escape energy Γ, the contact certificate, the intervals it
  certifies of the arm: actuator gain, arm stiffness, damping, valve lag and command delay; κ and ε, the
  guarantee's assumptions) and the immutable `GovernorModel` built from the parameters and the context;
- `plate_certificate`: what the certificate reads of a box of plates (`PlateCertificate`: P on the nearest plate,
  Γ̲^∂'s sources, the credits and offsets o_j; the plate's offset interval and a sheet derived there), the prior's
  and a learned one's;
- `state`: the per-run `GovernorState` (the predictor's command records, the target governor, the gain
  estimate and the certified gain ends, the plate certificate and the learned set of plates), one per simulation;
- `gain_feedback`: the gain interval narrowed online from the state's estimates;
- `plate_estimate` and `plate_feedback`: the plate's offset and stiffness learned online with a certified set
  (`plate_estimate`: the arm's rest deflection gives the normal force), from the gain feedback's rest samples;
- `pressure_interval`: the acting pressure's interval under a valve lag interval (the certificate's lag term);
- `box`: the certified intervals read from a study file's error box (`box` parameter: the falsifier's box);
- `steps`: `step(model, state, estimate, u_nom) -> (state, output)`, the call (times, the four steps,
  diagnostics, compute time), and `step_rows`, the same for a list of states (a batch);
- `adapter`: `EnergyGovernor` and `ContactEnergyGovernor`, the plug-in filters (`__call__`,
  `filter_batch(..., rows=...)`, `reset(rows=...)`) that hold the model and the states.

Batched (`filter_batch`, the plug-in contract of `controllers.contract.safety_filter`): B rows, each a state of its own
(`GovernorState`), by row position or, given `rows`, by the caller's indices (the batched step's simulations).
Steps 1–2 and 4 run per state, step 3 once for all the rows (per plate certificate: rows that learned different
plates are stepped in groups) in the compiled `energy_kernels.govern_rows`, which
the single call runs with one row: one implementation, row b bit for bit the b-th of B governors called in turn
(tests/test_energy_governor_batch.py, hypothesis over closed-loop-like sequences with resets, subsets of rows,
stale estimates and refused times). A new row's state is a copy of the governor's own state as it is then;
`reset()` forgets every row, `reset(rows)` starts those rows' states afresh. What it saves is step 3's per-call
overhead only: the rows' predictions and certificate states (steps 1–2) stay per row (tools/bench_governors.py
--batch; docs/safety-filter.md).
"""

from controllers.governors.energy_governor.adapter import ContactEnergyGovernor, EnergyGovernor
from controllers.governors.energy_governor.certificate import (TIP_TOLERANCE_M, GovernorModel, energy_kernels,
                                                     ray_may_come_nearer)
from controllers.governors.energy_governor.parameters import (MAX_COMMAND_DELAY_S, PARAMETERS, PREDICTION_HORIZON_S,
                                                    RECOMMENDED, ContactGovernorParams, GovernorParams)
from controllers.governors.energy_governor.state import GovernorState, new_state
from controllers.governors.energy_governor.steps import (DIAGNOSTIC_UNITS, GAIN_DIAGNOSTIC_UNITS, PLATE_DIAGNOSTIC_UNITS, step,
                                              step_rows)

__all__ = ["ContactEnergyGovernor", "ContactGovernorParams", "DIAGNOSTIC_UNITS", "EnergyGovernor",
           "GAIN_DIAGNOSTIC_UNITS", "GovernorModel", "GovernorParams", "GovernorState", "MAX_COMMAND_DELAY_S",
           "PARAMETERS", "PLATE_DIAGNOSTIC_UNITS", "PREDICTION_HORIZON_S", "RECOMMENDED", "TIP_TOLERANCE_M", "energy_kernels", "new_state",
           "ray_may_come_nearer", "step", "step_rows"]
