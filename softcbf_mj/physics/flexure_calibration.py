"""Calibrating a flexure plate as the paper did (docs/beyond-the-paper.md#flexure-plate): a known load at the calibration point → k.

The paper hung masses on the sheet's tip and read how far it moved: k = F / δ. Here, on
the model the scenario runs (`ArmModelConfig` with `plate="flexure"`, the arm straight and
clear of the sheet), a constant force F (N) along the gauge axis n̂ (fixed in direction,
as a hanging mass's weight) acts on the sheet's surface at distance s from the clamp; the
model is stepped with its own integrator and time step until it rests (the loaded point's
deflection changes by less than `tolerance` m over 0.1 s), and

    δ = n̂ · (p(s) − p₀(s))   (m, the loaded point's displacement along the gauge axis,
                              the gauge's own compliance included),
    k(s) = F / δ (N/m),  F_gauge = k_g x_g (N, the gauge's reading; = F at rest),

with the sheet's rotation at s (rad). `calibrate_flexure` loads the calibration point
(`FlexureParams.calibration_fraction`, the free end by default) and returns the controller's
k; `load_sheet` loads any s (the stiffness along the sheet, for tests and the model README).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from softcbf_mj.physics.flexure import SheetInModel, thickness_for_tip_stiffness
from softcbf_mj.physics.mjcf import ArmModelConfig, build_model
from vocabulary.settings import setting

CALIBRATION_LOAD = setting("f_max").default  # N, the paper's calibration load: the force limit F_max

SETTLE_WINDOW_S = 0.1  # s, rest: the deflection changes by less than `tolerance` over this window
MAX_SETTLE_S = 20.0  # s of simulated time before giving up


@dataclass(frozen=True)
class SheetLoadResult:
    """A static load on a flexure: load_N (N), s_m (m from the clamp), deflection_m (m along n̂),
    stiffness_N_per_m = load / deflection, gauge_N (the gauge's reading at rest, N),
    rotation_rad (the sheet's turn at s), settle_s (simulated time to rest, s)."""

    load_N: float
    s_m: float
    deflection_m: float
    stiffness_N_per_m: float
    gauge_N: float
    rotation_rad: float
    settle_s: float


def load_sheet(config: ArmModelConfig, s: float, load: float = CALIBRATION_LOAD, facet: int = 1,
               tolerance: float = 1e-9) -> SheetLoadResult:
    """Rest the sheet of `facet` (1-based) of `config` (made a flexure) under `load` N along n̂ at s m from its clamp."""
    if not (math.isfinite(load) and load > 0):
        raise ValueError(f"load must be finite and > 0 N, got {load}")
    if not (math.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be finite and > 0 m, got {tolerance}")
    config = dataclasses.replace(config, plate="flexure")
    if not 1 <= facet <= config.n_facets:
        raise ValueError(f"facet must be in 1..{config.n_facets}, got {facet}")
    length = config.flexures()[facet - 1].length
    if not (math.isfinite(s) and 0 < s <= length):
        raise ValueError(f"s must lie in (0, {length:g}] m (the sheet's length), got {s}")
    model = build_model(config)
    data = mujoco.MjData(model)
    sheet = SheetInModel.from_model(model, facet)
    body, local = sheet.point(s)
    mujoco.mj_forward(model, data)

    def point() -> np.ndarray:
        """World position (m, (3,)) of the loaded point."""
        return data.xpos[body] + data.xmat[body].reshape(3, 3) @ local

    rest = point()
    force = np.array([*(load * sheet.normal), 0.0])
    window = max(1, int(round(SETTLE_WINDOW_S / model.opt.timestep)))
    previous = math.inf
    for _ in range(int(round(MAX_SETTLE_S / SETTLE_WINDOW_S))):
        for _ in range(window):
            data.qfrc_applied[:] = 0.0
            mujoco.mj_applyFT(model, data, force, np.zeros(3), point(), body, data.qfrc_applied)
            mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        deflection = float(sheet.normal @ (point() - rest)[:2])
        if abs(deflection - previous) < tolerance:
            break
        previous = deflection
    else:
        raise RuntimeError(f"the sheet did not come to rest within {MAX_SETTLE_S:g} s (load {load:g} N at s = {s:g} m)")
    if np.any(data.warning.number):
        raise RuntimeError(f"MuJoCo warned while loading the sheet: {data.warning.number.tolist()}")
    x_axis = data.xmat[body].reshape(3, 3)[:2, 0]
    rotation = math.atan2(sheet.normal[0] * x_axis[1] - sheet.normal[1] * x_axis[0], float(sheet.normal @ x_axis))
    return SheetLoadResult(
        load_N=load, s_m=s, deflection_m=deflection, stiffness_N_per_m=load / deflection,
        gauge_N=sheet.gauge_stiffness * float(data.qpos[sheet.gauge_qpos]), rotation_rad=rotation, settle_s=float(data.time),
    )


def calibrate_flexure(config: ArmModelConfig | None = None, load: float = CALIBRATION_LOAD, facet: int = 1) -> SheetLoadResult:
    """The paper's calibration: `load` N (default F_max) at the calibration point of `facet`'s sheet;
    `.stiffness_N_per_m` is the k to give the controller."""
    config = config or ArmModelConfig(plate="flexure")
    config = dataclasses.replace(config, plate="flexure")
    return load_sheet(config, config.flexures()[facet - 1].calibration_s, load, facet)


def fit_thickness(target: float, config: ArmModelConfig | None = None, load: float = CALIBRATION_LOAD, facet: int = 1,
                  rtol: float = 1e-4, max_iterations: int = 10) -> float:
    """The sheet thickness (m, 6 significant digits) whose `calibrate_flexure` k is `target` N/m within `rtol`.

    Starts from Euler–Bernoulli's `thickness_for_tip_stiffness` and rescales t by (target / k)^(1/3)
    (k ∝ t³ for a thin sheet) until the calibrated k is within rtol of the target.
    """
    if not (math.isfinite(target) and target > 0):
        raise ValueError(f"target must be finite and > 0 N/m, got {target}")
    config = dataclasses.replace(config or ArmModelConfig(), plate="flexure")
    flex = config.flexures()[facet - 1]
    length = flex.calibration_s
    thickness = thickness_for_tip_stiffness(target, length, flex.width, flex.youngs_modulus)
    for _ in range(max_iterations):
        flexures = list(config.flexures())
        flexures[facet - 1] = dataclasses.replace(flex, thickness=float(f"{thickness:.6g}"))
        k = calibrate_flexure(dataclasses.replace(config, flexure=tuple(flexures)), load, facet).stiffness_N_per_m
        if abs(k / target - 1) <= rtol:
            return float(f"{thickness:.6g}")
        thickness *= (target / k) ** (1.0 / 3.0)
    raise RuntimeError(f"no thickness within {max_iterations} iterations gives k = {target:g} N/m (last {k:.6g} N/m)")
