"""Speed of the camera in the loop: render + detect + estimate per frame, and `camera_loop`'s real-time factor.

Runs the `camera_loop` scenario (defaults unless overridden: 1280 × 720 at 12.8 frames/s,
10 Hz loop, the camera rod of 5 links at 0.2 ms, 2 ms tick, window tracking) for
`--duration` s from `--t0` (the default window, 15–45 s of the paper's sinusoid, holds the
first contact) into a temporary folder, without report and recording, and prints per
tuning: the median wall time per frame of rendering, detection and estimation (ms) and
their sum, the camera's share of the run's wall time, and the real-time factor RTF =
simulated s / wall s of the closed loop (`realtime_factor` in summary.json; the
target: ≥ 2 on CPU at 12.8 fps). MUJOCO_GL picks the renderer (osmesa on CPU, egl on a GPU).

    python tools/bench_camera_loop.py [--duration 30] [--t0 15] [--width 1280 --height 720] [--tracking true]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

import softcbf_mj  # noqa: F401  (chooses MUJOCO_GL before mujoco is imported)
import mujoco

from scenarios import get
from scenarios.common import data_only
from softcbf_mj.outputs.runio import load_timeseries
from timing import emit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--t0", type=float, default=15.0)
    parser.add_argument("--tunings", default="None,HW-Low,HW-High")
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--tracking", choices=("true", "false"), default="true")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp, data_only():
        summary = get("camera_loop").run(
            Path(tmp), duration=args.duration, t0=args.t0, tunings=args.tunings, width=args.width, height=args.height,
            tracking=args.tracking == "true", saved_frames_hz=0.0, progress=False,
        )
        rows = []
        for run in summary["runs"]:
            frames, _ = load_timeseries(Path(tmp) / run["frames_timeseries"])
            taken = ~frames["dropped"]
            per_frame = float((frames["render_ms"] + frames["detect_ms"] + frames["estimate_ms"])[taken].mean())
            rows.append({
                "tuning": run["tuning"], "rtf": run["realtime_factor"], "render_ms": run["render_ms_median"],
                "detect_ms": run["detect_ms_median"], "estimate_ms": run["estimate_ms_median"],
                "camera_ms_per_frame_mean": per_frame,
                "camera_share_of_wall": float(frames["render_ms"][taken].sum() + frames["detect_ms"][taken].sum()
                                              + frames["estimate_ms"][taken].sum()) / 1e3 / run["wall_s"],
            })

    print(f"camera_loop, {args.duration:g} s from t0 = {args.t0:g} s, {args.width}x{args.height}, "
          f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, tracking {args.tracking}, MuJoCo {mujoco.__version__}")
    print(f"{'tuning':>8} {'render':>8} {'detect':>8} {'estimate':>9} {'frame sum':>10} {'camera share':>13} {'RTF':>6}")
    for r in rows:
        print(f"{r['tuning']:>8} {r['render_ms']:8.2f} {r['detect_ms']:8.2f} {r['estimate_ms']:9.3f} "
              f"{r['camera_ms_per_frame_mean']:10.2f} {r['camera_share_of_wall']:13.2f} {r['rtf']:6.2f}")
    worst = min(r["rtf"] for r in rows)
    print(f"slowest tuning: RTF {worst:.2f} (target >= 2: {'met' if worst >= 2 else 'NOT met'})")
    emit({"mujoco_gl": os.environ.get("MUJOCO_GL"), "machine": platform.machine(), "cpus": os.cpu_count(),
          "width": args.width, "height": args.height, "duration_s": args.duration, "t0_s": args.t0,
          "tracking": args.tracking == "true", "runs": rows, "rtf_min": worst, "target_rtf": 2.0})


if __name__ == "__main__":
    main()
