"""The energy governor's per-run state: one `GovernorState` per simulation (a batch row is a state of its own).

A governor's calls read its model (`controllers.governors.energy_governor.certificate.GovernorModel`, never changed) and
change its state, and nothing else:

- `predictor`: the commands this governor issued, with their application times, and the pressures the model's
  valves reach under them (`controllers.model.state_predictor`): the history that predicts x̂ at t_a and u_prev;
- `target_governor`: the parked certificate's quasi-static governor, whose warm start is its previous command
  (None for the contact certificate);
- the gain feedback (`controllers.governors.energy_governor.gain_feedback`): `gain_estimator` (its samples), `gain_previous`
  (t_capture, q, q̇) of the previous estimate, `rest_since` (when the current run at rest began), `gain_window`
  (with `gain_window_s`: the current run of rest blocks' frames and the scatter pooled over the blocks taken) and
  `gain_block` (the index of the block being filled in it);
- `ends`: the certified interval of the rest-shape ratio r = g/c (the actuator gain over the arm stiffness), the
  vertices (g, c) it leaves with the gain's and the stiffness's intervals, and their energy terms (`GainEnds`), and
  `scan_rows`, the recovery's grid rows at those ends, built when a recovery first needs them;
- `pressures`: the acting pressure's interval under the valve lag's interval
  (`controllers.governors.energy_governor.pressure_interval`; None without one);
- `plate`: the plate certificate the calls use (`controllers.governors.energy_governor.plate_certificate.PlateCertificate`:
  the model's prior one, or the one of the plates learned so far), and with `plate_estimate` the learned set
  (`plate_estimate`, a frozen `controllers.governors.energy_governor.plate_estimate.PlateEstimate`, replaced at each sample).

`new_state(model)` is a governor's state at `reset` (valves vented, nothing estimated); `GovernorState.copy()` a
state that continues independently (what changes is copied: the predictor's records, the target governor, the
gain estimator; the rest is never changed in place and is shared). `controllers.governors.energy_governor.steps.step`
advances a state and returns it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from controllers.governors.energy_governor.certificate import GovernorModel, arm_corners
from controllers.governors.energy_governor.plate_certificate import PlateCertificate
from controllers.governors.energy_governor.plate_estimate import PlateEstimate, prior_estimate
from controllers.governors.energy_governor.pressure_interval import PressureInterval
from controllers.governors.gain_estimate import GainEstimator, RestWindow
from controllers.governors.quasi_static_governor import QuasiStaticGovernor
from controllers.model.state_predictor import StatePredictor


@dataclass(frozen=True, eq=False)
class GainEnds:
    """The certified interval [lo, hi] of the rest-shape ratio r = g/c (1; the actuator gain's with the model's
    stiffness), the vertices (g, c) of the set it leaves with the gain's and the arm stiffness's intervals
    (`arm_corners`; (1.0, 1.0) alone is the model), their ratios `gains` = g/c (the command's scale, sorted) and
    stiffness scales `scales` = c, and their energy terms (E, 3, N): c·K, (g/c)·K⁻¹Λ, g²β per end
    (`GovernorModel.energy_terms`)."""

    lo: float
    hi: float
    gains: tuple
    terms: np.ndarray
    scales: tuple
    corners: tuple


def gain_ends(model: GovernorModel, lo: float, hi: float) -> GainEnds:
    """The ends for the ratio interval [lo, hi] with their energy terms (module docstring of
    `controllers.governors.energy_governor.certificate`, "actuator gain" and "arm stiffness")."""
    corners = arm_corners(model.gain_box, model.stiffness_box, (lo, hi))
    return GainEnds(lo, hi, tuple(g / c for g, c in corners),
                    np.array([model.energy_terms(g, c) for g, c in corners], dtype=float),
                    tuple(c for _, c in corners), corners)


@dataclass(eq=False)
class GovernorState:
    """One governor's per-run state (module docstring)."""

    predictor: StatePredictor
    target_governor: QuasiStaticGovernor | None
    gain_estimator: GainEstimator | None
    gain_previous: tuple | None
    rest_since: float | None
    ends: GainEnds
    scan_rows: np.ndarray | None = None
    pressures: PressureInterval | None = None
    gain_window: RestWindow | None = None
    gain_block: int = 0
    plate: PlateCertificate | None = None
    plate_estimate: PlateEstimate | None = None

    def copy(self) -> "GovernorState":
        """A state that continues from this one independently (module docstring)."""
        return GovernorState(self.predictor.copy(), copy.copy(self.target_governor), copy.deepcopy(self.gain_estimator),
                             self.gain_previous, self.rest_since, self.ends, self.scan_rows,
                             None if self.pressures is None else self.pressures.copy(),
                             copy.deepcopy(self.gain_window), self.gain_block, self.plate, self.plate_estimate)

    def set_plate(self, plate: PlateCertificate) -> None:
        """Certify on `plate` from now on (the recovery's grid rows rebuilt when needed)."""
        self.plate, self.scan_rows = plate, None

    def set_gain_ends(self, model: GovernorModel, lo: float, hi: float) -> None:
        """Certify the gain interval [lo, hi] from now on (the recovery's grid rows rebuilt when needed)."""
        self.ends, self.scan_rows = gain_ends(model, lo, hi), None

    def recovery_rows(self, model: GovernorModel) -> np.ndarray:
        """The recovery's grid rows (E, P', G) at the certified ends: c·Γ̲(r·u_c) (`PlateCertificate.grid_rows_at_gain`
        of the state's plate)."""
        if self.scan_rows is None:
            self.scan_rows = np.array([c * self.plate.grid_rows_at_gain(r) for r, c in zip(self.ends.gains, self.ends.scales)])
        return self.scan_rows


def new_state(model: GovernorModel) -> GovernorState:
    """A governor's state at `reset` (module docstring): vented valves since t = −inf, no estimate, the prior gain
    interval. The target governor is a copy of the model's configured one (copies share its memory of commands,
    a function of its inputs); with `gain_window_s` an empty rest window; the model's prior plate, and with
    `plate_estimate` the prior set of plates."""
    estimator = model.new_gain_estimator()
    window = RestWindow(model.n) if estimator is not None and model.params.gain_window_s > 0.0 else None
    return GovernorState(model.new_predictor(), copy.copy(model.target_governor), estimator, None, None,
                         gain_ends(model, *model.gain_prior),
                         pressures=None if model.lag_taus is None else PressureInterval(model.lag_taus, model.n),
                         gain_window=window, plate=model.plate, plate_estimate=new_plate_estimate(model))


def new_plate_estimate(model: GovernorModel) -> PlateEstimate | None:
    """The prior set of plates (`plate_estimate.prior_estimate` of the parameters' intervals), None without
    `plate_estimate`."""
    params = model.params
    if not params.plate_estimate:
        return None
    return prior_estimate(model.context.safe_set.n_facets, (params.stiffness_lo_ratio, params.stiffness_hi_ratio),
                          (params.plate_offset_lo_m, params.plate_offset_hi_m))
