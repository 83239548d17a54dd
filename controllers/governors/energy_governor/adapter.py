"""The energy governor as a plug-in safety filter (the contract of `controllers.contract.safety_filter`): e-erg and c-erg.

`EnergyGovernor(context, **parameters)` checks its parameters once (`GovernorParams`), builds the model
(`GovernorModel.build`) and holds the states it advances: its own (`state`, what `__call__` steps) and one per
simulation of `filter_batch` (`rows`, by the caller's indices). Every call is
`controllers.governors.energy_governor.steps`: `__call__` is `step` on `state`, `filter_batch` is `step_rows` on the rows'
states, so row b is, bit for bit, the governor whose state it holds called alone. A new row's state is a copy of
`state` as it is then (`GovernorState.copy`); `reset()` starts `state` afresh and forgets every row,
`reset(rows)` starts those rows' states afresh (`new_state`) and touches no other. Refused times
(ControllerInputError) are checked for every row before any state changes.

The constructor's signature is derived from the parameters' declaration (`parameter_signature`): what
`controllers.registry` reads (names, defaults, kinds) and `softcbf list` shows; the c-erg's is the contact
declaration (`ContactGovernorParams`) without `margin_m` and `certificate`.
"""

from __future__ import annotations

import numpy as np

from controllers.cbf.batch import checked_rows
from controllers.governors.energy_governor.certificate import GovernorModel
from controllers.governors.energy_governor.parameters import (CONTACT_FIXED, PARAMETERS, ContactGovernorParams, GovernorParams,
                                                    parameter_kind, parameter_signature)
from controllers.governors.energy_governor.state import GovernorState, new_state
from controllers.governors.energy_governor.steps import apply_time, step, step_rows
from controllers.core.errors import ControllerInputError, NonFiniteCommandError, NonFiniteStateError
from controllers.contract.filter_parameters import parameter_docs
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import (BatchOutput, Estimate, EstimateBatch, FilterContext, FilterOutput,
                                       batch_history_ids)


class EnergyGovernor:
    """The E-ERG as a safety filter (`controllers.governors.energy_governor` for the maths, actions and assumptions).

    Actions: "free" (σ = 1: the target is certified), "governed" (a certified step along
    one of the rays), "hold" (no step nearer the target), "recover" (the held command failed; infeasible when no candidate is
    certified), "stale" (the predictor cannot reach the estimate: older than its history or
    than PREDICTION_HORIZON_S; the held command is kept, infeasible). Bad times raise
    ControllerInputError (`controllers.governors.energy_governor.steps`).
    """

    capabilities = Capabilities(batched=True, rows=True, reset_rows=True)  # a state per simulation
    params_type = GovernorParams
    __signature__ = parameter_signature(GovernorParams)
    parameter_docs = parameter_docs(PARAMETERS)

    def __init__(self, context: FilterContext, **arguments) -> None:
        refused = sorted(set(arguments) - set(self.__signature__.parameters) - {"context"})
        if refused:
            raise TypeError(f"{type(self).__name__} takes no parameter(s) {', '.join(refused)}; valid: "
                            f"{', '.join(name for name in self.__signature__.parameters if name != 'context')}")
        self.params = self.params_type(**arguments)
        self.model = GovernorModel.build(self.params, context)
        self.state = new_state(self.model)
        self.rows: list[GovernorState] = []

    @classmethod
    def check_arguments(cls, arguments: dict[str, object]) -> dict[str, object]:
        """What the constructor refuses of `arguments` (by name), checked without a context (the parameters'
        declarations and the rules between them: `GovernorParams`); returns the checked values. (The context's
        delay and time constant, the table's size and ε against the table are checked at construction.)"""
        given = {name: value for name, value in arguments.items() if name in PARAMETERS}
        params = cls.params_type(**given)
        return {name: getattr(params, name) for name in given}

    def reset(self, rows=None) -> None:
        """Start afresh (vented valves, p = 0; no warm start, no gain estimate) and forget every row of
        `filter_batch`; with `rows` (indices of `filter_batch` rows), those rows' states alone (one simulation's
        new episode), as if their governors were reset."""
        if rows is not None:
            for i in batch_history_ids(rows).tolist():
                self._grow_rows(i + 1)
                self.rows[i] = new_state(self.model)
            return
        self.state = new_state(self.model)
        self.rows = []

    def __call__(self, estimate: Estimate, u_nom) -> FilterOutput:
        """Govern u_nom (N,) hPa at `estimate`: `step` on this governor's own state."""
        self.state, output = step(self.model, self.state, estimate, u_nom)
        return output

    def _grow_rows(self, needed: int) -> None:
        """Rows up to index needed − 1, the new ones copies of this governor's own state as it is now."""
        while len(self.rows) < needed:
            self.rows.append(self.state.copy())

    def filter_batch(self, estimates: EstimateBatch, u_nom, rows=None) -> BatchOutput:
        """B governors at once: row b is, bit for bit, a call of the governor whose state is rows[b] (None: b),
        each a copy of this governor's state at its first call after `reset` (module docstring); u_nom (B, N)
        hPa. A non-finite or misshapen row raises for the whole call (NonFiniteStateError /
        NonFiniteCommandError), a row whose times the governor refuses raises ControllerInputError before any
        state changes, and a call without `rows` with fewer rows than the states held raises ValueError (which
        state is which would be a guess)."""
        n_rows, n = len(estimates), self.model.n
        q = checked_rows("q", estimates.q, (n_rows, n), NonFiniteStateError)
        qd = checked_rows("qd", estimates.qd, (n_rows, n), NonFiniteStateError)
        u_nom = checked_rows("u_nom", u_nom, (n_rows, n), NonFiniteCommandError)
        t = np.asarray(estimates.t, dtype=float).reshape(n_rows).tolist()
        t_capture = np.asarray(estimates.t_capture, dtype=float).reshape(n_rows).tolist()
        ids = batch_history_ids(rows, n_rows, len(self.rows)).tolist()
        self._grow_rows(max(ids) + 1 if ids else 0)
        states = [self.rows[i] for i in ids]
        t_apply = []
        for b, state in enumerate(states):  # every row's times first: a refusal changes no state
            try:
                t_apply.append(apply_time(self.model, t[b], t_capture[b], state.predictor))
            except ControllerInputError as exc:
                raise ControllerInputError(f"row {b}: {exc}") from exc
        outputs = step_rows(self.model, states, q, qd, u_nom, t_capture, t_apply)
        u, action = np.empty((n_rows, n)), np.empty(n_rows, dtype=object)
        infeasible, rho = np.zeros(n_rows, dtype=bool), np.full(n_rows, np.nan)
        for b, out in enumerate(outputs):
            u[b], action[b], infeasible[b], rho[b] = out.u, out.action, out.infeasible, out.rho_pred
        return BatchOutput(u, action.astype(str), infeasible, rho)

    def gain_interval(self, row: int | None = None) -> tuple[float, float]:
        """The certified actuator gain interval [lo, hi] (1): this governor's own, or that of `filter_batch`'s
        row `row` (IndexError for a row it does not hold)."""
        ends = (self.state if row is None else self.rows[row]).ends
        return ends.lo, ends.hi


# what `controllers.registry` converts a parameter's text by (the declared kinds; the signature says the same)
EnergyGovernor.__init__.__annotations__.update({name: parameter_kind(p) for name, p in PARAMETERS.items()})


class ContactEnergyGovernor(EnergyGovernor):
    """Recommended for contact tasks with gain_lo_ratio=0.9, gain_hi_ratio=1.1, gain_estimate=true, gain_noise_rad=0.0015, gain_rest_rad_s=0.003, gain_rest_s=0.2, energy_margin_J=2e-6 (README): the energy governor with the contact certificate (c-erg; e-erg with certificate=contact, contact_aware=true).

    The target is u_nom itself; a command is certified when the arm's energy about its rest shape,
    with the plate's stored energy counted per facet, stays below the least energy to P's boundary
    (`controllers.governors.energy_governor.certificate`, "contact certificate"). The plate's stiffness interval
    [lo, hi] × ψ (`stiffness_lo_ratio`, `stiffness_hi_ratio`) keeps F_true ≤ F_max for any true plate within
    it, and the gain interval [gain_lo_ratio, gain_hi_ratio] × λ for any true actuator gain within it (the same
    module, "actuator gain").
    """

    params_type = ContactGovernorParams
    __signature__ = parameter_signature(ContactGovernorParams, CONTACT_FIXED)
    parameter_docs = {name: doc for name, doc in EnergyGovernor.parameter_docs.items() if name not in CONTACT_FIXED}

    @classmethod
    def check_arguments(cls, arguments: dict[str, object]) -> dict[str, object]:
        """`EnergyGovernor.check_arguments` with the contact certificate, which the c-erg fixes (it takes none)."""
        return {**super().check_arguments(arguments), "certificate": "contact"}
