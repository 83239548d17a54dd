"""Write the default MuJoCo model files (models/softcbf_arm/softcbf_arm.xml and scene.xml).

The files come from `softcbf_mj.model_builder` with `ArmModelConfig()` defaults (the
reference robot, the paper's plate, the chosen links per segment and physics step);
the same parameters always give the same bytes. Usage:
`python tools/generate_model.py [--out DIR]`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softcbf_mj.model_builder import write_model_files

DEFAULT_DIR = Path(__file__).resolve().parents[1] / "models" / "softcbf_arm"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=DEFAULT_DIR, help=f"output folder (default {DEFAULT_DIR})")
    args = parser.parse_args()
    for path in write_model_files(args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
