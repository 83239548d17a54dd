"""Write the default MuJoCo model folder models/softcbf_arm/ (XML, calibration board, tag textures).

The files come from `softcbf_mj.physics.mjcf` with `ArmModelConfig()` defaults (the
reference robot, the paper's plate, the chosen links per segment and physics step, 30 mm
tags): `softcbf_arm.xml`, `scene.xml`, `scene_calibration.xml`, its board
`scene_calibration_board.json` and the tag textures `assets/tag{id}.png` (36h11, from OpenCV's dictionary via
`perception.tags.tag_image`). The same parameters always give the same bytes.
Usage: `python tools/generate_model.py [--out DIR]`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softcbf_mj.physics.mjcf import write_model_files

DEFAULT_DIR = Path(__file__).resolve().parents[1] / "models" / "softcbf_arm"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=DEFAULT_DIR, help=f"output folder (default {DEFAULT_DIR})")
    args = parser.parse_args()
    for path in write_model_files(args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
