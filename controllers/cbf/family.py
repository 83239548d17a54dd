"""The standard CBF family on the tip's distance to the force-safe set P: exponential, sampled-data and ISSf CBFs.

Three registered filters (`ecbf`, `sdcbf`, `isscbf`, docs/beyond-the-paper.md#the-standard-cbf-family) share
one constraint and one QP, on any number of segments N (the backup CBF is `controllers.cbf.backup`).
Shapes: N inputs (hPa), P' rows of the force-safe set P = {r | H' r ≤ h'} (H' (P', 2), h' (P',), the
rows' own scaling, docs/model.md#force-safe-set).

Barrier and its derivatives (per row i; the tip terms of `controllers.model.dynamics.DynamicsEval.tip`):

    b_i  = h'_i − H'_i r(q)                                   (row-scaled m; > 0 inside P)
    ḃ_i  = −H'_i ṙ = −H'_i J_r q̇                              (row-scaled m/s)
    b̈_i  = −H'_i (r̈₀ + Σ_j ∂r̈/∂u_j u_j) = b̈₀_i − a_i · u        (row-scaled m/s²)
    a_i  = H'_i ∂r̈/∂u  (N,) = −L_g ḃ_i                        (row-scaled m/(s²·hPa))

with r̈₀ = J̇_r q̇ + J_r q̈₀ the tip's acceleration at u = 0 (q̈₀ = −M⁻¹(Cq̇ + Dq̇ + Kq), the drift)
and ∂r̈/∂u = J_r M⁻¹Λ (the input matrix). u enters b first in b̈: b has relative degree two
wherever a_i ≠ 0 (for the PCC arm, wherever J_r M⁻¹Λ has a component along the row's normal;
a_i = 0 at a configuration where no pressure moves the tip along H'_i, e.g. the straight arm
against a facet normal to it: there the row is a condition on the state alone).

Exponential (high-order) CBF, `ecbf` (Nguyen & Sreenath 2016; Xiao & Belta 2019). With the poles
−α₁, −α₂ < 0 (1/s) of the linear comparison system b̈ + k₁ ḃ + k₀ b = 0:

    ψ₁ = ḃ + α₁ b,   ψ₂ = ψ̇₁ + α₂ ψ₁ = b̈ + k₁ ḃ + k₀ b,   k₁ = α₁ + α₂ (1/s), k₀ = α₁ α₂ (1/s²)

and the filter's constraint per row is ψ₂(x, u) ≥ 0, one affine row in u:

    a_i · u ≤ c_i = b̈₀_i + k₁ ḃ_i + k₀ b_i − m_i       (row-scaled m/s²)

(m_i = 0 here; `isscbf` adds its robustness margin). Guarantee (continuous time): if ψ₂ ≥ 0 holds
at every instant and ψ₁(x₀) ≥ 0, b(x₀) ≥ 0, then ψ₁ ≥ 0 for all t (ψ̇₁ ≥ −α₂ ψ₁) and so
b ≥ 0 (ḃ ≥ −α₁ b): the tip stays in P. Assumptions: the model is the plant (M, C, D, K, Λ, the
kinematics), the state is exact, the input is applied continuously, the row is feasible with the
pressure box (relative degree two everywhere on the path; a_i → 0 loses authority) and the initial
state is inside the ψ₁ set (ḃ₀ ≥ −α₁ b₀: not approaching the boundary faster than α₁ b₀). Pole
placement: the gains set how fast b may decay towards the boundary, ‖b(t)‖ ~ e^{−α t}; larger
α lets the tip approach faster and brake later (needing more pressure), smaller α brakes early.
Outside P (b < 0, after a violation) the same row is defined and makes b → 0⁺ exponentially
(the set is attractive), so there is no separate recovery branch.
Sampling: the loop holds u for a control period T and the condition holds at the samples only.
On this arm that matters even at 1 kHz: the second segment's small inertia against its damping is
a mode near −3.7e3 1/s (docs/model.md), so b̈ jumps with every change of u and relaxes within
≈ 0.3 ms. Measured on `softcbf run paper_sim --filter ecbf --duration 5 --frequency 0.1` (PCC
plant = model, exact state, 1 kHz, no limits): with the row active, the mean b̈ over a period was
0.098 m/s² against 0.115 at its start; ψ₂ = 0 at every sample, yet ψ₁ drifted below 0 and b with
it: ρ_min −0.083. The exponential CBF keeps ψ₁ → 0⁺ as the tip approaches, so any such bias is a
violation; a positive margin on ψ₂ (the sampled-data and the ISSf terms below) absorbs it.

Sampled-data CBF, `sdcbf` (after Breeden, Garg & Panagou 2021). With u held over [t_k, t_k + T]
(T = `context.control_dt`), φ_i(t) = ψ₂_i(x(t), u_k) must stay ≥ 0 over the whole period, not only
at t_k; if |φ_i(t) − φ_i(t_k)| ≤ m_i over the period, φ_i(x_k, u_k) ≥ m_i suffices. φ = b̈ + k₁ḃ + k₀b:
its k-terms change by at most T (k₁ |b̈| + k₀ |ḃ|) (Lipschitz bounds from the derivatives at t_k);
its b̈ term is the problem (the fast mode above): b̈ jumps by a·(u_k − u_{k−1}) at t_k and relaxes
within the period. The filter bounds that jump by limiting the command's rate, |u_k − u_{k−1}| ≤ r T
per input (a box in the QP, `rate_hPa_per_s` = r), so |a·Δu| ≤ ‖a‖₁ r T, and asks

    ψ₂_i(x_k, u) ≥ m_i = `lipschitz_factor` · T · (k₁ |b̈_i(ū)| + k₀ |ḃ_i| + ‖a_i‖₁ r)   (row-scaled m/s²)

with b̈ at ū (u_nom clipped to both boxes). Assumptions of the guarantee, beyond the exponential
CBF's: the change of b̈ within a period through the state (the slow jerk) and the difference between
b̈ at ū and at the applied u are covered by `lipschitz_factor` (default 1: not covered); the
relaxation of the mode's jump is at most the jump itself; the state is sampled every T with the
command held. The margin is not a certified bound, and it is conservative: with the reference
arm ‖a‖₁ r T ≈ 1–6 m/s² at the default r = 1000 hPa/s. Measured (command above): the tip stays in
P and never reaches the plate (ρ_min 1.000 with two and three segments: no force); with r = 300
hPa/s, +0.31 with two segments (0.11 N) and −8.9 with three (the rate box cannot brake in time).
The first call after `reset()` takes u_{k−1} = 0 (the arm starts vented).

Input-to-state-safe CBF, `isscbf` (Kolathaya & Ames 2018; Alan, Taylor, He, Orosz & Ames 2021).
A bounded input disturbance d (hPa) on the applied pressure, u_applied = u + d with ‖d‖ ≤ δ
(an unmodelled actuator offset, valve error) makes ψ̇₁ = b̈ + α₁ ḃ gain −a_i · d. The ISSf condition

    ψ₂_i(x, u) ≥ m_i = ‖a_i‖² / ε                     (ε: `epsilon`, row-scaled m/(s²·hPa²))

gives, by Young's inequality −a·d ≥ −‖a‖²/ε − ε‖d‖²/4,
ψ̇₁ + α₂ ψ₁ ≥ −ε δ²/4 under the disturbance: the set ψ₁ ≥ −ε δ²/(4 α₂) is forward invariant, and
with it b ≥ −ε δ²/(4 α₁ α₂) (row-scaled m): the guarantee degrades gracefully, by a violation
that shrinks with ε (smaller ε: more robust, more conservative) and vanishes for d = 0. To keep the
tip inside P itself under ‖d‖ ≤ δ, shrink P by ε δ²/(4 α₁ α₂) (the plate's margin). Assumptions:
the exponential CBF's, with the disturbance entering through the input matrix (a pressure error,
not a model error) and ‖d‖ ≤ δ. On the reference arm ‖a_i‖ ≈ 1–4 m/(s²·hPa) (the light second
segment), so at the default ε = 10 the margin is 0.1–1.6 m/s² and one hPa of disturbance costs at
most ε/(4 α₁ α₂) = 25 mm of b: the term's practical effect here is the margin, which also covers the
sampling bias above (measured on the command above: ρ_min +0.081 at ε = 10, −0.067 at ε = 100).

The QP (`controllers.cbf.qp.solve_lists`, the paper filter's backend and tolerances):

    u* = argmin ‖u − ū‖²  s.t.  a_i · u ≤ c_i (every row),  u_min ≤ u ≤ u_max (when bounded),

ū = u_nom clipped to the limits (for `sdcbf` also to the rate box, which replaces the limits as the
QP's box). Actions: "nominal" (ū meets every row: no QP; u = ū), "qp" (solved),
"clipped" (rows and box together infeasible: the rows alone solved, then clipped to the box;
infeasible flagged), "vent" (the rows are inconsistent among themselves or a row is not finite:
u = 0 clipped; infeasible flagged). The command is finite and within the box in every branch.
Diagnostics: b and ψ₁ per row, ψ₂ − m per row at the returned u (≥ 0: the row holds), m per row.
The sampled-data filter keeps the last command (`reset()` forgets it); the others keep nothing.
"""

from __future__ import annotations

import math
import time

import numpy as np

from controllers.core.bounds import Bound
from controllers.model.dynamics import PCCDynamics
from controllers.core.errors import NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.contract.filter_parameters import FilterParameter, check_parameters, parameter_docs
from controllers.cbf.qp import DEFAULT_BACKEND, available_backends, check_backend, dot_lists, solve_lists
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput

ECBF_PARAMETERS = {
    "alpha1": FilterParameter("pole of the barrier: psi1 = bdot + alpha1 b >= 0", "1/s",
                              bound=Bound(0.0, 1e4, low_open=True, unit="1/s")),
    "alpha2": FilterParameter("pole of its derivative: psi2 = psi1dot + alpha2 psi1 >= 0", "1/s",
                              bound=Bound(0.0, 1e4, low_open=True, unit="1/s")),
    "qp_backend": FilterParameter(f"QP solver ({', '.join(available_backends())})", "", str),
}
"""The exponential CBF's parameters, declared once (`controllers.contract.filter_parameters`)."""

ISS_PARAMETERS = {
    **ECBF_PARAMETERS,
    "epsilon": FilterParameter("ISSf robustness: margin |a|^2/epsilon on psi2; b >= -epsilon delta^2/(4 alpha1 alpha2) "
                               "under a pressure disturbance |d| <= delta", "m/(s^2 hPa^2)",
                               bound=Bound(0.0, 1e12, low_open=True, unit="m/(s^2 hPa^2)")),
}
"""The ISSf CBF's parameters: the exponential CBF's and ε."""

SAMPLED_PARAMETERS = {
    **ECBF_PARAMETERS,
    "rate_hPa_per_s": FilterParameter("rate limit r of the command: |u - u_prev| <= r T per input", "hPa/s",
                                      bound=Bound(0.0, 1e6, low_open=True, unit="hPa/s")),
    "lipschitz_factor": FilterParameter("safety factor on the margin's bound of the constraint's change over one "
                                        "control period", "1", bound=Bound(1.0, 1e3)),
}
"""The sampled-data CBF's parameters: the exponential CBF's, the rate limit and the margin's factor."""

FAMILY_DIAGNOSTIC_UNITS = {
    "b": "row-scaled m (barrier per row of P)",
    "psi1": "row-scaled m/s (bdot + alpha1 b per row)",
    "constraint": "row-scaled m/s^2 (psi2 - margin per row at the returned u; >= 0: the row holds)",
    "margin": "row-scaled m/s^2 (sampled-data or ISSf margin per row; 0 for ecbf)",
    "solve_us": "us (time in QP solves)",
}


def barrier_derivatives(tip: tuple, rows: list[list[float]],
                        hs: list[float]) -> list[tuple[float, float, float, list[float]]]:
    """Per row of (H', h'): (b, ḃ, b̈₀, a) with b̈ = b̈₀ − a·u (module docstring), as Python floats.

    `tip` is `DynamicsEval.tip`: (r, ṙ, r̈₀, ∂r̈/∂u_1, …, ∂r̈/∂u_N), complex x + i·y.
    """
    r, r_dot, r_acc0, *r_acc_u = tip
    out = []
    for (hx, hy), h_i in zip(rows, hs):
        out.append((h_i - (hx * r.real + hy * r.imag), -(hx * r_dot.real + hy * r_dot.imag),
                    -(hx * r_acc0.real + hy * r_acc0.imag), [hx * g.real + hy * g.imag for g in r_acc_u]))
    return out


class ExponentialCBF:
    """The exponential CBF-QP on the PCC model `context.robot` (module docstring), with the ISSf margin
    ‖a_i‖²/ε when `epsilon` is given (None: the plain exponential CBF). The model is the filter's own."""

    capabilities = Capabilities()  # the minimal contract: one instance per simulation

    def __init__(self, context: FilterContext, alpha1: float, alpha2: float, epsilon: float | None = None,
                 qp_backend: str = DEFAULT_BACKEND) -> None:
        given = {"alpha1": alpha1, "alpha2": alpha2, "qp_backend": qp_backend}
        checked = check_parameters(ISS_PARAMETERS, given if epsilon is None else {**given, "epsilon": epsilon})
        self.qp_backend = check_backend(checked["qp_backend"])
        self.alpha1, self.alpha2 = checked["alpha1"], checked["alpha2"]
        self.k1, self.k0 = self.alpha1 + self.alpha2, self.alpha1 * self.alpha2  # 1/s, 1/s²
        self.epsilon = checked.get("epsilon")
        self.n = context.robot.n_segments
        self.safe_set = context.safe_set
        self.dynamics = PCCDynamics(context.robot)
        self._rows = np.array(context.safe_set.H_prime, dtype=float).tolist()
        self._hs = np.array(context.safe_set.h_prime, dtype=float).tolist()
        self._lb = list(context.limits[0]) if context.limits else None
        self._ub = list(context.limits[1]) if context.limits else None
        p = len(self._rows)
        self.diagnostic_layout = DiagnosticLayout({"b": (p,), "psi1": (p,), "constraint": (p,), "margin": (p,),
                                                   "solve_us": ()}, FAMILY_DIAGNOSTIC_UNITS)

    def terms(self, q: list[float], qd: list[float]) -> list[tuple[float, float, float, list[float]]]:
        """`barrier_derivatives` at (q, q̇) (Python float lists) from the filter's model: per row (b, ḃ, b̈₀, a)."""
        return barrier_derivatives(self.dynamics.evaluate_floats(q, qd).tip, self._rows, self._hs)

    def margins(self, terms: list[tuple], u_bar: list[float]) -> list[float]:
        """m_i per row (row-scaled m/s²): 0, or the ISSf term ‖a_i‖²/ε."""
        if self.epsilon is None:
            return [0.0] * len(terms)
        return [dot_lists(a, a) / self.epsilon for _, _, _, a in terms]

    def rows(self, terms: list[tuple], u_bar: list[float]) -> tuple[list[list[float]], list[float], list[float]]:
        """The QP's rows from `terms`: (a_i, c_i, m_i) with ψ₂_i − m_i = c_i − a_i·u ≥ 0 ⇔ a_i·u ≤ c_i."""
        margins = self.margins(terms, u_bar)
        rhs = [bdd0 + self.k1 * bd + self.k0 * b - m for (b, bd, bdd0, _), m in zip(terms, margins)]
        return [a for _, _, _, a in terms], rhs, margins

    def bounds(self) -> tuple[list[float] | None, list[float] | None]:
        """The QP's box on u (hPa): the pressure limits, or None."""
        return self._lb, self._ub

    def _clip(self, u: list[float], lb: list[float] | None, ub: list[float] | None) -> list[float]:
        if lb is None:
            return u
        return [min(max(v, lo), hi) for v, lo, hi in zip(u, lb, ub)]

    def __call__(self, estimate: Estimate, u_nom) -> FilterOutput:
        """The filtered command at the estimate's (q, q̇) (module docstring)."""
        q = as_vector("q", estimate.q, self.n, NonFiniteStateError).tolist()
        qd = as_vector("qd", estimate.qd, self.n, NonFiniteStateError).tolist()
        lb, ub = self.bounds()
        u_bar = self._clip(as_vector("u_nom", u_nom, self.n, NonFiniteCommandError).tolist(), lb, ub)
        ev = self.dynamics.evaluate_floats(q, qd)
        terms = barrier_derivatives(ev.tip, self._rows, self._hs)
        tip = ev.tip[0]
        a_rows, rhs, margins = self.rows(terms, u_bar)
        t0 = time.perf_counter()
        u, action, infeasible = self._solve(u_bar, a_rows, rhs, lb, ub)
        self.sent(u)
        solve_us = (time.perf_counter() - t0) * 1e6
        constraint = [c - dot_lists(a, u) for a, c in zip(a_rows, rhs)]
        values = [*(t[0] for t in terms), *(bd + self.alpha1 * b for b, bd, _, _ in terms), *constraint, *margins,
                  solve_us]
        return FilterOutput(np.array(u), action, infeasible, self.safe_set.margin_at(tip.real, tip.imag),
                            FlatDiagnostics(self.diagnostic_layout, values), FAMILY_DIAGNOSTIC_UNITS)

    def sent(self, u: list[float]) -> None:
        """Told the command returned (the exponential and ISSf CBFs keep no history)."""

    def _solve(self, u_bar: list[float], a_rows: list[list[float]], rhs: list[float], lb: list[float] | None,
               ub: list[float] | None) -> tuple[list[float], str, bool]:
        """(u, action, infeasible): the QP and its fallbacks (module docstring)."""
        if not all(map(math.isfinite, rhs + [v for a in a_rows for v in a])):
            return self._clip([0.0] * self.n, lb, ub), "vent", True
        if all(dot_lists(a, u_bar) <= c for a, c in zip(a_rows, rhs)):
            return u_bar, "nominal", False
        u = solve_lists(u_bar, a_rows, rhs, lb, ub, self.qp_backend)[0]
        if u is not None:
            return self._clip(u, lb, ub), "qp", False
        u = solve_lists(u_bar, a_rows, rhs, None, None, self.qp_backend)[0]
        if u is not None and all(map(math.isfinite, u)):
            return self._clip(u, lb, ub), "clipped", True
        return self._clip([0.0] * self.n, lb, ub), "vent", True


class SampledDataCBF(ExponentialCBF):
    """The sampled-data exponential CBF (module docstring): a rate box around the last command and the margin
    m_i = `lipschitz_factor` · T · (k₁ |b̈_i(ū)| + k₀ |ḃ_i| + ‖a_i‖₁ r) on ψ₂."""

    def __init__(self, context: FilterContext, alpha1: float, alpha2: float, rate_hPa_per_s: float,
                 lipschitz_factor: float, qp_backend: str = DEFAULT_BACKEND) -> None:
        super().__init__(context, alpha1, alpha2, None, qp_backend)
        checked = check_parameters(SAMPLED_PARAMETERS, {"rate_hPa_per_s": rate_hPa_per_s,
                                                        "lipschitz_factor": lipschitz_factor})
        self.rate, self.lipschitz_factor = checked["rate_hPa_per_s"], checked["lipschitz_factor"]
        self.period = float(context.control_dt)
        self._last = [0.0] * self.n

    def reset(self) -> None:
        """The last command is 0 again (the arm starts vented)."""
        self._last = [0.0] * self.n

    def sent(self, u: list[float]) -> None:
        self._last = list(u)

    def bounds(self) -> tuple[list[float], list[float]]:
        """The rate box |u − u_{k−1}| ≤ r T, within the pressure limits when they are on."""
        step = self.rate * self.period
        lb, ub = [v - step for v in self._last], [v + step for v in self._last]
        if self._lb is not None:
            lb = [min(max(v, lo), hi) for v, lo, hi in zip(lb, self._lb, self._ub)]
            ub = [min(max(v, lo), hi) for v, lo, hi in zip(ub, self._lb, self._ub)]
        return lb, ub

    def margins(self, terms: list[tuple], u_bar: list[float]) -> list[float]:
        """m_i = lipschitz_factor · T · (k₁ |b̈_i(ū)| + k₀ |ḃ_i| + ‖a_i‖₁ r) (row-scaled m/s²)."""
        return [self.lipschitz_factor * self.period * (self.k1 * abs(bdd0 - dot_lists(a, u_bar)) + self.k0 * abs(bd)
                                                       + self.rate * sum(map(abs, a)))
                for _, bd, bdd0, a in terms]


def ecbf(context: FilterContext, alpha1: float = 5.0, alpha2: float = 20.0,
         qp_backend: str = DEFAULT_BACKEND) -> ExponentialCBF:
    """Exponential (high-order) CBF on the tip's distance to P: b̈ + (α₁+α₂) ḃ + α₁α₂ b ≥ 0 (controllers.cbf.family)."""
    return ExponentialCBF(context, alpha1, alpha2, None, qp_backend)


def isscbf(context: FilterContext, alpha1: float = 5.0, alpha2: float = 20.0, epsilon: float = 10.0,
           qp_backend: str = DEFAULT_BACKEND) -> ExponentialCBF:
    """Input-to-state-safe exponential CBF: ψ₂ ≥ ‖L_g ψ₁‖²/ε (controllers.cbf.family)."""
    return ExponentialCBF(context, alpha1, alpha2, epsilon, qp_backend)


def sdcbf(context: FilterContext, alpha1: float = 5.0, alpha2: float = 20.0, rate_hPa_per_s: float = 1000.0,
          lipschitz_factor: float = 1.0, qp_backend: str = DEFAULT_BACKEND) -> SampledDataCBF:
    """Sampled-data exponential CBF: ψ₂ ≥ a margin bounding ψ₂'s change over the control period, the command
    rate-limited (controllers.cbf.family)."""
    return SampledDataCBF(context, alpha1, alpha2, rate_hPa_per_s, lipschitz_factor, qp_backend)


def check_sdcbf(arguments: dict[str, object]) -> None:
    """What `sdcbf` would refuse of its (converted) arguments, checked without building it."""
    check_parameters(SAMPLED_PARAMETERS, arguments)
    check_backend(arguments.get("qp_backend", DEFAULT_BACKEND))


def check_ecbf(arguments: dict[str, object]) -> None:
    """What `ecbf` would refuse of its (converted) arguments, checked without building it."""
    check_parameters(ECBF_PARAMETERS, arguments)
    check_backend(arguments.get("qp_backend", DEFAULT_BACKEND))


def check_isscbf(arguments: dict[str, object]) -> None:
    """What `isscbf` would refuse of its (converted) arguments, checked without building it."""
    check_parameters(ISS_PARAMETERS, arguments)
    check_backend(arguments.get("qp_backend", DEFAULT_BACKEND))


ecbf.check_arguments = check_ecbf
ecbf.parameter_docs = parameter_docs(ECBF_PARAMETERS)
isscbf.check_arguments = check_isscbf
isscbf.parameter_docs = parameter_docs(ISS_PARAMETERS)
sdcbf.check_arguments = check_sdcbf
sdcbf.parameter_docs = parameter_docs(SAMPLED_PARAMETERS)
