"""The generated model assembled: options, default classes, arm, plates and scene, as a spec and as files.

Options: `implicitfast` (joint damping integrated implicitly), MuJoCo's own choice of the
constraint Jacobian (`jacobian="auto"`, MuJoCo's default: dense below 60 degrees of freedom, so
the default arm with its plate, nv = 21, and the flexure, nv = 31, are dense and the convergence
study's finer arms, nv = 81 at n = 40, sparse), gravity off by default (the arm lies on a table; `gravity`
sets it, e.g. (0, −9.81, 0) for an arm in a vertical plane; `table_friction` instead makes the
links slide on the table with Coulomb friction, `softcbf_mj.physics.table_friction`). The defaults n = 10
and physics step 0.1 ms come from `tools/convergence_study.py` (models/softcbf_arm/README.md).

Default classes: `visual` (arm drawing, no contact), `collision` (the arm's capsules and tip sphere,
contype 1 / conaffinity 0) and `plate` (contype 0 / conaffinity 1), so the arm touches only the plates,
never itself, and the plates never touch each other; `collision` and `plate` share the contact
parameters (condim 1 and solref (`contact_timeconst`, 1); with `tip_friction` μ > 0, condim 3 and μ
on both sides).

Files (models/softcbf_arm/README.md): the robot file `ARM_FILE` (`arm_xml`: everything but the scene),
`SCENE_FILE` and `CALIBRATION_SCENE_FILE` (`scene_xml`: an include of the robot file plus
`softcbf_mj.physics.mjcf.scene`), the board's JSON and the tag textures under `assets/`. Units: SI (m, kg, s,
rad, N); pressure in hPa; numbers rounded by `softcbf_mj.physics.mjcf.precision`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco

from perception.tags import arm_tag_ids
from softcbf_mj.physics.mjcf.arm import add_arm
from softcbf_mj.physics.mjcf.config import ArmModelConfig
from softcbf_mj.physics.mjcf.plates import add_flexures, add_plates
from softcbf_mj.physics.mjcf.precision import r6, r6v
from softcbf_mj.physics.mjcf.scene import add_scene, calibration_board
from softcbf_mj.physics.mjcf.tags import tag_textures
from softcbf_mj.physics.plant import COMMAND_DELAY_NUMERIC
from softcbf_mj.physics.table_friction import TABLE_FRICTION_NUMERIC

ARM_FILE = "softcbf_arm.xml"
SCENE_FILE = "scene.xml"
SCENE_MODEL_NAME = "softcbf_arm scene"
CALIBRATION_SCENE_FILE = "scene_calibration.xml"
CALIBRATION_SCENE_MODEL_NAME = "softcbf_arm calibration scene"
CALIBRATION_BOARD_FILE = "scene_calibration_board.json"  # perception.plane.TagBoard

_ARM_COLOR = (0.55, 0.35, 0.75, 1.0)
_PLATE_COLOR = (0.15, 0.15, 0.15, 1.0)


def _add_defaults(spec: mujoco.MjSpec, config: ArmModelConfig) -> None:
    main = spec.add_default("softcbf_arm", spec.default)
    visual = spec.add_default("visual", main)
    visual.geom.contype = 0
    visual.geom.conaffinity = 0
    visual.geom.group = 2
    visual.geom.rgba = list(_ARM_COLOR)
    contact: dict[str, Any] = dict(condim=1, solref=[r6(config.contact_timeconst), 1.0])
    if config.tip_friction > 0:  # both sides carry μ (MuJoCo takes the larger of the two geoms')
        contact.update(condim=3, friction=[r6(config.tip_friction), 0.005, 0.0001])
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


def build_arm_spec(config: ArmModelConfig | None = None) -> mujoco.MjSpec:
    """The robot file's spec: options, defaults, arm, plates, tendons, actuators and the `home` key."""
    config = config or ArmModelConfig()
    spec = mujoco.MjSpec()
    spec.modelname = "softcbf_arm"
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    spec.option.timestep = r6(config.physics_dt)
    spec.option.integrator = mujoco.mjtIntegrator.__members__[f"mjINT_{config.integrator.upper()}"]
    spec.option.gravity = r6v(config.gravity)
    if config.table_friction > 0:  # read back by softcbf_mj.physics.table_friction.table_friction_of
        spec.add_numeric(name=TABLE_FRICTION_NUMERIC, data=[r6(config.table_friction)])
    if config.command_delay > 0:  # read back by softcbf_mj.physics.mujoco_plant.command_delay_of
        spec.add_numeric(name=COMMAND_DELAY_NUMERIC, data=[float(config.command_delay)])
    spec.assets = tag_textures(arm_tag_ids(config.robot.n_segments))
    _add_defaults(spec, config)
    add_arm(spec, config)
    if config.plate == "flexure":
        add_flexures(spec, config)
        plate_q = sum(1 + flex.links for flex in config.flexures())
    else:
        add_plates(spec, config)
        plate_q = config.n_facets
    n_q = config.robot.n_segments * config.links_per_segment + plate_q
    n_act = config.robot.n_segments if config.tau_p > 0 else 0
    spec.add_key(name="home", qpos=[0.0] * n_q, act=[0.0] * n_act, ctrl=[0.0] * config.robot.n_segments)
    return spec


def build_spec(config: ArmModelConfig | None = None, board: bool = False) -> mujoco.MjSpec:
    """The whole scene (what `scene.xml` loads; with `board`, `scene_calibration.xml`) as one spec."""
    config = config or ArmModelConfig()
    spec = build_arm_spec(config)
    spec.modelname = CALIBRATION_SCENE_MODEL_NAME if board else SCENE_MODEL_NAME
    add_scene(spec, config, board)
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
    add_scene(spec, config, board)
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
