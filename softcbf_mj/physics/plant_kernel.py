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

`plate_contacts`: MuJoCo's contact forces between the arm and each plate from the contact list's fields,
read as whole arrays once a period, and `efc_force`. The force of contact c in its frame (normal, two
tangents, N) is MuJoCo's `mj_contactForce`'s: zero when the contact has no constraint rows (efc_address
< 0); with the pyramidal cone (`mju_decodePyramid`) its normal force is the sum of its 2(dim − 1) pyramid
edge forces efc_force[adr + i] in that order (the one row efc_force[adr] when frictionless, dim = 1) and
its tangential force i is (efc_force[adr + 2i] − efc_force[adr + 2i + 1]) · friction[i]; with the elliptic
cone the dim rows efc_force[adr:adr + dim] are the force itself; then the adhesion is taken off the
normal force (MuJoCo ≥ 4.0.1: the net interface force; 0 in these models, where x − 0.0 = x bit for bit).
The sums over a facet's contacts follow the contact list's order (tests/test_plant_contacts.py: equal to
`mj_contactForce`'s, summed in Python, bit for bit, on states with several contacts).
"""

from __future__ import annotations

import math

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


@njit(cache=True, inline="always")
def contact_force(c, efc_address, dim, friction, adhesion, efc_force, pyramidal, force) -> None:
    """`mj_contactForce` of contact c into force (6,): normal, two tangential (N), the rest 0 (module docstring)."""
    for j in range(6):
        force[j] = 0.0
    adr = efc_address[c]
    if adr < 0:
        return
    d = dim[c]
    if pyramidal:
        if d == 1:
            force[0] = efc_force[adr]
        else:
            force[0] = 0.0
            for i in range(2 * (d - 1)):
                force[0] += efc_force[adr + i]
            for i in range(d - 1):
                force[i + 1] = (efc_force[adr + 2 * i] - efc_force[adr + 2 * i + 1]) * friction[c, i]
    else:
        for i in range(d):
            force[i] = efc_force[adr + i]
    force[0] -= adhesion[c]


@njit(cache=True)
def plate_contacts(geom: np.ndarray, efc_address: np.ndarray, dim: np.ndarray, friction: np.ndarray,
                   adhesion: np.ndarray, frame: np.ndarray, dist: np.ndarray, pos: np.ndarray, efc_force: np.ndarray,
                   pyramidal: bool, facet_of_geom: np.ndarray, on_arm: np.ndarray, points: bool, normal: np.ndarray,
                   tangential: np.ndarray, where: np.ndarray) -> None:
    """Per facet k, the contacts between the arm and plate k (`facet_of_geom` (ngeom,): a geom's facet, −1 none;
    `on_arm` (ngeom,) bool): normal[k] the sum of their normal forces and tangential[k] the norm of the sum of
    their tangential forces in world coordinates (N; both 0 when the facet has none, and left as they are when
    no contact touches a plate); with `points`, where[k] (x, y; m) the sheet-surface point of its strongest
    contact (the midpoint moved by half the penetration toward the plate; left as it is without one).
    The fields are the contact list's (ncon rows; dist and pos read only with `points`), efc_force MuJoCo's."""
    n_facets = normal.shape[0]
    normal_sum = np.zeros(n_facets)
    summed = np.zeros((n_facets, 3))
    strongest = np.zeros(n_facets)
    force = np.empty(6)
    touched = False
    for c in range(geom.shape[0]):
        geom1, geom2 = geom[c, 0], geom[c, 1]
        if facet_of_geom[geom1] >= 0 and on_arm[geom2]:
            k, sign = facet_of_geom[geom1], -1.0  # sign: the frame's normal (from geom1 to geom2) toward the plate
        elif facet_of_geom[geom2] >= 0 and on_arm[geom1]:
            k, sign = facet_of_geom[geom2], 1.0
        else:
            continue
        contact_force(c, efc_address, dim, friction, adhesion, efc_force, pyramidal, force)
        pressing, f1, f2 = force[0], force[1], force[2]
        normal_sum[k] += pressing
        touched = True
        stronger = points and pressing > strongest[k]
        if not (stronger or f1 != 0.0 or f2 != 0.0):
            continue  # a frictionless contact adds ±0.0 to the finite sums: nothing
        for j in range(3):
            summed[k, j] += f1 * frame[c, 3 + j] + f2 * frame[c, 6 + j]
        if stronger:
            strongest[k] = pressing
            half_dist = 0.5 * dist[c]
            for j in range(2):
                where[k, j] = pos[c, j] + half_dist * (sign * frame[c, j])
    if touched:
        for k in range(n_facets):
            normal[k] = normal_sum[k]
            x, y, z = summed[k, 0], summed[k, 1], summed[k, 2]
            tangential[k] = math.sqrt(x * x + y * y + z * z)
