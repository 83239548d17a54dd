"""Compiled state prediction with the plate pushing back: the contact-aware state predictor's steps
(`controllers.model.state_predictor`), one numba call per interval of constant command.

Per step of length h (s), from x = [q; q̇] (2N,) rad, rad/s, with the acting pressure p (N,) hPa:

    ū = u + (p − u)·mean (the pressure's exact mean over the step),  p ← u + (p − u)·decay,
    q̈(x) = M⁻¹(Λū − f) + M⁻¹τ_plate,  τ_plate,j = −Σ_i ψ(n_i(r)) (n̂_i · ∂r/∂q_j)   (N·m),
    one ROS2 step (`pcc_model.ros2_first`, q̈ at the stage state, `pcc_model.ros2_second`),

n_i(r) = max(n̂_i·r − d_i, 0) the facets' penetrations (m) at the model's tip r, ψ the plate's law:
LinearStiffness ψ(n) = k n (law 0) or PowerLawStiffness ψ(n) = k n^p (law 1). The arithmetic is that
of the per-step Python loop it replaces (the same kernels for the model terms, the acceleration and the
two ROS2 stages; the plate's force, torque and M⁻¹τ summed in the same order), so with a linear ψ the
predicted state is the same floats (tests/test_energy_governor.py compares the two; tests/references/eerg_references.py
the governor's commands); with a power law n^p is numba's pow, which may differ from numpy's in the last
bit (≤ 7e-16 rad after 80 steps in that test: far below the prediction's own error against the plant,
≈ 5e-4 rad, which κ is there for).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from controllers.model import pcc_model

LINEAR_LAW, POWER_LAW = 0, 1
"""The `law` codes of `advance_with_plate`."""


@njit(cache=True, error_model="numpy")
def plate_acceleration(x, acting, params, facets, law, k, exponent):
    """(q̈ (N,) with the facets' push, the model's `dyn` row (2N² + N,)) at x (2N,) under the pressure
    acting (1, N) hPa; facets (P, 3): n̂_x, n̂_y, d (m); law, k, exponent: the plate's ψ (module docstring)."""
    n = acting.shape[1]
    q, qd = np.empty((1, n)), np.empty((1, n))
    for j in range(n):
        q[0, j], qd[0, j] = x[j], x[n + j]
    kin, dyn = pcc_model.model_terms(q, qd, params)
    acc = pcc_model.accelerations(dyn, params, acting)[0]
    tip = kin[0, 4 * n]
    count = facets.shape[0]
    forces = np.empty(count)
    pushed = False
    for i in range(count):
        depth = facets[i, 0] * tip.real + facets[i, 1] * tip.imag - facets[i, 2]
        depth = 0.0 if 0.0 > depth else depth  # Python's max(depth, 0.0)
        pushed = pushed or depth != 0.0 or depth != depth
        forces[i] = depth
    if pushed:
        for i in range(count):
            depth = 0.0 if 0.0 > forces[i] else forces[i]  # numpy.maximum(n, 0) of the law
            forces[i] = k * depth if law == LINEAR_LAW else k * depth ** exponent
        nn = n * n
        tau = np.empty(n)
        for j in range(n):
            jac = kin[0, n + j]
            s = 0.0
            for i in range(count):
                s += forces[i] * (facets[i, 0] * jac.real + facets[i, 1] * jac.imag)
            tau[j] = -s
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += dyn[0, nn + i * n + j] * tau[j]
            acc[i] = acc[i] + s
    return acc, dyn[0].copy()


@njit(cache=True, error_model="numpy")
def advance_with_plate(x, u, p, params, h, steps, decay, mean, facets, law, k, exponent):
    """`steps` ROS2 steps of length h (s) under the command u (N,) hPa with the plate pushing back (module
    docstring), in place: x (2N,) the state, p (N,) the acting pressure (τ_p = 0: decay = mean = 0)."""
    n = u.shape[0]
    acting = np.empty((1, n))
    for _ in range(steps):
        for j in range(n):
            acting[0, j] = u[j] + (p[j] - u[j]) * mean
            p[j] = u[j] + (p[j] - u[j]) * decay
        acc, dyn = plate_acceleration(x, acting, params, facets, law, k, exponent)
        k1, x2, schur_inv = pcc_model.ros2_first(x, acc, dyn, params[0], h)
        acc2, _ = plate_acceleration(x2, acting, params, facets, law, k, exponent)
        new = pcc_model.ros2_second(x, x2, k1, acc2, dyn, schur_inv, params[0], h)
        for i in range(2 * n):
            x[i] = new[i]
