"""MJCF of the discretised PCC arm and its compliant plates, generated with MjSpec (docs/ground-truth.md).

Arm. Segment i of the PCC arm (length L_i, mass m_i, inertia I_i, stiffness k_i,
damping d_i, gain λ_i; `controllers.params.RobotParams`) becomes n rigid links joined
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

Flexure plates (`plate="flexure"`, docs/beyond-the-paper.md#flexure-plate; maths and defaults in `softcbf_mj.flexure`):
facet k instead gets a clamped sheet: the clamp body `plate{k}` on the force gauge's slide
joint `plate{k}_gauge` along n̂_k (stiffness k_g), the sheet's first half cell fixed to it
and links `plate{k}_link{j}` on hinges `plate{k}_h{j}` about z at the cell centres, on the
surface that faces the arm; that surface at rest lies on the facet line shifted by
`tip_radius` (as the ideal plate's), from the clamp at σ = `clamp_at` to the free end at
σ = `free_end_at` along t̂ = (−n̂_y, n̂_x) from the foot of the perpendicular from the base.
Sites `plate{k}_surface` (the surface's clamp end) and `plate{k}_calibration`.

AprilTags (docs/ground-truth.md, as on the hardware). Tag 0 (`perception.tags`) lies on `base`, centred
on the base point; tag i on the body that carries `seg{i}_end`, centred on that site,
except the tip tag, which is shifted back along its link by half its textured edge so
that its front edge is the tip point r and it never overhangs the plate. Each is a flat
box geom `tag{id}` (textured edge S = `textured_size(tag_size)`, m; 1 mm thick) whose top
face lies in the plane z = `TAG_PLANE_Z` above every other geom (plates reach
z = `_PLATE_HALF_HEIGHT`), so nothing occludes a tag from the overhead camera; its image
x axis runs along the body's x axis, its image up along +y. Tags are visual only
(contype = conaffinity = 0, density 0: no mass; the arm's bodies carry explicit
inertials), textured with the 36h11 images of `perception.tags.tag_image` (PNG files
`assets/tag{id}.png`; in-memory specs carry the same bytes in `spec.assets`), with a
matte material (no specular highlight). The calibration scene adds a board of tags
`CALIBRATION_BOARD_IDS` on the world in the same plane (`calibration_board`).

Options: `implicitfast` (joint damping integrated implicitly), MuJoCo's own choice of the
constraint Jacobian (`jacobian="auto"`, MuJoCo's default: dense below 60 degrees of freedom, so
the default arm with its plate, nv = 21, and the flexure, nv = 31, are dense and the convergence
study's finer arms, nv = 81 at n = 40, sparse), gravity off by default (the arm lies on a table; `gravity`
sets it, e.g. (0, −9.81, 0) for an arm in a vertical plane; `table_friction` instead makes the
links slide on the table with Coulomb friction, `softcbf_mj.table_friction`). The defaults n = 10
and physics step 0.1 ms come from `tools/convergence_study.py` (models/softcbf_arm/README.md).

Units: SI (m, kg, s, rad, N); pressure in hPa.
Every number goes into the spec rounded to 6 significant digits, the precision MuJoCo's
XML writer keeps, so the model compiled from the spec and from the written files are
identical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np

from controllers.params import RobotParams, per_segment, reference_robot
from softcbf_mj.flexure import FlexureParams
from softcbf_mj.table_friction import TABLE_FRICTION_NUMERIC, check_table_friction
from perception.plane import TagBoard, fovy_intrinsics
from perception.tags import arm_tag_ids, tag_image, textured_size

ARM_FILE = "softcbf_arm.xml"
SCENE_FILE = "scene.xml"
SCENE_MODEL_NAME = "softcbf_arm scene"
CALIBRATION_SCENE_FILE = "scene_calibration.xml"
CALIBRATION_SCENE_MODEL_NAME = "softcbf_arm calibration scene"
CALIBRATION_BOARD_FILE = "scene_calibration_board.json"  # perception.plane.TagBoard
ASSETS_DIR = "assets"

PAPER_H = ((0.36, 1.0),)  # docs/model.md#force-safe-set: the paper's single facet, H r ≤ h
PAPER_h = (0.15,)  # m
PAPER_PLATE_STIFFNESS = 11.16  # N/m, paper
PLATE_KINDS = ("ideal", "flexure")  # a rigid plate on a slide spring (docs/ground-truth.md) | a clamped sheet in a force gauge (§12)

DEFAULT_LINKS_PER_SEGMENT = 10  # chosen by tools/convergence_study.py (model README)
DEFAULT_PHYSICS_DT = 1e-4  # s, chosen by tools/convergence_study.py (model README)
DEFAULT_TAU_P = 0.05  # s, docs/ground-truth.md
# Coarser rod for loops that render a camera (camera_loop, the hardware emulator): about twice
# as fast; against the defaults on mujoco_contact's Low run, 0.08 mm of tip and ≈ 1 mN of plate
# force (tools/bench_mujoco_contact.py sweep, model README), far below the camera's own errors.
CAMERA_LINKS_PER_SEGMENT = 5
CAMERA_PHYSICS_DT = 2e-4  # s

# Appearance and scene geometry (no effect on the physics).
_VISUAL_RADIUS = 0.01  # m, drawn arm radius
_PLATE_THICKNESS = 0.005  # m
_PLATE_HALF_HEIGHT = 0.02  # m, along z
_PLATE_EDGE_MARGIN = 0.02  # m, beyond the reachable chord at each side
_FLEXURE_CLAMP_SIZE = 0.01  # m, the clamp block's edge (behind the sheet's surface)
CAMERA_FOVY_DEG = 45.0
CAMERA_RESOLUTION = (1280, 720)  # px, width × height
_CAMERA_FIELD_MARGIN = 1.1  # the image height covers ±1.1 Σ L around the workspace centre

_ARM_COLOR = (0.55, 0.35, 0.75, 1.0)
_PLATE_COLOR = (0.15, 0.15, 0.15, 1.0)
_TABLE_COLOR = (0.78, 0.76, 0.72, 1.0)

# AprilTags (visual only).
DEFAULT_TAG_SIZE = 0.03  # m, black square of the 36h11 tag (chosen: the hardware's printed size)
TAG_PLANE_Z = 0.025  # m, top faces of all tags: above the plates (z <= _PLATE_HALF_HEIGHT) and the arm
_TAG_HALF_THICKNESS = 0.0005  # m
TAG_TEXTURE_CELL_PX = 16  # texture px per tag cell: 160 × 160 px textures (8 cells + 1 quiet cell each side)
CALIBRATION_BOARD_IDS = tuple(range(10, 22))  # tags of the calibration board (arm: 0..N)
# Board tag centres in units of the reach Σ L (x from the base, y): one column behind the
# base, three beyond the reach; every tag lies outside the reach circle and inside the view.
_BOARD_COLUMNS = (-1.25, 1.3, 1.7, 2.1)
_BOARD_ROWS = (-0.8, 0.0, 0.8)


def _r6(x: float) -> float:
    """x rounded to 6 significant digits (MuJoCo's XML precision)."""
    return float(f"{float(x):.6g}")


def _r6v(values: Any) -> list[float]:
    return [_r6(v) for v in values]


@dataclass(frozen=True)
class ArmModelConfig:
    """Everything the generated model depends on (units in the module docstring).

    | field               | default                  | unit  | source                                  |
    |---------------------|--------------------------|-------|-----------------------------------------|
    | robot               | reference_robot()        | —     | docs/model.md#rppr-dynamics             |
    | H, h                | [[0.36, 1.0]], [0.15]    | —, m  | paper (docs/model.md#force-safe-set)    |
    | plate_stiffness     | 11.16 (per facet)        | N/m   | paper                                   |
    | links_per_segment   | 10                       | —     | convergence study                       |
    | tau_p               | 0.05                     | s     | chosen (docs/ground-truth.md)           |
    | physics_dt          | 1e-4                     | s     | convergence study                       |
    | integrator          | "implicitfast"           | —     | docs/ground-truth.md (see model README) |
    | tip_radius          | 0.004                    | m     | chosen                                  |
    | plate_mass          | 0.01                     | kg    | chosen                                  |
    | plate_damping_ratio | 0.2                      | —     | chosen (light damping)                  |
    | contact_timeconst   | 0.002                    | s     | chosen (stiff contact)                  |
    | tag_size            | 0.03                     | m     | chosen (hardware tags)                  |
    | plate               | "ideal"                  | —     | docs/ground-truth.md ("flexure": docs/beyond-the-paper.md) |
    | flexure             | FlexureParams()          | —     | docs/beyond-the-paper.md (softcbf_mj.flexure) |
    | tip_friction        | 0.0                      | —     | docs/beyond-the-paper.md (0: frictionless) |
    | gravity             | (0, 0, 0)                | m/s²  | chosen (arm on a table)                 |
    | table_friction      | 0.0                      | —     | docs/ground-truth.md (0: off)           |

    `tag_size` is the black square of each AprilTag; its texture (with the white quiet
    zone) spans `textured_size(tag_size)`, at most half the shortest segment so that
    neighbouring tags cannot overlap. An empty facet set (H of shape (0, 2)) gives the arm alone.
    `plate` "flexure" replaces every ideal plate by a clamped sheet in a force gauge
    (`flexure`: one `FlexureParams` for every facet, or one per facet; `plate_stiffness`
    is then unused). `tip_friction` μ ≥ 0 is the Coulomb friction between the arm and the
    plates (μ > 0: condim 3; μ = 0 keeps the frictionless condim 1 model exactly).
    `gravity` (m/s², world frame; the arm moves in the x-y plane): e.g. (0, −9.81, 0) for
    an arm in a vertical plane with +y up. `table_friction` μ ≥ 0 is the Coulomb friction
    between the arm's links and the table it lies on (`softcbf_mj.table_friction`; 0: off,
    the model unchanged; > 0: the model carries μ as its custom numeric `table_friction`,
    which `MujocoPlant` applies; refused with gravity and beyond the explicit stability limit).
    """

    robot: RobotParams = field(default_factory=reference_robot)
    H: tuple[tuple[float, float], ...] = PAPER_H
    h: tuple[float, ...] = PAPER_h
    plate_stiffness: tuple[float, ...] | float = PAPER_PLATE_STIFFNESS
    links_per_segment: int = DEFAULT_LINKS_PER_SEGMENT
    tau_p: float = DEFAULT_TAU_P
    physics_dt: float = DEFAULT_PHYSICS_DT
    integrator: str = "implicitfast"
    tip_radius: float = 0.004
    plate_mass: float = 0.01
    plate_damping_ratio: float = 0.2
    contact_timeconst: float = 0.002
    tag_size: float = DEFAULT_TAG_SIZE
    plate: str = "ideal"
    flexure: FlexureParams | tuple[FlexureParams, ...] = field(default_factory=FlexureParams)
    tip_friction: float = 0.0
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    table_friction: float = 0.0

    def __post_init__(self) -> None:
        H = np.atleast_2d(np.asarray(self.H, dtype=float)) if np.size(self.H) else np.zeros((0, 2))
        h = np.atleast_1d(np.asarray(self.h, dtype=float)) if np.size(self.h) else np.zeros(0)
        if H.ndim != 2 or H.shape[1] != 2:
            raise ValueError(f"H must have shape (P, 2), got {H.shape}")
        if h.ndim != 1 or H.shape[0] != h.shape[0]:
            raise ValueError(f"H and h must have one row per facet, got H {H.shape} and h {h.shape}")
        if not (np.all(np.isfinite(H)) and np.all(np.isfinite(h))):
            raise ValueError(f"H and h must be finite, got H={H.tolist()}, h={h.tolist()}")
        for k, (row, hk) in enumerate(zip(H, h)):
            if not np.linalg.norm(row) > 0:
                raise ValueError(f"H[{k}] must be non-zero, got {row.tolist()}")
            if not hk > 0:
                raise ValueError(f"h[{k}] must be > 0 (the base must lie inside free space H r <= h), got {hk}")
        object.__setattr__(self, "H", tuple(tuple(float(v) for v in row) for row in H))
        object.__setattr__(self, "h", tuple(float(v) for v in h))
        stiffness = per_segment(self.plate_stiffness, len(self.h), "plate_stiffness") if self.h else np.zeros(0)
        if np.any(~(stiffness > 0)) or not np.all(np.isfinite(stiffness)):
            raise ValueError(f"plate_stiffness must be finite and > 0, got {stiffness.tolist()}")
        object.__setattr__(self, "plate_stiffness", tuple(float(v) for v in stiffness))
        if int(self.links_per_segment) != self.links_per_segment or self.links_per_segment < 1:
            raise ValueError(f"links_per_segment must be an integer >= 1, got {self.links_per_segment}")
        object.__setattr__(self, "links_per_segment", int(self.links_per_segment))
        if not (math.isfinite(self.tau_p) and self.tau_p >= 0):
            raise ValueError(f"tau_p must be >= 0 (0: ideal actuator), got {self.tau_p}")
        for name in ("physics_dt", "tip_radius", "plate_mass", "contact_timeconst"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if f"mjINT_{self.integrator.upper()}" not in mujoco.mjtIntegrator.__members__:
            valid = ", ".join(k.removeprefix("mjINT_").lower() for k in mujoco.mjtIntegrator.__members__)
            raise ValueError(f"integrator must be one of {valid}, got {self.integrator!r}")
        if not (math.isfinite(self.plate_damping_ratio) and self.plate_damping_ratio >= 0):
            raise ValueError(f"plate_damping_ratio must be >= 0, got {self.plate_damping_ratio}")
        if not (math.isfinite(self.tag_size) and self.tag_size > 0):
            raise ValueError(f"tag_size must be > 0 m, got {self.tag_size}")
        if textured_size(self.tag_size) > min(self.robot.lengths) / 2:
            largest = min(self.robot.lengths) / 2 * self.tag_size / textured_size(self.tag_size)
            raise ValueError(
                f"tag_size {self.tag_size:g} m gives tags of {textured_size(self.tag_size):g} m with their quiet zone, "
                f"more than half the shortest segment ({min(self.robot.lengths):g} m), so neighbouring tags "
                f"could overlap; use tag_size <= {largest:.4g} m"
            )
        if self.plate not in PLATE_KINDS:
            raise ValueError(f"plate must be one of {', '.join(PLATE_KINDS)}, got {self.plate!r}")
        if not isinstance(self.flexure, FlexureParams):
            object.__setattr__(self, "flexure", tuple(self.flexure))
            if len(self.flexure) != len(self.h) or not all(isinstance(f, FlexureParams) for f in self.flexure):
                raise ValueError(f"flexure must be one FlexureParams or one per facet ({len(self.h)}), got {self.flexure!r}")
        if not (math.isfinite(self.tip_friction) and self.tip_friction >= 0):
            raise ValueError(f"tip_friction must be finite and >= 0 (0: frictionless), got {self.tip_friction}")
        gravity = tuple(float(g) for g in self.gravity)
        if len(gravity) != 3 or not all(math.isfinite(g) for g in gravity):
            raise ValueError(f"gravity must be 3 finite numbers (m/s²), got {self.gravity!r}")
        object.__setattr__(self, "gravity", gravity)
        check_table_friction(self.table_friction, self.physics_dt, gravity)
        if self.contact_timeconst < 2 * self.physics_dt:
            raise ValueError(
                f"contact_timeconst ({self.contact_timeconst:g} s) must be >= 2 physics_dt "
                f"({2 * self.physics_dt:g} s), or MuJoCo silently stiffens it to 2 physics_dt; "
                "raise contact_timeconst or lower physics_dt"
            )

    @property
    def n_facets(self) -> int:
        return len(self.h)

    def facet_normals(self) -> np.ndarray:
        """Unit outward normals n̂_k = H_kᵀ/‖H_k‖, shape (P, 2)."""
        H = np.array(self.H, dtype=float).reshape(-1, 2)
        return H / np.linalg.norm(H, axis=1, keepdims=True)

    def flexures(self) -> tuple[FlexureParams, ...]:
        """The flexure of each facet, (P,)."""
        return (self.flexure,) * self.n_facets if isinstance(self.flexure, FlexureParams) else self.flexure

    def plate_damping(self) -> np.ndarray:
        """Plate slide damping 2 ζ √(k m), N·s/m, shape (P,)."""
        return 2.0 * self.plate_damping_ratio * np.sqrt(np.array(self.plate_stiffness) * self.plate_mass)


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


def _add_defaults(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    main = spec.add_default("softcbf_arm", spec.default)
    visual = spec.add_default("visual", main)
    visual.geom.contype = 0
    visual.geom.conaffinity = 0
    visual.geom.group = 2
    visual.geom.rgba = list(_ARM_COLOR)
    contact: dict[str, Any] = dict(condim=1, solref=[_r6(config.contact_timeconst), 1.0])
    if config.tip_friction > 0:  # both sides carry μ (MuJoCo takes the larger of the two geoms')
        contact.update(condim=3, friction=[_r6(config.tip_friction), 0.005, 0.0001])
    collision = spec.add_default("collision", main)
    collision.geom.contype = 1
    collision.geom.conaffinity = 0
    collision.geom.group = 3
    for key, value in contact.items():
        setattr(collision.geom, key, value)
    plate = spec.add_default("plate", main)
    plate.geom.contype = 0
    plate.geom.conaffinity = 1
    plate.geom.group = 1
    plate.geom.rgba = list(_PLATE_COLOR)
    for key, value in contact.items():
        setattr(plate.geom, key, value)


_Z_TO_X = [_r6(math.sqrt(0.5)), 0.0, _r6(math.sqrt(0.5)), 0.0]  # quat turning a capsule's z axis onto x


def _capsule(body: mujoco.MjsBody, default: mujoco.MjsDefault, x0: float, x1: float, radius: float) -> None:
    """A capsule of `radius` along the body x axis from x0 to x1 (m)."""
    body.add_geom(
        default=default,
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        pos=_r6v([(x0 + x1) / 2, 0, 0]),
        quat=_Z_TO_X,
        size=[_r6(radius), _r6((x1 - x0) / 2), 0],
    )


def tag_texture_file(tag_id: int) -> str:
    """Path of tag `tag_id`'s texture relative to the model folder (MJCF `file` attribute)."""
    return f"{ASSETS_DIR}/tag{tag_id}.png"


def tag_textures(tag_ids: Any) -> dict[str, bytes]:
    """PNG bytes of the 36h11 textures of `tag_ids`, keyed by `tag_texture_file` (same ids, same bytes)."""
    textures = {}
    for tag_id in tag_ids:
        ok, png = cv2.imencode(".png", tag_image(int(tag_id), TAG_TEXTURE_CELL_PX))
        if not ok:
            raise RuntimeError(f"OpenCV could not encode tag {tag_id} as PNG")
        textures[tag_texture_file(int(tag_id))] = png.tobytes()
    return textures


@dataclass(frozen=True)
class TagPlacement:
    """Where an arm tag sits: its centre is site `site` + `offset` (m) along the body's x axis."""

    tag_id: int
    body: str
    site: str
    offset: float


def arm_tag_placements(config: ArmModelConfig) -> tuple[TagPlacement, ...]:
    """Tag 0 on `base` at the base point; tag i on the body of `seg{i}_end`, the tip tag shifted back by S/2."""
    n, n_seg = config.links_per_segment, config.robot.n_segments
    ids = arm_tag_ids(n_seg)
    placements = [TagPlacement(ids[0], "base", "base", 0.0)]
    for i in range(1, n_seg + 1):
        offset = -textured_size(config.tag_size) / 2 if i == n_seg else 0.0
        placements.append(TagPlacement(ids[i], f"seg{i}_link{n}", f"seg{i}_end", _r6(offset)))
    return tuple(placements)


def _add_tag(spec: mujoco.MjSpec, body: mujoco.MjsBody, tag_id: int, x: float, y: float, angle: float, tag_size: float) -> None:
    """Texture, matte material and flat visual box `tag{id}` centred at (x, y) of `body`, top face at TAG_PLANE_Z."""
    name = f"tag{tag_id}"
    spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, file=tag_texture_file(tag_id))
    spec.add_material(name=name, textures=["", name], specular=0.0, shininess=0.0, reflectance=0.0)
    half = textured_size(tag_size) / 2
    body.add_geom(
        name=name, type=mujoco.mjtGeom.mjGEOM_BOX, material=name, contype=0, conaffinity=0, group=2, density=0.0,
        pos=_r6v([x, y, TAG_PLANE_Z - _TAG_HALF_THICKNESS]),
        quat=[_r6(v) if abs(v) > 1e-12 else 0.0 for v in (math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))],
        size=_r6v([half, half, _TAG_HALF_THICKNESS]),
    )


def _add_arm(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    robot, n, r = config.robot, config.links_per_segment, config.tip_radius
    visual, collision = spec.find_default("visual"), spec.find_default("collision")
    cells = [L / n for L in robot.lengths]
    n_seg = robot.n_segments

    base = spec.worldbody.add_body(name="base")
    base.add_site(name="base", pos=[0, 0, 0], size=[_r6(r), 0, 0])
    base.add_geom(default=visual, type=mujoco.mjtGeom.mjGEOM_BOX, pos=_r6v([-0.015, 0, 0]), size=[0.015, 0.025, 0.012])
    _capsule(base, visual, 0.0, cells[0] / 2, _VISUAL_RADIUS)
    _capsule(base, collision, 0.0, cells[0] / 2, r)

    parent, offset = base, cells[0] / 2
    for i in range(n_seg):
        c = cells[i]
        for j in range(1, n + 1):
            body = parent.add_body(name=f"seg{i + 1}_link{j}", pos=_r6v([offset, 0, 0]))
            body.add_joint(
                name=f"seg{i + 1}_j{j}",
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[0.0, 0.0, 1.0],
                stiffness=[_r6(n * robot.stiffness[i]), 0, 0],
                damping=[_r6(n * robot.damping[i]), 0, 0],
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
            body.mass = _r6(mass)
            body.ipos = _r6v([com, 0, 0])
            body.inertia = [_r6(izz)] * 3
            _capsule(body, visual, 0.0, length, _VISUAL_RADIUS)
            if j == n:
                body.add_site(name=f"seg{i + 1}_end", pos=_r6v([c / 2, 0, 0]), size=[_r6(r), 0, 0])
            if i == n_seg - 1 and j == n:
                # The tip sphere is the last half cell's collision volume; a capsule ending r
                # before the tip keeps the axis covered without a second contact at the tip.
                body.add_geom(
                    default=collision, name="tip", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    pos=_r6v([c / 2, 0, 0]), size=[_r6(r), 0, 0], rgba=[0.9, 0.3, 0.1, 1],
                )
                if c / 2 > r:
                    _capsule(body, collision, 0.0, c / 2 - r, r)
            else:
                _capsule(body, collision, 0.0, length, r)
            parent, offset = body, length if j == n else c

    for tag in arm_tag_placements(config):
        site = spec.site(tag.site)
        _add_tag(spec, spec.body(tag.body), tag.tag_id, site.pos[0] + tag.offset, 0.0, 0.0, config.tag_size)

    for i in range(n_seg):
        tendon = spec.add_tendon(name=f"seg{i + 1}_bend")
        for j in range(1, n + 1):
            tendon.wrap_joint(f"seg{i + 1}_j{j}", 1.0)
        actuator = spec.add_actuator(
            name=f"seg{i + 1}_pressure",
            trntype=mujoco.mjtTrn.mjTRN_TENDON,
            target=f"seg{i + 1}_bend",
            gear=[_r6(robot.gains[i]), 0, 0, 0, 0, 0],
            ctrllimited=True,
            ctrlrange=_r6v([robot.u_min[i], robot.u_max[i]]),
        )
        if config.tau_p > 0:
            actuator.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            actuator.dynprm = [_r6(config.tau_p)] + [0.0] * 9


def _add_plates(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
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
            pos=_r6v([surface[0], surface[1], 0.0]),
            quat=_r6v([math.cos(angle / 2), 0, 0, math.sin(angle / 2)]),
        )
        body.add_joint(
            name=f"plate{k + 1}_slide",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[1.0, 0.0, 0.0],
            stiffness=[_r6(stiffness), 0, 0],
            damping=[_r6(damping[k]), 0, 0],
        )
        half = np.array([_PLATE_THICKNESS / 2, half_width, _PLATE_HALF_HEIGHT])
        body.explicitinertial = True
        body.mass = _r6(config.plate_mass)
        body.ipos = _r6v([half[0], 0, 0])
        box_inertia = config.plate_mass / 3.0 * np.array([half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2])
        body.inertia = _r6v(box_inertia)
        body.add_geom(default=plate, name=f"plate{k + 1}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=_r6v([half[0], 0, 0]), size=_r6v(half))
        body.add_site(name=f"plate{k + 1}_surface", pos=[0, 0, 0], size=[_r6(config.tip_radius), 0, 0])


def _box_inertia(mass: float, half: np.ndarray) -> list[float]:
    """Principal inertia (kg·m²) of a uniform box of `mass` (kg) and half sizes `half` (m)."""
    return _r6v(mass / 3.0 * np.array([half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2]))


def _add_flexures(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    """Per facet k a clamped sheet (`softcbf_mj.flexure`): body `plate{k}` (the clamp) on the
    gauge's slide joint `plate{k}_gauge` along n̂, the first half cell `plate{k}` fixed to it,
    then links `plate{k}_link{j}` on hinges `plate{k}_h{j}` about z at the cell centres, on
    the sheet's surface facing the arm. Sites: `plate{k}_surface` (the clamp end of the
    surface at rest) and `plate{k}_calibration` (the calibration point)."""
    plate = spec.find_default("plate")
    for k, (normal, hk, flex) in enumerate(zip(config.facet_normals(), config.h, config.flexures())):
        if flex.width / 2 > _PLATE_HALF_HEIGHT:
            raise ValueError(
                f"flexure width must be <= {2 * _PLATE_HALF_HEIGHT:g} m (the tags lie just above the plates), got {flex.width:g} m"
            )
        name = f"plate{k + 1}"
        tangent = np.array([-normal[1], normal[0]])
        distance = hk / float(np.linalg.norm(config.H[k]))
        clamp = normal * (distance + config.tip_radius) + flex.clamp_at * tangent
        angle = math.atan2(normal[1], normal[0])
        sign, c, t = flex.direction, flex.cell, flex.thickness
        body = spec.worldbody.add_body(
            name=name, pos=_r6v([clamp[0], clamp[1], 0.0]), quat=_r6v([math.cos(angle / 2), 0, 0, math.sin(angle / 2)]),
        )
        body.add_joint(
            name=f"{name}_gauge", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0, 0.0, 0.0],
            stiffness=[_r6(flex.gauge_stiffness), 0, 0], damping=[_r6(flex.gauge_damping), 0, 0],
        )
        clamp_half = np.array([_FLEXURE_CLAMP_SIZE / 2, _FLEXURE_CLAMP_SIZE / 2, _PLATE_HALF_HEIGHT])
        clamp_centre = [clamp_half[0], -sign * clamp_half[1], 0.0]  # behind the surface, beyond the clamped end
        body.explicitinertial = True
        body.mass = _r6(flex.gauge_mass)
        body.ipos = _r6v(clamp_centre)
        body.inertia = _box_inertia(flex.gauge_mass, clamp_half)
        body.add_geom(default=plate, name=f"{name}_clamp", type=mujoco.mjtGeom.mjGEOM_BOX, pos=_r6v(clamp_centre), size=_r6v(clamp_half))
        body.add_site(name=f"{name}_surface", pos=[0, 0, 0], size=[_r6(config.tip_radius), 0, 0])
        lengths = [c / 2] + [c] * (flex.links - 1) + [c / 2]  # the clamped half cell, the links
        starts = np.concatenate(([0.0], flex.hinge_positions()))
        calibration = min(int(np.searchsorted(starts, flex.calibration_s, side="right")) - 1, flex.links)
        parent = body
        for j, length in enumerate(lengths):
            half = np.array([t / 2, length / 2, flex.width / 2])
            centre = _r6v([t / 2, sign * length / 2, 0.0])
            if j > 0:
                parent = parent.add_body(name=f"{name}_link{j}", pos=_r6v([0.0, sign * lengths[j - 1], 0.0]))
                parent.add_joint(
                    name=f"{name}_h{j}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, 0.0, 1.0],
                    stiffness=[_r6(flex.hinge_stiffness), 0, 0], damping=[_r6(flex.hinge_damping), 0, 0],
                )
                mass = flex.density * t * length * flex.width
                parent.explicitinertial = True
                parent.mass = _r6(mass)
                parent.ipos = centre
                parent.inertia = _box_inertia(mass, half)
            parent.add_geom(default=plate, name=name if j == 0 else f"{name}_link{j}", type=mujoco.mjtGeom.mjGEOM_BOX,
                            pos=centre, size=_r6v(half))
            if j == calibration:
                parent.add_site(name=f"{name}_calibration", pos=_r6v([0.0, sign * (flex.calibration_s - starts[j]), 0.0]),
                                size=[_r6(config.tip_radius), 0, 0])


def build_arm_spec(config: ArmModelConfig | None = None) -> mujoco.MjSpec:
    """The robot file's spec: options, defaults, arm, plates, tendons, actuators and the `home` key."""
    config = config or ArmModelConfig()
    spec = mujoco.MjSpec()
    spec.modelname = "softcbf_arm"
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    spec.option.timestep = _r6(config.physics_dt)
    spec.option.integrator = mujoco.mjtIntegrator.__members__[f"mjINT_{config.integrator.upper()}"]
    spec.option.gravity = _r6v(config.gravity)
    if config.table_friction > 0:  # read back by softcbf_mj.table_friction.table_friction_of
        spec.add_numeric(name=TABLE_FRICTION_NUMERIC, data=[_r6(config.table_friction)])
    spec.assets = tag_textures(arm_tag_ids(config.robot.n_segments))
    _add_defaults(spec, config)
    _add_arm(spec, config)
    if config.plate == "flexure":
        _add_flexures(spec, config)
        plate_q = sum(1 + flex.links for flex in config.flexures())
    else:
        _add_plates(spec, config)
        plate_q = config.n_facets
    n_q = config.robot.n_segments * config.links_per_segment + plate_q
    n_act = config.robot.n_segments if config.tau_p > 0 else 0
    spec.add_key(name="home", qpos=[0.0] * n_q, act=[0.0] * n_act, ctrl=[0.0] * config.robot.n_segments)
    return spec


def overhead_camera_pose(config: ArmModelConfig) -> tuple[tuple[float, float, float], float]:
    """Position (m) of the overhead camera and its focal length fx = fy (px).

    The camera looks down −z with image right = +x and image up = +y; it sits above
    (Σ L / 2, 0) at the height where the image height spans ±1.1 Σ L. Intrinsics:
    `perception.plane.fovy_intrinsics` (fx = fy = (H_px / 2) / tan(fovy / 2), centred principal point).
    """
    reach = sum(config.robot.lengths)
    half_fov = math.radians(CAMERA_FOVY_DEG) / 2
    height = _r6(round(_CAMERA_FIELD_MARGIN * reach / math.tan(half_fov), 2))
    focal = float(fovy_intrinsics(*CAMERA_RESOLUTION, CAMERA_FOVY_DEG)[0, 0])
    return (_r6(reach / 2), 0.0, height), focal


def calibration_board(config: ArmModelConfig | None = None) -> TagBoard:
    """The calibration scene's board: tags `CALIBRATION_BOARD_IDS` of `tag_size` in the tag plane.

    Centres at (column, row) × Σ L for the columns `_BOARD_COLUMNS` and rows `_BOARD_ROWS`
    (one column behind the base, three beyond the reach), angles 0, π/2, π, −π/2 in turn;
    refused unless every tag lies outside the reach circle (Σ L plus the tag's
    half-diagonal: no arm tag can slide under it) and wholly inside the overhead view.
    """
    config = config or ArmModelConfig()
    reach = sum(config.robot.lengths)
    arm_ids = arm_tag_ids(config.robot.n_segments)
    if set(arm_ids) & set(CALIBRATION_BOARD_IDS):
        raise ValueError(
            f"the arm's tags {list(arm_ids)} overlap the calibration board's {list(CALIBRATION_BOARD_IDS)}; "
            f"the board needs an arm of at most {CALIBRATION_BOARD_IDS[0] - 1} segments"
        )
    centres = [(c * reach, r * reach) for c in _BOARD_COLUMNS for r in _BOARD_ROWS]
    angles = [0.0, math.pi / 2, math.pi, -math.pi / 2]
    tags = {tag_id: (_r6(x), _r6(y), angles[k % 4]) for k, (tag_id, (x, y)) in enumerate(zip(CALIBRATION_BOARD_IDS, centres))}
    half_diagonal = textured_size(config.tag_size) / math.sqrt(2)
    (cam_x, cam_y, cam_z), focal = overhead_camera_pose(config)
    half_h = (CAMERA_RESOLUTION[1] / 2) * (cam_z - TAG_PLANE_Z) / focal
    half_w = (CAMERA_RESOLUTION[0] / 2) * (cam_z - TAG_PLANE_Z) / focal
    for tag_id, (x, y, _) in tags.items():
        if math.hypot(x, y) < reach + half_diagonal:
            raise ValueError(f"board tag {tag_id} at ({x:g}, {y:g}) m is within the arm's reach; use a smaller tag_size")
        if abs(x - cam_x) + half_diagonal > half_w or abs(y - cam_y) + half_diagonal > half_h:
            raise ValueError(f"board tag {tag_id} at ({x:g}, {y:g}) m leaves the overhead view; use a smaller tag_size")
    return TagBoard(config.tag_size, tags)


def _add_scene(spec: mujoco.MjSpec, config: ArmModelConfig, board: bool) -> None:
    """Table, lights, overhead camera, render settings and optionally the calibration board.

    Lighting for detectable tags: a directional light straight down (diffuse 0.5) plus the
    headlight (ambient 0.25, diffuse 0.25), no specular light and no shadows, so an
    upward face of colour c is lit to c·1.0 everywhere in the view: tag white renders as
    255, tag black as 0, the table below saturation. No multisampling (offsamples 0): a
    tag's black-white edges lie inside its texture, not on polygon edges, so antialiasing
    does not change them (identical detections, measured) and costs 2-3× the render time
    on the CPU. The table is plain (untextured): a textured surface filling the view cost
    ≈ 40 % of a 1280×720 OSMesa frame (tools/bench_render.py: 20 → 12.5 ms, measured).
    """
    spec.visual.global_.offwidth = CAMERA_RESOLUTION[0]
    spec.visual.global_.offheight = CAMERA_RESOLUTION[1]
    spec.visual.quality.offsamples = 0
    spec.visual.headlight.diffuse = [0.25, 0.25, 0.25]
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.worldbody.add_light(
        name="top", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0.12, 0.0, 1.5], dir=[0.0, 0.0, -1.0],
        diffuse=[0.5, 0.5, 0.5], specular=[0.0, 0.0, 0.0], castshadow=False,
    )
    spec.worldbody.add_geom(
        name="table", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05], rgba=list(_TABLE_COLOR),
        pos=[0.0, 0.0, -_VISUAL_RADIUS], contype=0, conaffinity=0,
    )
    pos, _ = overhead_camera_pose(config)
    spec.worldbody.add_camera(
        name="overhead", pos=list(pos), fovy=CAMERA_FOVY_DEG, resolution=list(CAMERA_RESOLUTION)
    )
    if board:
        tags = calibration_board(config).tags
        spec.assets = {**spec.assets, **tag_textures(tags)}
        for tag_id, (x, y, angle) in tags.items():
            _add_tag(spec, spec.worldbody, tag_id, x, y, angle, config.tag_size)


def build_spec(config: ArmModelConfig | None = None, board: bool = False) -> mujoco.MjSpec:
    """The whole scene (what `scene.xml` loads; with `board`, `scene_calibration.xml`) as one spec."""
    config = config or ArmModelConfig()
    spec = build_arm_spec(config)
    spec.modelname = CALIBRATION_SCENE_MODEL_NAME if board else SCENE_MODEL_NAME
    _add_scene(spec, config, board)
    return spec


def build_model(config: ArmModelConfig | None = None, board: bool = False) -> mujoco.MjModel:
    """Compile the scene of `config` (with `board`: the calibration scene)."""
    return build_spec(config, board).compile()


def arm_xml(config: ArmModelConfig | None = None) -> str:
    """Text of `softcbf_arm.xml`."""
    return build_arm_spec(config).to_xml()


def scene_xml(config: ArmModelConfig | None = None, board: bool = False) -> str:
    """Text of `scene.xml` (with `board`: `scene_calibration.xml`): an include of the arm file plus
    table, lights, the overhead camera and, with `board`, the calibration board."""
    config = config or ArmModelConfig()
    spec = mujoco.MjSpec()
    spec.modelname = CALIBRATION_SCENE_MODEL_NAME if board else SCENE_MODEL_NAME
    _add_scene(spec, config, board)
    head, sep, body = spec.to_xml().partition("\n")
    if not head.startswith("<mujoco"):
        raise RuntimeError(f"unexpected MJCF header from MjSpec.to_xml: {head!r}")
    return f'{head}{sep}  <include file="{ARM_FILE}"/>\n\n{body}'


def model_textures(config: ArmModelConfig | None = None) -> dict[str, bytes]:
    """Every texture file the written model references (arm and board tags), keyed by relative path."""
    config = config or ArmModelConfig()
    return tag_textures(arm_tag_ids(config.robot.n_segments) + tuple(calibration_board(config).tags))


def write_tag_textures(directory: str | Path, config: ArmModelConfig | None = None) -> list[Path]:
    """Write `model_textures(config)` under `directory` (into `assets/`); return their paths."""
    directory = Path(directory)
    paths = []
    for name, data in model_textures(config).items():
        path = directory / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        paths.append(path)
    return paths


def write_model_files(directory: str | Path, config: ArmModelConfig | None = None) -> list[Path]:
    """Write the model folder into `directory`: `softcbf_arm.xml`, `scene.xml`,
    `scene_calibration.xml`, its board JSON and the tag textures; return their paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    texts = {ARM_FILE: arm_xml(config), SCENE_FILE: scene_xml(config), CALIBRATION_SCENE_FILE: scene_xml(config, board=True)}
    paths = []
    for name, text in texts.items():
        (directory / name).write_text(text, encoding="utf-8")
        paths.append(directory / name)
    calibration_board(config).save(directory / CALIBRATION_BOARD_FILE)
    return paths + [directory / CALIBRATION_BOARD_FILE] + write_tag_textures(directory, config)
