"""The discretised PCC arm of the generated model (docs/ground-truth.md): links, hinges, tendons, actuators.

Arm. Segment i of the PCC arm (length L_i, mass m_i, inertia I_i, stiffness k_i,
damping d_i, gain λ_i; `controllers.model.params.RobotParams`) becomes n rigid links joined
by n hinges about z, placed at the centres of n equal cells of length c_i = L_i / n:

    s = 0 ─ c/2 ─ hinge 1 ─ c ─ hinge 2 ─ … ─ hinge n ─ c/2 ─ s = L_i

so both ends of a segment are half-length links (the half links of adjacent segments
form one body; the first half link of segment 1 is part of the fixed `base`). With all n
hinges bent by q_i/n the segment end lies within ≈ L q²/(12 n²) of the PCC arc, and
the segment's generalised forces are exactly PCC's:

- hinge stiffness n·k_i and damping n·d_i (N·m/rad, N·m·s/rad) give −k_i q_i − d_i q̇_i
  on q_i = Σ_j θ_ij (the fixed tendon `seg{i}_bend`, coefficient 1 on each hinge, has
  length q_i);
- the pressure actuator `seg{i}_pressure` (command u_i in hPa, ctrlrange
  [u_min_i, u_max_i]) drives that tendon with gear λ_i (N·m/hPa), i.e. the torque
  λ_i u_i acts on EVERY hinge of the segment (equal bending moment along the segment),
  through first-order pressure dynamics  ṗ = (u − p)/τ_p  (`filterexact`), or no
  dynamics (p = u) when τ_p = 0;
- the mass is spread uniformly along the segment (density m_i / L_i, each link's share
  at its centre with its own rod inertia m ℓ²/12), so the straight segment's inertia
  about its centre is m_i L_i²/12; the difference I_i − m_i L_i²/12 from `RobotParams`
  is spread over the links in proportion to length (refused if a link's inertia would
  become ≤ 0). Only I_zz acts (every joint is a hinge about z); I_xx = I_yy = I_zz
  keeps the inertia valid.

Sites `seg{i}_end` mark the segment ends p_i; the collision sphere `tip` (radius
`tip_radius`, m) is centred on the tip point r = p_N. Collision capsules of the same
radius run along the links, so contact starts when the arm's centreline comes within
`tip_radius` of a plate. Arm geoms have contype 1 / conaffinity 0 and plates 0 / 1:
the arm touches only the plates, never itself; the plates never touch each other.

The links' geoms take the default classes `visual` and `collision` (`softcbf_mj.physics.mjcf.assembly`); the
tags on the arm are `softcbf_mj.physics.mjcf.tags`'.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco

from softcbf_mj.physics.mjcf.config import ArmModelConfig
from softcbf_mj.physics.mjcf.precision import r6, r6v
from softcbf_mj.physics.mjcf.tags import add_tag, arm_tag_placements

VISUAL_RADIUS = 0.01  # m, drawn arm radius (appearance only)


@dataclass(frozen=True)
class _Piece:
    """A straight stretch of one segment inside a body: from `start` (m, body x) of length `length`."""

    segment: int
    start: float
    length: float


def _body_inertial(config: ArmModelConfig, pieces: list[_Piece]) -> tuple[float, float, float]:
    """Mass (kg), centre of mass on the body x axis (m) and I_zz about it (kg·m²) of uniform pieces."""
    robot = config.robot
    masses, centres, own = [], [], []
    for p in pieces:
        L = robot.lengths[p.segment]
        mass = robot.masses[p.segment] * p.length / L
        excess = robot.inertias[p.segment] - robot.masses[p.segment] * L * L / 12.0
        masses.append(mass)
        centres.append(p.start + p.length / 2)
        own.append(mass * p.length**2 / 12.0 + excess * p.length / L)
    total = sum(masses)
    com = sum(m * c for m, c in zip(masses, centres)) / total
    izz = sum(i + m * (c - com) ** 2 for m, c, i in zip(masses, centres, own))
    if not izz > 0:
        seg = pieces[0].segment
        raise ValueError(
            f"inertias[{seg}] = {robot.inertias[seg]:g} kg·m² is too small to spread over "
            f"{config.links_per_segment} links (a link's inertia became {izz:g}); raise it towards "
            f"m L²/12 = {robot.masses[seg] * robot.lengths[seg] ** 2 / 12:g} or use fewer links"
        )
    return total, com, izz


_Z_TO_X = [r6(math.sqrt(0.5)), 0.0, r6(math.sqrt(0.5)), 0.0]  # quat turning a capsule's z axis onto x


def _capsule(body: mujoco.MjsBody, default: mujoco.MjsDefault, x0: float, x1: float, radius: float) -> None:
    """A capsule of `radius` along the body x axis from x0 to x1 (m)."""
    body.add_geom(
        default=default,
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        pos=r6v([(x0 + x1) / 2, 0, 0]),
        quat=_Z_TO_X,
        size=[r6(radius), r6((x1 - x0) / 2), 0],
    )


def add_arm(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    """The arm of `config` into `spec` (module docstring): `base`, the links on their hinges, the tags on the arm,
    one tendon `seg{i}_bend` and one pressure actuator `seg{i}_pressure` per segment."""
    robot, n, r = config.robot, config.links_per_segment, config.tip_radius
    visual, collision = spec.find_default("visual"), spec.find_default("collision")
    cells = [L / n for L in robot.lengths]
    n_seg = robot.n_segments

    base = spec.worldbody.add_body(name="base")
    base.add_site(name="base", pos=[0, 0, 0], size=[r6(r), 0, 0])
    base.add_geom(default=visual, type=mujoco.mjtGeom.mjGEOM_BOX, pos=r6v([-0.015, 0, 0]), size=[0.015, 0.025, 0.012])
    _capsule(base, visual, 0.0, cells[0] / 2, VISUAL_RADIUS)
    _capsule(base, collision, 0.0, cells[0] / 2, r)

    parent, offset = base, cells[0] / 2
    for i in range(n_seg):
        c = cells[i]
        for j in range(1, n + 1):
            body = parent.add_body(name=f"seg{i + 1}_link{j}", pos=r6v([offset, 0, 0]))
            body.add_joint(
                name=f"seg{i + 1}_j{j}",
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[0.0, 0.0, 1.0],
                stiffness=[r6(n * robot.stiffness[i]), 0, 0],
                damping=[r6(n * robot.damping[i]), 0, 0],
            )
            if j < n:
                pieces = [_Piece(i, 0.0, c)]
                length = c
            elif i < n_seg - 1:
                pieces = [_Piece(i, 0.0, c / 2), _Piece(i + 1, c / 2, cells[i + 1] / 2)]
                length = c / 2 + cells[i + 1] / 2
            else:
                pieces = [_Piece(i, 0.0, c / 2)]
                length = c / 2
            mass, com, izz = _body_inertial(config, pieces)
            body.explicitinertial = True
            body.mass = r6(mass)
            body.ipos = r6v([com, 0, 0])
            body.inertia = [r6(izz)] * 3
            _capsule(body, visual, 0.0, length, VISUAL_RADIUS)
            if j == n:
                body.add_site(name=f"seg{i + 1}_end", pos=r6v([c / 2, 0, 0]), size=[r6(r), 0, 0])
            if i == n_seg - 1 and j == n:
                # The tip sphere is the last half cell's collision volume; a capsule ending r
                # before the tip keeps the axis covered without a second contact at the tip.
                body.add_geom(
                    default=collision, name="tip", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    pos=r6v([c / 2, 0, 0]), size=[r6(r), 0, 0], rgba=[0.9, 0.3, 0.1, 1],
                )
                if c / 2 > r:
                    _capsule(body, collision, 0.0, c / 2 - r, r)
            else:
                _capsule(body, collision, 0.0, length, r)
            parent, offset = body, length if j == n else c

    for tag in arm_tag_placements(config):
        site = spec.site(tag.site)
        add_tag(spec, spec.body(tag.body), tag.tag_id, site.pos[0] + tag.offset, 0.0, 0.0, config.tag_size)

    for i in range(n_seg):
        tendon = spec.add_tendon(name=f"seg{i + 1}_bend")
        for j in range(1, n + 1):
            tendon.wrap_joint(f"seg{i + 1}_j{j}", 1.0)
        actuator = spec.add_actuator(
            name=f"seg{i + 1}_pressure",
            trntype=mujoco.mjtTrn.mjTRN_TENDON,
            target=f"seg{i + 1}_bend",
            gear=[r6(robot.gains[i]), 0, 0, 0, 0, 0],
            ctrllimited=True,
            ctrlrange=r6v([robot.u_min[i], robot.u_max[i]]),
        )
        if config.tau_p > 0:
            actuator.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            actuator.dynprm = [r6(config.tau_p)] + [0.0] * 9
