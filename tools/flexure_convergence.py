"""Convergence of the flexure plate (docs/beyond-the-paper.md#flexure-plate) in its links n and the physics step dt.

Statics (dt does not matter at rest): for each n, the sheet's stiffness k(s) = F / δ under
a load F along the gauge axis at s from the clamp (`softcbf_mj.physics.flexure_calibration.load_sheet`),
against Euler–Bernoulli's 3 EI / s³ and the finest n, at a small load (0.01 N: linear) and
at F_max (0.16 N, the paper's limit: ≈ 14 mm at the tip, large-deflection stiffening).

Dynamics: the reference arm (10 links per segment) presses the default sheet, u = (80,
80) hPa (the paper's amplitude) from t = 0 (the tip strikes the sheet at speed) and
releases at half-time with (−60, 60) hPa (the sheet springs back and rings), τ_p = 0.05 s;
every (n, dt) is compared with the finest (n = 80, dt = 10 µs): max over the run of the
gauge-force error, the true-contact-force error (MuJoCo's normal force) and the tip error,
the gauge error at rest (the end of the press), with MuJoCo's warnings. The arm's own
discretisation is fixed (its study: tools/convergence_study.py).

Usage: `python tools/flexure_convergence.py [--duration 2] [--links 5,10,20,40,80] [--dts 2e-4,1e-4,5e-5]`;
prints tables and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from softcbf_mj.physics.flexure import FlexureParams
from softcbf_mj.physics.flexure_calibration import load_sheet
from softcbf_mj.physics.mjcf import ArmModelConfig, build_model
from softcbf_mj.physics.mujoco_plant import MujocoPlant

CONTROL_DT = 1e-3  # s
FINEST = (80, 1e-5)  # (sheet links, dt s)
PRESS, RELEASE = (80.0, 80.0), (-60.0, 60.0)  # hPa
POINTS = (0.05, 0.10, 0.12, 0.14, 0.15)  # m from the clamp (the arm touches at 0.10–0.15 m)
LOADS = (0.01, 0.16)  # N


def sheet_config(links: int, dt: float) -> ArmModelConfig:
    return ArmModelConfig(plate="flexure", flexure=dataclasses.replace(FlexureParams(), links=links), physics_dt=dt)


def simulate(links: int, dt: float, duration: float) -> dict[str, np.ndarray]:
    """Gauge force (T,), true normal force (T,), tip (T, 2) and warnings of the press-and-release run."""
    plant = MujocoPlant(build_model(sheet_config(links, dt)), CONTROL_DT)
    plant.reset(np.zeros(plant.n_segments))
    steps = int(round(duration / CONTROL_DT))
    out = {"gauge": np.zeros(steps), "true": np.zeros(steps), "tip": np.zeros((steps, 2))}
    for k in range(steps):
        state = plant.step(np.array(PRESS if k * CONTROL_DT < duration / 2 else RELEASE))
        out["gauge"][k], out["true"][k], out["tip"][k] = state.contact_forces[0], state.extras["force_solver_N"][0], state.tip
    out["warnings"] = int(np.sum(plant.data.warning.number))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=2.0, help="seconds of the dynamic run (default 2)")
    parser.add_argument("--links", default="5,10,20,40,80", help="sheet links to try")
    parser.add_argument("--dts", default="2e-4,1e-4,5e-5", help="physics steps (s) to try at n = 10 and at the finest n")
    args = parser.parse_args()
    links = [int(n) for n in args.links.split(",")]
    dts = [float(dt) for dt in args.dts.split(",")]
    flex = FlexureParams()
    report: dict[str, object] = {"finest": {"links": FINEST[0], "dt": FINEST[1]}, "statics": [], "dynamics": []}

    print("statics: k(s) = F/δ (N/m) against Euler–Bernoulli 3EI/s³ and the finest n")
    print("    n   load/N    s/m      k/(N/m)   vs EB/%   vs finest/%")
    finest = {(load, s): load_sheet(sheet_config(FINEST[0], 1e-4), s, load).stiffness_N_per_m for load in LOADS for s in POINTS}
    for n in links:
        for load in LOADS:
            for s in POINTS:
                k = load_sheet(sheet_config(n, 1e-4), s, load).stiffness_N_per_m
                eb = float(flex.euler_bernoulli_stiffness(s))
                row = {"links": n, "load_N": load, "s_m": s, "k_N_per_m": k, "vs_eb_pct": 100 * (k / eb - 1),
                       "vs_finest_pct": 100 * (k / finest[(load, s)] - 1)}
                report["statics"].append(row)
                print(f"  {n:3d}  {load:7.3f}  {s:6.3f}  {k:10.4f}  {row['vs_eb_pct']:8.3f}  {row['vs_finest_pct']:10.3f}")

    t0 = time.perf_counter()
    reference = simulate(*FINEST, args.duration)
    print(f"\ndynamics: press and release, {args.duration:g} s; finest n={FINEST[0]} dt={FINEST[1]:g} s "
          f"({time.perf_counter() - t0:.0f} s wall), peak gauge {reference['gauge'].max():.4f} N, "
          f"peak true {reference['true'].max():.4f} N, gauge at rest {reference['gauge'][int(round(args.duration / 2 / CONTROL_DT)) - 1]:.4f} N")
    print("    n       dt/s   gauge err/mN   true err/mN   tip err/mm   rest err/mN   warnings   wall/s")
    rest = int(round(args.duration / 2 / CONTROL_DT)) - 1  # the last step of the press
    settings = [(n, FINEST[1] if n != FINEST[0] else dts[-1]) for n in links if n != FINEST[0]]
    settings += [(n, dt) for n in (10, 20) for dt in dts]
    for n, dt in sorted(set(settings)):
        t0 = time.perf_counter()
        result = simulate(n, dt, args.duration)
        row = {"links": n, "dt": dt, "gauge_err_N": float(np.max(np.abs(result["gauge"] - reference["gauge"]))),
               "true_err_N": float(np.max(np.abs(result["true"] - reference["true"]))),
               "tip_err_m": float(np.max(np.linalg.norm(result["tip"] - reference["tip"], axis=1))),
               "rest_gauge_err_N": float(abs(result["gauge"][rest] - reference["gauge"][rest])),
               "warnings": result["warnings"], "wall_s": time.perf_counter() - t0}
        report["dynamics"].append(row)
        print(f"  {n:3d}  {dt:9.2e}  {row['gauge_err_N'] * 1e3:12.3f}  {row['true_err_N'] * 1e3:12.3f}  "
              f"{row['tip_err_m'] * 1e3:10.4f}  {row['rest_gauge_err_N'] * 1e3:12.3f}  {row['warnings']:8d}  {row['wall_s']:7.1f}")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
