"""The PCC model's per-step terms at B states at once, any N (docs/model.md#one-implementation, docs/model.md#rppr-dynamics).

A thin front of the compiled kernels of `controllers.model.pcc_model` (the one implementation, which
`PCCDynamics` runs at B = 1): for B states (q, q̇), each (B, N) rad, rad/s, the segment ends, the
tip r, ṙ, J_r and the tip terms the barrier reads (r̈ at u = 0, ∂r̈/∂u_j), M (kg·m²),
f = C q̇ + D q̇ + K q (N·m), M⁻¹ and q̈ = M⁻¹(Λu − f). A row's arithmetic does not depend on
the other rows, so row b equals `PCCDynamics` at state b bit for bit (tested). Complex numbers are
points x + i·y of the plane (m).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Sequence

import numpy as np

from controllers.model.params import RobotParams
from controllers.core.lazy_import import lazy_module

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads on the first kernel call (controllers.core.lazy_import)

if TYPE_CHECKING:
    from controllers.model.pcc_model import ModelLayout


class BatchTerms(NamedTuple):
    """Model terms at B states: the kernel's `kin` (B, ·) complex and `dyn` (B, ·) float rows; views by name."""

    kin: np.ndarray
    dyn: np.ndarray
    layout: ModelLayout

    @property
    def ends(self) -> np.ndarray:
        """Segment ends p_1..p_N: (B, N) complex (m)."""
        return self.kin[:, self.layout.ends]

    @property
    def tip(self) -> np.ndarray:
        """r: (B,) complex (m)."""
        return self.kin[:, self.layout.tip_terms.start]

    @property
    def tip_vel(self) -> np.ndarray:
        """ṙ: (B,) complex (m/s)."""
        return self.kin[:, self.layout.tip_terms.start + 1]

    @property
    def tip_drift_acc(self) -> np.ndarray:
        """r̈ at u = 0: (B,) complex (m/s²)."""
        return self.kin[:, self.layout.tip_terms.start + 2]

    @property
    def tip_input_acc(self) -> np.ndarray:
        """∂r̈/∂u_j = (M⁻¹ J_r)_j λ_j: (B, N) complex (m/s² per hPa)."""
        return self.kin[:, self.layout.tip_terms.start + 3 : self.layout.tip_terms.stop]

    @property
    def tip_jac(self) -> np.ndarray:
        """J_r: (B, N) complex (m/rad)."""
        return self.kin[:, self.layout.tip_jac]

    @property
    def mass(self) -> np.ndarray:
        """M: (B, N, N) (kg·m²)."""
        n = self.layout.ends.stop
        return self.dyn[:, self.layout.mass].reshape(-1, n, n)

    @property
    def mass_inv(self) -> np.ndarray:
        """M⁻¹: (B, N, N) (1/(kg·m²))."""
        n = self.layout.ends.stop
        return self.dyn[:, self.layout.mass_inv].reshape(-1, n, n)

    @property
    def force(self) -> np.ndarray:
        """C q̇ + D q̇ + K q: (B, N) (N·m)."""
        return self.dyn[:, self.layout.force]


class BatchDynamics:
    """`PCCDynamics`'s per-step terms for B states at once (module docstring).

    `params`: one `RobotParams` for every state, or one per state (B of them, the same N:
    per-simulation model parameters, e.g. a mismatch study's true arms).
    """

    def __init__(self, params: RobotParams | Sequence[RobotParams]) -> None:
        self.params = params
        self.parameter_rows = pcc_model.parameter_rows(params)
        self.n = (params if isinstance(params, RobotParams) else params[0]).n_segments
        self.layout = pcc_model.ModelLayout.of(self.n)
        self._last: tuple = (None, None, None)  # (q, q̇, BatchTerms) of the last `terms` call

    def terms(self, q: np.ndarray, qd: np.ndarray) -> BatchTerms:
        """The model terms at (q, q̇), each (B, N) finite; no input checks.

        The last call's terms are kept: a plant and a filter sharing this object evaluate
        each reported state once (as `PCCDynamics.model_terms` does for one state).
        """
        last_q, last_qd, last = self._last
        if last is not None and np.array_equal(q, last_q) and np.array_equal(qd, last_qd):
            return last
        q, qd = np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(qd, dtype=float)
        terms = BatchTerms(*pcc_model.model_terms(q, qd, self.parameter_rows), self.layout)
        self._last = (q.copy(), qd.copy(), terms)
        return terms

    def keep(self, q: np.ndarray, qd: np.ndarray, kin: np.ndarray, dyn: np.ndarray) -> BatchTerms:
        """Take (kin, dyn), rows computed elsewhere by `pcc_model` at (q, q̇) (B, N) with these parameters
        (a batch plant's integrator), as the last call's terms (`terms`); returns them."""
        terms = BatchTerms(kin, dyn, self.layout)
        self._last = (np.array(q, dtype=float), np.array(qd, dtype=float), terms)
        return terms

    def acceleration(self, terms: BatchTerms, u: np.ndarray) -> np.ndarray:
        """q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q): (B, N) rad/s², as `PCCDynamics.acceleration_from_terms`; u (B, N) hPa."""
        return pcc_model.accelerations(terms.dyn, self.parameter_rows, np.ascontiguousarray(u, dtype=float))
