"""Convergence of the MuJoCo ground truth in links per segment n and physics step dt.

Three dynamic runs of the reference robot (1 kHz zero-order-hold control, `duration`
seconds each), every setting compared with the finest one (n = 40, dt = 10 µs) of the
same integrator:

- `chirp`: no plate; u_1 = A sin 2πφ(t), u_2 = −A sin(2πφ(t) + π/3), a linear chirp
  φ' = 0.2 → 5 Hz over the run (A = 120 hPa): the first modes and large bends;
- `contact`: the paper's plate (docs/model.md#force-safe-set); u = (120, 120) hPa from t = 0 (the tip strikes
  the plate at speed and deflects it ≈ 46 mm), then (−60, 60) hPa from half-time (an
  abrupt release: the plate springs back and rings); pressure dynamics τ_p = 0.05 s;
- `contact_ideal`: the same with an ideal actuator (τ_p = 0), the harshest case.

Figures per setting: the max over the run of the tip error ‖r − r_ref‖ (m), of the
plate-force error |F − F_ref| (N) and the error of the force peak (N), with the wall
time. Usage: `python tools/convergence_study.py [--integrator discrete] [--duration 3]`;
prints tables and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT
from softcbf_mj.physics.mujoco_plant import MujocoPlant

CONTROL_DT = 1e-3  # s
FINEST = (40, 1e-5)  # (n, dt s): the reference setting
AMPLITUDE = 120.0  # hPa
CHIRP_F0, CHIRP_F1 = 0.2, 5.0  # Hz
NO_PLATE = dict(H=np.zeros((0, 2)), h=())


def chirp_command(t: float, duration: float) -> np.ndarray:
    """Pressures (hPa) of the chirp run at time t (s)."""
    phase = 2 * np.pi * (CHIRP_F0 * t + (CHIRP_F1 - CHIRP_F0) * t * t / (2 * duration))
    return np.array([AMPLITUDE * np.sin(phase), -AMPLITUDE * np.sin(phase + np.pi / 3)])


def contact_command(t: float, duration: float) -> np.ndarray:
    """Pressures (hPa) of the contact runs at time t (s): press, then release at half-time."""
    return np.array([AMPLITUDE, AMPLITUDE]) if t < duration / 2 else np.array([-60.0, 60.0])


RUNS = {  # name: (command, model fields)
    "chirp": (chirp_command, NO_PLATE),
    "contact": (contact_command, {}),
    "contact_ideal": (contact_command, dict(tau_p=0.0)),
}


def simulate(run: str, n: int, dt: float, duration: float, integrator: str) -> dict[str, np.ndarray]:
    """Tip (T, 2) in m and plate forces (T, P) in N at every control step of `run`."""
    command, fields = RUNS[run]
    plant = MujocoPlant.from_config(
        None, CONTROL_DT, links_per_segment=n, physics_dt=dt, integrator=integrator, **fields
    )
    plant.reset(np.zeros(plant.n_segments))
    steps = int(round(duration / CONTROL_DT))
    tip, force = np.zeros((steps, 2)), np.zeros((steps, plant.n_facets))
    for k in range(steps):
        state = plant.step(command(k * CONTROL_DT, duration))
        tip[k], force[k] = state.tip, state.contact_forces
    return {"tip": tip, "force": force}


def errors(result: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> dict[str, float]:
    """Max tip error (m); with plates also the max force error and the force-peak error (N)."""
    out = {"tip_err_m": float(np.max(np.linalg.norm(result["tip"] - reference["tip"], axis=1)))}
    if result["force"].size:
        out["force_err_N"] = float(np.max(np.abs(result["force"] - reference["force"])))
        out["peak_force_err_N"] = float(abs(result["force"].max() - reference["force"].max()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per run (default 3)")
    parser.add_argument("--links", default="5,10,20", help="links per segment to try at the finest dt")
    parser.add_argument("--dts", default="1e-3,5e-4,2.5e-4,1e-4,5e-5,2.5e-5", help="physics steps (s) to try at the finest n")
    parser.add_argument("--integrator", default="implicitfast", help="MuJoCo integrator (default implicitfast)")
    parser.add_argument("--runs", default=",".join(RUNS), help=f"runs to do (default {','.join(RUNS)})")
    args = parser.parse_args()
    default = (DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT)
    settings = [(int(n), FINEST[1]) for n in args.links.split(",")]
    settings += [(FINEST[0], float(dt)) for dt in args.dts.split(",")]
    settings += [default] if default not in settings else []

    report: dict[str, object] = {
        "integrator": args.integrator, "duration_s": args.duration,
        "finest": {"n": FINEST[0], "dt": FINEST[1]}, "default": {"n": default[0], "dt": default[1]},
    }
    for run in args.runs.split(","):
        t0 = time.perf_counter()
        reference = simulate(run, *FINEST, args.duration, args.integrator)
        peak = float(reference["force"].max()) if reference["force"].size else None
        print(f"\n{run} ({args.integrator}): finest n={FINEST[0]} dt={FINEST[1]:g} s, {time.perf_counter() - t0:.1f} s wall"
              + (f", peak plate force {peak:.4f} N" if peak is not None else ""))
        print("    n       dt/s   tip err/mm   force err/mN   peak err/mN   wall/s")
        rows = []
        for n, dt in settings:
            t0 = time.perf_counter()
            row = {"n": n, "dt": dt, **errors(simulate(run, n, dt, args.duration, args.integrator), reference)}
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
            force = f"{row['force_err_N'] * 1e3:14.3f}{row['peak_force_err_N'] * 1e3:14.3f}" if "force_err_N" in row else " " * 28
            mark = "  <- default" if (n, dt) == default else ""
            print(f"  {n:3d}  {dt:9.2e}  {row['tip_err_m'] * 1e3:11.4f}{force}  {row['wall_s']:7.1f}{mark}")
        report[run] = {"peak_force_N": peak, "rows": rows}
    print(json.dumps(report))


if __name__ == "__main__":
    main()
