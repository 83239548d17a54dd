"""The energy governor's plate feedback: the certified set of plates narrowed online from the gain estimate's samples.

With `plate_estimate` (default off: then nothing here runs and the commands are those without it bit for bit),
every rest sample the gain feedback offers (`controllers.governors.energy_governor.gain_feedback.offer`: at rest for
`gain_rest_s`, the pressure settled, or a window's mean with its noise bound ε) whose tip lies within
`gain_clearance_m` of exactly one facet j of the nearest plate also bounds that facet's plate
(`controllers.governors.energy_governor.plate_estimate`): the normal force F ∈ [f_lo, f_hi] from the residual projected on
T = J_r(q̂)ᵀn̂_j over the certified (g, c) vertices (the state's `GainEnds.corners`), the penetration of the model's
facet plane δ̂ ± Σ_i ℓ_i (Δ + ε_i), and the set cut by the two half-planes they give. Two facets near (a corner)
give no sample (their forces do not separate along one T). The state then certifies on the learned plates'
certificate (`plate_certificate.learned_plate`) once the force-safe boundary has moved out by `REBUILD_M` or the
hull's stiffness or offset has narrowed by `REBUILD_RATIO` of the prior's (each rebuild costs ≈ 1 ms and drops the
recovery's rows); an empty set (an assumption proven false) returns the prior plate for good, until `reset`.
Soundness: every certified set contains the true plate (the estimate's assumptions), so each certificate issued on
any of them holds for it; the held command, issued on an earlier (larger) set, stays safe, and is re-tested on the
new one at the next call.
"""

from __future__ import annotations

import numpy as np

from controllers.governors.energy_governor.certificate import GovernorModel
from controllers.governors.energy_governor.plate_certificate import learned_plate
from controllers.governors.energy_governor.plate_estimate import add_sample, certified_box, contact_force, depth_margin
from controllers.governors.energy_governor.state import GovernorState

REBUILD_M = 5e-5
"""Growth of the certified force-safe boundary b (m) that rebuilds the state's plate certificate (0.4 % of the
reference plate's n_max = 14.3 mm)."""

REBUILD_RATIO = 0.02
"""Narrowing of the stiffness hull (relative) or of the offset hull (of the prior's width) that rebuilds it."""


def update_plate(model: GovernorModel, state: GovernorState, q_sample: np.ndarray, facet: int, jac: np.ndarray,
                 p: np.ndarray, residual: np.ndarray, scatter: np.ndarray | None) -> None:
    """Add the rest sample (the model's pressure p (N,) hPa, the residual (N,) rad, its noise bound `scatter` (N,)
    rad or None) at q_sample, the tip within the clearance of facet `facet` alone (jac: ∂r/∂q at q_sample as
    x + iy), to the state's plate estimate, and certify its plates when worth it (module docstring)."""
    params, nominal = model.params, model.context.safe_set
    noise = np.full(model.n, params.gain_noise_rad) if scatter is None else params.gain_noise_rad + scatter
    nx, ny = nominal.environment.normals[facet].tolist()
    torque = jac.real * nx + jac.imag * ny  # J_r(q)ᵀn̂ (N,) m
    force = contact_force(torque, model.k, np.asarray(model.a) * p, residual, state.ends.corners, noise)
    x, y = model.tip(q_sample)
    depth = nx * x + ny * y - float(nominal.environment.offsets[facet])
    margin = depth_margin(model.dynamics.lengths, noise)
    psi_k = nominal.stiffness.k
    state.plate_estimate = add_sample(state.plate_estimate, facet, (depth - margin, depth + margin), force, psi_k)
    if state.plate_estimate.inconsistent:
        if state.plate is not model.plate:
            state.set_plate(model.plate)
        return
    box, now = certified_box(state.plate_estimate, nominal.f_max, psi_k), state.plate.box
    prior = model.plate.box
    if (box.offset_lo + box.reach >= now.offset_lo + now.reach + REBUILD_M
            or box.lo >= now.lo * (1.0 + REBUILD_RATIO) or box.hi <= now.hi * (1.0 - REBUILD_RATIO)
            or box.width <= now.width - REBUILD_RATIO * prior.width and prior.width > 0.0):
        state.set_plate(learned_plate(params, model.context, box, state.plate_estimate.polygons, model.rest))
