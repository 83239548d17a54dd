"""Calibrate the PCC model's K, D, Λ (docs/model.md#rppr-dynamics) and write a robot JSON the controller loads.

Two sources of data (maths and conventions in `softcbf_mj/physics/calibration.py`):
- MuJoCo (default): motor babbling (seeded random pressure steps plus chirps within the
  pressure limits) of the ground-truth arm built WITHOUT plates (no contact), recorded
  at the control rate: q, q̇ from the rod's tendons, u = the pressure acting (after the
  first-order pressure dynamics). `--save-recording FILE.npz` keeps the arrays.
- Recorded arrays: `--data FILE.npz` with t (T,) s, q (T, N) rad, u (T, N) hPa and
  optionally qd (T, N) rad/s, e.g. from the camera; `--u-kind command --tau-p S` if u
  holds zero-order-held commands rather than measured pressures.

The fit takes M and C from the controller's PCC model of `--robot` (its masses, lengths
and inertias) and writes `--out` with `RobotParams.save`: `--robot` with stiffness,
damping and gains replaced. Beside it, `<out>.fit.json` holds the fit quality (R² per
equation, residual RMS, relative errors against `--robot`) and, for MuJoCo data, the
same fit with the rod's own constant-curvature inertia (the check of the method: that
one recovers the values the rod was built with; the difference is the PCC model's
inertia error, see models/softcbf_arm/README.md). Prints the tables and ends with one
line of JSON.

Usage: `python tools/calibrate.py --out robot.json [--duration 60] [--seed 0]`
or `python tools/calibrate.py --out robot.json --data camera.npz [--u-kind command --tau-p 0.05]`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from scenarios.common import load_robot
from softcbf_mj.physics import calibration as cal
from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT, DEFAULT_TAU_P
from softcbf_mj.outputs.runio import write_json


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="robot JSON to write (RobotParams.save format)")
    parser.add_argument("--robot", default="reference", help="nominal robot: M's masses/lengths/inertias, limits, reference values")
    parser.add_argument("--data", type=Path, help="fit recorded arrays from this .npz instead of simulating MuJoCo")
    parser.add_argument("--u-kind", choices=("pressure", "command"), default="pressure", help="what --data's u is")
    parser.add_argument("--tau-p", type=float, default=None,
                        help=f"pressure time constant (s): of --data's commands (default 0), or of the MuJoCo arm (default {DEFAULT_TAU_P})")
    parser.add_argument("--p0", type=float, default=0.0, help="pressure acting at t[0] for --u-kind command (hPa)")
    parser.add_argument("--duration", type=float, default=60.0, help="MuJoCo babbling duration (s)")
    parser.add_argument("--seed", type=int, default=0, help="babbling seed")
    parser.add_argument("--control-dt", type=float, default=1e-3, help="MuJoCo sampling / command period (s)")
    parser.add_argument("--links-per-segment", type=int, default=DEFAULT_LINKS_PER_SEGMENT)
    parser.add_argument("--physics-dt", type=float, default=DEFAULT_PHYSICS_DT)
    parser.add_argument("--save-recording", type=Path, help="write the MuJoCo recording here (.npz: t, q, qd, u, command)")
    parser.add_argument("--window-s", type=float, default=0.021, help="smoothing window (s)")
    parser.add_argument("--polyorder", type=int, default=3, help="smoothing polynomial degree")
    parser.add_argument("--skip-s", type=float, default=0.0, help="seconds dropped at the start")
    args = parser.parse_args(argv)

    nominal = load_robot(args.robot)
    fit_options = dict(window_s=args.window_s, polyorder=args.polyorder, skip_s=args.skip_s)
    report: dict = {"robot_file": str(args.out), "nominal": args.robot}
    rod_fit = None
    if args.data is not None:
        arrays = cal.load_arrays(args.data)
        report["source"] = {"data": str(args.data), "u_kind": args.u_kind, "tau_p": args.tau_p or 0.0}
        result = cal.fit_pcc_parameters(
            arrays["t"], arrays["q"], arrays["u"], nominal, arrays.get("qd"),
            u_kind=args.u_kind, tau_p=args.tau_p or 0.0, p0=args.p0, **fit_options,
        )
    else:
        tau_p = DEFAULT_TAU_P if args.tau_p is None else args.tau_p
        plant = cal.free_mujoco_plant(
            control_dt=args.control_dt, links_per_segment=args.links_per_segment, physics_dt=args.physics_dt, tau_p=tau_p
        )
        commands = cal.babbling_commands(args.duration, args.control_dt, plant.u_min, plant.u_max, seed=args.seed)
        start = time.perf_counter()
        recording = cal.record(plant, commands)
        print(f"MuJoCo babbling: {args.duration:g} s, seed {args.seed}, n = {args.links_per_segment}, "
              f"dt = {args.physics_dt:g} s, tau_p = {tau_p:g} s ({time.perf_counter() - start:.1f} s wall)")
        if args.save_recording is not None:
            recording.save(args.save_recording)
        report["source"] = {"mujoco": {"duration_s": args.duration, "seed": args.seed, "links_per_segment": args.links_per_segment,
                                       "physics_dt": args.physics_dt, "tau_p": tau_p, "control_dt": args.control_dt}}
        result = cal.fit_pcc_parameters(recording.t, recording.q, recording.u, nominal, recording.qd, **fit_options)
        rod_fit = cal.fit_pcc_parameters(recording.t, recording.q, recording.u, nominal, recording.qd,
                                         inertial_torque=cal.rod_inertial_torque(plant), **fit_options)

    result.params.save(args.out)
    report["fit"] = result.to_dict()
    print(f"\nfit with the controller's PCC inertia ({result.samples} samples, window {result.window} samples) -> {args.out}")
    print(result.table())
    if rod_fit is not None:
        report["fit_rod_inertia"] = rod_fit.to_dict()
        print("\ncheck: the same fit with the rod's own constant-curvature inertia (errors vs the values the rod was built with)")
        print(rod_fit.table())
    write_json(args.out.with_suffix(".fit.json"), report)
    summary = {
        "robot_file": str(args.out),
        "relative_error": result.relative_errors(),
        "r2": [s.r2 for s in result.segments],
        "residual_rms_Nm": [s.residual_rms for s in result.segments],
    }
    if rod_fit is not None:
        summary["rod_inertia_relative_error"] = rod_fit.relative_errors()
    print(json.dumps(summary))
    return report


if __name__ == "__main__":
    main()
