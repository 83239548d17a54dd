"""Energy-certified explicit reference governor (E-ERG, docs/beyond-the-paper.md#filters-beyond-the-paper) with a state predictor.

The elastic arm is its own stabilising controller: for a held command u (N,) hPa, its
rest shape q_u = K⁻¹Λu (rad) is an equilibrium, and an energy about q_u can only fall.

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
(`controllers.escape_energy`: Γ(u) = min over q with r(q) ∉ P of ½ (q − q_u)ᵀK(q − q_u),
tabulated as a lower bound).

The plate. Two variants. Plain (`contact_aware` False): the environment does not push
back (the PCC plant, the paper's simulation); the certificate is (1 + κ)W_u(x̂) + ε ≤ Γ(u).
Contact-aware: a facet pushes back with force ψ_true(n) ∈ [lo·ψ(n), hi·ψ(n)]
(`stiffness_lo_ratio`, `stiffness_hi_ratio`); it stores E_true(n) = ∫₀ⁿ ψ_true with
lo·E(n) ≤ E_true(n) ≤ hi·E(n) (E = `ψ.energy`), a conservative force, so W_u + E_true
never grows. Safety is F_true ≤ F_max, which holds if n ≤ n_max = ψ⁻¹(F_max/hi) (the
stiffest plate): P is built with that n_max whenever hi ≠ 1, in both variants. Leaving P
through facet j's row means n_j ≥ n_max, where the plate holds at least lo·E(n_max). So

    (1 + κ) [W_u(x̂) + hi Σ_facets E(n_i(x̂))] + ε ≤ min_j (Γ_j(u) + c_j),

c_j = lo·E(n_max) for facet rows, 0 for vertex-correction rows, implies
W_u + E_true ≤ Γ_j + c_j along the motion, hence the tip stays in P. The plain variant
is not sound where the plate pushes back while the tip is in contact (the plate's
stored energy can return to the arm), and the contact-aware one is not sound where the
plate does not push back (nothing stops the tip at n_max).
Contact certificate (`certificate="contact"`, the `c-erg` filter; issue 24). The parked
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
commands bit for bit those without the interval: tools/eerg_references.py). The true arm's gains are g·λ_i,
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
d_j(g·u_c) ≥ d̲_j(u_c) − |g − 1| ‖u_c‖_w ((*) of `controllers.escape_energy`, w_i = λ_i²/k_i: the rest
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
Gain feedback (`gain_estimate`, default off: then nothing below runs and the commands are those above bit for
bit). `controllers.gain_estimate` fits K⁻¹(M q̈ + (C + D) q̇ + K q) = g K⁻¹Λ p by least squares, p the pressure
the predictor integrates from this governor's commands, over samples out of contact (the model tip at least
`gain_clearance_m` clear of every facet plane) and, with `gain_contact` "normal" (default), in contact too: there
the plate's unknown force on the tip, along each near facet's normal, is eliminated (x projected K-orthogonally
off K⁻¹J_r(q̂)ᵀn̂_j; "any" eliminates the tangential force too, "off" takes no sample there); "rest" samples
(every |q̂̇_i| ≤ `gain_rest_rad_s`, in this estimate and in every one over the last `gain_rest_s` since the
previous rest sample, p settled, M q̈ + C q̇ left to the bound) and, where consecutive estimates are
at most `gain_difference_s` apart (1 kHz with an exact state), "difference" samples (q̈ from the two q̂̇, the
model's terms at their midpoint). Under its assumptions (each sample within Δ = `gain_noise_rad` of the model's
balance per segment, g constant and common to the segments, no force on the arm but the eliminated ones at the
tip) the true g lies in [ĝ − e, ĝ + e], e = Δ Σ_s Σ_i k_i|x̃_s,i| / Σ_s |x̃_s|²_K, and in the intersection of these
intervals with the prior [gain_lo_ratio, gain_hi_ratio], which only shrinks.
The governor certifies that narrowed interval from the call after it narrowed by 1 % of the prior's width
(`update_gain`; sound for every interval that contains g, the certificate above unchanged). Shrinking never
uncertifies the held command (the margin's minimum over a sub-interval is no smaller); an empty intersection
(an assumption proven false) returns the prior for good, until `reset`. The predictor still integrates the model's
gain (the assumption on the prediction above). What it gives (docs/results.md): at the camera rate a push from
rest reaches the plate before any sample out of contact, and the samples at rest against the plate narrow
[0.9, 1.1] while it presses (camera_push_120: 0.71 F_max with Δ = 5e-3 rad, 0.80 with Δ = 1.5e-3 rad and
`gain_rest_rad_s` 3e-3, 0.81 with `gain_rest_s` 0.2 and ε = 2e-6 J as well; the prior alone 0.23).

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

Times (refused with ControllerInputError, which the control step treats as a refused
command: hold, then vent; the governor's state is unchanged): NaN or infinite t or
t_capture, |t| or |t_capture| > TIME_LIMIT_S, an estimate from the future (t_capture > t),
and t going backwards across calls (t + δ before the latest recorded application time;
`reset` starts afresh). An estimate the predictor cannot reach — older than its history,
or with t_a − t_c > PREDICTION_HORIZON_S (2 s) — is "stale" at once (before, one 1000 s old
was integrated over 10⁶ steps: 8–20 s per call).

Each call (estimate captured at t_c, called at t, the command acting from t_a = t + δ,
δ = `command_delay_s` or the context's command delay):
1. target: the quasi-static governor's command for u_nom (`QuasiStaticGovernor`,
   margin `margin_m`, on the same P): its rest shape keeps the tip inside P, so Γ(target) > 0
   and the arm at rest at it is certified. The margin sets how fast the governor can move
   along P's boundary: a step of Δz (K-weighted rad) needs Γ ≥ ½(1 + κ)Δz² + ε, so a target
   parked at the boundary crawls. Default 5 mm; measured on the PCC plant at 10 Hz with
   camera timing, u_nom = 150 sin(2πt/T) hPa on both segments: longest time held beyond a
   retreating u_nom 0.4 s / 0.1 s (T = 8 s / 20 s), ρ_min 0.35; with 1 mm: 0.7 s / 0.8 s,
   ρ_min 0.16 / 0.13 (tools/bench_governors.py prints the figures).
2. prediction: x̂ = (q̂, q̂̇, p̂) at t_a from the estimate at t_c through the commands this
   governor issued and the pressure lag (`controllers.state_predictor`; contact-aware:
   with the model's plate pushing back); without it the
   certificate is evaluated at a state up to 0.2 s old (docs/beyond-the-paper.md#filters-beyond-the-paper: the governor then froze
   for 4–6 s against the plate while u_nom retreated).
3. step: along each ray from u_prev (the command acting at t_a, this governor's last
   output) towards a goal g, u(σ) = u_prev + σ (g − u_prev), the largest certified σ ∈ [0, 1]
   found by `bisection_steps` halvings (the certified σ need not form an interval: the
   result is certified, and the largest one when they do). σ = 1 towards the target ends
   the search ("free"); otherwise the goals are the target, the vented command 0 hPa and
   u_nom (clipped to the box), and the certified end point nearest the target wins (u_prev
   itself if none is nearer: "hold"). Near the boundary of P the straight ray to the
   target runs along it, where Γ is small, and advances slowly; the ray towards 0 hPa
   backs away from it first, which ends the hold when u_nom retreats (measured on the
   PCC plant: tests/test_energy_governor.py).
4. recovery: if even the held command fails ((1 + κ)W > Γ) at x̂ (model mismatch, a
   disturbance, a wrong estimate: a detected violation), the command is chosen among the
   table's grid commands, u_prev and the target: the certified one nearest the target,
   or, if none is certified (infeasible), the one with the largest certificate margin
   among those whose rest shape lies inside P (Γ̲ ≥ ε), so that the arm at least settles
   inside (the largest margin overall favours commands that hold the arm where it is,
   outside P: the least-violation trap of docs/model.md#control-barrier-function); the target if there is none.
The command is recorded for the predictor and returned; it lies in the box whenever the
context is bounded (the grid, u_prev and the target do, and so do their segments).

Assumptions of the guarantee (tip in P at all times): the model is the plant (M, C, K,
D, Λ, τ_p, the PCC kinematics, P and ψ within [lo, hi]); the estimate and the predictor
are accurate to within the κ-inflation; the commands this governor returns are applied
unchanged from t + δ and held until the next one acts (no clipping, no other source);
the valves start vented (p = 0) at `reset`; Γ̲ ≤ Γ (by construction); the arm starts
certified (e.g. at rest with its rest shape in P). Where it can fail: a wrong model
(an actuator gain outside [gain_lo_ratio, gain_hi_ratio], a plate stiffness outside its interval, arm
stiffness, plate position) is not covered by κ, and a state far from the
estimate is not caught until the next estimate shows it; the recovery then has no
guarantee.

Diagnostics per call (units in `DIAGNOSTIC_UNITS`): W_J (the certified energy of the
returned command at x̂, plate term included when contact-aware, before κ), Gamma_J
(min_j Γ̲_j + c_j at it), margin_J (Gamma_J − (1+κ)W_J − ε, and Gamma_J − (1+κ)W_J for
"hold", the held command's test: ≥ 0 for "free", "governed" and "hold"; < 0 beyond
rounding only in an infeasible "recover"),
step_fraction (σ along the ray to the target; NaN in recovery), blocked (1 when the
target was not reached), violation (1 when the held command failed its certificate at
x̂: the count of detected violations is their sum), prediction_s (t_a − t_c), solve_us
(the call's own wall time). All NaN but prediction_s and solve_us on a "stale" call.

Batched (`filter_batch`, the plug-in contract of `controllers.safety_filter`, issue 23): B rows, each a
governor of its own: its history (HISTORY_FIELDS: the predictor's command records, the target
governor's warm start, the gain estimate and the certified gain ends with their caches) is installed
for the row's steps 1–2 and 4 (`_install`), and step 3 runs once for all the rows in the compiled
`energy_kernels.govern_rows`, which `__call__` runs with one row: one implementation, row b bit
for bit the b-th of B governors called in turn (tests/test_energy_governor_batch.py, hypothesis
over closed-loop-like sequences with resets, subsets of rows, stale estimates and refused times).
Histories belong to row positions, or, given `rows`, to the caller's indices (the batched step's
simulations); a new one is a copy of this governor in its present state; `reset()` forgets all of
them, `reset(rows)` those. Refused times (ControllerInputError) are checked for every row before any
history changes. What it saves is step 3's per-call overhead only: the rows' predictions and
certificate states (steps 1–2) stay per row (tools/bench_governors.py --batch; docs/safety-filter.md).

Compute time (issues 13 and 24, tools/bench_governors.py, the `softcbf bench` step case). A camera-rate
call is step 2, 50–120 ROS2 steps over the estimate's age and the delay (`controllers.state_predictor`
runs them in compiled kernels, the plate's push included: ≈ 0.2 ms of CPU), then steps 3 or 4; a 1 kHz
call mostly step 1 (the quasi-static governor's QP iterations when u_nom's rest shape leaves P;
`QuasiStaticGovernor.command`, which remembers the commands of its last inputs: a held u_nom
cycles through a few), the state's energy (step 2's end) and step 3. Steps 3 and 4 are compiled
(`controllers.energy_kernels`, numba, loaded on the first call): step 3 is one call of
`govern_rows` (the held command's and the target's certificates, the rays' bisections, each
point's Γ̲ looked up in the kernel, ≈ 0.3 µs against ≈ 8–11 µs of Python floats near the
plate: ≈ 20 µs for the 2 × 12 bisection points of a "hold" call), step 4 one call of
`recovery_scan` over the table's grid (≈ 35 µs for its 14 641 commands, against 0.9–1.3 ms of
numpy). The kernels take every state with a leading row axis, which `filter_batch` uses for
B governors at once. A ray is skipped when no end point of it can come nearer the target
than the best so far (`ray_may_come_nearer`, with a rounding slack), and the state's energy
and ρ skip the array kinematics when the tip is clear of the plate (`state_energy`). None of
this changes a command: the kernels' arithmetic is the Python floats' operation for operation
(`x ** 2` as libm's pow, as Python computes it: `energy_kernels.PYTHON_SQUARE`), and the
commands are those of commit 45eacd9 (the step case: of 266e431; c-erg: of a6cdc5c), bit for bit
(tests/test_energy_governor_references.py, `python tools/eerg_references.py`: 0 hPa over every case).
"""

from __future__ import annotations

import copy
import math
import operator
import time
from dataclasses import dataclass, field, replace

import numpy as np

from controllers.dynamics import PCCDynamics
from controllers.errors import ControllerInputError, NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.escape_energy import (MAX_SEGMENTS, BoundaryDistanceBound, EscapeEnergyTable, lookup_arguments,
                                       lower_bounds)
from controllers.filter_parameters import FilterParameter, check_parameters, parameter_docs
from controllers.gain_estimate import GAIN_CONTACT, GainEstimator
from controllers.lazy_import import lazy_module
from controllers.pcc import kinematics_unchecked
from controllers.quasi_static_governor import PARAMETERS as QSG_PARAMETERS
from controllers.quasi_static_governor import QuasiStaticGovernor
from controllers.safe_set import ForceSafeSet
from controllers.safety_filter import BatchOutput, Estimate, EstimateBatch, FilterContext, FilterOutput, batch_history_ids
from controllers.state_predictor import StatePredictor
from controllers.bounds import Bound
from controllers.cbf_batch import checked_rows

energy_kernels = lazy_module("controllers.energy_kernels")  # numba loads on the first call (controllers.lazy_import)

TIP_TOLERANCE_M = 1e-9
"""A scalar tip this far outside every facet (m) has the array path's tip outside too (`EnergyGovernor.state_energy`)."""

DIAGNOSTIC_UNITS = {
    "W_J": "J", "Gamma_J": "J", "margin_J": "J", "step_fraction": "1", "blocked": "bool (1: the target was not reached)",
    "violation": "bool (1: the held command failed its certificate)", "prediction_s": "s", "solve_us": "µs",
}

GAIN_DIAGNOSTIC_UNITS = {**DIAGNOSTIC_UNITS, "gain_lo": "1", "gain_hi": "1", "gain_hat": "1"}
"""The diagnostics' units with `gain_estimate`: the certified gain interval and the estimate ĝ (module docstring)."""


PREDICTION_HORIZON_S = 2.0
"""The state predictor's horizon (s): an estimate whose prediction span t_a − t_c exceeds it is "stale"."""

MAX_COMMAND_DELAY_S = 0.5 * PREDICTION_HORIZON_S
"""Largest command delay δ (s): half the horizon, so an estimate up to that old can still be predicted."""

TIME_LIMIT_S = 1e9
"""Largest |t| and |t_capture| (s) a call accepts (32 years): far beyond, the delay and the estimate's age vanish in rounding."""

STIFFNESS_RATIOS = Bound(0.0, 1e3)
"""Valid plate stiffness ratios (1): a multiple of the model's ψ; hi must also be ≥ 1e-3 (P then grows 1000-fold)."""

GAIN_RATIOS = Bound(0.1, 10.0)
"""Valid actuator gain ratios (1): the true λ as a multiple of the model's; below 0.1 or above 10 the model is no model."""

PARAMETERS = {
    "margin_m": FilterParameter("rest-shape tip margin of the target (quasi-static governor) inside P", "m",
                                bound=QSG_PARAMETERS["margin_m"].bound),
    "kappa": FilterParameter("relative inflation of the certified energy against estimate/prediction errors", "1",
                             bound=Bound(0.0, 1e3)),
    "energy_margin_J": FilterParameter("absolute certificate margin ε; below ½ k_min (1.2 rad)², the escape energy "
                                       "the table resolves (checked at construction)", "J", bound=Bound(0.0, unit="J")),
    "contact_aware": FilterParameter("credit the plate's stored energy at the boundary (the plate pushes back)", "", bool),
    "stiffness_lo_ratio": FilterParameter("lowest true plate stiffness as a multiple of the model's ψ (<= hi)", "1",
                                          bound=STIFFNESS_RATIOS),
    "stiffness_hi_ratio": FilterParameter("highest true plate stiffness as a multiple of the model's ψ "
                                          "(n_max = ψ⁻¹(F_max/hi))", "1", bound=Bound(1e-3, 1e3)),
    "command_delay_s": FilterParameter("call → command acting at the valves (None: the context's, unknown = 0)", "s",
                                       bound=Bound(0.0, MAX_COMMAND_DELAY_S, unit="s"), optional=True),
    "actuator_tau_s": FilterParameter("valve pressure time constant τ_p (None: the context's, unknown = 0)", "s",
                                      bound=Bound(0.0, 10.0, unit="s"), optional=True),
    "grid_hPa": FilterParameter("command spacing of the escape-energy table; at most "
                                "controllers.escape_energy.MAX_TABLE_COMMANDS commands over the box "
                                "(checked at construction)", "hPa", bound=Bound(0.0, low_open=True, unit="hPa")),
    "predictor_step_s": FilterParameter("largest integration step of the state predictor", "s",
                                        bound=Bound(1e-4, 1e-2, unit="s")),
    "bisection_steps": FilterParameter("halvings of the step towards the target (beyond 52 a double's σ stops changing)",
                                       "1", int, Bound(1, 52)),
    "certificate": FilterParameter("'park' (the target parks margin_m inside P, Γ over the unsafe set) or 'contact' "
                                   "(the target is u_nom, Γ to P's boundary, the plate's energy counted per facet, κ on "
                                   "the kinetic energy: module docstring)", "", str),
    "escape_spacing_rad": FilterParameter("q-space spacing of the escape-energy table (per √k_i); finer: a tighter Γ̲ "
                                          "near P's boundary, a slower build (2.4 s at 4e-3, 6.7 s at 2e-3 on the "
                                          "reference arm)", "rad", bound=Bound(5e-4, 0.05, unit="rad")),
    "gain_lo_ratio": FilterParameter("lowest true actuator gain λ as a multiple of the model's (every segment alike; "
                                     "<= gain_hi_ratio; contact certificate only)", "1", bound=GAIN_RATIOS),
    "gain_hi_ratio": FilterParameter("highest true actuator gain λ as a multiple of the model's (the contact "
                                     "certificate holds for every gain in [lo, hi]: module docstring)", "1", bound=GAIN_RATIOS),
    "gain_estimate": FilterParameter("narrow [gain_lo_ratio, gain_hi_ratio] online to [ĝ − e, ĝ + e] from rest samples "
                                     "(in contact too: gain_contact) (controllers.gain_estimate; contact certificate "
                                     "only)", "", bool),
    "gain_noise_rad": FilterParameter("bound Δ on the rest samples' deviation from the model's balance per segment "
                                      "(estimate error and residual motion; gain_estimate only)", "rad",
                                      bound=Bound(0.0, 1.0, low_open=True, unit="rad")),
    "gain_rest_rad_s": FilterParameter("largest |q̇_i| of a rest sample (gain_estimate only)", "rad/s",
                                       bound=Bound(0.0, 10.0, unit="rad/s")),
    "gain_rest_s": FilterParameter("how long every estimate must have been at rest (|q̇_i| <= gain_rest_rad_s) before a "
                                   "rest sample is taken, and between two rest samples: the arm settled, not passing "
                                   "through q̇ = 0 (0: every estimate at rest; gain_estimate only)", "s",
                                   bound=Bound(0.0, 10.0, unit="s")),
    "gain_clearance_m": FilterParameter("least distance of a sample's tip from every facet plane for no contact "
                                        "(nearer: gain_contact; gain_estimate only)", "m", bound=Bound(0.0, 1.0, unit="m")),
    "gain_difference_s": FilterParameter("largest spacing of two estimates whose q̇ difference gives q̈ for a moving "
                                         "sample (0: rest samples only; gain_estimate only)", "s",
                                         bound=Bound(0.0, 0.1, unit="s")),
    "gain_contact": FilterParameter("samples with the tip within gain_clearance_m of a facet: 'normal' (the plate's "
                                    "force along its normal eliminated: frictionless), 'any' (also the tangential: "
                                    "friction), 'off' (none; controllers.gain_estimate; gain_estimate only)", "", str),
}
"""The E-ERG's parameters, declared once (`controllers.filter_parameters`): `check_arguments` and the constructor check them.

Computational bounds: command_delay_s ≤ MAX_COMMAND_DELAY_S keeps a prediction within the horizon
(δ = 100 s took 2 s per call: 10⁵ integration steps); predictor_step_s ≥ 1e-4 s caps a prediction at
PREDICTION_HORIZON_S/1e-4 = 2·10⁴ steps; bisection_steps ≤ 52; grid_hPa's table ≤ MAX_TABLE_COMMANDS commands
(1e-6 hPa asked for 639 PiB). Physical ones: κ ≥ 0 (an inflation; ≤ 1000: beyond, it is no estimate error),
ε ≥ 0 and below the table's saturation ½ k_min reach² (`EscapeEnergyTable.saturation_J`, 0.72 J on the
reference arm: a larger ε certifies no step at all), the stiffness ratios
0 ≤ lo ≤ hi, 1e-3 ≤ hi ≤ 1e3, the gain ratios 0.1 ≤ lo ≤ hi ≤ 10 (other than 1 only with the contact
certificate), τ_p ≤ 10 s; the gain estimate's Δ in (0, 1] rad (0 would trust a perfect model), |q̇| ≤ 10 rad/s
for a rest sample, a clearance ≤ 1 m, and estimates ≤ 0.1 s apart for a difference (beyond, no acceleration).
"""

BOUND_BELOW_J = 0.02
"""The contact certificate evaluates the second-order boundary bound only where the table's least row value is
below this (J): near the boundary, where the table is loose; beyond ≈ 0.01 J the table is the larger (measured
on the reference arm: 1.46e-2 against 1.15e-2 J at (32, 69) hPa, 0.10 against 0.057 J at rest), and the
bound's kinematics cost more than the table's look-up."""

HISTORY_FIELDS = ("predictor", "target_governor", "gain_estimator", "_gain_previous", "_rest_since", "gain_lo", "gain_hi",
                  "gains", "_energy_terms", "_grid_rows", "_scan_rows", "_kernel_terms")
"""What one governor's calls change (`EnergyGovernor.filter_batch` keeps one of these per simulation): the command
history, the target governor's warm start, the gain estimate (its samples, previous estimate and rest timer) with
the certified gain ends, and the caches of those ends (the recovery's grid rows, the kernels' energy terms)."""

_READ_HISTORY = operator.itemgetter(*HISTORY_FIELDS)

ACTION_NAMES = ("free", "governed", "hold", "recover")
"""The actions by `energy_kernels.govern_rows`' codes (FREE, GOVERNED, HOLD, RECOVER)."""

CERTIFICATES = ("park", "contact")
"""The `certificate` values (module docstring: the parked target, and the contact certificate)."""

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
    300 times that (`controllers.energy_kernels.ROUNDING_SLACK`, 1e-12). False therefore proves that
    no σ in the range gives a computed distance below `best`. σ = 0 gives a itself, which the caller
    has already counted. d = 0: False. The compiled ray search's test (`energy_kernels.ray_may_come_nearer`).
    """
    vectors = (np.asarray(v, dtype=float) for v in (start, goal, direction, aim))
    return bool(energy_kernels.ray_may_come_nearer(*vectors, float(best), float(sigma_min),
                                                   energy_kernels.PYTHON_SQUARE))


def pressure_lag_weights(context: FilterContext, actuator_tau: float) -> np.ndarray:
    """β_i = τ_p λ_i² / (4 d_i): (N,) J/hPa²; refuses τ_p > 0 with an undamped segment."""
    damping, gains = context.robot.array("damping"), context.robot.array("gains")
    if actuator_tau == 0.0:
        return np.zeros_like(gains)
    if np.any(damping <= 0):
        raise ValueError(f"a pressure lag (actuator_tau = {actuator_tau} s) needs damping > 0 on every segment, "
                         f"got {damping.tolist()}: the certificate's β = τ_p λ²/(4d) is undefined")
    return actuator_tau * gains**2 / (4.0 * damping)


@dataclass(eq=False)
class GovernorCall:
    """One call's state between its preparation and its step 3 (`EnergyGovernor._prepare`): the estimate's
    capture and the command's application times (s), u_prev, the target and u_nom clipped (N,) hPa; unless
    stale, the predicted q̂ (N,) rad and p̂ (N,) hPa, the certificate's base energy (J: (1 + κ)·½q̂̇ᵀMq̂̇
    for the contact certificate, the state's energy for the parked one), the rows' offsets o_j (J), whether
    x̂ lies strictly inside P, the tip's ρ, the inflation ι of W, the gain ends and their energy terms (E, 3, N)."""

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


def certificate_rows(calls: list[GovernorCall]) -> tuple:
    """The certificate's per-row arguments of `energy_kernels.certificate_terms` and `govern_rows` for the calls
    (B rows): the gain ends (B, E) and their count (B,), the energy terms (B, E, 3, N), base (B,) J, q̂ (B, N)
    rad, p̂ (B, N) hPa, the offsets (B, P') J and inside (B,); E the most ends of a call, the others' padded
    (never read: a row reads its count)."""
    ends = np.array([len(c.gains) for c in calls])
    most = int(ends.max())
    if most == len(calls[0].gains) and all(c.terms is calls[0].terms for c in calls):
        gains, terms = np.array([calls[0].gains] * len(calls)), np.array([calls[0].terms] * len(calls))
    else:
        gains = np.array([c.gains + (1.0,) * (most - len(c.gains)) for c in calls], dtype=float)
        terms = np.zeros((len(calls), most) + calls[0].terms.shape[1:])
        for b, c in enumerate(calls):
            terms[b, :len(c.gains)] = c.terms
    return (gains, ends, terms, np.array([c.base for c in calls]), np.array([c.q_hat for c in calls]),
            np.array([c.p_hat for c in calls]), np.array([c.offsets for c in calls], dtype=float),
            np.array([c.inside for c in calls]))


class EnergyGovernor:
    """The E-ERG as a safety filter (see the module docstring for the maths, actions and assumptions).

    Actions: "free" (σ = 1: the target is certified), "governed" (a certified step along
    one of the rays), "hold" (no step nearer the target), "recover" (the held command failed; infeasible when no candidate is
    certified), "stale" (the predictor cannot reach the estimate: older than its history or
    than PREDICTION_HORIZON_S; the held command is kept, infeasible). Bad times raise
    ControllerInputError (module docstring).
    """

    parameter_docs = parameter_docs(PARAMETERS)

    def __init__(self, context: FilterContext, margin_m: float = 5e-3, kappa: float = 0.5, energy_margin_J: float = 1e-5,
                 contact_aware: bool = False, stiffness_lo_ratio: float = 1.0, stiffness_hi_ratio: float = 1.0,
                 command_delay_s: float | None = None, actuator_tau_s: float | None = None, grid_hPa: float = 2.5,
                 predictor_step_s: float = 1e-3, bisection_steps: int = 12, certificate: str = "park",
                 escape_spacing_rad: float = 4e-3, gain_lo_ratio: float = 1.0, gain_hi_ratio: float = 1.0,
                 gain_estimate: bool = False, gain_noise_rad: float = 5e-3, gain_rest_rad_s: float = 0.02,
                 gain_rest_s: float = 0.0, gain_clearance_m: float = 5e-3,
                 gain_difference_s: float = 0.0, gain_contact: str = "normal") -> None:
        checked = self.check_arguments({"certificate": certificate, "escape_spacing_rad": escape_spacing_rad,
            "gain_lo_ratio": gain_lo_ratio, "gain_hi_ratio": gain_hi_ratio, "gain_estimate": gain_estimate,
            "gain_noise_rad": gain_noise_rad, "gain_rest_rad_s": gain_rest_rad_s, "gain_rest_s": gain_rest_s,
            "gain_clearance_m": gain_clearance_m, "gain_difference_s": gain_difference_s, "gain_contact": gain_contact,
            "margin_m": margin_m, "kappa": kappa, "energy_margin_J": energy_margin_J, "contact_aware": contact_aware,
            "stiffness_lo_ratio": stiffness_lo_ratio, "stiffness_hi_ratio": stiffness_hi_ratio,
            "command_delay_s": command_delay_s, "actuator_tau_s": actuator_tau_s, "grid_hPa": grid_hPa,
            "predictor_step_s": predictor_step_s, "bisection_steps": bisection_steps})
        delay = context.command_delay if command_delay_s is None else checked["command_delay_s"]
        tau = context.actuator_tau if actuator_tau_s is None else checked["actuator_tau_s"]
        delay, tau = (0.0 if delay is None else float(delay)), (0.0 if tau is None else float(tau))
        for name, value in (("command_delay_s", delay), ("actuator_tau_s", tau)):  # the context's, when not given
            PARAMETERS[name].check(f"{name} (the context's)", value)
        law = context.safe_set.stiffness
        if not callable(getattr(law, "energy", None)):
            raise ValueError(f"the plate's stiffness law {type(law).__name__} has no energy(n); "
                             "use LinearStiffness or PowerLawStiffness")
        self.kappa, self.energy_margin = checked["kappa"], checked["energy_margin_J"]
        self.contact_aware = checked["contact_aware"]
        self.stiffness_lo, self.stiffness_hi = checked["stiffness_lo_ratio"], checked["stiffness_hi_ratio"]
        self.gain_lo, self.gain_hi = checked["gain_lo_ratio"], checked["gain_hi_ratio"]
        # the gain ends the certificate is checked at (module docstring, "actuator gain"): (1.0,) is the model alone
        self.gains = tuple(sorted({self.gain_lo, self.gain_hi}))
        self.command_delay, self.actuator_tau = delay, tau
        self.bisection_steps = checked["bisection_steps"]
        self.context = context
        robot = context.robot
        self.n = robot.n_segments
        nominal = context.safe_set
        self.safe_set = nominal if self.stiffness_hi == 1.0 else ForceSafeSet(
            nominal.environment, law, nominal.f_max / self.stiffness_hi, nominal.row_scaling)
        governed = replace(context, safe_set=self.safe_set)
        self.contact = checked["certificate"] == "contact"
        self.target_governor = None if self.contact else QuasiStaticGovernor(governed, margin_m=margin_m)
        u_lo = robot.array("u_min") if context.u_min is None else context.u_min
        u_hi = robot.array("u_max") if context.u_max is None else context.u_max
        self.beta = pressure_lag_weights(context, tau)
        gridded = not self.contact or self.n <= MAX_SEGMENTS  # the contact certificate needs no table for N > 2
        self.table = EscapeEnergyTable(robot, self.safe_set, u_lo, u_hi, grid_hPa=grid_hPa, boundary=self.contact,
                                       q_spacing_rad=checked["escape_spacing_rad"]) if gridded else None
        self.boundary_bound = BoundaryDistanceBound(robot, self.safe_set) if self.contact else None
        credit = self.stiffness_lo * float(law.energy(self.safe_set.n_max)) if self.contact_aware else 0.0
        self._n_facets = nominal.n_facets
        self._rows = [(hx, hy, h) for (hx, hy), h in zip(np.asarray(self.safe_set.H_prime).tolist(),
                                                         np.asarray(self.safe_set.h_prime).tolist())]
        self._plate_weight = self.stiffness_hi if self.contact_aware else 0.0
        self._credit = [0.0 if corner else credit for corner in self.safe_set.is_vertex_correction.tolist()]
        self.dynamics = PCCDynamics(robot)
        self.predictor = StatePredictor(self.dynamics, tau, step_s=checked["predictor_step_s"],
                                        horizon_s=PREDICTION_HORIZON_S, plate=context.safe_set if self.contact_aware else None)
        self._k = robot.array("stiffness").tolist()
        self._a = (robot.array("gains") / robot.array("stiffness")).tolist()
        self._beta = self.beta.tolist()
        self._box = None if context.u_min is None else (context.u_min, context.u_max)
        self._rest_list = tuple((np.zeros(self.n) if self._box is None else np.clip(np.zeros(self.n), *self._box)).tolist())
        self._facets = [(nx, ny, d) for (nx, ny), d in zip(nominal.environment.normals.tolist(), nominal.environment.offsets.tolist())]
        self._free_plate_energy = self._plate_weight * float(np.sum(law.energy([0.0] * len(self._facets))))  # n = 0 everywhere
        if self.table is None:  # N > 2, contact certificate: the recovery's candidates are u_prev, u_nom and 0 hPa
            self._grid = np.array([self._rest_list])
            self._grid_values = np.array([self.boundary_bound.values(self._rest_list)]).T
            self._grid_rest_inside = np.array([self.rest_inside(self._grid[0])])
        else:
            self._grid = self.table.grid_commands()
            self._grid_values, self._grid_rest_inside = self.table.grid_values(), self.table.rest_inside
        self._scan_rows: tuple[tuple, np.ndarray] | None = None  # (gains, the recovery's grid rows (E, P', G) for them)
        self._kernel_terms: tuple | None = None  # (gains, their energy terms (E, 3, N): k, g·a, g²β): `_prepare`
        self._lookup = lookup_arguments(self.table, self.boundary_bound, BOUND_BELOW_J)  # the kernels' Γ̲ look-up
        self._rest = np.array(self._rest_list)
        self._grid_columns = np.ascontiguousarray(self._grid.T)  # (N, G): the compiled recovery scan's layout
        self.set_gain_ends(self.gain_lo, self.gain_hi)
        self.gain_estimator = GainEstimator(self._k, self._a, robot.array("damping"), (self.gain_lo, self.gain_hi),
                                            checked["gain_noise_rad"]) if checked["gain_estimate"] else None
        self.gain_prior = (self.gain_lo, self.gain_hi)
        self.gain_rest, self.gain_clearance = checked["gain_rest_rad_s"], checked["gain_clearance_m"]
        self.gain_rest_hold = checked["gain_rest_s"]
        self.gain_difference, self.gain_contact = checked["gain_difference_s"], checked["gain_contact"]
        self._gain_previous: tuple | None = None  # (t_capture, q, q̇) of the previous estimate (`update_gain`)
        self._rest_since: float | None = None  # t_capture of the first estimate of the current run at rest (`update_gain`)
        self._histories: list[dict] = []  # `filter_batch`'s, one per simulation (HISTORY_FIELDS → value)
        self._grid_gamma = np.min(self._grid_values + np.array(self._credit)[:, None], axis=0)
        if self.table is not None and not self.energy_margin < self.table.saturation_J:
            raise ValueError(f"energy_margin_J must be < {self.table.saturation_J:.6g} J (½ k_min reach², the escape "
                             f"energy the table resolves), got {self.energy_margin!r}")

    @staticmethod
    def check_arguments(arguments: dict[str, object]) -> dict[str, object]:
        """What the constructor refuses of `arguments` (by name), checked without a context: the
        declared bounds (`PARAMETERS`) and stiffness_lo_ratio ≤ stiffness_hi_ratio; returns the
        checked values. (The context's delay and time constant, the table's size and ε against
        the table are checked at construction.)"""
        checked = check_parameters(PARAMETERS, arguments)
        if checked.get("certificate", "park") not in CERTIFICATES:
            raise ValueError(f"certificate must be one of {', '.join(CERTIFICATES)}, got {checked['certificate']!r}")
        lo, hi = checked.get("stiffness_lo_ratio", 1.0), checked.get("stiffness_hi_ratio", 1.0)
        if lo > hi:
            raise ValueError(f"stiffness_lo_ratio must be <= stiffness_hi_ratio = {hi!r}, got {lo!r}")
        lo, hi = checked.get("gain_lo_ratio", 1.0), checked.get("gain_hi_ratio", 1.0)
        if lo > hi:
            raise ValueError(f"gain_lo_ratio must be <= gain_hi_ratio = {hi!r}, got {lo!r}")
        if (lo, hi) != (1.0, 1.0) and checked.get("certificate", "park") != "contact":
            raise ValueError(f"gain_lo_ratio and gain_hi_ratio other than 1 need certificate='contact' (the parked "
                             f"target's rest shape assumes the model's gain), got [{lo!r}, {hi!r}]")
        if checked.get("gain_contact", "normal") not in GAIN_CONTACT:
            raise ValueError(f"gain_contact must be one of {', '.join(GAIN_CONTACT)}, got {checked['gain_contact']!r}")
        if checked.get("gain_estimate", False) and checked.get("certificate", "park") != "contact":
            raise ValueError("gain_estimate needs certificate='contact' (the certificate that covers a gain interval)")
        return checked

    def reset(self, rows=None) -> None:
        """Forget the command history (vented valves, p = 0), the target governor's warm start and the gain
        estimate, and every history of `filter_batch`; with `rows` (indices of `filter_batch` histories), those
        histories alone (one simulation's new episode), as if their governors were reset."""
        if rows is not None:
            for i in batch_history_ids(rows).tolist():
                self._grow_histories(i + 1)
                saved = self._install(self._histories[i])
                try:
                    self._reset_own()
                finally:
                    self._histories[i] = self._install(saved)
            return
        self._reset_own()
        self._histories = []

    def _reset_own(self) -> None:
        """`reset` of the installed history (the governor's own, or a row's: `_install`)."""
        self.predictor.reset()
        if self.target_governor is not None:
            self.target_governor.reset()
        if self.gain_estimator is not None:
            self.gain_estimator.reset()
            self.set_gain_ends(*self.gain_prior)
            self._gain_previous = self._rest_since = None

    # -- batched (B governors: one history each) -----------------------------------------------------------
    def _install(self, history: dict) -> dict:
        """Make `history` (HISTORY_FIELDS → value) this governor's state; return the state it replaces."""
        state = self.__dict__
        previous = dict(zip(HISTORY_FIELDS, _READ_HISTORY(state)))
        state.update(history)
        return previous

    def _copy_history(self) -> dict:
        """A copy of the installed history: what changes across calls copied (the predictor's records, the target
        governor's previous command, the gain estimator), the rest shared (never changed in place; the target
        governors' shallow copies share `QuasiStaticGovernor.command`'s memory, a function's values)."""
        history = {name: getattr(self, name) for name in HISTORY_FIELDS}
        history["predictor"] = self.predictor.copy()
        history["target_governor"] = None if self.target_governor is None else copy.copy(self.target_governor)
        history["gain_estimator"] = None if self.gain_estimator is None else copy.deepcopy(self.gain_estimator)
        history["_grid_rows"] = dict(self._grid_rows)
        return history

    def _grow_histories(self, needed: int) -> None:
        """Histories up to index needed − 1, the new ones copies of this governor in its present state."""
        while len(self._histories) < needed:
            self._histories.append(self._copy_history())

    def filter_batch(self, estimates: EstimateBatch, u_nom, rows=None) -> BatchOutput:
        """B governors at once: row b is, bit for bit, a call of the governor whose history is rows[b] (None: b),
        each history a copy of this governor in its state at its first call after `reset` (module docstring,
        "Batched"); u_nom (B, N) hPa. A non-finite or misshapen row raises for the whole call
        (NonFiniteStateError / NonFiniteCommandError), a row whose times the governor refuses raises
        ControllerInputError before any history changes, and a call without `rows` with fewer rows than the
        histories held raises ValueError (which history is which would be a guess)."""
        n_rows, n = len(estimates), self.n
        q = checked_rows("q", estimates.q, (n_rows, n), NonFiniteStateError)
        qd = checked_rows("qd", estimates.qd, (n_rows, n), NonFiniteStateError)
        u_nom = checked_rows("u_nom", u_nom, (n_rows, n), NonFiniteCommandError)
        t = np.asarray(estimates.t, dtype=float).reshape(n_rows).tolist()
        t_capture = np.asarray(estimates.t_capture, dtype=float).reshape(n_rows).tolist()
        ids = batch_history_ids(rows, n_rows, len(self._histories)).tolist()
        self._grow_histories(max(ids) + 1 if ids else 0)
        t_apply = []
        for b, i in enumerate(ids):  # every row's times first: a refusal changes no history
            try:
                t_apply.append(self._apply_time(t[b], t_capture[b], self._histories[i]["predictor"]))
            except ControllerInputError as exc:
                raise ControllerInputError(f"row {b}: {exc}") from exc
        calls = []
        for b, i in enumerate(ids):
            saved = self._install(self._histories[i])
            try:
                calls.append(self._prepare(q[b], qd[b], u_nom[b], t_capture[b], t_apply[b]))
            finally:
                self._histories[i] = self._install(saved)
        live = [b for b, call in enumerate(calls) if not call.stale]
        outputs = self._govern([calls[b] for b in live]) if live else None
        position = {b: k for k, b in enumerate(live)}
        u, action = np.empty((n_rows, n)), np.empty(n_rows, dtype=object)
        infeasible, rho = np.zeros(n_rows, dtype=bool), np.full(n_rows, math.nan)
        for b, i in enumerate(ids):
            call, t0 = calls[b], time.perf_counter()
            saved = self._install(self._histories[i])
            try:
                out = (self._finish(call.u_prev, "stale", True, math.nan, {}, call.t_apply, call.t_capture, t0)
                       if call.stale else self._conclude(call, outputs, position[b], t0))
            finally:
                self._histories[i] = self._install(saved)
            u[b], action[b], infeasible[b], rho[b] = out.u, out.action, out.infeasible, out.rho_pred
        return BatchOutput(u, action.astype(str), infeasible, rho)

    def gain_interval(self, row: int | None = None) -> tuple[float, float]:
        """The certified actuator gain interval [lo, hi] (1): this governor's own, or that of `filter_batch`'s
        history `row` (IndexError for a row it does not hold)."""
        if row is None:
            return self.gain_lo, self.gain_hi
        history = self._histories[row]
        return history["gain_lo"], history["gain_hi"]

    def set_gain_ends(self, lo: float, hi: float) -> None:
        """Certify the gain interval [lo, hi] from now on (module docstring, "actuator gain"; narrowed online by
        `gain_estimate`): the ends' energy terms (K, g·K⁻¹Λ, g²β; g = 1 gives the model's floats exactly,
        1.0·x = x) and the recovery's grid rows (computed when needed)."""
        self.gain_lo, self.gain_hi = lo, hi
        self.gains = tuple(sorted({lo, hi}))
        self._energy_terms = {g: (self._k, [g * a for a in self._a], [g * g * b for b in self._beta]) for g in self.gains}
        self._grid_rows: dict[float, np.ndarray] = {}  # g → `grid_rows_at_gain(g)`, computed when needed

    def update_gain(self, q: np.ndarray, qd: np.ndarray, t_capture: float) -> None:
        """Offer the estimate (q, q̇) at t_capture to the gain estimator (`controllers.gain_estimate`), as a difference
        sample when the previous estimate was captured at most gain_difference_s before (midpoint state, q̈ by the
        difference of the q̇'s, y = K⁻¹(M q̈ + C q̇ + D q̇ + K q)), else as a rest sample when every |q̇_i| ≤
        gain_rest_rad_s, in this estimate and in every one captured over the last gain_rest_s (an arm that has
        settled, not one passing through q̇ = 0; with gain_rest_s > 0 the timer restarts at each rest sample, so an
        arm resting at 1 kHz offers one per gain_rest_s, not one per call), and the model's pressure has settled
        (|λ_i/k_i (p_i − u_i)| ≤ gain_noise_rad). With the model's tip at least gain_clearance_m clear of every facet
        plane the sample is one out of contact; else (`gain_contact` not "off") the plate's force on the tip is
        eliminated: along the normal n̂_j of each facet within the clearance ("normal", a frictionless plate), and
        along its tangent too ("any"), the directions J_r(q)ᵀv at the sample's q (`GainEstimator.sample_in_contact`).
        Its interval is applied once it has narrowed by 1 % of the prior's width (a wider interval than the estimator's is also sound, and each change rebuilds
        the ends' terms), or at once when it fell back to the prior."""
        estimator, previous = self.gain_estimator, self._gain_previous
        self._gain_previous = (t_capture, q, qd)
        moving = previous is not None and 0.0 < t_capture - previous[0] <= self.gain_difference
        if max(abs(v) for v in qd.tolist()) > self.gain_rest:
            self._rest_since = None
        elif self._rest_since is None:
            self._rest_since = t_capture
        if not moving and (self._rest_since is None or t_capture - self._rest_since < self.gain_rest_hold):
            return  # neither kind of sample (checked before the kinematics: the common case at the camera rate)
        if not moving and self.gain_rest_hold > 0.0:
            self._rest_since = t_capture  # the next rest sample after gain_rest_s more at rest: one per gain_rest_s
        x, y = self._tip(q)
        near = [(nx, ny) for nx, ny, d in self._facets if nx * x + ny * y - d > -self.gain_clearance]
        if near and self.gain_contact == "off":
            return
        if moving:
            t0, q0, qd0 = previous
            h = t_capture - t0
            q_sample, qd_mid = 0.5 * (q0 + q), 0.5 * (qd0 + qd)
            terms = self.dynamics.evaluate(q_sample, qd_mid)
            residual = (terms.mass @ ((qd - qd0) / h) + terms.bias) / np.asarray(self._k)
            p = self.predictor.pressure_at(t0 + 0.5 * h)
        else:
            q_sample, p = q, self.predictor.pressure_at(t_capture)
            if np.any(np.abs(estimator.a * (p - self.predictor.command_at(t_capture))) > estimator.noise_rad):
                return
            residual = estimator.rest_residual(q, qd)
        if near:
            jac = kinematics_unchecked(np.asarray(q_sample, dtype=float), self.dynamics.lengths, 1).jac[-1]  # ∂r/∂q as x + iy
            directions = near if self.gain_contact == "normal" else near + [(-ny, nx) for nx, ny in near]
            torques = np.array([jac.real * vx + jac.imag * vy for vx, vy in directions]).T  # (N, m): J_r(q)ᵀv
            accepted = estimator.sample_in_contact(p, residual, torques)
        else:
            accepted = estimator.sample(p, residual)
        if accepted:
            lo, hi = estimator.interval
            width = self.gain_hi - self.gain_lo
            if estimator.inconsistent or hi - lo <= width - 0.01 * (self.gain_prior[1] - self.gain_prior[0]):
                self.set_gain_ends(lo, hi)

    # -- certificate ------------------------------------------------------------------
    def energy(self, kinetic_and_plate: float, q: list[float], p: list[float], u, gain: float = 1.0) -> float:
        """W_u + plate term at (q, p) for command u, given ½q̇ᵀMq̇ + hi·ΣE(n) (J), for the true actuator
        gain g = `gain` × the model's (one of `gains`): ½(q − g q_u)ᵀK(q − g q_u) + ½ g² Σβ(p − u)², segment
        by segment (the compiled `energy_kernels.energy_at`, which the certificate's kernels evaluate)."""
        terms = np.array([[self._energy_terms[gain]]], dtype=float)
        return float(energy_kernels.energy_at(np.asarray(u, dtype=float), np.array([q], dtype=float),
                                              np.array([p], dtype=float), terms, 0, 0, float(kinetic_and_plate),
                                              energy_kernels.PYTHON_SQUARE))

    def escape(self, u) -> float:
        """min_j (Γ̲_j(u) + c_j) (J)."""
        return min(g + c for g, c in zip(self.table.values(u), self._credit))

    def boundary_escape(self, u) -> list[float]:
        """Γ̲^∂_j(u) for every row (J): the larger of the boundary table's and the second-order bound's
        (`controllers.escape_energy`; both are lower bounds of the least elastic energy to P's boundary),
        the second only where some row's table value is below BOUND_BELOW_J (any of the two is a valid bound)."""
        return lower_bounds(u, self.table, self.boundary_bound, BOUND_BELOW_J)

    def contact_offsets(self, q: np.ndarray) -> tuple[list[float], bool, float]:
        """The contact certificate's per-row offsets o_j (J) at q (N,) rad, whether the tip r(q) lies
        strictly inside P (every row H'_j r < h'_j; module docstring, "contact certificate") and its ρ
        (`ForceSafeSet.margin_at` of the context's set).

        Facet row j: o_j = lo·(E(n_max) − E(n_j)) − hi Σ_{i≠j} E(n_i); vertex-correction row:
        o_j = −hi Σ_i E(n_i); n_i the model's facet penetrations at r(q) (m), E = ψ.energy.
        Without contact_aware every o_j = 0 (the environment does not push back)."""
        x, y = self._tip(q)
        inside = all(hx * x + hy * y < h for hx, hy, h in self._rows)
        nominal = self.context.safe_set
        rho = nominal.margin_at(x, y)
        if not self.contact_aware:
            return [0.0] * len(self._rows), inside, rho
        energies = np.asarray(nominal.stiffness.energy(nominal.penetration_at(x, y)), dtype=float).tolist()
        total = self.stiffness_hi * sum(energies)
        offsets = [credit - self.stiffness_lo * e - self.stiffness_hi * (sum(energies) - e) if j < self._n_facets
                   else -total for j, (credit, e) in enumerate(zip(self._credit, energies + [0.0] * len(self._rows)))]
        return offsets, inside, rho

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
        if max(nx * x + ny * y - d for nx, ny, d in self._facets) < -TIP_TOLERANCE_M:
            return kinetic + self._free_plate_energy if self._plate_weight else kinetic, 1.0
        return self._plate_and_margin(kinetic, kinematics_unchecked(np.asarray(q, dtype=float), self.dynamics.lengths, 0).points[-1])

    def _plate_and_margin(self, kinetic: float, tip: complex) -> tuple[float, float]:
        """`state_energy` from the kinetic energy (J) and the tip r (m)."""
        rho = self.context.safe_set.margin_at(tip.real, tip.imag)
        if not self._plate_weight:
            return kinetic, rho
        nominal = self.context.safe_set
        return kinetic + self._plate_weight * float(np.sum(nominal.stiffness.energy(nominal.penetration_at(tip.real, tip.imag)))), rho

    # -- the filter -------------------------------------------------------------------
    def __call__(self, estimate: Estimate, u_nom) -> FilterOutput:
        """Govern u_nom (N,) hPa at `estimate`; see the module docstring."""
        t0 = time.perf_counter()
        q = as_vector("q", estimate.q, self.n, NonFiniteStateError)
        qd = as_vector("qd", estimate.qd, self.n, NonFiniteStateError)
        u_nom = as_vector("u_nom", u_nom, self.n, NonFiniteCommandError)
        t_apply = self._apply_time(float(estimate.t), float(estimate.t_capture), self.predictor)
        call = self._prepare(q, qd, u_nom, float(estimate.t_capture), t_apply)
        if call.stale:
            return self._finish(call.u_prev, "stale", True, math.nan, {}, t_apply, call.t_capture, t0)
        return self._conclude(call, self._govern([call]), 0, t0)

    def _apply_time(self, t: float, t_capture: float, predictor: StatePredictor) -> float:
        """t_a = t + δ (s) for a call at t with an estimate captured at t_capture, given the call's history's
        predictor, or ControllerInputError (module docstring, "Times"): checked before the call changes anything."""
        if not -TIME_LIMIT_S <= t_capture <= t <= TIME_LIMIT_S:  # also False for NaN
            raise ControllerInputError(f"the estimate's times must satisfy -{TIME_LIMIT_S:g} <= t_capture <= t <= "
                                       f"{TIME_LIMIT_S:g} s, got t_capture = {t_capture!r}, t = {t!r}")
        t_apply = t + self.command_delay
        if t_apply < predictor.latest_time:
            raise ControllerInputError(f"t must not go backwards: got t = {t!r} s after a call at "
                                       f"t = {predictor.latest_time - self.command_delay!r} s (reset first)")
        return t_apply

    def _prepare(self, q: np.ndarray, qd: np.ndarray, u_nom: np.ndarray, t_capture: float,
                 t_apply: float) -> GovernorCall:
        """Steps 1 and 2 of a call (module docstring) and the certificate's state at x̂: everything before the
        compiled step 3 (`energy_kernels.govern_rows`), which takes the calls of one or many governors."""
        nominal = u_nom if self._box is None else np.clip(u_nom, *self._box)
        target = nominal if self.contact else self.target_governor.command(u_nom)
        u_prev = self.predictor.command_at(t_apply)
        call = GovernorCall(t_capture, t_apply, u_prev, target, nominal)
        if not self.predictor.can_predict(t_capture, t_apply):
            call.stale = True
            return call
        if self.gain_estimator is not None:
            self.update_gain(q, qd, t_capture)
        q_hat, qd_hat, p_hat = self.predictor.predict(t_capture, q, qd, t_apply)
        if self.contact:
            offsets, inside, rho = self.contact_offsets(q_hat)
            base = (1.0 + self.kappa) * self.dynamics.kinetic_energy(q_hat, qd_hat)  # (1 + κ)·½q̇ᵀMq̇
            inflation = 1.0  # κ inflates the kinetic energy alone
        else:
            base, rho = self.state_energy(q_hat, qd_hat)
            offsets, inside, inflation = self._credit, True, 1.0 + self.kappa
        if self._kernel_terms is None or self._kernel_terms[0] != self.gains:
            self._kernel_terms = (self.gains, np.array([self._energy_terms[g] for g in self.gains], dtype=float))
        call.q_hat, call.p_hat, call.base, call.offsets, call.inside, call.rho = q_hat, p_hat, base, offsets, inside, rho
        call.inflation, call.gains, call.terms = inflation, self.gains, self._kernel_terms[1]
        return call

    def _govern(self, calls: list[GovernorCall]) -> tuple:
        """Step 3 for the calls (module docstring), row b the call calls[b]: `energy_kernels.govern_rows`."""
        return energy_kernels.govern_rows(
            np.array([c.u_prev for c in calls]), np.array([c.target for c in calls]), self._rest,
            np.array([c.nominal for c in calls]), 2 if self.contact else 3, *certificate_rows(calls),
            calls[0].inflation, self.energy_margin, self.bisection_steps, *self._lookup)

    def _conclude(self, call: GovernorCall, outputs: tuple, b: int, t0: float) -> FilterOutput:
        """Step 4 where step 3 found the held command failed, the diagnostics, and the command recorded for the
        predictor: the call's output from row b of `_govern`'s outputs."""
        u_rows, codes, sigmas, gammas, ws, held_margins = outputs
        code, sigma, held_margin = int(codes[b]), float(sigmas[b]), float(held_margins[b])
        held_ok = held_margin > 0.0  # Γ = W = 0 (the arm at rest on or beyond P's boundary) certifies nothing
        infeasible, action = False, ACTION_NAMES[code]
        if code == energy_kernels.RECOVER:
            if self.contact:
                u, infeasible = self._recover_contact(call.base, call.offsets, call.inside, call.q_hat, call.p_hat,
                                                      call.u_prev, call.target)
            else:
                u, infeasible = self._recover(call.base, call.q_hat, call.p_hat, call.u_prev, call.target)
            gamma, w = self.certificate_terms(u, call)
        else:
            u, gamma, w = u_rows[b], float(gammas[b]), float(ws[b])
        # the held command keeps its certificate down to Γ − ιW = 0 (the hysteresis), a new one needs ε
        certified_margin = held_margin if action == "hold" else gamma - call.inflation * w - self.energy_margin
        diagnostics = {"W_J": w, "Gamma_J": gamma, "margin_J": certified_margin,
                       "step_fraction": sigma, "blocked": float(action != "free"), "violation": float(not held_ok)}
        return self._finish(u, action, infeasible, call.rho, diagnostics, call.t_apply, call.t_capture, t0)

    def certificate_terms(self, u, call: GovernorCall) -> tuple[float, float]:
        """(Γ, W) (J) of the command u (N,) hPa at the call's state x̂: the gain end with the least Γ − W,
        Γ = min_j (Γ̲_j(g·u) + o_j) (−inf outside P), W at g (module docstring; `energy_kernels.certificate_terms`)."""
        rows = len(call.offsets)
        gamma, w = energy_kernels.certificate_terms(np.asarray(u, dtype=float), 0, *certificate_rows([call]),
                                                    *self._lookup, np.empty(self.n), np.empty(rows), np.empty(rows))
        return float(gamma), float(w)

    def _recover(self, base: float, q_hat: np.ndarray, p_hat: np.ndarray, u_prev: np.ndarray,
                 target: np.ndarray) -> tuple[np.ndarray, bool]:
        """The held command failed: the certified candidate nearest the target, else the best margin among the
        candidates whose rest shape lies inside P (Γ ≥ ε); the compiled scan (`controllers.energy_kernels`)."""
        extra_rows = np.array([[self.table.values(c) for c in (u_prev, target)]]).transpose(0, 2, 1)  # (1, P', 2)
        terms = np.array([(self._k, self._a, self._beta)])
        return self._scan(self._grid_values[None], extra_rows, self._credit, terms, base, q_hat, p_hat, u_prev,
                          target, 1.0 + self.kappa, True, None)

    def _scan(self, grid_rows: np.ndarray, extra_rows: np.ndarray, offsets: list[float], terms: np.ndarray,
              base: float, q_hat: np.ndarray, p_hat: np.ndarray, u_prev: np.ndarray, target: np.ndarray,
              inflation: float, inside: bool, resting_extra: np.ndarray | None) -> tuple[np.ndarray, bool]:
        """The recovery's choice among the grid commands, u_prev and the target (`energy_kernels.recovery_scan`):
        grid_rows (E, P', G) and extra_rows (E, P', 2) per gain end; resting_extra None: the rest shape is inside
        P where Γ ≥ ε (the parked certificate), else the grid's flags and these two."""
        by_gamma = resting_extra is None
        index, infeasible = energy_kernels.recovery_scan(
            self._grid_columns, grid_rows, np.array((u_prev, target)).T.copy(), extra_rows,
            np.array(offsets, dtype=float), terms,
            base, q_hat, p_hat, target, inflation, self.energy_margin, inside, self._grid_rest_inside,
            np.zeros(2, dtype=bool) if by_gamma else resting_extra, by_gamma)
        index = int(index)
        grid_size = len(self._grid)
        chosen = target if index < 0 else self._grid[index] if index < grid_size else (u_prev, target)[index - grid_size]
        return np.array(chosen, dtype=float), bool(infeasible)

    def _tip(self, q: np.ndarray) -> tuple[float, float]:
        """The model's tip r(q) (m) as Python floats."""
        tip = kinematics_unchecked(np.asarray(q, dtype=float), self.dynamics.lengths, 0).points[-1]
        return tip.real, tip.imag

    def grid_rows_at_gain(self, gain: float) -> np.ndarray:
        """Lower bounds of Γ^∂_j(g·u_c) (J) for the recovery's grid commands u_c under the gain g: (P', G).

        g = 1: the table's values. Else, from (*) of `controllers.escape_energy` (the distance to the boundary
        is 1-Lipschitz in z = K^{1/2}q and z moves by |g − 1| ‖u_c‖_w from u_c to g·u_c, w_i = λ_i²/k_i):
        d_j(g u_c) ≥ d̲_j(u_c) − |g − 1| ‖u_c‖_w, Γ ≥ ½ max(0, ·)². Without a table (N > 2) the one grid
        command is bounded at g·u_c directly (`BoundaryDistanceBound`)."""
        if gain == 1.0:
            return self._grid_values
        if self.table is None:
            return np.array([self.boundary_bound.values(gain * c) for c in self._grid]).T
        shift = abs(gain - 1.0) * np.sqrt(np.sum(self.table.weights * self._grid**2, axis=1))  # (G,) J^{1/2}
        return 0.5 * np.maximum(self.table.distance - shift, 0.0) ** 2

    def rest_inside(self, u: np.ndarray) -> bool:
        """Whether the rest shape q_u = K⁻¹Λu of the command u (N,) hPa puts the tip strictly inside P."""
        x, y = self._tip(np.array(self._a) * np.asarray(u, dtype=float))
        return all(hx * x + hy * y < h for hx, hy, h in self._rows)

    def _recover_contact(self, base: float, offsets: list[float], inside: bool, q_hat: np.ndarray, p_hat: np.ndarray,
                         u_prev: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, bool]:
        """The contact certificate's recovery (module docstring, step 4): the certified candidate nearest the target;
        else, with x̂ inside P, the largest margin among the candidates whose rest shape lies inside P; else (x̂
        outside P, where no certificate holds) the one of those nearest the target; the target if there is none.
        The margin is the least over the gain ends (module docstring, "actuator gain"); the compiled scan."""
        if self._scan_rows is None or self._scan_rows[0] != self.gains:  # the grid rows of these gain ends, stacked
            for g in self.gains:
                if g not in self._grid_rows:
                    self._grid_rows[g] = self.grid_rows_at_gain(g)
            self._scan_rows = (self.gains, np.array([self._grid_rows[g] for g in self.gains]))
        extra_rows = np.array([[self.boundary_escape(scaled_command(g, tuple(c.tolist()))) for c in (u_prev, target)]
                               for g in self.gains]).transpose(0, 2, 1)
        terms = np.array([self._energy_terms[g] for g in self.gains])
        resting = np.array([self.rest_inside(u_prev), self.rest_inside(target)])
        return self._scan(self._scan_rows[1], extra_rows, offsets, terms, base, q_hat, p_hat, u_prev, target, 1.0,
                          inside, resting)

    def _finish(self, u: np.ndarray, action: str, infeasible: bool, rho: float, diagnostics: dict,
                t_apply: float, t_capture: float, t0: float) -> FilterOutput:
        u = np.array(u, dtype=float)
        self.predictor.record(t_apply, u)
        full = {"W_J": math.nan, "Gamma_J": math.nan, "margin_J": math.nan, "step_fraction": math.nan,
                "blocked": math.nan, "violation": math.nan}
        full.update(diagnostics)
        full["prediction_s"] = t_apply - t_capture
        if self.gain_estimator is not None:  # the interval certified from this call on, and ĝ (NaN before a sample)
            full.update(gain_lo=self.gain_lo, gain_hi=self.gain_hi, gain_hat=self.gain_estimator.estimate)
        full["solve_us"] = (time.perf_counter() - t0) * 1e6
        return FilterOutput(u, action, infeasible, rho, full,
                            DIAGNOSTIC_UNITS if self.gain_estimator is None else GAIN_DIAGNOSTIC_UNITS)


RECOMMENDED = {"gain_lo_ratio": 0.9, "gain_hi_ratio": 1.1, "gain_estimate": True, "gain_noise_rad": 0.0015,
               "gain_rest_rad_s": 0.003, "gain_rest_s": 0.2, "energy_margin_J": 2e-6}
"""c-erg's recommended setting for contact tasks (README; `ContactEnergyGovernor`'s first docstring line names it,
`softcbf list` marks it): the actuator gain interval [0.9, 1.1] narrowed online by samples at rest for 0.2 s,
trusted to Δ = 1.5e-3 rad, and ε = 2e-6 J (docs/results.md#the-recommended-filter-over-the-full-battery)."""


class ContactEnergyGovernor(EnergyGovernor):
    """Recommended for contact tasks with gain_lo_ratio=0.9, gain_hi_ratio=1.1, gain_estimate=true, gain_noise_rad=0.0015, gain_rest_rad_s=0.003, gain_rest_s=0.2, energy_margin_J=2e-6 (README): the energy governor with the contact certificate (c-erg; e-erg with certificate=contact, contact_aware=true).

    The target is u_nom itself; a command is certified when the arm's energy about its rest shape,
    with the plate's stored energy counted per facet, stays below the least energy to P's boundary
    (module docstring, "contact certificate"). The plate's stiffness interval [lo, hi] × ψ
    (`stiffness_lo_ratio`, `stiffness_hi_ratio`) keeps F_true ≤ F_max for any true plate within it, and the
    gain interval [gain_lo_ratio, gain_hi_ratio] × λ for any true actuator gain within it (module docstring,
    "actuator gain").
    """

    parameter_docs = {name: doc for name, doc in EnergyGovernor.parameter_docs.items() if name not in ("margin_m", "certificate")}

    @staticmethod
    def check_arguments(arguments: dict[str, object]) -> dict[str, object]:
        """`EnergyGovernor.check_arguments` with the contact certificate (c-erg takes no `certificate`)."""
        return EnergyGovernor.check_arguments({**arguments, "certificate": "contact"})

    def __init__(self, context: FilterContext, kappa: float = 0.5, energy_margin_J: float = 1e-5, contact_aware: bool = True,
                 stiffness_lo_ratio: float = 1.0, stiffness_hi_ratio: float = 1.0, command_delay_s: float | None = None,
                 actuator_tau_s: float | None = None, grid_hPa: float = 2.5, predictor_step_s: float = 1e-3,
                 bisection_steps: int = 12, escape_spacing_rad: float = 4e-3, gain_lo_ratio: float = 1.0,
                 gain_hi_ratio: float = 1.0, gain_estimate: bool = False, gain_noise_rad: float = 5e-3,
                 gain_rest_rad_s: float = 0.02, gain_rest_s: float = 0.0, gain_clearance_m: float = 5e-3,
                 gain_difference_s: float = 0.0, gain_contact: str = "normal") -> None:
        super().__init__(context, kappa=kappa, energy_margin_J=energy_margin_J, contact_aware=contact_aware,
                         stiffness_lo_ratio=stiffness_lo_ratio, stiffness_hi_ratio=stiffness_hi_ratio,
                         command_delay_s=command_delay_s, actuator_tau_s=actuator_tau_s, grid_hPa=grid_hPa,
                         predictor_step_s=predictor_step_s, bisection_steps=bisection_steps, certificate="contact",
                         escape_spacing_rad=escape_spacing_rad, gain_lo_ratio=gain_lo_ratio, gain_hi_ratio=gain_hi_ratio,
                         gain_estimate=gain_estimate, gain_noise_rad=gain_noise_rad, gain_rest_rad_s=gain_rest_rad_s,
                         gain_rest_s=gain_rest_s, gain_clearance_m=gain_clearance_m, gain_difference_s=gain_difference_s,
                         gain_contact=gain_contact)
