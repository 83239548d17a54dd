"""The paper's CBF safety filter: state estimate + nominal command → safe command (docs/model.md#control-barrier-function).

A plug-in of `controllers.contract.safety_filter`: `CBFFilter(estimate, u_nom)` returns a
`FilterOutput` whose diagnostics hold the CBF's own terms (CBF_DIAGNOSTIC_UNITS);
`CBFFilter.step(x, u_nom)` is the same computation on x = [q; q̇] returning the typed
`CBFResult`. It uses the estimate's q and q̇ as the state now (no prediction over the
estimate's age: the paper's design).

Every control step, with x = [q; q̇] (rad, rad/s) and u_nom (N,) hPa:

    u* = argmin ‖u − ū‖²  s.t.  L_gB_i u ≤ γ/B_i − L_fB_i   (every row i of P)
                                u_min ≤ u ≤ u_max            (when pressure_limits)

with ū = clip(u_nom, u_min, u_max), u_nom saturated to the box, when pressure_limits (ū =
u_nom otherwise). The box is a hard row, so a u_nom beyond it can only be met at its
saturation; and the QP's rounding grows with |ū| (`controllers.cbf.qp.tolerances`): before the
saturation, u_nom = (1e17, 1e17) hPa made the native solver return a command violating its CBF
row by 124 /s labelled "qp", and daqp a "slack" command flagged infeasible on a feasible problem.
Below, "u_nom" in the branches means ū.

One implementation of the QP: every call, one state (B = 1) or a batch (`filter_batch`), runs the
compiled kernel of the batched filter (`controllers.cbf.batch.PaperCBFKernel`, `controllers.cbf.kernels`):
the barrier rows, the "disabled", "nominal", "qp" and "recovery" branches, the QP solved exactly by
enumerating its active sets (derivation: `controllers.cbf.batch`). The scalar path (`controllers.cbf.qp`'s
active-set QP over Python floats, on the barrier and quasi-static rows the kernel computed at that state:
one implementation of the rows, `controllers.cbf.kernels.barrier_rows`) is the documented fallback for the
states the kernel hands back: no
feasible candidate ("slack", the rest target, "vent"), a row that is not finite, and QP states beyond the
enumeration's reach (more than `controllers.cbf.batch.ENUMERATION_MAX_CANDIDATES` candidates: N ≥ 6 with one
facet and the box). Both agree where both apply: the same label, commands within 1e-9 hPa
(tests/test_cbf_batch.py; `step(..., scalar=True)` runs the scalar path for every state).

Defined behaviour in every state (the result says which branch ran, in `action`):
- "disabled": tuning None (a_E = b_E = γ = 0): u = u_nom, clipped to the limits when
  they are on (the paper's unfiltered run).
- "nominal": u_nom already satisfies every row and bound; u = u_nom, no QP solved.
- "qp": the QP above was solved and its answer passed the post-check (solve_lists' own
  acceptance test, repeated here only if clipping to the limits moved u): every defined CBF
  row holds within the QP's acceptance tolerance (`controllers.cbf.qp.tolerances`: 1e-6 hPa ·
  (1 + max|u_min|, |u_max|) on unit rows, plus the rounding floor 1e-13 · max|u_nom|; so
  ≈ 1.5e-4 hPa with the reference limits, whatever u_nom). An answer that fails it is
  treated as infeasible ("slack"). (Before, the tolerance grew with |u_nom|: u_nom = 1e12 hPa
  returned the box corner with the barrier row violated by 79 hPa as "qp".)
- "recovery": some row has b_i ≤ 0 (the estimate is outside P, B undefined). For those
  rows the barrier row is replaced by a quasi-static row: the rest configuration of
  the command, q_ss = K⁻¹Λu, must lie inside P by ε_i (`recovery_margin` m times
  ‖H'_i‖), linearised about the current q:
      b_i − H'_i J_r(q) (K⁻¹Λu − q) ≥ ε_i.
  The arm's own stiffness and damping then carry the tip back inside, where the CBF
  rows take over. Rows still inside P keep their CBF rows; `recovery` is flagged.
  (Rules based on the instantaneous b̈, e.g. an exponential CBF on b or 'maximise b̈',
  settle at a box corner whose rest shape is outside P: the tip stays outside for
  tens of seconds. docs/model.md#control-barrier-function reports the same; tests/test_filter.py checks this rule
  over time.)
  Rest target: when the quasi-static rows cannot hold even as hard rows of the slack QP
  below — e.g. the straight arm at rest before a vertical wall, where H'_i J_r = 0 makes the
  row all zeros — u is the rest target nearest to u_nom: a command of a grid over
  [u_min, u_max] (`rest_targets`, ≤ REST_GRID_POINTS points) whose exact rest tip
  r(K⁻¹Λu) is inside every row of P by ε_i. It cannot deadlock: it is a fixed command whose
  rest shape is inside P, which the arm's stiffness and damping approach. Measured (wall
  x ≤ 0.2 m, q = 0, u_nom = 0, PCC plant, limits on): the tip, 29.7 mm outside P, is
  inside after 0.126 s with Low and HW-High (before: "slack" with u = 0 for 3000 of 3000
  steps, never inside); afterwards u_nom = 0 keeps pulling the rest shape outside and the
  tip cycles around P's boundary (b ≥ −3.0 mm Low, −4.2 mm HW-High; 91 % / 96 % of the
  steps after re-entry have b < 0, most of them "recovery"). That is the CBF's exit, not the
  recovery's: started at rest with its rest shape 1, 5 or 10 mm inside P and u_nom = 0, the
  CBF alone ("qp", "slack" under the box, one "nominal") lets the tip out within 11–39 ms
  and down to b = −3.1…−10.0 mm, before any recovery step (tests/test_filter.py). Near
  rest L_gB ∝ ḃ vanishes (docs/model.md#control-barrier-function), so the CBF acts only once
  the tip moves outwards, too late at 1 kHz within ±150 hPa; keeping the tip inside after
  re-entry would need a different barrier after re-entry, not a different recovery. `infeasible` is
  flagged if the target violates a defined CBF row or a CBF row is not finite (below).
  With no target inside P the slack QP without hard rows runs, as below.
- "slack": the rows and the bounds cannot all hold (infeasible), or a CBF row is not
  finite (L_fB, L_gB or γ/B overflowed, e.g. at |q̇| ≳ 1e154 rad/s; such a row is
  replaced by its quasi-static row, never dropped, and `constraint` reads +inf there).
  The filter solves the least-violation QP over (u, s), one slack per row in
  hPa-equivalent units (rows normalised to unit norm in u):
      min ‖u − u_nom‖² + w ‖s‖²  s.t.  â_i u − s_i ≤ b̂_i,  s ≥ 0,  bounds on u,
      and, as hard rows, the quasi-static rows above for every row of P,
  with w = `slack_weight` (default 1e6: 1 hPa of violation costs as much as 1000 hPa of
  deviation from u_nom). The hard quasi-static rows stop the least-violation command
  from settling at a box corner whose rest shape is outside P (the trap of docs/model.md#control-barrier-function);
  if they cannot hold with the bounds, they are dropped (outside P: the rest target
  first). `infeasible` is flagged and `slack` holds max_i s_i. If the filter's backend
  fails on this QP, the native solver solves it: OSQP reports it "primal infeasible
  inaccurate" (in the identity-Hessian form the slack variable √w s reaches ≈ 6.6e5
  against a 1e-3 coefficient) and used to vent on every infeasible step. Measured on
  `softcbf run paper_sim --duration 10 --frequency 0.1 --tunings High --pressure-limits
  true --qp-backend qpsolvers:osqp`: chatter 61/s → 1.40/s (native: 1.40/s), 1011 infeasible
  steps (native 1010), filter p99 70 ms → 14 ms (OSQP still spends its 4000 iterations
  before the fallback; native: 4 ms), real-time factor 0.2 → 0.7.
- "vent": only if every solver fails outright: u = 0 hPa clipped to the limits (the arm
  relaxes towards its rest shape). `infeasible` is flagged.
The command is finite and within the bounds in every branch.
`paper_cbf(context, tuning, ...)` is the registry's factory ("paper-cbf"): the paper's
presets by name, or tuning="custom" with a_E, b_E and γ. A non-finite state or
nominal command raises NonFiniteStateError / NonFiniteCommandError (controllers.core.errors).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from controllers.cbf.barrier import B_MIN, TUNING_PARAMETERS, TUNINGS, Tuning, get_tuning
from controllers.cbf.batch import CODE_LABELS, SCALAR_BELOW, KernelOutput, PaperCBFKernel, RecoveryRows, cbf_qp_batch
from controllers.model.dynamics_batch import BatchDynamics
from controllers.model.dynamics import PCCDynamics
from controllers.core.errors import NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.contract.filter_parameters import FilterParameter, check_parameters, parameter_docs, value_text
from controllers.model.params import RobotParams
from controllers.model.pcc import step_kinematics
from controllers.cbf.qp import DEFAULT_BACKEND, available_backends, check_backend, dot_lists, row_norm, solve_lists, tolerances
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import BatchOutput, Estimate, EstimateBatch, FilterContext, FilterOutput
from controllers.core.bounds import Bound

PARAMETERS = {
    "tuning": FilterParameter(f"preset ({', '.join(TUNINGS)}) or 'custom' (a_E, b_E, gamma below)", "", str),
    **TUNING_PARAMETERS,
    "qp_backend": FilterParameter(f"QP solver ({', '.join(available_backends())})", "", str),
    "recovery_margin": FilterParameter("quasi-static recovery: rest shape inside P by this much", "m",
                                       bound=Bound(0.0, unit="m")),
    "slack_weight": FilterParameter("infeasible rows: cost of 1 hPa of violation vs 1 hPa of deviation, squared "
                                    "(beyond 1e12 the slack's column 1/√w is below the solvers' tolerances)", "1",
                                    bound=Bound(0.0, 1e12, low_open=True)),
}
"""The paper-cbf filter's parameters, declared once (`controllers.contract.filter_parameters`): `check_paper_cbf`
(its `check_arguments`) and the constructors check them (a_E, b_E, gamma through `Tuning`)."""

REST_GRID_POINTS = 1024
"""Grid size (at most) of the rest-target search over the pressure box (`CBFFilter.rest_targets`)."""

ACTIONS = ("disabled", "nominal", "qp", "recovery", "slack", "vent")

CBF_DIAGNOSTIC_UNITS = {
    "b": "row-scaled m (barrier value per row of P)",
    "B": "1 (barrier function per row; inf where b <= 0)",
    "constraint": "1/s (L_fB + L_gB u - gamma/B per row at the returned u; <= 0 is safe)",
    "active": "bool (per row: active in the QP)",
    "recovery": "bool (some row has b <= 0: quasi-static recovery rows)",
    "slack": "hPa (max row violation accepted by the slack branch)",
    "solve_us": "us (time in QP solves)",
}


@dataclass(frozen=True, eq=False)
class CBFResult:
    """One filter step. Arrays: u, u_nom (N,) hPa; b, B, constraint, active (P,) over rows of P.

    constraint: L_fB + L_gB u − γ/B at the returned u (≤ 0 is safe; +inf where B is
    undefined). rho_pred: predicted safety margin of the estimate, min over facets.
    solve_us: time spent in QP solves (µs). slack: max row violation accepted by the
    "slack" branch (hPa-equivalent), else 0.
    """

    u: np.ndarray
    u_nom: np.ndarray
    b: np.ndarray
    B: np.ndarray
    constraint: np.ndarray
    active: np.ndarray
    infeasible: bool
    recovery: bool
    action: str
    rho_pred: float
    solve_us: float
    slack: float


class CBFFilter:
    """CBF-QP safety filter for the PCC model `params` and force-safe set `safe_set`.

    `dynamics`: the model object to evaluate (default: a new `PCCDynamics(params)`). A
    simulation whose plant integrates the same model may pass the plant's, so that the
    filter reuses the plant's evaluation at the state it reports (`PCCDynamics.model_terms`).
    """

    def __init__(
        self,
        params: RobotParams,
        safe_set: ForceSafeSet,
        tuning: Tuning,
        pressure_limits: bool = True,
        qp_backend: str = DEFAULT_BACKEND,
        recovery_margin: float = 1e-3,
        slack_weight: float = 1e6,
        dynamics: PCCDynamics | None = None,
        batch_dynamics: BatchDynamics | None = None,
    ) -> None:
        check_backend(qp_backend)
        checked = check_parameters(PARAMETERS, {"recovery_margin": recovery_margin, "slack_weight": slack_weight})
        recovery_margin, slack_weight = checked["recovery_margin"], checked["slack_weight"]
        if dynamics is not None and dynamics.params != params:
            raise ValueError("dynamics must be a PCCDynamics of the same params as the filter")
        if batch_dynamics is not None and batch_dynamics.params != params:
            raise ValueError("batch_dynamics must be a BatchDynamics of the same params as the filter")
        self.params = params
        self.safe_set = safe_set
        self.tuning = tuning
        self.pressure_limits = bool(pressure_limits)
        self.qp_backend = qp_backend
        self.recovery_margin = float(recovery_margin)
        self.slack_weight = float(slack_weight)
        self.dynamics = PCCDynamics(params) if dynamics is None else dynamics
        self._batch_dynamics = batch_dynamics
        self.n = params.n_segments
        self._H = np.array(safe_set.H_prime, dtype=float)
        self._h = np.array(safe_set.h_prime, dtype=float)
        self._rows, self._hs = self._H.tolist(), self._h.tolist()
        self._recovery_rows = RecoveryRows.of(params, safe_set, self.recovery_margin)  # K⁻¹Λ and ε_i
        self._eps = list(self._recovery_rows.margins)
        self._lb_list = list(params.u_min) if self.pressure_limits else None
        self._ub_list = list(params.u_max) if self.pressure_limits else None
        self._static_gain = list(self._recovery_rows.static_gain)  # K⁻¹Λ, rad/hPa
        self._rest_targets: np.ndarray | None = None
        self._kernel = PaperCBFKernel(self.n, safe_set, tuning, *((np.array(params.u_min), np.array(params.u_max))
                                      if self.pressure_limits else (None, None)), self._recovery_rows)
        self._kernel_out = self._kernel.outputs(1)  # one state's results, overwritten by each call (read as lists)
        p = len(self._rows)
        self.diagnostic_layout = DiagnosticLayout(
            {"b": (p,), "B": (p,), "constraint": (p,), "active": (p,), "recovery": (), "slack": (), "solve_us": ()},
            CBF_DIAGNOSTIC_UNITS, frozenset({"active", "recovery"}))

    @property
    def enabled(self) -> bool:
        """False for the paper's None tuning (u = u_nom)."""
        return not self.tuning.disabled

    @property
    def capabilities(self) -> Capabilities:
        """Batched (`filter_batch`); a pass-through under the paper's None tuning."""
        return Capabilities(batched=True, passthrough=not self.enabled)

    def _clip(self, u: list[float]) -> list[float]:
        """u within the pressure limits when they are on (like np.clip: NaN stays NaN)."""
        if not self.pressure_limits:
            return u
        return [min(max(v, lo), hi) for v, lo, hi in zip(u, self._lb_list, self._ub_list)]

    def _slack_qp(self, u_nom: list[float], rows: list[list[float]], rhs: list[float],
                  hard: list[tuple[list[float], float]]) -> tuple[list[float] | None, float]:
        """Least-violation QP over z = (u, √w s) with hard rows `hard`; returns (u, max s) or (None, nan).

        If the filter's backend fails on it, the native solver gets the same problem (module docstring).
        """
        n, p = self.n, len(rows)
        root_w = math.sqrt(self.slack_weight)
        minus_eye = [[-1.0 if k == i else -0.0 for k in range(p)] for i in range(p)]
        a_rows, b_rows = [], []
        for row, c, e in zip(rows, rhs, minus_eye):  # â_i u − s_i ≤ b̂_i
            norm = max(row_norm(row), 1e-12)
            a_rows.append([v / norm for v in row] + [v / root_w for v in e])
            b_rows.append(c / norm)
        a_rows += [[0.0] * n + e for e in minus_eye]  # s ≥ 0
        b_rows += [0.0] * p
        a_rows += [a + [0.0] * p for a, _ in hard]
        b_rows += [c for _, c in hard]
        if self.pressure_limits:
            eye = [[1.0 if k == j else 0.0 for k in range(n + p)] for j in range(n)]
            a_rows += eye + [[-v for v in row] for row in eye]
            b_rows += self._ub_list + [-v for v in self._lb_list]
        z0 = u_nom + [0.0] * p
        z = solve_lists(z0, a_rows, b_rows, None, None, self.qp_backend)[0]
        if z is None and self.qp_backend != "native":
            z = solve_lists(z0, a_rows, b_rows, None, None, "native")[0]
        if z is None:
            return None, math.nan
        return z[:n], max(z[n:]) / root_w

    def rest_targets(self) -> np.ndarray:
        """Commands (K, N) hPa on a grid over [u_min, u_max] whose rest tip r(K⁻¹Λu) is inside every row of P by ε_i.

        The grid has max(2, ⌊REST_GRID_POINTS^(1/N)⌋) points per input, box corners included;
        it is built on first use (measured 12–23 ms CPU for N = 1..4) and kept. Empty when no rest
        shape of the grid is inside P.
        """
        if self._rest_targets is None:
            per_axis = max(2, int(REST_GRID_POINTS ** (1.0 / self.n)))
            axes = [np.linspace(lo, hi, per_axis) for lo, hi in zip(self.params.u_min, self.params.u_max)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, self.n)
            lengths, rest_velocity, keep = list(self.params.lengths), [0.0] * self.n, []
            for u in grid.tolist():
                tip = step_kinematics([g * v for g, v in zip(self._static_gain, u)], rest_velocity, lengths).tip
                if all(h_i - (hx * tip.real + hy * tip.imag) > e
                       for (hx, hy), h_i, e in zip(self._rows, self._hs, self._eps)):
                    keep.append(u)
            self._rest_targets = np.array(keep, dtype=float).reshape(-1, self.n)
        return self._rest_targets

    def _rest_target(self, u_nom: list[float]) -> list[float] | None:
        """The rest target nearest to u_nom (clipped to [u_min, u_max] first), or None when there is none."""
        targets = self.rest_targets()
        if not len(targets):
            return None
        ref = np.clip(u_nom, self.params.u_min, self.params.u_max)
        return targets[int(np.argmin(((targets - ref) ** 2).sum(axis=1)))].tolist()

    def __call__(self, estimate: Estimate, u_nom) -> FilterOutput:
        """The plug-in call: `step` at x = [estimate.q; estimate.qd], as a FilterOutput (built
        straight from the step's floats: no CBFResult in between) whose diagnostics are
        `FlatDiagnostics` in `diagnostic_layout` (the keys of CBF_DIAGNOSTIC_UNITS)."""
        x = as_vector("x", np.concatenate((estimate.q, estimate.qd)), 2 * self.n, NonFiniteStateError)
        u_nom = as_vector("u_nom", u_nom, self.n, NonFiniteCommandError)
        u, b, big_b, constraint, active, infeasible, recovery, action, rho_pred, solve_us, slack = self._step_floats(
            x.tolist(), u_nom.tolist())
        diagnostics = FlatDiagnostics(self.diagnostic_layout, [*b, *big_b, *constraint, *(
            [False] * len(b) if active is None else active), recovery, slack, solve_us])
        return FilterOutput(u_nom if u is None else np.array(u), action, infeasible, rho_pred, diagnostics,
                            CBF_DIAGNOSTIC_UNITS)

    def filter_batch(self, estimates: EstimateBatch, u_nom) -> BatchOutput:
        """B states at once: `controllers.cbf.batch.cbf_qp_batch` (the "disabled", "nominal", "qp" and
        "recovery" branches compiled; infeasible states through `__call__`), the same
        actions as B calls and commands within 1e-9 hPa. Batches smaller than SCALAR_BELOW
        go state by state; where the enumeration has more than ENUMERATION_MAX_CANDIDATES candidates
        (N ≥ 6 with one facet and the box) the QP states go through `__call__` too (the enumeration
        would cost more than the scalar QP). u_nom: (B, N) hPa."""
        if len(estimates) < SCALAR_BELOW:
            outputs = [self(estimates[i], u_nom[i]) for i in range(len(estimates))]
            return BatchOutput(np.array([o.u for o in outputs]), np.array([o.action for o in outputs]),
                               np.array([o.infeasible for o in outputs]), np.array([o.rho_pred for o in outputs]))
        if self._batch_dynamics is None:
            self._batch_dynamics = BatchDynamics(self.params)
        lo, hi = (np.array(self.params.u_min), np.array(self.params.u_max)) if self.pressure_limits else (None, None)
        out = cbf_qp_batch(self._batch_dynamics, self.safe_set, self.tuning, estimates.q, estimates.qd, u_nom, lo, hi,
                           fallback=lambda i: self(estimates[i], u_nom[i]),
                           recovery=self._recovery_rows, kernel=self._kernel)
        return BatchOutput(out.u, out.action, out.infeasible, out.rho_pred)

    def step(self, x, u_nom, scalar: bool = False) -> CBFResult:
        """Filter u_nom (N,) hPa at state x = [q; q̇] (2N,); see the module docstring. scalar: every branch through
        the scalar QP of `controllers.cbf.qp` on the rows the kernel computed (the fallback's path; the tests compare it
        with the kernel's QP)."""
        x = as_vector("x", x, 2 * self.n, NonFiniteStateError)
        u_nom = as_vector("u_nom", u_nom, self.n, NonFiniteCommandError)
        u, b, big_b, constraint, active, infeasible, recovery, action, rho_pred, solve_us, slack = self._step_floats(
            x.tolist(), u_nom.tolist(), scalar)
        return CBFResult(u_nom if u is None else np.array(u), u_nom, np.array(b), np.array(big_b), np.array(constraint),
                         np.zeros(len(b), dtype=bool) if active is None else np.array(active, dtype=bool),
                         infeasible, recovery, action, rho_pred, solve_us, slack)

    def _step_floats(self, xs: list[float], u_list: list[float], scalar: bool = False) -> tuple:
        """`step` on checked Python floats (x = xs, u_nom = u_list): (u, b, B, constraint, active,
        infeasible, recovery, action, rho_pred, solve_us, slack) with u None when it is u_nom,
        b, B, constraint lists over the rows of P and active a list of bools over them (None when no
        QP's active set applies). The kernel of the batched paper CBF at B = 1 (`controllers.cbf.batch.PaperCBFKernel`:
        the barrier rows, the "disabled", "nominal", "qp" and "recovery" branches); for a state it hands back
        (FALLBACK), or every state with `scalar`, the scalar QP on the rows the kernel computed (`_scalar_step`).
        solve_us: the kernel call's time where it solved a QP."""
        n = self.n
        q = xs[:n]
        core = self.dynamics.model_terms(q, xs[n:])
        layout = core.layout
        t0 = time.perf_counter()
        out = self._kernel.run(core.kin[None], layout.tip_terms.start, layout.tip_jac.start, np.array((q,)),
                               np.array((u_list,)), self._kernel_out)
        solve_us = (time.perf_counter() - t0) * 1e6
        tip = complex(core.kin[layout.tip_terms.start])
        rho_pred = self.safe_set.margin_at(tip.real, tip.imag)
        action = str(CODE_LABELS[out.code[0]])
        if scalar or action == "fallback":
            return self._scalar_step(u_list, out, rho_pred)
        u = out.u[0].tolist()
        b = out.b[0].tolist()
        solved = action == "qp" or action == "recovery"
        return (None if not solved and u == u_list else u, b, out.B[0].tolist(), out.constraint[0].tolist(),
                out.active[0].tolist() if solved else None, False, self.enabled and not all(v > B_MIN for v in b),
                action, rho_pred, solve_us if solved else 0.0, 0.0)

    def _scalar_step(self, u_list: list[float], out: KernelOutput, rho_pred: float) -> tuple:
        """`_step_floats` in Python floats with the QP of `controllers.cbf.qp`, on the rows the kernel computed at this
        state (`out`, its `KernelOutput` at B = 1: b, B, L_fB, L_gB and the quasi-static rows): the fallback for the
        states the kernel hands back (module docstring); every branch."""
        # Python floats from here on: P and N are tiny and numpy's per-call overhead would dominate.
        given = u_list
        if self.pressure_limits and not all(lo <= v <= hi for lo, v, hi in zip(self._lb_list, u_list, self._ub_list)):
            u_list = self._clip(u_list)  # saturated u_nom (module docstring)
        barrier = list(zip(out.b[0].tolist(), out.B[0].tolist(), out.LfB[0].tolist(), out.LgB[0].tolist()))
        static = list(zip(out.static_a[0].tolist(), out.static_c[0].tolist()))  # per row: its quasi-static row
        defined = [row[0] > B_MIN for row in barrier]
        recovery = self.enabled and not all(defined)
        gamma = self.tuning.gamma
        u, action, active, infeasible, slack, solve_us = u_list, "nominal", None, False, 0.0, 0.0
        if not self.enabled:
            u, action = u_list, "disabled"
        else:
            rows, rhs, cbf_rows, unevaluable = [], [], [], False
            feasible = True  # u_list is inside the box
            for i, (ok, (_, big_b, lfb, lgb)) in enumerate(zip(defined, barrier)):
                if ok:
                    row, c = lgb, gamma / big_b - lfb
                    if math.isfinite(c + sum(row)):  # (also false for finite terms whose sum overflows: flagged)
                        cbf_rows.append(i)
                    else:  # overflowed terms (huge q̇): unevaluable, see "slack"
                        defined[i], unevaluable = False, True
                        row, c = static[i]
                else:
                    row, c = static[i]
                rows.append(row)
                rhs.append(c)
                feasible = feasible and dot_lists(row, u_list) <= c
            if unevaluable or not feasible:
                t0 = time.perf_counter()
                u, action, active, infeasible, slack = self._qp_command(
                    u_list, rows, rhs, static, cbf_rows, recovery, unevaluable)
                solve_us = (time.perf_counter() - t0) * 1e6
        constraint = [lfb + dot_lists(lgb, u) - gamma / big_b if ok else math.inf
                      for ok, (_, big_b, lfb, lgb) in zip(defined, barrier)]
        return (None if u is given else u, [row[0] for row in barrier], [row[1] for row in barrier], constraint, active,
                infeasible, recovery, action, rho_pred, solve_us, slack)

    def _violates(self, u: list[float], u_nom: list[float], rows: list[list[float]], rhs: list[float],
                  cbf_rows: list[int]) -> bool:
        """Whether u violates a defined CBF row by more than the QP's acceptance tolerance (hPa, unit rows)."""
        tol = tolerances(u_nom, self._lb_list, self._ub_list)[1]
        return any(dot_lists(rows[i], u) - rhs[i] > tol * row_norm(rows[i]) for i in cbf_rows)

    def _qp_command(self, u_list: list[float], rows: list[list[float]], rhs: list[float],
                    static: list[tuple[list[float], float]], cbf_rows: list[int], recovery: bool,
                    unevaluable: bool) -> tuple[list[float], str, list[bool] | None, bool, float]:
        """The QP branches ("qp", "recovery", "slack", "vent"): (u, action, active, infeasible, slack); static: every
        row's quasi-static row (a, c), the slack QP's hard rows."""
        if not unevaluable:
            u, qp_active, _, _ = solve_lists(u_list, rows, rhs, self._lb_list, self._ub_list, self.qp_backend)
            if u is not None:
                # solve_lists accepted u only if every row holds within the acceptance tolerance (the
                # post-check); only a clip that moved u (by rounding) needs the rows checked again.
                clipped = self._clip(u)
                if clipped == u or not self._violates(clipped, u_list, rows, rhs, cbf_rows):
                    return clipped, ("recovery" if recovery else "qp"), qp_active, False, 0.0
        u, slack = self._slack_qp(u_list, rows, rhs, static)
        action = "slack"
        if u is None and recovery:
            u = self._rest_target(u_list)
            action, slack = "recovery", 0.0
        if u is None:
            u, slack = self._slack_qp(u_list, rows, rhs, [])
            action = "slack"
        if u is None:
            u, action = [0.0] * self.n, "vent"
        u = self._clip(u)
        if not all(map(math.isfinite, u)):
            u, action = self._clip([0.0] * self.n), "vent"
        infeasible = action != "recovery" or unevaluable or self._violates(u, u_list, rows, rhs, cbf_rows)
        return u, action, None, infeasible, slack



CUSTOM_TUNING = "custom"


def paper_tuning(tuning: str, a_E: float | None = None, b_E: float | None = None,
                 gamma: float | None = None) -> Tuning:
    """The tuning `paper_cbf` runs: the preset named `tuning`, or with tuning 'custom' the
    (a_E, b_E, γ) given; ValueError naming what is missing or contradictory."""
    if tuning.strip().lower() == CUSTOM_TUNING:
        missing = [name for name, value in (("a_E", a_E), ("b_E", b_E), ("gamma", gamma)) if value is None]
        if missing:
            raise ValueError(f"tuning 'custom' needs a_E, b_E and gamma (each >= 0), missing {', '.join(missing)}")
        return Tuning(CUSTOM_TUNING, a_E, b_E, gamma)
    given = [name for name, value in (("a_E", a_E), ("b_E", b_E), ("gamma", gamma)) if value is not None]
    if given:
        raise ValueError(f"{', '.join(given)} set a custom tuning: use tuning='custom' (not {tuning!r}), "
                         f"or a preset alone ({', '.join(TUNINGS)})")
    return get_tuning(tuning)


def paper_cbf(
    context: FilterContext,
    tuning: str = "Low",
    a_E: float | None = None,
    b_E: float | None = None,
    gamma: float | None = None,
    qp_backend: str = DEFAULT_BACKEND,
    recovery_margin: float = 1e-3,
    slack_weight: float = 1e6,
) -> CBFFilter:
    """The paper's CBF-QP filter (docs/model.md#control-barrier-function), a preset tuning or a custom (a_E, b_E, γ).

    The pressure limits are the robot model's own when `context.bounded`; the model's dynamics is the filter's own.
    """
    check_paper_cbf({"tuning": tuning, "a_E": a_E, "b_E": b_E, "gamma": gamma, "qp_backend": qp_backend,
                     "recovery_margin": recovery_margin, "slack_weight": slack_weight})
    chosen = paper_tuning(tuning, a_E, b_E, gamma)
    return CBFFilter(context.robot, context.safe_set, chosen, pressure_limits=context.bounded, qp_backend=qp_backend,
                     recovery_margin=recovery_margin, slack_weight=slack_weight)


def paper_cbf_label(params: dict[str, object]) -> str:
    """A run's label: the preset's name, or custom(a_E=..,b_E=..,gamma=..)."""
    tuning = str(params.get("tuning", "Low"))
    if tuning.strip().lower() != CUSTOM_TUNING:
        return tuning
    return "custom(" + ",".join(f"{k}={value_text(params.get(k))}" for k in ("a_E", "b_E", "gamma")) + ")"


def check_paper_cbf(arguments: dict[str, object]) -> None:
    """What `paper_cbf` would refuse of its (converted) `arguments`, checked without building
    it: the declared bounds (`PARAMETERS`), the tuning (`paper_tuning`) and the QP backend."""
    check_parameters(PARAMETERS, arguments)
    paper_tuning(str(arguments.get("tuning", "Low")), arguments.get("a_E"), arguments.get("b_E"), arguments.get("gamma"))
    check_backend(arguments.get("qp_backend", DEFAULT_BACKEND))


paper_cbf.run_label = paper_cbf_label
paper_cbf.check_arguments = check_paper_cbf
paper_cbf.parameter_docs = parameter_docs(PARAMETERS)
