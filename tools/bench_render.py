"""Speed of the offscreen camera: ms per rendered frame of the overhead camera vs resolution.

The default scene (`mjcf.build_model()`, its offscreen buffer raised to the
largest size asked for) is rendered by `softcbf_mj.camera.render.OffscreenRenderer` with the
backend MUJOCO_GL selects (osmesa on a CPU-only machine, egl with MUJOCO_GL=egl on a
GPU). Each frame shows the arm in a new pose (both segments sweeping ±60°), so the scene
is rebuilt every frame as in a simulation. After `--warmup` frames, `--frames` frames are
timed one by one (wall clock); the median and 90th percentile are reported, with the
median time of AprilTag detection (`perception.detect.TagDetector`) on the same frames
for comparison with the camera's ~78 ms period (12.8 frames/s, docs/ground-truth.md). The default
resolution is the camera's, 1280 × 720. Usage:
`python tools/bench_render.py [--frames 30] [--warmup 3] [--sizes 640x360,1280x720,1920x1080]`;
prints a table and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import mujoco
import numpy as np

from perception.detect import TagDetector
from softcbf_mj.physics import mjcf as mb
from softcbf_mj.camera.render import OffscreenRenderer, requested_gl_backend
from timing import emit


def parse_sizes(text: str) -> list[tuple[int, int]]:
    sizes = []
    for item in text.split(","):
        try:
            width, height = (int(v) for v in item.lower().split("x"))
        except ValueError as error:
            raise argparse.ArgumentTypeError(f"sizes are WIDTHxHEIGHT separated by commas, got {item!r}") from error
        sizes.append((width, height))
    return sizes


def bench(model: mujoco.MjModel, data: mujoco.MjData, width: int, height: int, frames: int, warmup: int) -> dict[str, float]:
    detector = TagDetector(tag_ids=(0, 1, 2))
    hinges = [[model.joint(f"seg{i}_j{j}").qposadr[0] for j in range(1, mb.DEFAULT_LINKS_PER_SEGMENT + 1)] for i in (1, 2)]
    render_s, detect_s, detected = [], [], []
    with OffscreenRenderer(model, width=width, height=height) as renderer:
        for k in range(warmup + frames):
            phase = 2 * math.pi * k / max(frames, 1)
            for i, qpos in enumerate(hinges):
                data.qpos[qpos] = math.radians(60) * math.sin(phase + i) / len(qpos)
            mujoco.mj_forward(model, data)
            start = time.perf_counter()
            image = renderer.render(data)
            rendered = time.perf_counter()
            detections = detector.detect(image[:, :, ::-1])
            done = time.perf_counter()
            if k >= warmup:
                render_s.append(rendered - start)
                detect_s.append(done - rendered)
                detected.append(len(detections))
    return {
        "width": width, "height": height,
        "render_ms_median": 1e3 * float(np.median(render_s)), "render_ms_p90": 1e3 * float(np.percentile(render_s, 90)),
        "detect_ms_median": 1e3 * float(np.median(detect_s)), "arm_tags_detected_min": int(min(detected)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--sizes", type=parse_sizes, default=parse_sizes("640x360,1280x720,1920x1080"))
    args = parser.parse_args()

    spec = mb.build_spec()
    spec.visual.global_.offwidth = max(w for w, _ in args.sizes)
    spec.visual.global_.offheight = max(h for _, h in args.sizes)
    model = spec.compile()
    data = mujoco.MjData(model)
    report: dict[str, object] = {
        "backend": requested_gl_backend(), "mujoco": mujoco.__version__, "machine": platform.machine(),
        "cpus": os.cpu_count(), "default_size": list(mb.CAMERA_RESOLUTION), "frames": args.frames,
    }
    print(f"MuJoCo {mujoco.__version__}, MUJOCO_GL={report['backend']}, {args.frames} frames after {args.warmup} warm-up")
    print("  resolution    render median / p90 (ms)   detect median (ms)   arm tags found (min)")
    rows = []
    for width, height in args.sizes:
        row = bench(model, data, width, height, args.frames, args.warmup)
        rows.append(row)
        print(f"  {width:4d} x {height:<4d} {row['render_ms_median']:12.1f} / {row['render_ms_p90']:6.1f} "
              f"{row['detect_ms_median']:18.1f} {row['arm_tags_detected_min']:18d}")
    report["sizes"] = rows
    emit(report)


if __name__ == "__main__":
    main()
