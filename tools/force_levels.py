"""The step levels of the benchmark's contact tasks (softcbf/bench.py `PUSHES`, docs/beyond-the-paper.md#contact-tasks).

"A push asking for F" is a constant step command u_nom = (L, …, L) hPa from rest whose
unfiltered plant settles at the measured force F (N). This script finds L once per plant
(mujoco_contact and camera_loop at their defaults, filter "none", nominal "step" with
low_hPa = high_hPa = L) and asked ratio F/F_max, and the steady force of the force-target
nominal; the printed values are pasted into softcbf/bench.py, where they are stored with the
cases (the bench never searches them itself).

Procedure: the steady force of a level is `softcbf.bench.steady_force` (the mean measured
force over the last third) of a push as long as the bench's (PROBE_S = `PUSH_DURATION_S`,
6 s). Under a step the unfiltered arm settles within 0.5 s (mujoco_contact at 100 hPa:
0.3902 N from t = 0.75 s on, to 4 digits); the force-target nominal needs ≈ 4 s (its integral
ramps the pressure to first contact; a 3 s probe read 0.074 N where 6 s read 0.094 N).
Beyond first contact the steady force rises monotonically with L; the level is found by the
secant method on F(L) − F started from 60 and 100 hPa, kept inside [0, 150] hPa, until
|F(L) − F| ≤ TOLERANCE · F_max (0.2 %) or MAX_PROBES probes (then it stops with an error).
Run 2026-12-03 (≈ 6 min): the values in `PUSHES`.

    PYTHONPATH=. python tools/force_levels.py            # every plant, prints one JSON object
    PYTHONPATH=. python tools/force_levels.py --plants mujoco_contact
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from softcbf.bench import (FORCE_TARGET_RATIO, PUSH_DURATION_S, PUSH_PLANTS, PUSH_RATIOS, plant_parameters,
                          steady_force_of_folder)

PROBE_S = PUSH_DURATION_S
TOLERANCE = 2e-3
MAX_PROBES = 12
F_MAX_N = 0.16  # the plants' default F_max (mujoco_contact and camera_loop: f_max = 0.16 N)


def probe(plant: str, nominal: str, nominal_params: str) -> float:
    """The unfiltered plant's steady measured force (N) under the nominal."""
    from scenarios import get

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "run"
        folder.mkdir()
        get(plant).run(folder, duration=PROBE_S, filter="none", nominal=nominal, nominal_params=nominal_params,
                       progress=False, **plant_parameters(plant))
        return steady_force_of_folder(folder)


def push_level(plant: str, ratio: float) -> tuple[float, float]:
    """(L hPa, its steady force N) with |F(L) − ratio·F_max| ≤ TOLERANCE·F_max (module docstring)."""
    goal = ratio * F_MAX_N
    force = lambda level: probe(plant, "step", f"seed=0;low_hPa={level!r};high_hPa={level!r}")  # noqa: E731
    a, b = 60.0, 100.0
    fa, fb = force(a), force(b)
    for _ in range(MAX_PROBES):
        if abs(fb - goal) <= TOLERANCE * F_MAX_N:
            return b, fb
        slope = (fb - fa) / (b - a)
        if not slope > 0.0:
            raise RuntimeError(f"{plant}: the steady force does not rise between {a} and {b} hPa ({fa}, {fb} N)")
        a, fa = b, fb
        b = min(max(b + (goal - fb) / slope, 0.0), 150.0)
        fb = force(b)
    raise RuntimeError(f"{plant}: no level within {TOLERANCE} F_max of {goal} N after {MAX_PROBES} probes")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", default=",".join(PUSH_PLANTS), help="comma separated plants")
    args = parser.parse_args(argv)
    out = {}
    for plant in args.plants.split(","):
        levels = {}
        for ratio in PUSH_RATIOS:
            level, force = push_level(plant, ratio)
            levels[f"{ratio:g}"] = {"level_hPa": round(level, 3), "steady_N": round(force, 5)}
            print(f"{plant}: asking {ratio:g} F_max: {level:.3f} hPa -> {force:.5f} N", flush=True)
        full = probe(plant, "step", "seed=0;low_hPa=150;high_hPa=150")
        target = probe(plant, "force-target", f"target_N={FORCE_TARGET_RATIO * F_MAX_N!r}")
        print(f"{plant}: 150 hPa -> {full:.5f} N; force-target {FORCE_TARGET_RATIO:g} F_max -> {target:.5f} N", flush=True)
        out[plant] = {"levels": levels, "full_push_N": round(full, 5), "force_target_N": round(target, 5)}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
