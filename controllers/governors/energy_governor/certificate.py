"""The energy governor's certificate and its model: everything built once from the parameters and the context.

`GovernorModel.build(params, context)` makes the immutable model a governor's calls read (the tables and
bounds of Γ̲, P with the plate's stiffness interval, the energy's weights, the recovery's grid, the target
governor's configuration); nothing in it changes during calls. The per-run state is
`controllers.governors.energy_governor.state.GovernorState`.

Certificate. Model (docs/model.md#rppr-dynamics) with the pressure p (hPa) lagging the command (τ_p, s):

    M(q) q̈ + C(q, q̇) q̇ + D q̇ + K q = Λ p,     ṗ = (u − p)/τ_p,

    W_u(q, q̇, p) = ½ q̇ᵀM(q)q̇ + ½ (q − q_u)ᵀK(q − q_u) + ½ Σ_i β_i (p_i − u_i)²   (J),
    β_i = τ_p λ_i² / (4 d_i)   (J/hPa²).

Along the model's trajectories with u held,
    Ẇ = q̇ᵀ(Λp − Cq̇ − Dq̇ − Kq) + ½ q̇ᵀṀq̇ + q̇ᵀK(q − q_u) − Σ β_i (p_i − u_i)²/τ_p
      = q̇ᵀΛ(p − u) − q̇ᵀDq̇ − Σ (β_i/τ_p)(p_i − u_i)²            (q̇ᵀ(Ṁ − 2C)q̇ = 0, K q_u = Λu)
      = −Σ_i (√d_i q̇_i − λ_i (p_i − u_i)/(2√d_i))² ≤ 0            (β_i/τ_p = λ_i²/(4 d_i)),
so W_u never grows while u is held (τ_p = 0: β = 0, p = u, Ẇ = −q̇ᵀDq̇). Since
W_u ≥ ½ (q − q_u)ᵀK(q − q_u), the tip stays in P for as long as u is held if
W_u(x(t_a)) ≤ Γ(u) at the instant t_a when u starts to act, with Γ(u) the escape energy
(`controllers.energy.escape_energy`: Γ(u) = min over q with r(q) ∉ P of ½ (q − q_u)ᵀK(q − q_u),
tabulated as a lower bound).

The plate (the plain and contact-aware variants, its offset interval, a sheet, and a plate learned online):
`controllers.governors.energy_governor.plate_certificate`, whose `PlateCertificate` is what this certificate reads of it (P,
Γ̲^∂'s sources, the credits c_j and the offsets o_j below).
Contact certificate (`certificate="contact"`, the `c-erg` filter). The parked
certificate above delivers about half the force budget on a plate (measured: 0.45–0.50 F_max
on mujoco_contact): its target's rest shape parks `margin_m` inside P, and its Γ(u) is 0 for
every rest shape beyond P, although the arm pressing a plate rests well inside P with its rest
shape beyond it. Three changes make the equilibrium at P's boundary reachable:
(a) Γ to the boundary: the arm starts strictly inside P (checked at x̂: every row H'_j r(q̂) < h'_j,
    else nothing is certified), so to leave P its tip must cross some row's boundary g_j = 0
    first. Γ^∂_j(u) = min {½(q − q_u)ᵀK(q − q_u) : g_j(q) = 0} is then the barrier, > 0 also for a
    rest shape beyond P. Γ̲^∂_j = the larger of the boundary table (`EscapeEnergyTable(boundary=True)`,
    N ≤ 2) and the grid-free second-order bound (`BoundaryDistanceBound`: exact to second order
    near the boundary, where the table's looseness, ≈ 2.6 h_z in distance, halved Γ: 1.06e-4 J
    against 2.39e-4 J at 70 hPa on both segments of the reference arm).
(b) The plate's energy per facet, with lo on the difference only. With the true plate energy
    E_true,i(n_i) (conservative, ψ_true ∈ [lo ψ, hi ψ]), V = W_u + Σ_i E_true,i never grows (u
    held). At the first exit through facet row j, n_j = n_max, so V ≥ Γ^∂_j(u) + E_true,j(n_max).
    For n_j ≤ n_max, E_true,j(n_max) − E_true,j(n_j) = ∫_{n_j}^{n_max} ψ_true ≥ lo (E(n_max) − E(n_j)),
    and E_true,i ≤ hi E(n_i), so V(x̂) < Γ^∂_j + E_true,j(n_max) follows from
        W_u(x̂) + hi Σ_{i≠j} E(n_i) < Γ^∂_j(u) + lo (E(n_max) − E(n_j)).
    Per row: o_j = lo (E(n_max) − E(n_j)) − hi Σ_{i≠j} E(n_i) for a facet row, o_j = −hi Σ_i E(n_i)
    for a vertex-correction row (no facet is at n_max on it); without `contact_aware` o_j = 0.
    The parked variant's hi E(n) in W against lo E(n_max) in Γ costs (hi − lo) E(n_max) at the
    plate; this one costs lo's share of the last bit of penetration only. For the exact model
    (lo = hi = 1) and a rest state, Γ^∂_j + E(n_max) − (W_u + E(n)) is the gap between the arm-plate
    energy's minimum on the boundary and at the equilibrium: > 0 for every equilibrium strictly
    inside P, so the governor can approach the boundary.
(c) κ inflates the kinetic energy alone: (1 + κ)·½q̇ᵀMq̇ + ½(q − q_u)ᵀK(q − q_u) + ½Σβ(p − u)² + ε ≤
    min_j (Γ̲^∂_j(u) + o_j). κ stands for the velocity's estimation error (finite differences); a
    whole-energy inflation would ask (1 + κ) W ≤ Γ + ... at a contact equilibrium, where W is
    the arm's elastic energy against the plate: never certified near the boundary.
Any number of segments: for N > 2 (no q-space table) Γ̲^∂ is the second-order bound alone and the
recovery's candidates are u_prev, u_nom and 0 hPa (tests/test_contact_governor.py: N = 3 and 4 on
the PCC plant). The target is u_nom itself (clipped to the box); the rays are those to it and to 0 hPa. The
recovery (step 4) ranks the table's grid commands, u_prev and u_nom by the same margin; with x̂
outside P (no certificate holds) it takes the command nearest u_nom whose rest shape lies inside P.
Measured (mujoco_contact, push asking 1.2 F_max, 6 s; `softcbf bench`): exact model 0.946 F_max;
plate stiffness within ±10 % (n_max = ψ⁻¹(F_max/1.1)): 0.841 F_max, ρ_meas 0.159.

Actuator gain (`gain_lo_ratio`, `gain_hi_ratio`; contact certificate only; default 1, 1: the model's λ, the
commands bit for bit those without the interval: tests/references/eerg_references.py). The true arm's gains are g·λ_i,
one unknown scale g ∈ [g_lo, g_hi] for every segment (dimensionless; the bench's camera_mismatch draws g
from U(0.9, 1.1)). Only two things change with g: the true rest shape q_u(g) = K⁻¹(gΛ)u = g·q_u (rad), and
the lag weights, β_i(g) = τ_p (gλ_i)²/(4d_i) = g²β_i (J/hPa²), the derivation of Ẇ ≤ 0 above with gΛ in place
of Λ. So the certificate for the gain g, at a state x̂ = (q̂, q̂̇, p̂) (κ, o_j and the plate terms depend on
the state alone), asks for every row j

    m_j(g) = Γ^∂_j(g·u) + o_j − (1 + κ)·½q̂̇ᵀMq̂̇ − ½(q̂ − g q_u)ᵀK(q̂ − g q_u) − ½ g² Σ_i β_i (p̂_i − u_i)² ≥ ε,

Γ^∂_j(g·u) the least energy to row j's boundary from the rest shape g·q_u (the table's function at the
command g·u, whose model rest shape that is). Claim: m_j is concave in g, so min over [g_lo, g_hi] of m_j is
min(m_j(g_lo), m_j(g_hi)) and checking the two ends certifies every gain between them. Proof: in z = K^{1/2}q
(J^{1/2}), with ζ = K^{1/2}q̂, z_u = K^{1/2}q_u and S_j = {z : g_j = 0},
    Γ^∂_j(g·u) − ½|ζ − g z_u|² = min_{s∈S_j} ½(|s − g z_u|² − |ζ − g z_u|²) = min_{s∈S_j} (½|s|² − ½|ζ|² − g z_u·(s − ζ)),
a minimum of affine functions of g, hence concave (the g² terms cancel exactly; any set S_j, also the
parked certificate's unsafe set); −½g² Σβ(p̂ − u)² is concave (≤ 0 curvature) and the rest does not depend
on g. Neither term is concave alone (the elastic energy is convex in g, Γ^∂(g·u) neither in general), only
their difference, so they are not bounded separately (min Γ^∂ − max W would also be sound, but it gives
away the motion of the rest shape twice). Γ̲^∂_j(g·u) ≤ Γ^∂_j(g·u) at each end (the
table's bounds hold for any command, 4b outside its box; the second-order bound anywhere), so the governor
takes min over the ends g ∈ {g_lo, g_hi} of min_j (Γ̲^∂_j(g·u) + o_j) − W(g) as its margin (W(g): `energy` at
gain g; the diagnostics report the binding end). The recovery's grid commands u_c use
d_j(g·u_c) ≥ d̲_j(u_c) − |g − 1| ‖u_c‖_w ((*) of `controllers.energy.escape_energy`, w_i = λ_i²/k_i: the rest
shape moves by that much in z), tests/test_contact_governor.py checks it against brute force; its fallback
(no candidate certified: no guarantee either way) ranks by the model's rest shapes.
Assumptions added: g is constant and common to the segments (per-segment gains in a box would need the 2^N
vertices, by the same concavity along each axis: not built); the state predictor integrates the model's
gain, so over the prediction span t_a − t_c (estimate age plus delay, ≈ 0.05–0.12 s at the camera rate, 0
at 1 kHz with an exact state) the gain's effect on x̂ is an estimate error, not covered beyond κ.
What it costs (measured on the reference arm, docs/results.md): the plate's whole force range lies within a
few hPa (`softcbf.bench.PUSHES`: 57.0, 62.5, 68.2 and 74.0 hPa on both segments press with 0.3, 0.6, 0.9 and
1.2 F_max), so 10 % of the gain, ≈ 6 hPa there, is ≈ 0.3 F_max of steady force; and the certificate
(which cannot use damping) must also allow the arm's swing from the state where a stronger actuator would
start, so [0.9, 1.1] holds the nominal arm at ≈ 0.23 F_max
(mujoco_contact, asked ≥ F_max) where [1, 1] delivers 0.84. Without a measurement of g (gain feedback)
this is the price of certifying ±10 % of actuator gain on this arm.
Arm stiffness (`arm_stiffness_lo_ratio`, `arm_stiffness_hi_ratio`; contact certificate only; default 1, 1). The true
arm's stiffness is c·K, one scale c ∈ [c_lo, c_hi] for every segment, with the gain g ∈ [g_lo, g_hi] (both 1).
M does not depend on K (the augmented-body model's inertia), so with c the derivation of Ẇ ≤ 0 holds for
    W = ½q̇ᵀMq̇ + ½(q − r q_u)ᵀcK(q − r q_u) + ½ g² Σ β_i (p_i − u_i)²,     r = g/c,
(cK·r q_u = gΛu), and Γ^∂ for the true arm is min over the boundary of ½(q − r q_u)ᵀcK(q − r q_u) = c·Γ^∂_j(r·u)
(the model's rest shape of r·u is r q_u). So the margin at a state is
    m_j(g, c) = c·f_j(g/c) + o_j − (1 + κ)·½q̂̇ᵀMq̂̇ − g² B,     f_j(r) = Γ^∂_j(r·u) − ½|q̂ − r q_u|²_K,
B = ½ Σβ(p̂ − u)² ≥ 0. f_j is concave in r (the "actuator gain" proof above), so c·f_j(g/c), its perspective, is
jointly concave in (g, c) on c > 0, and −g² B is concave: m_j is jointly concave, and its least value over any
convex polygon of (g, c) is at a vertex. The rest shape depends on r = g/c alone: the two intervals move every
rest shape within r ∈ [g_lo/c_hi, g_hi/c_lo] (±10 % each: [0.818, 1.222], ±22 %), and that interval is what the gain
estimate measures (`controllers.governors.gain_estimate`: at rest y = q̂ + K⁻¹Dq̂̇ = r x + δ, the true K⁻¹ = K⁻¹/c scaling
the damping and plate terms only, which the rest test and the elimination already leave to Δ or remove). So
the certified set is the polygon {g ∈ [g_lo, g_hi], c ∈ [c_lo, c_hi], r_lo ≤ g/c ≤ r_hi}, [r_lo, r_hi] the gain
estimate's interval (its prior [g_lo/c_hi, g_hi/c_lo]); its vertices (`arm_corners`: up to 6) are the ends the
governor checks: Γ_e = min_j (c·Γ̲_j(r·u) + o_j), W_e with (c·K, r·K⁻¹Λ, g²β) (`energy_terms`); c = 1 gives the
gain ends alone, bit for bit. The recovery's grid rows are c·Γ̲(r·u_c) (`grid_rows_at_gain`). What it costs: the
gain estimate narrows r, the product that sets the force against the plate; c is left in its interval (it
scales the escape energy and the elastic energy alike, a ±10 % change of the margin's size). Assumptions added: c is
constant and common to the segments; a moving gain sample (`gain_difference_s` > 0) is refused with an arm
stiffness or damping interval (its M q̈ and D q̇ scale unlike K).

Damping and valve lag (`damping_lo_ratio`; `actuator_tau_lo_s` ≤ `actuator_tau_hi_s`; contact certificate only;
defaults 1 and None: the model's β and p̂). Neither moves a rest shape: they shape the transient, which the energy
already covers for any D > 0 and τ_p > 0 whose β it uses. With weights β̃_i ≥ τ_p g²λ_i²/(4 c_d d_i) (the true
damping c_d·D, lag τ_p) the same algebra gives
    Ẇ = −Σ_i (√(c_d d_i) q̇_i − gλ_i(p_i − u_i)/(2√(c_d d_i)))² − Σ_i (β̃_i/τ_p − g²λ_i²/(4 c_d d_i))(p_i − u_i)² ≤ 0,
so β = τ_hi λ²/(4 c_lo d) (`pressure_lag_weights`, with g² per end) certifies every damping ≥ c_lo·D and every lag
≤ τ_hi; a larger β only adds energy, never a guarantee's failure. What the energy does not know is the pressure
at t_a itself: the model's p̂ is integrated with the model's τ_p. With the lag interval the governor bounds it
(`controllers.governors.energy_governor.pressure_interval`: from its own commands, every τ_p ∈ [τ_lo, τ_hi], joined with p̂)
and takes the lag term at the interval's end farther from u_i, ½β_i max((p_i − u_i)², (p̄_i − u_i)²) (concave in
p_i, so its maximum over the interval is at an end; the kernels' `energy_at`). Assumptions added: c_d and τ_p
constant and common to the segments; the arm's own motion over the prediction span under another lag or damping is
an estimate error, left to κ. The gain estimate's settled-pressure test still uses the model's lag; at a rest
sample the arm follows its rest shape quasi-statically (q ≈ a p, first mode ≈ 20 rad/s), so q̇ ≈ a(u − p)/τ_p and
the rest test |q̂̇_i| ≤ `gain_rest_rad_s` bounds the unsettled part a|p − u| ≤ τ_hi·gain_rest_rad_s (3e-4 rad at
0.1 s and 3e-3 rad/s, within Δ = 1.5e-3 rad).

Command delay (`command_delay_lo_s` ≤ `command_delay_hi_s`, s; `command_delay_spacing_s`; default None: δ alone). A
command issued at t acts at the valves from t + δ', one true delay δ' ∈ [δ_lo, δ_hi] for every command of a run; the
governor records its commands at t + δ (δ: `command_delay_s` or the context's). A constant delay keeps the commands
in the order issued, so u_prev (the governor's previous command) is the one u replaces whatever δ' is.
Time shift. Let s = δ' − δ (s) and y(τ) = x(τ + s) (x: the true state, (2N,) rad and rad/s, with p (N,) hPa). The
model is time-invariant (M, C, D, K, Λ, τ_p do not depend on t), so y is the model's trajectory under the commands
at their RECORDED times t_j + δ, and the estimate captured at t_c is y(t_c − s). u then acts from y(t_a),
t_a = t + δ: the predictor's prediction from t_c − s (not t_c) to t_a through the same records
(`StatePredictor.predict`, exact under the model, as for δ alone). So a delay δ' is an estimate whose capture
time is off by s, and the certificate holds for δ' exactly when it holds at that prediction; the chain argument
(each command certified at the state it acts from; W_u does not grow while u is held) then keeps the tip in P
under every delay for which every command was certified.
Covering set. The certificate is evaluated at the delays D = `delay_states(δ_lo, δ_hi, h)`: both ends and equally
spaced ones at most h = `command_delay_spacing_s` apart (0.01 s: {0, 0.01, 0.02} s for 0–20 ms; at most
`MAX_DELAY_STATES`), one prediction x̂_d (N,) per d, one row of `energy_kernels.govern_rows` per d. A command is
certified when it is certified at every x̂_d (margin min_d (Γ_d − ιW_d) ≥ ε); the held one keeps its hysteresis at
every x̂_d (`steps.combine`: the target if every row is free; else each row's end point, nearest the target
first, checked at every row; else u_prev if every row holds it; else the recovery at the row whose held margin is
least). Why D covers the interval: a delay δ' inside lies within h/2 of some d ∈ D, and x̂_{δ'} differs from x̂_d by
the state's motion over an estimate time off by ≤ h/2 (the arm's speed × h/2): an estimate error, the kind κ and
ε are there for (as the predictor's own span, ≈ ±0.03 s at the camera rate). That is an assumption, not a proof:
the margin is neither monotone nor concave in δ' in general (the switch state runs along a trajectory that swings),
so no finite set of delays proves the interior; the brute force checks random interior delays
(tests/test_command_delay.py: a swinging arm, exact state, κ = 0: [0, 0.1] s holds at 0, 0.1 s and interior
delays, where δ = 0.1 s alone leaves P with the commands acting at once: ρ −0.70). A sound bound exists but was not built: under u_prev (certified)
V_prev = W_{u_prev} + plate energy does not grow, and W_u − W_{u_prev} is affine in (q, p), so over the sublevel set
½|q − q_{u'}|²_K ≤ V_prev, W_u ≤ (√V_prev + |q_u − q_{u'}|_K/√2)² + the lag terms at any switch time; it charges every
step √(2V_prev)|Δq_u|_K, large at the plate where V_prev holds the arm's elastic energy against it, and with
δ_hi − δ_lo beyond the control period several commands are in flight, so the bound compounds over them.
Zero width at δ (δ_lo = δ_hi = δ): D = {δ}, s = 0, the call is the single-delay call bit for bit. Assumptions added:
δ' is constant over a run (jitter, a δ' varying from command to command, is not covered beyond κ); the gain
feedback's and the valve-lag interval's records use δ. Cost: one prediction and one kernel row per delay of D, and
where the rows disagree a few certificate evaluations per candidate (docs/results.md).

κ (`kappa`, default 0.5) inflates the whole energy (the parked certificate) against estimate and prediction
errors (the velocity from finite differences above all); ε (`energy_margin_J`, J) is
the absolute margin a new command must keep. No guarantee above needs ε > 0 (each holds for margins ≥ 0), so ε
is a buffer for what the assumptions leave out, and at the plate it has a price: at rest against it the margin
is the rise of the arm–plate energy from the equilibrium to the boundary, ≈ ½ k_c (n_max − n)² (k_c the arm and
plate's stiffness along the normal), so the governor stops where that rise is ε (measured with the recommended
setting, mujoco_push_120: 0.808 F_max at ε = 2e-6 J against 0.797 at the default 1e-5 J; docs/results.md).
The held command, certified when it was issued, counts as failed only when it has lost all of ε ((1 + κ)W ≥ Γ,
tested as Γ − (1 + κ)W > 0, not as (Γ − (1 + κ)W − ε) + ε ≥ 0, which for ε = 1e300 held any W): a
hysteresis that keeps integration round-off from reading as a violation.

Assumptions of the guarantee (tip in P at all times): the model is the plant (M, C, K,
D, Λ, τ_p, the PCC kinematics, P and ψ within [lo, hi]); the estimate and the predictor
are accurate to within the κ-inflation; the commands this governor returns are applied
unchanged from t + δ (t + δ' for a delay δ' of the delay interval) and held until the next one acts (no clipping, no other source);
the valves start vented (p = 0) at `reset`; Γ̲ ≤ Γ (by construction); the arm starts
certified (e.g. at rest with its rest shape in P). The intervals above relax "the model is the plant" to: an
actuator gain, arm stiffness, arm damping (from below), valve lag, command delay, plate stiffness and plate offset
each within its interval (each at the model's value by default). Where it can fail: a wrong model outside those intervals
(or a turned plate, per-segment errors, a command delay outside its interval beyond what κ covers) is not covered, and a
state far from the estimate is not caught until the next estimate shows it; the recovery then has no
guarantee.

"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from controllers.model.dynamics import PCCDynamics
from controllers.energy.escape_energy import MAX_SEGMENTS, EscapeEnergyTable, lower_bounds
from controllers.governors.energy_governor.parameters import PARAMETERS, PREDICTION_HORIZON_S, GovernorParams, delay_states
from controllers.governors.energy_governor.plate_certificate import (BOUND_BELOW_J, PlateCertificate, cantilever_stiffness_ratios,
                                                           nearest_environment, prior_plate, rest_shape_inside, tip_of)
from controllers.governors.gain_estimate import GainEstimator
from controllers.core.lazy_import import lazy_module
from controllers.model.pcc import kinematics_unchecked
from controllers.governors.quasi_static_governor import QuasiStaticGovernor
from controllers.model.safe_set import ForceSafeSet, LinearStiffness
from controllers.contract.safety_filter import FilterContext
from controllers.model.state_predictor import StatePredictor

__all__ = ["GovernorCall", "GovernorModel", "TIP_TOLERANCE_M", "arm_corners", "cantilever_stiffness_ratios",
           "certificate_rows", "energy_kernels", "nearest_environment", "pressure_lag_weights", "ray_may_come_nearer",
           "scaled_command"]
"""The certificate's names (the plate's `cantilever_stiffness_ratios` and `nearest_environment` importable from here too)."""

energy_kernels = lazy_module("controllers.energy.energy_kernels")  # numba loads on the first call (controllers.core.lazy_import)

TIP_TOLERANCE_M = 1e-9
"""A scalar tip this far outside every facet (m) has the array path's tip outside too (`GovernorModel.state_energy`)."""

def scaled_command(gain: float, u: tuple) -> tuple:
    """g·u per entry (hPa): the command whose model rest shape is the true one, g K⁻¹Λu, under the gain g; u itself at g = 1."""
    return u if gain == 1.0 else tuple(gain * v for v in u)


def ray_may_come_nearer(start, goal, direction, aim, best: float, sigma_min: float) -> bool:
    """Whether a point a + σ·d of the ray from a = `start` towards g = `goal` (d = `direction`
    = g − a as floats), σ ∈ [sigma_min, 1], may have a squared distance to t = `aim` below
    `best` (hPa²) as the governor computes it (per entry a + σd, then Σ (c − t)²).

    The exact distance Q(σ) = Σ_i (e_i + σ d_i)², e = a − t, is a convex quadratic with its
    least value on [sigma_min, 1] at σ* = clip(−e·d/|d|², sigma_min, 1). Each float step
    (d, σd, a + σd, c − t, its square, the sum) errs by at most one rounding u = 2⁻⁵³ of
    entries bounded by M_i = |a_i| + |g_i| + |t_i|, so the computed distance and the computed
    Q(σ*) each lie within about 30u Σ M_i² of the exact ones; ROUNDING_SLACK Σ M_i² is over
    300 times that (`controllers.energy.energy_kernels.ROUNDING_SLACK`, 1e-12). False therefore proves that
    no σ in the range gives a computed distance below `best`. σ = 0 gives a itself, which the caller
    has already counted. d = 0: False. The compiled ray search's test (`energy_kernels.ray_may_come_nearer`).
    """
    vectors = (np.asarray(v, dtype=float) for v in (start, goal, direction, aim))
    return bool(energy_kernels.ray_may_come_nearer(*vectors, float(best), float(sigma_min)))


def pressure_lag_weights(context: FilterContext, actuator_tau: float, damping_ratio: float = 1.0) -> np.ndarray:
    """β_i = τ_p λ_i² / (4 c_d d_i): (N,) J/hPa², c_d the lowest damping's ratio (module docstring, "valve lag");
    refuses τ_p > 0 with an undamped segment."""
    damping, gains = context.robot.array("damping"), context.robot.array("gains")
    if actuator_tau == 0.0:
        return np.zeros_like(gains)
    if np.any(damping <= 0):
        raise ValueError(f"a pressure lag (actuator_tau = {actuator_tau} s) needs damping > 0 on every segment, "
                         f"got {damping.tolist()}: the certificate's β = τ_p λ²/(4d) is undefined")
    if damping_ratio != 1.0:
        damping = damping_ratio * damping
    return actuator_tau * gains**2 / (4.0 * damping)


def arm_corners(gains: tuple, stiffnesses: tuple, ratios: tuple) -> tuple:
    """The vertices (g, c) of the arm's certified set {g ∈ [g_lo, g_hi], c ∈ [c_lo, c_hi], r_lo ≤ g/c ≤ r_hi}
    (module docstring, "arm stiffness"): the ends of its edges on the lines c = c_lo, c = c_hi, g = g_lo and
    g = g_hi (every vertex lies on one of them: the lines g = r c meet only at 0), sorted by (g/c, c), repeats
    dropped. The model's stiffness (c_lo = c_hi = 1) gives (r_lo, 1), (r_hi, 1): the gain ends alone.
    ValueError where the set is empty."""
    (g_lo, g_hi), (c_lo, c_hi), (r_lo, r_hi) = gains, stiffnesses, ratios
    points = set()
    for c in (c_lo, c_hi):
        lo, hi = max(g_lo, r_lo * c), min(g_hi, r_hi * c)
        if lo <= hi:
            points.update({(lo, c), (hi, c)})
    for g in (g_lo, g_hi):
        lo, hi = max(c_lo, g / r_hi), min(c_hi, g / r_lo)
        if lo <= hi:
            points.update({(g, lo), (g, hi)})
    if not points:
        raise ValueError(f"no actuator gain in [{g_lo!r}, {g_hi!r}] and arm stiffness in [{c_lo!r}, {c_hi!r}] has a "
                         f"ratio in [{r_lo!r}, {r_hi!r}]")
    return tuple(sorted(points, key=lambda end: (end[0] / end[1], end[1])))


@dataclass(eq=False)
class GovernorCall:
    """One call's state between its preparation and its step 3 (`controllers.governors.energy_governor.steps`): the estimate's
    capture and the command's application times (s), u_prev, the target and u_nom clipped (N,) hPa; unless
    stale, the predicted q̂ (N,) rad and p̂ (N,) hPa, the certificate's base energy (J: (1 + κ)·½q̂̇ᵀMq̂̇
    for the contact certificate, the state's energy for the parked one), the rows' offsets o_j (J), whether
    x̂ lies strictly inside P, the tip's ρ, the inflation ι of W, the ends' rest-shape ratios and stiffness scales
    and their energy terms (E, 3, N), p̄ (N,) hPa, the other end of the pressure's interval (None: p̂ alone), the
    plate certificate the call is certified on (the state's), and `covers`: the same call at the other delays of a
    command delay interval (module docstring, "command delay"; empty without one)."""

    t_capture: float
    t_apply: float
    u_prev: np.ndarray
    target: np.ndarray
    nominal: np.ndarray
    stale: bool = False
    q_hat: np.ndarray | None = None
    p_hat: np.ndarray | None = None
    base: float = math.nan
    offsets: list[float] = field(default_factory=list)
    inside: bool = False
    rho: float = math.nan
    inflation: float = 1.0
    gains: tuple = ()
    terms: np.ndarray | None = None
    scales: tuple = ()
    p_far: np.ndarray | None = None
    plate: PlateCertificate | None = None
    covers: list = field(default_factory=list)


def certificate_rows(calls: list[GovernorCall]) -> tuple:
    """The certificate's per-row arguments of `energy_kernels.certificate_terms` and `govern_rows` for the calls
    (B rows): the ends' rest-shape ratios and stiffness scales (B, E) and their count (B,), the energy terms
    (B, E, 3, N), base (B,) J, q̂ (B, N) rad, p̂ and p̄ (B, N) hPa, the offsets (B, P') J and inside (B,); E the
    most ends of a call, the others' padded (never read: a row reads its count)."""
    ends = np.array([len(c.gains) for c in calls])
    most = int(ends.max())
    if most == len(calls[0].gains) and all(c.terms is calls[0].terms for c in calls):
        gains, terms = np.array([calls[0].gains] * len(calls)), np.array([calls[0].terms] * len(calls))
        scales = np.array([calls[0].scales] * len(calls))
    else:
        gains = np.array([c.gains + (1.0,) * (most - len(c.gains)) for c in calls], dtype=float)
        scales = np.array([c.scales + (1.0,) * (most - len(c.gains)) for c in calls], dtype=float)
        terms = np.zeros((len(calls), most) + calls[0].terms.shape[1:])
        for b, c in enumerate(calls):
            terms[b, :len(c.gains)] = c.terms
    p_hat = np.array([c.p_hat for c in calls])
    p_far = p_hat if all(c.p_far is None for c in calls) else \
        np.array([c.p_hat if c.p_far is None else c.p_far for c in calls])
    return (gains, scales, ends, terms, np.array([c.base for c in calls]), np.array([c.q_hat for c in calls]),
            p_hat, p_far, np.array([c.offsets for c in calls], dtype=float), np.array([c.inside for c in calls]))


@dataclass(frozen=True, eq=False)
class GovernorModel:
    """What a governor's calls read and never change (module docstring), built by `build`.

    params: the checked parameters; context: the filter's context; command_delay δ and actuator_tau τ_p (s, the
    parameters' or the context's); contact: the contact certificate; target_governor: the parked certificate's
    quasi-static governor, configured (each state holds a copy: `controllers.governors.energy_governor.state.new_state`), None
    for the contact certificate; beta (N,) J/hPa²; k, a, beta_list: K, K⁻¹Λ and β as lists; plate: the prior's
    plate certificate (`controllers.governors.energy_governor.plate_certificate.PlateCertificate`: P with n_max = ψ⁻¹(F_max/hi)
    on the nearest plate, Γ̲'s sources and look-up, the credits, the recovery's grid; a state may hold a learned
    one); plate_weight: hi when contact-aware, else 0; free_plate_energy: its term at n = 0 (J); box: the pressure
    box or None; rest: 0 hPa clipped to it; gain_prior: the certified interval of the rest-shape ratio r = g/c
    before any estimate ([g_lo/c_hi, g_hi/c_lo]); gain_box, stiffness_box: the actuator gain's and the arm
    stiffness's intervals (1); lag_taus: (τ_lo, τ_hi) of the pressure's interval (s), None without one;
    delay_shifts: s = δ' − δ (s) for each delay δ' the certificate is evaluated at (`delay_states`; (0.0,) without a
    command delay interval, or with one of zero width at δ)."""

    params: GovernorParams
    context: FilterContext
    n: int
    command_delay: float
    actuator_tau: float
    contact: bool
    target_governor: QuasiStaticGovernor | None
    dynamics: PCCDynamics
    beta: np.ndarray
    k: list
    a: list
    beta_list: list
    plate: PlateCertificate
    plate_weight: float
    free_plate_energy: float
    box: tuple | None
    rest: np.ndarray
    gain_prior: tuple
    gain_box: tuple
    stiffness_box: tuple
    lag_taus: tuple | None
    delay_shifts: tuple

    @classmethod
    def build(cls, params: GovernorParams, context: FilterContext) -> "GovernorModel":
        """The model of `params` on `context`; ValueError for what needs the context to check (module docstring of
        `controllers.governors.energy_governor.parameters`): the context's delay and time constant, the plate's law, the
        table's size, ε against the table's saturation."""
        delay = context.command_delay if params.command_delay_s is None else params.command_delay_s
        tau = context.actuator_tau if params.actuator_tau_s is None else params.actuator_tau_s
        delay, tau = (0.0 if delay is None else float(delay)), (0.0 if tau is None else float(tau))
        for name, value in (("command_delay_s", delay), ("actuator_tau_s", tau)):  # the context's, when not given
            PARAMETERS[name].check(f"{name} (the context's)", value)
        law = context.safe_set.stiffness
        if not callable(getattr(law, "energy", None)):
            raise ValueError(f"the plate's stiffness law {type(law).__name__} has no energy(n); "
                             "use LinearStiffness or PowerLawStiffness")
        if params.plate_estimate and not isinstance(law, LinearStiffness):
            raise ValueError(f"plate_estimate needs a linear plate law ψ(n) = k n (LinearStiffness), got "
                             f"{type(law).__name__}")
        delays = tuple(delay if d is None else float(d) for d in (params.command_delay_lo_s, params.command_delay_hi_s))
        if delays[0] > delays[1]:
            raise ValueError(f"command_delay_lo_s must be <= command_delay_hi_s = {delays[1]!r} (None: the assumed "
                             f"delay {delay!r} s), got {delays[0]!r}")
        delay_shifts = tuple(d - delay for d in delay_states(*delays, params.command_delay_spacing_s))
        robot, contact = context.robot, params.contact
        n = robot.n_segments
        taus = (params.actuator_tau_lo_s, params.actuator_tau_hi_s)
        lag_taus = None if taus == (None, None) else tuple(tau if t is None else float(t) for t in taus)
        if lag_taus is not None and lag_taus[0] > lag_taus[1]:
            raise ValueError(f"actuator_tau_lo_s must be <= actuator_tau_hi_s = {lag_taus[1]!r} (None: the model's "
                             f"{tau!r} s), got {lag_taus[0]!r}")
        beta = pressure_lag_weights(context, tau if lag_taus is None else max(tau, lag_taus[1]), params.damping_lo_ratio)
        box = None if context.u_min is None else (context.u_min, context.u_max)
        rest = np.zeros(n) if box is None else np.clip(np.zeros(n), *box)
        plate = prior_plate(params, context, not contact or n <= MAX_SEGMENTS, rest)  # no table for N > 2 (contact)
        if plate.table is not None and not params.energy_margin_J < plate.table.saturation_J:
            raise ValueError(f"energy_margin_J must be < {plate.table.saturation_J:.6g} J (½ k_min reach², the escape "
                             f"energy the table resolves), got {params.energy_margin_J!r}")
        target_governor = None if contact else QuasiStaticGovernor(replace(context, safe_set=plate.safe_set),
                                                                   margin_m=params.margin_m)
        plate_weight = params.stiffness_hi_ratio if params.contact_aware else 0.0
        return cls(params=params, context=context, n=n, command_delay=delay, actuator_tau=tau, contact=contact,
                   target_governor=target_governor, dynamics=PCCDynamics(robot), beta=beta,
                   k=robot.array("stiffness").tolist(), a=(robot.array("gains") / robot.array("stiffness")).tolist(),
                   beta_list=beta.tolist(), plate=plate, plate_weight=plate_weight,
                   free_plate_energy=plate_weight * float(np.sum(law.energy([0.0] * len(plate.facets)))),  # n = 0
                   box=box, rest=np.array(rest.tolist()),
                   gain_prior=(params.gain_lo_ratio / params.arm_stiffness_hi_ratio,
                               params.gain_hi_ratio / params.arm_stiffness_lo_ratio),
                   gain_box=(params.gain_lo_ratio, params.gain_hi_ratio),
                   stiffness_box=(params.arm_stiffness_lo_ratio, params.arm_stiffness_hi_ratio), lag_taus=lag_taus,
                   delay_shifts=delay_shifts)

    # -- the prior plate's parts (`plate`) ----------------------------------------------------------------
    @property
    def safe_set(self) -> ForceSafeSet:
        """P of the prior plate (`PlateCertificate.safe_set`)."""
        return self.plate.safe_set

    @property
    def table(self) -> EscapeEnergyTable | None:
        """The prior plate's escape-energy table (None for N > 2 with the contact certificate)."""
        return self.plate.table

    @property
    def grid(self) -> np.ndarray:
        """The prior plate's recovery candidates (G, N) hPa."""
        return self.plate.grid

    @property
    def grid_values(self) -> np.ndarray:
        """The prior plate's Γ̲ rows at its recovery candidates (P', G) J."""
        return self.plate.grid_values

    @property
    def credit(self) -> list:
        """The prior plate's credits c_j per row (J)."""
        return self.plate.credit

    @property
    def offset_width(self) -> float:
        """w, the plate offset interval's width (m)."""
        return self.plate.box.width

    # -- what each state starts from --------------------------------------------------------------------
    def new_predictor(self) -> StatePredictor:
        """A state predictor of this model, vented since t = −inf (`controllers.model.state_predictor`)."""
        return StatePredictor(self.dynamics, self.actuator_tau, step_s=self.params.predictor_step_s,
                              horizon_s=PREDICTION_HORIZON_S,
                              plate=self.context.safe_set if self.params.contact_aware else None)

    def new_gain_estimator(self) -> GainEstimator | None:
        """A gain estimator with the prior interval and no sample (None without `gain_estimate`)."""
        if not self.params.gain_estimate:
            return None
        return GainEstimator(self.k, self.a, self.context.robot.array("damping"), self.gain_prior,
                             self.params.gain_noise_rad)

    # -- certificate ------------------------------------------------------------------
    def energy_terms(self, gain: float, stiffness: float = 1.0) -> tuple[list, list, list]:
        """The energy's weights at the actuator gain g and arm stiffness scale c: (c·K, (g/c)·K⁻¹Λ, g²β) as lists
        (g = c = 1: the model's floats exactly, 1.0·x = x/1.0 = x)."""
        ratio = gain / stiffness
        return [stiffness * k for k in self.k], [ratio * a for a in self.a], [gain * gain * b for b in self.beta_list]

    def energy(self, kinetic_and_plate: float, q: list[float], p: list[float], u, gain: float = 1.0,
               stiffness: float = 1.0, p_far: list[float] | None = None) -> float:
        """W_u + plate term at (q, p) for command u, given ½q̇ᵀMq̇ + hi·ΣE(n) (J), for the true actuator
        gain g = `gain` and arm stiffness c = `stiffness` × the model's: ½(q − r q_u)ᵀcK(q − r q_u) +
        ½ g² Σβ max((p − u)², (p̄ − u)²), r = g/c, p̄ = `p_far` (None: p), segment by segment (the compiled
        `energy_kernels.energy_at`, which the certificate's kernels evaluate)."""
        terms = np.array([[self.energy_terms(gain, stiffness)]], dtype=float)
        pressure = np.array([p], dtype=float)
        return float(energy_kernels.energy_at(np.asarray(u, dtype=float), np.array([q], dtype=float), pressure,
                                              pressure if p_far is None else np.array([p_far], dtype=float), terms,
                                              0, 0, float(kinetic_and_plate)))

    def escape(self, u) -> float:
        """min_j (Γ̲_j(u) + c_j) (J) of the prior plate."""
        return min(g + c for g, c in zip(self.plate.table.values(u), self.plate.credit))

    def boundary_escape(self, u, plate: PlateCertificate) -> list[float]:
        """Γ̲^∂_j(u) for every row of `plate` (J): the larger of the boundary table's and the second-order bound's
        (`controllers.energy.escape_energy`; both are lower bounds of the least elastic energy to P's boundary),
        the second only where some row's table value is below BOUND_BELOW_J (any of the two is a valid bound)."""
        return lower_bounds(u, plate.table, plate.boundary_bound, BOUND_BELOW_J)

    def certificate_terms(self, u, call: GovernorCall, plate: PlateCertificate) -> tuple[float, float]:
        """(Γ, W) (J) of the command u (N,) hPa at the call's state x̂ on `plate`: the gain end with the least Γ − W,
        Γ = min_j (Γ̲_j(g·u) + o_j) (−inf outside P), W at g (module docstring; `energy_kernels.certificate_terms`)."""
        return self.row_terms(u, certificate_rows([call]), 0, plate)

    def row_terms(self, u, rows: tuple, b: int, plate: PlateCertificate) -> tuple[float, float]:
        """(Γ, W) (J) of the command u (N,) hPa at row b of `rows` (`certificate_rows` of calls on `plate`), as
        `certificate_terms` gives them for that row's call."""
        count = rows[8].shape[1]  # the offsets' rows P'
        gamma, w = energy_kernels.certificate_terms(np.asarray(u, dtype=float), b, *rows, *plate.lookup,
                                                    np.empty(self.n), np.empty(count), np.empty(count))
        return float(gamma), float(w)

    def tip(self, q) -> tuple[float, float]:
        """The model's tip r(q) (m) as Python floats."""
        return tip_of(self.dynamics.lengths, q)

    def rest_inside(self, u: np.ndarray, plate: PlateCertificate) -> bool:
        """Whether the rest shape q_u = K⁻¹Λu of the command u (N,) hPa puts the tip strictly inside `plate`'s P."""
        return rest_shape_inside(self.dynamics.lengths, self.a, plate.rows, u)

    def grid_rows_at_gain(self, gain: float) -> np.ndarray:
        """The prior plate's `PlateCertificate.grid_rows_at_gain`."""
        return self.plate.grid_rows_at_gain(gain)

    def contact_offsets(self, q: np.ndarray, plate: PlateCertificate) -> tuple[list[float], bool, float]:
        """The contact certificate's per-row offsets o_j (J) at q (N,) rad on `plate`
        (`PlateCertificate.contact_offsets`), whether the tip r(q) lies strictly inside its P, and its ρ
        (`ForceSafeSet.margin_at` of the context's set)."""
        x, y = self.tip(q)
        offsets, inside = plate.contact_offsets(x, y)
        return offsets, inside, self.context.safe_set.margin_at(x, y)

    def state_energy(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """(½q̇ᵀM(q)q̇ + hi·Σ_facets E(n_i(r(q))) in J (the plate term only when contact-aware),
        the tip's margin ρ in P (`ForceSafeSet.margin_at`, 1 outside the plate)).

        The tip r(q) is taken from `pcc.kinematics` (array path). The per-step model
        (`PCCDynamics.model_terms`, which also gives M) decides first: when its tip lies more
        than TIP_TOLERANCE_M outside every facet, so does the array path's tip (they differ by
        rounding, ≤ 1e-15 m: tests/test_energy_governor.py), every penetration is 0, ρ = 1 and the
        plate term is its value at n = 0, the same floats without the array path.
        """
        qd = np.asarray(qd, dtype=float)
        core = self.dynamics.model_terms([float(v) for v in q], [0.0] * self.n)
        kinetic = 0.5 * float(qd @ core.mass @ qd)  # `PCCDynamics.kinetic_energy`'s floats
        tip = core.kin[core.layout.tip_terms.start].item()
        x, y = tip.real, tip.imag
        if max(nx * x + ny * y - d for nx, ny, d in self.plate.facets) < -TIP_TOLERANCE_M:
            return kinetic + self.free_plate_energy if self.plate_weight else kinetic, 1.0
        tip = kinematics_unchecked(np.asarray(q, dtype=float), self.dynamics.lengths, 0).points[-1]
        rho = self.context.safe_set.margin_at(tip.real, tip.imag)
        if not self.plate_weight:
            return kinetic, rho
        nominal = self.context.safe_set
        plate = float(np.sum(nominal.stiffness.energy(nominal.penetration_at(tip.real, tip.imag))))
        return kinetic + self.plate_weight * plate, rho
