"""The plates of the generated model: ideal plates on slide springs, or flexures (clamped sheets in a force gauge).

Plates. Facet k of the free space N = {r | H r ≤ h} (H: (P, 2), h: (P,) in m) gets a
rigid plate `plate{k}` on the slide joint `plate{k}_slide` along the outward normal
n̂_k = H_kᵀ/‖H_k‖ (m), with spring stiffness `plate_stiffness` (N/m), mass `plate_mass`
(kg) and damping 2 ζ √(k m) (N·s/m). Its surface at rest lies on the facet line shifted
by `tip_radius` along n̂_k, so the tip sphere touches it exactly when H_k r = h_k. The
plate is centred on the foot of the perpendicular from the base and is wide enough to
cover every point of the facet line within the arm's reach Σ L_i. Contacts are
frictionless by default (condim 1: normal force only, as in the paper's model) and stiff
(solref = (`contact_timeconst`, 1)); `tip_friction` μ > 0 makes them Coulomb contacts
(condim 3, sliding friction μ on the arm's and the plates' geoms).

Flexure plates (`plate="flexure"`, docs/beyond-the-paper.md#flexure-plate; maths and defaults in `softcbf_mj.physics.flexure`):
facet k instead gets a clamped sheet: the clamp body `plate{k}` on the force gauge's slide
joint `plate{k}_gauge` along n̂_k (stiffness k_g), the sheet's first half cell fixed to it
and links `plate{k}_link{j}` on hinges `plate{k}_h{j}` about z at the cell centres, on the
surface that faces the arm; that surface at rest lies on the facet line shifted by
`tip_radius` (as the ideal plate's), from the clamp at σ = `clamp_at` to the free end at
σ = `free_end_at` along t̂ = (−n̂_y, n̂_x) from the foot of the perpendicular from the base.
Sites `plate{k}_surface` (the surface's clamp end) and `plate{k}_calibration`.

Both kinds take the default class `plate` (`softcbf_mj.physics.mjcf.assembly`).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from softcbf_mj.physics.mjcf.config import ArmModelConfig
from softcbf_mj.physics.mjcf.precision import r6, r6v

# Scene geometry of the plates (no effect on the contact: the arm's geoms lie in z = 0).
_PLATE_THICKNESS = 0.005  # m
PLATE_HALF_HEIGHT = 0.02  # m, along z
_PLATE_EDGE_MARGIN = 0.02  # m, beyond the reachable chord at each side
_FLEXURE_CLAMP_SIZE = 0.01  # m, the clamp block's edge (behind the sheet's surface)


def add_plates(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    plate = spec.find_default("plate")
    reach = sum(config.robot.lengths)
    damping = config.plate_damping()
    for k, (normal, hk, stiffness) in enumerate(zip(config.facet_normals(), config.h, config.plate_stiffness)):
        norm_H = float(np.linalg.norm(config.H[k]))
        distance = hk / norm_H  # from the base to the facet line, m
        surface = normal * (distance + config.tip_radius)
        half_width = math.sqrt(max(reach**2 - distance**2, 0.0)) + _PLATE_EDGE_MARGIN
        angle = math.atan2(normal[1], normal[0])
        body = spec.worldbody.add_body(
            name=f"plate{k + 1}",
            pos=r6v([surface[0], surface[1], 0.0]),
            quat=r6v([math.cos(angle / 2), 0, 0, math.sin(angle / 2)]),
        )
        body.add_joint(
            name=f"plate{k + 1}_slide",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[1.0, 0.0, 0.0],
            stiffness=[r6(stiffness), 0, 0],
            damping=[r6(damping[k]), 0, 0],
        )
        half = np.array([_PLATE_THICKNESS / 2, half_width, PLATE_HALF_HEIGHT])
        body.explicitinertial = True
        body.mass = r6(config.plate_mass)
        body.ipos = r6v([half[0], 0, 0])
        body.inertia = _box_inertia(config.plate_mass, half)
        body.add_geom(default=plate, name=f"plate{k + 1}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=r6v([half[0], 0, 0]), size=r6v(half))
        body.add_site(name=f"plate{k + 1}_surface", pos=[0, 0, 0], size=[r6(config.tip_radius), 0, 0])


def _box_inertia(mass: float, half: np.ndarray) -> list[float]:
    """Principal inertia (kg·m²) of a uniform box of `mass` (kg) and half sizes `half` (m)."""
    return r6v(mass / 3.0 * np.array([half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2]))


def add_flexures(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    """Per facet k a clamped sheet (`softcbf_mj.physics.flexure`): body `plate{k}` (the clamp) on the
    gauge's slide joint `plate{k}_gauge` along n̂, the first half cell `plate{k}` fixed to it,
    then links `plate{k}_link{j}` on hinges `plate{k}_h{j}` about z at the cell centres, on
    the sheet's surface facing the arm. Sites: `plate{k}_surface` (the clamp end of the
    surface at rest) and `plate{k}_calibration` (the calibration point)."""
    plate = spec.find_default("plate")
    for k, (normal, hk, flex) in enumerate(zip(config.facet_normals(), config.h, config.flexures())):
        if flex.width / 2 > PLATE_HALF_HEIGHT:
            raise ValueError(
                f"flexure width must be <= {2 * PLATE_HALF_HEIGHT:g} m (the tags lie just above the plates), got {flex.width:g} m"
            )
        name = f"plate{k + 1}"
        tangent = np.array([-normal[1], normal[0]])
        distance = hk / float(np.linalg.norm(config.H[k]))
        clamp = normal * (distance + config.tip_radius) + flex.clamp_at * tangent
        angle = math.atan2(normal[1], normal[0])
        sign, c, t = flex.direction, flex.cell, flex.thickness
        body = spec.worldbody.add_body(
            name=name, pos=r6v([clamp[0], clamp[1], 0.0]), quat=r6v([math.cos(angle / 2), 0, 0, math.sin(angle / 2)]),
        )
        body.add_joint(
            name=f"{name}_gauge", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0, 0.0, 0.0],
            stiffness=[r6(flex.gauge_stiffness), 0, 0], damping=[r6(flex.gauge_damping), 0, 0],
        )
        clamp_half = np.array([_FLEXURE_CLAMP_SIZE / 2, _FLEXURE_CLAMP_SIZE / 2, PLATE_HALF_HEIGHT])
        clamp_centre = [clamp_half[0], -sign * clamp_half[1], 0.0]  # behind the surface, beyond the clamped end
        body.explicitinertial = True
        body.mass = r6(flex.gauge_mass)
        body.ipos = r6v(clamp_centre)
        body.inertia = _box_inertia(flex.gauge_mass, clamp_half)
        body.add_geom(default=plate, name=f"{name}_clamp", type=mujoco.mjtGeom.mjGEOM_BOX, pos=r6v(clamp_centre), size=r6v(clamp_half))
        body.add_site(name=f"{name}_surface", pos=[0, 0, 0], size=[r6(config.tip_radius), 0, 0])
        lengths = [c / 2] + [c] * (flex.links - 1) + [c / 2]  # the clamped half cell, the links
        starts = np.concatenate(([0.0], flex.hinge_positions()))
        calibration = min(int(np.searchsorted(starts, flex.calibration_s, side="right")) - 1, flex.links)
        parent = body
        for j, length in enumerate(lengths):
            half = np.array([t / 2, length / 2, flex.width / 2])
            centre = r6v([t / 2, sign * length / 2, 0.0])
            if j > 0:
                parent = parent.add_body(name=f"{name}_link{j}", pos=r6v([0.0, sign * lengths[j - 1], 0.0]))
                parent.add_joint(
                    name=f"{name}_h{j}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, 0.0, 1.0],
                    stiffness=[r6(flex.hinge_stiffness), 0, 0], damping=[r6(flex.hinge_damping), 0, 0],
                )
                mass = flex.density * t * length * flex.width
                parent.explicitinertial = True
                parent.mass = r6(mass)
                parent.ipos = centre
                parent.inertia = _box_inertia(mass, half)
            parent.add_geom(default=plate, name=name if j == 0 else f"{name}_link{j}", type=mujoco.mjtGeom.mjGEOM_BOX,
                            pos=centre, size=r6v(half))
            if j == calibration:
                parent.add_site(name=f"{name}_calibration", pos=r6v([0.0, sign * (flex.calibration_s - starts[j]), 0.0]),
                                size=[r6(config.tip_radius), 0, 0])
