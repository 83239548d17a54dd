"""The energy governor's step: `step(model, state, estimate, u_nom) -> (state, output)`, one call of one governor,
and `step_rows`, the same for B states at once (a batch row is a state of its own: row b is, bit for bit, the
call `step` makes with state b).

The state (`controllers.governors.energy_governor.state.GovernorState`) is advanced in place and returned (its predictor's
records grow by one command per call; `GovernorState.copy()` keeps one to branch from); the model
(`controllers.governors.energy_governor.certificate.GovernorModel`) is only read.

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
2. prediction: x̂ = (q̂, q̂̇, p̂) at t_a from the estimate at t_c (with a command delay interval: from
   t_c − (d − δ) for each delay d of its covering set, `combine` in step 3) through the commands this
   governor issued and the pressure lag (`controllers.model.state_predictor`; contact-aware:
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

Diagnostics per call (units in `DIAGNOSTIC_UNITS`): W_J (the certified energy of the
returned command at x̂, plate term included when contact-aware, before κ), Gamma_J
(min_j Γ̲_j + c_j at it), margin_J (Gamma_J − (1+κ)W_J − ε, and Gamma_J − (1+κ)W_J for
"hold", the held command's test: ≥ 0 for "free", "governed" and "hold"; < 0 beyond
rounding only in an infeasible "recover"),
step_fraction (σ along the ray to the target; NaN in recovery), blocked (1 when the
target was not reached), violation (1 when the held command failed its certificate at
x̂: the count of detected violations is their sum), prediction_s (t_a − t_c), solve_us
(the call's own wall time). All NaN but prediction_s and solve_us on a "stale" call.

Compute time (tools/bench_governors.py, the `softcbf bench` step case). A camera-rate
call is step 2, 50–120 ROS2 steps over the estimate's age and the delay (`controllers.model.state_predictor`
runs them in compiled kernels, the plate's push included: ≈ 0.2 ms of CPU), then steps 3 or 4; a 1 kHz
call mostly step 1 (the quasi-static governor's QP iterations when u_nom's rest shape leaves P;
`QuasiStaticGovernor.command`, which remembers the commands of its last inputs: a held u_nom
cycles through a few), the state's energy (step 2's end) and step 3. Steps 3 and 4 are compiled
(`controllers.energy.energy_kernels`, numba, loaded on the first call): step 3 is one call of
`govern_rows` (the held command's and the target's certificates, the rays' bisections, each
point's Γ̲ looked up in the kernel, ≈ 0.3 µs against ≈ 8–11 µs of Python floats near the
plate: ≈ 20 µs for the 2 × 12 bisection points of a "hold" call), step 4 one call of
`recovery_scan` over the table's grid (≈ 35 µs for its 14 641 commands, against 0.9–1.3 ms of
numpy). The kernels take every state with a leading row axis, which `filter_batch` uses for
B governors at once. A ray is skipped when no end point of it can come nearer the target
than the best so far (`ray_may_come_nearer`, with a rounding slack), and the state's energy
and ρ skip the array kinematics when the tip is clear of the plate (`state_energy`). The
commands are checked against stored references within a stated tolerance
(tests/test_energy_governor_references.py, `python tests/references/eerg_references.py`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from controllers.governors.energy_governor.certificate import (GovernorCall, GovernorModel, certificate_rows, energy_kernels,
                                                     scaled_command)
from controllers.governors.energy_governor.gain_feedback import update_gain
from controllers.governors.energy_governor.state import GovernorState
from controllers.core.errors import ControllerInputError, NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.contract.safety_filter import Estimate, FilterOutput
from controllers.model.state_predictor import StatePredictor

DIAGNOSTIC_UNITS = {
    "W_J": "J", "Gamma_J": "J", "margin_J": "J", "step_fraction": "1", "blocked": "bool (1: the target was not reached)",
    "violation": "bool (1: the held command failed its certificate)", "prediction_s": "s", "solve_us": "µs",
}

GAIN_DIAGNOSTIC_UNITS = {**DIAGNOSTIC_UNITS, "gain_lo": "1", "gain_hi": "1", "gain_hat": "1"}
"""The diagnostics' units with `gain_estimate`: the certified gain interval and the estimate ĝ
(`controllers.governors.energy_governor.gain_feedback`)."""

PLATE_DIAGNOSTIC_UNITS = {**GAIN_DIAGNOSTIC_UNITS, "plate_boundary_m": "m", "plate_lo": "1", "plate_hi": "1",
                          "plate_offset_lo_m": "m", "plate_offset_hi_m": "m"}
"""The diagnostics' units with `plate_estimate`: the certified plates' hull (stiffness ratios, offsets) and P's
force-safe boundary beyond the model's facet plane (`controllers.governors.energy_governor.plate_feedback`)."""

TIME_LIMIT_S = 1e9
"""Largest |t| and |t_capture| (s) a call accepts (32 years): far beyond, the delay and the estimate's age vanish in rounding."""

ACTION_NAMES = ("free", "governed", "hold", "recover")
"""The actions by `energy_kernels.govern_rows`' codes (FREE, GOVERNED, HOLD, RECOVER)."""


def step(model: GovernorModel, state: GovernorState, estimate: Estimate, u_nom) -> tuple[GovernorState, FilterOutput]:
    """Govern u_nom (N,) hPa at `estimate` (module docstring) from `state`: (the state advanced, the output).
    A non-finite or misshapen input raises NonFiniteStateError / NonFiniteCommandError, refused times
    ControllerInputError, both before the state changes."""
    t0 = time.perf_counter()
    q = as_vector("q", estimate.q, model.n, NonFiniteStateError)
    qd = as_vector("qd", estimate.qd, model.n, NonFiniteStateError)
    u_nom = as_vector("u_nom", u_nom, model.n, NonFiniteCommandError)
    t_apply = apply_time(model, float(estimate.t), float(estimate.t_capture), state.predictor)
    (output,) = step_rows(model, [state], [q], [qd], [u_nom], [float(estimate.t_capture)], [t_apply], t0)
    return state, output


def step_rows(model: GovernorModel, states: list[GovernorState], q, qd, u_nom, t_capture: list[float],
              t_apply: list[float], t0: float | None = None) -> list[FilterOutput]:
    """Row b: `step` of states[b] with the checked inputs q[b], qd[b] (N,), u_nom[b] (N,) hPa, captured at
    t_capture[b] and acting from t_apply[b] (`apply_time`, checked for every row before this is called): steps
    1–2 per row, step 3 once for all the rows on one plate certificate (`energy_kernels.govern_rows`; with
    `plate_estimate` the rows' learned plates may differ), step 4 per row. t0: the call's start
    for its `solve_us` (None: each row's conclusion)."""
    calls = [prepare(model, state, q[b], qd[b], u_nom[b], t_capture[b], t_apply[b]) for b, state in enumerate(states)]
    groups: dict[int, list[int]] = {}  # the live rows by plate certificate: step 3 once per plate (one without learning)
    for b, call in enumerate(calls):
        if not call.stale:
            groups.setdefault(id(call.plate), []).append(b)
    found = {}
    for rows in groups.values():
        found.update(zip(rows, govern(model, [calls[b] for b in rows])))
    out = []
    for b, (state, call) in enumerate(zip(states, calls)):
        start = time.perf_counter() if t0 is None else t0
        if call.stale:
            out.append(finish(model, state, call.u_prev, "stale", True, math.nan, {}, call.t_apply, call.t_capture, start))
        else:
            outputs, k, binding = found[b]
            out.append(conclude(model, state, binding, outputs, k, start))
    return out


def apply_time(model: GovernorModel, t: float, t_capture: float, predictor: StatePredictor) -> float:
    """t_a = t + δ (s) for a call at t with an estimate captured at t_capture, given the state's predictor, or
    ControllerInputError (module docstring, "Times"): checked before the call changes anything."""
    if not -TIME_LIMIT_S <= t_capture <= t <= TIME_LIMIT_S:  # also False for NaN
        raise ControllerInputError(f"the estimate's times must satisfy -{TIME_LIMIT_S:g} <= t_capture <= t <= "
                                   f"{TIME_LIMIT_S:g} s, got t_capture = {t_capture!r}, t = {t!r}")
    t_apply = t + model.command_delay
    if t_apply < predictor.latest_time:
        raise ControllerInputError(f"t must not go backwards: got t = {t!r} s after a call at "
                                   f"t = {predictor.latest_time - model.command_delay!r} s (reset first)")
    return t_apply


def prepare(model: GovernorModel, state: GovernorState, q: np.ndarray, qd: np.ndarray, u_nom: np.ndarray,
            t_capture: float, t_apply: float) -> GovernorCall:
    """Steps 1 and 2 of a call (module docstring) and the certificate's state at x̂: everything before the
    compiled step 3 (`govern`), which takes the calls of one or many states."""
    nominal = u_nom if model.box is None else np.clip(u_nom, *model.box)
    target = nominal if model.contact else state.target_governor.command(u_nom)
    predictor = state.predictor
    call = GovernorCall(t_capture, t_apply, predictor.command_at(t_apply), target, nominal)
    starts = [t_capture - shift for shift in model.delay_shifts]  # the estimate's time in each delay's frame
    if not all(predictor.can_predict(start, t_apply) for start in starts):
        call.stale = True
        return call
    if state.gain_estimator is not None:
        update_gain(model, state, q, qd, t_capture)
    call.plate = state.plate
    certify_at(model, state, call, predictor.predict(starts[0], q, qd, t_apply))
    for start in starts[1:]:  # a command delay interval: the same call at its other delays
        cover = GovernorCall(t_capture, t_apply, call.u_prev, target, nominal, plate=state.plate)
        certify_at(model, state, cover, predictor.predict(start, q, qd, t_apply))
        call.covers.append(cover)
    return call


def certify_at(model: GovernorModel, state: GovernorState, call: GovernorCall, predicted: tuple) -> None:
    """The certificate's state of `call` at the predicted x̂ = (q̂, q̂̇, p̂) (rad, rad/s, hPa): the base energy,
    the rows' offsets, whether x̂ lies inside P, ρ, the gain ends and the pressure's interval (`prepare`)."""
    q_hat, qd_hat, p_hat = predicted
    kappa = model.params.kappa
    if model.contact:
        offsets, inside, rho = model.contact_offsets(q_hat, state.plate)
        base = (1.0 + kappa) * model.dynamics.kinetic_energy(q_hat, qd_hat)  # (1 + κ)·½q̇ᵀMq̇
        inflation = 1.0  # κ inflates the kinetic energy alone
    else:
        base, rho = model.state_energy(q_hat, qd_hat)
        offsets, inside, inflation = model.plate.credit, True, 1.0 + kappa
    call.q_hat, call.p_hat, call.base, call.offsets, call.inside, call.rho = q_hat, p_hat, base, offsets, inside, rho
    call.inflation, call.gains, call.terms, call.scales = inflation, state.ends.gains, state.ends.terms, state.ends.scales
    if state.pressures is not None:  # the valve lag's interval: the pressure's hull with the model's p̂
        lowest, highest = state.pressures.at(call.t_apply)
        call.p_hat, call.p_far = np.minimum(p_hat, lowest), np.maximum(p_hat, highest)


def govern(model: GovernorModel, calls: list[GovernorCall]) -> list[tuple]:
    """Step 3 for the calls on one plate certificate (module docstring): one row of `energy_kernels.govern_rows`
    per call and delay (the call and its `covers`); per call (outputs, k, binding): `govern_rows`' outputs, the
    call's row k in them and the call that row certifies (the call itself; with covers, `combine`'s)."""
    rows = [row for call in calls for row in (call, *call.covers)]
    outputs = energy_kernels.govern_rows(
        np.array([c.u_prev for c in rows]), np.array([c.target for c in rows]), model.rest,
        np.array([c.nominal for c in rows]), 2 if model.contact else 3, *certificate_rows(rows),
        rows[0].inflation, model.params.energy_margin_J, model.params.bisection_steps, *rows[0].plate.lookup)
    found, first = [], 0
    for call in calls:
        covered = [call, *call.covers]
        found.append((outputs, first, call) if len(covered) == 1 else
                     combine(model, covered, tuple(o[first:first + len(covered)] for o in outputs)))
        first += len(covered)
    return found


def combine(model: GovernorModel, rows: list[GovernorCall], outputs: tuple) -> tuple:
    """Step 3 over a command delay interval (`controllers.governors.energy_governor.certificate`, "command delay"): from
    `govern_rows`' outputs for one call at each of its delays (row r: rows[r]), the command certified at every
    delay: the target where every row is free; else the rows' end points, nearest the target first, the first
    certified at every row; else u_prev where every row holds it; else recovery. Returns (outputs, 0, binding):
    one row of outputs as `govern_rows` gives them (σ the least over the rows) and the row whose certificate binds
    (the least margin of the command; for recovery, of the held command), whose call `conclude` uses."""
    u_rows, codes, sigmas, gammas, ws, held = outputs
    worst_held = int(np.argmin(held))
    inflation, eps, target = rows[0].inflation, model.params.energy_margin_J, rows[0].target
    sigma = float(np.min(sigmas)) if not np.isnan(sigmas).any() else math.nan

    def single(u, code, gamma, w, binding):
        return ((np.array([u], dtype=float), np.array([code]), np.array([sigma]), np.array([gamma]), np.array([w]),
                 np.array([held[worst_held]])), 0, rows[binding])

    if np.all(codes == energy_kernels.FREE):
        binding = int(np.argmin(gammas - inflation * ws))
        return single(target, energy_kernels.FREE, gammas[binding], ws[binding], binding)
    terms = certificate_rows(rows)
    plate = rows[0].plate
    moved = [r for r in range(len(rows)) if codes[r] in (energy_kernels.FREE, energy_kernels.GOVERNED)]
    distance = {r: float(np.sum((u_rows[r] - target) ** 2)) for r in moved}
    order = sorted(range(len(rows)), key=lambda b: -distance.get(b, math.inf))  # the most restrictive rows first
    for r in sorted(moved, key=distance.get):
        binding, least = r, (gammas[r], ws[r])  # row r certified its own end point (govern_rows)
        for b in order:
            if b == r:
                continue
            gamma, w = model.row_terms(u_rows[r], terms, b, plate)
            if gamma - inflation * w < least[0] - inflation * least[1]:
                binding, least = b, (gamma, w)
                if gamma - inflation * w < eps:
                    break
        if least[0] - inflation * least[1] >= eps:
            code = energy_kernels.FREE if np.array_equal(u_rows[r], target) else energy_kernels.GOVERNED
            return single(u_rows[r], code, *least, binding)
    if held[worst_held] > 0.0:
        return single(rows[0].u_prev, energy_kernels.HOLD, *model.row_terms(rows[0].u_prev, terms, worst_held, plate),
                      worst_held)
    return single(rows[0].u_prev, energy_kernels.RECOVER, math.nan, math.nan, worst_held)


def conclude(model: GovernorModel, state: GovernorState, call: GovernorCall, outputs: tuple, b: int,
             t0: float) -> FilterOutput:
    """Step 4 where step 3 found the held command failed, the diagnostics, and the command recorded for the
    predictor: the call's output from row b of `govern`'s outputs."""
    u_rows, codes, sigmas, gammas, ws, held_margins = outputs
    code, sigma, held_margin = int(codes[b]), float(sigmas[b]), float(held_margins[b])
    held_ok = held_margin > 0.0  # Γ = W = 0 (the arm at rest on or beyond P's boundary) certifies nothing
    action = ACTION_NAMES[code]
    if code == energy_kernels.RECOVER:
        u, infeasible = recover_contact(model, state, call) if model.contact else recover(model, call)
        gamma, w = model.certificate_terms(u, call, call.plate)
    else:
        u, gamma, w, infeasible = u_rows[b], float(gammas[b]), float(ws[b]), False
    # the held command keeps its certificate down to Γ − ιW = 0 (the hysteresis), a new one needs ε
    certified_margin = held_margin if action == "hold" else gamma - call.inflation * w - model.params.energy_margin_J
    diagnostics = {"W_J": w, "Gamma_J": gamma, "margin_J": certified_margin,
                   "step_fraction": sigma, "blocked": float(action != "free"), "violation": float(not held_ok)}
    return finish(model, state, u, action, infeasible, call.rho, diagnostics, call.t_apply, call.t_capture, t0)


def recover(model: GovernorModel, call: GovernorCall) -> tuple[np.ndarray, bool]:
    """The parked certificate's recovery (module docstring, step 4): the certified candidate nearest the target,
    else the best margin among the candidates whose rest shape lies inside P (Γ ≥ ε); the compiled scan."""
    extra_rows = np.array([[model.plate.table.values(c) for c in (call.u_prev, call.target)]]).transpose(0, 2, 1)
    terms = np.array([(model.k, model.a, model.beta_list)])  # extra_rows: (1, P', 2)
    return scan(model, model.plate.grid_values[None], extra_rows, call.offsets, terms, call, 1.0 + model.params.kappa,
                True, None)


def recover_contact(model: GovernorModel, state: GovernorState, call: GovernorCall) -> tuple[np.ndarray, bool]:
    """The contact certificate's recovery (module docstring, step 4): the certified candidate nearest the target;
    else, with x̂ inside P, the largest margin among the candidates whose rest shape lies inside P; else (x̂
    outside P, where no certificate holds) the one of those nearest the target; the target if there is none.
    The margin is the least over the state's gain ends (`controllers.governors.energy_governor.certificate`, "actuator gain")."""
    ends = state.ends
    extra_rows = np.array([[np.multiply(scale, model.boundary_escape(scaled_command(r, tuple(c.tolist())), call.plate))
                            for c in (call.u_prev, call.target)]
                           for r, scale in zip(ends.gains, ends.scales)]).transpose(0, 2, 1)
    terms = ends.terms
    resting = np.array([model.rest_inside(call.u_prev, call.plate), model.rest_inside(call.target, call.plate)])
    return scan(model, state.recovery_rows(model), extra_rows, call.offsets, terms, call, 1.0, call.inside, resting)


def scan(model: GovernorModel, grid_rows: np.ndarray, extra_rows: np.ndarray, offsets: list[float], terms: np.ndarray,
         call: GovernorCall, inflation: float, inside: bool, resting_extra: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The recovery's choice among the grid commands, u_prev and the target (`energy_kernels.recovery_scan`):
    grid_rows (E, P', G) and extra_rows (E, P', 2) per gain end; resting_extra None: the rest shape is inside
    P where Γ ≥ ε (the parked certificate), else the grid's flags and these two."""
    by_gamma = resting_extra is None
    u_prev, target = call.u_prev, call.target
    plate = call.plate
    index, infeasible = energy_kernels.recovery_scan(
        plate.grid_columns, grid_rows, np.array((u_prev, target)).T.copy(), extra_rows,
        np.array(offsets, dtype=float), terms, call.base, call.q_hat, call.p_hat, target, inflation,
        model.params.energy_margin_J, inside, plate.grid_rest_inside,
        np.zeros(2, dtype=bool) if by_gamma else resting_extra, by_gamma, call.p_far)
    index = int(index)
    grid_size = len(plate.grid)
    chosen = target if index < 0 else plate.grid[index] if index < grid_size else (u_prev, target)[index - grid_size]
    return np.array(chosen, dtype=float), bool(infeasible)


def finish(model: GovernorModel, state: GovernorState, u: np.ndarray, action: str, infeasible: bool, rho: float,
           diagnostics: dict, t_apply: float, t_capture: float, t0: float) -> FilterOutput:
    """The call's output: the command u recorded in the state's predictor, the diagnostics completed (NaN where
    the call gave none; the gain interval certified from this call on and ĝ with `gain_estimate`; the plates' hull
    and P's boundary with `plate_estimate`)."""
    u = np.array(u, dtype=float)
    state.predictor.record(t_apply, u)
    if state.pressures is not None:
        state.pressures.record(t_apply, u)
    full = {"W_J": math.nan, "Gamma_J": math.nan, "margin_J": math.nan, "step_fraction": math.nan,
            "blocked": math.nan, "violation": math.nan}
    full.update(diagnostics)
    full["prediction_s"] = t_apply - t_capture
    if state.gain_estimator is not None:  # the interval certified from this call on, and ĝ (NaN before a sample)
        full.update(gain_lo=state.ends.lo, gain_hi=state.ends.hi, gain_hat=state.gain_estimator.estimate)
    units = DIAGNOSTIC_UNITS if state.gain_estimator is None else GAIN_DIAGNOSTIC_UNITS
    if state.plate_estimate is not None:  # the plates certified from this call on
        box = state.plate.box
        full.update(plate_boundary_m=box.offset_lo + box.reach, plate_lo=box.lo, plate_hi=box.hi,
                    plate_offset_lo_m=box.offset_lo, plate_offset_hi_m=box.offset_lo + box.width)
        units = PLATE_DIAGNOSTIC_UNITS
    full["solve_us"] = (time.perf_counter() - t0) * 1e6
    return FilterOutput(u, action, infeasible, rho, full, units)
