"""Calibrate a flexure plate as the paper did: a known load at the calibration point → the controller's k.

The paper hung masses on its ABS sheet's tip and read how far the tip moved; here a constant
force of `--load` N along the gauge axis rests on the MuJoCo sheet at its calibration point
(`softcbf_mj.physics.flexure_calibration.calibrate_flexure`; the sheet of `mujoco_contact --plate flexure`
with the same `--sheet-*` values) and k = F / δ is the stiffness to give the controller
(`--assumed-plate-stiffness`). Also printed: the gauge's reading at rest (= the load), the
sheet's rotation there, Euler–Bernoulli's 3EI/s³ and the hinge chain's small-deflection
stiffness. `--fit K` instead finds the thickness whose calibrated k is K N/m
(`fit_thickness`; how the default sheet's thickness was chosen: `--fit 11.16`).

Usage: `python tools/calibrate_flexure.py [--load 0.16] [--sheet-thickness 1.23044e-3 …] [--fit 11.16]`;
ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

from softcbf_mj.physics.flexure import FlexureParams
from softcbf_mj.physics.flexure_calibration import calibrate_flexure, fit_thickness
from softcbf_mj.physics.mjcf import ArmModelConfig

SHEET_FIELDS = ("clamp_at", "free_end_at", "thickness", "width", "youngs_modulus", "links", "calibration_fraction")


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--load", type=float, default=0.16, help="the known load at the calibration point, N (default 0.16, F_max)")
    parser.add_argument("--fit", type=float, default=None, help="find the thickness whose calibrated k is this, N/m")
    defaults = FlexureParams()
    for name in SHEET_FIELDS:
        parser.add_argument(f"--sheet-{name.replace('_', '-')}", type=type(getattr(defaults, name)), default=getattr(defaults, name),
                            help=f"FlexureParams.{name} (default {getattr(defaults, name)})")
    args = parser.parse_args(argv)
    flex = FlexureParams(**{name: getattr(args, f"sheet_{name}") for name in SHEET_FIELDS})
    config = ArmModelConfig(plate="flexure", flexure=flex)
    out: dict = {"load_N": args.load, "sheet": dataclasses.asdict(flex)}
    if args.fit is not None:
        thickness = fit_thickness(args.fit, config, args.load)
        flex = dataclasses.replace(flex, thickness=thickness)
        config = dataclasses.replace(config, flexure=flex)
        out["fitted_thickness_m"] = thickness
        print(f"thickness for k = {args.fit:g} N/m at {args.load:g} N: {thickness * 1e3:.6g} mm")
    result = calibrate_flexure(config, args.load)
    s = flex.calibration_s
    out.update(dataclasses.asdict(result))
    out["euler_bernoulli_N_per_m"] = float(flex.euler_bernoulli_stiffness(s))
    out["chain_small_deflection_N_per_m"] = float(flex.chain_stiffness(s))
    print(f"sheet {flex.length * 1e3:g} mm × {flex.width * 1e3:g} mm × {flex.thickness * 1e3:.6g} mm, E = {flex.youngs_modulus:g} Pa, "
          f"{flex.links} links; calibration point {s * 1e3:g} mm from the clamp")
    print(f"load {args.load:g} N → deflection {result.deflection_m * 1e3:.4f} mm, k = {result.stiffness_N_per_m:.4f} N/m "
          f"(Euler–Bernoulli 3EI/s³ {out['euler_bernoulli_N_per_m']:.4f}, chain small-deflection {out['chain_small_deflection_N_per_m']:.4f}); "
          f"gauge {result.gauge_N:.6f} N, rotation {result.rotation_rad:.4f} rad")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
