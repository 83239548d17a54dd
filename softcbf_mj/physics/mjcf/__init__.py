"""The MJCF generator: the discretised PCC arm, its compliant plates and its scene, built with MjSpec (docs/ground-truth.md).

One module per part of the model, each with its derivation and assumptions:

- `config`: `ArmModelConfig`, what the model depends on, with its defaults and checks;
- `arm`: the PCC arm as rigid links on hinges, its tendons and pressure actuators;
- `plates`: the ideal plates on slide springs, or the flexures (clamped sheets in a force gauge);
- `tags`: the AprilTags on the arm (textures, placements, geoms);
- `scene`: table, lights, the overhead camera and the calibration board;
- `assembly`: options and default classes, the spec of the robot file and of the scene, the written files;
- `precision`: every number rounded to MuJoCo's XML precision.

The names users import (`build_model`, `ArmModelConfig`, the defaults, the file names) are importable from
this package.
"""

from softcbf_mj.physics.mjcf.assembly import (
    ARM_FILE,
    CALIBRATION_BOARD_FILE,
    CALIBRATION_SCENE_FILE,
    CALIBRATION_SCENE_MODEL_NAME,
    SCENE_FILE,
    SCENE_MODEL_NAME,
    arm_xml,
    build_arm_spec,
    build_model,
    build_spec,
    model_textures,
    scene_xml,
    write_model_files,
    write_tag_textures,
)
from softcbf_mj.physics.mjcf.config import (
    CAMERA_LINKS_PER_SEGMENT,
    CAMERA_PHYSICS_DT,
    DEFAULT_LINKS_PER_SEGMENT,
    DEFAULT_PHYSICS_DT,
    DEFAULT_TAG_SIZE,
    DEFAULT_TAU_P,
    PAPER_H,
    PAPER_PLATE_STIFFNESS,
    PLATE_KINDS,
    ArmModelConfig,
    PAPER_h,
)
from softcbf_mj.physics.mjcf.scene import (
    CALIBRATION_BOARD_IDS,
    CAMERA_FOVY_DEG,
    CAMERA_RESOLUTION,
    calibration_board,
    overhead_camera_pose,
)
from softcbf_mj.physics.mjcf.tags import (
    ASSETS_DIR,
    TAG_PLANE_Z,
    TAG_TEXTURE_CELL_PX,
    TagPlacement,
    arm_tag_placements,
    tag_texture_file,
    tag_textures,
)

__all__ = [
    "ARM_FILE", "ASSETS_DIR", "CALIBRATION_BOARD_FILE", "CALIBRATION_BOARD_IDS", "CALIBRATION_SCENE_FILE",
    "CALIBRATION_SCENE_MODEL_NAME", "CAMERA_FOVY_DEG", "CAMERA_LINKS_PER_SEGMENT", "CAMERA_PHYSICS_DT",
    "CAMERA_RESOLUTION", "DEFAULT_LINKS_PER_SEGMENT", "DEFAULT_PHYSICS_DT", "DEFAULT_TAG_SIZE", "DEFAULT_TAU_P",
    "PAPER_H", "PAPER_PLATE_STIFFNESS", "PAPER_h", "PLATE_KINDS", "SCENE_FILE", "SCENE_MODEL_NAME",
    "TAG_PLANE_Z", "TAG_TEXTURE_CELL_PX", "ArmModelConfig", "TagPlacement", "arm_tag_placements", "arm_xml",
    "build_arm_spec", "build_model", "build_spec", "calibration_board", "model_textures", "overhead_camera_pose",
    "scene_xml", "tag_texture_file", "tag_textures", "write_model_files", "write_tag_textures",
]
