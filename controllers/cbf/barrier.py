"""Control barrier function of the force-safe set (docs/model.md#control-barrier-function, paper eqns 9–10).

For each row i of the force-safe set P = {r | H' r ≤ h'} (H' shape (P, 2), h' shape
(P,), in the caller's row scaling, so b is in "row-scaled metres"):

    b_i  = h'_i − H'_i r(q)                      (> 0 inside P)
    ḃ_i  = −H'_i J_r q̇,   b̈_i = −H'_i (J_r q̈ + J̇_r q̇)
    B_i  = −ln(b_i / (1 + b_i)) + a_E b_E ḃ_i² / (1 + b_E ḃ_i²)     (defined for b_i > 0)
    ∂B/∂b = −1 / (b (1 + b)),   ∂B/∂ḃ = 2 a_E b_E ḃ / (1 + b_E ḃ²)²
    ∂B/∂q = ∂B/∂b (−H' J_r) + ∂B/∂ḃ (−H' J̇_r),   ∂B/∂q̇ = ∂B/∂ḃ (−H' J_r)

(∂ḃ/∂q = −H' J̇_r: ∂(J_r q̇)/∂q_m = Σ_j ∂²r/∂q_j∂q_m q̇_j = J̇_r[:, m], the Hessian being symmetric.)
With q̈ = q̈₀ + M⁻¹Λ u (q̈₀ the drift), the Lie derivatives collapse to tip terms:

    L_f B = ∇_x B · f = ∂B/∂b ḃ + ∂B/∂ḃ b̈₀   (1/s)
    L_g B = (∂B/∂q̇) M⁻¹ Λ = ∂B/∂ḃ (−H' J_r M⁻¹ Λ)   (1/(s·hPa))

and the filter's constraint is L_f B + L_g B u − γ / B ≤ 0. −ln(b/(1+b)) is evaluated
as log1p(1/b), accurate for large b. Rows with b ≤ `B_MIN` (outside P, or so close
to its boundary that 1/b² would overflow) are reported as not `defined` with B = +inf
and zero L_f B, L_g B: recovery there is the filter's decision, not this module's.

These formulas have one implementation, compiled: `controllers.cbf.kernels.barrier_rows`, which the
filter's kernel runs per state (and whose rows the filter's scalar fallback reads); `barrier_terms`
runs it at one state from Python (tests/test_cbf.py checks it against finite differences of B).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from controllers.model.dynamics import DynamicsEval
from controllers.core.errors import ControllerInputError, NonFiniteCommandError, as_vector
from controllers.contract.filter_parameters import FilterParameter
from controllers.core.bounds import Bound
from controllers.core.lazy_import import lazy_module

cbf_kernels = lazy_module("controllers.cbf.kernels")  # numba loads on the first call (controllers.core.lazy_import)

B_MIN = math.sqrt(sys.float_info.min)  # ≈ 1.5e-154: smallest b treated as inside P

TUNING_PARAMETERS = {
    "a_E": FilterParameter("custom tuning: weight of the velocity term a_E b_E bdot^2 / (1 + b_E bdot^2) of B", "1",
                           bound=Bound(0.0), optional=True),
    "b_E": FilterParameter("custom tuning: velocity scale of that term (bdot in row-scaled m/s)", "s^2/m^2",
                           bound=Bound(0.0, unit="s^2/m^2"), optional=True),
    "gamma": FilterParameter("custom tuning: class-K gain of the constraint L_fB + L_gB u <= gamma/B", "1/s",
                             bound=Bound(0.0, unit="1/s"), optional=True),
}
"""The bounds of a tuning's numbers (`controllers.contract.filter_parameters`), declared once: `Tuning` and the
paper-cbf filter's parameters (None there: a preset's) check them. Also 2 a_E b_E must be finite."""


@dataclass(frozen=True)
class Tuning:
    """Barrier tuning (a_E, b_E, γ), all finite and ≥ 0, with 2 a_E b_E finite.

    a_E, b_E shape the velocity term of B; γ is the class-κ gain of the constraint.
    a_E = b_E = γ = 0 is the paper's "None": the filter is disabled (u* = u_nom).
    """

    name: str
    a_E: float
    b_E: float
    gamma: float

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        for field in ("a_E", "b_E", "gamma"):
            value = TUNING_PARAMETERS[field].check(field, getattr(self, field))
            if value is None:
                raise ValueError(f"{field} must be a number {TUNING_PARAMETERS[field].bound}, got None")
            object.__setattr__(self, field, value)
        if not math.isfinite(2.0 * self.a_E * self.b_E):
            raise ValueError(f"a_E·b_E must be finite (2 a_E b_E enters ∂B/∂ḃ), got a_E = {self.a_E:g}, b_E = {self.b_E:g}")

    @property
    def disabled(self) -> bool:
        """True for a_E = b_E = γ = 0, the paper's unfiltered "None" tuning."""
        return self.a_E == 0.0 and self.b_E == 0.0 and self.gamma == 0.0


TUNINGS = MappingProxyType(
    {
        t.name: t
        for t in (
            Tuning("None", 0.0, 0.0, 0.0),  # paper Table I: filter disabled
            Tuning("Low", 2.0, 2.0, 2.0),  # paper Table I (simulation)
            Tuning("High", 0.2, 0.2, 0.2),  # paper Table I (simulation)
            Tuning("HW-Low", 100.0, 100.0, 100.0),  # paper Table II (hardware)
            Tuning("HW-High", 10.0, 10.0, 10.0),  # paper Table II (hardware)
        )
    }
)


def get_tuning(name: str) -> Tuning:
    """The paper's tuning called `name` (case-insensitive): None, Low, High, HW-Low, HW-High."""
    key = name.strip().lower() if isinstance(name, str) else None
    for tuning_name, tuning in TUNINGS.items():
        if tuning_name.lower() == key:
            return tuning
    raise ValueError(f"unknown tuning {name!r}; valid: {', '.join(TUNINGS)} (or a custom Tuning(name, a_E, b_E, gamma))")


class BarrierTerms(NamedTuple):
    """Per-row barrier quantities at one state; P rows, N inputs."""

    b: np.ndarray  # (P,) row-scaled m
    bdot: np.ndarray  # (P,) row-scaled m/s
    B: np.ndarray  # (P,) +inf where not defined
    LfB: np.ndarray  # (P,) 1/s; 0 where not defined
    LgB: np.ndarray  # (P, N) 1/(s·hPa); 0 where not defined
    dB_db: np.ndarray  # (P,) ∂B/∂b, 1/(row-scaled m); 0 where not defined
    dB_dbdot: np.ndarray  # (P,) ∂B/∂ḃ, s/(row-scaled m); 0 where not defined
    defined: np.ndarray  # (P,) bool: b > B_MIN
    gamma: float

    def constraint(self, u) -> np.ndarray:
        """L_f B + L_g B u − γ/B per row (≤ 0 is safe); +inf where B is not defined."""
        u = as_vector("u", u, self.LgB.shape[1], NonFiniteCommandError)
        return np.where(self.defined, self.LfB + self.LgB @ u - self.gamma / self.B, np.inf)


def facet_table(H, h) -> np.ndarray:
    """H' (P, 2) and h' (P,) as the kernel's rows (P, 3): H'_i (x, y), h'_i; checked for shape and finiteness."""
    H = np.asarray(H, dtype=float)
    if H.ndim != 2 or H.shape[1] != 2:
        raise ControllerInputError(f"H must have shape (P, 2), got {H.shape}")
    h = as_vector("h", h, H.shape[0], ControllerInputError)
    if not np.isfinite(H).all():
        raise ControllerInputError(f"H must be finite, got {H.tolist()}")
    return np.column_stack((H, h))


def barrier_terms(ev: DynamicsEval, H, h, tuning: Tuning) -> BarrierTerms:
    """b, ḃ, B, L_f B, L_g B, ∂B/∂b, ∂B/∂ḃ of every row of (H', h') at the state `ev` was evaluated at: the compiled
    barrier rows (`controllers.cbf.kernels.barrier_rows`, which the filter's kernel runs) at one state."""
    facets = facet_table(H, h)
    p, n = len(facets), len(ev.tip) - 3
    b, bdot, big_b, lfb, d_b, d_bdot = (np.empty(p) for _ in range(6))
    lgb = np.empty((p, n))
    cbf_kernels.barrier_rows(ev.tip_terms, facets, tuning.a_E * tuning.b_E, tuning.b_E, B_MIN, b, bdot, big_b, lfb,
                             lgb, d_b, d_bdot)
    return BarrierTerms(b, bdot, big_b, lfb, lgb, d_b, d_bdot, b > B_MIN, tuning.gamma)


def barrier_gradients(ev: DynamicsEval, H, h, tuning: Tuning) -> tuple[np.ndarray, np.ndarray]:
    """(∂B/∂q, ∂B/∂q̇), each (P, N) (per rad, per rad/s); zero rows where B is not defined."""
    terms = barrier_terms(ev, H, h, tuning)
    H = np.asarray(H, dtype=float)
    h_conj = (H[:, 0] - 1j * H[:, 1])[:, None]  # H'_i · w = Re(conj(H'_i) w) for w = x + i·y
    db_dq = -(h_conj * ev.tip_jac).real  # ∂b/∂q = ∂ḃ/∂q̇ = −H' J_r
    dbdot_dq = -(h_conj * ev.tip_jac_dot).real  # −H' J̇_r
    return terms.dB_db[:, None] * db_dq + terms.dB_dbdot[:, None] * dbdot_dq, terms.dB_dbdot[:, None] * db_dq
