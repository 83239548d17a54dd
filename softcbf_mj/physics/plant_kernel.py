"""`softcbf_mj.physics.mujoco_plant.MujocoPlant.state`'s read of MuJoCo's arrays, compiled: one call per control period.

The state's fixed-size part is gathered from MuJoCo's own arrays (views of the MjData, bound once)
into one new float array, in this order, N segments and P facets:

    q (N) = ten_length[tendon], q̇ (N) = ten_velocity[tendon]        rad, rad/s
    segment_ends (N+1, 2) = site_xpos[site, :2] …, geom_xpos[tip, :2]  m, row-major
    contact_forces (P) = max(0, k_p · qpos[plate_qpos])                N
    u_applied (N) = actuator_force[actuator]                           hPa
    spring (P) = qpos[plate_qpos]                                      m

`index` packs the ids: tendon (N), actuator (N), site (N), the tip geom (1), plate qpos (P).
Copies and one product a facet, so the values are those numpy's indexing and `np.maximum(0.0, k · x)`
give, bit for bit (no fastmath; np.maximum(0.0, f) is 0.0 only where f < 0: it keeps −0.0, its second
operand on a tie, and propagates NaN).
Why compiled (numba, `@njit(cache=True)`): numpy's indexing costs 0.5–1 µs a call on these few floats
and the state took about ten of them every control period; one compiled call reads them all.
Loaded on the first call (`controllers.core.lazy_import`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def read_state(qpos: np.ndarray, ten_length: np.ndarray, ten_velocity: np.ndarray, site_xpos: np.ndarray,
               geom_xpos: np.ndarray, actuator_force: np.ndarray, index: np.ndarray, stiffness: np.ndarray,
               out: np.ndarray) -> None:
    p = len(stiffness)
    n = (len(index) - p - 1) // 3
    for i in range(n):
        tendon = index[i]
        out[i] = ten_length[tendon]
        out[n + i] = ten_velocity[tendon]
    ends = 2 * n
    for i in range(n):
        site = index[2 * n + i]
        out[ends + 2 * i] = site_xpos[site, 0]
        out[ends + 2 * i + 1] = site_xpos[site, 1]
    tip = index[3 * n]
    out[ends + 2 * n] = geom_xpos[tip, 0]
    out[ends + 2 * n + 1] = geom_xpos[tip, 1]
    forces = ends + 2 * n + 2
    applied = forces + p
    springs = applied + n
    for k in range(p):
        x = qpos[index[3 * n + 1 + k]]
        force = stiffness[k] * x
        out[forces + k] = 0.0 if force < 0.0 else force  # np.maximum(0.0, force): −0.0 and NaN kept
        out[springs + k] = x
    for i in range(n):
        out[applied + i] = actuator_force[index[n + i]]
