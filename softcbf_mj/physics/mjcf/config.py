"""What the generated MuJoCo model depends on: `ArmModelConfig`, its defaults and its checks.

Units: SI (m, kg, s, rad, N); pressure in hPa. A field that is a setting of the vocabulary takes its
default from there (`vocabulary.settings`, the one home of a default). The defaults' sources are the class's table: the
paper's facet and plate stiffness (docs/model.md#force-safe-set), the discretisation and physics step
chosen by tools/convergence_study.py (models/softcbf_arm/README.md), and a coarser discretisation for
the loops that render a camera. Every check refuses a bad value with a one-line message that names
the field; nothing is clipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from controllers.model.params import RobotParams, per_segment, reference_robot
from perception.tags import textured_size
from softcbf_mj.physics.flexure import FlexureParams
from softcbf_mj.physics.table_friction import check_table_friction
from vocabulary.settings import default, setting

PAPER_H = ((0.36, 1.0),)  # docs/model.md#force-safe-set: the paper's single facet, H r ≤ h
PAPER_h = (0.15,)  # m
PLATE_KINDS = ("ideal", "flexure")  # a rigid plate on a slide spring (docs/ground-truth.md) | a clamped sheet in a force gauge (§12)

# The defaults are the vocabulary's (vocabulary.settings, their one home), named here for the model's users.
PAPER_PLATE_STIFFNESS = setting("plate_stiffness").default  # N/m, paper
DEFAULT_LINKS_PER_SEGMENT = setting("links_per_segment").default  # chosen by tools/convergence_study.py (model README)
DEFAULT_PHYSICS_DT = setting("physics_dt").default  # s, chosen by tools/convergence_study.py (model README)
DEFAULT_TAU_P = setting("tau_p").default  # s, docs/ground-truth.md
# Coarser rod for loops that render a camera (camera_loop, the hardware emulator): about twice
# as fast; against the defaults on mujoco_contact's Low run, 0.08 mm of tip and ≈ 1 mN of plate
# force (tools/bench_mujoco_contact.py sweep, model README), far below the camera's own errors.
CAMERA_LINKS_PER_SEGMENT = default("links_per_segment", "camera_loop")
CAMERA_PHYSICS_DT = default("physics_dt", "camera_loop")  # s
DEFAULT_TAG_SIZE = 0.03  # m, black square of the 36h11 tag (chosen: the hardware's printed size)


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
    | flexure             | FlexureParams()          | —     | docs/beyond-the-paper.md (softcbf_mj.physics.flexure) |
    | tip_friction        | 0.0                      | —     | docs/beyond-the-paper.md (0: frictionless) |
    | gravity             | (0, 0, 0)                | m/s²  | chosen (arm on a table)                 |
    | table_friction      | 0.0                      | —     | docs/ground-truth.md (0: off)           |
    | command_delay       | 0.0                      | s     | softcbf_mj.physics.plant (0: none)              |

    `tag_size` is the black square of each AprilTag; its texture (with the white quiet
    zone) spans `textured_size(tag_size)`, at most half the shortest segment so that
    neighbouring tags cannot overlap. An empty facet set (H of shape (0, 2)) gives the arm alone.
    `plate` "flexure" replaces every ideal plate by a clamped sheet in a force gauge
    (`flexure`: one `FlexureParams` for every facet, or one per facet; `plate_stiffness`
    is then unused). `tip_friction` μ ≥ 0 is the Coulomb friction between the arm and the
    plates (μ > 0: condim 3; μ = 0 keeps the frictionless condim 1 model exactly).
    `gravity` (m/s², world frame; the arm moves in the x-y plane): e.g. (0, −9.81, 0) for
    an arm in a vertical plane with +y up. `table_friction` μ ≥ 0 is the Coulomb friction
    between the arm's links and the table it lies on (`softcbf_mj.physics.table_friction`; 0: off,
    the model unchanged; > 0: the model carries μ as its custom numeric `table_friction`,
    which `MujocoPlant` applies; refused with gravity and beyond the explicit stability limit).
    `command_delay` δ ≥ 0 (s) holds the commands back on their way to the valves (`softcbf_mj.physics.plant`: a FIFO
    of δ/T control periods, whole, checked by the plant that knows T; 0: the model unchanged; > 0: the
    model carries δ as its custom numeric `command_delay`, which the MuJoCo plants apply).
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
    plate: str = setting("plate").default
    flexure: FlexureParams | tuple[FlexureParams, ...] = field(default_factory=FlexureParams)
    tip_friction: float = setting("tip_friction").default
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the setting gravity (m/s², along −y) 0: no gravity
    table_friction: float = setting("table_friction").default
    command_delay: float = setting("command_delay").default

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
        if not (math.isfinite(self.command_delay) and self.command_delay >= 0):
            raise ValueError(f"command_delay must be finite and >= 0 s (0: none), got {self.command_delay}")
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
