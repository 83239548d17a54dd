"""The energy governor's gain feedback: the certified actuator gain interval narrowed online.

Gain feedback (`gain_estimate`, default off: then nothing below runs and the commands are those without it bit for
bit). `controllers.governors.gain_estimate` fits K⁻¹(M q̈ + (C + D) q̇ + K q) = g K⁻¹Λ p by least squares, p the pressure
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

A noisy camera (`gain_window_s` > 0; `window_sample`): the rest test above never passes with q̂̇ from noisy frames
(pixel noise 8: |q̂̇| ≈ 0.1 rad/s at rest), so a sample is instead the mean of the distinct estimates of a window
of gain_window_s, at rest when each segment's fitted slope is at most gain_rest_rad_s, trusted to Δ plus the bound
of its mean's noise from the scatter pooled over the windows taken (`controllers.governors.gain_estimate`, "averaged
frames": a statistical bound at gain_scatter_risk per segment and sample, not a worst case). Measured on the
150 hPa push with pixel noise 8 and 20 % drops: docs/beyond-the-paper.md#a-noisy-camera.
"""

from __future__ import annotations

import numpy as np

from controllers.governors.energy_governor.certificate import GovernorModel
from controllers.governors.energy_governor.plate_feedback import update_plate
from controllers.governors.energy_governor.state import GovernorState
from controllers.model.pcc import kinematics_unchecked


def update_gain(model: GovernorModel, state: GovernorState, q: np.ndarray, qd: np.ndarray, t_capture: float) -> None:
    """Offer the estimate (q, q̇) at t_capture to the state's gain estimator (`controllers.governors.gain_estimate`), as a
    difference sample when the previous estimate was captured at most gain_difference_s before (midpoint state, q̈ by
    the difference of the q̇'s, y = K⁻¹(M q̈ + C q̇ + D q̇ + K q)), else as a rest sample when every |q̇_i| ≤
    gain_rest_rad_s, in this estimate and in every one captured over the last gain_rest_s (an arm that has
    settled, not one passing through q̇ = 0; with gain_rest_s > 0 the timer restarts at each rest sample, so an
    arm resting at 1 kHz offers one per gain_rest_s, not one per call), and the model's pressure has settled
    (|λ_i/k_i (p_i − u_i)| ≤ gain_noise_rad). With the model's tip at least gain_clearance_m clear of every facet
    plane the sample is one out of contact; else (`gain_contact` not "off") the plate's force on the tip is
    eliminated: along the normal n̂_j of each facet within the clearance ("normal", a frictionless plate), and
    along its tangent too ("any"), the directions J_r(q)ᵀv at the sample's q (`GainEstimator.sample_in_contact`).
    Its interval is applied once it has narrowed by 1 % of the prior's width (a wider interval than the
    estimator's is also sound, and each change rebuilds the ends' terms), or at once when it fell back to the prior.
    With gain_window_s > 0 the estimate goes to the rest window instead (`window_sample`), q̂̇ unused."""
    params, estimator, previous = model.params, state.gain_estimator, state.gain_previous
    if state.gain_window is not None:
        window_sample(model, state, q, t_capture)
        return
    state.gain_previous = (t_capture, q, qd)
    moving = previous is not None and 0.0 < t_capture - previous[0] <= params.gain_difference_s
    if max(abs(v) for v in qd.tolist()) > params.gain_rest_rad_s:
        state.rest_since = None
    elif state.rest_since is None:
        state.rest_since = t_capture
    if not moving and (state.rest_since is None or t_capture - state.rest_since < params.gain_rest_s):
        return  # neither kind of sample (checked before the kinematics: the common case at the camera rate)
    if not moving and params.gain_rest_s > 0.0:
        state.rest_since = t_capture  # the next rest sample after gain_rest_s more at rest: one per gain_rest_s
    x, y = model.tip(q)
    near = near_facets(model, x, y)
    if near and params.gain_contact == "off":
        return
    predictor = state.predictor
    if moving:
        t0, q0, qd0 = previous
        h = t_capture - t0
        q_sample, qd_mid = 0.5 * (q0 + q), 0.5 * (qd0 + qd)
        terms = model.dynamics.evaluate(q_sample, qd_mid)
        residual = (terms.mass @ ((qd - qd0) / h) + terms.bias) / np.asarray(model.k)
        p = predictor.pressure_at(t0 + 0.5 * h)
    else:
        q_sample, p = q, predictor.pressure_at(t_capture)
        if np.any(np.abs(estimator.a * (p - predictor.command_at(t_capture))) > estimator.noise_rad):
            return
        residual = estimator.rest_residual(q, qd)
    offer(model, state, q_sample, near, p, residual)


def window_sample(model: GovernorModel, state: GovernorState, q: np.ndarray, t_capture: float) -> None:
    """With gain_window_s: add the estimate q captured at t_capture (once per capture) to the state's rest window
    (`controllers.governors.gain_estimate.RestWindow`); a frame whose model pressure has not settled (|λ_i/k_i (p_i − u_i)| >
    gain_noise_rad) empties the window. The window holds a run of blocks at rest and the block being filled (from
    `state.gain_block`). Once the block spans gain_window_s with ≥ 3 frames it is fitted: with every |β_i| ≤
    gain_rest_rad_s (at rest: the fitted slope, not the noisy q̂̇) its residuals join the pooled scatter (the
    pooled blocks are disjoint) and it joins the run; the run's mean q̄ (all its n frames, the run's own slope at
    most gain_rest_rad_s too, else the block alone) is offered as a rest sample (p the frames' mean model pressure,
    y = q̄, trusted to Δ + ε_i, ε = `RestWindow.scatter_bound` of n frames at gain_scatter_risk, from
    gain_frame_sigma_rad where given; in contact as `update_gain`), and the next block starts. A block not at rest
    ends the run and slides on (its oldest frame dropped) and is not pooled (measured: pooling the moving windows'
    curvature too left the interval at the prior on the 150 hPa push with pixel noise 8)."""
    params, estimator, window, predictor = model.params, state.gain_estimator, state.gain_window, state.predictor
    p = predictor.pressure_at(t_capture)
    if np.any(np.abs(estimator.a * (p - predictor.command_at(t_capture))) > estimator.noise_rad):
        window.clear()
        state.gain_block = 0
        return
    if not window.add(t_capture, q, p):
        return
    block = state.gain_block
    if window.span(block) < params.gain_window_s or len(window.times) - block < 3:
        return
    _, slope, rss, n = window.fit(block)
    if np.any(np.abs(slope) > params.gain_rest_rad_s):
        window.drop_before(block + 1)  # the run ends; the block slides on
        state.gain_block = 0
        return
    window.pool(rss, n)
    mean, slope, _, n = window.fit()
    if np.any(np.abs(slope) > params.gain_rest_rad_s):  # the run drifts: the block alone
        window.drop_before(block)
        mean, _, _, n = window.fit()
    state.gain_block = len(window.times)
    pressure = np.mean(window.inputs, axis=0)
    x, y = model.tip(mean)
    near = near_facets(model, x, y)
    if near and params.gain_contact == "off":
        return
    offer(model, state, mean, near, pressure, mean,
          window.scatter_bound(n, params.gain_scatter_risk, params.gain_frame_sigma_rad))


def near_facets(model: GovernorModel, x: float, y: float) -> list[int]:
    """The facets of the nearest plate (the prior's) whose plane the tip r = (x, y) (m) is within gain_clearance_m of."""
    clearance = model.params.gain_clearance_m
    return [j for j, (nx, ny, d) in enumerate(model.plate.facets) if nx * x + ny * y - d > -clearance]


def offer(model: GovernorModel, state: GovernorState, q_sample: np.ndarray, near: list, p: np.ndarray,
          residual: np.ndarray, scatter: np.ndarray | None = None) -> None:
    """Give the estimator the sample (p, residual) at q_sample, in contact with the facets `near` (indices; their
    normal, and their tangent with gain_contact "any", J_r(q)ᵀv at q_sample eliminated) or out of contact; apply its
    interval once it has narrowed by 1 % of the prior's width, or at once when it fell back to the prior. With
    `plate_estimate` and one facet near, the same sample bounds its plate (`plate_feedback.update_plate`)."""
    params, estimator = model.params, state.gain_estimator
    if near:
        jac = kinematics_unchecked(np.asarray(q_sample, dtype=float), model.dynamics.lengths, 1).jac[-1]  # ∂r/∂q: x + iy
        normals = [model.plate.facets[j][:2] for j in near]
        directions = normals if params.gain_contact == "normal" else normals + [(-ny, nx) for nx, ny in normals]
        torques = np.array([jac.real * vx + jac.imag * vy for vx, vy in directions]).T  # (N, m): J_r(q)ᵀv
        accepted = estimator.sample_in_contact(p, residual, torques, scatter)
        if state.plate_estimate is not None and len(near) == 1:  # the arm as its own force sensor: the plate's sample
            update_plate(model, state, q_sample, near[0], jac, p, residual, scatter)
    else:
        accepted = estimator.sample(p, residual, scatter)
    if accepted:
        lo, hi = estimator.interval
        width = state.ends.hi - state.ends.lo
        prior_lo, prior_hi = model.gain_prior
        if estimator.inconsistent or hi - lo <= width - 0.01 * (prior_hi - prior_lo):
            state.set_gain_ends(model, lo, hi)
