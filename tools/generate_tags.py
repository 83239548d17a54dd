"""Write the AprilTag textures of the default model: models/softcbf_arm/assets/tag{id}.png.

One PNG per tag the model uses — the arm's tags 0..N (base, segment ends) and the
calibration board's 10..21 — each `perception.tags.tag_image(id)` at
`model_builder.TAG_TEXTURE_CELL_PX` px per cell (36h11: 8 cells plus one white quiet cell on
each side, 160 × 160 px), grey, PNG-encoded by OpenCV; the same ids always give the same
bytes, and in-memory models carry the same bytes (`model_builder.tag_textures`).
`tools/generate_model.py` writes them too, with the XML. Usage:
`python tools/generate_tags.py [--out DIR]` (files go to DIR/assets/).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softcbf_mj.model_builder import write_tag_textures

DEFAULT_DIR = Path(__file__).resolve().parents[1] / "models" / "softcbf_arm"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=DEFAULT_DIR, help=f"model folder (default {DEFAULT_DIR})")
    args = parser.parse_args()
    for path in write_tag_textures(args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
